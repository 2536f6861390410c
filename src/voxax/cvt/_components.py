"""The separate pieces of a sampled surface, and seeds enough on each of them to close it."""

from __future__ import annotations

import numpy as np

from ._fragments import Fragments

__all__ = ["components", "cover_components"]


def components(frag: Fragments, threads=None) -> tuple[int, np.ndarray]:
    """Connected pieces of the sampled surface: fragments closer than twice the grid
    spacing are joined (neighbouring fragments of a connected surface are within
    `sqrt(2)` spacings). **Returns:** `(count, label per fragment)`."""
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    from .._spatial import nearest_neighbors

    k = min(12, frag.size - 1)
    if k < 1:
        return 1, np.zeros(frag.size, np.int64)
    d, idx = nearest_neighbors(frag.points, frag.points, k=k + 1, threads=threads)
    near = (d[:, 1:] < 2.0 * frag.spacing) & (idx[:, 1:] >= 0)
    rows = np.repeat(np.arange(frag.size), k).reshape(-1, k)[near]
    g = coo_matrix((np.ones(len(rows)), (rows, idx[:, 1:][near])), shape=(frag.size, frag.size))
    return connected_components(g, directed=False)


def cover_components(frag: Fragments, seeds: np.ndarray, threads=None, least: int = 4) -> tuple[np.ndarray, int]:
    """Gives every piece of the surface with at least one seed's share of the area four
    seeds or more (the fewest that close a surface), taken from the pieces with the most
    seeds (their seeds closest to another seed first); placed by farthest-point sampling
    from the fragment nearest the piece's centroid. Deterministic. **Returns:**
    `(seeds, moved)`."""
    from .._spatial import nearest_neighbors

    count, label = components(frag, threads)
    if count < 2:
        return seeds, 0
    n = len(seeds)
    area = np.bincount(label, frag.weights, minlength=count)
    share = area / area.sum() * n
    _, idx = nearest_neighbors(frag.points, seeds, k=1, threads=threads)
    owner = label[idx[:, 0]]  # the piece of each seed's nearest fragment
    have = np.bincount(owner, minlength=count)
    need = np.nonzero((share >= 1.0) & (have < least) & (np.bincount(label, minlength=count) >= 4))[0]
    if len(need) == 0:
        return seeds, 0
    s = np.array(seeds, np.float64)
    # donors are taken where seeds crowd most: by their distance to the nearest other seed
    crowd, _ = nearest_neighbors(s, s, k=2, threads=threads)
    by_crowd = np.lexsort((np.arange(n), crowd[:, 1]))
    moved = 0
    for c in need[np.argsort(-area[need], kind="stable")]:
        pts = frag.points[label == c]
        want = least - int(have[c])
        # donors: seeds of the piece with the most seeds to spare, the most crowded first
        donors = []
        for _ in range(want):
            spare = have - least
            spare[c] = -1
            d = int(np.argmax(spare))
            if spare[d] <= 0:
                break
            mine = by_crowd[owner[by_crowd] == d]
            mine = mine[~np.isin(mine, donors)]
            donors.append(int(mine[0]))
            have[d] -= 1
        taken = s[owner == c]
        pick = []
        if len(taken):
            gap = np.min(np.sum((pts[:, None, :] - taken[None]) ** 2, axis=2), axis=1)
        else:  # start at the fragment nearest the piece's centroid
            centroid = np.average(pts, axis=0, weights=frag.weights[label == c])
            pick = [int(np.argmin(np.sum((pts - centroid) ** 2, axis=1)))]
            gap = np.sum((pts - pts[pick[0]]) ** 2, axis=1)
        while len(pick) < len(donors):
            j = int(np.argmax(gap))
            pick.append(j)
            gap = np.minimum(gap, np.sum((pts - pts[j]) ** 2, axis=1))
        for i, j in zip(donors, pick):
            s[i] = pts[j]
            owner[i] = c
        have[c] += len(donors)
        moved += len(donors)
    return s, moved
