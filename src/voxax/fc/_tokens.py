"""Faithful Contour Tokens: the token rows of a grid, their array layouts, selection and union."""

from __future__ import annotations

import dataclasses

import numpy as np

from .. import _validate as check
from .._grid import Grid
from .._values import ValueEquality

__all__ = ["EDGE_AXIS", "EDGE_OFFSETS", "FORMATS", "Tokens", "merge", "select"]

# Corner offsets of the 12 cell edges: EDGE_OFFSETS[e] is the lower end of edge e relative
# to the cell's lower corner, EDGE_AXIS[e] its axis.
EDGE_AXIS = np.repeat(np.arange(3), 4)
_QUAD = ((0, 0), (1, 0), (1, 1), (0, 1))
EDGE_OFFSETS = np.zeros((12, 3), np.int64)
for _e in range(12):
    _a = _e // 4
    _others = [b for b in range(3) if b != _a]
    EDGE_OFFSETS[_e, _others[0]] = _QUAD[_e % 4][0]
    EDGE_OFFSETS[_e, _others[1]] = _QUAD[_e % 4][1]
del _e, _a, _others


@dataclasses.dataclass(frozen=True, eq=False)
class Tokens(ValueEquality):
    """Faithful Contour Tokens: one row per active cell (per surface patch in the cells that
    several patches cross, per component with `anchors_per_cell="components"`), sorted by
    C-order cell index, then component.
    Tokens compare by value (`==`: every field, arrays element by element).

    **Fields:**

    - `grid`: the [`Grid`][voxax.Grid] the tokens live on.
    - `index`: `(K,)` int64 C-order cell index (`cells` gives `(K, 3)` int32).
    - `offsets`: `(K, 3)` float64 anchors in cell units, `(x - centre) / spacing`, within
      `[-0.5, 0.5]` (`anchors` gives world coordinates).
    - `normals`: `(K, 3)` float64 unit normals.
    - `edge_signs`: `(K, 12)` int8 net flux of the surface through the cell's edges (see
      the module docstring for the edge order): -1, 0, +1 unless sheets overlap.
    - `component`: `(K,)` int32 component of the row within its cell (0 with one anchor per cell).
    - `area`: `(K,)` float64 surface area of the row's pieces (0 for rows added for cells
      that a crossing only touches).
    - `dual_offsets`, `dual_normals`, `dual_mask`, `semi_axis`: the dual layout (or None):
      `(K, 8, 3)` anchors of the dual cells centred on the cell's 8 corners (corner `c` at
      offset `unravel_index(c, (2, 2, 2))`; in units of the spacing, relative to the
      corner), their `(K, 8, 3)` normals, `(K, 8)` bool (whether the dual cell is active),
      and `(K, 6)` int8 net signs of the segments from the cell's centre to its 6
      neighbours' centres (along +axis), in the order -x, +x, -y, +y, -z, +z.
    """

    grid: Grid
    index: np.ndarray
    offsets: np.ndarray
    normals: np.ndarray
    edge_signs: np.ndarray
    component: np.ndarray
    area: np.ndarray
    dual_offsets: np.ndarray | None = None
    dual_normals: np.ndarray | None = None
    dual_mask: np.ndarray | None = None
    semi_axis: np.ndarray | None = None

    def __len__(self) -> int:
        return len(self.index)

    @property
    def cells(self) -> np.ndarray:
        """`(K, 3)` int32 cell indices `(i, j, k)`."""
        return _unravel(self.index, self.grid.shape)

    @property
    def anchors(self) -> np.ndarray:
        """`(K, 3)` float64 anchors in world coordinates."""
        lo = np.asarray(self.grid.lower)
        h = np.asarray(self.grid.spacing)
        out = self.cells + 0.5
        out += self.offsets
        out *= h
        out += lo
        return out

    def __repr__(self) -> str:
        return f"Tokens({len(self)} rows on {self.grid})"


def _unravel(index, shape) -> np.ndarray:
    """`(K, 3)` int32 cell indices of C-order indices `index` on a grid of `shape`."""
    out = np.empty((len(index), 3), np.int32)
    rest = np.asarray(index, np.int64)
    for a in (2, 1):
        rest, out[:, a] = np.divmod(rest, shape[a])
    out[:, 0] = rest
    return out


FORMATS = {"fct18": 18, "fct19": 19, "fct69": 69}


