"""`minimize`: a step-by-step driver around optimistix solvers, with progress, history,
callbacks and the stopping rules of the paper's applications.

`optimistix.minimise` runs its whole loop inside one compiled `while_loop`: fast, but it
gives no progress report, no per-step history and no way to stop on problem-specific
rules ("no voxel above 1 + 1e-3", "no vertex moved more than 5e-4"). `minimize` instead
drives the solver's own `init` / `step` / `terminate` API from Python. The step (one
solver step plus the bookkeeping) is compiled once with `equinox.filter_jit`, as a module
of everything it uses, so later calls on the same problem reuse the compilation; each
iteration then costs one compiled call and one small device-to-host copy of scalars.

Solvers: `"adam"` and `"sgd"` (optax), `"bfgs"` (`optimistix.BFGS`), `"lbfgs"`
(`optimistix.LBFGS`), any optax `GradientTransformation`, any optimistix minimizer
instance, and `"lbfgsb"` (jaxopt's `LBFGSB`, for box bounds; the optional extra
`voxax[bounds]`). Only the libraries' public APIs are used: optax's `init`/`update`,
optimistix's `init`/`step`/`terminate`, jaxopt's `init_state`/`update` and the fields of
its documented state.

Box bounds (`bounds=(lower, upper)`, e.g. every vertex inside a build volume) keep every
iterate inside the box: optax steps are projected onto it
(`optax.projections.projection_box`, projected gradient descent), and L-BFGS-B handles
the bounds itself. optimistix has no constrained minimizers, so its solvers take no bounds.
"""

from __future__ import annotations

import dataclasses
import math
import time
from collections.abc import Callable
from typing import Any

import equinox as eqx
import jax
import jax.numpy as jnp
import jax.tree_util as jtu
import numpy as np
import optax
import optimistix as optx

from .. import _validate
from .._optional import require
from .._progress import ProgressBar
from .._values import ValueEquality

__all__ = ["StopReason", "StopRules", "MinimizeResult", "minimize"]


class StopReason:
    """Why `minimize` stopped: the values of `MinimizeResult.stop_reason`.

    Plain strings, so `result.stop_reason == voxax.StopReason.CONVERGED` and
    `result.stop_reason == "converged"` are the same test. A solver failure is reported
    as `FAILED + ": " + message`, e.g. `"failed: The linear solver returned non-finite
    output."` (test it with `result.stop_reason.startswith(StopReason.FAILED)`).

    - `MAX_STEPS` (`"max_steps"`): `StopRules.max_steps` steps were taken.
    - `MAX_W` (`"max_w"`): `aux["max_w"] <= StopRules.max_w_threshold`.
    - `MIN_STEP` (`"min_step"`): the step size stayed below `StopRules.min_step`.
    - `ENERGY_TOL` (`"energy_tol"`): the energy changed by less than `StopRules.energy_tol`.
    - `CONVERGED` (`"converged"`): the solver's own convergence test (`rtol`/`atol`) held.
    - `CALLBACK` (`"callback"`): the callback returned True.
    - `NONFINITE` (`"nonfinite"`): the energy became NaN or infinite.
    - `INTERRUPTED` (`"interrupted"`): KeyboardInterrupt.
    - `FAILED` (`"failed"`): the solver reported a failure (followed by its message).
    """

    MAX_STEPS = "max_steps"
    MAX_W = "max_w"
    MIN_STEP = "min_step"
    ENERGY_TOL = "energy_tol"
    CONVERGED = "converged"
    CALLBACK = "callback"
    NONFINITE = "nonfinite"
    INTERRUPTED = "interrupted"
    FAILED = "failed"


