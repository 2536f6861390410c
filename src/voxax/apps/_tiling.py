"""Space-filling tilings of R^3 by deformed copies of shapes (paper section 4.4)."""

from __future__ import annotations

import dataclasses
import itertools
import math
from collections.abc import Sequence
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

#: A cell voxel counts as "covered exactly once" when its folded value is within this of 1.
COVERAGE_TOLERANCE = 0.5


@dataclasses.dataclass(frozen=True, eq=False)
class TilingReport(_common.Report):
    """The outcome of [`optimize_tiling`][voxax.apps.optimize_tiling].

    Besides the shared fields of every report (`energy_history`, `history`, `steps`,
    `stop_reason`, `energy`, `resolution`):

    - `instances`: the number of instances `B`.
    - `mesh_index`: `(B,)` int, which input mesh each instance is a copy of.
    - `translations`: `(B, 3)` final translation of each instance (of its vertex mean).
    - `angles`: `(B, 3)` final yaw, pitch, roll in radians; the rotation is
      `Rz(yaw) @ Ry(pitch) @ Rx(roll)`.
    - `rotations`: `(B, 3, 3)` the same rotations as matrices.
    - `fill_initial`, `fill_final`: the tiling energy `voxax.energies.tiling` before and
      after; `relative_improvement = 1 - fill_final / fill_initial`.
    - `coverage_initial`, `coverage_final`: the fraction of the periodic cell's voxels
      covered exactly once, that is with `|cell - 1| < 0.5` (`COVERAGE_TOLERANCE`), where
      `cell` is the sum of all instances folded into one cell.
    - `empty_final`, `overlap_final`: the fractions with `cell < 0.5` and `cell > 1.5`.
    - `arap_final`: the summed ARAP energy of all instances' deformations.
    - `max_offset`: the largest vertex offset from the (scaled) input shape.
    - `scales`: `(K,)` the uniform scale applied to each input mesh before tiling.
    - `cell`: `(n/3, n/3, n/3)` the final folded cell (winding numbers summed over the
      instances and the 27 blocks), for the box `[cell_lower, cell_upper]^3`.
    - `cell_lower`, `cell_upper`: the periodic cell's box along each axis (`-1/3`, `1/3`
      for 3 blocks).
    - `coverage_fine_initial`, `coverage_fine_final`: the coverage measured on a grid twice
      as fine (`2 * resolution` cells per axis); `coverage_shifted_initial`,
      `coverage_shifted_final`: on the working grid shifted by half a voxel along every
      axis. Both check that the coverage is not an artefact of the working grid.
    - `instances_intersect`: whether any two instances of the result (or an instance and a
      periodic copy of another or of itself, translated by whole periods) intersect or
      touch, by the exact triangle-triangle test
      ([`voxax.intersections`][voxax.intersections], on the translated float64 copies).
    - `intersecting_instance_pairs`: how many (instance, instance, period shift)
      combinations intersect.
    """

    instances: int
    mesh_index: np.ndarray
    translations: np.ndarray
    angles: np.ndarray
    rotations: np.ndarray
    fill_initial: float
    fill_final: float
    relative_improvement: float
    coverage_initial: float
    coverage_final: float
    empty_final: float
    overlap_final: float
    arap_final: float
    max_offset: float
    scales: np.ndarray
    cell: np.ndarray
    cell_lower: float
    cell_upper: float
    coverage_fine_initial: float
    coverage_fine_final: float
    coverage_shifted_initial: float
    coverage_shifted_final: float
    instances_intersect: bool
    intersecting_instance_pairs: int

    def summary(self) -> str:
        """The report's scalar fields, and a note when the voxel coverage and the exact
        intersection test disagree (overlaps thinner than a voxel)."""
        text = super().summary()
        if self.instances_intersect:
            text += (
                f"\n  note: {self.intersecting_instance_pairs} instance pairs still intersect by the exact "
                f"triangle test, although {self.coverage_final:.1%} of the cell's voxels are covered once: "
                "the overlaps are thinner than a voxel (a finer resolution or more steps resolves them)"
            )
        return text


