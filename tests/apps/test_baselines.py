"""Tests of `voxax.baselines.point_sampled`, the "discretise, then differentiate" baseline
of the paper's Sec. 4.1 / Fig. 6: its derivatives vanish, voxax's match finite differences."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import voxax
from voxax import baselines, curves

GRID = voxax.Grid.cube(24, dim=2)
STAR = voxax.data.star_polyline(center=(0.031, 0.017))


def _shapes():
    # (name, vertices as a function of a scalar parameter, faces, parameter value)
    return [
        ("polygon, translation x", lambda t: jnp.asarray(STAR.vertices) + t * jnp.array([1.0, 0.0]), STAR.faces, 0.0),
        ("circle, radius", lambda r: curves.circle(jnp.array([0.013, -0.021]), r, 128).vertices, curves.circle((0, 0), 1, 128).faces, 0.47),
    ]


def test_point_samples_are_the_ray_count():
    for mesh, grid in [(STAR, GRID), (voxax.data.overlapping_squares(), voxax.Grid.cube(15, dim=2)), (voxax.data.overlapping_cubes(), voxax.Grid.cube(9))]:
        P = np.asarray(baselines.point_sampled(mesh.vertices, mesh.faces, grid))
        ray = voxax.reference.winding_number_ray(mesh.vertices, mesh.faces, grid.centers().reshape(-1, grid.dim))
        np.testing.assert_array_equal(P, ray.reshape(grid.shape))
    assert P.max() == 2.0
    inv = voxax.data.with_inverted_component(subdivisions=1)
    assert np.asarray(baselines.point_sampled(inv.vertices, inv.faces, voxax.Grid.cube(9))).min() == -1.0


@pytest.mark.parametrize("name, shape, faces, t0", _shapes(), ids=[s[0] for s in _shapes()])
def test_derivatives_vanish_for_point_sampling_but_not_for_voxax(name, shape, faces, t0):
    t0 = jnp.asarray(t0, jnp.float64)
    # Point sampling: piecewise constant in the parameter.
    base = lambda t: baselines.point_sampled(shape(t), faces, GRID)
    h = 1e-7
    fd_base = (base(t0 + h) - base(t0 - h)) / (2 * h)
    assert np.all(np.asarray(fd_base) == 0.0)
    assert np.all(np.asarray(jax.jacfwd(base)(t0)) == 0.0)
    assert np.all(np.asarray(jax.grad(lambda t: jnp.sum(base(t) * GRID.centers()[..., 0]))(t0)) == 0.0)
    # voxax: the full grid of derivatives (jacrev) matches central finite differences.
    vox = lambda t: voxax.voxelize(shape(t), faces, GRID)
    ad = np.asarray(jax.jacrev(vox)(t0))
    eps = 1e-6
    fd = np.asarray((vox(t0 + eps) - vox(t0 - eps)) / (2 * eps))
    assert np.linalg.norm(fd) > 1.0  # the shape does move the voxel values
    np.testing.assert_allclose(ad, fd, atol=1e-7 * np.abs(fd).max())


def test_supersampling_and_interpolation():
    # More samples per voxel approach the box filter but stay piecewise constant.
    W = np.asarray(voxax.voxelize(STAR.vertices, STAR.faces, GRID))
    errs = [np.abs(np.asarray(baselines.point_sampled(STAR.vertices, STAR.faces, GRID, supersample=s)) - W).mean() for s in (1, 4)]
    assert errs[1] < 0.5 * errs[0]
    g = jax.grad(lambda v: jnp.sum(baselines.point_sampled(v, STAR.faces, GRID, supersample=2) ** 2))(jnp.asarray(STAR.vertices))
    assert np.all(np.asarray(g) == 0.0)
    # Interpolation: exact at the centres, reproduces linear functions between them.
    c = GRID.centers()
    lin = 0.3 * c[..., 0] - 1.2 * c[..., 1] + 0.5
    np.testing.assert_allclose(baselines.interpolate(lin, GRID, c), lin, atol=1e-13)
    q = np.random.default_rng(0).uniform(-0.9, 0.9, size=(50, 2))
    np.testing.assert_allclose(baselines.interpolate(lin, GRID, q), 0.3 * q[:, 0] - 1.2 * q[:, 1] + 0.5, atol=1e-12)
    vals = baselines.point_sampled(STAR.vertices, STAR.faces, GRID, points=q)
    assert vals.shape == (50,)
    with pytest.raises(ValueError, match="supersample"):
        baselines.point_sampled(STAR.vertices, STAR.faces, GRID, supersample=0)
