"""Marching cubes (squares) on sampled grids: `isosurface`, `isosurface_topology`, `isosurface_vertices`."""

from __future__ import annotations

import warnings

import jax
import jax.numpy as jnp
import numpy as np

from .._grid import Grid
from .checks import _INT32_MAX, _capacities, _check_inside, _check_level, _check_threads, _check_values, _concrete, _pad
from .interpolate import _interpolate, _interpolate_eager
from .mesh import IsoMesh
from .scale import rescale_traced, unscale
from .stream import _isosurface_streamed
from .topology import _ffi_topology, host_topology


def isosurface_vertices(
    values,
    topology: IsoMesh,
    grid: Grid,
    level: float = 0.0,
    *,
    close=False,
    inside="below",
):
    """Vertex positions of a fixed topology, differentiable in the samples `values`.

    The exact adjoint of marching cubes' edge interpolation: vertex
    `v = p_a + t (p_b - p_a)`, `t = (level - f_a) / (f_b - f_a)`, computed in float64 (when x64
    is enabled), so `jax.grad` gives `dv/df_a = (t - 1)/(f_b - f_a) (p_b - p_a)` and
    `dv/df_b = -t/(f_b - f_a) (p_b - p_a)`. Works under `jit`, `grad` and `vmap`.

    **Arguments:**

    - `values`: `(..., *grid.shape)` float, the field samples at the cell centres.
    - `topology`: an [`IsoMesh`][voxax.IsoMesh] from [`isosurface_topology`][voxax.isosurface_topology]
      (or `isosurface`) of the same grid and `close` setting.
    - `grid`, `level`, `close`, `inside`: as in [`isosurface`][voxax.isosurface].

    **Returns:**

    `(..., V, d)` float, the vertices.
    """
    name = "isosurface_vertices"
    level = _check_level(level, name)
    inside = _check_inside(inside, name)
    values = _check_values(values, grid, name)
    concrete = _concrete(values)
    if concrete is not None and not np.all(np.isfinite(concrete)):
        raise ValueError(f"voxax.{name}: `values` must be finite (they contain NaN or Inf)")
    values, _ = _rescaled(values, level)
    if close is not False:
        values, grid = _pad(values, grid, level, inside, close)
    edges = _check_topology(topology, grid, name)
    v, gap = _interpolate(values, edges, topology.n_vertices, grid, level)
    msg = (
        f"voxax.{name}: `values` must differ at the two ends of every edge of `topology` "
        "(f_a == f_b leaves a vertex undefined)"
    )
    return _refuse(v, gap == 0, msg)


def isosurface_topology(
    values,
    grid: Grid,
    level: float = 0.0,
    *,
    inside: str = "below",
    close=False,
    capacity=None,
    threads: int | None = None,
):
    """The combinatorial part of [`isosurface`][voxax.isosurface] (no gradient flows through it).

    Same arguments as `isosurface`; returns an `IsoMesh` whose vertices are computed from the
    samples, with `jax.lax.stop_gradient` applied to them.
    """
    _check_threads(threads, "isosurface_topology")
    return isosurface(
        jax.lax.stop_gradient(_check_values(values, grid, "isosurface_topology")),
        grid,
        level,
        inside=inside,
        close=close,
        capacity=capacity,
        threads=threads,
    )


