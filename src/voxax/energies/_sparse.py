"""Grid energies on a `voxax.SparseGrid`: the same values as on the dense grid, from the
boundary cells and runs alone (memory and time grow with the surface, not the volume)."""

from __future__ import annotations

import jax
import jax.numpy as jnp

from .. import _validate
from .._voxelize.sparse import SparseGrid

__all__ = ["sparse_column_sums", "sparse_self_intersection", "sparse_silhouette_z", "sparse_volume"]


def _check(sg, name):
    if not isinstance(sg, SparseGrid):
        raise TypeError(f"{name}: expected a voxax.SparseGrid, got {type(sg).__name__}")
    if sg.values.ndim != 1:
        raise ValueError(f"{name}: takes an unbatched SparseGrid (use jax.vmap over batches), got {sg.batch_shape}")


def _lengths(sg):
    return (sg.runs[:, 3] - sg.runs[:, 2]).astype(sg.run_values.dtype)


def sparse_self_intersection(sg: SparseGrid, eps: float = 1e-3):
    """`voxax.energies.self_intersection` of `sg.to_dense()`, without the dense grid.

    `sum(W^2 over cells with W > 1 + eps) / grid.size`: only boundary cells and runs
    above `1 + eps` count (the padding rows hold 0).

    **Arguments:**

    - `sg`: an unbatched `voxax.SparseGrid` (`jax.vmap` for batches).
    - `eps`: non-negative float, the tolerance above 1.

    **Returns:**

    A scalar; its gradient flows through the boundary values.
    """
    _check(sg, "voxax.energies.sparse_self_intersection")
    # traced: NaN or Inf refused under the trace (a NaN eps would count no cell)
    eps = _validate.positive_number("voxax.energies.sparse_self_intersection", "eps", eps, allow_zero=True)
    b = sg.values
    r = sg.run_values
    e = jnp.sum(jnp.where(b > 1.0 + eps, b * b, 0.0)) + jnp.sum(jnp.where(r > 1.0 + eps, r * r * _lengths(sg), 0.0))
    return e / sg.grid.size


def sparse_volume(sg: SparseGrid):
    """The enclosed volume, `sg.volume()` (`voxax.energies.volume` of the dense grid)."""
    if not isinstance(sg, SparseGrid):
        raise TypeError(f"voxax.energies.sparse_volume: expected a voxax.SparseGrid, got {type(sg).__name__}")
    return sg.volume()


def sparse_column_sums(sg: SparseGrid, axis: int = 2):
    """The sums of the dense grid along `axis`, `to_dense().sum(axis)`, as a 2D array.

    Along z (`axis=2`) each run adds `length * value` to its column; along x or y a run
    adds its value to the cells `k_start <= k < k_stop` of one line (a difference array
    along z). Boundary values scatter into their lines.

    **Returns:**

    `(ny, nz)`, `(nx, nz)` or `(nx, ny)` float (the axis removed).
    """
    _check(sg, "voxax.energies.sparse_column_sums")
    if axis not in (0, 1, 2, -1, -2, -3):
        raise ValueError(f"voxax.energies.sparse_column_sums: `axis` must be 0, 1 or 2, got {axis!r}")
    axis %= 3
    nx, ny, nz = sg.grid.shape
    dt = sg.values.dtype
    c, r = sg.cells, sg.runs
    if axis == 2:
        out = jnp.zeros((nx, ny), dt)
        out = out.at[c[:, 0], c[:, 1]].add(sg.values, mode="drop")
        return out.at[r[:, 0], r[:, 1]].add(sg.run_values * _lengths(sg), mode="drop")
    keep = 1 - axis  # the other of x and y
    n_keep = (nx, ny)[keep]
    diff = jnp.zeros((n_keep, nz + 1), dt)
    diff = diff.at[r[:, keep], r[:, 2]].add(sg.run_values, mode="drop")
    diff = diff.at[r[:, keep], r[:, 3]].add(-sg.run_values, mode="drop")
    out = jnp.cumsum(diff[:, :-1], axis=1)
    return out.at[c[:, keep], c[:, 2]].add(sg.values, mode="drop")


def sparse_silhouette_z(sg: SparseGrid, w: float = 1000.0):
    """The silhouette along z, `voxax.energies.silhouettes(to_dense(), w)[2]`, from the
    column sums of `exp(w (W - m))` over the boundary cells, the runs (times their
    lengths) and the column's zero cells, with `m` the column's largest value.

    **Returns:**

    `(nx, ny)` float, the mellowmax of every column.
    """
    _check(sg, "voxax.energies.sparse_silhouette_z")
    # traced: the value-check kernel refuses NaN, Inf and w <= 0 under the trace
    w = _validate.positive_number("voxax.energies.sparse_silhouette_z", "w", w)
    nx, ny, nz = sg.grid.shape
    dt = sg.values.dtype
    c, r = sg.cells, sg.runs
    n = sg.counts
    bmask = jnp.arange(c.shape[0]) < n[0]
    rmask = jnp.arange(r.shape[0]) < n[1]
    lengths = jnp.where(rmask, _lengths(sg), 0)
    # Cells per column stored (boundary + runs): the rest of the column holds zeros.
    stored = jnp.zeros((nx, ny), dt).at[c[:, 0], c[:, 1]].add(bmask.astype(dt), mode="drop")
    stored = stored.at[r[:, 0], r[:, 1]].add(lengths, mode="drop")
    zeros = nz - stored
    neg = jnp.asarray(-jnp.inf, dt)
    m = jnp.where(zeros > 0, 0.0, neg).astype(dt)
    m = m.at[c[:, 0], c[:, 1]].max(jnp.where(bmask, sg.values, neg), mode="drop")
    m = m.at[r[:, 0], r[:, 1]].max(jnp.where(rmask, sg.run_values, neg), mode="drop")
    m = jax.lax.stop_gradient(m)
    s = zeros * jnp.exp(w * (0.0 - m))
    # Padding rows (index nx, dropped) get an exponent of 0, never an overflow.
    mb = m[jnp.minimum(c[:, 0], nx - 1), jnp.minimum(c[:, 1], ny - 1)]
    mr = m[jnp.minimum(r[:, 0], nx - 1), jnp.minimum(r[:, 1], ny - 1)]
    eb = jnp.exp(w * jnp.where(bmask, sg.values - mb, 0.0))
    er = jnp.exp(w * jnp.where(rmask, sg.run_values - mr, 0.0))
    s = s.at[c[:, 0], c[:, 1]].add(jnp.where(bmask, eb, 0.0), mode="drop")
    s = s.at[r[:, 0], r[:, 1]].add(jnp.where(rmask, lengths * er, 0.0), mode="drop")
    return m + (jnp.log(s) - jnp.log(jnp.asarray(nz, dt))) / w
