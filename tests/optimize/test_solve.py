"""`voxax.minimize`: solvers, stopping rules, history, callbacks, compile-once."""

import dataclasses

import jax.numpy as jnp
import numpy as np
import optax
import optimistix as optx
import pytest
from conftest import random_star_mesh

import voxax
from voxax import MinimizeResult, StopRules, minimize
from voxax import energies as E


def rosenbrock(y, args):
    return jnp.sum(100.0 * (y[1:] - y[:-1] ** 2) ** 2 + (1.0 - y[:-1]) ** 2)


TARGET = np.array([[0.3, -0.2, 0.5], [1.0, 0.0, -1.0], [0.25, 0.75, 0.1], [-0.4, 0.2, 0.9]])
SCALES = np.array([1.0, 2.0, 0.5])


def quadratic(y, args):
    """A smooth, well-conditioned energy on (V, 3) 'vertices'; minimum at TARGET."""
    return jnp.sum(SCALES * (y - TARGET) ** 2)


def quadratic_aux(y, args):
    e = quadratic(y, args)
    return e, {"quad": e, "max_w": 1.0 + jnp.max(jnp.abs(y - TARGET)), "grid": jnp.zeros((2, 2))}


def test_adam_converges_on_a_quadratic():
    r = minimize(quadratic, np.zeros((4, 3)), solver="adam", learning_rate=0.05,
                 stop=StopRules(max_steps=2000, min_step=1e-5), progress=False)
    assert isinstance(r, MinimizeResult)
    assert r.stop_reason in ("min_step", "converged")
    np.testing.assert_allclose(np.asarray(r.y), TARGET, atol=1e-3)
    assert r.energy == pytest.approx(float(quadratic(r.y, None)))
    assert r.energy < 1e-5


@pytest.mark.parametrize("solver", ["bfgs", "lbfgs"])
def test_quasi_newton_converges_on_rosenbrock(solver):
    r = minimize(rosenbrock, jnp.zeros(4), solver=solver, stop=StopRules(max_steps=500), progress=False)
    assert r.stop_reason == "converged"
    np.testing.assert_allclose(np.asarray(r.y), 1.0, atol=1e-6)
    assert r.energy == pytest.approx(float(rosenbrock(r.y, None)), abs=1e-14)
    assert len(r.history["energy"]) == r.steps < 500
    # The accepted energies never increase.
    assert np.all(np.diff(r.history["energy"][1:]) <= 1e-12)


def test_solver_instances_and_optax_transformations():
    r = minimize(quadratic, np.zeros((4, 3)), solver=optx.BFGS(rtol=1e-10, atol=1e-12),
                 stop=StopRules(max_steps=200), progress=False)
    assert r.stop_reason == "converged"
    np.testing.assert_allclose(np.asarray(r.y), TARGET, atol=1e-7)
    r = minimize(quadratic, np.zeros((4, 3)), solver=optax.sgd(0.1), stop=StopRules(max_steps=300), progress=False)
    np.testing.assert_allclose(np.asarray(r.y), TARGET, atol=1e-6)
    with pytest.raises(ValueError, match="unknown solver"):
        minimize(quadratic, np.zeros((4, 3)), solver="newton", progress=False)
    with pytest.raises(TypeError):
        minimize(quadratic, np.zeros((4, 3)), solver=3, progress=False)


def test_max_steps_and_history():
    r = minimize(quadratic_aux, np.zeros((4, 3)), has_aux=True, learning_rate=1e-3,
                 stop=StopRules(max_steps=7), progress=False)
    assert r.stop_reason == "max_steps" and r.steps == 7
    assert set(r.history) == {"energy", "step_size", "time", "quad", "max_w"}  # non-scalar aux skipped
    assert all(len(v) == 7 for v in r.history.values())
    # Adam records the energy at the iterate each step starts from: entry 0 is at y0.
    assert r.history["energy"][0] == pytest.approx(float(quadratic(np.zeros((4, 3)), None)))
    np.testing.assert_allclose(r.history["quad"], r.history["energy"])
    # Adam's first step moves every coordinate by the learning rate.
    assert r.history["step_size"][0] == pytest.approx(1e-3 * np.sqrt(3), rel=1e-6)
    assert np.all(np.diff(r.history["time"]) >= 0)
    assert r.energy == pytest.approx(float(quadratic(r.y, None)))
    assert r.aux["quad"] == pytest.approx(r.energy)
    r0 = minimize(quadratic, np.zeros((4, 3)), stop=StopRules(max_steps=0), progress=False)
    assert r0.steps == 0 and r0.stop_reason == "max_steps" and len(r0.history["energy"]) == 0
    np.testing.assert_array_equal(np.asarray(r0.y), 0.0)