def _to_array(tokens: Tokens, fmt: str = "fct19", anchor_frame: str = "cell") -> np.ndarray:
    where = "voxax.fc.Tokens.to_array"
    if fmt not in FORMATS:
        raise ValueError(f"{where}: `fmt` must be one of {tuple(FORMATS)}, got {fmt!r}")
    if anchor_frame not in ("cell", "world"):
        raise ValueError(f"{where}: `anchor_frame` must be 'cell' or 'world', got {anchor_frame!r}")
    world = anchor_frame == "world"
    cols = [] if fmt == "fct18" else [tokens.index[:, None].astype(np.float64)]
    cols += [tokens.anchors if world else tokens.offsets, tokens.normals]
    if fmt == "fct69":
        if tokens.dual_offsets is None:
            raise ValueError(f"{where}: `fmt` 'fct69' must have tokens encoded with layout='dual'")
        h = np.asarray(tokens.grid.spacing)
        corners = tokens.cells[:, None, :] + np.array(np.unravel_index(np.arange(8), (2, 2, 2))).T[None]
        dual = tokens.dual_offsets
        if world:
            dual = np.where(tokens.dual_mask[..., None], np.asarray(tokens.grid.lower) + (corners + dual) * h, 0.0)
        per = np.concatenate([tokens.dual_mask[..., None].astype(np.float64), dual, tokens.dual_normals], axis=2)
        cols += [per.reshape(len(tokens), 56), tokens.semi_axis.astype(np.float64)]
    else:
        cols.append(tokens.edge_signs.astype(np.float64))
    return np.concatenate(cols, axis=1)


def _from_array(arr, grid: Grid, fmt: str = "fct19", anchor_frame: str = "cell", index=None) -> Tokens:
    where = "voxax.fc.Tokens.from_array"
    if fmt not in FORMATS:
        raise ValueError(f"{where}: `fmt` must be one of {tuple(FORMATS)}, got {fmt!r}")
    if anchor_frame not in ("cell", "world"):
        raise ValueError(f"{where}: `anchor_frame` must be 'cell' or 'world', got {anchor_frame!r}")
    grid = check.grid(where, grid, dim=3)
    a = np.asarray(arr)
    if a.dtype.kind not in "fiu":
        raise TypeError(f"{where}: `arr` must be a real array, got dtype {a.dtype}")
    a = a.astype(np.float64)
    if a.ndim != 2 or a.shape[1] != FORMATS[fmt]:
        raise ValueError(f"{where}: `arr` must have shape (K, {FORMATS[fmt]}) for '{fmt}', got {a.shape}")
    if not np.all(np.isfinite(a)):
        raise ValueError(f"{where}: `arr` must be finite (it contains NaN or Inf)")
    if fmt == "fct18":
        if index is None:
            raise TypeError(f"{where}: `index` must be given for 'fct18' (it has no index column): (K,) integers")
        idx = np.asarray(index)
        if idx.shape != (len(a),) or idx.dtype.kind not in "iu":
            raise ValueError(f"{where}: `index` must be (K,) integers, got {idx.dtype}{idx.shape}")
        idx = idx.astype(np.int64)
        body = a
    else:
        if np.any(a[:, 0] != np.round(a[:, 0])):
            raise ValueError(f"{where}: `arr`'s index column must hold integers")
        idx = a[:, 0].astype(np.int64)
        body = a[:, 1:]
    if len(idx) and (idx.min() < 0 or idx.max() >= grid.size):
        raise ValueError(f"{where}: `arr`'s cell indices must lie in [0, {grid.size})")
    if np.any(np.diff(idx) < 0):
        raise ValueError(f"{where}: `arr`'s rows must be sorted by cell index")
    cells = np.stack(np.unravel_index(idx, grid.shape), axis=1)
    h = np.asarray(grid.spacing)
    lo = np.asarray(grid.lower)
    off = body[:, 0:3]
    if anchor_frame == "world":
        off = (off - lo) / h - cells - 0.5
    if len(off) and np.abs(off).max() > 0.5 + 1e-9:
        raise ValueError(f"{where}: `arr`'s anchors must lie in their cells (offsets in [-0.5, 0.5] cell units)")
    nrm = body[:, 3:6]
    # Rows of the same cell are its components, in order.
    first = np.concatenate([[True], idx[1:] != idx[:-1]]) if len(idx) else np.zeros(0, bool)
    start = np.maximum.accumulate(np.where(first, np.arange(len(idx)), 0)) if len(idx) else np.zeros(0, np.int64)
    comp = (np.arange(len(idx)) - start).astype(np.int32)
    kw = {}
    if fmt == "fct69":
        per = body[:, 6:62].reshape(-1, 8, 7)
        mask = per[..., 0] != 0
        doff = per[..., 1:4]
        if anchor_frame == "world":
            corners = cells[:, None, :] + np.array(np.unravel_index(np.arange(8), (2, 2, 2))).T[None]
            doff = np.where(mask[..., None], (doff - lo) / h - corners, 0.0)
        kw = dict(
            dual_offsets=doff, dual_normals=per[..., 4:7], dual_mask=mask, semi_axis=_signs(where, body[:, 62:68])
        )
        signs = np.zeros((len(idx), 12), np.int8)
    else:
        signs = _signs(where, body[:, 6:18])
    return Tokens(grid, idx, off, nrm, signs, comp, np.full(len(idx), np.nan), **kw)