@dataclasses.dataclass(frozen=True)
class StopRules:
    """When `minimize` stops. The first rule that holds wins; its name becomes
    `MinimizeResult.stop_reason`.

    **Attributes:**

    - `max_steps`: int, stop after this many solver steps (`"max_steps"`).
    - `max_w_threshold`: float or None, stop as soon as `aux["max_w"] <= max_w_threshold`
      (`"max_w"`), e.g. `1 + 1e-3` to stop once no voxel is covered twice. Needs
      `has_aux=True` and an objective whose aux dict holds `"max_w"` (e.g. `W.max()`).
      The iterate returned is the one whose `max_w` satisfied the rule.
    - `max_w`: alias of `max_w_threshold` (give one of the two).
    - `min_step`: float or None, stop when the step size (largest per-vertex move of the
      step; see `minimize`) falls below this (`"min_step"`).
    - `energy_tol`: float or None, stop when the energy changes by less than this
      (absolute) between consecutive steps (`"energy_tol"`).
    - `patience`: int, how many consecutive steps `min_step` / `energy_tol` must hold
      before stopping (default 1).

    Besides these, `minimize` stops when the solver itself reports convergence
    (`"converged"`, from the solver's `rtol`/`atol`), when it reports a failure
    (`"failed: <message>"`), when the energy becomes NaN or infinite (`"nonfinite"`,
    returning the last iterate with a finite energy), when the callback returns True
    (`"callback"`) and on KeyboardInterrupt (`"interrupted"`).

    **Example:**

    ```python
    >>> stop = voxax.StopRules(max_steps=2000, min_step=5e-4)
    ```
    """

    max_steps: int = 1000
    max_w: float | None = None
    max_w_threshold: float | None = None
    min_step: float | None = None
    energy_tol: float | None = None
    patience: int = 1

    def __post_init__(self):
        if self.max_w is not None and self.max_w_threshold is not None and self.max_w != self.max_w_threshold:
            raise ValueError("voxax.StopRules: give `max_w_threshold` or its alias `max_w`, not two different values")
        if self.max_w is not None and self.max_w_threshold is None:
            object.__setattr__(self, "max_w_threshold", self.max_w)
        if self.max_w_threshold is not None and self.max_w is None:
            object.__setattr__(self, "max_w", self.max_w_threshold)
        where = "voxax.StopRules"
        object.__setattr__(self, "max_steps", _validate.positive_int(where, "max_steps", self.max_steps, minimum=0))
        object.__setattr__(self, "patience", _validate.positive_int(where, "patience", self.patience))
        for name in ("min_step", "energy_tol"):
            if getattr(self, name) is not None:
                object.__setattr__(self, name, _validate.positive_float(where, name, getattr(self, name), allow_zero=True))
        for name in ("max_w", "max_w_threshold"):
            if getattr(self, name) is not None:
                object.__setattr__(self, name, _validate.finite_number(where, name, getattr(self, name)))


@dataclasses.dataclass(frozen=True, eq=False)
class MinimizeResult(ValueEquality):
    """What `minimize` returns.

    **Attributes:**

    - `y`: the final iterate (same structure as `y0`).
    - `steps`: int, the number of solver steps taken.
    - `stop_reason`: str, the rule that stopped the run, one of the
      [`StopReason`][voxax.StopReason] constants: `"max_steps"`, `"max_w"`,
      `"min_step"`, `"energy_tol"`, `"converged"`, `"callback"`, `"nonfinite"`,
      `"interrupted"` or `"failed: <message>"`.
    - `history`: dict of 1D NumPy arrays, one entry per step: `"energy"`, `"step_size"`,
      `"time"` (seconds since the start), `"max_w"` (when the aux has it) and every scalar
      aux term under its name.
    - `energy`: float, the energy at `y`.
    - `aux`: the aux at `y` (None without `has_aux`).

    Compares with `==` by value (arrays entry by entry); pickles and deep-copies.
    """

    y: Any
    steps: int
    stop_reason: str
    history: dict
    energy: float
    aux: Any = None


class _WithAux(eqx.Module):
    fn: Callable
    has_aux: bool = eqx.field(static=True)

    def __call__(self, y, args):
        out = self.fn(y, args)
        if self.has_aux:
            if not (isinstance(out, tuple) and len(out) == 2):
                raise ValueError("voxax.minimize: with has_aux=True, `fn(y, args)` must return (scalar, aux)")
            f, aux = out
        else:
            if isinstance(out, tuple):
                raise ValueError("voxax.minimize: `fn(y, args)` returned a tuple; pass has_aux=True for (scalar, aux)")
            f, aux = out, None
        return jnp.asarray(f), aux


