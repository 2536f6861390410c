"""The evaluation of NESI queries (`voxax.nesi.occupancy`, `raytrace`) on their inputs: the
checks of concrete and traced points, and the occupancy of concrete points, each network
evaluated in fixed chunks of points (one compilation per network) and only where the
answer is still open."""

from __future__ import annotations

from typing import TYPE_CHECKING

import equinox as eqx
import jax.numpy as jnp
import numpy as np

from ..fields import Siren
from ._siren import _apply

if TYPE_CHECKING:
    from ..nesi import NESI


def _real_points(where: str, name: str, value) -> np.ndarray:
    """Concrete `(..., 3)` real, finite points as a NumPy array (integers as float64)."""
    p = np.asarray(value)
    if p.dtype.kind not in "fiu":
        raise TypeError(f"{where}: `{name}` must be a real array, got dtype {p.dtype}")
    if p.ndim < 1 or p.shape[-1] != 3:
        raise ValueError(f"{where}: `{name}` must have shape (..., 3), got {p.shape}")
    if p.dtype.kind != "f":
        p = p.astype(np.float64)
    if not np.all(np.isfinite(p)):
        raise ValueError(f"{where}: `{name}` must be finite (they contain NaN or Inf)")
    return p


def _traced_points(where: str, name: str, value):
    """Traced `(..., 3)` real points, checked to be finite when the computation runs."""
    p = jnp.asarray(value)
    if not (jnp.issubdtype(p.dtype, jnp.floating) or jnp.issubdtype(p.dtype, jnp.integer)):
        raise TypeError(f"{where}: `{name}` must be a real array, got dtype {p.dtype}")
    if p.ndim < 1 or p.shape[-1] != 3:
        raise ValueError(f"{where}: `{name}` must have shape (..., 3), got {p.shape}")
    if not jnp.issubdtype(p.dtype, jnp.floating):
        p = p.astype(jnp.result_type(float))
    return eqx.error_if(p, ~jnp.all(jnp.isfinite(p)), f"{where}: `{name}` must be finite (they contain NaN or Inf)")


_CHUNK = 1 << 16


@eqx.filter_jit
def _apply_chunk(siren: Siren, x):
    return _apply(siren, x)


def _chunked(fn, first, x, axis=0):
    """`fn(first, chunk)` over fixed-size chunks of `x` (the last one padded), the outputs
    joined along `axis` (their point axis); NumPy out."""
    n = len(x)
    out = []
    for i in range(0, n, _CHUNK):
        xi = x[i : i + _CHUNK]
        k = len(xi)
        if k < _CHUNK:
            xi = np.concatenate([xi, np.zeros((_CHUNK - k,) + xi.shape[1:], xi.dtype)])
        out.append(np.take(np.asarray(fn(first, xi)), np.arange(k), axis=axis))
    return np.concatenate(out, axis=axis)


def _occupancy_eager(net: NESI, p):
    n = len(p)
    result = np.zeros(n, bool)
    if n == 0:
        return result
    dt = np.dtype(jnp.result_type(float))
    # normalised frame coordinates in float64 (world points of any finite size), then in
    # the networks' precision: points far outside land outside the DHF's box
    q = (np.asarray(p, np.float64) - np.asarray(net.center)) * net.scale
    with np.errstate(over="ignore", invalid="ignore"):
        loc = np.einsum("nk,ejk->enj", q, np.asarray(net.frames, np.float64)).astype(dt)  # (m+1, n, 3)
    idx = np.flatnonzero(np.all(np.abs(loc[0]) <= 1.0, -1))
    if len(idx):
        out = _chunked(_apply_chunk, net.dhf, loc[0, idx, :2])
        z = loc[0, idx, 2]
        idx = idx[(z <= out[:, 0]) & (z >= out[:, 1])]
    for k in range(net.n_hf):
        if not len(idx):
            break
        xy, z = loc[k + 1, idx, :2], loc[k + 1, idx, 2]
        keep = _chunked(_apply_chunk, net.masks[k], xy) > 0
        idx, xy, z = idx[keep], xy[keep], z[keep]
        if not len(idx):
            break
        idx = idx[z <= _chunked(_apply_chunk, net.heights[k], xy)]
    result[idx] = True
    return result
