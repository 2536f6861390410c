"""The remeshing driver: fragments of the source, seeds optimised towards a restricted CVT,
its Delaunay triangulation made a closed 2-manifold, and the finishing passes."""

from __future__ import annotations

import contextlib
import dataclasses
import time
import warnings
from collections.abc import Mapping
from typing import Any

import numpy as np

from .. import _validate
from .._grid import Grid
from .._mesh import Mesh
from .._values import ValueEquality
from . import _relax
from ._components import cover_components
from ._fragments import (
    CSG,
    Fragments,
    as_mesh,
    ball_fragments,
    checked,
    checked_key,
    checked_threads,
    sample,
    union_all,
)
from ._manifold import Balls, problem_edges
from ._optimize import init_seeds, run, run_hinted
from ._rdt import RdtReport, rdt

__all__ = ["RemeshResult", "line_faults", "open_lines", "remesh", "topology_seeds"]

_WHERE = "voxax.cvt.remesh"


@dataclasses.dataclass(frozen=True, eq=False)
class RemeshResult(ValueEquality):
    """What [`remesh`][voxax.cvt.remesh] returns: the mesh and the report of the run.

    - `mesh`: the [`Mesh`][voxax.Mesh].
    - `n_fragments`, `n_seeds`, `n_vertices`, `alpha`, `grid`: the samples (fragments per
      seed, on `grid`), the seeds asked for and the vertices made.
    - `method`, `steps`, `polish`, `polish_steps`, `tol`, `polish_tol`, `relax`,
      `respawned`, `component_seeds`, `energy`: the optimiser's run (`steps`: the
      optimiser's steps that ran, at most the `steps` asked for; `polish`: the Lloyd
      polish asked for, `polish_steps` those that ran; the stopping tolerances; seeds
      moved out of empty regions, seeds moved onto small pieces of the surface, the final
      CVT energy).
    - `rdt`: the last [`RdtReport`][voxax.cvt.RdtReport]; `rounds`, `balls`: the
      2-manifold step's rounds and regularisation balls.
    - `closed`, `manifold`, `euler_characteristic`, `manifold_report`: the result's
      topology ([`ManifoldReport`][voxax.metrics.ManifoldReport]).
    - `source_euler_characteristic`: the closed source mesh's (None for other sources);
      `topology_rounds`, `topology_seeds`: the rounds that added seeds where they differed,
      and the seeds added.
    - `quality_min`, `quality_mean`: triangle quality.
    - `time`, `cpu_time`: wall-clock and process CPU seconds per stage.

    It unpacks as `(mesh, result)`, and `result[name]` is `getattr(result, name)` (the
    report was a dict before).
    """

    mesh: Mesh
    n_fragments: int
    n_seeds: int
    n_vertices: int
    alpha: float
    grid: Grid
    method: str
    steps: int
    polish: int
    polish_steps: int
    tol: float
    polish_tol: float
    relax: int
    respawned: int
    component_seeds: int
    energy: float
    rdt: RdtReport
    rounds: int
    balls: int
    closed: bool
    manifold: bool
    euler_characteristic: int
    manifold_report: Any
    source_euler_characteristic: int | None
    topology_rounds: int
    topology_seeds: int
    quality_min: float
    quality_mean: float
    time: Mapping
    cpu_time: Mapping

    def __iter__(self):
        return iter((self.mesh, self))

    def __getitem__(self, name: str):
        if name not in {f.name for f in dataclasses.fields(self)}:
            raise KeyError(name)
        return getattr(self, name)


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


def line_faults(frag: Fragments) -> dict:
    """Why lines fail `open_lines`, counted per line: `"nested"`
    lines enter the solid again before leaving it (overlapping parts, self-intersections,
    internal walls), `"negative"` ones leave it before entering (inside-out parts, or a solid
    beyond the grid), `"unbalanced"` ones end inside it (an odd number of crossings)."""
    if frag.size == 0:
        return {"nested": 0, "negative": 0, "unbalanced": 0}
    key = frag.axis.astype(np.int64) * (1 << 40) + frag.line
    start = np.concatenate([[True], key[1:] != key[:-1]])
    gid = np.cumsum(start) - 1
    step = -frag.sign.astype(np.int64)  # +1 entering the solid
    depth = np.cumsum(step)
    depth -= np.concatenate([[0], depth[:-1]])[start][gid]  # the depth after each crossing, per line
    n = gid[-1] + 1
    high = np.zeros(n, np.int64)
    np.maximum.at(high, gid, depth)
    low = np.zeros(n, np.int64)
    np.minimum.at(low, gid, depth)
    final = np.bincount(gid, step, minlength=n)
    return {"nested": int(np.sum(high > 1)), "negative": int(np.sum(low < 0)), "unbalanced": int(np.sum(final != 0))}


