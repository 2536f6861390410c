"""The kernels' own checks, reached by calling the raw FFI targets with hostile attributes.

These calls bypass every Python check, as a user of `jax.ffi.ffi_call` could. Each must
fail with an error of the right category (`INVALID_ARGUMENT`, `RESOURCE_EXHAUSTED`,
`INTERNAL`) and a message that says what is wrong, before the kernel allocates anything
sized by the attributes; afterwards the process keeps working.
"""

from __future__ import annotations

import os
import resource
import shutil
import subprocess
import sys
import textwrap
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import voxax
from voxax import Grid, _constants, _kernels

GRID = Grid((-1.0, -1.0, -1.0), (1.0, 1.0, 1.0), (6, 5, 4))
ROOT = Path(__file__).resolve().parents[2]


def _box():
    m = voxax.data.box((-0.5, -0.5, -0.5), (0.5, 0.5, 0.5))
    return jnp.asarray(m.vertices), jnp.asarray(m.faces, dtype=jnp.int32)


def _forward(v, f, shape=GRID.shape, dtype=jnp.float64, **over):
    attrs = dict(_kernels.grid_attributes(GRID), **over)
    return jax.ffi.ffi_call(_kernels.FORWARD, jax.ShapeDtypeStruct(shape, dtype))(v, f, **attrs)


def _backward(v, f, cot, shape=None, dtype=jnp.float64, **over):
    attrs = dict(_kernels.grid_attributes(GRID), **over)
    shape = shape or f.shape[:-2] + (f.shape[-2], f.shape[-1], f.shape[-1])
    return jax.ffi.ffi_call(_kernels.BACKWARD, jax.ShapeDtypeStruct(shape, dtype))(v, f, cot, **attrs)


def _assert_still_works():
    """Valid forward and backward calls after errors give the right answers."""
    v, f = _box()
    W = voxax.voxelize(v, f, GRID)
    assert float(jnp.sum(W)) * GRID.voxel_volume == pytest.approx(1.0, abs=1e-12)
    # d(volume)/d(vertices) sums to zero for a closed mesh; the kernel's corner
    # gradients of the all-ones cotangent give it.
    g = jax.grad(lambda x: jnp.sum(voxax.voxelize(x, f, GRID)) * GRID.voxel_volume)(v)
    np.testing.assert_allclose(np.asarray(g).sum(axis=0), 0.0, atol=1e-12)


def test_kernel_constants_equal_the_python_constants():
    consts = _kernels.kernel_constants()
    assert consts["MAX_ABS_COORDINATE"] == _constants.MAX_ABS_COORDINATE
    assert consts["MIN_CELL_VOLUME"] == _constants.MIN_CELL_VOLUME
    assert consts["MAX_CELL_VOLUME"] == _constants.MAX_CELL_VOLUME
    assert consts["MAX_CELLS_PER_AXIS"] == 2.0**31


FORWARD_CASES = {
    # Grid attributes.
    "nx = 0": (dict(nx=np.int64(0)), r"grid shape must be in \[1, 2\^31\].*got 0 cells along axis 0"),
    "nz = -3": (dict(nz=np.int64(-3)), r"got -3 cells along axis 2"),
    "nx = 2^62": (dict(nx=np.int64(2**62)), r"grid shape must be in \[1, 2\^31\]"),
    "x0 = NaN": (dict(x0=np.float64(np.nan)), "grid corners must be finite with upper > lower"),
    "y1 = -Inf": (dict(y1=np.float64(-np.inf)), "grid corners must be finite with upper > lower"),
    "z1 = +Inf": (dict(z1=np.float64(np.inf)), "grid corners must be finite with upper > lower"),
    "lower > upper": (dict(x1=np.float64(-2.0)), "grid corners must be finite with upper > lower"),
    "lower == upper": (dict(y1=np.float64(-1.0)), "grid corners must be finite with upper > lower"),
    "cells too small to invert": (
        dict(x0=np.float64(0.0), x1=np.float64(2.2250738585072014e-308)),
        "grid cell size is not a positive finite number",
    ),
    "cell volume below 1e-300": (
        dict(x0=np.float64(0.0), x1=np.float64(1e-100), y0=np.float64(0.0), y1=np.float64(1e-100),
             z0=np.float64(0.0), z1=np.float64(1e-100)),
        r"cell volume must lie in \[1e-300, 1e300\]",
    ),
    "cell volume above 1e300": (
        dict(x1=np.float64(1e110), y1=np.float64(1e110), z1=np.float64(1e110)),
        r"cell volume must lie in \[1e-300, 1e300\]",
    ),
    # Grid attributes that disagree with the output buffer (checked before the plane
    # tables are allocated: nx = 2^31 would need 16 GiB).
    "nx = 2^31, output (6, 5, 4)": (dict(nx=np.int64(2**31)), r"output shape \(6, 5, 4\) does not match the grid"),
    "ny = 7, output (6, 5, 4)": (dict(ny=np.int64(7)), "does not match the grid"),
    # Windows along x (the slabs of a sharded grid) must lie within the frame's cells.
    "window past the end": (dict(x_first=np.int64(3), x_count=np.int64(6)), "does not fit the 6 cells along x"),
    "negative window": (dict(x_first=np.int64(-1), x_count=np.int64(2)), "does not fit"),
    "window start without a count": (dict(x_first=np.int64(2)), "does not fit"),
    "window of 2^31 frame cells, output (6, 5, 4)": (
        dict(nx=np.int64(2**31), x_first=np.int64(2**31 - 6), x_count=np.int64(5)),
        r"output shape \(6, 5, 4\) does not match the grid",
    ),
}


