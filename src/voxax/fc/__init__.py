"""Faithful Contouring: a triangle mesh as sparse surface tokens on a grid, and back.

[`encode`][voxax.fc.encode] clips every triangle into the cells it meets (exactly, with
the voxelizer's clipping), and gives every active cell a *token*: an anchor point solved
from a quadratic error function (QEF) over the cell's pieces, a normal, and the signs of
the surface's net crossings of the cell's 12 edges. [`decode`][voxax.fc.decode] turns
tokens back into a triangle mesh by dual contouring: one vertex per token, one quad per
crossed lattice edge. No signed distance field, no watertight repair: open, non-manifold
and hollow surfaces keep their topology, and sharp edges and corners are kept by the QEF.

The anchor of a cell minimizes, in cell-local coordinates `u = (x - centre) / h`,

    sum_i w_i [lambda_n (n_i . (u - c_i))^2 + lambda_d |u - c_i|^2],   w_i = A_i^p / sum A^p

over the cell's pieces `i` (area `A_i`, area centroid `c_i`, the triangle's normal `n_i`,
normals taken in local coordinates). When the minimizer leaves the cell, it is clamped to
the cell and moved to the closest point of the cell's own pieces. Beyond the paper: open
boundaries of the mesh add their lines to the QEF (`open_boundaries=True`), so open sheets
keep their extent; with `anchors_per_cell="components"` every connected component of a
cell's pieces (faces joined by a mesh edge through the cell) gets its own anchor, so nearby
sheets are no longer merged into one vertex; and the decoder joins anchors that no quad uses (sharp tips
thinner than a cell) to the surface.

Edge signs are the net flux of the surface through each lattice edge: the sum over the
crossings of the edge (exact, from `voxax.raster.line_crossings` through the grid nodes)
of +1 where the surface normal points along the edge's axis and -1 where it points against
it (int8, clipped to [-127, 127]; the decoder uses its sign). For a closed mesh it is the
winding number at the edge's lower end minus the one at its upper end. Nodes on the
surface are decided exactly as if every node were moved to `p + (e_x, e_y, e_z)` with
`e_x >> e_y >> e_z > 0` (the perturbation that the lines' tie rule applies), the same for
all three axes, so meshes through grid nodes still decode closed.

Edge order in a token: edges 0-3 run along x through the cell's corners at (y, z) offsets
(0, 0), (1, 0), (1, 1), (0, 1); edges 4-7 along y at (x, z) offsets in the same order;
edges 8-11 along z at (x, y) offsets in the same order.

>>> import voxax
>>> tok = voxax.fc.encode(voxax.data.cube(1.2), voxax.Grid.cube(16))
>>> mesh = voxax.fc.decode(tok)
>>> voxax.metrics.euler_characteristic(mesh)
2
"""

from __future__ import annotations

import ctypes
import dataclasses
from typing import NamedTuple

import numpy as np

from .. import _kernels
from .. import _validate as check
from .._grid import Grid
from .._mesh import Mesh, face_normals, mesh_from_trusted

__all__ = [
    "EDGE_OFFSETS",
    "Pieces",
    "RoundtripReport",
    "Tokens",
    "decode",
    "encode",
    "merge",
    "pieces",
    "roundtrip",
    "select",
]

_D, _I32, _I64, _VP = _kernels.D, _kernels.I32, _kernels.I64, _kernels.VP
_SIGNATURES = {
    "voxax_fc_encode": (
        ctypes.c_int,
        [
            _D,
            ctypes.c_int64,
            _I32,
            ctypes.c_int64,
            ctypes.POINTER(ctypes.c_uint8),
            _D,
            _I64,
            _D,
            ctypes.c_int32,
            _I64,
            ctypes.c_int64,
            ctypes.c_int32,
            ctypes.POINTER(_VP),
            _I64,
            ctypes.c_char_p,
            ctypes.c_int64,
        ],
    ),
    "voxax_fc_rows": (None, [_VP, _I64, _I32, _D, _D, _D, _I32, _I64, _I32]),
    "voxax_fc_pieces": (None, [_VP, _I64, _I32, _D, _D]),
    "voxax_fc_free": (None, [_VP]),
    "voxax_fc_decode": (
        ctypes.c_int,
        [
            _I64,
            _D,
            _D,
            ctypes.POINTER(ctypes.c_int8),
            ctypes.c_int64,
            _I64,
            ctypes.c_int32,
            ctypes.c_int32,
            ctypes.POINTER(_VP),
            _I64,
            ctypes.c_char_p,
            ctypes.c_int64,
        ],
    ),
    "voxax_fc_triangles": (None, [_VP, _I64]),
    "voxax_fc_node_side": (
        ctypes.c_int,
        [
            _D,
            ctypes.c_int64,
            _I32,
            ctypes.c_int64,
            ctypes.c_int64,
            _I32,
            _D,
            _I32,
            ctypes.POINTER(ctypes.c_int8),
            ctypes.c_char_p,
            ctypes.c_int64,
        ],
    ),
    "voxax_fc_free_triangles": (None, [_VP]),
    "voxax_fc_signs": (
        ctypes.c_int,
        [
            _I64,
            ctypes.c_int64,
            _I64,
            _I64,
            ctypes.POINTER(ctypes.c_int8),
            ctypes.c_int64,
            ctypes.c_int32,
            ctypes.POINTER(ctypes.c_int8),
            ctypes.POINTER(_VP),
            _I64,
            ctypes.c_char_p,
            ctypes.c_int64,
        ],
    ),
}

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


def _lib():
    return _kernels.declare(_SIGNATURES)


_CTYPES = {np.dtype(np.float64): _D, np.dtype(np.int32): _I32, np.dtype(np.int64): _I64}


def _copy_out(copy, handle, free, *specs):
    """Fresh arrays of `specs` (`(shape, dtype)` pairs) filled by `copy(handle, *pointers)`;
    the handle is released by `free(handle)` in any case."""
    try:
        out = [np.empty(shape, dtype) for shape, dtype in specs]
        copy(handle, *(a.ctypes.data_as(_CTYPES[a.dtype]) for a in out))
    finally:
        free(handle)
    return out


