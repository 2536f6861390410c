"""Curved closed meshes against independent oracles.

- Exact volumes: for every voxel that a triangle may touch, manifold3d intersects the
  solid with the voxel's box (a mesh boolean, computed in double precision by a library
  that shares nothing with voxax) and measures the volume of the result. `voxax.voxelize`
  must give the same fraction of the voxel to 1e-9 on off-centre, anisotropic grids with
  odd cell counts, for a torus, the `hand` and a smooth star-shaped blob.
- Monte Carlo: `voxax.voxelize_mc` with the one-voxel `Box(0.5)` is an unbiased,
  stratified estimate of the same values; its deviations from `voxax.voxelize` must have
  the mean and spread that the exact per-stratum variances predict.
"""

from __future__ import annotations

import jax
import numpy as np
import pytest

import voxax

m3 = pytest.importorskip("manifold3d")

TOL = 1e-9


def _blob() -> voxax.Mesh:
    """A smooth, star-shaped blob: an icosphere with a radius that varies with direction."""
    s = voxax.data.icosphere(3)
    u = np.asarray(s.vertices, dtype=np.float64)
    u = u / np.linalg.norm(u, axis=1, keepdims=True)
    r = 0.62 * (1 + 0.18 * np.sin(3 * u[:, 0] + 1) * np.cos(2 * u[:, 1]) + 0.1 * u[:, 2] ** 3)
    return voxax.Mesh(u * r[:, None] * np.array([1.0, 0.8, 1.1]), s.faces)


CASES = {
    # off-centre, anisotropic cells, odd counts; the torus pokes out of the grid along -x
    "torus": (lambda: voxax.data.torus(), voxax.Grid((-0.77, -0.91, -0.33), (0.93, 0.87, 0.41), (17, 13, 9))),
    "hand": (lambda: voxax.data.hand(), voxax.Grid((-0.71, -0.79, -0.23), (0.73, 0.81, 0.25), (15, 19, 7))),
    "blob": (_blob, voxax.Grid((-0.69, -0.57, -0.71), (0.75, 0.61, 0.77), (11, 9, 13))),
}


def _solid(mesh) -> m3.Manifold:
    solid = m3.Manifold(
        m3.Mesh64(
            vert_properties=np.array(mesh.vertices, dtype=np.float64),
            tri_verts=np.array(mesh.faces, dtype=np.uint64),
        )
    )
    assert solid.status() == m3.Error.NoError, solid.status()
    return solid


def _touched(mesh, grid) -> np.ndarray:
    """A mask of the voxels whose box meets the bounding box of some triangle, grown by
    one voxel: a superset of the voxels the surface passes through (without voxax)."""
    lower, h, shape = np.asarray(grid.lower), np.asarray(grid.spacing), np.asarray(grid.shape)
    tri = np.asarray(mesh.vertices, dtype=np.float64)[np.asarray(mesh.faces)]
    lo = np.clip(np.floor((tri.min(axis=1) - lower) / h).astype(int) - 1, 0, shape - 1)
    hi = np.clip(np.floor((tri.max(axis=1) - lower) / h).astype(int) + 1, 0, shape - 1)
    touched = np.zeros(grid.shape, dtype=bool)
    for a, b in zip(lo, hi):
        touched[a[0] : b[0] + 1, a[1] : b[1] + 1, a[2] : b[2] + 1] = True
    return touched


def _box(grid, ijk) -> m3.Manifold:
    lower, h = np.asarray(grid.lower), np.asarray(grid.spacing)
    a = lower + np.asarray(ijk) * h
    b = lower + (np.asarray(ijk) + 1) * h
    return m3.Manifold.cube(tuple(float(x) for x in b - a)).translate(tuple(float(x) for x in a))


def _oracle(solid, grid, voxels) -> np.ndarray:
    """The fraction of each voxel's box inside the solid, by mesh booleans."""
    out = np.empty(len(voxels))
    for n, ijk in enumerate(voxels):
        box = _box(grid, ijk)
        out[n] = (solid ^ box).volume() / box.volume()
    return out


@pytest.fixture(scope="module", autouse=True)
def _x64():
    previous = jax.config.jax_enable_x64
    jax.config.update("jax_enable_x64", True)
    yield
    jax.config.update("jax_enable_x64", previous)


