"""Deforming a shape so that it can be cast in a two-piece mould."""

from __future__ import annotations

import dataclasses
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from .. import _validate, energies, esi
from .._mesh import Mesh
from .._voxelize import voxelize
from . import _common


@dataclasses.dataclass(frozen=True, eq=False)
class MoldingReport(_common.Report):
    """The outcome of [`optimize_for_molding`][voxax.apps.optimize_for_molding].

    Besides the shared fields of every report:

    - `axis`: the mould's axis (0, 1, 2: the parting plane is perpendicular to it).
    - `gap_initial`, `gap_final`: the soft hull gap `mean((H - W)^2)` of the input and of
      the result (`H` the soft double-height-field hull along `axis`).
    - `relative_improvement`: `1 - gap_final / gap_initial`.
    - `undercut_volume_initial`, `undercut_volume_final`: `volume(DHF) - volume(shape)`,
      measured exactly on the mesh (the DHF meshed from `2 * resolution` depth maps with
      [`voxax.esi.to_mesh`][voxax.esi.to_mesh]), in the input's units cubed: the material
      a two-piece mould along `axis` would add.
    - `arap_final`, `max_displacement`, `w`, `centre`, `scale`: as for the bandsaw.
    """

    axis: int
    gap_initial: float
    gap_final: float
    relative_improvement: float
    undercut_volume_initial: float
    undercut_volume_final: float
    arap_final: float
    max_displacement: float
    w: float
    centre: np.ndarray
    scale: float


def _undercut(mesh: Mesh, axis: int, resolution: int) -> float:
    d = np.eye(3)[axis]
    hull = esi.to_mesh((d, ()), mesh, resolution=resolution)
    return float(hull.signed_volume() - mesh.signed_volume())


@_validate.surface_first
def optimize_for_molding(
    mesh: Any,
    axis: int = 2,
    *,
    resolution: int = 64,
    w: float = 1000.0,
    arap_weight: float = 0.05,
    learning_rate: float = 1e-3,
    min_step: float | None = 5e-4,
    max_steps: int = 500,
    solver: Any = "adam",
    normalize: bool = True,
    max_abs: float = 0.8,
    dtype=None,
    progress: bool = True,
    callback=None,
) -> tuple[Mesh, MoldingReport]:
    """Deforms a mesh as rigidly as possible towards a shape a two-piece mould can cast.

    A solid can be cast in two mould halves that part along `axis` exactly when it equals
    its double height field hull along `axis` (every line parallel to the axis meets it in
    one segment, so no undercut locks either half). This voxelizes the mesh (`W`), takes
    the soft hull `H = voxax.esi.height_field_hull(W, axis, w)` and minimizes the gap
    `mean((H - W)^2)` plus `arap_weight * E_arap` with Adam, like
    [`optimize_for_bandsaw`][voxax.apps.optimize_for_bandsaw] does for the three
    silhouettes (the DHF lies inside the silhouette extrusion along the same axis, so it
    asks for more).

    **Arguments:**

    - `mesh`: a closed, outward-oriented triangle mesh (`Mesh`, `trimesh.Trimesh` or
      `(vertices, faces)`).
    - `axis`: 0, 1 or 2.
    - `resolution`, `w`, `arap_weight`, `learning_rate`, `min_step`, `max_steps`,
      `solver`, `normalize`, `max_abs`, `dtype`, `progress`, `callback`: as for
      `optimize_for_bandsaw`.

    **Returns:** `(mesh, report)`: the deformed `Mesh` (same faces, input frame) and a
    [`MoldingReport`][voxax.apps.MoldingReport].
    """
    where = "voxax.apps.optimize_for_molding"
    source = _common.as_mesh(where, mesh)
    _common.warn_if_open(source, where)
    if isinstance(axis, bool) or not isinstance(axis, (int, np.integer)) or int(axis) not in (0, 1, 2):
        raise ValueError(f"{where}: `axis` must be 0, 1 or 2, got {axis!r}")
    axis = int(axis)
    resolution = _common.check_resolution(where, resolution)
    w = _common.check_positive(where, w, "w")
    alpha, learning_rate, min_step = _common.check_steps(where, arap_weight, learning_rate, min_step)
    grid, work, centre, scale, dt = _common.working_mesh(where, source, resolution, normalize, max_abs, dtype)
    faces = jnp.asarray(work.faces)
    rest = _common.to_jax(work.vertices, dt)

    def energy(v, args):
        W = voxelize(v, faces, grid)
        gap = esi.esi_gap(W, (axis,), w)
        e_arap = energies.arap(v, rest, faces)
        return gap + alpha * e_arap, {"gap": gap, "arap": e_arap}

    @jax.jit
    def measure(v):
        W = voxelize(v, faces, grid)
        return esi.esi_gap(W, (axis,), w), energies.arap(v, rest, faces)

    gap0, _ = measure(rest)
    under0 = _undercut(source, axis, 2 * resolution)
    result = _common.run_minimize(
        energy,
        rest,
        _common.check_run(where, solver, learning_rate, progress, callback, max_steps),
        min_step=min_step,
    )
    v_final = jnp.asarray(result.y, dtype=dt)
    gap1, arap1 = measure(v_final)
    out = Mesh(_common.restore(v_final, centre, scale), source.faces)
    gap0, gap1 = float(gap0), float(gap1)
    report = MoldingReport(
        **_common.result_fields(result),
        resolution=resolution,
        axis=axis,
        gap_initial=gap0,
        gap_final=gap1,
        relative_improvement=(1.0 - gap1 / gap0) if gap0 > 0 else 0.0,
        undercut_volume_initial=under0,
        undercut_volume_final=_undercut(out, axis, 2 * resolution),
        arap_final=float(arap1),
        max_displacement=float(np.max(np.linalg.norm(out.vertices - source.vertices, axis=1))),
        w=w,
        centre=centre,
        scale=scale,
    )
    return out, report
