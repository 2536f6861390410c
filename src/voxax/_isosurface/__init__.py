"""Iso-surfaces of sampled fields: marching cubes / squares, differentiable in the samples."""

from __future__ import annotations

import ctypes
import dataclasses
import os
import warnings

import jax
import jax.numpy as jnp
import numpy as np

from .. import _kernels
from .._grid import Grid

__all__ = [
    "IsoMesh",
    "isosurface",
    "isosurface_fn",
    "isosurface_topology",
    "isosurface_vertices",
]

_INT32_MAX = np.iinfo(np.int32).max


@jax.tree_util.register_dataclass
@dataclasses.dataclass(frozen=True)
class IsoMesh:
    """An extracted iso-surface: a triangle mesh (3D) or segment polyline (2D) and how it was made.

    It unpacks like a mesh, `vertices, faces = iso`, and is a JAX pytree (it passes through
    `jax.jit` and `jax.vmap`). With a static `capacity` the arrays are padded: vertices
    beyond `n_vertices` are zero and faces beyond `n_faces` are `(0, 0, 0)` (degenerate, so
    `voxelize` and the energies ignore them).

    **Fields:**

    - `vertices`: `(V, d)` float, the vertex positions (float64 when x64 is enabled).
    - `faces`: `(F, d)` int32, triangles (3D) or segments (2D), oriented outward: normals
      point from the inside (`inside=`) to the outside.
    - `edges`: `(V, 2)` int32, for each vertex the flat (C-order) indices of the two grid
      cells whose centres bracket it (of the padded grid when `close` was used).
    - `n_vertices`, `n_faces`: int32 scalars, the counts of valid entries.
    - `min_gap`: float scalar, the smallest `|f_b - f_a|` over the crossed edges (`inf` for
      an empty mesh). A vertex moves by at most `h / min_gap` per unit change of a sample,
      so a small gap flags an ill-conditioned (large) gradient.
    - `samples`: the sampled field the mesh was extracted from (only set by
      [`isosurface_fn`][voxax.isosurface_fn]; pass it as `band=` to the next call).
    - `n_evaluated`: how many field evaluations `isosurface_fn` made (eager calls only).
    """

    vertices: jax.Array
    faces: jax.Array
    edges: jax.Array
    n_vertices: jax.Array
    n_faces: jax.Array
    min_gap: jax.Array
    samples: object = None
    n_evaluated: object = dataclasses.field(default=None, metadata={"static": True})

    def __iter__(self):
        yield self.vertices
        yield self.faces

    def to_mesh(self):
        """The valid part as a `voxax.Mesh` (eager, unbatched results only)."""
        from .._mesh import Mesh

        nv, nf = int(self.n_vertices), int(self.n_faces)
        return Mesh(np.asarray(self.vertices)[:nv], np.asarray(self.faces)[:nf])


# -- topology: the C++ kernel ----------------------------------------------------------------


def _threads() -> int:
    return max(1, min(os.cpu_count() or 1, 64))


def _mc_lib():
    lib = _kernels.library()
    if not getattr(lib, "_voxax_mc_typed", False):
        lib.voxax_mc_count.restype = ctypes.c_int
        lib.voxax_mc_count.argtypes = [
            ctypes.c_void_p,
            ctypes.c_int,
            ctypes.c_int,
            ctypes.POINTER(ctypes.c_int64),
            ctypes.c_double,
            ctypes.c_int,
            ctypes.POINTER(ctypes.c_void_p),
            ctypes.POINTER(ctypes.c_int64),
            ctypes.c_char_p,
            ctypes.c_int64,
        ]
        lib.voxax_mc_fill.restype = ctypes.c_int
        lib.voxax_mc_fill.argtypes = [ctypes.c_void_p, ctypes.c_void_p, ctypes.c_void_p]
        lib.voxax_mc_release.restype = None
        lib.voxax_mc_release.argtypes = [ctypes.c_void_p]
        lib.voxax_mc_slice_vertices.restype = ctypes.c_int64
        lib.voxax_mc_slice_vertices.argtypes = [ctypes.c_void_p, ctypes.c_int64]
        lib._voxax_mc_typed = True
    return lib


class _Count:
    """Pass 1 of the C++ kernel on one array: the counts, and a context for pass 2.

    Holds a reference to the (contiguous) samples, which pass 2 reads again.
    """

    def __init__(self, values: np.ndarray, level: float, threads: int | None = None):
        lib = _mc_lib()
        values = np.ascontiguousarray(values)
        if values.dtype not in (np.float32, np.float64):
            values = values.astype(np.float64)
        self.values = values
        self.dim = dim = values.ndim
        dtype = 0 if values.dtype == np.float32 else 1
        shape = (ctypes.c_int64 * 3)(*(list(values.shape) + [1] * (3 - dim)))
        counts = (ctypes.c_int64 * 2)()
        self.ctx = ctypes.c_void_p()
        err = ctypes.create_string_buffer(512)
        rc = lib.voxax_mc_count(
            values.ctypes.data,
            dtype,
            dim,
            shape,
            float(level),
            threads or _threads(),
            ctypes.byref(self.ctx),
            counts,
            err,
            512,
        )
        if rc != 0:
            msg = err.value.decode(errors="replace")
            raise (MemoryError if rc == 2 else ValueError)(msg)
        self.n_vertices, self.n_faces = int(counts[0]), int(counts[1])

    def slice_vertices(self, i: int) -> int:
        """Vertices owned by x slice `i` (crossed edges with their lower cell there)."""
        return int(_mc_lib().voxax_mc_slice_vertices(self.ctx, int(i)))

    def fill(self):
        """Pass 2: `edges (V, 2)` and `faces (F, d)` int32; releases the context."""
        lib = _mc_lib()
        try:
            edges = np.zeros((self.n_vertices, 2), np.int32)
            faces = np.zeros((self.n_faces, self.dim), np.int32)
            if lib.voxax_mc_fill(self.ctx, edges.ctypes.data, faces.ctypes.data) != 0:
                raise MemoryError("voxax.isosurface: out of memory")
        finally:
            self.release()
        return edges, faces

    def release(self):
        if self.ctx:
            _mc_lib().voxax_mc_release(self.ctx)
            self.ctx = ctypes.c_void_p()
        self.values = None

    def __del__(self):
        try:
            self.release()
        except Exception:  # noqa: BLE001 - interpreter shutdown
            pass


