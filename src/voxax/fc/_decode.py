"""Decoding: dual contouring of token rows into a triangle mesh, and the anchors of sharp tips."""

from __future__ import annotations

import numpy as np

from .. import _validate as check
from .._kernels import fc as _kernel
from .._mesh import Mesh, mesh_from_trusted
from ._tokens import Tokens, _unravel, check_tokens


def decode(tokens: Tokens, *, split: str = "normal", tips: bool = True, threads=None) -> Mesh:
    """Dual contouring of Faithful Contour Tokens into a triangle mesh.

    Every row gives a vertex at its anchor. Every lattice edge with a non-zero sign gives
    a quad through the rows of the 4 cells around it, oriented so that its normal points
    along the edge's axis where the sign is +1; the quad is split into two triangles
    along the diagonal chosen by `split`. Each edge is listed by the 4 tokens around it:
    the decoder takes the sign of the sum of their votes (a majority vote, which matters
    for edited tokens). Where cells hold several rows (surface patches, or
    `anchors_per_cell="components"`),
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

    **Raises:** `TypeError` or `ValueError` naming the field for tokens that are not what
    [`encode`][voxax.fc.encode] makes (edited ones are checked field by field: integer sorted
    `index` in the grid, finite `offsets` in `[-0.5, 0.5]`, finite `normals`, integer
    `edge_signs` in `[-127, 127]`, matching shapes).
    """
    where = "voxax.fc.decode"
    tokens = check_tokens(where, tokens)
    if not isinstance(split, str) or split not in ("normal", "short", "none"):
        raise ValueError(f"{where}: `split` must be 'normal', 'short' or 'none', got {split!r}")
    check.host_threads(where, threads)
    grid = tokens.grid
    K = len(tokens)
    P = np.ascontiguousarray(tokens.anchors, np.float64)
    N, index, signs = tokens.normals, tokens.index, tokens.edge_signs
    split_code = {"normal": 0, "short": 1, "none": 2}[split]
    tris = _kernel.decode(where, index, P, N, signs, grid.shape, split_code, threads)
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
