"""Shared pieces of the applications: mesh input, normalization, reports."""

from __future__ import annotations

import dataclasses
import operator
import typing
import warnings
from collections.abc import Mapping
from typing import Any, NamedTuple

import jax.numpy as jnp
import numpy as np

from .. import _validate
from .. import io as _io
from .._grid import Grid
from .._mesh import Mesh
from .._optimize import minimization as solve
from .._values import ValueEquality


def as_mesh(where: str, mesh: Any) -> Mesh:
    """A 3D voxax `Mesh` from a `Mesh`, a `trimesh.Trimesh` or a `(vertices, faces)` pair.

    A closed mesh that encloses a negative volume is inside out: the applications, which
    expect outward faces, refuse it with a message that says how to flip it.
    """
    out = mesh if isinstance(mesh, Mesh) else Mesh(*_validate.mesh_like(where, mesh))
    _validate.mesh(where, out.vertices, out.faces, dim=3, context="the applications need a 3D triangle mesh")
    refuse_inside_out(where, out)
    return out


def refuse_inside_out(where: str, mesh: Mesh) -> None:
    """Raises a `ValueError` for a closed mesh whose faces point inwards (negative volume)."""
    if mesh.n_faces == 0 or not _io.is_watertight(mesh.vertices, mesh.faces):
        return
    volume = mesh.signed_volume()
    if volume < 0:
        raise ValueError(
            f"{where}: the mesh is inside out (closed, enclosing a negative volume, {volume:.6g}): its faces "
            "must point outwards. Flip them: voxax.Mesh(mesh.vertices, mesh.faces[:, ::-1])"
        )


def warn_if_open(mesh: Mesh, where: str) -> None:
    if not _io.is_watertight(mesh.vertices, mesh.faces):
        warnings.warn(
            f"{where}: the mesh is not closed (it has boundary edges or inconsistently oriented "
            "faces), so its voxelization depends on the +z ray direction; results may be "
            "meaningless. Repair the mesh first (e.g. trimesh's fill_holes / fix_normals).",
            RuntimeWarning,
            stacklevel=3,
        )


def float_dtype(where: str, dtype=None):
    """The working float dtype: `dtype`, or float64 when x64 is enabled, else float32."""
    return _validate.float_dtype(where, dtype)


def check_resolution(where: str, resolution: int, multiple: int = 1, name: str = "resolution") -> int:
    """Cells per axis of a working grid: an int `>= 2` (a multiple of `multiple`) whose
    `resolution^3` float64 grid fits in memory (a `MemoryError` before any work)."""
    out = _validate.positive_int(where, name, resolution, minimum=max(2, multiple), multiple=multiple)
    _validate.check_allocation(where, 8.0 * float(out) ** 3, f"a {out}^3 grid (`{name}`)")
    return out


def check_positive(where: str, value: float, name: str, allow_zero: bool = False) -> float:
    return _validate.positive_float(where, name, value, allow_zero=allow_zero)


def check_steps(where: str, arap_weight: float, learning_rate: float, min_step: float | None = None):
    """The settings every deformation shares, checked: `(alpha, learning_rate, min_step)`."""
    alpha = check_positive(where, arap_weight, "arap_weight", allow_zero=True)
    learning_rate = check_positive(where, learning_rate, "learning_rate")
    if min_step is not None:
        min_step = check_positive(where, min_step, "min_step")
    return alpha, learning_rate, min_step


def working_mesh(where: str, source: Mesh, resolution: int, normalize: bool, max_abs: float, dtype):
    """The `[-1, 1]^3` grid of `resolution` cells, the mesh in its working frame (see
    `prepare`) and the working float dtype: `(grid, work, centre, scale, dtype)`."""
    normalize = _validate.flag(where, "normalize", normalize)
    grid = Grid.cube(resolution)
    work, centre, scale = prepare(source, normalize, max_abs, grid, where, stacklevel=4)
    return grid, work, centre, scale, float_dtype(where, dtype)


def prepare(mesh: Mesh, normalize: bool, max_abs: float, grid: Grid, where: str, stacklevel: int = 3):
    """Normalizes (or checks) a mesh for optimization on `grid`.

    Returns `(working mesh, centre, scale)` with `working = (mesh - centre) * scale`.
    """
    if normalize:
        work, centre, scale = _io.normalize(mesh, max_abs, return_transform=True)
    else:
        work, centre, scale = mesh, np.zeros(3), 1.0
        lo, hi = np.asarray(grid.lower), np.asarray(grid.upper)
        if np.any(work.vertices < lo) or np.any(work.vertices > hi):
            warnings.warn(
                f"{where}: parts of the mesh lie outside the grid {lo.tolist()}..{hi.tolist()}; "
                "they are not penalised. Pass normalize=True to fit the mesh in the grid.",
                RuntimeWarning,
                stacklevel=stacklevel,
            )
    return work, np.asarray(centre, dtype=np.float64), float(scale)


