"""Optimizing the parameters of an implicit field through its extracted iso-surface."""

from __future__ import annotations

import dataclasses
import time
from collections.abc import Callable
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from .. import _validate, energies, metrics
from .._grid import Grid
from .._isosurface import isosurface_fn
from .._values import ValueEquality
from .._voxelize import voxelize
from ._common import as_mesh, check_report

_RULES = ("meshsdf", "theorem1", "level_set")


@dataclasses.dataclass(frozen=True, eq=False)
class ImplicitReport(ValueEquality):
    """What [`optimize_implicit`][voxax.apps.optimize_implicit] did.

    - `loss_history`: `(steps,)` float, the silhouette loss at each step (before its update).
    - `euler_history`: `(steps,)` int, the Euler characteristic of the extracted mesh.
    - `faces_history`: `(steps,)` int, its face count.
    - `steps`: steps taken; `stop_reason`: `"max_steps"` or `"target_euler"`.
    - `loss`, `euler`: loss and Euler characteristic of the mesh of the returned parameters.
    - `seconds`: wall time.

    Reports pickle and compare with `==` by value; every field is checked against its type
    when a report is built.
    """

    loss_history: np.ndarray
    euler_history: np.ndarray
    faces_history: np.ndarray
    steps: int
    stop_reason: str
    loss: float
    euler: int
    seconds: float

    def __post_init__(self) -> None:
        check_report(self)

    def summary(self) -> str:
        """A few human-readable lines."""
        chi = self.euler_history
        changes = [f"{int(c)}@{i}" for i, c in enumerate(chi) if i == 0 or c != chi[i - 1]]
        start = f"{self.loss_history[0]:.4g} -> " if self.loss_history.size else ""
        return (
            f"ImplicitReport: {self.steps} steps ({self.stop_reason}), loss {start}{self.loss:.4g}, "
            f"Euler characteristic {' -> '.join(changes + [str(self.euler)])}, {self.seconds:.1f} s"
        )


def _bucket(n: int) -> int:
    return max(256, 1 << int(np.ceil(np.log2(max(n, 1)))))


def _target_silhouettes(target, grid: Grid, w: float):
    if isinstance(target, (tuple, list)) and len(target) == 3 and all(np.ndim(t) == 2 for t in target):
        sil = tuple(jnp.asarray(_validate.finite_values("voxax.apps.optimize_implicit", "target",
                                                        _validate.typed_array("voxax.apps.optimize_implicit", "target", t)))
                    for t in target)
    else:
        m = as_mesh("voxax.apps.optimize_implicit", target)
        W = voxelize(jnp.asarray(m.vertices, jnp.result_type(float)), jnp.asarray(m.faces), grid)
        sil = energies.silhouettes(W, w)
    want = ((grid.shape[1], grid.shape[2]), (grid.shape[0], grid.shape[2]), (grid.shape[0], grid.shape[1]))
    if tuple(s.shape for s in sil) != want:
        raise ValueError(f"voxax.apps.optimize_implicit: `target` silhouettes must have shapes {want}, got "
                         f"{tuple(s.shape for s in sil)}")
    return sil


