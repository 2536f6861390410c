"""Resolving self-intersections (paper section 4.2)."""

from __future__ import annotations

import dataclasses
import time
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from .. import _validate, energies
from .._grid import Grid
from .._mesh import Mesh
from .._spatial import intersections
from .._voxelize import voxelize
from . import _common


@dataclasses.dataclass(frozen=True, eq=False)
class SelfIntersectionReport(_common.Report):
    """The outcome of [`resolve_self_intersections`][voxax.apps.resolve_self_intersections].

    Besides the shared fields of every report (`energy_history`, `history`, `steps`,
    `stop_reason`, `energy`, `resolution`):

    - `resolved`: whether the exact triangle-triangle test
      ([`voxax.intersections`][voxax.intersections]) finds no pair of intersecting or
      touching faces in the result. Only then is the result called resolved.
    - `intersections_initial`, `intersections_final`: intersecting face pairs (exact test)
      of the input and of the result; `intersections_after_voxel_stage`: after the paper's
      voxel stage, before any refinement.
    - `refinement_rounds`, `refinement_steps`: rounds and optimization steps of the local
      refinement (see `resolve_self_intersections`); `refinement_seconds`: its run time
      (with the volume steps).
    - `volume_steps`: the verified Newton steps that restored the enclosed volume after
      the overlap was gone (0 when it was already within `volume_tolerance`).
    - `voxel_resolved`: whether no voxel of the working grid exceeds `1 + eps` (the paper's
      criterion, necessary but not sufficient).
    - `enclosed_volume_initial`: the volume enclosed by the input counting overlaps once
      (signed volume minus the overlap volume measured on a grid twice as fine as the
      working grid); the volume option aims the result's signed volume at it.
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
    intersections_initial: int
    intersections_after_voxel_stage: int
    intersections_final: int
    refinement_rounds: int
    refinement_steps: int
    refinement_seconds: float
    volume_steps: int
    voxel_resolved: bool
    enclosed_volume_initial: float
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


def _signed_volume(v, faces):
    a, b, c = v[faces[:, 0]], v[faces[:, 1]], v[faces[:, 2]]
    return jnp.sum(a * jnp.cross(b, c)) / 6.0


def _restore_volume(v, faces, faces_np, v_target, tolerance, max_steps=8):
    """Brings a resolved mesh's signed volume back to `v_target` (within `tolerance`,
    relative) by Newton steps along the volume gradient, each checked with the exact
    intersection test; a step that makes faces intersect is halved, and after four halvings
    the last intersection-free mesh is kept. Returns the mesh and the steps accepted."""
    volume_and_gradient = jax.jit(jax.value_and_grad(lambda x: _signed_volume(x, faces)))
    accepted = 0
    for _ in range(max_steps):
        volume, g = volume_and_gradient(v)
        gap = float(volume) - v_target
        if abs(gap) <= tolerance * abs(v_target):
            break
        step = gap / float(jnp.sum(g * g)) * g  # first order: removes the whole gap
        for _halving in range(5):
            candidate = v - step
            if intersections(np.asarray(candidate, dtype=np.float64), faces_np).count == 0:
                break
            step = 0.5 * step
        else:
            break
        v = candidate
        accepted += 1
    return v, accepted


def _local_box(vertices: np.ndarray, faces: np.ndarray, pairs: np.ndarray, spacing: float,
               pad: float, cells: int, shift: float) -> tuple[np.ndarray, float]:
    """The lower corner and cell size of a `cells^3` grid of cubic cells of size `spacing`
    around the faces in `pairs` (grown by `pad`), shifted by `shift` cells. When they do
    not fit, the grid is centred on the face that appears in the most pairs instead."""
    bad, counts = np.unique(pairs.reshape(-1), return_counts=True)
    pts = vertices[faces[bad]].reshape(-1, 3)
    lo, hi = pts.min(axis=0) - pad, pts.max(axis=0) + pad
    h = spacing
    if np.max(hi - lo) <= cells * h:
        centre = 0.5 * (lo + hi)
    else:
        centre = vertices[faces[bad[np.argmax(counts)]]].mean(axis=0)
    return centre - 0.5 * cells * h + shift * h, h


@_validate.surface_first
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
    keep_volume: bool = True,
    volume_weight: float = 10.0,
    volume_tolerance: float | None = 0.005,
    refine: bool = True,
    max_rounds: int = 20,
    round_steps: int = 200,
    local_cells: int = 32,
    time_budget: float | None = None,
    dtype=None,
    progress: bool = True,
    callback=None,
) -> tuple[Mesh, SelfIntersectionReport]:
    """Deforms a mesh as rigidly as possible until no part of it overlaps another.

    **The voxel stage** (the paper's section 4.2): voxelize the mesh on the `[-1, 1]^3` grid
    at `resolution`, penalise every voxel whose box-filtered winding number exceeds
    `1 + eps` with `E_sect = sum_{W > 1 + eps} W^2 / n_voxels`
    (`voxax.energies.self_intersection`), add `arap_weight * E_arap` (spokes-and-rims ARAP
    against the input, `voxax.energies.arap`), and minimize with Adam until no voxel
    exceeds `1 + eps`, or for at most `max_steps` steps.

    **The exact stage** (`refine=True`): a grid only sees overlaps thicker than a fraction
    of its voxels, so the result is then checked with the exact triangle-triangle test
    [`voxax.intersections`][voxax.intersections]. While faces still intersect (or touch),
    a refinement round places a small grid of finer cubic cells (half, then a quarter,
    then an eighth of a working voxel, `local_cells` per axis, shifted by half a cell every
    other round) around the intersecting faces, and minimizes the overlap
    volume measured there (`sum max(W - 1, 0)` times the cell volume; voxax is exact on
    any grid) together with the working grid's energy, ARAP and the volume term, with Adam
    steps proportional to the fine cell size. The exact test runs every 10 steps; a round
    ends when it finds nothing, or after `round_steps` steps (a local grid has
    `local_cells^3` cells; when the intersecting faces do not fit in it, it is centred on
    the face in the most pairs, and later rounds take the rest). The stage stops when the exact test finds no intersection, after `max_rounds` rounds, or when `time_budget`
    seconds have passed.

    **Volume** (`keep_volume=True`): `volume_weight * ((V - V_0) / V_0)^2` is added to
    both stages, with `V` the signed volume of the mesh and `V_0` the volume the input
    encloses counting overlaps once (its signed volume minus its overlap volume, measured
    on a grid twice as fine as the working grid; overlapping parts count twice in a signed
    volume). A resolved mesh's signed
    volume is its enclosed volume, so the term keeps the enclosed volume while the
    overlap goes.

    `report.resolved` is True only when the exact test finds no intersecting or touching
    faces in the result; otherwise `report.intersections_final` says how many pairs are
    left. By default the mesh is first centred and scaled so that `max |v| = max_abs = 0.8`
    (the paper's set-up); the result is mapped back to the input's frame. A component
    nested inside another, or an inverted one, has no intersecting faces and is left alone.

    **Arguments:**

    - `mesh`: a closed, outward-oriented triangle mesh: voxax `Mesh`, `trimesh.Trimesh` or
      `(vertices (V, 3), faces (F, 3))`.
    - `resolution`: cells per axis of the working grid (paper: 128).
    - `eps`: voxels above `1 + eps` count as overlapping (paper: 1e-3).
    - `arap_weight`: weight of the ARAP regulariser (paper: 0.005).
    - `learning_rate`: Adam's learning rate of the voxel stage (paper: 1e-2).
    - `max_steps`: the most steps of the voxel stage.
    - `solver`: passed to `voxax.minimize` for the voxel stage (`"adam"`, `"lbfgs"`, ...).
    - `normalize`, `max_abs`: normalize the mesh to `max |v| = max_abs` first (else the
      mesh must already lie inside `[-1, 1]^3`).
    - `keep_volume`, `volume_weight`: the volume term and its weight.
    - `volume_tolerance`: the relative volume error left to the final Newton steps
      (None: no such steps).
    - `refine`: run the exact stage.
    - `max_rounds`, `round_steps`, `local_cells`, `time_budget`: the exact stage's budget
      (rounds, steps per round, cells per axis of a local grid, seconds or None).
    - `dtype`: float32 or float64 (default: float64 when JAX's x64 mode is on).
    - `progress`: show the solver's progress.
    - `callback`: passed to `voxax.minimize`.

    **Returns:** `(mesh, report)`: the deformed `Mesh` (same faces, input frame) and a
    [`SelfIntersectionReport`][voxax.apps.SelfIntersectionReport].

    **Example:**

    ```python
    The voxel stage alone (`refine=False`) removes every overlapping voxel of its grid but
    can leave intersections thinner than a voxel; the report says so:

    >>> import voxax, voxax.apps
    >>> mesh, report = voxax.apps.resolve_self_intersections(
    ...     voxax.data.bent_bar(), resolution=32, refine=False, progress=False)
    >>> report.voxel_resolved, report.intersections_final > 0, report.resolved
    (True, True, False)

    ```
    """
    source = _common.as_mesh("voxax.apps.resolve_self_intersections", mesh)
    _common.warn_if_open(source, "voxax.apps.resolve_self_intersections")
    resolution = _common.check_resolution("voxax.apps.resolve_self_intersections", resolution)
    eps = _common.check_positive("voxax.apps.resolve_self_intersections", eps, "eps", allow_zero=True)
    alpha, learning_rate, _ = _common.check_steps("voxax.apps.resolve_self_intersections", arap_weight, learning_rate)
    max_rounds = _validate.positive_int("voxax.apps.resolve_self_intersections", "max_rounds", max_rounds, minimum=0)
    round_steps = _validate.positive_int("voxax.apps.resolve_self_intersections", "round_steps", round_steps)
    keep_volume = _validate.flag("voxax.apps.resolve_self_intersections", "keep_volume", keep_volume)
    refine = _validate.flag("voxax.apps.resolve_self_intersections", "refine", refine)
    local_cells = _common.check_resolution("voxax.apps.resolve_self_intersections", local_cells, name="local_cells")
    beta = _common.check_positive("voxax.apps.resolve_self_intersections", volume_weight, "volume_weight", allow_zero=True) if keep_volume else 0.0
    if time_budget is not None:
        time_budget = _common.check_positive("voxax.apps.resolve_self_intersections", time_budget, "time_budget")
    if volume_tolerance is not None:
        volume_tolerance = _common.check_positive("voxax.apps.resolve_self_intersections", volume_tolerance, "volume_tolerance")
    grid, work, centre, scale, dt = _common.working_mesh("voxax.apps.resolve_self_intersections", source, resolution, normalize, max_abs, dtype)
    faces_np = np.asarray(work.faces)
    faces = jnp.asarray(faces_np)
    rest = _common.to_jax(work.vertices, dt)
    threshold = 1.0 + eps
    h_work = float(grid.spacing[0])

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
    signed0 = float(_signed_volume(rest, faces))
    # The overlap volume from a grid twice as fine: a voxel that holds both overlap and
    # empty space hides part of the overlap, less so on finer cells.
    fine = Grid.cube(2 * resolution)
    ovol_fine = float(jnp.sum(jnp.maximum(voxelize(rest, faces, fine) - 1.0, 0.0)) * fine.voxel_volume)
    enclosed0 = signed0 - max(float(ovol0), ovol_fine)
    v_target = enclosed0 if abs(enclosed0) > 1e-12 else 1.0

    def volume_term(v):
        return beta * ((_signed_volume(v, faces) - v_target) / v_target) ** 2

    def energy(v, args):
        W = voxelize(v, faces, grid)
        e_sect = energies.self_intersection(W, eps=eps)
        e_arap = energies.arap(v, rest, faces)
        e_vol = volume_term(v)
        return e_sect + alpha * e_arap + e_vol, {
            "self_intersection": e_sect,
            "arap": e_arap,
            "volume": e_vol,
            "max_w": jnp.max(W),
        }

    count0 = intersections(work.vertices, faces_np).count
    result = _common.run_minimize(
        energy,
        rest,
        _common.check_run("voxax.apps.resolve_self_intersections", solver, learning_rate, progress, callback, max_steps),
        max_w_threshold=threshold,
    )
    v_final = jnp.asarray(result.y, dtype=dt)
    found = intersections(np.asarray(v_final, dtype=np.float64), faces_np)
    count_voxel = found.count

    rounds = steps = 0
    t0 = time.perf_counter()
    if refine and found.count:
        v_final, found, rounds, steps = _refine(
            v_final, found, rest, faces, faces_np, grid, h_work, eps, alpha, volume_term,
            max_rounds, round_steps, local_cells, time_budget, progress,
        )  # fmt: skip
    volume_steps = 0
    if keep_volume and found.count == 0 and volume_tolerance is not None:
        # The stages stop as soon as the overlap is gone, often before the volume term has
        # acted (parts pushed apart keep their own volume): restore the enclosed volume.
        v_final, volume_steps = _restore_volume(v_final, faces, faces_np, v_target, volume_tolerance)
    seconds = time.perf_counter() - t0
    max_w1, over1, ovol1, arap1 = measure(v_final)
    out = Mesh(_common.restore(v_final, centre, scale), source.faces)
    s3 = scale**3
    report = SelfIntersectionReport(
        **_common.result_fields(result),
        resolution=resolution,
        resolved=found.count == 0,
        intersections_initial=int(count0),
        intersections_after_voxel_stage=int(count_voxel),
        intersections_final=int(found.count),
        refinement_rounds=int(rounds),
        refinement_steps=int(steps),
        refinement_seconds=float(seconds),
        volume_steps=int(volume_steps),
        voxel_resolved=bool(float(max_w1) <= threshold),
        enclosed_volume_initial=enclosed0 / s3,
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


def _refine(v, found, rest, faces, faces_np, grid, h_work, eps, alpha, volume_term,
            max_rounds, round_steps, local_cells, time_budget, progress):
    """The exact stage: local fine grids around the intersecting faces (see the caller).

    The local grid moves and changes its cell size from round to round; to compile the
    step once, the mesh is mapped into a fixed `[0, n]^3` grid of unit cells instead
    (`(v - lower) / h`: box-filtered winding numbers are invariant under this map).
    """
    import optax

    t0 = time.perf_counter()
    steps = 0
    rounds = 0
    check_every = 10
    n = local_cells
    unit_grid = Grid(lower=(0.0, 0.0, 0.0), upper=(float(n),) * 3, shape=(n, n, n))
    unit = h_work**3  # overlap volumes in working voxels
    adam = optax.scale_by_adam()

    def energy(x, lower, h):
        W_l = voxelize((x - lower) / h, faces, unit_grid)
        W_w = voxelize(x, faces, grid)
        e_local = jnp.sum(jnp.maximum(W_l - 1.0 - eps, 0.0)) * h**3 / unit
        e_work = jnp.sum(jnp.maximum(W_w - 1.0 - eps, 0.0)) * grid.voxel_volume / unit
        return e_local + e_work + alpha * energies.arap(x, rest, faces) + volume_term(x)

    @jax.jit
    def step(x, state, lower, h):
        g = jax.grad(energy)(x, lower, h)
        upd, state = adam.update(g, state, x)
        return x - 0.5 * h * upd, state

    while found.count and rounds < max_rounds:
        if time_budget is not None and time.perf_counter() - t0 > time_budget:
            break
        rounds += 1
        level = min(rounds, 3)
        lower, h = _local_box(np.asarray(v, dtype=np.float64), faces_np, found.pairs, h_work / 2**level,
                              2 * h_work, n, 0.5 * (rounds % 2))  # fmt: skip
        lower_j, h_j = jnp.asarray(lower, dtype=v.dtype), jnp.asarray(h, dtype=v.dtype)
        state = adam.init(v)
        for k in range(round_steps):
            v, state = step(v, state, lower_j, h_j)
            steps += 1
            if (k + 1) % check_every == 0 or k + 1 == round_steps:
                found = intersections(np.asarray(v, dtype=np.float64), faces_np)
                if progress:
                    print(f"refinement round {rounds} step {k + 1}: {found.count} intersecting pairs "
                          f"(local cells {h:.2e})", flush=True)
                if found.count == 0:
                    break
                if time_budget is not None and time.perf_counter() - t0 > time_budget:
                    break
    return v, found, rounds, steps
