"""One grid across devices: `voxelize_sharded`, `voxelize_slab`, `slab_grids`."""

import os
import subprocess
import sys
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from jax.sharding import Mesh

import voxax


def test_slabs_share_the_grid_planes():
    g = voxax.Grid(lower=(-0.9, -1.0, -0.8), upper=(1.0, 0.9, 1.1), shape=(12, 5, 7))
    slabs = voxax.slab_grids(g, 4)
    edges = np.concatenate([s.edges(0)[:-1] for s in slabs] + [slabs[-1].edges(0)[-1:]])
    np.testing.assert_array_equal(edges, g.edges(0))
    assert [s.lower[0] for s in slabs] == [float(x) for x in g.edges(0)[::3][:4]]
    assert slabs[-1].upper == g.upper and all(s.shape == (3, 5, 7) for s in slabs)
    with pytest.raises(ValueError, match="do not divide"):
        voxax.slab_grids(g, 5)


def test_one_device_is_the_plain_voxelization():
    mesh = Mesh(np.array(jax.devices()[:1]), ("x",))
    m = voxax.data.icosphere(1, radius=0.7)
    g = voxax.Grid.cube(6)
    v = jnp.asarray(m.vertices)
    np.testing.assert_array_equal(voxax.voxelize_sharded(v, m.faces, g, mesh, "x"), voxax.voxelize(v, m.faces, g))
    with pytest.raises(ValueError, match="no axis named 'y'"):
        voxax.voxelize_sharded(v, m.faces, g, mesh, "y")
    with pytest.raises(TypeError, match="jax.sharding.Mesh"):
        voxax.voxelize_sharded(v, m.faces, g, "x", "x")


def test_four_simulated_devices():
    """Forward, gradient and JVP on 2 and 4 simulated CPU devices against one device,
    inside jit with sharding annotations and inside a user's shard_map; the errors for a
    device count that does not divide the grid and a mesh without the named axis."""
    script = Path(__file__).resolve().parent / "_sharded_check.py"
    env = dict(os.environ)
    env["PYTHONPATH"] = os.pathsep.join([str(Path(voxax.__file__).resolve().parent.parent), env.get("PYTHONPATH", "")])
    proc = subprocess.run([sys.executable, str(script)], env=env, capture_output=True, text=True, timeout=600,
                          check=False)
    report = f"exit {proc.returncode}\n{proc.stdout}\n{proc.stderr[-4000:]}"
    assert proc.returncode == 0, report
    for line in ("sharded on 2 devices: ok", "sharded on 4 devices: ok", "errors: ok"):
        assert line in proc.stdout, report


def test_two_processes(tmp_path):
    """The same call on a mesh of two processes (jax.distributed on localhost, one CPU
    device each): each process holds its slab, and the gradient sums across processes.
    A 256^3 float32 grid (64 MiB) is voxelized within a budget of 0.6 of its size per
    process: no process could hold the whole grid, each holds its slab."""
    import socket

    with socket.socket() as s:
        s.bind(("localhost", 0))
        port = str(s.getsockname()[1])
    script = Path(__file__).resolve().parent / "_multiprocess_check.py"
    env = dict(os.environ)
    env.pop("XLA_FLAGS", None)
    env["PYTHONPATH"] = os.pathsep.join([str(Path(voxax.__file__).resolve().parent.parent), env.get("PYTHONPATH", "")])
    procs = [subprocess.Popen([sys.executable, str(script), port, str(i), str(tmp_path / f"p{i}.npz")], env=env,
                              stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True) for i in range(2)]
    outs = [p.communicate(timeout=600) for p in procs]
    for p, (so, se) in zip(procs, outs):
        assert p.returncode == 0, f"{so}\n{se[-4000:]}"
    grid = voxax.Grid(lower=(-0.9, -1.0, -0.8), upper=(1.0, 0.9, 1.1), shape=(8, 7, 6))
    m = voxax.data.icosphere(2, radius=0.7)
    v = jnp.asarray(m.vertices + np.array([0.3, 0.0, 0.1]))
    c = np.random.default_rng(0).normal(size=grid.shape)
    W = np.asarray(voxax.voxelize(v, m.faces, grid))
    g = np.asarray(jax.grad(lambda x: jnp.sum(c * jnp.sin(voxax.voxelize(x, m.faces, grid))))(v))
    starts = []
    for i in range(2):
        with np.load(tmp_path / f"p{i}.npz") as z:
            start = int(z["start"])
            starts.append(start)
            np.testing.assert_array_equal(z["slab"], W[start : start + 4])
            np.testing.assert_allclose(z["grad"], g, rtol=0, atol=1e-13 * np.abs(g).max())
    assert sorted(starts) == [0, 4]
    big = voxax.data.icosphere(3, radius=0.7)
    Wb = np.asarray(voxax.voxelize(jnp.asarray(big.vertices, jnp.float32), big.faces, voxax.Grid.cube(256)))
    budget = 0.6 * Wb.nbytes
    for i in range(2):
        with np.load(tmp_path / f"p{i}.npz") as z:
            start = int(z["big_start"])
            np.testing.assert_array_equal(z["big_slab"], Wb[start : start + 128])
            peak = int(z["big_peak"])
            assert 0.45 * Wb.nbytes <= peak <= budget, (peak, budget)  # holds its half, not the grid
