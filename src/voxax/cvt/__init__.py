"""Quality triangle meshes of anything that can be rasterised, by a discrete restricted CVT.

The pipeline (after Raster2Mesh): sample the surface where the cell-centre lines of a grid
along x, y and z cross it ([`fragments`][voxax.cvt.fragments]: meshes, implicit fields,
sampled grids and boolean combinations of them); place seeds in proportion to area
([`init_seeds`][voxax.cvt.init_seeds]) and optimise them towards a centroidal Voronoi
tessellation restricted to the samples ([`optimize`][voxax.cvt.optimize]: Lloyd or
L-BFGS on [`energy`][voxax.cvt.energy]); read the restricted Delaunay triangulation off
the samples' nearest seeds ([`rdt`][voxax.cvt.rdt], C++). [`remesh`][voxax.cvt.remesh]
runs it all.

```python
>>> import jax; jax.config.update("jax_enable_x64", True)
>>> import voxax
>>> mesh, report = voxax.cvt.remesh(voxax.data.icosphere(3), 300, method="lloyd", steps=20, progress=False)
>>> report.closed, report.euler_characteristic
(True, 2)

```
"""

from __future__ import annotations

from ._fragments import CSG, Fragments, fragments
from ._optimize import CVTResult, assign, energy, energy_gradient, init_seeds, lloyd_step, optimize, respawn
from ._rdt import RdtReport, rdt
from ._remesh import RemeshResult, remesh

__all__ = [
    "CSG",
    "CVTResult",
    "Fragments",
    "RdtReport",
    "RemeshResult",
    "assign",
    "energy",
    "energy_gradient",
    "fragments",
    "init_seeds",
    "lloyd_step",
    "optimize",
    "rdt",
    "remesh",
    "respawn",
]
