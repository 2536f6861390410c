"""The grid's lattice edges: edge ids, the cells around an edge, and the exact crossings of a
mesh with the lattice edges (from `voxax.raster`'s node lines)."""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from .. import raster
from .._grid import Grid
from .._kernels import fc as _kernel
from ._tokens import _QUAD, EDGE_AXIS, EDGE_OFFSETS


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
    return _kernel.node_side(V, F, faces, nodes, axis)


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
