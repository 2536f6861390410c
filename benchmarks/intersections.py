"""The exact intersection test: speed on a 1M-face mesh against one 512^3 voxelization of
the same mesh (same run), and agreement with independent checks on smaller meshes.

    PYTHONPATH=src python benchmarks/intersections.py [--faces 1000000] [--json out.json]

1. `voxax.intersections(large(1_000_000))` (self test: the mesh is clean, so every
   candidate pair is examined and rejected), timed once cold and then `--repeats` times;
   then `voxax.voxelize` of the same mesh on the `[-1, 1]^3` grid at 512^3 (float32),
   timed after a compiling call. The issue's bar: the exact test takes at most the time of
   one voxelization.
2. A self-intersecting mesh (`bent_bar` at low resolution): the non-adjacent intersecting
   pairs against a brute-force exact oracle (every pair of non-adjacent faces whose
   bounding boxes meet, decided in rational arithmetic by the oracle of
   `tests/spatial/test_intersections.py`), and the intersecting faces against MeshLab's
   `compute_selection_by_self_intersections_per_face` (pymeshlab; floating point).
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))

import jax  # noqa: E402
import jax.numpy as jnp  # noqa: E402

import voxax  # noqa: E402


def timed(fn, repeats):
    out = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()
        out.append(time.perf_counter() - t0)
    return out


def speed(n_faces, repeats, resolution):
    mesh = voxax.data.large(n_faces)
    t0 = time.perf_counter()
    r = voxax.intersections(mesh)
    cold = time.perf_counter() - t0
    exact = timed(lambda: voxax.intersections(mesh), repeats)
    v = jnp.asarray(mesh.vertices, dtype=jnp.float32)
    f = jnp.asarray(mesh.faces)
    grid = voxax.Grid.cube(resolution)
    vox = jax.jit(lambda v: voxax.voxelize(v, f, grid))
    t0 = time.perf_counter()
    W = vox(v).block_until_ready()
    vox_cold = time.perf_counter() - t0
    del W
    vox_times = timed(lambda: vox(v).block_until_ready(), max(1, repeats // 2))
    return dict(faces=int(mesh.n_faces), pairs=int(r.count), exact_cold_s=cold, exact_s=min(exact),
                exact_all_s=exact, voxelize_resolution=resolution, voxelize_cold_s=vox_cold,
                voxelize_s=min(vox_times), voxelize_all_s=vox_times, threads=os.cpu_count())


def agreement():
    from test_intersections import oracle_intersect

    mesh = voxax.data.bent_bar(n_along=40, n_around=8)
    v, f = mesh.vertices, mesh.faces
    pairs = voxax.intersections(mesh).pairs
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
    out = dict(faces=int(len(f)), brute_force_pairs=len(brute), voxax_nonadjacent_pairs=len(ours),
               identical=ours == brute, brute_force_s=brute_s, voxax_pairs_all=int(len(pairs)))
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
    return out


def main(argv=None):
    parser = argparse.ArgumentParser()
    parser.add_argument("--faces", type=int, default=1_000_000)
    parser.add_argument("--resolution", type=int, default=512)
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--json")
    args = parser.parse_args(argv)
    res = {"speed": speed(args.faces, args.repeats, args.resolution), "agreement": agreement()}
    s = res["speed"]
    print(f"exact self test, {s['faces']} faces: {s['exact_s']:.2f} s (cold {s['exact_cold_s']:.2f} s), "
          f"{s['pairs']} pairs; voxelize {s['voxelize_resolution']}^3: {s['voxelize_s']:.2f} s "
          f"(cold {s['voxelize_cold_s']:.2f} s); ratio {s['exact_s'] / s['voxelize_s']:.2f}")
    print("agreement:", json.dumps(res["agreement"]))
    if args.json:
        Path(args.json).write_text(json.dumps(res, indent=1))


if __name__ == "__main__":
    main()