def host_topology(values: np.ndarray, level: float, threads: int | None = None):
    """Exact-size topology of one field: `edges (V, 2)`, `faces (F, d)` (int32).

    `values` is a NumPy array (float32 or float64) of the grid's shape; `threads` defaults to
    the number of CPUs (the result does not depend on it). No input checks: see `isosurface`.
    """
    return _Count(values, level, threads).fill()


def _ffi_topology(values, level: float, dim: int, vcap: int, fcap: int):
    batch = values.shape[: values.ndim - dim]
    out = (
        jax.ShapeDtypeStruct(batch + (vcap, 2), jnp.int32),
        jax.ShapeDtypeStruct(batch + (fcap, dim), jnp.int32),
        jax.ShapeDtypeStruct(batch + (2,), jnp.int32),
    )
    call = jax.ffi.ffi_call(_kernels.MARCHING_CUBES, out, vmap_method="expand_dims")
    return call(values, level=np.float64(level), dim=np.int64(dim))


def _concrete(x):
    """The concrete value behind `x` (unwrapping the tracers of eager `jax.grad`), or None."""
    seen = 0
    while isinstance(x, jax.core.Tracer) and hasattr(x, "primal") and seen < 64:
        x = x.primal
        seen += 1
    if isinstance(x, jax.core.Tracer):
        return None
    return np.asarray(x)


# -- checks ----------------------------------------------------------------------------------


def _check_values(values, grid: Grid, name: str):
    if not isinstance(grid, Grid):
        raise TypeError(
            f"{name}: `grid` must be a voxax.Grid, got {type(grid).__name__}"
        )
    if not hasattr(values, "dtype"):
        values = np.asarray(values)
    dtype = np.dtype(values.dtype)
    if dtype.kind in "iub":
        values = np.asarray(
            values, dtype=np.float64 if jax.config.jax_enable_x64 else np.float32
        )
    elif dtype not in (np.float32, np.float64):
        raise TypeError(
            f"{name}: `values` must be a real float array, got dtype {dtype}"
        )
    d = grid.dim
    if values.ndim < d or tuple(values.shape[values.ndim - d :]) != grid.shape:
        raise ValueError(
            f"{name}: `values` must have shape (..., {', '.join(map(str, grid.shape))}) to match the grid, "
            f"got {tuple(values.shape)}"
        )
    if isinstance(values, (jax.Array, np.ndarray)):
        if (
            isinstance(values, np.ndarray)
            and values.dtype == np.float64
            and not jax.config.jax_enable_x64
        ):
            values = values.astype(np.float32)
        return values  # NumPy input stays NumPy on the eager path (no device copies)
    return jnp.asarray(values)


def _check_level(level, name):
    try:
        level = float(level)
    except (TypeError, jax.errors.ConcretizationTypeError):
        raise TypeError(
            f"{name}: `level` must be a Python number (it is static under jit), got {level!r}"
        ) from None
    if not np.isfinite(level):
        raise ValueError(f"{name}: `level` must be finite, got {level}")
    return level


def _check_inside(inside, name):
    if inside not in ("below", "above"):
        raise ValueError(f'{name}: `inside` must be "below" or "above", got {inside!r}')
    return inside


def _capacities(capacity, name):
    if capacity is None:
        return None
    if isinstance(capacity, (int, np.integer)):
        vcap = fcap = int(capacity)
    else:
        try:
            vcap, fcap = (int(c) for c in capacity)
        except (TypeError, ValueError):
            raise TypeError(
                f"{name}: `capacity` must be an int or a (vertices, faces) pair, got {capacity!r}"
            ) from None
    if not (1 <= vcap <= _INT32_MAX and 1 <= fcap <= _INT32_MAX):
        raise ValueError(
            f"{name}: capacities must lie in [1, 2^31 - 1], got {(vcap, fcap)}"
        )
    return vcap, fcap


def _padded(grid: Grid) -> Grid:
    h = grid.spacing
    return Grid(
        tuple(lo - s for lo, s in zip(grid.lower, h)),
        tuple(up + s for up, s in zip(grid.upper, h)),
        tuple(n + 2 for n in grid.shape),
    )


def _explicit_pad(close, level: float, inside: str) -> float:
    """The pad value given as `close=<value>`: finite, and on the outside of the level."""
    pad = float(close)
    ok = pad > level if inside == "below" else pad < level
    if not np.isfinite(pad) or not ok:
        side = "above" if inside == "below" else "below"
        raise ValueError(
            f"isosurface: `close` must be True or a finite value {side} the level, got {close!r}"
        )
    return pad