def _not_a_solid(frag: Fragments, mesh_report) -> str:
    """The message for fragments whose lines do not alternate entering and leaving a solid."""
    bad = open_lines(frag)
    faults = line_faults(frag)
    counts = f"{bad} grid lines do not enter and leave a solid alternately"
    if mesh_report is not None and mesh_report.n_nonmanifold_edges:
        why = (f"the mesh is closed but not a 2-manifold: {mesh_report.n_nonmanifold_edges} edges have more than two "
               "faces (internal walls, or parts joined along edges), so it bounds no single solid")
    elif faults["nested"]:
        why = (f"the surface overlaps itself: {faults['nested']} lines enter the solid again before leaving it "
               "(overlapping closed parts or a self-intersecting surface); union the parts first")
    elif faults["negative"] and mesh_report is not None:
        why = (f"parts of the mesh are inside out: {faults['negative']} lines leave the solid before entering it "
               "(faces wound clockwise seen from outside); flip those parts' faces")
    elif mesh_report is not None:
        why = "the surface is open"
    else:
        why = "the surface is open or reaches beyond the grid; pass a grid that contains the whole surface"
    return f"{_WHERE}: `source` must bound a solid to be oriented: {why} ({counts}); or pass orient=False"


def _degenerate(mesh: Mesh, orient: bool) -> None:
    """Refuses a mesh without extent (its faces' vertices all at one point) or whose
    faces all have zero area: it has no surface to sample; with `orient`, also a flat one
    (extent 0 along an axis): it bounds no solid."""
    v, f = np.asarray(mesh.vertices, np.float64), np.asarray(mesh.faces, np.int64)
    used = v[np.unique(f)]
    extent = used.max(axis=0) - used.min(axis=0)
    size = float(extent.max())
    if size == 0:
        raise ValueError(f"{_WHERE}: `source` must have an extent: the mesh is degenerate (every vertex of its faces "
                         "lies at one point)")
    u = (v - used.min(axis=0)) / size  # unit size: the areas neither underflow nor overflow
    if not np.any(np.cross(u[f[:, 1]] - u[f[:, 0]], u[f[:, 2]] - u[f[:, 0]])):
        raise ValueError(f"{_WHERE}: `source` must have a surface: the mesh is degenerate (every face has zero "
                         "area)")
    if orient and not np.all(extent > 0):
        axis = "xyz"[int(np.argmin(extent))]
        raise ValueError(f"{_WHERE}: `source` must bound a solid to be oriented: the mesh is flat (extent 0 along "
                         f"{axis}, no enclosed volume); or pass orient=False")


def _mesh_source(source):
    return as_mesh(_WHERE, source) if _validate.is_mesh_object(source) or _validate.is_mesh_pair(source) else None


