"""Several anchors per cell (`anchors_per_cell="components"`): the rows of each sheet and
their edge signs."""

from __future__ import annotations

import numpy as np

from .._mesh import face_normals
from ._lattice import _lookup
from ._tokens import Tokens


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
