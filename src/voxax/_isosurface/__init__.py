"""Iso-surfaces of sampled fields: marching cubes / squares, differentiable in the samples.

- `mesh`: the result, `IsoMesh`;
- `checks`: argument checks and the padding of `close`;
- `topology`: the C++ kernel (through `voxax._kernels.contour`);
- `interpolate`: vertex positions along the crossed edges (differentiable);
- `stream`: the eager path, swept over slabs of x planes;
- `grid`: `isosurface`, `isosurface_topology`, `isosurface_vertices`;
- `samples`, `meshsdf`: fields given as functions, `isosurface_fn`.
"""

from __future__ import annotations

from .grid import isosurface, isosurface_topology, isosurface_vertices
from .mesh import IsoMesh
from .meshsdf import isosurface_fn

__all__ = [
    "IsoMesh",
    "isosurface",
    "isosurface_fn",
    "isosurface_topology",
    "isosurface_vertices",
]