def isosurface(
    values,
    grid: Grid,
    level: float = 0.0,
    *,
    inside: str = "below",
    close=False,
    capacity=None,
    threads: int | None = None,
) -> IsoMesh:
    """Extracts the iso-surface `f = level` of a sampled field by marching cubes (squares in 2D).

    The field is sampled at the cell centres of `grid` (`values[i, j, k]` at
    `grid.centers()[i, j, k]`). Marching cubes runs in C++ on the cubes formed by 8 adjacent
    cell centres, with one vertex per crossed centre-to-centre edge (vertices sorted by edge)
    and the face-by-face rule with the asymptotic decider on ambiguous faces, so the output
    is closed, 2-manifold and consistently oriented wherever the level set stays inside the
    grid (use `close=True` otherwise). Samples equal to the level count as "above" the level,
    so exact ties leave no holes and no duplicate faces (such vertices sit exactly at the
    cell centre; their triangles may be degenerate, which voxax accepts).

    Vertex positions are interpolated along the edges in float64 (when x64 is enabled) and
    are differentiable in `values` (the exact adjoint of the interpolation; see
    [`isosurface_vertices`][voxax.isosurface_vertices]). The topology is piecewise constant in
    the values and carries no gradient.

    Two paths:

    - eager (`capacity=None`): exact-size arrays. It also works under eager `jax.grad`.
      Grids of more than 2^24 cells are swept in slabs of x planes, so that besides the
      input and the result it holds only one slab's worth of memory (with `close`, a padded
      copy of one slab instead of the whole grid); the result is the same, bit for bit.
    - jittable (`capacity` given): padded arrays of static size; `n_vertices`/`n_faces` give
      the counts, and a result that does not fit raises a `JaxRuntimeError` whose one-line
      message names the capacity it needs. Use this path under `jax.jit` and `jax.vmap`
      (leading axes of `values` are batch axes too).

    Samples of magnitude outside about `[1e-270, 1e270]` (float64; `[1e-27, 1e27]` for
    float32), subnormal ones included, are rescaled by a power of two before the
    interpolation, which is the same for `2^k f` (bit for bit where no sample is subnormal).
    Under jit this holds for `level=0`; at other levels keep the field inside that range.

    **Arguments:**

    - `values`: `(..., *grid.shape)` float32/float64 samples (integers are converted).
    - `grid`: the `voxax.Grid` the samples live on (2D or 3D).
    - `level`: float, the iso-value (static).
    - `inside`: `"below"` (SDF-like: `f < level` inside, the default) or `"above"`
      (occupancy-like, such as `voxelize`'s output with `level=0.5`). Faces are oriented
      with normals pointing out of the inside.
    - `close`: `False`, `True` or a number. `True` pads the grid with one layer of cells holding
      an outside value (`level ± max|f - level|`), a number pads with that value, so that
      surfaces reaching the grid's boundary close there. Vertices on the padding edges lie
      between the boundary cell centres and the padding cells, up to one cell beyond `grid`.
    - `capacity`: `None`, an int (vertices and faces) or a `(vertices, faces)` pair.
    - `threads`: threads of the eager path's kernel, an int >= 1 or `None` (`VOXAX_NUM_THREADS`,
      or all cores); the result is the same for any count. The `capacity` path runs on
      XLA's CPU thread pool instead.

    **Returns:**

    An [`IsoMesh`][voxax.IsoMesh]: `vertices (..., V, d)`, `faces (..., F, d)` int32 and more.
    An empty mesh (with a warning, eagerly) when the field does not cross the level.

    **Example:**

    ```python
    >>> import numpy as np, voxax
    >>> grid = voxax.Grid.cube(32)
    >>> f = np.linalg.norm(grid.centers(), axis=-1) - 0.6
    >>> iso = voxax.isosurface(f, grid)
    >>> mesh = iso.to_mesh()
    >>> bool(abs(mesh.signed_volume() - 4 / 3 * np.pi * 0.6**3) < 0.01)
    True
    ```
    """
    name = "isosurface"
    level = _check_level(level, name)
    inside = _check_inside(inside, name)
    caps = _capacities(capacity, name)
    _check_threads(threads, name)
    values = _check_values(values, grid, name)
    d = grid.dim
    batch = values.shape[: values.ndim - d]
    if caps is None and not isinstance(values, jax.core.Tracer) and all(n == 1 for n in batch):
        iso = _isosurface_streamed(
            np.asarray(values).reshape(grid.shape), grid, level, inside, close, threads=threads
        )
        if not batch:
            return iso
        return jax.tree_util.tree_map(lambda x: x.reshape(batch + x.shape), iso)
    concrete = _concrete(values)
    if concrete is not None and not np.all(np.isfinite(concrete)):
        raise ValueError("voxax.isosurface: `values` must be finite (they contain NaN or Inf)")
    values, k = _rescaled(values, level)
    if concrete is not None:
        concrete = _concrete(values)
    if close is not False:
        values, grid = _pad(values, grid, level, inside, close)
        if concrete is not None:
            concrete = _concrete(values)
    if grid.size > _INT32_MAX:
        raise ValueError("voxax.isosurface: the grid has more than 2^31 - 1 cells")
    batch = values.shape[: values.ndim - d]
    if caps is None:
        edges, faces, nv, nf = _eager_topology(concrete, grid, level, batch, threads)
    else:
        edges, faces, nv, nf = _capacity_topology(values, level, d, caps)
    if inside == "above":
        faces = faces[..., ::-1] if d == 2 else faces[..., jnp.array([0, 2, 1])]
    if caps is None and not isinstance(values, jax.core.Tracer):
        vertices, min_gap = _interpolate_eager(np.asarray(values), edges, grid, level)
    else:
        vertices, min_gap = _interpolate(values, jnp.asarray(edges), nv, grid, level)
    if k is not None:
        min_gap = unscale(min_gap, k)
    return IsoMesh(vertices, faces, jnp.asarray(edges), nv, nf, min_gap)


