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

The package follows the pipeline: `_frames` (inputs, pixel frames, candidate axes),
`_depth` (depth maps, height-field solids), `_problem` (the selection's precomputed
energy terms), `_search` (branch and bound), `_select` (`select`, `ESI`) and `_mesh`
(occupancy, meshing, the energy of one choice); the C++ calls are in
`voxax._kernels.esi`. The grid energies `height_field_hull` and `esi_gap` live in
`voxax.energies` (kept here as aliases).
"""

from __future__ import annotations

from ..energies import esi_gap, height_field_hull
from ._depth import DepthMap, depth_map, height_field_solid
from ._frames import Frame, candidates, closed_mesh, fibonacci_sphere, frame_for
from ._mesh import energy, intersect_solids, occupancy, to_mesh
from ._select import ESI, select

__all__ = [
    "DepthMap",
    "ESI",
    "Frame",
    "candidates",
    "closed_mesh",
    "depth_map",
    "energy",
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
