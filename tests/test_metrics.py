"""voxax.metrics against analytic values, brute-force NumPy and trimesh."""

import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest
import trimesh

from voxax import Grid, Mesh, data, metrics


def _pairwise(P, Q):
    return np.sqrt(((P[:, None, :] - Q[None, :, :]) ** 2).sum(-1))


# -- sampling --------------------------------------------------------------------------------


def test_sample_surface_uniform_and_deterministic():
    cube = data.cube(2.0)
    s1 = metrics.sample_surface(cube, 6000, key=3)
    s2 = metrics.sample_surface(cube, 6000, key=3)
    s3 = metrics.sample_surface(cube, 6000, key=4)
    for x, y in zip(s1, s2):
        assert np.array_equal(x, y)
    assert not np.array_equal(s1.points, s3.points)
    # every point on its face: in the face's plane, inside its three edges
    V, F = cube.vertices, cube.faces
    a, b, c = (V[F[s1.faces, k]] for k in range(3))
    n = np.cross(b - a, c - a)
    np.testing.assert_allclose(np.sum((s1.points - a) * n, 1), 0, atol=1e-12)
    for u, v in ((a, b), (b, c), (c, a)):
        assert np.all(np.sum(np.cross(v - u, s1.points - u) * n, 1) >= -1e-12)
    np.testing.assert_allclose(
        s1.normals, n / np.linalg.norm(n, axis=1, keepdims=True), atol=1e-15
    )
    # the six sides get 1/6 each (binomial standard deviation ~ 0.005)
    side = np.argmax(np.abs(s1.points) > 1 - 1e-12, axis=1) * 2 + (
        s1.points.max(1) > 1 - 1e-12
    )
    frac = np.bincount(side, minlength=6) / 6000
    assert np.all(np.abs(frac - 1 / 6) < 0.025)
    # area weighting: two triangles of areas 1 and 3
    V = np.array([[0, 0, 0], [2, 0, 0], [0, 1, 0], [0, 0, 1], [3, 0, 1], [0, 2, 1.0]])
    s = metrics.sample_surface((V, [[0, 1, 2], [3, 4, 5]]), 20000, key=0)
    assert abs(np.mean(s.faces == 1) - 0.75) < 0.015
    # uniform inside a triangle: the mean is the centroid
    np.testing.assert_allclose(s.points[s.faces == 1].mean(0), [1, 2 / 3, 1], atol=0.02)
    # a jax key works and is deterministic
    k = jax.random.key(7)
    assert np.array_equal(
        metrics.sample_surface(cube, 10, k).points,
        metrics.sample_surface(cube, 10, k).points,
    )
    with pytest.raises(ValueError, match="zero area"):
        metrics.sample_surface((np.zeros((3, 3)), [[0, 1, 2]]), 5)


# -- chamfer, hausdorff, f-score ----------------------------------------------------------------


def test_chamfer_conventions_vs_brute_force():
    rng = np.random.default_rng(0)
    P, Q = rng.normal(size=(300, 3)), rng.normal(size=(200, 3)) + 0.3
    D = _pairwise(P, Q)
    dpq, dqp = D.min(1), D.min(0)
    np.testing.assert_allclose(
        metrics.chamfer(P, Q, convention="l2"),
        (dpq**2).sum() + (dqp**2).sum(),
        rtol=1e-12,
    )
    diag = np.linalg.norm(Q.max(0) - Q.min(0))
    np.testing.assert_allclose(
        metrics.chamfer(P, Q, convention="l1_bbox"),
        1000 * (dpq.mean() + dqp.mean()) / diag,
        rtol=1e-12,
    )
    np.testing.assert_allclose(
        metrics.chamfer(P, Q, convention="g2p"), (dqp**2).mean(), rtol=1e-12
    )
    assert metrics.chamfer(P, P, convention="l2") == 0.0
    with pytest.raises(ValueError, match="convention"):
        metrics.chamfer(P, Q, convention="l3")
    with pytest.raises(ValueError, match="NaN"):
        metrics.chamfer(np.full((3, 3), np.nan), Q)


