"""`voxelize_sparse`: the exact box-filtered winding numbers of `voxelize` in sparse form.

A dense grid costs one value per cell, yet only the cells the surface passes through hold
fractions: along each column (the z axis) every other cell holds the value of the cell
above it, which changes only where the surface passes. `SparseGrid` stores the boundary
cells (the cells a piece of the surface lies in) with their values, and the runs of equal
values between them, so its size grows with the surface, not with the volume.

Three primitives, lowered to the kernels of csrc/voxelize/sparse_ffi.cc (called through
`voxax._kernels.voxelize`):

- `voxax_voxelize_sparse(vertices, faces) -> cells, values, runs, run_values, counts`,
  whose JVP is the tangent primitive (the values' tangents; everything else has none);
- `voxax_voxelize_sparse_tangent(vertices, faces, corner_tangents, cells, counts) ->
  dvalues`, linear in the corner tangents, with the backward primitive as its transpose;
- `voxax_voxelize_sparse_backward(vertices, faces, cells, cotangent, counts) -> corner
  gradients`, linear in the cotangent, with the tangent primitive as its transpose.
"""

from __future__ import annotations

import dataclasses
import functools
import math

import jax
import jax.numpy as jnp
import numpy as np
from jax.extend.core import Primitive
from jax.interpreters import ad, batching, mlir

from .. import _validate
from .._grid import Grid
from .._kernels import voxelize as kernels
from . import primitives as _ops
from .api import _lead

__all__ = ["SparseGrid", "sparse_capacity", "voxelize_sparse"]

FORWARD, BACKWARD, TANGENT = kernels.SPARSE_FORWARD, kernels.SPARSE_BACKWARD, kernels.SPARSE_TANGENT

_INT32_MAX = _validate.INT32_MAX


# -- the result type ------------------------------------------------------------------------


