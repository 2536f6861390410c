"""Tests of `voxax.filters`: Monte Carlo voxelization with general kernels, and box_filter.

What is compared with what:

- Forward, box of radius 0.5: the Monte Carlo estimate against the exact one-voxel
  `voxelize` (its expectation), with the RMS error over the grid falling like
  1/sqrt(samples) for plain Monte Carlo (`strata=1`), and faster with the default
  stratification.
- Forward, Gaussian: against the exact smoothed winding number of an axis-aligned rectangle
  (a product over the axes of truncated-normal probabilities, i.e. erf differences), within
  4 standard errors; the standard error of plain Monte Carlo with w in {0, 1} is
  sqrt(W (1 - W) / samples), and stratification can only lower it.
- Backward: the forward estimate is piecewise constant in the vertices, so its finite
  differences say nothing. Instead the Monte Carlo gradient is compared with exact
  gradients of the same smoothed quantity: with the closed-form `voxelize` gradient for the
  box of radius 0.5, with `box_filter(voxelize, 3)`'s gradient for the box of radius 1.5,
  and with finite differences of the exact erf formula for the Gaussian (moving one edge
  of the rectangle), statistically (mean and spread over independent keys).
"""

import functools

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from jax.scipy.special import erf

import voxax
from voxax import Box, Gaussian, box_filter, voxelize_mc, voxelize_mc_tangent

STAR = voxax.data.star_polyline(center=(0.031, 0.017))
GRID2 = voxax.Grid.cube(24, dim=2)
LO, HI = np.array([-0.43, -0.31]), np.array([0.37, 0.52])
RECT = voxax.data.polygon_square(LO, HI)  # vertices: (lo,lo), (hi,lo), (hi,hi), (lo,hi)


def _exact_rect(lo, hi, grid, kernel):
    """The Gaussian-smoothed winding number of the rectangle [lo, hi] at the voxel centres."""
    c = jnp.asarray(grid.centers())
    out = 1.0
    mass = erf(kernel.truncate / np.sqrt(2))
    for a in range(2):
        s = kernel.sigma * grid.spacing[a]
        T = kernel.truncate * s

        def cdf(x, T=T, s=s):  # CDF of the normal truncated to [-T, T] (renormalized)
            return (erf(jnp.clip(x, -T, T) / (s * np.sqrt(2))) + mass) / (2 * mass)

        out = out * (cdf(hi[a] - c[..., a]) - cdf(lo[a] - c[..., a]))
    return out


def _grad(fn, vertices, cot):
    return jax.grad(lambda v: jnp.sum(cot * fn(v)))(jnp.asarray(vertices))


@functools.partial(jax.jit, static_argnames=("grid", "kernel", "surface_samples"))
def _mc_grad(vertices, faces, cot, key, grid, kernel, surface_samples):
    """The Monte Carlo gradient of sum(cot * W) (one compilation per setting, shared by tests)."""
    fn = lambda v: jnp.sum(cot * voxelize_mc(v, faces, grid, kernel, key, samples=1, surface_samples=surface_samples))
    return jax.grad(fn)(vertices)


def _mc_grads(mesh, grid, kernel, n, cot, seed, runs=8):
    keys = jax.random.split(jax.random.key(seed), runs)
    return np.stack([np.asarray(_mc_grad(mesh.vertices, mesh.faces, cot, k, grid, kernel, n)) for k in keys])


def _rel(a, b):
    return float(np.linalg.norm(np.asarray(a) - np.asarray(b)) / np.linalg.norm(np.asarray(b)))


def test_box_half_converges_to_voxelize_like_one_over_sqrt_n():
    W = voxax.voxelize(STAR.vertices, STAR.faces, GRID2)

    def rms(n, strata):
        Wm = voxelize_mc(STAR.vertices, STAR.faces, GRID2, Box(0.5), jax.random.key(0), samples=n, strata=strata)
        return float(jnp.sqrt(jnp.mean((Wm - W) ** 2)))

    iid = rms(16, 1) / rms(256, 1)
    assert 2.5 < iid < 6.0, iid  # 1/sqrt(N): sqrt(16) = 4
    strat = rms(16, None) / rms(256, None)
    assert strat > iid  # 4x4 -> 16x16 strata: ~ N^-(3/4) in 2D, ratio ~ 8
    assert rms(256, None) < 0.01


