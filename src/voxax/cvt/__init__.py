"""Quality triangle meshes of anything that can be rasterised, by a discrete restricted CVT.

The pipeline (after Raster2Mesh): sample the surface where the cell-centre lines of a grid
along x, y and z cross it ([`fragments`][voxax.cvt.fragments]: meshes, implicit fields,
sampled grids and boolean combinations of them); place seeds in proportion to area
([`init_seeds`][voxax.cvt.init_seeds]) and optimise them towards a centroidal Voronoi
tessellation restricted to the samples ([`optimize`][voxax.cvt.optimize]: Lloyd or
L-BFGS on [`energy`][voxax.cvt.energy]); read the restricted Delaunay triangulation off
the samples' nearest seeds ([`rdt`][voxax.cvt.rdt], C++). [`remesh`][voxax.cvt.remesh]
runs it all.

```python
>>> import jax; jax.config.update("jax_enable_x64", True)
>>> import voxax
>>> mesh, report = voxax.cvt.remesh(voxax.data.icosphere(3), 300, method="lloyd", steps=20)
>>> report["closed"], report["euler_characteristic"]
(True, 2)

```
"""

from __future__ import annotations

import time

import numpy as np

from .._grid import Grid
from .._mesh import Mesh
from ._fragments import CSG, Fragments, fragments
from ._optimize import CVTResult, assign, energy, energy_gradient, init_seeds, lloyd_step, optimize, respawn
from ._rdt import RdtReport, rdt

__all__ = [
    "CSG",
    "CVTResult",
    "Fragments",
    "RdtReport",
    "assign",
    "energy",
    "energy_gradient",
    "fragments",
    "init_seeds",
    "lloyd_step",
    "optimize",
    "rdt",
    "remesh",
    "respawn",
]


def _open_lines(frag: Fragments) -> int:
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


def _components(frag: Fragments, threads=None) -> tuple[int, np.ndarray]:
    """Connected pieces of the sampled surface: fragments closer than twice the grid
    spacing are joined (neighbouring fragments of a connected surface are within
    `sqrt(2)` spacings). **Returns:** `(count, label per fragment)`."""
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    from .._spatial import nearest_neighbors

    k = min(12, frag.size - 1)
    if k < 1:
        return 1, np.zeros(frag.size, np.int64)
    d, idx = nearest_neighbors(frag.points, frag.points, k=k + 1, threads=threads)
    near = (d[:, 1:] < 2.0 * frag.spacing) & (idx[:, 1:] >= 0)
    rows = np.repeat(np.arange(frag.size), k).reshape(-1, k)[near]
    g = coo_matrix((np.ones(len(rows)), (rows, idx[:, 1:][near])), shape=(frag.size, frag.size))
    return connected_components(g, directed=False)


def _cover_components(frag: Fragments, seeds: np.ndarray, threads=None, least: int = 4) -> tuple[np.ndarray, int]:
    """Gives every piece of the surface with at least one seed's share of the area four
    seeds or more (the fewest that close a surface), taken from the pieces with the most
    seeds (their seeds closest to another seed first); placed by farthest-point sampling
    from the fragment nearest the piece's centroid. Deterministic. **Returns:**
    `(seeds, moved)`."""
    from .._spatial import nearest_neighbors

    count, label = _components(frag, threads)
    if count < 2:
        return seeds, 0
    n = len(seeds)
    area = np.bincount(label, frag.weights, minlength=count)
    share = area / area.sum() * n
    _, idx = nearest_neighbors(frag.points, seeds, k=1, threads=threads)
    owner = label[idx[:, 0]]  # the piece of each seed's nearest fragment
    have = np.bincount(owner, minlength=count)
    need = np.nonzero((share >= 1.0) & (have < least) & (np.bincount(label, minlength=count) >= 4))[0]
    if len(need) == 0:
        return seeds, 0
    s = np.array(seeds, np.float64)
    # donors are taken where seeds crowd most: by their distance to the nearest other seed
    crowd, _ = nearest_neighbors(s, s, k=2, threads=threads)
    by_crowd = np.lexsort((np.arange(n), crowd[:, 1]))
    moved = 0
    for c in need[np.argsort(-area[need], kind="stable")]:
        pts = frag.points[label == c]
        want = least - int(have[c])
        # donors: seeds of the piece with the most seeds to spare, the most crowded first
        donors = []
        for _ in range(want):
            spare = have - least
            spare[c] = -1
            d = int(np.argmax(spare))
            if spare[d] <= 0:
                break
            mine = by_crowd[owner[by_crowd] == d]
            mine = mine[~np.isin(mine, donors)]
            donors.append(int(mine[0]))
            have[d] -= 1
        taken = s[owner == c]
        pick = []
        if len(taken):
            gap = np.min(np.sum((pts[:, None, :] - taken[None]) ** 2, axis=2), axis=1)
        else:  # start at the fragment nearest the piece's centroid
            centroid = np.average(pts, axis=0, weights=frag.weights[label == c])
            pick = [int(np.argmin(np.sum((pts - centroid) ** 2, axis=1)))]
            gap = np.sum((pts - pts[pick[0]]) ** 2, axis=1)
        while len(pick) < len(donors):
            j = int(np.argmax(gap))
            pick.append(j)
            gap = np.minimum(gap, np.sum((pts - pts[j]) ** 2, axis=1))
        for i, j in zip(donors, pick):
            s[i] = pts[j]
            owner[i] = c
        have[c] += len(donors)
        moved += len(donors)
    return s, moved