def _pad(values, grid: Grid, level: float, inside: str, close):
    """Pads the field with one layer of an outside value; returns (values, grid)."""
    d = grid.dim
    outward = 1.0 if inside == "below" else -1.0
    if isinstance(values, np.ndarray):
        if close is True:
            span = np.max(
                np.abs(values.astype(np.float64) - level),
                axis=tuple(range(values.ndim - d, values.ndim)),
            )
            pad = level + outward * np.where(span > 0, span, 1.0)
        else:
            pad = _explicit_pad(close, level, inside)
        pad = np.broadcast_to(
            np.asarray(pad, values.dtype), values.shape[: values.ndim - d]
        )
        out = np.empty(
            values.shape[: values.ndim - d] + tuple(n + 2 for n in grid.shape),
            values.dtype,
        )
        out[...] = pad.reshape(pad.shape + (1,) * d)
        out[(Ellipsis,) + (slice(1, -1),) * d] = values
        return out, _padded(grid)
    if close is True:
        g = jax.lax.stop_gradient(values) - level
        span = jnp.max(
            jnp.abs(g), axis=tuple(range(values.ndim - d, values.ndim)), keepdims=True
        )
        pad = level + outward * jnp.where(span > 0, span, 1.0)
    else:
        pad = jnp.full((1,) * values.ndim, _explicit_pad(close, level, inside), values.dtype)
    pad = jnp.broadcast_to(
        pad.astype(values.dtype), values.shape[: values.ndim - d] + (1,) * d
    )
    widths = [(0, 0)] * (values.ndim - d) + [(1, 1)] * d
    # Pad with zeros, then fill the border with the pad value (traced values are allowed).
    out = jnp.pad(values, widths)
    mask = np.pad(np.zeros(grid.shape, bool), 1, constant_values=True)
    out = jnp.where(mask, pad, out)
    return out, _padded(grid)


# -- geometry: differentiable vertex positions -----------------------------------------------


def _float():
    return jnp.float64 if jax.config.jax_enable_x64 else jnp.float32


def _cell_points(idx, grid: Grid):
    """Centres of the cells with flat C-order indices `idx`, `(..., d)`."""
    coords = jnp.unravel_index(idx, grid.shape)
    ft = _float()
    lo = jnp.asarray(grid.lower, ft)
    h = jnp.asarray(grid.spacing, ft)
    return lo + (jnp.stack(coords, axis=-1).astype(ft) + 0.5) * h


def _interpolate(values, edges, n_vertices, grid: Grid, level: float):
    """Vertex positions and the conditioning figure; differentiable in `values`."""
    ft = _float()
    flat = values.reshape(values.shape[: values.ndim - grid.dim] + (-1,))
    fa = jnp.take_along_axis(flat, edges[..., 0], axis=-1).astype(ft)
    fb = jnp.take_along_axis(flat, edges[..., 1], axis=-1).astype(ft)
    return _from_samples(fa, fb, edges, n_vertices, grid, level)


def _from_samples(fa, fb, edges, n_vertices, grid: Grid, level):
    """`_interpolate` after the samples at the edge ends, `fa` and `fb`, are gathered."""
    ia, ib = edges[..., 0], edges[..., 1]
    valid = jnp.arange(edges.shape[-2]) < n_vertices[..., None]
    gap = fb - fa
    safe = jnp.where(valid, gap, 1.0)
    t = jnp.where(valid, (level - fa) / safe, 0.0)
    pa, pb = _cell_points(ia, grid), _cell_points(ib, grid)
    v = pa + t[..., None] * (pb - pa)
    v = jnp.where(valid[..., None], v, 0.0)
    min_gap = jnp.min(
        jnp.where(valid, jnp.abs(jax.lax.stop_gradient(gap)), jnp.inf),
        axis=-1,
        initial=jnp.inf,
    )
    return v, min_gap


_from_samples_jit = jax.jit(_from_samples, static_argnames=("grid",))


def _interpolate_eager(values: np.ndarray, edges: np.ndarray, grid: Grid, level: float):
    """`_interpolate` of concrete samples: gathered in NumPy, computed by one compiled
    function for vertex counts rounded up to a power of two (so a loop of eager calls with
    varying vertex counts compiles a handful of times, not once per call)."""
    ft = _float()
    n = edges.shape[-2]
    bucket = max(64, 1 << max(n - 1, 0).bit_length())
    flat = values.reshape(values.shape[: values.ndim - grid.dim] + (-1,))  # a view
    padded = np.zeros(edges.shape[:-2] + (bucket, 2), edges.dtype)
    padded[..., :n, :] = edges
    fa = jnp.asarray(np.take_along_axis(flat, padded[..., 0], axis=-1), ft)
    fb = jnp.asarray(np.take_along_axis(flat, padded[..., 1], axis=-1), ft)
    nv = jnp.full(edges.shape[:-2], n, jnp.int32)
    v, min_gap = _from_samples_jit(fa, fb, jnp.asarray(padded), nv, grid, jnp.asarray(level, ft))
    return v[..., :n, :], min_gap


# -- the eager path, streamed over slabs of x planes ------------------------------------------

# Cells per slab of the eager path (64 MiB of float32 samples): grids up to this size run as
# one slab; larger ones are swept slab by slab, so that nothing of the grid's size is
# allocated besides the result (no padded copy, no mask, no float64 copy).
_SLAB_CELLS = 1 << 24


