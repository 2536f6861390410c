"""Explicit surface intersections: ray throughput, depth maps, axis selection, neural fits.

Cases (run from the repository root, `PYTHONPATH=src` when voxax is not installed):

- `bvh`: first hits (rays per second; origins uniform in [-1, 1]^3, directions uniform)
  and closest points (points uniform in [-1, 1]^3) on `voxax.data.large(1_000_000)`.
- `depth`: a 512^2 `voxax.esi.depth_map` of `voxax.data.large(1_000_000)`.
- `select`: `voxax.esi.select` with the paper's candidate counts (50 DHF, 80 HF, up to
  3 HFs, 10,000 samples) on `voxax.data.large(100_000)` and on a mug (cup + handle), with
  the Chamfer distances (CD-L1 x 1000 over the bounding-box diagonal, 20,000 samples) of
  the ESI mesh, of the DHF alone and of the bandsaw cut shape
  (`voxax.fabricate.cut_solid`, the three axis silhouettes extruded and intersected), next
  to the shape's self-Chamfer.
- `levels`: the selection of `select`, level by level (preparation, then m = 0, 1, ...
  HFs, each timed in wall and CPU seconds), without the meshing.
- `nesi`: `voxax.nesi.fit` of the torus (DHF along z) and of the mug (its selected axes)
  at levels of detail 1 and 2, Chamfer of the neural mesh against the ESI mesh's, and
  level-4 occupancy throughput.
- `siren`: the same fits on the five shapes of `NESI_SHAPES` (torus, mug, a CSG part, the
  blob, the bent bar; `--nesi-shapes` picks some), each next to a plain 3D SIREN with the
  same parameter count and number of steps (signed-distance regression, marching cubes
  at 192^3), both against the input's self-Chamfer and the ESI's.

    python benchmarks/esi.py                      # every case, prints the results
    python benchmarks/esi.py select --steps 2000  # some cases
"""

from __future__ import annotations

import argparse
import functools
import sys
import time
from pathlib import Path

import numpy as np

import voxax
from voxax import data, esi, fabricate, metrics, nesi
from voxax.esi import _search as esi_search
from voxax.esi import _select as esi_select

print = functools.partial(print, flush=True)  # noqa: A001

sys.path.insert(0, str(Path(__file__).resolve().parent.parent / "tests"))


def _best(fn, repeats=3):
    best = np.inf
    out = None
    for _ in range(repeats):
        t = time.perf_counter()
        out = fn()
        best = min(best, time.perf_counter() - t)
    return best, out


def _cd(a, b, n=20_000):
    return metrics.chamfer(a, b, convention="l1_bbox", n=n)


def bench_bvh():
    m = data.large(1_000_000)
    t0 = time.perf_counter()
    bvh = voxax.BVH(m)
    build = time.perf_counter() - t0
    rng = np.random.default_rng(0)
    n = 1_000_000
    o = rng.uniform(-1, 1, (n, 3))
    d = rng.normal(size=(n, 3))
    t_rays, _ = _best(lambda: bvh.first_hits(o, d))
    t_cp, _ = _best(lambda: bvh.closest_points(o[:500_000]))
    print(
        f"bvh: {m.n_faces} faces, build {build:.2f} s, first hits {n / t_rays / 1e6:.2f} M rays/s, "
        f"closest points {5e5 / t_cp / 1e6:.2f} M points/s"
    )


def bench_depth():
    m = data.large(1_000_000)
    esi.depth_map(m, (0.3, -0.2, 1.0), resolution=64)  # warm-up
    t, dm = _best(lambda: esi.depth_map(m, (0.3, -0.2, 1.0), resolution=512), repeats=2)
    bvh = voxax.BVH(m)
    esi.depth_map(bvh, (1.0, 0.0, 0.0), resolution=64)  # checks the mesh once per tree
    t_q, again = _best(lambda: esi.depth_map(bvh, (0.3, -0.2, 1.0), resolution=512), repeats=3)
    assert np.array_equal(again.first, dm.first, equal_nan=True)
    print(
        f"depth map 512^2 of {m.n_faces} faces: {t:.2f} s with the closed-mesh check and the BVH build, "
        f"{t_q:.3f} s from a built BVH (`depth_map(bvh, d)`); mask {dm.mask.mean():.3f} ({_load()})"
    )