_NAMES = "'adam', 'sgd', 'bfgs', 'lbfgs', 'lbfgsb', an optax GradientTransformation or an optimistix minimizer"


_NAMED_OPTAX: dict = {}


def _named_optax(name: str, learning_rate):
    """`optax.adam` / `optax.sgd` of a learning rate, the same object for the same
    (hashable) learning rate, so that the compiled steps of later calls are reused."""
    make = optax.adam if name == "adam" else optax.sgd
    try:
        key = (name, learning_rate)
        hash(key)
    except TypeError:  # an array learning rate: a fresh transformation
        return make(learning_rate)
    if key not in _NAMED_OPTAX:
        if len(_NAMED_OPTAX) >= 64:
            _NAMED_OPTAX.clear()
        _NAMED_OPTAX[key] = make(learning_rate)
    return _NAMED_OPTAX[key]


def _make_solver(solver, learning_rate):
    """`(kind, solver)`: kind is "optax" (a GradientTransformation), "lbfgsb" (None),
    "quasi_newton" or "optimistix" (an optimistix minimizer)."""
    if isinstance(solver, str):
        name = solver.lower()
        if name in ("adam", "sgd"):
            if learning_rate is not None and not callable(learning_rate):  # a number, or an optax schedule
                learning_rate = _validate.positive_float("voxax.minimize", "learning_rate", learning_rate)
            return "optax", _named_optax(name, learning_rate)
        if name == "lbfgsb":
            return "lbfgsb", None
        if name in ("bfgs", "lbfgs"):
            return "quasi_newton", name
        raise ValueError(f"voxax.minimize: unknown solver {solver!r}; use {_NAMES}")
    if isinstance(solver, optax.GradientTransformation):
        return "optax", solver
    if isinstance(solver, optx.AbstractMinimiser):
        return ("quasi_newton" if isinstance(solver, optx.AbstractQuasiNewton) else "optimistix"), solver
    raise TypeError(f"voxax.minimize: `solver` must be {_NAMES}; got {type(solver).__name__}")


def _box(bounds, y0):
    """`(lower, upper)` pytrees shaped like `y0` from scalars, arrays or pytrees (None: unbounded)."""
    if not (isinstance(bounds, (tuple, list)) and len(bounds) == 2):
        raise TypeError("voxax.minimize: `bounds` must be a pair (lower, upper) of scalars, arrays or pytrees like y0")
    leaves, treedef = jtu.tree_flatten(y0)

    def side(b, fill, name):
        if b is None:
            return [jnp.full(jnp.shape(x), fill, jnp.result_type(x)) for x in leaves]
        b_leaves = jtu.tree_leaves(b)
        if jtu.tree_structure(b) == treedef:
            pairs = zip(b_leaves, leaves)
        elif len(b_leaves) == 1:
            pairs = ((b_leaves[0], x) for x in leaves)
        else:
            raise ValueError(f"voxax.minimize: `bounds` {name} must be a scalar, an array or a pytree like y0")
        out = []
        for bl, x in pairs:
            bl = jnp.asarray(bl, jnp.result_type(x))
            try:
                out.append(jnp.broadcast_to(bl, jnp.shape(x)))
            except ValueError:
                raise ValueError(
                    f"voxax.minimize: `bounds` {name} of shape {bl.shape} does not broadcast to a variable of shape {jnp.shape(x)}"
                ) from None
            if jnp.any(jnp.isnan(out[-1])):
                raise ValueError(f"voxax.minimize: `bounds` {name} contains NaN")
        return out

    lower, upper = side(bounds[0], -jnp.inf, "lower"), side(bounds[1], jnp.inf, "upper")
    if any(bool(jnp.any(lo > hi)) for lo, hi in zip(lower, upper)):
        raise ValueError("voxax.minimize: `bounds` need lower <= upper everywhere")
    return jtu.tree_unflatten(treedef, lower), jtu.tree_unflatten(treedef, upper)


