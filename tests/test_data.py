"""Tests for voxax.data: the procedural demo meshes."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from voxax import data, io

# Demo meshes that deliberately break "one outward, non-overlapping component".
DELIBERATE = {"with_inverted_component", "bent_bar", "overlapping_cubes", "overlapping_squares"}


def crossing_count(vertices, faces, point):
    """Signed count of triangles crossed by the ray from `point` straight up (+z).

    A triangle counts sign(N.z) if its xy-projection contains the point's xy and it lies
    above the point. For a closed surface this is the winding number at the point.
    """
    p = np.asarray(point, dtype=np.float64)
    tri = np.asarray(vertices, dtype=np.float64)[np.asarray(faces)]
    a, b, c = tri[:, 0], tri[:, 1], tri[:, 2]
    nz = (b[:, 0] - a[:, 0]) * (c[:, 1] - a[:, 1]) - (b[:, 1] - a[:, 1]) * (c[:, 0] - a[:, 0])
    ok = nz != 0
    a, b, c, nz = a[ok], b[ok], c[ok], nz[ok]

    def edge(u, v):  # twice the signed area of (u, v, p) in xy
        return (v[:, 0] - u[:, 0]) * (p[1] - u[:, 1]) - (v[:, 1] - u[:, 1]) * (p[0] - u[:, 0])

    w0, w1, w2 = edge(b, c) / nz, edge(c, a) / nz, edge(a, b) / nz
    inside = (w0 > 0) & (w1 > 0) & (w2 > 0)
    z = w0 * a[:, 2] + w1 * b[:, 2] + w2 * c[:, 2]
    hit = inside & (z > p[2])
    return int(np.sum(np.sign(nz[hit])))


def trimesh_closed_oriented(mesh: data.Mesh) -> bool:
    tm = mesh.to_trimesh()
    return bool(tm.is_watertight and tm.is_winding_consistent)


@pytest.fixture(scope="module")
def meshes():
    return {name: data.get(name) for name in data.names()}


# ------------------------------------------------------------------------- the container


def test_mesh_container_basics():
    m = data.cube()
    assert m.vertices.dtype == np.float64 and m.faces.dtype == np.int32
    assert m.dim == 3 and m.n_faces == 12 and m.n_vertices == 8
    v, f = m
    assert v is m.vertices and f is m.faces
    with pytest.raises(dataclasses.FrozenInstanceError):
        m.vertices = np.zeros((3, 3))
    assert m.flipped().signed_volume() == -m.signed_volume()
    np.testing.assert_array_equal(m.flipped().flipped().faces, m.faces)
    assert "n_faces=12" in repr(m)
    np.testing.assert_array_equal(m.bounds, [[-0.5] * 3, [0.5] * 3])
    np.testing.assert_allclose(m.translated((1, 2, 3)).bounds[0], [0.5, 1.5, 2.5])
    both = data.Mesh.concatenate(m, m.translated((3, 0, 0)))
    assert both.n_faces == 24 and both.signed_volume() == pytest.approx(2.0)


def test_mesh_validation():
    with pytest.raises(ValueError, match="shape"):
        data.Mesh(np.zeros((4, 4)), np.zeros((1, 3), int))
    with pytest.raises(ValueError, match="triangles"):
        data.Mesh(np.zeros((4, 3)), np.zeros((1, 2), int))
    with pytest.raises(ValueError, match="indices"):
        data.Mesh(np.zeros((3, 3)), np.array([[0, 1, 3]]))
    with pytest.raises(TypeError):
        data.Mesh(np.zeros((3, 3)), np.array([[0.0, 1.0, 2.0]]))
    with pytest.raises(ValueError, match="2D"):
        data.polygon_square().to_trimesh()
    empty = data.Mesh(np.zeros((0, 3)), np.zeros((0, 3), int))
    assert empty.n_faces == 0 and empty.signed_volume() == 0.0


def test_info_is_read_only():
    m = data.overlapping_cubes()
    with pytest.raises(TypeError):
        m.info["overlap"] = None


# ------------------------------------------------------------------------- 3D meshes


@pytest.mark.parametrize("name", data.names(3))
def test_3d_meshes_closed_and_oriented(meshes, name):
    m = meshes[name]
    assert m.dim == 3 and m.vertices.dtype == np.float64 and m.faces.dtype == np.int32
    assert np.all(np.isfinite(m.vertices))
    assert trimesh_closed_oriented(m)
    assert io.is_watertight(m.vertices, m.faces, strict=True)
    assert m.signed_volume() > 0
    # Everything fits the default grid [-1, 1]^3.
    assert np.abs(m.vertices).max() <= 1.0
    if name not in DELIBERATE and name not in ("large",):
        # Outward orientation, component by component (no inverted parts).
        tm = m.to_trimesh()
        for part in tm.split(only_watertight=False):
            assert part.volume > 0


@pytest.mark.parametrize("name", data.names(2))
def test_2d_polylines_closed_and_ccw(meshes, name):
    m = meshes[name]
    assert m.dim == 2 and m.faces.shape[1] == 2
    assert io.is_watertight(m.vertices, m.faces, strict=True)
    assert m.signed_volume() > 0


def test_box_and_cube_exact():
    m = data.box((0.1, -0.2, 0.3), (0.6, 0.4, 1.0))
    assert m.n_faces == 12
    assert m.signed_volume() == pytest.approx(0.5 * 0.6 * 0.7, rel=1e-14)
    assert data.cube(2.0).signed_volume() == 8.0
    # Each face normal is axis-aligned and points away from the centre.
    tri = m.vertices[m.faces]
    n = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    out = tri.mean(axis=1) - m.vertices.mean(axis=0)
    assert np.all(np.einsum("ij,ij->i", n, out) > 0)
    with pytest.raises(ValueError):
        data.box((0, 0, 0), (1, 0, 1))


@pytest.mark.parametrize("subdivisions", [0, 1, 2, 3])
def test_icosphere(subdivisions):
    r, c = 0.7, np.array([0.1, -0.2, 0.05])
    m = data.icosphere(subdivisions, radius=r, center=c)
    assert m.n_faces == 20 * 4**subdivisions
    assert m.n_vertices == 10 * 4**subdivisions + 2
    np.testing.assert_allclose(np.linalg.norm(m.vertices - c, axis=1), r, rtol=1e-14)
    exact = 4 / 3 * math.pi * r**3
    vol = m.signed_volume()
    assert 0 < vol < exact
    if subdivisions >= 3:
        assert vol == pytest.approx(exact, rel=0.02)
    assert trimesh_closed_oriented(m)


def test_torus():
    m = data.torus(0.6, 0.25, 64, 32)
    assert m.n_faces == 2 * 64 * 32
    assert m.signed_volume() == pytest.approx(2 * math.pi**2 * 0.6 * 0.25**2, rel=0.02)
    with pytest.raises(ValueError):
        data.torus(0.2, 0.3)


def test_bent_bar_self_overlap(meshes):
    m = meshes["bent_bar"]
    assert trimesh_closed_oriented(m)
    assert io.is_watertight(m.vertices, m.faces, strict=True)
    # A single connected surface (not a union of pieces).
    assert len(m.to_trimesh().split(only_watertight=False)) == 1
    p = m.info["overlap_point"]
    assert crossing_count(m.vertices, m.faces, p) == 2
    # On the opposite side of the ring the bar is single: winding 1 at its centre line.
    r0 = 0.45 + 0.06 * 0.5  # centre line radius at half a turn
    z0 = -0.08 * 1.25 / 2 + 0.08 * 0.5
    assert crossing_count(m.vertices, m.faces, [-r0, 1e-3, z0]) == 1
    assert crossing_count(m.vertices, m.faces, [0.0, 0.0, 0.0]) == 0
    # The winding number integrates to the signed volume: about length x cross-section.
    assert m.signed_volume() > 0


def test_bent_bar_no_overlap_when_under_one_turn():
    m = data.bent_bar(turns=0.75)
    assert trimesh_closed_oriented(m)
    assert m.to_trimesh().volume == pytest.approx(m.signed_volume())


def test_inverted_component(meshes):
    m = meshes["with_inverted_component"]
    info = m.info
    k = info["n_faces_inverted"]
    main = data.Mesh(m.vertices, m.faces[:-k])
    inv = data.Mesh(m.vertices, m.faces[-k:])
    assert main.signed_volume() > 0
    assert inv.signed_volume() < 0
    assert inv.signed_volume() == pytest.approx(-4 / 3 * math.pi * info["inverted_radius"] ** 3, rel=0.03)
    assert m.signed_volume() == pytest.approx(main.signed_volume() + inv.signed_volume())
    assert crossing_count(m.vertices, m.faces, info["center"] + 1e-3) == 1
    assert crossing_count(m.vertices, m.faces, info["inverted_center"] + 1e-3) == -1
    # Disjoint and inside the paper's normalization box.
    assert np.abs(m.vertices).max() <= 0.8
    gap = np.linalg.norm(info["inverted_center"] - info["center"]) - info["radius"] - info["inverted_radius"]
    assert gap > 0


def test_overlapping_cubes(meshes):
    m = meshes["overlapping_cubes"]
    assert m.n_faces == 24
    assert m.signed_volume() == pytest.approx(2 * 0.8**3, rel=1e-12)
    lo, hi = m.info["overlap"]
    np.testing.assert_allclose(lo, -0.2)
    np.testing.assert_allclose(hi, 0.2)
    assert crossing_count(m.vertices, m.faces, [0.01, 0.02, 0.03]) == 2
    assert crossing_count(m.vertices, m.faces, [-0.41, -0.42, -0.43]) == 1
    assert crossing_count(m.vertices, m.faces, [0.41, 0.42, 0.43]) == 1
    assert crossing_count(m.vertices, m.faces, [0.41, -0.42, 0.0]) == 0
    assert data.overlapping_cubes((0, 0, 0), (1, 1, 1), (2, 2, 2), (3, 3, 3)).info["overlap"] is None


def test_hand(meshes):
    m = meshes["hand"]
    assert 1200 <= m.n_faces <= 1900  # "the ~1.5K-face mesh"
    assert np.abs(m.vertices).max() == pytest.approx(0.75)
    tm = m.to_trimesh()
    assert len(tm.split(only_watertight=False)) == 1
    # Clearly non-convex: the hull is much larger than the hand.
    assert tm.convex_hull.volume > 1.5 * m.signed_volume()
    assert data.hand(resolution=24).n_faces > m.n_faces


def test_large(meshes):
    m = meshes["large"]
    assert 100_000 <= m.n_faces < 101_000
    assert np.abs(m.vertices).max() == pytest.approx(0.75)
    # Volume of the tube: polygonal cross-section area x centre-line length.
    n_along, n_around, r = m.info["n_along"], m.info["n_around"], m.info["tube_radius"]
    rings = m.vertices.reshape(n_along, n_around, 3)
    centre = rings.mean(axis=1)
    length = np.linalg.norm(np.roll(centre, -1, axis=0) - centre, axis=1).sum()
    area = n_around / 2 * r**2 * math.sin(2 * math.pi / n_around)
    assert m.signed_volume() == pytest.approx(area * length, rel=5e-3)
    small = data.large(5000)
    assert small.n_faces >= 5000
    assert trimesh_closed_oriented(small)


def test_large_million():
    m = data.large(1_000_000)
    assert 1_000_000 <= m.n_faces < 1_005_000
    assert m.signed_volume() > 0


def test_2d_areas():
    assert data.polygon_square((0, 0), (2, 3)).signed_volume() == 6.0
    n, r = 64, 0.5
    assert data.circle_polyline(n, r).signed_volume() == pytest.approx(n / 2 * r**2 * math.sin(2 * math.pi / n))
    s = data.star_polyline(5, 0.7, 0.3)
    assert s.signed_volume() == pytest.approx(5 * 0.7 * 0.3 * math.sin(math.pi / 5))
    # Outward normals (dy, -dx) point away from the centre for the convex ones.
    for m in (data.polygon_square(), data.circle_polyline(16)):
        seg = m.vertices[m.faces]
        d = seg[:, 1] - seg[:, 0]
        normal = np.stack([d[:, 1], -d[:, 0]], 1)
        mid = seg.mean(axis=1)
        assert np.all(np.einsum("ij,ij->i", normal, mid) > 0)
    sq = data.overlapping_squares()
    assert sq.signed_volume() == pytest.approx(2 * 0.64)
    np.testing.assert_allclose(sq.info["overlap"], [[-0.2, -0.2], [0.2, 0.2]])


def test_get_and_names():
    assert set(data.names()) == set(data.names(2)) | set(data.names(3))
    assert "torus" in data.names(3) and "circle_polyline" in data.names(2)
    assert data.get("sphere", subdivisions=1).n_faces == 80
    assert data.get("Bent-Bar", n_along=10, n_around=6).n_faces == 2 * 10 * 6
    assert data.get("circle", n=10).n_faces == 10
    with pytest.raises(ValueError, match="torus"):
        data.get("no such mesh")


@pytest.mark.parametrize("name", ["hand", "bent_bar", "large", "icosphere"])
def test_deterministic(name):
    a, b = data.get(name), data.get(name)
    np.testing.assert_array_equal(a.vertices, b.vertices)
    np.testing.assert_array_equal(a.faces, b.faces)