def _arguments(source, faces, n_seeds, grid, alpha, method, steps, polish, relax, max_rounds, round_steps, inside,
               topology_rounds, key, threads, tol=0.0, polish_tol=0.0) -> tuple:
    """The checked arguments: `(source, {name: value})`, a mesh source given as vertices and
    faces made one."""
    if _validate.is_mesh_object(source) or _validate.is_mesh_pair(source) or faces is not None:
        if not (_validate.is_mesh_object(source) or _validate.is_mesh_pair(source)) and np.ndim(faces) < 2:
            faces, n_seeds = None, faces  # remesh(field, n_seeds, ...)
        else:
            v, f, (n_seeds,) = _validate.unpack_mesh(_WHERE, source, faces, n_seeds)
            source = as_mesh(_WHERE, (v, f))
    if not (isinstance(source, Mesh) or callable(source) or isinstance(source, (CSG, Fragments, tuple))):
        raise TypeError(f"{_WHERE}: `source` must be a mesh, a field, a (values, level) grid, a CSG expression or "
                        f"Fragments, got {type(source).__name__}")
    if n_seeds is None:
        raise TypeError(f"{_WHERE}: missing `n_seeds`")
    checked_key(_WHERE, key)
    if grid is not None:
        _validate.grid(_WHERE, grid, 3)
    if method not in ("lbfgs", "lloyd"):
        raise ValueError(f'{_WHERE}: `method` must be "lbfgs" or "lloyd", got {method!r}')
    if inside not in ("below", "above"):
        raise ValueError(f'{_WHERE}: `inside` must be "below" or "above", got {inside!r}')
    checked_threads(_WHERE, threads)
    checks = {"n_seeds": (n_seeds, 4), "steps": (steps, 0), "polish": (polish, 0), "relax": (relax, 0),
              "max_rounds": (max_rounds, 0), "round_steps": (round_steps, 0), "topology_rounds": (topology_rounds, 0)}
    a = {name: _validate.positive_int(_WHERE, name, value, minimum) for name, (value, minimum) in checks.items()}
    a["alpha"] = _validate.positive_float(_WHERE, "alpha", alpha)
    for name, value in (("tol", tol), ("polish_tol", polish_tol)):
        a[name] = _validate.positive_float(_WHERE, name, value, allow_zero=True)
    if a["n_seeds"] >= 1 << 21:
        raise ValueError(f"{_WHERE}: `n_seeds` must be below 2^21 (the restricted Delaunay step's limit), "
                         f"got {a['n_seeds']}")
    need = _BYTES_PER_FRAGMENT * a["alpha"] * a["n_seeds"]
    total = _physical_memory()
    if total and need > total:
        raise MemoryError(f"{_WHERE}: {a['n_seeds']} seeds at `alpha` {a['alpha']:g} need about "
                          f"{a['alpha'] * a['n_seeds']:.3g} fragments, {need / 2**30:.1f} GiB, more than this "
                          f"machine's {total / 2**30:.1f} GiB; use fewer seeds or a smaller alpha")
    return source, a


#: working memory per fragment while sampling and optimising: its 66 bytes, the sorting
#: and padding copies and the optimiser's device arrays (an estimate, checked before sampling)
_BYTES_PER_FRAGMENT = 400


def _physical_memory() -> int:
    """The machine's memory in bytes (0 when unknown)."""
    import os

    try:
        return int(os.sysconf("SC_PAGE_SIZE")) * int(os.sysconf("SC_PHYS_PAGES"))
    except (AttributeError, ValueError, OSError):
        return 0


class _Bar:
    """A progress bar over the optimiser's steps (off with `enabled=False`), whose total
    grows when the 2-manifold or the topology rounds add steps."""

    def __init__(self, total: int, enabled: bool):
        from .._progress import ProgressBar

        self.bar = ProgressBar(max(total, 1), desc="voxax.cvt.remesh") if enabled else None

    def step(self, energy: float) -> None:
        if self.bar is not None:
            self.bar.update({"energy": f"{energy:.4g}"})

    def extend(self, steps: int) -> None:
        if self.bar is not None and steps:
            self.bar.total += steps
            self.bar.bar.total = self.bar.total
            self.bar.bar.refresh()

    def close(self) -> None:
        if self.bar is not None:
            self.bar.close()


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
        frag = sample(source, grid, inside=inside, threads=threads, where=_WHERE)[0]
    return frag