def test_chamfer_on_meshes_to_surface():
    # concentric spheres of radii 1 and 0.9 (fine icospheres): point-to-surface distances
    # are close to 0.1 everywhere
    a, b = data.icosphere(4, radius=1.0), data.icosphere(4, radius=0.9)
    g2p = metrics.chamfer(a, b, convention="g2p", n=3000, to_surface=True)
    assert 0.0097 < g2p < 0.0101
    l1 = metrics.chamfer(a, b, convention="l1_bbox", n=3000, to_surface=True)
    assert abs(l1 - 1000 * 0.2 / (1.8 * math.sqrt(3))) < 2.0
    # the same surface sampled twice: small, and it falls as n grows
    c1 = metrics.chamfer(a, a, convention="l1_bbox", n=1000)
    c2 = metrics.chamfer(a, a, convention="l1_bbox", n=8000)
    assert 0 < c2 < c1
    assert metrics.chamfer(a, a, convention="l1_bbox", n=1000, to_surface=True) < 1e-9
    with pytest.raises(ValueError, match="meshes"):
        metrics.chamfer(np.ones((4, 3)), a, to_surface=True)


def test_hausdorff_analytic():
    # concentric similar icospheres: the farthest points are the outer vertices, at R - r
    a, b = data.icosphere(2, radius=1.0), data.icosphere(2, radius=0.6)
    assert abs(metrics.hausdorff(a, b, n=2000) - 0.4) < 1e-12
    assert metrics.directed_hausdorff(b, a, n=2000) < 0.4
    # a unit cube and the same cube moved by 0.1 along x
    c = data.cube(1.0)
    assert abs(metrics.hausdorff(c, c.translated((0.1, 0, 0)), n=2000) - 0.1) < 1e-12
    assert metrics.hausdorff(c, c, n=500) < 1e-15


def test_hausdorff_vs_brute_force_on_small_meshes():
    # directed Hausdorff over the same samples, with the brute-force distance to every face
    from conftest import brute_distance

    a, b = data.icosphere(1, radius=0.8), data.torus()
    samples = np.concatenate(
        [a.vertices, metrics.sample_surface(a, 500, key=0).points]
    )
    expect = brute_distance(samples, b.vertices, b.faces).max()
    np.testing.assert_allclose(
        metrics.directed_hausdorff(a, b, n=500, key=0), expect, rtol=1e-12
    )


def test_f_score():
    rng = np.random.default_rng(1)
    P, Q = rng.uniform(size=(200, 3)), rng.uniform(size=(150, 3))
    D = _pairwise(P, Q)
    t = 0.1
    prec, rec = np.mean(D.min(1) <= t), np.mean(D.min(0) <= t)
    np.testing.assert_allclose(
        metrics.f_score(P, Q, t), 2 * prec * rec / (prec + rec), rtol=1e-12
    )
    assert metrics.f_score(P, P, 1e-9) == 1.0
    assert metrics.f_score(P, P + 10, 0.1) == 0.0
    with pytest.raises(ValueError, match="threshold"):
        metrics.f_score(P, Q, 0.0)


# -- quality and topology ---------------------------------------------------------------------


def test_triangle_quality():
    rng = np.random.default_rng(2)
    R, _ = np.linalg.qr(rng.normal(size=(3, 3)))
    eq = np.array([[0, 0, 0], [1, 0, 0], [0.5, math.sqrt(3) / 2, 0]]) * 2.7 @ R.T + 5
    right = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0.0]])
    flat = np.array([[0, 0, 0], [1, 0, 0], [2, 0, 0.0]])
    V = np.concatenate([eq, right, flat])
    q = metrics.triangle_quality((V, [[0, 1, 2], [3, 4, 5], [6, 7, 8], [0, 0, 1]]))
    # right isosceles: A = 1/2, p = 1 + 1/sqrt2, e_max = sqrt2 -> (6/sqrt3)(1/2) / (sqrt2 + 1)
    np.testing.assert_allclose(
        q, [1.0, math.sqrt(3) / (math.sqrt(2) + 1), 0.0, 0.0], atol=1e-14
    )
    q = metrics.triangle_quality(data.icosphere(3))
    assert q.min() > 0.8 and q.max() <= 1.0


