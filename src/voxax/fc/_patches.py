"""The surface patches of a cell, from its 12 edge signs alone.

Dual contouring with one vertex per cell glues together the separate sheets that cross one
cell (a thin part, two parts closer than a cell), and the output gets edges with four faces.
Its manifold form gives the cell one vertex per patch instead: the crossed edges of a cell
are joined on each of the cell's 6 faces as marching cubes joins them (two crossed edges of
a face form one segment; with four, every corner whose winding number is above its two
neighbours' is cut off by the segment of its two edges), and each connected set of edges is
a patch. The rule reads only the face's own 4 signs, so the two cells of a face join its
edges alike: every segment is an edge of exactly two quads, and a closed mesh decodes to a
closed 2-manifold. Faces with 1 or 3 crossed edges (open meshes) join all of them.
"""

from __future__ import annotations

import numpy as np

from ._tokens import EDGE_AXIS, EDGE_OFFSETS


def _cell_faces():
    """`(6, 4)` edges of each cell face in cyclic order, and `(6, 4, 2)` whether corner k (between
    edges k and k + 1) is the lower end of each of its two edges."""
    lower = EDGE_OFFSETS
    upper = EDGE_OFFSETS + np.eye(3, dtype=np.int64)[EDGE_AXIS]
    edges, ends = [], []
    for a in range(3):
        for v in (0, 1):
            on = [e for e in range(12) if lower[e, a] == v and upper[e, a] == v]
            ring = [on[0]]  # cyclic order: each next edge shares a corner with the last one
            while len(ring) < 4:
                last = ring[-1]
                ring.append(next(e for e in on if e not in ring and _shared(lower, upper, last, e) is not None))
            corner_ends = []
            for k in range(4):
                e0, e1 = ring[k], ring[(k + 1) % 4]
                c = _shared(lower, upper, e0, e1)
                corner_ends.append((np.array_equal(lower[e0], c), np.array_equal(lower[e1], c)))
            edges.append(ring)
            ends.append(corner_ends)
    return np.array(edges), np.array(ends)


def _shared(lower, upper, e0, e1):
    for p in (lower[e0], upper[e0]):
        if np.array_equal(p, lower[e1]) or np.array_equal(p, upper[e1]):
            return p
    return None


_FACE_EDGES, _LOWER_END = _cell_faces()


def patch_labels(signs: np.ndarray) -> np.ndarray:
    """`(K, 12)` int8: the patch of each crossed edge of each row (0, 1, ... in order of the
    patches' lowest edges), -1 where the edge's sign is 0."""
    S = np.asarray(signs, np.int8)
    crossed = S != 0
    label = np.where(crossed, np.arange(12, dtype=np.int8)[None], np.int8(12))
    joins = []  # (edge i, edge j, (K,) mask) to join
    for f in range(6):
        ring = _FACE_EDGES[f]
        c = crossed[:, ring]
        n = c.sum(axis=1)
        s = S[:, ring].astype(np.int64)
        # Height of each face corner over its neighbours along each of its two edges.
        high = np.zeros((len(S), 4), bool)
        consistent = np.ones(len(S), bool)
        for k in range(4):
            h0 = np.where(_LOWER_END[f, k, 0], s[:, k], -s[:, k])
            h1 = np.where(_LOWER_END[f, k, 1], s[:, (k + 1) % 4], -s[:, (k + 1) % 4])
            high[:, k] = (h0 > 0) & (h1 > 0)
            consistent &= np.sign(h0) == np.sign(h1)
        four = n == 4
        cut = four & consistent & (high.sum(axis=1) == 2)
        for k in range(4):
            joins.append((ring[k], ring[(k + 1) % 4], cut & high[:, k]))
        every = (n == 2) | (n == 3) | (four & ~cut)
        for i in range(4):
            for j in range(i + 1, 4):
                joins.append((ring[i], ring[j], every & c[:, i] & c[:, j]))
    for _ in range(12):
        changed = False
        for i, j, m in joins:
            lo = np.minimum(label[:, i], label[:, j])
            for e in (i, j):
                upd = m & (label[:, e] != lo)
                if upd.any():
                    label[upd, e] = lo[upd]
                    changed = True
        if not changed:
            break
    # Renumber: 0, 1, ... in order of the lowest edge of each patch.
    out = np.full(S.shape, -1, np.int8)
    rank = np.zeros(len(S), np.int8)
    for e in range(12):
        new = crossed[:, e] & (label[:, e] == e)
        out[new, e] = rank[new]
        rank += new
    root = np.where(crossed, label, 0).astype(np.int64)
    out = np.where(crossed, np.take_along_axis(out, root, axis=1), -1).astype(np.int8)
    return out


