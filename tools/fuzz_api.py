"""Fuzzes the public entry points of every system with hostile arguments.

For each entry point below, one argument at a time is replaced by a hostile value (NaN,
Inf, 1e80 and subnormal coordinates; bool, complex, string and object arrays; wrong shapes;
empty arrays; int64 indices beyond 2^31; parameters that are NaN, Inf, negative, zero,
1e80, 2.5, True, a string, None, 2^31, 2^63 or a list), eagerly and, for array arguments,
under `jax.jit` with the argument traced. Every call runs in its own forked process (from
one that imported voxax without starting XLA; see `tests/hostile/_forked.py`), with a time
limit and an address-space limit, and is classified:

- `error`: an exception whose first line names voxax (`voxax.<ns>.<fn>: ...`, or the
  kernel's `voxax...` under jit) in a single line: the expected outcome for most cases;
- `returned`: the call returned; its float outputs are scanned, and a non-finite value is
  reported as `nonfinite` (to be judged: ray misses are `inf` on purpose);
- `raw`: an exception without voxax's prefix, or a multi-line message (a raw message from
  deep inside);
- `crash` (the child died) and `hang` (it ran past the limit, or past the memory limit).

Run from the repository root (`PYTHONPATH=src` when voxax is not installed):

    python tools/fuzz_api.py                     # every entry point; prints a summary
    python tools/fuzz_api.py --only closest_points,winding_number --show returned
    python tools/fuzz_api.py --json fuzz.json    # every outcome

It exits 1 when any call is `raw`, `crash` or `hang`, else 0 (`nonfinite` results are
listed for review, not counted as failures).
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "tests" / "hostile"))

# Built in every child before its call (numpy and voxax; XLA starts in the child).
SETUP = """
import jax, jax.numpy as jnp, numpy as np
jax.config.update("jax_enable_x64", True)
import voxax
from voxax import cvt, energies, esi, fc, fields, io, metrics, raster
BALL = voxax.data.icosphere(1, radius=0.5)
V, F = np.asarray(BALL.vertices, np.float64), np.asarray(BALL.faces, np.int32)
G = voxax.Grid.cube(8)
P = np.random.default_rng(0).uniform(-0.9, 0.9, (5, 3))
D = np.random.default_rng(1).normal(size=(5, 3))
S = np.asarray(fields.sphere(np.asarray(G.centers()), 0.5))
W = np.clip(0.5 - S * 4.0, 0.0, 1.0)
SPH = lambda params, x: fields.sphere(x, 0.5)
"""

# Hostile replacements, by the kind of the argument they replace (Python expressions,
# evaluated in the child after SETUP; `X` is the valid value being replaced).
ARRAYS = {
    "NaN": "np.where(np.arange(np.size(X)).reshape(np.shape(X)) == 1, np.nan, X)",
    "Inf": "np.where(np.arange(np.size(X)).reshape(np.shape(X)) == 1, np.inf, X)",
    "1e80": "np.asarray(X, np.float64) * 1e80",
    "subnormal": "np.asarray(X, np.float64) * 1e-310",
    "bool": "np.asarray(X) > 0",
    "complex": "np.asarray(X, np.complex128)",
    "string": "np.asarray(X).astype(str)",
    "object": "np.asarray(X).astype(object)",
    "1-D": "np.asarray(X).reshape(-1)",
    "empty": "np.asarray(X)[:0]",
    "wrong width": "np.asarray(X)[..., :1]",
}
INDICES = {
    "beyond 2^31": "np.asarray(X, np.int64) + 2**31",
    "negative": "np.asarray(X, np.int64) - 1000",
    "float": "np.asarray(X, np.float64) + 0.5",
    "bool": "np.asarray(X) > 0",
    "1-D": "np.asarray(X).reshape(-1)",
    "empty": "np.asarray(X)[:0]",
}
SCALARS = {
    "NaN": "float('nan')", "Inf": "float('inf')", "-1": "-1", "0": "0", "1e80": "1e80",
    "2.5": "2.5", "True": "True", "string": "'2'", "None": "None", "2^31": "2**31",
    "2^63": "2**63", "list": "[1, 2]",
}

# Entry points: (name, call template with {a} placeholders, {argument: (kind, valid value)}).
# kind: "array" (coordinates / samples), "index" (face indices), "scalar" (parameters).
A, IX, K = "array", "index", "scalar"
ENTRIES = [
    ("voxelize", "voxax.voxelize({vertices}, {faces}, G)", {"vertices": (A, "V"), "faces": (IX, "F")}),
    ("voxelize_sparse", "voxax.voxelize_sparse({vertices}, {faces}, G, capacity={capacity})",
     {"vertices": (A, "V"), "faces": (IX, "F"), "capacity": (K, "None")}),
    ("voxelize_mc", "voxax.voxelize_mc({vertices}, {faces}, G, key=0, samples={samples})",
     {"vertices": (A, "V"), "faces": (IX, "F"), "samples": (K, "8")}),
    ("box_filter", "voxax.box_filter({W}, {factor})", {"W": (A, "W"), "factor": (K, "2")}),
    ("isosurface", "voxax.isosurface({values}, G, {level}, threads={threads})",
     {"values": (A, "S"), "level": (K, "0.0"), "threads": (K, "1")}),
    ("isosurface_fn", "voxax.isosurface_fn(SPH, None, G, {level}, chunk={chunk})",
     {"level": (K, "0.0"), "chunk": (K, "4096")}),
    ("isosurface_topology", "voxax.isosurface_topology({values}, G, {level})",
     {"values": (A, "S"), "level": (K, "0.0")}),
    ("closest_points", "voxax.closest_points(({vertices}, {faces}), {points}, threads={threads})",
     {"vertices": (A, "V"), "faces": (IX, "F"), "points": (A, "P"), "threads": (K, "1")}),
    ("first_hits", "voxax.first_hits(({vertices}, {faces}), {origins}, {directions}, t_max={t_max})",
     {"vertices": (A, "V"), "faces": (IX, "F"), "origins": (A, "P"), "directions": (A, "D"),
      "t_max": (K, "10.0")}),
    ("any_hits", "voxax.any_hits(({vertices}, {faces}), {origins}, {directions})",
     {"vertices": (A, "V"), "faces": (IX, "F"), "origins": (A, "P"), "directions": (A, "D")}),
    ("all_hits", "voxax.all_hits(({vertices}, {faces}), {origins}, {directions})",
     {"vertices": (A, "V"), "faces": (IX, "F"), "origins": (A, "P"), "directions": (A, "D")}),
    ("BVH.closest", "voxax.BVH({vertices}, {faces}).closest_points({points}, max_distance={max_distance})",
     {"vertices": (A, "V"), "faces": (IX, "F"), "points": (A, "P"), "max_distance": (K, "1.0")}),
    ("winding_number", "voxax.winding_number({vertices}, {faces}, {points}, chunk_size={chunk_size})",
     {"vertices": (A, "V"), "faces": (IX, "F"), "points": (A, "P"), "chunk_size": (K, "None")}),
    ("nearest_neighbors", "voxax.nearest_neighbors({points}, {queries}, {k})",
     {"points": (A, "V"), "queries": (A, "P"), "k": (K, "2")}),
    ("intersections", "voxax.intersections({vertices}, {faces})", {"vertices": (A, "V"), "faces": (IX, "F")}),
    ("raster.line_crossings", "raster.line_crossings({vertices}, {faces}, G, {axis})",
     {"vertices": (A, "V"), "faces": (IX, "F"), "axis": (K, "2")}),
    ("fc.encode", "fc.encode({vertices}, {faces}, G, lambda_n={lambda_n})",
     {"vertices": (A, "V"), "faces": (IX, "F"), "lambda_n": (K, "1.0")}),
    ("fc.pieces", "fc.pieces({vertices}, {faces}, G)", {"vertices": (A, "V"), "faces": (IX, "F")}),
    ("cvt.fragments", "cvt.fragments(({vertices}, {faces}), G, iterations={iterations})",
     {"vertices": (A, "V"), "faces": (IX, "F"), "iterations": (K, "30")}),
    ("esi.depth_map", "esi.depth_map({vertices}, {faces}, [0.0, 0.0, 1.0], resolution={resolution})",
     {"vertices": (A, "V"), "faces": (IX, "F"), "resolution": (K, "16")}),
    ("metrics.hausdorff", "metrics.hausdorff(({vertices}, {faces}), BALL, n={n})",
     {"vertices": (A, "V"), "faces": (IX, "F"), "n": (K, "500")}),
    ("metrics.chamfer", "metrics.chamfer(BALL, ({vertices}, {faces}), n={n})",
     {"vertices": (A, "V"), "faces": (IX, "F"), "n": (K, "500")}),
    ("metrics.sample_surface", "metrics.sample_surface(({vertices}, {faces}), {n}, key=0)",
     {"vertices": (A, "V"), "faces": (IX, "F"), "n": (K, "100")}),
    ("metrics.triangle_quality", "metrics.triangle_quality(({vertices}, {faces}))",
     {"vertices": (A, "V"), "faces": (IX, "F")}),
    ("metrics.manifold_report", "metrics.manifold_report(({vertices}, {faces}))",
     {"vertices": (A, "V"), "faces": (IX, "F")}),
    ("metrics.iou", "metrics.iou({a}, W, G, threshold={threshold})", {"a": (A, "W"), "threshold": (K, "0.5")}),
    ("io.normalize", "io.normalize(({vertices}, {faces}), {max_abs})",
     {"vertices": (A, "V"), "faces": (IX, "F"), "max_abs": (K, "0.8")}),
    ("energies.volume", "energies.volume({W}, G)", {"W": (A, "W")}),
    ("energies.silhouettes", "energies.silhouettes({W}, {w})", {"W": (A, "W"), "w": (K, "1000.0")}),
    ("energies.bandsaw_cut", "energies.bandsaw_cut({W}, {w})", {"W": (A, "W"), "w": (K, "1000.0")}),
    ("energies.self_intersection", "energies.self_intersection({W}, {eps})", {"W": (A, "W"), "eps": (K, "1e-3")}),
    ("energies.height_field_hull", "energies.height_field_hull({W}, {axis}, {w})",
     {"W": (A, "W"), "axis": (K, "2"), "w": (K, "1000.0")}),
    ("energies.fold_periodic", "energies.fold_periodic({W}, {blocks})", {"W": (A, "W"), "blocks": (K, "2")}),
    ("energies.mellowmax", "energies.mellowmax({x}, {w})", {"x": (A, "W"), "w": (K, "1000.0")}),
    ("fields.chebyshev", "fields.chebyshev({points}, {degree})", {"points": (A, "P"), "degree": (K, "8")}),
    ("fields.gyroid", "fields.gyroid({points}, {period})", {"points": (A, "P"), "period": (K, "1.0")}),
    ("data.icosphere", "voxax.data.icosphere({subdivisions})", {"subdivisions": (K, "1")}),
    ("data.large", "voxax.data.large({n_faces_target})", {"n_faces_target": (K, "2000")}),
]

_MARK = "@@voxax-fuzz@@"


def cases(only: set | None):
    """`(entry, argument, label, jit, code)` of every case."""
    out = []
    for name, template, args in ENTRIES:
        if only and name not in only:
            continue
        for arg, (kind, valid) in args.items():
            table = {A: ARRAYS, IX: INDICES, K: SCALARS}[kind]
            for label, expr in table.items():
                hostile = f"(lambda X: {expr})({valid})"
                filled = {a: (hostile if a == arg else v) for a, (_, v) in args.items()}
                eager = template.format(**filled)
                out.append((name, arg, label, False, "_result = " + eager))
                if kind != K and label not in ("string", "object"):  # the same call, the argument traced
                    # (string and object arrays cannot be traced: jax.jit refuses them itself)
                    filled[arg] = "_x"
                    call = template.format(**filled)
                    out.append((name, arg, label, True, f"_x0 = {hostile}\n_result = jax.jit(lambda _x: {call})(_x0)"))
    return out


def _leaves_finite(result) -> bool:
    import jax
    import numpy as np

    for leaf in jax.tree_util.tree_leaves(result):
        try:
            a = np.asarray(leaf)
        except Exception:
            continue
        if a.dtype.kind in "fc" and a.size and not np.isfinite(a).all():
            return False
    return True


def _body(code: str, memory: int):
    def body():
        resource.setrlimit(resource.RLIMIT_AS, (memory, memory))
        try:
            env = {}
            exec(SETUP, env)
            exec(code, env)
            import jax

            result = jax.block_until_ready(env.get("_result"))
            out = {"status": "returned" if _leaves_finite(result) else "nonfinite"}
        except MemoryError as err:
            out = {"status": "error" if "voxax" in str(err) else "raw", "type": "MemoryError", "message": str(err)}
        except BaseException as err:
            msg = str(err)
            lines = [ln for ln in msg.strip().splitlines() if ln.strip()]
            named = bool(lines) and "voxax" in lines[0]
            out = {"status": "error" if named and len(lines) == 1 else "raw", "type": type(err).__name__,
                   "message": msg[:400]}
        print("\n" + _MARK + json.dumps(out), flush=True)
        return 0

    return body


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--only", default="", help="comma-separated entry names")
    ap.add_argument("--limit", type=float, default=60.0, help="seconds per call")
    ap.add_argument("--memory-gib", type=float, default=10.0, help="address-space limit per call")
    ap.add_argument("--json", default=None, help="write every outcome here")
    ap.add_argument("--show", default="raw,crash,hang,nonfinite", help="outcomes to list")
    args = ap.parse_args()
    from _forked import run_forked

    import voxax  # noqa: F401  (imported once; XLA starts in each child)

    todo = cases({s for s in args.only.split(",") if s} or None)
    memory = int(args.memory_gib * 2**30)
    results, start = [], time.monotonic()
    for name, arg, label, jit, code in todo:
        status, seconds, stdout, stderr = run_forked(_body(code, memory), args.limit)
        if status is None:
            out = {"status": "hang"}
        elif status != 0 or _MARK not in stdout:
            out = {"status": "crash", "exit": status, "stderr": stderr[-400:]}
        else:
            out = json.loads(stdout[stdout.rindex(_MARK) + len(_MARK):])
        out.update(entry=name, argument=arg, value=label, jit=jit, seconds=round(seconds, 2))
        results.append(out)
    counts: dict = {}
    for r in results:
        counts[r["status"]] = counts.get(r["status"], 0) + 1
    print(f"{len(results)} calls over {len({r['entry'] for r in results})} entry points in "
          f"{time.monotonic() - start:.0f} s: " + ", ".join(f"{k} {v}" for k, v in sorted(counts.items())))
    show = set(args.show.split(","))
    for r in results:
        if r["status"] in show:
            where = f"{r['entry']} {r['argument']}={r['value']}{' (jit)' if r['jit'] else ''}"
            print(f"  {r['status']:9s} {where}: {r.get('type', '')} {r.get('message', r.get('stderr', ''))[:200]!r}")
    if args.json:
        Path(args.json).write_text(json.dumps(results, indent=1))
    bad = sum(counts.get(k, 0) for k in ("raw", "crash", "hang"))
    return 1 if bad else 0


if __name__ == "__main__":
    os.environ.setdefault("MPLBACKEND", "Agg")
    sys.exit(main())