def _bowtie():
    V = np.array(
        [
            [0, 0, 0],
            [1, 0, 0],
            [0, 1, 0],
            [0, 0, 1],
            [-1, 0, 0],
            [0, -1, 0],
            [0, 0, -1.0],
        ]
    )
    tet = np.array([[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]])
    tet2 = np.array([[0, 4, 5], [0, 6, 4], [0, 5, 6], [4, 6, 5]])
    return Mesh(V, np.concatenate([tet, tet2]))


def test_euler_characteristic():
    assert metrics.euler_characteristic(data.cube()) == 2
    assert metrics.euler_characteristic(data.icosphere(3)) == 2
    assert metrics.euler_characteristic(data.torus()) == 0
    two = Mesh.concatenate(data.icosphere(1), data.icosphere(1).translated((3, 0, 0)))
    assert metrics.euler_characteristic(two) == 4
    for m in (data.hand(8), data.large(3000), data.bent_bar(), _bowtie()):
        tm = trimesh.Trimesh(m.vertices, m.faces, process=False)
        assert metrics.euler_characteristic(m) == tm.euler_number


def test_manifold_report_cases():
    cube = data.cube()
    r = metrics.manifold_report(cube)
    assert (
        r.watertight
        and r.genus == 0
        and r.n_components == 1
        and r.n_boundary_loops == 0
    )
    # one face removed: an open surface with one boundary loop of 3 edges
    r = metrics.manifold_report(Mesh(cube.vertices, cube.faces[1:]))
    assert not r.closed and r.manifold and r.oriented
    assert r.n_boundary_edges == 3 and r.n_boundary_loops == 1 and r.genus is None
    # two opposite faces removed: two loops
    r = metrics.manifold_report(Mesh(cube.vertices, _drop_opposite(cube)))
    assert r.n_boundary_loops == 2
    # one face flipped: three misoriented edges
    f = cube.faces.copy()
    f[0] = f[0, ::-1]
    r = metrics.manifold_report(Mesh(cube.vertices, f))
    assert not r.oriented and r.n_misoriented_edges == 3 and r.closed
    # a duplicated face: three non-manifold edges, one duplicate
    r = metrics.manifold_report(
        Mesh(cube.vertices, np.concatenate([cube.faces, cube.faces[:1, ::-1]]))
    )
    assert (
        r.n_duplicate_faces == 1 and r.n_nonmanifold_edges == 3 and not r.edge_manifold
    )
    # two tetrahedra sharing a vertex: edge-manifold, one non-manifold vertex
    r = metrics.manifold_report(_bowtie())
    assert r.edge_manifold and not r.vertex_manifold and r.n_nonmanifold_vertices == 1
    assert r.n_components == 2 and r.euler_characteristic == 3
    # two cubes sharing an edge: non-manifold edge
    two = _cubes_sharing_edge()
    r = metrics.manifold_report(two)
    assert r.n_nonmanifold_edges == 1
    # degenerate faces
    r = metrics.manifold_report(
        Mesh(cube.vertices, np.concatenate([cube.faces, [[0, 0, 1]]]))
    )
    assert r.n_degenerate_faces == 1
    # torus genus 1; two spheres two components
    assert metrics.manifold_report(data.torus()).genus == 1
    two = Mesh.concatenate(data.icosphere(1), data.icosphere(1).translated((3, 0, 0)))
    r = metrics.manifold_report(two)
    assert r.n_components == 2 and r.genus == 0 and r.watertight


def _drop_opposite(cube):
    # the faces lying in x = -0.5 and x = +0.5
    c = cube.vertices[cube.faces].mean(1)
    keep = np.abs(np.abs(c[:, 0]) - 0.5) > 1e-9
    return cube.faces[keep]


def _cubes_sharing_edge():
    a = data.cube(1.0)
    b = a.translated((1.0, 1.0, 0.0))
    m = Mesh.concatenate(a, b)
    # merge coincident vertices so the shared edge is one edge
    uniq, inv = np.unique(np.round(m.vertices, 12), axis=0, return_inverse=True)
    return Mesh(uniq, inv.reshape(-1)[m.faces])