def _cauchy(rtol, atol, y, y_diff, f, f_diff):
    """optimistix's Cauchy test (max norm): small change in both y and f."""
    ratios = [jnp.max(jnp.abs(d) / (atol + rtol * jnp.abs(v))) for v, d in zip(jtu.tree_leaves(y), jtu.tree_leaves(y_diff)) if jnp.size(v)]
    y_small = jnp.max(jnp.stack(ratios)) < 1 if ratios else jnp.array(True)
    f_small = jnp.abs(f_diff) / (atol + rtol * jnp.abs(f)) < 1
    return y_small & f_small


def _default_step_size(y_new, y_old):
    """Max per-point move for an array (..., 3) or (..., 2); max abs change otherwise."""
    leaves_new, leaves_old = jtu.tree_leaves(y_new), jtu.tree_leaves(y_old)
    if len(leaves_new) == 1 and jnp.ndim(leaves_new[0]) >= 2 and jnp.shape(leaves_new[0])[-1] in (2, 3):
        d = leaves_new[0] - leaves_old[0]
        return jnp.max(jnp.linalg.norm(d, axis=-1)) if d.size else jnp.zeros((), d.dtype)
    moves = [jnp.max(jnp.abs(a - b)) for a, b in zip(leaves_new, leaves_old) if jnp.size(a)]
    return jnp.max(jnp.stack(moves)) if moves else jnp.zeros(())


def _is_scalar(v) -> bool:
    if isinstance(v, (bool, int, float, np.number)):
        return True
    return hasattr(v, "shape") and hasattr(v, "dtype") and tuple(v.shape) == ()


def _scalar_aux(aux) -> dict:
    """The scalar entries of an aux dict (or a scalar aux, as `"aux"`)."""
    if isinstance(aux, dict):
        return {str(k): v for k, v in aux.items() if _is_scalar(v)}
    if aux is not None and _is_scalar(aux):
        return {"aux": aux}
    return {}


def _as_inexact(x):
    x = jnp.asarray(x)
    return x if jnp.issubdtype(x.dtype, jnp.inexact) else x.astype(jnp.result_type(float))


def _info(energy, aux, step_size, accepted, done, failed):
    return {"energy": energy, "step_size": step_size, "aux": _scalar_aux(aux),
            "accepted": accepted, "done": done, "failed": failed}


# The steps are modules of everything they use, compiled through the module-level
# `_compiled`: equal problems (the same `fn`, solver, options and shapes) hit the same
# compilation in later `minimize` calls instead of compiling their closures anew.


class _OptaxStep(eqx.Module):
    fn_aux: _WithAux
    opt: Any  # a GradientTransformation (its functions are static)
    lower: Any  # pytrees like y0, or None without bounds
    upper: Any
    rtol: float
    atol: float
    step_size_fn: Callable

    f_max: Any  # the largest value of the energy's dtype: the "previous energy" of step 0

    def init(self, y, args):
        return self.opt.init(y), self.f_max

    def __call__(self, y, state, args):
        opt_state, f_prev = state
        fn_aux = self.fn_aux
        (f, aux), grads = eqx.filter_value_and_grad(fn_aux, has_aux=True)(y, args)
        if isinstance(self.opt, optax.GradientTransformationExtraArgs):
            updates, opt_state = self.opt.update(grads, opt_state, y, value=f, grad=grads,
                                                 value_fn=lambda z: fn_aux(z, args)[0])
        else:
            updates, opt_state = self.opt.update(grads, opt_state, y)
        y_new = optax.apply_updates(y, updates)
        if self.lower is not None:
            y_new = optax.projections.projection_box(y_new, self.lower, self.upper)
        y_diff = jtu.tree_map(lambda a, b: a - b, y_new, y)
        done = _cauchy(self.rtol, self.atol, y, y_diff, f, f - f_prev)
        info = _info(f, aux, self.step_size_fn(y_new, y), jnp.array(True), done, jnp.array(False))
        return y_new, (opt_state, f), info, jnp.array(0)


