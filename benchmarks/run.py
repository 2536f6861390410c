#!/usr/bin/env python
"""voxax vs dvx-python (the paper's PyTorch implementation), in one run on one machine.

Run from the repository root in voxax's environment; the peer runs in its own virtual
environment (see benchmarks/README.md):

    python benchmarks/run.py --peer-python /path/to/peer-venv/bin/python
    python benchmarks/run.py --quick --repeats 2          # hand + 100K faces, 128^3 and 256^3
    python benchmarks/run.py --write-readme               # refresh benchmarks/README.md

This driver imports neither jax nor torch: it starts one worker process per
implementation (`_voxax.py` with this interpreter, `_peer.py` with `--peer-python`),
hands them meshes as .npy files and reads their answers as JSON lines on their stdout.
Every (mesh, grid) case gets a fresh pair of workers. For each case it

1. checks that both give the same grid (dvx returns (z, y, x), voxax (x, y, z): the
   comparison transposes) and the same gradient of sum(W**2);
2. times, interleaving the implementations (the order rotates every repeat):
   - fwd: jitted `voxax.voxelize` vs `dvx.torch.voxelize` (each allocates its output),
     plus dvx's raw `voxelize_cf_f32` into a preallocated array ("fwd kernel"; voxax's
     forward already is its kernel plus XLA's allocation);
   - bwd kernel: jitted `voxax.voxelize_corner_gradients` vs raw
     `voxelize_backward_cf_f32`, both with the fixed cotangent 2 W;
   - e2e: jitted `value_and_grad(sum(voxelize(v)**2))` vs `voxelize` +
     `(W**2).sum().backward()`;
   - floor: jitted `jnp.full(grid.shape, 1.0, float32)` (and `torch.full` for dvx): the
     time to produce an array of the grid's size;
3. measures the peak RSS of one e2e run in a fresh worker per implementation, one at a
   time, as a multiple of the grid's bytes.

Results: a table on stdout, `results.json` and `plot.png` in --out-dir.
"""

from __future__ import annotations

import argparse
import datetime
import json
import math
import os
import platform
import shlex
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
README = HERE / "README.md"
RESULTS_DIR = HERE / "results"
BEGIN, END = "<!-- results -->", "<!-- /results -->"

MESHES = {"hand": ("hand", None), "100k": ("large", 100_000), "1m": ("large", 1_000_000)}
QUICK_MESHES, QUICK_SIZES = ["hand", "100k"], [128, 256]
ALL_OPS = ["fwd", "bwd_kernel", "e2e", "floor"]
# What each timing phase runs, per implementation.
PHASES = {
    "fwd": [("peer", "fwd"), ("peer", "fwd_kernel"), ("voxax", "fwd")],
    "bwd_kernel": [("peer", "bwd_kernel"), ("voxax", "bwd_kernel")],
    "e2e": [("peer", "e2e"), ("voxax", "e2e")],
    "floor": [("peer", "floor"), ("voxax", "floor")],
}
# Rough memory a phase needs, in grid sizes (both workers together; see the README).
PHASE_MEMORY = {"fwd": 3.0, "bwd_kernel": 4.5, "e2e": 5.0, "floor": 1.5, "check": 8.0}
GIB = 2**30


# ----------------------------------------------------------------------------------------
# Workers
# ----------------------------------------------------------------------------------------


class WorkerError(RuntimeError):
    pass


class Worker:
    """A worker process answering JSON-line requests (see _common.serve)."""

    def __init__(self, name: str, python: str, script: str, env: dict | None = None):
        self.name = name
        self.proc = subprocess.Popen(
            [python, str(HERE / script)],
            stdin=subprocess.PIPE,
            stdout=subprocess.PIPE,
            text=True,
            bufsize=1,
            env=env,
        )
        self.last_rss_mib = None

    def call(self, cmd: str, **kwargs):
        try:
            self.proc.stdin.write(json.dumps({"cmd": cmd, **kwargs}) + "\n")
            self.proc.stdin.flush()
        except BrokenPipeError:
            pass
        line = self.proc.stdout.readline()
        if not line:
            code = self.proc.wait()
            why = " (killed: out of memory?)" if code in (-9, 137) else ""
            raise WorkerError(f"{self.name} worker exited with code {code}{why} during {cmd!r}")
        reply = json.loads(line)
        self.last_rss_mib = reply.get("rss_mib")
        if not reply.pop("ok"):
            sys.stderr.write(reply.get("traceback", ""))
            raise WorkerError(f"{self.name} worker: {cmd!r} failed: {reply['error']}")
        return reply

    def close(self):
        if self.proc.poll() is None:
            try:
                self.proc.stdin.write(json.dumps({"cmd": "exit"}) + "\n")
                self.proc.stdin.close()
                self.proc.wait(timeout=120)
            except (BrokenPipeError, OSError, subprocess.TimeoutExpired):
                self.proc.kill()
                self.proc.wait()

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()


class Pythons:
    def __init__(self, voxax_python: str, peer_python: str):
        self.voxax, self.peer = voxax_python, peer_python

    def start(self, which: str) -> Worker:
        if which == "voxax":
            return Worker("voxax", self.voxax, "_voxax.py")
        return Worker("dvx", self.peer, "_peer.py")


# ----------------------------------------------------------------------------------------
# Machine information
# ----------------------------------------------------------------------------------------