def _signs(where, x):
    if np.any((x != np.round(x)) | (np.abs(x) > 127)):
        raise ValueError(f"{where}: `arr`'s signs must be integers in [-127, 127]")
    return x.astype(np.int8)


Tokens.to_array = _to_array
Tokens.to_array.__doc__ = """The tokens as a float64 array, one row per token.

**Arguments:**

- `fmt`: `"fct19"`: `[index, anchor (3), normal (3), edge signs (12)]`; `"fct18"`: the
  same without the index (the 18-D token); `"fct69"` (dual layout): `[index, anchor (3),
  normal (3), 8 x [mask, dual anchor (3), dual normal (3)], semi-axis signs (6)]`.
- `anchor_frame`: `"cell"` (offsets in cell units from the cell centre; dual anchors from
  the corner) or `"world"`.

**Returns:** `(K, 18 | 19 | 69)` float64.
"""
Tokens.from_array = staticmethod(_from_array)
Tokens.from_array.__doc__ = """Tokens from [`Tokens.to_array`][voxax.fc.Tokens.to_array]'s layout.

**Arguments:** `arr` `(K, C)`, `grid`, `fmt`, `anchor_frame` as in `to_array`; `index`
`(K,)` int cell indices for `"fct18"`. Rows must be sorted by cell index; rows of one cell
are its components. The area is unknown (NaN).
"""


def select(tokens: Tokens, mask) -> Tokens:
    """The tokens where `mask` holds: `(K,)` bool, or integer row indices (kept sorted).

    >>> import voxax
    >>> tok = voxax.fc.encode(voxax.data.cube(1.2), voxax.Grid.cube(8))
    >>> len(voxax.fc.select(tok, tok.cells[:, 0] < 4)) < len(tok)
    True
    """
    if not isinstance(tokens, Tokens):
        raise TypeError(f"voxax.fc.select: `tokens` must be voxax.fc.Tokens, got {type(tokens).__name__}")
    m = np.asarray(mask)
    if m.dtype == bool:
        if m.shape != (len(tokens),):
            raise ValueError(f"voxax.fc.select: `mask` must have shape ({len(tokens)},) when boolean, got {m.shape}")
        rows = np.flatnonzero(m)
    elif m.dtype.kind in "iu":
        rows = np.unique(m.reshape(-1))
        if len(rows) and (rows[0] < -len(tokens) or rows[-1] >= len(tokens)):
            raise ValueError(f"voxax.fc.select: `mask`'s row indices must lie in [-{len(tokens)}, {len(tokens)})")
        rows = np.unique(np.where(rows < 0, rows + len(tokens), rows))
    else:
        raise TypeError(f"voxax.fc.select: `mask` must be boolean or integer, got {m.dtype}")
    return _take(tokens, rows)


def _take(tokens: Tokens, rows) -> Tokens:
    kw = {}
    for name in ("dual_offsets", "dual_normals", "dual_mask", "semi_axis"):
        v = getattr(tokens, name)
        kw[name] = None if v is None else v[rows]
    return Tokens(
        tokens.grid,
        tokens.index[rows],
        tokens.offsets[rows],
        tokens.normals[rows],
        tokens.edge_signs[rows],
        tokens.component[rows],
        tokens.area[rows],
        **kw,
    )