@jax.tree_util.register_dataclass
@dataclasses.dataclass(frozen=True)
class SparseGrid:
    """The box-filtered winding numbers of a mesh on a grid, in sparse form.

    Made by [`voxelize_sparse`][voxax.voxelize_sparse]. Along each column `(i, j)` (the z
    axis) the value of a cell equals the value `voxelize` gives it, bit for bit:

    - at a *boundary cell* (a cell a piece of the surface lies in), `values[n]` for the
      row `n` with `cells[n] == (i, j, k)`;
    - in a *run* `runs[m] == (i, j, k_start, k_stop)`, `run_values[m]` for every
      `k_start <= k < k_stop` (whole numbers up to rounding: 1 inside, 2 where two parts
      overlap, ...);
    - zero everywhere else.

    Rows are sorted by `(i, j, k)`. Rows past `counts[..., 0]` (cells) and
    `counts[..., 1]` (runs) are padding (cells `grid.shape`, runs `(nx, ny, 0, 0)`, values
    0): they exist under `jax.jit`, whose arrays have a static capacity, and in batches.
    Only the boundary values depend on the vertices to first order: the runs' cells hold
    no piece of the surface, so `jax.grad` and `jax.jvp` through `values` follow the
    closed-form splat of `voxelize`, and `run_values` carry no derivative.

    **Fields:**

    - `grid`: the [`Grid`][voxax.Grid] (static).
    - `cells`: `(..., C, 3)` int32 boundary cells `(i, j, k)`.
    - `values`: `(..., C)` float, their values.
    - `runs`: `(..., R, 4)` int32 runs `(i, j, k_start, k_stop)`.
    - `run_values`: `(..., R)` float, their values.
    - `counts`: `(..., 2)` int32, the numbers of boundary cells and runs.

    A `SparseGrid` is a JAX pytree: it passes through `jax.jit`, `jax.vmap` and
    `jax.grad`. Leading axes are batch axes (as for `voxelize`); the methods below take an
    unbatched grid (`jax.vmap` them over batches) unless they say otherwise.
    """

    cells: jax.Array
    values: jax.Array
    runs: jax.Array
    run_values: jax.Array
    counts: jax.Array
    grid: Grid = dataclasses.field(metadata=dict(static=True))

    # -- sizes ----------------------------------------------------------------------------

    @property
    def batch_shape(self) -> tuple:
        """The leading (batch) axes."""
        return tuple(self.values.shape[:-1])

    @property
    def capacity(self) -> tuple[int, int]:
        """`(C, R)`: the rows held for boundary cells and for runs (counts plus padding)."""
        return int(self.values.shape[-1]), int(self.run_values.shape[-1])

    @property
    def count(self) -> jax.Array:
        """`(...)` int32, the number of boundary cells."""
        return self.counts[..., 0]

    @property
    def run_count(self) -> jax.Array:
        """`(...)` int32, the number of runs."""
        return self.counts[..., 1]

    @property
    def nbytes(self) -> int:
        """The bytes of its arrays (the dense grid would take `grid.size` values)."""
        return int(sum(np.dtype(a.dtype).itemsize * math.prod(a.shape) for a in self._arrays()))

    def _arrays(self):
        return (self.cells, self.values, self.runs, self.run_values, self.counts)

    def __repr__(self) -> str:
        return (
            f"SparseGrid(batch={self.batch_shape}, capacity={self.capacity}, dtype={self.values.dtype}, "
            f"grid={self.grid})"
        )

    def _unbatched(self, where: str) -> None:
        if self.values.ndim != 1:
            raise ValueError(
                f"voxax.SparseGrid.{where}: takes an unbatched grid, got batch axes {self.batch_shape}; "
                "use jax.vmap or index the batch first (e.g. `jax.tree.map(lambda a: a[0], sg)`)"
            )

    # -- whole-grid quantities -------------------------------------------------------------

    def volume(self) -> jax.Array:
        """The enclosed volume, `sum(W) * voxel_volume` of the dense grid (one per batch item).

        Exact (up to rounding) for closed meshes inside the grid; differentiable in the
        vertices through the boundary values.
        """
        length = (self.runs[..., 3] - self.runs[..., 2]).astype(self.run_values.dtype)
        total = self.values.sum(axis=-1) + (self.run_values * length).sum(axis=-1)
        return total * jnp.asarray(self.grid.voxel_volume, self.values.dtype)

    def to_dense(self) -> jax.Array:
        """The dense grid `(..., *grid.shape)`, equal bit for bit to `voxelize`'s."""
        return self.window((0, 0, 0), self.grid.shape)

    # -- dense windows ----------------------------------------------------------------------

    def window(self, start, stop) -> jax.Array:
        """The cells `start <= (i, j, k) < stop` as a dense array (batch axes kept).

        **Arguments:**

        - `start`, `stop`: 3 ints each (static), within the grid, `start < stop`.

        **Returns:**

        `(..., *(stop - start))` float, the values `voxelize` gives these cells.
        """
        start, stop = _window_bounds("window", self.grid, start, stop)
        fn = functools.partial(_window, start=start, stop=stop)
        for _ in self.batch_shape:
            fn = jax.vmap(fn)
        return fn(self.cells, self.values, self.runs, self.run_values)

    def slab(self, start: int, stop: int, axis: int = 0) -> jax.Array:
        """The cells `start <= index < stop` along `axis` (all of the other axes), dense."""
        axis = operator_axis(axis)
        lo = [0, 0, 0]
        hi = list(self.grid.shape)
        lo[axis], hi[axis] = start, stop
        return self.window(lo, hi)

    def occupancy(self, threshold: float = 0.5, start=None, stop=None) -> jax.Array:
        """A dense boolean mask `W > threshold` of the grid or of a window `[start, stop)`."""
        start = (0, 0, 0) if start is None else start
        stop = self.grid.shape if stop is None else stop
        return self.window(start, stop) > threshold

    def isosurface(self, level: float = 0.5, start=None, stop=None, **kwargs):
        """The iso-surface `W = level` of the grid or a window, by `voxax.isosurface`.

        The window's values are sampled at its cell centres, on the window's own grid
        (`kwargs` go to `voxax.isosurface`, e.g. `close=True` to close it at the window's
        sides). Returns an `IsoMesh` in world coordinates.
        """
        from .._isosurface import isosurface

        self._unbatched("isosurface")
        start = (0, 0, 0) if start is None else start
        stop = self.grid.shape if stop is None else stop
        start, stop = _window_bounds("isosurface", self.grid, start, stop)
        lo = np.asarray(self.grid.lower, np.float64)
        h = np.asarray(self.grid.spacing, np.float64)
        sub = Grid(
            tuple(float(x) for x in lo + np.asarray(start) * h),
            tuple(float(x) for x in lo + np.asarray(stop) * h),
            tuple(int(b - a) for a, b in zip(start, stop)),
        )
        return isosurface(self.window(start, stop), sub, level, **kwargs)

    # -- values at cells --------------------------------------------------------------------

    def values_at(self, indices) -> jax.Array:
        """The values at cells `indices` (`(..., 3)` int `(i, j, k)`), as `voxelize` gives them.

        Differentiable through the boundary values; works under `jit`. Indices outside
        the grid give 0.
        """
        self._unbatched("values_at")
        q = jnp.asarray(indices)
        if q.shape[-1:] != (3,) or not jnp.issubdtype(q.dtype, jnp.integer):
            raise TypeError(f"voxax.SparseGrid.values_at: `indices` must be (..., 3) int, got {q.shape} {q.dtype}")
        shape = q.shape[:-1]
        out = _values_at(self.cells, self.values, self.runs, self.run_values, self.counts, q.reshape(-1, 3))
        return out.reshape(shape)

    def boundary_mask(self) -> jax.Array:
        """`(..., C)` bool: which rows of `cells`/`values` hold boundary cells (not padding)."""
        return jnp.arange(self.values.shape[-1]) < self.counts[..., 0:1]

    def run_mask(self) -> jax.Array:
        """`(..., R)` bool: which rows of `runs`/`run_values` hold runs (not padding)."""
        return jnp.arange(self.run_values.shape[-1]) < self.counts[..., 1:2]

    def fc_cells(self) -> np.ndarray:
        """`(K,)` int64 C-order indices of the boundary cells: the cells that pieces of the
        surface lie in, where `voxax.fc` places its tokens. Eager, unbatched."""
        self._unbatched("fc_cells")
        n = int(self.counts[0])
        c = np.asarray(self.cells[:n]).astype(np.int64)
        return np.ravel_multi_index((c[:, 0], c[:, 1], c[:, 2]), self.grid.shape)