def _sample(source, grid, n_seeds: int, alpha: float, orient: bool, inside: str, threads) -> tuple:
    """The source's fragments, at about `alpha` per seed (a `(values, level)` grid as given),
    checked to bound a solid with `orient`, the Euler characteristic of a closed mesh
    source (None for other sources) and whether the source is a mesh of one connected
    piece (its faces joined through edges). **Returns:** `(frag, euler characteristic,
    one piece)`."""
    from .. import metrics

    mesh = _mesh_source(source)
    report = expected = None
    if mesh is not None:
        if len(mesh.faces) == 0:
            raise ValueError(f"{_WHERE}: `source` must be a non-empty triangle mesh, got no faces")
        _degenerate(mesh, orient)
        report = metrics.manifold_report(mesh)
        if orient and report.n_boundary_edges:
            raise ValueError(f"{_WHERE}: `source` must be closed to be oriented: the mesh is open "
                             f"({report.n_boundary_edges} boundary edges); or pass orient=False")
        if orient and not report.closed:
            raise ValueError(f"{_WHERE}: `source` must bound a solid to be oriented: the mesh is closed but not a "
                             f"2-manifold ({report.n_nonmanifold_edges} edges have more than two faces: internal "
                             "walls, or parts joined along edges); or pass orient=False")
        volume = mesh.signed_volume()
        if orient and report.edge_manifold and volume < 0:
            raise ValueError(f"{_WHERE}: `source` must be oriented outward: the mesh is inside out (enclosed volume "
                             f"{volume:.6g} < 0); flip its faces, Mesh(vertices, faces[:, ::-1]), or pass orient=False")
        if orient and report.closed and report.vertex_manifold:  # it bounds the solid sampled
            expected = report.euler_characteristic
    if isinstance(source, Fragments):
        frag = checked(_WHERE, source)
    else:
        if grid is None:
            if mesh is None:
                raise ValueError(f"{_WHERE}: `grid` must be given for fields, grids and CSG expressions")
            grid = _default_grid(mesh, n_seeds)
        frag, starts = sample(mesh if mesh is not None else source, grid, inside=inside, threads=threads,
                              where=_WHERE)
        beyond = sum(int(np.sum(st)) for st in starts) if mesh is None else 0  # a mesh's: from its signs
        if mesh is not None and orient and open_lines(frag):
            lo, hi = np.asarray(grid.lower), np.asarray(grid.upper)
            v = mesh.vertices[np.unique(mesh.faces)]
            if np.any(v < lo) or np.any(v > hi):
                raise ValueError(f"{_WHERE}: `grid` must contain the whole mesh to orient its surface: the mesh "
                                 "reaches beyond the grid's box; pass a larger grid (or none), or pass orient=False")
        if orient and beyond:
            raise ValueError(f"{_WHERE}: `grid` must contain the whole solid to orient its surface: {beyond} grid "
                             "lines start inside it (the surface is cut by the grid's box); pass a larger grid, "
                             "or pass orient=False")
        if not (isinstance(source, tuple) and mesh is None):
            frag = _refine(mesh if mesh is not None else source, grid, frag, n_seeds, alpha, inside, threads)
    if frag.size < n_seeds:
        raise ValueError(f"{_WHERE}: `n_seeds` must be at most the number of fragments: {n_seeds} seeds but only "
                         f"{frag.size} fragments; use fewer seeds or a finer grid")
    if orient and open_lines(frag):
        raise ValueError(_not_a_solid(frag, report))
    return frag, expected, report is not None and report.n_components == 1


def _optimized_seeds(frag, n_seeds, key, components, method, steps, polish, weighted, threads, bar, tol=0.0,
                     polish_tol=0.0) -> dict:
    """Seeds placed by area (and on every piece with `components`), optimised by `method`
    and polished by Lloyd steps after L-BFGS; `tol` and `polish_tol` stop the L-BFGS
    and the polish steps early (0: off)."""
    seeds0 = init_seeds(frag, n_seeds, key)
    seeds0, covered = cover_components(frag, seeds0, threads) if components else (seeds0, 0)
    stop = tol if method == "lbfgs" else 0.0
    res, hint = run_hinted(frag, np.asarray(seeds0, np.float64), method, steps, weighted, step_done=bar.step,
                           stop_tol=stop)
    seeds = res.seeds
    polish = polish if method == "lbfgs" else 0
    energy = float(res.energy[-1])
    polish_steps = 0
    if polish:
        pol, hint = run_hinted(frag, seeds, "lloyd", polish, weighted, step_done=bar.step, hint=hint,
                               stop_tol=polish_tol)
        seeds, energy, polish_steps = pol.seeds, float(pol.energy[-1]), pol.steps
    return dict(seeds=seeds, result=res, polish=polish, polish_steps=polish_steps, energy=energy, covered=covered,
                hint=hint, tol=tol, polish_tol=polish_tol)


