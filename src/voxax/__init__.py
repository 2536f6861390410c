"""voxax: exact differentiable voxelization of triangle meshes and polylines for JAX.

The public API:

- `voxax.Grid`: the regular grid a voxelization lives on.
- `voxax.voxelize(vertices, faces, grid)`: box-filtered winding numbers, differentiable
  in the vertices (closed-form gradient), under jit, grad and vmap.
- `voxax.data`: procedurally generated demo meshes; `voxax.io`: mesh loading and saving.
- `voxax.intersections(vertices, faces)`: the exact triangle-triangle intersection test.
- `voxax.winding_number`: exact generalised winding numbers at points;
  `voxax.voxelize_mc`: Monte Carlo voxelization with wider boxes and Gaussians;
  `voxax.box_filter`: integer-scaled box filters of a voxelization.
- `voxax.energies`: pure-JAX energies on grids and meshes (self-intersection, bandsaw,
  tiling, ARAP, ...); `voxax.minimize`: an optimistix/optax minimization driver.
- `voxax.apps`: the paper's applications (self-intersections, bandsaw, tiling);
  `voxax.fabricate`: bandsaw templates (SVG) and exact cut solids.
- `voxax.reference`: a slow, independent NumPy implementation used as the test oracle.
"""

from . import _ffi  # noqa: F401  (registers the kernels with XLA)
from ._grid import Grid
from ._mesh import Mesh
from ._voxelize import use_host_callback, voxelize, voxelize_corner_gradients
from . import baselines, curves, data, energies, io, plot, reference
from . import apps, fabricate
from ._filters import Box, Gaussian, box_filter, voxelize_mc, voxelize_mc_tangent
from ._winding import winding_number
from ._intersections import Intersections, intersections
from ._minimize import MinimizeResult, StopRules, minimize

__version__ = "0.1.0"

__all__ = [
    "Grid",
    "Mesh",
    "use_host_callback",
    "voxelize",
    "voxelize_corner_gradients",
    "winding_number",
    "intersections",
    "Intersections",
    "voxelize_mc",
    "voxelize_mc_tangent",
    "box_filter",
    "Box",
    "Gaussian",
    "minimize",
    "MinimizeResult",
    "StopRules",
    "apps",
    "fabricate",
    "baselines",
    "curves",
    "data",
    "energies",
    "io",
    "plot",
    "reference",
    "__version__",
]
