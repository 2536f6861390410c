"""`voxelize`: exact box-filtered winding numbers with closed-form gradients."""

from __future__ import annotations

import functools
import os

import jax
import jax.numpy as jnp
import numpy as np

from . import _ffi
from ._grid import Grid

__all__ = ["voxelize", "voxelize_corner_gradients", "use_host_callback"]

_INT32_MAX = np.iinfo(np.int32).max
# Largest coordinate magnitude accepted (the kernels check the same bound).
MAX_ABS_COORDINATE = 1e75


def voxelize(vertices, faces, grid: Grid) -> jax.Array:
    """Voxelizes a closed triangle mesh (3D) or closed polyline (2D) on `grid`.

    Every cell holds the *box-filtered winding number*: the average over the cell of the
    winding number of the surface, so cells fully inside a closed, outward-oriented mesh
    hold 1, cells outside hold 0, boundary cells hold the exact fraction of their volume
    inside, overlapping parts add up (2, 3, ...) and inverted parts count negatively.
    The value is computed exactly (up to rounding) by a C++ kernel, for meshes anywhere in
    space: parts outside the grid contribute exactly what they should to the cells inside.

    The result is differentiable in `vertices`: the gradient is the closed-form
    sub-triangle splat (see the docs, "How gradients are computed"). `voxelize` works
    under `jax.jit`, `jax.grad`/`jax.vjp` and `jax.vmap`; leading axes of `vertices` and
    `faces` are batch axes and broadcast against each other.

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
    vertices, faces = _check(vertices, faces, grid)
    try:
        return _voxelize(vertices, faces, grid)
    except TypeError as err:
        if "forward-mode" in str(err):
            raise TypeError(
                "voxax.voxelize supports reverse-mode differentiation only (jax.grad, jax.vjp, "
                "jax.jacrev, jax.value_and_grad); forward mode (jax.jvp, jax.jacfwd, jax.linearize) "
                "is not implemented. Use reverse mode instead."
            ) from err
        raise


# -- validation ----------------------------------------------------------------------------


def _is_concrete(x) -> bool:
    return not isinstance(x, jax.core.Tracer)


def _check(vertices, faces, grid):
    if not isinstance(grid, Grid):
        raise TypeError(f"voxelize: `grid` must be a voxax.Grid, got {type(grid).__name__}")
    if not hasattr(vertices, "dtype"):
        vertices = np.asarray(vertices)
        if vertices.dtype.kind in "iu":
            raise TypeError("voxelize: `vertices` must be float32 or float64, got integers")
    if not hasattr(faces, "dtype"):
        faces = np.asarray(faces)
    vdtype = np.dtype(vertices.dtype)
    if vdtype not in (np.float32, np.float64):
        raise TypeError(f"voxelize: `vertices` must be float32 or float64, got {vdtype}")
    if vdtype == np.float64 and not jax.config.jax_enable_x64:
        vdtype = np.dtype(np.float32)
    fdtype = np.dtype(faces.dtype)
    if fdtype.kind not in "iu":
        raise TypeError(f"voxelize: `faces` must be an integer array, got {fdtype}")
    d = grid.dim
    if vertices.ndim < 2 or vertices.shape[-1] != d:
        raise ValueError(
            f"voxelize: `vertices` must have shape (..., V, {d}) for a {d}D grid, got {tuple(vertices.shape)}"
        )
    if faces.ndim < 2 or faces.shape[-1] != d:
        kind = "triangles (F, 3)" if d == 3 else "segments (F, 2)"
        raise ValueError(f"voxelize: `faces` must hold {kind} for a {d}D grid, got shape {tuple(faces.shape)}")
    nv, nf = vertices.shape[-2], faces.shape[-2]
    if nv == 0 or nf == 0:
        raise ValueError(f"voxelize: empty mesh ({nv} vertices, {nf} faces)")
    if nv > _INT32_MAX or nf > _INT32_MAX:
        raise ValueError("voxelize: at most 2^31 - 1 vertices and faces are supported")
    try:
        batch = np.broadcast_shapes(tuple(vertices.shape[:-2]), tuple(faces.shape[:-2]))
    except ValueError:
        raise ValueError(
            f"voxelize: batch axes of vertices {tuple(vertices.shape)} and faces {tuple(faces.shape)} do not broadcast"
        ) from None
    _check_memory(grid, batch, vdtype)

    if _is_concrete(vertices):
        v = np.asarray(vertices)
        if not np.all(np.isfinite(v)):
            raise ValueError("voxelize: `vertices` contain NaN or Inf")
        if v.size and float(np.max(np.abs(v))) > MAX_ABS_COORDINATE:
            raise ValueError("voxelize: vertex coordinates must have magnitude <= 1e75")
    if _is_concrete(faces) and np.size(faces):
        f = np.asarray(faces)
        lo, hi = int(f.min()), int(f.max())
        if lo < 0:
            raise ValueError(f"voxelize: negative face index {lo}")
        if hi >= nv:
            raise ValueError(f"voxelize: face index {hi} is out of range for {nv} vertices")
    vertices = jnp.asarray(vertices, dtype=vdtype)
    if fdtype != np.int32:
        if _is_concrete(faces):
            faces = np.asarray(faces).astype(np.int32)  # in range: checked above
        else:
            # Traced indices are checked in the kernel; clipping first keeps values
            # beyond int32 out of range instead of wrapping them into it.
            faces = jnp.clip(faces, -1 if fdtype.kind == "i" else 0, _INT32_MAX).astype(jnp.int32)
    faces = jnp.asarray(faces)
    return vertices, faces


def _available_memory() -> int:
    try:
        with open("/proc/meminfo") as fh:
            for line in fh:
                if line.startswith("MemAvailable:"):
                    return int(line.split()[1]) * 1024
    except OSError:
        pass
    try:
        return os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES")
    except (ValueError, OSError, AttributeError):
        return 1 << 62


def _check_memory(grid: Grid, batch, dtype) -> None:
    count = int(np.prod(batch, dtype=np.float64)) * grid.size
    nbytes = count * np.dtype(dtype).itemsize
    available = _available_memory()
    if nbytes > available:
        raise MemoryError(
            f"voxelize: the output of shape {tuple(batch) + grid.shape} needs {nbytes / 2**30:.1f} GiB, "
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
    v, f, batch = _lead(vertices, faces)
    return _kernel(_ffi.FORWARD, jax.ShapeDtypeStruct(batch + grid.shape, v.dtype), grid, v, f)


# -- running the kernels: XLA FFI on CPU, a host callback elsewhere ------------------------

_FORCE_HOST_CALLBACK = os.environ.get("VOXAX_HOST_CALLBACK", "") == "1"


def use_host_callback(enabled: bool) -> None:
    """Forces (or stops forcing) the host-callback path used on non-CPU backends.

    The kernels are CPU code. A traced `voxelize` holds both ways of running them and
    the platform it is compiled for picks one (`jax.lax.platform_dependent`): the XLA
    FFI call on CPU, and on a GPU or TPU a `jax.pure_callback` that runs them on the
    host (data goes to the host and back). This switch makes functions traced after
    the call use the host callback on every platform, CPU included, which is how that
    path is tested. The environment variable `VOXAX_HOST_CALLBACK=1` sets it at import.

    **Arguments:**

    - `enabled`: `True` to force the host callback, `False` to choose by platform.
    """
    global _FORCE_HOST_CALLBACK
    _FORCE_HOST_CALLBACK = bool(enabled)


def _kernel(target: str, result: jax.ShapeDtypeStruct, grid: Grid, *args):
    """Runs FFI target `target` on `args`: directly on CPU, through the host elsewhere."""

    def on_cpu(*a):
        call = jax.ffi.ffi_call(target, result, vmap_method="expand_dims")
        return call(*a, **_ffi.grid_attributes(grid))

    def on_host(*a):
        host = functools.partial(_host_kernel, target, tuple(result.shape[a[0].ndim - 2 :]), grid)
        return jax.pure_callback(host, result, *a, vmap_method="expand_dims")

    if _FORCE_HOST_CALLBACK:
        out = on_host(*args)
    else:
        out = jax.lax.platform_dependent(*args, cpu=on_cpu, default=on_host)
    return _vary_like(out, *args)


def _varying_axes(x) -> frozenset:
    aval = jax.typeof(x)
    mat = getattr(aval, "mat", None)
    if mat is not None:
        return frozenset(getattr(mat, "varying", ()))
    return frozenset(getattr(aval, "vma", ()))


def _vary_like(out, *args):
    """Types `out` as varying over the mesh axes (inside `shard_map`) its inputs vary over.

    Kernel outputs are typed as invariant across mesh axes, which would make JAX treat a
    per-device result as replicated (and sum its cotangents across devices).
    """
    axes = frozenset().union(*(_varying_axes(a) for a in args)) - _varying_axes(out)
    if not axes:
        return out
    return jax.lax.pcast(out, tuple(sorted(axes)), to="varying")


def _host_kernel(target, trailing, grid, *args):
    # Runs the FFI kernel on the host CPU device with the arguments as given (a vmap
    # of the callback adds leading axes, which the kernel treats as batch axes).
    v, _, batch = _lead(args[0], args[1])
    result = jax.ShapeDtypeStruct(batch + tuple(trailing), v.dtype)
    cpu = jax.devices("cpu")[0]
    with jax.default_device(cpu):
        out = _host_jit(target, result, grid)(*[jax.device_put(a, cpu) for a in args])
    return np.asarray(out)


@functools.lru_cache(maxsize=64)
def _host_jit(target, result, grid):
    call = jax.ffi.ffi_call(target, result, vmap_method="expand_dims")
    return jax.jit(lambda *a: call(*a, **_ffi.grid_attributes(grid)))


def voxelize_corner_gradients(vertices, faces, cotangent, grid: Grid):
    """Per-face-corner gradients of `sum(cotangent * voxelize(vertices, faces, grid))`.

    This is the raw output of the backward kernel: for each face and each of its
    corners, the gradient with respect to that corner's position. `voxelize`'s VJP sums
    them into the vertices.

    **Arguments:**

    - `vertices`: `(..., V, d)` float, `faces`: `(..., F, d)` int, as for `voxelize`.
    - `cotangent`: `(..., *grid.shape)` float of the vertices' dtype.
    - `grid`: the `voxax.Grid`.

    **Returns:**

    `(..., F, d, d)` array: `out[..., f, c, :]` is the gradient for corner `c` of face `f`.
    """
    v, f, batch = _lead(vertices, faces)
    nf, d = f.shape[-2], f.shape[-1]
    g = jnp.asarray(cotangent, v.dtype)
    if g.shape[: g.ndim - grid.dim] != batch:
        g = jnp.broadcast_to(g, batch + grid.shape)
    return _kernel(_ffi.BACKWARD, jax.ShapeDtypeStruct(batch + (nf, d, d), v.dtype), grid, v, f, g)


def _sum_corners(corners, vertices, faces):
    """Sums corner gradients (*B, F, k, d) into vertex gradients of `vertices`' shape."""
    v, f, batch = _lead(vertices, faces)
    nv, d = v.shape[-2], v.shape[-1]
    nf, k = f.shape[-2], f.shape[-1]
    nb = int(np.prod(batch, dtype=np.int64))
    c = corners.reshape(nb, nf * k, d)
    idx = jnp.broadcast_to(f, batch + (nf, k)).reshape(nb, nf * k)
    dv = jax.vmap(lambda ci, fi: jnp.zeros((nv, d), corners.dtype).at[fi].add(ci))(c, idx)
    dv = dv.reshape(batch + (nv, d))
    # Sum over the batch axes along which the vertices were broadcast.
    axes = tuple(a for a in range(len(batch)) if v.shape[a] == 1 and batch[a] != 1)
    if axes:
        dv = dv.sum(axis=axes, keepdims=True)
    return dv.reshape(vertices.shape)


@functools.partial(jax.custom_vjp, nondiff_argnums=(2,))
def _voxelize(vertices, faces, grid):
    return _forward_call(vertices, faces, grid)


def _voxelize_fwd(vertices, faces, grid):
    return _forward_call(vertices, faces, grid), (vertices, faces)


def _voxelize_bwd(grid, residuals, cotangent):
    vertices, faces = residuals
    corners = voxelize_corner_gradients(vertices, faces, cotangent, grid)
    return _sum_corners(corners, vertices, faces), None


_voxelize.defvjp(_voxelize_fwd, _voxelize_bwd)