def _close_value(values: np.ndarray, level: float, inside: str, close, planes: int):
    """The pad value of `close` (as in `_pad`), reading `values` slab by slab."""
    if close is True:
        span = 0.0
        for a in range(0, max(values.shape[0], 1), planes):
            part = values[a : a + planes]
            if part.size:
                # max |f - level| in float64 without a float64 copy: the rounded difference
                # is monotone in f, so its extremes come from the extreme samples
                lo, hi = float(np.min(part)), float(np.max(part))
                span = max(span, hi - level, level - lo)
        outward = 1.0 if inside == "below" else -1.0
        return np.asarray(level + outward * (span if span > 0 else 1.0), values.dtype)
    return np.asarray(_explicit_pad(close, level, inside), values.dtype)


def _edge_keys(edges: np.ndarray, strides: np.ndarray, offset: int) -> np.ndarray:
    """Sort keys `d * (global lower cell) + axis` of edges given in local cell indices."""
    d = len(strides)
    diff = (edges[:, 1] - edges[:, 0]).astype(np.int64)
    axis = np.zeros(len(edges), np.int64)
    for a, st in enumerate(strides):
        axis[diff == st] = a
    return (edges[:, 0].astype(np.int64) + offset) * d + axis


def _vertices_of(fa, fb, edges: np.ndarray, grid: Grid, level: float):
    """Vertex positions (NumPy) and min gap of gathered samples, by the compiled
    interpolation (vertex counts rounded up to a power of two, as in `_interpolate_eager`)."""
    ft = _float()
    n = len(edges)
    bucket = max(64, 1 << max(n - 1, 0).bit_length())
    pe = np.zeros((bucket, 2), np.int32)
    pe[:n] = edges
    pa = np.zeros(bucket, fa.dtype)
    pb = np.zeros(bucket, fb.dtype)
    pa[:n], pb[:n] = fa, fb
    v, gap = _from_samples_jit(
        jnp.asarray(pa, ft),
        jnp.asarray(pb, ft),
        jnp.asarray(pe),
        jnp.asarray(n, jnp.int32),
        grid,
        jnp.asarray(level, ft),
    )
    return np.asarray(v)[:n], gap