def split_patches(tok, V, F, cr, lambda_n, lambda_d, weight_power, threads):
    """`tok` (one row per cell) with the rows of cells crossed by several patches replaced by
    one row per patch (component 0, 1, ... in patch order), each with the signs of its own
    edges. A patch's anchor minimizes the encoder's QEF over the pieces, in its cell, of the
    faces that cross its edges (exact pieces, `voxax.fc.pieces`); where that leaves the cell
    it is their mean centroid (inside the closed cell), and a patch without such pieces takes
    the mean of its crossings."""
    from .._kernels import fc as _kernel
    from ._lattice import _token_edges
    from ._tokens import Tokens

    # Two patches need 3 crossed edges each: only rows with 6 or more can have several.
    rows = np.flatnonzero(np.count_nonzero(tok.edge_signs, axis=1) >= 6)
    labels = np.full(tok.edge_signs.shape, -1, np.int8)
    labels[rows] = patch_labels(tok.edge_signs[rows])
    count = labels.max(axis=1).astype(np.int64) + 1
    multi = np.flatnonzero(count >= 2)
    if not len(multi):
        return tok
    grid = tok.grid
    # The rows to make: (multi row, patch).
    owner = np.repeat(multi, count[multi])
    patch = (np.arange(len(owner)) - np.repeat(np.cumsum(count[multi]) - count[multi], count[multi])).astype(np.int8)
    edges = _token_edges(grid, tok.cells[multi])  # (M, 12)
    new_signs = np.where(labels[owner] == patch[:, None], tok.edge_signs[owner], 0).astype(np.int8)
    # The crossings of each new row's edges.
    order = np.argsort(cr.edge, kind="stable")
    sorted_edge = cr.edge[order]
    m_of = np.repeat(np.arange(len(multi)), count[multi])
    r_idx, e_idx = np.nonzero(new_signs != 0)
    eid = edges[m_of[r_idx], e_idx]
    a, b = np.searchsorted(sorted_edge, eid, "left"), np.searchsorted(sorted_edge, eid, "right")
    n = b - a
    xr = np.repeat(r_idx, n)  # the new row of each crossing
    xc = order[np.repeat(a - np.cumsum(n) + n, n) + np.arange(n.sum())]  # the crossing
    cell_of = tok.index[owner]
    # The pieces of the crossing faces, in the rows' cells.
    faces = np.unique(cr.face[xc])
    pc, pf, pa, pcen = _kernel.encode_pieces("voxax.fc.encode", V, F[faces], grid.lower, grid.upper, grid.shape,
                                             threads)  # fmt: skip
    pf = faces[pf]
    # Row of each piece: the new row of its cell whose crossings hold its face (the first).
    nf = np.int64(max(len(F), 1))
    rkey = cell_of[xr] * nf + cr.face[xc]
    ko = np.lexsort((xr, rkey))
    rkey_s, xr_s = rkey[ko], xr[ko]
    pkey = pc * nf + pf
    at = np.clip(np.searchsorted(rkey_s, pkey), 0, max(len(rkey_s) - 1, 0))
    hit = (rkey_s[at] == pkey) if len(rkey_s) else np.zeros(len(pkey), bool)
    prow = xr_s[at[hit]]
    pa, pcen, pfh = pa[hit], pcen[hit], pf[hit]
    off, nrm, area = _patch_anchors(tok, owner, (prow, pa, pcen, pfh), (xr, xc), cr, V, F, lambda_n, lambda_d,
                                    weight_power)  # fmt: skip
    keep = np.ones(len(tok), bool)
    keep[multi] = False
    index = np.concatenate([tok.index[keep], cell_of])
    comp = np.concatenate([tok.component[keep], patch.astype(np.int32)])
    o = np.lexsort((comp, index))
    cat = [
        (tok.offsets[keep], off),
        (tok.normals[keep], nrm),
        (tok.edge_signs[keep], new_signs),
        (tok.area[keep], area),
    ]
    off, nrm, signs, area = (np.concatenate(p)[o] for p in cat)
    return Tokens(grid, index[o], off, nrm, signs, comp[o], area)