def test_min_step_rule():
    tol = 2e-3
    r = minimize(quadratic, np.zeros((4, 3)), solver="sgd", learning_rate=0.05,
                 stop=StopRules(max_steps=1000, min_step=tol), progress=False)
    assert r.stop_reason == "min_step"
    s = r.history["step_size"]
    assert len(s) == r.steps and s[-1] < tol and np.all(s[:-1] >= tol)
    # Step sizes are per-point Euclidean moves for (..., 3) arrays.
    r1 = minimize(quadratic, np.zeros((4, 3)), solver="sgd", learning_rate=0.05,
                  stop=StopRules(max_steps=1), progress=False)
    moved = np.asarray(r1.y)
    assert r1.history["step_size"][0] == pytest.approx(np.linalg.norm(moved, axis=-1).max())
    # patience: the rule must hold for several consecutive steps.
    r2 = minimize(quadratic, np.zeros((4, 3)), solver="sgd", learning_rate=0.05,
                  stop=StopRules(max_steps=1000, min_step=tol, patience=3), progress=False)
    assert r2.stop_reason == "min_step" and r2.steps == r.steps + 2


def test_max_w_threshold_rule():
    thr = 1.1
    r = minimize(quadratic_aux, np.zeros((4, 3)), has_aux=True, learning_rate=0.01,
                 stop=StopRules(max_steps=1000, max_w_threshold=thr), progress=False)
    assert r.stop_reason == "max_w"
    mw = r.history["max_w"]
    assert mw[-1] <= thr and np.all(mw[:-1] > thr)
    # The returned iterate is the one that satisfied the rule.
    assert float(quadratic_aux(r.y, None)[1]["max_w"]) == pytest.approx(mw[-1])
    assert r.aux["max_w"] == pytest.approx(mw[-1])
    # The alias `max_w` does the same.
    r2 = minimize(quadratic_aux, np.zeros((4, 3)), has_aux=True, learning_rate=0.01,
                  stop=StopRules(max_steps=1000, max_w=thr), progress=False)
    assert r2.stop_reason == "max_w" and r2.steps == r.steps
    with pytest.raises(ValueError, match="max_w"):
        minimize(quadratic, np.zeros((4, 3)), stop=StopRules(max_w_threshold=thr), progress=False)
    with pytest.raises(ValueError):
        StopRules(max_w=1.0, max_w_threshold=2.0)


def test_energy_tol_rule():
    r = minimize(quadratic, np.zeros((4, 3)), solver="sgd", learning_rate=0.05,
                 stop=StopRules(max_steps=1000, energy_tol=1e-6), progress=False)
    assert r.stop_reason == "energy_tol"
    e = r.history["energy"]
    assert abs(e[-1] - e[-2]) < 1e-6 and np.all(np.abs(np.diff(e[:-1])) >= 1e-6)


def test_callback_is_called_and_can_stop():
    calls = []

    def callback(step, y, info):
        calls.append((step, np.asarray(y).copy(), dict(info)))
        return step == 5

    r = minimize(quadratic_aux, np.zeros((4, 3)), has_aux=True, callback=callback,
                 stop=StopRules(max_steps=100), progress=False)
    assert r.stop_reason == "callback" and r.steps == 5
    assert [c[0] for c in calls] == [1, 2, 3, 4, 5]
    assert set(calls[0][2]) >= {"energy", "step_size", "quad", "max_w"}
    np.testing.assert_array_equal(calls[-1][1], np.asarray(r.y))
    assert all(len(v) == 5 for v in r.history.values())


