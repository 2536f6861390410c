"""Resolving self-intersections (paper section 4.2)."""

from __future__ import annotations

import dataclasses
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from .. import energies
from .._grid import Grid
from .._mesh import Mesh
from .._voxelize import voxelize
from . import _common


@dataclasses.dataclass(frozen=True, eq=False)
class SelfIntersectionReport(_common.Report):
    """The outcome of [`resolve_self_intersections`][voxax.apps.resolve_self_intersections].

    Besides the shared fields of every report (`energy_history`, `history`, `steps`,
    `stop_reason`, `energy`, `resolution`):

    - `resolved`: whether no voxel of the result exceeds `1 + eps`.
    - `eps`: the tolerance used.
    - `max_w_initial`, `max_w_final`: the largest voxel value before and after.
    - `overlap_voxels_initial`, `overlap_voxels_final`: voxels above `1 + eps`.
    - `overlap_volume_initial`, `overlap_volume_final`: `sum(max(W - 1, 0)) * voxel volume`,
      in the input mesh's units (cubed).
    - `arap_final`: the ARAP energy of the result against the input (working frame).
    - `max_displacement`: the largest vertex move, in the input mesh's units.
    - `volume_initial`, `volume_final`: signed volumes of the input and the result.
    - `centre`, `scale`: the normalization, `working = (input - centre) * scale`.
    """

    resolved: bool
    eps: float
    max_w_initial: float
    max_w_final: float
    overlap_voxels_initial: int
    overlap_voxels_final: int
    overlap_volume_initial: float
    overlap_volume_final: float
    arap_final: float
    max_displacement: float
    volume_initial: float
    volume_final: float
    centre: np.ndarray
    scale: float


def resolve_self_intersections(
    mesh: Any,
    *,
    resolution: int = 128,
    eps: float = 1e-3,
    arap_weight: float = 0.005,
    learning_rate: float = 1e-2,
    max_steps: int = 2000,
    solver: Any = "adam",
    normalize: bool = True,
    max_abs: float = 0.8,
    dtype=None,
    progress: bool = True,
    callback=None,
) -> tuple[Mesh, SelfIntersectionReport]:
    """Deforms a mesh as rigidly as possible until no part of it overlaps another.

    The paper's section 4.2: voxelize the mesh on the `[-1, 1]^3` grid at `resolution`,
    penalise every voxel whose box-filtered winding number exceeds `1 + eps` with
    `E_sect = sum_{W > 1 + eps} W^2 / n_voxels` (`voxax.energies.self_intersection`), add
    `arap_weight * E_arap` (spokes-and-rims ARAP against the input,
    `voxax.energies.arap`), and minimize with Adam until no voxel exceeds `1 + eps`
    (stop reason `max_w`), or for at most `max_steps` steps.

    By default the mesh is first centred and scaled so that `max |v| = max_abs = 0.8` (the
    paper's set-up, so `eps` and `arap_weight` mean the same for every input); the result
    is mapped back to the input's frame. Overlaps thinner than a voxel, and overlaps hidden
    by inverted parts (negative winding numbers), are not seen at a given resolution.

    **Arguments:**

    - `mesh`: a closed, outward-oriented triangle mesh: voxax `Mesh`, `trimesh.Trimesh` or
      `(vertices (V, 3), faces (F, 3))`.
    - `resolution`: cells per axis of the grid (paper: 128).
    - `eps`: voxels above `1 + eps` count as overlapping (paper: 1e-3).
    - `arap_weight`: weight of the ARAP regulariser (paper: 0.005).
    - `learning_rate`: Adam's learning rate (paper: 1e-2).
    - `max_steps`: the most optimization steps.
    - `solver`: passed to `voxax.minimize` (`"adam"`, `"lbfgs"`, ...).
    - `normalize`, `max_abs`: normalize the mesh to `max |v| = max_abs` first (else the
      mesh must already lie inside `[-1, 1]^3`).
    - `dtype`: float32 or float64 (default: float64 when JAX's x64 mode is on).
    - `progress`: show the solver's progress.
    - `callback`: passed to `voxax.minimize`.

    **Returns:** `(mesh, report)`: the deformed `Mesh` (same faces, input frame) and a
    [`SelfIntersectionReport`][voxax.apps.SelfIntersectionReport].

    **Example:**

    ```python
    >>> import voxax, voxax.apps
    >>> mesh, report = voxax.apps.resolve_self_intersections(voxax.data.bent_bar(), resolution=32, progress=False)
    >>> report.resolved, report.max_w_initial > 1.9
    (True, True)

    ```
    """
    source = _common.as_mesh(mesh)
    _common.warn_if_open(source, "resolve_self_intersections")
    resolution = _common.check_resolution(resolution)
    eps = _common.check_positive(eps, "eps", allow_zero=True)
    alpha = _common.check_positive(arap_weight, "arap_weight", allow_zero=True)
    learning_rate = _common.check_positive(learning_rate, "learning_rate")
    grid = Grid.cube(resolution)
    work, centre, scale = _common.prepare(source, normalize, max_abs, grid, "resolve_self_intersections")
    dt = _common.float_dtype(dtype)
    faces = jnp.asarray(work.faces)
    rest = _common.to_jax(work.vertices, dt)
    threshold = 1.0 + eps

    def energy(v, args):
        W = voxelize(v, faces, grid)
        e_sect = energies.self_intersection(W, eps=eps)
        e_arap = energies.arap(v, rest, faces)
        return e_sect + alpha * e_arap, {
            "self_intersection": e_sect,
            "arap": e_arap,
            "max_w": jnp.max(W),
        }

    @jax.jit
    def measure(v):
        W = voxelize(v, faces, grid)
        over = W > threshold
        return (
            jnp.max(W),
            jnp.sum(over),
            jnp.sum(jnp.maximum(W - 1.0, 0.0)) * grid.voxel_volume,
            energies.arap(v, rest, faces),
        )

    max_w0, over0, ovol0, _ = measure(rest)
    result = _common.run_minimize(
        energy,
        rest,
        solver=solver,
        learning_rate=learning_rate,
        progress=progress,
        callback=callback,
        max_steps=int(max_steps),
        max_w_threshold=threshold,
    )
    v_final = jnp.asarray(result.y, dtype=dt)
    max_w1, over1, ovol1, arap1 = measure(v_final)
    out = Mesh(_common.restore(v_final, centre, scale), source.faces)
    s3 = scale**3
    report = SelfIntersectionReport(
        energy_history=_common.energy_series(result),
        history=_common.history_dict(result.history),
        steps=int(result.steps),
        stop_reason=str(result.stop_reason),
        energy=float(result.energy),
        resolution=resolution,
        resolved=bool(float(max_w1) <= threshold),
        eps=eps,
        max_w_initial=float(max_w0),
        max_w_final=float(max_w1),
        overlap_voxels_initial=int(over0),
        overlap_voxels_final=int(over1),
        overlap_volume_initial=float(ovol0) / s3,
        overlap_volume_final=float(ovol1) / s3,
        arap_final=float(arap1),
        max_displacement=float(np.max(np.linalg.norm(out.vertices - source.vertices, axis=1))),
        volume_initial=source.signed_volume(),
        volume_final=out.signed_volume(),
        centre=centre,
        scale=scale,
    )
    return out, report
