"""Tests of `voxax.curves`: differentiable parametric curves, composed with voxelization."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import voxax
from voxax import Box, box_filter, curves

GRID = voxax.Grid.cube(32, dim=2)
KAPPA = 0.5522847498  # cubic Bezier approximation of a quarter circle


def _bezier_circle(r=0.5, c=(0.02, -0.03)):
    k = KAPPA
    unit = np.array(
        [[1, 0], [1, k], [k, 1], [0, 1], [-k, 1], [-1, k], [-1, 0], [-1, -k], [-k, -1], [0, -1], [k, -1], [1, -k]],
        dtype=float,
    )
    return unit * r + np.asarray(c)


def test_circle_polygon_area_and_gradients():
    n, r = 96, 0.47
    c = curves.circle(jnp.array([0.05, -0.02]), r, n)
    assert c.vertices.shape == (n, 2) and c.faces.shape == (n, 2)
    np.testing.assert_allclose(np.linalg.norm(np.asarray(c.vertices) - [0.05, -0.02], axis=1), r, rtol=1e-14)

    def area(center, radius):
        return voxax.voxelize(*curves.circle(center, radius, n), GRID).sum() * GRID.voxel_volume

    a, (gc, gr) = jax.value_and_grad(area, argnums=(0, 1))(jnp.array([0.05, -0.02]), r)
    np.testing.assert_allclose(a, n / 2 * r**2 * np.sin(2 * np.pi / n), rtol=1e-12)
    np.testing.assert_allclose(gr, n * r * np.sin(2 * np.pi / n), rtol=1e-10)  # d area / d r
    np.testing.assert_allclose(gc, 0.0, atol=1e-10)  # translation inside the grid keeps the area


def test_bezier_closed_interpolates_anchors_and_approximates_a_circle():
    P = _bezier_circle()
    c = curves.bezier_closed(P, 16)
    assert c.vertices.shape == (64, 2)
    np.testing.assert_allclose(c.vertices[::16], P[::3], atol=1e-15)  # anchors are vertices
    t = jnp.arange(64) / 64
    np.testing.assert_allclose(curves.bezier_point(P, t), c.vertices, atol=1e-14)
    radii = np.linalg.norm(np.asarray(c.vertices) - [0.02, -0.03], axis=1)
    np.testing.assert_allclose(radii, 0.5, rtol=3e-4)
    area = voxax.voxelize(*curves.bezier_closed(P, 64), GRID).sum() * GRID.voxel_volume
    np.testing.assert_allclose(area, np.pi * 0.25, rtol=1e-3)
    with pytest.raises(ValueError, match="3K"):
        curves.bezier_closed(P[:5])


def test_gradients_flow_to_control_points():
    P = jnp.asarray(_bezier_circle())
    cot = jnp.asarray(np.random.default_rng(0).normal(size=GRID.shape))
    energy = jax.jit(lambda p: jnp.sum(cot * voxax.voxelize(*curves.bezier_closed(p, 32), GRID)))
    g = jax.jit(jax.grad(energy))(P)
    assert g.shape == P.shape and np.abs(g).max() > 0
    eps = 1e-6
    for i, j in [(0, 0), (1, 0), (4, 1), (11, 1)]:
        d = jnp.zeros_like(P).at[i, j].set(eps)
        fd = (energy(P + d) - energy(P - d)) / (2 * eps)
        np.testing.assert_allclose(g[i, j], fd, rtol=1e-6, atol=1e-8)


def test_mc_on_the_exact_circle():
    # The Monte Carlo gradient samples the exact circle; compare with the exact gradient of
    # the box-3 filter of a fine polygon (2048 segments: its own error is ~1e-6).
    params = jnp.array([0.05, -0.02, 0.47])
    cot = jnp.asarray(np.random.default_rng(1).normal(size=GRID.shape))
    key = jax.random.key(0)
    mc_fn = lambda p: jnp.sum(cot * curves.voxelize_curve_mc(curves.circle_point, p, GRID, Box(1.5), key, samples=4, curve_samples=4096, segments=256))
    fine = lambda p: jnp.sum(cot * box_filter(voxax.voxelize(*curves.polyline(curves.circle_point, p, 2048), GRID), 3))
    g_mc, g_ref = jax.grad(mc_fn)(params), jax.grad(fine)(params)
    np.testing.assert_allclose(g_mc, g_ref, rtol=0.02, atol=0.02 * float(jnp.abs(g_ref).max()))
    # Forward: unbiased estimate of the box-3 filtered circle.
    W = curves.voxelize_curve_mc(curves.circle_point, params, GRID, Box(1.5), key, samples=64, segments=256)
    ref = np.asarray(box_filter(voxax.voxelize(*curves.polyline(curves.circle_point, params, 2048), GRID), 3))
    se = np.sqrt(np.clip(ref * (1 - ref), 0, None) / 64)
    assert np.all(np.abs(np.asarray(W) - ref) <= 4 * se + 1 / 64)
    W2 = curves.voxelize_curve_mc(curves.circle_point, params, GRID, Box(1.5), key, samples=64, segments=256)
    assert np.array_equal(np.asarray(W), np.asarray(W2))
