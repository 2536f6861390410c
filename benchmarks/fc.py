"""Faithful Contouring: encode + decode on `data.large` against the dense voxelize + isosurface path.

For every mesh size (`--faces`, faces of `voxax.data.large`) and grid size (`--sizes`, n^3
cells over [-1, 1]^3), one fresh process runs

- `fc`: `voxax.fc.encode` then `voxax.fc.decode` (all cores), timed separately (wall clock
  and process CPU time), with the number of tokens (active cells), the time per token and
  the peak resident memory of the process;
- `dense` (up to `--dense-max`): `voxax.voxelize` (float32) then `voxax.isosurface(W, 0.5)`,
  timed the same way, with its peak memory;

and both outputs are compared with the input by the two-sided Hausdorff distance
(`voxax.metrics.hausdorff`, vertices plus `--samples` area samples per surface), reported in
cells. The first call of each path in a process includes one-time costs (JIT compilation of
the dense path, page faults); `--repeats` > 1 reports the best of the later calls.

Usage:

```bash
PYTHONPATH=src python benchmarks/fc.py --faces 100000 1000000 --sizes 256 512 1024 --write-readme
```

`--write-readme` replaces the section between the Faithful Contouring markers in
`benchmarks/README.md`.

`--manifold N ...` encodes and decodes closed meshes (`voxax.data`'s hand, mug, torus, the
100K-face `large`, a 5-subdivision icosphere and the CAD part) at N cells along their longest
side with each `anchors_per_cell` (1, "patches", "components"), side by side in one process
(best of `--repeats`), and counts the output's non-manifold and misoriented edges;
`--report-cost N` times `voxax.fc.roundtrip` at N on the hand against the measures it
took before (`metrics.hausdorff`, `chamfer`, `f_score`, `manifold_report` on the same
output). With `--write-readme` they replace the sections between their own markers.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import re
import subprocess
import sys
import time
from pathlib import Path


def _peak_kib() -> int:
    with open("/proc/self/status") as fh:
        for line in fh:
            if line.startswith("VmHWM:"):
                return int(line.split()[1])
    return 0


def _timed(fn):
    w, c = time.perf_counter(), time.process_time()
    out = fn()
    return time.perf_counter() - w, time.process_time() - c, out


def cad_part():
    """A block with a cylindrical bore and a 45-degree chamfer (manifold3d booleans), turned
    off the grid axes (the part of notebook 08)."""
    import numpy as np
    from manifold3d import Manifold

    import voxax

    block = Manifold.cube([1.2, 0.8, 0.5], center=True)
    bore = Manifold.cylinder(0.8, 0.2, 0.2, 64, center=True).translate([-0.25, 0.0, 0.0])
    cutter = Manifold.cube([1.4, 0.3, 0.3], center=True).rotate([45.0, 0.0, 0.0]).translate([0.0, -0.4, 0.25])
    m = (block - bore - cutter).rotate([12.0, 21.0, 7.0]).to_mesh()
    return voxax.Mesh(np.asarray(m.vert_properties, np.float64)[:, :3], np.asarray(m.tri_verts, np.int32))


def cad_worker(kind: str, n: int, samples: int) -> dict:
    """Fidelity on the CAD part at n cells along its longest side: FC or the dense path."""
    import numpy as np

    import voxax

    mesh = cad_part()
    grid = voxax.Grid.around(mesh.vertices, n)
    h = max(grid.spacing)
    if kind == "cad-fc":
        te, ce, tok = _timed(lambda: voxax.fc.encode(mesh, grid))
        td, cd, out = _timed(lambda: voxax.fc.decode(tok))
        tokens = len(tok)
    else:
        te, ce, W = _timed(lambda: np.asarray(voxax.voxelize(mesh.vertices.astype(np.float32), mesh.faces, grid)))
        td, cd, out = _timed(lambda: voxax.isosurface(W, grid, 0.5).to_mesh())
        tokens = None
    side = max(u - lo for lo, u in zip(grid.lower, grid.upper))
    thr = 0.005 * side
    rep = voxax.metrics.manifold_report(out)
    g128 = voxax.Grid.around(mesh.vertices, 128)
    # |W| >= 0.5: marching cubes' triangles face the other way (towards larger W).
    w_in = np.abs(np.asarray(voxax.voxelize(mesh.vertices, mesh.faces, g128))) >= 0.5
    w_out = np.abs(np.asarray(voxax.voxelize(out.vertices, out.faces, g128))) >= 0.5
    return {
        "kind": kind,
        "faces": mesh.n_faces,
        "n": n,
        "grid": list(grid.shape),
        "tokens": tokens,
        "encode_s": te,
        "decode_s": td,
        "cpu_s": ce + cd,
        "peak_gib": _peak_kib() / 2**20,
        "hausdorff_cells": voxax.metrics.hausdorff(out, mesh, n=samples) / h,
        "chamfer_cells2": voxax.metrics.chamfer(out, mesh, convention="g2p", n=samples, to_surface=True) / h**2,
        "f_score": 100 * voxax.metrics.f_score(out, mesh, thr, n=samples, to_surface=True),
        "iou128": float((w_in & w_out).sum() / max((w_in | w_out).sum(), 1)),
        "nonmanifold_edges": int(rep.n_nonmanifold_edges),
        "boundary_edges": int(rep.n_boundary_edges),
        "edges": int(rep.n_edges),
    }


def worker(kind: str, faces: int, n: int, repeats: int, samples: int) -> dict:
    import numpy as np

    import voxax

    mesh = voxax.data.large(faces)
    grid = voxax.Grid.cube(n)
    h = grid.spacing[0]
    base = _peak_kib()
    row = {"kind": kind, "faces": mesh.n_faces, "n": n}
    best = None
    for _ in range(repeats):
        if kind == "fc":
            te, ce, tok = _timed(lambda: voxax.fc.encode(mesh, grid))
            td, cd, out = _timed(lambda tok=tok: voxax.fc.decode(tok))
            tokens = len(tok)
            del tok
        else:
            v32 = mesh.vertices.astype(np.float32)
            te, ce, W = _timed(lambda v32=v32: np.asarray(voxax.voxelize(v32, mesh.faces, grid)))
            td, cd, iso = _timed(lambda W=W: voxax.isosurface(W, grid, 0.5).to_mesh())
            tokens, out = None, iso
            del W
        t = {"encode_s": te, "decode_s": td, "encode_cpu_s": ce, "decode_cpu_s": cd, "total_s": te + td}
        if best is None or t["total_s"] < best["total_s"]:
            best = t
    row.update(best)
    row["peak_gib"] = _peak_kib() / 2**20
    row["input_gib"] = base / 2**20
    row["tokens"] = tokens
    row["out_faces"] = int(out.n_faces)
    if tokens:
        row["us_per_token"] = 1e6 * row["total_s"] / tokens
    row["hausdorff_cells"] = voxax.metrics.hausdorff(out, mesh, n=samples) / h
    return row


def _closed_meshes():
    import voxax

    meshes = {name: voxax.data.get(name) for name in ("hand", "mug", "torus")}
    meshes["large (100K)"] = voxax.data.large(100_000)
    meshes["icosphere(5)"] = voxax.data.icosphere(5)
    try:
        meshes["CAD part"] = cad_part()
    except ImportError:
        pass
    return meshes


def manifold_rows(sizes, repeats, only=None):
    """Time and output topology of each `anchors_per_cell` on closed meshes (those named in
    `only`, or all)."""
    import voxax

    lines = [
        "| mesh | faces | grid | anchors_per_cell | tokens | encode + decode (CPU) | non-manifold edges | "
        "misoriented edges | closed 2-manifold | Euler characteristic (input) |",
        "|---|---|---|---|---|---|---|---|---|---|",
    ]
    for name, mesh in _closed_meshes().items():
        if only and name not in only:
            continue
        chi = voxax.fc.edge_topology(mesh).euler_characteristic
        for n in sizes:
            grid = voxax.Grid.around(mesh.vertices, n)
            voxax.fc.decode(voxax.fc.encode(mesh, voxax.Grid.around(mesh.vertices, 8)))  # warm
            for mode in (1, "patches", "components"):
                best = None
                for _ in range(repeats):
                    w, c = time.perf_counter(), time.process_time()
                    tok = voxax.fc.encode(mesh, grid, anchors_per_cell=mode)
                    out = voxax.fc.decode(tok)
                    t = (time.perf_counter() - w, time.process_time() - c)
                    best = t if best is None or t[0] < best[0] else best
                topo = voxax.fc.edge_topology(out)
                ok = "yes" if topo.closed and topo.oriented else "no"
                lines.append(
                    f"| {name} | {mesh.n_faces:,} | {'x'.join(map(str, grid.shape))} | {mode!r} | {len(tok):,} | "
                    f"{best[0]:.2f} s ({best[1]:.2f} s) | {topo.n_nonmanifold_edges} | {topo.n_misoriented_edges} | "
                    f"{ok} | {topo.euler_characteristic} ({chi}) |"
                )
                print(lines[-1], flush=True)
    return lines


def report_cost_rows(n, samples):
    """`voxax.fc.roundtrip` at n on the hand, and the measures it took before on its output."""
    import warnings

    import voxax

    mesh = voxax.data.hand()
    grid = voxax.Grid.around(mesh.vertices, n)
    voxax.fc.roundtrip(mesh, 8, samples=100, progress=False)  # warm
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        w, c = time.perf_counter(), time.process_time()
        out, rep = voxax.fc.roundtrip(mesh, grid=grid, samples=samples, progress=False)
        now = (time.perf_counter() - w, time.process_time() - c)
    m = voxax.metrics
    w, c = time.perf_counter(), time.process_time()
    hd = m.hausdorff(out, mesh, n=samples)
    cd = m.chamfer(out, mesh, convention="g2p", n=samples, to_surface=True)
    fs = m.f_score(out, mesh, rep.threshold, n=samples, to_surface=True)
    t_metrics = (time.perf_counter() - w, time.process_time() - c)
    w, c = time.perf_counter(), time.process_time()
    mr = m.manifold_report(out)
    t_manifold = (time.perf_counter() - w, time.process_time() - c)
    same = (hd, cd, fs) == (rep.hausdorff, rep.chamfer_g2p, rep.f_score) and all(
        getattr(rep.manifold, f) == getattr(mr, f)
        for f in ("n_edges", "n_nonmanifold_edges", "n_misoriented_edges", "n_boundary_loops", "n_components")
    )
    enc_dec = rep.encode_seconds + rep.decode_seconds
    return [
        f"The hand ({mesh.n_faces:,} faces) at {'x'.join(map(str, grid.shape))}: {rep.tokens:,} tokens, "
        f"{out.n_faces:,} output faces, {samples:,} samples per surface; the same values both ways: {same}.",
        "",
        "| step | wall (CPU) |",
        "|---|---|",
        f"| encode + decode | {enc_dec:.2f} s |",
        f"| roundtrip's measures now (one BVH per mesh, `fc.edge_topology`) | {rep.measure_seconds:.2f} s |",
        f"| roundtrip in all | {now[0]:.2f} s ({now[1]:.2f} s) |",
        f"| before: `metrics.hausdorff` + `chamfer` + `f_score` (7 BVH builds) | {t_metrics[0]:.2f} s "
        f"({t_metrics[1]:.2f} s) |",
        f"| before: `metrics.manifold_report` | {t_manifold[0]:.2f} s ({t_manifold[1]:.2f} s) |",
    ]


def _write_section(key, title, argv, lines):
    with open("/proc/loadavg") as fh:
        load = fh.read().split()[:3]
    machine = f"{platform.machine()}, {os.cpu_count()} CPUs, Python {platform.python_version()}"
    cmd = "python benchmarks/fc.py " + " ".join(argv if argv is not None else sys.argv[1:])
    start, end = f"<!-- {key}:start -->", f"<!-- {key}:end -->"
    body = f"{start}\n\nMachine: {machine}; load average at the end {', '.join(load)}. Command: `{cmd}`.\n\n"
    body += "\n".join(lines) + f"\n\n{end}"
    readme = Path(__file__).with_name("README.md")
    old = readme.read_text()
    if start in old:
        new = re.sub(re.escape(start) + ".*?" + re.escape(end), lambda _: body, old, flags=re.DOTALL)
    else:
        new = old.rstrip() + f"\n\n### {title}\n\n" + body + "\n"
    readme.write_text(new)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--faces", type=int, nargs="+", default=[100_000])
    ap.add_argument("--sizes", type=int, nargs="+", default=[256, 512])
    ap.add_argument("--dense-max", type=int, default=512, help="largest grid for the dense path")
    ap.add_argument("--repeats", type=int, default=1)
    ap.add_argument("--samples", type=int, default=20_000)
    ap.add_argument("--write-readme", action="store_true")
    ap.add_argument("--cad", type=int, default=0, metavar="N", help="only the CAD part's fidelity at N cells")
    ap.add_argument("--manifold", type=int, nargs="+", metavar="N", help="only the anchors' topology at N cells")
    ap.add_argument("--meshes", nargs="+", help="with --manifold: only these meshes (e.g. 'CAD part')")
    ap.add_argument("--report-cost", type=int, metavar="N", help="only the cost of roundtrip's report at N cells")
    ap.add_argument("--worker", nargs=3, metavar=("KIND", "FACES", "N"), help=argparse.SUPPRESS)
    args = ap.parse_args(argv)
    if args.worker:
        kind, faces, n = args.worker
        if kind.startswith("cad"):
            print(json.dumps(cad_worker(kind, int(n), args.samples)), flush=True)
        else:
            print(json.dumps(worker(kind, int(faces), int(n), args.repeats, args.samples)), flush=True)
        return 0
    if args.manifold:
        lines = manifold_rows(args.manifold, args.repeats, args.meshes)
        print("\n".join(lines))
        if args.write_readme:
            _write_section("fc-manifold", "Faithful Contouring: closed meshes, anchors per cell", argv, lines)
        return 0
    if args.report_cost:
        lines = report_cost_rows(args.report_cost, args.samples)
        print("\n".join(lines))
        if args.write_readme:
            _write_section("fc-report", "Faithful Contouring: the cost of roundtrip's report", argv, lines)
        return 0
    if args.cad:
        lines = [
            "| part | grid | path | tokens | time (CPU) | Hausdorff | Chamfer G->P | F@0.01 | IoU at 128^3 | "
            "non-manifold edges |",
            "|---|---|---|---|---|---|---|---|---|---|",
        ]
        for kind in ("cad-fc", "cad-dense"):
            cmd = [sys.executable, __file__, "--worker", kind, "0", str(args.cad), "--samples", str(args.samples)]
            proc = subprocess.run(cmd, capture_output=True, text=True)
            if proc.returncode != 0:
                print(f"{kind} failed:\n{proc.stderr[-2000:]}", flush=True)
                continue
            r = json.loads(proc.stdout.strip().splitlines()[-1])
            print(json.dumps(r), flush=True)
            name = "FC encode + decode" if kind == "cad-fc" else "voxelize + isosurface"
            tok = f"{r['tokens']:,}" if r["tokens"] else "-"
            lines.append(
                f"| {r['faces']} faces | {'x'.join(map(str, r['grid']))} | {name} | {tok} | "
                f"{r['encode_s'] + r['decode_s']:.2f} s ({r['cpu_s']:.2f} s) | {r['hausdorff_cells']:.3f} h | "
                f"{r['chamfer_cells2']:.2e} h^2 | {r['f_score']:.3f} | {r['iou128']:.5f} | "
                f"{r['nonmanifold_edges']} of {r['edges']:,} |"
            )
        print("\n".join(lines))
        return 0
    with open("/proc/loadavg") as fh:
        load_start = fh.read().split()[:3]
    rows = []
    for faces in args.faces:
        for n in args.sizes:
            for kind in ("fc", "dense"):
                if kind == "dense" and n > args.dense_max:
                    continue
                cmd = [
                    sys.executable,
                    __file__,
                    "--worker",
                    kind,
                    str(faces),
                    str(n),
                    "--repeats",
                    str(args.repeats),
                    "--samples",
                    str(args.samples),
                ]
                proc = subprocess.run(cmd, capture_output=True, text=True)
                if proc.returncode != 0:
                    print(f"{kind} {faces} {n}^3 failed:\n{proc.stderr[-2000:]}", flush=True)
                    rows.append({"kind": kind, "faces": faces, "n": n, "failed": proc.stderr.strip().splitlines()[-1:]})
                    continue
                row = json.loads(proc.stdout.strip().splitlines()[-1])
                rows.append(row)
                print(json.dumps(row), flush=True)
    table = [
        "| faces | grid | path | tokens | encode | decode | total (CPU) | us / token (CPU) | peak memory | Hausdorff |",
        "|---|---|---|---|---|---|---|---|---|---|",
    ]
    for r in rows:
        if "failed" in r:
            table.append(f"| {r['faces']} | {r['n']}^3 | {r['kind']} | failed: {' '.join(r['failed'])} | | | | | | |")
            continue
        name = "FC encode + decode" if r["kind"] == "fc" else "voxelize + isosurface"
        tok = f"{r['tokens']:,}" if r["tokens"] else "-"
        cpu = r["encode_cpu_s"] + r["decode_cpu_s"]
        per = f"{r['us_per_token']:.2f} ({1e6 * cpu / r['tokens']:.2f})" if r.get("us_per_token") else "-"
        table.append(
            f"| {r['faces']:,} | {r['n']}^3 | {name} | {tok} | {r['encode_s']:.2f} s | {r['decode_s']:.2f} s | "
            f"{r['total_s']:.2f} s ({cpu:.2f} s) | {per} | {r['peak_gib']:.2f} GiB | {r['hausdorff_cells']:.3f} h |"
        )
    text = "\n".join(table)
    print(text)
    if args.write_readme:
        with open("/proc/loadavg") as fh:
            load = fh.read().split()[:3]
        machine = f"{platform.machine()}, {os.cpu_count()} CPUs, Python {platform.python_version()}"
        cmd = "python benchmarks/fc.py " + " ".join(argv if argv is not None else sys.argv[1:])
        start, end = "<!-- fc-results:start -->", "<!-- fc-results:end -->"
        body = (
            f"{start}\n\nMachine: {machine}; load average at the start {', '.join(load_start)}, at the end "
            f"{', '.join(load)} (the machine is shared, "
            f"so wall times are inflated; the CPU column is the process CPU time). Command: `{cmd}`.\n\n"
            f"{text}\n\n{end}"
        )
        readme = Path(__file__).with_name("README.md")
        old = readme.read_text()
        if start in old:
            new = re.sub(re.escape(start) + ".*?" + re.escape(end), lambda _: body, old, flags=re.DOTALL)
        else:
            new = (
                old.rstrip()
                + "\n\n## Faithful Contouring: encode + decode against voxelize + isosurface\n\n"
                + "`fc.py` encodes `data.large` into Faithful Contour Tokens and decodes them, and runs the dense "
                + "path `voxelize` + `isosurface` on the same grid; see its docstring.\n\n"
                + body
                + "\n"
            )
        readme.write_text(new)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