def optimize_implicit(
    fn: Callable,
    params: Any,
    target,
    grid: Grid,
    *,
    steps: int = 200,
    learning_rate: float = 0.05,
    level: float = 0.0,
    rule: str = "meshsdf",
    w: float = 1000.0,
    target_euler: int | None = None,
    callback: Callable | None = None,
):
    """Optimizes the parameters of a field so that its iso-surface casts given silhouettes.

    Each step extracts the iso-surface of `fn(params, ·)` on `grid` (marching cubes, closed
    at the grid border), voxelizes it on the same grid (the differentiable renderer), takes
    its three axis silhouettes with [`energies.silhouettes`][voxax.energies.silhouettes]
    and compares them with the target's: `loss = Σ_axis mean((S - S_target)²)`. The gradient
    reaches `params` through the vertices by the MeshSDF rule (see
    [`isosurface_fn`][voxax.isosurface_fn]), so the mesh may change topology from one step
    to the next. Parameters are updated with Adam (optax). The mesh size changes every step,
    so each step runs [`isosurface_fn`][voxax.isosurface_fn] with a static `capacity` (padded
    vertex and face counts, twice the first mesh's, doubled when a mesh outgrows them) inside
    one compiled function.

    **Arguments:**

    - `fn`: `fn(params, x) -> f`, `x` `(N, 3)` float points, `f` `(N,)` values, inside where
      `f < level` (a signed distance for the default rule).
    - `params`: pytree of float arrays, the starting parameters (a latent code, weights).
    - `target`: a closed mesh (voxax `Mesh`, `trimesh.Trimesh` or `(vertices, faces)`) whose
      silhouettes are matched, or its three silhouettes `(Sx, Sy, Sz)`.
    - `grid`: 3D `voxax.Grid` for extraction and rendering.
    - `steps`: at most this many Adam steps; `learning_rate`: Adam's step size.
    - `level`: the iso-level; `rule`: `"meshsdf"`, `"theorem1"` or `"level_set"`.
    - `w`: mellowmax sharpness of the silhouettes.
    - `target_euler`: if given, stop as soon as the extracted mesh has this Euler
      characteristic.
    - `callback`: `callback(step, params, iso, loss)` called every step.

    **Returns:**

    `(params, report)`: the parameters with the lowest loss seen (or, when stopped by
    `target_euler`, those that reached it) and an
    [`ImplicitReport`][voxax.apps.ImplicitReport] (loss, Euler characteristic and face
    count per step).
    """
    import optax

    name = "voxax.apps.optimize_implicit"
    if not callable(fn):
        raise TypeError(f"{name}: `fn` must be callable as fn(params, x)")
    if not isinstance(grid, Grid) or grid.dim != 3:
        raise TypeError(f"{name}: `grid` must be a 3D voxax.Grid")
    if rule not in _RULES:
        raise ValueError(f"{name}: `rule` must be one of {_RULES}, got {rule!r}")
    if isinstance(steps, bool) or not isinstance(steps, (int, np.integer)) or steps < 1:
        raise ValueError(f"{name}: `steps` must be a positive int, got {steps!r}")
    learning_rate = _validate.positive_float(name, "learning_rate", learning_rate)
    w = _validate.positive_float(name, "w", w)
    if target_euler is not None:
        target_euler = _validate.positive_int(name, "target_euler", target_euler, minimum=-(2**62))
    if callback is not None and not callable(callback):
        raise TypeError(f"{name}: `callback` must be None or callable as callback(step, params, iso, loss)")
    for leaf in jax.tree_util.tree_leaves(params):
        _validate.typed_array(name, "params", leaf, "fiu", "a pytree of real arrays")
    sil = _target_silhouettes(target, grid, w)
    # Strong (not weakly typed) float leaves, so that the compiled step is not retraced.
    params = jax.tree_util.tree_map(
        lambda a: jnp.array(a, dtype=jnp.result_type(a) if jnp.issubdtype(jnp.result_type(a), jnp.floating)
                            else jnp.result_type(float)), params)

    def loss(p, capacity):
        iso = isosurface_fn(fn, p, grid, level, rule=rule, close=True, capacity=capacity)
        S = energies.silhouettes(voxelize(iso.vertices, iso.faces, grid), w)
        return sum(jnp.mean((a - b) ** 2) for a, b in zip(S, sil)), jax.lax.stop_gradient(iso)

    loss_and_grad = jax.jit(jax.value_and_grad(loss, has_aux=True), static_argnums=1)

    opt = optax.adam(learning_rate)
    state = opt.init(params)
    losses, chis, nfaces = [], [], []
    best = (np.inf, params, None)
    reason = "max_steps"
    start = time.perf_counter()
    for step in range(steps):
        if step == 0:
            first = isosurface_fn(fn, params, grid, level, rule=rule, close=True).to_mesh()
            capacity = (_bucket(2 * first.n_vertices), _bucket(2 * first.n_faces))
        while True:
            try:
                (value, iso), grads = jax.block_until_ready(loss_and_grad(params, capacity))
                break
            except (RuntimeError, ValueError) as err:  # the mesh outgrew the capacity
                if "capacity" not in str(err):
                    raise
                capacity = (2 * capacity[0], 2 * capacity[1])
        mesh = iso.to_mesh()
        if mesh.n_faces == 0:
            raise ValueError(f"{name}: the iso-surface is empty at step {step}; start from parameters with a surface")
        value = float(value)
        if not np.isfinite(value):
            raise ValueError(f"{name}: the loss is not finite at step {step} (NaN or Inf in the field's values "
                             "or its gradient); start from other parameters or lower `learning_rate`")
        chi = metrics.euler_characteristic(mesh)
        losses.append(value)
        chis.append(chi)
        nfaces.append(mesh.n_faces)
        if callback is not None:
            callback(step, params, iso, value)
        if value < best[0] or target_euler is not None and chi == target_euler:
            best = (value, params, chi)
        if target_euler is not None and chi == target_euler:
            reason = "target_euler"
            break
        updates, state = opt.update(grads, state, params)
        params = optax.apply_updates(params, updates)
    report = ImplicitReport(
        loss_history=np.asarray(losses),
        euler_history=np.asarray(chis, dtype=np.int64),
        faces_history=np.asarray(nfaces, dtype=np.int64),
        steps=len(losses),
        stop_reason=reason,
        loss=float(best[0]),
        euler=int(best[2]),
        seconds=time.perf_counter() - start,
    )
    return best[1], report
