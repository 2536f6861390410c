"""`voxelize`: exact box-filtered winding numbers with closed-form gradients."""

from __future__ import annotations

import os

import jax
import jax.numpy as jnp
import numpy as np

from .. import _validate
from .._grid import Grid
from . import primitives as _ops

__all__ = ["use_host_callback", "voxelize", "voxelize_corner_gradients"]

_INT32_MAX = _validate.INT32_MAX


def voxelize(vertices, faces=None, grid: Grid | None = None) -> jax.Array:
    """Voxelizes a closed triangle mesh (3D) or closed polyline (2D) on `grid`.

    Every cell holds the *box-filtered winding number*: the average over the cell of the
    winding number of the surface, so cells fully inside a closed, outward-oriented mesh
    hold 1, cells outside hold 0, boundary cells hold the exact fraction of their volume
    inside, overlapping parts add up (2, 3, ...) and inverted parts count negatively.
    The value is computed exactly (up to rounding) by a C++ kernel, for meshes anywhere in
    space: parts outside the grid contribute exactly what they should to the cells inside.

    The result is differentiable in `vertices`: the gradient is the closed-form
    sub-triangle splat (see the docs, "How gradients are computed"), and the
    directional derivative (forward mode) is the same splat scattered into the voxels.
    `voxelize` works under `jax.jit`, `jax.grad`/`jax.vjp`/`jax.jacrev`,
    `jax.jvp`/`jax.jacfwd`/`jax.linearize`/`jax.linear_transpose` and `jax.vmap`; leading
    axes of `vertices` and `faces` are batch axes and broadcast against each other.
    Second derivatives with respect to the vertices (`jax.hessian`) raise
    `NotImplementedError`; Gauss-Newton products `J^T H J` (one `jax.jvp` and one
    `jax.vjp`) are available.

    A mesh object (a `voxax.Mesh` or a `trimesh.Trimesh`) may take the place of
    `vertices, faces`: `voxelize(mesh, grid)`.

    The count uses rays along +z (+y in 2D). For closed surfaces this is the winding
    number; for open surfaces (holes, lone sheets) it depends on the ray direction — use
    `voxax.io.is_watertight` to check a mesh, and `voxax.winding_number` for the
    generalised winding number of open surfaces at points.

    **Arguments:**

    - `vertices`: `(..., V, 3)` or `(..., V, 2)` float32 or float64, the vertex positions.
    - `faces`: `(..., F, 3)` int triangles or `(..., F, 2)` int segments, indexing
      `vertices`, oriented with outward normals (counter-clockwise seen from outside;
      in 2D, counter-clockwise loops). Degenerate faces are allowed and contribute nothing.
    - `grid`: a `voxax.Grid` with as many axes as the vertices have coordinates.

    **Returns:**

    `(..., *grid.shape)` array of the vertices' dtype, indexed `W[..., i, j, k]` (x, y, z).

    **Raises:**

    `TypeError` for non-float vertices or non-integer faces, `ValueError` for wrong shapes,
    empty meshes, NaN/Inf coordinates or face indices out of range, `MemoryError` when the
    output would not fit in memory. Under `jax.jit` the value checks run inside the kernel
    and raise a `jax.errors.JaxRuntimeError` (or `ValueError`) with the same message.

    **Example:**

    ```python
    >>> import voxax
    >>> mesh = voxax.data.box((-0.5, -0.5, -0.5), (0.5, 0.5, 0.5))
    >>> W = voxax.voxelize(mesh.vertices, mesh.faces, voxax.Grid.cube(4))
    >>> W.shape
    (4, 4, 4)
    >>> float(W.sum() * voxax.Grid.cube(4).voxel_volume)
    1.0
    ```
    """
    vertices, faces, (grid,) = _validate.unpack_mesh("voxax.voxelize", vertices, faces, grid)
    vertices, faces = _check(vertices, faces, grid)
    return _forward_call(vertices, faces, grid)


# -- validation ----------------------------------------------------------------------------


def _check(vertices, faces, grid, where="voxax.voxelize"):
    grid = _validate.grid(where, grid)
    vertices, faces = _validate.mesh(where, vertices, faces, dim=grid.dim, batch=True)
    vdtype = np.dtype(vertices.dtype)
    if vdtype == np.float64 and not jax.config.jax_enable_x64:
        vdtype = np.dtype(np.float32)
    batch = np.broadcast_shapes(tuple(vertices.shape[:-2]), tuple(faces.shape[:-2]))
    _check_memory(grid, batch, vdtype)
    vertices = jnp.asarray(vertices, dtype=vdtype)
    return vertices, _validate.int32_faces(faces)  # concrete indices: in range, checked above


