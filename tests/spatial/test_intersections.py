"""The exact triangle-triangle intersection test against an independent exact oracle.

The oracle decides whether two closed triangles meet as a linear feasibility problem in
exact rational arithmetic: is there `(l, m) >= 0` with `sum l = sum m = 1` and
`sum l_i p_i = sum m_j q_j`? By the fundamental theorem of linear programming a feasible
system has a basic feasible solution, so it suffices to try every set of linearly
independent columns. It knows nothing about orientations, projections or degenerate
cases, which the kernel has to handle explicitly.
"""

from __future__ import annotations

import itertools
from fractions import Fraction

import numpy as np
import pytest

import voxax

# -- the oracle -------------------------------------------------------------------------------


def _solve_exact(columns, rhs):
    """The unique solution of `A x = rhs` for the given independent columns, or None when
    the columns are dependent or the system is inconsistent."""
    rows = len(rhs)
    n = len(columns)
    m = [[columns[c][r] for c in range(n)] + [rhs[r]] for r in range(rows)]
    pivot_row = 0
    pivots = []
    for c in range(n):
        p = next((r for r in range(pivot_row, rows) if m[r][c] != 0), None)
        if p is None:
            return None  # dependent columns
        m[pivot_row], m[p] = m[p], m[pivot_row]
        inv = 1 / m[pivot_row][c]
        m[pivot_row] = [x * inv for x in m[pivot_row]]
        for r in range(rows):
            if r != pivot_row and m[r][c] != 0:
                f = m[r][c]
                m[r] = [a - f * b for a, b in zip(m[r], m[pivot_row])]
        pivots.append(pivot_row)
        pivot_row += 1
    if any(m[r][n] != 0 for r in range(pivot_row, rows)):
        return None  # inconsistent
    return [m[r][n] for r in pivots]


def oracle_intersect(t1, t2) -> bool:
    """Exact: do the closed triangles t1, t2 ((3, 3) float arrays) share a point?"""
    t1, t2 = np.asarray(t1, dtype=np.float64), np.asarray(t2, dtype=np.float64)
    if np.any(t1.max(axis=0) < t2.min(axis=0)) or np.any(t2.max(axis=0) < t1.min(axis=0)):
        return False  # separated along an axis
    p = [[Fraction(float(x)) for x in row] for row in np.asarray(t1)]
    q = [[Fraction(float(x)) for x in row] for row in np.asarray(t2)]
    # Columns: l_i -> (p_i, 1, 0), m_j -> (-q_j, 0, 1); right-hand side (0, 0, 0, 1, 1).
    cols = [p[i] + [Fraction(1), Fraction(0)] for i in range(3)]
    cols += [[-x for x in q[j]] + [Fraction(0), Fraction(1)] for j in range(3)]
    rhs = [Fraction(0)] * 3 + [Fraction(1), Fraction(1)]
    for na in range(1, 4):
        for nb in range(1, 4):
            if na + nb > 5:
                continue
            for sa in itertools.combinations(range(3), na):
                for sb in itertools.combinations(range(3, 6), nb):
                    x = _solve_exact([cols[c] for c in sa + sb], rhs)
                    if x is not None and all(v >= 0 for v in x):
                        return True
    return False


# -- random configurations ----------------------------------------------------------------------


def _dyadic(rng, shape, scale=8, denom=64):
    return rng.integers(-scale * denom, scale * denom + 1, size=shape) / denom