def _manifold_rounds(frag, seeds, max_rounds, round_steps, weighted, threads, bar, hint=None) -> dict:
    """The restricted Delaunay triangulation, with rounds of Lloyd steps (and, from the
    second round on, regularisation balls on the defective edges) while it is not a
    2-manifold, at most `max_rounds`. `hint`: the seeds' assignment on `frag` (only speeds
    the first round's search)."""
    faces, rep = rdt(frag, seeds, threads=threads)
    rounds = 0
    balls = Balls()
    base = frag
    while rounds < max_rounds:
        bad = problem_edges(faces, len(seeds))
        if len(bad) == 0:
            break
        same = rounds == 0  # the fragments of the triangulation
        if rounds > 0:  # the first round only optimises further: most defects are unconverged seeds
            balls.add(seeds, bad, frag.spacing)
            frag = union_all([base, ball_fragments(balls.center, balls.radius, base.grid)])
            hint = None  # other fragments
        bar.extend(round_steps)
        moved, hint = run_hinted(frag, seeds, "lloyd", round_steps, weighted, step_done=bar.step, hint=hint)
        rounds += 1
        if same and np.array_equal(moved.seeds, seeds):
            continue  # at a fixed point of the same fragments already: the same triangulation
        seeds = moved.seeds
        faces, rep = rdt(frag, seeds, threads=threads)
    return dict(frag=frag, seeds=seeds, faces=faces, rdt=rep, rounds=rounds, balls=len(balls),
                topology_rounds=0, topology_seeds=0)


def euler_characteristic(faces: np.ndarray) -> int:
    """`V - E + F` of a triangulation (its vertices: those its faces use)."""
    if len(faces) == 0:
        return 0
    from ..metrics import _unique_rows

    f = np.asarray(faces, np.int64)
    e = np.sort(np.concatenate([f[:, [0, 1]], f[:, [1, 2]], f[:, [2, 0]]]), axis=1)
    return int(len(np.unique(f)) - len(_unique_rows(e)) + len(f))


def topology_seeds(frag: Fragments, seeds: np.ndarray, threads=None) -> np.ndarray:
    """New seeds where a region is not a topological disk of one sheet: in every region
    (the fragments nearest one seed) with fragments whose normal points against the
    region's weighted mean normal (the region spans two sheets facing each other, which
    joins them in the triangulation), at its fragment most against it. Deterministic.
    **Returns:** `(k, 3)`."""
    from .._spatial import nearest_neighbors

    _, idx = nearest_neighbors(seeds, frag.points, k=1, threads=threads)
    idx = np.asarray(idx[:, 0], np.int64)
    n = len(seeds)
    mean = np.stack([np.bincount(idx, frag.weights * frag.normals[:, a], minlength=n) for a in range(3)], axis=1)
    mean /= np.maximum(np.linalg.norm(mean, axis=1, keepdims=True), 1e-300)
    dot = np.sum(frag.normals * mean[idx], axis=1)
    order = np.lexsort((np.arange(frag.size), dot, idx))  # per region, the most opposed fragment first
    first = order[np.concatenate([[True], idx[order][1:] != idx[order][:-1]])]
    pick = first[dot[first] < 0.0]
    return frag.points[np.sort(pick)].copy()


def _topology_rounds(base, tri, expected, max_rounds, rounds, round_steps, weighted, threads, bar) -> dict:
    """While the triangulation's Euler characteristic differs from `expected`, seeds are
    added by `topology_seeds` on the source's fragments
    and optimised again (Lloyd steps, then the 2-manifold step), at most `max_rounds` times;
    a round that finds no place for a seed ends them."""
    done = added = 0
    while expected is not None and done < max_rounds and euler_characteristic(tri["faces"]) != expected:
        new = topology_seeds(base, tri["seeds"], threads)
        if len(new) == 0:
            break
        seeds = np.concatenate([tri["seeds"], new])
        bar.extend(round_steps)
        seeds = run(base, seeds, "lloyd", round_steps, weighted, step_done=bar.step).seeds
        again = _manifold_rounds(base, seeds, rounds, round_steps, weighted, threads, bar)
        tri = {**again, "rounds": tri["rounds"] + again["rounds"]}
        done += 1
        added += len(new)
    return {**tri, "topology_rounds": done, "topology_seeds": added}


def _finish(seeds, faces, frag, base, project: bool, relax: int, relax_on_source: bool, threads) -> Mesh:
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


def _result(out: Mesh, n_seeds, seeded, tri, relax, expected, times, cpu) -> RemeshResult:
    from .. import metrics

    res = seeded["result"]
    mr = metrics.manifold_report(out)
    q = metrics.triangle_quality(out)
    frag = tri["frag"]
    return RemeshResult(
        mesh=out, n_fragments=frag.size, n_seeds=n_seeds, n_vertices=out.n_vertices, alpha=frag.size / n_seeds,
        grid=frag.grid, method=res.method, steps=res.steps, polish=seeded["polish"],
        polish_steps=seeded["polish_steps"], tol=seeded["tol"], polish_tol=seeded["polish_tol"], relax=relax,
        respawned=res.respawned,
        component_seeds=seeded["covered"], energy=seeded["energy"], rdt=tri["rdt"], rounds=tri["rounds"],
        balls=tri["balls"], closed=mr.closed, manifold=mr.edge_manifold and mr.vertex_manifold,
        euler_characteristic=mr.euler_characteristic, manifold_report=mr, source_euler_characteristic=expected,
        topology_rounds=tri["topology_rounds"], topology_seeds=tri["topology_seeds"],
        quality_min=float(q.min()) if len(q) else 0.0, quality_mean=float(q.mean()) if len(q) else 0.0,
        time=times, cpu_time=cpu,
    )  # fmt: skip