def restore(vertices, centre: np.ndarray, scale: float) -> np.ndarray:
    """Maps working-frame vertices back to the input mesh's frame."""
    return np.asarray(vertices, dtype=np.float64) / scale + centre


def history_dict(history: Mapping[str, Any]) -> dict[str, np.ndarray]:
    return {str(k): np.asarray(v) for k, v in dict(history or {}).items()}


def _field_value(where: str, name: str, kind, value):
    """One report field checked against its annotation and converted (`int`, `float`,
    `bool`, `str`, a real NumPy array, a mapping of names to real arrays)."""
    if kind is bool:
        if not isinstance(value, (bool, np.bool_)):
            raise TypeError(f"{where}: `{name}` must be a bool, got {type(value).__name__}")
        return bool(value)
    if kind is int:
        if isinstance(value, (bool, np.bool_)):
            raise TypeError(f"{where}: `{name}` must be an int, got bool")
        try:
            return int(operator.index(value))
        except TypeError:
            raise TypeError(f"{where}: `{name}` must be an int, got {type(value).__name__}") from None
    if kind is float:
        if isinstance(value, (bool, np.bool_, str, bytes, complex, np.complexfloating)) or np.ndim(value) != 0:
            raise TypeError(f"{where}: `{name}` must be a real number, got {type(value).__name__}")
        try:
            return float(value)
        except (TypeError, ValueError):
            raise TypeError(f"{where}: `{name}` must be a real number, got {type(value).__name__}") from None
    if kind is str:
        if not isinstance(value, str):
            raise TypeError(f"{where}: `{name}` must be a str, got {type(value).__name__}")
        return value
    if kind is np.ndarray:
        return np.asarray(_validate.typed_array(where, name, value, "fiub", "a real array"))
    # Mapping[str, np.ndarray]: the recorded series
    if not isinstance(value, Mapping):
        raise TypeError(f"{where}: `{name}` must be a mapping of names to arrays, got {type(value).__name__}")
    return {str(k): np.asarray(_validate.typed_array(where, f"{name}[{k!r}]", v, "fiub", "a real array"))
            for k, v in value.items()}


def check_report(report) -> None:
    """Checks and converts every field of a report dataclass against its annotation, so
    that a report built by hand with a wrong value fails at construction (one line naming
    the field) instead of printing or plotting garbage later. Arrays become NumPy arrays;
    `centre` must be a 3-vector and the histories 1D."""
    where = f"voxax.apps.{type(report).__name__}"
    hints = typing.get_type_hints(type(report))
    for f in dataclasses.fields(report):
        kind = hints[f.name]
        kind = kind if kind in (bool, int, float, str, np.ndarray) else Mapping
        value = _field_value(where, f.name, kind, getattr(report, f.name))
        if f.name == "centre" and value.shape != (3,):
            raise ValueError(f"{where}: `centre` must have shape (3,), got {value.shape}")
        if f.name.endswith("_history") and value.ndim != 1:
            raise ValueError(f"{where}: `{f.name}` must be 1D, got shape {value.shape}")
        object.__setattr__(report, f.name, value)


