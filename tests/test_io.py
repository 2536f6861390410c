"""Tests for voxax.io: loading, saving, normalizing, conversions, watertightness."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh

from voxax import data, io

# ------------------------------------------------------------------------- round trips


@pytest.mark.parametrize("ext", ["ply", "obj", "off"])
def test_round_trip_preserves_vertices_and_faces(tmp_path, ext):
    m = data.torus(n_major=12, n_minor=8)
    path = tmp_path / f"torus.{ext}"
    io.save(m, path)
    back = io.load(path)
    assert isinstance(back, data.Mesh)
    np.testing.assert_array_equal(back.faces, m.faces)
    tol = 0.0 if ext == "ply" else 1e-12
    np.testing.assert_allclose(back.vertices, m.vertices, rtol=0, atol=tol)
    assert io.is_watertight(back.vertices, back.faces, strict=True)


def test_round_trip_accepts_trimesh_and_tuple(tmp_path):
    m = data.icosphere(1)
    io.save(m.to_trimesh(), tmp_path / "a.ply")
    io.save((m.vertices, m.faces), str(tmp_path / "b.ply"))
    for name in ("a.ply", "b.ply"):
        back = io.load(tmp_path / name)
        np.testing.assert_array_equal(back.vertices, m.vertices)
        np.testing.assert_array_equal(back.faces, m.faces)


def test_load_stl_merges_triangle_soup(tmp_path):
    m = data.icosphere(2)
    path = tmp_path / "s.stl"
    io.save(m, path)
    soup = io.load(path, merge=False)
    assert soup.n_vertices == 3 * m.n_faces
    assert not io.is_watertight(soup.vertices, soup.faces)
    merged = io.load(path)
    assert merged.n_vertices == m.n_vertices
    assert io.is_watertight(merged.vertices, merged.faces, strict=True)
    assert merged.signed_volume() == pytest.approx(m.signed_volume(), rel=1e-6)


def test_load_scene_concatenates_with_transforms(tmp_path):
    scene = trimesh.Scene()
    scene.add_geometry(data.cube().to_trimesh(), node_name="a")
    shift = np.eye(4)
    shift[:3, 3] = [3.0, 0.0, 0.0]
    scene.add_geometry(data.icosphere(1, 0.5).to_trimesh(), node_name="b", transform=shift)
    mirror = np.diag([-1.0, 1.0, 1.0, 1.0])
    mirror[:3, 3] = [-3.0, 0.0, 0.0]
    scene.add_geometry(data.box((0, 0, 0), (1, 2, 1)).to_trimesh(), node_name="c", transform=mirror)
    path = tmp_path / "scene.glb"
    scene.export(path)
    m = io.load(path)
    assert m.n_faces == 12 + 80 + 12
    expected = 1.0 + data.icosphere(1, 0.5).signed_volume() + 2.0
    assert m.signed_volume() == pytest.approx(expected, rel=1e-5)  # glb stores float32
    assert io.is_watertight(m.vertices, m.faces, strict=True)
    assert m.bounds[1][0] == pytest.approx(3.5, abs=1e-5)
    assert m.bounds[0][0] == pytest.approx(-4.0, abs=1e-5)


def test_load_without_triangles_fails_clearly(tmp_path):
    path = tmp_path / "points.obj"
    path.write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\n")
    with pytest.raises(ValueError, match="no triangles"):
        io.load(path)


def test_save_rejects_2d(tmp_path):
    with pytest.raises(ValueError, match="3D"):
        io.save(data.polygon_square(), tmp_path / "sq.ply")


# ------------------------------------------------------------------------- normalize


@pytest.mark.parametrize("name", ["torus", "hand", "overlapping_cubes", "star_polyline"])
def test_normalize(name):
    m = data.get(name).translated((0.3, -2.0) if data.get(name).dim == 2 else (0.3, -2.0, 5.0))
    n, centre, scale = io.normalize(m, return_transform=True)
    assert np.abs(n.vertices).max() == pytest.approx(0.8, rel=1e-15)
    np.testing.assert_allclose(n.bounds.sum(axis=0), 0.0, atol=1e-14)
    np.testing.assert_allclose(n.vertices, (m.vertices - centre) * scale, atol=1e-15)
    np.testing.assert_array_equal(n.faces, m.faces)
    assert n.signed_volume() == pytest.approx(m.signed_volume() * scale**m.dim, rel=1e-12)
    assert np.abs(io.normalize(m, 0.5).vertices).max() == pytest.approx(0.5)


def test_normalize_accepts_trimesh_and_tuple():
    m = data.box((1, 1, 1), (3, 2, 2))
    a = io.normalize(m.to_trimesh())
    b = io.normalize((m.vertices, m.faces))
    np.testing.assert_allclose(a.vertices, b.vertices)
    np.testing.assert_allclose(a.bounds, [[-0.8, -0.4, -0.4], [0.8, 0.4, 0.4]])
    assert io.normalize is io.normalize
    with pytest.raises(ValueError):
        io.normalize((np.ones((3, 3)), np.array([[0, 1, 2]])))


# ------------------------------------------------------------------------- as_arrays


def test_as_arrays():
    m = data.cube()
    v, f = io.as_arrays(m)
    assert v is m.vertices and f is m.faces
    v, f = io.as_arrays(m.to_trimesh())
    assert v.dtype == np.float64 and f.dtype == np.int32
    np.testing.assert_array_equal(v, m.vertices)
    v32, f = io.as_arrays((m.vertices.astype(np.float32), m.faces.astype(np.int64)))
    assert v32.dtype == np.float32 and f.dtype == np.int32
    v, f = io.as_arrays(([[0, 0], [1, 0], [0, 1]], [[0, 1], [1, 2], [2, 0]]))
    assert v.dtype == np.float64 and f.shape == (3, 2)
    batch = np.stack([m.vertices, m.vertices + 1])
    v, f = io.as_arrays((batch, m.faces))
    assert v.shape == (2, 8, 3)


def test_as_arrays_errors():
    with pytest.raises(TypeError):
        io.as_arrays("cube")
    with pytest.raises(ValueError, match="triangles"):
        io.as_arrays((np.zeros((4, 3)), np.zeros((2, 2), int)))
    with pytest.raises(ValueError, match="shape"):
        io.as_arrays((np.zeros((4, 4)), np.zeros((2, 3), int)))
    with pytest.raises(ValueError, match="indices"):
        io.as_arrays((np.zeros((4, 3)), np.array([[0, 1, 4]])))
    with pytest.raises(TypeError):
        io.as_arrays((np.zeros((4, 3)), np.zeros((2, 3))))


def test_as_arrays_passes_jax_arrays_through():
    jnp = pytest.importorskip("jax.numpy")
    m = data.cube()
    v = jnp.asarray(m.vertices, dtype=jnp.float32)
    out_v, out_f = io.as_arrays((v, m.faces))
    assert out_v is v
    assert out_f.dtype == np.int32


# ------------------------------------------------------------------------- is_watertight


def test_is_watertight_3d():
    m = data.cube()
    assert io.is_watertight(m.vertices, m.faces)
    assert io.is_watertight(m.vertices, m.faces, strict=True)
    assert not io.is_watertight(m.vertices, m.faces[1:])  # a hole
    bad = m.faces.copy()
    bad[0] = bad[0, ::-1]  # one face flipped
    assert not io.is_watertight(m.vertices, bad)
    assert io.is_watertight(m.vertices, m.faces[:, ::-1])  # all flipped: still closed
    padded = np.concatenate([m.faces, np.zeros((5, 3), np.int32)])  # batch padding
    assert io.is_watertight(m.vertices, padded, strict=True)
    assert io.is_watertight(np.zeros((0, 3)), np.zeros((0, 3), int))


def test_is_watertight_non_manifold_but_closed():
    # Two cubes sharing one edge (common vertices): closed, but the edge has four faces.
    a = data.box((0, 0, 0), (1, 1, 1))
    b = data.box((1, 1, 0), (2, 2, 1))
    both = data.Mesh.concatenate(a, b)
    vertices, inverse = np.unique(both.vertices, axis=0, return_inverse=True)
    faces = inverse.reshape(-1)[both.faces]
    assert len(vertices) == 14
    assert io.is_watertight(vertices, faces)
    assert not io.is_watertight(vertices, faces, strict=True)


def test_is_watertight_2d():
    m = data.polygon_square()
    assert io.is_watertight(m.vertices, m.faces, strict=True)
    assert not io.is_watertight(m.vertices, m.faces[1:])
    bad = m.faces.copy()
    bad[0] = bad[0, ::-1]
    assert not io.is_watertight(m.vertices, bad)
    # Figure eight: two squares sharing a vertex.
    v = np.array([[0, 0], [1, 0], [1, 1], [0, 1], [2, 1], [2, 2], [1, 2]], float)
    f = np.array([[0, 1], [1, 2], [2, 3], [3, 0], [2, 4], [4, 5], [5, 6], [6, 2]])
    assert io.is_watertight(v, f)
    assert not io.is_watertight(v, f, strict=True)


def test_is_watertight_errors():
    m = data.cube()
    with pytest.raises(ValueError, match="do not match"):
        io.is_watertight(m.vertices[:, :2], m.faces)
    with pytest.raises(ValueError, match="indices"):
        io.is_watertight(m.vertices[:4], m.faces)
    with pytest.raises(ValueError):
        io.is_watertight(m.vertices, m.faces[:, :1])


@pytest.mark.parametrize("name", data.names())
def test_demo_meshes_watertight(name):
    m = data.get(name)
    assert io.is_watertight(m.vertices, m.faces, strict=True)
