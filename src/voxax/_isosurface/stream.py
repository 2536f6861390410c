"""The eager `isosurface` of concrete samples, streamed over slabs of x planes."""

from __future__ import annotations

import warnings

import jax.numpy as jnp
import numpy as np

from .._grid import Grid
from .checks import _INT32_MAX, _explicit_pad, _float, _padded
from .interpolate import _vertices_of
from .mesh import IsoMesh
from .scale import scale_exponent
from .topology import _Count

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


def _isosurface_streamed(
    values: np.ndarray, grid: Grid, level: float, inside: str, close, planes=None, threads=None
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
        _value_range(values, planes)  # NaN and Inf refused before padding
        pad = _close_value(values, level, inside, close, planes)
        g = _padded(grid)
    else:
        g = grid
    if int(np.prod(shape, dtype=np.int64)) > _INT32_MAX:
        raise ValueError("voxax.isosurface: the grid has more than 2^31 - 1 cells")
    nx = shape[0]
    starts = list(range(0, max(nx - 1, 1), planes))
    spans = [(a, min(a + planes, nx - 1)) for a in starts]
    view = pad is None and values.flags.c_contiguous and values.dtype in (np.float32, np.float64)

    slab = _Slab(values, pad, shape)
    kept, counts, (lo, hi) = _count_slabs(slab, spans, level, view, threads)
    # samples outside XLA's range: the interpolation runs on 2^k times them (exact)
    k = scale_exponent(max(-lo, hi, abs(level)), values.dtype)
    n_vertices = sum(o for o, _ in counts)
    n_faces = sum(f for _, f in counts)
    if n_vertices > _INT32_MAX or n_faces > _INT32_MAX:
        raise ValueError("voxax.isosurface: more than 2^31 - 1 vertices or faces")
    ft = np.dtype(_float())
    order = None if inside == "below" else ([1, 0] if d == 2 else [0, 2, 1])
    if len(spans) == 1:  # one sweep: the kernel's arrays are the result
        c = kept[0] if kept[0] is not None else _Count(slab(*spans[0]), level, threads)
        part = c.values
        edges, faces = c.fill()
        if order is not None:
            faces = faces[:, order]
        vertices, gaps = np.zeros((0, d), ft), []
        if n_vertices:
            flat = part.reshape(-1)
            vertices, gap = _vertices_of(flat[edges[:, 0]], flat[edges[:, 1]], edges, g, level, k)
            gaps.append(gap)
        del part, c
        return _result(vertices, faces, edges, gaps, k, (lo, hi, pad, level))
    edges = np.zeros((n_vertices, 2), np.int32)
    faces = np.zeros((n_faces, d), np.int32)
    vertices = np.zeros((n_vertices, d), ft)
    strides = np.array([int(np.prod(shape[a + 1 :], dtype=np.int64)) for a in range(d)])
    gaps = []
    voff = foff = 0
    pending = None  # (faces, own, vertex offset, face offset, keys of its last-plane vertices)

    for s, (a, b) in enumerate(spans):
        c = kept[s] if kept[s] is not None else _Count(slab(a, b), level, threads)
        kept[s] = None
        part = c.values
        el, fl = c.fill()
        own, nf = counts[s]
        gl = edges[voff : voff + own]
        gl[...] = el[:own]
        gl += a * m  # int32: below the cell count
        if pending is not None:
            pf, pown, poff, pfo, pkeys = pending
            nfirst = int(np.searchsorted(el[:, 0], m))
            keys = _edge_keys(el[:nfirst], strides, a * m)
            idx = np.searchsorted(keys, pkeys)
            if len(pkeys) and (
                idx.max() >= len(keys) or not np.array_equal(keys[idx], pkeys)
            ):
                raise RuntimeError("voxax.isosurface: slabs disagree on a shared plane")
            _put_faces(faces, pf, pown, poff, pfo, voff + idx, order)
            pending = None
        if s == len(spans) - 1:
            _put_faces(faces, fl, own, voff, foff, None, order)
        else:
            pending = (fl, own, voff, foff, _edge_keys(el[own:], strides, a * m))
        if own:
            flat = part.reshape(-1)
            v, gap = _vertices_of(flat[el[:own, 0]], flat[el[:own, 1]], gl, g, level, k)
            vertices[voff : voff + own] = v
            gaps.append(gap)
        del part, el, fl, c
        voff += own
        foff += nf
    return _result(vertices, faces, edges, gaps, k, (lo, hi, pad, level))


def _result(vertices, faces, edges, gaps, k: int, empty) -> IsoMesh:
    """The `IsoMesh` of the assembled NumPy arrays; `gaps` the slabs' min gaps (scaled by
    `2^k`), `empty` = (lo, hi, pad, level) for the warning of an empty mesh."""
    ft = vertices.dtype
    min_gap = jnp.asarray(np.inf, ft)
    for gap in gaps:
        min_gap = jnp.minimum(min_gap, gap)
    if k:
        min_gap = jnp.asarray(np.ldexp(float(min_gap), -k), ft)
    n_vertices, n_faces = len(vertices), len(faces)
    if n_faces == 0:
        lo, hi, pad, level = empty
        _warn_empty(lo, hi, pad, level)
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


def _value_range(values: np.ndarray, planes: int):
    """The smallest and largest sample (float), read slab by slab; refuses NaN and Inf."""
    lo, hi = np.inf, -np.inf
    for a in range(0, max(values.shape[0], 1), planes):
        part = values[a : a + planes]
        if part.size:
            plo, phi = float(np.min(part)), float(np.max(part))  # NaN propagates
            if not (np.isfinite(plo) and np.isfinite(phi)):
                raise ValueError("voxax.isosurface: `values` must be finite (they contain NaN or Inf)")
            lo, hi = min(lo, plo), max(hi, phi)
    return (lo, hi) if values.size else (0.0, 0.0)


class _Slab:
    """The samples of x planes `a..b` of the (padded, with a pad value) grid: a view of
    `values`, or a padded copy of those planes."""

    def __init__(self, values: np.ndarray, pad, shape):
        self.values, self.pad, self.shape = values, pad, shape

    def __call__(self, a: int, b: int) -> np.ndarray:
        values, pad, shape = self.values, self.pad, self.shape
        if pad is None:
            return values[a : b + 1]
        out = np.empty((b - a + 1,) + shape[1:], values.dtype)
        out[...] = pad
        lo, hi = max(a, 1), min(b, values.shape[0])
        if lo <= hi:
            inner = (slice(1, -1),) * (len(shape) - 1)
            out[(slice(lo - a, hi - a + 1),) + inner] = values[lo - 1 : hi]
        return out


def _count_slabs(slab: _Slab, spans, level: float, view: bool, threads):
    """Pass 1: per slab, the vertices it owns and its faces (the contexts of views are kept
    for pass 2, None for padded copies), and the samples' range (NaN and Inf refused)."""
    kept, counts = [], []
    lo, hi = np.inf, -np.inf
    for s, (a, b) in enumerate(spans):
        part = slab(a, b)
        c = _Count(part, level, threads)
        last = s == len(spans) - 1
        own = c.n_vertices - (0 if last else c.slice_vertices(b - a))
        counts.append((own, c.n_faces))
        lo, hi = min(lo, c.lo), max(hi, c.hi)
        if view:
            kept.append(c)
        else:
            c.release()
            kept.append(None)
    return kept, counts, (lo, hi)


def _put_faces(dest, fl, own, off, at, mapped, order):
    """Writes a slab's faces at row `at`: its own vertices shifted by `off`, those of its last
    plane through `mapped` (the next slab's numbering), columns in `order`."""
    out = dest[at : at + len(fl)]
    if mapped is not None:
        tail = fl >= own
        src = np.where(tail, 0, fl + off)
        src[tail] = mapped[fl[tail] - own]
    else:
        src = fl
        src += off  # int32: below the vertex count
    for col, from_col in enumerate(order if order is not None else range(fl.shape[1])):
        out[:, col] = src[:, from_col]


def _warn_empty(lo: float, hi: float, pad, level: float):
    if pad is not None:
        lo, hi = min(lo, float(pad)), max(hi, float(pad))
    warnings.warn(
        f"voxax.isosurface: the field does not cross level {level} (values in "
        f"[{lo:.6g}, {hi:.6g}]): the mesh is empty",
        RuntimeWarning,
        stacklevel=5,
    )
