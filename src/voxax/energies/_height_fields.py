"""Soft height-field hulls of voxel grids: differentiable double-height-field hulls and the
gap of a grid to their intersection (pure JAX)."""

from __future__ import annotations

import numpy as np

from .. import _validate

__all__ = ["esi_gap", "height_field_hull"]


def height_field_hull(W, axis: int = 2, w: float = 1000.0):
    """A differentiable double-height-field hull of a voxel grid along a grid axis.

    A cell lies in `DHF(axis)` when some occupied cell precedes it (or is it) along its
    column and some occupied cell follows it: `min(P, Q)` with `P` the mellowmax of every
    prefix of the column (`(logcumsumexp(w W) - log n) / w`, the soft "anything so far")
    and `Q` that of every suffix (the minimum, not the product, keeps partly filled
    boundary cells of a height field at their own value). As `w -> inf` it tends to the exact hull of a binary
    grid; the bandsaw's cut shape is the product of the three silhouettes instead, and
    `height_field_hull(W, a) <= silhouette extrusion along a`.

    **Arguments:**

    - `W`: `(..., nx, ny, nz)` float grid (leading axes are batch axes).
    - `axis`: 0, 1 or 2 (x, y, z).
    - `w`: the mellowmax sharpness (finite, > 0).

    `W` must be finite: NaN or Inf raise `ValueError` eagerly and fail the computation
    with the same message under `jax.jit` (a `jax.errors.JaxRuntimeError`).

    **Returns:** `(..., nx, ny, nz)`, the soft hull.

    >>> import jax.numpy as jnp
    >>> W = jnp.zeros((1, 1, 5)).at[0, 0, 1].set(1.0).at[0, 0, 3].set(1.0)
    >>> height_field_hull(W, 2, w=1e4).round(2).tolist()
    [[[0.0, 1.0, 1.0, 1.0, 0.0]]]
    """
    import jax
    import jax.numpy as jnp

    where = "voxax.energies.height_field_hull"
    axis = _axis(where, axis)
    if not hasattr(W, "dtype"):
        W = np.asarray(W)
    if not jnp.issubdtype(W.dtype, jnp.floating):
        raise TypeError(f"{where}: `W` must be a float array, got dtype {W.dtype}")
    W = jnp.asarray(W)
    if W.ndim < 3:
        raise ValueError(f"{where}: `W` must have shape (..., nx, ny, nz), got {W.shape}")
    w = _sharpness(where, w)
    W = _validate.finite_values(where, "W", W)
    if W.size == 0:
        return jnp.zeros_like(W)
    ax = W.ndim - 3 + axis
    n = W.shape[ax]
    shape = [1] * W.ndim
    shape[ax] = n
    logn = jnp.log(jnp.arange(1, n + 1, dtype=W.dtype)).reshape(shape)
    m = jax.lax.stop_gradient(W.max())
    x = w * (W - m)
    pre = m + (jax.lax.cumlogsumexp(x, axis=ax) - logn) / w
    suf = m + (jax.lax.cumlogsumexp(x, axis=ax, reverse=True) - jnp.flip(logn, ax)) / w
    return jnp.clip(jnp.minimum(pre, suf), 0.0, None)


def _axis(where: str, axis) -> int:
    if isinstance(axis, (bool, np.bool_)) or not isinstance(axis, (int, np.integer)):
        raise TypeError(f"{where}: `axis` must be an int (0, 1 or 2), got {type(axis).__name__}")
    if axis not in (0, 1, 2):
        raise ValueError(f"{where}: `axis` must be 0, 1 or 2, got {axis}")
    return int(axis)


def _sharpness(where: str, w) -> float:
    if isinstance(w, (bool, np.bool_)) or not isinstance(w, (int, float, np.integer, np.floating)):
        raise TypeError(f"{where}: `w` must be a real number, got {type(w).__name__}")
    w = float(w)
    if not (w > 0 and np.isfinite(w)):
        raise ValueError(f"{where}: `w` must be finite and > 0, got {w}")
    return w


def esi_gap(W, axes=(2,), w: float = 1000.0):
    """`mean((H - W)^2)` with `H` the minimum of the soft double-height-field hulls of `W`
    along the given grid axes ([`height_field_hull`][voxax.energies.height_field_hull]): zero
    exactly when the shape equals the intersection of those hulls (for one axis: when it
    can be cast in a two-piece mould parting perpendicular to the axis)."""
    import jax.numpy as jnp

    where = "voxax.energies.esi_gap"
    if isinstance(axes, (int, np.integer)) and not isinstance(axes, (bool, np.bool_)):
        axes = (axes,)
    if not isinstance(axes, (tuple, list)):
        raise TypeError(f"{where}: `axes` must be a tuple of grid axes (0, 1, 2), got {type(axes).__name__}")
    axes = tuple(_axis(where, a) for a in axes)
    if not axes:
        raise ValueError(f"{where}: `axes` must hold at least one axis")
    H = height_field_hull(W, axes[0], w)
    for a in axes[1:]:
        H = jnp.minimum(H, height_field_hull(W, a, w))
    return jnp.mean((H - jnp.asarray(W)) ** 2)