@pytest.mark.parametrize("name", sorted(CASES))
def test_voxelize_equals_exact_boolean_volumes_on_curved_meshes(name):
    make, grid = CASES[name]
    mesh = make()
    solid = _solid(mesh)
    assert solid.volume() == pytest.approx(float(mesh.signed_volume()), rel=1e-12)
    W = np.asarray(voxax.voxelize(np.asarray(mesh.vertices, np.float64), mesh.faces, grid))
    assert W.dtype == np.float64 and W.shape == grid.shape

    mask = _touched(mesh, grid)
    touched = np.argwhere(mask)
    expected = _oracle(solid, grid, touched)
    got = W[tuple(touched.T)]
    err = np.abs(got - expected)
    assert err.max() <= TOL, f"{name}: max |W - boolean| = {err.max():.3e} at voxel {touched[err.argmax()]}"
    # Several hundred of them are genuinely cut by the surface (762, 675 and 394 voxels).
    cut = (expected > 1e-6) & (expected < 1 - 1e-6)
    assert cut.sum() >= 300, cut.sum()

    # Every other voxel is entirely inside or outside: check a sample of them too.
    others = np.argwhere(~mask)
    rng = np.random.default_rng(0)
    sample = others[rng.choice(len(others), size=min(40, len(others)), replace=False)]
    expected = _oracle(solid, grid, sample)
    assert np.all((expected < 1e-12) | (expected > 1 - 1e-12))
    np.testing.assert_allclose(W[tuple(sample.T)], expected, rtol=0, atol=TOL)


def test_voxelize_mc_box_is_voxelize_within_its_standard_error():
    """`voxelize_mc(..., Box(0.5))` draws `n` uniform samples in each of the `m^3` equal
    sub-cells of a voxel and averages the winding number, which is 0 or 1 for this closed
    torus. With `p_s` the exact fraction of sub-cell `s` inside the solid (`voxelize` on
    the `m`-times finer grid), the estimate of a voxel has mean `mean_s p_s` (= `voxelize`)
    and variance `sum_s p_s (1 - p_s) / n / m^6`; its fourth cumulant follows the same way.
    The aggregate error, the mean z-score and the mean squared z-score must agree with
    these to within 4 standard errors; voxels with zero variance must be exact."""
    mesh = voxax.data.torus(n_major=24, n_minor=12)
    grid = voxax.Grid((-0.95, -0.83, -0.31), (0.91, 0.97, 0.35), (13, 12, 7))
    m, n = 2, 1
    v = np.asarray(mesh.vertices, np.float64)
    W = np.asarray(voxax.voxelize(v, mesh.faces, grid))
    W_mc = np.asarray(
        voxax.voxelize_mc(v, mesh.faces, grid, voxax.Box(0.5), jax.random.key(0), samples=n * m**3, strata=m)
    )
    assert W_mc.shape == grid.shape and W_mc.dtype == np.float64

    fine = voxax.Grid(grid.lower, grid.upper, tuple(m * s for s in grid.shape))
    p = np.asarray(voxax.voxelize(v, mesh.faces, fine)).clip(0.0, 1.0)
    p = p.reshape(grid.shape[0], m, grid.shape[1], m, grid.shape[2], m)
    np.testing.assert_allclose(p.mean(axis=(1, 3, 5)), W, atol=1e-12)  # the estimator's mean
    c = 1.0 / m**3
    q = p * (1 - p)
    var = (c**2 * q / n).sum(axis=(1, 3, 5))
    kappa4 = (c**4 * q * (1 - 6 * q) / n**3).sum(axis=(1, 3, 5))

    d = W_mc - W
    # Voxels whose sub-cells are all inside or all outside: no randomness at all.
    exact = var == 0
    assert np.abs(d[exact]).max() <= 1e-10
    # The sum over all voxels (independent estimates).
    assert abs(d.sum()) <= 4 * np.sqrt(var.sum()), (d.sum(), np.sqrt(var.sum()))
    # z-scores of the voxels with a standard error of at least 0.02 (smaller ones have
    # rare, huge z-scores, a heavy tail that says nothing about the mean).
    ok = var >= 0.02**2
    N = int(ok.sum())
    assert N >= 300, N
    z = d[ok] / np.sqrt(var[ok])
    assert abs(z.mean()) <= 4 / np.sqrt(N), z.mean()
    var_z2 = 3 + kappa4[ok] / var[ok] ** 2 - 1  # Var(z^2) = E[z^4] - 1
    assert abs((z**2).mean() - 1) <= 4 * np.sqrt(var_z2.sum()) / N, ((z**2).mean(), np.sqrt(var_z2.sum()) / N)
