"""Remeshing a closed surface mesh: `voxax.cvt.remesh` against pymeshlab's isotropic remeshing
and gpytoolbox's `remesh_botsch`.

All remesh the same closed input at about the same vertex count: voxax with `n_seeds`
vertices; pymeshlab's `meshing_isotropic_explicit_remeshing` and gpytoolbox's
`remesh_botsch` (both Botsch-Kobbelt split / collapse / flip / smooth remeshing, 10
iterations, with projection onto the input) with a target edge length calibrated per
library (untimed, before the timed calls) so that its output has about that many vertices.
All run on the same cores (`os.sched_setaffinity`, `--threads` of them), with
`VOXAX_NUM_THREADS`, `threads=` and `OMP_NUM_THREADS` set to that count (the two peers use
one thread whatever the count). For every size the first `remesh` call in the process
(compilation included) is timed apart, then the calls alternate (voxax, pymeshlab,
gpytoolbox, voxax, ...) `--repeat` times and the medians are reported, with the load
average before and after. A peer that is not installed is left out (`--peers`). Quality: vertices, Euler characteristic, closed
2-manifold, Q min / Q mean (`voxax.metrics.triangle_quality`), the two-sided Hausdorff
distance to the source (`voxax.metrics.hausdorff`) in % of the source's bounding-box
diagonal.

Sources (generated in code; no mesh file is read):

- `bumpy`: a bumpy sphere, `data.icosphere(6)` (40,962 vertices) with its radius modulated;
  well-shaped triangles.
- `scan`: the same bumpy solid as marching cubes on a 128^3 grid (about 37k vertices,
  slivers as in scanned or voxel-derived meshes: Q min about 0.01).
- `knot`: `data.large(80_000)`, a tube around a trefoil knot (chi 0).

    PYTHONPATH=src python benchmarks/remesh_peers.py [--sources bumpy,scan,knot] [--sizes 1000,5000,20000]
        [--repeat 3] [--threads 2] [--json out.json]
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import sys
import time


def _pin(threads: int) -> None:
    cores = sorted(os.sched_getaffinity(0))[:threads]
    os.sched_setaffinity(0, set(cores))
    for name in ("VOXAX_NUM_THREADS", "OMP_NUM_THREADS"):
        os.environ[name] = str(threads)


def _radius(x, y, z):
    import numpy as np

    return 1.0 + 0.12 * np.sin(3 * x + 1) * np.sin(4 * y) * np.cos(3 * z + 0.5) + 0.06 * np.cos(7 * x - 5 * z)


def source(name: str):
    import numpy as np

    import voxax

    if name == "bumpy":
        m = voxax.data.icosphere(6)
        v = np.asarray(m.vertices)
        return voxax.Mesh(v * _radius(*v.T)[:, None], np.asarray(m.faces))
    if name == "scan":
        g = voxax.Grid.cube(128, half_width=1.3)
        p = g.centers().reshape(-1, 3)
        r = np.linalg.norm(p, axis=1)
        u = p / np.maximum(r, 1e-12)[:, None]
        w = (r - _radius(*u.T)).reshape(g.shape)
        iso = voxax.isosurface(w, g, 0.0)
        return voxax.Mesh(np.asarray(iso.vertices), np.asarray(iso.faces))
    if name == "knot":
        return voxax.data.large(80_000)
    raise SystemExit(f"unknown source {name!r}")


def summary(mesh, src, diag: float, hausdorff_n: int) -> dict:
    from voxax import metrics

    q = metrics.triangle_quality(mesh)
    mr = metrics.manifold_report(mesh)
    return {
        "vertices": int(mesh.n_vertices),
        "chi": int(mr.euler_characteristic),
        "closed_manifold": bool(mr.closed and mr.edge_manifold and mr.vertex_manifold),
        "q_min": float(q.min()),
        "q_mean": float(q.mean()),
        "hausdorff_pct": 100.0 * metrics.hausdorff(mesh, src, n=hausdorff_n) / diag,
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--sources", default="bumpy,scan,knot")
    ap.add_argument("--sizes", default="1000,5000,20000")
    ap.add_argument("--repeat", type=int, default=3, help="interleaved timed calls per library and size")
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--iterations", type=int, default=10, help="the peers' remeshing iterations")
    ap.add_argument("--peers", default="pymeshlab,gpytoolbox", help="peers to run, of pymeshlab,gpytoolbox")
    ap.add_argument("--hausdorff-n", type=int, default=200_000)
    ap.add_argument("--json", default=None, help="write the results here")
    args = ap.parse_args()
    _pin(args.threads)

    import jax

    jax.config.update("jax_enable_x64", True)
    import numpy as np

    import voxax
    from voxax import cvt, metrics

    def voxax_call(src, n):
        return cvt.remesh(src, n, threads=args.threads, progress=False)

    peers, versions = {}, {}
    wanted = [p for p in args.peers.split(",") if p]
    if "pymeshlab" in wanted:
        try:
            import pymeshlab
        except ImportError:
            print("pymeshlab is not installed: left out", flush=True)
        else:

            def pml_call(v, f, edge):
                ms = pymeshlab.MeshSet()
                ms.add_mesh(pymeshlab.Mesh(v, f))
                ms.meshing_isotropic_explicit_remeshing(targetlen=pymeshlab.PureValue(edge),
                                                        iterations=args.iterations)
                pm = ms.current_mesh()
                return voxax.Mesh(pm.vertex_matrix(), pm.face_matrix())

            peers["pymeshlab"] = pml_call
            versions["pymeshlab"] = getattr(pymeshlab, "__version__", "?")
    if "gpytoolbox" in wanted:
        try:
            import gpytoolbox
        except ImportError:
            print("gpytoolbox is not installed: left out", flush=True)
        else:

            def gpy_call(v, f, edge):
                vo, fo = gpytoolbox.remesh_botsch(np.array(v), np.array(f), i=args.iterations, h=edge, project=True)
                return voxax.Mesh(np.asarray(vo), np.asarray(fo))

            peers["gpytoolbox"] = gpy_call
            versions["gpytoolbox"] = getattr(gpytoolbox, "__version__", "?")

    out = {"threads": args.threads, "cores": sorted(os.sched_getaffinity(0)), "load_start": os.getloadavg(),
           "python": sys.version.split()[0], **versions, "runs": []}
    print(f"load average at the start: {out['load_start']}, cores {out['cores']}", flush=True)
    print("| source | size | library | vertices | chi | closed 2-manifold | Q min | Q mean | dH (% diag) | "
          "first call | later calls (median) | ratio voxax / peer |")
    print("|---|---|---|---|---|---|---|---|---|---|---|---|")
    for name in args.sources.split(","):
        src = source(name)
        v, f = np.asarray(src.vertices, np.float64), np.asarray(src.faces, np.int32)
        diag = float(np.linalg.norm(v.max(0) - v.min(0)))
        area = float(0.5 * np.linalg.norm(np.cross(v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]]), axis=1).sum())
        src_q = metrics.triangle_quality(src)
        print(f"source {name}: {len(v)} vertices, {len(f)} faces, chi {metrics.euler_characteristic(src)}, "
              f"Q min {src_q.min():.3f}, Q mean {src_q.mean():.3f}", flush=True)
        for n in (int(s) for s in args.sizes.split(",")):
            # each peer's target edge: from the area (equilateral triangles, F = 2V), then
            # corrected twice by the vertex count it gave (untimed)
            edges = {}
            for lib, call in peers.items():
                edge = float(np.sqrt(4.0 * area / (np.sqrt(3.0) * 2 * n)))
                for _ in range(2):
                    edge *= float(np.sqrt(call(v, f, edge).n_vertices / n))
                edges[lib] = edge
            t = time.perf_counter()
            vm, vrep = voxax_call(src, n)
            first = time.perf_counter() - t
            tv, tp, results = [], {lib: [] for lib in peers}, {}
            for _ in range(args.repeat):
                t = time.perf_counter()
                vm, vrep = voxax_call(src, n)
                tv.append(time.perf_counter() - t)
                for lib, call in peers.items():
                    t = time.perf_counter()
                    results[lib] = call(v, f, edges[lib])
                    tp[lib].append(time.perf_counter() - t)
            sv = summary(vm, src, diag, args.hausdorff_n)
            mv = statistics.median(tv)
            run = {"source": name, "size": n, "voxax": {**sv, "first_s": first, "times_s": tv, "median_s": mv,
                                                         "stages_s": dict(vrep.time), "cpu_s": dict(vrep.cpu_time),
                                                         "fragments": vrep.n_fragments,
                                                         "steps": vrep.steps, "polish_steps": vrep.polish_steps,
                                                         "rounds": vrep.rounds}}
            rows = [("voxax", sv, f"{first:.2f} s", mv, "")]
            for lib in peers:
                sp, mp = summary(results[lib], src, diag, args.hausdorff_n), statistics.median(tp[lib])
                run[lib] = {**sp, "edge": edges[lib], "times_s": tp[lib], "median_s": mp}
                rows.append((lib, sp, "-", mp, f"{mv / mp:.2f}"))
            run["load"] = os.getloadavg()
            out["runs"].append(run)
            for lib, s, fc, med, ratio in rows:
                print(f"| {name} | {n} | {lib} | {s['vertices']} | {s['chi']} | "
                      f"{'yes' if s['closed_manifold'] else 'no'} | {s['q_min']:.3f} | {s['q_mean']:.3f} | "
                      f"{s['hausdorff_pct']:.3f} | {fc} | {med:.2f} s | {ratio} |", flush=True)
            st = {k: round(x, 2) for k, x in vrep.time.items()}
            peer_times = "; ".join(f"{lib} {[round(x, 2) for x in tp[lib]]}" for lib in peers)
            print(f"  voxax stages (last call) {st}, {vrep.n_fragments} fragments, L-BFGS {vrep.steps}, "
                  f"polish {vrep.polish_steps}, "
                  f"rounds {vrep.rounds}; times voxax {[round(x, 2) for x in tv]}; {peer_times}; "
                  f"load {os.getloadavg()}", flush=True)
    out["load_end"] = os.getloadavg()
    print(f"load average at the end: {out['load_end']}", flush=True)
    if args.json:
        with open(args.json, "w") as fh:
            json.dump(out, fh, indent=1)


if __name__ == "__main__":
    main()
