"""Deforming a shape so that a bandsaw can cut it (paper section 4.3)."""

from __future__ import annotations

import dataclasses
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from .. import _validate, energies
from .._mesh import Mesh
from .._voxelize import voxelize
from . import _common


@dataclasses.dataclass(frozen=True, eq=False)
class BandsawReport(_common.Report):
    """The outcome of [`optimize_for_bandsaw`][voxax.apps.optimize_for_bandsaw].

    Besides the shared fields of every report (`energy_history`, `history`, `steps`,
    `stop_reason`, `energy`, `resolution`):

    - `cut_initial`, `cut_final`: the cut energy `E_cut = mean((S - W)^2)` of the input and
      of the result (same grid, same `w`).
    - `relative_improvement`: `1 - cut_final / cut_initial`, the paper's measure of how
      much of the material that cutting cannot remove the deformation got rid of.
    - `waste_volume_initial`, `waste_volume_final`: `sum(max(S - W, 0)) * voxel volume` in
      the input mesh's units (cubed): the voxel estimate of the material left by cutting
      along the three silhouettes that does not belong to the shape.
    - `cut_fine_initial`, `cut_fine_final`, `waste_volume_fine_initial`,
      `waste_volume_fine_final`, `relative_improvement_fine`: the same figures measured on a
      grid twice as fine (`2 * resolution` cells per axis, same box), to check that the
      improvement is not an artefact of the working grid.
    - `cut_shifted_initial`, `cut_shifted_final`, `waste_volume_shifted_initial`,
      `waste_volume_shifted_final`, `relative_improvement_shifted`: the same figures on the
      working grid shifted by half a voxel along every axis.
    - `arap_final`: ARAP energy of the result against the input (working frame).
    - `max_displacement`: the largest vertex move, in the input mesh's units.
    - `w`: the mellowmax sharpness used for the silhouettes.
    - `centre`, `scale`: the normalization, `working = (input - centre) * scale`.
    """

    cut_initial: float
    cut_final: float
    relative_improvement: float
    waste_volume_initial: float
    waste_volume_final: float
    cut_fine_initial: float
    cut_fine_final: float
    waste_volume_fine_initial: float
    waste_volume_fine_final: float
    relative_improvement_fine: float
    cut_shifted_initial: float
    cut_shifted_final: float
    waste_volume_shifted_initial: float
    waste_volume_shifted_final: float
    relative_improvement_shifted: float
    arap_final: float
    max_displacement: float
    w: float
    centre: np.ndarray
    scale: float