class _OptxStep(eqx.Module):
    fn_aux: _WithAux
    optimizer: Any  # an optimistix minimizer
    options: dict
    f_struct: Any
    aux_struct: Any
    quasi_newton: bool = eqx.field(static=True)
    step_size_fn: Callable

    def init(self, y, args):
        return self.optimizer.init(self.fn_aux, y, args, self.options, self.f_struct, self.aux_struct, frozenset())

    def __call__(self, y, state, args):
        fn_aux, tags = self.fn_aux, frozenset()
        y_new, new_state, _ = self.optimizer.step(fn_aux, y, args, self.options, state, tags)
        done, result = self.optimizer.terminate(fn_aux, y_new, args, self.options, new_state, tags)
        energy, aux = fn_aux(y_new, args)  # at the (accepted) iterate the step returns
        step_size = self.step_size_fn(y_new, y)
        # A line search that rejects its trial point returns the previous iterate.
        moved = jnp.any(jnp.stack([jnp.any(a != b) for a, b in zip(jtu.tree_leaves(y_new), jtu.tree_leaves(y))]))
        accepted = moved if self.quasi_newton else jnp.array(True)
        failed = done & (result != optx.RESULTS.successful)
        return y_new, new_state, _info(energy, aux, step_size, accepted, done, failed), result


@eqx.filter_jit
def _compiled_init(step, y, args):
    return step.init(y, args)


@eqx.filter_jit
def _compiled_step(step, y, state, args):
    return step(y, state, args)


@eqx.filter_jit
def _compiled_eval(fn_aux, y, args):
    return fn_aux(y, args)


def _steppers(kind, solver, fn_aux, bounds, lower, upper, rtol, atol, step_size_fn, f_struct, aux_struct,
              options, stop, jit):
    """`(init, step, failure)` of the chosen solver: `init(y, args) -> state`,
    `step(y, state, args) -> (y_new, state, info, result)`, and `failure(result)`, the
    message of a failed step."""
    failure = None  # maps the step's `result` to a failure message

    if kind == "optax":
        lo, hi = (lower, upper) if bounds is not None else (None, None)
        f_max = jnp.array(jnp.finfo(f_struct.dtype).max, f_struct.dtype)
        stepper = _OptaxStep(fn_aux, solver, lo, hi, rtol, atol, step_size_fn, f_max)

    elif kind == "lbfgsb":
        jaxopt = require("jaxopt", 'minimize(solver="lbfgsb")')
        lbfgsb = jaxopt.LBFGSB(fun=fn_aux, has_aux=True, tol=atol, maxiter=max(stop.max_steps, 1))
        box = (lower, upper)

        def _init(y, args):
            return lbfgsb.init_state(y, box, args)

        def _step(y, state, args):
            y_new, state = lbfgsb.update(y, state, box, args)
            done = state.error <= lbfgsb.tol
            info = _info(state.value, state.aux, step_size_fn(y_new, y), jnp.array(True), done, state.failed_linesearch)
            return y_new, state, info, jnp.array(0)

        def failure(result):
            return "the line search failed"

    else:
        if isinstance(solver, str):
            solver = optx.BFGS(rtol=rtol, atol=atol) if solver == "bfgs" else optx.LBFGS(rtol=rtol, atol=atol)
        stepper = _OptxStep(fn_aux, solver, options, f_struct, aux_struct, kind == "quasi_newton", step_size_fn)

        def failure(result):
            return str(optx.RESULTS[result])

    if kind == "lbfgsb":
        if jit:
            _init = eqx.filter_jit(_init)
            _step = eqx.filter_jit(_step)
    elif jit:
        def _init(y, args):
            return _compiled_init(stepper, y, args)

        def _step(y, state, args):
            return _compiled_step(stepper, y, state, args)
    else:
        _init, _step = stepper.init, stepper

    return _init, _step, failure