def operator_axis(axis) -> int:
    if isinstance(axis, bool) or not isinstance(axis, (int, np.integer)) or not -3 <= axis < 3:
        raise ValueError(f"voxax.SparseGrid.slab: `axis` must be 0, 1 or 2, got {axis!r}")
    return int(axis) % 3


def _window_bounds(where, grid, start, stop):
    try:
        start = tuple(int(s) for s in start)
        stop = tuple(int(s) for s in stop)
    except (TypeError, ValueError):
        raise TypeError(f"voxax.SparseGrid.{where}: `start` and `stop` must be 3 ints each") from None
    if len(start) != 3 or len(stop) != 3:
        raise ValueError(f"voxax.SparseGrid.{where}: `start` and `stop` must be 3 ints each, got {start}, {stop}")
    for a in range(3):
        if not 0 <= start[a] < stop[a] <= grid.shape[a]:
            raise ValueError(
                f"voxax.SparseGrid.{where}: the window [{start}, {stop}) must lie in the grid {grid.shape} "
                "with start < stop on every axis"
            )
    return start, stop


@functools.partial(jax.jit, static_argnames=("start", "stop"))
def _window(cells, values, runs, run_values, *, start, stop):
    """The dense window of one (unbatched) sparse grid: runs painted by their row number
    (integer differences along z, exact), then the boundary values set."""
    shape = tuple(b - a for a, b in zip(start, stop))
    lo = jnp.asarray(start[:2], jnp.int32)
    ij = runs[:, :2] - lo
    out_of = jnp.any((ij < 0) | (ij >= jnp.asarray(shape[:2], jnp.int32)), axis=-1)
    k0 = jnp.clip(runs[:, 2] - start[2], 0, shape[2])
    k1 = jnp.clip(runs[:, 3] - start[2], 0, shape[2])
    drop = out_of | (k1 <= k0)
    i = jnp.where(drop, shape[0], ij[:, 0])  # out of range: dropped
    rid = jnp.arange(1, runs.shape[0] + 1, dtype=jnp.int32)
    diff = jnp.zeros((shape[0], shape[1], shape[2] + 1), jnp.int32)
    diff = diff.at[i, ij[:, 1], k0].add(rid, mode="drop")
    diff = diff.at[i, ij[:, 1], k1].add(-rid, mode="drop")
    which = jnp.cumsum(diff[..., :-1], axis=-1)
    padded = jnp.concatenate([jnp.zeros((1,), values.dtype), run_values])
    dense = padded[which]
    c = cells - jnp.asarray(start, jnp.int32)
    bad = jnp.any((c < 0) | (c >= jnp.asarray(shape, jnp.int32)), axis=-1)
    ci = jnp.where(bad, shape[0], c[:, 0])
    return dense.at[ci, c[:, 1], c[:, 2]].set(values, mode="drop")


