"""The BVH kernels (`csrc/spatial/bvh*`): its host entry points and its FFI calls.

Arrays in, arrays out: the arguments are checked and shaped by `voxax._spatial`. Host
calls take C-contiguous float64 `(n, 3)` arrays and int32 `(F, 3)` faces; the BVH is a
handle that [`bvh_free`][voxax._kernels.spatial.bvh_free] releases.
"""

from __future__ import annotations

import ctypes

import jax
import numpy as np

from ._ctypes import ERRLEN, I8, I32, I64, VP, D, check, declare, error_buffer, pointer
from ._loader import CLOSEST_POINTS, FIRST_HITS, WINDING_CHECK

__all__ = [
    "bvh_all_hits",
    "bvh_build",
    "bvh_closest",
    "bvh_first_hits",
    "bvh_free",
    "bvh_stats",
    "closest_points_ffi",
    "first_hits_ffi",
    "library",
    "winding_check_ffi",
    "winding_number",
]

_i64, _i32, _dbl, _err = ctypes.c_int64, ctypes.c_int32, ctypes.c_double, ctypes.c_char_p

_SIGNATURES = {
    "voxax_bvh_build": (ctypes.c_int, [D, _i64, I32, _i64, ctypes.POINTER(VP), _err, _i64]),
    "voxax_bvh_free": (None, [VP]),
    "voxax_bvh_stats": (None, [VP, I64]),
    "voxax_bvh_closest": (ctypes.c_int, [VP, D, _i64, _dbl, _i32, D, I32, D, D, _err, _i64]),
    "voxax_bvh_first_hit": (
        ctypes.c_int, [VP, D, D, _i64, _dbl, _dbl, _i32, _i32, D, I32, D, I8, _err, _i64]
    ),
    "voxax_bvh_all_hits": (
        ctypes.c_int, [VP, D, D, _i64, _dbl, _dbl, _i32, I64, ctypes.POINTER(VP), _err, _i64]
    ),
    "voxax_hits_size": (_i64, [VP]),
    "voxax_hits_copy": (None, [VP, D, I32, D, I8]),
    "voxax_hits_free": (None, [VP]),
    "voxax_winding_number": (ctypes.c_int, [D, _i64, I32, _i64, D, _i64, _i32, _dbl, _i32, D, I64, _err, _i64]),
}  # fmt: skip


def library() -> ctypes.CDLL:
    """The kernel library with the BVH's (and the kNN host call's) signatures declared."""
    return declare(_SIGNATURES)


def bvh_build(vertices: np.ndarray, faces: np.ndarray) -> VP:
    """A BVH over `vertices (V, 3) f64`, `faces (F, 3) i32`: an opaque handle."""
    handle = VP()
    err = error_buffer()
    status = library().voxax_bvh_build(
        pointer(vertices, D), len(vertices), pointer(faces, I32), len(faces), ctypes.byref(handle), err, ERRLEN
    )
    check(status, err)
    return handle


def bvh_free(handle: VP) -> None:
    library().voxax_bvh_free(handle)


def bvh_stats(handle: VP) -> tuple[int, int]:
    """`(node count, face count)` of a BVH."""
    out = np.zeros(2, np.int64)
    library().voxax_bvh_stats(handle, pointer(out, I64))
    return int(out[0]), int(out[1])


def bvh_closest(handle: VP, points: np.ndarray, max_distance: float, threads: int):
    """Closest points of `points (n, 3) f64`: `(distance, face, barycentric, point)`."""
    n = len(points)
    dist = np.empty(n, np.float64)
    face = np.empty(n, np.int32)
    bary = np.empty((n, 3), np.float64)
    point = np.empty((n, 3), np.float64)
    err = error_buffer()
    status = library().voxax_bvh_closest(
        handle, pointer(points, D), n, max_distance, threads,
        pointer(dist, D), pointer(face, I32), pointer(bary, D), pointer(point, D), err, ERRLEN,
    )  # fmt: skip
    check(status, err)
    return dist, face, bary, point


def bvh_first_hits(handle: VP, origins, directions, t_min: float, t_max: float, any_hit: bool, threads: int):
    """First (or any) hits of rays `(n, 3) f64`: `(t, face, barycentric, sign int8)`."""
    n = len(origins)
    t = np.empty(n, np.float64)
    face = np.empty(n, np.int32)
    bary = np.empty((n, 3), np.float64)
    sign = np.empty(n, np.int8)
    err = error_buffer()
    status = library().voxax_bvh_first_hit(
        handle, pointer(origins, D), pointer(directions, D), n, t_min, t_max, int(any_hit), threads,
        pointer(t, D), pointer(face, I32), pointer(bary, D), pointer(sign, I8), err, ERRLEN,
    )  # fmt: skip
    check(status, err)
    return t, face, bary, sign


