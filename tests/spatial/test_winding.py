"""Tests of `voxax.winding.winding_number`: exact generalised winding numbers at points."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import voxax
from voxax import winding_number


def _uniform(rng, lo, hi, n, d=3):
    return rng.uniform(lo, hi, size=(n, d))


def test_box_inside_outside(rng):
    m = voxax.data.box()
    inside = _uniform(rng, -0.45, 0.45, 200)
    outside = rng.uniform(-2, 2, size=(400, 3))
    outside = outside[np.abs(outside).max(axis=1) > 0.55]
    np.testing.assert_allclose(winding_number(m.vertices, m.faces, inside), 1.0, atol=1e-12)
    np.testing.assert_allclose(winding_number(m.vertices, m.faces, outside), 0.0, atol=1e-12)


def test_overlapping_cubes_and_inverted_parts(rng):
    m = voxax.data.overlapping_cubes()
    both = _uniform(rng, -0.19, 0.19, 100)
    only_a = _uniform(rng, -0.59, -0.21, 100)
    np.testing.assert_allclose(winding_number(m.vertices, m.faces, both), 2.0, atol=1e-12)
    np.testing.assert_allclose(winding_number(m.vertices, m.faces, only_a), 1.0, atol=1e-12)

    m = voxax.data.with_inverted_component(subdivisions=2)
    dirs = rng.normal(size=(100, 3))
    dirs *= rng.uniform(0, 0.8, size=(100, 1)) / np.linalg.norm(dirs, axis=1, keepdims=True)
    main = m.info["center"] + m.info["radius"] * dirs
    inv = m.info["inverted_center"] + m.info["inverted_radius"] * dirs
    np.testing.assert_allclose(winding_number(m.vertices, m.faces, main), 1.0, atol=1e-10)
    np.testing.assert_allclose(winding_number(m.vertices, m.faces, inv), -1.0, atol=1e-10)


def test_half_on_the_faces_of_a_cube(rng):
    m = voxax.data.box()
    pts = []
    for axis in range(3):
        for side in (-0.5, 0.5):
            p = rng.uniform(-0.45, 0.45, size=(20, 3))
            p[:, axis] = side
            pts.append(p)
    pts = np.concatenate(pts)
    np.testing.assert_allclose(winding_number(m.vertices, m.faces, pts), 0.5, atol=1e-6)
    # 2D: on the edges of a square.
    sq = voxax.data.polygon_square()
    p = np.stack([rng.uniform(-0.45, 0.45, 20), np.full(20, 0.5)], axis=1)
    np.testing.assert_allclose(winding_number(sq.vertices, sq.faces, p), 0.5, atol=1e-6)
    np.testing.assert_allclose(winding_number(sq.vertices, sq.faces, p[:, ::-1]), 0.5, atol=1e-6)


@pytest.mark.parametrize(
    "name, n, kwargs",
    [
        ("star_polyline", 64, {}),
        ("overlapping_squares", 50, {}),
        ("torus", 20, {"n_major": 24, "n_minor": 12}),
        ("overlapping_cubes", 10, {}),
    ],
)
def test_agrees_with_voxelize_away_from_the_surface(name, n, kwargs):
    # A voxel whose box-filtered value is an integer is not crossed by the surface, so the
    # winding number at its centre is that integer.
    m = voxax.data.get(name, **kwargs)
    grid = voxax.Grid.cube(n + 1, dim=m.dim)  # odd count: centres off the mesh's planes
    W = np.asarray(voxax.voxelize(m.vertices, m.faces, grid))
    clean = np.abs(W - np.round(W)) < 1e-12
    assert clean.sum() > 0.5 * W.size
    w = np.asarray(winding_number(m.vertices, m.faces, grid.centers()))
    np.testing.assert_allclose(w[clean], W[clean], atol=1e-6)
    if name.startswith("overlapping"):
        assert np.isclose(w, 2.0).sum() > 0


def test_agrees_with_the_ray_count(rng):
    v, f = voxax.data.star_polyline().vertices, voxax.data.star_polyline().faces
    p = rng.uniform(-1, 1, size=(500, 2))
    ray = voxax.reference.winding_number_ray(v, f, p)
    np.testing.assert_allclose(winding_number(v, f, p), ray, atol=1e-9)


def test_shapes_chunks_dtypes_jit_vmap(rng):
    m = voxax.data.icosphere(1)
    pts = rng.uniform(-1, 1, size=(4, 5, 3))
    w = winding_number(m.vertices, m.faces, pts)
    assert w.shape == (4, 5) and w.dtype == jnp.float64
    w7 = winding_number(m.vertices, m.faces, pts, chunk_size=7)  # 20 points: 3 chunks, padded
    np.testing.assert_allclose(w7, w, atol=1e-13)
    w32 = winding_number(m.vertices.astype(np.float32), m.faces, pts.astype(np.float32), chunk_size=3)
    assert w32.dtype == jnp.float32
    np.testing.assert_allclose(w32, w, atol=1e-5)
    wj = jax.jit(lambda v, p: winding_number(v, m.faces, p, chunk_size=6))(m.vertices, pts)
    np.testing.assert_allclose(wj, w, atol=1e-13)
    wv = jax.vmap(lambda s: winding_number(m.vertices * s, m.faces, pts))(jnp.array([1.0, 2.0]))
    np.testing.assert_allclose(wv[0], w, atol=1e-13)
    assert winding_number(m.vertices, m.faces, np.zeros((0, 3))).shape == (0,)


def _fd_check(f, args, eps=1e-6, rtol=1e-6):
    """Compares jax.grad of a scalar f with central finite differences in every input entry."""
    grads = jax.jit(jax.grad(f, argnums=tuple(range(len(args)))))(*args)
    fj = jax.jit(f)
    for i, (x, g) in enumerate(zip(args, grads)):
        basis = np.eye(x.size).reshape((x.size,) + x.shape)

        def shifted(e, i=i):
            return fj(*[a + e if j == i else a for j, a in enumerate(args)])

        fd = (jax.vmap(shifted)(eps * basis) - jax.vmap(shifted)(-eps * basis)) / (2 * eps)
        np.testing.assert_allclose(np.asarray(g).reshape(-1), fd, rtol=rtol, atol=rtol)


def test_gradients_of_open_surfaces():
    # An open surface has a smooth winding number: autodiff must match finite differences,
    # also through the chunked map (with rematerialisation).
    tri = np.array([[0.0, 0.0, 0.0], [1.0, 0.1, 0.0], [0.2, 0.9, 0.3]])
    faces = np.array([[0, 1, 2]])
    pts = np.array([[0.3, 0.3, 0.5], [0.4, -0.2, -0.3], [1.0, 1.0, 1.0]])
    _fd_check(lambda v, p: jnp.sum(winding_number(v, faces, p, chunk_size=2) ** 2), (tri, pts))
    seg = np.array([[0.0, 0.0], [1.0, 0.2], [0.3, 1.0]])
    sfaces = np.array([[0, 1], [1, 2]])
    _fd_check(lambda v, p: jnp.sum(jnp.sin(winding_number(v, sfaces, p))), (seg, np.array([[0.2, 0.5], [2.0, 1.0]])))
    # A closed mesh: w is constant away from the surface, its gradients vanish (and are finite).
    m = voxax.data.box()
    gv, gp = jax.grad(lambda v, p: winding_number(v, m.faces, p).sum(), argnums=(0, 1))(
        jnp.asarray(m.vertices), jnp.array([[0.1, 0.2, 0.3], [0.5, 0.0, 0.0]])
    )
    assert np.all(np.isfinite(gv)) and np.all(np.isfinite(gp))
    assert np.abs(gp[0]).max() < 1e-12
    gv = jax.grad(lambda v: winding_number(v, m.faces, jnp.array([[0.1, 0.2, 0.3]])).sum())(jnp.asarray(m.vertices))
    assert np.abs(gv).max() < 1e-12


def test_bad_input():
    m = voxax.data.box()
    with pytest.raises(ValueError, match="points"):
        winding_number(m.vertices, m.faces, np.zeros((3, 2)))
    with pytest.raises(ValueError, match="face indices"):
        winding_number(m.vertices, m.faces + 8, np.zeros((3, 3)))
    with pytest.raises(TypeError):
        winding_number(m.vertices.astype(int), m.faces, np.zeros((3, 3)))
    with pytest.raises(ValueError, match="segments"):
        winding_number(np.zeros((3, 2)), m.faces, np.zeros((3, 2)))
