"""`jax.export` round trips of voxelize's value, gradient and directional derivative.

The exported functions are serialized here and run in a fresh Python process (which only
imports voxax to register the kernels); the results must be the same bits as here.
"""

import os
import subprocess
import sys
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import voxax
from voxax import _kernels

pytest.importorskip("flatbuffers")

_RUNNER = r"""
import sys
import jax
jax.config.update("jax_enable_x64", True)
import numpy as np
import voxax  # registers the FFI targets
data = np.load(sys.argv[1])
out = {}
for name in ("forward", "grad", "jvp", "forward32"):
    exp = jax.export.deserialize(bytearray(open(sys.argv[2] + "." + name, "rb").read()))
    args = [data[name + "_arg%d" % i] for i in range(len(exp.in_avals))]
    out[name] = np.asarray(exp.call(*args))
np.savez(sys.argv[3], **out)
"""


def _functions():
    rng = np.random.default_rng(5)
    mesh = voxax.data.icosphere(2, radius=0.6)
    v = np.asarray(mesh.vertices) + 0.02 * rng.normal(size=mesh.vertices.shape)
    f = np.asarray(mesh.faces)
    grid = voxax.Grid(lower=(-0.8, -0.7, -0.75), upper=(0.7, 0.8, 0.72), shape=(9, 8, 10))
    c = rng.normal(size=grid.shape)
    t = rng.normal(size=v.shape)
    poly = voxax.data.star_polyline()
    g2 = voxax.Grid.cube(12, dim=2)
    fns = {
        "forward": (jax.jit(lambda x: voxax.voxelize(x, f, grid)), (v,)),
        "grad": (jax.jit(jax.grad(lambda x: jnp.sum(c * jnp.sin(voxax.voxelize(x, f, grid))))), (v,)),
        "jvp": (jax.jit(lambda x, tt: jax.jvp(lambda y: voxax.voxelize(y, f, grid), (x,), (tt,))), (v, t)),
        "forward32": (
            jax.jit(lambda x: voxax.voxelize(x, poly.faces, g2)),
            (np.asarray(poly.vertices, np.float32),),
        ),
    }
    return fns


def test_safety_checks_cover_every_target():
    checks = voxax.export_safety_checks()
    assert len(checks) == len(_kernels.TARGETS) == len(set(_kernels.TARGETS))
    assert {"voxax_forward", "voxax_backward", "voxax_tangent", "voxax_marching_cubes"} <= set(voxax.ffi_targets())
    # Every registered target is a symbol of the kernel library.
    lib = voxax._kernels.library()
    assert all(hasattr(lib, name) for name in voxax.ffi_targets())
    # Every registered target is an exported symbol of the library.
    import ctypes

    lib = ctypes.CDLL(str(_kernels.library_path()))
    for name in _kernels.TARGETS:
        assert hasattr(lib, name)
    # Without the checks, export refuses the custom calls.
    fn = jax.jit(lambda x: voxax.voxelize(x, voxax.data.box().faces, voxax.Grid.cube(3)))
    spec = jax.ShapeDtypeStruct((8, 3), jnp.float64)
    with pytest.raises(ValueError, match="custom calls"):
        jax.export.export(fn)(spec).serialize()


def test_round_trip_in_fresh_process(tmp_path):
    data = {}
    expected = {}
    base = str(tmp_path / "fn")
    for name, (fn, args) in _functions().items():
        specs = [jax.ShapeDtypeStruct(a.shape, a.dtype) for a in args]
        exp = jax.export.export(fn, disabled_checks=voxax.export_safety_checks())(*specs)
        text = exp.mlir_module()
        if name in ("forward", "forward32"):
            assert "voxax_forward" in text
        if name == "grad":
            assert "voxax_backward" in text
        if name == "jvp":
            assert "voxax_tangent" in text
        Path(base + "." + name).write_bytes(exp.serialize())
        for i, a in enumerate(args):
            data[f"{name}_arg{i}"] = a
        result = fn(*args)
        expected[name] = np.asarray(result[1] if name == "jvp" else result)
    np.savez(tmp_path / "inputs.npz", **data)
    # The jvp's exported function returns (W, dW); the runner keeps dW.
    runner = _RUNNER.replace('out[name] = np.asarray(exp.call(*args))',
                             'res = exp.call(*args)\n    out[name] = np.asarray(res[1] if name == "jvp" else res)')
    env = dict(os.environ)
    env["PYTHONPATH"] = os.pathsep.join([str(Path(voxax.__file__).resolve().parent.parent), env.get("PYTHONPATH", "")])
    proc = subprocess.run(
        [sys.executable, "-c", runner, str(tmp_path / "inputs.npz"), base, str(tmp_path / "out.npz")],
        env=env, capture_output=True, text=True, timeout=300, check=False,
    )
    assert proc.returncode == 0, proc.stderr[-4000:]
    with np.load(tmp_path / "out.npz") as z:
        for name, want in expected.items():
            got = z[name]
            assert got.dtype == want.dtype and got.shape == want.shape, name
            assert np.abs(want).max() > 0, name
            np.testing.assert_array_equal(got, want, err_msg=name)