def _isosurface_streamed(
    values: np.ndarray, grid: Grid, level: float, inside: str, close, planes=None
) -> IsoMesh:
    """The eager `isosurface` of concrete samples `values` (of `grid.shape`), swept over slabs.

    Slab `s` covers the x planes `a..b` (`b = a + planes`, the last one clipped) of the
    (padded, with `close`) grid; neighbouring slabs share one plane. Each slab runs the C++
    kernel on its own (a view of `values`, or a padded copy of the slab with `close`). A slab
    owns the vertices whose lower cell lies in its planes `a..b-1` (the last slab: all), so
    the concatenated vertices are numbered exactly as in one sweep (by edge id); faces of a
    slab that use vertices of its last plane are renumbered to those of the next slab's first
    plane, found by their edge keys. Vertex positions are interpolated per slab by the same
    compiled elementwise function. The result is the same, bit for bit, for any `planes`.
    Memory: the result, plus one slab's samples, topology and (with `close`) padded copy.
    """
    d = grid.dim
    base = grid.shape
    shape = tuple(n + 2 for n in base) if close is not False else base
    m = int(np.prod(shape[1:], dtype=np.int64))
    if planes is None:
        planes = max(1, _SLAB_CELLS // max(m, 1))
    planes = int(planes)
    pad = None
    if close is not False:
        _check_finite_slabs(values, planes)
        pad = _close_value(values, level, inside, close, planes)
        g = _padded(grid)
    else:
        g = grid
    if int(np.prod(shape, dtype=np.int64)) > _INT32_MAX:
        raise ValueError("isosurface: the grid has more than 2^31 - 1 cells")
    nx = shape[0]
    starts = list(range(0, max(nx - 1, 1), planes))
    spans = [(a, min(a + planes, nx - 1)) for a in starts]
    view = pad is None and values.flags.c_contiguous and values.dtype in (np.float32, np.float64)

    def slab(a, b):
        if pad is None:
            return values[a : b + 1]
        out = np.empty((b - a + 1,) + shape[1:], values.dtype)
        out[...] = pad
        lo, hi = max(a, 1), min(b, base[0])
        if lo <= hi:
            out[(slice(lo - a, hi - a + 1),) + (slice(1, -1),) * (d - 1)] = values[lo - 1 : hi]
        return out

    # Pass 1: counts per slab (the contexts of views are kept for pass 2).
    kept, counts = [], []
    for s, (a, b) in enumerate(spans):
        part = slab(a, b)
        if pad is None and not np.all(np.isfinite(part)):
            raise ValueError("isosurface: `values` contain NaN or Inf")
        c = _Count(part, level)
        last = s == len(spans) - 1
        own = c.n_vertices - (0 if last else c.slice_vertices(b - a))
        counts.append((own, c.n_faces))
        if view:
            kept.append(c)
        else:
            c.release()
            kept.append(None)
    n_vertices = sum(o for o, _ in counts)
    n_faces = sum(f for _, f in counts)
    if n_vertices > _INT32_MAX or n_faces > _INT32_MAX:
        raise ValueError("isosurface: more than 2^31 - 1 vertices or faces")
    ft = np.dtype(_float())
    edges = np.zeros((n_vertices, 2), np.int32)
    faces = np.zeros((n_faces, d), np.int32)
    vertices = np.zeros((n_vertices, d), ft)
    strides = np.array([int(np.prod(shape[a + 1 :], dtype=np.int64)) for a in range(d)])
    order = None if inside == "below" else ([1, 0] if d == 2 else [0, 2, 1])
    gaps = []
    voff = foff = 0
    pending = None  # (faces, own, vertex offset, face offset, keys of its last-plane vertices)

    def put_faces(dest, fl, own, off, at, mapped):
        out = fl.astype(np.int64)
        tail = out >= own
        out[~tail] += off
        if mapped is not None:
            out[tail] = mapped[out[tail] - own]
        if order is not None:
            out = out[:, order]
        dest[at : at + len(fl)] = out

    for s, (a, b) in enumerate(spans):
        c = kept[s] if kept[s] is not None else _Count(slab(a, b), level)
        kept[s] = None
        part = c.values
        el, fl = c.fill()
        own, nf = counts[s]
        gl = el[:own].astype(np.int64) + a * m
        edges[voff : voff + own] = gl
        if pending is not None:
            pf, pown, poff, pfo, pkeys = pending
            nfirst = int(np.searchsorted(el[:, 0], m))
            keys = _edge_keys(el[:nfirst], strides, a * m)
            idx = np.searchsorted(keys, pkeys)
            if len(pkeys) and (
                idx.max() >= len(keys) or not np.array_equal(keys[idx], pkeys)
            ):
                raise RuntimeError("isosurface: slabs disagree on a shared plane")
            put_faces(faces, pf, pown, poff, pfo, voff + idx)
            pending = None
        if s == len(spans) - 1:
            put_faces(faces, fl, own, voff, foff, None)
        else:
            pending = (fl, own, voff, foff, _edge_keys(el[own:], strides, a * m))
        if own:
            flat = part.reshape(-1)
            v, gap = _vertices_of(flat[el[:own, 0]], flat[el[:own, 1]], gl, g, level)
            vertices[voff : voff + own] = v
            gaps.append(gap)
        del part, el, fl, c
        voff += own
        foff += nf
    min_gap = jnp.asarray(np.inf, ft)
    for gap in gaps:
        min_gap = jnp.minimum(min_gap, gap)
    if n_faces == 0:
        lo, hi = float(values.min()), float(values.max())
        if pad is not None:
            lo, hi = min(lo, float(pad)), max(hi, float(pad))
        warnings.warn(
            f"isosurface: the field does not cross level {level} (values in "
            f"[{lo:.6g}, {hi:.6g}]): the mesh is empty",
            RuntimeWarning,
            stacklevel=3,
        )
    out_v = jnp.asarray(vertices)
    del vertices
    out_f = jnp.asarray(faces)
    del faces
    out_e = jnp.asarray(edges)
    del edges
    return IsoMesh(
        out_v,
        out_f,
        out_e,
        jnp.asarray(n_vertices, jnp.int32),
        jnp.asarray(n_faces, jnp.int32),
        min_gap,
    )


def _check_finite_slabs(values: np.ndarray, planes: int):
    for a in range(0, max(values.shape[0], 1), planes):
        if not np.all(np.isfinite(values[a : a + planes])):
            raise ValueError("isosurface: `values` contain NaN or Inf")


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
    if close is not False:
        values, grid = _pad(values, grid, level, inside, close)
    v, _ = _interpolate(values, topology.edges, topology.n_vertices, grid, level)
    return v


def isosurface_topology(
    values,
    grid: Grid,
    level: float = 0.0,
    *,
    inside: str = "below",
    close=False,
    capacity=None,
):
    """The combinatorial part of [`isosurface`][voxax.isosurface] (no gradient flows through it).

    Same arguments as `isosurface`; returns an `IsoMesh` whose vertices are computed from the
    samples, with `jax.lax.stop_gradient` applied to them.
    """
    return isosurface(
        jax.lax.stop_gradient(_check_values(values, grid, "isosurface_topology")),
        grid,
        level,
        inside=inside,
        close=close,
        capacity=capacity,
    )


def isosurface(
    values,
    grid: Grid,
    level: float = 0.0,
    *,
    inside: str = "below",
    close=False,
    capacity=None,
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
      the counts, and a result that does not fit raises an error (through
      `equinox.error_if`). Use this path under `jax.jit` and `jax.vmap` (leading axes of
      `values` are batch axes too).

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
    values = _check_values(values, grid, name)
    d = grid.dim
    batch = values.shape[: values.ndim - d]
    if caps is None and not isinstance(values, jax.core.Tracer) and all(n == 1 for n in batch):
        iso = _isosurface_streamed(
            np.asarray(values).reshape(grid.shape), grid, level, inside, close
        )
        if not batch:
            return iso
        return jax.tree_util.tree_map(lambda x: x.reshape(batch + x.shape), iso)
    concrete = _concrete(values)
    if concrete is not None and not np.all(np.isfinite(concrete)):
        raise ValueError("isosurface: `values` contain NaN or Inf")
    if close is not False:
        values, grid = _pad(values, grid, level, inside, close)
        if concrete is not None:
            concrete = _concrete(values)
    if grid.size > _INT32_MAX:
        raise ValueError("isosurface: the grid has more than 2^31 - 1 cells")
    batch = values.shape[: values.ndim - d]
    if caps is None:
        if concrete is None:
            raise TypeError(
                "isosurface: the eager path needs concrete values; under jax.jit or jax.vmap pass a static "
                "`capacity=` (the largest number of vertices/faces expected)"
            )
        flat = concrete.reshape((-1,) + grid.shape)
        if batch and flat.shape[0] != 1:
            raise ValueError(
                "isosurface: batched values need a static `capacity=` (results of different sizes are padded)"
            )
        edges, faces = host_topology(
            flat[0] if flat.shape[0] else np.zeros(grid.shape), level
        )
        if len(faces) == 0:
            warnings.warn(
                f"isosurface: the field does not cross level {level} (values in "
                f"[{concrete.min():.6g}, {concrete.max():.6g}]): the mesh is empty",
                RuntimeWarning,
                stacklevel=2,
            )
        edges = edges.reshape(batch + edges.shape)
        faces = jnp.asarray(faces.reshape(batch + faces.shape))
        nv = jnp.full(batch, edges.shape[-2], jnp.int32)
        nf = jnp.full(batch, faces.shape[-2], jnp.int32)
    else:
        import equinox as eqx

        vcap, fcap = caps
        edges, faces, counts = _ffi_topology(
            jax.lax.stop_gradient(values), level, d, vcap, fcap
        )
        nv, nf = counts[..., 0], counts[..., 1]
        over = jnp.any(nv > vcap) | jnp.any(nf > fcap)
        msg = (
            f"isosurface: the mesh does not fit the capacity (vertices, faces) = ({vcap}, {fcap}); "
            "pass a larger `capacity=`"
        )
        edges = eqx.error_if(edges, over, msg)
        nv = jnp.minimum(nv, vcap)
        nf = jnp.minimum(nf, fcap)
    if inside == "above":
        faces = faces[..., ::-1] if d == 2 else faces[..., jnp.array([0, 2, 1])]
    if caps is None and not isinstance(values, jax.core.Tracer):
        vertices, min_gap = _interpolate_eager(np.asarray(values), edges, grid, level)
    else:
        vertices, min_gap = _interpolate(values, jnp.asarray(edges), nv, grid, level)
    return IsoMesh(vertices, faces, jnp.asarray(edges), nv, nf, min_gap)


# -- fields given as functions (MeshSDF) -----------------------------------------------------

_RULES = ("meshsdf", "theorem1", "level_set", "interpolation")


def _evaluate_np(fn, params, points: np.ndarray, chunk: int) -> np.ndarray:
    """`fn(params, points)` in chunks, as a float64 NumPy array (no gradient)."""
    out = np.empty(points.shape[0], np.float64)
    for s in range(0, points.shape[0], chunk):
        part = points[s : s + chunk]
        n = len(part)
        # pad to a power of two (at least 256) so that a few shapes cover every call and
        # a compiled `fn` (or the primitives of an eager one) is reused
        size = min(max(chunk, n), max(256, 1 << max(n - 1, 0).bit_length()))
        if size > n:
            part = np.concatenate([part, np.broadcast_to(part[:1], (size - n,) + part.shape[1:])])
        out[s : s + n] = np.asarray(fn(params, jnp.asarray(part)), np.float64).reshape(-1)[:n]
    return out


def _active_corners(values: np.ndarray, level: float) -> np.ndarray:
    """Cells that are corners of at least one cube (square) whose corners differ in sign."""
    pos = values >= level
    d = values.ndim
    lo = np.ones(tuple(n - 1 for n in values.shape), bool)
    hi = np.zeros_like(lo)
    for corner in np.ndindex(*(2,) * d):
        sl = tuple(slice(c, c + n - 1) for c, n in zip(corner, values.shape))
        lo &= pos[sl]
        hi |= pos[sl]
    active = hi & ~lo
    out = np.zeros(values.shape, bool)
    for corner in np.ndindex(*(2,) * d):
        sl = tuple(slice(c, c + n - 1) for c, n in zip(corner, values.shape))
        out[sl] |= active
    return out


def _with_pad(values: np.ndarray, pad) -> np.ndarray:
    return values if pad is None else np.pad(values, 1, constant_values=pad)


def _strip_pad(mask: np.ndarray, pad) -> np.ndarray:
    return mask if pad is None else mask[(slice(1, -1),) * mask.ndim]


def _dilate(mask: np.ndarray, width: int) -> np.ndarray:
    from scipy.ndimage import maximum_filter

    return maximum_filter(mask, size=2 * width + 1, mode="constant", cval=False)


def _centers_at(grid: Grid, mask: np.ndarray) -> np.ndarray:
    """The cell centres `(N, d)` of the cells where `mask` holds (C order), as
    `grid.centers()[mask]` without building every centre."""
    idx = np.nonzero(mask)
    lower = np.asarray(grid.lower, np.float64)
    h = np.asarray(grid.spacing, np.float64)
    return lower + (np.stack(idx, -1).astype(np.float64) + 0.5) * h


def _lipschitz_samples(
    fn, params, grid: Grid, level: float, lipschitz: float, pad, chunk: int
):
    """Coarse-to-fine samples: exact where marching cubes reads them, sign-exact elsewhere."""
    n = np.array(grid.shape)
    h = np.array(grid.spacing)
    lower = np.array(grid.lower)
    d = grid.dim
    values = np.zeros(grid.shape, np.float64)
    exact = np.zeros(grid.shape, bool)
    evaluated = 0
    size = 1
    while size < min(16, int(n.max())):
        size *= 2
    axes = [np.arange(0, m, size) for m in n]
    origins = np.stack(np.meshgrid(*axes, indexing="ij"), -1).reshape(-1, d)
    while len(origins):
        count = np.minimum(size, n - origins)
        centre = lower + (origins + (count - 1) / 2.0 + 0.5) * h
        radius = 0.5 * np.sqrt((((count - 1) * h) ** 2).sum(-1))
        g = _evaluate_np(fn, params, centre, chunk) - level
        evaluated += len(origins)
        if size == 1:
            idx = tuple(origins.T)
            values[idx] = g + level
            exact[idx] = True
            break
        decided = np.abs(g) > lipschitz * radius
        if decided.any():
            # every cell of a decided block gets a value of the block's sign whose distance to
            # the level is a lower bound of |f - level| over the block
            coarse = np.full(tuple(-(-n // size)), np.nan)
            coarse[tuple((origins[decided] // size).T)] = level + np.sign(g[decided]) * (
                np.abs(g[decided]) - lipschitz * radius[decided]
            )
            for axis in range(d):
                coarse = np.repeat(coarse, size, axis=axis)
            coarse = coarse[tuple(slice(0, m) for m in n)]
            hit = ~np.isnan(coarse)
            values[hit] = coarse[hit]
        size //= 2
        rest = origins[~decided]
        children = [rest + np.array(off) * size for off in np.ndindex(*(2,) * d)]
        origins = np.concatenate(children)
        origins = origins[np.all(origins < n, axis=1)]
    need = _strip_pad(_active_corners(_with_pad(values, pad), level), pad) & ~exact
    if need.any():
        pts = _centers_at(grid, need)
        values[need] = _evaluate_np(fn, params, pts, chunk)
        evaluated += len(pts)
    return values, evaluated


def _band_samples(
    fn, params, grid: Grid, level: float, previous: np.ndarray, pad, chunk: int
):
    """Re-evaluates the field near the previous surface, growing the evaluated set until closed.

    Starts from the previous active corners (cells of cubes whose corners differ in sign) and
    repeats: evaluate the pending cells; then every cell that is an active corner of the
    current samples, or a neighbour (26-connected) of an evaluated cell whose sign changed,
    and was not evaluated yet, is pending. It stops when nothing is pending: every active
    corner then holds an exact value, and every region of changed signs that reaches the
    evaluated set is explored to its border, so the mesh equals dense evaluation unless a
    region of changed signs lies entirely outside it (a new component far from the previous
    surface).
    """
    previous = np.asarray(previous, np.float64)
    if previous.shape != grid.shape:
        raise ValueError(
            f"isosurface_fn: `band` must have the grid's shape {grid.shape}, got {previous.shape}"
        )
    before = previous >= level
    todo = _strip_pad(_active_corners(_with_pad(previous, pad), level), pad)
    if not todo.any():
        todo = np.ones(grid.shape, bool)
    values = previous.copy()
    done = np.zeros(grid.shape, bool)
    evaluated = 0
    while todo.any():
        values[todo] = _evaluate_np(fn, params, _centers_at(grid, todo), chunk)
        evaluated += int(todo.sum())
        done |= todo
        flipped = done & ((values >= level) != before)
        todo = _strip_pad(_active_corners(_with_pad(values, pad), level), pad)
        if flipped.any():
            todo |= _dilate(flipped, 1)
        todo &= ~done
    return values, evaluated


def _field_gradient(fn, params, points):
    return jax.grad(lambda x: jnp.sum(fn(params, x)))(points)


def isosurface_fn(
    fn,
    params,
    grid: Grid,
    level: float = 0.0,
    *,
    rule: str = "meshsdf",
    inside: str = "below",
    close=False,
    capacity=None,
    band=None,
    lipschitz=None,
    chunk: int = 1 << 16,
) -> IsoMesh:
    """Iso-surface of a field given as a function, differentiable in its parameters (MeshSDF).

    The field `fn(params, x)` is sampled at the cell centres of `grid`, marching cubes gives
    the mesh, and the vertices `v0` (interpolated along the grid edges) are made
    differentiable in `params` by one of these rules, each a first-order model of how a surface
    point moves when the field changes by `δf` (`g = ∇f(v0)`, `n = g/|g|`):

    | `rule=` | `∂v` per unit `δf` | right when |
    |---|---|---|
    | `"meshsdf"` | `-n` | `f` is a signed distance (`|∇f| = 1`); the MeshSDF authors' implementation of Eq. 4 |
    | `"theorem1"` | `-∇f` | as written in Theorem 1 / Eq. 4; equal to `meshsdf` for true SDFs, scaled by `|∇f|` otherwise |
    | `"level_set"` | `-∇f/|∇f|²` | any field: the exact first-order motion of the level set along its normal |
    | `"interpolation"` | through the samples | the exact derivative of the discrete marching-cubes output |

    For a field that is not a distance (a scaled SDF `3(|x| - r)`, occupancies, networks that
    drift from `|∇f| = 1`), `meshsdf` is off by the factor `|∇f|` and `theorem1` by `|∇f|²`;
    `level_set` stays exact to first order. The first three are built with the
    straight-through construction `v = sg(v0) - sg(d)·(f(v0; θ) - sg(f(v0; θ)))` (`sg` =
    `stop_gradient`, `d` the rule's direction): forward values are exactly `v0`, and it
    composes with `jit`, `grad` and `vmap` (over `params`, with `capacity`).

    Fast paths for expensive fields (eager calls only; the mesh is identical to dense
    evaluation when their assumptions hold):

    - `band=previous.samples`: re-evaluate the cells of the previous surface (the corners of
      its cubes), then grow the evaluated set until it holds every corner of the new
      surface's cubes and the full extent of every region whose sign changed; other cells
      keep their previous values. Exact unless a region of changed sign lies entirely away
      from the evaluated cells (a component appearing far from the previous surface): refresh
      with a dense call (or `lipschitz`) from time to time.
    - `lipschitz=L`: coarse-to-fine evaluation that skips blocks whose centre value exceeds
      `L` times the block's radius (their sign is certain), then evaluates exactly every cell
      marching cubes reads. Exact whenever `L` bounds `|∇f|` (`L = 1` for SDFs).

    **Arguments:**

    - `fn`: `fn(params, x) -> f`, with `x` `(N, d)` float points and `f` `(N,)` values.
    - `params`: any pytree of parameters (latent codes, network weights).
    - `grid`, `level`, `inside`, `capacity`: as in [`isosurface`][voxax.isosurface].
    - `close`: `False`, `True` (pads with `level ± max(spacing)`, a distance of one cell) or
      a pad value.
    - `rule`: one of `"meshsdf"`, `"theorem1"`, `"level_set"`, `"interpolation"`.
    - `band`: `None` or the `samples` of a previous result on the same grid.
    - `lipschitz`: `None` or a Lipschitz bound of `fn` in `x`.
    - `chunk`: points per evaluation of `fn` on the eager paths.

    **Returns:**

    An [`IsoMesh`][voxax.IsoMesh] whose `vertices` carry the rule's gradient, with `samples`
    (the grid of values used) and `n_evaluated` (eager calls).

    **Example:**

    ```python
    >>> import jax, jax.numpy as jnp, voxax
    >>> sphere = lambda r, x: jnp.linalg.norm(x, axis=-1) - r
    >>> grid = voxax.Grid.cube(32)
    >>> loss = lambda r: jnp.mean(jnp.sum(voxax.isosurface_fn(sphere, r, grid).vertices ** 2, -1))
    >>> bool(abs(jax.grad(loss)(0.6) - 1.2) < 0.01)
    True
    ```
    """
    name = "isosurface_fn"
    if not callable(fn):
        raise TypeError(
            f"{name}: `fn` must be callable as fn(params, x), got {type(fn).__name__}"
        )
    if rule not in _RULES:
        raise ValueError(f"{name}: `rule` must be one of {_RULES}, got {rule!r}")
    level = _check_level(level, name)
    inside = _check_inside(inside, name)
    if not isinstance(grid, Grid):
        raise TypeError(
            f"{name}: `grid` must be a voxax.Grid, got {type(grid).__name__}"
        )
    if lipschitz is not None and not (np.isfinite(lipschitz) and lipschitz > 0):
        raise ValueError(
            f"{name}: `lipschitz` must be a positive finite number, got {lipschitz!r}"
        )
    outward = 1.0 if inside == "below" else -1.0
    pad = None
    if close is True:
        pad = level + outward * max(grid.spacing)
    elif close is not False:
        pad = float(close)
    p0 = jax.lax.stop_gradient(params)
    evaluated = None
    fast = band is not None or lipschitz is not None
    if fast:
        if capacity is not None or _concrete_tree(p0) is None:
            raise TypeError(
                f"{name}: `band` and `lipschitz` work on eager calls only (no jit, no capacity)"
            )
        p0 = _concrete_tree(p0)
        if band is not None:
            samples, evaluated = _band_samples(fn, p0, grid, level, band, pad, chunk)
        else:
            samples, evaluated = _lipschitz_samples(
                fn, p0, grid, level, float(lipschitz), pad, chunk
            )
        samples = jnp.asarray(samples, _float())
    else:
        pts = grid.centers().reshape(-1, grid.dim)
        concrete = _concrete_tree(p0)
        if capacity is None and concrete is not None:
            samples = jnp.asarray(
                _evaluate_np(fn, concrete, pts, chunk).reshape(grid.shape), _float()
            )
            evaluated = grid.size
        else:
            samples = (
                jnp.asarray(fn(p0, jnp.asarray(pts, _float())))
                .astype(_float())
                .reshape(grid.shape)
            )
    iso = isosurface(
        samples,
        grid,
        level,
        inside=inside,
        close=False if pad is None else pad,
        capacity=capacity,
    )
    v0 = jax.lax.stop_gradient(iso.vertices)
    valid = (jnp.arange(v0.shape[-2]) < iso.n_vertices[..., None])[..., None]
    if rule == "interpolation":
        g = _padded(grid) if pad is not None else grid
        ia, ib = iso.edges[..., 0], iso.edges[..., 1]
        pa, pb = _cell_points(ia, g), _cell_points(ib, g)

        def at(idx, p):
            f = jnp.asarray(fn(params, p)).astype(_float())
            if pad is None:
                return f
            coords = jnp.stack(jnp.unravel_index(idx, g.shape), -1)
            border = jnp.any((coords == 0) | (coords == jnp.asarray(g.shape) - 1), -1)
            return jnp.where(border, pad, f)

        fa, fb = at(ia, pa), at(ib, pb)
        safe = jnp.where(valid[..., 0], fb - fa, 1.0)
        t = jnp.where(valid[..., 0], (level - fa) / safe, 0.0)
        v = jnp.where(valid, pa + t[..., None] * (pb - pa), 0.0)
    else:
        grad = jax.lax.stop_gradient(_field_gradient(fn, p0, v0))
        norm2 = jnp.sum(grad * grad, -1, keepdims=True)
        safe2 = jnp.where(norm2 > 0, norm2, 1.0)
        if rule == "meshsdf":
            direction = grad / jnp.sqrt(safe2)
        elif rule == "theorem1":
            direction = grad
        else:
            direction = grad / safe2
        direction = jnp.where(valid & (norm2 > 0), direction, 0.0)
        f = jnp.asarray(fn(params, v0)).astype(_float())
        delta = f - jax.lax.stop_gradient(f)
        v = v0 - direction * delta[..., None]
    return dataclasses.replace(iso, vertices=v, samples=samples, n_evaluated=evaluated)


def _concrete_tree(tree):
    leaves, treedef = jax.tree_util.tree_flatten(tree)
    out = []
    for leaf in leaves:
        c = _concrete(leaf)
        if c is None:
            return None
        out.append(jnp.asarray(c))
    return jax.tree_util.tree_unflatten(treedef, out)
