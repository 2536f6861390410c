"""CVT meshing benchmark: the Chebyshev octic with 20k seeds (about 1M fragments).

Measures the nearest-seed pass and a Lloyd step at 20k seeds / ~1M fragments, the end-to-end
`voxax.cvt.remesh` (topology, triangle quality, Hausdorff distance to a fine marching-cubes
reference, time), marching cubes at the same vertex count, marching cubes followed by
pymeshlab's isotropic remeshing, and the time ratio t(40k) / t(20k).

    PYTHONPATH=src python benchmarks/cvt.py [--seeds 20000] [--steps 60] [--polish 40] [--relax 2] [--method lbfgs|lloyd] [--alpha 50] [--quick]
    PYTHONPATH=src python benchmarks/cvt.py --topology    # the source's Euler characteristic kept or not
"""

from __future__ import annotations

import argparse
import json
import os
import time

import jax
import numpy as np

jax.config.update("jax_enable_x64", True)

import voxax  # noqa: E402
from voxax import cvt, fields, metrics  # noqa: E402

HALF = 1.05  # the octic lies in [-1.0136, 1.0136]^3: leave a margin of cells


def octic(p):
    return fields.chebyshev(p, 8)


def best_of(fn, repeat=3):
    best = np.inf
    out = None
    for _ in range(repeat):
        t = time.perf_counter()
        out = fn()
        best = min(best, time.perf_counter() - t)
    return best, out


def mc_mesh(n_cells: int):
    g = voxax.Grid.cube(n_cells, half_width=HALF)
    w = np.asarray(octic(g.centers().reshape(-1, 3))).reshape(g.shape)
    t = time.perf_counter()
    iso = voxax.isosurface(w, g, 0.0)
    dt = time.perf_counter() - t
    return voxax.Mesh(np.asarray(iso.vertices), np.asarray(iso.faces)), dt


def summary(m, ref, diag):
    q = metrics.triangle_quality(m)
    mr = metrics.manifold_report(m)
    return {
        "vertices": len(m.vertices),
        "faces": len(m.faces),
        "chi": int(mr.euler_characteristic),
        "manifold": bool(mr.edge_manifold and mr.vertex_manifold and mr.closed),
        "q_min": float(q.min()),
        "q_mean": float(q.mean()),
        "hausdorff_pct": 100.0 * metrics.hausdorff(m, ref, n=200_000) / diag,
    }


def draw_scenes(rng_seed: int = 0):
    """Random 3-primitive scenes (spheres and boxes; union, intersection, difference), as
    `(index, ops, CSG expression, manifold3d solid)`; scenes whose exact volume is below
    0.02 are skipped (their indices are not yielded)."""
    import manifold3d
    from jax.tree_util import Partial

    rng = np.random.default_rng(rng_seed)
    i = 0
    while True:
        prims = []
        for _ in range(3):
            c = tuple(float(x) for x in rng.uniform(-0.35, 0.35, 3))
            if rng.random() < 0.5:
                r = float(rng.uniform(0.3, 0.55))
                prims.append(
                    (Partial(fields.sphere, radius=r, center=c), manifold3d.Manifold.sphere(r, 256).translate(c))
                )
            else:
                h = tuple(float(x) for x in rng.uniform(0.2, 0.45, 3))
                prims.append(
                    (
                        Partial(fields.box, half_extents=h, center=c),
                        manifold3d.Manifold.cube(tuple(2 * x for x in h), center=True).translate(c),
                    )
                )
        ops = [str(rng.choice(["union", "intersection", "difference"])) for _ in range(2)]
        expr, solid = prims[0]
        for op, (f, m) in zip(ops, prims[1:]):
            expr = cvt.CSG(op, expr, f)
            solid = {"union": solid + m, "intersection": solid ^ m, "difference": solid - m}[op]
        if solid.volume() >= 0.02:
            yield i, ops, expr, solid
        i += 1