def _patch_anchors(tok, owner, pieces, crossings, cr, V, F, lambda_n, lambda_d, weight_power):
    """The offsets, normals and areas of the new rows (`owner`: the row each replaces) from
    their pieces `(row, area, centroid, face)` and their crossings `(row, crossing)`."""
    from .._mesh import face_normals

    prow, pa, pcen, pfh = pieces
    xr, xc = crossings
    grid = tok.grid
    h, lo = np.asarray(grid.spacing), np.asarray(grid.lower)
    R = len(owner)
    cells = tok.cells[owner].astype(np.float64)
    centre = lo + (cells + 0.5) * h
    u = (pcen - centre[prow]) / h  # piece centroids in cell units
    fn = face_normals(V, F)
    nl = fn[pfh] * h
    nl /= np.maximum(np.linalg.norm(nl, axis=1, keepdims=True), 1e-300)
    w = pa**weight_power if weight_power else np.ones(len(pa))
    S0 = np.bincount(prow, w, minlength=R)
    M = np.zeros((R, 3, 3))
    rhs = np.zeros((R, 3))
    np.add.at(M, prow, (lambda_n * w)[:, None, None] * nl[:, :, None] * nl[:, None, :])
    nnu = np.einsum("pi,pj,pj->pi", nl, nl, u)
    np.add.at(rhs, prow, (w[:, None] * (lambda_d * u + lambda_n * nnu)))
    M += (lambda_d * S0)[:, None, None] * np.eye(3)
    Sc = np.zeros((R, 3))
    np.add.at(Sc, prow, w[:, None] * u)
    has = S0 > 0
    off = np.zeros((R, 3))
    if has.any():
        off[has] = np.linalg.solve(M[has], rhs[has][..., None])[..., 0]
        mean = Sc[has] / S0[has, None]
        out = np.any(np.abs(off[has]) > 0.5, axis=1)
        off[np.flatnonzero(has)[out]] = mean[out]
    if (~has).any():  # no piece of positive area: the mean of the crossings
        sx = np.zeros((R, 3))
        np.add.at(sx, xr, cr.point[xc])
        cnt = np.bincount(xr, minlength=R)
        pts = sx / np.maximum(cnt, 1)[:, None]
        off[~has] = (pts[~has] - centre[~has]) / h
    off = np.clip(off, -0.5, 0.5)
    area = np.bincount(prow, pa, minlength=R)
    sn = np.zeros((R, 3))
    np.add.at(sn, prow, w[:, None] * fn[pfh])
    np.add.at(sn, xr, np.where(has[xr][:, None], 0.0, fn[cr.face[xc]]))
    ln = np.linalg.norm(sn, axis=1, keepdims=True)
    nrm = np.where(ln > 0, sn / np.where(ln > 0, ln, 1), tok.normals[owner])
    return off, nrm, area
