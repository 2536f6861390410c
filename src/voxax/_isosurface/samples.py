"""Sampling fields given as functions: chunked evaluation and the `band` / `lipschitz` fast paths."""

from __future__ import annotations

import jax.numpy as jnp
import numpy as np

from .._grid import Grid


def field_values(f, n: int):
    """The values `fn` returned for `n` points as an `(n,)` array (NumPy or JAX); `(n, 1)`
    is accepted, anything else refused."""
    shape = tuple(f.shape if hasattr(f, "shape") else np.shape(f))
    if shape not in ((n,), (n, 1)):
        raise ValueError(
            f"voxax.isosurface_fn: `fn(params, x)` must return one value per point, shape ({n},) "
            f"for x of shape ({n}, d), got shape {shape}"
        )
    dtype = np.dtype(f.dtype if hasattr(f, "dtype") else np.asarray(f).dtype)
    if dtype.kind not in "fiub":
        raise TypeError(f"voxax.isosurface_fn: `fn(params, x)` must return real values, got dtype {dtype}")
    return jnp.reshape(f, (n,))


def _evaluate_np(fn, params, points: np.ndarray, chunk: int) -> np.ndarray:
    """`fn(params, points)` in chunks, as a float64 NumPy array (no gradient)."""
    out = np.empty(points.shape[0], np.float64)
    for s in range(0, points.shape[0], chunk):
        part = points[s : s + chunk]
        n = len(part)
        # pad to a power of two (at least 256) so that a few shapes cover every call and
        # a compiled `fn` (or the primitives of an eager one) is reused
        size = min(max(chunk, n), max(256, 1 << max(n - 1, 0).bit_length()))
        if size > n:
            part = np.concatenate([part, np.broadcast_to(part[:1], (size - n,) + part.shape[1:])])
        out[s : s + n] = np.asarray(field_values(fn(params, jnp.asarray(part)), size), np.float64)[:n]
    return out


def _active_corners(values: np.ndarray, level: float) -> np.ndarray:
    """Cells that are corners of at least one cube (square) whose corners differ in sign."""
    pos = values >= level
    d = values.ndim
    lo = np.ones(tuple(n - 1 for n in values.shape), bool)
    hi = np.zeros_like(lo)
    for corner in np.ndindex(*(2,) * d):
        sl = tuple(slice(c, c + n - 1) for c, n in zip(corner, values.shape))
        lo &= pos[sl]
        hi |= pos[sl]
    active = hi & ~lo
    out = np.zeros(values.shape, bool)
    for corner in np.ndindex(*(2,) * d):
        sl = tuple(slice(c, c + n - 1) for c, n in zip(corner, values.shape))
        out[sl] |= active
    return out


def _with_pad(values: np.ndarray, pad) -> np.ndarray:
    return values if pad is None else np.pad(values, 1, constant_values=pad)


def _strip_pad(mask: np.ndarray, pad) -> np.ndarray:
    return mask if pad is None else mask[(slice(1, -1),) * mask.ndim]


def _dilate(mask: np.ndarray, width: int) -> np.ndarray:
    from scipy.ndimage import maximum_filter

    return maximum_filter(mask, size=2 * width + 1, mode="constant", cval=False)


def _centers_at(grid: Grid, mask: np.ndarray) -> np.ndarray:
    """The cell centres `(N, d)` of the cells where `mask` holds (C order), as
    `grid.centers()[mask]` without building every centre."""
    idx = np.nonzero(mask)
    lower = np.asarray(grid.lower, np.float64)
    h = np.asarray(grid.spacing, np.float64)
    return lower + (np.stack(idx, -1).astype(np.float64) + 0.5) * h


def _lipschitz_samples(
    fn, params, grid: Grid, level: float, lipschitz: float, pad, chunk: int
):
    """Coarse-to-fine samples: exact where marching cubes reads them, sign-exact elsewhere."""
    n = np.array(grid.shape)
    h = np.array(grid.spacing)
    lower = np.array(grid.lower)
    d = grid.dim
    values = np.zeros(grid.shape, np.float64)
    exact = np.zeros(grid.shape, bool)
    evaluated = 0
    size = 1
    while size < min(16, int(n.max())):
        size *= 2
    axes = [np.arange(0, m, size) for m in n]
    origins = np.stack(np.meshgrid(*axes, indexing="ij"), -1).reshape(-1, d)
    while len(origins):
        count = np.minimum(size, n - origins)
        centre = lower + (origins + (count - 1) / 2.0 + 0.5) * h
        radius = 0.5 * np.sqrt((((count - 1) * h) ** 2).sum(-1))
        g = _evaluate_np(fn, params, centre, chunk) - level
        evaluated += len(origins)
        if size == 1:
            idx = tuple(origins.T)
            values[idx] = g + level
            exact[idx] = True
            break
        decided = np.abs(g) > lipschitz * radius
        if decided.any():
            # every cell of a decided block gets a value of the block's sign whose distance to
            # the level is a lower bound of |f - level| over the block
            coarse = np.full(tuple(-(-n // size)), np.nan)
            coarse[tuple((origins[decided] // size).T)] = level + np.sign(g[decided]) * (
                np.abs(g[decided]) - lipschitz * radius[decided]
            )
            for axis in range(d):
                coarse = np.repeat(coarse, size, axis=axis)
            coarse = coarse[tuple(slice(0, m) for m in n)]
            hit = ~np.isnan(coarse)
            values[hit] = coarse[hit]
        size //= 2
        rest = origins[~decided]
        children = [rest + np.array(off) * size for off in np.ndindex(*(2,) * d)]
        origins = np.concatenate(children)
        origins = origins[np.all(origins < n, axis=1)]
    need = _strip_pad(_active_corners(_with_pad(values, pad), level), pad) & ~exact
    if need.any():
        pts = _centers_at(grid, need)
        values[need] = _evaluate_np(fn, params, pts, chunk)
        evaluated += len(pts)
    return values, evaluated


def _band_samples(
    fn, params, grid: Grid, level: float, previous: np.ndarray, pad, chunk: int
):
    """Re-evaluates the field near the previous surface, growing the evaluated set until closed.

    Starts from the previous active corners (cells of cubes whose corners differ in sign) and
    repeats: evaluate the pending cells; then every cell that is an active corner of the
    current samples, or a neighbour (26-connected) of an evaluated cell whose sign changed,
    and was not evaluated yet, is pending. It stops when nothing is pending: every active
    corner then holds an exact value, and every region of changed signs that reaches the
    evaluated set is explored to its border, so the mesh equals dense evaluation unless a
    region of changed signs lies entirely outside it (a new component far from the previous
    surface).
    """
    previous = np.asarray(previous, np.float64)
    if previous.shape != grid.shape:
        raise ValueError(
            f"voxax.isosurface_fn: `band` must have the grid's shape {grid.shape}, got {previous.shape}"
        )
    before = previous >= level
    todo = _strip_pad(_active_corners(_with_pad(previous, pad), level), pad)
    if not todo.any():
        todo = np.ones(grid.shape, bool)
    values = previous.copy()
    done = np.zeros(grid.shape, bool)
    evaluated = 0
    while todo.any():
        values[todo] = _evaluate_np(fn, params, _centers_at(grid, todo), chunk)
        evaluated += int(todo.sum())
        done |= todo
        flipped = done & ((values >= level) != before)
        todo = _strip_pad(_active_corners(_with_pad(values, pad), level), pad)
        if flipped.any():
            todo |= _dilate(flipped, 1)
        todo &= ~done
    return values, evaluated