def _call_encode(where, V, F, grid, params, flags, threads, open_boundaries=False, joined=None):
    lib = _lib()
    V = np.ascontiguousarray(V, dtype=np.float64)
    F = np.ascontiguousarray(F, dtype=np.int32)
    box = np.ascontiguousarray(np.concatenate([grid.lower, grid.upper]), dtype=np.float64)
    shape = np.ascontiguousarray(grid.shape, dtype=np.int64)
    prm = np.ascontiguousarray(params, dtype=np.float64)
    if joined is not None:
        joined = np.ascontiguousarray(joined, dtype=np.int64)
    handle = _VP()
    sizes = np.zeros(3, np.int64)
    err = _kernels.error_buffer()
    status = lib.voxax_fc_encode(
        V.ctypes.data_as(_D),
        len(V),
        F.ctypes.data_as(_I32),
        len(F),
        None,
        box.ctypes.data_as(_D),
        shape.ctypes.data_as(_I64),
        prm.ctypes.data_as(_D),
        int(flags) | (16 if open_boundaries else 0),
        None if joined is None else joined.ctypes.data_as(_I64),
        0 if joined is None else len(joined),
        _kernels.threads(threads),
        ctypes.byref(handle),
        sizes.ctypes.data_as(_I64),
        err,
        _kernels.ERRLEN,
    )
    if status != 0:
        msg = err.value.decode("utf-8", "replace").removeprefix("voxax: ")
        raise ValueError(f"{where}: {msg}")
    return handle, sizes


def _mesh_args(where, vertices, faces, grid):
    vertices, faces, (grid,) = check.unpack_mesh(where, vertices, faces, grid)
    vertices, faces = check.mesh(where, vertices, faces, dim=3, integer_vertices=True, allow_empty=True)
    grid = check.grid(where, grid, dim=3)
    return np.asarray(vertices, np.float64), np.asarray(faces, np.int32), grid


class Pieces(NamedTuple):
    """The pieces of a mesh clipped into a grid's cells, sorted by (cell, face).

    - `cell`: `(P,)` int64 C-order cell index; `face`: `(P,)` int32 face index.
    - `area`: `(P,)` float64 piece area (> 0; pieces of zero area are left out).
    - `centroid`: `(P, 3)` float64 area centroid (inside the closed cell).
    """

    cell: np.ndarray
    face: np.ndarray
    area: np.ndarray
    centroid: np.ndarray


def pieces(vertices, faces=None, grid=None, *, threads=None) -> Pieces:
    """Clips every triangle into the cells it meets; the pieces partition each triangle.

    Cells are half-open (`[lower, upper)` per axis, the last one closed), as in
    [`voxax.voxelize`][voxax.voxelize], so every part of a triangle belongs to exactly
    one cell. Degenerate triangles give no pieces.

    **Arguments:**

    - `vertices`: `(V, 3)` float; `faces`: `(F, 3)` int (or a `Mesh` in place of both).
    - `grid`: a 3D [`Grid`][voxax.Grid].
    - `threads`: worker threads (None: all cores); results do not depend on it.

    **Returns:** [`Pieces`][voxax.fc.Pieces].

    >>> import voxax
    >>> p = voxax.fc.pieces(voxax.data.cube(1.0), voxax.Grid.cube(4))
    >>> round(float(p.area.sum()), 12)
    6.0
    """
    where = "voxax.fc.pieces"
    V, F, grid = _mesh_args(where, vertices, faces, grid)
    handle, sizes = _call_encode(where, V, F, grid, (1.0, 1e-3, 1.0), 1 | 8, threads)
    lib, n = _lib(), int(sizes[2])
    specs = ((n, np.int64), (n, np.int32), (n, np.float64), ((n, 3), np.float64))
    return Pieces(*_copy_out(lib.voxax_fc_pieces, handle, lib.voxax_fc_free, *specs))


