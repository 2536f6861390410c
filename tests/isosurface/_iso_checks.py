"""Independent mesh checks for the iso-surface tests (plain NumPy, no voxax code)."""

from __future__ import annotations

import numpy as np


def closed_report(vertices, faces) -> dict:
    """Closedness, orientation, manifoldness, duplicates and Euler characteristic of a triangle mesh."""
    V = len(vertices)
    F = np.asarray(faces, np.int64)
    report = {}
    report["degenerate_indices"] = int(
        np.sum((F[:, 0] == F[:, 1]) | (F[:, 1] == F[:, 2]) | (F[:, 0] == F[:, 2]))
    )
    key = np.sort(F, axis=1)
    key = (key[:, 0] * V + key[:, 1]) * V + key[:, 2]
    report["duplicate_faces"] = len(F) - len(np.unique(key))
    directed = np.concatenate([F[:, [0, 1]], F[:, [1, 2]], F[:, [2, 0]]])
    code = directed[:, 0] * V + directed[:, 1]
    rev = directed[:, 1] * V + directed[:, 0]
    report["repeated_directed_edges"] = len(code) - len(np.unique(code))
    report["unmatched_edges"] = int(np.sum(~np.isin(rev, code)))
    report["unreferenced_vertices"] = V - len(np.unique(F))
    undirected = np.unique(
        np.minimum(directed[:, 0], directed[:, 1]) * V
        + np.maximum(directed[:, 0], directed[:, 1])
    )
    report["euler"] = V - len(undirected) + len(F)
    # Vertex manifoldness: rotating around vertex a moves from face (a, b, c) to the face
    # holding the directed edge (a, c). On a manifold every vertex has one such orbit.
    bad = -1
    if report["repeated_directed_edges"] == 0 and report["unmatched_edges"] == 0:
        from scipy.sparse import coo_matrix
        from scipy.sparse.csgraph import connected_components

        order = np.argsort(code)
        sorted_codes = code[order]
        # corner (f, i) sits at F[f, i]; the directed edge F[f, i] -> F[f, i + 1] is index i * nf + f
        a = F.T.reshape(-1)  # vertex of corner k = i * nf + f
        c = np.roll(F, 1, axis=1).T.reshape(-1)  # F[f, i - 1] = F[f, i + 2]
        target = a * V + c
        pos = np.searchsorted(sorted_codes, target)
        nxt = order[pos]  # edge index i * nf + f, which is also that face's corner at a
        graph = coo_matrix(
            (np.ones(len(a)), (np.arange(len(a)), nxt)), shape=(len(a), len(a))
        )
        n_orbits = connected_components(graph, directed=True, connection="weak")[0]
        bad = n_orbits - len(np.unique(F))
    report["nonmanifold_vertices"] = bad
    return report


def assert_closed_manifold(vertices, faces, euler=None):
    r = closed_report(vertices, faces)
    assert len(faces) > 0
    assert r["degenerate_indices"] == 0, r
    assert r["duplicate_faces"] == 0, r
    assert r["repeated_directed_edges"] == 0, r
    assert r["unmatched_edges"] == 0, r
    assert r["unreferenced_vertices"] == 0, r
    assert r["nonmanifold_vertices"] == 0, r
    if euler is not None:
        assert r["euler"] == euler, r
    return r


def signed_volume(vertices, faces) -> float:
    v = np.asarray(vertices, np.float64)
    a, b, c = (v[np.asarray(faces)[:, i]] for i in range(3))
    return float(np.sum(np.einsum("ij,ij->i", a, np.cross(b, c))) / 6.0)


def area(vertices, faces) -> float:
    v = np.asarray(vertices, np.float64)
    a, b, c = (v[np.asarray(faces)[:, i]] for i in range(3))
    return float(np.sum(np.linalg.norm(np.cross(b - a, c - a), axis=1)) / 2.0)


def brute_force_vertices(values, lower, spacing, level):
    """Every crossed centre-to-centre edge, sorted by (lower cell, axis), interpolated in float64.

    Only edges that belong to at least one cube are kept (all of them when every axis has
    at least 2 cells).
    """
    f = np.asarray(values, np.float64)
    d = f.ndim
    pos = f >= level
    ids, pts = [], []
    centres = np.stack(
        np.meshgrid(
            *[lower[a] + (np.arange(f.shape[a]) + 0.5) * spacing[a] for a in range(d)],
            indexing="ij",
        ),
        -1,
    )
    lin = np.arange(f.size).reshape(f.shape)
    for axis in range(d):
        a_sl = tuple(slice(0, -1) if ax == axis else slice(None) for ax in range(d))
        b_sl = tuple(slice(1, None) if ax == axis else slice(None) for ax in range(d))
        crossed = pos[a_sl] != pos[b_sl]
        fa, fb = f[a_sl][crossed], f[b_sl][crossed]
        t = (level - fa) / (fb - fa)
        pa, pb = centres[a_sl][crossed], centres[b_sl][crossed]
        pts.append(pa + t[:, None] * (pb - pa))
        ids.append(lin[a_sl][crossed] * d + axis)
    ids = np.concatenate(ids)
    order = np.argsort(ids, kind="stable")
    return np.concatenate(pts)[order]
