"""Pure-JAX energies on voxel grids and meshes, for optimizing shapes through `voxax.voxelize`.

Grid energies take the output `W` of `voxax.voxelize` (box-filtered winding numbers,
`W[..., i, j, k]` indexed x, y, z):

- `self_intersection(W, eps)`: voxels covered more than once (paper, Sec. 4.2).
- `mellowmax`, `silhouettes`, `cut_shape`, `bandsaw_cut` (alias `bandsaw`): the bandsaw
  cut energy (paper, Sec. 4.3).
- `fold_periodic`, `tiling`: the space-filling energy (paper, Sec. 4.4).
- `volume(W, grid)`, `interpenetration(W_a, W_b)`: enclosed volume; overlap of two shapes.
- On a `voxax.SparseGrid` (from `voxax.voxelize_sparse`), without the dense grid:
  `sparse_self_intersection`, `sparse_volume`, `sparse_column_sums`, `sparse_silhouette_z`.
- `height_field_hull(W, axis, w)`, `esi_gap(W, axes, w)`: soft double-height-field hulls
  and the gap of a shape to their intersection (explicit surface intersections on grids).

Mesh energies:

- `arap(vertices, rest_vertices, faces)`: as-rigid-as-possible regulariser (spokes and
  rims, cotangent weights, SVD rotations held fixed), with `cotangent_weights` and
  `arap_rotations`.

Every function is pure JAX: it works under `jax.jit`, `jax.grad` and `jax.vmap`.
Solvers (`voxax.minimize`, optimistix) want objectives shaped `fn(y, args) -> scalar`;
write them as lambdas, or combine named terms with `objective`:

```python
grid = voxax.Grid.cube(64)

def fn(V, args):
    W = voxax.voxelize(V, F, grid)
    e_sect = voxax.energies.self_intersection(W)
    e_arap = voxax.energies.arap(V, V0, F)
    return e_sect + 0.005 * e_arap, {"sect": e_sect, "arap": e_arap, "max_w": W.max()}

result = voxax.minimize(fn, V0, has_aux=True, stop=voxax.StopRules(max_w_threshold=1.001))
```
"""

from ._arap import arap, arap_rotations, cotangent_weights
from ._grid import (
    bandsaw,
    bandsaw_cut,
    cut_shape,
    fold_periodic,
    interpenetration,
    mellowmax,
    self_intersection,
    silhouettes,
    tiling,
    volume,
)
from ._height_fields import esi_gap, height_field_hull
from ._objective import objective
from ._sparse import sparse_column_sums, sparse_self_intersection, sparse_silhouette_z, sparse_volume

__all__ = [
    "height_field_hull",
    "esi_gap",
    "mellowmax",
    "silhouettes",
    "cut_shape",
    "bandsaw_cut",
    "bandsaw",
    "self_intersection",
    "fold_periodic",
    "tiling",
    "volume",
    "interpenetration",
    "cotangent_weights",
    "arap_rotations",
    "arap",
    "objective",
    "sparse_self_intersection",
    "sparse_volume",
    "sparse_column_sums",
    "sparse_silhouette_z",
]
