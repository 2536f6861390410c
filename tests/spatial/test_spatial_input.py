"""Hostile and far-away input of the BVH queries and the winding numbers, their derivatives,
and the winding numbers' ray path against the exact solid-angle sum."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import voxax
from voxax._kernels import spatial as kernels


@pytest.fixture(autouse=True)
def _x64():
    with jax.enable_x64(True):
        yield


# ---------------------------------------------------------------- closest points far away


@pytest.mark.parametrize("scale", [5e29, 1e30, 2e30, 1e31, 1e32, 1e40, 1e74])
def test_far_closest_points_do_not_depend_on_the_batch(scale):
    m = voxax.data.icosphere(2, radius=0.6)
    v0 = np.asarray(m.vertices)
    q = v0[[0, 33]] * scale
    pair = voxax.closest_points(m, q)
    alone = [voxax.closest_points(m, q[i : i + 1]) for i in range(2)]
    jitted = jax.jit(lambda p: voxax.closest_points(m, p))(jnp.asarray(q))
    for r in (pair, jitted):
        assert np.all(np.isfinite(np.asarray(r.distance))) and np.all(np.isfinite(np.asarray(r.point)))
    # the distance to a sphere of radius 0.6 from |q| = 0.6 scale is |q| - 0.6 (rounded: |q|)
    want = np.linalg.norm(q, axis=1) - 0.6
    np.testing.assert_allclose(pair.distance, want, rtol=1e-12)
    np.testing.assert_array_equal(pair.distance, [a.distance[0] for a in alone])
    np.testing.assert_array_equal(np.asarray(jitted.distance), pair.distance)
    # the closest point lies on the sphere's hull (within its size)
    assert np.all(np.linalg.norm(pair.point, axis=1) <= 0.6 + 1e-12)


def test_far_hausdorff_is_finite():
    m = voxax.data.icosphere(2, radius=0.6)
    far = voxax.Mesh(np.asarray(m.vertices) * 1e30, np.asarray(m.faces))
    h = voxax.metrics.hausdorff(m, far)
    assert np.isfinite(h) and h == pytest.approx(0.6e30, rel=1e-9)


def test_random_queries_at_every_scale_are_finite_and_on_the_mesh(rng):
    m = voxax.data.icosphere(1)
    q = rng.normal(size=(3000, 3)) * 10.0 ** rng.uniform(-3, 74, size=(3000, 1))
    r = voxax.closest_points(m, q)
    assert np.all(np.isfinite(r.distance)) and np.all(np.isfinite(r.point))
    assert np.all((r.barycentric >= -1e-9) & (r.barycentric <= 1 + 1e-9))
    corners = np.asarray(m.vertices)[np.asarray(m.faces)[r.face]]
    np.testing.assert_allclose(np.einsum("nk,nkd->nd", r.barycentric, corners), r.point, atol=1e-9)


# ---------------------------------------------------------------- dtypes and face indices


@pytest.mark.parametrize("dtype", [bool, np.complex128])
def test_bool_and_complex_vertices_and_queries_are_refused(dtype):
    m = voxax.data.box()
    v, f = np.asarray(m.vertices), np.asarray(m.faces)
    z = np.zeros((1, 3), dtype)
    calls = [
        lambda: voxax.BVH(v.astype(dtype), f),
        lambda: voxax.closest_points((v.astype(dtype), f), np.zeros((1, 3))),
        lambda: voxax.closest_points(m, z),
        lambda: voxax.first_hits(m, z, np.ones((1, 3))),
        lambda: voxax.winding_number(v.astype(dtype), f, np.zeros((1, 3))),
        lambda: voxax.winding_number(m, z),
        lambda: jax.jit(lambda q: voxax.closest_points(m, q))(jnp.asarray(z)),
        lambda: jax.jit(lambda w: voxax.closest_points((w, f), jnp.zeros((1, 3))))(jnp.asarray(v).astype(dtype)),
        lambda: jax.jit(lambda w: voxax.first_hits((w, f), jnp.zeros((1, 3)), jnp.ones((1, 3))))(
            jnp.asarray(v).astype(dtype)
        ),
    ]
    for call in calls:
        with pytest.raises(TypeError):
            call()


def test_int64_faces_beyond_int32_are_refused_under_jit():
    m = voxax.data.box()
    v = jnp.asarray(m.vertices)
    big = jnp.asarray(m.faces, jnp.int64) + 2**32  # would wrap to the valid faces in int32
    with pytest.raises(Exception, match="out of range"):
        jax.jit(lambda f: voxax.closest_points((v, f), jnp.zeros((1, 3))))(big).distance.block_until_ready()
    with pytest.raises(Exception, match="out of range"):
        jax.jit(lambda f: voxax.first_hits((v, f), jnp.zeros((1, 3)), jnp.ones((1, 3))))(big).t.block_until_ready()
    with pytest.raises(Exception, match="out of range"):
        jax.jit(lambda f: voxax.winding_number(v, f, jnp.zeros((1, 3))))(big).block_until_ready()
    with pytest.raises(Exception, match="out of range"):  # constant faces, traced vertices
        jax.jit(lambda w: voxax.closest_points((w, np.asarray(big)), jnp.zeros((1, 3))))(v).face.block_until_ready()
    # in range, int64 faces give the int32 answer
    r64 = jax.jit(lambda f: voxax.closest_points((v, f), jnp.ones((1, 3))))(big - 2**32)
    assert float(r64.distance[0]) == pytest.approx(np.sqrt(3) * 0.5)


# ---------------------------------------------------------------- winding numbers: checks


@pytest.mark.parametrize("bad", [np.nan, np.inf, 1e80])
def test_winding_number_refuses_bad_points_and_vertices_eagerly_and_under_jit(bad):
    m = voxax.data.box()
    v, f = np.asarray(m.vertices), np.asarray(m.faces)
    p = np.zeros((2, 3))
    p[1, 2] = bad
    with pytest.raises(ValueError, match="points"):
        voxax.winding_number(m, p)
    with pytest.raises(Exception, match="points"):
        jax.jit(lambda q: voxax.winding_number(v, f, q))(jnp.asarray(p)).block_until_ready()
    w = v.copy()
    w[3, 0] = bad
    with pytest.raises(Exception, match="vertices"):
        jax.jit(lambda x: voxax.winding_number(x, f, jnp.zeros((1, 3))))(jnp.asarray(w)).block_until_ready()


def test_winding_number_refuses_out_of_range_faces_under_jit():
    m = voxax.data.box()
    v = jnp.asarray(m.vertices)
    f = jnp.asarray(m.faces).at[0, 0].set(8)
    with pytest.raises(Exception, match="out of range"):
        jax.jit(lambda g: voxax.winding_number(v, g, jnp.zeros((1, 3))))(f).block_until_ready()


# ---------------------------------------------------------------- winding numbers: ray path


def _probe_points(rng, mesh, n=600):
    v = np.asarray(mesh.vertices)
    lo, hi = v.min(0), v.max(0)
    p = rng.uniform(lo - 0.3 * (hi - lo), hi + 0.3 * (hi - lo), size=(n, 3))
    # on the surface: vertices, face centres and lattice points (rays through edges)
    centres = v[np.asarray(mesh.faces)[:50]].mean(axis=1)
    return np.concatenate([p, v[:40], centres, np.round(p[:100] * 4) / 4])


@pytest.mark.parametrize("name", ["box", "overlapping_cubes", "with_inverted_component", "icosphere", "torus"])
def test_ray_winding_numbers_equal_the_solid_angle_sum(rng, name):
    make = getattr(voxax.data, name)
    mesh = make(subdivisions=1) if name == "with_inverted_component" else make()
    v = np.ascontiguousarray(mesh.vertices, np.float64)
    f = np.ascontiguousarray(mesh.faces, np.int32)
    p = _probe_points(rng, mesh)
    rays, closed, by_ray = kernels.winding_number(v, f, p, False, 0)
    exact, _, none = kernels.winding_number(v, f, p, True, 0)
    assert closed and none == 0 and by_ray > len(p) // 2
    # the independent oracle: the JAX solid-angle sum (traced, so the JAX path runs), away
    # from the surface (within rounding of it, which side a point is on is a coin toss)
    oracle = np.asarray(jax.jit(lambda q: voxax.winding_number(v, f, q))(jnp.asarray(p)))
    away = voxax.closest_points(mesh, p).distance > 1e-9
    np.testing.assert_allclose(exact[away], oracle[away], atol=1e-9)
    np.testing.assert_allclose(rays[away], oracle[away], atol=1e-9)
    # every point decided by its ray is an exact integer; the others (all points on the
    # surface: 1/2 on faces, ...) get the sum through the hierarchy, equal up to rounding
    np.testing.assert_allclose(rays, exact, atol=1e-9)
    assert np.sum(rays == np.round(rays)) >= by_ray
    np.testing.assert_array_equal(kernels.winding_number(v, f, p, False, 1)[0], rays)


def test_open_surface_takes_the_exact_sum(rng):
    mesh = voxax.data.box()
    v = np.asarray(mesh.vertices)
    f = np.asarray(mesh.faces)[2:]  # one side removed: open
    p = rng.uniform(-1, 1, size=(300, 3))
    w = np.asarray(voxax.winding_number(v, f, p))
    _, closed, by_ray = kernels.winding_number(
        np.ascontiguousarray(v, np.float64), np.ascontiguousarray(f, np.int32), p, False, 0
    )
    assert not closed and by_ray == 0  # a boundary as large as the mesh: the exact sum
    oracle = np.asarray(jax.jit(lambda q: voxax.winding_number(v, f, q))(jnp.asarray(p)))
    np.testing.assert_allclose(w, oracle, atol=1e-12)
    assert np.any(np.abs(w - np.round(w)) > 1e-3)  # not integers


def test_winding_number_eager_and_traced_agree_and_stay_differentiable(rng):
    m = voxax.data.icosphere(1)
    p = rng.uniform(-1.2, 1.2, size=(12, 3))
    eager = np.asarray(voxax.winding_number(m, p))
    traced = np.asarray(jax.jit(lambda q: voxax.winding_number(m, q))(jnp.asarray(p)))
    np.testing.assert_allclose(eager, traced, atol=1e-9)
    g = jax.grad(lambda q: voxax.winding_number(m, q).sum())(jnp.asarray(p))
    assert np.all(np.isfinite(np.asarray(g))) and float(jnp.abs(g).max()) < 1e-9  # closed: zero


# ---------------------------------------------------------------- closest points: derivatives


def test_closest_point_gradients(rng):
    m = voxax.data.icosphere(1)
    v, f = jnp.asarray(m.vertices), np.asarray(m.faces)
    q = jnp.asarray(rng.normal(size=(6, 3)) * 0.8)
    g = jax.jit(jax.grad(lambda x: voxax.closest_points((v, f), x).distance.sum()))(q)
    r = voxax.closest_points(m, np.asarray(q))
    np.testing.assert_allclose(g, (np.asarray(q) - r.point) / r.distance[:, None], atol=1e-12)
    eps = 1e-6
    dv = jnp.asarray(rng.normal(size=v.shape))
    dq = jnp.asarray(rng.normal(size=q.shape))

    def fn(w, x):
        c = voxax.closest_points((w, f), x)
        return jnp.stack([c.distance.sum(), c.point.sum(), c.barycentric[:, 1].sum()])

    jac = jax.jit(jax.jacrev(fn, argnums=(0, 1)))
    jv, jq = jac(v, q)
    directional = jnp.einsum("kvd,vd->k", jv, dv) + jnp.einsum("kqd,qd->k", jq, dq)
    fd = (fn(v + eps * dv, q + eps * dq) - fn(v - eps * dv, q - eps * dq)) / (2 * eps)
    np.testing.assert_allclose(directional, fd, rtol=1e-5, atol=1e-7)


@pytest.mark.parametrize("kind", ["soup", "open_sphere"])
def test_hierarchical_winding_numbers_equal_the_plain_sum(rng, kind):
    if kind == "soup":
        v = rng.normal(size=(600, 3))
        f = rng.integers(0, 600, size=(400, 3)).astype(np.int32)
    else:
        m = voxax.data.icosphere(3)
        v, f = np.asarray(m.vertices, np.float64), np.asarray(m.faces, np.int32)[:-37]
    p = np.concatenate([rng.uniform(-1.5, 1.5, size=(400, 3)), v[:20]])
    tree, closed, by_ray = kernels.winding_number(v, f, p, False, 0)
    plain, _, _ = kernels.winding_number(v, f, p, True, 2)
    # the soup takes the hierarchy, the open sphere (a small boundary) a ray through it and
    # a cap over its hole at all but the points on its vertices
    assert not closed and by_ray == (0 if kind == "soup" else 400)
    np.testing.assert_allclose(tree, plain, atol=1e-12)
    np.testing.assert_array_equal(tree, kernels.winding_number(v, f, p, False, 1)[0])
    oracle = np.asarray(jax.jit(lambda q: voxax.winding_number(v, f, q))(jnp.asarray(p)))
    np.testing.assert_allclose(tree, oracle, atol=1e-9)


def test_winding_number_threads_and_concurrent_calls(rng):
    import concurrent.futures

    closed = voxax.data.icosphere(2)
    soup = (rng.normal(size=(90, 3)), rng.integers(0, 90, size=(60, 3)))
    p = rng.uniform(-1.2, 1.2, size=(700, 3))  # several chunks of points
    for mesh in (closed, soup):
        one = np.asarray(voxax.winding_number(mesh, p, threads=1))
        np.testing.assert_array_equal(np.asarray(voxax.winding_number(mesh, p, threads=np.int64(2))), one)
        with concurrent.futures.ThreadPoolExecutor(4) as pool:
            for got in pool.map(lambda _, m=mesh: np.asarray(voxax.winding_number(m, p)), range(4)):
                np.testing.assert_array_equal(got, one)
    for bad, err in ((2.5, TypeError), (True, TypeError), (0, ValueError)):
        with pytest.raises(err, match="`threads` must"):
            voxax.winding_number(closed, p, threads=bad)