def meminfo_bytes(field: str) -> int | None:
    try:
        with open("/proc/meminfo") as fh:
            for line in fh:
                if line.startswith(field + ":"):
                    return int(line.split()[1]) * 1024
    except OSError:
        pass
    return None


def machine_info() -> dict:
    cpu = platform.processor() or platform.machine()
    try:
        with open("/proc/cpuinfo") as fh:
            for line in fh:
                if line.startswith("model name"):
                    cpu = line.split(":", 1)[1].strip()
                    break
    except OSError:
        pass
    info = {
        "cpu": cpu,
        "logical_cores": os.cpu_count(),
        "usable_cores": len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count(),
        "memory_gib": round((meminfo_bytes("MemTotal") or 0) / GIB, 1),
        "memory_available_gib_at_start": round((meminfo_bytes("MemAvailable") or 0) / GIB, 1),
        "os": f"{platform.system()} {platform.release()}",
        "load_average_at_start": [round(x, 2) for x in os.getloadavg()],
        "date": datetime.datetime.now().astimezone().isoformat(timespec="seconds"),
    }
    for path in ("/sys/fs/cgroup/memory.max", "/sys/fs/cgroup/cpu.max"):
        try:
            info[Path(path).name] = Path(path).read_text().strip()
        except OSError:
            pass
    return info


def command_line() -> str:
    env = " ".join(f"{k}={shlex.quote(os.environ[k])}" for k in ("PYTHONPATH", "VOXAX_PEER_PYTHON") if k in os.environ)
    cmd = shlex.join([sys.executable, *sys.argv])
    return f"{env} {cmd}".strip()


# ----------------------------------------------------------------------------------------
# Correctness
# ----------------------------------------------------------------------------------------