def csg_scenes(
    count: int,
    seeds: int,
    rng_seed: int = 0,
    max_rounds: int = 10,
    relax: int = 2,
    relax_on_source: bool = True,
    components: bool = True,
    only=None,
    alpha: float = 50.0,
):
    """`count` random 3-primitive scenes (see `draw_scenes`) meshed at `seeds` seeds:
    closed 2-manifold?, volume against manifold3d's exact boolean, and Hausdorff distance
    against manifold3d's mesh in units of the CVT mesh's mean edge. Scenes whose exact
    volume is below 0.02 are redrawn (and counted). `only`: scene indices to mesh (of the
    same random stream), instead of the first `count`.

    The primitives are `jax.tree_util.Partial` fields, so sampling and root refinement
    compile once per primitive type, not once per scene."""
    rows = []
    drawn = 0
    for i, ops, expr, solid in draw_scenes(rng_seed):
        if only is not None and i not in only:
            if i > max(only):
                break
            continue
        if only is None and len(rows) >= count:
            break
        drawn = i + 1
        try:
            mesh, rep = cvt.remesh(
                expr,
                seeds,
                grid=voxax.Grid.cube(24, half_width=1.0),
                steps=40,
                polish=20,
                max_rounds=max_rounds,
                relax=relax,
                relax_on_source=relax_on_source,
                components=components,
                alpha=alpha,
            )
        except ValueError as err:
            rows.append({"scene": i, "ops": ops, "error": str(err)})
            print(json.dumps(rows[-1], default=str), flush=True)
            continue
        v, f = mesh.vertices, mesh.faces
        vol = mesh.signed_volume()
        ref = solid.to_mesh()
        refm = voxax.Mesh(np.asarray(ref.vert_properties)[:, :3], np.asarray(ref.tri_verts))
        edge = float(np.mean(np.linalg.norm(v[f[:, 0]] - v[f[:, 1]], axis=1)))
        rows.append(
            {
                "scene": i,
                "ops": ops,
                "manifold": bool(rep["closed"] and rep["manifold"]),
                "chi": rep["euler_characteristic"],
                "rounds": rep["rounds"],
                "balls": rep["balls"],
                "component_seeds": rep["component_seeds"],
                "volume_err": vol / solid.volume() - 1,
                "hausdorff_edges": metrics.hausdorff(mesh, refm, n=50_000) / edge,
                "q_min": rep["quality_min"],
                "q_mean": rep["quality_mean"],
                "time_s": rep["time"]["total"],
                "cpu_s": time.process_time(),
            }
        )
        print(json.dumps(rows[-1], default=str), flush=True)  # progress: one line per scene
    ok = [r for r in rows if "error" not in r]
    return {
        "scenes": len(rows),
        "drawn": drawn,
        "redrawn_nearly_empty": drawn - len(rows) if only is None else None,
        "manifold": sum(r["manifold"] for r in ok),
        "volume_within_2pct": sum(abs(r["volume_err"]) <= 0.02 for r in ok),
        "hausdorff_within_1.5_edges": sum(r["hausdorff_edges"] <= 1.5 for r in ok),
        "all_three": sum(r["manifold"] and abs(r["volume_err"]) <= 0.02 and r["hausdorff_edges"] <= 1.5 for r in ok),
        "errors": [r for r in rows if "error" in r],
        "worst_volume_err": max((abs(r["volume_err"]) for r in ok), default=None),
        "worst_hausdorff_edges": max((r["hausdorff_edges"] for r in ok), default=None),
        "time_s_total": sum(r["time_s"] for r in ok),
        "load_average_end": os.getloadavg(),
        "rows": rows,
    }


