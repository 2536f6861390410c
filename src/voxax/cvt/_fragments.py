"""Surface samples ("fragments") from axis-aligned rasterisations, and dexel booleans.

A fragment is a point where a line parallel to one grid axis, through the centres of the
grid's cells in the two other axes, crosses the surface. Fragments carry the outward unit
normal there, the axis of their line, the index of the line, and a weight (the surface area
the fragment stands for), so that weighted sums over fragments approximate surface
integrals: the three families of lines sample a surface patch with normal `n` with density
`sum_a |n_a| / A_a` (fragments per unit area; `A_a` the area of a line's cell across axis
`a`), and the weight is its inverse.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from typing import Any, NamedTuple

import numpy as np

from .. import _validate
from .._constants import MAX_ABS_COORDINATE
from .._grid import Grid
from .._mesh import Mesh

__all__ = ["CSG", "Fragments", "as_mesh", "checked", "checked_key", "checked_threads", "fragments", "real_array", "sample"]

_OPS = ("union", "intersection", "difference")


class Fragments(NamedTuple):
    """Surface samples on the grid lines of three axes.

    **Fields:**

    - `points`: `(P, 3)` float64, the crossings of the lines with the surface.
    - `normals`: `(P, 3)` float64, unit outward normals there.
    - `weights`: `(P,)` float64, the surface area each fragment stands for (their sum
      approximates the area).
    - `axis`: `(P,)` int8, the axis of the fragment's line (0, 1, 2).
    - `line`: `(P,)` int64, the line index `iu * n_v + iv` (the cell indices in the two
      other axes, in increasing axis order).
    - `sign`: `(P,)` int8, `+1` where the surface exits the solid along `+axis` (normal
      along `+axis`), `-1` where it enters.
    - `grid`: the [`Grid`][voxax.Grid] whose cell-centre lines were cast.

    Fragments are sorted by axis, line and position along the line.
    """

    points: np.ndarray
    normals: np.ndarray
    weights: np.ndarray
    axis: np.ndarray
    line: np.ndarray
    sign: np.ndarray
    grid: Grid

    @property
    def size(self) -> int:
        """The number of fragments `P`."""
        return int(self.points.shape[0])

    @property
    def spacing(self) -> float:
        """The largest grid spacing `d` (fragments form a `sqrt(3) d` covering)."""
        return float(max(self.grid.spacing))


_WHERE = "voxax.cvt.fragments"


def real_array(where: str, name: str, value, dtype=np.float64) -> np.ndarray:
    """`value` as a C-contiguous NumPy array of `dtype`, refusing booleans, complex numbers
    and objects (which would be cast silently)."""
    a = np.asarray(value)
    if a.dtype.kind not in "fiu":
        raise TypeError(f"{where}: `{name}` must be a real (float or integer) array, got {a.dtype}")
    return np.ascontiguousarray(a, dtype)


def as_mesh(where: str, source) -> Mesh:
    """A mesh source (a `voxax.Mesh`, a `trimesh.Trimesh`, a `(vertices, faces)` pair) as a
    3D triangle `Mesh`, through `_validate`: real finite vertices (no booleans or complex
    numbers), integer faces in range."""
    v, f = _validate.mesh_object_arrays(where, source) if _validate.is_mesh_object(source) else source
    v, f = np.asarray(v), np.asarray(f)
    if v.dtype.kind == "b":
        raise TypeError(f"{where}: `vertices` must be float32 or float64, got bool")
    v, f = _validate.mesh(where, v, f, dim=3, integer_vertices=True, allow_empty=True,
                          context="a triangle mesh in 3D")
    return source if isinstance(source, Mesh) else Mesh(v, f)


def checked_threads(where: str, threads):
    """`threads` checked by the one threads rule (`voxax._kernels.threads`), the message
    naming `where`; returns it unchanged (None stays None)."""
    from .._kernels import _ctypes

    try:
        _ctypes.threads(threads)
    except (TypeError, ValueError) as err:
        raise type(err)(f"{where}: {err}") from None
    return threads


def checked_key(where: str, key):
    """`key` checked: an int (>= 0) or a JAX PRNG key; returns it unchanged."""
    if not isinstance(key, (int, np.integer)) and not hasattr(key, "dtype"):
        raise TypeError(f"{where}: `key` must be an int or a JAX PRNG key, got {type(key).__name__}")
    _validate.numpy_rng(where, key)
    return key


def checked(where: str, frag, *, allow_empty: bool = False) -> Fragments:
    """`frag` checked as [`Fragments`][voxax.cvt.Fragments] (a hand-made one too): every
    field an array of one row per point (points and normals `(P, 3)` finite, weights finite
    and `>= 0`), the grid a 3D [`Grid`][voxax.Grid]; returns it with C-contiguous arrays
    of the documented dtypes."""
    if not isinstance(frag, Fragments):
        raise TypeError(f"{where}: `frag` must be voxax.cvt.Fragments (from voxax.cvt.fragments), got {type(frag).__name__}")
    if not isinstance(frag.grid, Grid) or frag.grid.dim != 3:
        raise TypeError(f"{where}: `frag.grid` must be a 3D voxax.Grid, got {frag.grid!r:.80}")
    points = real_array(where, "frag.points", frag.points)
    if points.ndim != 2 or points.shape[1] != 3:
        raise ValueError(f"{where}: `frag.points` must have shape (P, 3), got {points.shape}")
    p = len(points)
    out = {"points": points}
    for name, dtype, shape in (("normals", np.float64, (p, 3)), ("weights", np.float64, (p,)),
                               ("axis", np.int8, (p,)), ("line", np.int64, (p,)), ("sign", np.int8, (p,))):
        value = np.asarray(getattr(frag, name))
        if value.shape != shape:
            raise ValueError(f"{where}: `frag.{name}` must have shape {shape} (one row per point), got {value.shape}")
        if dtype != np.float64 and value.dtype.kind not in "iu":
            raise TypeError(f"{where}: `frag.{name}` must be an integer array, got {value.dtype}")
        out[name] = real_array(where, f"frag.{name}", value, dtype)
    for name in ("points", "normals", "weights"):
        if not np.all(np.isfinite(out[name])):
            raise ValueError(f"{where}: `frag.{name}` must be finite (it contains NaN or Inf)")
    if p and float(np.max(np.abs(points))) > MAX_ABS_COORDINATE:
        raise ValueError(f"{where}: `frag.points` coordinates must have magnitude <= 1e75")
    if np.any(out["weights"] < 0):
        raise ValueError(f"{where}: `frag.weights` must be >= 0")
    if p == 0 and not allow_empty:
        raise ValueError(f"{where}: `frag` must hold fragments: there are none (empty surface)")
    return Fragments(grid=frag.grid, **out)


@dataclasses.dataclass(frozen=True)
class CSG:
    """A boolean combination of two solids, evaluated on the rays of the grid (dexels).

    `op` is `"union"`, `"intersection"` or `"difference"` (`a` minus `b`); `a` and `b` are
    anything [`fragments`][voxax.cvt.fragments] takes that bounds a solid (closed meshes,
    fields, grids, other `CSG` nodes). Along every grid line the inside intervals of `a` and
    `b` are merged exactly, so the result is sampled on the same lines as its operands.

    Fields given as `jax.tree_util.Partial(fields.sphere, radius=0.5, center=(0.6, 0.0, 0.0))`
    (or equinox modules) compile once per function: their float parameters are passed to the
    compiled sampler as arrays, so many scenes of the same primitives compile nothing new
    (a closure such as `lambda p: fields.sphere(p, 0.5, c)` compiles once per closure).
    Operands may reach beyond the grid: which lines start inside each operand is tracked
    (from the field values, or from the first crossing of a mesh's line).

    >>> import voxax
    >>> from jax.tree_util import Partial
    >>> from voxax import fields
    >>> scene = voxax.cvt.CSG("difference", fields.sphere, Partial(fields.sphere, radius=0.5, center=(0.6, 0.0, 0.0)))
    """

    op: str
    a: Any
    b: Any

    def __post_init__(self):
        if self.op not in _OPS:
            raise ValueError(f"voxax.cvt.CSG: `op` must be one of {_OPS}, got {self.op!r}")


def _weights(normals: np.ndarray, grid: Grid) -> np.ndarray:
    h = np.asarray(grid.spacing, np.float64)
    cell = np.array([h[1] * h[2], h[0] * h[2], h[0] * h[1]])  # line cell area across each axis
    density = np.abs(normals) @ (1.0 / cell)
    return 1.0 / np.maximum(density, 1e-300)


def _line_coords(grid: Grid, axis: int):
    u, v = [a for a in range(3) if a != axis]
    cu = grid.lower[u] + (np.arange(grid.shape[u]) + 0.5) * grid.spacing[u]
    cv = grid.lower[v] + (np.arange(grid.shape[v]) + 0.5) * grid.spacing[v]
    return u, v, cu, cv


def _assemble(parts, grid: Grid) -> Fragments:
    """Concatenates per-axis pieces `(axis, line, depth, normals[, exits])` into sorted
    fragments. `exits` (bool) says where the solid is left along `+axis` (from the samples'
    order, which stays right where the normal is perpendicular to the line); without it the
    normal's sign along the axis decides."""
    pts, nrm, ax, ln, sg = [], [], [], [], []
    for part in parts:
        axis, line, depth, normals = part[:4]
        exits = part[4] if len(part) > 4 else normals[:, axis] > 0
        u, v, cu, cv = _line_coords(grid, axis)
        nv = len(cv)
        p = np.empty((len(line), 3))
        p[:, axis] = depth
        p[:, u] = cu[line // nv]
        p[:, v] = cv[line % nv]
        order = np.lexsort((depth, line))
        pts.append(p[order])
        nrm.append(normals[order])
        ax.append(np.full(len(line), axis, np.int8))
        ln.append(line[order].astype(np.int64))
        sg.append(np.where(exits[order], 1, -1).astype(np.int8))
    points = np.concatenate(pts) if pts else np.zeros((0, 3))
    normals = np.concatenate(nrm) if nrm else np.zeros((0, 3))
    axis = np.concatenate(ax) if ax else np.zeros(0, np.int8)
    line = np.concatenate(ln) if ln else np.zeros(0, np.int64)
    sign = np.concatenate(sg) if sg else np.zeros(0, np.int8)
    return Fragments(points, normals, _weights(normals, grid), axis, line, sign, grid)


# ---------------------------------------------------------------------------------------
# Meshes


def _mesh_fragments(mesh: Mesh, grid: Grid, threads) -> Fragments:
    from ..raster import line_crossings

    v = np.asarray(mesh.vertices, np.float64)
    f = np.asarray(mesh.faces, np.int64)
    if len(f) == 0:
        raise ValueError("voxax.cvt.fragments: `source` must have faces: the mesh has none")
    fn = np.cross(v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]])
    norm = np.linalg.norm(fn, axis=1, keepdims=True)
    fn = fn / np.where(norm > 0, norm, 1.0)
    parts = []
    for axis in range(3):
        dx = line_crossings(mesh, grid=grid, axis=axis, lines="centers", threads=threads)
        parts.append((axis, dx.line_index(), dx.depth, fn[dx.face]))
    return _assemble(parts, grid)


