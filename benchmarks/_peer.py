"""dvx-python side of the benchmark: a worker process driven by `run.py`.

Runs in the peer's environment (`--peer-python`, with `dvx-python` and `torch`) and
never imports jax or voxax. Same JSON-lines protocol as `_voxax.py`.

dvx conventions, read from `dvx/torch/voxelize.py` (dvx-python 0.1.1):

- `dvx.torch.voxelize(n, vertices, indices)` voxelizes [-1, 1]^3 on an n^3 grid with the
  closed-form ('cf') method and returns `voxels.transpose(0, -1)`, a (z, y, x) *view*;
  the array the kernel writes is (x, y, z), the same layout as voxax's `W[i, j, k]`.
- The raw kernels `dvx_ext.voxelize_cf_f32(vertices, simplices, occupancy)` and
  `dvx_ext.voxelize_backward_cf_f32(vertices, simplices, occupancy, d_vertices,
  d_occupancy)` take C-contiguous NumPy/torch arrays, float32 vertices and *uint32*
  simplices, and ADD into `occupancy` / `d_vertices` (the torch wrapper zero-fills them
  first), so the timed raw calls get arrays zeroed outside the timer.
- Faces are passed as uint32 everywhere, the kernels' own index type, so no call pays
  for a conversion. Batches (B, V, 3) are B separate calls, as a user would write them.
"""

from __future__ import annotations

import os
import sys

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))

import dvx_ext  # noqa: E402
import numpy as np  # noqa: E402
import torch  # noqa: E402
from _common import op_handlers, proc_status_kib, reset_peak_rss, serve, timed, trim_memory  # noqa: E402
from dvx.torch import voxelize as dvx_voxelize  # noqa: E402

STATE: dict = {"v": None, "f": None, "ops": {}}


def info():
    import importlib.metadata as md

    return {
        "python": sys.version.split()[0],
        "torch": torch.__version__,
        "dvx-python": md.version("dvx-python"),
        "dvx_ext": getattr(dvx_ext, "__version__", None),
        "dvx_ext_build_type": str(getattr(dvx_ext, "build_type", None)),
        "numpy": np.__version__,
        "torch_threads": torch.get_num_threads(),
        "cpu_count": os.cpu_count(),
    }


def load(vertices, faces):
    STATE["ops"].clear()
    v = np.ascontiguousarray(np.load(vertices), dtype=np.float32)
    f = np.load(faces)
    if f.min() < 0:
        raise ValueError("negative face index")
    f = np.ascontiguousarray(f, dtype=np.uint32)
    STATE["v"], STATE["f"] = v, f
    STATE["vt"], STATE["ft"] = torch.from_numpy(v), torch.from_numpy(f)
    trim_memory()
    return {"shape": list(v.shape)}


def _batch():
    v = STATE["v"]
    return v.shape[0] if v.ndim == 3 else None


def _instances(x):
    """The per-mesh slices of a batched array (or the array itself)."""
    return [x[b] for b in range(x.shape[0])] if _batch() is not None else [x]


def _raw_forward(n):
    b = _batch()
    out = np.zeros(((b,) if b is not None else ()) + (n, n, n), np.float32)
    for vb, ob in zip(_instances(STATE["v"]), _instances(out)):
        dvx_ext.voxelize_cf_f32(vb, STATE["f"], ob)
    return out


