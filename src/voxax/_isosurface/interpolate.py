"""Vertex positions by interpolation along the crossed edges, differentiable in the samples."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

from .._grid import Grid
from .checks import _float


def _cell_points(idx, grid: Grid):
    """Centres of the cells with flat C-order indices `idx`, `(..., d)`."""
    coords = jnp.unravel_index(idx, grid.shape)
    ft = _float()
    lo = jnp.asarray(grid.lower, ft)
    h = jnp.asarray(grid.spacing, ft)
    return lo + (jnp.stack(coords, axis=-1).astype(ft) + 0.5) * h


def _interpolate(values, edges, n_vertices, grid: Grid, level: float):
    """Vertex positions and the conditioning figure; differentiable in `values`."""
    ft = _float()
    flat = values.reshape(values.shape[: values.ndim - grid.dim] + (-1,))
    fa = jnp.take_along_axis(flat, edges[..., 0], axis=-1).astype(ft)
    fb = jnp.take_along_axis(flat, edges[..., 1], axis=-1).astype(ft)
    return _from_samples(fa, fb, edges, n_vertices, grid, level)


def _from_samples(fa, fb, edges, n_vertices, grid: Grid, level):
    """`_interpolate` after the samples at the edge ends, `fa` and `fb`, are gathered."""
    ia, ib = edges[..., 0], edges[..., 1]
    valid = jnp.arange(edges.shape[-2]) < n_vertices[..., None]
    gap = fb - fa
    safe = jnp.where(valid, gap, 1.0)
    t = jnp.where(valid, (level - fa) / safe, 0.0)
    pa, pb = _cell_points(ia, grid), _cell_points(ib, grid)
    v = pa + t[..., None] * (pb - pa)
    v = jnp.where(valid[..., None], v, 0.0)
    min_gap = jnp.min(
        jnp.where(valid, jnp.abs(jax.lax.stop_gradient(gap)), jnp.inf),
        axis=-1,
        initial=jnp.inf,
    )
    return v, min_gap


_from_samples_jit = jax.jit(_from_samples, static_argnames=("grid",))


def _interpolate_eager(values: np.ndarray, edges: np.ndarray, grid: Grid, level: float):
    """`_interpolate` of concrete samples: gathered in NumPy, computed by one compiled
    function for vertex counts rounded up to a power of two (so a loop of eager calls with
    varying vertex counts compiles a handful of times, not once per call)."""
    ft = _float()
    n = edges.shape[-2]
    bucket = max(64, 1 << max(n - 1, 0).bit_length())
    flat = values.reshape(values.shape[: values.ndim - grid.dim] + (-1,))  # a view
    padded = np.zeros(edges.shape[:-2] + (bucket, 2), edges.dtype)
    padded[..., :n, :] = edges
    fa = jnp.asarray(np.take_along_axis(flat, padded[..., 0], axis=-1), ft)
    fb = jnp.asarray(np.take_along_axis(flat, padded[..., 1], axis=-1), ft)
    nv = jnp.full(edges.shape[:-2], n, jnp.int32)
    v, min_gap = _from_samples_jit(fa, fb, jnp.asarray(padded), nv, grid, jnp.asarray(level, ft))
    return jnp.asarray(np.asarray(v)[..., :n, :]), min_gap  # sliced in NumPy: no compilation per n


def _vertices_of(fa, fb, edges: np.ndarray, grid: Grid, level: float, k: int = 0):
    """Vertex positions (NumPy) and min gap (of `2^k` times the samples) of gathered
    samples, by the compiled interpolation (vertex counts rounded up to a power of two, as in
    `_interpolate_eager`). With `k`, the samples and the level are scaled by `2^k` first
    (exact), so that XLA sees no subnormal or huge samples."""
    ft = _float()
    if k:
        fa, fb = np.ldexp(np.asarray(fa, np.float64), k), np.ldexp(np.asarray(fb, np.float64), k)
        level = float(np.ldexp(level, k))
    n = len(edges)
    bucket = max(64, 1 << max(n - 1, 0).bit_length())
    pe = np.zeros((bucket, 2), np.int32)
    pe[:n] = edges
    # converted in NumPy (exact), not by a dispatched XLA conversion
    pa = np.zeros(bucket, ft)
    pb = np.zeros(bucket, ft)
    pa[:n], pb[:n] = fa, fb
    v, gap = _from_samples_jit(
        jnp.asarray(pa),
        jnp.asarray(pb),
        jnp.asarray(pe),
        jnp.asarray(n, jnp.int32),
        grid,
        jnp.asarray(level, ft),
    )
    return np.asarray(v)[:n], gap
