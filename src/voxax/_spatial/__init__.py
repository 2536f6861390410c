"""Spatial queries on triangle meshes and points (public names re-exported by `voxax`).

- `bvh`: the BVH, exact closest points, watertight ray hits, k nearest neighbours.
- `winding`: generalised winding numbers at points.
- `intersect`: the exact triangle-triangle intersection test of a mesh with itself.
"""

from .bvh import BVH, AllHits, ClosestPoints, RayHits, all_hits, any_hits, closest_points, first_hits, nearest_neighbors
from .intersect import Intersections, intersections
from .winding import winding_number

__all__ = [
    "BVH", "AllHits", "ClosestPoints", "RayHits", "all_hits", "any_hits", "closest_points", "first_hits",
    "nearest_neighbors", "Intersections", "intersections", "winding_number",
]