def _checked_fn(fn_aux, y0, args, stop: StopRules):
    """The shapes of `fn`'s value and aux at `y0`, checked (a floating-point scalar, and a
    scalar aux['max_w'] where the stopping rules need it), and the names of aux's scalar
    entries."""
    f_struct, aux_struct = eqx.filter_eval_shape(fn_aux, y0, args)
    if not (f_struct.shape == () and jnp.issubdtype(f_struct.dtype, jnp.floating)):
        raise ValueError(f"voxax.minimize: `fn` must return a floating-point scalar, got shape {f_struct.shape} "
                         f"and dtype {f_struct.dtype}")
    aux_names = sorted(_scalar_aux(aux_struct)) if aux_struct is not None else []
    if stop.max_w_threshold is not None and "max_w" not in aux_names:
        raise ValueError("voxax.minimize: the `max_w_threshold` stopping rule needs has_aux=True and a scalar "
                         "aux['max_w'] (e.g. W.max()) from `fn`")
    return f_struct, aux_struct, aux_names


def _box_bounds(bounds, kind: str, y0):
    """`y0` projected into the box `bounds`, and the box's `(lower, upper)` pytrees: None
    without bounds, unbounded for `"lbfgsb"`."""
    lower = upper = None
    if bounds is not None:
        if kind in ("quasi_newton", "optimistix"):
            raise ValueError("voxax.minimize: `bounds` need an optax solver ('adam', 'sgd', an optax "
                             "GradientTransformation) or solver='lbfgsb'; optimistix minimizers are unconstrained")
        lower, upper = _box(bounds, y0)
        y0 = optax.projections.projection_box(y0, lower, upper)
    elif kind == "lbfgsb":
        lower = jtu.tree_map(lambda x: jnp.full(x.shape, -jnp.inf, x.dtype), y0)
        upper = jtu.tree_map(lambda x: jnp.full(x.shape, jnp.inf, x.dtype), y0)
    return y0, lower, upper


def _bar_postfix(energy: float, step_size: float, aux_vals: dict) -> dict:
    """The progress bar's postfix of a step: energy, max W (when recorded), step size."""
    post = {"E": f"{energy:.4g}"}
    if "max_w" in aux_vals:
        post["max_w"] = f"{aux_vals['max_w']:.4f}"
    post["step"] = f"{step_size:.2e}"
    return post