@jax.jit
def _values_at(cells, values, runs, run_values, counts, q):
    q = q.astype(jnp.int32)
    n, r = counts[0], counts[1]
    c = _lower_bound(cells, n, q)
    cc = jnp.minimum(c, max(values.shape[0] - 1, 0))
    hit = (c < n) & jnp.all(cells[cc] == q, axis=-1) if values.shape[0] else jnp.zeros(q.shape[0], bool)
    m = _lower_bound(runs[:, :3], r, q.at[:, 2].add(1)) - 1
    mm = jnp.clip(m, 0, max(run_values.shape[0] - 1, 0))
    if run_values.shape[0]:
        run, rv = runs[mm], run_values[mm]
    else:
        run, rv = jnp.zeros((q.shape[0], 4), jnp.int32), jnp.zeros(q.shape[0], values.dtype)
    in_run = (m >= 0) & (run[:, 0] == q[:, 0]) & (run[:, 1] == q[:, 1]) & (q[:, 2] < run[:, 3])
    bv = values[cc] if values.shape[0] else jnp.zeros(q.shape[0], values.dtype)
    return jnp.where(hit, bv, jnp.where(in_run, rv, jnp.zeros((), values.dtype)))


def _lex_less(a, q):
    """Row-wise lexicographic a < q for int triples."""
    return (a[:, 0] < q[:, 0]) | (
        (a[:, 0] == q[:, 0]) & ((a[:, 1] < q[:, 1]) | ((a[:, 1] == q[:, 1]) & (a[:, 2] < q[:, 2])))
    )


def _lower_bound(keys, n, q):
    """For each query triple, the first row in keys[:n] (sorted) not below it."""
    size = keys.shape[0]
    lo = jnp.zeros(q.shape[0], jnp.int32)
    hi = jnp.full(q.shape[0], n, jnp.int32)
    if size == 0:
        return lo

    def step(_, lohi):
        lo, hi = lohi
        active = lo < hi
        mid = (lo + hi) // 2
        less = _lex_less(keys[jnp.minimum(mid, size - 1)], q)
        return jnp.where(active & less, mid + 1, lo), jnp.where(active & ~less, mid, hi)

    return jax.lax.fori_loop(0, max(1, int(size).bit_length()), step, (lo, hi))[0]


# -- the public function --------------------------------------------------------------------


