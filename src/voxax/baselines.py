"""Baselines to compare voxax against: "discretise, then differentiate".

[`point_sampled`][voxax.baselines.point_sampled] is the approach of Luo et al. (2024)
("DOPH") that the paper compares against in Sec. 4.1 and Fig. 6: sample the *sharp*
(unsmoothed) winding number at points of the grid, interpolate (multi)linearly between the
samples, and differentiate with plain autodiff. Because the sharp winding number is
piecewise constant in the vertices, the result does not change under small moves of the
surface: its finite-difference derivatives are zero (unless a sample point sits within the
perturbation of the surface), and its autodiff derivatives are exactly zero here (the
indicator is `round` of the generalised winding number; the original's spurious non-zero
autodiff values very close to the surface come from its soft indicator). voxax instead
samples the *box-filtered* winding number, whose derivatives are the expected ones.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

from . import _validate
from ._grid import Grid
from ._spatial import winding_number

__all__ = ["point_sampled", "interpolate"]


def interpolate(W, grid: Grid, points) -> jax.Array:
    """Multilinear (bilinear in 2D, trilinear in 3D) interpolation of voxel-centre values.

    `W[i, j, k]` is taken to be the value at the centre of voxel (i, j, k); outside the
    grid the values are 0 (points between the outer centres and the grid's border blend
    towards 0). Differentiable in `W` and `points`.

    **Arguments:**

    - `W`: `grid.shape` float array; `grid`: its `voxax.Grid`.
    - `points`: `(..., d)` float.

    **Returns:** `points.shape[:-1]` array.
    """
    where = "voxax.baselines.interpolate"
    _validate.grid(where, grid)
    W = _validate.typed_array(where, "W", W, "fiub")
    W = jnp.asarray(W)
    if not jnp.issubdtype(W.dtype, jnp.floating):
        W = W.astype(jnp.result_type(float))
    points = jnp.asarray(_validate.coordinates(where, "points", points, grid.dim), W.dtype)
    d = grid.dim
    if W.shape != grid.shape or points.shape[-1] != d:
        raise ValueError(f"voxax.baselines.interpolate: need W of shape {grid.shape} and points (..., {d})")
    lead = points.shape[:-1]
    x = points.reshape(-1, d)
    Wp = jnp.pad(W, 1)  # zero ring: index i of W is i + 1 of Wp
    base, frac = [], []
    for a in range(d):
        u = (x[:, a] - grid.lower[a]) / grid.spacing[a] - 0.5  # continuous centre index
        u = jnp.clip(u, -1.0, grid.shape[a])
        i0 = jnp.floor(u)
        base.append(i0.astype(jnp.int32) + 1)
        frac.append(u - i0)
    out = jnp.zeros(x.shape[0], W.dtype)
    for corner in np.ndindex(*(2,) * d):
        idx = tuple(jnp.clip(base[a] + corner[a], 0, Wp.shape[a] - 1) for a in range(d))
        wgt = jnp.ones(x.shape[0], W.dtype)
        for a in range(d):
            wgt = wgt * (frac[a] if corner[a] else 1 - frac[a])
        out = out + wgt * Wp[idx]
    return out.reshape(lead)


def point_sampled(vertices, faces=None, grid: Grid | None = None, *, supersample: int = 1, points=None, chunk_size: int | None = None):
    """Point-sampled winding numbers: the "discretise, then differentiate" baseline.

    The sharp winding number `round(w)` (w the generalised winding number of
    [`voxax.winding_number`][voxax.winding_number], so the integer ray-crossing
    count of a closed mesh) is sampled at `supersample^d` regularly spaced points per voxel
    (the centres of the voxels of the grid refined `supersample` times per axis; with
    `supersample=1`, the voxel centres) and averaged per voxel. With `points`, the result
    is then interpolated multilinearly at those points (see
    [`interpolate`][voxax.baselines.interpolate]) — smooth in the points, but still
    piecewise constant in the vertices.

    Plain JAX and plain autodiff: the gradient with respect to `vertices` is zero (exactly,
    `round` has derivative 0), and finite differences are zero for perturbations smaller
    than the distance from the surface to the nearest sample point.

    **Arguments:**

    - `vertices`: `(..., V, d)` float; `faces`: `(..., F, d)` int, as for `voxax.voxelize`
      (leading axes broadcast; or a mesh object in place of `vertices, faces`).
    - `grid`: the `voxax.Grid`.
    - `supersample`: int >= 1, samples per voxel and axis.
    - `points`: optional `(..., d)` float query points.
    - `chunk_size`: passed to `winding_number`.

    **Returns:** `batch + grid.shape` array (or `batch + points.shape[:-1]` with `points`),
    `batch` the broadcast batch axes of the mesh (none for one mesh).
    """
    where = "voxax.baselines.point_sampled"
    vertices, faces, (grid,) = _validate.unpack_mesh(where, vertices, faces, grid)
    grid = _validate.grid(where, grid)
    s = _validate.positive_int(where, "supersample", supersample)
    vertices, faces = _validate.mesh(where, vertices, faces, dim=grid.dim, batch=True)
    vertices = jnp.asarray(vertices)
    fine = Grid(grid.lower, grid.upper, tuple(n * s for n in grid.shape))
    centres = jnp.asarray(fine.centers(), vertices.dtype)
    w = jnp.round(winding_number(vertices, faces, centres, chunk_size=chunk_size))
    d = grid.dim
    batch = w.shape[: w.ndim - d]
    # (n0 s, n1 s, ...) -> (n0, s, n1, s, ...) -> mean over the s axes.
    split = sum(((n, s) for n in grid.shape), ())
    W = w.reshape(batch + split).mean(axis=tuple(len(batch) + a for a in range(1, 2 * d, 2)))
    if points is None:
        return W
    flat = W.reshape((-1,) + grid.shape)
    out = jax.vmap(lambda Wi: interpolate(Wi, grid, points))(flat)
    return out.reshape(batch + out.shape[1:])