@jax.jit
def grid_lloyd(y, x, w):
    """One Lloyd step by the plain grid search and XLA segment sums, the fragments as
    arguments (how `cvt.optimize` stepped before its warm-started assignment kernel)."""
    n = y.shape[0]
    idx = voxax.nearest_neighbors(y, x, k=1)[1][:, 0]
    mass = jax.ops.segment_sum(w, idx, num_segments=n)
    first = jax.ops.segment_sum(w[:, None] * x, idx, num_segments=n)
    return jax.numpy.where(mass[:, None] > 0, first / jax.numpy.where(mass > 0, mass, 1.0)[:, None], y)


def kernel_times(n: int, alpha: float, repeat: int = 7) -> dict:
    """Best-of-`repeat` wall time of the nearest-seed pass and of one `grid_lloyd` step, on the octic's fragments from a
    cubic grid sized for about `alpha * n` fragments, with `n` area-proportional seeds."""
    out = {"seeds": n, "cores": os.cpu_count(), "load_average_start": os.getloadavg()}
    cells = 64
    for _ in range(3):
        frag = cvt.fragments(octic, voxax.Grid.cube(cells, half_width=HALF))
        ratio = frag.size / (alpha * n)
        if 0.9 <= ratio <= 1.1:
            break
        cells = int(round(cells / np.sqrt(ratio)))
    out["cells"], out["fragments"] = cells, int(frag.size)
    seeds = cvt.init_seeds(frag, n, 0)
    voxax.nearest_neighbors(seeds, frag.points, k=1)
    out["nearest_seed_s"], _ = best_of(lambda: voxax.nearest_neighbors(seeds, frag.points, k=1), repeat)
    x, w = jax.numpy.asarray(frag.points), jax.numpy.asarray(frag.weights)
    y = jax.numpy.asarray(seeds)
    jax.block_until_ready(grid_lloyd(y, x, w))
    out["lloyd_step_s"], _ = best_of(lambda: jax.block_until_ready(grid_lloyd(y, x, w)), repeat)
    out["load_average_end"] = os.getloadavg()
    return out


