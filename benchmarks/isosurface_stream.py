"""Marching cubes on large grids: peak memory and time of the eager `voxax.isosurface`.

The eager path sweeps grids larger than 2^24 cells slab by slab (x planes), so it should hold
no more than the input, the output and O(one slab). Each size runs in a fresh subprocess,
which builds the float32 sphere field `|x| - 0.6` on `Grid.cube(n)` plane by plane (no
temporaries of the grid's size), then reads its resident set (`VmRSS`) before the input
exists, after it exists, and the peak (`VmHWM`, reset through `/proc/self/clear_refs` before
each call) while `voxax.isosurface` runs. Reported: the peak minus the resident set before
the input (interpreter, JAX, libraries), against input + output bytes (vertices, faces and
edges of the `IsoMesh`), wall and CPU time. At the largest size but one, the result of the
default slabs is asserted bit-identical to one sweep over the whole grid (`planes` covering
every plane); at every size, chi = V - F/2 = 2 (closed sphere).

Usage:

```bash
PYTHONPATH=src python benchmarks/isosurface_stream.py --sizes 512 1024 [--close]
```
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import subprocess
import sys
import time


def status(key):
    with open("/proc/self/status") as fh:
        for line in fh:
            if line.startswith(key + ":"):
                return int(line.split()[1]) * 1024
    raise KeyError(key)


def reset_peak():
    with open("/proc/self/clear_refs", "w") as fh:
        fh.write("5")


def cpu():
    r = resource.getrusage(resource.RUSAGE_SELF)
    return r.ru_utime + r.ru_stime


def child(n, close, check):
    import jax

    jax.config.update("jax_enable_x64", True)
    import numpy as np

    import voxax
    from voxax._isosurface.stream import _isosurface_streamed

    # warm up the compiled interpolation on a small grid (not timed)
    voxax.isosurface(np.linalg.norm(voxax.Grid.cube(16).centers(), axis=-1) - 0.6, voxax.Grid.cube(16))
    grid = voxax.Grid.cube(n)
    base = status("VmRSS")
    x = ((np.arange(n) + 0.5) * (2.0 / n) - 1.0).astype(np.float32)
    f = np.empty((n, n, n), np.float32)
    yz = x[:, None] ** 2 + x[None, :] ** 2
    for i in range(n):
        np.sqrt(x[i] ** 2 + yz, out=f[i])
        f[i] -= np.float32(0.6)
    del yz
    with_input = status("VmRSS")
    out = {"n": n, "close": close, "base": base, "with_input": with_input, "input": f.nbytes}
    reset_peak()
    t0, c0 = time.perf_counter(), cpu()
    iso = voxax.isosurface(f, grid, 0.0, close=close)
    iso.vertices.block_until_ready()
    out["wall"] = time.perf_counter() - t0
    out["cpu"] = cpu() - c0
    out["peak"] = status("VmHWM")
    out["output"] = int(iso.vertices.nbytes + iso.faces.nbytes + iso.edges.nbytes)
    nv, nf = int(iso.n_vertices), int(iso.n_faces)
    out["vertices"], out["faces"] = nv, nf
    out["chi"] = nv - nf // 2
    assert out["chi"] == 2 and nf % 2 == 0, out
    if check:
        t0 = time.perf_counter()
        one = _isosurface_streamed(f, grid, 0.0, "below", close, planes=10**9)
        out["one_sweep_wall"] = time.perf_counter() - t0
        for name in ("vertices", "faces", "edges", "n_vertices", "n_faces", "min_gap"):
            a, b = np.asarray(getattr(iso, name)), np.asarray(getattr(one, name))
            assert a.shape == b.shape and a.tobytes() == b.tobytes(), name
        out["bit_identical"] = True
    print("RESULT " + json.dumps(out), flush=True)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--sizes", type=int, nargs="+", default=[512, 1024])
    ap.add_argument("--close", action="store_true", help="also run with close=True")
    ap.add_argument("--child", type=int, default=None, help=argparse.SUPPRESS)
    ap.add_argument("--child-close", action="store_true", help=argparse.SUPPRESS)
    ap.add_argument("--child-check", action="store_true", help=argparse.SUPPRESS)
    args = ap.parse_args(argv)
    if args.child is not None:
        child(args.child, args.child_close, args.child_check)
        return
    gib = 1 << 30
    rows = []
    for n in args.sizes:
        for close in [False, True] if args.close else [False]:
            cmd = [sys.executable, __file__, "--child", str(n)]
            if close:
                cmd.append("--child-close")
            if n != max(args.sizes) and not close:
                cmd.append("--child-check")
            with open("/proc/loadavg") as fh:
                load = fh.read().split()[:3]
            res = subprocess.run(cmd, capture_output=True, text=True, env=os.environ)
            line = [s for s in res.stdout.splitlines() if s.startswith("RESULT ")]
            if res.returncode or not line:
                print(res.stdout, res.stderr, file=sys.stderr)
                raise SystemExit(f"child for {n}^3 failed")
            r = json.loads(line[0][7:])
            r["load"] = " ".join(load)
            rows.append(r)
            extra = r["peak"] - r["base"] - r["input"] - r["output"]
            print(
                f"{n}^3 close={close}: faces {r['faces']}, wall {r['wall']:.2f} s, cpu {r['cpu']:.2f} s, "
                f"peak - base {(r['peak'] - r['base']) / gib:.3f} GiB, input {r['input'] / gib:.3f} GiB, "
                f"output {r['output'] / gib:.3f} GiB, extra {extra / gib:.3f} GiB"
                + (f", one sweep {r['one_sweep_wall']:.2f} s, bit-identical" if "bit_identical" in r else "")
                + f" (load before: {r['load']})",
                flush=True,
            )
    print(
        "| grid | close | faces | wall | CPU | peak - base | input | output | peak - base - input - output | load before |"
    )
    print("|---|---|---|---|---|---|---|---|---|---|")
    for r in rows:
        extra = r["peak"] - r["base"] - r["input"] - r["output"]
        print(
            f"| {r['n']}^3 | {r['close']} | {r['faces']:,} | {r['wall']:.2f} s | {r['cpu']:.2f} s | "
            f"{(r['peak'] - r['base']) / gib:.3f} GiB | {r['input'] / gib:.3f} GiB | {r['output'] / gib:.3f} GiB | "
            f"{extra / 2**20:.0f} MiB | {r['load']} |"
        )


if __name__ == "__main__":
    main()