def _pipeline(source, grid, a: dict, o: dict) -> RemeshResult:
    """The stages of [`remesh`][voxax.cvt.remesh] on checked arguments `a` and options `o`,
    timed."""
    times, cpu = {}, {}
    t0, c0 = time.perf_counter(), time.process_time()
    with _timed(times, cpu, "fragments"):
        frag, expected, one_piece = _sample(source, grid, a["n_seeds"], a["alpha"], o["orient"], o["inside"],
                                            o["threads"])
    bar = _Bar(a["steps"] + (a["polish"] if o["method"] == "lbfgs" else 0), o["progress"])
    try:
        with _timed(times, cpu, "optimize"):
            # a mesh of one connected piece samples to one piece (neighbouring fragments of a
            # connected surface are within sqrt(2) spacings): no search for other pieces
            components = o["components"] and not one_piece
            seeded = _optimized_seeds(frag, a["n_seeds"], o["key"], components, o["method"], a["steps"],
                                      a["polish"], o["weighted"], o["threads"], bar, a["tol"], a["polish_tol"])
        with _timed(times, cpu, "rdt"):
            rounds = a["max_rounds"] if o["orient"] else 0
            tri = _manifold_rounds(frag, seeded["seeds"], rounds, a["round_steps"], o["weighted"], o["threads"], bar,
                                   seeded["hint"])
            tri = _topology_rounds(frag, tri, expected, a["topology_rounds"], rounds, a["round_steps"], o["weighted"],
                                   o["threads"], bar)
    finally:
        bar.close()
    with _timed(times, cpu, "relax"):
        out = _finish(tri["seeds"], tri["faces"], tri["frag"], frag, o["project"], a["relax"], o["relax_on_source"],
                      o["threads"])
    result = _result(out, a["n_seeds"], seeded, tri, a["relax"], expected, times, cpu)
    times["total"] = time.perf_counter() - t0
    cpu["total"] = time.process_time() - c0
    return result