def voxelize_sparse(vertices, faces=None, grid: Grid | None = None, *, capacity=None) -> SparseGrid:
    """Voxelizes a closed triangle mesh on a 3D `grid` into a [`SparseGrid`][voxax.SparseGrid].

    The values are those of [`voxelize`][voxax.voxelize], bit for bit
    (`voxelize_sparse(V, F, grid).to_dense()` equals `voxelize(V, F, grid)`), for any grid
    (odd, off-centre, anisotropic), meshes partly or wholly outside it, self-intersecting
    meshes, float32 and float64, and leading batch axes. The kernel clips the faces into
    the same column pieces as the dense one and sums them in the same order, but keeps only
    the cells the surface touches and the runs between them: memory and time grow with the
    surface (about n^2 on an n^3 grid), not with the volume.

    Differentiable in `vertices` through the boundary values (`jax.grad`, `jax.vjp`,
    `jax.jvp`, `jax.jacfwd`), by the closed-form splat of `voxelize` over the boundary cells
    only; the run values are whole numbers whose cells no piece of the surface enters and
    have derivative zero. So the gradient of any sum over cells (the volume, `sum(W^2)`,
    overlaps `W > 1`) equals the dense one. Works under `jax.jit` and `jax.vmap`.

    **Arguments:**

    - `vertices`: `(..., V, 3)` float32 or float64, `faces`: `(..., F, 3)` int, as for
      `voxelize` (or a mesh object in their place).
    - `grid`: a 3D `voxax.Grid`.
    - `capacity`: the rows to hold, an int (for both) or `(cells, runs)`. `None`: eagerly,
      exactly as many as needed (estimated by [`sparse_capacity`][voxax.sparse_capacity],
      and run again with the exact counts when the estimate was short); with traced
      vertices (under `jax.jit`, `jax.grad`, `jax.vmap`), `sparse_capacity(grid=grid)`.
      A result that does not fit raises an error naming the counts it needs — never a
      truncated grid. Under transformations, pass the capacity of an eager call
      (`voxelize_sparse(V, F, grid).capacity`) or a margin above it.

    **Returns:**

    A `SparseGrid` with the mesh's batch axes.

    **Raises:**

    As `voxelize` (`TypeError`, `ValueError` for bad meshes or grids, a 2D grid included);
    a `ValueError` (eagerly) or `jax.errors.JaxRuntimeError` (under `jax.jit`) when the
    capacity is exceeded.

    **Example:**

    ```python
    >>> import voxax
    >>> mesh = voxax.data.box((-0.5, -0.5, -0.5), (0.5, 0.5, 0.5))
    >>> sg = voxax.voxelize_sparse(mesh.vertices, mesh.faces, voxax.Grid.cube(8))
    >>> float(sg.volume())
    1.0
    >>> bool((sg.to_dense() == voxax.voxelize(mesh.vertices, mesh.faces, voxax.Grid.cube(8))).all())
    True
    ```
    """
    where = "voxax.voxelize_sparse"
    vertices, faces, (grid,) = _validate.unpack_mesh(where, vertices, faces, grid)
    vertices, faces = _check(where, vertices, faces, grid)
    v, f, batch = _lead(vertices, faces)
    concrete = _validate.is_concrete(v) and _validate.is_concrete(f)
    if capacity is not None:
        cap = _capacity(where, capacity)
        out = forward(v, f, grid, cap, strict=not concrete)
        if concrete:
            _raise_if_over(where, out[4], cap)
        return _build(out, grid)
    if not concrete:
        return _build(forward(v, f, grid, sparse_capacity(grid=grid), strict=True), grid)
    guess = tuple(_bucket(x, grid.size) for x in sparse_capacity(np.asarray(v), np.asarray(f), grid))
    out = forward(v, f, grid, guess, strict=False)
    need = np.asarray(out[4]).reshape(-1, 2).max(axis=0) if out[4].size else np.zeros(2, np.int64)
    need = (int(need[0]), int(need[1]))
    if need[0] > guess[0] or need[1] > guess[1]:
        out = forward(v, f, grid, need, strict=True)
    else:
        out = _trim(out, need)
    return _build(out, grid)


