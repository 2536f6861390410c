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


# --- `accuracy`: the error-bounded far-field expansion of the eager path -------------------


def _solid_angle_sum(v, f, p, block=256):
    """The winding numbers by the plain solid-angle sum, in numpy (an oracle independent of
    the kernels): Van Oosterom and Strackee's tan(Omega / 2), face by face."""
    tri = np.asarray(v, np.float64)[np.asarray(f)]
    out = []
    for s in range(0, len(p), block):
        q = np.asarray(p[s : s + block], np.float64)[:, None, None, :]
        a, b, c = (tri[None, :, k, :] - q[:, :, 0, :] for k in range(3))
        la, lb, lc = (np.linalg.norm(x, axis=-1) for x in (a, b, c))
        num = np.einsum("pfi,pfi->pf", a, np.cross(b, c))
        den = la * lb * lc + (a * b).sum(-1) * lc + (a * c).sum(-1) * lb + (b * c).sum(-1) * la
        out.append(np.where(num == 0, 0.0, 2 * np.arctan2(num, den)).sum(-1) / (4 * np.pi))
    return np.concatenate(out)


def _open_and_soup(rng):
    m = voxax.data.large(2000)
    v = np.asarray(m.vertices, np.float64)
    f = np.asarray(m.faces)[: len(m.faces) * 9 // 10]  # 10% of the faces cut: open
    sv = rng.uniform(-1, 1, size=(900, 3))
    sv = np.concatenate([sv, sv[:300] + 1e-9])  # also near-duplicate vertices
    sf = rng.integers(0, len(sv), size=(600, 3))  # random triangles (some degenerate)
    sf = np.concatenate([sf, rng.choice(len(sv), size=(40, 3), replace=False)])
    return (v, f), (sv, sf)


def _points_near_and_far(rng, v, n=300):
    lo, hi = v.min(0), v.max(0)
    near = v[rng.integers(0, len(v), n)] + rng.normal(scale=1e-3 * np.abs(hi - lo).max(), size=(n, 3))
    box = rng.uniform(lo - 0.2 * (hi - lo), hi + 0.2 * (hi - lo), size=(n, 3))
    far = rng.normal(size=(n, 3))
    far *= (np.abs(hi - lo).max() * rng.uniform(1.5, 20, size=(n, 1))) / np.linalg.norm(far, axis=1, keepdims=True)
    return np.concatenate([near, v[:20], box, far])


def test_accuracy_bounds_the_error_on_open_surfaces_and_soups(rng):
    for v, f in _open_and_soup(rng):
        p = _points_near_and_far(rng, v)
        exact = _solid_angle_sum(v, f, p)
        np.testing.assert_allclose(winding_number(v, f, p), exact, atol=1e-11)
        errors = {}
        for eps in (0.3, 1e-2, 1e-4, 1e-7):
            w = np.asarray(winding_number(v, f, p, accuracy=eps))
            err = np.abs(w - exact)
            errors[eps] = err.max()
            assert err.max() <= eps + 1e-11, (eps, err.max(), np.argmax(err))
        # The expansion is used (the bound is not met vacuously by the exact sum): the loose
        # budgets give errors well above rounding, the tight ones much smaller.
        assert errors[0.3] > 1e-6 and errors[1e-2] > 1e-9, errors
        assert errors[1e-7] < errors[0.3]


def test_accuracy_mesh_scales_and_thread_counts(rng):
    (v, f), (sv, sf) = _open_and_soup(rng)
    p = _points_near_and_far(rng, v, 100)
    exact = _solid_angle_sum(v, f, p)
    for s in (1e-60, 1.0, 1e60):  # scale-free: no under- or overflow of the moments
        w = np.asarray(winding_number(v * s, f, p * s, accuracy=1e-3))
        assert np.abs(w - exact).max() <= 1e-3 + 1e-11, s
    # the same bits for any thread count (and an error within the bound)
    q = _points_near_and_far(rng, sv, 700)  # more than one chunk of points
    w1 = np.asarray(winding_number(sv, sf, q, accuracy=1e-3, threads=1))
    for t in (2, 3):
        np.testing.assert_array_equal(np.asarray(winding_number(sv, sf, q, accuracy=1e-3, threads=t)), w1)
    assert np.abs(w1 - _solid_angle_sum(sv, sf, q)).max() <= 1e-3 + 1e-11


def test_accuracy_none_zero_closed_meshes_and_the_jax_path(rng):
    (v, f), _ = _open_and_soup(rng)
    p = _points_near_and_far(rng, v, 50)
    w = np.asarray(winding_number(v, f, p))
    np.testing.assert_array_equal(np.asarray(winding_number(v, f, p, accuracy=None)), w)
    np.testing.assert_array_equal(np.asarray(winding_number(v, f, p, accuracy=0)), w)
    np.testing.assert_array_equal(np.asarray(winding_number(v, f, p, accuracy=np.float32(0.0))), w)
    # A closed mesh keeps its exact rays: integers (1/2 on the faces), whatever the accuracy.
    m = voxax.data.icosphere(2)
    q = rng.uniform(-1.5, 1.5, size=(200, 3))
    np.testing.assert_array_equal(
        np.asarray(winding_number(m.vertices, m.faces, q, accuracy=0.4)), np.asarray(winding_number(m.vertices, m.faces, q))
    )
    # The JAX path (traced, batched, 2D) is exact, which meets any accuracy.
    wj = jax.jit(lambda x: winding_number(v, f, x, accuracy=0.5))(p)
    np.testing.assert_allclose(wj, w, atol=1e-10)
    sq = voxax.data.polygon_square()
    p2 = rng.uniform(-1, 1, size=(20, 2))
    np.testing.assert_array_equal(
        np.asarray(winding_number(sq.vertices, sq.faces, p2, accuracy=0.1)), np.asarray(winding_number(sq.vertices, sq.faces, p2))
    )


@pytest.mark.parametrize(
    "value, error, match",
    [
        (True, TypeError, "`accuracy`"),
        ("0.1", TypeError, "`accuracy`"),
        (1j, TypeError, "`accuracy`"),
        (np.array([0.1, 0.2]), TypeError, "`accuracy`"),
        ([0.1], TypeError, "`accuracy`"),
        (float("nan"), ValueError, "`accuracy`"),
        (float("inf"), ValueError, "`accuracy`"),
        (-1e-3, ValueError, ">= 0"),
    ],
)
def test_accuracy_bad_values(value, error, match):
    m = voxax.data.box()
    with pytest.raises(error, match=match):
        winding_number(m.vertices, m.faces[:10], np.zeros((2, 3)), accuracy=value)


def test_accuracy_traced_is_refused():
    m = voxax.data.box()
    with pytest.raises(TypeError, match="traced"):
        jax.jit(lambda a: winding_number(m.vertices, m.faces, jnp.zeros((2, 3)), accuracy=a))(0.1)


def test_tiny_meshes_do_not_underflow():
    # The cubic terms of the solid angle underflow below about 1e-150 (float64) and 1e-20
    # (float32); the coordinates are then scaled to unit size first (C++: per triangle and
    # point, JAX: per mesh and points): eager, jit, 3D and 2D.
    m, sq = voxax.data.box(), voxax.data.polygon_square()
    p = np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.5, 0.1, 0.1]])
    want = [1.0, 0.0, 0.5]
    for s in (1e-300, 1e-160, 1.0):
        v, q = np.asarray(m.vertices) * s, p * s
        np.testing.assert_allclose(winding_number(v, m.faces, q), want, atol=1e-12)
        np.testing.assert_allclose(winding_number(v, m.faces[:-1], q[:1], accuracy=1e-6), 11 / 12, atol=1e-6)
        np.testing.assert_allclose(jax.jit(lambda v, q: winding_number(v, m.faces, q))(v, q), want, atol=1e-12)
        w2 = jax.jit(lambda v, q: winding_number(v, sq.faces, q))(np.asarray(sq.vertices) * s, p[:, :2] * s)
        np.testing.assert_allclose(w2, want, atol=1e-12)
    v32, q32 = (np.asarray(m.vertices) * 1e-20).astype(np.float32), (p * 1e-20).astype(np.float32)
    np.testing.assert_allclose(jax.jit(lambda v, q: winding_number(v, m.faces, q))(v32, q32), want, atol=1e-5)
