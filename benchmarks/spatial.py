"""Throughput of the BVH: build time, rays per second and closest points per second.

Meshes: `voxax.data.large(100_000)` and `voxax.data.large(1_000_000)` (a tube around a
trefoil knot, max |v| = 0.75). Queries:

- rays: origins uniform in [-1, 1]^3, directions uniform on the sphere (incoherent rays;
  about one in seven hits the thin tube), `first_hits` and `any_hits`;
- closest points: points uniform in [-1, 1]^3 ("volume") and points within 0.01 of the
  surface ("near"), `closest_points`;
- nearest neighbours: the "near" points against 20,000 seeds sampled on the surface
  (`nearest_neighbors`, k = 1 and 3), the nearest-seed pass of CVT meshing.

Each query set is timed `--repeats` times after one warm-up; the best time is reported,
both as wall-clock throughput and as a CPU-time estimate: `threads * queries / CPU seconds`
(the process's CPU time over all its threads). On a machine shared with other jobs the
wall clock understates the kernels; the CPU-time figure is what the given number of
otherwise idle cores would deliver if the threads scale linearly (the table shows the
1-thread CPU-time rate next to it, so the scaling can be judged).
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


def best_time(fn, repeats: int) -> tuple[float, float]:
    """(best wall seconds, best CPU seconds) over the repeats, after a warm-up."""
    fn()
    wall, cpu = [], []
    for _ in range(repeats):
        c0, t0 = time.process_time(), time.perf_counter()
        fn()
        wall.append(time.perf_counter() - t0)
        cpu.append(time.process_time() - c0)
    return min(wall), min(cpu)


def run(n_faces: int, n_queries: int, threads: int, repeats: int, rng) -> dict:
    mesh = data.large(n_faces)
    t0 = time.perf_counter()
    bvh = voxax.BVH(mesh)
    build = time.perf_counter() - t0
    o = rng.uniform(-1, 1, (n_queries, 3))
    d = rng.normal(size=(n_queries, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    vol = rng.uniform(-1, 1, (n_queries, 3))
    s = voxax.metrics.sample_surface(mesh, n_queries, key=1)
    near = s.points + rng.uniform(-0.01, 0.01, (n_queries, 1)) * s.normals
    res = {
        "faces": mesh.n_faces,
        "nodes": bvh.n_nodes,
        "build_s": build,
        "queries": n_queries,
    }
    hit_rate = float(np.mean(bvh.first_hits(o, d, threads=threads).hit))
    res["hit_rate"] = hit_rate
    sets = {
        "first_hits": lambda: bvh.first_hits(o, d, threads=threads),
        "any_hits": lambda: bvh.any_hits(o, d, threads=threads),
        "closest_volume": lambda: bvh.closest_points(vol, threads=threads),
        "closest_near": lambda: bvh.closest_points(near, threads=threads),
    }
    for name, fn in sets.items():
        wall, cpu = best_time(fn, repeats)
        res[f"{name}_wall"] = n_queries / wall
        res[f"{name}_cpu"] = threads * n_queries / cpu
    # nearest neighbours: 20k seeds on the surface, the near-surface points as queries
    seeds = voxax.metrics.sample_surface(mesh, 20_000, key=2).points
    for k in (1, 3):
        wall, cpu = best_time(
            lambda k=k: voxax.nearest_neighbors(seeds, near, k, threads=threads),
            repeats,
        )
        res[f"knn{k}_wall"] = n_queries / wall
        res[f"knn{k}_cpu"] = threads * n_queries / cpu
    for name, fn in (
        ("first_hits", lambda: bvh.first_hits(o, d, threads=1)),
        ("closest_near", lambda: bvh.closest_points(near, threads=1)),
    ):
        res[f"{name}_1thread_cpu"] = n_queries / best_time(fn, 1)[1]
    return res


def table(results: list[dict], threads: int) -> str:
    m = lambda x: f"{x / 1e6:.2f} M"
    lines = [
        (
            "| mesh faces | BVH nodes | build (s) | query set | per s, CPU-time estimate "
            f"({threads} cores) | per s, 1 thread (CPU time) | per s, wall clock |"
        ),
        "|---|---|---|---|---|---|---|",
    ]
    names = {
        "knn1": "nearest of 20k seeds (k=1)",
        "knn3": "3 nearest of 20k seeds (k=3)",
        "first_hits": "first hits",
        "any_hits": "any hits",
        "closest_near": "closest points, near surface",
        "closest_volume": "closest points, volume",
    }
    for r in results:
        for key, label in names.items():
            one = m(r[f"{key}_1thread_cpu"]) if f"{key}_1thread_cpu" in r else ""
            lines.append(
                f"| {r['faces']:,} | {r['nodes']:,} | {r['build_s']:.2f} | {label} | {m(r[f'{key}_cpu'])} "
                f"| {one} | {m(r[f'{key}_wall'])} |"
            )
    verdict = []
    for r in results:
        rays, near, vol = (
            r["first_hits_cpu"],
            r["closest_near_cpu"],
            r["closest_volume_cpu"],
        )
        verdict.append(
            f"- {r['faces']:,} faces: first hits {m(rays)}/s ({'meets' if rays >= TARGET_RAYS else 'misses'} 2M/s; "
            f"{100 * r['hit_rate']:.0f}% of the rays hit), closest points near the surface {m(near)}/s "
            f"({'meets' if near >= TARGET_POINTS else 'misses'} 1M/s), in the volume {m(vol)}/s "
            f"({'meets' if vol >= TARGET_POINTS else 'misses'} 1M/s)."
        )
    cpu = platform.processor() or platform.machine()
    load = os.getloadavg()[0] if hasattr(os, "getloadavg") else float("nan")
    head = (
        f"Measured on {os.cpu_count()} logical CPUs ({cpu}; 1-minute load average {load:.1f} at the end of "
        f"the run), {threads} threads, {results[0]['queries']:,} queries per set, best of the repeats, "
        f"{time.strftime('%Y-%m-%d')}. Command: `python benchmarks/spatial.py --write-readme`."
    )
    return head + "\n\n" + "\n".join(lines) + "\n\n" + "\n".join(verdict) + "\n"


def write_readme(text: str) -> None:
    path = Path(__file__).with_name("README.md")
    readme = path.read_text()
    block = f"{BEGIN}\n{text}{END}"
    if BEGIN in readme:
        readme = re.sub(
            re.escape(BEGIN) + r".*?" + re.escape(END),
            lambda _: block,
            readme,
            flags=re.DOTALL,
        )
    else:
        readme = (
            readme.rstrip("\n")
            + "\n\n## Spatial queries (BVH)\n\n"
            + (
                "`spatial.py` times `voxax.BVH` (closest points and ray hits) on `data.large` meshes; "
                "see its docstring for the query sets.\n\n"
            )
            + block
            + "\n"
        )
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
