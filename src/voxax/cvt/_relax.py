"""The finishing passes of a remeshed surface: projection onto the fragments' tangent
planes and tangential relaxation."""

from __future__ import annotations

import numpy as np

from ._fragments import Fragments
from ._manifold import problem_edges

__all__ = ["FLOOR", "project", "relax"]

#: a relaxation move that would push a triangle's quality below this (or below its
#: quality before the step, if lower) is undone
FLOOR = 0.2


def project(points: np.ndarray, frag: Fragments) -> np.ndarray:
    from .._spatial import nearest_neighbors

    _, idx = nearest_neighbors(frag.points, points, k=1)
    i = idx[:, 0]
    x, n = frag.points[i], frag.normals[i]
    return points - np.sum((points - x) * n, axis=1, keepdims=True) * n


def relax(verts: np.ndarray, faces: np.ndarray, frag: Fragments, steps: int, floor: float = 0.0) -> np.ndarray:
    """Tangential smoothing of a mesh on the sampled surface: each step moves every vertex
    to the mean of its neighbours within its tangent plane (the area-weighted normal), then
    onto the tangent plane of its nearest fragment; a vertex whose move would turn one of
    its triangles over, or push its quality below `floor` (or below its quality before the
    step, if lower), stays. Vertices of edges with other than two triangles stay."""
    from ..metrics import triangle_quality

    v = np.array(verts, np.float64)
    n = len(v)
    f = faces.astype(np.int64)
    if steps <= 0 or len(f) == 0:
        return v
    fixed = np.zeros(n, bool)
    fixed[problem_edges(faces, n).ravel()] = True
    src = np.concatenate([f[:, 0], f[:, 1], f[:, 2], f[:, 1], f[:, 2], f[:, 0]])
    dst = np.concatenate([f[:, 1], f[:, 2], f[:, 0], f[:, 0], f[:, 1], f[:, 2]])
    degree = np.bincount(src, minlength=n).astype(np.float64)
    degree[degree == 0] = 1.0

    def face_normals(x):
        return np.cross(x[f[:, 1]] - x[f[:, 0]], x[f[:, 2]] - x[f[:, 0]])

    for _ in range(steps):
        fn = face_normals(v)
        oriented = np.any(fn != 0, axis=1)
        vn = np.stack([np.bincount(f.ravel(), np.repeat(fn[:, a], 3), minlength=n) for a in range(3)], axis=1)
        vn /= np.maximum(np.linalg.norm(vn, axis=1, keepdims=True), 1e-300)
        mean = np.stack([np.bincount(src, v[dst, a], minlength=n) for a in range(3)], axis=1) / degree[:, None]
        d = mean - v
        d -= np.sum(d * vn, axis=1, keepdims=True) * vn
        d[fixed] = 0.0
        new = project(v + d, frag)
        new[fixed] = v[fixed]
        q0 = triangle_quality((v, f)) if floor > 0 else None
        for _ in range(20):  # undo moves that turn a triangle over (neighbours may need it too)
            flipped = (np.sum(face_normals(new) * fn, axis=1) <= 0) & oriented
            if floor > 0:  # or that crush a triangle below the floor
                flipped |= triangle_quality((new, f)) < np.minimum(floor, q0)
            if not flipped.any():
                break
            back = np.unique(f[flipped])
            new[back] = v[back]
        v = new
    return v
