"""The soft double-height-field hull on grids and the two-piece-mould application."""

import importlib.util
import pathlib

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from voxax import energies, esi


def _exact_hull(B, axis):
    """Exact DHF of a binary grid: occupied somewhere before-or-at and after-or-at."""
    pre = np.maximum.accumulate(B, axis=axis)
    suf = np.flip(np.maximum.accumulate(np.flip(B, axis), axis=axis), axis)
    return np.minimum(pre, suf)


@pytest.mark.parametrize("axis", [0, 1, 2])
def test_soft_hull_of_a_binary_grid_tends_to_the_exact_hull(axis):
    B = (np.random.default_rng(axis).random((6, 7, 8)) < 0.2).astype(np.float64)
    H = np.asarray(jax.jit(esi.height_field_hull, static_argnums=(1, 2))(jnp.asarray(B), axis, 1e4))
    # mellowmax undershoots the maximum by at most log(n) / w
    np.testing.assert_allclose(H, _exact_hull(B, axis), atol=np.log(8) / 1e4 + 1e-12)
    # the hull lies inside the silhouette extrusion along the same axis (the bandsaw's)
    sil = np.asarray(jax.jit(energies.silhouettes, static_argnums=1)(jnp.asarray(B), 1e4)[axis])
    assert np.all(H <= np.expand_dims(sil, axis) + np.log(8) / 1e4)


def test_esi_gap_is_zero_exactly_for_height_fields():
    B = np.zeros((4, 4, 6))
    B[1:3, 1:3, 1:5] = 1.0
    gap = jax.jit(esi.esi_gap, static_argnums=(1, 2))
    assert float(gap(jnp.asarray(B), (0, 1, 2), 1e4)) < 1e-8
    B2 = B.copy()
    B2[1:3, 1:3, 2:4] = 0.0  # a hole inside the column: an undercut along z only
    assert float(gap(jnp.asarray(B2), (2,), 1e4)) > 1e-2
    with pytest.raises(ValueError, match="axis"):
        esi.height_field_hull(jnp.asarray(B), 3)


def test_molding_example_runs(tmp_path):
    # also the gradient path: the application minimizes esi_gap through voxax.voxelize
    path = pathlib.Path(__file__).resolve().parents[2] / "examples" / "molding.py"
    spec = importlib.util.spec_from_file_location("voxax_example_molding", path)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    argv = ["--resolution", "12", "--max-steps", "3", "--out", str(tmp_path), "--quiet"]
    assert module.main(argv) == 0
    for name in ("input.ply", "optimized.ply", "hull_input.ply", "history.png"):
        assert (tmp_path / name).exists(), name


def test_molding_app_rejects_bad_axes():
    import voxax.apps
    from voxax import data

    with pytest.raises(ValueError, match="axis"):
        voxax.apps.optimize_for_molding(data.cube(1.0), 3)
    with pytest.raises(ValueError, match="axis"):
        voxax.apps.optimize_for_molding(data.cube(1.0), True)