def test_box_half_3d_and_reproducibility():
    b = voxax.data.box((-0.37, -0.29, -0.41), (0.33, 0.45, 0.22))
    grid = voxax.Grid.cube(6)
    W = voxax.voxelize(b.vertices, b.faces, grid)
    key = jax.random.key(7)
    Wm = voxelize_mc(b.vertices, b.faces, grid, Box(0.5), key, samples=64)
    se = np.sqrt(np.clip(W * (1 - W), 0, None) / 64)
    assert np.all(np.abs(Wm - W) <= 4 * se + 1 / 64 + 1e-12)
    again = voxelize_mc(b.vertices, b.faces, grid, Box(0.5), key, samples=64)
    assert np.array_equal(np.asarray(again), np.asarray(Wm))  # same key -> same bits
    other = voxelize_mc(b.vertices, b.faces, grid, Box(0.5), jax.random.key(8), samples=64)
    assert not np.array_equal(np.asarray(other), np.asarray(Wm))
    # The backward against the closed-form gradient of voxelize.
    cot = np.random.default_rng(0).normal(size=grid.shape)
    exact = _grad(lambda v: voxax.voxelize(v, b.faces, grid), b.vertices, cot)
    mc = _mc_grads(b, grid, Box(0.5), 256, cot, 0, runs=4)
    assert _rel(mc.mean(0), exact) < 0.05


def test_gaussian_forward_matches_the_erf_formula():
    ker = Gaussian(1.3, truncate=2.0)  # 4.5% of the mass cut off: truncation matters
    We = np.asarray(_exact_rect(LO, HI, GRID2, ker))
    n = 256
    se = np.sqrt(np.clip(We * (1 - We), 0, None) / n)
    Wm = np.asarray(voxelize_mc(RECT.vertices, RECT.faces, GRID2, ker, jax.random.key(3), samples=n))
    assert np.all(np.abs(Wm - We) <= 4 * se + 1.0 / n)
    # Plain Monte Carlo: the standardised errors have unit variance.
    Wi = np.asarray(voxelize_mc(RECT.vertices, RECT.faces, GRID2, ker, jax.random.key(3), samples=n, strata=1))
    mid = (We > 0.05) & (We < 0.95)
    z = (Wi - We)[mid] / se[mid]
    assert mid.sum() > 50 and 0.7 < np.mean(z**2) < 1.4 and np.abs(z).max() < 5
    # Truncation matters: the untruncated normal would differ by more than the noise.
    assert np.abs(np.asarray(_exact_rect(LO, HI, GRID2, Gaussian(1.3, truncate=1.0))) - We).max() > 0.05


def test_box_half_backward_matches_the_closed_form_statistically():
    cot = np.random.default_rng(1).normal(size=GRID2.shape)
    exact = np.asarray(_grad(lambda v: voxax.voxelize(v, STAR.faces, GRID2), STAR.vertices, cot))

    runs = _mc_grads(STAR, GRID2, Box(0.5), 64, cot, 5)
    mean, sem = runs.mean(0), runs.std(0, ddof=1) / np.sqrt(len(runs))
    assert np.all(np.abs(mean - exact) <= 5 * sem + 1e-9 * np.abs(exact).max())
    assert _rel(mean, exact) < 0.05
    assert np.all(sem > 0)  # the estimator is random (the test can fail)


def test_gaussian_backward_matches_fd_of_the_erf_formula():
    ker = Gaussian(1.3, truncate=2.0)  # 4.5% of the mass cut off: truncation matters
    cot = np.random.default_rng(2).normal(size=GRID2.shape)
    energy = lambda lo, hi: float(jnp.sum(cot * _exact_rect(lo, hi, GRID2, ker)))
    eps = 1e-6
    # Moving one edge of the rectangle: lo_x (vertices 0, 3), hi_x (1, 2), lo_y (0, 1), hi_y (2, 3).
    edges = {"lo_x": (0, 0, (0, 3)), "hi_x": (1, 0, (1, 2)), "lo_y": (0, 1, (0, 1)), "hi_y": (1, 1, (2, 3))}
    fd = {}
    for name, (side, axis, _) in edges.items():
        d = np.zeros(2)
        d[axis] = eps
        lo_p, hi_p = (LO + d, HI) if side == 0 else (LO, HI + d)
        lo_m, hi_m = (LO - d, HI) if side == 0 else (LO, HI - d)
        fd[name] = (energy(lo_p, hi_p) - energy(lo_m, hi_m)) / (2 * eps)

    runs = _mc_grads(RECT, GRID2, ker, 256, cot, 9)
    for name, (_, axis, verts) in edges.items():
        est = runs[:, verts, axis].sum(axis=1)
        mean, sem = est.mean(), est.std(ddof=1) / np.sqrt(len(est))
        assert abs(mean - fd[name]) <= 5 * sem + 1e-6 * abs(fd[name]), (name, mean, fd[name], sem)
        assert abs(mean - fd[name]) < 0.01 * abs(fd[name])


def test_tangent_is_the_adjoint_of_the_vjp():
    rng = np.random.default_rng(3)
    for mesh, grid, ker, n in [
        (STAR, GRID2, Box(1.5), 256),
        (voxax.data.box((-0.37, -0.29, -0.41), (0.33, 0.45, 0.22)), voxax.Grid.cube(6), Box(0.5), 256),
    ]:
        cot, t = rng.normal(size=grid.shape), rng.normal(size=mesh.vertices.shape)
        key = jax.random.key(2)
        vjp = _mc_grad(mesh.vertices, mesh.faces, cot, key, grid, ker, n)
        tan = voxelize_mc_tangent(mesh.vertices, mesh.faces, grid, ker, key, t, surface_samples=n)
        np.testing.assert_allclose(np.sum(cot * tan), np.sum(vjp * t), rtol=1e-10)