@pytest.mark.parametrize("name", list(FORWARD_CASES))
def test_forward_rejects_hostile_attributes(name):
    over, match = FORWARD_CASES[name]
    v, f = _box()
    with pytest.raises(jax.errors.JaxRuntimeError, match="INVALID_ARGUMENT: voxax: .*" + match):
        jax.block_until_ready(_forward(v, f, **over))


def test_huge_grid_attributes_are_rejected_before_allocating():
    """nx = 2^31 (and ny, nz) with a small output: a 16 GiB plane table per axis if the
    grid were built first. The resident-set peak stays far below that."""
    v, f = _box()
    before = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    huge = np.int64(2**31)
    for over in (dict(nx=huge), dict(nx=huge, ny=huge, nz=huge)):
        with pytest.raises(jax.errors.JaxRuntimeError, match="INVALID_ARGUMENT: .*does not match the grid"):
            jax.block_until_ready(_forward(v, f, **over))
        cot = jnp.ones(GRID.shape)
        with pytest.raises(jax.errors.JaxRuntimeError, match="INVALID_ARGUMENT: .*cotangent shape .* does not match"):
            jax.block_until_ready(_backward(v, f, cot, **over))
    grown_kib = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss - before
    assert grown_kib < 256 * 1024
    _assert_still_works()


def _shape_and_dtype_cases():
    v, f = _box()
    vb3, fb2 = jnp.stack([v] * 3), jnp.stack([f] * 2)
    return {
        "output rank 2": (lambda: _forward(v, f, shape=(6, 5)), r"output \(6, 5\) has fewer than 3 axes"),
        "output with an extra axis": (lambda: _forward(v, f, shape=(1, 6, 5, 4)), "same number of batch axes"),
        "batch sizes 3 and 2": (
            lambda: _forward(vb3, fb2, shape=(3,) + GRID.shape),
            r"batch axes of vertices \(3, 8, 3\) and faces \(2, 12, 3\) do not broadcast",
        ),
        "batched vertices, unbatched faces": (
            lambda: _forward(vb3, f, shape=(3,) + GRID.shape),
            "must have the same number of batch axes",
        ),
        "output batch 2 for inputs of 3": (
            lambda: _forward(vb3, jnp.stack([f] * 3), shape=(2,) + GRID.shape),
            "do not broadcast to",
        ),
        "int64 faces": (lambda: _forward(v, f.astype(jnp.int64)), "faces must be int32"),
        "float faces": (lambda: _forward(v, f.astype(jnp.float64)), "faces must be int32"),
        "int32 vertices": (lambda: _forward(v.astype(jnp.int32), f), "vertices must be float32 or float64"),
        "float32 output for float64 vertices": (
            lambda: _forward(v, f, dtype=jnp.float32),
            "output dtype must match the vertices",
        ),
        "4 coordinates": (
            lambda: _forward(jnp.zeros((8, 4)), jnp.zeros((4, 4), jnp.int32)),
            "vertices must have 2 or 3 coordinates",
        ),
        "rank-1 vertices": (lambda: _forward(v.reshape(-1), f), r"vertices must have shape \(\.\.\., V, d\)"),
        "2 indices per face for 3D vertices": (lambda: _forward(v, f[:, :2]), "must have 3 indices per face"),
        "face index 8 of 8 vertices": (lambda: _forward(v, f.at[3, 1].set(8)), r"face index 8 is out of range \[0, 8\)"),
        "negative face index": (lambda: _forward(v, f.at[0, 0].set(-1)), "face index -1 is out of range"),
        "NaN vertex": (lambda: _forward(v.at[2, 2].set(jnp.nan), f), "vertices contain NaN or Inf"),
        "1e200 vertex": (lambda: _forward(v.at[2, 2].set(1e200), f), "exceeds 1e75"),
        "backward: cotangent shape": (
            lambda: _backward(v, f, jnp.ones((6, 5, 5))),
            r"cotangent shape \(6, 5, 5\) does not match the grid",
        ),
        "backward: cotangent rank": (lambda: _backward(v, f, jnp.ones((6, 5))), "has the wrong rank"),
        "backward: cotangent dtype": (
            lambda: _backward(v, f, jnp.ones(GRID.shape, jnp.float32)),
            "cotangent dtype must match the vertices",
        ),
        "backward: output (F, 3, 2)": (
            lambda: _backward(v, f, jnp.ones(GRID.shape), shape=(12, 3, 2)),
            r"backward output must have shape \(\.\.\., F, d, d\)",
        ),
        "backward: output F + 1": (
            lambda: _backward(v, f, jnp.ones(GRID.shape), shape=(13, 3, 3)),
            r"backward output must have shape",
        ),
        "backward: cotangent batch 3 for 2": (
            lambda: _backward(jnp.stack([v] * 2), fb2, jnp.ones((3,) + GRID.shape), shape=(2, 12, 3, 3)),
            "cotangent batch axes .* do not broadcast",
        ),
        "backward: nx = -1": (lambda: _backward(v, f, jnp.ones(GRID.shape), nx=np.int64(-1)), "grid shape must be in"),
        "backward: NaN bounds": (
            lambda: _backward(v, f, jnp.ones(GRID.shape), z0=np.float64(np.nan)),
            "grid corners must be finite",
        ),
    }


