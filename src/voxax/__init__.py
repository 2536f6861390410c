"""voxax: exact differentiable voxelization of triangle meshes and polylines for JAX.

The public API:

- `voxax.Grid`: the regular grid a voxelization lives on.
- `voxax.voxelize(vertices, faces, grid)`: box-filtered winding numbers, differentiable
  in the vertices (closed-form gradient), under jit, grad and vmap.
- `voxax.data`: procedurally generated demo meshes; `voxax.io`: mesh loading and saving.
- `voxax.intersections(vertices, faces)`: the exact triangle-triangle intersection test.
- `voxax.winding_number`: exact generalised winding numbers at points;
  `voxax.voxelize_mc`: Monte Carlo voxelization with wider boxes and Gaussians;
  `voxax.box_filter`: integer-scaled box filters of a voxelization; `voxax.Kernel`: the
  filter-kernel protocol (bring your own kernel).
- `voxax.energies`: pure-JAX energies on grids and meshes (self-intersection, bandsaw,
  tiling, ARAP, ...); `voxax.minimize`: an optax/optimistix minimization driver with
  stopping rules (`voxax.StopRules`, `voxax.StopReason`) and box bounds.
  tiling, ARAP, ...); `voxax.minimize`: an optimistix/optax minimization driver;
  `voxax.least_squares`: Levenberg-Marquardt, Gauss-Newton and dogleg on residuals.
- `voxax.apps`: the paper's applications (self-intersections, bandsaw, tiling);
  `voxax.fabricate`: bandsaw templates (SVG) and exact cut solids.
- `voxax.isosurface(values, grid, level)`: marching cubes (squares in 2D), differentiable in
  the samples; `voxax.isosurface_fn(fn, params, grid)`: MeshSDF for fields given as functions.
- `voxax.BVH`, `voxax.closest_points`, `voxax.first_hits`, `voxax.any_hits`,
  `voxax.all_hits`: exact closest points and watertight ray hits on triangle meshes;
  `voxax.nearest_neighbors`: exact k nearest neighbours of points.
- `voxax.metrics`: surface sampling, Chamfer, Hausdorff, F-score, triangle quality,
  topology reports and IoU.
- `voxax.fields`: analytic signed distances, implicit surfaces, CSG, SIREN and DeepSDF.
- `voxax.reference`: a slow, independent NumPy implementation used as the test oracle.
- `voxax.export_safety_checks()`: what `jax.export` needs to export functions that call the
  kernels.
- `voxax.show_config()`: the version, the kernel library and the vector paths and thread
  count this machine uses; `voxax.__version__`.
"""

from typing import TYPE_CHECKING

from . import _kernels  # noqa: F401  (registers the kernels with XLA)
from ._grid import Grid
from ._mesh import Mesh
from ._voxelize import use_host_callback, voxelize, voxelize_corner_gradients
from ._voxelize import Box, Gaussian, Kernel, box_filter, voxelize_mc, voxelize_mc_tangent
from ._spatial import winding_number
from ._isosurface import IsoMesh, isosurface, isosurface_fn, isosurface_topology, isosurface_vertices
from ._spatial import (
    BVH,
    AllHits,
    ClosestPoints,
    RayHits,
    all_hits,
    any_hits,
    closest_points,
    first_hits,
    nearest_neighbors,
)
from ._kernels.export import export_safety_checks, ffi_targets
from ._voxelize import slab_grids, voxelize_sharded, voxelize_slab
from ._voxelize import SparseGrid, sparse_capacity, voxelize_sparse
from ._spatial import Intersections, intersections

from ._config import show_config
from . import _version

__version__ = _version.version()

# The systems and the optimization drivers load on first use (PEP 562), so that
# `import voxax` (and every command-line call) does not pay for optimistix, equinox,
# trimesh or manifold3d until they are needed.
_LAZY_MODULES = frozenset({
    "apps", "baselines", "curves", "cvt", "data", "energies", "esi", "fabricate", "fc", "fields", "io",
    "metrics", "nesi", "plot", "raster", "reference",
})
_LAZY_NAMES = {
    "minimize": "_optimize", "MinimizeResult": "_optimize", "StopReason": "_optimize", "StopRules": "_optimize",
    "least_squares": "_optimize", "LeastSquaresResult": "_optimize",
}


if TYPE_CHECKING:  # the lazy names, for type checkers and the documentation's static analysis
    from . import (
        apps,
        baselines,
        curves,
        cvt,
        data,
        energies,
        esi,
        fabricate,
        fc,
        fields,
        io,
        metrics,
        nesi,
        plot,
        raster,
        reference,
    )
    from ._optimize import LeastSquaresResult, MinimizeResult, StopReason, StopRules, least_squares, minimize


def __getattr__(name: str):
    import importlib

    if name in _LAZY_MODULES:
        return importlib.import_module(f".{name}", __name__)
    if name in _LAZY_NAMES:
        value = getattr(importlib.import_module(f".{_LAZY_NAMES[name]}", __name__), name)
        globals()[name] = value
        return value
    raise AttributeError(f"module 'voxax' has no attribute {name!r}")


def __dir__():
    return sorted(set(globals()) | _LAZY_MODULES | set(_LAZY_NAMES))

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
    "Kernel",
    "Box",
    "Gaussian",
    "minimize",
    "isosurface",
    "isosurface_fn",
    "isosurface_topology",
    "isosurface_vertices",
    "IsoMesh",
    "MinimizeResult",
    "StopRules",
    "StopReason",
    "BVH",
    "ClosestPoints",
    "RayHits",
    "AllHits",
    "closest_points",
    "first_hits",
    "any_hits",
    "all_hits",
    "nearest_neighbors",
    "fields",
    "metrics",
    "raster",
    "cvt",
    "fc",
    "esi",
    "nesi",
    "export_safety_checks",
    "least_squares",
    "voxelize_sharded",
    "voxelize_slab",
    "voxelize_sparse",
    "SparseGrid",
    "sparse_capacity",
    "slab_grids",
    "LeastSquaresResult",
    "ffi_targets",
    "apps",
    "fabricate",
    "baselines",
    "curves",
    "data",
    "energies",
    "io",
    "plot",
    "reference",
    "show_config",
    "__version__",
]