def test_box_filter_matches_a_wide_mc_box_and_the_volume_identity():
    W = voxax.voxelize(STAR.vertices, STAR.faces, GRID2)
    B = np.asarray(box_filter(W, 3))
    # Volume identity: the star keeps > 1 voxel from the border.
    np.testing.assert_allclose(B.sum() * GRID2.voxel_volume, STAR.signed_volume(), rtol=1e-12)
    n = 256
    Wm = np.asarray(voxelize_mc(STAR.vertices, STAR.faces, GRID2, Box(1.5), jax.random.key(0), samples=n))
    se = np.sqrt(np.clip(B * (1 - B), 0, None) / n)
    assert np.all(np.abs(Wm - B) <= 4 * se + 1.0 / n)
    assert np.abs(Wm - B).max() > 0  # an estimate, not a copy
    # Gradients: box_filter is differentiated by JAX; compare with the MC backward.
    cot = np.random.default_rng(4).normal(size=GRID2.shape)
    exact = _grad(lambda v: box_filter(voxax.voxelize(v, STAR.faces, GRID2), 3), STAR.vertices, cot)
    mc = _mc_grad(STAR.vertices, STAR.faces, cot, jax.random.key(1), GRID2, Box(1.5), 256)
    assert _rel(mc, exact) < 0.02


def test_box_filter_windows_batches_and_errors():
    rng = np.random.default_rng(5)
    W = rng.normal(size=(2, 7, 6))
    # Even factor: voxels i .. i + 1 per axis (centred on the upper corner of voxel i).
    P = np.pad(W, ((0, 0), (0, 1), (0, 1)))
    ref2 = (P[:, :-1, :-1] + P[:, 1:, :-1] + P[:, :-1, 1:] + P[:, 1:, 1:]) / 4
    np.testing.assert_allclose(box_filter(W, 2, dim=2), ref2, atol=1e-14)
    # Odd factor in 3D, against a direct sum with zero padding.
    V = rng.normal(size=(5, 4, 6))
    P = np.pad(V, 1)
    ref3 = sum(P[i : i + 5, j : j + 4, k : k + 6] for i in range(3) for j in range(3) for k in range(3)) / 27
    np.testing.assert_allclose(box_filter(V, 3), ref3, atol=1e-14)
    np.testing.assert_array_equal(box_filter(V, 1), V)
    g = jax.grad(lambda x: jnp.sum(box_filter(x, 3) * V))(jnp.asarray(V))
    np.testing.assert_allclose(g, box_filter(V, 3), atol=1e-14)  # a symmetric (self-adjoint) filter
    with pytest.raises(ValueError, match="dim"):
        box_filter(W[None], 3)
    with pytest.raises(ValueError, match="factor"):
        box_filter(V, 0)
    with pytest.raises(TypeError, match="`factor` must be an int"):
        box_filter(V, 1.5)
    with pytest.raises(ValueError, match="`factor` must be at most"):
        box_filter(V, 2**31)  # a box wider than twice the grid: refused, not a reduction that never ends


def test_batches_dtypes_and_bad_input():
    key = jax.random.key(0)
    v = np.stack([STAR.vertices, STAR.vertices * 0.8])
    both = voxelize_mc(v, STAR.faces, GRID2, Gaussian(1.0), key, samples=16)
    one = voxelize_mc(v[1], STAR.faces, GRID2, Gaussian(1.0), key, samples=16)
    assert both.shape == (2,) + GRID2.shape
    np.testing.assert_allclose(both[1], one, atol=1e-12)
    w32 = voxelize_mc(STAR.vertices.astype(np.float32), STAR.faces, GRID2, Gaussian(1.0), jax.random.PRNGKey(0), samples=16)
    assert w32.dtype == jnp.float32 and np.all(np.isfinite(w32))
    with pytest.raises(TypeError, match="key"):
        voxelize_mc(STAR.vertices, STAR.faces, GRID2, Box(1.0), 0.5)
    with pytest.raises(TypeError, match="kernel"):
        voxelize_mc(STAR.vertices, STAR.faces, GRID2, "box", key)
    with pytest.raises(ValueError, match="radius"):
        Box(-1.0)
    with pytest.raises(ValueError, match="sigma"):
        Gaussian(0.0)
    with pytest.raises(ValueError, match="vertices"):
        voxelize_mc(STAR.vertices, STAR.faces, voxax.Grid.cube(4), Box(1.0), key)
    with pytest.raises(ValueError, match="face indices"):
        voxelize_mc(STAR.vertices, STAR.faces + 100, GRID2, Box(1.0), key)