def _pair(rng, kind: str):
    """Two triangles (3, 3) of a given kind of configuration (all constructions exact)."""
    t1 = _dyadic(rng, (3, 3))
    t2 = _dyadic(rng, (3, 3))
    if kind == "random_float":
        t1, t2 = rng.normal(size=(3, 3)), rng.normal(size=(3, 3)) * 0.7 + rng.normal(size=3) * 0.5
    elif kind == "random_dyadic":
        pass
    elif kind == "vertex_on_face":
        # a point with dyadic barycentrics (1/4, 1/4, 1/2) in some order
        bary = rng.permutation([0.25, 0.25, 0.5])
        t2[0] = bary @ t1
    elif kind == "vertex_on_edge":
        i = rng.integers(3)
        t2[rng.integers(3)] = (t1[i] + t1[(i + 1) % 3]) / 2
    elif kind == "vertex_on_vertex":
        t2[rng.integers(3)] = t1[rng.integers(3)]
    elif kind == "edge_on_edge":
        i = rng.integers(3)
        x = (t1[i] + t1[(i + 1) % 3]) / 2
        d = _dyadic(rng, 3, scale=2)
        t2[0], t2[1] = x + d, x - d
    elif kind in ("coplanar", "coplanar_touch"):
        o, e1, e2 = t1[0], t1[1] - t1[0], t1[2] - t1[0]
        ab = rng.integers(-4, 9, size=(3, 2)) / 4
        t2 = o + ab[:, :1] * e1 + ab[:, 1:] * e2
        if kind == "coplanar_touch":
            t2[0] = (t1[1] + t1[2]) / 2
    elif kind == "near_touch":
        bary = rng.permutation([0.25, 0.25, 0.5])
        t2[0] = bary @ t1
        k = rng.integers(3)
        t2[0, k] = np.nextafter(t2[0, k], np.inf if rng.random() < 0.5 else -np.inf)
    elif kind == "degenerate_segment":
        d = _dyadic(rng, 3, scale=2)
        t1 = t1[0] + np.array([[0.0], [1.0], [0.5]]) * d
    elif kind == "degenerate_point":
        t1 = np.repeat(t1[:1], 3, axis=0)
        if rng.random() < 0.5:
            t1[:] = rng.permutation([0.25, 0.25, 0.5]) @ t2
    elif kind == "degenerate_both":
        d1, d2 = _dyadic(rng, 3, scale=2), _dyadic(rng, 3, scale=2)
        t1 = t1[0] + np.array([[0.0], [1.0], [-1.0]]) * d1
        base = t1[0] + 0.5 * d1 if rng.random() < 0.6 else t2[0]
        t2 = base + np.array([[0.0], [1.0], [2.0]]) * d2
    elif kind == "identical":
        t2 = t1[rng.permutation(3)]
    elif kind == "small_scale":
        t1, t2 = t1 * 2.0**-40, t2 * 2.0**-40
        t2[0] = rng.permutation([0.25, 0.25, 0.5]) @ t1
    else:
        raise AssertionError(kind)
    return np.asarray(t1, dtype=np.float64), np.asarray(t2, dtype=np.float64)


KINDS = (
    "random_float",
    "random_dyadic",
    "vertex_on_face",
    "vertex_on_edge",
    "vertex_on_vertex",
    "edge_on_edge",
    "coplanar",
    "coplanar_touch",
    "near_touch",
    "degenerate_segment",
    "degenerate_point",
    "degenerate_both",
    "identical",
    "small_scale",
)


def _kernel_pair(t1, t2) -> bool:
    faces = np.array([[0, 1, 2]])
    r = voxax.intersections(t1, faces, other=(t2, faces), threads=1)
    assert r.count in (0, 1)
    return r.count == 1


def test_random_pairs_match_the_exact_oracle():
    rng = np.random.default_rng(20261128)
    verdicts = {k: [0, 0] for k in KINDS}
    mismatches = []
    for n in range(1000):
        kind = KINDS[n % len(KINDS)]
        t1, t2 = _pair(rng, kind)
        if rng.random() < 0.5:
            t1, t2 = t2, t1
        expected = oracle_intersect(t1, t2)
        got = _kernel_pair(t1, t2)
        verdicts[kind][int(expected)] += 1
        if got != expected:
            mismatches.append((kind, t1.tolist(), t2.tolist(), expected))
    assert not mismatches, mismatches[:3]
    # The configurations really are mixed: each touching kind has both verdicts or hits.
    assert sum(v[1] for v in verdicts.values()) > 300
    assert sum(v[0] for v in verdicts.values()) > 250
    for kind in ("vertex_on_face", "vertex_on_edge", "edge_on_edge", "coplanar_touch", "identical"):
        assert verdicts[kind][1] > 0 and verdicts[kind][0] == 0, (kind, verdicts[kind])
    for kind in ("coplanar", "degenerate_segment", "degenerate_both", "near_touch"):
        assert verdicts[kind][0] > 0 and verdicts[kind][1] > 0, (kind, verdicts[kind])


