"""One grid across devices: `voxelize_sharded` decomposes the grid into slabs along x."""

from __future__ import annotations

import functools

import jax
import numpy as np
from jax.sharding import Mesh, NamedSharding
from jax.sharding import PartitionSpec as P

from .. import _validate
from .._grid import Grid
from .api import voxelize

__all__ = ["slab_grids", "voxelize_sharded", "voxelize_slab"]


def slab_grids(grid: Grid, count: int) -> list[Grid]:
    """Splits `grid` into `count` slabs of equal width along x (axis 0).

    Slab `k` covers the cells `[k * m, (k + 1) * m)` along x, with `m = shape[0] // count`;
    its x planes are the planes of `grid` (`grid.edges(0)`), the other axes are unchanged.

    **Arguments:**

    - `grid`: a `voxax.Grid`.
    - `count`: int, how many slabs; must divide `grid.shape[0]`.

    **Returns:**

    A list of `count` `voxax.Grid`s.
    """
    where = "voxax.slab_grids"
    if not isinstance(grid, Grid):
        raise TypeError(f"{where}: `grid` must be a voxax.Grid, got {type(grid).__name__}")
    count = _validate.positive_int(where, "count", count)
    if grid.shape[0] % count:
        raise ValueError(f"{where}: `count` must divide the grid's {grid.shape[0]} cells along x ({count} slabs do "
                         f"not divide {grid.shape[0]} cells)")
    return _slabs(grid, count)


def _slabs(grid: Grid, count: int) -> list[Grid]:
    """`slab_grids` for a device count, refused in the words of `voxelize_sharded`."""
    nx = grid.shape[0]
    if count < 1 or nx % count:
        raise ValueError(
            f"voxax.voxelize_sharded: {count} devices along the sharded axis do not divide the grid's "
            f"{nx} cells along x; choose a grid whose x resolution is a multiple of the device count"
        )
    m = nx // count
    return [grid.slab(k * m, (k + 1) * m) for k in range(count)]


def voxelize_sharded(vertices, faces=None, grid: Grid | None = None, mesh: Mesh | None = None,
                     axis_name: str | None = None):
    """Voxelizes on a grid distributed across the devices of `mesh` along x.

    Every device along `axis_name` voxelizes its own slab of the grid (the cells
    `[k * m, (k + 1) * m)` along x, `m = grid.shape[0] / devices`) from the whole mesh.
    This is exact, as `voxelize` handles meshes partly outside its grid: each slab holds
    the values the full grid holds there. No device ever stores more than its slab, so
    a grid `devices` times larger than one device's memory fits. The vertices and faces
    are replicated; the result is a global `jax.Array` sharded along x with a
    `NamedSharding(mesh, P(..., axis_name, None, None))`. Gradients with respect to the
    vertices are the sums of every slab's gradient across the devices. The function
    works eagerly, under `jax.jit`, `jax.grad`, `jax.jvp` and `jax.vmap`.

    The slabs are windows of the full grid ([`Grid.slab`][voxax.Grid.slab]): the kernels
    cut every face at the full grid's planes, starting from the face's own first cell, so
    the result equals `voxelize(vertices, faces, grid)` bit for bit (values and forward-mode
    tangents). Gradients are sums of per-slab sums, equal to the single-device gradient up
    to rounding (about 1e-16 relative).

    **Arguments:**

    - `vertices`: `(..., V, d)` float, `faces`: `(..., F, d)` int, as for `voxelize`.
    - `grid`: the global `voxax.Grid`; `grid.shape[0]` must be a multiple of the number
      of devices along `axis_name`.
    - `mesh`: a `jax.sharding.Mesh`.
    - `axis_name`: str, the mesh axis the grid's x axis is split over.

    **Returns:**

    `(..., *grid.shape)` array, sharded along its x axis over `axis_name`.

    **Raises:**

    `TypeError` for a mesh that is not a `jax.sharding.Mesh`, `ValueError` for a mesh
    without the named axis or a device count that does not divide `grid.shape[0]`, and
    what `voxelize` raises for bad vertices or faces.
    """
    vertices, faces, (grid, mesh, axis_name) = _validate.unpack_mesh(
        "voxax.voxelize_sharded", vertices, faces, grid, mesh, axis_name
    )
    if not isinstance(mesh, Mesh):
        raise TypeError(f"voxax.voxelize_sharded: `mesh` must be a jax.sharding.Mesh, got {type(mesh).__name__}")
    if axis_name not in mesh.axis_names:
        raise ValueError(
            f"voxax.voxelize_sharded: the device mesh has axes {tuple(mesh.axis_names)} and no axis named {axis_name!r}"
        )
    if not isinstance(grid, Grid):
        raise TypeError(f"voxax.voxelize_sharded: `grid` must be a voxax.Grid, got {type(grid).__name__}")
    if _validate.is_concrete(vertices) and _validate.is_concrete(faces):
        _validate.mesh("voxax.voxelize_sharded", vertices, faces, dim=grid.dim, batch=True)  # before any int32 cast
    count = int(mesh.shape[axis_name])
    slabs = tuple(_slabs(grid, count))
    nb = max(np.ndim(vertices), np.ndim(faces)) - 2
    out_spec = P(*([None] * nb), axis_name, *([None] * (grid.dim - 1)))
    fn = _sharded_fn(slabs, mesh, axis_name, nb, out_spec)
    return fn(vertices, faces)