def test_manifold_report_vs_trimesh_random():
    rng = np.random.default_rng(5)
    for m in (data.hand(8), data.large(3000), data.torus()):
        F = m.faces.copy()
        drop = rng.choice(len(F), 3, replace=False)
        for faces in (F, np.delete(F, drop, axis=0)):
            r = metrics.manifold_report(Mesh(m.vertices, faces))
            tm = trimesh.Trimesh(m.vertices, faces, process=False)
            assert r.watertight == tm.is_watertight
            assert r.oriented == tm.is_winding_consistent
            assert r.n_components == tm.body_count


# -- IoU -------------------------------------------------------------------------------------------


def test_iou_cubes():
    grid = Grid.cube(16)  # h = 0.125: both cubes' faces lie on grid planes
    a = data.cube(1.0)
    b = a.translated((0.25, 0, 0))
    assert abs(float(metrics.iou(a, b, grid)) - 0.6) < 1e-12
    assert abs(float(metrics.iou(a, b, grid, soft=False)) - 0.6) < 1e-12
    assert float(metrics.iou(a, a.translated((1.5, 0, 0)), grid)) == 0.0
    # off the grid planes: soft IoU is the exact volumetric IoU up to the voxel blur
    c = a.translated((0.3, 0.1, 0))
    exact = (0.7 * 0.9) / (2 - 0.7 * 0.9)
    assert abs(float(metrics.iou(a, c, Grid.cube(64))) - exact) < 0.01
    # differentiable in the vertices
    g = jax.grad(lambda v: metrics.iou((v, c.faces), a, grid))(jnp.asarray(c.vertices))
    assert np.all(np.isfinite(g)) and np.abs(g).max() > 0
    with pytest.raises(ValueError, match="threshold"):
        metrics.iou(a, b, grid, soft=False, threshold=1.0)


def test_chamfer_loss_jax():
    rng = np.random.default_rng(9)
    P, Q = rng.normal(size=(150, 3)), rng.normal(size=(90, 3)) + 0.2
    D = _pairwise(P, Q)
    for squared, e in ((True, 2), (False, 1)):
        val = metrics.chamfer_loss(P, Q, squared=squared, chunk_size=64)
        np.testing.assert_allclose(
            val, (D.min(1) ** e).mean() + (D.min(0) ** e).mean(), rtol=1e-12
        )
    # gradient: the nearest-pair formula, 2 (p - q*) / N for the p side
    g = np.asarray(
        jax.grad(lambda x: metrics.chamfer_loss(x, Q, chunk_size=32))(jnp.asarray(P))
    )
    nn_pq, nn_qp = D.argmin(1), D.argmin(0)
    expect = 2 * (P - Q[nn_pq]) / len(P)
    np.add.at(expect, nn_qp, 2 * (P[nn_qp] - Q) / len(Q))
    np.testing.assert_allclose(g, expect, rtol=1e-10, atol=1e-14)
    # samples recomputed from barycentrics are differentiable and equal the points
    s = metrics.sample_surface(data.icosphere(1), 50, key=0)
    V, F = data.icosphere(1)
    np.testing.assert_allclose(
        np.einsum("nk,nkd->nd", s.barycentric, V[F[s.faces]]), s.points, atol=1e-15
    )


def test_unique_rows_is_numpys_unique_along_rows():
    # the packed-key path and the fallback (negative values, keys past 2^62, floats)
    # against np.unique(axis=0): rows, first indices, inverse and counts
    rng = np.random.default_rng(4)
    cases = [rng.integers(0, hi, size=(n, k)) for n, k, hi in ((0, 2, 1), (1, 3, 5), (500, 2, 40), (800, 3, 12))]
    cases += [rng.integers(-5, 5, size=(200, 2)), np.array([[2**40, 1], [0, 2**40], [2**40, 1]]),
              rng.integers(0, 3, size=(50, 2)).astype(np.int32), rng.random((20, 2)).round(1)]
    for a in cases:
        want = np.unique(a, axis=0, return_index=True, return_inverse=True, return_counts=True)
        got = metrics._unique_rows(a, return_index=True, return_inverse=True, return_counts=True)
        for w, g in zip(want, got):
            np.testing.assert_array_equal(np.reshape(g, -1), np.reshape(w, -1))
        assert got[0].dtype == a.dtype and got[0].shape == want[0].shape
        np.testing.assert_array_equal(metrics._unique_rows(a), np.unique(a, axis=0))
