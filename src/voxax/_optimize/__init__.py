"""Optimization drivers (public names re-exported by `voxax`).

- `minimization`: the jit-compiled optimistix/optax loop with the paper's stopping rules.
- `lsq`: Gauss-Newton, Levenberg-Marquardt and dogleg on residuals.
"""

from .lsq import LeastSquaresResult, least_squares
from .minimization import MinimizeResult, StopReason, StopRules, minimize

__all__ = ["LeastSquaresResult", "least_squares", "MinimizeResult", "StopReason", "StopRules", "minimize"]
