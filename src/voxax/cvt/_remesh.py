"""The remeshing driver: fragments of the source, seeds optimised towards a restricted CVT,
its Delaunay triangulation made a closed 2-manifold, and the finishing passes."""

from __future__ import annotations

import contextlib
import time

import numpy as np

from .._grid import Grid
from .._mesh import Mesh
from . import _relax
from ._components import cover_components
from ._fragments import Fragments, ball_fragments, fragments, union_all
from ._manifold import Balls, problem_edges
from ._optimize import init_seeds, optimize
from ._rdt import rdt

__all__ = ["open_lines", "remesh"]


def open_lines(frag: Fragments) -> int:
    """Lines whose crossings do not alternate enter/exit starting with an entry."""
    if frag.size == 0:
        return 0
    key = frag.axis.astype(np.int64) * (1 << 40) + frag.line
    start = np.concatenate([[True], key[1:] != key[:-1]])
    gid = np.cumsum(start) - 1
    pos = np.arange(len(key)) - np.nonzero(start)[0][gid]
    expected = np.where(pos % 2 == 0, -1, 1)
    bad = np.zeros(gid[-1] + 1, bool)
    np.logical_or.at(bad, gid, frag.sign != expected)
    counts = np.bincount(gid)
    bad |= counts % 2 == 1
    return int(bad.sum())


def _mesh_source(source):
    if isinstance(source, Mesh):
        return source
    if isinstance(source, tuple) and len(source) == 2 and np.ndim(source[1]) == 2:
        return Mesh(*source)
    return None


@contextlib.contextmanager
def _timed(times: dict, cpu: dict, stage: str):
    """Adds the wall-clock and CPU time of the block to `times[stage]` and `cpu[stage]`."""
    t0, c0 = time.perf_counter(), time.process_time()
    try:
        yield
    finally:
        times[stage] = time.perf_counter() - t0
        cpu[stage] = time.process_time() - c0


def _default_grid(mesh: Mesh, n_seeds: int) -> Grid:
    """A mesh's box with a margin of about two edge lengths (room for the regularisation
    balls), in cubic cells, 64 along its longest side."""
    v, f = mesh.vertices, mesh.faces
    area = 0.5 * np.linalg.norm(np.cross(v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]]), axis=1).sum()
    margin = 2.0 * np.sqrt(4.0 * area / (np.sqrt(3.0) * n_seeds))
    lo, hi = v.min(axis=0) - margin, v.max(axis=0) + margin
    h = float(np.max(hi - lo)) / 64
    shape = tuple(int(max(1, np.ceil(e / h))) for e in hi - lo)
    return Grid(tuple(lo), tuple(lo + np.asarray(shape) * h), shape)


def _refine(source, grid: Grid, frag: Fragments, n_seeds: int, alpha: float, inside: str, threads) -> Fragments:
    """Resamples on finer cubic grids (at most three times) until there are about `alpha`
    fragments per seed."""
    box_lo, box_hi = np.asarray(grid.lower), np.asarray(grid.upper)
    for _ in range(3):
        ratio = frag.size / (alpha * n_seeds)
        if 0.8 <= ratio:
            break
        scale = 1.0 / np.sqrt(ratio)
        h = max(grid.spacing) / scale
        # the finer grid spans the fragments' box (the surface lies within a cell of
        # it) with a margin of two coarse cells and two edge lengths (room for the
        # regularisation balls), inside the box given
        edge = np.sqrt(4.0 * frag.weights.sum() / (np.sqrt(3.0) * n_seeds))
        margin = 2.0 * max(grid.spacing) + 2.0 * edge
        lo = np.maximum(box_lo, frag.points.min(axis=0) - margin)
        hi = np.minimum(box_hi, frag.points.max(axis=0) + margin)
        shape = np.maximum(1, np.ceil((hi - lo) / h)).astype(int)
        mid = 0.5 * (lo + hi)
        half = 0.5 * shape * h
        grid = Grid(tuple(mid - half), tuple(mid + half), tuple(int(n) for n in shape))
        frag = fragments(source, grid, inside=inside, threads=threads)
    return frag


