"""The core: exact box-filtered winding numbers of meshes on grids (public names re-exported
by `voxax`).

- `primitives`: the JAX primitives over the C++ forward, backward and tangent kernels, with
  their JVP, transpose and batching rules.
- `api`: `voxelize` and the corner gradients.
- `filters`: Monte Carlo voxelization with general kernels, integer box filters.
- `sharded`: one grid across several devices, by slabs.
- `sparse`: `voxelize_sparse` and `SparseGrid`, the boundary cells and runs along z.
"""

from .api import use_host_callback, voxelize, voxelize_corner_gradients
from .filters import Box, Gaussian, Kernel, box_filter, voxelize_mc, voxelize_mc_tangent
from .sharded import slab_grids, voxelize_sharded, voxelize_slab
from .sparse import SparseGrid, sparse_capacity, voxelize_sparse

__all__ = [
    "use_host_callback", "voxelize", "voxelize_corner_gradients",
    "Box", "Gaussian", "Kernel", "box_filter", "voxelize_mc", "voxelize_mc_tangent",
    "slab_grids", "voxelize_sharded", "voxelize_slab",
    "SparseGrid", "sparse_capacity", "voxelize_sparse",
]