def _problem_edges(faces: np.ndarray, n: int) -> np.ndarray:
    """Undirected edges `(E, 2)` with other than two triangles, and the edges at vertices
    whose triangles do not form one fan."""
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    if len(faces) == 0:
        return np.zeros((0, 2), np.int64)
    f = faces.astype(np.int64)
    e = np.sort(np.concatenate([f[:, [0, 1]], f[:, [1, 2]], f[:, [2, 0]]]), axis=1)
    ukey, count = np.unique(e[:, 0] * n + e[:, 1], return_counts=True)  # 1D keys: sorted like the rows
    uniq = np.stack([ukey // n, ukey % n], axis=1)
    bad = [uniq[count != 2]]
    # fans: nodes (face, corner); corners of one vertex joined across shared edges
    nf = len(f)
    corner_v = f.ravel()
    node = np.arange(3 * nf)
    pairs = []
    for c in range(3):
        for d in (1, 2):  # the two edges at corner c: (v, f[:, c + d])
            other = f[:, (c + d) % 3]
            key = corner_v[c::3] * n + other
            pairs.append((key, node[c::3]))
    key = np.concatenate([p[0] for p in pairs])
    nd = np.concatenate([p[1] for p in pairs])
    order = np.argsort(key, kind="stable")
    key, nd = key[order], nd[order]
    same = key[1:] == key[:-1]
    a, b = nd[:-1][same], nd[1:][same]
    g = coo_matrix((np.ones(len(a)), (a, b)), shape=(3 * nf, 3 * nf))
    _, label = connected_components(g, directed=False)
    fans = np.unique(corner_v * (3 * nf) + label)  # distinct (vertex, fan) pairs
    per_vertex = np.bincount(fans // (3 * nf), minlength=n)
    nonmanifold = np.nonzero(per_vertex > 1)[0]
    if len(nonmanifold):
        bad.append(uniq[np.isin(uniq[:, 0], nonmanifold) | np.isin(uniq[:, 1], nonmanifold)])
    if not sum(len(b) for b in bad):
        return np.zeros((0, 2), np.int64)
    key = np.unique(np.concatenate([b[:, 0] * n + b[:, 1] for b in bad]))
    return np.stack([key // n, key % n], axis=1)


class _Balls:
    """Regularisation balls: placed on problem edges, grown when hit again (paper 4.4)."""

    def __init__(self):
        self.center = np.zeros((0, 3))
        self.radius = np.zeros(0)
        self.rmax = np.zeros(0)
        self.rinc = np.zeros(0)

    def add(self, seeds: np.ndarray, edges: np.ndarray, d: float) -> None:
        growing = self.radius < self.rmax
        new_c, new_r, new_max = [], [], []
        grown = np.zeros(len(self.radius), bool)
        for i, j in edges:
            a, b = seeds[i], seeds[j]
            length = float(np.linalg.norm(b - a))
            if length == 0:
                continue
            if growing.any():
                # distance from the segment to the growing balls' centres
                ab = b - a
                t = np.clip((self.center - a) @ ab / (ab @ ab), 0, 1)
                dist = np.linalg.norm(a + t[:, None] * ab - self.center, axis=1)
                hit = growing & (dist < self.radius)
                if hit.any():
                    grown |= hit
                    continue
            count = max(1, int(np.ceil(0.5 * np.min(np.abs(b - a)) / d)))
            for k in range(count):
                new_c.append(a + (k + 0.5) / count * (b - a))
                new_r.append(length / 2)
                new_max.append(length)
        self.radius = np.where(grown, np.minimum(self.radius + self.rinc, self.rmax), self.radius)
        if new_c:
            self.center = np.concatenate([self.center, np.array(new_c)])
            self.radius = np.concatenate([self.radius, new_r])
            self.rmax = np.concatenate([self.rmax, new_max])
            self.rinc = np.concatenate([self.rinc, np.array(new_max) / 20])

    def __len__(self):
        return len(self.radius)


#: a relaxation move that would push a triangle's quality below this (or below its
#: quality before the step, if lower) is undone
_FLOOR = 0.2


def _project(points: np.ndarray, frag: Fragments) -> np.ndarray:
    from .._spatial import nearest_neighbors

    _, idx = nearest_neighbors(frag.points, points, k=1)
    i = idx[:, 0]
    x, n = frag.points[i], frag.normals[i]
    return points - np.sum((points - x) * n, axis=1, keepdims=True) * n


def _relax(verts: np.ndarray, faces: np.ndarray, frag: Fragments, steps: int, floor: float = 0.0) -> np.ndarray:
    """Tangential smoothing of a mesh on the sampled surface: each step moves every vertex
    to the mean of its neighbours within its tangent plane (the area-weighted normal), then
    onto the tangent plane of its nearest fragment; a vertex whose move would turn one of
    its triangles over, or push its quality below `floor` (or below its quality before the
    step, if lower), stays. Vertices of edges with other than two triangles stay."""
    from ..metrics import triangle_quality

    v = np.array(verts, np.float64)
    n = len(v)
    f = faces.astype(np.int64)
    if steps <= 0 or len(f) == 0:
        return v
    fixed = np.zeros(n, bool)
    fixed[_problem_edges(faces, n).ravel()] = True
    src = np.concatenate([f[:, 0], f[:, 1], f[:, 2], f[:, 1], f[:, 2], f[:, 0]])
    dst = np.concatenate([f[:, 1], f[:, 2], f[:, 0], f[:, 0], f[:, 1], f[:, 2]])
    degree = np.bincount(src, minlength=n).astype(np.float64)
    degree[degree == 0] = 1.0

    def face_normals(x):
        return np.cross(x[f[:, 1]] - x[f[:, 0]], x[f[:, 2]] - x[f[:, 0]])

    for _ in range(steps):
        fn = face_normals(v)
        oriented = np.any(fn != 0, axis=1)
        vn = np.stack([np.bincount(f.ravel(), np.repeat(fn[:, a], 3), minlength=n) for a in range(3)], axis=1)
        vn /= np.maximum(np.linalg.norm(vn, axis=1, keepdims=True), 1e-300)
        mean = np.stack([np.bincount(src, v[dst, a], minlength=n) for a in range(3)], axis=1) / degree[:, None]
        d = mean - v
        d -= np.sum(d * vn, axis=1, keepdims=True) * vn
        d[fixed] = 0.0
        new = _project(v + d, frag)
        new[fixed] = v[fixed]
        q0 = triangle_quality((v, f)) if floor > 0 else None
        for _ in range(20):  # undo moves that turn a triangle over (neighbours may need it too)
            flipped = (np.sum(face_normals(new) * fn, axis=1) <= 0) & oriented
            if floor > 0:  # or that crush a triangle below the floor
                flipped |= triangle_quality((new, f)) < np.minimum(floor, q0)
            if not flipped.any():
                break
            back = np.unique(f[flipped])
            new[back] = v[back]
        v = new
    return v


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
    from .. import metrics

    n_seeds = int(n_seeds)
    if n_seeds < 4:
        raise ValueError(f"cvt.remesh: n_seeds must be >= 4, got {n_seeds}")
    if int(relax) < 0:
        raise ValueError(f"cvt.remesh: relax must be >= 0, got {relax}")
    polish = int(polish)
    if polish < 0:
        raise ValueError(f"cvt.remesh: polish must be >= 0, got {polish}")
    alpha = float(alpha)
    if not alpha > 0:
        raise ValueError(f"cvt.remesh: alpha must be > 0, got {alpha}")
    times, cpu = {}, {}
    t0, c0 = time.perf_counter(), time.process_time()
    mesh = _mesh_source(source)
    if mesh is not None:
        if mesh.vertices.shape[1:] != (3,) or len(mesh.faces) == 0:
            raise ValueError("cvt.remesh: the mesh must be a non-empty 3D triangle mesh")
        if orient and not metrics.manifold_report(mesh).closed:
            raise ValueError("cvt.remesh: the mesh is open, so it cannot be oriented; pass orient=False")
    if isinstance(source, Fragments):
        frag = source
    else:
        fixed = isinstance(source, tuple) and mesh is None
        if grid is None:
            if mesh is None:
                raise ValueError("cvt.remesh: fields, grids and CSG expressions need a grid")
            # a margin of about two edge lengths, room for the regularisation balls
            v, f = mesh.vertices, mesh.faces
            area = 0.5 * np.linalg.norm(np.cross(v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]]), axis=1).sum()
            margin = 2.0 * np.sqrt(4.0 * area / (np.sqrt(3.0) * n_seeds))
            lo, hi = v.min(axis=0) - margin, v.max(axis=0) + margin
            h = float(np.max(hi - lo)) / 64
            shape = tuple(int(max(1, np.ceil(e / h))) for e in hi - lo)
            grid = Grid(tuple(lo), tuple(lo + np.asarray(shape) * h), shape)
        frag = fragments(source, grid, inside=inside, threads=threads)
        if not fixed:
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
    times["fragments"] = time.perf_counter() - t0
    cpu["fragments"] = time.process_time() - c0
    if frag.size < n_seeds:
        raise ValueError(f"cvt.remesh: {n_seeds} seeds but only {frag.size} fragments; use fewer seeds or a finer grid")
    if orient:
        bad = _open_lines(frag)
        if bad:
            raise ValueError(
                f"cvt.remesh: the surface is open ({bad} grid lines do not enter and exit a solid); "
                "it cannot be oriented: pass orient=False or a grid that contains the whole surface"
            )
    t1, c1 = time.perf_counter(), time.process_time()
    seeds0 = init_seeds(frag, n_seeds, key)
    seeds0, covered = _cover_components(frag, seeds0, threads) if components else (seeds0, 0)
    res = optimize(frag, seeds0, method=method, steps=steps, weighted=weighted)
    seeds = res.seeds
    polish = polish if method == "lbfgs" else 0
    energy = float(res.energy[-1])
    polish_steps = 0
    if polish:
        pol = optimize(frag, seeds, method="lloyd", steps=polish, weighted=weighted)
        seeds, energy, polish_steps = pol.seeds, float(pol.energy[-1]), pol.steps
    times["optimize"] = time.perf_counter() - t1
    cpu["optimize"] = time.process_time() - c1
    t2, c2 = time.perf_counter(), time.process_time()
    faces, rep = rdt(frag, seeds, threads=threads)
    rounds = 0
    balls = _Balls()
    base = frag
    if orient and max_rounds > 0:
        from ._fragments import ball_fragments, union_all

        while rounds < max_rounds:
            bad = _problem_edges(faces, len(seeds))
            if len(bad) == 0:
                break
            if rounds > 0:  # the first round only optimises further: most defects are unconverged seeds
                balls.add(seeds, bad, frag.spacing)
                frag = union_all([base, ball_fragments(balls.center, balls.radius, base.grid)])
            seeds = optimize(frag, seeds, method="lloyd", steps=round_steps, weighted=weighted).seeds
            faces, rep = rdt(frag, seeds, threads=threads)
            rounds += 1
    times["rdt"] = time.perf_counter() - t2
    cpu["rdt"] = time.process_time() - c2
    used = np.unique(faces)
    remap = np.full(len(seeds), -1, np.int64)
    remap[used] = np.arange(len(used))
    verts = seeds[used]
    relax = int(relax)
    t3, c3 = time.perf_counter(), time.process_time()
    if project or relax > 0:
        verts = _project(verts, frag)
    surface = base if relax_on_source else frag
    verts = _relax(verts, remap[faces], surface, relax, _FLOOR)
    times["relax"] = time.perf_counter() - t3
    cpu["relax"] = time.process_time() - c3
    out = Mesh(verts, remap[faces].astype(np.int32))
    mr = metrics.manifold_report(out)
    q = metrics.triangle_quality(out)
    times["total"] = time.perf_counter() - t0
    cpu["total"] = time.process_time() - c0
    report = {
        "n_fragments": frag.size,
        "n_seeds": n_seeds,
        "n_vertices": len(verts),
        "alpha": frag.size / n_seeds,
        "grid": frag.grid,
        "method": res.method,
        "steps": res.steps,
        "polish": polish,
        "polish_steps": polish_steps,
        "relax": relax,
        "respawned": res.respawned,
        "component_seeds": covered,
        "energy": energy,
        "rdt": rep,
        "rounds": rounds,
        "balls": len(balls),
        "closed": mr.closed,
        "manifold": mr.edge_manifold and mr.vertex_manifold,
        "euler_characteristic": mr.euler_characteristic,
        "manifold_report": mr,
        "quality_min": float(q.min()) if len(q) else 0.0,
        "quality_mean": float(q.mean()) if len(q) else 0.0,
        "time": times,
        "cpu_time": cpu,
    }
    return out, report
