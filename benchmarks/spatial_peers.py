"""voxax's spatial queries against the libraries users pick for them, side by side.

Each query runs on the same inputs in voxax and in the peers that are installed (benchmark
only, never dependencies of voxax): first hits against embree (`embreex`), fcpw and
point-cloud-utils' `RayMeshIntersector` (embree inside); exact winding numbers against
libigl's `winding_number` (and the approximate `fast_winding_number` of libigl and of
point-cloud-utils); closest points against libigl's AABB (`point_mesh_squared_distance`),
fcpw and point-cloud-utils' `closest_points_on_mesh`; k nearest neighbours against
pykdtree, scipy's cKDTree and point-cloud-utils' `k_nearest_neighbors`. fcpw computes in
float32 (its vectorised BVH); its scene is built once, outside the timed calls, as voxax's
BVH is, and the builds are timed on their own rows. Calls alternate (voxax, peer, voxax,
peer, ...) after a warm-up, the order rotating every round, and the median of `--repeat`
rounds is reported (builds: one call each); results are checked for agreement. The
1-minute load average is printed before and after.

    pip install embreex libigl pykdtree fcpw point-cloud-utils   # the peers

`--cores 1` pins the process to one core (`os.sched_setaffinity`), which holds every
library, thread pools included, to one thread; voxax is also passed `threads`.

    nice -n 10 python benchmarks/spatial_peers.py --faces 300000 --rays 300000 --cores 1
    nice -n 10 python benchmarks/spatial_peers.py --faces 1500000 --rays 1000000 --first-hits-only

`--only winding` (or `rays`, `closest`, `knn`; repeatable) runs one group of rows. The
winding rows include voxax's error-bounded `accuracy=` mode against libigl's
`fast_winding_number` at equal accuracy (see `winding_accuracy`). `--first-hits-only` runs the first-hit row alone.
"""

from __future__ import annotations

import argparse
import os
import time

import numpy as np

import voxax


def _best(fn, repeat):
    best, out = np.inf, None
    for _ in range(repeat):
        t = time.perf_counter()
        out = fn()
        best = min(best, time.perf_counter() - t)
    return best, out


def _interleave(fns, repeat):
    """{name: (median seconds, last result)}: one warm-up call each, then `repeat` rounds
    of calls alternating (the order rotating every round)."""
    names = list(fns)
    outs = {k: fns[k]() for k in names}
    times = {k: [] for k in names}
    for r in range(repeat):
        for k in names[r % len(names) :] + names[: r % len(names)]:
            t = time.perf_counter()
            outs[k] = fns[k]()
            times[k].append(time.perf_counter() - t)
    return {k: (float(np.median(times[k])), outs[k]) for k in names}


def _row(query, peer, tv, tp, agree):
    print(f"| {query} | {peer} | {tv:.3f} s | {tp:.3f} s | {tp / tv:.2f}x | {agree} |", flush=True)


def _fcpw_scene(v, f):
    """An fcpw scene of the triangles (float32 vertices), its vectorised SAH BVH built; None
    when fcpw is not installed."""
    try:
        import fcpw
    except ImportError:
        return None
    scene = fcpw.scene_3D()
    scene.set_object_count(1)
    scene.set_object_vertices(np.asfortranarray(v, np.float32), 0)
    scene.set_object_triangles(np.asfortranarray(f, np.int32), 0)
    scene.build(fcpw.aggregate_type.bvh_surface_area, True)
    return scene


def _fcpw_results(interactions):
    """(distance or t, primitive index) arrays of an fcpw interaction list (-1 where none)."""
    d = np.array([it.d for it in interactions], np.float64)
    prim = np.array([it.primitive_index for it in interactions], np.int64)
    return d, prim