def _eager_topology(concrete, grid: Grid, level: float, batch, threads):
    """Exact-size topology of concrete samples (a batch of at most one field)."""
    if concrete is None:
        raise TypeError(
            "voxax.isosurface: `capacity` must be given under jax.jit or jax.vmap (the eager path needs "
            "concrete values): pass a static capacity=(vertices, faces), the fast path for loops"
        )
    flat = concrete.reshape((-1,) + grid.shape)
    if batch and flat.shape[0] != 1:
        raise ValueError(
            "voxax.isosurface: batched values need a static `capacity=` (results of different sizes are padded)"
        )
    edges, faces = host_topology(
        flat[0] if flat.shape[0] else np.zeros(grid.shape), level, threads
    )
    if len(faces) == 0:
        warnings.warn(
            f"voxax.isosurface: the field does not cross level {level} (values in "
            f"[{concrete.min():.6g}, {concrete.max():.6g}]): the mesh is empty",
            RuntimeWarning,
            stacklevel=3,
        )
    edges = edges.reshape(batch + edges.shape)
    faces = jnp.asarray(faces.reshape(batch + faces.shape))
    nv = jnp.full(batch, edges.shape[-2], jnp.int32)
    nf = jnp.full(batch, faces.shape[-2], jnp.int32)
    return edges, faces, nv, nf


def _capacity_topology(values, level: float, d: int, caps):
    """Topology padded to static capacities, through the FFI call (jittable). A mesh that
    does not fit is refused by the kernel, naming the capacity it needs."""
    vcap, fcap = caps
    edges, faces, counts = _ffi_topology(
        jax.lax.stop_gradient(values), level, d, vcap, fcap
    )
    return edges, faces, counts[..., 0], counts[..., 1]


def _rescaled(values, level: float):
    """Samples of a level-0 field rescaled by a power of two when their magnitudes leave the
    range XLA computes with (see `scale`), and the traced exponent (None: not rescaled).
    Fields of another level keep their values (their level is static in the kernel)."""
    if level != 0.0:
        return values, None
    return rescale_traced(jnp.asarray(values), 0.0)


def _refuse(x, bad, msg: str):
    """`x`, or a `ValueError(msg)` when `bad` holds: eagerly when `bad` is concrete, else
    through `equinox.error_if`."""
    concrete = _concrete(bad)
    if concrete is not None:
        if np.any(concrete):
            raise ValueError(msg)
        return x
    import equinox as eqx

    return eqx.error_if(x, jnp.any(bad), msg)


def _check_topology(topology, grid: Grid, name: str):
    """The edges of `topology`, checked to be crossed edges of `grid` (the padded grid with
    `close`): cell indices in range, one grid step apart along an axis."""
    if not isinstance(topology, IsoMesh):
        raise TypeError(
            f"voxax.{name}: `topology` must be an IsoMesh (from isosurface_topology), got {type(topology).__name__}"
        )
    edges = jnp.asarray(topology.edges)
    d = grid.dim
    if edges.ndim < 2 or edges.shape[-1] != 2 or jnp.shape(topology.faces)[-1] != d:
        raise ValueError(
            f"voxax.{name}: `topology` must come from a {d}D grid (edges (V, 2), faces (F, {d})), "
            f"got edges {tuple(edges.shape)} and faces {tuple(jnp.shape(topology.faces))}"
        )
    shape = grid.shape
    strides = [int(np.prod(shape[a + 1 :], dtype=np.int64)) for a in range(d)]
    concrete, counts = _concrete(topology.edges), _concrete(topology.n_vertices)
    xp = np if concrete is not None and counts is not None else jnp  # a concrete topology is checked now
    if xp is np:
        edges = concrete.astype(np.int64)
    ia, ib = edges[..., 0], edges[..., 1]
    valid = xp.arange(edges.shape[-2]) < xp.asarray(topology.n_vertices)[..., None]
    step = ib - ia
    along = xp.zeros(step.shape, bool)
    for s in strides:
        along = along | (step == s)
    bad = valid & ((ia < 0) | (ib >= grid.size) | ~along)
    msg = (
        f"voxax.{name}: `topology` must be made on this grid {shape} with the same `close` "
        "setting: its edges are not edges of this grid"
    )
    if xp is np:
        if np.any(bad):
            raise ValueError(msg)
        return jnp.asarray(topology.edges)
    return _refuse(edges, bad, msg)