def bench_select(shapes, max_hf, n_dhf=50, n_hf=80):
    from _esi_shapes import mug

    cases = {"knot100k": lambda: data.large(100_000), "mug": lambda: mug(64)}
    for name in shapes:
        m = cases[name]()
        t = time.perf_counter()
        r = esi.select(m, n_dhf=n_dhf, n_hf=n_hf, max_hf=max_hf, n_samples=10_000, resolution=128)
        t_sel = time.perf_counter() - t
        t = time.perf_counter()
        full = esi.to_mesh(r, m, resolution=256)
        dhf = esi.to_mesh((r.dhf_axis, ()), m, resolution=256)
        t_mesh = time.perf_counter() - t
        t = time.perf_counter()
        cut = fabricate.cut_solid(m)
        t_cut = time.perf_counter() - t
        print(
            f"select {name} ({m.n_faces} faces): {t_sel:.1f} s, {len(r.hf_axes)} HFs, dhf {np.round(r.dhf_axis, 3)}, "
            f"hfs {np.round(r.hf_axes, 3).tolist()}, E by m {np.array2string(r.by_m, precision=3)}, "
            f"leaves {r.leaves.tolist()}, full evaluations {r.evaluations.tolist()}, prune rate {r.prune_rate:.3f}"
        )
        print(
            f"  meshing {t_mesh:.1f} s, bandsaw cut shape {t_cut:.2f} s; CD-L1x1000: self {_cd(m, m):.3f}, "
            f"ESI {_cd(full, m):.3f}, DHF alone {_cd(dhf, m):.3f}, bandsaw cut {_cd(cut, m):.3f}; "
            f"volume ratio to the shape: ESI {full.signed_volume() / m.signed_volume():.3f}, "
            f"bandsaw {cut.signed_volume() / m.signed_volume():.3f}"
        )


def bench_levels(shapes, max_hf, n_dhf=50, n_hf=80):
    """The selection of `bench_select`, level by level: the preparation, then the branch and
    bound for m = 0, 1, ... HFs (with `select`'s stopping rule), each with its wall and CPU
    time, so that a run stopped early still reports the levels it finished."""
    from _esi_shapes import mug

    cases = {"knot100k": lambda: data.large(100_000), "mug": lambda: mug(64)}
    eps1, eps2, angle, tol = 1e-4, 1e-3, 85.0, 1e-4
    for name in shapes:
        m = cases[name]()
        cdhf, chf = esi.candidates(n_dhf, n_hf)
        t0, c0 = time.perf_counter(), time.process_time()
        prob, dk, hk = esi_select._prepare("levels", m, None, cdhf, chf, 128, 10_000, 0, None)
        print(
            f"levels {name}: preparation {time.perf_counter() - t0:.1f} s wall, {time.process_time() - c0:.1f} s CPU "
            f"({len(prob.vec)} signed directions)"
        )
        chosen, first = None, None
        for level in range(max_hf + 1):
            t1, c1 = time.perf_counter(), time.process_time()
            rays = prob.n_rays
            # as `select` does: a level only looks for a choice better than the last by tol
            cap = np.inf if chosen is None else chosen - tol
            best, leaves, evals = esi_search._search(prob, dk, hk, level, eps1, eps2, angle, False, cap=cap, first=first)
            found = best[1] != np.inf
            first = best[1] if found else first
            print(
                f"  m = {level}: E {best[0]:.6f}{'' if found else ' (cap: nothing below it)'}, DHF {best[1]}, "
                f"HFs {best[2]}; {evals} of {leaves} leaves evaluated, {prob.n_rays - rays} rays; "
                f"{time.perf_counter() - t1:.1f} s wall, {time.process_time() - c1:.1f} s CPU; "
                f"total {time.perf_counter() - t0:.1f} s wall, {time.process_time() - c0:.1f} s CPU; {_load()}"
            )
            if found and (chosen is None or best[0] < chosen - tol):
                chosen = best[0]
            else:
                break


def _load():
    import os

    return f"load {os.getloadavg()[0]:.1f}"


def _csg_part():
    """A block with a spherical pocket on top and a ball fused to one end (marching cubes
    of the CSG distance bound on a 96^3 grid)."""
    import jax.numpy as jnp

    from voxax import fields

    def f(p):
        block = fields.box(p, (0.6, 0.35, 0.2))
        pocket = fields.sphere(p, 0.28, (-0.1, 0.0, 0.32))
        ball = fields.sphere(p, 0.22, (0.55, 0.0, 0.12))
        return fields.union(fields.difference(block, pocket), ball)

    return _iso_mesh(f, 1.0, jnp)


def _blob():
    """`voxax.fields.blob` (marching cubes on a 96^3 grid of [-2, 2]^3)."""
    import jax.numpy as jnp

    from voxax import fields

    return _iso_mesh(fields.blob, 2.0, jnp)


