"""Explicit surface intersections (ESI): a closed shape as the intersection of height fields.

A *height field* along a unit direction `d` is the solid `HF(d)` of the points whose ray
along `+d` hits the surface S: below the surface's top depth map seen from `+d`. A
*double height field* hull `DHF(d) = HF(d) ∩ HF(-d)` is bounded by both depth maps along
`d`. An ESI is `DHF(d_0) ∩ HF(d_1) ∩ ... ∩ HF(d_m)` (m <= 3); it always contains S, and for
well-chosen axes it is close to S.

- [`depth_map`][voxax.esi.depth_map]: first and last hits along `d` on an orthographic
  pixel frame (exact BVH ray casts), with the mask and the hit faces' normals.
- [`candidates`][voxax.esi.candidates]: the DHF axes (a half sphere, since `DHF(d) =
  DHF(-d)`) and HF axes (the full sphere), spherical Fibonacci points plus the
  coordinate axes.
- [`select`][voxax.esi.select]: the DHF axis and up to three HF axes minimising the
  energy `E = Dist + min(mu (Dist + eps1), eps2)` (Chamfer distance plus surface coverage)
  by branch and bound.
- [`occupancy`][voxax.esi.occupancy]: exact inside/outside of an ESI at points (ray casts
  against the mesh).
- [`to_mesh`][voxax.esi.to_mesh]: a watertight mesh of the ESI, as the manifold3d
  intersection of height-field solids built from depth maps.

All geometry is float64 and computed eagerly on NumPy arrays through `voxax.BVH`.

**Arguments, in one order.** A surface is any of a `voxax.Mesh`, a `trimesh.Trimesh`, a
`(vertices, faces)` pair or the two arrays (`vertices, faces=None`), closed and
consistently oriented, with finite coordinates of magnitude at most `1e75` (the
selection, depth maps, occupancy and meshing scale the mesh by an exact power of two to
about unit size, so they work alike at every scale). Functions of a surface take it first
(`depth_map(vertices, faces, direction)`, `select(vertices, faces, ...)`); functions of an
ESI take the ESI first and then the mesh it was selected for, since an ESI holds only its
axes: `occupancy(esi, vertices, faces, points)`, `to_mesh(esi, vertices, faces, *,
resolution)`, `energy(esi, vertices, faces, ...)`, like `voxax.nesi.fit(esi, vertices,
faces, ...)`. A NESI holds its networks, so `voxax.nesi.occupancy(net, points)` and
`voxax.nesi.to_mesh(net, *, resolution)` take no mesh. Randomness is `key` (an int or a
JAX PRNG key; `seed` is its deprecated name), `threads` is `None` (`VOXAX_NUM_THREADS` or
every core) or an int >= 1 with the same bits for every count, and `select` shows a
progress bar unless `progress=False`. Errors read ``"voxax.esi.<fn>: `arg` must ..."``.

The package follows the pipeline: `_frames` (inputs, pixel frames, candidate axes),
`_depth` (depth maps, height-field solids), `_problem` (the selection's precomputed
energy terms), `_search` (branch and bound), `_select` (`select`, `ESI`) and `_mesh`
(occupancy, meshing, the energy of one choice); the C++ calls are in
`voxax._kernels.esi`. The grid energies `height_field_hull` and `esi_gap` live in
`voxax.energies` (kept here as aliases).
"""

from __future__ import annotations

from ..energies import esi_gap, height_field_hull
from ._depth import DepthMap, HeightFieldSolid, depth_map, height_field_solid
from ._frames import Candidates, Frame, candidates, closed_mesh, fibonacci_sphere, frame_for
from ._mesh import EnergyTerms, energy, energy_terms, intersect_solids, occupancy, to_mesh
from ._select import ESI, select

__all__ = [
    "Candidates",
    "DepthMap",
    "ESI",
    "EnergyTerms",
    "Frame",
    "HeightFieldSolid",
    "candidates",
    "closed_mesh",
    "depth_map",
    "energy",
    "energy_terms",
    "esi_gap",
    "height_field_hull",
    "fibonacci_sphere",
    "frame_for",
    "height_field_solid",
    "intersect_solids",
    "occupancy",
    "select",
    "to_mesh",
]
