"""Exact k nearest neighbours of points (a uniform-grid search in C++, `csrc/spatial/knn.h`)."""

from __future__ import annotations

import jax

from .. import _kernels
from .._kernels import knn as _knn
from .bvh import any_traced, as_coords, as_rows

__all__ = ["nearest_neighbors"]


def nearest_neighbors(points, queries, k: int = 1, *, threads: int | None = None):
    """The `k` nearest of `points` to every query point, exactly (a uniform-grid search).

    Neighbours are ordered by distance, ties by index (so the result is unique and the
    same for any thread count). Where `k` exceeds the number of points, the missing
    neighbours have index -1 and distance `inf`. Under `jax.jit` (traced arguments) this
    runs as an FFI kernel with a static `(M, k)` output and returns JAX arrays.

    **Arguments:**

    - `points`: `(N, 3)` float, the data points.
    - `queries`: `(..., 3)` float.
    - `k`: number of neighbours, 1 <= k <= 32.
    - `threads`: number of threads for the eager path (default: all cores).

    **Returns:** `(distances (..., k) float64, indices (..., k) int32)`, like
    `scipy.spatial.cKDTree.query` (which returns int64 indices and drops the last axis
    for `k=1`; here the `k` axis is always kept).

    >>> d, i = nearest_neighbors([[0, 0, 0], [1, 0, 0], [3, 0, 0]], [[0.9, 0, 0]], k=2)
    >>> i.tolist(), d.round(12).tolist()
    ([[1, 0]], [[0.1, 0.9]])
    """
    k = int(k)
    if not 1 <= k <= 32:
        raise ValueError(f"k must lie in [1, 32], got {k}")
    if any_traced(points, queries):

        if not jax.config.jax_enable_x64:
            raise ValueError("the jit path of nearest_neighbors computes in float64: enable jax_enable_x64")
        s = as_rows(points, "points")
        if s.ndim != 2:
            raise ValueError(f"points must have shape (N, 3), got {s.shape}")
        q = as_rows(queries, "queries")
        lead = q.shape[:-1]
        flat = q.reshape(-1, 3)
        idx, dist = _knn.knn_call(s, flat, k)
        return dist.reshape(lead + (k,)), idx.reshape(lead + (k,))
    s = as_coords(points, "points")
    if s.ndim != 2:
        raise ValueError(f"points must have shape (N, 3), got {s.shape}")
    q = as_coords(queries, "queries")
    lead = q.shape[:-1]
    q = q.reshape(-1, 3)
    idx, dist = _knn.knn_host(s, q, k, _kernels.threads(threads))
    return dist.reshape(lead + (k,)), idx.reshape(lead + (k,))
