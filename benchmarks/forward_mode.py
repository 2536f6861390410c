"""Forward mode and optimization loops: tangent vs backward kernel time, and the cost of a
jitted loop step against the kernels' own time.

    python benchmarks/forward_mode.py                      # 256^3 kernels, 512^3 loop
    python benchmarks/forward_mode.py --kernel-size 128 --loop-size 256 --repeats 3

1. Kernels (float32): the forward, the backward (`voxelize_corner_gradients` with a dense
   cotangent) and the tangent kernel (the JVP's linear part, per-corner tangents) on the
   same mesh and grid, each jitted, median of `--repeats` timed calls after a warm-up.
2. Loops: one step is value and gradient of `mean((W - target)^2)` plus a gradient-descent
   update of the vertices. (a) a jitted step called from Python, returning the loss, so
   every step allocates its grids afresh (the allocation floor: fresh pages); (b) the
   same with the target grid donated and handed back (`donate_argnums`), so one big input
   buffer is reused; (c) `lax.fori_loop` over the steps inside one jit, where XLA assigns
   the loop body's grids once and reuses them every iteration. Each is compared with the
   kernels' own time per step (forward + backward, timed alone).

Prints a Markdown table; `--json FILE` also writes the numbers.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import statistics
import sys
import time

import jax
import jax.numpy as jnp
import numpy as np

sys.path.insert(0, os.path.join(os.path.dirname(__file__), "..", "src"))

import voxax  # noqa: E402
from voxax import _voxelize_ops  # noqa: E402


def _status(key: str) -> int:
    with open("/proc/self/status") as fh:
        for line in fh:
            if line.startswith(key):
                return int(line.split()[1]) * 1024
    return 0


def reset_peak() -> int:
    """Resets the peak resident set size (Linux) and returns the current one."""
    try:
        with open("/proc/self/clear_refs", "w") as fh:
            fh.write("5")
    except OSError:
        pass
    return _status("VmRSS")


def peak_since(base: int) -> float:
    """GiB of resident memory above `base` at the peak since the last `reset_peak` (in the
    JSON only: pages freed by an earlier variant stay resident, so the figure depends on
    the order of the variants)."""
    return (_status("VmHWM") - base) / 2**30


def timed(fn, *args, repeats=5):
    jax.block_until_ready(fn(*args))  # compile and warm up
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        jax.block_until_ready(fn(*args))
        times.append(time.perf_counter() - t0)
    return statistics.median(times)


def kernels(n: int, subdivisions: int, repeats: int) -> dict:
    mesh = voxax.data.icosphere(subdivisions, radius=0.8)
    grid = voxax.Grid.cube(n)
    v = jnp.asarray(mesh.vertices, jnp.float32)
    f = jnp.asarray(mesh.faces, jnp.int32)
    rng = np.random.default_rng(0)
    cot = jnp.asarray(rng.normal(size=grid.shape).astype(np.float32))
    tc = jnp.asarray(rng.normal(size=(mesh.n_faces, 3, 3)).astype(np.float32))
    fwd = jax.jit(lambda x: voxax.voxelize(x, f, grid))
    bwd = jax.jit(lambda x, c: voxax.voxelize_corner_gradients(x, f, grid, c))
    tan = jax.jit(lambda x, t: _voxelize_ops.tangent(x, f, t, grid))
    out = {
        "grid": n,
        "faces": mesh.n_faces,
        "forward_s": timed(fwd, v, repeats=repeats),
        "backward_s": timed(bwd, v, cot, repeats=repeats),
        "tangent_s": timed(tan, v, tc, repeats=repeats),
    }
    out["tangent_over_backward"] = out["tangent_s"] / out["backward_s"]
    return out


def loops(n: int, subdivisions: int, steps: int, repeats: int) -> dict:
    mesh = voxax.data.icosphere(subdivisions, radius=0.6)
    grid = voxax.Grid.cube(n)
    v0 = jnp.asarray(mesh.vertices, jnp.float32)
    f = jnp.asarray(mesh.faces, jnp.int32)
    tgt = voxax.data.box((-0.5, -0.4, -0.45), (0.45, 0.5, 0.4))
    target = voxax.voxelize(jnp.asarray(tgt.vertices, jnp.float32), tgt.faces, grid)
    lr = 1e-3

    def loss(x, t):
        return jnp.mean((voxax.voxelize(x, f, grid) - t) ** 2)

    vg = jax.value_and_grad(loss)

    @jax.jit
    def step(x, t):
        value, g = vg(x, t)
        return x - lr * g / (jnp.abs(g).max() + 1e-30), value

    @jax.jit
    def step_donated_impl(x, t):
        value, g = vg(x, t)
        return x - lr * g / (jnp.abs(g).max() + 1e-30), value, t

    step_donated = jax.jit(step_donated_impl, donate_argnums=(1,))

    @jax.jit
    def run_loop(x, t):
        def body(_, carry):
            y, _v = carry
            y2, value = step(y, t)
            return y2, value

        return jax.lax.fori_loop(0, steps, body, (x, jnp.zeros((), x.dtype)))

    fwd = jax.jit(lambda x: voxax.voxelize(x, f, grid))
    cot = jnp.full(grid.shape, 1.0 / grid.size, jnp.float32)
    bwd = jax.jit(lambda x, c: voxax.voxelize_corner_gradients(x, f, grid, c))
    kernel_s = timed(fwd, v0, repeats=repeats) + timed(bwd, v0, cot, repeats=repeats)

    def python_loop(x, t):
        for _ in range(steps):
            x, value = step(x, t)
        return x, value

    def python_loop_donated(x, t):
        for _ in range(steps):
            x, value, t = step_donated(x, t)
        return x, value, t

    out = {"grid": n, "faces": mesh.n_faces, "steps": steps, "kernels_per_step_s": kernel_s}
    base = reset_peak()
    out["python_loop_per_step_s"] = timed(python_loop, v0, target, repeats=repeats) / steps
    out["python_loop_peak_gib"] = peak_since(base)
    # One target buffer at a time (at 1024^3 each grid is 4 GiB): donation consumes it and
    # each call hands it back.
    t_don = target
    del target
    base = reset_peak()
    x, value, t_don = python_loop_donated(v0, t_don)  # compile
    jax.block_until_ready((x, value, t_don))
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        x, value, t_don = python_loop_donated(v0, t_don)
        jax.block_until_ready((x, value, t_don))
        times.append(time.perf_counter() - t0)
    out["donated_loop_per_step_s"] = statistics.median(times) / steps
    out["donated_loop_peak_gib"] = peak_since(base)
    base = reset_peak()
    out["fori_loop_per_step_s"] = timed(run_loop, v0, t_don, repeats=repeats) / steps
    out["fori_loop_peak_gib"] = peak_since(base)
    for k in ("python_loop", "donated_loop", "fori_loop"):
        out[f"{k}_over_kernels"] = out[f"{k}_per_step_s"] / kernel_s
    return out


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--kernel-size", type=int, default=256)
    parser.add_argument("--loop-size", type=int, default=512)
    parser.add_argument("--subdivisions", type=int, default=5, help="icosphere subdivisions (5: 20480 faces)")
    parser.add_argument("--steps", type=int, default=4)
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--json")
    args = parser.parse_args(argv)
    print(f"machine: {platform.machine()}, {os.cpu_count()} CPUs; jax {jax.__version__}; "
          f"XLA pool threads as configured by JAX")
    k = kernels(args.kernel_size, args.subdivisions, args.repeats)
    print(f"\n| kernel ({k['grid']}^3, {k['faces']} faces, float32) | median time |")
    print("|---|---:|")
    for name in ("forward", "backward", "tangent"):
        print(f"| {name} | {k[name + '_s'] * 1e3:.1f} ms |")
    print(f"\ntangent / backward: {k['tangent_over_backward']:.2f}")
    lp = loops(args.loop_size, args.subdivisions, args.steps, args.repeats)
    print(f"\n| loop step ({lp['grid']}^3, {lp['faces']} faces, float32) | per step | / kernels |")
    print("|---|---:|---:|")
    print(f"| kernels alone (forward + backward) | {lp['kernels_per_step_s'] * 1e3:.0f} ms | 1.00 |")
    for name, label in (("python_loop", "jitted step, Python loop"),
                        ("donated_loop", "jitted step, target donated"),
                        ("fori_loop", "lax.fori_loop in one jit")):
        print(f"| {label} | {lp[name + '_per_step_s'] * 1e3:.0f} ms | {lp[name + '_over_kernels']:.2f} |")
    if args.json:
        with open(args.json, "w") as fh:
            json.dump({"kernels": k, "loops": lp}, fh, indent=1)
    return 0


if __name__ == "__main__":
    sys.exit(main())