def remesh(
    source,
    faces=None,
    n_seeds: int | None = None,
    *,
    grid: Grid | None = None,
    alpha: float = 50.0,
    method: str = "lbfgs",
    steps: int = 60,
    polish: int = 40,
    tol: float = 1e-4,
    polish_tol: float = 0.02,
    orient: bool = True,
    project: bool = True,
    relax: int = 2,
    relax_on_source: bool = True,
    components: bool = True,
    weighted: bool = True,
    max_rounds: int = 30,
    round_steps: int = 20,
    inside: str = "below",
    topology_rounds: int = 3,
    key=0,
    threads: int | None = None,
    progress: bool = True,
) -> RemeshResult:
    """A quality triangle mesh of a surface with about `n_seeds` vertices (discrete CVT).

    **Arguments:**

    - `source`: a closed, outward-oriented surface mesh (a [`Mesh`][voxax.Mesh], a
      `trimesh.Trimesh`, a `(vertices, faces)` pair, or `vertices` with `faces` next), a field `f(points) -> values` (negative
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
      convergence) and its step budget (the report's `"steps"` says how many ran). Each
      step's nearest-seed search starts from the previous step's assignment.
    - `tol`: L-BFGS stops early once two of its steps in a row each lower the energy by
      less than `tol` of it (relative decrease; counted after a first step that lowered
      it by more, and over the steps that move the seeds). `0` runs all `steps` (unless
      optimistix's own test ends them). On three 20,000-seed inputs
      (`benchmarks/remesh_peers.py`) the default `tol` and `polish_tol` stopped L-BFGS
      after 32-34 of its 60 steps and the polish after 6-10 steps (6-7, to a fixed
      point, without them), the quality changing by at most 0.0003 in the mean and not
      in the minimum (on the Chebyshev octic: 35 steps, 0.570 / 0.9083 to 0.565 /
      0.9081, minimum / mean). Lloyd steps
      (`method="lloyd"`) stop only at an exact fixed point.
    - `polish`, `polish_tol`: Lloyd steps after L-BFGS (L-BFGS lowers the energy fastest
      but stalls at the switches of the assignment; the centroid steps then even out the
      worst regions, which lifts the minimum triangle quality), at most `polish`. They stop
      at an exact fixed point, or after a step whose largest seed move is below
      `polish_tol` times the edge length expected (that of equilateral triangles, two per
      seed, covering the sampled area; `0`: only at a fixed point). Near convergence the
      seeds move only where fragments switch regions (each carries about `1 / alpha` of
      its region's weight), so the largest move does not shrink smoothly: on a
      20,000-seed knot after L-BFGS it went from 0.05 of an edge to about 0.01 and then
      to 0 (a fixed point) within 19 steps. The default stops once it is below 0.02 (the
      report's `"polish_steps"` says how many ran).
    - `orient`: require a closed surface (every grid line enters and exits the solid
      alternately) and orient the result outward; `False` meshes open surfaces too
      (triangles still oriented consistently per component, direction unspecified). A
      mesh with a negative enclosed volume (inside out), overlapping closed parts, or
      closed but non-manifold (internal walls) bounds no solid of this kind, and the error
      says which of these it is.
    - `project`: move each vertex onto the tangent plane of its nearest fragment.
    - `relax`: tangential smoothing steps of the final mesh (connectivity kept): each moves
      every vertex to the mean of its neighbours within its tangent plane, then onto the
      tangent plane of its nearest fragment (a move that would turn a triangle over or push
      its quality below 0.2 is undone; vertices of non-manifold or boundary edges stay). The seeds quantise their
      regions' centroids to the fragments, and this evens out the result: on the Chebyshev
      octic at 20,000 seeds two steps lift the quality from 0.50 / 0.864 (minimum / mean)
      to 0.57 / 0.908 (every optimiser step run; the default `tol` and `polish_tol` end
      at 0.565 / 0.908). `0` returns the seeds themselves (projected with `project`).
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
      `"component_seeds"` says how many seeds were moved. A mesh source whose faces form
      one connected piece is taken as one piece without the search (at 20,000 seeds the
      search over 1M fragments took 2.7 s of a 7.4 s run).
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
    - `topology_rounds`: when the source is a closed 2-manifold mesh (with `orient`), its
      Euler characteristic is the one expected: while the triangulation's differs (a spurious handle where one
      seed's region spans two nearby sheets, or a missing piece), seeds are added in the
      regions whose fragments face opposite ways (their normals against the region's
      mean) and the seeds take `round_steps` Lloyd steps and the 2-manifold step again, at
      most this many times. If they still differ a `UserWarning` names both Euler
      characteristics (the result's `source_euler_characteristic` and
      `euler_characteristic`; `topology_rounds` and `topology_seeds` say what ran).
    - `key`: the random seeding's key, an int or a JAX PRNG key.
    - `threads`: threads for the C++ passes (None: `VOXAX_NUM_THREADS`, else every core).
    - `progress`: a progress bar over the optimiser's steps on standard error.

    **Returns:** a [`RemeshResult`][voxax.cvt.RemeshResult]: the mesh (`.mesh`) and the
    report's fields. It unpacks as `mesh, report = cvt.remesh(...)` (the report being the
    result itself), and `report["closed"]` reads a field as `report.closed` does.
    """
    source, a = _arguments(source, faces, n_seeds, grid, alpha, method, steps, polish, relax, max_rounds,
                           round_steps, inside, topology_rounds, key, threads, tol, polish_tol)
    o = dict(orient=orient, inside=inside, key=key, components=components, method=method, weighted=weighted,
             project=project, relax_on_source=relax_on_source, threads=threads, progress=progress)
    result = _pipeline(source, grid, a, o)
    expected = result.source_euler_characteristic
    if expected is not None and result.euler_characteristic != expected:
        warnings.warn(
            f"voxax.cvt.remesh: the result's Euler characteristic is {result.euler_characteristic}, the source's "
            f"{expected}: the topology changed (after {result.topology_rounds} topology rounds); use more seeds "
            "(n_seeds) or denser samples (alpha)", UserWarning, stacklevel=2)  # fmt: skip
    return result
