"""voxax side of the benchmark: a worker process driven by `run.py`.

Runs in voxax's environment and never imports torch. It reads one JSON request per
line on stdin and answers one JSON line on stdout (see `_common.serve`). Vertices are
timed in float32 with int32 faces; a batch of meshes is vertices `(B, V, 3)` with shared
faces `(F, 3)`, which `voxax.voxelize` handles in one call.
"""

from __future__ import annotations

import os
import sys

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))

import jax  # noqa: E402
import jax.numpy as jnp  # noqa: E402
import numpy as np  # noqa: E402
from _common import op_handlers, proc_status_kib, reset_peak_rss, serve, timed, trim_memory  # noqa: E402

import voxax  # noqa: E402

STATE: dict = {"v": None, "f": None, "ops": {}}


def info():
    import importlib.metadata as md

    import jaxlib

    def version(dist):
        try:
            return md.version(dist)
        except md.PackageNotFoundError:
            return None

    return {
        "python": sys.version.split()[0],
        "jax": jax.__version__,
        "jaxlib": jaxlib.__version__,
        "voxax": voxax.__version__,
        "voxax_installed_dist": version("voxax"),
        "voxax_path": os.path.dirname(voxax.__file__),
        "kernel_library": str(voxax._kernels.library_path()),
        "numpy": np.__version__,
        "backend": jax.default_backend(),
        "devices": [str(d) for d in jax.devices()],
        "cpu_count": os.cpu_count(),
        "affinity": len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else None,
    }


def make_mesh(kind, vertices_path, faces_path, n_faces=None):
    if kind == "hand":
        mesh = voxax.data.hand()
    elif kind == "large":
        mesh = voxax.data.large(int(n_faces))
    else:
        raise ValueError(f"unknown mesh kind {kind!r}")
    np.save(vertices_path, mesh.vertices)
    np.save(faces_path, mesh.faces)
    return {
        "n_vertices": int(mesh.n_vertices),
        "n_faces": int(mesh.n_faces),
        "max_abs": float(np.abs(mesh.vertices).max()),
        "signed_volume": float(mesh.signed_volume()),
    }


def load(vertices, faces):
    STATE["ops"].clear()
    STATE["v"] = jnp.asarray(np.load(vertices).astype(np.float32))
    STATE["f"] = jnp.asarray(np.load(faces).astype(np.int32))
    trim_memory()
    return {"shape": list(STATE["v"].shape)}


def _forward_fn(grid):
    return jax.jit(lambda v, f: voxax.voxelize(v, f, grid))


def _energy_fn(grid):
    return jax.jit(jax.value_and_grad(lambda v, f: jnp.sum(voxax.voxelize(v, f, grid) ** 2)))


def _build(op, n):
    """Compiles (ahead of time) the function timed for `op` and returns (pre, run)."""
    grid = voxax.Grid.cube(int(n))
    v, f = STATE["v"], STATE["f"]
    if op == "fwd":
        fn = _forward_fn(grid).lower(v, f).compile()
        return None, lambda: fn(v, f).block_until_ready()
    if op == "bwd_kernel":
        # the cotangent of sum(W**2): 2 W, made in one call so that XLA can reuse W's buffer
        cot = jax.jit(lambda v, f: 2 * voxax.voxelize(v, f, grid))(v, f).block_until_ready()
        corners = jax.jit(lambda v, f, c: voxax.voxelize_corner_gradients(v, f, grid, c))
        fn = corners.lower(v, f, cot).compile()
        return None, lambda: fn(v, f, cot).block_until_ready()
    if op == "e2e":
        fn = _energy_fn(grid).lower(v, f).compile()
        return None, lambda: jax.block_until_ready(fn(v, f))
    if op == "floor":
        shape = tuple(v.shape[:-2]) + grid.shape
        one = jnp.float32(1.0)
        fn = jax.jit(lambda x: jnp.full(shape, x, jnp.float32)).lower(one).compile()
        return None, lambda: fn(one).block_until_ready()
    raise ValueError(f"voxax worker: unknown op {op!r}")


def check(n, prefix):
    """Saves W (x, y, z order) and the gradient of sum(W**2), in float32 (as timed) and
    in float64, as `{prefix}_W32.npy`, `_g32`, `_W64`, `_g64`, for the driver to compare."""
    grid = voxax.Grid.cube(int(n))
    out = {"layout": "W[..., x, y, z]"}
    arrays = {}
    for bits in (32, 64):
        with jax.enable_x64(bits == 64):
            dtype = jnp.float32 if bits == 32 else jnp.float64
            v = jnp.asarray(STATE["v"], dtype=dtype)
            f = STATE["f"]
            W = np.asarray(_forward_fn(grid)(v, f))
            np.save(f"{prefix}_W{bits}.npy", W)
            out[f"volume{bits}"] = float(W.sum(dtype=np.float64) * grid.voxel_volume)
            loss, grad = _energy_fn(grid)(v, f)
            grad = np.asarray(grad)
            np.save(f"{prefix}_g{bits}.npy", grad)
            out[f"loss{bits}"] = float(loss)
            arrays[bits] = (W, grad)
            del v
    (W32, g32), (W64, g64) = arrays[32], arrays[64]
    out["self_f32_vs_f64_grid_max_abs"] = float(np.abs(W32.astype(np.float64) - W64).max())
    out["self_f32_vs_f64_grad_rel_l2"] = float(np.linalg.norm(g32 - g64) / max(np.linalg.norm(g64), 1e-300))
    del arrays, W32, W64
    trim_memory()
    return out


def peak(op, n):
    """Peak RSS of one run of `op`, above the RSS just before it (compiled beforehand)."""
    pre, fn = _build(op, n)
    if pre is not None:
        pre()
    trim_memory()
    reset_ok = reset_peak_rss()
    base = proc_status_kib("VmRSS")
    seconds, out = timed(fn)
    hwm = proc_status_kib("VmHWM")
    del out
    return {
        "base_kib": base,
        "hwm_kib": hwm,
        "peak_bytes": (hwm - base) * 1024,
        "hwm_reset": reset_ok,
        "seconds": seconds,
    }


if __name__ == "__main__":
    serve(
        {
            "info": info,
            "make_mesh": make_mesh,
            "load": load,
            **op_handlers(STATE["ops"], _build),
            "check": check,
            "peak": peak,
        }
    )