def voxelize_slab(vertices, faces=None, grid: Grid | None = None, axis_name: str | None = None):
    """Inside `jax.shard_map`: this device's slab of `voxelize(vertices, faces, grid)`.

    The device with index `k` along `axis_name` (of `n` devices) gets the cells
    `[k * m, (k + 1) * m)` along x, `m = grid.shape[0] / n`, as an array of shape
    `(..., m, *grid.shape[1:])`; with `out_specs=P(..., axis_name, None, None)` the
    slabs form the global grid. The vertices and faces are typed as varying along
    `axis_name`, so gradients with respect to replicated vertices are summed across
    the devices.

    **Arguments:**

    - `vertices`, `faces`: as for `voxelize` (the whole mesh on every device).
    - `grid`: the global `voxax.Grid`.
    - `axis_name`: str, a mesh axis of the enclosing `shard_map`.

    **Returns:**

    `(..., grid.shape[0] / n, *grid.shape[1:])` array.
    """
    vertices, faces, (grid, axis_name) = _validate.unpack_mesh("voxax.voxelize_slab", vertices, faces, grid, axis_name)
    if not isinstance(grid, Grid):
        raise TypeError(f"voxax.voxelize_slab: `grid` must be a voxax.Grid, got {type(grid).__name__}")
    try:
        count = int(jax.lax.axis_size(axis_name))
    except (NameError, ValueError, KeyError) as err:
        raise ValueError(
            f"voxax.voxelize_slab: no mesh axis named {axis_name!r} here; call it inside jax.shard_map over that axis"
        ) from err
    slabs = _slabs(grid, count)
    vertices = jax.lax.pcast(jax.numpy.asarray(vertices), (axis_name,), to="varying")
    faces = jax.lax.pcast(jax.numpy.asarray(faces), (axis_name,), to="varying")
    branches = [functools.partial(_one_slab, grid=s) for s in slabs]
    return jax.lax.switch(jax.lax.axis_index(axis_name), branches, vertices, faces)


@functools.lru_cache(maxsize=32)
def _sharded_fn(slabs, mesh, axis_name, nb, out_spec):
    branches = [functools.partial(_one_slab, grid=s) for s in slabs]

    def body(v, f):
        # Each device computes a different slab from the replicated mesh: typing the inputs
        # as varying makes the transpose sum the per-slab vertex gradients across devices.
        v = jax.lax.pcast(v, (axis_name,), to="varying")
        f = jax.lax.pcast(f, (axis_name,), to="varying")
        return jax.lax.switch(jax.lax.axis_index(axis_name), branches, v, f)

    smap = jax.shard_map(body, mesh=mesh, in_specs=(P(), P()), out_specs=out_spec)

    def run(v, f):
        out = smap(v, f)
        return jax.lax.with_sharding_constraint(out, NamedSharding(mesh, out_spec))

    return run


def _one_slab(v, f, grid):
    return voxelize(v, f, grid)