# ---------------------------------------------------------------------------------------
# Implicit fields and sampled grids


def _crossing_pairs(values: np.ndarray, axis: int):
    """Indices of consecutive samples along `axis` whose sides differ (`inside = value < 0`)."""
    inside = values < 0
    a = np.moveaxis(inside, axis, -1)
    change = a[..., :-1] != a[..., 1:]
    idx = np.nonzero(change)
    # idx over (u, v, i) after moveaxis (the two other axes keep their order)
    iu, iv, i = idx
    return iu, iv, i


def _is_pytree_field(fn) -> bool:
    """Whether `fn` is a field whose parameters are pytree leaves (a `jax.tree_util.Partial`
    or an equinox `Module`): such fields compile once per function and structure, with
    their array parameters passed as arguments."""
    import jax

    if isinstance(fn, jax.tree_util.Partial):
        return True
    try:
        import equinox as eqx
    except ImportError:  # pragma: no cover - equinox is a dependency
        return False
    return isinstance(fn, eqx.Module)


def _dynamic(fn):
    """A pytree field with its Python float parameters turned into float64 arrays (so they
    are traced, not baked into the compilation); integers and other leaves stay static."""
    import jax
    import jax.numpy as jnp

    def leaf(a):
        if isinstance(a, float) or (isinstance(a, np.ndarray) and a.dtype.kind == "f"):
            return jnp.asarray(a, jnp.float64)
        return a

    return jax.tree_util.tree_map(leaf, fn)


