"""k nearest neighbours: `voxax.nearest_neighbors` against pykdtree and scipy's cKDTree, at
equal thread counts.

Data: 20,000 points sampled on the surface of `voxax.data.large(100_000)` (a tube around a
trefoil knot, max |v| = 0.75). Queries (100,000 per set, the same arrays for every library):

- "near": points within 0.01 of the surface (the nearest-seed pass of CVT meshing);
- "far": points uniform in [-1, 1]^3, mostly far from the surface (most grid cells around
  them are empty).

Every timed call includes building the search structure (voxax builds it inside every call;
`KDTree(points).query(...)`, `cKDTree(points).query(...)` for the peers). The libraries run at
the same thread count: one thread each (voxax `threads=1`, pykdtree with
`OMP_NUM_THREADS=1`, cKDTree `workers=1`), then every core each, in a separate process per
thread count (pykdtree reads `OMP_NUM_THREADS` when it loads). Within a process the
libraries alternate call by call (the order rotating every round) after one warm-up call
each, and the median of the repeats is reported; the 1-minute load average is recorded
before and after each process. Answers are checked: voxax's indices against cKDTree's where
cKDTree's distances have no tie, and its distances to 1e-12.

    PYTHONPATH=src nice -n 10 python benchmarks/knn.py                  # prints the tables
    PYTHONPATH=src nice -n 10 python benchmarks/knn.py --write-readme   # and replaces the kNN section
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

BEGIN, END = "<!-- knn-results:begin -->", "<!-- knn-results:end -->"
LIBS = ("voxax", "pykdtree", "cKDTree")


def _inputs(n_points: int, n_queries: int):
    import numpy as np

    import voxax

    mesh = voxax.data.large(100_000)
    rng = np.random.default_rng(0)
    points = voxax.metrics.sample_surface(mesh, n_points, key=2).points
    s = voxax.metrics.sample_surface(mesh, n_queries, key=1)
    near = s.points + rng.uniform(-0.01, 0.01, (n_queries, 1)) * s.normals
    far = rng.uniform(-1, 1, (n_queries, 3))
    return points, {"near": np.ascontiguousarray(near), "far": far}


def worker(threads: int, n_points: int, n_queries: int, ks, repeats: int) -> dict:
    """Runs in its own process with OMP_NUM_THREADS = threads."""
    import numpy as np
    from pykdtree.kdtree import KDTree
    from scipy.spatial import cKDTree

    import voxax

    points, sets = _inputs(n_points, n_queries)
    out = {"threads": threads, "load_before": os.getloadavg()[0], "rows": []}
    for set_name, q in sets.items():
        for k in ks:
            calls = {
                "voxax": lambda q=q, k=k: voxax.nearest_neighbors(points, q, k, threads=threads),
                "pykdtree": lambda q=q, k=k: KDTree(points).query(q, k),
                "cKDTree": lambda q=q, k=k: cKDTree(points).query(q, k, workers=threads),
            }
            answers = {name: fn() for name, fn in calls.items()}  # warm-up, and the answers
            d, i = answers["voxax"]
            dc, ic = (np.asarray(a).reshape(len(q), k) for a in answers["cKDTree"])
            tied = np.zeros(len(q), bool)
            if k > 1:
                tied |= np.any(np.diff(dc, axis=1) == 0, axis=1)
            agree = bool(np.allclose(d, dc, rtol=1e-12, atol=0) and np.array_equal(i[~tied], ic[~tied]))
            times = {name: [] for name in calls}
            cpu = {name: [] for name in calls}
            for r in range(repeats):
                names = list(calls)
                names = names[r % len(names):] + names[: r % len(names)]
                for name in names:
                    c0, t0 = time.process_time(), time.perf_counter()
                    calls[name]()
                    times[name].append(time.perf_counter() - t0)
                    cpu[name].append(time.process_time() - c0)
            row = {"set": set_name, "k": k, "agree": agree}
            for name, t in times.items():
                row[name] = float(np.median(t))
                row[name + "_cpu"] = float(np.median(cpu[name]))
                row[name + "_all"] = [float(x) for x in t]
            out["rows"].append(row)
            print(json.dumps({"threads": threads, "set": set_name, "k": k,
                              **{n: round(row[n], 4) for n in LIBS}, "agree": agree}), file=sys.stderr, flush=True)
    out["load_after"] = os.getloadavg()[0]
    return out


def run(thread_counts, n_points, n_queries, ks, repeats) -> list[dict]:
    results = []
    for t in thread_counts:
        env = dict(os.environ, OMP_NUM_THREADS=str(t))
        cmd = [sys.executable, __file__, "--worker", str(t), "--points", str(n_points), "--queries", str(n_queries),
               "--repeats", str(repeats), "--k", *map(str, ks)]
        proc = subprocess.run(cmd, env=env, capture_output=True, text=True)
        sys.stderr.write(proc.stderr)
        if proc.returncode != 0:
            raise RuntimeError(f"the {t}-thread worker failed")
        results.append(json.loads(proc.stdout.strip().splitlines()[-1]))
    return results


def table(results, n_points, n_queries, repeats) -> str:
    cpu = platform.processor() or platform.machine()
    lines = [
        f"Measured on {os.cpu_count()} logical CPUs ({cpu}), {time.strftime('%Y-%m-%d')}: {n_points:,} points on "
        f"`data.large(100_000)`, {n_queries:,} queries per set, median of {repeats} interleaved calls after a "
        "warm-up, each call building its structure. Command: `python benchmarks/knn.py --write-readme`.",
        "",
    ]
    for res in results:
        t = res["threads"]
        label = "one thread each (equal threads)" if t == 1 else f"{t} threads each (every core; multi-threaded)"
        lines += [
            f"**{label}**; 1-minute load average {res['load_before']:.1f} before, {res['load_after']:.1f} after.",
            "",
            "| queries | k | voxax (M/s) | pykdtree (M/s) | cKDTree (M/s) | voxax / pykdtree | voxax / cKDTree "
            "| same answers |",
            "|---|---|---|---|---|---|---|---|",
        ]
        for r in res["rows"]:
            rate = {n: n_queries / r[n] / 1e6 for n in LIBS}
            lines.append(
                f"| {r['set']} | {r['k']} | {rate['voxax']:.2f} | {rate['pykdtree']:.2f} | {rate['cKDTree']:.2f} "
                f"| {r['pykdtree'] / r['voxax']:.2f}x | {r['cKDTree'] / r['voxax']:.2f}x "
                f"| {'yes' if r['agree'] else 'NO'} |"
            )
        if t == 1:
            lines += ["", "The same calls by median CPU time (one thread: less sensitive to other jobs on the machine):", "",
                      "| queries | k | voxax / pykdtree | voxax / cKDTree |", "|---|---|---|---|"]
            for r in res["rows"]:
                lines.append(f"| {r['set']} | {r['k']} | {r['pykdtree_cpu'] / r['voxax_cpu']:.2f}x "
                             f"| {r['cKDTree_cpu'] / r['voxax_cpu']:.2f}x |")
        lines.append("")
    return "\n".join(lines)


def write_readme(text: str) -> None:
    path = Path(__file__).with_name("README.md")
    readme = path.read_text()
    block = f"{BEGIN}\n{text}{END}"
    if BEGIN in readme:
        readme = re.sub(re.escape(BEGIN) + r".*?" + re.escape(END), lambda _: block, readme, flags=re.DOTALL)
    else:
        readme = readme.rstrip("\n") + "\n\n## k nearest neighbours: voxax vs pykdtree and cKDTree\n\n" + block + "\n"
    path.write_text(readme)


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--points", type=int, default=20_000)
    parser.add_argument("--queries", type=int, default=100_000)
    parser.add_argument("--k", type=int, nargs="+", default=[1, 3, 8])
    parser.add_argument("--threads", type=int, nargs="+", default=[1, os.cpu_count() or 1])
    parser.add_argument("--repeats", type=int, default=7)
    parser.add_argument("--write-readme", action="store_true")
    parser.add_argument("--worker", type=int, help=argparse.SUPPRESS)
    args = parser.parse_args(argv)
    if args.worker:
        print(json.dumps(worker(args.worker, args.points, args.queries, args.k, args.repeats)))
        return
    threads = list(dict.fromkeys(args.threads))
    results = run(threads, args.points, args.queries, args.k, args.repeats)
    text = table(results, args.points, args.queries, args.repeats)
    print(text)
    if args.write_readme:
        write_readme(text)


if __name__ == "__main__":
    main()