@dataclasses.dataclass(frozen=True, eq=False)
class Tokens:
    """Faithful Contour Tokens: one row per active cell (per component with
    `anchors_per_cell="components"`), sorted by C-order cell index, then component.

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


def _node_ids(grid: Grid, axis, nodes) -> np.ndarray:
    """Canonical int64 id of the lattice edge along `axis` starting at node `nodes`."""
    s = np.asarray(grid.shape, np.int64) + 1
    lin = (nodes[..., 0] * s[1] + nodes[..., 1]) * s[2] + nodes[..., 2]
    return np.asarray(axis, np.int64) * (s[0] * s[1] * s[2]) + lin


class _Crossings(NamedTuple):
    edge: np.ndarray  # (C,) edge id
    sign: np.ndarray  # (C,) int8
    face: np.ndarray  # (C,) int32
    point: np.ndarray  # (C, 3)


def _crossings(V, F, grid: Grid, threads) -> _Crossings:
    """Every crossing of the mesh with the lattice edges, exact (grid-node lines)."""
    from .. import raster

    edges, signs, faces, points = [], [], [], []
    # The lines' tie rule treats every node p as p + (e_x, e_y, e_z), e_x >> e_y >> e_z, for
    # all three families of lines, so they agree on each node's side of the surface.
    for a in range(3):
        d = raster.line_crossings(V, F, grid, a, lines="nodes", threads=threads)
        depth = np.asarray(d.depth)
        planes = grid.edges(a)
        slack = 1e-9 * (grid.spacing[a] + np.abs(planes[[0, -1]]))
        keep = (depth >= planes[0] - slack[0]) & (depth <= planes[-1] + slack[1])
        line = np.asarray(d.line_index())[keep]
        depth = depth[keep]
        face = np.asarray(d.face, np.int32)[keep]
        seg = np.clip(np.searchsorted(planes, depth, side="right") - 1, 0, len(planes) - 2)
        nv = len(d.line_coords[1])
        iu, iv = np.divmod(line.astype(np.int64), nv)
        others = [b for b in range(3) if b != a]
        # Crossings within rounding distance of a node: which side of the node they lie
        # on is decided exactly, with the nodes perturbed as the lines are.
        tol = 1e-9 * (grid.spacing[a] + np.abs(planes[seg]))
        lo_near = depth - planes[seg] <= tol
        hi_near = planes[seg + 1] - depth <= tol
        near = np.flatnonzero(lo_near | hi_near)
        if len(near):
            k = np.where(lo_near[near], seg[near], seg[near] + 1)
            pts = np.empty((len(near), 3))
            pts[:, a] = planes[k]
            pts[:, others[0]] = grid.edges(others[0])[iu[near]]
            pts[:, others[1]] = grid.edges(others[1])[iv[near]]
            side = _node_side(V, F, face[near], pts, a)
            seg[near] = np.where(side < 0, k - 1, k)
        # Crossings beyond the first or last node (after the tie rule) leave the grid.
        inside = (seg >= 0) & (seg < grid.shape[a])
        keep[np.flatnonzero(keep)[~inside]] = False
        line, depth, face, seg, iu, iv = line[inside], depth[inside], face[inside], seg[inside], iu[inside], iv[inside]
        nodes = np.empty((len(line), 3), np.int64)
        nodes[:, a] = seg
        nodes[:, others[0]] = iu
        nodes[:, others[1]] = iv
        edges.append(_node_ids(grid, a, nodes))
        sign = np.asarray(d.sign, np.int8)[keep]
        pts = np.asarray(d.points(), np.float64)[keep]
        signs.append(sign)
        faces.append(face)
        points.append(pts)
    return _Crossings(np.concatenate(edges), np.concatenate(signs), np.concatenate(faces), np.concatenate(points))


def _node_side(V, F, faces, nodes, axis) -> np.ndarray:
    """+1 where the crossing of each face with the line along `axis` through each node lies
    above the node, -1 below (exact, nodes perturbed as the lines are)."""
    V = np.ascontiguousarray(V, np.float64)
    F = np.ascontiguousarray(F, np.int32)
    faces = np.ascontiguousarray(faces, np.int32)
    nodes = np.ascontiguousarray(nodes, np.float64)
    ax = np.full(len(faces), axis, np.int32)
    out = np.zeros(len(faces), np.int8)
    err = _kernels.error_buffer()
    status = _lib().voxax_fc_node_side(
        V.ctypes.data_as(_D),
        len(V),
        F.ctypes.data_as(_I32),
        len(F),
        len(faces),
        faces.ctypes.data_as(_I32),
        nodes.ctypes.data_as(_D),
        ax.ctypes.data_as(_I32),
        out.ctypes.data_as(ctypes.POINTER(ctypes.c_int8)),
        err,
        _kernels.ERRLEN,
    )
    _kernels.check(status, err)
    return out


def _edge_geometry(grid: Grid, edge: np.ndarray):
    """Axis and start node `(C, 3)` of edge ids."""
    s = np.asarray(grid.shape, np.int64) + 1
    total = s[0] * s[1] * s[2]
    axis, lin = np.divmod(edge, total)
    nodes = np.stack(np.unravel_index(lin, tuple(s)), axis=1).astype(np.int64)
    return axis, nodes


def _around_offsets() -> np.ndarray:
    """`(3, 4, 3)`: the offsets from an edge's start node to the 4 cells around it, per axis."""
    off = np.zeros((3, 4, 3), np.int64)
    for a in range(3):
        others = [b for b in range(3) if b != a]
        for p in range(4):
            o = _QUAD[(p + 2) % 4]
            off[a, p, others[0]] = -o[0]
            off[a, p, others[1]] = -o[1]
    return off


_AROUND = _around_offsets()


def _cells_around(grid: Grid, axis, nodes):
    """The C-order indices of the 4 cells around each edge, `(C, 4)` int64, in the order
    of positions 0-3 (-1 where the cell lies outside the grid).

    Position p holds the cell whose edge `_QUAD[(p + 2) % 4]` is this edge: positions run
    counter-clockwise around the edge in the plane of the two other axes (in increasing
    axis order)."""
    shape = np.asarray(grid.shape, np.int64)
    out = np.empty((len(axis), 4), np.int64)
    for p in range(4):
        d = _AROUND[axis, p]  # (C, 3)
        lin = np.zeros(len(axis), np.int64)
        ok = np.ones(len(axis), bool)
        for k in range(3):
            c = nodes[:, k] + d[:, k]
            ok &= (c >= 0) & (c < shape[k])
            lin = lin * shape[k] + c
        out[:, p] = np.where(ok, lin, -1)
    return out


def _token_edges(grid: Grid, cells: np.ndarray) -> np.ndarray:
    """`(K, 12)` edge ids of the cells' edges."""
    nodes = cells[:, None, :].astype(np.int64) + EDGE_OFFSETS[None]
    return _node_ids(grid, EDGE_AXIS[None, :], nodes)


def _rows(
    where, V, F, grid, lambda_n, lambda_d, weight_power, clamp, components, threads, boundaries=True, joined=None
):
    flags = (1 if clamp else 0) | (2 | 4 if components else 0)
    handle, sizes = _call_encode(
        where, V, F, grid, (lambda_n, lambda_d, weight_power), flags, threads, open_boundaries=boundaries, joined=joined
    )
    lib = _lib()
    k, nfc = int(sizes[0]), int(sizes[1])
    # The face counts are written only when the faces were recorded (`components`).
    fcount_k = k if components else 0
    specs = ((k, np.int64), (k, np.int32), ((k, 3), np.float64), ((k, 3), np.float64), (k, np.float64))
    specs += ((k, np.int32), (fcount_k, np.int64), (nfc, np.int32))
    index, comp, off, nrm, area, _, fcount, faces = _copy_out(lib.voxax_fc_rows, handle, lib.voxax_fc_free, *specs)
    if not components:
        fcount = np.zeros(k, np.int64)
    return index, comp, off, nrm, area, fcount, faces


def _group(keys):
    """Sorts `keys`; returns (order, start of each run of equal keys in sorted order)."""
    order = np.argsort(keys, kind="stable")
    k = keys[order]
    starts = np.flatnonzero(np.concatenate([[True], k[1:] != k[:-1]])) if len(k) else np.zeros(0, np.int64)
    return order, starts


def _lookup(index, cells):
    """Rows of `cells` in the sorted `index` (-1 where absent)."""
    if not len(index):
        return np.full(cells.shape, -1, np.int64)
    pos = np.clip(np.searchsorted(index, cells), 0, len(index) - 1)
    return np.where(index[pos] == cells, pos, -1)