def first_hits_more(mesh, n_rays, threads, repeat, rng):
    """First hits against fcpw and point-cloud-utils (embree through its own binding)."""
    v, f = np.asarray(mesh.vertices), np.asarray(mesh.faces)
    lo, hi = v.min(0), v.max(0)
    o = rng.uniform(lo, hi, size=(n_rays, 3))
    d = rng.normal(size=(n_rays, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    bvh = voxax.BVH(mesh)
    fns = {"voxax": lambda: bvh.first_hits(o, d, threads=threads).face}
    tb, scene = _best(lambda: _fcpw_scene(v, f), 1)
    if scene is not None:
        import fcpw

        o32, d32 = np.asfortranarray(o, np.float32), np.asfortranarray(d, np.float32)
        far = np.full(n_rays, np.inf, np.float32)

        def fcpw_hits():  # the interactions are read out after the timed call
            out = fcpw.interaction_3D_list()
            scene.intersect(o32, d32, far, out)
            return out

        fns["fcpw"] = fcpw_hits
        _row(f"BVH build, {len(f)} faces", "fcpw (SAH, vectorised)", _best(lambda: voxax.BVH(mesh), 1)[0], tb, "-")
    try:
        import point_cloud_utils as pcu

        pcu_rays = pcu.RayMeshIntersector(v, f.astype(np.int32))
        fns["point-cloud-utils"] = lambda: pcu_rays.intersect_rays(o, d)[0]
    except ImportError:
        pass
    r = _interleave(fns, repeat)
    if "fcpw" in r:
        r["fcpw"] = (r["fcpw"][0], _fcpw_results(r["fcpw"][1])[1])
    for name in fns:
        if name != "voxax":
            same = np.mean(np.asarray(r[name][1]) == np.where(r["voxax"][1] >= 0, r["voxax"][1], -1))
            _row(f"first hits, {n_rays} rays", name, r["voxax"][0], r[name][0], f"same face {100 * same:.2f}% of rays")


def first_hits(mesh, n_rays, threads, repeat, rng):
    try:
        from embreex import rtcore_scene
        from embreex.mesh_construction import TriangleMesh
    except ImportError:
        print("| first hits | embree | (embreex not installed) |")
        return
    v, f = np.asarray(mesh.vertices), np.asarray(mesh.faces)
    lo, hi = v.min(0), v.max(0)
    o = rng.uniform(lo, hi, size=(n_rays, 3))
    d = rng.normal(size=(n_rays, 3))
    tb, bvh = _best(lambda: voxax.BVH(mesh), 1)

    def build_embree():
        scene = rtcore_scene.EmbreeScene()
        TriangleMesh(scene, v[f].astype(np.float32))
        return scene

    te, scene = _best(build_embree, 1)
    o32, d32 = o.astype(np.float32), d.astype(np.float32)
    r = _interleave(
        {
            "voxax": lambda: bvh.first_hits(o, d, threads=threads),
            "embree": lambda: scene.run(o32, d32, output=1),
        },
        repeat,
    )
    hv, he = r["voxax"][1], r["embree"][1]
    same = np.mean(hv.face == he["primID"])
    both = (hv.face >= 0) & (he["primID"] >= 0)
    t_err = np.max(np.abs(hv.t[both] - he["tfar"][both]) / np.maximum(hv.t[both], 1e-12)) if both.any() else 0
    agree = f"same face {100 * same:.2f}% of rays, t rel. diff <= {t_err:.1e} where both hit"
    _row(f"BVH build, {len(f)} faces", "embree", tb, te, "-")
    _row(f"first hits, {n_rays} rays", "embree", r["voxax"][0], r["embree"][0], agree)


def _winding_inputs(mesh, n_points, rng, cut=0.0):
    """The mesh's vertices and faces (the last fraction `cut` of the faces removed, which
    opens the surface) and `n_points` points uniform in its box grown by 10%."""
    v = np.ascontiguousarray(mesh.vertices, np.float64)
    f = np.ascontiguousarray(mesh.faces, np.int64)
    f = f[: len(f) - int(round(len(f) * cut))]
    lo, hi = v.min(0), v.max(0)
    p = rng.uniform(lo - 0.1 * (hi - lo), hi + 0.1 * (hi - lo), size=(n_points, 3))
    return v, f, p


def winding(mesh, n_points, threads, repeat, rng, open_faces=False):
    try:
        import igl
    except ImportError:
        print("| winding numbers | libigl | (libigl not installed) |")
        return
    v, f, p = _winding_inputs(mesh, n_points, rng, 0.1 if open_faces else 0.0)
    r = _interleave(
        {
            "voxax": lambda: np.asarray(voxax.winding_number(v, f, p, threads=threads)),
            "igl": lambda: igl.winding_number(v, f.astype(np.int32), p),
        },
        repeat,
    )
    wv, wi = r["voxax"][1], r["igl"][1]
    kind = "open" if open_faces else "closed"
    _row(
        f"exact winding numbers, {kind}, {len(f)} faces, {n_points} points",
        "libigl winding_number",
        r["voxax"][0],
        r["igl"][0],
        f"max |diff| {np.max(np.abs(wv - wi)):.1e}",
    )
    fast = {"libigl fast_winding_number": lambda: igl.fast_winding_number(v, f.astype(np.int32), p)}
    try:
        import point_cloud_utils as pcu

        fast["point-cloud-utils triangle_soup_fast_winding_number"] = lambda: pcu.triangle_soup_fast_winding_number(
            v, f.astype(np.int32), p
        )
    except ImportError:
        pass
    for name, fn in fast.items():
        tf, wf = _best(fn, repeat)
        _row(
            f"winding numbers, {kind}, {len(f)} faces, {n_points} points",
            name,
            r["voxax"][0],
            tf,
            f"fast's max |error| {np.max(np.abs(np.asarray(wf) - wv)):.1e}",
        )


def winding_accuracy(mesh, n_points, threads, repeat, rng, cut=0.1):
    """voxax's error-bounded winding numbers (`accuracy=`) against libigl's
    `fast_winding_number` at equal accuracy, on an open mesh (a fraction `cut` of the faces
    removed): libigl's max error against the exact sum is measured first and voxax is run
    with `accuracy` set to it, so voxax's error is guaranteed to be at most libigl's
    measured one; both times and both measured max errors are reported. A second voxax row
    takes the loosest `accuracy` (a multiple of libigl's error) whose measured max error
    still stays below libigl's (not guaranteed, for comparison)."""
    try:
        import igl
    except ImportError:
        print("| winding numbers at equal accuracy | libigl | (libigl not installed) |")
        return
    v, f, p = _winding_inputs(mesh, n_points, rng, cut)
    f32 = f.astype(np.int32)
    exact = np.asarray(voxax.winding_number(v, f, p, threads=threads))
    fast = np.asarray(igl.fast_winding_number(v, f32, p))
    e_igl = float(np.max(np.abs(fast - exact)))
    loose = e_igl
    for k in (2, 5, 10, 20, 50):  # the loosest accuracy whose measured error stays below libigl's
        w = np.asarray(voxax.winding_number(v, f, p, accuracy=k * e_igl, threads=threads))
        if np.max(np.abs(w - exact)) > e_igl:
            break
        loose = k * e_igl
    r = _interleave(
        {
            "bound": lambda: np.asarray(voxax.winding_number(v, f, p, accuracy=e_igl, threads=threads)),
            "loose": lambda: np.asarray(voxax.winding_number(v, f, p, accuracy=loose, threads=threads)),
            "exact": lambda: np.asarray(voxax.winding_number(v, f, p, threads=threads)),
            "igl": lambda: igl.fast_winding_number(v, f32, p),
        },
        repeat,
    )
    what = f"winding numbers, open ({cut:.0%} of faces cut), {len(f)} faces, {n_points} points"
    for key, label in (
        ("bound", f"accuracy={e_igl:.1e} (libigl's error: guaranteed)"),
        ("loose", f"accuracy={loose:.1e} (measured error below libigl's)"),
        ("exact", "exact"),
    ):
        err = np.max(np.abs(r[key][1] - exact))
        _row(
            f"{what}, voxax {label}",
            "libigl fast_winding_number",
            r[key][0],
            r["igl"][0],
            f"max error voxax {err:.1e}, libigl {e_igl:.1e}",
        )


def closest(mesh, n_points, threads, repeat, rng):
    try:
        import igl
    except ImportError:
        print("| closest points | libigl | (libigl not installed) |")
        return
    v = np.ascontiguousarray(mesh.vertices, np.float64)
    f = np.ascontiguousarray(mesh.faces, np.int32)
    p = v[rng.integers(0, len(v), n_points)] + rng.normal(scale=0.01, size=(n_points, 3))
    bvh = voxax.BVH(mesh)
    fns = {
        "voxax": lambda: np.asarray(bvh.closest_points(p, threads=threads).distance),
        "libigl AABB (builds in its call)": lambda: np.sqrt(igl.point_mesh_squared_distance(p, v, f)[0]),
    }
    scene = _fcpw_scene(v, f)
    if scene is not None:
        import fcpw

        p32, r2 = np.asfortranarray(p, np.float32), np.full(len(p), np.inf, np.float32)

        def fcpw_closest():  # the interactions are read out after the timed call
            out = fcpw.interaction_3D_list()
            scene.find_closest_points(p32, r2, out)
            return out

        fns["fcpw (prebuilt, float32)"] = fcpw_closest
    try:
        import point_cloud_utils as pcu

        fns["point-cloud-utils (builds in its call)"] = lambda: pcu.closest_points_on_mesh(p, v, f)[0]
    except ImportError:
        pass
    r = _interleave(fns, repeat)
    fc = "fcpw (prebuilt, float32)"
    if fc in r:
        r[fc] = (r[fc][0], _fcpw_results(r[fc][1])[0])
    for name in fns:
        if name != "voxax":
            _row(
                f"closest points near the surface, {len(f)} faces, {n_points} points (voxax prebuilt)",
                name,
                r["voxax"][0],
                r[name][0],
                f"max |diff| {np.max(np.abs(r['voxax'][1] - np.asarray(r[name][1]))):.1e}",
            )


def knn(n_points, threads, repeat, rng, k=8):
    pts = rng.uniform(size=(n_points, 3))
    q = rng.uniform(size=(n_points, 3))
    fns = {"voxax": lambda: voxax.nearest_neighbors(pts, q, k, threads=threads)[0]}
    try:
        from pykdtree.kdtree import KDTree

        fns["pykdtree"] = lambda: KDTree(pts).query(q, k)[0]
    except ImportError:
        pass
    from scipy.spatial import cKDTree

    fns["cKDTree"] = lambda: cKDTree(pts).query(q, k, workers=threads)[0]
    try:
        import point_cloud_utils as pcu

        fns["point-cloud-utils"] = lambda: pcu.k_nearest_neighbors(q, pts, k, num_threads=threads)[0]
    except ImportError:
        pass
    r = _interleave(fns, repeat)
    for name in fns:
        if name != "voxax":
            diff = np.max(np.abs(r["voxax"][1] - r[name][1]))
            _row(f"k = {k} nearest neighbours, {n_points} points and queries", name, r["voxax"][0], r[name][0],
                 f"max |diff| {diff:.1e}")  # fmt: skip


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--faces", type=int, default=300_000)
    parser.add_argument("--rays", type=int, default=300_000)
    parser.add_argument("--points", type=int, default=100_000)
    parser.add_argument("--cores", type=int, default=1)
    parser.add_argument("--repeat", type=int, default=3)
    parser.add_argument(
        "--only",
        choices=("rays", "winding", "closest", "knn"),
        action="append",
        help="run only these groups of rows (repeatable; default: all)",
    )
    parser.add_argument("--first-hits-only", action="store_true", help="only the first hits against embree")
    args = parser.parse_args(argv)
    only = set(args.only or ("rays", "winding", "closest", "knn"))
    os.sched_setaffinity(0, set(sorted(os.sched_getaffinity(0))[: args.cores]))
    threads = args.cores
    rng = np.random.default_rng(0)
    big = voxax.data.large(args.faces) if "rays" in only else None
    mid = voxax.data.large(min(args.faces, 100_000))
    load = os.getloadavg()[0]
    print(f"{args.cores} core(s), voxax threads={threads}, median of {args.repeat} alternating rounds, load {load:.1f}\n")
    print("| query | peer | voxax | peer | voxax speed-up | agreement |")
    print("|---|---|---|---|---|---|")
    if "rays" in only:
        first_hits(big, args.rays, threads, args.repeat, rng)
        if args.first_hits_only:
            print(f"\n1-minute load average at the end: {os.getloadavg()[0]:.1f}")
            return
        first_hits_more(big, args.rays, threads, args.repeat, rng)
    if "winding" in only:
        winding(mid, args.points, threads, args.repeat, rng)
        winding(voxax.data.large(2_000), args.points // 10, threads, args.repeat, rng, open_faces=True)
        winding_accuracy(voxax.data.large(2_000), args.points // 10, threads, args.repeat, rng)
        winding_accuracy(mid, args.points, threads, args.repeat, rng)
    if "closest" in only:
        closest(mid, args.points, threads, args.repeat, rng)
    if "knn" in only:
        knn(args.points, threads, args.repeat, rng)
    print(f"\n1-minute load average at the end: {os.getloadavg()[0]:.1f}")


if __name__ == "__main__":
    main()