def test_soup_self_test_matches_brute_force():
    rng = np.random.default_rng(7)
    n = 30
    tris = rng.uniform(-1, 1, size=(n, 1, 3)) + rng.normal(scale=0.35, size=(n, 3, 3))
    # A few exact touches between different triangles.
    for k in range(0, 10, 2):
        tris[k + 1, 0] = np.array([0.25, 0.25, 0.5]) @ tris[k]
    vertices = tris.reshape(-1, 3)
    faces = np.arange(3 * n).reshape(n, 3)
    expected = sorted((i, j) for i in range(n) for j in range(i + 1, n) if oracle_intersect(tris[i], tris[j]))
    for threads in (1, 3):
        r = voxax.intersections(vertices, faces, threads=threads)
        assert [tuple(p) for p in r.pairs.tolist()] == expected
        assert r.count == len(expected)
    assert len(expected) > 5


def test_two_mesh_test_matches_brute_force():
    rng = np.random.default_rng(3)
    a = rng.uniform(-1, 1, size=(18, 1, 3)) + rng.normal(scale=0.3, size=(18, 3, 3))
    b = rng.uniform(-1, 1, size=(20, 1, 3)) + rng.normal(scale=0.3, size=(20, 3, 3))
    fa, fb = np.arange(54).reshape(18, 3), np.arange(60).reshape(20, 3)
    r = voxax.intersections(a.reshape(-1, 3), fa, other=(b.reshape(-1, 3), fb))
    expected = [(i, j) for i in range(18) for j in range(20) if oracle_intersect(a[i], b[j])]
    assert [tuple(p) for p in r.pairs.tolist()] == expected and len(expected) > 3


# -- adjacency ---------------------------------------------------------------------------------


def _mesh_count(vertices, faces):
    return voxax.intersections(np.asarray(vertices, float), np.asarray(faces)).count


def test_shared_edge_folds_only_when_coplanar_on_one_side():
    u, v = [0, 0, 0], [1, 0, 0]
    # Hinged at the edge u-v: flat (opposite sides), bent, folded flat onto itself.
    assert _mesh_count([u, v, [0, 1, 0], [0, -1, 0]], [[0, 1, 2], [1, 0, 3]]) == 0
    assert _mesh_count([u, v, [0, 1, 0], [0, -1, 1]], [[0, 1, 2], [1, 0, 3]]) == 0
    assert _mesh_count([u, v, [0, 1, 0], [0.5, 2, 0]], [[0, 1, 2], [1, 0, 3]]) == 1
    # A nearly folded hinge is not a fold.
    assert _mesh_count([u, v, [0, 1, 0], [0.5, 2, 1e-12]], [[0, 1, 2], [1, 0, 3]]) == 0


def test_shared_vertex_meets_beyond_it():
    s = [0, 0, 0]
    a1, a2 = [1, 0, 0], [0, 1, 0]
    # A fan around s: no overlap; a triangle through the first one; one lying on an edge.
    assert _mesh_count([s, a1, a2, [-1, 0, 0], [0, -1, 0]], [[0, 1, 2], [0, 3, 4]]) == 0
    assert _mesh_count([s, a1, a2, [0.3, 0.3, 1], [0.3, 0.3, -1]], [[0, 1, 2], [0, 3, 4]]) == 1
    assert _mesh_count([s, a1, a2, [2, 0, 0], [0, 0, 1]], [[0, 1, 2], [0, 3, 4]]) == 1
    # Coplanar, overlapping cones at s; coplanar, touching only at s.
    assert _mesh_count([s, a1, a2, [1, 2, 0], [2, 1, 0]], [[0, 1, 2], [0, 3, 4]]) == 1
    assert _mesh_count([s, a1, a2, [-1, 2, 0], [-2, 1, 0]], [[0, 1, 2], [0, 3, 4]]) == 0
    # Perpendicular, touching only at s.
    assert _mesh_count([s, a1, a2, [0, 0, 1], [-1, -1, 1]], [[0, 1, 2], [0, 3, 4]]) == 0