def test_nonfinite_energy_stops_and_returns_a_finite_iterate():
    def fn(y, args):
        return jnp.where(y[0] < 0.5, jnp.nan, jnp.sum((y - 0.0) ** 2))

    r = minimize(fn, jnp.array([1.0, 1.0]), learning_rate=0.1, stop=StopRules(max_steps=100), progress=False)
    assert r.stop_reason == "nonfinite"
    assert np.isfinite(r.energy) and float(r.y[0]) >= 0.5


def test_step_compiles_once():
    def make_fn():
        traces = {"n": 0}

        def fn(y, args):
            traces["n"] += 1
            return quadratic(y, args)

        return fn, traces

    counts = {}
    for steps in (3, 40):
        for solver in ("adam", "bfgs"):
            fn, traces = make_fn()  # a fresh function: no compilation cache from other runs
            minimize(fn, np.zeros((4, 3)), solver=solver, stop=StopRules(max_steps=steps), progress=False)
            counts[steps, solver] = traces["n"]
    # A handful of traces (shape inference, the step, the final evaluation), the same
    # however many steps run.
    for solver in ("adam", "bfgs"):
        assert counts[3, solver] == counts[40, solver] <= 3


def test_later_calls_reuse_the_compiled_step():
    """A second `minimize` of the same function, solver and shapes (other values) reuses
    the compiled step and final evaluation: only the shape inference traces `fn` again."""
    traces = {"n": 0}

    def fn(y, args):
        traces["n"] += 1
        return quadratic(y, args)

    bounds = (-jnp.ones(3), jnp.ones(3))
    for solver, kw in (("adam", {"bounds": bounds}), ("bfgs", {})):
        first = minimize(fn, np.zeros((4, 3)), solver=solver, stop=StopRules(max_steps=3), progress=False, **kw)
        before = traces["n"]
        again = minimize(fn, np.full((4, 3), 0.5), solver=solver, stop=StopRules(max_steps=3), progress=False, **kw)
        assert traces["n"] - before == 1, (solver, kw)
        assert again.steps == first.steps == 3 and not np.array_equal(again.y, first.y)
        # the reused step gives what a fresh compilation gives
        fresh = minimize(lambda y, a: quadratic(y, a), np.full((4, 3), 0.5), solver=solver,
                         stop=StopRules(max_steps=3), progress=False, **kw)
        assert np.array_equal(again.y, fresh.y) and again.energy == fresh.energy


def test_pytree_parameters_and_args():
    def fn(y, args):
        return jnp.sum((y["a"] - args["t"]) ** 2) + (y["b"] - 2.0) ** 2

    y0 = {"a": jnp.zeros(3), "b": jnp.asarray(0.0)}
    r = minimize(fn, y0, {"t": jnp.array([1.0, 2.0, 3.0])}, solver="bfgs", progress=False)
    assert r.stop_reason == "converged"
    np.testing.assert_allclose(np.asarray(r.y["a"]), [1, 2, 3], atol=1e-6)
    assert float(r.y["b"]) == pytest.approx(2.0, abs=1e-6)
    r1 = minimize(fn, y0, {"t": jnp.array([1.0, 2.0, 3.0])}, solver="sgd", learning_rate=0.1,
                  stop=StopRules(max_steps=1), progress=False)
    # Pytrees: the step size is the largest absolute change of any entry.
    assert r1.history["step_size"][0] == pytest.approx(0.6)


def test_bad_objectives_are_reported():
    with pytest.raises(ValueError, match="scalar"):
        minimize(lambda y, a: y * 2, np.zeros(3), progress=False)
    with pytest.raises(ValueError, match="has_aux"):
        minimize(lambda y, a: (jnp.sum(y), {}), np.zeros(3), progress=False)


def test_progress_bar_and_eager_mode(capsys):
    r = minimize(quadratic, np.zeros((4, 3)), stop=StopRules(max_steps=3), progress=True)
    assert r.steps == 3
    assert "minimize" in capsys.readouterr().err
    r2 = minimize(quadratic, np.zeros((4, 3)), stop=StopRules(max_steps=3), progress=False, jit=False)
    np.testing.assert_allclose(np.asarray(r2.y), np.asarray(r.y), rtol=1e-12)