@dataclasses.dataclass(frozen=True, eq=False)
class Report(ValueEquality):
    """What an optimization did: the fields shared by every application's report.

    - `energy_history`: `(steps,)` total energy per step.
    - `history`: every recorded series by name (the energy terms, `"max_w"`, ...),
      as returned by `voxax.minimize`.
    - `steps`: optimization steps taken.
    - `stop_reason`: why the optimization stopped (from `voxax.minimize`).
    - `energy`: the final total energy.
    - `resolution`: cells per axis of the `[-1, 1]^3` grid used.

    Reports pickle, deep-copy and compare with `==` by value (arrays entry by entry). Every
    field is checked against its type when a report is built (a `TypeError` or
    `ValueError` naming the field).
    """

    energy_history: np.ndarray
    history: Mapping[str, np.ndarray]
    steps: int
    stop_reason: str
    energy: float
    resolution: int

    def __post_init__(self) -> None:
        check_report(self)

    def summary(self) -> str:
        """A few human-readable lines: every scalar field of the report."""
        lines = [f"{type(self).__name__}:"]
        for f in dataclasses.fields(self):
            value = getattr(self, f.name)
            if isinstance(value, (bool, np.bool_)):
                lines.append(f"  {f.name:<24} {bool(value)}")
            elif isinstance(value, (int, np.integer)):
                lines.append(f"  {f.name:<24} {int(value)}")
            elif isinstance(value, (float, np.floating)):
                lines.append(f"  {f.name:<24} {float(value):.6g}")
            elif isinstance(value, str):
                lines.append(f"  {f.name:<24} {value}")
        return "\n".join(lines)

    def to_dict(self, exclude: tuple[str, ...] = ("cell",)) -> dict:
        """The report as JSON-serialisable Python values (arrays become nested lists).

        **Arguments:**

        - `exclude`: field names to leave out (by default the large `cell` grid of a
          tiling report); a single name may be given as a string.
        """
        if isinstance(exclude, str):
            exclude = (exclude,)
        elif not isinstance(exclude, (tuple, list, set, frozenset)) or not all(isinstance(n, str) for n in exclude):
            raise TypeError(f"voxax.apps.{type(self).__name__}.to_dict: `exclude` must be a tuple of field names")

        def plain(x):
            if isinstance(x, np.ndarray):
                return x.tolist()
            if isinstance(x, (np.bool_, bool)):
                return bool(x)
            if isinstance(x, np.integer):
                return int(x)
            if isinstance(x, np.floating):
                return float(x)
            if isinstance(x, Mapping):
                return {str(k): plain(v) for k, v in x.items()}
            return x

        return {
            f.name: plain(getattr(self, f.name)) for f in dataclasses.fields(self) if f.name not in exclude
        } | {"type": type(self).__name__}

    def plot_history(self, path=None, title: str | None = None):
        """Plots every recorded series (energy terms, `max_w`, step size) against the step.

        One panel per series; series spanning more than two decades get a log scale (drawn
        by [`voxax.plot.history`][voxax.plot.history]).

        **Arguments:**

        - `path`: if given, the figure is saved there (PNG, PDF, ... by extension).
        - `title`: an optional figure title.

        **Returns:** the matplotlib `Figure`.
        """
        from .. import plot

        return plot.history(self, title=title or f"{type(self).__name__}: {self.steps} steps ({self.stop_reason})",
                            path=path)


def to_jax(x, dtype):
    return jnp.asarray(np.asarray(x), dtype=dtype)


class Run(NamedTuple):
    """The optimization options every application takes (see `voxax.minimize`)."""

    solver: Any
    learning_rate: float | None
    progress: Any
    callback: Any
    max_steps: int


def check_run(where: str, solver, learning_rate, progress, callback, max_steps) -> Run:
    """The optimization options of an application, checked: `max_steps` an int `>= 0`,
    `progress` a bool, `callback` None or callable (the solver is checked by `minimize`)."""
    if callback is not None and not callable(callback):
        raise TypeError(f"{where}: `callback` must be None or callable as callback(step, y, info), "
                        f"got {type(callback).__name__}")
    return Run(solver, learning_rate, _validate.flag(where, "progress", progress), callback,
               _validate.positive_int(where, "max_steps", max_steps, minimum=0))


def run_minimize(fn, y0, run: Run, *, step_size_fn=None, **stop):
    """Runs `voxax.minimize` on `fn(y, args) -> (energy, aux)` with the options of `run`
    and the given extra stop rules.

    Returns `voxax.MinimizeResult` (`y`, `steps`, `stop_reason`, `history`, `energy`).
    """
    stop["max_steps"] = run.max_steps
    rules = solve.StopRules(**{k: v for k, v in stop.items() if v is not None})
    kwargs = {} if step_size_fn is None else {"step_size_fn": step_size_fn}
    return solve.minimize(
        fn,
        y0,
        None,
        solver=run.solver,
        learning_rate=run.learning_rate,
        stop=rules,
        has_aux=True,
        progress=run.progress,
        callback=run.callback,
        **kwargs,
    )


def result_fields(result) -> dict[str, Any]:
    """The report fields every application takes from its `MinimizeResult`."""
    return {
        "energy_history": energy_series(result),
        "history": history_dict(result.history),
        "steps": int(result.steps),
        "stop_reason": str(result.stop_reason),
        "energy": float(result.energy),
    }


def check_grids(grid: Grid, resolution: int) -> dict[str, Grid]:
    """The grids on which applications re-measure their results beyond the working grid:
    twice as fine, and shifted by half a cell."""
    h = grid.spacing[0]
    shifted = Grid(
        lower=tuple(lo + h / 2 for lo in grid.lower), upper=tuple(hi + h / 2 for hi in grid.upper), shape=grid.shape
    )
    return {"fine": Grid.cube(2 * resolution), "shifted": shifted}


def energy_series(result) -> np.ndarray:
    hist = dict(getattr(result, "history", {}) or {})
    for key in ("energy", "value", "loss", "f"):
        if key in hist:
            return np.asarray(hist[key], dtype=np.float64).reshape(-1)
    return np.zeros(0)
