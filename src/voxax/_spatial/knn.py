"""Exact k nearest neighbours of points (C++: a uniform grid near the data and a kd-tree
far from it, `csrc/spatial/knn.h`)."""

from __future__ import annotations

import operator

import jax
import numpy as np

from .. import _kernels, _validate
from .._constants import MAX_ABS_COORDINATE
from .._kernels import knn as _knn
from .._validate import INT32_MAX

__all__ = ["nearest_neighbors"]

_WHERE = "voxax.nearest_neighbors"
MAX_K = 32


def nearest_neighbors(points, queries, k: int = 1, *, threads: int | None = None):
    """The `k` nearest of `points` to every query point, exactly.

    Neighbours are ordered by distance, ties by index (so the result is unique and the
    same for any thread count). Where `k` exceeds the number of points, the missing
    neighbours have index -1 and distance `inf`. Under `jax.jit` (traced arguments) this
    runs as an FFI kernel with a static `(M, k)` output and returns JAX arrays; it needs
    `jax_enable_x64`, and the kernel checks the traced values (finite, within 1e75).

    The search bins the points in a uniform grid and scans the cells around a query; a
    query with no point in the 3 x 3 x 3 cells around its own, or beyond the points' box,
    goes to a kd-tree instead (points on a surface leave most of the volume empty). Both
    return the exact k smallest (distance, index) pairs, so the results do not depend on
    which one answers.

    **Arguments:**

    - `points`: `(N, 3)` float or int, the data points (finite, magnitudes up to 1e75, not
      all below 1e-75; N < 2^31).
    - `queries`: `(..., 3)` float or int (finite, magnitudes up to 1e75).
    - `k`: number of neighbours, an int with 1 <= k <= 32 (static under `jax.jit`).
    - `threads`: host threads for the eager path (`None`: `VOXAX_NUM_THREADS`, else every
      core).

    **Returns:** `(distances (..., k) float64, indices (..., k) int32)`, like
    `scipy.spatial.cKDTree.query` (which returns int64 indices and drops the last axis
    for `k=1`; here the `k` axis is always kept).

    **Raises:** `TypeError` for a `k` that is not an int (a float, a string, a bool or a
    traced value) and for bool, complex or non-numeric coordinates; `ValueError` for a `k`
    outside [1, 32], wrong shapes, NaN or infinite coordinates or magnitudes beyond 1e75.

    >>> d, i = nearest_neighbors([[0, 0, 0], [1, 0, 0], [3, 0, 0]], [[0.9, 0, 0]], k=2)
    >>> i.tolist(), d.round(12).tolist()
    ([[1, 0]], [[0.1, 0.9]])
    """
    k = _check_k(k)
    if _traced(points) or _traced(queries):
        if not jax.config.jax_enable_x64:
            raise ValueError(f"{_WHERE}: under jax.jit the search computes in float64: enable jax_enable_x64")
        s = _traced_rows(points, "points")
        q = _traced_rows(queries, "queries")
        lead = q.shape[:-1]
        idx, dist = _knn.knn_call(s, q.reshape(-1, 3), k)
        return dist.reshape(lead + (k,)), idx.reshape(lead + (k,))
    s = _rows(points, "points")
    q = _rows(queries, "queries")
    lead = q.shape[:-1]
    idx, dist = _knn.knn_host(s, q.reshape(-1, 3), k, _kernels.threads(threads))
    return dist.reshape(lead + (k,)), idx.reshape(lead + (k,))


def _traced(x) -> bool:
    return any(isinstance(leaf, jax.core.Tracer) for leaf in jax.tree_util.tree_leaves(x))


def _check_k(k) -> int:
    if isinstance(k, jax.core.Tracer):
        raise TypeError(f"{_WHERE}: `k` must be a Python int, got a traced value (make it static under jax.jit)")
    if isinstance(k, (bool, np.bool_)) or isinstance(k, (str, bytes)):
        raise TypeError(f"{_WHERE}: `k` must be an int, got {type(k).__name__} {k!r}")
    try:
        out = operator.index(k)
    except TypeError:
        raise TypeError(f"{_WHERE}: `k` must be an int, got {type(k).__name__} {k!r}") from None
    if not 1 <= out <= MAX_K:
        raise ValueError(f"{_WHERE}: `k` must lie in [1, {MAX_K}], got {out}")
    return int(out)


def _check_shape(shape: tuple, name: str) -> None:
    if (name == "points" and len(shape) != 2) or len(shape) < 1 or shape[-1] != 3:
        want = "(N, 3)" if name == "points" else "(..., 3)"
        raise ValueError(f"{_WHERE}: `{name}` must have shape {want}, got {shape}")
    if name == "points" and shape[0] > INT32_MAX:
        raise ValueError(f"{_WHERE}: `points` must hold at most 2^31 - 1 rows, got {shape[0]}")


def _rows(x, name: str) -> np.ndarray:
    """Concrete coordinates as C-contiguous float64, checked as the kernel checks them (the
    kernel alone checks that the points are not all below 1e-75)."""
    a = np.asarray(_validate.typed_array(_WHERE, name, x, "fiu", "a real (float or int) array of 3D points"))
    _check_shape(a.shape, name)
    a = np.ascontiguousarray(a, dtype=np.float64)
    if a.size:
        hi, lo = a.max(), a.min()  # NaN propagates through both, an infinity shows
        if not (np.isfinite(hi) and np.isfinite(lo)):
            row = int(np.flatnonzero(~np.isfinite(a).all(axis=-1).reshape(-1))[0])
            raise ValueError(f"{_WHERE}: `{name}` must be finite: row {row} holds NaN or Inf")
        if max(hi, -lo) > MAX_ABS_COORDINATE:
            row = int(np.flatnonzero((np.abs(a) > MAX_ABS_COORDINATE).any(axis=-1).reshape(-1))[0])
            raise ValueError(f"{_WHERE}: `{name}` must be at most 1e75 in magnitude: row {row} exceeds it")
    return a


def _traced_rows(x, name: str):
    """JAX float64 coordinates for the FFI call; values are checked here when concrete, else
    by the kernel."""
    import jax.numpy as jnp

    if not _traced(x):
        return jnp.asarray(_rows(x, name))
    x = jnp.asarray(x)
    if x.dtype == jnp.bool_ or not (jnp.issubdtype(x.dtype, jnp.floating) or jnp.issubdtype(x.dtype, jnp.integer)):
        raise TypeError(f"{_WHERE}: `{name}` must be a real (float or int) array, got dtype {x.dtype}")
    _check_shape(x.shape, name)
    return x.astype(jnp.float64)