def test_stop_rules_and_result_are_frozen():
    s = StopRules()
    assert s.max_steps == 1000 and s.max_w_threshold is None and s.min_step is None and s.energy_tol is None
    with pytest.raises(dataclasses.FrozenInstanceError):
        s.max_steps = 3
    r = minimize(quadratic, np.zeros((4, 3)), stop=StopRules(max_steps=1), progress=False)
    with pytest.raises(dataclasses.FrozenInstanceError):
        r.steps = 3


def test_resolving_an_overlap_through_voxelize(rng):
    """End to end: the self-intersection energy of two overlapping blobs, with a grid in args."""
    Va, Fa = random_star_mesh(rng, center=(-0.15, 0.0, 0.0), scale=0.4)
    Vb, Fb = random_star_mesh(rng, center=(0.15, 0.0, 0.0), scale=0.4)
    V0 = np.concatenate([Va, Vb])
    F = np.concatenate([Fa, Fb + len(Va)]).astype(np.int32)

    def fn(V, grid):
        W = voxax.voxelize(V, F, grid)
        e_sect = E.self_intersection(W)
        e_arap = E.arap(V, V0, F)
        return e_sect + 0.005 * e_arap, {"sect": e_sect, "arap": e_arap, "max_w": W.max()}

    r = minimize(fn, V0, voxax.Grid.cube(16), has_aux=True, learning_rate=2e-2,
                 stop=StopRules(max_steps=150, max_w_threshold=1 + 1e-3), progress=False)
    assert r.history["sect"][0] > 0
    assert r.stop_reason == "max_w", r.history["max_w"][-5:]
    assert r.aux["max_w"] <= 1 + 1e-3


class _FailingAdam(optx.OptaxMinimiser):
    """An optax minimizer whose own termination check reports a failure after 3 steps."""

    def terminate(self, fn, y, args, options, state, tags):
        return state.step >= 3, optx.RESULTS.where(state.step >= 3, optx.RESULTS.nonlinear_divergence,
                                                   optx.RESULTS.successful)


def test_solver_failures_are_reported():
    solver = _FailingAdam(optax.adam(1e-2), rtol=1e-8, atol=1e-8)
    r = minimize(quadratic, np.zeros((4, 3)), solver=solver, stop=StopRules(max_steps=50), progress=False)
    assert r.stop_reason.startswith("failed: ") and "diverged" in r.stop_reason
    assert r.steps == 3


# -- stop reasons and box bounds ------------------------------------------------------------


def test_stop_reasons_are_the_documented_constants():
    from voxax import StopReason

    r = minimize(quadratic, np.zeros((4, 3)), solver="bfgs", progress=False)
    assert r.stop_reason == StopReason.CONVERGED == "converged"
    r = minimize(quadratic, np.zeros((4, 3)), solver="sgd", stop=StopRules(max_steps=2), progress=False)
    assert r.stop_reason == StopReason.MAX_STEPS
    names = {k for k in vars(StopReason) if k.isupper()}
    assert names == {"MAX_STEPS", "MAX_W", "MIN_STEP", "ENERGY_TOL", "CONVERGED", "CALLBACK", "NONFINITE",
                     "INTERRUPTED", "FAILED"}


def test_the_analytic_box_optimum_of_a_quadratic():
    """min sum s (y - t)^2 over a box is t clipped into the box (separable and convex)."""
    lower, upper = np.array([-0.2, -0.1, 0.0]), 0.4
    expected = np.clip(TARGET, lower, upper)
    for solver in ("adam", "sgd", "lbfgsb"):
        r = minimize(quadratic, np.zeros((4, 3)), solver=solver, learning_rate=0.05, bounds=(lower, upper),
                     stop=StopRules(max_steps=400), progress=False)
        assert r.stop_reason == "converged", (solver, r.stop_reason)
        np.testing.assert_allclose(r.y, expected, atol=1e-6)
        assert np.all(np.asarray(r.y) >= lower) and np.all(np.asarray(r.y) <= upper)


def _grow(mesh, grid):
    """Minus the enclosed volume measured on the grid: pushes every vertex outwards."""

    def fn(v, args):
        W = voxax.voxelize(v, mesh.faces, grid)
        return -jnp.sum(W) * grid.voxel_volume, {"max_w": W.max()}

    return fn