def _sample(source, grid, n_seeds: int, alpha: float, orient: bool, inside: str, threads) -> Fragments:
    """The source's fragments, at about `alpha` per seed (a `(values, level)` grid as given)."""
    from .. import metrics

    mesh = _mesh_source(source)
    if mesh is not None:
        if mesh.vertices.shape[1:] != (3,) or len(mesh.faces) == 0:
            raise ValueError("cvt.remesh: the mesh must be a non-empty 3D triangle mesh")
        if orient and not metrics.manifold_report(mesh).closed:
            raise ValueError("cvt.remesh: the mesh is open, so it cannot be oriented; pass orient=False")
    if isinstance(source, Fragments):
        return source
    fixed = isinstance(source, tuple) and mesh is None
    if grid is None:
        if mesh is None:
            raise ValueError("cvt.remesh: fields, grids and CSG expressions need a grid")
        grid = _default_grid(mesh, n_seeds)
    frag = fragments(source, grid, inside=inside, threads=threads)
    return frag if fixed else _refine(source, grid, frag, n_seeds, alpha, inside, threads)


def _optimized_seeds(frag, n_seeds, key, components, method, steps, polish, weighted, threads) -> dict:
    """Seeds placed by area (and on every piece with `components`), optimised by `method`
    and polished by Lloyd steps after L-BFGS."""
    seeds0 = init_seeds(frag, n_seeds, key)
    seeds0, covered = cover_components(frag, seeds0, threads) if components else (seeds0, 0)
    res = optimize(frag, seeds0, method=method, steps=steps, weighted=weighted)
    seeds = res.seeds
    polish = polish if method == "lbfgs" else 0
    energy = float(res.energy[-1])
    polish_steps = 0
    if polish:
        pol = optimize(frag, seeds, method="lloyd", steps=polish, weighted=weighted)
        seeds, energy, polish_steps = pol.seeds, float(pol.energy[-1]), pol.steps
    return dict(seeds=seeds, result=res, polish=polish, polish_steps=polish_steps, energy=energy, covered=covered)


def _manifold_rounds(frag, seeds, max_rounds, round_steps, weighted, threads) -> dict:
    """The restricted Delaunay triangulation, with rounds of Lloyd steps (and, from the
    second round on, regularisation balls on the defective edges) while it is not a
    2-manifold, at most `max_rounds`."""
    faces, rep = rdt(frag, seeds, threads=threads)
    rounds = 0
    balls = Balls()
    base = frag
    while rounds < max_rounds:
        bad = problem_edges(faces, len(seeds))
        if len(bad) == 0:
            break
        if rounds > 0:  # the first round only optimises further: most defects are unconverged seeds
            balls.add(seeds, bad, frag.spacing)
            frag = union_all([base, ball_fragments(balls.center, balls.radius, base.grid)])
        seeds = optimize(frag, seeds, method="lloyd", steps=round_steps, weighted=weighted).seeds
        faces, rep = rdt(frag, seeds, threads=threads)
        rounds += 1
    return dict(frag=frag, seeds=seeds, faces=faces, rdt=rep, rounds=rounds, balls=len(balls))


def _finish(seeds, faces, frag, base, project: bool, relax: int, relax_on_source: bool) -> Mesh:
    """The seeds that have triangles, projected and relaxed, as a mesh."""
    used = np.unique(faces)
    remap = np.full(len(seeds), -1, np.int64)
    remap[used] = np.arange(len(used))
    verts = seeds[used]
    if project or relax > 0:
        verts = _relax.project(verts, frag)
    surface = base if relax_on_source else frag
    verts = _relax.relax(verts, remap[faces], surface, relax, _relax.FLOOR)
    return Mesh(verts, remap[faces].astype(np.int32))