def _instance_intersections(meshes: list, period: float) -> int:
    """Intersecting (instance, instance, period shift) combinations, exactly."""
    boxes = [(m.vertices.min(axis=0), m.vertices.max(axis=0)) for m in meshes]
    found = 0
    for a, b in itertools.combinations_with_replacement(range(len(meshes)), 2):
        # Whole-period shifts k of b whose box can meet a's box, per axis.
        lo_k = np.ceil((boxes[a][0] - boxes[b][1]) / period - 1e-9).astype(int)
        hi_k = np.floor((boxes[a][1] - boxes[b][0]) / period + 1e-9).astype(int)
        for k in itertools.product(*(range(lo_k[i], hi_k[i] + 1) for i in range(3))):
            if a == b and k <= tuple(-x for x in k):
                continue  # an instance is not compared with itself; +k and -k are the same pair
            moved = (meshes[b].vertices + np.array(k, dtype=np.float64) * period, meshes[b].faces)
            if intersections(meshes[a], other=moved).count:
                found += 1
    return found


def rotation_matrices(angles):
    """Rotation matrices `Rz(yaw) @ Ry(pitch) @ Rx(roll)` from `(..., 3)` yaw, pitch, roll
    (real, finite when concrete)."""
    where = "voxax.apps.rotation_matrices"
    angles = jnp.asarray(_validate.coordinates(where, "angles", angles, 3))
    if not jnp.issubdtype(angles.dtype, jnp.floating):
        angles = angles.astype(jnp.result_type(float))
    yaw, pitch, roll = angles[..., 0], angles[..., 1], angles[..., 2]
    cy, sy = jnp.cos(yaw), jnp.sin(yaw)
    cp, sp = jnp.cos(pitch), jnp.sin(pitch)
    cr, sr = jnp.cos(roll), jnp.sin(roll)
    rows = [
        [cy * cp, cy * sp * sr - sy * cr, cy * sp * cr + sy * sr],
        [sy * cp, sy * sp * sr + cy * cr, sy * sp * cr - cy * sr],
        [-sp, cp * sr, cp * cr],
    ]
    return jnp.stack([jnp.stack(r, axis=-1) for r in rows], axis=-2)


def _is_mesh_like(m) -> bool:
    return isinstance(m, Mesh) or (hasattr(m, "vertices") and hasattr(m, "faces"))


def _mesh_list(meshes) -> list[Mesh]:
    """One mesh, or a list of meshes (a `(vertices, faces)` pair counts as one mesh)."""
    if _is_mesh_like(meshes) or not isinstance(meshes, (list, tuple)):
        return [_common.as_mesh("voxax.apps.optimize_tiling", meshes)]
    if not meshes:
        raise ValueError("voxax.apps.optimize_tiling: `meshes` must hold at least one mesh")
    first = meshes[0]
    if len(meshes) == 2 and not _is_mesh_like(first) and np.ndim(first) == 2:
        return [_common.as_mesh("voxax.apps.optimize_tiling", meshes)]  # a single (vertices, faces) pair
    return [_common.as_mesh("voxax.apps.optimize_tiling", m) for m in meshes]


