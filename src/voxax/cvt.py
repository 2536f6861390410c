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
>>> mesh, report = voxax.cvt.remesh(voxax.data.icosphere(3), 300, steps=20)
>>> report["closed"], report["euler_characteristic"]
(True, 2)

```
"""

from __future__ import annotations

import time

import numpy as np

from ._cvt_fragments import CSG, Fragments, fragments
from ._cvt_optimize import CVTResult, assign, energy, energy_gradient, init_seeds, lloyd_step, optimize, respawn
from ._cvt_rdt import RdtReport, rdt
from ._grid import Grid
from ._mesh import Mesh

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
    if len(frag) == 0:
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


def _project(points: np.ndarray, frag: Fragments) -> np.ndarray:
    from ._spatial import nearest_neighbors

    _, idx = nearest_neighbors(frag.points, points, k=1)
    i = idx[:, 0]
    x, n = frag.points[i], frag.normals[i]
    return points - np.sum((points - x) * n, axis=1, keepdims=True) * n


def remesh(
    source,
    n_seeds: int,
    *,
    grid: Grid | None = None,
    alpha: float = 50.0,
    method: str = "lbfgs",
    steps: int = 100,
    orient: bool = True,
    project: bool = True,
    weighted: bool = True,
    inside: str = "below",
    key=0,
    threads=None,
):
    """A quality triangle mesh of a surface with about `n_seeds` vertices (discrete CVT).

    **Arguments:**

    - `source`: a closed [`Mesh`][voxax.Mesh], a field `f(points) -> values` (negative
      inside; needs `grid`), a `(values, level)` grid (needs `grid`), a
      [`CSG`][voxax.cvt.CSG] expression (needs `grid`) or ready [`Fragments`][voxax.cvt.Fragments].
    - `n_seeds`: the number of seeds (vertices; seeds whose regions end up without a
      triangle are dropped).
    - `grid`: the box to sample in. Its shape is refined (cubic cells) until there are about
      `alpha` fragments per seed; for a mesh the default box is the mesh's bounding box.
      A `(values, level)` source is sampled on its own grid as given.
    - `alpha`: fragments per seed (the paper uses > 50).
    - `method`, `steps`: the optimiser (`"lbfgs"` or `"lloyd"`) and its step budget.
    - `orient`: require a closed surface (every grid line enters and exits the solid
      alternately) and orient the result outward; `False` meshes open surfaces too
      (triangles still oriented consistently per component, direction unspecified).
    - `project`: move each vertex onto the tangent plane of its nearest fragment.
    - `weighted`: use area weights (uniform density).
    - `inside`: for `(values, level)` sources, `"below"` or `"above"` the level.
    - `key`: seed of the random seeding.
    - `threads`: threads for the C++ passes.

    **Returns:** `(Mesh, report)`; the report is a dict with the fragment and seed counts,
    `alpha`, the energies, the [`RdtReport`][voxax.cvt.RdtReport] (`"rdt"`), the topology
    (`"closed"`, `"manifold"`, `"euler_characteristic"`), triangle quality (`"quality_min"`,
    `"quality_mean"`) and timings in seconds.
    """
    from . import metrics

    n_seeds = int(n_seeds)
    if n_seeds < 4:
        raise ValueError(f"cvt.remesh: n_seeds must be >= 4, got {n_seeds}")
    alpha = float(alpha)
    if not alpha > 0:
        raise ValueError(f"cvt.remesh: alpha must be > 0, got {alpha}")
    times = {}
    t0 = time.perf_counter()
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
            grid = Grid.around(mesh.vertices, 64)
        frag = fragments(source, grid, inside=inside, threads=threads)
        if not fixed:
            for _ in range(3):
                ratio = len(frag) / (alpha * n_seeds)
                if 0.8 <= ratio:
                    break
                scale = 1.0 / np.sqrt(ratio)
                h = max(grid.spacing) / scale
                ext = np.asarray(grid.upper) - np.asarray(grid.lower)
                shape = tuple(int(max(1, np.ceil(e / h))) for e in ext)
                grid = Grid(grid.lower, tuple(np.asarray(grid.lower) + np.asarray(shape) * h), shape)
                frag = fragments(source, grid, inside=inside, threads=threads)
    times["fragments"] = time.perf_counter() - t0
    if len(frag) < n_seeds:
        raise ValueError(
            f"cvt.remesh: {n_seeds} seeds but only {len(frag)} fragments; use fewer seeds or a finer grid"
        )
    if orient:
        bad = _open_lines(frag)
        if bad:
            raise ValueError(
                f"cvt.remesh: the surface is open ({bad} grid lines do not enter and exit a solid); "
                "it cannot be oriented: pass orient=False or a grid that contains the whole surface"
            )
    t1 = time.perf_counter()
    seeds0 = init_seeds(frag, n_seeds, key)
    res = optimize(frag, seeds0, method=method, steps=steps, weighted=weighted)
    times["optimize"] = time.perf_counter() - t1
    t2 = time.perf_counter()
    faces, rep = rdt(frag, res.seeds, threads=threads)
    times["rdt"] = time.perf_counter() - t2
    used = np.unique(faces)
    remap = np.full(len(res.seeds), -1, np.int64)
    remap[used] = np.arange(len(used))
    verts = res.seeds[used]
    if project:
        verts = _project(verts, frag)
    out = Mesh(verts, remap[faces].astype(np.int32))
    mr = metrics.manifold_report(out)
    q = metrics.triangle_quality(out)
    times["total"] = time.perf_counter() - t0
    report = {
        "n_fragments": len(frag),
        "n_seeds": n_seeds,
        "n_vertices": len(verts),
        "alpha": len(frag) / n_seeds,
        "grid": frag.grid,
        "method": res.method,
        "steps": res.steps,
        "respawned": res.respawned,
        "energy": float(res.energy[-1]),
        "rdt": rep,
        "closed": mr.closed,
        "manifold": mr.edge_manifold and mr.vertex_manifold,
        "euler_characteristic": mr.euler_characteristic,
        "manifold_report": mr,
        "quality_min": float(q.min()) if len(q) else 0.0,
        "quality_mean": float(q.mean()) if len(q) else 0.0,
        "time": times,
    }
    return out, report
