"""`voxax.least_squares`: Levenberg-Marquardt, Gauss-Newton and dogleg on voxel residuals."""

import importlib.util
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import voxax

EXAMPLE = Path(__file__).resolve().parents[2] / "examples" / "fit_template_lm.py"


@pytest.mark.parametrize("solver", ["levenberg_marquardt", "gauss_newton", "dogleg"])
def test_solvers_on_an_analytic_problem(solver):
    a = jnp.array([2.0, 4.0, 9.0])
    res = voxax.least_squares(lambda y, args: y**2 - args, jnp.array([1.0, 3.0, 2.0]), a, solver=solver,
                              rtol=1e-10, atol=1e-12)
    assert res.converged
    np.testing.assert_allclose(res.value, np.sqrt([2.0, 4.0, 9.0]), rtol=1e-9)
    assert res.loss < 1e-16


def test_bad_arguments():
    with pytest.raises(ValueError, match="unknown solver"):
        voxax.least_squares(lambda y, a: y, jnp.ones(2), solver="newton")
    with pytest.raises(TypeError, match="solver"):
        voxax.least_squares(lambda y, a: y, jnp.ones(2), solver=3)
    with pytest.raises(ValueError, match="max_steps"):
        voxax.least_squares(lambda y, a: y, jnp.ones(2), max_steps=0)


def test_levenberg_marquardt_fits_a_template_to_a_voxelization():
    """A small version of examples/fit_template_lm.py: LM converges, the fitted mesh's
    voxelization is close to the target, and the result is a stationary point of the
    loss (its gradient, by reverse mode, vanishes)."""
    spec = importlib.util.spec_from_file_location("fit_template_lm", EXAMPLE)
    ex = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(ex)
    residuals, d0, grid = ex.problem(10, 1, "ellipsoid", 1e-2)
    initial = ex.loss_of(residuals, d0)
    res = voxax.least_squares(residuals, d0, rtol=1e-6, atol=1e-9, max_steps=60)
    assert res.converged, res.message
    assert res.steps < 60
    assert res.loss < 0.01 * initial
    loss = lambda d: 0.5 * sum(jnp.sum(r**2) for r in residuals(d, None))  # noqa: E731
    g0 = np.abs(np.asarray(jax.grad(loss)(d0))).max()
    g = np.abs(np.asarray(jax.grad(loss)(res.value))).max()
    assert g < 1e-3 * g0
    voxel_residual = np.asarray(residuals(res.value, None)[0])
    assert np.abs(voxel_residual).sum() * grid.voxel_volume < 0.05  # of a target volume ~0.5


def test_example_runs(capsys):
    spec = importlib.util.spec_from_file_location("fit_template_lm", EXAMPLE)
    ex = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(ex)
    assert ex.main(["-n", "8", "--subdivisions", "1", "--lm-steps", "10", "--adam-steps", "50"]) == 0
    out = capsys.readouterr().out
    assert "Levenberg-Marquardt (" in out and "loss" in out and "Adam (lr" in out