def test_hostile_shapes_and_dtypes_are_rejected_then_the_kernels_still_work():
    for name, (call, match) in _shape_and_dtype_cases().items():
        with pytest.raises(jax.errors.JaxRuntimeError, match="INVALID_ARGUMENT: voxax: .*" + match) as info:
            jax.block_until_ready(call())
        assert "voxax:" in str(info.value), name
    _assert_still_works()


def test_hostile_attributes_under_jit_give_the_same_message():
    v, f = _box()
    fn = jax.jit(lambda a, b: _forward(a, b, nx=np.int64(2**31)))
    for _ in range(2):  # compiled, then cached dispatch
        with pytest.raises(Exception, match=r"INVALID_ARGUMENT: voxax: output shape \(6, 5, 4\) does not match"):
            jax.block_until_ready(fn(v, f))
    _assert_still_works()


# -- out of memory, in a subprocess with a limited address space ---------------------------

_OOM_SCRIPT = textwrap.dedent(
    """
    import resource
    import jax, jax.numpy as jnp, numpy as np
    import voxax
    from voxax import _kernels

    def vm_size():
        with open("/proc/self/status") as fh:
            for line in fh:
                if line.startswith("VmSize:"):
                    return int(line.split()[1]) * 1024

    def limited(extra, fn):
        resource.setrlimit(resource.RLIMIT_AS, (vm_size() + extra, resource.RLIM_INFINITY))
        try:
            jax.block_until_ready(fn())
            print("no error")
        except Exception as e:
            print("error:", str(e).splitlines()[0])
        finally:
            resource.setrlimit(resource.RLIMIT_AS, (resource.RLIM_INFINITY, resource.RLIM_INFINITY))

    def call(grid, v, f):
        out = jax.ShapeDtypeStruct(f.shape[:-2] + grid.shape, jnp.float32)
        return lambda: jax.ffi.ffi_call(_kernels.FORWARD, out)(v, f, **_kernels.grid_attributes(grid))

    # Binning: 2^20 copies of a segment across a grid of 256 tiles lists 2^28 entries
    # (1 GiB); the output is 32 MiB.
    g2 = voxax.Grid((-1.0, 0.0), (1.0, 1.0), (256 * 32768, 1))
    v2 = jnp.asarray([[1.5, 0.5], [-1.5, 0.5]], jnp.float32)
    f2 = jnp.zeros((1 << 20, 2), jnp.int32).at[:, 1].set(1)
    limited(768 << 20, call(g2, v2, f2))

    # Tile scratch in the workers: a batch of two, one column of 2^25 cells each
    # (128 MiB of float32 output, 256 MiB of double scratch per worker).
    g3 = voxax.Grid((-1.0, -1.0, -1.0), (1.0, 1.0, 1.0), (1, 1, 1 << 25))
    m = voxax.data.box((-0.5, -0.5, -0.5), (0.5, 0.5, 0.5))
    v3 = jnp.asarray(np.stack([m.vertices] * 2), jnp.float32)
    f3 = jnp.asarray(np.stack([m.faces] * 2), jnp.int32)
    limited(384 << 20, call(g3, v3, f3))

    g = voxax.Grid.cube(4)
    W = voxax.voxelize(m.vertices.astype(np.float32), m.faces, g)
    print("volume after:", float(W.sum()) * g.voxel_volume)
    """
)


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="limits the address space with RLIMIT_AS")
def test_out_of_memory_is_reported_as_resource_exhausted():
    # The child imports the same voxax as this process (installed, or on PYTHONPATH).
    env = dict(os.environ, JAX_PLATFORMS="cpu")
    proc = subprocess.run([sys.executable, "-c", _OOM_SCRIPT], capture_output=True, text=True, env=env, timeout=300)
    assert proc.returncode == 0, proc.stderr[-3000:]
    lines = [line for line in proc.stdout.splitlines() if line.startswith(("error:", "no error", "volume"))]
    assert lines[:2] == ["error: RESOURCE_EXHAUSTED: voxax: out of memory in the forward kernel"] * 2, proc.stdout
    assert lines[2] == "volume after: 1.0", proc.stdout


