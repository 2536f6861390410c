"""`least_squares`: Gauss-Newton-type solvers (optimistix) on voxel residuals.

Levenberg-Marquardt, Gauss-Newton and dogleg linearize the residual function
(`jax.linearize`: forward mode) and solve with its Jacobian and the Jacobian's transpose
(reverse mode); `voxax.voxelize` provides both, so these solvers work on residuals built
from voxelizations, such as `voxelize(template + offsets) - target`.
"""

from __future__ import annotations

import dataclasses
import time
from collections.abc import Callable
from typing import Any

import jax
import jax.numpy as jnp
import lineax as lx
import numpy as np
import optimistix as optx

from .. import _validate

__all__ = ["LeastSquaresResult", "least_squares"]

_SOLVERS = {
    "levenberg_marquardt": optx.LevenbergMarquardt,
    "gauss_newton": optx.GaussNewton,
    "dogleg": optx.Dogleg,
}


@dataclasses.dataclass(frozen=True)
class LeastSquaresResult:
    """The outcome of `least_squares`.

    **Attributes:**

    - `value`: the parameters found (a pytree like `y0`).
    - `loss`: float, half the sum of squared residuals at `value`.
    - `steps`: int, the solver steps taken.
    - `converged`: bool, whether the solver met its tolerances (rather than running out of
      steps or failing).
    - `message`: str, optimistix's description of the outcome.
    - `seconds`: float, wall-clock time of the solve (including compilation).
    - `solution`: the full `optimistix.Solution`.
    """

    value: Any
    loss: float
    steps: int
    converged: bool
    message: str
    seconds: float
    solution: Any


def least_squares(
    residual_fn: Callable,
    y0,
    args=None,
    *,
    solver: str | optx.AbstractLeastSquaresSolver = "levenberg_marquardt",
    rtol: float = 1e-6,
    atol: float = 1e-8,
    max_steps: int = 100,
    linear_solver=None,
    throw: bool = False,
) -> LeastSquaresResult:
    """Minimizes `0.5 * sum(residual_fn(y, args) ** 2)` with an optimistix least-squares solver.

    A thin wrapper around `optimistix.least_squares` that picks the solver by name and
    reports the outcome as a `LeastSquaresResult`. The residuals may be any pytree of
    arrays (for example a voxel difference and a smoothness term). The solvers need the
    Jacobian-vector products and their transposes of `residual_fn`, which
    `voxax.voxelize` supports (forward and reverse mode). Calling
    `optimistix.least_squares` directly works just as well.

    **Arguments:**

    - `residual_fn`: `fn(y, args) -> residuals`, a pytree of float arrays.
    - `y0`: the initial parameters, a pytree of float arrays.
    - `args`: passed through to `residual_fn`.
    - `solver`: `"levenberg_marquardt"` (default), `"gauss_newton"`, `"dogleg"`, or an
      optimistix least-squares solver instance (then `rtol`, `atol` and `linear_solver`
      are ignored).
    - `rtol`, `atol`: the solver's relative and absolute tolerances on the steps and the
      residuals.
    - `max_steps`: int, the most solver steps.
    - `linear_solver`: a lineax solver for the linear subproblems. The default, None,
      is matrix-free conjugate gradients on the normal equations,
      `lineax.Normal(lineax.CG(rtol=1e-6, atol=1e-12))`: one JVP and one VJP of the
      residuals per iteration, never the whole Jacobian. With few parameters,
      `lineax.Normal(lineax.Cholesky())` (one JVP and one VJP per parameter and step) is
      a robust alternative; optimistix's own default for Levenberg-Marquardt, a dense
      `lineax.QR()` of the Jacobian, was far slower on voxel residuals in our
      measurements.
    - `throw`: bool, raise when the solver fails or runs out of steps (default False:
      the result says so instead).

    **Returns:**

    A `LeastSquaresResult`.

    **Example:**

    ```python
    >>> import jax.numpy as jnp, voxax
    >>> res = voxax.least_squares(lambda y, a: y ** 2 - a, jnp.array([1.0, 3.0]), jnp.array([2.0, 4.0]))
    >>> [round(float(x), 6) for x in res.value]
    [1.414214, 2.0]
    ```
    """
    where = "voxax.least_squares"
    if not callable(residual_fn):
        raise TypeError(f"{where}: `residual_fn` must be a function residual_fn(y, args), got "
                        f"{type(residual_fn).__name__}")
    rtol = _validate.positive_float(where, "rtol", rtol, allow_zero=True)
    atol = _validate.positive_float(where, "atol", atol, allow_zero=True)
    for leaf in jax.tree_util.tree_leaves(y0):
        a = np.asarray(leaf) if _validate.is_concrete(leaf) else None
        if a is not None and a.dtype.kind in "fc" and not np.all(np.isfinite(a)):
            raise ValueError(f"{where}: `y0` must be finite (it contains NaN or Inf)")
    if isinstance(solver, str):
        if solver not in _SOLVERS:
            raise ValueError(f"voxax.least_squares: unknown solver {solver!r}; choose one of {sorted(_SOLVERS)}")
        if linear_solver is None:
            linear_solver = lx.Normal(lx.CG(rtol=1e-6, atol=1e-12))
        solver = _SOLVERS[solver](rtol=rtol, atol=atol, linear_solver=linear_solver)
    elif not isinstance(solver, optx.AbstractLeastSquaresSolver):
        raise TypeError(
            f"voxax.least_squares: `solver` must be a name or an optimistix least-squares solver, got {type(solver).__name__}"
        )
    max_steps = _validate.positive_int("voxax.least_squares", "max_steps", max_steps, maximum=2**63 - 1)
    start = time.perf_counter()
    sol = optx.least_squares(residual_fn, solver, y0, args=args, max_steps=max_steps, throw=throw)
    value = jax.block_until_ready(sol.value)
    seconds = time.perf_counter() - start
    residuals = residual_fn(value, args)
    loss = 0.5 * sum(float(jnp.sum(jnp.square(r))) for r in jax.tree_util.tree_leaves(residuals))
    converged = bool(sol.result == optx.RESULTS.successful)
    return LeastSquaresResult(
        value=value,
        loss=loss,
        steps=int(sol.stats["num_steps"]),
        converged=converged,
        message="converged" if converged else str(optx.RESULTS[sol.result]),
        seconds=seconds,
        solution=sol,
    )
