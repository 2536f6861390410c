"""The CVT kernels (`csrc/cvt/`): the restricted Delaunay extraction (host entry points) and
the nearest-seed assignment with region moments (an FFI call and its host twin).

Arrays in, arrays out: the algorithms that call them live in `voxax.cvt`.
"""

from __future__ import annotations

import ctypes

import numpy as np

from . import _ctypes
from ._ctypes import ERRLEN, I32, I64, VP, D, check, declare, error_buffer, pointer
from ._loader import CVT_ASSIGN

__all__ = ["CVT_ASSIGN", "assign", "assign_host", "rdt"]

_SIGNATURES = {
    "voxax_rdt_run": (
        ctypes.c_int,
        [D, ctypes.c_int64, D, ctypes.c_int64, D, ctypes.c_int64, ctypes.c_double, ctypes.c_int32, ctypes.c_int32,
         ctypes.POINTER(VP), ctypes.c_char_p, ctypes.c_int64],
    ),
    "voxax_rdt_size": (ctypes.c_int64, [VP]),
    "voxax_rdt_copy": (None, [VP, I32, I64]),
    "voxax_rdt_free": (None, [VP]),
    "voxax_cvt_assign_host": (
        ctypes.c_int,
        [D, ctypes.c_int64, D, D, ctypes.c_int64, I32, ctypes.c_int32, I32, D, I32, D, ctypes.c_char_p,
         ctypes.c_int64],
    ),
}  # fmt: skip


def _rows(a, width: int | None = 3) -> np.ndarray:
    """`a` as a C-contiguous float64 array of rows of `width` (or a vector)."""
    out = np.ascontiguousarray(a, np.float64)
    return out.reshape(-1, width) if width else out.reshape(-1)


def rdt(seeds, points, normals, tau: float, max_hole: int, threads=None) -> tuple[np.ndarray, np.ndarray]:
    """`voxax_rdt_run` on `seeds (n, 3)`, fragment `points (P, 3)` and `normals (P, 3)` (the
    kernel refuses other counts of normals). **Returns:** `(faces (F, 3) int32, stats (6,) int64)`:
    candidates, greedy, filled, flipped, boundary edges, components."""
    s, x, nrm = _rows(seeds), _rows(points), _rows(normals)
    lib = declare(_SIGNATURES)
    handle = VP()
    err = error_buffer()
    status = lib.voxax_rdt_run(
        pointer(s, D), len(s), pointer(x, D), len(x), pointer(nrm, D), len(nrm), float(tau), int(max_hole),
        _ctypes.threads(threads), ctypes.byref(handle), err, ERRLEN,
    )  # fmt: skip
    check(status, err)
    try:
        nf = int(lib.voxax_rdt_size(handle))
        faces = np.empty((nf, 3), np.int32)
        stats = np.zeros(6, np.int64)
        lib.voxax_rdt_copy(handle, pointer(faces, I32), pointer(stats, I64))
    finally:
        lib.voxax_rdt_free(handle)
    return faces, stats


def assign(seeds, points, weights, hint):
    """The FFI assignment kernel (`csrc/cvt/assign_ffi.cc`) on JAX arrays (under `jit` too):
    seeds `(n, 3)`, points `(m, 3)`, weights `(m,)` float64 and `hint (m,)` int32 (any earlier
    assignment; out-of-range entries mean none). **Returns:** `(idx (m,) int32, moments
    (n, 4) float64, count (n,) int32, energy (1,) float64)`."""
    import jax

    n, m = seeds.shape[0], points.shape[0]
    out = (
        jax.ShapeDtypeStruct((m,), np.int32),
        jax.ShapeDtypeStruct((n, 4), np.float64),
        jax.ShapeDtypeStruct((n,), np.int32),
        jax.ShapeDtypeStruct((1,), np.float64),
    )
    return jax.ffi.ffi_call(CVT_ASSIGN, out, vmap_method="sequential")(seeds, points, weights, hint)


def assign_host(seeds, points, weights, hint=None, *, threads=None):
    """The assignment kernel's eager host entry point (`voxax_cvt_assign_host`) on NumPy
    arrays with `threads` threads: the nearest seed of every point (ties: the smaller
    index), the regions' weights and weighted first moments, their counts of
    positive-weight points, and the energy. **Returns:** `(idx (m,) int32, moments (n, 4),
    count (n,) int32, energy)`."""
    s, x, w = _rows(seeds), _rows(points), _rows(weights, None)
    m = len(x)
    if len(w) != m:
        raise ValueError(f"voxax.cvt: {m} points but {len(w)} weights")
    h = np.full(m, -1, np.int32) if hint is None else np.ascontiguousarray(hint, np.int32).reshape(-1)
    if len(h) != m:
        raise ValueError(f"voxax.cvt: {m} points but {len(h)} hints")
    lib = declare(_SIGNATURES)
    idx = np.empty(m, np.int32)
    mom = np.empty((len(s), 4))
    count = np.empty(len(s), np.int32)
    energy = np.zeros(1)
    err = error_buffer()
    status = lib.voxax_cvt_assign_host(
        pointer(s, D), len(s), pointer(x, D), pointer(w, D), m, pointer(h, I32), _ctypes.threads(threads),
        pointer(idx, I32), pointer(mom, D), pointer(count, I32), pointer(energy, D), err, ERRLEN,
    )  # fmt: skip
    check(status, err)
    return idx, mom, count, float(energy[0])