def minimize(
    fn: Callable,
    y0,
    args=None,
    *,
    solver="adam",
    learning_rate: float = 1e-2,
    stop: StopRules = StopRules(),
    has_aux: bool = False,
    progress: bool = True,
    callback: Callable | None = None,
    jit: bool = True,
    rtol: float = 1e-8,
    atol: float = 1e-10,
    step_size_fn: Callable | None = None,
    options: dict | None = None,
    bounds=None,
) -> MinimizeResult:
    """Minimizes `fn(y, args)` step by step, with progress bar, history and stopping rules.

    One compiled step runs one solver step, its convergence check, and the bookkeeping;
    Python then records the history, updates the progress bar, calls `callback` and
    checks the `StopRules`. The step is compiled on the first call and reused by later
    calls with the same `fn` (the same function object), solver, options and shapes
    (solvers given by name count as the same for the same learning rate; `"lbfgsb"`
    compiles per call).

    Which point a history entry describes: for optax solvers (`"adam"`, `"sgd"`), step
    `k` evaluates the energy at the iterate it starts from (the usual training-loss
    convention), so `history["energy"][0]` is the energy at `y0`. For optimistix
    minimizers the energy and aux are evaluated at the iterate the step returns (one
    extra evaluation per step); for the line-search solvers (BFGS, L-BFGS) that is the
    last accepted iterate, and steps whose line search rejected the trial point move
    nothing (and do not count for `min_step` / `energy_tol`). For `"lbfgsb"` it is the
    new iterate (jaxopt evaluates it anyway).

    With `bounds=(lower, upper)` every iterate stays in the box `lower <= y <= upper`
    (elementwise; `y0` is first clipped into it): optax steps are projected onto the box
    (projected gradient methods) and `"lbfgsb"` (jaxopt's L-BFGS-B) keeps to it by
    construction. `lower` and `upper` are scalars, arrays that broadcast to `y0` (for
    vertices `(V, 3)`, a `(3,)` corner of a build volume), pytrees like `y0`, or None
    (unbounded on that side).

    The step size of a step is the largest move of a point — `max(norm(y_new - y_old,
    axis=-1))` when `y` is a single array of points `(..., 3)` (or `(..., 2)`) — and the
    largest absolute change of any entry when `y` is any other pytree (override with
    `step_size_fn(y_new, y_old) -> scalar`).

    **Arguments:**

    - `fn`: `fn(y, args) -> scalar`, or `-> (scalar, aux)` with `has_aux=True`; `aux` is
      a dict whose scalar entries (named energy terms, `"max_w"`) are recorded. It must
      be traceable by JAX (pure, no Python side effects besides tracing).
    - `y0`: the initial point: an array (e.g. vertices `(V, 3)`) or a pytree of arrays.
    - `args`: passed to `fn` unchanged (arrays are traced; other leaves such as a
      `voxax.Grid` are static).
    - `solver`: `"adam"` (default), `"sgd"`, `"bfgs"`, `"lbfgs"`, `"lbfgsb"` (needs
      jaxopt: `pip install "voxax[bounds]"`), an optax `GradientTransformation`, or an
      optimistix minimizer instance.
    - `learning_rate`: for `"adam"` / `"sgd"`.
    - `stop`: a `StopRules`.
    - `has_aux`: whether `fn` returns `(scalar, aux)`.
    - `progress`: show a progress bar (energy and max W as postfix).
    - `callback`: `callback(step, y, info) -> bool | None`, called after every step
      (before the stopping rules are checked) with the number of steps taken so far (1
      after the first), the new iterate, and a dict of floats: this step's history
      entries (`"energy"`, `"step_size"`, `"max_w"` if given, the aux terms). Returning
      True stops the run (`stop_reason == "callback"`, returning the new iterate) unless
      the energy is not finite or `max_w` already met its threshold.
    - `jit`: compile the step (default). `jit=False` runs it eagerly, for debugging.
    - `rtol`, `atol`: the solver's own (Cauchy) convergence tolerances, for solvers built
      from a name or an optax transformation (stop when both the step and the energy
      change are below `atol + rtol * |value|`); for `"lbfgsb"`, `atol` bounds the
      projected gradient's norm.
    - `step_size_fn`: optional `step_size_fn(y_new, y_old) -> scalar`.
    - `options`: optimistix solver options.
    - `bounds`: optional `(lower, upper)` box constraints (see above); for optax
      solvers and `"lbfgsb"` only.

    **Returns:**

    A `MinimizeResult` (`y`, `steps`, `stop_reason`, `history`, `energy`, `aux`).

    **Example:**

    ```python
    >>> rosen = lambda y, args: jnp.sum(100 * (y[1:] - y[:-1] ** 2) ** 2 + (1 - y[:-1]) ** 2)
    >>> r = voxax.minimize(rosen, jnp.zeros(4), solver="bfgs", progress=False)
    >>> r.stop_reason, r.y.round(4)
    ('converged', Array([1., 1., 1., 1.], dtype=float64))
    ```
    """
    if not callable(fn):
        raise TypeError(f"voxax.minimize: `fn` must be a callable fn(y, args), got {type(fn).__name__}")
    if not isinstance(stop, StopRules):
        raise TypeError(f"voxax.minimize: `stop` must be a StopRules, got {type(stop).__name__}")
    kind, solver = _make_solver(solver, learning_rate)
    options = {} if options is None else dict(options)
    y0 = jtu.tree_map(_as_inexact, y0)
    fn_aux = _WithAux(fn, has_aux)
    step_size_fn = _default_step_size if step_size_fn is None else step_size_fn

    f_struct, aux_struct, aux_names = _checked_fn(fn_aux, y0, args, stop)

    y0, lower, upper = _box_bounds(bounds, kind, y0)

    _init, _step, failure = _steppers(kind, solver, fn_aux, bounds, lower, upper, rtol, atol, step_size_fn, f_struct,
                                      aux_struct, options, stop, jit)

    state = _init(y0, args)
    y = y0

    def _record_name(name):
        return f"aux_{name}" if name in ("energy", "step_size", "time") else name

    records: dict[str, list] = {"energy": [], "step_size": [], "time": []}
    for name in aux_names:
        records[_record_name(name)] = []

    stop_reason = StopReason.MAX_STEPS
    steps = 0
    y_out = y0
    out_energy = None  # known energy at y_out (None: evaluate at the end)
    out_aux = None
    last_finite = None  # (y, energy, aux) of the last recorded point with finite energy
    streak_step = streak_energy = 0
    prev_energy = None
    start = time.perf_counter()

    bar = None
    if progress:
        bar = ProgressBar(stop.max_steps, "minimize")
    try:
        while steps < stop.max_steps:
            y_new, state, info, result = _step(y, state, args)
            info, result = jax.device_get((info, result))
            steps += 1
            energy = float(info["energy"])
            step_size = float(info["step_size"])
            aux_vals = {k: float(v) for k, v in info["aux"].items()}
            records["energy"].append(energy)
            records["step_size"].append(step_size)
            records["time"].append(time.perf_counter() - start)
            for k, v in aux_vals.items():
                records[_record_name(k)].append(v)
            point = y if kind == "optax" else y_new  # the point `energy` belongs to
            if bar is not None:
                bar.update(_bar_postfix(energy, step_size, aux_vals))
            if callback is not None:
                cb_info = {"energy": energy, "step_size": step_size, **aux_vals}
                stop_by_callback = bool(callback(steps, y_new, cb_info))
            else:
                stop_by_callback = False

            if not math.isfinite(energy):
                stop_reason = StopReason.NONFINITE
                if last_finite is not None:
                    y_out, out_energy, out_aux = last_finite
                else:
                    y_out, out_energy, out_aux = point, energy, None
                break
            last_finite = (point, energy, None)

            if stop.max_w_threshold is not None and aux_vals["max_w"] <= stop.max_w_threshold:
                stop_reason = StopReason.MAX_W
                y_out, out_energy = point, energy
                break

            y, y_out, out_energy = y_new, y_new, (None if kind == "optax" else energy)

            if stop_by_callback:
                stop_reason = StopReason.CALLBACK
                break

            if bool(info["failed"]):
                stop_reason = f"{StopReason.FAILED}: {failure(result)}"
                break
            if bool(info["done"]):
                stop_reason = StopReason.CONVERGED
                break
            accepted = bool(info["accepted"])
            if stop.min_step is not None and accepted:
                streak_step = streak_step + 1 if step_size < stop.min_step else 0
                if streak_step >= stop.patience:
                    stop_reason = StopReason.MIN_STEP
                    break
            if stop.energy_tol is not None and accepted:
                if prev_energy is not None:
                    streak_energy = streak_energy + 1 if abs(energy - prev_energy) < stop.energy_tol else 0
                    if streak_energy >= stop.patience:
                        stop_reason = StopReason.ENERGY_TOL
                        break
                prev_energy = energy
    except KeyboardInterrupt:
        stop_reason = StopReason.INTERRUPTED
    finally:
        if bar is not None:
            bar.close(stop_reason)

    # The energy and aux at the returned iterate (one extra evaluation when unknown).
    if out_energy is None or has_aux:
        f, out_aux = _compiled_eval(fn_aux, y_out, args) if jit else fn_aux(y_out, args)
        out_energy = float(f)
    history = {k: np.asarray(v, dtype=np.float64) for k, v in records.items()}
    return MinimizeResult(y=y_out, steps=steps, stop_reason=stop_reason, history=history,
                          energy=float(out_energy), aux=out_aux if has_aux else None)