def _counts(instances, k: int) -> list[int]:
    if isinstance(instances, (int, np.integer)) and not isinstance(instances, bool):
        n = int(instances)
        if n < k:
            raise ValueError(f"voxax.apps.optimize_tiling: `instances` ({n}) must be at least the number of meshes ({k})")
        return [n // k + (1 if i < n % k else 0) for i in range(k)]
    if isinstance(instances, (str, bytes)) or not hasattr(instances, "__iter__"):
        raise TypeError(f"voxax.apps.optimize_tiling: `instances` must be an int or a sequence of ints, "
                        f"got {type(instances).__name__}")
    counts = [_validate.positive_int("voxax.apps.optimize_tiling", "instances", c, minimum=-(2**62)) for c in instances]
    if len(counts) != k:
        raise ValueError(f"voxax.apps.optimize_tiling: `instances` gives {len(counts)} counts for {k} meshes")
    if any(c < 1 for c in counts):
        raise ValueError(f"voxax.apps.optimize_tiling: `instances` must give every mesh at least one instance, got {counts}")
    return counts


def _rest_shapes(sources: list, mesh_index: np.ndarray, fill_volume: bool, cell_volume: float):
    """The instances' rest shapes: each mesh centred at its vertex mean and, with
    `fill_volume`, scaled so that the instances fill the cell. Returns the rest vertices per
    mesh, their scales, the padded rest vertices `(B, V, 3)` and the faces (shared, or
    padded per instance with degenerate faces)."""
    B = len(mesh_index)
    rests, scales = [], []
    for m in sources:
        v = m.vertices - m.vertices.mean(axis=0)
        s = 1.0
        if fill_volume:
            vol = m.signed_volume()
            if not vol > 0:
                raise ValueError(
                    "voxax.apps.optimize_tiling: a mesh has non-positive signed volume; it must be closed "
                    "and outward-oriented (or pass fill_volume=False)"
                )
            s = (cell_volume / B / vol) ** (1.0 / 3.0)
        rests.append(v * s)
        scales.append(s)
    n_v = max(len(r) for r in rests)
    n_f = max(m.n_faces for m in sources)
    rest_pad = np.zeros((B, n_v, 3))
    for b, c in enumerate(mesh_index):
        rest_pad[b, : len(rests[c])] = rests[c]
    if len(sources) == 1:
        faces_all = jnp.asarray(sources[0].faces)  # shared by all instances
    else:
        fp = np.zeros((B, n_f, 3), dtype=np.int32)  # padding: degenerate (0, 0, 0) faces
        for b, c in enumerate(mesh_index):
            fp[b, : sources[c].n_faces] = sources[c].faces
        faces_all = jnp.asarray(fp)
    return rests, scales, rest_pad, faces_all


def _initial_placement(rng, init: str, B: int, lower: float, upper: float, period: float, translations, angles):
    """The instances' first translations and angles `(B, 3)`: random (uniformly distributed
    rotations) or on a lattice, unless given."""
    if init == "random":
        t0 = rng.uniform(lower, upper, size=(B, 3))
        a0 = np.stack(
            [rng.uniform(-np.pi, np.pi, B), np.arcsin(rng.uniform(-1, 1, B)), rng.uniform(-np.pi, np.pi, B)],
            axis=1,
        )
    else:
        k = int(math.ceil(B ** (1.0 / 3.0) - 1e-9))
        ticks = lower + (np.arange(k) + 0.5) * (period / k)
        lattice = np.stack(np.meshgrid(ticks, ticks, ticks, indexing="ij"), axis=-1).reshape(-1, 3)
        t0 = lattice[np.sort(rng.permutation(len(lattice))[:B])]
        a0 = np.zeros((B, 3))
    if translations is not None:
        t0 = np.asarray(translations, dtype=np.float64)
        if t0.shape != (B, 3):
            raise ValueError(f"voxax.apps.optimize_tiling: `translations` must have shape ({B}, 3), got {t0.shape}")
    if angles is not None:
        a0 = np.asarray(angles, dtype=np.float64)
        if a0.shape != (B, 3):
            raise ValueError(f"voxax.apps.optimize_tiling: `angles` must have shape ({B}, 3), got {a0.shape}")
    return t0, a0


def _report(result, resolution, mesh_index, y1, fills, cells, arap1, offsets1, deform, scales, box, coverages,
            crossing) -> TilingReport:
    """The tiling's report from the optimization's result and the measurements around it."""
    fill0, fill1 = (float(f) for f in fills)
    cell0, cell1 = cells
    (lower, upper), (coverage_before, coverage_after) = box, coverages
    ang1 = np.asarray(y1["angles"], dtype=np.float64)
    return TilingReport(
        **_common.result_fields(result),
        resolution=resolution,
        instances=len(mesh_index),
        mesh_index=mesh_index,
        translations=np.asarray(y1["translations"], dtype=np.float64),
        angles=ang1,
        rotations=np.asarray(rotation_matrices(jnp.asarray(ang1)), dtype=np.float64),
        fill_initial=fill0,
        fill_final=fill1,
        relative_improvement=(1.0 - fill1 / fill0) if fill0 > 0 else 0.0,
        coverage_initial=float(np.mean(np.abs(cell0 - 1.0) < COVERAGE_TOLERANCE)),
        coverage_final=float(np.mean(np.abs(cell1 - 1.0) < COVERAGE_TOLERANCE)),
        empty_final=float(np.mean(cell1 < 1.0 - COVERAGE_TOLERANCE)),
        overlap_final=float(np.mean(cell1 > 1.0 + COVERAGE_TOLERANCE)),
        arap_final=float(arap1),
        max_offset=float(np.max(np.linalg.norm(offsets1, axis=-1))) if deform else 0.0,
        scales=np.asarray(scales),
        cell=cell1,
        cell_lower=lower,
        cell_upper=upper,
        coverage_fine_initial=coverage_before["fine"],
        coverage_fine_final=coverage_after["fine"],
        coverage_shifted_initial=coverage_before["shifted"],
        coverage_shifted_final=coverage_after["shifted"],
        instances_intersect=crossing > 0,
        intersecting_instance_pairs=crossing,
    )


def optimize_tiling(
    meshes: Any,
    *,
    instances: int | Sequence[int] = 27,
    resolution: int = 192,
    arap_weight: float = 0.005,
    learning_rate: float = 1e-3,
    max_steps: int = 1000,
    min_step: float | None = 1e-3,
    solver: Any = "adam",
    blocks: int = 3,
    fill_volume: bool = True,
    deform: bool = True,
    init: str = "random",
    translations=None,
    angles=None,
    key=None,
    dtype=None,
    progress: bool = True,
    callback=None,
    seed=None,
) -> tuple[list[Mesh], TilingReport]:
    """Places and deforms copies of one or more meshes so that they fill space periodically.

    The paper's section 4.4. Each of the `B` instances is a copy of an input mesh with its
    own vertex offsets (deformation), rotation (yaw, pitch, roll) and translation. All
    instances are voxelized on `[-1, 1]^3` at `resolution` in ONE batched call
    (`vertices (B, V, 3)`), the grid is cut into `blocks^3 = 27` blocks which are summed
    into one periodic cell (`voxax.energies.fold_periodic`: what sticks out of the central
    block re-enters on the opposite side), and the energy is
    `E_fill = sum over cell voxels of (cell - 1)^2` (`voxax.energies.tiling`) plus
    `arap_weight * sum over instances of E_arap`, minimized with Adam.

    Each input mesh is centred at its vertex mean and, with `fill_volume`, scaled so that
    every instance has the volume `cell volume / B` (the volume a perfect tiling needs).
    With `init="random"` (the paper's) the instances start at random positions in the
    cell with uniformly random orientations; `init="lattice"` puts them on a regular
    lattice in the cell, unrotated. `translations` / `angles` override either.

    The results are in the frame of the `[-1, 1]^3` grid, whose central block
    `[-1/3, 1/3]^3` is the periodic cell: repeating all instances with period `2/3` along
    x, y and z tiles space (as well as the optimization could make it). Instances of
    several meshes may have different vertex and face counts; they are padded with unused
    vertices and degenerate faces.

    **On `arap_weight`.** As in the paper, `E_fill` is a plain sum over the cell's voxels,
    so it grows with `resolution^3` while the (area-normalized) ARAP energy does not. With
    the paper's weight 0.005 the deformation is practically unregularised: Adam shrinks
    and crumples instances freely to fill the cell (27 hands at 48^3 reach full coverage
    with an ARAP energy of about 25 per instance). Larger weights keep the shapes: at 48^3,
    5 gave 99.9% coverage with ARAP about 0.9 per instance, and 50 gave 95% with about 0.2.

    **Arguments:**

    - `meshes`: a closed mesh (voxax `Mesh`, `trimesh.Trimesh`, `(vertices, faces)`) or a
      list of them.
    - `instances`: the total number of instances (split as evenly as possible between the
      meshes), or one count per mesh (paper: 27).
    - `resolution`: cells per axis of the `[-1, 1]^3` grid, a multiple of `blocks`
      (paper: 192, so the cell has 64^3 voxels).
    - `arap_weight`: weight of the ARAP regulariser (paper: 0.005).
    - `learning_rate`: Adam's learning rate (paper: 1e-3).
    - `max_steps`: the most optimization steps.
    - `min_step`: stop when no vertex of any instance (placed in the `[-1, 1]^3` frame)
      moves more than this in a step (paper: 1e-3); `None` runs `max_steps` steps.
    - `solver`: passed to `voxax.minimize`.
    - `blocks`: blocks per axis folded into the cell (paper: 3).
    - `fill_volume`: scale the meshes so the instances' volumes add up to the cell's.
    - `deform`: optimize per-instance vertex offsets (else only rigid motions).
    - `init`: `"random"` or `"lattice"`.
    - `translations`, `angles`: optional `(B, 3)` initial translations and yaw/pitch/roll.
    - `key`: the random initialisation's key, an int (default 0) or a JAX PRNG key. `seed`
      is its deprecated old name.
    - `dtype`: float32 or float64 (default: float64 when JAX's x64 mode is on).
    - `progress`, `callback`: passed to `voxax.minimize`.

    **Returns:** `(meshes, report)`: a list of `B` `Mesh`es, each instance placed in the
    `[-1, 1]^3` frame, and a [`TilingReport`][voxax.apps.TilingReport].

    **Example:**

    ```python
    >>> import voxax, voxax.apps
    >>> placed, report = voxax.apps.optimize_tiling(
    ...     voxax.data.icosphere(1), instances=8, resolution=24, max_steps=20, progress=False)
    >>> len(placed), report.fill_final < report.fill_initial
    (8, True)

    ```
    """
    sources = _mesh_list(meshes)
    for m in sources:
        _common.warn_if_open(m, "voxax.apps.optimize_tiling")
    if isinstance(blocks, bool) or not isinstance(blocks, (int, np.integer)) or blocks < 1:
        raise ValueError(f"voxax.apps.optimize_tiling: `blocks` must be a positive int, got {blocks!r}")
    blocks = int(blocks)
    fill_volume = _validate.flag("voxax.apps.optimize_tiling", "fill_volume", fill_volume)
    deform = _validate.flag("voxax.apps.optimize_tiling", "deform", deform)
    key = _validate.key_or_seed("voxax.apps.optimize_tiling", key, seed)
    resolution = _common.check_resolution("voxax.apps.optimize_tiling", resolution, blocks)
    alpha, learning_rate, min_step = _common.check_steps("voxax.apps.optimize_tiling", arap_weight, learning_rate, min_step)
    if init not in ("random", "lattice"):
        raise ValueError(f"voxax.apps.optimize_tiling: `init` must be 'random' or 'lattice', got {init!r}")
    counts = _counts(instances, len(sources))
    B = sum(counts)
    mesh_index = np.repeat(np.arange(len(sources)), counts)
    grid = Grid.cube(resolution)
    period = 2.0 / blocks
    # The folded cell's voxel i sits where the central block's does: [lower, lower + period]^3.
    lower = -1.0 + (blocks // 2) * period
    upper = lower + period
    cell_volume = period**3
    dt = _common.float_dtype("voxax.apps.optimize_tiling", dtype)

    rests, scales, rest_pad, faces_all = _rest_shapes(sources, mesh_index, fill_volume, cell_volume)
    n_v = rest_pad.shape[1]
    rng = _validate.numpy_rng("voxax.apps.optimize_tiling", key)
    t0, a0 = _initial_placement(rng, init, B, lower, upper, period, translations, angles)

    rest_j = _common.to_jax(rest_pad, dt)
    class_rows = []  # per mesh: (instance indices, vertex count, rest (V, 3), faces (F, 3))
    for c, m in enumerate(sources):
        class_rows.append((np.flatnonzero(mesh_index == c), len(rests[c]), _common.to_jax(rests[c], dt), jnp.asarray(m.faces)))

    def split(y):
        offsets = y["offsets"] if deform else jnp.zeros_like(rest_j)
        return offsets, y["angles"], y["translations"]

    def placed(y):
        offsets, ang, trans = split(y)
        local = rest_j + offsets
        return jnp.einsum("bij,bvj->bvi", rotation_matrices(ang), local) + trans[:, None, :], local

    def arap_total(local):
        total = jnp.zeros((), dt)
        for idx, nv, rest_c, faces_c in class_rows:
            per = jax.vmap(lambda x, rest_c=rest_c, faces_c=faces_c: energies.arap(x, rest_c, faces_c))(local[idx, :nv])
            total = total + jnp.sum(per)
        return total

    valid = np.zeros((B, n_v), dtype=bool)
    for b, c in enumerate(mesh_index):
        valid[b, : len(rests[c])] = True
    valid_j = jnp.asarray(valid)

    def vertex_move(y_new, y_old):
        """The largest move of any (real, unpadded) vertex between two iterates."""
        d = jnp.linalg.norm(placed(y_new)[0] - placed(y_old)[0], axis=-1)
        return jnp.max(jnp.where(valid_j, d, 0.0))

    def coverage(cell):
        return jnp.mean(jnp.abs(cell - 1.0) < COVERAGE_TOLERANCE)

    def energy(y, args):
        world, local = placed(y)
        W = voxelize(world, faces_all, grid)  # (B, n, n, n): one batched call
        e_fill = energies.tiling(W, blocks=blocks)
        aux = {"fill": e_fill}
        if deform and alpha > 0:
            e_arap = arap_total(local)
            aux["arap"] = e_arap
            total = e_fill + alpha * e_arap
        else:
            total = e_fill
        aux["coverage"] = coverage(energies.fold_periodic(jnp.sum(W, axis=0), blocks=blocks))
        return total, aux

    @jax.jit
    def measure(y):
        world, local = placed(y)
        W = voxelize(world, faces_all, grid)
        cell = energies.fold_periodic(jnp.sum(W, axis=0), blocks=blocks)
        return energies.tiling(W, blocks=blocks), cell, arap_total(local)

    y0 = {"angles": _common.to_jax(a0, dt), "translations": _common.to_jax(t0, dt)}
    if deform:
        y0["offsets"] = jnp.zeros_like(rest_j)
    fill0, cell0, _ = measure(y0)
    check_grids = _common.check_grids(grid, resolution)

    def coverage_on(y, g):
        world, _ = placed(y)
        W = voxelize(world, faces_all, g)
        return float(coverage(energies.fold_periodic(jnp.sum(W, axis=0), blocks=blocks)))

    coverage_before = {k: coverage_on(y0, g) for k, g in check_grids.items()}
    result = _common.run_minimize(
        energy,
        y0,
        _common.check_run("voxax.apps.optimize_tiling", solver, learning_rate, progress, callback, max_steps),
        min_step=min_step,
        step_size_fn=vertex_move,
    )
    y1 = jax.tree_util.tree_map(lambda a: jnp.asarray(a, dtype=dt), result.y)
    fill1, cell1, arap1 = measure(y1)
    world1, _ = placed(y1)
    world1 = np.asarray(world1, dtype=np.float64)
    offsets1 = np.asarray(split(y1)[0], dtype=np.float64)
    cell0 = np.asarray(cell0, dtype=np.float64)
    cell1 = np.asarray(cell1, dtype=np.float64)
    out = [Mesh(world1[b, : len(rests[c])], sources[c].faces) for b, c in enumerate(mesh_index)]
    coverage_after = {k: coverage_on(y1, g) for k, g in check_grids.items()}
    report = _report(result, resolution, mesh_index, y1, (fill0, fill1), (cell0, cell1), arap1, offsets1, deform,
                     scales, (lower, upper), (coverage_before, coverage_after), _instance_intersections(out, period))
    return out, report
