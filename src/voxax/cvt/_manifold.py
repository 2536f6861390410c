"""The 2-manifold step's parts: the defective edges of a triangulation, and the
regularisation balls placed on them."""

from __future__ import annotations

import numpy as np

__all__ = ["Balls", "problem_edges"]


def problem_edges(faces: np.ndarray, n: int) -> np.ndarray:
    """Undirected edges `(E, 2)` with other than two triangles, and the edges at vertices
    whose triangles do not form one fan."""
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    if len(faces) == 0:
        return np.zeros((0, 2), np.int64)
    f = faces.astype(np.int64)
    e = np.sort(np.concatenate([f[:, [0, 1]], f[:, [1, 2]], f[:, [2, 0]]]), axis=1)
    ukey, count = np.unique(e[:, 0] * n + e[:, 1], return_counts=True)  # 1D keys: sorted like the rows
    uniq = np.stack([ukey // n, ukey % n], axis=1)
    bad = [uniq[count != 2]]
    # fans: nodes (face, corner); corners of one vertex joined across shared edges
    nf = len(f)
    corner_v = f.ravel()
    node = np.arange(3 * nf)
    pairs = []
    for c in range(3):
        for d in (1, 2):  # the two edges at corner c: (v, f[:, c + d])
            other = f[:, (c + d) % 3]
            key = corner_v[c::3] * n + other
            pairs.append((key, node[c::3]))
    key = np.concatenate([p[0] for p in pairs])
    nd = np.concatenate([p[1] for p in pairs])
    order = np.argsort(key, kind="stable")
    key, nd = key[order], nd[order]
    same = key[1:] == key[:-1]
    a, b = nd[:-1][same], nd[1:][same]
    g = coo_matrix((np.ones(len(a)), (a, b)), shape=(3 * nf, 3 * nf))
    _, label = connected_components(g, directed=False)
    fans = np.unique(corner_v * (3 * nf) + label)  # distinct (vertex, fan) pairs
    per_vertex = np.bincount(fans // (3 * nf), minlength=n)
    nonmanifold = np.nonzero(per_vertex > 1)[0]
    if len(nonmanifold):
        bad.append(uniq[np.isin(uniq[:, 0], nonmanifold) | np.isin(uniq[:, 1], nonmanifold)])
    if not sum(len(b) for b in bad):
        return np.zeros((0, 2), np.int64)
    key = np.unique(np.concatenate([b[:, 0] * n + b[:, 1] for b in bad]))
    return np.stack([key // n, key % n], axis=1)


class Balls:
    """Regularisation balls: placed on problem edges, grown when hit again (paper 4.4)."""

    def __init__(self):
        self.center = np.zeros((0, 3))
        self.radius = np.zeros(0)
        self.rmax = np.zeros(0)
        self.rinc = np.zeros(0)

    def add(self, seeds: np.ndarray, edges: np.ndarray, d: float) -> None:
        growing = self.radius < self.rmax
        new_c, new_r, new_max = [], [], []
        grown = np.zeros(len(self.radius), bool)
        for i, j in edges:
            a, b = seeds[i], seeds[j]
            length = float(np.linalg.norm(b - a))
            if length == 0:
                continue
            if growing.any():
                # distance from the segment to the growing balls' centres
                ab = b - a
                t = np.clip((self.center - a) @ ab / (ab @ ab), 0, 1)
                dist = np.linalg.norm(a + t[:, None] * ab - self.center, axis=1)
                hit = growing & (dist < self.radius)
                if hit.any():
                    grown |= hit
                    continue
            count = max(1, int(np.ceil(0.5 * np.min(np.abs(b - a)) / d)))
            for k in range(count):
                new_c.append(a + (k + 0.5) / count * (b - a))
                new_r.append(length / 2)
                new_max.append(length)
        self.radius = np.where(grown, np.minimum(self.radius + self.rinc, self.rmax), self.radius)
        if new_c:
            self.center = np.concatenate([self.center, np.array(new_c)])
            self.radius = np.concatenate([self.radius, new_r])
            self.rmax = np.concatenate([self.rmax, new_max])
            self.rinc = np.concatenate([self.rinc, np.array(new_max) / 20])

    def __len__(self):
        return len(self.radius)