@pytest.mark.parametrize("solver", ["adam", "sgd", "lbfgsb"])
def test_bounds_hold_on_a_voxel_objective(solver):
    mesh = voxax.data.icosphere(1, radius=0.3)
    grid = voxax.Grid.cube(8)
    fn = _grow(mesh, grid)
    lr = {"adam": 0.05, "sgd": 2.0, "lbfgsb": 0.0}[solver]  # (L-BFGS-B takes no learning rate)
    free = minimize(fn, mesh.vertices, solver="adam", learning_rate=0.05, has_aux=True,
                    stop=StopRules(max_steps=12), progress=False)
    assert np.abs(np.asarray(free.y)).max() > 0.42  # unbounded, the sphere grows past the box
    lower, upper = np.array([-0.35, -0.4, -0.32]), np.array([0.4, 0.33, 0.36])
    seen = []

    def record(step, y, info):
        seen.append(np.asarray(y))

    r = minimize(fn, mesh.vertices, solver=solver, learning_rate=lr, has_aux=True, bounds=(lower, upper),
                 stop=StopRules(max_steps=12), progress=False, callback=record)
    assert seen and r.steps == len(seen)
    for y in seen + [np.asarray(r.y)]:
        assert np.all(y >= lower) and np.all(y <= upper)
    assert r.energy < fn(jnp.asarray(mesh.vertices), None)[0] - 0.01  # it did grow
    touching = np.isclose(np.asarray(r.y), lower) | np.isclose(np.asarray(r.y), upper)
    assert touching.any()  # and the bounds were active


def test_bounds_validation_and_pytrees():
    with pytest.raises(ValueError, match="optimistix minimizers are unconstrained"):
        minimize(quadratic, np.zeros((4, 3)), solver="bfgs", bounds=(0.0, 1.0), progress=False)
    with pytest.raises(ValueError, match="lower <= upper"):
        minimize(quadratic, np.zeros((4, 3)), bounds=(1.0, 0.0), progress=False)
    with pytest.raises(ValueError, match="does not broadcast"):
        minimize(quadratic, np.zeros((4, 3)), bounds=(np.zeros(2), None), progress=False)
    with pytest.raises(TypeError, match="pair"):
        minimize(quadratic, np.zeros((4, 3)), bounds=0.0, progress=False)

    def fn(y, args):
        return jnp.sum((y["a"] - 2.0) ** 2) + jnp.sum((y["b"] + 2.0) ** 2)

    y0 = {"a": jnp.zeros(2), "b": jnp.zeros(3)}
    r = minimize(fn, y0, solver="sgd", learning_rate=0.2, bounds=({"a": 1.0, "b": -1.0}, None),
                 stop=StopRules(max_steps=200), progress=False)
    np.testing.assert_allclose(r.y["a"], [2.0, 2.0], atol=1e-6)  # above its lower bound 1
    np.testing.assert_allclose(r.y["b"], [-1.0] * 3, atol=1e-12)  # held at its lower bound -1
    # y0 outside the box is clipped into it first.
    r = minimize(fn, {"a": jnp.full(2, 5.0), "b": jnp.zeros(3)}, solver="sgd", bounds=(-0.5, 0.5),
                 stop=StopRules(max_steps=0), progress=False)
    np.testing.assert_array_equal(r.y["a"], [0.5, 0.5])


def test_lbfgsb_without_jaxopt_names_the_extra(monkeypatch):
    import sys

    monkeypatch.setitem(sys.modules, "jaxopt", None)  # makes `import jaxopt` fail
    with pytest.raises(ImportError, match=r'pip install "voxax\[bounds\]"'):
        minimize(quadratic, np.zeros((4, 3)), solver="lbfgsb", progress=False)


def test_plotting_without_matplotlib_names_the_extra(monkeypatch):
    import sys

    monkeypatch.setitem(sys.modules, "matplotlib", None)
    r = minimize(quadratic, np.zeros((4, 3)), solver="sgd", stop=StopRules(max_steps=2), progress=False)
    report = voxax.apps.Report(energy_history=r.history["energy"], history=r.history, steps=r.steps,
                               stop_reason=r.stop_reason, energy=r.energy, resolution=8)
    with pytest.raises(ImportError, match=r'pip install "voxax\[plot\]"'):
        report.plot_history()