def _check_memory(grid: Grid, batch, dtype) -> None:
    count = int(np.prod(batch, dtype=np.float64)) * grid.size
    nbytes = count * np.dtype(dtype).itemsize
    available = _validate.available_memory()
    if nbytes > available:
        raise MemoryError(
            f"voxax.voxelize: the output of shape {tuple(batch) + grid.shape} needs {nbytes / 2**30:.1f} GiB, "
            f"more than the {available / 2**30:.1f} GiB of memory available; use a coarser grid or smaller batches"
        )


# -- the differentiable op ------------------------------------------------------------------


def _lead(vertices, faces):
    """Gives vertices and faces the same number of leading axes (size-1 where absent)."""
    nb = max(vertices.ndim, faces.ndim) - 2
    v = vertices.reshape((1,) * (nb - (vertices.ndim - 2)) + vertices.shape)
    f = faces.reshape((1,) * (nb - (faces.ndim - 2)) + faces.shape)
    batch = tuple(np.broadcast_shapes(v.shape[:-2], f.shape[:-2]))
    return v, f, batch


def _forward_call(vertices, faces, grid: Grid):
    v, f, _ = _lead(vertices, faces)
    return _ops.forward(v, f, grid)


def use_host_callback(enabled: bool) -> None:
    """Forces (or stops forcing) the host-callback path used on non-CPU backends.

    The kernels are CPU code. A traced `voxelize` holds both ways of running them and
    the platform it is compiled for picks one (each primitive has a CPU lowering and a
    default one): the XLA FFI call on CPU, and on a GPU or TPU a `jax.pure_callback`
    that runs them on the host (data goes to the host and back). This switch makes
    functions lowered after the call use the host callback on every platform, CPU
    included, which is how that path is tested. The environment variable
    `VOXAX_HOST_CALLBACK=1` sets it at import.

    **Arguments:**

    - `enabled`: `True` to force the host callback, `False` to choose by platform.
    """
    if not isinstance(enabled, (bool, np.bool_)):
        raise TypeError(f"voxax.use_host_callback: `enabled` must be True or False, got {type(enabled).__name__}")
    _ops.set_host_callback(bool(enabled))


_ops.set_host_callback(os.environ.get("VOXAX_HOST_CALLBACK", "") == "1")


def voxelize_corner_gradients(vertices, faces=None, grid: Grid | None = None, cotangent=None):
    """Per-face-corner gradients of `sum(cotangent * voxelize(vertices, faces, grid))`.

    This is the raw output of the backward kernel: for each face and each of its
    corners, the gradient with respect to that corner's position. `voxelize`'s VJP sums
    them into the vertices. The arguments come in the order of
    `voxax.reference.voxelize_backward`, which computes the summed result in NumPy.

    **Arguments:**

    - `vertices`: `(..., V, d)` float, `faces`: `(..., F, d)` int, as for `voxelize`
      (or a mesh object in their place: `voxelize_corner_gradients(mesh, grid, cotangent)`).
    - `grid`: the `voxax.Grid`.
    - `cotangent`: `(..., *grid.shape)` float of the vertices' dtype.

    **Returns:**

    `(..., F, d, d)` array: `out[..., f, c, :]` is the gradient for corner `c` of face `f`.
    """
    where = "voxax.voxelize_corner_gradients"
    vertices, faces, (grid, cotangent) = _validate.unpack_mesh(where, vertices, faces, grid, cotangent)
    if cotangent is None:
        raise TypeError(f"{where}: missing `cotangent`")
    vertices, faces = _check(vertices, faces, grid, where)
    if not hasattr(cotangent, "dtype"):
        cotangent = np.asarray(cotangent)
    if np.dtype(cotangent.dtype).kind not in "fiu":
        raise TypeError(f"{where}: `cotangent` must be a real array, got {cotangent.dtype}")
    batch = np.broadcast_shapes(tuple(np.shape(vertices)[:-2]), tuple(np.shape(faces)[:-2]))
    if tuple(cotangent.shape[cotangent.ndim - grid.dim:]) != tuple(grid.shape) or cotangent.ndim - grid.dim < 0:
        raise ValueError(f"{where}: `cotangent` must have shape (..., *grid.shape) = (..., "
                         f"{', '.join(map(str, grid.shape))}), got {tuple(cotangent.shape)}")
    try:
        np.broadcast_shapes(tuple(cotangent.shape[: cotangent.ndim - grid.dim]), batch)
    except ValueError:
        raise ValueError(f"{where}: the batch axes of `cotangent` {tuple(cotangent.shape)} do not broadcast with "
                         f"those of the mesh {batch}") from None
    return _corner_gradients(vertices, faces, grid, cotangent)


def _corner_gradients(vertices, faces, grid, cotangent):
    v, f, batch = _lead(vertices, faces)
    g = jnp.asarray(cotangent, v.dtype)
    if g.shape[: g.ndim - grid.dim] != batch:
        g = jnp.broadcast_to(g, batch + grid.shape)
    return _ops.backward(v, f, g, grid)