@_validate.surface_first
def optimize_for_bandsaw(
    mesh: Any,
    *,
    resolution: int = 128,
    w: float = 1000.0,
    arap_weight: float = 0.05,
    learning_rate: float = 1e-3,
    min_step: float | None = 5e-4,
    max_steps: int = 1000,
    solver: Any = "adam",
    normalize: bool = True,
    max_abs: float = 0.8,
    dtype=None,
    progress: bool = True,
    callback=None,
) -> tuple[Mesh, BandsawReport]:
    """Deforms a mesh as rigidly as possible so that cutting its three silhouettes wastes less.

    The paper's section 4.3: voxelize the mesh (`W`) on the `[-1, 1]^3` grid, take its
    silhouettes along x, y and z by mellowmax with sharpness `w`
    (`voxax.energies.silhouettes`), form the cut shape `S = Sx * Sy * Sz` (the silhouettes
    extruded along their axes and intersected: what a bandsaw cutting the three
    silhouettes leaves), and minimize `E_cut = mean((S - W)^2)`
    (`voxax.energies.bandsaw_cut`) plus `arap_weight * E_arap` with Adam. The optimization
    stops when no vertex coordinate moves more than `min_step` in a step (stop reason from
    `voxax.minimize`), or after `max_steps`.

    By default the mesh is first centred and scaled to `max |v| = max_abs`, and the result
    is mapped back to the input's frame. Winding numbers above one (self-overlaps) count
    as extra volume, so overlaps are penalised too.

    **Arguments:**

    - `mesh`: a closed, outward-oriented triangle mesh: voxax `Mesh`, `trimesh.Trimesh` or
      `(vertices (V, 3), faces (F, 3))`.
    - `resolution`: cells per axis (paper: 128).
    - `w`: mellowmax sharpness (paper: 1000).
    - `arap_weight`: weight of the ARAP regulariser (paper: 0.05).
    - `learning_rate`: Adam's learning rate (paper: 1e-3).
    - `min_step`: stop when the largest vertex-coordinate change of a step is below this
      (paper: 5e-4, in the normalized frame); `None` to run `max_steps` steps.
    - `max_steps`: the most optimization steps.
    - `solver`: passed to `voxax.minimize`.
    - `normalize`, `max_abs`: normalize the mesh to `max |v| = max_abs` first.
    - `dtype`: float32 or float64 (default: float64 when JAX's x64 mode is on).
    - `progress`, `callback`: passed to `voxax.minimize`.

    **Returns:** `(mesh, report)`: the deformed `Mesh` (same faces, input frame) and a
    [`BandsawReport`][voxax.apps.BandsawReport] with the relative improvement.

    **Example:**

    ```python
    >>> import voxax, voxax.apps
    >>> mesh, report = voxax.apps.optimize_for_bandsaw(voxax.data.hand(), resolution=32, progress=False)
    >>> report.relative_improvement > 0.2
    True

    ```
    """
    source = _common.as_mesh("voxax.apps.optimize_for_bandsaw", mesh)
    _common.warn_if_open(source, "voxax.apps.optimize_for_bandsaw")
    resolution = _common.check_resolution("voxax.apps.optimize_for_bandsaw", resolution)
    w = _common.check_positive("voxax.apps.optimize_for_bandsaw", w, "w")
    alpha, learning_rate, min_step = _common.check_steps("voxax.apps.optimize_for_bandsaw", arap_weight, learning_rate, min_step)
    grid, work, centre, scale, dt = _common.working_mesh("voxax.apps.optimize_for_bandsaw", source, resolution, normalize, max_abs, dtype)
    faces = jnp.asarray(work.faces)
    rest = _common.to_jax(work.vertices, dt)

    def energy(v, args):
        W = voxelize(v, faces, grid)
        e_cut = energies.bandsaw_cut(W, w)
        e_arap = energies.arap(v, rest, faces)
        return e_cut + alpha * e_arap, {"cut": e_cut, "arap": e_arap}

    @jax.jit
    def measure(v):
        W = voxelize(v, faces, grid)
        S = energies.cut_shape(W, w)
        return (
            energies.bandsaw_cut(W, w),
            jnp.sum(jnp.maximum(S - W, 0.0)) * grid.voxel_volume,
            energies.arap(v, rest, faces),
        )

    cut0, waste0, _ = measure(rest)
    checks = _common.check_grids(grid, resolution)

    def cut_and_waste(v, g):
        W = voxelize(v, faces, g)
        S = energies.cut_shape(W, w)
        return float(energies.bandsaw_cut(W, w)), float(jnp.sum(jnp.maximum(S - W, 0.0)) * g.voxel_volume)

    before = {k: cut_and_waste(rest, g) for k, g in checks.items()}
    result = _common.run_minimize(
        energy,
        rest,
        _common.check_run("voxax.apps.optimize_for_bandsaw", solver, learning_rate, progress, callback, max_steps),
        min_step=min_step,
    )
    v_final = jnp.asarray(result.y, dtype=dt)
    cut1, waste1, arap1 = measure(v_final)
    after = {k: cut_and_waste(v_final, g) for k, g in checks.items()}
    extra = {}
    for k in checks:
        extra[f"cut_{k}_initial"], extra[f"waste_volume_{k}_initial"] = before[k]
        extra[f"cut_{k}_final"], extra[f"waste_volume_{k}_final"] = after[k]
        extra[f"relative_improvement_{k}"] = 1.0 - after[k][0] / before[k][0] if before[k][0] > 0 else 0.0
        extra[f"waste_volume_{k}_initial"] /= scale**3
        extra[f"waste_volume_{k}_final"] /= scale**3
    out = Mesh(_common.restore(v_final, centre, scale), source.faces)
    cut0, cut1 = float(cut0), float(cut1)
    s3 = scale**3
    report = BandsawReport(
        **_common.result_fields(result),
        resolution=resolution,
        cut_initial=cut0,
        cut_final=cut1,
        relative_improvement=(1.0 - cut1 / cut0) if cut0 > 0 else 0.0,
        waste_volume_initial=float(waste0) / s3,
        waste_volume_final=float(waste1) / s3,
        arap_final=float(arap1),
        max_displacement=float(np.max(np.linalg.norm(out.vertices - source.vertices, axis=1))),
        **extra,
        w=w,
        centre=centre,
        scale=scale,
    )
    return out, report