def _encode_primal(where, V, F, grid, lambda_n, lambda_d, weight_power, clamp, components, threads, boundaries):
    index, comp, off, nrm, area, fcount, rfaces = _rows(
        where, V, F, grid, lambda_n, lambda_d, weight_power, clamp, components, threads, boundaries
    )
    cr = _crossings(V, F, grid, threads)
    shape = grid.shape
    h = np.asarray(grid.spacing)
    lo = np.asarray(grid.lower)
    if not components:
        signs, missing, src = _net_signs_host(grid, index, cr, threads)
        if len(missing):
            # Cells that a crossing touches without a piece of positive area get a row at
            # the crossing point, so every quad has its four vertices.
            mcells = np.stack(np.unravel_index(missing, shape), axis=1)
            moff = np.clip((cr.point[src] - lo) / h - mcells - 0.5, -0.5, 0.5)
            order = np.argsort(np.concatenate([index, missing]), kind="stable")
            index = np.concatenate([index, missing])[order]
            comp = np.concatenate([comp, np.zeros(len(missing), np.int32)])[order]
            off = np.concatenate([off, moff])[order]
            nrm = np.concatenate([nrm, face_normals(V, F)[cr.face[src]]])[order]
            area = np.concatenate([area, np.zeros(len(missing))])[order]
            signs, missing, _ = _net_signs_host(grid, index, cr, threads)
            assert not len(missing)
        return Tokens(grid, index, off, nrm, signs, comp, area)
    # anchors_per_cell="components": every crossing counts for the rows of its own sheet,
    # so every crossing needs its cells.
    edge = cr.edge
    axis, nodes = _edge_geometry(grid, edge)
    cidx = _cells_around(grid, axis, nodes)
    flat = cidx.reshape(-1)
    forder, fstarts = _group(flat)
    want = flat[forder[fstarts]]
    firsts = forder[fstarts]
    # A cell whose components split the crossings of an edge that one row of a neighbour
    # holds together (two sheets that join just outside the cell) would leave holes: such
    # cells get one anchor for all their pieces, until every edge's crossings are split
    # alike in its 4 cells.
    joined = np.zeros(0, np.int64)
    for _ in range(64):
        tok, bad = _component_tokens(V, F, grid, cr, cidx, want, firsts, index, comp, off, nrm, area, fcount, rfaces)
        bad = np.setdiff1d(bad, joined)
        if not len(bad):
            break
        joined = np.union1d(joined, bad)
        index, comp, off, nrm, area, fcount, rfaces = _rows(
            where, V, F, grid, lambda_n, lambda_d, weight_power, clamp, True, threads, boundaries, joined=joined
        )
    return tok


def _component_tokens(V, F, grid, cr, cidx, want, firsts, index, comp, off, nrm, area, fcount, rfaces):
    """Tokens with several rows per cell, and the cells whose rows split an edge's group."""
    shape = grid.shape
    h = np.asarray(grid.spacing)
    lo = np.asarray(grid.lower)
    inside = cidx >= 0
    # Cells that a crossing touches without a piece of positive area get a row at the
    # crossing point, so every quad has its four vertices.
    keep = (want >= 0) & (_lookup(index, want) < 0)
    missing, src = want[keep], firsts[keep] // 4
    if len(missing):
        mcells = np.stack(np.unravel_index(missing, shape), axis=1)
        moff = np.clip((cr.point[src] - lo) / h - mcells - 0.5, -0.5, 0.5)
        fn = face_normals(V, F)[cr.face[src]]
        index = np.concatenate([index, missing])
        comp = np.concatenate([comp, np.zeros(len(missing), np.int32)])
        off = np.concatenate([off, moff])
        nrm = np.concatenate([nrm, fn])
        area = np.concatenate([area, np.zeros(len(missing))])
        fcount = np.concatenate([fcount, np.ones(len(missing), np.int64)])
        rfaces_rows = np.split(rfaces, np.cumsum(fcount[: len(fcount) - len(missing)])[:-1])
        rfaces_rows += [np.array([f], np.int32) for f in cr.face[src]]
        order = np.lexsort((comp, index))
        index, comp, off, nrm, area = index[order], comp[order], off[order], nrm[order], area[order]
        rfaces_rows = [rfaces_rows[i] for i in order]
        fcount = fcount[order]
        rfaces = np.concatenate(rfaces_rows) if rfaces_rows else np.zeros(0, np.int32)
    signs, bad = _component_signs(grid, cr, inside, cidx, index, off, fcount, rfaces, F, len(index))
    return Tokens(grid, index, off, nrm, signs, comp, area), bad


def _net_signs_host(grid: Grid, index, cr: _Crossings, threads):
    """`(K, 12)` int8 net signs of the rows' edges (one row per cell), and the cells around
    signed edges that have no row with the crossing each takes its row from."""
    lib = _lib()
    K = len(index)
    index = np.ascontiguousarray(index, np.int64)
    edge = np.ascontiguousarray(cr.edge, np.int64)
    sign = np.ascontiguousarray(cr.sign, np.int8)
    shape = np.ascontiguousarray(grid.shape, np.int64)
    S = np.zeros((K, 12), np.int8)
    handle = _VP()
    count = np.zeros(1, np.int64)
    err = _kernels.error_buffer()
    status = lib.voxax_fc_signs(
        index.ctypes.data_as(_I64),
        K,
        shape.ctypes.data_as(_I64),
        edge.ctypes.data_as(_I64),
        sign.ctypes.data_as(ctypes.POINTER(ctypes.c_int8)),
        len(edge),
        _kernels.threads(threads),
        S.ctypes.data_as(ctypes.POINTER(ctypes.c_int8)),
        ctypes.byref(handle),
        count.ctypes.data_as(_I64),
        err,
        _kernels.ERRLEN,
    )
    _kernels.check(status, err)
    (pairs,) = _copy_out(lib.voxax_fc_triangles, handle, lib.voxax_fc_free_triangles, ((int(count[0]), 2), np.int64))
    return S, pairs[:, 0].copy(), pairs[:, 1].copy()