def _report(out: Mesh, n_seeds, seeded, tri, relax, times, cpu) -> dict:
    from .. import metrics

    res = seeded["result"]
    mr = metrics.manifold_report(out)
    q = metrics.triangle_quality(out)
    return {
        "n_fragments": tri["frag"].size,
        "n_seeds": n_seeds,
        "n_vertices": out.n_vertices,
        "alpha": tri["frag"].size / n_seeds,
        "grid": tri["frag"].grid,
        "method": res.method,
        "steps": res.steps,
        "polish": seeded["polish"],
        "polish_steps": seeded["polish_steps"],
        "relax": relax,
        "respawned": res.respawned,
        "component_seeds": seeded["covered"],
        "energy": seeded["energy"],
        "rdt": tri["rdt"],
        "rounds": tri["rounds"],
        "balls": tri["balls"],
        "closed": mr.closed,
        "manifold": mr.edge_manifold and mr.vertex_manifold,
        "euler_characteristic": mr.euler_characteristic,
        "manifold_report": mr,
        "quality_min": float(q.min()) if len(q) else 0.0,
        "quality_mean": float(q.mean()) if len(q) else 0.0,
        "time": times,
        "cpu_time": cpu,
    }


def remesh(
    source,
    n_seeds: int,
    *,
    grid: Grid | None = None,
    alpha: float = 50.0,
    method: str = "lbfgs",
    steps: int = 60,
    polish: int = 40,
    orient: bool = True,
    project: bool = True,
    relax: int = 2,
    relax_on_source: bool = True,
    components: bool = True,
    weighted: bool = True,
    max_rounds: int = 30,
    round_steps: int = 20,
    inside: str = "below",
    key=0,
    threads=None,
):
    """A quality triangle mesh of a surface with about `n_seeds` vertices (discrete CVT).

    **Arguments:**

    - `source`: a closed [`Mesh`][voxax.Mesh], a field `f(points) -> values` (negative
      inside; needs `grid`), a `(values, level)` grid (needs `grid`), a
      [`CSG`][voxax.cvt.CSG] expression (needs `grid`) or ready [`Fragments`][voxax.cvt.Fragments].
      Fields given as `jax.tree_util.Partial(fields.sphere, radius=r, center=c)` compile
      once per function, so meshing many scenes of the same primitives compiles nothing new.
    - `n_seeds`: the number of seeds (vertices; seeds whose regions end up without a
      triangle are dropped).
    - `grid`: the box to sample in. Its shape is refined (cubic cells) until there are about
      `alpha` fragments per seed, the finer grids spanning only the part of the box around
      the surface found on the coarser one; for a mesh the default box is the mesh's
      bounding box.
      A `(values, level)` source is sampled on its own grid as given.
    - `alpha`: fragments per seed (the paper uses > 50). The fragments quantise the
      regions' centroids, and that limits the triangle quality: on the Chebyshev octic at
      20,000 seeds and without relaxation (`relax=0`), `alpha=50` gives a mean quality of
      0.864 and `alpha=100` 0.885 (minimum 0.41 against 0.55), for about twice the time;
      the relaxation makes up for the coarser sampling (0.57 / 0.91 at `alpha=50`).
    - `method`, `steps`: the optimiser (`"lbfgs"`, or `"lloyd"`: cheaper steps but slower
      convergence) and its step budget. Each step's nearest-seed search starts from the
      previous step's assignment.
    - `polish`: Lloyd steps after L-BFGS (L-BFGS lowers the energy fastest but stalls
      at the switches of the assignment; the centroid steps then even out the worst
      regions, which lifts the minimum triangle quality). They stop early at an exact fixed
      point (the report's `"polish_steps"` says how many ran).
    - `orient`: require a closed surface (every grid line enters and exits the solid
      alternately) and orient the result outward; `False` meshes open surfaces too
      (triangles still oriented consistently per component, direction unspecified).
    - `project`: move each vertex onto the tangent plane of its nearest fragment.
    - `relax`: tangential smoothing steps of the final mesh (connectivity kept): each moves
      every vertex to the mean of its neighbours within its tangent plane, then onto the
      tangent plane of its nearest fragment (a move that would turn a triangle over or push
      its quality below 0.2 is undone; vertices of non-manifold or boundary edges stay). The seeds quantise their
      regions' centroids to the fragments, and this evens out the result: on the Chebyshev
      octic at 20,000 seeds two steps lift the quality from 0.50 / 0.864 (minimum / mean)
      to 0.57 / 0.908. `0` returns the seeds themselves (projected with `project`).
    - `relax_on_source`: after manifold rounds with balls, relax onto the source's fragments
      instead of their union with the balls: the vertices the balls pushed out come back
      to the surface, which removes most of the balls' volume (a CSG scene with 1,160
      balls: +13.3% of the exact boolean's volume with `False`, -0.7% with `True`).
      Where balls bridged nearby sheets, the bridge's triangles get thinner as their
      vertices return; a move that would push a triangle's quality below 0.2 (or below
      its quality before the step, if lower) is undone, as in every relaxation step (that
      scene's minimum quality: 0.55 with `False`, 0.21 with `True`). Meshes made without
      balls are the same either way.
    - `components`: give every separate piece of the sampled surface with at least one
      seed's share of the area four seeds or more before optimising (fragments closer
      than two grid spacings count as connected), moved from the largest piece.
      Area-proportional seeding alone leaves a small island (a few seeds' worth of area)
      with too few seeds to close, and the mesh then drops it (a CSG scene at 2,000 seeds:
      an island 0.2% of the area, Hausdorff distance 7.25 mean edge lengths without, 0.69
      with). Pieces smaller than one seed's share are not meshed. The report's
      `"component_seeds"` says how many seeds were moved.
    - `weighted`: use area weights (uniform density).
    - `max_rounds`, `round_steps`: the 2-manifold step (with `orient`): while some edge
      has other than two triangles or some vertex more than one fan, the seeds first take
      `round_steps` more Lloyd steps; if that does not help, balls are placed on
      those edges (radius half the edge, at most the edge; a ball hit again grows by a
      twentieth of it), the solid is replaced by its union with the balls on the grid's
      rays, and the seeds take `round_steps` Lloyd steps before the triangulation is read
      again; at most `max_rounds` times. The report says how many rounds ran, how many balls
      were placed, and whether the result is a closed 2-manifold.
    - `inside`: for `(values, level)` sources, `"below"` or `"above"` the level.
    - `key`: seed of the random seeding.
    - `threads`: threads for the C++ passes.

    **Returns:** `(Mesh, report)`; the report is a dict with the fragment and seed counts,
    `alpha`, the energies, the [`RdtReport`][voxax.cvt.RdtReport] (`"rdt"`), the topology
    (`"closed"`, `"manifold"`, `"euler_characteristic"`), triangle quality (`"quality_min"`,
    `"quality_mean"`), wall-clock timings in seconds per stage (`"time"`) and the process's
    CPU time per stage (`"cpu_time"`, all threads).
    """
    n_seeds = int(n_seeds)
    if n_seeds < 4:
        raise ValueError(f"cvt.remesh: n_seeds must be >= 4, got {n_seeds}")
    relax = int(relax)
    if relax < 0:
        raise ValueError(f"cvt.remesh: relax must be >= 0, got {relax}")
    polish = int(polish)
    if polish < 0:
        raise ValueError(f"cvt.remesh: polish must be >= 0, got {polish}")
    alpha = float(alpha)
    if not alpha > 0:
        raise ValueError(f"cvt.remesh: alpha must be > 0, got {alpha}")
    times, cpu = {}, {}
    t0, c0 = time.perf_counter(), time.process_time()
    with _timed(times, cpu, "fragments"):
        frag = _sample(source, grid, n_seeds, alpha, orient, inside, threads)
    if frag.size < n_seeds:
        raise ValueError(f"cvt.remesh: {n_seeds} seeds but only {frag.size} fragments; use fewer seeds or a finer grid")
    if orient:
        bad = open_lines(frag)
        if bad:
            raise ValueError(
                f"cvt.remesh: the surface is open ({bad} grid lines do not enter and exit a solid); "
                "it cannot be oriented: pass orient=False or a grid that contains the whole surface"
            )
    with _timed(times, cpu, "optimize"):
        seeded = _optimized_seeds(frag, n_seeds, key, components, method, steps, polish, weighted, threads)
    with _timed(times, cpu, "rdt"):
        tri = _manifold_rounds(frag, seeded["seeds"], max_rounds if orient else 0, round_steps, weighted, threads)
    with _timed(times, cpu, "relax"):
        out = _finish(tri["seeds"], tri["faces"], tri["frag"], frag, project, relax, relax_on_source)
    report = _report(out, n_seeds, seeded, tri, relax, times, cpu)
    times["total"] = time.perf_counter() - t0
    cpu["total"] = time.process_time() - c0
    return out, report
