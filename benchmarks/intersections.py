"""The exact intersection test: speed against its peers at equal threads, against one 512^3
voxelization of the same mesh, and agreement with independent checks.

    PYTHONPATH=src nice -n 10 python benchmarks/intersections.py [--write-readme] [--json out.json]

1. Peers (`--peer-faces`, default `large(100_000)`, a clean mesh: every candidate pair is
   examined and rejected): `voxax.intersections(mesh, threads=1)` against libigl's exact
   `copyleft.cgal.remesh_self_intersections(V, F, detect_only=True)` (CGAL's exact kernel)
   and MeshLab's `compute_selection_by_self_intersections_per_face` (pymeshlab, floating
   point), both single-threaded, on the same arrays; then voxax on every core, labelled
   apart. One warm-up call each, then `--repeats` rounds in which the calls alternate (the
   order rotating every round); medians, with the 1-minute load average before and after.
2. `voxax.intersections(large(1_000_000))` on every core against `voxax.voxelize` of the
   same mesh on the `[-1, 1]^3` grid at 512^3 (float32, after a compiling call), medians of
   interleaved repeats. The bar: the exact test takes at most the time of one voxelization.
3. A self-intersecting mesh (`bent_bar` at low resolution): the intersecting pairs against
   libigl's exact pairs and against a brute-force exact oracle (every pair of non-adjacent
   faces whose bounding boxes meet, decided in rational arithmetic by the oracle of
   `tests/spatial/test_intersections.py`; `--no-brute-force` skips it), and the
   intersecting faces against MeshLab's selection.
Peers that are not installed are left out (they are benchmark-only installs:
`pip install libigl pymeshlab`).
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import re
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests" / "spatial"))

import jax  # noqa: E402
import jax.numpy as jnp  # noqa: E402

import voxax  # noqa: E402

BEGIN, END = "<!-- intersections-results:begin -->", "<!-- intersections-results:end -->"


def interleaved(calls: dict, repeats: int) -> dict:
    """Median seconds per call: one warm-up call each, then `repeats` rounds of alternating
    calls (the order rotating every round)."""
    for fn in calls.values():
        fn()
    times = {name: [] for name in calls}
    for r in range(repeats):
        names = list(calls)
        for name in names[r % len(names):] + names[: r % len(names)]:
            t0 = time.perf_counter()
            calls[name]()
            times[name].append(time.perf_counter() - t0)
    return {name: float(np.median(t)) for name, t in times.items()}


def peer_calls(v, f) -> dict:
    """The single-threaded peers that are installed, by name: each returns what it found."""
    calls = {}
    try:
        import igl.copyleft.cgal as cgal

        f64 = f.astype(np.int64)
        calls["libigl (CGAL, exact)"] = lambda: len(cgal.remesh_self_intersections(v, f64, detect_only=True)[2])
    except ImportError:
        pass
    try:
        import pymeshlab

        def meshlab():
            ms = pymeshlab.MeshSet()
            ms.add_mesh(pymeshlab.Mesh(v, f))
            ms.compute_selection_by_self_intersections_per_face()
            return int(ms.current_mesh().face_selection_array().sum())

        calls["MeshLab (pymeshlab)"] = meshlab
    except ImportError:
        pass
    return calls


def peers(n_faces, repeats):
    mesh = voxax.data.large(n_faces)
    v, f = np.asarray(mesh.vertices, np.float64), np.asarray(mesh.faces, np.int32)
    cores = os.cpu_count() or 1
    calls = {"voxax, 1 thread": lambda: voxax.intersections(mesh, threads=1).count, **peer_calls(v, f),
             f"voxax, {cores} threads": lambda: voxax.intersections(mesh, threads=cores).count}
    found = {name: int(fn()) for name, fn in calls.items()}
    load = os.getloadavg()[0]
    med = interleaved(calls, repeats)
    return dict(faces=int(mesh.n_faces), seconds=med, found=found, load_before=load, load_after=os.getloadavg()[0],
                repeats=repeats)


def speed(n_faces, repeats, resolution):
    mesh = voxax.data.large(n_faces)
    t0 = time.perf_counter()
    r = voxax.intersections(mesh)
    cold = time.perf_counter() - t0
    v = jnp.asarray(mesh.vertices, dtype=jnp.float32)
    f = jnp.asarray(mesh.faces)
    grid = voxax.Grid.cube(resolution)
    vox = jax.jit(lambda v: voxax.voxelize(v, f, grid))
    t0 = time.perf_counter()
    vox(v).block_until_ready()
    vox_cold = time.perf_counter() - t0
    load = os.getloadavg()[0]
    med = interleaved({"exact": lambda: voxax.intersections(mesh), "voxelize": lambda: vox(v).block_until_ready()},
                      repeats)
    return dict(faces=int(mesh.n_faces), pairs=int(r.count), exact_cold_s=cold, exact_s=med["exact"],
                voxelize_resolution=resolution, voxelize_cold_s=vox_cold, voxelize_s=med["voxelize"],
                threads=os.cpu_count(), load_before=load, load_after=os.getloadavg()[0], repeats=repeats)


def agreement(brute_force=True):
    mesh = voxax.data.bent_bar(n_along=40, n_around=8)
    v, f = mesh.vertices, mesh.faces
    pairs = voxax.intersections(mesh).pairs
    out = dict(faces=int(len(f)), voxax_pairs_all=int(len(pairs)))
    try:
        import igl.copyleft.cgal as cgal

        theirs = cgal.remesh_self_intersections(np.asarray(v, np.float64), np.asarray(f, np.int64),
                                                detect_only=True)[2]
        a = {tuple(sorted(p)) for p in np.asarray(pairs).tolist()}
        b = {tuple(sorted(p)) for p in np.asarray(theirs).tolist()}
        out.update(libigl_pairs=len(b), pairs_in_both=len(a & b), libigl_identical=a == b)
    except ImportError:
        pass
    try:
        import pymeshlab

        ms = pymeshlab.MeshSet()
        ms.add_mesh(pymeshlab.Mesh(v, f))
        ms.compute_selection_by_self_intersections_per_face()
        sel = np.flatnonzero(ms.current_mesh().face_selection_array())
        mine = np.unique(pairs.reshape(-1))
        out.update(meshlab_faces=int(len(sel)), voxax_faces=int(len(mine)),
                   faces_in_both=int(len(np.intersect1d(sel, mine))))
    except ImportError:
        pass
    if brute_force:
        out.update(brute(v, f, pairs))
    return out


def brute(v, f, pairs):
    from test_intersections import oracle_intersect

    # Brute force over every non-adjacent pair of faces with meeting bounding boxes.
    tri = v[f]
    lo, hi = tri.min(axis=1), tri.max(axis=1)
    t0 = time.perf_counter()
    brute = []
    for i in range(len(f)):
        meet = np.all(hi[i] >= lo[i + 1:], axis=1) & np.all(hi[i + 1:] >= lo[i], axis=1)
        for j in np.flatnonzero(meet) + i + 1:
            if set(f[i]) & set(f[j]):
                continue
            if oracle_intersect(tri[i], tri[j]):
                brute.append((i, int(j)))
    brute_s = time.perf_counter() - t0
    ours = [tuple(p) for p in pairs.tolist() if not set(f[p[0]]) & set(f[p[1]])]
    out = dict(brute_force_pairs=len(brute), voxax_nonadjacent_pairs=len(ours), identical=ours == brute,
               brute_force_s=brute_s)
    return out


def table(res) -> str:
    p, s, a = res["peers"], res["speed"], res["agreement"]
    cores = os.cpu_count() or 1
    one = p["seconds"]["voxax, 1 thread"]
    lines = [
        f"Measured {time.strftime('%Y-%m-%d')} on {cores} logical CPUs ({platform.processor() or platform.machine()}). "
        "Command: `python benchmarks/intersections.py --write-readme`.",
        "",
        f"**Against the peers**, `large({p['faces']:,} faces)` (clean: 0 pairs), median of {p['repeats']} interleaved "
        f"calls after a warm-up; 1-minute load average {p['load_before']:.1f} before, {p['load_after']:.1f} after. "
        "The peers run on one thread, so the equal-thread comparison is voxax on 1 thread; the last row is "
        "voxax on every core, not an equal-thread figure.",
        "",
        "| call | threads | seconds | found | voxax 1 thread is faster by |",
        "|---|---|---|---|---|",
    ]
    for name, sec in p["seconds"].items():
        thr = name.split(", ")[1].split(" ")[0] if name.startswith("voxax") else "1"
        ratio = "" if name.startswith("voxax") else f"{sec / one:.2f}x"
        lines.append(f"| {name} | {thr} | {sec:.2f} | {p['found'][name]} | {ratio} |")
    lines += [
        "",
        f"**Against one voxelization**, `large({s['faces']:,} faces)`, every core ({s['threads']} threads) for both, "
        f"median of {s['repeats']} interleaved calls; load {s['load_before']:.1f} before, {s['load_after']:.1f} after.",
        "",
        "| | seconds |",
        "|---|---|",
        f"| exact self test ({s['pairs']} pairs) | {s['exact_s']:.2f} (first call {s['exact_cold_s']:.2f}, "
        "welding included) |",
        f"| `voxelize` at {s['voxelize_resolution']}^3, float32 | {s['voxelize_s']:.2f} (first call "
        f"{s['voxelize_cold_s']:.2f}, compilation included) |",
        f"| ratio exact / voxelize | {s['exact_s'] / s['voxelize_s']:.2f} |",
        "",
        f"**Agreement** on `bent_bar(n_along=40, n_around=8)` ({a['faces']} faces, self-intersecting): voxax "
        f"reports {a['voxax_pairs_all']} pairs.",
        "",
    ]
    if "libigl_pairs" in a:
        lines.append(f"- libigl's exact pairs: {a['libigl_pairs']}, {a['pairs_in_both']} of them also voxax's "
                     f"({'the same set' if a['libigl_identical'] else 'the sets differ'}).")
    if "brute_force_pairs" in a:
        lines.append(f"- brute force with the rational oracle ({a['brute_force_s']:.0f} s): "
                     f"{a['brute_force_pairs']} non-adjacent pairs; voxax's non-adjacent pairs: "
                     f"{a['voxax_nonadjacent_pairs']} ({'identical' if a['identical'] else 'different'}).")
    if "meshlab_faces" in a:
        lines.append(f"- MeshLab's selection (floating point): {a['meshlab_faces']} faces; voxax's pairs involve "
                     f"{a['voxax_faces']} faces, {a['faces_in_both']} of them in both.")
    return "\n".join(lines) + "\n"


def write_readme(text: str) -> None:
    path = Path(__file__).with_name("README.md")
    readme = path.read_text()
    block = f"{BEGIN}\n{text}{END}"
    if BEGIN in readme:
        readme = re.sub(re.escape(BEGIN) + r".*?" + re.escape(END), lambda _: block, readme, flags=re.DOTALL)
    else:
        readme = readme.rstrip("\n") + "\n\n" + block + "\n"
    path.write_text(readme)


def main(argv=None):
    parser = argparse.ArgumentParser()
    parser.add_argument("--faces", type=int, default=1_000_000)
    parser.add_argument("--peer-faces", type=int, default=100_000)
    parser.add_argument("--resolution", type=int, default=512)
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--no-brute-force", action="store_true")
    parser.add_argument("--write-readme", action="store_true")
    parser.add_argument("--json")
    args = parser.parse_args(argv)
    res = {"peers": peers(args.peer_faces, args.repeats)}
    print(json.dumps(res["peers"]), flush=True)
    res["speed"] = speed(args.faces, max(1, args.repeats // 2), args.resolution)
    print(json.dumps(res["speed"]), flush=True)
    res["agreement"] = agreement(not args.no_brute_force)
    text = table(res)
    print(text)
    if args.write_readme:
        write_readme(text)
    if args.json:
        Path(args.json).write_text(json.dumps(res, indent=1))


if __name__ == "__main__":
    main()