def _component_signs(grid, cr, inside, cidx, index, off, fcount, rfaces, F, K):
    """Per-row edge signs with several rows per cell.

    In each of the 4 cells around its edge, a crossing belongs to the row whose pieces
    hold the crossing face (or else the row nearest to the crossing). Crossings of one
    edge that share a row in any of its cells form one group (one sheet through the
    edge); each group puts its net sign on one row per cell (the row most of its
    crossings belong to), so every cell around the edge gets the same groups."""
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    h = np.asarray(grid.spacing)
    lo = np.asarray(grid.lower)
    nf = np.uint64(max(len(F), 1))
    C = len(cr.edge)
    row_of_face = np.repeat(np.arange(K), fcount)
    key = index[row_of_face].astype(np.uint64) * nf + rfaces.astype(np.uint64)
    korder = np.argsort(key, kind="stable")
    skey = key[korder]
    first = np.searchsorted(index, cidx, side="left")
    last = np.searchsorted(index, cidx, side="right")
    cells = np.stack(np.unravel_index(index, grid.shape), axis=1)
    anchors = lo + (cells + 0.5 + off) * h
    rows = np.full((C, 4), -1, np.int64)
    for p in range(4):
        ok = inside[:, p]
        c = np.where(ok, cidx[:, p], 0).astype(np.uint64)
        q = c * nf + cr.face.astype(np.uint64)
        at = np.clip(np.searchsorted(skey, q), 0, max(len(skey) - 1, 0))
        hit = ok & (skey[at] == q) if len(skey) else np.zeros(C, bool)
        rows[:, p] = np.where(hit, row_of_face[korder[at]] if len(skey) else -1, -1)
        for t in np.nonzero(ok & ~hit)[0]:
            a, b = first[t, p], last[t, p]
            if b > a:
                d = np.linalg.norm(anchors[a:b] - cr.point[t], axis=1)
                rows[t, p] = a + int(np.argmin(d))
    signs = np.zeros((K, 12), np.int8)
    if C == 0:
        return signs, np.zeros(0, np.int64)
    # Groups: crossings joined through a shared (edge, row) in any cell.
    t_idx, p_idx = np.nonzero(rows >= 0)
    ekey = np.stack([cr.edge[t_idx], rows[t_idx, p_idx]], 1)
    _, node = np.unique(ekey, axis=0, return_inverse=True)
    node = node.reshape(-1)
    graph = coo_matrix((np.ones(len(t_idx)), (t_idx, C + node)), shape=(C + node.max() + 1,) * 2)
    _, label = connected_components(graph, directed=False)
    group = label[:C]
    _, group = np.unique(group, return_inverse=True)
    net = np.zeros(group.max() + 1, np.int64)
    np.add.at(net, group, cr.sign.astype(np.int64))
    axis = (cr.edge // np.prod(np.asarray(grid.shape, np.int64) + 1)).astype(np.int64)
    # The row each group uses in each cell: the most frequent one (ties: the lowest row).
    g = group[t_idx]
    r = rows[t_idx, p_idx]
    trip = np.stack([g, p_idx, r], 1)
    uniq, counts = np.unique(trip, axis=0, return_counts=True)
    # Cells where one group's crossings belong to several rows.
    split = np.flatnonzero(np.all(uniq[1:, :2] == uniq[:-1, :2], axis=1))
    bad = np.unique(index[np.concatenate([uniq[split, 2], uniq[split + 1, 2]])])
    order = np.lexsort((uniq[:, 2], -counts, uniq[:, 1], uniq[:, 0]))
    uniq = uniq[order]
    firsts = np.concatenate([[True], np.any(uniq[1:, :2] != uniq[:-1, :2], axis=1)])
    chosen = uniq[firsts]  # (group, position, row)
    gaxis = np.zeros(len(net), np.int64)
    gaxis[group] = axis
    slot = gaxis[chosen[:, 0]] * 4 + (chosen[:, 1] + 2) % 4
    signs[chosen[:, 2], slot] = np.clip(net[chosen[:, 0]], -127, 127)
    # The decoder pairs an edge's voting rows across its 4 cells in the order of their
    # anchors along the edge: where that order differs between cells, the groups would be
    # paired wrongly, so those cells join their components too.
    cg = chosen[net[chosen[:, 0]] != 0]
    if len(cg):
        gedge = np.zeros(len(net), np.int64)
        gedge[group] = cr.edge
        e = gedge[cg[:, 0]]
        coord = anchors[cg[:, 2], gaxis[cg[:, 0]]]
        o = np.lexsort((cg[:, 2], coord, cg[:, 1], e))
        cg, e = cg[o], e[o]
        run = np.concatenate([[True], (e[1:] != e[:-1]) | (cg[1:, 1] != cg[:-1, 1])])
        start = np.maximum.accumulate(np.where(run, np.arange(len(cg)), 0))
        rank = np.arange(len(cg)) - start
        lo_rank = np.full(len(net), np.iinfo(np.int64).max)
        hi_rank = np.full(len(net), -1)
        np.minimum.at(lo_rank, cg[:, 0], rank)
        np.maximum.at(hi_rank, cg[:, 0], rank)
        mixed = lo_rank[cg[:, 0]] != hi_rank[cg[:, 0]]
        if mixed.any():
            edges = np.unique(e[mixed])
            bad = np.union1d(bad, index[cg[np.isin(e, edges), 2]])
    return signs, bad


def encode(
    vertices,
    faces=None,
    grid=None,
    *,
    layout: str = "primal",
    lambda_n: float = 1.0,
    lambda_d: float = 1e-3,
    weight_power: float = 1.0,
    clamp: bool = True,
    anchors_per_cell=1,
    open_boundaries: bool = True,
    threads=None,
) -> Tokens:
    """Encodes a triangle mesh into Faithful Contour Tokens on `grid`.

    **Arguments:**

    - `vertices`: `(V, 3)` float; `faces`: `(F, 3)` int (or a `Mesh` in place of both).
      Open, non-manifold and degenerate faces are allowed.
    - `grid`: a 3D [`Grid`][voxax.Grid] (any shape, cells may be anisotropic).
    - `layout`: `"primal"` (anchors and the 12 edge signs) or `"dual"` (also the dual
      anchors at the cell's 8 corners and the 6 semi-axis signs).
    - `lambda_n`, `lambda_d`: QEF weights of the tangent planes and of the centroids
      (`lambda_d > 0`, in cell units).
    - `weight_power`: `p` in the piece weights `A^p` (0: uniform).
    - `clamp`: move anchors that leave their cell back onto the cell's pieces.
    - `anchors_per_cell`: `1`, or `"components"` for one anchor per connected component
      of the cell's pieces (pieces of faces that share a mesh edge passing through the
      cell are joined), so that nearby sheets, and the two faces of a sharp edge that
      passes just outside the cell, get a vertex each. A cell keeps one anchor where its
      components would split the crossings of one of its edges differently from the cells
      around that edge (two sheets that join just outside the cell, or sheets in another
      order along the edge), which would leave holes in the decoded mesh.
    - `open_boundaries`: where an open boundary of the mesh (an edge of one face only)
      passes through a cell, add its lines to the QEF with the weight of the tangent
      planes, so that the anchor lies on the boundary and open sheets keep their extent
      (beyond the paper; no effect on closed meshes).
    - `threads`: worker threads (None: all cores); the result does not depend on it.

    **Returns:** [`Tokens`][voxax.fc.Tokens].
    """
    where = "voxax.fc.encode"
    V, F, grid = _mesh_args(where, vertices, faces, grid)
    if layout not in ("primal", "dual"):
        raise ValueError(f"{where}: `layout` must be 'primal' or 'dual', got {layout!r}")
    if anchors_per_cell not in (1, "components") or isinstance(anchors_per_cell, bool):
        raise ValueError(f"{where}: `anchors_per_cell` must be 1 or 'components', got {anchors_per_cell!r}")
    lambda_n = check.positive_float(where, "lambda_n", lambda_n, allow_zero=True)
    lambda_d = check.positive_float(where, "lambda_d", lambda_d)
    weight_power = check.positive_float(where, "weight_power", weight_power, allow_zero=True)
    if weight_power > 16:
        raise ValueError(f"{where}: `weight_power` must lie in [0, 16], got {weight_power}")
    _kernels.threads(threads)
    components = anchors_per_cell == "components"
    b = bool(open_boundaries)
    tok = _encode_primal(where, V, F, grid, lambda_n, lambda_d, weight_power, bool(clamp), components, threads, b)
    if layout == "dual":
        tok = _add_dual(where, tok, V, F, lambda_n, lambda_d, weight_power, bool(clamp), threads, b)
    return tok


def dual_grid(grid: Grid) -> Grid:
    """The half-shifted grid whose cells are centred on `grid`'s nodes (shape + 1)."""
    h = np.asarray(grid.spacing)
    return Grid(
        tuple(np.asarray(grid.lower) - h / 2), tuple(np.asarray(grid.upper) + h / 2), tuple(s + 1 for s in grid.shape)
    )


def _net_signs(grid: Grid, cr: _Crossings, edges: np.ndarray) -> np.ndarray:
    uniq, inv = np.unique(cr.edge, return_inverse=True)
    net = np.zeros(len(uniq), np.int64)
    np.add.at(net, inv, cr.sign.astype(np.int64))
    if not len(uniq):
        return np.zeros(edges.shape, np.int8)
    pos = np.clip(np.searchsorted(uniq, edges), 0, len(uniq) - 1)
    return np.where(uniq[pos] == edges, np.clip(net[pos], -127, 127), 0).astype(np.int8)


def _add_dual(where, tok, V, F, lambda_n, lambda_d, weight_power, clamp, threads, boundaries) -> Tokens:
    grid = tok.grid
    dg = dual_grid(grid)
    index, _, off, nrm, _, _, _ = _rows(
        where, V, F, dg, lambda_n, lambda_d, weight_power, clamp, False, threads, boundaries
    )
    cells = tok.cells.astype(np.int64)
    corners = cells[:, None, :] + np.array(np.unravel_index(np.arange(8), (2, 2, 2))).T[None]
    cid = np.ravel_multi_index(tuple(np.moveaxis(corners, 2, 0)), dg.shape)
    pos = np.clip(np.searchsorted(index, cid), 0, max(len(index) - 1, 0))
    mask = (index[pos] == cid) if len(index) else np.zeros(cid.shape, bool)
    doff = np.where(mask[..., None], off[pos] if len(index) else 0.0, 0.0)
    dnrm = np.where(mask[..., None], nrm[pos] if len(index) else 0.0, 0.0)
    # Semi-axes: dual-grid edges between the cell's centre and its neighbours' centres.
    cr = _crossings(V, F, dg, threads)
    nodes = np.repeat(cells[:, None, :] + 1, 6, axis=1)
    axis = np.repeat(np.arange(3), 2)[None].repeat(len(cells), 0)
    nodes[:, 0::2, :] -= np.eye(3, dtype=np.int64)[None]
    edges = _node_ids(dg, axis, nodes)
    semi = _net_signs(dg, cr, edges)
    return dataclasses.replace(tok, dual_offsets=doff, dual_normals=dnrm, dual_mask=mask, semi_axis=semi)


def decode(tokens: Tokens, *, split: str = "normal", tips: bool = True, threads=None) -> Mesh:
    """Dual contouring of Faithful Contour Tokens into a triangle mesh.

    Every row gives a vertex at its anchor. Every lattice edge with a non-zero sign gives
    a quad through the rows of the 4 cells around it, oriented so that its normal points
    along the edge's axis where the sign is +1; the quad is split into two triangles
    along the diagonal chosen by `split`. Each edge is listed by the 4 tokens around it:
    the decoder takes the sign of the sum of their votes (a majority vote, which matters
    for edited tokens). Where cells hold several rows (`anchors_per_cell="components"`),
    the rows voting on an edge are paired across the 4 cells in the order of their
    anchors along the edge, one quad per pair. Edges whose 4 cells are not all present
    (the grid's boundary, removed tokens) give no quad.

    **Arguments:**

    - `tokens`: [`Tokens`][voxax.fc.Tokens].
    - `split`: `"normal"` (the diagonal whose triangles deviate least from the anchors'
      normals), `"short"` (the shorter diagonal) or `"none"` (always the diagonal from
      the first corner).
    - `tips`: also connect the anchors that no quad uses -- cells that a sharp corner
      pokes into without crossing any of their edges, which plain dual contouring cuts
      off -- by splitting the closest output triangle into three around the anchor (only
      where the anchor lies over that triangle's interior; the topology is unchanged).
    - `threads`: worker threads (None: all cores); the result does not depend on it.

    **Returns:** a [`Mesh`][voxax.Mesh] (vertices referenced by faces only, in row order).
    """
    where = "voxax.fc.decode"
    if not isinstance(tokens, Tokens):
        raise TypeError(f"{where}: expected voxax.fc.Tokens, got {type(tokens).__name__}")
    if split not in ("normal", "short", "none"):
        raise ValueError(f"{where}: `split` must be 'normal', 'short' or 'none', got {split!r}")
    grid = tokens.grid
    K = len(tokens)
    P = np.ascontiguousarray(tokens.anchors, np.float64)
    N = np.ascontiguousarray(tokens.normals, np.float64)
    index = np.ascontiguousarray(tokens.index, np.int64)
    signs = np.ascontiguousarray(tokens.edge_signs, np.int8)
    if index.shape != (K,) or P.shape != (K, 3) or N.shape != (K, 3) or signs.shape != (K, 12):
        raise ValueError(f"{where}: inconsistent token fields")
    lib = _lib()
    handle = _VP()
    count = np.zeros(1, np.int64)
    shape = np.ascontiguousarray(grid.shape, np.int64)
    err = _kernels.error_buffer()
    status = lib.voxax_fc_decode(
        index.ctypes.data_as(_I64),
        P.ctypes.data_as(_D),
        N.ctypes.data_as(_D),
        signs.ctypes.data_as(ctypes.POINTER(ctypes.c_int8)),
        K,
        shape.ctypes.data_as(_I64),
        {"normal": 0, "short": 1, "none": 2}[split],
        _kernels.threads(threads),
        ctypes.byref(handle),
        count.ctypes.data_as(_I64),
        err,
        _kernels.ERRLEN,
    )
    if status != 0:
        raise ValueError(f"{where}: " + err.value.decode("utf-8", "replace").removeprefix("voxax: "))
    (tris,) = _copy_out(lib.voxax_fc_triangles, handle, lib.voxax_fc_free_triangles, ((int(count[0]), 3), np.int64))
    used = np.zeros(K, bool)
    used[tris.reshape(-1)] = True
    if tips and len(tris):
        tris, used = _insert_tips(tokens, P, tris, used)
    remap = np.cumsum(used) - 1
    # Every index is a used row by construction: no validation pass over the output.
    return mesh_from_trusted(np.ascontiguousarray(P[used]), remap[tris].astype(np.int32))


def _near_rows(tokens: Tokens, rows) -> np.ndarray:
    """Boolean `(K,)`: the rows in the 27 cells around the cells of `rows`."""
    grid = tokens.grid
    shape = np.asarray(grid.shape, np.int64)
    d = np.stack(np.meshgrid(*[[-1, 0, 1]] * 3, indexing="ij"), -1).reshape(-1, 3)
    cells = (_unravel(tokens.index[rows], grid.shape).astype(np.int64)[:, None, :] + d[None]).reshape(-1, 3)
    cells = cells[np.all((cells >= 0) & (cells < shape), axis=1)]
    lin = np.unique((cells[:, 0] * shape[1] + cells[:, 1]) * shape[2] + cells[:, 2])
    lo = np.searchsorted(tokens.index, lin, side="left")
    hi = np.searchsorted(tokens.index, lin, side="right")
    mark = np.zeros(len(tokens.index) + 1, np.int64)
    np.add.at(mark, lo, 1)
    np.add.at(mark, hi, -1)
    return np.cumsum(mark)[:-1] > 0


def _insert_tips(tokens: Tokens, P, tris, used):
    """Connects the anchors that no quad uses (cells a sharp tip pokes into without
    crossing any of their edges): works on the triangles near them only. `used` marks the
    rows that `tris` uses; returns the new triangles and marks."""
    K = len(tokens)
    todo = np.flatnonzero(~used & ~(np.asarray(tokens.area) == 0))
    if not len(todo):
        return tris, used
    near = _near_rows(tokens, todo)
    ring = near[tris[:, 0]] | near[tris[:, 1]] | near[tris[:, 2]]
    verts = np.zeros(K, bool)
    verts[tris[ring].reshape(-1)] = True
    sub = verts[tris[:, 0]] | verts[tris[:, 1]] | verts[tris[:, 2]]  # near the tips, and their neighbours
    # Work on the vertices of these triangles and the tips only (renumbered in order).
    local = np.union1d(np.unique(tris[sub]), todo)
    lt = np.searchsorted(local, tris[sub])
    new = local[_split_for_tips(P[local], lt, np.searchsorted(local, todo))]
    used[new.reshape(-1)] = True  # the split triangles keep their corners
    return np.concatenate([tris[~sub], new]), used


def _split_for_tips(P, tris, todo, rounds: int = 4):
    """Connects the anchors that no quad uses (cells a sharp tip pokes into without
    crossing any of their edges) to the output: the closest triangle is split into three
    around the anchor where its closest point is interior, or the closest edge and the
    two triangles sharing it into four where it lies on an edge. The topology (Euler
    characteristic, closedness, orientation) is unchanged."""
    from .._spatial import closest_points

    for _ in range(rounds):
        if not len(todo):
            break
        cp = closest_points((P, tris.astype(np.int32)), P[todo])
        zero = cp.barycentric <= 1e-9
        ok = (cp.distance > 0) & (zero.sum(axis=1) <= 1)
        order = np.argsort(cp.distance, kind="stable")
        touched = np.zeros(len(tris), bool)
        nv = np.int64(len(P))
        he = (tris.astype(np.int64) * nv + np.roll(tris, -1, axis=1)).reshape(-1)
        he_order = np.argsort(he, kind="stable")
        he_sorted = he[he_order]

        def faces_with(u, v, he_sorted=he_sorted, he_order=he_order, nv=nv):
            key = u * nv + v
            lo, hi = np.searchsorted(he_sorted, [key, key + 1])
            return (he_order[lo:hi] // 3).tolist()

        new, drop, done = [], [], []
        for q in order:
            if not ok[q]:
                continue
            f = int(cp.face[q])
            x = int(todo[q])
            if touched[f]:
                continue
            a, b, c = (int(v) for v in tris[f])
            if not zero[q].any():
                new += [(a, b, x), (b, c, x), (c, a, x)]
                touched[f] = True
                drop.append(f)
                done.append(x)
                continue
            k = int(np.argmax(zero[q]))  # the edge opposite corner k
            u, v = int(tris[f, (k + 1) % 3]), int(tris[f, (k + 2) % 3])
            w = int(tris[f, k])
            twin = faces_with(v, u)
            if len(twin) != 1 or len(faces_with(u, v)) != 1 or touched[twin[0]]:
                continue
            g = twin[0]
            w2 = [int(y) for y in tris[g] if y != u and y != v][0]
            new += [(u, x, w), (x, v, w), (v, x, w2), (x, u, w2)]
            touched[f] = touched[g] = True
            drop += [f, g]
            done.append(x)
        if not done:
            break
        keep = np.ones(len(tris), bool)
        keep[drop] = False
        tris = np.concatenate([tris[keep], np.asarray(new, tris.dtype).reshape(-1, 3)])
        todo = np.setdiff1d(todo, done)
    return tris


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
            raise ValueError(f"{where}: 'fct69' needs tokens encoded with layout='dual'")
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
        raise ValueError(f"{where}: '{fmt}' needs shape (K, {FORMATS[fmt]}), got {a.shape}")
    if not np.all(np.isfinite(a)):
        raise ValueError(f"{where}: `arr` contains NaN or Inf")
    if fmt == "fct18":
        if index is None:
            raise TypeError(f"{where}: 'fct18' has no index column: pass `index` (K,)")
        idx = np.asarray(index)
        if idx.shape != (len(a),) or idx.dtype.kind not in "iu":
            raise ValueError(f"{where}: `index` must be (K,) integers, got {idx.dtype}{idx.shape}")
        idx = idx.astype(np.int64)
        body = a
    else:
        if np.any(a[:, 0] != np.round(a[:, 0])):
            raise ValueError(f"{where}: the index column must hold integers")
        idx = a[:, 0].astype(np.int64)
        body = a[:, 1:]
    if len(idx) and (idx.min() < 0 or idx.max() >= grid.size):
        raise ValueError(f"{where}: cell indices must lie in [0, {grid.size})")
    if np.any(np.diff(idx) < 0):
        raise ValueError(f"{where}: rows must be sorted by cell index")
    cells = np.stack(np.unravel_index(idx, grid.shape), axis=1)
    h = np.asarray(grid.spacing)
    lo = np.asarray(grid.lower)
    off = body[:, 0:3]
    if anchor_frame == "world":
        off = (off - lo) / h - cells - 0.5
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
        raise ValueError(f"{where}: signs must be integers in [-127, 127]")
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
        raise TypeError(f"voxax.fc.select: expected voxax.fc.Tokens, got {type(tokens).__name__}")
    m = np.asarray(mask)
    if m.dtype == bool:
        if m.shape != (len(tokens),):
            raise ValueError(f"voxax.fc.select: a boolean mask must have shape ({len(tokens)},), got {m.shape}")
        rows = np.flatnonzero(m)
    elif m.dtype.kind in "iu":
        rows = np.unique(m.reshape(-1))
        if len(rows) and (rows[0] < -len(tokens) or rows[-1] >= len(tokens)):
            raise ValueError("voxax.fc.select: row index out of range")
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
    for x in (a, b):
        if not isinstance(x, Tokens):
            raise TypeError(f"voxax.fc.merge: expected voxax.fc.Tokens, got {type(x).__name__}")
    if a.grid != b.grid:
        raise ValueError("voxax.fc.merge: the tokens live on different grids")
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


@dataclasses.dataclass(frozen=True)
class RoundtripReport:
    """What [`roundtrip`][voxax.fc.roundtrip] measured (distances in world units).

    - `grid`, `tokens` (number of rows), `encode_seconds`, `decode_seconds`;
    - `hausdorff`: two-sided Hausdorff distance ([`voxax.metrics.hausdorff`][voxax.metrics.hausdorff]);
    - `chamfer_g2p`: Faithful Contouring's Chamfer (input to output, mean squared);
    - `f_score`: F-score at `threshold`, a fraction in [0, 1];
    - `threshold`: the F-score's distance (by default 0.005 of the grid's longest side: the
      paper's F@0.01 measured on the cube [-1, 1]^3);
    - `manifold`: the output's [`ManifoldReport`][voxax.metrics.ManifoldReport].
    """

    grid: Grid
    tokens: int
    encode_seconds: float
    decode_seconds: float
    hausdorff: float
    chamfer_g2p: float
    f_score: float
    threshold: float
    manifold: object


def roundtrip(
    mesh,
    resolution: int = 512,
    *,
    grid: Grid | None = None,
    samples: int = 100_000,
    threshold: float | None = None,
    **encode_options,
):
    """Encodes `mesh` into tokens at `resolution` and decodes them; measures the result.

    **Arguments:**

    - `mesh`: a `Mesh` (or `(vertices, faces)`).
    - `resolution`: cells along the longest side of `Grid.around(mesh, resolution)`
      (ignored when `grid` is given).
    - `samples`: surface samples per mesh for the metrics.
    - `threshold`: the F-score distance (default: 0.005 of the grid's longest side, the
      paper's F@0.01 on the cube [-1, 1]^3).
    - `**encode_options`: passed to [`encode`][voxax.fc.encode].

    **Returns:** `(Mesh, RoundtripReport)`.
    """
    import time

    from .. import metrics

    where = "voxax.fc.roundtrip"
    V, F = check.mesh_like(where, mesh)
    V = np.asarray(V, np.float64)
    F = np.asarray(F, np.int32)
    if grid is None:
        resolution = check.positive_int(where, "resolution", resolution)
        grid = Grid.around(V, resolution)
    t0 = time.perf_counter()
    tok = encode(V, F, grid, **encode_options)
    t1 = time.perf_counter()
    out = decode(tok)
    t2 = time.perf_counter()
    side = max(u - lo for lo, u in zip(grid.lower, grid.upper))
    thr = 0.005 * side if threshold is None else check.positive_float(where, "threshold", threshold)
    ref = Mesh(V, F)
    if out.n_faces:
        hd = metrics.hausdorff(out, ref, n=samples)
        cd = metrics.chamfer(out, ref, convention="g2p", n=samples, to_surface=True)
        fs = metrics.f_score(out, ref, thr, n=samples, to_surface=True)
    else:
        hd, cd, fs = float("inf"), float("inf"), 0.0
    rep = RoundtripReport(grid, len(tok), t1 - t0, t2 - t1, hd, cd, fs, thr, metrics.manifold_report(out))
    return out, rep
