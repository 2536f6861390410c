"""Throughput of the BVH: build time, rays per second and closest points per second.

Meshes: `voxax.data.large(100_000)` and `voxax.data.large(1_000_000)` (a tube around a
trefoil knot, max |v| = 0.75). Queries:

- rays: origins uniform in [-1, 1]^3, directions uniform on the sphere (incoherent rays,
  most of them hit the tube), `first_hits` and `any_hits`;
- closest points: points uniform in [-1, 1]^3 ("volume") and points within 0.01 of the
  surface ("near"), `closest_points`.

Each query set is timed `--repeats` times after one warm-up; the best time is reported.
Run from the repository root (`PYTHONPATH=src` when voxax is not installed):

    python benchmarks/spatial.py                    # prints a table
    python benchmarks/spatial.py --write-readme     # and replaces the BVH section of README.md
"""

from __future__ import annotations

import argparse
import os
import platform
import re
import time
from pathlib import Path

import numpy as np

import voxax
from voxax import data

TARGET_RAYS = 2e6
TARGET_POINTS = 1e6
BEGIN, END = "<!-- spatial-results:begin -->", "<!-- spatial-results:end -->"


def best_time(fn, repeats: int) -> float:
    fn()
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return min(times)


def run(n_faces: int, n_queries: int, threads: int, repeats: int, rng) -> dict:
    mesh = data.large(n_faces)
    t0 = time.perf_counter()
    bvh = voxax.BVH(mesh)
    build = time.perf_counter() - t0
    o = rng.uniform(-1, 1, (n_queries, 3))
    d = rng.normal(size=(n_queries, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    vol = rng.uniform(-1, 1, (n_queries, 3))
    s = voxax.metrics.sample_surface(mesh, n_queries, seed=1)
    near = s.points + rng.uniform(-0.01, 0.01, (n_queries, 1)) * s.normals
    res = {"faces": mesh.n_faces, "nodes": bvh.n_nodes, "build_s": build, "queries": n_queries}
    hit_rate = float(np.mean(bvh.first_hits(o, d, threads=threads).hit))
    res["hit_rate"] = hit_rate
    res["first_hits_per_s"] = n_queries / best_time(lambda: bvh.first_hits(o, d, threads=threads), repeats)
    res["any_hits_per_s"] = n_queries / best_time(lambda: bvh.any_hits(o, d, threads=threads), repeats)
    res["closest_volume_per_s"] = n_queries / best_time(lambda: bvh.closest_points(vol, threads=threads), repeats)
    res["closest_near_per_s"] = n_queries / best_time(lambda: bvh.closest_points(near, threads=threads), repeats)
    one = n_queries / best_time(lambda: bvh.first_hits(o, d, threads=1), 1)
    res["first_hits_per_s_1thread"] = one
    return res


def table(results: list[dict], threads: int) -> str:
    lines = [
        f"| mesh faces | BVH nodes | build (s) | first hits/s | any hits/s | closest points/s (volume) "
        f"| closest points/s (near surface) | first hits/s, 1 thread |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for r in results:
        lines.append(
            f"| {r['faces']:,} | {r['nodes']:,} | {r['build_s']:.2f} | {r['first_hits_per_s'] / 1e6:.2f} M "
            f"| {r['any_hits_per_s'] / 1e6:.2f} M | {r['closest_volume_per_s'] / 1e6:.2f} M "
            f"| {r['closest_near_per_s'] / 1e6:.2f} M | {r['first_hits_per_s_1thread'] / 1e6:.2f} M |"
        )
    verdict = []
    for r in results:
        rays_ok = r["first_hits_per_s"] >= TARGET_RAYS
        pts_ok = min(r["closest_volume_per_s"], r["closest_near_per_s"]) >= TARGET_POINTS
        verdict.append(
            f"- {r['faces']:,} faces: rays {'meet' if rays_ok else 'miss'} the 2M/s target "
            f"({r['first_hits_per_s'] / 1e6:.2f} M/s, {100 * r['hit_rate']:.0f}% of rays hit); closest points "
            f"{'meet' if pts_ok else 'miss'} the 1M/s target "
            f"({min(r['closest_volume_per_s'], r['closest_near_per_s']) / 1e6:.2f} M/s, the slower query set)."
        )
    cpu = platform.processor() or platform.machine()
    head = (
        f"Measured on {os.cpu_count()} logical CPUs ({cpu}), {threads} threads, "
        f"{results[0]['queries']:,} queries per set, best of the repeats, "
        f"{time.strftime('%Y-%m-%d')}. Command: `python benchmarks/spatial.py --write-readme`."
    )
    return head + "\n\n" + "\n".join(lines) + "\n\n" + "\n".join(verdict) + "\n"


def write_readme(text: str) -> None:
    path = Path(__file__).with_name("README.md")
    readme = path.read_text()
    block = f"{BEGIN}\n{text}{END}"
    if BEGIN in readme:
        readme = re.sub(re.escape(BEGIN) + r".*?" + re.escape(END), lambda _: block, readme, flags=re.S)
    else:
        readme = readme.rstrip("\n") + "\n\n## Spatial queries (BVH)\n\n" + (
            "`spatial.py` times `voxax.BVH` (closest points and ray hits) on `data.large` meshes; "
            "see its docstring for the query sets.\n\n"
        ) + block + "\n"
    path.write_text(readme)


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--faces", type=int, nargs="+", default=[100_000, 1_000_000])
    parser.add_argument("--queries", type=int, default=1_000_000)
    parser.add_argument("--threads", type=int, default=2)
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--write-readme", action="store_true")
    args = parser.parse_args(argv)
    rng = np.random.default_rng(0)
    results = []
    for nf in args.faces:
        r = run(nf, args.queries, args.threads, args.repeats, rng)
        print(r, flush=True)
        results.append(r)
    text = table(results, args.threads)
    print(text)
    if args.write_readme:
        write_readme(text)


if __name__ == "__main__":
    main()
