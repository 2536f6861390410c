"""Memory stress test: thousands of consecutive jit-compiled forward + backward calls.

    PYTHONPATH=src python benchmarks/stress.py [--calls 10000] [--every 100] [--json out.json]

Cycles through a few set-ups (different meshes, face counts, grids, 2D and 3D, one
`vmap`-ed batch), each a `jax.jit(jax.value_and_grad(...))` of `sum(C * voxelize(v))`, and
calls them one after the other with freshly perturbed vertices on every call, so the
compiled executables are reused (cache hits) while the inputs always change. The resident
set size (VmRSS) is sampled every `--every` calls; the script prints the trend (start, end,
peak, least-squares slope per 1000 calls after the warm-up) and writes it, with all
samples, to JSON. A leak of even a few hundred bytes per call shows up as a positive slope.
"""

from __future__ import annotations

import argparse
import ctypes
import gc
import json
import os
import platform
import sys
import time
from pathlib import Path

import jax

jax.config.update("jax_enable_x64", True)

import jax.numpy as jnp  # noqa: E402
import numpy as np  # noqa: E402

import voxax  # noqa: E402
from voxax import Grid  # noqa: E402


def rss_mib() -> float:
    with open("/proc/self/status") as fh:
        for line in fh:
            if line.startswith("VmRSS:"):
                return int(line.split()[1]) / 1024
    raise RuntimeError("no VmRSS in /proc/self/status")


def trim() -> None:
    gc.collect()
    try:
        ctypes.CDLL("libc.so.6").malloc_trim(0)
    except (OSError, AttributeError):
        pass


def setups(rng):
    """(name, jitted value_and_grad, base vertices, noise scale) tuples."""
    out = []

    def add(name, v, f, grid, dtype=np.float64, batch=None):
        v = np.asarray(v, dtype)
        f = np.asarray(f, np.int32)
        cot = jnp.asarray(rng.normal(size=((batch,) if batch else ()) + grid.shape), dtype)

        def loss(x):
            W = jax.vmap(lambda y: voxax.voxelize(y, f, grid))(x) if batch else voxax.voxelize(x, f, grid)
            return jnp.sum(cot * W)

        base = np.stack([v] * batch) if batch else v
        out.append((name, jax.jit(jax.value_and_grad(loss)), base))

    ico = voxax.data.icosphere(2)
    add("icosphere(2) 320 faces, 16^3", 0.7 * ico.vertices, ico.faces, Grid.cube(16))
    torus = voxax.data.torus()
    add("torus 2304 faces, 20^3", torus.vertices, torus.faces, Grid.cube(20))
    ico3 = voxax.data.icosphere(3)
    add("icosphere(3) 1280 faces, 24x20x22 float32", 0.6 * ico3.vertices, ico3.faces,
        Grid((-0.9, -0.8, -0.85), (0.9, 0.8, 0.85), (24, 20, 22)), dtype=np.float32)
    add("icosphere(2) x4 vmap, 16^3", 0.6 * ico.vertices, ico.faces, Grid.cube(16), batch=4)
    circ = voxax.data.circle_polyline(64)
    add("circle 64 segments, 2D 64x48", circ.vertices, circ.faces, Grid((-0.8, -0.6), (0.8, 0.6), (64, 48)))
    return out


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--calls", type=int, default=10_000)
    parser.add_argument("--every", type=int, default=100, help="sample RSS every N calls")
    parser.add_argument("--warmup", type=int, default=500, help="calls excluded from the slope")
    parser.add_argument("--json", default=str(Path(__file__).resolve().parent / "results" / "stress.json"))
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args(argv)

    rng = np.random.default_rng(args.seed)
    cases = setups(rng)
    # Compile everything first: the compiled executables are part of the baseline.
    for _name, fn, base in cases:
        jax.block_until_ready(fn(base))
    trim()
    samples = [(0, rss_mib())]
    print(f"{len(cases)} set-ups; RSS after compiling: {samples[0][1]:.1f} MiB", flush=True)
    t0 = time.perf_counter()
    checksum = 0.0
    for i in range(1, args.calls + 1):
        name, fn, base = cases[i % len(cases)]
        noise = rng.normal(scale=5e-3, size=base.shape).astype(base.dtype)
        val, grad = fn(base + noise)
        checksum += float(val) + float(grad.reshape(-1)[0])
        if i % args.every == 0:
            samples.append((i, rss_mib()))
        if i % (args.every * 20) == 0:
            rate = i / (time.perf_counter() - t0)
            print(f"  {i:6d} calls  RSS {samples[-1][1]:8.1f} MiB  ({rate:.0f} calls/s)", flush=True)
    elapsed = time.perf_counter() - t0
    trim()
    after_trim = rss_mib()

    calls = np.array([c for c, _ in samples], float)
    rss = np.array([r for _, r in samples])
    keep = calls >= args.warmup
    slope = float(np.polyfit(calls[keep], rss[keep], 1)[0] * 1000) if keep.sum() >= 2 else float("nan")
    ref = rss[keep][0] if keep.any() else rss[0]
    result = {
        "calls": args.calls,
        "sample_every": args.every,
        "warmup_calls": args.warmup,
        "setups": [name for name, _, _ in cases],
        "seconds": elapsed,
        "calls_per_second": args.calls / elapsed,
        "rss_mib_start": float(rss[0]),
        "rss_mib_after_warmup": float(ref),
        "rss_mib_end": float(rss[-1]),
        "rss_mib_peak": float(rss.max()),
        "rss_mib_end_after_trim": after_trim,
        "slope_mib_per_1000_calls": slope,
        "growth_after_warmup_mib": float(rss[-1] - ref),
        "samples": samples,
        "checksum": checksum,
        "jax": jax.__version__,
        "python": sys.version.split()[0],
        "machine": platform.platform(),
        "cpus": os.cpu_count(),
    }
    print(f"\n{args.calls} calls in {elapsed:.1f} s ({args.calls / elapsed:.0f} calls/s)")
    print(f"RSS start {rss[0]:.1f} MiB, after {args.warmup} calls {ref:.1f} MiB, end {rss[-1]:.1f} MiB, "
          f"peak {rss.max():.1f} MiB, end after malloc_trim {after_trim:.1f} MiB")
    print(f"slope after warm-up: {slope:+.3f} MiB per 1000 calls "
          f"({slope * 1024 * 1024 / 1000:+.0f} bytes per call)")
    path = Path(args.json)
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(result, indent=1))
    print(f"wrote {path}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