def topology_cases(keys=(0, 1, 2), only=None) -> list:
    """`remesh` of closed genus-0 meshes whose thin parts are near the seed spacing, without
    topology rounds and (where the Euler characteristic changed) with the default three:
    the result's Euler characteristic against the source's, the rounds, the seeds they
    added and the wall-clock time."""
    import warnings

    def plate(t):
        return voxax.data.box((-0.5, -0.5, -t / 2), (0.5, 0.5, t / 2))

    lloyd = {"method": "lloyd", "steps": 20}  # fewer, cheaper steps: the test's setting
    cases = [("hand", voxax.data.hand(), 5000, {}), ("mug", voxax.data.mug(), 5000, {}),
             ("plate 0.05", plate(0.05), 300, {}), ("plate 0.05 lloyd20", plate(0.05), 300, lloyd),
             ("plate 0.02", plate(0.02), 2000, {})]
    if only:
        cases = [c for c in cases if c[0] in only]
    out = []
    for name, mesh, n, options in cases:
        for key in keys:
            row = {"mesh": name, "seeds": n, "key": key}
            for rounds in (0, 3):
                t = time.perf_counter()
                with warnings.catch_warnings(record=True) as caught:
                    warnings.simplefilter("always")
                    res = cvt.remesh(mesh, n, key=key, topology_rounds=rounds, progress=False, **options)
                row[f"rounds={rounds}"] = {
                    "chi": res.euler_characteristic, "source_chi": res.source_euler_characteristic,
                    "closed_manifold": bool(res.closed and res.manifold), "topology_rounds": res.topology_rounds,
                    "topology_seeds": res.topology_seeds, "warned": any(w.category is UserWarning for w in caught),
                    "seconds": round(time.perf_counter() - t, 1),
                }
                if res.euler_characteristic == res.source_euler_characteristic:
                    break  # the rounds would not run: the same result
            print(json.dumps(row), flush=True)
            out.append(row)
    return out


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--seeds", type=int, default=20000)
    ap.add_argument("--steps", type=int, default=60)
    ap.add_argument("--polish", type=int, default=40, help="Lloyd steps after L-BFGS")
    ap.add_argument("--tol", type=float, default=1e-4, help="L-BFGS stopping tolerance (0: every step)")
    ap.add_argument("--polish-tol", type=float, default=0.02, help="polish stopping tolerance (0: to a fixed point)")
    ap.add_argument("--relax", type=int, default=2, help="tangential relaxation steps of the final mesh")
    ap.add_argument("--method", default="lbfgs")
    ap.add_argument("--alpha", type=float, default=50.0, help="fragments per seed")
    ap.add_argument("--quick", action="store_true", help="skip the 40k run and pymeshlab")
    ap.add_argument("--csg", type=int, default=0, metavar="N", help="only run N random CSG scenes at 2k seeds")
    ap.add_argument("--csg-rounds", type=int, default=30, help="manifold rounds per CSG scene")
    ap.add_argument(
        "--relax-on-union",
        action="store_true",
        help="relax CSG meshes onto the union of the source with the balls, not the source",
    )
    ap.add_argument(
        "--no-components", action="store_true", help="CSG meshes without seeds moved onto the surface's small pieces"
    )
    ap.add_argument("--only", default=None, help="comma-separated CSG scene indices to mesh (with --csg)")
    ap.add_argument("--topology", action="store_true", help="only the topology cases (source chi kept or not)")
    ap.add_argument("--cases", default=None, help="comma-separated names of topology cases to run (with --topology)")
    ap.add_argument(
        "--kernels",
        action="store_true",
        help="only the nearest-seed pass and the Lloyd step at --seeds seeds and about alpha x seeds fragments",
    )
    args = ap.parse_args()
    if args.topology:
        print(json.dumps({"load_average_start": os.getloadavg()}), flush=True)
        topology_cases(only=args.cases.split(",") if args.cases else None)
        print(json.dumps({"load_average_end": os.getloadavg()}), flush=True)
        return
    if args.kernels:
        print(json.dumps(kernel_times(args.seeds, args.alpha), indent=1))
        return
    if args.csg:
        print(json.dumps({"load_average_start": os.getloadavg()}), flush=True)
        print(
            json.dumps(
                csg_scenes(
                    args.csg,
                    2000,
                    max_rounds=args.csg_rounds,
                    relax=args.relax,
                    relax_on_source=not args.relax_on_union,
                    components=not args.no_components,
                    only=None if args.only is None else {int(x) for x in args.only.split(",")},
                    alpha=args.alpha,
                ),
                indent=1,
                default=str,
            )
        )
        return
    n = args.seeds
    diag = 2 * HALF * np.sqrt(3)
    out = {
        "seeds": n,
        "alpha_asked": args.alpha,
        "cores": os.cpu_count(),
        "threads": "all",
        "load_average_start": os.getloadavg(),
    }
    ref, _ = mc_mesh(300)  # fine reference surface
    out["reference_vertices"] = len(ref.vertices)

    # fragments, nearest-seed pass, Lloyd step at n seeds
    def remesh_octic(seeds):
        return cvt.remesh(
            octic,
            seeds,
            grid=voxax.Grid.cube(64, half_width=HALF),
            method=args.method,
            steps=args.steps,
            polish=args.polish,
            tol=args.tol,
            polish_tol=args.polish_tol,
            relax=args.relax,
            alpha=args.alpha,
        )

    t, c = time.perf_counter(), time.process_time()
    mesh, rep = remesh_octic(n)
    out["remesh_s"] = time.perf_counter() - t
    out["remesh_cpu_s"] = time.process_time() - c
    out["remesh_times"] = rep["time"]
    out["remesh_cpu_times"] = rep["cpu_time"]
    out["fragments"] = rep["n_fragments"]
    out["alpha"] = rep["alpha"]
    out["optimizer_steps"] = rep["steps"]
    out["polish_steps"] = rep["polish_steps"]
    out["relax_steps"] = rep["relax"]
    out["manifold_rounds"], out["balls"] = rep["rounds"], rep["balls"]
    out["rdt"] = rep["rdt"]._asdict()
    out["cvt"] = summary(mesh, ref, diag)
    frag = cvt.fragments(octic, rep["grid"])
    seeds = cvt.init_seeds(frag, n, 0)
    out["nearest_seed_s"], _ = best_of(lambda: voxax.nearest_neighbors(seeds, frag.points, k=1), 5)
    c = time.process_time()
    voxax.nearest_neighbors(seeds, frag.points, k=1, threads=1)
    out["nearest_seed_1thread_cpu_s"] = time.process_time() - c
    x, w = jax.numpy.asarray(frag.points), jax.numpy.asarray(frag.weights)
    seeds = jax.numpy.asarray(seeds)

    def step(y):
        return grid_lloyd(y, x, w)

    jax.block_until_ready(step(seeds))
    out["lloyd_step_s"], _ = best_of(lambda: jax.block_until_ready(step(seeds)), 5)
    c = time.process_time()
    for _ in range(3):
        jax.block_until_ready(step(seeds))
    out["lloyd_step_cpu_s"] = (time.process_time() - c) / 3
    # the optimiser's own Lloyd steps (search warm-started from the previous step's
    # assignment, moments from the same kernel): 11 steps less 1 step, per step
    y0 = np.asarray(seeds)
    cvt.optimize(frag, y0, method="lloyd", steps=2)
    runs = {}
    for k in (1, 11):
        t, c = time.perf_counter(), time.process_time()
        cvt.optimize(frag, y0, method="lloyd", steps=k)
        runs[k] = (time.perf_counter() - t, time.process_time() - c)
    out["optimizer_lloyd_step_s"] = (runs[11][0] - runs[1][0]) / 10
    out["optimizer_lloyd_step_cpu_s"] = (runs[11][1] - runs[1][1]) / 10

    # marching cubes at about the same vertex count
    best = None
    for cells in range(36, 60, 2):
        m, dt = mc_mesh(cells)
        if best is None or abs(len(m.vertices) - len(mesh.vertices)) < abs(len(best[0].vertices) - len(mesh.vertices)):
            best = (m, dt, cells)
    mc, mc_t, cells = best
    out["mc"] = {"cells": cells, "time_s": mc_t, **summary(mc, ref, diag)}
    out["cvt_vs_mc_qmin"] = out["cvt"]["q_min"] / max(out["mc"]["q_min"], 1e-12)

    if not args.quick:
        import pymeshlab

        fine, _ = mc_mesh(120)
        t = time.perf_counter()
        ms = pymeshlab.MeshSet()
        ms.add_mesh(pymeshlab.Mesh(fine.vertices, fine.faces))
        edge = float(np.mean(np.linalg.norm(mesh.vertices[mesh.faces[:, 0]] - mesh.vertices[mesh.faces[:, 1]], axis=1)))
        ms.meshing_isotropic_explicit_remeshing(targetlen=pymeshlab.PureValue(edge), iterations=10)
        pm = ms.current_mesh()
        rm = voxax.Mesh(pm.vertex_matrix(), pm.face_matrix())
        out["mc_pymeshlab"] = {"time_s": time.perf_counter() - t, "mc_cells": 120, **summary(rm, ref, diag)}

        t = time.perf_counter()
        m2, rep2 = remesh_octic(2 * n)
        out["remesh_2x_s"] = time.perf_counter() - t
        out["t2x_over_t"] = out["remesh_2x_s"] / out["remesh_s"]
        out["cvt_2x"] = {"fragments": rep2["n_fragments"], **summary(m2, ref, diag)}
    out["load_average_end"] = os.getloadavg()
    print(json.dumps(out, indent=1, default=str))


if __name__ == "__main__":
    main()
