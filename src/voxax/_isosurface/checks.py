"""Argument checks and the padding of `close`, shared by the iso-surface functions."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

from .. import _kernels, _validate
from .._grid import Grid

_INT32_MAX = np.iinfo(np.int32).max


def _concrete(x):
    """The concrete value behind `x` (unwrapping the tracers of eager `jax.grad`), or None."""
    seen = 0
    while isinstance(x, jax.core.Tracer) and hasattr(x, "primal") and seen < 64:
        x = x.primal
        seen += 1
    if isinstance(x, jax.core.Tracer):
        return None
    return np.asarray(x)


def _concrete_tree(tree):
    leaves, treedef = jax.tree_util.tree_flatten(tree)
    out = []
    for leaf in leaves:
        c = _concrete(leaf)
        if c is None:
            return None
        out.append(jnp.asarray(c))
    return jax.tree_util.tree_unflatten(treedef, out)


def _check_values(values, grid: Grid, name: str):
    if not isinstance(grid, Grid):
        raise TypeError(
            f"voxax.{name}: `grid` must be a voxax.Grid, got {type(grid).__name__}"
        )
    if not hasattr(values, "dtype"):
        values = np.asarray(values)
    dtype = np.dtype(values.dtype)
    if dtype.kind in "iub":
        to = np.float64 if jax.config.jax_enable_x64 else np.float32
        # a traced array stays traced (jnp), a concrete one becomes NumPy
        values = values.astype(to) if isinstance(values, jax.core.Tracer) else np.asarray(values, dtype=to)
    elif dtype not in (np.float32, np.float64):
        raise TypeError(
            f"voxax.{name}: `values` must be a real float array, got dtype {dtype}"
        )
    d = grid.dim
    if values.ndim < d or tuple(values.shape[values.ndim - d :]) != grid.shape:
        raise ValueError(
            f"voxax.{name}: `values` must have shape (..., {', '.join(map(str, grid.shape))}) to match the grid, "
            f"got {tuple(values.shape)}"
        )
    if isinstance(values, (jax.Array, np.ndarray)):
        if (
            isinstance(values, np.ndarray)
            and values.dtype == np.float64
            and not jax.config.jax_enable_x64
        ):
            values = values.astype(np.float32)
        return values  # NumPy input stays NumPy on the eager path (no device copies)
    return jnp.asarray(values)


def _check_level(level, name):
    return _validate.finite_number(f"voxax.{name}", "level", level, note=" (it is static under jit)")


def _check_inside(inside, name):
    if inside not in ("below", "above"):
        raise ValueError(f'voxax.{name}: `inside` must be "below" or "above", got {inside!r}')
    return inside


def _capacities(capacity, name):
    if capacity is None:
        return None
    where = f"voxax.{name}"
    if isinstance(capacity, (tuple, list)) and len(capacity) == 2:
        vcap, fcap = (_validate.positive_int(where, "capacity", c) for c in capacity)
    elif isinstance(capacity, (int, np.integer)) and not isinstance(capacity, bool):
        vcap = fcap = int(capacity)
    else:
        raise TypeError(f"{where}: `capacity` must be an int or a (vertices, faces) pair of ints, got {capacity!r}")
    if not (1 <= vcap <= _INT32_MAX and 1 <= fcap <= _INT32_MAX):
        raise ValueError(
            f"voxax.{name}: capacities must lie in [1, 2^31 - 1], got {(vcap, fcap)}"
        )
    return vcap, fcap


def _padded(grid: Grid) -> Grid:
    h = grid.spacing
    return Grid(
        tuple(lo - s for lo, s in zip(grid.lower, h)),
        tuple(up + s for up, s in zip(grid.upper, h)),
        tuple(n + 2 for n in grid.shape),
    )


def _explicit_pad(close, level: float, inside: str) -> float:
    """The pad value given as `close=<value>`: finite, and on the outside of the level."""
    side = "above" if inside == "below" else "below"
    try:
        pad = float(close)
    except (TypeError, ValueError):
        raise TypeError(
            f"voxax.isosurface: `close` must be True, False or a finite value {side} the level, got {close!r}"
        ) from None
    ok = pad > level if inside == "below" else pad < level
    if not np.isfinite(pad) or not ok:
        raise ValueError(
            f"voxax.isosurface: `close` must be True or a finite value {side} the level, got {close!r}"
        )
    return pad


def _pad(values, grid: Grid, level: float, inside: str, close):
    """Pads the field with one layer of an outside value; returns (values, grid)."""
    d = grid.dim
    outward = 1.0 if inside == "below" else -1.0
    if isinstance(values, np.ndarray):
        if close is True:
            span = np.max(
                np.abs(values.astype(np.float64) - level),
                axis=tuple(range(values.ndim - d, values.ndim)),
            )
            pad = level + outward * np.where(span > 0, span, 1.0)
        else:
            pad = _explicit_pad(close, level, inside)
        pad = np.broadcast_to(
            np.asarray(pad, values.dtype), values.shape[: values.ndim - d]
        )
        out = np.empty(
            values.shape[: values.ndim - d] + tuple(n + 2 for n in grid.shape),
            values.dtype,
        )
        out[...] = pad.reshape(pad.shape + (1,) * d)
        out[(Ellipsis,) + (slice(1, -1),) * d] = values
        return out, _padded(grid)
    if close is True:
        g = jax.lax.stop_gradient(values) - level
        span = jnp.max(
            jnp.abs(g), axis=tuple(range(values.ndim - d, values.ndim)), keepdims=True
        )
        pad = level + outward * jnp.where(span > 0, span, 1.0)
    else:
        pad = jnp.full((1,) * values.ndim, _explicit_pad(close, level, inside), values.dtype)
    pad = jnp.broadcast_to(
        pad.astype(values.dtype), values.shape[: values.ndim - d] + (1,) * d
    )
    widths = [(0, 0)] * (values.ndim - d) + [(1, 1)] * d
    # Pad with zeros, then fill the border with the pad value (traced values are allowed).
    out = jnp.pad(values, widths)
    mask = np.pad(np.zeros(grid.shape, bool), 1, constant_values=True)
    out = jnp.where(mask, pad, out)
    return out, _padded(grid)


def _check_threads(threads, name):
    """Checks `threads` by the one rule (`voxax._kernels.threads`), errors naming `name`."""
    try:
        _kernels.threads(threads)
        return threads
    except (TypeError, ValueError) as err:
        raise type(err)(f"voxax.{name}: {err}") from None


def _float():
    return jnp.float64 if jax.config.jax_enable_x64 else jnp.float32
