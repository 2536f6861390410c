"""Spatial queries on triangle meshes and points (public names re-exported by `voxax`).

- `bvh`: the BVH, exact closest points and watertight ray hits.
- `knn`: exact k nearest neighbours of points.
- `winding`: generalised winding numbers at points.
- `intersect`: the exact triangle-triangle intersection test of a mesh with itself.
"""

from .bvh import BVH, AllHits, ClosestPoints, RayHits, all_hits, any_hits, closest_points, first_hits
from .intersect import Intersections, intersections
from .knn import nearest_neighbors
from .winding import winding_number

__all__ = [
    "BVH", "AllHits", "ClosestPoints", "RayHits", "all_hits", "any_hits", "closest_points", "first_hits",
    "nearest_neighbors", "Intersections", "intersections", "winding_number",
]
