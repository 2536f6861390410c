"""Tests of voxax.fields: analytic fields against closed forms, CSG on points, neural fields."""

import math

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import optax
import pytest

from voxax import fields


def _grad_norm(fn, p):
    g = jax.vmap(jax.grad(fn))(p)
    return np.linalg.norm(np.asarray(g), axis=-1)


@pytest.fixture
def pts():
    return np.random.default_rng(0).uniform(-1.5, 1.5, (2000, 3))


def _closest_on_box(p, h):
    """Independent oracle: the closest point of the box surface, by brute force over faces."""
    best = np.full(len(p), np.inf)
    for axis in range(3):
        for sign in (-1, 1):
            q = np.clip(p, -h, h)
            q[:, axis] = sign * h[axis]
            best = np.minimum(best, np.linalg.norm(p - q, axis=1))
    return best


def test_sphere_box_torus_are_distances(pts):
    p = jnp.asarray(pts)
    # sphere: closed form from the definition of distance to a sphere surface
    s = fields.sphere(p, radius=0.7, center=jnp.array([0.1, -0.2, 0.3]))
    np.testing.assert_allclose(
        s, np.linalg.norm(pts - [0.1, -0.2, 0.3], axis=1) - 0.7, atol=1e-14
    )
    # box: |value| is the brute-force distance to the surface, sign from containment
    h = np.array([0.3, 0.5, 0.8])
    b = np.asarray(fields.box(p, half_extents=h))
    inside = np.all(np.abs(pts) < h, axis=1)
    np.testing.assert_allclose(np.abs(b), _closest_on_box(pts, h), atol=1e-14)
    assert np.all((b < 0) == inside)
    # torus: the distance to the tube's centre circle, sampled densely, minus r
    t = np.asarray(fields.torus(p, major_radius=0.6, minor_radius=0.25, axis="y"))
    ang = np.linspace(0, 2 * np.pi, 20001)
    circle = np.stack([0.6 * np.cos(ang), np.zeros_like(ang), 0.6 * np.sin(ang)], 1)
    d = np.min(np.linalg.norm(pts[:200, None] - circle[None], axis=2), axis=1) - 0.25
    np.testing.assert_allclose(t[:200], d, atol=1e-6)
    # |grad| = 1 almost everywhere for all three
    for fn in (
        lambda x: fields.sphere(x, 0.7),
        lambda x: fields.box(x, h),
        lambda x: fields.torus(x, 0.6, 0.25),
    ):
        np.testing.assert_allclose(_grad_norm(fn, p), 1.0, atol=1e-12)


def test_zero_level_sets():
    rng = np.random.default_rng(1)
    u = rng.normal(size=(100, 3))
    u /= np.linalg.norm(u, axis=1, keepdims=True)
    np.testing.assert_allclose(fields.sphere(0.4 * u, 0.4), 0, atol=1e-15)
    # points on the box faces
    q = rng.uniform(-1, 1, (100, 3)) * [0.2, 0.3, 0.4]
    q[np.arange(100), rng.integers(0, 3, 100)] = 0
    axis = rng.integers(0, 3, 100)
    q[np.arange(100), axis] = np.array([0.2, 0.3, 0.4])[axis] * rng.choice([-1, 1], 100)
    np.testing.assert_allclose(fields.box(q, [0.2, 0.3, 0.4]), 0, atol=1e-15)
    # torus around z: R + r cos(s) in the plane, r sin(s) along z
    a, s = rng.uniform(0, 2 * np.pi, (2, 100))
    R, r = 0.5, 0.2
    tp = np.stack(
        [
            (R + r * np.cos(s)) * np.cos(a),
            (R + r * np.cos(s)) * np.sin(a),
            r * np.sin(s),
        ],
        1,
    )
    np.testing.assert_allclose(fields.torus(tp, R, r), 0, atol=1e-15)
    # gyroid at lattice points: sin(0)=0 terms
    np.testing.assert_allclose(
        fields.gyroid(jnp.array([[0.5, 0.5, 0.5], [0, 0, 0]])), 0, atol=1e-12
    )
    # 2D: circle and rectangle
    assert float(fields.sphere(jnp.array([3.0, 4.0]), 5.0)) == 0.0
    assert float(fields.box(jnp.array([1.0, 0.2]), [1.0, 0.5])) == 0.0