def _build(op, n):
    n = int(n)
    v, f, vt, ft = STATE["v"], STATE["f"], STATE["vt"], STATE["ft"]
    batch = _batch()
    if op == "fwd":  # as users call it: the wrapper allocates its output
        if batch is None:
            return None, lambda: dvx_voxelize(n, vt, ft)
        return None, lambda: [dvx_voxelize(n, vb, ft) for vb in _instances(vt)]
    if op == "fwd_kernel":  # raw kernel into a preallocated, zeroed array
        out = np.zeros(((batch,) if batch is not None else ()) + (n, n, n), np.float32)

        def fwd_kernel():
            for vb, ob in zip(_instances(v), _instances(out)):
                dvx_ext.voxelize_cf_f32(vb, f, ob)

        return lambda: out.fill(0), fwd_kernel
    if op == "bwd_kernel":  # raw backward kernel, cotangent 2 W = d sum(W**2) / dW
        occ = _raw_forward(n)
        dout = 2 * occ
        dv = np.zeros_like(v)

        def bwd_kernel():
            for vb, ob, dvb, dob in zip(_instances(v), _instances(occ), _instances(dv), _instances(dout)):
                dvx_ext.voxelize_backward_cf_f32(vb, f, ob, dvb, dob)

        return lambda: dv.fill(0), bwd_kernel
    if op == "e2e":  # voxelize + (W**2).sum().backward(), one call per mesh
        leaf = torch.from_numpy(v.copy()).requires_grad_(True)

        def e2e():
            total = 0.0
            for vb in _instances(leaf):
                W = dvx_voxelize(n, vb, ft)
                loss = (W**2).sum()
                loss.backward()
                total += loss.detach().item()
            return total, leaf.grad

        return lambda: setattr(leaf, "grad", None), e2e
    if op == "floor":
        shape = ((batch,) if batch is not None else ()) + (n, n, n)
        return None, lambda: torch.full(shape, 1.0, dtype=torch.float32)
    raise ValueError(f"peer worker: unknown op {op!r}")


def check(n, prefix):
    """Saves dvx's output exactly as `voxelize` returns it ((z, y, x) order) and the
    gradient of sum(W**2), in float32 (as timed) and in float64, as `{prefix}_W32.npy`,
    `_g32`, `_W64`, `_g64`; also checks the raw float32 kernels against the wrapper."""
    n = int(n)
    ft = STATE["ft"]
    out = {"layout": "voxelize() returns (z, y, x); the raw kernel writes (x, y, z)"}
    arrays = {}
    for bits, dtype in ((32, np.float32), (64, np.float64)):
        v = STATE["v"].astype(dtype)
        with torch.no_grad():
            P = [dvx_voxelize(n, vb, ft).numpy() for vb in _instances(torch.from_numpy(v))]
        grid = P[0] if _batch() is None else np.stack(P)
        np.save(f"{prefix}_W{bits}.npy", grid)
        out[f"volume{bits}"] = float(grid.sum(dtype=np.float64) * (2.0 / n) ** 3)
        leaf = torch.from_numpy(v).requires_grad_(True)
        total = 0.0
        for vb in _instances(leaf):
            W = dvx_voxelize(n, vb, ft)
            loss = (W**2).sum()
            loss.backward()
            total += loss.detach().item()
            del W, loss
        grad = leaf.grad.numpy()
        np.save(f"{prefix}_g{bits}.npy", grad)
        out[f"loss{bits}"] = total
        arrays[bits] = (grid, grad)
        del P
    (W32, g32), (W64, g64) = arrays[32], arrays[64]
    out["self_f32_vs_f64_grid_max_abs"] = float(np.abs(W32.astype(np.float64) - W64).max())
    out["self_f32_vs_f64_grad_rel_l2"] = float(np.linalg.norm(g32 - g64) / max(np.linalg.norm(g64), 1e-300))

    # the raw float32 kernels (x, y, z) against the wrapper's (z, y, x) view
    raw = _raw_forward(n)
    out["raw_fwd_vs_wrapper_max_abs"] = max(
        float(np.abs(r - p.transpose(2, 1, 0)).max()) for r, p in zip(_instances(raw), _instances(W32))
    )
    dv = np.zeros_like(STATE["v"])
    for vb, ob, dvb in zip(_instances(STATE["v"]), _instances(raw), _instances(dv)):
        dvx_ext.voxelize_backward_cf_f32(vb, STATE["f"], ob, dvb, 2 * ob)
    out["raw_bwd_vs_autograd_max_rel"] = float(np.abs(dv - g32).max() / max(np.abs(g32).max(), 1e-30))
    del arrays, raw, W32, W64
    trim_memory()
    return out


def peak(op, n):
    """Peak RSS of one run of `op`, above the RSS just before it (after a tiny warm-up
    that initialises torch's autograd machinery)."""
    leaf = torch.from_numpy(STATE["v"].copy()).requires_grad_(True)
    for vb in _instances(leaf)[:1]:
        (dvx_voxelize(8, vb, STATE["ft"]) ** 2).sum().backward()
    del leaf
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
            "load": load,
            **op_handlers(STATE["ops"], _build),
            "check": check,
            "peak": peak,
        }
    )