def sparse_capacity(vertices=None, faces=None, grid: Grid | None = None) -> tuple[int, int]:
    """An estimate of the rows `voxelize_sparse` needs: `(cells, runs)`.

    With a concrete mesh, from its faces' areas and perimeters in cell units: a surface
    of area `A` and unit normal `n` crosses about `A (|n_x| + |n_y| + |n_z|)` cells and
    makes about `A |n_z|` runs (on `voxax.data.large(100_000)` at 512^3 to 4096^3 the
    cells are this sum to 0.1%, the runs 0.83 to 0.93 of it); the estimate adds 15% and
    10% of the perimeters. It is an estimate, not a bound: `voxelize_sparse` runs again
    with the exact counts when it falls short. With `grid` alone, a
    size that fits a closed surface of moderate complexity spanning the grid:
    `4 (nx ny + ny nz + nz nx)` cells and `2 nx ny` runs. Both at most `grid.size`.
    """
    where = "voxax.sparse_capacity"
    if vertices is not None:
        vertices, faces, (grid,) = _validate.unpack_mesh(where, vertices, faces, grid)
    if grid is None:
        raise TypeError(f"{where}: missing `grid`")
    grid = _validate.grid(where, grid, dim=3)
    if vertices is not None:
        vertices, faces = _validate.mesh(where, vertices, faces, dim=3, batch=True, allow_empty=True)
        if not (_validate.is_concrete(vertices) and _validate.is_concrete(faces)):
            raise TypeError(f"{where}: needs concrete vertices and faces (call it outside jax.jit), or none")
    nx, ny, nz = grid.shape
    size = grid.size
    if vertices is None:
        cells = 4 * (nx * ny + ny * nz + nz * nx)
        runs = 2 * nx * ny
        return _clip_capacity(cells, size), _clip_capacity(runs, size)
    V = np.asarray(vertices, np.float64)
    F = np.asarray(faces, np.int64)
    lo = np.asarray(grid.lower, np.float64)
    hi = np.asarray(grid.upper, np.float64)
    h = np.asarray(grid.spacing, np.float64)
    batch = np.broadcast_shapes(V.shape[:-2], F.shape[:-2])
    nb = int(np.prod(batch, dtype=np.int64))  # not -1: a reshape cannot infer it next to an axis of 0
    Vb = np.broadcast_to(V, batch + V.shape[-2:]).reshape((nb,) + V.shape[-2:])
    Fb = np.broadcast_to(F, batch + F.shape[-2:]).reshape((nb,) + F.shape[-2:])
    best = (0, 0)
    for Vi, Fi in zip(Vb, Fb):
        P = (np.clip(Vi, lo, hi) - lo) / h  # cell units, clamped to the grid's box
        a, b, c = P[Fi[:, 0]], P[Fi[:, 1]], P[Fi[:, 2]]
        N = 0.5 * np.cross(b - a, c - a)
        per = (np.abs(b - a) + np.abs(c - b) + np.abs(a - c)).sum(axis=-1)
        per_xy = (np.abs(b - a) + np.abs(c - b) + np.abs(a - c))[:, :2].sum(axis=-1)
        cells = 1.15 * np.abs(N).sum() + 0.1 * per.sum()
        runs = 1.1 * np.abs(N[:, 2]).sum() + 0.1 * per_xy.sum()
        best = (max(best[0], cells), max(best[1], runs))
    return _clip_capacity(int(best[0]) + 256, size), _clip_capacity(int(best[1]) + 256, size)


def _clip_capacity(n, size):
    return int(max(1, min(n, size, _INT32_MAX)))


def _capacity(where, capacity):
    if isinstance(capacity, (tuple, list)):
        if len(capacity) != 2:
            raise ValueError(f"{where}: `capacity` must be an int or (cells, runs), got {capacity!r}")
        c, r = capacity
    else:
        c = r = capacity
    c = _validate.positive_int(where, "capacity", c)
    r = _validate.positive_int(where, "capacity", r)
    if c > _INT32_MAX or r > _INT32_MAX:
        raise ValueError(f"{where}: `capacity` must be below 2^31, got {capacity!r}")
    return c, r


def _check(where, vertices, faces, grid):
    grid = _validate.grid(where, grid)
    if grid.dim != 3:
        raise ValueError(f"{where}: `grid` must be 3D (the sparse form runs along z), got a {grid.dim}D grid")
    if getattr(grid, "frame", None) is not None:
        raise ValueError(f"{where}: slabs of a grid (Grid.slab) are not supported; pass the whole grid")
    vertices, faces = _validate.mesh(where, vertices, faces, dim=3, batch=True)
    vdtype = np.dtype(vertices.dtype)
    if vdtype == np.float64 and not jax.config.jax_enable_x64:
        vdtype = np.dtype(np.float32)
    vertices = jnp.asarray(vertices, dtype=vdtype)
    return vertices, _validate.int32_faces(faces)  # concrete indices: in range, checked above