def test_chebyshev_polynomials_and_surface():
    t = np.linspace(0, np.pi, 101)
    for n in range(10):
        np.testing.assert_allclose(
            fields.chebyshev_polynomial(jnp.cos(t), n), np.cos(n * t), atol=1e-12
        )
    x = np.linspace(-1.2, 1.2, 50)
    t8 = 128 * x**8 - 256 * x**6 + 160 * x**4 - 32 * x**2 + 1
    np.testing.assert_allclose(
        fields.chebyshev_polynomial(jnp.asarray(x), 8), t8, rtol=1e-12, atol=1e-12
    )
    # T8(1) = 1, T8(cos(pi/8)) = cos(pi) = -1
    p = jnp.array([1.0, np.cos(np.pi / 8), np.cos(np.pi / 8)])
    assert abs(float(fields.chebyshev(p)) + 1) < 1e-12
    # The octic's extent: T8 >= -1 on [-1, 1] and grows beyond, so the surface ends where
    # T8(x) = 2: x = cosh(arccosh(2) / 8)
    a = math.cosh(math.acosh(2) / 8)
    rng = np.random.default_rng(2)
    q = rng.uniform(-1.1, 1.1, (5000, 3))
    q[:, 0] = a + 1e-9
    assert np.all(np.asarray(fields.chebyshev(q)) > 0)
    c = np.cos(np.pi / 8)
    assert float(fields.chebyshev(jnp.array([a - 1e-6, c, c]))) < 0
    assert float(fields.chebyshev(jnp.array([a + 1e-6, c, c]))) > 0
    with pytest.raises(ValueError, match="degree"):
        fields.chebyshev_polynomial(1.0, -1)


def test_blob_formula():
    p = np.random.default_rng(3).normal(size=(50, 3))
    x, y, z = p.T
    np.testing.assert_allclose(
        fields.blob(p),
        x**2 + y**2 + z**2 + np.sin(4 * x) - np.cos(4 * y) + np.sin(4 * z),
        rtol=1e-13,
    )


def test_csg_on_points(pts):
    a = fields.sphere(pts, 0.8)
    b = fields.box(pts, 0.5, center=[0.6, 0, 0])
    ina, inb = np.asarray(a) < 0, np.asarray(b) < 0
    assert np.array_equal(np.asarray(fields.union(a, b)) < 0, ina | inb)
    assert np.array_equal(np.asarray(fields.intersection(a, b)) < 0, ina & inb)
    assert np.array_equal(np.asarray(fields.difference(a, b)) < 0, ina & ~inb)
    c = fields.sphere(pts, 0.3, center=[0, 0.9, 0])
    assert np.array_equal(
        np.asarray(fields.union(a, b, c)) < 0, ina | inb | (np.asarray(c) < 0)
    )
    # smooth union: equal to min where far apart, below min and within k/4 elsewhere
    k = 0.2
    su = np.asarray(fields.smooth_union(a, b, k))
    m = np.minimum(a, b)
    far = np.abs(np.asarray(a) - np.asarray(b)) >= k
    np.testing.assert_allclose(su[far], m[far], atol=1e-15)
    assert np.all(su <= m + 1e-15) and np.all(su >= m - k / 4 - 1e-15)
    # union of disjoint-ish spheres is still the exact distance outside both
    outside = ~(ina | inb)
    assert np.all(np.asarray(fields.union(a, b))[outside] >= 0)
    with pytest.raises(ValueError):
        fields.union(a)


def test_transforms(pts):
    f = fields.translated(fields.sphere, jnp.array([0.2, 0.0, -0.1]))
    np.testing.assert_allclose(
        f(pts, 0.5), fields.sphere(pts, 0.5, center=[0.2, 0.0, -0.1]), atol=1e-15
    )
    g = fields.scaled(lambda p: fields.box(p, 0.5), 2.0)
    np.testing.assert_allclose(g(pts), fields.box(pts, 1.0), atol=1e-15)


def test_jit_grad_vmap():
    p = jnp.array([[0.3, 0.2, 0.1], [1.0, -0.5, 0.2]])
    eps = 1e-6
    e = eps * jnp.eye(3)
    for fn in (
        fields.sphere,
        fields.box,
        fields.torus,
        fields.gyroid,
        fields.chebyshev,
        fields.blob,
    ):

        def everything(q, fn=fn):
            # jit, vmap, grad and central differences, compiled once per field
            g = jax.grad(lambda x: jnp.sum(fn(x)))(q)
            fd = (fn(q[:, None, :] + e) - fn(q[:, None, :] - e)) / (2 * eps)
            return fn(q), jax.vmap(fn)(q), g, fd

        v, vm, g, fd = jax.jit(everything)(p)
        np.testing.assert_allclose(v, fn(p), rtol=1e-14)
        np.testing.assert_allclose(vm, v, rtol=1e-14)
        np.testing.assert_allclose(g, fd, rtol=1e-6, atol=1e-6)
    # gradient in a parameter
    dr = jax.grad(lambda r: jnp.sum(fields.sphere(p, r)))(0.5)
    assert float(dr) == -2.0
    # gradient at the sphere's centre is finite
    assert np.all(np.isfinite(jax.grad(lambda q: fields.sphere(q, 1.0))(jnp.zeros(3))))
    # float32 stays float32
    assert fields.torus(p.astype(jnp.float32)).dtype == jnp.float32


def test_bad_shapes():
    with pytest.raises(ValueError, match=r"\(\.\.\., 3\)"):
        fields.torus(jnp.zeros((4, 2)))
    with pytest.raises(ValueError, match="center"):
        fields.sphere(jnp.zeros((4, 3)), 1.0, center=[0.0, 0.0])
    with pytest.raises(ValueError, match="axis"):
        fields.torus(jnp.zeros((4, 3)), axis="w")


