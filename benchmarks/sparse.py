"""Sparse versus dense voxelization: time and peak memory as the grid grows.

    nice -n 10 python benchmarks/sparse.py [--sizes 256 512 1024] [--sparse-only 2048 4096]
                                           [--faces 100000] [--json out.json]

Every measurement runs in a fresh subprocess (so peak memory is its own): the mesh is
`voxax.data.large(faces)` (a trefoil tube, max |v| = 0.75) on `Grid.cube(n)`.

- `sparse` and `dense` at each of `--sizes` in float32: `voxax.voxelize_sparse` and
  `voxax.voxelize` (the second of two calls, so without compilation), with the peak
  resident memory the call adds (VmHWM reset before it).
- `sparse` alone at each of `--sparse-only` in float64 (one call, compilation included),
  with the enclosed volume against the mesh's exact volume (sum of signed tetrahedra).

Reported per boundary cell: time and added peak memory, which stay near constant when the
cost grows with the surface.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import time

HERE = os.path.dirname(os.path.abspath(__file__))

_WORKER = r"""
import json, sys, time
sys.path.insert(0, {here!r})
import numpy as np
import jax
jax.config.update("jax_enable_x64", True)
import voxax
from _common import proc_status_kib, reset_peak_rss

kind, n, dtype, faces, repeat = {kind!r}, {n}, {dtype!r}, {faces}, {repeat}
mesh = voxax.data.large(faces)
V = np.asarray(mesh.vertices, dtype)
F = np.asarray(mesh.faces, np.int32)
grid = voxax.Grid.cube(n)
fn = (lambda: voxax.voxelize_sparse(V, F, grid)) if kind == "sparse" else (lambda: voxax.voxelize(V, F, grid))
out = {{}}
for rep in range(repeat):
    res = None
    rss0 = proc_status_kib("VmRSS")
    reset_peak_rss()
    t0 = time.perf_counter()
    res = fn()
    jax.block_until_ready(res)
    dt = time.perf_counter() - t0
    peak = proc_status_kib("VmHWM")
    out = dict(seconds=dt, peak_added_mib=(peak - rss0) / 1024, peak_mib=peak / 1024)
    if kind == "sparse":
        out["boundary_cells"] = int(res.counts[0])
        out["runs"] = int(res.counts[1])
        out["nbytes_mib"] = res.nbytes / 2**20
        vol = float(res.volume())
    else:
        out["nbytes_mib"] = res.size * res.dtype.itemsize / 2**20
        vol = float(res.sum(dtype=np.float64) * grid.voxel_volume)
    if rep + 1 < repeat:
        del res
res = None
a, b, c = (np.asarray(mesh.vertices, np.float64)[np.asarray(mesh.faces)[:, k]] for k in range(3))
exact = float(np.einsum("ij,ij->i", a, np.cross(b, c)).sum() / 6)
out.update(volume=vol, exact_volume=exact, volume_rel_error=abs(vol - exact) / abs(exact), faces=int(len(F)))
print("RESULT " + json.dumps(out), flush=True)
"""


def measure(kind, n, dtype, faces, repeat, timeout):
    code = _WORKER.format(here=HERE, kind=kind, n=n, dtype=dtype, faces=faces, repeat=repeat)
    t0 = time.perf_counter()
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=timeout)
    for line in proc.stdout.splitlines():
        if line.startswith("RESULT "):
            out = json.loads(line[7:])
            out.update(kind=kind, n=n, dtype=dtype, wall=time.perf_counter() - t0)
            return out
    return dict(kind=kind, n=n, dtype=dtype, error=(proc.stderr or proc.stdout)[-2000:])


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--sizes", type=int, nargs="*", default=[256, 512, 1024])
    ap.add_argument("--sparse-only", type=int, nargs="*", default=[2048, 4096])
    ap.add_argument("--faces", type=int, default=100_000)
    ap.add_argument("--timeout", type=float, default=1800)
    ap.add_argument("--json")
    args = ap.parse_args(argv)
    rows = []
    for n in args.sizes:
        for kind in ("sparse", "dense"):
            rows.append(measure(kind, n, "float32", args.faces, 2, args.timeout))
            print(json.dumps(rows[-1]), flush=True)
    for n in args.sparse_only:
        rows.append(measure("sparse", n, "float64", args.faces, 1, args.timeout))
        print(json.dumps(rows[-1]), flush=True)
    print()
    print("| n^3 | kind | dtype | time (s) | peak added (MiB) | result (MiB) | boundary cells | runs "
          "| us / cell | bytes / cell | volume rel. error |")
    print("|---|---|---|---|---|---|---|---|---|---|---|")
    for r in rows:
        if "error" in r:
            print(f"| {r['n']} | {r['kind']} | {r['dtype']} | failed: {r['error'].splitlines()[-1][:80]} |")
            continue
        cells = r.get("boundary_cells")
        per_t = f"{r['seconds'] / cells * 1e6:.3f}" if cells else "-"
        per_b = f"{r['peak_added_mib'] * 2**20 / cells:.0f}" if cells else "-"
        print(f"| {r['n']} | {r['kind']} | {r['dtype']} | {r['seconds']:.2f} | {r['peak_added_mib']:.0f} "
              f"| {r['nbytes_mib']:.0f} | {cells or '-'} | {r.get('runs', '-')} | {per_t} | {per_b} "
              f"| {r['volume_rel_error']:.1e} |")
    if args.json:
        with open(args.json, "w") as fh:
            json.dump(rows, fh, indent=1)


if __name__ == "__main__":
    main()
