"""The k-nearest-neighbour kernels (`csrc/spatial/knn_host.cc`, `csrc/spatial/knn_ffi.cc`).

Arrays in, arrays out: the checks and the public function live in `voxax._spatial.knn`.
"""

from __future__ import annotations

import ctypes

import jax
import numpy as np

from ._ctypes import ERRLEN, I32, D, check, declare, error_buffer, pointer
from ._loader import KNN

__all__ = ["KNN", "knn_call", "knn_host"]

_SIGNATURES = {
    "voxax_knn_host": (
        ctypes.c_int,
        [D, ctypes.c_int64, D, ctypes.c_int64, ctypes.c_int32, ctypes.c_int32, I32, D, ctypes.c_char_p,
         ctypes.c_int64],
    ),
}


def knn_host(points: np.ndarray, queries: np.ndarray, k: int, threads: int) -> tuple[np.ndarray, np.ndarray]:
    """`(indices (M, k) int32, distances (M, k) float64)` of the `k` nearest of `points`
    `(N, 3)` to each of `queries` `(M, 3)` (both C-contiguous float64), on `threads` host
    threads (0: every core). Raises the kernel's message as a `ValueError`."""
    lib = declare(_SIGNATURES)
    m = len(queries)
    idx = np.empty((m, k), np.int32)
    dist = np.empty((m, k), np.float64)
    err = error_buffer()
    status = lib.voxax_knn_host(
        pointer(points, D), len(points), pointer(queries, D), m, k, threads, pointer(idx, I32), pointer(dist, D),
        err, ERRLEN,
    )
    check(status, err)
    return idx, dist


def knn_call(points, queries, k: int):
    """The FFI kernel inside XLA: `(indices (M, k) int32, distances (M, k) float64)` for
    `points` `(N, 3)` and `queries` `(M, 3)` float64 JAX arrays."""
    m = queries.shape[0]
    out = (jax.ShapeDtypeStruct((m, k), np.int32), jax.ShapeDtypeStruct((m, k), np.float64))
    return jax.ffi.ffi_call(KNN, out, vmap_method="sequential")(points, queries)