def compare_grids(voxax_path: str, peer_path: str, atol: float) -> dict:
    """Max |W_voxax.transpose(2, 1, 0) - W_dvx| over the grid, in slabs (memory-mapped).

    voxax's W is (..., x, y, z); dvx's is (..., z, y, x)."""
    W = np.load(voxax_path, mmap_mode="r")
    P = np.load(peer_path, mmap_mode="r")
    if W.ndim == 3:
        W, P = W[None], P[None]
    if W.shape[:1] + W.shape[1:][::-1] != P.shape:
        raise ValueError(f"grid shapes differ: voxax {W.shape}, dvx {P.shape}")
    nb, nx = W.shape[0], W.shape[1]
    step = max(1, (1 << 24) // (W.shape[2] * W.shape[3]))
    best = (-1.0, None)
    untransposed = 0.0
    over = 0
    w_abs = 0.0
    for b in range(nb):
        for i0 in range(0, nx, step):
            w = np.asarray(W[b, i0 : i0 + step])
            p = np.asarray(P[b, :, :, i0 : i0 + step]).transpose(2, 1, 0)
            d = np.abs(w - p)
            k = int(np.argmax(d))
            if d.flat[k] > best[0]:
                loc = np.unravel_index(k, d.shape)
                best = (float(d.flat[k]), (b, i0 + int(loc[0]), int(loc[1]), int(loc[2]), float(w[loc]), float(p[loc])))
            over += int(np.count_nonzero(d > atol))
            w_abs = max(w_abs, float(np.abs(w).max()))
            if W.shape[1:] == P.shape[1:]:  # cubic: also the difference *without* the transpose
                untransposed = max(untransposed, float(np.abs(w - np.asarray(P[b, i0 : i0 + step])).max()))
    b, i, j, k, wv, pv = best[1]
    return {
        "max_abs_diff": best[0],
        "at": {"batch": b, "ijk": [i, j, k], "voxax": wv, "dvx": pv},
        "cells_over_atol": over,
        "cells": int(np.prod(W.shape)),
        "max_abs_value": w_abs,
        "max_abs_diff_without_transpose": untransposed,
        "atol": atol,
        "ok": best[0] <= atol,
    }


def on_grid_planes(vertices_path: str, n: int) -> np.ndarray:
    """Which vertices (as float32, as the workers use them) lie exactly on a cell face of
    the n^3 grid on [-1, 1]^3. There sum(W**2) has a kink (a face lying in a grid plane
    moves voxels on one side or the other), so its gradient is a one-sided choice."""
    v = np.load(vertices_path).astype(np.float32).astype(np.float64)
    t = (v + 1.0) * (n / 2.0)
    return np.any(t == np.round(t), axis=-1)


def compare_grads(voxax_path: str, peer_path: str, rtol: float, on_plane: np.ndarray) -> dict:
    gv = np.load(voxax_path).astype(np.float64)
    gp = np.load(peer_path).astype(np.float64)
    if gv.shape != gp.shape:
        raise ValueError(f"gradient shapes differ: voxax {gv.shape}, dvx {gp.shape}")
    diff = gv - gp
    scale = max(float(np.abs(gp).max()), 1e-300)
    rel_l2 = float(np.linalg.norm(diff) / max(np.linalg.norm(gp), 1e-300))
    off = ~on_plane
    rel_off = float(np.linalg.norm(diff[off]) / max(np.linalg.norm(gp[off]), 1e-300)) if off.any() else 0.0
    per_vertex = np.linalg.norm(diff, axis=-1) / scale
    return {
        "rel_l2": rel_l2,
        "max_abs_diff": float(np.abs(diff).max()),
        "max_abs_diff_over_max_abs": float(np.abs(diff).max() / scale),
        "max_abs": scale,
        "vertices_differing": int(np.count_nonzero(per_vertex > rtol)),
        "vertices_on_grid_planes": int(np.count_nonzero(on_plane)),
        "vertices_differing_off_planes": int(np.count_nonzero((per_vertex > rtol) & off)),
        "rel_l2_off_planes": rel_off,
        "rtol": rtol,
        "ok": rel_l2 <= rtol,
        "ok_off_planes": rel_off <= rtol,
    }


def run_check(workers: dict, n: int, tmp: Path, tag: str, vertices_path: str, args) -> dict:
    """Both implementations in float32 (as timed) and float64; cross comparisons here,
    each one's float32-vs-float64 error in its worker."""
    t0 = time.perf_counter()
    prefix = {impl: str(tmp / f"{tag}_{impl}") for impl in ("voxax", "dvx")}
    x = workers["voxax"].call("check", n=n, prefix=prefix["voxax"])
    p = workers["peer"].call("check", n=n, prefix=prefix["dvx"])
    result = {"n": n}
    on_plane = on_grid_planes(vertices_path, n)
    for bits in (32, 64):
        atol, rtol = (args.grid_atol, args.grad_rtol) if bits == 32 else (args.grid_atol64, args.grad_rtol64)
        result[f"grid{bits}"] = compare_grids(f"{prefix['voxax']}_W{bits}.npy", f"{prefix['dvx']}_W{bits}.npy", atol)
        result[f"grad{bits}"] = compare_grads(f"{prefix['voxax']}_g{bits}.npy", f"{prefix['dvx']}_g{bits}.npy", rtol, on_plane)
        lx, lp = x[f"loss{bits}"], p[f"loss{bits}"]
        result[f"loss{bits}"] = {"voxax": lx, "dvx": lp, "rel_diff": abs(lx - lp) / max(abs(lp), 1e-300)}
        result[f"volume{bits}"] = {"voxax": x[f"volume{bits}"], "dvx": p[f"volume{bits}"]}
    result["f32_vs_f64"] = {
        impl: {"grid_max_abs": r["self_f32_vs_f64_grid_max_abs"], "grad_rel_l2": r["self_f32_vs_f64_grad_rel_l2"]}
        for impl, r in (("voxax", x), ("dvx", p))
    }
    result["dvx_raw_fwd_vs_wrapper_max_abs"] = p["raw_fwd_vs_wrapper_max_abs"]
    result["dvx_raw_bwd_vs_autograd_max_rel"] = p["raw_bwd_vs_autograd_max_rel"]
    err = result["f32_vs_f64"]
    g32, g64, d32, d64 = result["grid32"], result["grid64"], result["grad32"], result["grad64"]
    notes, ok = [], True
    if g32["ok"]:
        notes.append("grids agree")
    elif g64["ok"]:
        worse = max(("voxax", "dvx"), key=lambda i: err[i]["grid_max_abs"])
        notes.append(
            f"float32 grids differ by up to {g32['max_abs_diff']:.2g} (> {args.grid_atol:g}), which is {worse}'s "
            f"float32 rounding: its float32 grid is {err[worse]['grid_max_abs']:.2g} from its float64 grid, and the "
            f"float64 grids agree to {g64['max_abs_diff']:.2g}"
        )
    else:
        ok = False
        notes.append(f"GRIDS DISAGREE: max abs difference {g32['max_abs_diff']:.3g} (float32), {g64['max_abs_diff']:.3g} (float64)")
    if d32["ok"] and d64["ok"]:
        notes.append("gradients agree")
    elif d32["ok_off_planes"] and d64["ok_off_planes"]:
        notes.append(
            f"gradients agree except at vertices lying exactly on a grid plane (float32: {d32['vertices_differing']}, "
            f"float64: {d64['vertices_differing']} vertices differ, of {d32['vertices_on_grid_planes']} on planes): "
            f"sum(W**2) is not differentiable there and the two pick different one-sided values (relative error "
            f"float32 {d32['rel_l2']:.2g}, float64 {d64['rel_l2']:.2g}; without those vertices "
            f"{d32['rel_l2_off_planes']:.2g}, {d64['rel_l2_off_planes']:.2g})"
        )
    elif d64["ok_off_planes"]:
        worse = max(("voxax", "dvx"), key=lambda i: err[i]["grad_rel_l2"])
        notes.append(
            f"float32 gradients differ (relative error {d32['rel_l2']:.2g}), which is {worse}'s float32 rounding: "
            f"float64 gradients agree to {d64['rel_l2_off_planes']:.2g} (off grid planes)"
        )
    else:
        ok = False
        notes.append(f"GRADIENTS DISAGREE: relative error {d32['rel_l2']:.3g} (float32), {d64['rel_l2']:.3g} (float64)")
    result["verdict"] = ("OK: " if ok else "MISMATCH: ") + "; ".join(notes)
    result["ok"] = ok
    result["within_tolerance_f32"] = g32["ok"] and d32["ok"]
    result["seconds"] = time.perf_counter() - t0
    for path in tmp.glob(f"{tag}_*.npy"):
        path.unlink(missing_ok=True)
    return result


# ----------------------------------------------------------------------------------------
# Cases
# ----------------------------------------------------------------------------------------


def memory_guard(phase: str, grid_bytes: int, args) -> str | None:
    need = PHASE_MEMORY[phase] * grid_bytes + 0.5 * GIB
    avail = meminfo_bytes("MemAvailable")
    if avail is not None and avail < need and not args.force:
        return f"skipped: needs ~{need / GIB:.1f} GiB, {avail / GIB:.1f} GiB available (--force to run anyway)"
    return None


def time_case(case: dict, pythons: Pythons, tmp: Path, args, check_cache: dict) -> None:
    n, big = case["n"], case["n"] >= args.big
    repeats = args.repeats_big if big else args.repeats
    warmup = args.warmup if args.warmup is not None else (0 if big else 1)
    case.update(repeats=repeats, warmup=warmup, times={"voxax": {}, "dvx": {}}, skipped={}, rss_mib={})
    started = time.perf_counter()
    workers = {"peer": pythons.start("peer"), "voxax": pythons.start("voxax")}
    try:
        for w in workers.values():
            w.call("load", vertices=case["vertices_path"], faces=case["faces_path"])

        # -- correctness, before any timing
        check_n = min(n, args.check_max)
        key = (case["mesh"], check_n)
        if key not in check_cache:
            why = memory_guard("check", case["grid_bytes"] // n**3 * check_n**3, args)
            check_cache[key] = {"skipped": why} if why else run_check(
                workers, check_n, tmp, f"{case['mesh']}_{check_n}", case["vertices_path"], args
            )
        case["check"] = check_cache[key]
        print_check(case)

        # -- timings, interleaved
        for phase in args.ops:
            why = memory_guard(phase, case["grid_bytes"], args)
            if why:
                case["skipped"][phase] = why
                print(f"    {phase}: {why}", flush=True)
                continue
            entries = PHASES[phase]
            for w in workers.values():
                w.call("release")
            for impl, op in entries:
                workers[impl].call("prepare", op=op, n=n)
            for _ in range(warmup):
                for impl, op in entries:
                    workers[impl].call("run", op=op)
            samples = {entry: [] for entry in entries}
            for r in range(repeats):
                shift = r % len(entries)
                for impl, op in entries[shift:] + entries[:shift]:
                    samples[(impl, op)].append(workers[impl].call("run", op=op)["seconds"])
            for impl, op in entries:
                case["times"]["dvx" if impl == "peer" else "voxax"][op] = samples[(impl, op)]
            case["rss_mib"][phase] = {impl: w.last_rss_mib for impl, w in workers.items()}
            for w in workers.values():
                w.call("release")
            print_phase(case, phase, entries)
    finally:
        for w in workers.values():
            w.close()

    # -- peak memory of one e2e run, each implementation alone in a fresh process
    if args.memory and "e2e" in args.ops and "e2e" not in case["skipped"]:
        case["memory"] = {}
        for impl in ("peer", "voxax"):
            name = "dvx" if impl == "peer" else "voxax"
            with pythons.start(impl) as w:
                w.call("load", vertices=case["vertices_path"], faces=case["faces_path"])
                m = w.call("peak", op="e2e", n=n)
            m["grids"] = m["peak_bytes"] / case["grid_bytes"]
            case["memory"][name] = m
        print(
            "    peak RSS of one e2e run: voxax {:.2f} x grid ({:.0f} MiB), dvx {:.2f} x grid ({:.0f} MiB)".format(
                case["memory"]["voxax"]["grids"],
                case["memory"]["voxax"]["peak_bytes"] / 2**20,
                case["memory"]["dvx"]["grids"],
                case["memory"]["dvx"]["peak_bytes"] / 2**20,
            ),
            flush=True,
        )
    case["seconds"] = time.perf_counter() - started
    summarise(case)


def summarise(case: dict) -> None:
    med = {impl: {op: statistics.median(v) for op, v in ops.items()} for impl, ops in case["times"].items()}
    case["median"] = med
    x, p = med["voxax"], med["dvx"]
    ratio = {}
    for label, xo, po in (("fwd", "fwd", "fwd"), ("fwd_kernel", "fwd", "fwd_kernel"), ("bwd_kernel", "bwd_kernel", "bwd_kernel"), ("e2e", "e2e", "e2e")):
        if xo in x and po in p:
            ratio[label] = x[xo] / p[po]
    if "fwd" in x and "floor" in x:
        ratio["voxax_fwd_over_floor"] = x["fwd"] / x["floor"]
    if "fwd" in p and "floor" in p:
        ratio["dvx_fwd_over_floor"] = p["fwd"] / p["floor"]
        if "fwd_kernel" in p:
            ratio["dvx_fwd_kernel_over_floor"] = p["fwd_kernel"] / p["floor"]
    case["ratio"] = ratio


# ----------------------------------------------------------------------------------------
# Output
# ----------------------------------------------------------------------------------------


def ms(seconds: float | None) -> str:
    if seconds is None:
        return "-"
    v = seconds * 1e3
    return f"{v:.0f}" if v >= 100 else f"{v:.1f}" if v >= 10 else f"{v:.2f}"


def fx(r: float | None, digits: int = 2) -> str:
    return "-" if r is None or not math.isfinite(r) else f"{r:.{digits}f}"


def label(case: dict) -> str:
    return case["label"]


def grid_label(case: dict) -> str:
    return f"{case['n']}^3" + (f" x{case['batch']}" if case["batch"] > 1 else "")


def check_lines(c: dict) -> list[str]:
    if "skipped" in c:
        return [f"check: {c['skipped']}"]
    lines = []
    for bits in (32, 64):
        g, d, loss = c[f"grid{bits}"], c[f"grad{bits}"], c[f"loss{bits}"]
        lines.append(
            f"float{bits}: max|W_voxax.T - W_dvx| = {g['max_abs_diff']:.3g} ({g['cells_over_atol']} of {g['cells']} "
            f"cells over {g['atol']:g}; without the transpose {g['max_abs_diff_without_transpose']:.3g}); "
            f"grad rel L2 err {d['rel_l2']:.3g} (max|dg|/max|g| {d['max_abs_diff_over_max_abs']:.3g}; "
            f"{d['rel_l2_off_planes']:.3g} without the {d['vertices_on_grid_planes']} vertices on grid planes); "
            f"loss rel diff {loss['rel_diff']:.3g}"
        )
        if not g["ok"]:
            a = g["at"]
            lines.append(f"  largest difference at batch {a['batch']}, W[i,j,k] = {a['ijk']}: voxax {a['voxax']!r}, dvx {a['dvx']!r}")
    e = c["f32_vs_f64"]
    lines.append(
        "float32 vs own float64: voxax grid {:.3g}, grad rel {:.3g}; dvx grid {:.3g}, grad rel {:.3g}".format(
            e["voxax"]["grid_max_abs"], e["voxax"]["grad_rel_l2"], e["dvx"]["grid_max_abs"], e["dvx"]["grad_rel_l2"]
        )
    )
    lines.append(
        f"dvx raw kernels vs its torch wrapper: forward max abs {c['dvx_raw_fwd_vs_wrapper_max_abs']:.3g}, "
        f"backward max rel {c['dvx_raw_bwd_vs_autograd_max_rel']:.3g}"
    )
    lines.append(f"verdict at {c['n']}^3: {c['verdict']}")
    return lines


def print_check(case: dict) -> None:
    for line in check_lines(case["check"]):
        print("    check " + line, flush=True)


def print_phase(case: dict, phase: str, entries) -> None:
    parts = []
    for impl, op in entries:
        name = "dvx" if impl == "peer" else "voxax"
        parts.append(f"{name} {op} {ms(statistics.median(case['times'][name][op]))} ms")
    print(f"    {phase}: " + ", ".join(parts), flush=True)


def tables(results: dict) -> str:
    """The results as two Markdown tables."""
    rows1, rows2 = [], []
    for c in results["cases"]:
        if "median" not in c:
            rows1.append(f"| {label(c)} | {c['faces']:,} | {grid_label(c)} | failed: {c.get('error', '?')} |")
            continue
        x, p, r = c["median"]["voxax"], c["median"]["dvx"], c["ratio"]
        rows1.append(
            "| "
            + " | ".join(
                [
                    label(c), f"{c['faces']:,}", grid_label(c),
                    ms(x.get("fwd")), ms(p.get("fwd")), fx(r.get("fwd")),
                    ms(p.get("fwd_kernel")), fx(r.get("fwd_kernel")),
                    ms(x.get("bwd_kernel")), ms(p.get("bwd_kernel")), fx(r.get("bwd_kernel")),
                    ms(x.get("e2e")), ms(p.get("e2e")), fx(r.get("e2e")),
                ]
            )
            + " |"
        )
        mem = c.get("memory", {})
        chk = c.get("check", {})
        if "grid32" in chk:
            e = chk["f32_vs_f64"]
            agree = " | ".join(
                [
                    f"{chk['grid32']['max_abs_diff']:.2g}", f"{chk['grad32']['rel_l2']:.2g}",
                    f"{chk['grid64']['max_abs_diff']:.2g}", f"{chk['grad64']['rel_l2']:.2g}",
                    f"{e['voxax']['grid_max_abs']:.2g} / {e['dvx']['grid_max_abs']:.2g}",
                    f"{chk['n']}^3" + ("" if chk["within_tolerance_f32"] else " (!)" if chk["ok"] else " **MISMATCH**"),
                ]
            )
        else:
            agree = " | ".join(["-"] * 5 + [chk.get("skipped", "not checked")])
        rows2.append(
            "| "
            + " | ".join(
                [
                    label(c), grid_label(c),
                    ms(x.get("floor")), fx(r.get("voxax_fwd_over_floor"), 1),
                    ms(p.get("floor")), fx(r.get("dvx_fwd_over_floor"), 1), fx(r.get("dvx_fwd_kernel_over_floor"), 1),
                    fx(mem.get("voxax", {}).get("grids")), fx(mem.get("dvx", {}).get("grids")),
                    agree,
                ]
            )
            + " |"
        )
    head1 = (
        "| mesh | faces | grid | fwd voxax | fwd dvx | ratio | fwd kernel dvx | ratio | bwd kernel voxax | bwd kernel dvx | ratio | e2e voxax | e2e dvx | ratio |\n"
        "|---|--:|---|--:|--:|--:|--:|--:|--:|--:|--:|--:|--:|--:|"
    )
    head2 = (
        "| mesh | grid | floor voxax | voxax fwd / floor | floor dvx | dvx fwd / floor | dvx fwd kernel / floor "
        "| peak voxax (x grid) | peak dvx (x grid) | max abs dW f32 | grad rel err f32 | max abs dW f64 | grad rel err f64 "
        "| f32 err voxax / dvx | checked at |\n"
        "|---|---|--:|--:|--:|--:|--:|--:|--:|--:|--:|--:|--:|--:|---|"
    )
    return (
        "Median wall time in ms over the repeats; ratio = voxax / dvx-python (below 1: voxax is faster).\n\n"
        + head1 + "\n" + "\n".join(rows1)
        + "\n\nFloor = time to produce an array of the output's size (voxax: jitted `jnp.full`; dvx: `torch.full`). "
        "Peak = peak RSS of one e2e run in a fresh process above its RSS before the run, in multiples of the "
        "output's bytes. max abs dW = max |W_voxax.transpose(2, 1, 0) - W_dvx| with float32 (as timed) and "
        "float64 vertices; grad rel err = ||g_voxax - g_dvx|| / ||g_dvx|| for the gradient of sum(W**2); "
        "f32 err = max |W_float32 - W_float64| of each implementation against its own float64 result. "
        "(!) marks a case whose float32 results differ beyond tolerance for a reason the check identified "
        "(see the verdicts below the tables), **MISMATCH** one it could not explain.\n\n"
        + head2 + "\n" + "\n".join(rows2)
    )


def verdicts(results: dict) -> list[str]:
    """One line per checked (mesh, resolution)."""
    seen, lines = set(), []
    for c in results["cases"]:
        chk = c.get("check")
        if not chk or "grid32" not in chk or (c["mesh"], chk["n"]) in seen:
            continue
        seen.add((c["mesh"], chk["n"]))
        e = chk["f32_vs_f64"]
        lines.append(
            f"{label(c)} at {chk['n']}^3: {chk['verdict']} (float32: max abs dW {chk['grid32']['max_abs_diff']:.2g}, "
            f"grad rel err {chk['grad32']['rel_l2']:.2g}; float64: {chk['grid64']['max_abs_diff']:.2g}, "
            f"{chk['grad64']['rel_l2']:.2g}; float32 vs own float64: voxax {e['voxax']['grid_max_abs']:.2g} / "
            f"{e['voxax']['grad_rel_l2']:.2g}, dvx {e['dvx']['grid_max_abs']:.2g} / {e['dvx']['grad_rel_l2']:.2g})"
        )
    return lines


def header(results: dict) -> str:
    m, v = results["machine"], results["versions"]
    lines = [
        f"Machine: {m['cpu']}, {m['usable_cores']} usable cores ({m['logical_cores']} logical), "
        f"{m['memory_gib']} GiB memory ({m['memory_available_gib_at_start']} GiB available at start), {m['os']}; "
        f"load average at start {m['load_average_at_start']}, at end {m.get('load_average_at_end', '-')}.",
        f"Versions: voxax {v['voxax']['voxax']} (jax {v['voxax']['jax']}, jaxlib {v['voxax']['jaxlib']}, numpy {v['voxax']['numpy']}, "
        f"Python {v['voxax']['python']}); dvx-python {v['dvx']['dvx-python']} (torch {v['dvx']['torch']}, "
        f"{v['dvx']['torch_threads']} torch threads, numpy {v['dvx']['numpy']}, Python {v['dvx']['python']}).",
        f"Date: {m['date']}. Repeats: {results['settings']['repeats']} "
        f"({results['settings']['repeats_big']} at >= {results['settings']['big']}^3), float32, grid [-1, 1]^3.",
        f"Command: `{results['command']}`",
    ]
    return "\n".join(lines)


def plot(results: dict, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import matplotlib.ticker

    cases = [c for c in results["cases"] if "median" in c and c["batch"] == 1]
    fig, axes = plt.subplots(2, 2, figsize=(12, 9))
    colours = plt.rcParams["axes.prop_cycle"].by_key()["color"]
    styles = {"voxax": "-", "dvx": "--"}
    for row, (op, title) in enumerate((("fwd", "forward"), ("e2e", "forward + backward (e2e)"))):
        meshes = sorted({c["mesh"] for c in cases}, key=lambda m: min(c["faces"] for c in cases if c["mesh"] == m))
        ax = axes[row][0]
        for i, mesh in enumerate(meshes):
            cs = sorted((c for c in cases if c["mesh"] == mesh), key=lambda c: c["n"])
            for impl in ("voxax", "dvx"):
                pts = [(c["n"], c["median"][impl][op]) for c in cs if op in c["median"][impl]]
                if pts:
                    ax.plot(*zip(*pts), styles[impl], marker="o", color=colours[i % len(colours)], label=f"{impl}, {cs[0]['label']}")
        ax.set(xscale="log", yscale="log", xlabel="grid resolution n (n^3 cells)", ylabel="median time [s]", title=f"{title} vs resolution")
        ax.xaxis.set_minor_locator(matplotlib.ticker.NullLocator())
        ax.set_xticks(sorted({c["n"] for c in cases}), [str(n) for n in sorted({c["n"] for c in cases})])
        ax.grid(True, which="both", alpha=0.3)
        if ax.get_legend_handles_labels()[0]:
            ax.legend(fontsize=8)
        ax = axes[row][1]
        for i, n in enumerate(sorted({c["n"] for c in cases})):
            cs = sorted((c for c in cases if c["n"] == n), key=lambda c: c["faces"])
            for impl in ("voxax", "dvx"):
                pts = [(c["faces"], c["median"][impl][op]) for c in cs if op in c["median"][impl]]
                if pts:
                    ax.plot(*zip(*pts), styles[impl], marker="o", color=colours[i % len(colours)], label=f"{impl}, {n}^3")
        ax.set(xscale="log", yscale="log", xlabel="faces", ylabel="median time [s]", title=f"{title} vs face count")
        ax.grid(True, which="both", alpha=0.3)
        if ax.get_legend_handles_labels()[0]:
            ax.legend(fontsize=8)
    m = results["machine"]
    fig.suptitle(f"voxax (solid) vs dvx-python (dashed), float32 — {m['cpu']}, {m['usable_cores']} cores", fontsize=11)
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110)
    plt.close(fig)


def write_readme(results: dict, readme: Path, plot_rel: str) -> None:
    text = readme.read_text()
    if BEGIN not in text or END not in text:
        raise SystemExit(f"{readme} lacks the markers {BEGIN} and {END}")
    block = [BEGIN, "", header(results), "", tables(results), ""]
    block += ["Agreement checks:", ""] + [f"- {line}" for line in verdicts(results)] + [""]
    block += [f"![time vs resolution and vs face count]({plot_rel})", "", END]
    before, rest = text.split(BEGIN, 1)
    after = rest.split(END, 1)[1]
    readme.write_text(before + "\n".join(block) + after)


# ----------------------------------------------------------------------------------------
# Main
# ----------------------------------------------------------------------------------------


def csv(kind):
    return lambda s: [kind(x) for x in s.split(",") if x.strip()]


def parse_args(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0], formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--peer-python", default=os.environ.get("VOXAX_PEER_PYTHON"),
                    help="python of the venv with dvx-python and torch (default: $VOXAX_PEER_PYTHON)")
    ap.add_argument("--voxax-python", default=sys.executable, help="python for the voxax worker (default: this one)")
    ap.add_argument("--meshes", type=csv(str), default=None,
                    help="comma list of hand, 100k, 1m or large:N (default: hand,100k,1m)")
    ap.add_argument("--sizes", type=csv(int), default=None, help="comma list of grid resolutions (default: 128,256,512,1024)")
    ap.add_argument("--quick", action="store_true", help="hand and 100k at 128 and 256 only, no tiling case")
    ap.add_argument("--tiling", action=argparse.BooleanOptionalAction, default=None,
                    help="the tiling case: 27 perturbed copies of the hand at 192^3, batched (default: on unless --quick)")
    ap.add_argument("--tiling-size", type=int, default=192)
    ap.add_argument("--tiling-count", type=int, default=27)
    ap.add_argument("--seed", type=int, default=0, help="seed of the tiling case's random transforms")
    ap.add_argument("--ops", type=csv(str), default=ALL_OPS, help=f"timing phases (default: {','.join(ALL_OPS)})")
    ap.add_argument("--repeats", type=int, default=5, help="timed runs per measurement (default 5)")
    ap.add_argument("--repeats-big", type=int, default=3, help="timed runs at resolutions >= --big (default 3)")
    ap.add_argument("--big", type=int, default=1024, help="resolution from which --repeats-big applies (default 1024)")
    ap.add_argument("--warmup", type=int, default=None, help="untimed runs before timing (default: 1, 0 at >= --big)")
    ap.add_argument("--check-max", type=int, default=512,
                    help="largest resolution checked; larger cases are checked at this one (default 512)")
    ap.add_argument("--grid-atol", type=float, default=1e-4, help="max abs grid difference accepted (default 1e-4)")
    ap.add_argument("--grad-rtol", type=float, default=1e-3, help="relative L2 gradient difference accepted (default 1e-3)")
    ap.add_argument("--grid-atol64", type=float, default=1e-6, help="the same for float64 (default 1e-6)")
    ap.add_argument("--grad-rtol64", type=float, default=1e-6, help="the same for float64 (default 1e-6)")
    ap.add_argument("--no-memory", dest="memory", action="store_false", help="skip the peak-RSS measurement")
    ap.add_argument("--force", action="store_true", help="run phases even when MemAvailable looks too small")
    ap.add_argument("--out-dir", type=Path, default=None,
                    help="where results.json and plot.png go (default: benchmarks/results/last-run, "
                    "or benchmarks/results with --write-readme)")
    ap.add_argument("--write-readme", action="store_true",
                    help="also rewrite the results section of benchmarks/README.md")
    ap.add_argument("--readme", type=Path, default=README,
                    help=f"the file whose section between {BEGIN} and {END} --write-readme rewrites")
    args = ap.parse_args(argv)
    if not args.peer_python:
        ap.error("give --peer-python (or set VOXAX_PEER_PYTHON): the python of a venv with dvx-python and torch")
    if args.meshes is None:
        args.meshes = QUICK_MESHES if args.quick else list(MESHES)
    if args.sizes is None:
        args.sizes = QUICK_SIZES if args.quick else [128, 256, 512, 1024]
    if args.tiling is None:
        args.tiling = not args.quick
    for m in args.meshes:
        if m not in MESHES and not (m.startswith("large:") and m[6:].isdigit()):
            ap.error(f"unknown mesh {m!r}")
    for op in args.ops:
        if op not in PHASES:
            ap.error(f"unknown op {op!r}; choose from {', '.join(PHASES)}")
    if args.out_dir is None:
        args.out_dir = RESULTS_DIR if args.write_readme else RESULTS_DIR / "last-run"
    return args


def mesh_spec(name: str) -> tuple[str, int | None, str]:
    if name in MESHES:
        kind, nf = MESHES[name]
    else:
        kind, nf = "large", int(name[6:])
    pretty = "hand" if kind == "hand" else f"large({nf:_})"
    return kind, nf, pretty


def tiling_vertices(vertices: np.ndarray, count: int, seed: int) -> np.ndarray:
    """`count` copies with random rotations (<= 10 degrees about a random axis through the
    origin) and translations (<= 0.05 per axis)."""
    rng = np.random.default_rng(seed)
    out = np.empty((count,) + vertices.shape)
    for b in range(count):
        axis = rng.normal(size=3)
        axis /= np.linalg.norm(axis)
        angle = np.deg2rad(rng.uniform(-10, 10))
        K = np.array([[0, -axis[2], axis[1]], [axis[2], 0, -axis[0]], [-axis[1], axis[0], 0]])
        R = np.eye(3) + np.sin(angle) * K + (1 - np.cos(angle)) * K @ K
        out[b] = vertices @ R.T + rng.uniform(-0.05, 0.05, size=3)
    return out


def main(argv=None) -> int:
    args = parse_args(argv)
    results = {
        "command": command_line(),
        "machine": machine_info(),
        "settings": {k: (str(v) if isinstance(v, Path) else v) for k, v in vars(args).items()},
        "cases": [],
    }
    pythons = Pythons(args.voxax_python, args.peer_python)
    out_dir = args.out_dir
    out_dir.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(prefix="voxax-bench-"))
    try:
        # Versions, and the meshes (generated by voxax.data in a voxax worker).
        meshes = {}
        with pythons.start("voxax") as xw, pythons.start("peer") as pw:
            results["versions"] = {"voxax": xw.call("info"), "dvx": pw.call("info")}
            for name in args.meshes + (["hand"] if args.tiling and "hand" not in args.meshes else []):
                kind, nf, pretty = mesh_spec(name)
                vp, fp = str(tmp / f"{name}_v.npy"), str(tmp / f"{name}_f.npy")
                meta = xw.call("make_mesh", kind=kind, n_faces=nf, vertices_path=vp, faces_path=fp)
                meshes[name] = dict(meta, label=pretty, vertices_path=vp, faces_path=fp)
        for k in ("rss_mib",):
            for v in results["versions"].values():
                v.pop(k, None)
        print(header(results))
        print("meshes: " + ", ".join(f"{m['label']} ({m['n_faces']:,} faces, {m['n_vertices']:,} vertices)" for m in meshes.values()))

        cases = []
        for name in args.meshes:
            for n in args.sizes:
                cases.append({"mesh": name, "n": n, "batch": 1})
        if args.tiling:
            cases.append({"mesh": "tiling", "n": args.tiling_size, "batch": args.tiling_count})
            hand = meshes["hand"]
            tv = tiling_vertices(np.load(hand["vertices_path"]), args.tiling_count, args.seed)
            tvp = str(tmp / "tiling_v.npy")
            np.save(tvp, tv)
            meshes["tiling"] = dict(
                hand, label=f"hand x{args.tiling_count} (tiling)", vertices_path=tvp, max_abs=float(np.abs(tv).max())
            )
            print(f"tiling: {args.tiling_count} perturbed copies of the hand, max |coordinate| {np.abs(tv).max():.3f}")
        cases.sort(key=lambda c: (c["n"] ** 3 * c["batch"], meshes[c["mesh"]]["n_faces"]))

        check_cache = {}
        json_path = out_dir / "results.json"
        for case in cases:
            mesh = meshes[case["mesh"]]
            case.update(
                label=mesh["label"], faces=mesh["n_faces"], vertices=mesh["n_vertices"],
                vertices_path=mesh["vertices_path"], faces_path=mesh["faces_path"],
                grid_bytes=4 * case["batch"] * case["n"] ** 3,
            )
            print(f"\n== {case['label']}, {grid_label(case)} ({case['grid_bytes'] / 2**20:.0f} MiB output)", flush=True)
            try:
                time_case(case, pythons, tmp, args, check_cache)
            except WorkerError as err:
                case["error"] = str(err)
                print(f"    FAILED: {err}", flush=True)
                if any(case.get("times", {}).values()):
                    summarise(case)  # keep what was measured before the failure
            for k in ("vertices_path", "faces_path"):
                case.pop(k, None)
            results["cases"].append(case)
            json_path.write_text(json.dumps(results, indent=1))

        results["machine"]["load_average_at_end"] = [round(x, 2) for x in os.getloadavg()]
        json_path.write_text(json.dumps(results, indent=1))
        print()
        print(tables(results))
        print("\n" + "\n".join(verdicts(results)))
        plot_path = out_dir / "plot.png"
        plot(results, plot_path)
        print(f"\nwrote {json_path} and {plot_path}")
        if args.write_readme:
            write_readme(results, args.readme, os.path.relpath(plot_path, args.readme.resolve().parent))
            print(f"rewrote the results section of {args.readme}")
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