def test_siren_init_statistics():
    width, n_in = 256, 3
    net = fields.Siren(n_in, 1, width=width, depth=4, key=jax.random.key(0))
    w0, w1 = np.asarray(net.weights[0]), np.asarray(net.weights[1])
    assert np.abs(w0).max() <= 1 / n_in and np.abs(w0).max() > 0.9 / n_in
    c = math.sqrt(6 / width) / 30
    assert np.abs(w1).max() <= c
    # uniform on [-c, c] has variance c^2 / 3
    assert abs(w1.var() / (c * c / 3) - 1) < 0.02
    # activations of the deeper sine layers: arcsine distributed on [-1, 1], mean 0, var 1/2
    x = jax.random.uniform(jax.random.key(1), (2000, n_in), minval=-1, maxval=1)
    acts = jax.vmap(net.hidden)(x)
    for a in acts[1:]:
        a = np.asarray(a)
        assert abs(a.mean()) < 0.05
        assert abs(a.var() - 0.5) < 0.03
        # arcsine law: P(|a| < sin(pi/4)) = 1/2
        assert abs(np.mean(np.abs(a) < math.sin(math.pi / 4)) - 0.5) < 0.03
    # the weight part of the hidden pre-activations has unit standard deviation
    pre = np.asarray(jax.vmap(lambda h: 30 * (net.weights[2] @ h))(acts[1]))
    assert abs(pre.std() - 1.0) < 0.1


def test_siren_height_field_and_shapes():
    net = fields.Siren(2, 1, width=32, depth=2, key=jax.random.key(0))
    assert net(jnp.zeros((4, 5, 2))).shape == (4, 5)
    assert net(jnp.zeros(2)).shape == ()
    net3 = fields.Siren(3, 2, width=8, depth=1, key=jax.random.key(0))
    assert net3(jnp.zeros((6, 3))).shape == (6, 2)
    g = jax.grad(lambda m: jnp.sum(m(jnp.ones((3, 2)))))(net)
    assert all(np.all(np.isfinite(w)) for w in g.weights)
    with pytest.raises(ValueError):
        net(jnp.zeros((4, 3)))
    with pytest.raises(ValueError, match="depth"):
        fields.Siren(2, 1, depth=0, key=jax.random.key(0))


def test_siren_fits_a_height_field():
    # A small SIREN fits a smooth 2D height field quickly (its reason to exist)
    xy = jax.random.uniform(jax.random.key(2), (512, 2), minval=-1, maxval=1)
    target = 0.3 * jnp.sin(3 * xy[:, 0]) * jnp.cos(2 * xy[:, 1])
    net = fields.Siren(2, 1, width=32, depth=2, key=jax.random.key(3))
    opt = optax.adam(1e-3)
    state = opt.init(eqx.filter(net, eqx.is_array))

    @eqx.filter_jit
    def step(net, state):
        loss, g = eqx.filter_value_and_grad(lambda m: jnp.mean((m(xy) - target) ** 2))(
            net
        )
        upd, state = opt.update(g, state)
        return eqx.apply_updates(net, upd), state, loss

    loss0 = float(jnp.mean((net(xy) - target) ** 2))
    for _ in range(300):
        net, state, loss = step(net, state)
    assert float(loss) < 1e-3 * max(loss0, 1e-2)


def test_deepsdf_fits_two_spheres():
    key = jax.random.key(0)
    net = fields.DeepSDF(n_shapes=2, latent_size=4, width=32, depth=4, skip=2, key=key)
    assert net.codes.shape == (2, 4) and abs(float(jnp.std(net.codes)) - 0.01) < 0.01
    pts = jax.random.uniform(jax.random.key(1), (2, 1024, 3), minval=-1, maxval=1)
    radii = jnp.array([0.3, 0.6])[:, None]
    sdf = jnp.linalg.norm(pts, axis=-1) - radii
    idx = jnp.array([0, 1])[:, None]
    opt = optax.adam(3e-3)
    state = opt.init(eqx.filter(net, eqx.is_array))

    @eqx.filter_jit
    def step(net, state):
        loss, g = eqx.filter_value_and_grad(
            lambda m: fields.deepsdf_loss(m, pts, sdf, idx, clamp=1.0)
        )(net)
        upd, state = opt.update(g, state)
        return eqx.apply_updates(net, upd), state, loss

    for _ in range(500):
        net, state, _ = step(net, state)
    test = jax.random.uniform(jax.random.key(5), (500, 3), minval=-0.8, maxval=0.8)
    for i, r in enumerate((0.3, 0.6)):
        err = jnp.abs(net(test, i) - (jnp.linalg.norm(test, axis=-1) - r))
        assert float(jnp.mean(err)) < 0.02
    # decode with an explicit code equals the indexed call
    np.testing.assert_allclose(net.decode(net.codes[1], test), net(test, 1), rtol=1e-12)
    with pytest.raises(ValueError, match="skip"):
        fields.DeepSDF(1, 4, depth=2, skip=2, key=key)
    with pytest.raises(ValueError, match="latent"):
        net.decode(jnp.zeros(3), test)