# -- the error mapping itself, compiled as a small C++ program ----------------------------

_GUARD_PROGRAM = r"""
#include <cstdio>
#include <new>
#include <stdexcept>
#include <string>

#include "common/errors.h"
#include "common/parallel.h"
#include "voxelize/clip.h"

using namespace voxax;

static void show(const char* name, const ffi::Error& e) {
  std::printf("%s|%d|%s\n", name, static_cast<int>(e.errc().value_or(ffi::ErrorCode::kOk)),
              e.message().c_str());
}

int main() {
  show("ok", guarded("k", [] { return ffi::Error::Success(); }));
  show("bad_alloc", guarded("k", []() -> ffi::Error { throw std::bad_alloc(); }));
  show("length_error", guarded("k", []() -> ffi::Error { throw std::length_error("vector"); }));
  show("invalid", guarded("k", []() -> ffi::Error { throw InvalidInput("voxax: bad face"); }));
  show("runtime", guarded("k", []() -> ffi::Error { throw std::runtime_error("boom"); }));
  show("int", guarded("k", []() -> ffi::Error { throw 7; }));
  // A worker's exception reaches the caller with its own type.
  show("worker", guarded("k", [] {
    ParallelFor::run(nullptr, 10, [](int64_t i) {
      if (i == 6) throw std::bad_alloc();
    });
    return ffi::Error::Success();
  }));
  // Overfilling a polygon is reported, never written out of bounds.
  show("poly", guarded("k", [] {
    Poly<3> p;
    const double x[3] = {0, 0, 0};
    for (int i = 0; i <= kMaxVerts; ++i) p.push(x);
    return ffi::Error::Success();
  }));
  return 0;
}
"""


def test_guarded_maps_exceptions_to_error_categories(tmp_path):
    cxx = os.environ.get("CXX") or shutil.which("g++") or shutil.which("c++")
    if cxx is None:
        pytest.skip("no C++ compiler")
    src = tmp_path / "guard.cc"
    src.write_text(_GUARD_PROGRAM)
    exe = tmp_path / "guard"
    cmd = [cxx, "-std=c++17", "-O0", "-I", str(ROOT / "csrc"), "-isystem", jax.ffi.include_dir(), str(src), "-o", str(exe)]
    subprocess.run(cmd, check=True, capture_output=True, timeout=300)
    out = subprocess.run([str(exe)], check=True, capture_output=True, text=True, timeout=60).stdout
    rows = {name: (int(code), msg) for name, code, msg in (line.split("|", 2) for line in out.splitlines())}
    OK, INVALID, EXHAUSTED, INTERNAL = 0, 3, 8, 13  # absl / XLA status codes
    assert rows["ok"] == (OK, "")
    assert rows["bad_alloc"] == (EXHAUSTED, "voxax: out of memory in k")
    assert rows["length_error"] == (EXHAUSTED, "voxax: out of memory in k")
    assert rows["invalid"] == (INVALID, "voxax: bad face")
    assert rows["runtime"] == (INTERNAL, "voxax: internal error in k: boom")
    assert rows["int"] == (INTERNAL, "voxax: internal error in k: unknown exception")
    assert rows["worker"] == (EXHAUSTED, "voxax: out of memory in k")
    assert rows["poly"] == (INTERNAL, "voxax: internal error in k: polygon clipping exceeded its vertex bound")