def _raise_if_over(where, counts, cap):
    need = np.asarray(counts).reshape(-1, 2)
    over = np.nonzero((need[:, 0] > cap[0]) | (need[:, 1] > cap[1]))[0]
    if over.size:
        b = int(over[0])
        raise ValueError(
            f"{where}: batch item {b} has {int(need[b, 0])} boundary cells and {int(need[b, 1])} runs, more "
            f"than the capacity of {cap[0]} cells and {cap[1]} runs; pass a larger `capacity` (at least "
            f"({int(need[:, 0].max())}, {int(need[:, 1].max())}))"
        )


def _bucket(n, size):
    """n rounded up to 1, 1.25, 1.5 or 1.75 times a power of two (fewer compiled shapes)."""
    if n <= 64:
        return _clip_capacity(64, size)
    top = 1 << (int(n).bit_length() - 1)
    for m in (4, 5, 6, 7, 8):
        if top * m // 4 >= n:
            return _clip_capacity(top * m // 4, size)
    return _clip_capacity(n, size)


def _trim(out, need):
    """The rows in use (host-side slices: no compilation per shape)."""
    cells, values, runs, run_values, counts = (np.asarray(a) for a in out)
    c, r = max(need[0], 1), max(need[1], 1)
    return tuple(
        jnp.asarray(a)
        for a in (cells[..., :c, :], values[..., :c], runs[..., :r, :], run_values[..., :r], counts)
    )


def _build(out, grid):
    cells, values, runs, run_values, counts = out
    return SparseGrid(cells, values, runs, run_values, counts, grid)


# -- primitives -----------------------------------------------------------------------------

forward_p = Primitive("voxax_voxelize_sparse")
forward_p.multiple_results = True
tangent_p = Primitive("voxax_voxelize_sparse_tangent")
backward_p = Primitive("voxax_voxelize_sparse_backward")


def forward(vertices, faces, grid, capacity, strict=True):
    """The five arrays of a SparseGrid (same batch rank for vertices and faces)."""
    return forward_p.bind(vertices, faces, grid=grid, capacity=tuple(capacity), strict=bool(strict))


def tangent(vertices, faces, corner_tangents, cells, counts, grid):
    return tangent_p.bind(vertices, faces, corner_tangents, cells, counts, grid=grid)


def backward(vertices, faces, cells, cotangent, counts, grid):
    return backward_p.bind(vertices, faces, cells, cotangent, counts, grid=grid)


def _batch(*shapes_and_trailing):
    return tuple(np.broadcast_shapes(*[tuple(s[: len(s) - k]) for s, k in shapes_and_trailing]))


def _forward_abstract(vertices, faces, *, grid, capacity, strict):
    b = _batch((vertices.shape, 2), (faces.shape, 2))
    c, r = capacity
    dt = vertices.dtype
    S = jax.core.ShapedArray
    return [S(b + (c, 3), np.int32), S(b + (c,), dt), S(b + (r, 4), np.int32), S(b + (r,), dt), S(b + (2,), np.int32)]


def _tangent_abstract(vertices, faces, corner_tangents, cells, counts, *, grid):
    b = _batch((vertices.shape, 2), (faces.shape, 2), (corner_tangents.shape, 3), (cells.shape, 2))
    return jax.core.ShapedArray(b + (cells.shape[-2],), vertices.dtype)


def _backward_abstract(vertices, faces, cells, cotangent, counts, *, grid):
    b = _batch((vertices.shape, 2), (faces.shape, 2), (cells.shape, 2), (cotangent.shape, 1))
    return jax.core.ShapedArray(b + (faces.shape[-2], 3, 3), vertices.dtype)


forward_p.def_abstract_eval(_forward_abstract)
tangent_p.def_abstract_eval(_tangent_abstract)
backward_p.def_abstract_eval(_backward_abstract)


def _impl(prim):
    @functools.lru_cache(maxsize=128)
    def compiled(params, on_host):
        del on_host
        return jax.jit(functools.partial(prim.bind, **dict(params)))

    def impl(*args, **params):
        return compiled(tuple(sorted(params.items())), _ops.host_callback_forced())(*args)

    return impl


for _p in (forward_p, tangent_p, backward_p):
    _p.def_impl(_impl(_p))


def _zero(x):
    return ad.Zero(jax.typeof(x).to_tangent_aval())


def _forward_jvp(primals, tangents, *, grid, capacity, strict):
    vertices, faces = primals
    dv = tangents[0]
    out = forward(vertices, faces, grid, capacity, strict)
    zeros = [_zero(x) for x in out]
    if type(dv) is ad.Zero:
        return out, zeros
    cells, counts = out[0], out[4]
    dvalues = tangent(vertices, faces, _ops.gather_corners(dv, faces), cells, counts, grid)
    zeros[1] = dvalues
    return out, zeros


def _linear_jvp(op, index):
    """The JVP rule of a kernel linear in its argument `index` (the corner tangents or the
    cotangent) for fixed vertices; derivatives in the vertices are not defined."""

    def jvp(primals, tangents, *, grid):
        if type(tangents[0]) is not ad.Zero:
            raise NotImplementedError(_ops.SECOND_DERIVATIVE_MESSAGE)
        out = op(*primals, grid)
        if type(tangents[index]) is ad.Zero:
            return out, _zero(out)
        return out, op(*primals[:index], tangents[index], *primals[index + 1 :], grid)

    return jvp


def _defined(*xs):
    if any(ad.is_undefined_primal(x) for x in xs):
        raise NotImplementedError(_ops.SECOND_DERIVATIVE_MESSAGE)


def _tangent_transpose(ct, vertices, faces, tc, cells, counts, *, grid):
    _defined(vertices, faces, cells, counts)
    if type(ct) is ad.Zero:
        return None, None, ad.Zero(tc.aval), None, None
    out = backward(vertices, faces, cells, ct, counts, grid)
    return None, None, _ops._reduce_to(out, tc.aval.shape).astype(tc.aval.dtype), None, None


def _backward_transpose(ct, vertices, faces, cells, cot, counts, *, grid):
    _defined(vertices, faces, cells, counts)
    if type(ct) is ad.Zero:
        return None, None, None, ad.Zero(cot.aval), None
    out = tangent(vertices, faces, ct, cells, counts, grid)
    return None, None, None, _ops._reduce_to(out, cot.aval.shape).astype(cot.aval.dtype), None


ad.primitive_jvps[forward_p] = _forward_jvp
ad.primitive_jvps[tangent_p] = _linear_jvp(tangent, 2)
ad.primitive_jvps[backward_p] = _linear_jvp(backward, 3)
ad.primitive_transposes[tangent_p] = _tangent_transpose
ad.primitive_transposes[backward_p] = _backward_transpose


def _batch_rule(prim, args, dims, **params):
    moved = [a[None] if d is None else jnp.moveaxis(a, d, 0) for a, d in zip(args, dims)]
    out = prim.bind(*moved, **params)
    return out, ([0] * len(out) if prim.multiple_results else 0)


for _p in (forward_p, tangent_p, backward_p):
    batching.primitive_batchers[_p] = functools.partial(_batch_rule, _p)


# -- lowering -------------------------------------------------------------------------------

_TARGETS = {forward_p: FORWARD, tangent_p: TANGENT, backward_p: BACKWARD}


def _lowering(prim):
    target = _TARGETS[prim]

    def rule(ctx, *args, grid, **params):
        strict = params.get("strict")
        avals = ctx.avals_out
        results = tuple(jax.ShapeDtypeStruct(a.shape, a.dtype) for a in avals)
        if not prim.multiple_results:
            results = results[0]
        platforms = tuple(getattr(ctx.module_context, "platforms", ()) or ())
        if _ops.host_callback_forced() or any(p != "cpu" for p in platforms):
            host = functools.partial(kernels.sparse_host_call, target, results, grid, strict)

            def run(*a):
                return jax.pure_callback(host, results, *a)

        else:

            def run(*a):
                return kernels.sparse_call(target, results, grid, strict, *a)

        return mlir.lower_fun(run, multiple_results=prim.multiple_results)(ctx, *args)

    return rule


for _p in (forward_p, tangent_p, backward_p):
    mlir.register_lowering(_p, _lowering(_p))