def merge(a: Tokens, b: Tokens) -> Tokens:
    """The union of two token sets on the same grid.

    Rows of the same cell and component are combined: the mean of the anchors, the
    normalized sum of the normals, the summed areas, and for every edge the sign of the
    sum of the two signs (the non-zero one where only one is non-zero, 0 where they
    disagree). The dual layout is kept only when both have it.
    """
    for name, x in (("a", a), ("b", b)):
        if not isinstance(x, Tokens):
            raise TypeError(f"voxax.fc.merge: `{name}` must be voxax.fc.Tokens, got {type(x).__name__}")
    if a.grid != b.grid:
        raise ValueError("voxax.fc.merge: `a` and `b` must live on the same grid")
    dual = a.dual_offsets is not None and b.dual_offsets is not None
    both = [a, b]
    idx = np.concatenate([t.index for t in both])
    comp = np.concatenate([t.component for t in both])
    order = np.lexsort((np.repeat([0, 1], [len(a), len(b)]), comp, idx))
    idx, comp = idx[order], comp[order]
    new = np.concatenate([[True], (idx[1:] != idx[:-1]) | (comp[1:] != comp[:-1])]) if len(idx) else np.zeros(0, bool)
    gid = np.cumsum(new) - 1
    n = int(gid[-1]) + 1 if len(gid) else 0
    cnt = np.bincount(gid, minlength=n).astype(np.float64)

    def cat(name):
        return np.concatenate([getattr(t, name) for t in both])[order]

    def mean(x):
        out = np.zeros((n,) + x.shape[1:])
        np.add.at(out, gid, x)
        return out / cnt.reshape((-1,) + (1,) * (x.ndim - 1))

    def vote(x):
        out = np.zeros((n,) + x.shape[1:], np.int64)
        np.add.at(out, gid, x.astype(np.int64))
        return np.sign(out).astype(np.int8)

    nrm = mean(cat("normals"))
    ln = np.linalg.norm(nrm, axis=1, keepdims=True)
    # Rows that come from one token (or from equal ones) keep their normal bit for bit.
    alone = (cnt == 1)[:, None] | (np.abs(ln - 1) <= 1e-15)
    nrm = np.where(alone, nrm, np.where(ln > 0, nrm / np.where(ln > 0, ln, 1), cat("normals")[new]))
    area = np.zeros(n)
    np.add.at(area, gid, cat("area"))
    kw = {}
    if dual:
        m = cat("dual_mask")
        w = np.zeros((n, 8))
        np.add.at(w, gid, m.astype(np.float64))
        ds = np.zeros((n, 8, 3))
        np.add.at(ds, gid, cat("dual_offsets") * m[..., None])
        dn = np.zeros((n, 8, 3))
        np.add.at(dn, gid, cat("dual_normals") * m[..., None])
        safe = np.where(w > 0, w, 1)[..., None]
        ln = np.linalg.norm(dn, axis=2, keepdims=True)
        kw = dict(
            dual_offsets=ds / safe,
            dual_normals=dn / np.where(ln > 0, ln, 1),
            dual_mask=w > 0,
            semi_axis=vote(cat("semi_axis")),
        )
    return Tokens(a.grid, idx[new], mean(cat("offsets")), nrm, vote(cat("edge_signs")), comp[new], area, **kw)


def _real(where, name, x, shape, kinds="fiu"):
    a = np.asarray(x)
    if a.dtype == bool or a.dtype.kind not in kinds:
        what = "real numbers" if kinds == "fiu" else "integers"
        raise TypeError(f"{where}: `tokens.{name}` must hold {what}, got dtype {a.dtype}")
    if a.shape != shape:
        raise ValueError(f"{where}: `tokens.{name}` must have shape {shape}, got {a.shape}")
    return a


def check_tokens(where: str, tokens) -> Tokens:
    """`tokens` checked field by field (types, shapes, ranges): a `TypeError` or `ValueError`
    naming the field, never a silent cast (edited tokens go through here before decoding)."""
    if not isinstance(tokens, Tokens):
        raise TypeError(f"{where}: `tokens` must be voxax.fc.Tokens, got {type(tokens).__name__}")
    grid = check.grid(where, tokens.grid, dim=3)
    index = np.asarray(tokens.index)
    if index.ndim != 1:
        raise ValueError(f"{where}: `tokens.index` must have shape (K,), got {index.shape}")
    K = len(index)
    index = _real(where, "index", index, (K,), "iu")
    if K and (index.min() < 0 or index.max() >= grid.size):
        raise ValueError(f"{where}: `tokens.index` must lie in [0, {grid.size}) (C-order cells of the grid)")
    if np.any(np.diff(index) < 0):
        raise ValueError(f"{where}: `tokens.index` must be sorted (rows sorted by cell index)")
    off = _real(where, "offsets", tokens.offsets, (K, 3))
    if not np.all(np.isfinite(off)) or (K and np.abs(off).max() > 0.5 + 1e-9):
        raise ValueError(f"{where}: `tokens.offsets` must be finite and lie in [-0.5, 0.5] (cell units)")
    nrm = _real(where, "normals", tokens.normals, (K, 3))
    if not np.all(np.isfinite(nrm)):
        raise ValueError(f"{where}: `tokens.normals` must be finite")
    signs = _real(where, "edge_signs", tokens.edge_signs, (K, 12), "iu")
    if K and (signs.min() < -127 or signs.max() > 127):
        raise ValueError(f"{where}: `tokens.edge_signs` must lie in [-127, 127]")
    _real(where, "component", tokens.component, (K,), "iu")
    _real(where, "area", tokens.area, (K,))
    return Tokens(
        grid,
        np.ascontiguousarray(index, np.int64),
        np.ascontiguousarray(off, np.float64),
        np.ascontiguousarray(nrm, np.float64),
        np.ascontiguousarray(signs, np.int8),
        np.asarray(tokens.component, np.int32),
        np.asarray(tokens.area, np.float64),
        tokens.dual_offsets,
        tokens.dual_normals,
        tokens.dual_mask,
        tokens.semi_axis,
    )
