"""The core: exact box-filtered winding numbers of meshes on grids (public names re-exported
by `voxax`).

- `primitives`: the JAX primitives over the C++ forward, backward and tangent kernels, with
  their JVP, transpose and batching rules.
- `api`: `voxelize` and the corner gradients.
- `filters`: Monte Carlo voxelization with general kernels, integer box filters.
- `sharded`: one grid across several devices, by slabs.
"""

from .api import use_host_callback, voxelize, voxelize_corner_gradients
from .filters import Box, Gaussian, Kernel, box_filter, voxelize_mc, voxelize_mc_tangent
from .sharded import slab_grids, voxelize_sharded, voxelize_slab

__all__ = [
    "use_host_callback", "voxelize", "voxelize_corner_gradients",
    "Box", "Gaussian", "Kernel", "box_filter", "voxelize_mc", "voxelize_mc_tangent",
    "slab_grids", "voxelize_sharded", "voxelize_slab",
]
