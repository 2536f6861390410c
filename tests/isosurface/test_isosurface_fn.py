"""MeshSDF: iso-surfaces of fields given as functions, differentiable in their parameters."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import voxax

GRID = voxax.Grid.cube(64)


def sphere(r, x):
    return jnp.linalg.norm(x, axis=-1) - r


def scaled_sphere(r, x):
    return 3.0 * (jnp.linalg.norm(x, axis=-1) - r)


def mean_sq(iso):
    return jnp.mean(jnp.sum(iso.vertices**2, -1))


@pytest.fixture(scope="module")
def sphere_grads():
    out = {}
    for name, fn in (("sdf", sphere), ("scaled", scaled_sphere)):
        for rule in ("meshsdf", "theorem1", "level_set", "interpolation"):
            out[name, rule] = float(
                jax.grad(
                    lambda r, fn=fn, rule=rule: mean_sq(
                        voxax.isosurface_fn(fn, r, GRID, rule=rule)
                    )
                )(0.6)
            )
    return out


@pytest.mark.parametrize("rule", ["meshsdf", "theorem1", "level_set"])
def test_sphere_radius_gradient_field_rules(sphere_grads, rule):
    # L = mean |v|^2 of the sphere of radius r: dL/dr = 2 r.
    assert sphere_grads["sdf", rule] == pytest.approx(1.2, rel=1e-3)


def test_interpolation_rule_is_the_discrete_derivative(sphere_grads):
    def loss(r):
        return float(
            mean_sq(voxax.isosurface_fn(sphere, r, GRID, rule="interpolation"))
        )

    eps = 1e-6
    fd = (loss(0.6 + eps) - loss(0.6 - eps)) / (2 * eps)
    assert sphere_grads["sdf", "interpolation"] == pytest.approx(fd, rel=1e-6)
    # the discrete derivative is close to, not equal to, the continuum one
    assert sphere_grads["sdf", "interpolation"] == pytest.approx(1.2, rel=0.02)
    assert abs(sphere_grads["sdf", "interpolation"] / 1.2 - 1) > 1e-3


def test_scaled_sdf_shows_the_rules_differ(sphere_grads):
    # f = 3(|x| - r): |grad f| = 3. level_set and interpolation are unchanged, meshsdf scales
    # by |grad f| and Theorem 1 by |grad f|^2.
    assert sphere_grads["scaled", "level_set"] == pytest.approx(
        sphere_grads["sdf", "level_set"], rel=1e-12
    )
    assert sphere_grads["scaled", "interpolation"] == pytest.approx(
        sphere_grads["sdf", "interpolation"], rel=1e-9
    )
    assert sphere_grads["scaled", "meshsdf"] == pytest.approx(
        3 * sphere_grads["sdf", "meshsdf"], rel=1e-12
    )
    assert sphere_grads["scaled", "theorem1"] == pytest.approx(
        9 * sphere_grads["sdf", "theorem1"], rel=1e-12
    )


@pytest.mark.parametrize("scale", [1.0, 2.5])
def test_uniform_shift_moves_vertices_along_the_rule(scale):
    grid = voxax.Grid.cube(24)

    def fn(c, x):
        return scale * (jnp.linalg.norm(x, axis=-1) - 0.55) + c

    v0 = np.asarray(voxax.isosurface_fn(fn, 0.0, grid).vertices)
    n = v0 / np.linalg.norm(v0, axis=1, keepdims=True)  # analytic unit normal
    for rule, expected in (
        ("meshsdf", -n),
        ("level_set", -n / scale),
        ("theorem1", -n * scale),
    ):
        _, dv = jax.jvp(
            lambda c, rule=rule: voxax.isosurface_fn(fn, c, grid, rule=rule).vertices,
            (0.0,),
            (1.0,),
        )
        np.testing.assert_allclose(np.asarray(dv), expected, rtol=0, atol=1e-12)


def test_forward_values_are_the_marching_cubes_vertices():
    grid = voxax.Grid.cube(20)
    f = np.linalg.norm(grid.centers(), axis=-1) - 0.5
    ref = voxax.isosurface(f, grid)
    for rule in ("meshsdf", "interpolation"):
        iso = voxax.isosurface_fn(sphere, 0.5, grid, rule=rule)
        assert np.array_equal(np.asarray(iso.faces), np.asarray(ref.faces))
        np.testing.assert_allclose(
            np.asarray(iso.vertices), np.asarray(ref.vertices), rtol=0, atol=1e-15
        )


def test_jit_and_vmap_over_latents():
    grid = voxax.Grid.cube(12)

    def loss(r):
        iso = voxax.isosurface_fn(sphere, r, grid, capacity=1500)
        w = (jnp.arange(iso.vertices.shape[0]) < iso.n_vertices).astype(
            iso.vertices.dtype
        )
        return jnp.sum(w * jnp.sum(iso.vertices**2, -1)) / iso.n_vertices

    radii = jnp.array([0.4, 0.5, 0.6])
    grads = jax.jit(jax.vmap(jax.grad(loss)))(radii)
    np.testing.assert_allclose(np.asarray(grads), 2 * np.asarray(radii), rtol=2e-2)
    eager = [
        float(
            jax.grad(lambda r: mean_sq(voxax.isosurface_fn(sphere, r, grid)))(float(r))
        )
        for r in radii
    ]
    np.testing.assert_allclose(np.asarray(grads), eager, rtol=1e-12)


def test_lipschitz_path_equals_dense_and_evaluates_less():
    grid = voxax.Grid.cube(64)
    dense = voxax.isosurface_fn(sphere, 0.6, grid)
    fast = voxax.isosurface_fn(sphere, 0.6, grid, lipschitz=1.0)
    assert np.array_equal(np.asarray(fast.faces), np.asarray(dense.faces))
    assert np.array_equal(np.asarray(fast.vertices), np.asarray(dense.vertices))
    assert fast.n_evaluated < 0.25 * grid.size
    # a non-SDF needs its own bound: 3(|x| - r) is 3-Lipschitz
    fast3 = voxax.isosurface_fn(scaled_sphere, 0.6, grid, lipschitz=3.0)
    assert np.array_equal(np.asarray(fast3.faces), np.asarray(dense.faces))
    # two components, one small
    two = lambda p, x: jnp.minimum(
        jnp.linalg.norm(x - 0.5, axis=-1) - 0.3, jnp.linalg.norm(x + 0.6, axis=-1) - p
    )
    d2 = voxax.isosurface_fn(two, 0.06, grid)
    f2 = voxax.isosurface_fn(two, 0.06, grid, lipschitz=1.0)
    assert np.array_equal(np.asarray(f2.faces), np.asarray(d2.faces))


def test_band_path_follows_a_moving_surface():
    grid = voxax.Grid.cube(32)
    h = grid.spacing[0]
    prev = voxax.isosurface_fn(sphere, 0.5, grid)
    for step in range(1, 3):
        r = 0.5 + 0.5 * h * step
        dense = voxax.isosurface_fn(sphere, r, grid)
        band = voxax.isosurface_fn(sphere, r, grid, band=prev.samples)
        assert np.array_equal(np.asarray(band.faces), np.asarray(dense.faces))
        assert np.array_equal(np.asarray(band.vertices), np.asarray(dense.vertices))
        assert band.n_evaluated < 0.3 * grid.size
        prev = band
    # a jump by several cells widens the band until it holds the new surface
    jump = voxax.isosurface_fn(sphere, 0.5 + 6 * h, grid, band=prev.samples)
    dense = voxax.isosurface_fn(sphere, 0.5 + 6 * h, grid)
    assert np.array_equal(np.asarray(jump.faces), np.asarray(dense.faces))


def test_bad_input():
    grid = voxax.Grid.cube(8)
    with pytest.raises(ValueError, match="rule"):
        voxax.isosurface_fn(sphere, 0.5, grid, rule="sdf")
    with pytest.raises(TypeError, match="callable"):
        voxax.isosurface_fn(3.0, 0.5, grid)
    with pytest.raises(ValueError, match="lipschitz"):
        voxax.isosurface_fn(sphere, 0.5, grid, lipschitz=-1.0)
    with pytest.raises(ValueError, match="band"):
        voxax.isosurface_fn(sphere, 0.5, grid, band=np.zeros((4, 4, 4)))
    for chunk in (-1, 0):
        with pytest.raises(ValueError, match="`chunk` must be at least 1"):
            voxax.isosurface_fn(sphere, 0.5, grid, chunk=chunk)
    for chunk in (2.5, True):
        with pytest.raises(TypeError, match="`chunk` must be an int"):
            voxax.isosurface_fn(sphere, 0.5, grid, chunk=chunk)
    with pytest.raises(ValueError, match="`lipschitz` must be"):
        voxax.isosurface_fn(sphere, 0.5, grid, lipschitz="1")
    with pytest.raises(ValueError, match="`close` must be"):
        voxax.isosurface_fn(sphere, 0.5, grid, close=np.nan)
    scalar = lambda r, x: jnp.sum(x) - r  # noqa: E731 - one value for all points
    wide = lambda r, x: jnp.stack([sphere(r, x)] * 2, -1)  # noqa: E731
    for bad in (scalar, wide):
        with pytest.raises(ValueError, match=r"must return one value per point, shape \(\d+,\)"):
            voxax.isosurface_fn(bad, 0.5, grid)
        with pytest.raises(ValueError, match="one value per point"):
            jax.jit(lambda r, bad=bad: voxax.isosurface_fn(bad, r, grid, capacity=500).vertices)(0.5)
    with pytest.raises(TypeError, match="real values"):
        voxax.isosurface_fn(lambda r, x: sphere(r, x) * 1j, 0.5, grid)
    with pytest.raises(TypeError, match="eager"):
        jax.jit(
            lambda r: (
                voxax.isosurface_fn(
                    sphere, r, grid, lipschitz=1.0, capacity=100
                ).vertices
            )
        )(0.5)


def test_eager_calls_reuse_the_compiled_field():
    """Repeated eager calls with the same field function trace it once per structure (vertex
    counts vary within a power of two), and give the same result as a fresh function."""
    traced = []

    def field(r, x):
        traced.append(isinstance(x, jax.core.Tracer))
        return jnp.linalg.norm(x, axis=-1) - r

    grid = voxax.Grid.cube(16)
    first = voxax.isosurface_fn(field, 0.5, grid)
    n = len(traced)
    assert n and all(traced)
    counts = set()
    for r in (0.5, 0.53, 0.56, 0.6):  # 312 to 449 vertices: one bucket of 512
        iso = voxax.isosurface_fn(field, r, grid)
        counts.add(int(iso.n_vertices))
        g = jax.grad(lambda r: jnp.sum(voxax.isosurface_fn(field, r, grid).vertices))(r)
        assert np.isfinite(g)
    assert len(counts) > 1 and len(traced) <= n + 2  # the gradient's trace, at most
    fresh = voxax.isosurface_fn(lambda r, x: jnp.linalg.norm(x, axis=-1) - r, 0.5, grid)
    assert np.asarray(fresh.vertices).tobytes() == np.asarray(first.vertices).tobytes()
    # a field written with NumPy (not traceable) still runs, uncompiled
    np_field = lambda r, x: np.linalg.norm(np.asarray(x), axis=-1) - r  # noqa: E731
    out = voxax.isosurface_fn(np_field, 0.5, grid, rule="interpolation")
    assert np.array_equal(out.faces, first.faces)