def _iso_mesh(f, half, jnp, n=96):
    g = voxax.Grid(lower=(-half,) * 3, upper=(half,) * 3, shape=(n,) * 3)
    iso = voxax.isosurface(f(jnp.asarray(g.centers())), g, 0.0, close=True)
    return voxax.Mesh(np.asarray(iso.vertices, np.float64), np.asarray(iso.faces, np.int32))


#: The five shapes of the NESI-against-SIREN comparison (fixed before any run).
NESI_SHAPES = {
    "torus": lambda: (data.torus(), ((0.0, 0.0, 1.0), ())),
    "mug": lambda: (data.mug(48), None),
    "csg_part": lambda: (_csg_part(), None),
    "blob": lambda: (_blob(), None),
    "bent_bar": lambda: (data.bent_bar(), None),
}


def _siren3d_fit(m, n_params, steps, learning_rate=1e-3, n_surface=20_000, seed=0):
    """A plain 3D SIREN (five hidden sine layers, `voxax.fields.Siren(3 -> 1)`, width chosen
    for `n_params` parameters) regressing the exact signed distance (L1, no Eikonal term)
    in the same normalised coordinates as NESI (bounding sphere of radius 1/1.1), with the
    same optimiser (Adam, cosine-decayed learning rate, full batch, `voxax.minimize`).
    Training points: `n_surface` surface samples (distance 0), as many within about 0.03
    of the surface and half as many uniform in [-1, 1]^3; distances from the BVH, signs
    from the winding number along a ray (all hits)."""
    import equinox as eqx
    import jax.numpy as jnp
    import optax

    w = int(round((-9 + np.sqrt(81 + 16 * (n_params - 1))) / 8))
    c, R = esi.bounding_sphere(m)
    s = (1.0 / 1.1) / R
    rng = np.random.default_rng(seed)
    S = metrics.sample_surface(m, n_surface, seed).points
    near = S + rng.normal(scale=0.03 / s, size=S.shape)
    far = c + rng.uniform(-1, 1, (n_surface // 2, 3)) / s
    pts = np.concatenate([S, near, far])
    bvh = voxax.BVH(m)
    dist = bvh.closest_points(pts).distance
    d = np.array([0.5773, 0.6031, 0.5505])
    hits = bvh.all_hits(pts, d / np.linalg.norm(d))
    wind = -np.bincount(hits.ray, weights=hits.sign, minlength=len(pts))
    sdf = np.where(wind > 0.5, -dist, dist)
    sdf[:n_surface] = 0.0
    x = jnp.asarray((pts - c) * s, jnp.float32)
    y = jnp.asarray(sdf * s, jnp.float32)
    net = nesi._siren(3, 1, w, 5, np.random.default_rng(seed), jnp.float32)
    params, static = eqx.partition(net, eqx.is_inexact_array)

    def energy(p, args):
        xx, yy = args
        return jnp.mean(jnp.abs(nesi._apply(eqx.combine(p, static), xx) - yy))

    sched = optax.cosine_decay_schedule(learning_rate, steps)
    res = voxax.minimize(
        energy,
        params,
        (x, y),
        solver=optax.adam(sched),
        stop=voxax.StopRules(max_steps=steps),
        progress=False,
        rtol=0.0,
        atol=0.0,
    )
    net = eqx.combine(res.y, static)
    return net, c, s, nesi.param_count(net), float(np.median(np.diff(res.history["time"])))


def _siren3d_mesh(net, c, s, n=192):
    """Marching cubes of the SIREN's zero level on an n^3 grid of [-1, 1]^3 (normalised)."""
    import equinox as eqx
    import jax.numpy as jnp

    g = voxax.Grid(lower=(-1.0,) * 3, upper=(1.0,) * 3, shape=(n,) * 3)
    pts = np.asarray(g.centers(), np.float32).reshape(-1, 3)
    f = eqx.filter_jit(nesi._apply)
    vals = np.concatenate(
        [np.asarray(f(net, jnp.asarray(pts[i : i + (1 << 18)]))) for i in range(0, len(pts), 1 << 18)]
    )
    iso = voxax.isosurface(jnp.asarray(vals.reshape((n,) * 3)), g, 0.0, close=True)
    return voxax.Mesh(np.asarray(iso.vertices, np.float64) / s + c, np.asarray(iso.faces, np.int32))


def bench_nesi(steps, lods, shapes=("torus", "mug"), siren=False, resolution=256):
    """NESI fits at the given levels of detail (Chamfer against the ESI's), and with
    `siren` a 3D SIREN of the same parameter count and steps next to the level-1 fit."""
    import jax

    for name in shapes:
        m, ax = NESI_SHAPES[name]()
        cd_self = _cd(m, m)
        if ax is None:
            t = time.perf_counter()
            ax = esi.select(m, n_dhf=20, n_hf=30, max_hf=2, n_samples=4000, resolution=96)
            print(
                f"[{name}] {m.n_faces} faces; selection {time.perf_counter() - t:.1f} s ({_load()}): "
                f"dhf {np.round(ax.dhf_axis, 3)}, {len(ax.hf_axes)} HFs {np.round(ax.hf_axes, 3).tolist()}"
            )
        ref = esi.to_mesh(ax, m, resolution=resolution)
        cd_esi = _cd(ref, m)
        print(f"[{name}] CD-L1x1000: self {cd_self:.3f}, ESI (meshed at {resolution}^2) {cd_esi:.3f}")
        for lod in lods:
            t, c0, load = time.perf_counter(), time.process_time(), _load()
            net = nesi.fit(ax, m, lod=lod, steps=steps, n_samples=20_000, learning_rate=1e-3)
            t_fit, c_fit = time.perf_counter() - t, time.process_time() - c0
            nm = nesi.to_mesh(net, resolution=resolution)
            cd = _cd(nm, m)
            print(
                f"[{name}] NESI lod {lod}: {nesi.param_count(net)} parameters, fit {t_fit:.0f} s wall / {c_fit:.0f} s CPU "
                f"({steps} steps, {load} -> {_load()}), CD-L1x1000 {cd:.3f} vs ESI {cd_esi:.3f} ({cd / cd_esi:.2f}x), "
                f"self {cd_self:.3f}, watertight {metrics.manifold_report(nm).watertight}"
            )
            if siren and lod == 1:
                t, c0, load = time.perf_counter(), time.process_time(), _load()
                snet, c, s, n_par, per_step = _siren3d_fit(m, nesi.param_count(net), steps)
                t_fit, c_fit = time.perf_counter() - t, time.process_time() - c0
                sm = _siren3d_mesh(snet, c, s)
                cd_s = _cd(sm, m)
                print(
                    f"[{name}] SIREN-3D: {n_par} parameters, fit {t_fit:.0f} s wall / {c_fit:.0f} s CPU ({steps} steps, "
                    f"{load} -> {_load()}), mesh 192^3 {sm.n_faces} faces, CD-L1x1000 {cd_s:.3f}; "
                    f"NESI {cd:.3f} -> {'NESI' if cd < cd_s else 'SIREN'} wins"
                )
    if "mug" not in shapes or siren:
        return
    net = nesi.fit(ax, m, lod=4, steps=1, n_samples=2000)
    p = np.random.default_rng(0).uniform(-1, 1, (1_000_000, 3))
    nesi.occupancy(net, p[:1000]).block_until_ready()
    t, _ = _best(lambda: nesi.occupancy(net, p).block_until_ready(), repeats=2)
    print(
        f"nesi level-4 occupancy ({len(net.heights)} HFs, {nesi.param_count(net)} parameters): "
        f"{1e6 / t / 1e6:.2f} M points/s ({jax.devices()[0].platform})"
    )


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("cases", nargs="*", default=["bvh", "depth", "select", "nesi"])
    ap.add_argument("--shapes", nargs="*", default=["mug", "knot100k"])
    ap.add_argument("--max-hf", type=int, default=3)
    ap.add_argument("--n-dhf", type=int, default=50, help="Fibonacci DHF candidates (paper: 50)")
    ap.add_argument("--n-hf", type=int, default=80, help="Fibonacci HF candidates (paper: 80)")
    ap.add_argument("--steps", type=int, default=1000)
    ap.add_argument("--lods", type=int, nargs="*", default=[1, 2])
    ap.add_argument("--resolution", type=int, default=256, help="meshing resolution of the `siren` case")
    ap.add_argument("--nesi-shapes", nargs="*", default=list(NESI_SHAPES), help="shapes of the `siren` case")
    args = ap.parse_args(argv)
    if "bvh" in args.cases:
        bench_bvh()
    if "depth" in args.cases:
        bench_depth()
    if "select" in args.cases:
        bench_select(args.shapes, args.max_hf, args.n_dhf, args.n_hf)
    if "levels" in args.cases:
        bench_levels(args.shapes, args.max_hf, args.n_dhf, args.n_hf)
    if "nesi" in args.cases:
        bench_nesi(args.steps, args.lods)
    if "siren" in args.cases:
        bench_nesi(args.steps, args.lods, args.nesi_shapes, siren=True, resolution=args.resolution)
    return 0


if __name__ == "__main__":
    sys.exit(main())