def test_duplicates_degenerates_and_welding():
    v = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [2, 2, 2]], float)
    # The same face twice (either orientation) is reported.
    assert _mesh_count(v, [[0, 1, 2], [0, 2, 1]]) == 1
    # A degenerate face sharing a vertex is never reported; away from the others it is a segment.
    assert _mesh_count(v, [[0, 1, 2], [0, 0, 3]]) == 0
    seg = np.array([[0.2, 0.2, -1], [0.2, 0.2, 1], [0.2, 0.2, 0.5], [5, 5, 5]])
    assert _mesh_count(np.vstack([v, seg]), [[0, 1, 2], [4, 5, 6]]) == 1
    # Unwelded copies of shared vertices are merged, so a flat fan stays clean ...
    fan = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 0], [0, 1, 0], [-1, 0, 0]], float)
    assert _mesh_count(fan, [[0, 1, 2], [3, 4, 5]]) == 0
    # ... unless welding is off, and then the shared edge is a touch.
    assert voxax.intersections(fan, np.array([[0, 1, 2], [3, 4, 5]]), weld=False).count == 1


def test_closed_meshes_and_a_known_overlap():
    for mesh in (voxax.data.icosphere(), voxax.data.torus(), voxax.data.hand(), voxax.data.large(5000)):
        assert voxax.intersections(mesh).count == 0
    bar = voxax.data.bent_bar()
    r = voxax.intersections(bar)
    assert r.count > 0
    # The intersecting faces are the ones around the known overlap.
    near = np.linalg.norm(bar.vertices[bar.faces[r.faces]].mean(axis=1) - bar.info["overlap_point"], axis=1)
    assert near.max() < 0.5


def test_deterministic_across_threads():
    m = voxax.data.bent_bar()
    base = voxax.intersections(m, threads=1).pairs
    for t in (2, 5, 16):
        assert np.array_equal(voxax.intersections(m, threads=t).pairs, base)


@pytest.mark.parametrize(
    "vertices, faces, error, match",
    [
        (np.array([[0, 0, np.nan], [1, 0, 0], [0, 1, 0]]), [[0, 1, 2]], ValueError, "NaN"),
        (np.eye(3), [[0, 1, 3]], ValueError, "out of range"),
        (np.eye(3), [[0, 1, -1]], ValueError, "out of range"),
        (np.eye(3) * 1e80, [[0, 1, 2]], ValueError, "magnitude"),
        (np.eye(3) * 1e-60, [[0, 1, 2]], ValueError, "magnitude"),
        (np.eye(3), [[0.0, 1.0, 2.0]], TypeError, "integer"),
        (np.eye(3)[:, :2], [[0, 1, 2]], ValueError, "shape"),
        (np.eye(3), [[0, 1]], ValueError, "shape"),
        (np.array([["a", "b", "c"]]), [[0, 0, 0]], TypeError, "float"),
    ],
)
def test_bad_input(vertices, faces, error, match):
    with pytest.raises(error, match=match):
        voxax.intersections(vertices, np.asarray(faces))


def test_empty_and_open_meshes():
    assert voxax.intersections(np.zeros((0, 3)), np.zeros((0, 3), int)).count == 0
    assert voxax.intersections(np.eye(3), np.zeros((0, 3), int), other=voxax.data.cube()).count == 0
    # An open mesh (a cube with one face missing) is tested like any other.
    cube = voxax.data.cube()
    assert voxax.intersections(cube.vertices, cube.faces[:-1]).count == 0