def _values_impl(fn, p):
    import jax.numpy as jnp

    out = jnp.asarray(fn(p))
    if not (jnp.issubdtype(out.dtype, jnp.floating) or jnp.issubdtype(out.dtype, jnp.integer)):
        raise TypeError(f"voxax.cvt.fragments: the field `source` must return real values, got {out.dtype}")
    if out.size != p.shape[0]:
        raise ValueError(f"voxax.cvt.fragments: the field `source` must return one value per point, got shape "
                         f"{out.shape} for {p.shape[0]} points")
    return out.astype(jnp.float64).reshape(p.shape[0])


class _Centers:
    """The cell centres of a grid by flat index (the values `Grid.centers()` holds, without
    building that `(*shape, 3)` array)."""

    def __init__(self, grid: Grid):
        self.axes = [
            grid.lower[a] + (np.arange(grid.shape[a], dtype=np.float64) + 0.5) * grid.spacing[a] for a in range(3)
        ]
        self.shape = tuple(grid.shape)

    def __getitem__(self, flat: np.ndarray) -> np.ndarray:
        ny, nz = self.shape[1], self.shape[2]
        out = np.empty((len(flat), 3))
        out[:, 0] = self.axes[0][flat // (ny * nz)]
        out[:, 1] = self.axes[1][(flat // nz) % ny]
        out[:, 2] = self.axes[2][flat % nz]
        return out


_CHUNK = 1 << 16  # field samples per compiled call


def _grid_values_impl(fn, axes, dims, start):
    """The field at the cell centres `start .. start + _CHUNK` (flat order; past the end the
    last centre again), the centres gathered from the axes' `(3, L)` centres."""
    import jax.numpy as jnp

    lin = start + jnp.arange(_CHUNK, dtype=jnp.int64)
    ny, nz = dims[1], dims[2]
    i = jnp.minimum(lin // (ny * nz), dims[0] - 1)
    p = jnp.stack([axes[0][i], axes[1][(lin // nz) % ny], axes[2][lin % nz]], axis=1)
    return _values_impl(fn, p)


def _field_values(fn: Callable, centers: _Centers) -> np.ndarray:
    """The field at every cell centre, `(*shape,)`, evaluated in chunks of one shape (the
    centres made in the compiled call; all chunks are queued before any is read)."""
    import jax
    import jax.numpy as jnp

    size = max(1024, 1 << (max(centers.shape) - 1).bit_length())  # padded axes: few shapes
    axes = np.zeros((3, size))
    for a in range(3):
        axes[a, : centers.shape[a]] = centers.axes[a]
    axes, dims = jnp.asarray(axes), jnp.asarray(np.array(centers.shape, np.int64))
    if _is_pytree_field(fn):
        dyn = _dynamic(fn)
        jitted = _pytree_jit("grid_values", _grid_values_impl)
        run = lambda start: jitted(dyn, axes, dims, start)  # noqa: E731
    else:
        compiled = _compiled("grid_values", fn, lambda: jax.jit(lambda *a: _grid_values_impl(fn, *a)))
        run = lambda start: compiled(axes, dims, start)  # noqa: E731
    total = int(np.prod(centers.shape))
    parts = [run(jnp.asarray(s, jnp.int64)) for s in range(0, total, _CHUNK)]
    return np.concatenate([np.asarray(p) for p in parts])[:total].reshape(centers.shape)


_COMPILED: dict = {}
_PYTREE_JIT: dict = {}


def _pytree_jit(kind: str, impl: Callable):
    """One `equinox.filter_jit` wrapper per kind: arrays in the field are traced, the rest
    (the function, integers) is static and keys the compilation cache."""
    hit = _PYTREE_JIT.get(kind)
    if hit is None:
        import equinox as eqx

        hit = _PYTREE_JIT[kind] = eqx.filter_jit(impl)
    return hit


def _compiled(kind: str, fn: Callable, build: Callable):
    """A jitted function per (kind, field), kept for the last few fields (shapes are padded
    to fixed chunks, so repeated calls on the same field reuse the compilations)."""
    key = (kind, id(fn))
    hit = _COMPILED.get(key)
    if hit is not None and hit[0] is fn:
        return hit[1]
    if len(_COMPILED) >= 8:
        _COMPILED.pop(next(iter(_COMPILED)))
    out = build()
    _COMPILED[key] = (fn, out)
    return out


def _refine_roots(fn: Callable, x0, x1, f0, f1, iterations: int):
    """Bracketed Illinois regula falsi on the segments `x0 -> x1` (vectorised, float64): at
    most `iterations` steps, fewer once every segment's root estimate has stopped moving
    (steps of a few ulps)."""
    import jax
    import jax.numpy as jnp

    args = (jnp.asarray(x0), jnp.asarray(x1), jnp.asarray(f0), jnp.asarray(f1))
    if _is_pytree_field(fn):
        return _pytree_jit("refine", _refine_impl)(_dynamic(fn), iterations, *args)
    run = _compiled(f"refine{iterations}", fn, lambda: jax.jit(lambda *a: _refine_impl(fn, iterations, *a)))
    return run(*args)


_STEP = 2.0**-50  # a segment is converged once its root estimate moves less than this (a few ulps of t)


def _refine_impl(fn, iterations: int, x0, x1, f0, f1):
    import jax
    import jax.numpy as jnp

    def evaluate(p):
        return _values_impl(fn, p)

    a = jnp.zeros_like(f0)
    b = jnp.ones_like(f0)
    fa, fb = f0, f1

    def body(st):
        k, a, b, fa, fb, side, done, t_prev = st
        t = (a * fb - b * fa) / (fb - fa)
        t = jnp.where(jnp.isfinite(t) & (t > a) & (t < b), t, 0.5 * (a + b))
        ft = evaluate(x0 + t[:, None] * (x1 - x0))
        left = (ft < 0) == (fa < 0)  # root lies in [t, b]
        # Illinois: halve the stale end's value when the same side is kept twice
        fb_new = jnp.where(left & (side == 1), 0.5 * fb, fb)
        fa_new = jnp.where(~left & (side == -1), 0.5 * fa, fa)
        a2 = jnp.where(left, t, a)
        fa2 = jnp.where(left, ft, fa_new)
        b2 = jnp.where(left, b, t)
        fb2 = jnp.where(left, fb_new, ft)
        side2 = jnp.where(left, 1, -1).astype(jnp.int32)
        # converged segments keep their bracket
        keep = lambda old, new: jnp.where(done, old, new)  # noqa: E731
        a2, b2, fa2, fb2, side2 = keep(a, a2), keep(b, b2), keep(fa, fa2), keep(fb, fb2), keep(side, side2)
        # a segment is done once its root estimate stops moving (or hits a zero)
        return k + 1, a2, b2, fa2, fb2, side2, done | (jnp.abs(t - t_prev) <= _STEP) | (ft == 0), t

    def more(st):
        return (st[0] < iterations) & ~jnp.all(st[6])

    zeros = jnp.zeros(f0.shape, bool)
    init = (0, a, b, fa, fb, jnp.zeros(f0.shape, jnp.int32), zeros, jnp.full(f0.shape, -1.0))
    _, a, b, fa, fb, _, _, _ = jax.lax.while_loop(more, body, init)
    t = (a * fb - b * fa) / (fb - fa)
    t = jnp.where(jnp.isfinite(t), jnp.clip(t, a, b), 0.5 * (a + b))
    p = x0 + t[:, None] * (x1 - x0)
    g = jax.vmap(jax.grad(lambda q: evaluate(q[None])[0]))(p)
    return p, g


def _unit(g: np.ndarray, what: str) -> np.ndarray:
    n = np.linalg.norm(g, axis=1, keepdims=True)
    bad = ~(n[:, 0] > 0) | ~np.isfinite(n[:, 0])
    if np.any(bad):
        raise ValueError(f"voxax.cvt.fragments: the {what} gradient vanishes or is not finite at {int(bad.sum())} crossings")
    return g / n


def _starts_from_values(negative_inside: np.ndarray) -> tuple:
    """Per axis, whether each line (index `iu * n_v + iv`) starts inside the solid."""
    return tuple(np.moveaxis(negative_inside, axis, -1)[..., 0].ravel() for axis in range(3))


def _starts_from_signs(frag: Fragments) -> tuple:
    """Per axis, the lines whose first crossing is an exit (so they start inside)."""
    out = []
    for axis in range(3):
        u, v = [a for a in range(3) if a != axis]
        start = np.zeros(frag.grid.shape[u] * frag.grid.shape[v], bool)
        sel = np.nonzero(frag.axis == axis)[0]
        if len(sel):
            line = frag.line[sel]
            first = np.concatenate([[True], line[1:] != line[:-1]])
            start[line[first]] = frag.sign[sel][first] > 0
        out.append(start)
    return tuple(out)


def _field_fragments(fn: Callable, grid: Grid, iterations: int, starts: list | None = None) -> Fragments:
    import jax

    if not jax.config.jax_enable_x64:
        raise ValueError("voxax.cvt.fragments: fields are sampled in float64; enable jax_enable_x64")
    centers = _Centers(grid)
    values = _field_values(fn, centers)
    if not np.all(np.isfinite(values)):
        raise ValueError("voxax.cvt.fragments: the field `source` must be finite: it is not at some cell centres")
    if starts is not None:
        starts.append(_starts_from_values(values < 0))
    shape = grid.shape
    flat = values.ravel()
    segs = []
    for axis in range(3):
        u, v, _, _ = _line_coords(grid, axis)
        iu, iv, i = _crossing_pairs(values, axis)
        idx0 = [None] * 3
        idx0[axis], idx0[u], idx0[v] = i, iu, iv
        idx1 = list(idx0)
        idx1[axis] = i + 1
        segs.append(
            (
                axis,
                iu.astype(np.int64) * shape[v] + iv,
                np.ravel_multi_index(tuple(idx0), shape),
                np.ravel_multi_index(tuple(idx1), shape),
            )
        )
    total = sum(len(s[1]) for s in segs)
    if total == 0:
        return _assemble([], grid)
    f0 = np.concatenate([s[2] for s in segs])
    f1 = np.concatenate([s[3] for s in segs])
    chunk = 1 << 14  # one shape: one compilation per field
    p = np.empty((total, 3))
    g = np.empty((total, 3))
    for s in range(0, total, chunk):
        sel = np.arange(s, s + chunk)
        sel[sel >= total] = s
        pc, gc = _refine_roots(fn, centers[f0[sel]], centers[f1[sel]], flat[f0[sel]], flat[f1[sel]], iterations)
        n = min(chunk, total - s)
        p[s : s + n] = np.asarray(pc)[:n]
        g[s : s + n] = np.asarray(gc)[:n]
    parts, at = [], 0
    exits = flat[f0] < 0  # inside at the lower sample: the line leaves the solid
    for axis, line, _, _ in segs:
        n = len(line)
        if n:
            parts.append((axis, line, p[at : at + n, axis], _unit(g[at : at + n], "field"), exits[at : at + n]))
        at += n
    return _assemble(parts, grid)


def _grid_fragments(values, level: float, inside: str, grid: Grid, starts: list | None = None) -> Fragments:
    where = "voxax.cvt.fragments"
    w = np.asarray(values)
    if w.dtype.kind not in "fiub":  # booleans too: an occupancy grid (level 0.5, inside="above")
        raise TypeError(f"{where}: the grid values of `source` must be real numbers, got {w.dtype}")
    w = w.astype(np.float64)
    if w.shape != tuple(grid.shape):
        raise ValueError(f"{where}: the grid values of `source` must have the grid's shape {grid.shape}, got {w.shape}")
    if not np.all(np.isfinite(w)):
        raise ValueError(f"{where}: the grid values of `source` must be finite (they contain NaN or Inf)")
    if not np.isfinite(level):
        raise ValueError(f"{where}: the level of `source` must be finite, got {level}")
    s = (w - level) if inside == "below" else (level - w)  # negative inside
    if starts is not None:
        starts.append(_starts_from_values(s < 0))
    grads = np.stack(np.gradient(s, *grid.spacing, edge_order=1), axis=-1)
    centers = grid.centers()
    parts = []
    for axis in range(3):
        u, v, _, _ = _line_coords(grid, axis)
        iu, iv, i = _crossing_pairs(s, axis)
        if len(i) == 0:
            continue
        idx0 = [None] * 3
        idx0[axis], idx0[u], idx0[v] = i, iu, iv
        idx1 = list(idx0)
        idx1[axis] = i + 1
        s0, s1 = s[tuple(idx0)], s[tuple(idx1)]
        t = s0 / (s0 - s1)
        x0, x1 = centers[tuple(idx0)], centers[tuple(idx1)]
        depth = x0[:, axis] + t * (x1[:, axis] - x0[:, axis])
        g = (1 - t)[:, None] * grads[tuple(idx0)] + t[:, None] * grads[tuple(idx1)]
        gn = np.linalg.norm(g, axis=1)
        # a vanishing interpolated gradient: fall back to the crossing direction
        fallback = np.zeros_like(g)
        fallback[:, axis] = np.sign(s1 - s0)
        g = np.where((gn > 0)[:, None], g, fallback)
        parts.append((axis, iu.astype(np.int64) * grid.shape[v] + iv, depth, _unit(g, "grid"), s0 < 0))
    return _assemble(parts, grid)


# ---------------------------------------------------------------------------------------
# Dexel booleans


_COMBINE = {
    "union": lambda a, b: a | b,
    "intersection": lambda a, b: a & b,
    "difference": lambda a, b: a & ~b,
}


def _csg(op: str, a: Fragments, b: Fragments, start_a: tuple, start_b: tuple) -> tuple:
    """The boolean `op` of two solids' fragments, merged per line; `start_a`, `start_b`
    say per axis which lines start inside each solid (a solid larger than the grid).
    **Returns:** `(Fragments, starts of the result)`."""
    combine = _COMBINE[op]
    n_a = a.size
    pts = np.concatenate([a.points, b.points])
    nrm = np.concatenate([a.normals, b.normals])
    axis = np.concatenate([a.axis, b.axis]).astype(np.int64)
    line = np.concatenate([a.line, b.line])
    sign = np.concatenate([a.sign, b.sign]).astype(np.int64)
    src = np.concatenate([np.zeros(n_a, np.int64), np.ones(b.size, np.int64)])
    depth = pts[np.arange(len(pts)), axis]
    order = np.lexsort((src, depth, line, axis))
    pts, nrm, axis, line, sign, src, depth = (x[order] for x in (pts, nrm, axis, line, sign, src, depth))
    n = len(order)
    group = np.concatenate([[True], (axis[1:] != axis[:-1]) | (line[1:] != line[:-1])]) if n else np.zeros(0, bool)
    gid = np.cumsum(group) - 1
    g_axis, g_line = axis[group], line[group]
    inside, init = [], []
    for s, st in ((0, start_a), (1, start_b)):
        first = np.zeros(len(g_axis), bool)
        for ax in range(3):
            sel = g_axis == ax
            first[sel] = st[ax][g_line[sel]]
        step = np.where(src == s, -sign, 0)
        cum = np.cumsum(step)
        before = np.concatenate([[0], cum[:-1]])[group]  # cum before each line's first event
        inside.append((cum - before[gid] + first[gid]) > 0)
        init.append(first)
    res = combine(*inside)
    prev = np.concatenate([[False], res[:-1]])
    prev[group] = combine(*init)  # the result's state where the line starts
    keep = res != prev
    new_sign = np.where(res, -1, 1)  # the result enters where it becomes inside
    flip = (new_sign != sign)[:, None]
    nrm = np.where(flip, -nrm, nrm)
    k = np.nonzero(keep)[0]
    out_sign = new_sign[k].astype(np.int8)
    out = Fragments(pts[k], nrm[k], _weights(nrm[k], a.grid), axis[k].astype(np.int8), line[k], out_sign, a.grid)
    return out, tuple(combine(x, y) for x, y in zip(start_a, start_b))


def union_all(parts: list) -> Fragments:
    """The union of several closed solids' fragments on the same grid (dexel merge)."""
    parts = [p for p in parts if p.size]
    if not parts:
        raise ValueError("voxax.cvt: the union is empty")
    grid = parts[0].grid
    pts = np.concatenate([p.points for p in parts])
    nrm = np.concatenate([p.normals for p in parts])
    axis = np.concatenate([p.axis for p in parts]).astype(np.int64)
    line = np.concatenate([p.line for p in parts])
    sign = np.concatenate([p.sign for p in parts]).astype(np.int64)
    depth = pts[np.arange(len(pts)), axis]
    order = np.lexsort((depth, line, axis))
    pts, nrm, axis, line, sign = (x[order] for x in (pts, nrm, axis, line, sign))
    group = np.concatenate([[True], (axis[1:] != axis[:-1]) | (line[1:] != line[:-1])])
    gid = np.cumsum(group) - 1
    cum = np.cumsum(-sign)
    start = np.concatenate([[0], cum[:-1]])[group]
    inside = (cum - start[gid]) > 0  # inside at least one solid after the event
    prev = np.concatenate([[False], inside[:-1]])
    prev[group] = False
    k = np.nonzero(inside != prev)[0]
    return Fragments(
        pts[k], nrm[k], _weights(nrm[k], grid), axis[k].astype(np.int8), line[k], sign[k].astype(np.int8), grid
    )


def ball_fragments(centers, radii, grid: Grid) -> Fragments:
    """Exact crossings of the cell-centre lines of `grid` with balls (each ball separately)."""
    centers = np.asarray(centers, np.float64).reshape(-1, 3)
    radii = np.asarray(radii, np.float64).reshape(-1)
    parts = []
    for axis in range(3):
        u, v, cu, cv = _line_coords(grid, axis)
        lines, depth, nrm = [], [], []
        for c, r in zip(centers, radii):
            iu = np.nonzero(np.abs(cu - c[u]) < r)[0]
            iv = np.nonzero(np.abs(cv - c[v]) < r)[0]
            if len(iu) == 0 or len(iv) == 0:
                continue
            U, V = np.meshgrid(iu, iv, indexing="ij")
            du, dv = cu[U.ravel()] - c[u], cv[V.ravel()] - c[v]
            h2 = r * r - du * du - dv * dv
            ok = h2 > 0
            h = np.sqrt(h2[ok])
            ln = U.ravel()[ok].astype(np.int64) * len(cv) + V.ravel()[ok]
            for side in (-1.0, 1.0):
                p = np.empty((len(h), 3))
                p[:, axis] = c[axis] + side * h
                p[:, u] = cu[U.ravel()[ok]]
                p[:, v] = cv[V.ravel()[ok]]
                lines.append(ln)
                depth.append(p[:, axis])
                nrm.append((p - c) / r)
        if lines:
            parts.append((axis, np.concatenate(lines), np.concatenate(depth), np.concatenate(nrm)))
    return _assemble(parts, grid)


def _check_grid(grid) -> Grid:
    if not isinstance(grid, Grid):
        raise TypeError(f"voxax.cvt.fragments: `grid` must be a voxax.Grid, got {type(grid).__name__}")
    if grid.dim != 3:
        raise ValueError(f"voxax.cvt.fragments: `grid` must be 3D, got dimension {grid.dim}")
    return grid


@_validate.host_only("voxax.cvt.fragments")
def fragments(
    source, grid: Grid | None = None, *, inside: str = "below", iterations: int = 30, threads=None
) -> Fragments:
    """Surface samples where the cell-centre lines of `grid` along x, y and z cross a surface.

    **Arguments:**

    - `source`: what to sample:
        - a [`Mesh`][voxax.Mesh] (or `(vertices, faces)` pair): exact crossings of the
          lines with the triangles (watertight ray-triangle tests); normals are the face
          normals (outward for an outward-oriented mesh);
        - a callable `f(points (N, 3)) -> (N,)` (a `voxax.fields` function or any JAX
          function), negative inside: sign changes between consecutive cell centres,
          refined by bracketed regula falsi (`iterations` steps); normals `grad f / |grad f|`.
          A `jax.tree_util.Partial` or an equinox module compiles once per function (its
          float parameters are traced); any other callable once per object;
        - a tuple `(values, level)` of samples `(*grid.shape)` at the cell centres: linear
          interpolation of the level crossings (inside below the level, or above with
          `inside="above"`), normals from the interpolated central-difference gradient;
        - a [`CSG`][voxax.cvt.CSG] node: its operands sampled on the same lines and merged
          per line (dexel booleans).
    - `grid`: a 3D [`Grid`][voxax.Grid] spanning the surface (for a mesh, default
      `Grid.around(mesh, 128)`).
    - `inside`: for sampled grids, `"below"` or `"above"` the level.
    - `iterations`: root refinement steps for fields.
    - `threads`: threads for the mesh ray casting (default all cores).

    **Returns:** [`Fragments`][voxax.cvt.Fragments].

    >>> import jax; jax.config.update("jax_enable_x64", True)
    >>> import voxax
    >>> from voxax import fields
    >>> frag = voxax.cvt.fragments(fields.sphere, voxax.Grid.cube(32, half_width=1.2))
    >>> bool(abs(frag.weights.sum() / (4 * 3.14159265) - 1) < 0.01)  # the sphere's area within 1%
    True
    """
    if inside not in ("below", "above"):
        raise ValueError(f'voxax.cvt.fragments: `inside` must be "below" or "above", got {inside!r}')
    iterations = _validate.positive_int("voxax.cvt.fragments", "iterations", iterations)
    checked_threads("voxax.cvt.fragments", threads)
    return sample(source, grid, inside=inside, iterations=iterations, threads=threads)[0]


def sample(source, grid=None, *, inside: str = "below", iterations: int = 30, threads=None,
           where: str = _WHERE) -> tuple:
    """[`fragments`][voxax.cvt.fragments] with, per axis, which lines start inside the solid
    (`(n_u * n_v,)` bool): a line that starts inside without crossing the surface shows
    that the solid reaches beyond the grid. Errors name `where` (the public function
    that samples). **Returns:** `(Fragments, starts)`."""
    try:
        return _sample_checked(source, grid, inside, iterations, threads)
    except (TypeError, ValueError, MemoryError) as err:
        text = str(err)
        if where == _WHERE or not text.startswith(_WHERE + ":"):
            raise
        raise type(err)(where + text[len(_WHERE):]) from None


def _sample_checked(source, grid, inside: str, iterations: int, threads) -> tuple:
    frag, starts = _sample(source, grid, inside, iterations, threads)
    if frag.size == 0 and not isinstance(source, Fragments):
        # checked here, for the whole: the operands of a CSG node may have no surface on
        # the grid (a solid that covers it, or one between its lines)
        if isinstance(source, CSG):
            what = "the CSG expression has no surface on this grid (empty surface)"
        elif isinstance(source, tuple) and len(source) == 2 and np.ndim(source[1]) == 0:
            what = "the grid has no crossing of the level (empty surface)"
        elif callable(source) and not isinstance(source, Mesh):
            what = "the field has no zero crossing on the grid (empty surface)"
        else:
            what = "no grid line crosses the mesh (empty surface on this grid)"
        raise ValueError(f"voxax.cvt.fragments: {what}")
    return frag, starts


def _sample(source, grid, inside: str, iterations: int, threads) -> tuple:
    """`(Fragments, starts)`: the samples (possibly none), and per axis which lines start
    inside."""
    if isinstance(source, CSG):
        grid = _check_grid(grid)
        fa, sa = _sample(source.a, grid, inside, iterations, threads)
        fb, sb = _sample(source.b, grid, inside, iterations, threads)
        return _csg(source.op, fa, fb, sa, sb)
    if isinstance(source, Fragments):
        source = checked("voxax.cvt.fragments", source, allow_empty=True)
        return source, _starts_from_signs(source)
    starts: list = []
    if isinstance(source, tuple) and len(source) == 2 and np.ndim(source[1]) == 0:
        grid = _check_grid(grid)
        level = real_array("voxax.cvt.fragments", "source", source[1])
        return _grid_fragments(source[0], float(level.reshape(-1)[0]), inside, grid, starts), starts[0]
    if callable(source) and not isinstance(source, Mesh):
        grid = _check_grid(grid)
        return _field_fragments(source, grid, iterations, starts), starts[0]
    if _validate.is_mesh_object(source) or _validate.is_mesh_pair(source):
        mesh = as_mesh("voxax.cvt.fragments", source)
        if grid is None:
            grid = Grid.around(mesh.vertices, 128)
        frag = _mesh_fragments(mesh, _check_grid(grid), threads)
        return frag, _starts_from_signs(frag)
    raise TypeError(
        "voxax.cvt.fragments: `source` must be a Mesh, a callable field, a (values, level) tuple or a CSG, "
        f"got {type(source).__name__}"
    )