def bvh_all_hits(handle: VP, origins, directions, t_min: float, t_max: float, threads: int):
    """Every hit of rays `(n, 3) f64`: `(counts (n,) int64, t, face, barycentric, sign)`,
    the hits sorted by ray, then `t`, then face."""
    lib = library()
    n = len(origins)
    counts = np.zeros(n, np.int64)
    out = VP()
    err = error_buffer()
    status = lib.voxax_bvh_all_hits(
        handle, pointer(origins, D), pointer(directions, D), n, t_min, t_max, threads,
        pointer(counts, I64), ctypes.byref(out), err, ERRLEN,
    )  # fmt: skip
    check(status, err)
    try:
        h = int(lib.voxax_hits_size(out))
        t = np.empty(h, np.float64)
        face = np.empty(h, np.int32)
        bary = np.empty((h, 3), np.float64)
        sign = np.empty(h, np.int8)
        lib.voxax_hits_copy(out, pointer(t, D), pointer(face, I32), pointer(bary, D), pointer(sign, I8))
    finally:
        lib.voxax_hits_free(out)
    return counts, t, face, bary, sign


def winding_number(
    vertices: np.ndarray, faces: np.ndarray, points: np.ndarray, exact_sum: bool, threads: int, accuracy: float = 0.0
):
    """Winding numbers of mesh `(vertices (V, 3) f64, faces (F, 3) i32)` at `points (n, 3)
    f64`: `(values (n,) f64, closed, points decided by a ray)`. `exact_sum`: the solid-angle
    sum at every point instead of one ray per point on a closed mesh. `accuracy` (a finite
    float >= 0, not with `exact_sum`): 0 for the exact hierarchy, eps > 0 for the far-field
    expansion within eps of the sum (at the points no ray decides)."""
    n = len(points)
    out = np.empty(n, np.float64)
    stats = np.zeros(2, np.int64)
    err = error_buffer()
    status = library().voxax_winding_number(
        pointer(vertices, D), len(vertices), pointer(faces, I32), len(faces), pointer(points, D), n,
        int(exact_sum), float(accuracy), threads, pointer(out, D), pointer(stats, I64), err, ERRLEN,
    )  # fmt: skip
    check(status, err)
    return out, bool(stats[0]), int(stats[1])


def closest_points_ffi(vertices, faces, points):
    """The closest-point FFI kernel on JAX arrays `vertices (V, 3) f64`, `faces (F, 3) i32`,
    `points (n, 3) f64`: `(distance, face, barycentric, point)`."""
    n = points.shape[0]
    out = (
        jax.ShapeDtypeStruct((n,), np.float64),
        jax.ShapeDtypeStruct((n,), np.int32),
        jax.ShapeDtypeStruct((n, 3), np.float64),
        jax.ShapeDtypeStruct((n, 3), np.float64),
    )
    return jax.ffi.ffi_call(CLOSEST_POINTS, out, vmap_method="sequential")(vertices, faces, points)


def first_hits_ffi(vertices, faces, origins, directions, t_min: float, t_max: float):
    """The first-hit FFI kernel on JAX arrays (rays `(n, 3) f64`): `(t, face, barycentric,
    sign int32)`."""
    n = origins.shape[0]
    out = (
        jax.ShapeDtypeStruct((n,), np.float64),
        jax.ShapeDtypeStruct((n,), np.int32),
        jax.ShapeDtypeStruct((n, 3), np.float64),
        jax.ShapeDtypeStruct((n,), np.int32),
    )
    call = jax.ffi.ffi_call(FIRST_HITS, out, vmap_method="sequential")
    return call(vertices, faces, origins, directions, t_min=np.float64(t_min), t_max=np.float64(t_max))


def winding_check_ffi(vertices, faces, points):
    """The winding numbers' input check as an FFI kernel (for jit): `vertices (..., V, d)`
    f32/f64, `faces (..., F, k)` int32, `points (..., d)` f32/f64; returns a 0 int32
    scalar, or fails with the reason."""
    call = jax.ffi.ffi_call(WINDING_CHECK, jax.ShapeDtypeStruct((), np.int32), vmap_method="sequential")
    return call(vertices, faces, points)
