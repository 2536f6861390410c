"""Fuzz driver for the voxax kernels, meant to run under AddressSanitizer and UBSan.

`run_sanitized.py` builds the kernels with `-DVOXAX_SANITIZE=ON` and runs this script with
the sanitizer runtimes preloaded and `VOXAX_KERNELS` pointing at the sanitized library.
It can also run on its own (unsanitized) while developing: `python tests/sanitize/driver.py`.

It drives the forward, backward and tangent kernels -- eagerly and under `jax.jit`, float32 and
float64, 2D and 3D, single meshes, `vmap`-ed and leading-axis batches, zero-size batches
-- on random and adversarial inputs:

- triangle soups / random segments, closed star-shaped meshes and polygons;
- degenerate (zero-area, collinear, all-equal) and sliver faces, vertical faces;
- vertices exactly on voxel planes, on the grid's boundary and corners, faces lying in
  a grid plane, a box exactly on the grid's boundary;
- huge (1e30, up to the accepted 1e75) and tiny (1e-30) coordinates, meshes far
  outside the grid (above, below, beside it);
- 1-voxel, very thin and extreme-aspect grids ((1, 1, 500), (300, 1, 1), ...), grids
  spanning many kernel tiles, grids at 1e-30 and 1e30 scales;
- duplicate faces (identical and flipped);
- invalid inputs (NaN, Inf, |x| > 1e75, out-of-range and negative indices), which must
  raise the documented errors, and hostile raw FFI calls (bad grid attributes, mismatched
  shapes and dtypes), which must be rejected by the kernel's own validation.

Every result is checked for being finite and for |W| <= F (a face adds at most 1 to a
voxel); some results are compared bit for bit across eager/jit and single/batched calls;
closed meshes inside the grid are checked against the volume identity, and small benign
cases against the NumPy reference. The script prints how many inputs and kernel calls it
made. Sanitizer findings abort the process (the runner sets `abort_on_error=1` /
`halt_on_error=1`); failed checks give exit status 3 (`--artifacts DIR` saves their inputs).
"""

from __future__ import annotations

import argparse
import collections
import json
import os
import re
import sys
import time
import traceback
import warnings

import jax

jax.config.update("jax_enable_x64", True)

import jax.numpy as jnp  # noqa: E402
import numpy as np  # noqa: E402

import voxax  # noqa: E402
from voxax import (  # noqa: E402
    Grid,  # noqa: E402
    _kernels,
    reference,
)

# -- bookkeeping ---------------------------------------------------------------------------

COUNTS: collections.Counter = collections.Counter()  # inputs tried, per family
CALLS = collections.Counter()  # kernel-calling invocations, per mode
FAILURES: list[str] = []
TIMES: collections.Counter = collections.Counter()  # seconds per grid
OBSERVED: dict[str, str] = {}


def fail(msg: str) -> None:
    FAILURES.append(msg)
    print("CHECK FAILED:", msg, file=sys.stderr, flush=True)


# -- grids ---------------------------------------------------------------------------------

GRIDS_3D = {
    "cube6": Grid.cube(6),
    "odd": Grid((-0.7, -1.1, -0.9), (0.9, 0.6, 1.3), (5, 7, 3)),
    "one_voxel": Grid((-1, -1, -1), (1, 1, 1), (1, 1, 1)),
    "z500": Grid((-1, -1, -1), (1, 1, 1), (1, 1, 500)),
    "x300": Grid((-1, -1, -1), (1, 1, 1), (300, 1, 1)),
    "thin_y": Grid((-1, -0.01, -1), (1, 0.01, 1), (9, 1, 9)),
    "flat_z": Grid((-1, -1, -1e-6), (1, 1, 1e-6), (8, 8, 1)),
    "tiles": Grid((-1, -1, -1), (1, 1, 1), (33, 37, 64)),  # 6 kernel tiles
    "long_columns": Grid((-1, -1, -1), (1, 1, 1), (1, 2, 16400)),  # 1 column per tile
    "tiny": Grid((-1e-30,) * 3, (1e-30,) * 3, (4, 3, 5)),
    "huge": Grid((-1e30,) * 3, (1e30,) * 3, (3, 4, 5)),
    "offset": Grid((1e6, -1e6, 1e6), (1e6 + 1, -1e6 + 2, 1e6 + 3), (4, 5, 6)),
}
GRIDS_2D = {
    "square7": Grid.cube(7, dim=2),
    "odd": Grid((-0.7, -1.1), (0.9, 0.6), (5, 9)),
    "one_pixel": Grid((-1, -1), (1, 1), (1, 1)),
    "x500": Grid((-1, -1), (1, 1), (500, 1)),
    "y500": Grid((-1, -1), (1, 1), (1, 500)),
    "tiles": Grid((-1, -1), (1, 1), (100, 1000)),  # 4 kernel tiles
    "tiny": Grid((-1e-30,) * 2, (1e-30,) * 2, (4, 3)),
    "huge": Grid((-1e30,) * 2, (1e30,) * 2, (3, 4)),
}
# Grids on which the (slow) NumPy reference is cheap enough to compare with.
REFERENCE_GRIDS = {"cube6", "odd", "one_voxel", "thin_y", "flat_z", "square7", "one_pixel"}
# Padded sizes (V, F): inputs are padded with copies of vertex 0 and degenerate faces
# (which contribute nothing) so that every jitted function compiles once per bucket.
BUCKETS = {3: [(192, 256)], 2: [(128, 128)]}


# -- input families ------------------------------------------------------------------------


def box_of(grid: Grid, rng, pad=0.3):
    lo, hi = np.array(grid.lower), np.array(grid.upper)
    ext = hi - lo
    return lo - pad * ext, hi + pad * ext


def closed_star(rng, dim, center, scale):
    if dim == 3:
        n_theta, n_phi = int(rng.integers(3, 7)), int(rng.integers(2, 6))
        verts = [(0.0, 0.0, 1.0)]
        for i in range(1, n_phi):
            phi = np.pi * i / n_phi
            for j in range(n_theta):
                th = 2 * np.pi * j / n_theta
                verts.append((np.sin(phi) * np.cos(th), np.sin(phi) * np.sin(th), np.cos(phi)))
        verts.append((0.0, 0.0, -1.0))
        v = np.array(verts)
        v = v * (1.0 + 0.4 * (rng.random(len(v)) - 0.5))[:, None]
        faces = [(0, 1 + j, 1 + (j + 1) % n_theta) for j in range(n_theta)]
        for i in range(n_phi - 2):
            a0, b0 = 1 + i * n_theta, 1 + (i + 1) * n_theta
            for j in range(n_theta):
                j1 = (j + 1) % n_theta
                faces += [(a0 + j, b0 + j, b0 + j1), (a0 + j, b0 + j1, a0 + j1)]
        last, bottom = 1 + (n_phi - 2) * n_theta, len(v) - 1
        faces += [(bottom, last + (j + 1) % n_theta, last + j) for j in range(n_theta)]
        f = np.array(faces)
    else:
        n = int(rng.integers(3, 14))
        th = np.sort(rng.random(n)) * 2 * np.pi
        r = 1.0 + 0.5 * (rng.random(n) - 0.5)
        v = np.stack([r * np.cos(th), r * np.sin(th)], axis=1)
        f = np.stack([np.arange(n), (np.arange(n) + 1) % n], axis=1)
    return v * scale + center, f


def soup(rng, dim, grid, nf=None):
    lo, hi = box_of(grid, rng)
    nf = nf or int(rng.integers(1, 20))
    v = rng.uniform(lo, hi, size=(nf * dim, dim))
    return v, np.arange(nf * dim).reshape(nf, dim)


def snap_to_planes(rng, v, grid, p=0.7):
    """Moves coordinates exactly onto grid planes (including the boundary planes)."""
    v = v.copy()
    for a in range(grid.dim):
        e = grid.edges(a)
        idx = np.clip(np.round((v[:, a] - e[0]) / (e[-1] - e[0]) * (len(e) - 1)), 0, len(e) - 1).astype(int)
        mask = rng.random(len(v)) < p
        v[mask, a] = e[idx[mask]]
    return v


def family_soup(rng, dim, grid):
    return soup(rng, dim, grid)


def family_closed(rng, dim, grid):
    if rng.random() < 0.5:  # inside the grid
        lo, hi = np.array(grid.lower), np.array(grid.upper)
        scale = rng.uniform(0.05, 0.35) * (hi - lo)
        return closed_star(rng, dim, 0.5 * (lo + hi) + rng.uniform(-0.2, 0.2) * (hi - lo), scale)
    lo, hi = box_of(grid, rng, pad=0.2)
    center = rng.uniform(lo, hi)
    scale = float(np.max(hi - lo)) * rng.uniform(0.05, 0.7)
    return closed_star(rng, dim, center, scale)


def family_on_planes(rng, dim, grid):
    v, f = soup(rng, dim, grid) if rng.random() < 0.5 else family_closed(rng, dim, grid)
    return snap_to_planes(rng, v, grid), f


def family_in_plane(rng, dim, grid):
    """Faces lying exactly in a grid plane (horizontal or vertical), and along edges."""
    v, f = soup(rng, dim, grid)
    a = int(rng.integers(dim))
    e = grid.edges(a)
    for t in range(len(f)):
        v[f[t], a] = e[int(rng.integers(len(e)))]
    if rng.random() < 0.5:  # also put some faces on a second plane (along a grid line)
        b = (a + 1) % dim
        eb = grid.edges(b)
        for t in range(0, len(f), 2):
            v[f[t], b] = eb[int(rng.integers(len(eb)))]
    return v, f


def family_boundary_box(rng, dim, grid):
    """A box (square) whose faces lie exactly on the grid's boundary or inner planes."""
    lo, hi = np.array(grid.lower), np.array(grid.upper)
    if rng.random() < 0.5:
        for a in range(dim):
            e = grid.edges(a)
            i, j = sorted(rng.choice(len(e), size=2, replace=len(e) < 2))
            if i == j:
                j = min(i + 1, len(e) - 1)
                i = j - 1
            lo[a], hi[a] = e[i], e[j]
    if dim == 3:
        m = voxax.data.box(tuple(lo), tuple(hi))
        return np.asarray(m.vertices, np.float64), np.asarray(m.faces)
    v = np.array([[lo[0], lo[1]], [hi[0], lo[1]], [hi[0], hi[1]], [lo[0], hi[1]]])
    return v, np.array([[0, 1], [1, 2], [2, 3], [3, 0]])


def family_degenerate(rng, dim, grid):
    v, f = soup(rng, dim, grid)
    for t in range(len(f)):
        kind = rng.integers(4)
        if kind == 0:  # all corners equal
            v[f[t]] = v[f[t][0]]
        elif kind == 1 and dim == 3:  # collinear
            a, b = v[f[t][0]], v[f[t][1]]
            v[f[t][2]] = a + rng.uniform(-1, 2) * (b - a)
        elif kind == 2:  # repeated index
            f[t][-1] = f[t][0]
    return v, f


def family_sliver(rng, dim, grid):
    v, f = soup(rng, dim, grid)
    eps = 10.0 ** rng.uniform(-300, -6)
    for t in range(len(f)):
        a = v[f[t][0]]
        v[f[t][1]] = a + eps * rng.normal(size=dim) * float(np.max(np.abs(a)) + 1)
        if dim == 3 and rng.random() < 0.5:  # nearly collinear instead of nearly coincident
            b = v[f[t][2]]
            v[f[t][1]] = 0.5 * (a + b) + eps * rng.normal(size=dim)
    return v, f


def family_vertical(rng, dim, grid):
    v, f = soup(rng, dim, grid)
    for t in range(len(f)):  # no shadow: the projection along the ray axis (z, y in 2D) is degenerate
        if dim == 3:
            v[f[t][2], :2] = v[f[t][0], :2] + rng.uniform(-1, 2) * (v[f[t][1], :2] - v[f[t][0], :2])
        else:
            v[f[t][1], 0] = v[f[t][0], 0]
    return v, f


def family_huge(rng, dim, grid, dtype):
    top = 1e30 if dtype == np.float32 else 1e75
    mag = 10.0 ** rng.uniform(1, np.log10(top))
    scale = float(np.max(np.abs(grid.upper)) + np.max(np.abs(grid.lower)))
    if rng.random() < 0.5:  # a closed mesh enclosing (or far from) the grid
        center = rng.normal(size=dim) * mag * scale * rng.choice([0.0, 1e-3, 1.0])
        v, f = closed_star(rng, dim, center, mag * scale)
    else:
        v, f = soup(rng, dim, grid)
        mask = rng.random(v.shape) < 0.4
        v[mask] = rng.choice([-1, 1], size=mask.sum()) * mag * scale * rng.random(mask.sum())
    if rng.random() < 0.2:
        v[0, rng.integers(dim)] = rng.choice([-1, 1]) * top
    return np.clip(v, -top, top), f


def family_tiny(rng, dim, grid):
    eps = 10.0 ** rng.uniform(-300, -20)
    lo, hi = box_of(grid, rng, pad=0.0)
    anchor = rng.uniform(lo, hi)
    if rng.random() < 0.5:  # anchored on a grid plane
        anchor = snap_to_planes(rng, anchor[None], grid, p=1.0)[0]
    if rng.random() < 0.5:
        v, f = closed_star(rng, dim, anchor, eps)
    else:
        v, f = soup(rng, dim, grid)
        v = anchor + (v - v.mean(axis=0)) * eps
    return v, f


def family_far(rng, dim, grid):
    lo, hi = np.array(grid.lower), np.array(grid.upper)
    ext = float(np.max(hi - lo))
    v, f = closed_star(rng, dim, 0.5 * (lo + hi), ext * rng.uniform(0.1, 2.0))
    shift = np.zeros(dim)
    a = int(rng.integers(dim))
    shift[a] = rng.choice([-1, 1]) * ext * 10.0 ** rng.uniform(0.5, 8)
    if rng.random() < 0.3:
        shift[(a + 1) % dim] = rng.normal() * ext
    return v + shift, f


def family_duplicates(rng, dim, grid):
    v, f = family_closed(rng, dim, grid) if rng.random() < 0.5 else soup(rng, dim, grid)
    kind = rng.integers(3)
    if kind == 0:
        f = np.concatenate([f, f])  # duplicated faces: double winding
    elif kind == 1:
        f = np.concatenate([f, f[:, ::-1]])  # each face and its flip: cancel
    else:
        f = f[rng.integers(0, len(f), size=2 * len(f))]  # random repeats
    return v, f


def family_mixed(rng, dim, grid):
    parts = [FAMILIES[k](rng, dim, grid) for k in rng.choice(["soup", "closed", "on_planes", "far", "degenerate"], 2)]
    v = np.concatenate([p[0] for p in parts])
    f = np.concatenate([parts[0][1], parts[1][1] + len(parts[0][0])])
    return v, f


FAMILIES = {
    "soup": family_soup,
    "closed": family_closed,
    "on_planes": family_on_planes,
    "in_plane": family_in_plane,
    "boundary_box": family_boundary_box,
    "degenerate": family_degenerate,
    "sliver": family_sliver,
    "vertical": family_vertical,
    "huge": None,  # takes the dtype, see make_input
    "tiny": family_tiny,
    "far": family_far,
    "duplicates": family_duplicates,
    "mixed": family_mixed,
}
BENIGN = {"soup", "closed", "on_planes", "in_plane", "boundary_box", "degenerate", "vertical", "duplicates", "far"}


def is_closed(f, dim):
    """Whether every directed edge is matched by its reverse (segments: in = out degree).

    For such meshes (self-intersecting or not) the volume identity holds: when the mesh
    lies inside the grid, sum(W) * voxel volume is its signed volume.
    """
    f = np.asarray(f, np.int64)
    if dim == 2:  # every vertex is entered as often as it is left
        starts, n_out = np.unique(f[:, 0], return_counts=True)
        ends, n_in = np.unique(f[:, 1], return_counts=True)
        return bool(np.array_equal(starts, ends) and np.array_equal(n_out, n_in))
    a = np.concatenate([f[:, 0], f[:, 1], f[:, 2]])
    b = np.concatenate([f[:, 1], f[:, 2], f[:, 0]])
    key = lambda x, y: x * (int(f.max()) + 1) + y  # noqa: E731
    fwd, nf = np.unique(key(a, b), return_counts=True)
    rev, nr = np.unique(key(b, a), return_counts=True)
    return bool(np.array_equal(fwd, rev) and np.array_equal(nf, nr))


def make_input(rng, family, dim, grid, dtype):
    if family == "huge":
        v, f = family_huge(rng, dim, grid, dtype)
    else:
        v, f = FAMILIES[family](rng, dim, grid)
    v = np.asarray(v, np.float64)
    f = np.asarray(f, np.int64)
    if dtype == np.float32:
        v = np.clip(v, -1e30, 1e30)
    nf_real = len(f)
    # Pad to the smallest bucket that fits (shuffling the face order on the way).
    f = f[rng.permutation(len(f))]
    for nv_b, nf_b in BUCKETS[dim]:
        if len(v) <= nv_b and len(f) <= nf_b:
            break
    else:
        nv_b, nf_b = len(v), len(f)
    v = np.concatenate([v, np.repeat(v[:1], nv_b - len(v), axis=0)])
    f = np.concatenate([f, np.zeros((nf_b - len(f), dim), np.int64)])
    return v.astype(dtype), f.astype(np.int32), nf_real


def check_volume(label, W, v, f, nf_real, grid):
    """The volume identity for closed meshes inside the grid."""
    v64 = np.asarray(v, np.float64)
    f = np.asarray(f)[:nf_real]
    lo, hi = np.array(grid.lower), np.array(grid.upper)
    if not (is_closed(f, grid.dim) and np.all(v64[np.unique(f)] >= lo) and np.all(v64[np.unique(f)] <= hi)):
        return
    W = np.asarray(W)
    got = float(np.sum(W, dtype=np.float64)) * grid.voxel_volume
    # Relative to the grid's centre: sum(det(a, b, c)) / 6 cancels badly far from the origin.
    expected = reference.signed_volume(v64 - 0.5 * (lo + hi), f)
    box = float(np.prod(hi - lo))
    tol = (1e-10 if W.dtype == np.float64 else 1e-5) * box * max(1.0, float(np.max(np.abs(W))))
    if not abs(got - expected) <= tol:
        fail(f"{label}: volume identity: sum(W) * voxel volume = {got!r}, signed volume = {expected!r}")
    COUNTS["volume_checks"] += 1


# -- running and checking ------------------------------------------------------------------

_JIT: dict = {}


def jitted(kind, grid):
    key = (kind, grid)
    if key not in _JIT:
        if kind == "fwd":
            fn = jax.jit(lambda v, f: voxax.voxelize(v, f, grid))
        elif kind == "vjp":  # forward and gradient of sum(cot * W)

            def fn(v, f, cot):
                W, pull = jax.vjp(lambda x: voxax.voxelize(x, f, grid), v)
                return W, pull(cot)[0]

            fn = jax.jit(fn)
        elif kind == "corners":
            fn = jax.jit(lambda v, f, cot: voxax.voxelize_corner_gradients(v, f, grid, cot))
        elif kind == "vmap_vjp":

            def one(v, f, cot):
                W, pull = jax.vjp(lambda x: voxax.voxelize(x, f, grid), v)
                return W, pull(cot)[0]

            fn = jax.jit(jax.vmap(one, in_axes=(0, None, 0)))
        else:
            raise KeyError(kind)
        _JIT[key] = fn
    return _JIT[key]


ARTIFACTS = None  # directory for the inputs of failed checks (--artifacts)


def save_failure(label, v, f, grid):
    if ARTIFACTS is None:
        return
    os.makedirs(ARTIFACTS, exist_ok=True)
    name = os.path.join(ARTIFACTS, f"failure{len(FAILURES):03d}.npz")
    np.savez(name, vertices=v, faces=f, lower=grid.lower, upper=grid.upper, shape=grid.shape, label=label)
    print(f"  input saved to {name}", file=sys.stderr, flush=True)


def check_result(label, W, grads, nf_real, grid, batch=()):
    W = np.asarray(W)
    if W.shape != tuple(batch) + grid.shape:
        fail(f"{label}: output shape {W.shape}, expected {tuple(batch) + grid.shape}")
        return
    if not np.all(np.isfinite(W)):
        fail(f"{label}: non-finite output ({np.sum(~np.isfinite(W))} cells)")
        return
    bound = nf_real * (1 + 1e-6) + 1e-6
    if W.size and float(np.max(np.abs(W))) > bound:
        fail(f"{label}: |W| = {float(np.max(np.abs(W))):.6g} exceeds the face count {nf_real}")
    for g in grads:
        if not np.all(np.isfinite(np.asarray(g))):
            fail(f"{label}: non-finite gradient")


def run_single(rng, family, dim, grid_name, grid, dtype, mode):
    v, f, nf = make_input(rng, family, dim, grid, dtype)
    label = f"{family}/{dim}D/{grid_name}/{np.dtype(dtype).name}/{mode}"
    before = len(FAILURES)
    cot = rng.normal(size=grid.shape).astype(dtype)
    if mode == "eager":
        W = voxax.voxelize(v, f, grid)
        C = voxax.voxelize_corner_gradients(jnp.asarray(v), jnp.asarray(f), grid, jnp.asarray(cot))
        CALLS["eager_forward"] += 1
        CALLS["eager_backward"] += 1
        check_result(label, W, [C], nf, grid)
        if rng.random() < 0.25:  # eager and jit agree bit for bit
            Wj = jitted("fwd", grid)(v, f)
            CALLS["jit_forward"] += 1
            if np.asarray(Wj).tobytes() != np.asarray(W).tobytes():
                fail(f"{label}: eager and jit results differ")
    else:
        W, dv = jitted("vjp", grid)(v, f, cot)
        CALLS["jit_forward"] += 1
        CALLS["jit_backward"] += 1
        check_result(label, W, [dv], nf, grid)
    COUNTS[family] += 1
    COUNTS[f"dim{dim}"] += 1
    COUNTS[np.dtype(dtype).name] += 1
    COUNTS[mode] += 1
    check_volume(label, W, v, f, nf, grid)
    # Small benign float64 cases: compare with the NumPy reference.
    if (
        family in BENIGN
        and dtype == np.float64
        and grid_name in REFERENCE_GRIDS
        and nf <= 24
        and rng.random() < REFERENCE_FRACTION * (3 if family in ("on_planes", "in_plane", "boundary_box") else 1)
    ):
        expected = reference.voxelize(v, f[:nf], grid)
        scale = max(1.0, float(np.max(np.abs(v))) / float(np.max(np.abs(np.array(grid.upper) - grid.lower))))
        err = float(np.max(np.abs(np.asarray(W) - expected)))
        if err > 1e-9 * scale * max(1, nf):
            fail(f"{label}: differs from the reference by {err:.3g}")
        COUNTS["reference_comparisons"] += 1
    if len(FAILURES) > before:
        save_failure(label, v, f, grid)


def run_batched(rng, family, dim, grid_name, grid, dtype, B):
    items = [make_input(rng, family, dim, grid, dtype) for _ in range(B)]
    # One bucket for the whole batch: re-pad to the largest.
    nv = max(len(it[0]) for it in items)
    nfb = max(len(it[1]) for it in items)
    vs = np.stack([np.concatenate([it[0], np.repeat(it[0][:1], nv - len(it[0]), axis=0)]) for it in items])
    fs = np.stack([np.concatenate([it[1], np.zeros((nfb - len(it[1]), dim), np.int32)]) for it in items])
    nf = max(it[2] for it in items)
    label = f"{family}/{dim}D/{grid_name}/{np.dtype(dtype).name}/batch{B}"
    cot = rng.normal(size=(B,) + grid.shape).astype(dtype)
    how = rng.integers(3)
    if how == 0:  # vmap over vertices (shared faces: use item 0's faces for all)
        vs_shared = vs
        W, dv = jitted("vmap_vjp", grid)(vs_shared, fs[0], cot)
        CALLS["jit_vmap_forward"] += 1
        CALLS["jit_vmap_backward"] += 1
        check_result(label + "/vmap", W, [dv], nf, grid, (B,))
        k = int(rng.integers(B))
        W1 = jitted("fwd", grid)(vs_shared[k], fs[0])
        CALLS["jit_forward"] += 1
        if np.asarray(W1).tobytes() != np.asarray(W)[k].tobytes():
            fail(f"{label}: vmap item {k} differs from the single call")
    elif how == 1:  # leading axes on both
        W = voxax.voxelize(vs, fs, grid)
        C = voxax.voxelize_corner_gradients(jnp.asarray(vs), jnp.asarray(fs), grid, jnp.asarray(cot))
        CALLS["eager_batched_forward"] += 1
        CALLS["eager_batched_backward"] += 1
        check_result(label + "/leading", W, [C], nf, grid, (B,))
        k = int(rng.integers(B))
        W1 = voxax.voxelize(vs[k], fs[k], grid)
        CALLS["eager_forward"] += 1
        if np.asarray(W1).tobytes() != np.asarray(W)[k].tobytes():
            fail(f"{label}: batch item {k} differs from the single call")
    else:  # broadcast: (B, 1, V, d) vertices against (1, 2, F, d) faces
        f2 = np.stack([fs[0], fs[-1]])[None]
        W = jitted("fwd", grid)(vs[:, None], f2)
        CALLS["jit_batched_forward"] += 1
        check_result(label + "/broadcast", W, [], nf, grid, (B, 2))
    COUNTS[family] += B
    COUNTS[f"dim{dim}"] += B
    COUNTS[np.dtype(dtype).name] += B
    COUNTS["batched"] += B


def run_zero_size(dim, dtype):
    """Zero-size batches through every path."""
    grid = GRIDS_3D["cube6"] if dim == 3 else GRIDS_2D["square7"]
    v, f, _ = make_input(np.random.default_rng(0), "closed", dim, grid, dtype)
    v0 = np.zeros((0,) + v.shape, dtype)
    cases = {
        "vertices (0, V, d), eager": lambda: voxax.voxelize(v0, f, grid),
        "vertices (0, V, d), jit": lambda: jitted("fwd", grid)(v0, f),
        "vertices (2, 0, V, d), eager": lambda: voxax.voxelize(np.zeros((2, 0) + v.shape, dtype), f, grid),
        "faces (0, F, d), jit": lambda: jitted("fwd", grid)(v, np.zeros((0,) + f.shape, np.int32)),
        "vmap over 0 items, jit": lambda: jax.jit(jax.vmap(lambda x: voxax.voxelize(x, f, grid)))(v0),
        "grad through vmap over 0 items": lambda: jax.grad(
            lambda x: jax.vmap(lambda y: voxax.voxelize(y, f, grid))(x).sum()
        )(jnp.asarray(v0)),
        "vjp, jit": lambda: jitted("vjp", grid)(v0, f, np.zeros((0,) + grid.shape, dtype))[1],
        "corner gradients (0, F, d, d)": lambda: jitted("corners", grid)(v0, f, np.zeros((0,) + grid.shape, dtype)),
    }
    for name, fn in cases.items():
        out = jax.block_until_ready(fn())
        shape = tuple(np.shape(out))
        if 0 not in shape:
            fail(f"zero-size batch {name}: got shape {shape}")
        OBSERVED[f"zero-size batch {dim}D {np.dtype(dtype).name}: {name}"] = f"shape {shape}"
        CALLS["zero_size"] += 1
    # Eagerly, a zero-size *faces* batch is rejected by the Python validation with an
    # unhelpful NumPy message (see tests/voxelize/test_robustness.py); record what happens.
    try:
        out = voxax.voxelize(v, np.zeros((0,) + f.shape, np.int32), grid)
        OBSERVED[f"zero-size batch {dim}D {np.dtype(dtype).name}: faces (0, F, d), eager"] = f"shape {out.shape}"
    except Exception as err:  # noqa: BLE001
        OBSERVED[f"zero-size batch {dim}D {np.dtype(dtype).name}: faces (0, F, d), eager"] = (
            f"{type(err).__name__}: {err}"
        )
    COUNTS["zero_size"] += len(cases) + 1


INVALID = [
    ("nan", "NaN or Inf"),
    ("inf", "NaN or Inf"),
    ("-inf", "NaN or Inf"),
    ("too_big", "1e75"),
    ("index_high", "out of range"),
    ("index_negative", "negative|out of range"),
    ("index_int32_max", "out of range"),
]


def run_invalid(rng, dim, grid_name, grid, dtype, case, match):
    v, f, _ = make_input(rng, "closed", dim, grid, dtype)
    B = int(rng.choice([0, 0, BATCH]))  # also inside a batch item other than the first
    if B:
        v = np.stack([v] * B)
    flat_v = v.reshape(-1)
    if case in ("nan", "inf", "-inf", "too_big"):
        per = flat_v.size // max(B, 1)
        pos = int(rng.integers(per)) + per * max(B - 1, 0)  # in the last batch item
        value = {"nan": np.nan, "inf": np.inf, "-inf": -np.inf, "too_big": 1e151 if dtype == np.float64 else 3e38}[case]
        if case == "too_big" and dtype == np.float32:
            return  # float32 cannot hold a finite value above 1e75
        flat_v[pos] = value
    else:
        pos = tuple(int(rng.integers(s)) for s in f.shape)
        f[pos] = {"index_high": v.shape[-2] + int(rng.integers(0, 100)), "index_negative": -int(rng.integers(1, 2**31)),
                  "index_int32_max": 2**31 - 1}[case]
    cot = np.ones(v.shape[:-2] + grid.shape, dtype)
    label = f"invalid {case}/{dim}D/{grid_name}/{np.dtype(dtype).name}"
    paths = {
        "eager": lambda: voxax.voxelize(v, f, grid),
        "jit forward": lambda: jitted("fwd", grid)(v, f),
        "jit backward": lambda: jitted("corners", grid)(v, f, cot),
        "jit vjp": lambda: jitted("vmap_vjp", grid)(v, f, cot) if B else jitted("vjp", grid)(v, f, cot),
    }
    for path, fn in paths.items():
        try:
            jax.block_until_ready(fn())
        except (ValueError, jax.errors.JaxRuntimeError) as err:
            if not re.search(match, str(err)):
                fail(f"{label} [{path}]: unexpected message: {err}")
        except Exception as err:  # noqa: BLE001
            fail(f"{label} [{path}]: unexpected {type(err).__name__}: {err}")
        else:
            fail(f"{label} [{path}]: no error raised")
        CALLS["invalid"] += 1
    COUNTS["invalid"] += 1


def run_raw_ffi(rng):
    """Hostile direct FFI calls that bypass the Python checks: the kernel must reject them."""
    g = GRIDS_3D["odd"]
    v, f, _ = make_input(rng, "closed", 3, g, np.float64)
    v, f = jnp.asarray(v), jnp.asarray(f)
    attrs = _kernels.grid_attributes(g)

    def fwd(vv, ff, shape=g.shape, dtype=jnp.float64, **over):
        a = dict(attrs)
        a.update(over)
        return jax.ffi.ffi_call(_kernels.FORWARD, jax.ShapeDtypeStruct(shape, dtype))(vv, ff, **a)

    def bwd(vv, ff, cot, shape=None, dtype=jnp.float64, **over):
        a = dict(attrs)
        a.update(over)
        shape = shape or (ff.shape[-2], 3, 3)
        return jax.ffi.ffi_call(_kernels.BACKWARD, jax.ShapeDtypeStruct(shape, dtype))(vv, ff, cot, **a)

    cot = jnp.ones(g.shape)
    cases = {
        "nx = 0": lambda: fwd(v, f, nx=np.int64(0)),
        "nz = -7": lambda: fwd(v, f, nz=np.int64(-7)),
        "x0 = NaN": lambda: fwd(v, f, x0=np.float64(np.nan)),
        "y1 = Inf": lambda: fwd(v, f, y1=np.float64(np.inf)),
        "x1 < x0": lambda: fwd(v, f, x1=np.float64(-5.0)),
        "x1 == x0": lambda: fwd(v, f, x1=np.float64(attrs["x0"])),
        "subnormal cell": lambda: fwd(v, f, x0=np.float64(0.0), x1=np.float64(5e-324), nx=np.int64(5)),
        "output shape != grid": lambda: fwd(v, f, shape=(5, 7, 4)),
        "output rank too small": lambda: fwd(v, f, shape=(5, 7)),
        "output dtype != vertices": lambda: fwd(v, f, dtype=jnp.float32),
        "int64 faces": lambda: fwd(v, f.astype(jnp.int64)),
        "float faces": lambda: fwd(v, f.astype(jnp.float64)),
        "int vertices": lambda: fwd(v.astype(jnp.int32), f),
        "4 coordinates": lambda: fwd(jnp.zeros((8, 4)), jnp.zeros((4, 4), jnp.int32)),
        "1 coordinate": lambda: fwd(jnp.zeros((8, 1)), jnp.zeros((4, 1), jnp.int32)),
        "faces of 2 for 3D vertices": lambda: fwd(v, f[:, :2]),
        "rank-1 vertices": lambda: fwd(v.reshape(-1), f),
        "batch mismatch": lambda: fwd(jnp.stack([v] * 3), jnp.stack([f] * 2), shape=(3,) + g.shape),
        "batch axes count mismatch": lambda: fwd(jnp.stack([v] * 3), f, shape=(3,) + g.shape),
        "out batch mismatch": lambda: fwd(jnp.stack([v] * 3), jnp.stack([f] * 3), shape=(2,) + g.shape),
        "index out of range": lambda: fwd(v, f.at[3, 1].set(10**6)),
        "NaN vertex": lambda: fwd(v.at[2, 2].set(jnp.nan), f),
        "backward: cotangent shape": lambda: bwd(v, f, jnp.ones((5, 7, 4))),
        "backward: cotangent rank": lambda: bwd(v, f, jnp.ones((5, 7))),
        "backward: cotangent dtype": lambda: bwd(v, f, jnp.ones(g.shape, jnp.float32)),
        "backward: output shape": lambda: bwd(v, f, cot, shape=(f.shape[0], 3, 2)),
        "backward: output rank": lambda: bwd(v, f, cot, shape=(f.shape[0], 9)),
        "backward: output F": lambda: bwd(v, f, cot, shape=(f.shape[0] + 1, 3, 3)),
        "backward: cotangent batch": lambda: bwd(jnp.stack([v] * 2), jnp.stack([f] * 2), jnp.ones((3,) + g.shape),
                                                  shape=(2, f.shape[0], 3, 3)),
        "backward: index": lambda: bwd(v, f.at[0, 0].set(-3), cot),
        "window x_first < 0": lambda: fwd(v, f, x_first=np.int64(-1), x_count=np.int64(2), shape=(2,) + g.shape[1:]),
        "window past the frame": lambda: fwd(v, f, x_first=np.int64(g.shape[0] - 1), x_count=np.int64(2),
                                             shape=(2,) + g.shape[1:]),
        "window x_count < 0": lambda: fwd(v, f, x_first=np.int64(0), x_count=np.int64(-2)),
        "window x_first without x_count": lambda: fwd(v, f, x_first=np.int64(1), x_count=np.int64(0)),
        "window huge": lambda: fwd(v, f, x_first=np.int64(2**62), x_count=np.int64(2**62), shape=(2,) + g.shape[1:]),
        "window output != x_count": lambda: fwd(v, f, x_first=np.int64(1), x_count=np.int64(2),
                                                shape=(3,) + g.shape[1:]),
        "backward: window cotangent": lambda: bwd(v, f, jnp.ones((3,) + g.shape[1:]), x_first=np.int64(1),
                                                  x_count=np.int64(2)),
    }
    for name, fn in cases.items():
        try:
            jax.block_until_ready(fn())
        except Exception as err:  # noqa: BLE001 - a crash would abort instead
            if "INVALID_ARGUMENT" not in str(err):
                fail(f"raw FFI call '{name}' failed with an error that is not INVALID_ARGUMENT: {err}")
        else:
            fail(f"raw FFI call '{name}' was accepted")
        CALLS["raw_ffi"] += 1
    COUNTS["raw_ffi"] += len(cases)
    # The handlers still work afterwards.
    W = jax.block_until_ready(fwd(v, f))
    check_result("raw FFI after errors", W, [], len(f), g)
    # Random valid windows along x hold the frame's values bit for bit.
    nx = g.shape[0]
    for _ in range(6):
        first = int(rng.integers(0, nx))
        count = int(rng.integers(1, nx - first + 1))
        Ww = jax.block_until_ready(fwd(v, f, x_first=np.int64(first), x_count=np.int64(count),
                                       shape=(count,) + g.shape[1:]))
        if not np.array_equal(np.asarray(Ww), np.asarray(W)[first : first + count]):
            fail(f"raw FFI window [{first}, {first + count}) differs from the frame's cells")
        gw = jax.block_until_ready(bwd(v, f, jnp.ones((count,) + g.shape[1:]), x_first=np.int64(first),
                                       x_count=np.int64(count)))
        if not np.all(np.isfinite(np.asarray(gw))):
            fail(f"raw FFI window [{first}, {first + count}): non-finite backward")
        CALLS["raw_ffi"] += 2


# -- spatial queries (BVH) -----------------------------------------------------------------


def _spatial_soup(rng, kind):
    nf = int(rng.integers(0, 60))
    v = rng.uniform(-1, 1, (3 * nf + 1, 3))
    f = rng.integers(0, len(v), (nf, 3)).astype(np.int32)
    if kind == "degenerate" and nf:
        f = np.arange(3 * nf, dtype=np.int32).reshape(nf, 3)
        k = 3 * nf
        v[2:k:3] = v[0:k:3] + 0.37 * (v[1:k:3] - v[0:k:3])  # collinear corners
        f[: nf // 3, 2] = f[: nf // 3, 1]  # repeated index
    elif kind == "huge":
        v = v * 10.0 ** rng.integers(20, 75)
    elif kind == "tiny":
        v = v * 10.0 ** -rng.integers(20, 70)  # sets below 1e-75 are rejected (see the hostile inputs)
    elif kind == "flat":
        v[:, 2] = 0.0  # every face in one plane, rays in it
    elif kind == "grid":
        v = np.round(v * 2) / 2  # coincident vertices and faces on shared edges
    return v, f


def expect_rejected(kind: str, bad: dict, errors: tuple) -> None:
    """Each `name: (call, match)` of `bad` must raise one of `errors` (under jit: when its
    result is waited for) with a message matching `match`; counted in
    COUNTS[kind + "_invalid"]."""
    for name, (call, match) in bad.items():
        try:
            jax.block_until_ready(call())
        except errors as err:
            if not re.search(match, str(err)):
                fail(f"{kind} '{name}': unexpected message: {err}")
        except Exception as err:  # noqa: BLE001
            fail(f"{kind} '{name}': unexpected {type(err).__name__}: {err}")
        else:
            fail(f"{kind} '{name}': no error raised")
        COUNTS[kind + "_invalid"] += 1


def run_spatial(rng, n_inputs):
    """BVH closest points and ray hits (host and FFI paths) on adversarial soups, with
    brute-force checks of the distances on small inputs and hostile inputs that must raise."""
    kinds = ("random", "degenerate", "huge", "tiny", "flat", "grid")
    for i in range(n_inputs):
        kind = kinds[i % len(kinds)]
        v, f = _spatial_soup(rng, kind)
        scale = float(np.abs(v).max()) if v.size else 1.0
        p = rng.uniform(-1.5, 1.5, (40, 3)) * scale
        k = min(5, len(v))
        p[:k] = v[:k]  # queries exactly on vertices
        o = rng.uniform(-1.5, 1.5, (40, 3)) * scale
        d = rng.normal(size=(40, 3))
        d[:10] = np.round(d[:10])  # axis-aligned and diagonal directions
        d[np.all(d == 0, axis=1)] = (0.0, 0.0, 1.0)
        o[:k] = v[:k] - d[:k]  # rays through vertices
        label = f"spatial/{kind}/{i}"
        try:
            bvh = voxax.BVH(v, f)
            cp = bvh.closest_points(p, threads=1 + i % 3)
            hits = bvh.all_hits(o, d, threads=1 + i % 2)
            first = bvh.first_hits(o, d)
            CALLS["spatial_host"] += 3
            if len(f):
                if not np.all(np.isfinite(cp.distance)) or np.any(cp.face < 0) or np.any(cp.face >= len(f)):
                    fail(f"{label}: non-finite distance or bad face")
                # the reported point is at the reported distance
                err = np.abs(np.linalg.norm(p - cp.point, axis=1) - cp.distance)
                if np.any(err > 1e-9 * (1 + scale)):
                    fail(f"{label}: closest point not at its distance (max error {err.max():.3g})")
                # no vertex is closer than the reported distance
                dv = np.min(np.linalg.norm(p[:, None] - v[np.unique(f)][None], axis=2), axis=1)
                if np.any(cp.distance > dv * (1 + 1e-12) + 1e-300):
                    fail(f"{label}: a vertex is closer than the reported closest point")
            if np.any(hits.face >= len(f)) or not np.all(np.isfinite(hits.t)):
                fail(f"{label}: bad hits")
            firsts = np.where(hits.counts() > 0, hits.t[np.minimum(hits.offsets[:-1], max(len(hits.t) - 1, 0))]
                              if len(hits.t) else np.inf, np.inf)
            if not np.array_equal(np.where(first.hit, first.t, np.inf), firsts):
                fail(f"{label}: first hit differs from the first of all hits")
            if len(f):
                jf = jax.jit(lambda vv, ff, pp: voxax.closest_points((vv, ff), pp))(v, f, p)
                if not np.array_equal(np.asarray(jf.distance), cp.distance):
                    fail(f"{label}: FFI closest points differ from the host path")
                jr = jax.jit(lambda vv, ff, a, b: voxax.first_hits((vv, ff), a, b))(v, f, o, d)
                if not np.array_equal(np.asarray(jr.t), first.t):
                    fail(f"{label}: FFI first hits differ from the host path")
                CALLS["spatial_ffi"] += 2
                # closest points within a distance: the unbounded answer where it is within
                # the bound, none beyond (bounds 0, a quantile and inf)
                for cap in (0.0, float(np.quantile(cp.distance, 0.3)), np.inf):
                    cc = bvh.closest_points(p, threads=1 + i % 2, max_distance=cap)
                    near = cp.distance <= cap
                    if not (np.array_equal(cc.distance[near], cp.distance[near])
                            and np.all(np.isinf(cc.distance[~near])) and np.all(cc.face[~near] == -1)):
                        fail(f"{label}: closest points within {cap} differ from the unbounded ones")
                CALLS["spatial_host"] += 3
            # k nearest neighbours of the vertices, host and FFI, against brute force
            kn = 1 + i % 8
            dk, ik = voxax.nearest_neighbors(v, p, kn, threads=1 + i % 2)
            jd, ji = jax.jit(lambda s_, q_, kn=kn: voxax.nearest_neighbors(s_, q_, kn))(v, p)
            if not (np.array_equal(np.asarray(jd), dk) and np.array_equal(np.asarray(ji), ik)):
                fail(f"{label}: kNN FFI differs from the host path")
            ref = np.sort(np.sqrt(((p[:, None] - v[None]) ** 2).sum(-1)), axis=1)[:, :kn]
            if not np.allclose(dk[:, : ref.shape[1]], ref, rtol=1e-12, atol=0):
                fail(f"{label}: kNN distances differ from brute force")
            CALLS["spatial_knn"] += 2
            # the ESI column test (random frames and depth limits, points off the grid, NaN)
            # against its formula evaluated here, away from cell borders and limits
            from voxax._kernels import esi as _kesi

            sc = scale if scale > 0 else 1.0
            G = 1 + i % 7
            frames = np.zeros((3, 15))
            for kk in range(3):
                q_, _ = np.linalg.qr(rng.normal(size=(3, 3)))
                frames[kk, :9] = q_.ravel()
                frames[kk, 9:12] = rng.uniform(-0.2, 0.2, 3) * sc
                frames[kk, 12:15] = (rng.choice([-1.0, 1.0]), sc, 2 * sc / G)
            lims = rng.uniform(-sc, sc, (3, G * G))
            lims[:, ::3] = np.inf
            lims[:, 1::5] = -np.inf
            qp = np.concatenate([p, [[np.nan, 0.0, 0.0], [0.0, np.inf, 0.0]]])
            qk = rng.integers(3, size=len(qp))
            got = _kesi.column_test(qp, qk, frames, G, lims, 1 + i % 2)
            if not np.array_equal(got, _kesi.column_test(qp, qk, frames, G, lims, 1)):
                fail(f"{label}: column test differs across thread counts")
            for j in range(len(qp)):
                q_ = frames[qk[j]]
                with np.errstate(invalid="ignore"):
                    loc = qp[j] @ q_[:9].reshape(3, 3) - q_[9:12]
                    fi, fj = (loc[:2] + q_[13]) / q_[14]
                if not (np.all(np.isfinite(loc)) and 0 <= fi < G and 0 <= fj < G):
                    want = False
                else:
                    near = min(abs(fi - round(fi)), abs(fj - round(fj))) < 1e-9
                    lim = lims[qk[j], int(fi) * G + int(fj)]
                    if near or (np.isfinite(lim) and abs(q_[12] * loc[2] - lim) < 1e-9 * sc):
                        continue
                    want = q_[12] * loc[2] < lim
                if bool(got[j]) != want:
                    fail(f"{label}: column test of point {j} is {bool(got[j])}, its formula {want}")
            CALLS["esi_column_test"] += 2
            # the ESI column lists and exact column casts over this soup (two random lines,
            # both signs): the same bits for 1 and 2 threads, hits only where the column test
            # passes; on random soups the BVH's hits; the block-wise known casts equal them
            if len(f):
                from voxax._kernels import esi as _kesi

                R = 1.8 * sc
                Gl = 1 + i % 9
                lf = np.zeros((2, 15))
                for li in range(2):
                    q_, _ = np.linalg.qr(rng.normal(size=(3, 3)))
                    lf[li, :9] = q_.ravel()
                    lf[li, 12:15] = (1.0, R, 2 * R / Gl)
                offs, ents, lo_, hi_ = _kesi.column_lists(v, f, lf, Gl, 1e-6 * sc, 1 + i % 2)
                prm = np.repeat(lf, 2, axis=0)
                prm[1::2, 12] = -1.0
                dirs_ = lf[:, [2, 5, 8]].repeat(2, axis=0) * prm[:, 12:13]
                lims_ = np.stack([hi_[0], -lo_[0], hi_[1], -lo_[1]])
                casts = _kesi.Casts.make(prm, dirs_, [0, 0, 1, 1], Gl, lims_, offs, ents,
                                    np.asarray(v, np.float64)[np.asarray(f)].reshape(-1, 9), 1e-9 * sc)
                qp = np.concatenate([o, [[np.nan, 0.0, 0.0]]])
                qk = rng.integers(4, size=len(qp))
                got = _kesi.column_hits(qp, qk, casts, 2)
                if not np.array_equal(got, _kesi.column_hits(qp, qk, casts, 1)) or np.any((got & 1) > (got >> 1)):
                    fail(f"{label}: column casts differ across thread counts or hit without a look")
                if kind == "random":
                    want = bvh.any_hits(o[k:], dirs_[qk[k:-1]], t_min=1e-9 * sc)
                    if not np.array_equal((got[k:-1] & 1) == 1, want):
                        fail(f"{label}: column casts differ from the BVH's any hits")
                IN = np.zeros((4, len(o)), bool)
                ghit = np.full((4, len(o)), -1, np.int8)
                pairs = np.array([(b, c) for b in range(2) for c in range(4)])
                _kesi.column_known(pairs, [0, len(o) // 3, len(o)], IN, np.arange(len(o)), np.arange(4), ghit,
                              len(o), o, casts, 1 + i % 2)
                direct = np.stack([_kesi.column_hits(o, np.full(len(o), c), casts, 1) & 1 for c in range(4)])
                if not (np.array_equal(IN, direct == 1) and np.array_equal(ghit, direct.astype(np.int8))):
                    fail(f"{label}: known column casts differ from the direct casts")
                # inside two height fields, a block at a time (one with a single direction,
                # points outside every block untouched): the direct casts' AND
                third = len(o) // 3
                blocks = [(0, third, 0, 3), (third, 2 * third, 2, -1)]
                inside, _ = _kesi.column_inside(o, blocks, casts, 1 + i % 2)
                want = np.zeros(len(o), bool)
                want[:third] = (direct[0] & direct[3])[:third] == 1
                want[third : 2 * third] = direct[2][third : 2 * third] == 1
                if not np.array_equal(inside, want):
                    fail(f"{label}: column inside-tests differ from the direct casts")
                CALLS["esi_column_casts"] += 4
            # the CVT assignment (nearest seed and region moments) from random hints, host and FFI
            from voxax._kernels.cvt import assign as _assign_moments
            from voxax._kernels.cvt import assign_host as assign_moments_host

            if len(v):
                wq = rng.uniform(0.0, 1.0, len(p))
                hq = rng.integers(-2, len(v) + 2, len(p)).astype(np.int32)
                ai, am, _, _ = assign_moments_host(v, p, wq, hq, threads=1 + i % 2)
                if not np.array_equal(ai, ik[:, 0]):
                    fail(f"{label}: CVT assignment differs from the nearest neighbour")
                ja = jax.jit(_assign_moments)(v, p, wq, hq)
                if not (np.array_equal(np.asarray(ja[0]), ai) and np.asarray(ja[1]).tobytes() == am.tobytes()):
                    fail(f"{label}: CVT assignment FFI differs from the host path")
                CALLS["cvt_assign"] += 2
        except Exception:  # noqa: BLE001
            fail(f"{label}: raised\n" + traceback.format_exc())
        COUNTS["spatial"] += 1
    # hostile inputs: every path must raise a clear error
    from voxax._kernels import esi as _kesi
    from voxax._kernels.cvt import assign as _assign_moments
    from voxax._kernels.cvt import assign_host as assign_moments_host

    v, f = rng.uniform(-1, 1, (30, 3)), np.arange(30, dtype=np.int32).reshape(10, 3)

    def good_casts(entries=None, bad=False):
        offs, ents, lo_, hi_ = _kesi.column_lists(v, f, col_ok[None], 2, 1e-9, None)
        if entries is not None:
            ents = ents[:entries]
        if bad:
            ents = np.where(np.arange(len(ents)) == 0, 99, ents)
        return _kesi.Casts.make(col_ok[None], [col_ok[[2, 5, 8]]], [0], 2, np.full((1, 4), np.inf), offs, ents,
                           v[f].reshape(-1, 9), 1e-9)

    col_ok = np.array([1.0, 0, 0, 0, 1, 0, 0, 0, 1, 0, 0, 0, 1, 1, 1])  # identity frame, R = h = 1
    bad = {
        "NaN point": (lambda: voxax.closest_points((v, f), [[np.nan, 0, 0]]), "NaN"),
        "Inf origin": (lambda: voxax.first_hits((v, f), [[np.inf, 0, 0]], [[1, 0, 0]]), "NaN or Inf"),
        "zero direction": (lambda: voxax.all_hits((v, f), [[0, 0, 0]], [[0, 0, 0]]), "zero"),
        "index high": (lambda: voxax.BVH(v, f.clip(max=29) + 1), "range"),
        "huge vertex": (lambda: voxax.BVH(v * 1e80, f), "1e75"),
        "tiny mesh": (lambda: voxax.BVH(v * 10.0 ** -int(rng.integers(76, 320)), f), "below 1e-75"),
        "jit tiny mesh": (lambda: jax.jit(lambda vv: voxax.closest_points((vv, f), jnp.zeros((1, 3))))(v * 1e-200),
                          "below 1e-75"),
        "jit NaN point": (lambda: jax.jit(lambda pp: voxax.closest_points((v, f), pp))(jnp.full((3, 3), jnp.nan)),
                          "NaN"),
        "jit index": (lambda: jax.jit(lambda ff: voxax.closest_points((v, ff), jnp.zeros((1, 3))))(f + 100),
                      "out of range"),
        "jit zero direction": (lambda: jax.jit(lambda dd: voxax.first_hits((v, f), jnp.zeros((1, 3)), dd))(
            jnp.zeros((1, 3))), "zero"),
        "raw FFI wrong rank": (lambda: jax.ffi.ffi_call(_kernels.CLOSEST_POINTS, (
            jax.ShapeDtypeStruct((3,), jnp.float64), jax.ShapeDtypeStruct((3,), jnp.int32),
            jax.ShapeDtypeStruct((3, 3), jnp.float64), jax.ShapeDtypeStruct((3, 3), jnp.float64)))(
            jnp.asarray(v), jnp.asarray(f), jnp.zeros((3, 2))), "shape"),
        "raw FFI wrong outputs": (lambda: jax.ffi.ffi_call(_kernels.CLOSEST_POINTS, (
            jax.ShapeDtypeStruct((5,), jnp.float64), jax.ShapeDtypeStruct((3,), jnp.int32),
            jax.ShapeDtypeStruct((3, 3), jnp.float64), jax.ShapeDtypeStruct((3, 3), jnp.float64)))(
            jnp.asarray(v), jnp.asarray(f), jnp.zeros((3, 3))), "outputs"),
        # the ESI column test
        "column test direction": (lambda: _kesi.column_test(v, np.full(30, 3), np.tile(col_ok, (3, 1)), 2,
                                                       np.zeros((3, 4)), None), r"outside \[0, 3\)"),
        "column test negative direction": (lambda: _kesi.column_test(v, np.full(30, -1), np.tile(col_ok, (3, 1)), 2,
                                                                np.zeros((3, 4)), None), "outside"),
        "column test zero width": (lambda: _kesi.column_test(v, np.zeros(30, np.int64),
                                                        np.where(np.arange(15) == 14, 0.0, col_ok)[None], 2,
                                                        np.zeros((1, 4)), None), "cell width"),
        "column test NaN frame": (lambda: _kesi.column_test(v, np.zeros(30, np.int64), np.where(
            np.arange(15) == 3, np.nan, col_ok)[None], 2, np.zeros((1, 4)), None), "finite"),
        "column test resolution 0": (lambda: _kesi.column_test(v, np.zeros(30, np.int64), col_ok[None], 0,
                                                          np.zeros((1, 0)), None), "resolution"),
        "column test short table": (lambda: _kesi.column_test(v, np.zeros(30, np.int64), col_ok[None], 2,
                                                         np.zeros((1, 3)), None), "lims"),
        "closest points negative bound": (lambda: voxax.BVH(v, f).closest_points(v, max_distance=-1.0), "max_distance"),
        "closest points NaN bound": (lambda: voxax.BVH(v, f).closest_points(v, max_distance=np.nan), "max_distance"),
        # the ESI column lists and casts
        "column lists face index": (lambda: _kesi.column_lists(v, f + 1, col_ok[None], 2, 0.0, None),
                                    "vertex index"),
        "column lists NaN vertex": (lambda: _kesi.column_lists(np.where(v == v[0], np.nan, v), f, col_ok[None], 2,
                                                               0.0, None),
                                    "finite"),
        "column lists negative margin": (lambda: _kesi.column_lists(v, f, col_ok[None], 2, -1.0, None), "margin"),
        "column casts direction": (lambda: _kesi.column_hits(v, np.full(30, 1), good_casts(), None), "outside"),
        "column casts short entries": (lambda: _kesi.column_hits(v, np.zeros(30, np.int64), good_casts(entries=3),
                                                            None), "out of range"),
        "column casts bad entry": (lambda: _kesi.column_hits(v, np.zeros(30, np.int64), good_casts(bad=True), None),
                                   "out of range"),
        "column casts table shapes": (lambda: _kesi.Casts.make(col_ok[None], np.zeros((2, 3)), [0], 2, np.zeros((1, 4)),
                                                          np.zeros(5, np.int64), [], np.zeros((0, 9)), 0.0), "shapes"),
        "column known pair": (lambda: _kesi.column_known([[2, 0]], [0, 10, 30], np.zeros((1, 30), bool), np.arange(30),
                                                    [0], np.full((1, 30), -1, np.int8), 30, v, good_casts(), None),
                              "pair"),
        "column known unregistered": (lambda: _kesi.column_known([[0, 0]], [0, 10, 30], np.zeros((1, 30), bool),
                                                            np.full(30, -1), [0], np.full((1, 30), -1, np.int8), 30, v,
                                                            good_casts(), None), "not registered"),
        "column known blocks": (lambda: _kesi.column_known([[0, 0]], [0, 40], np.zeros((1, 30), bool), np.arange(30),
                                                      [0], np.full((1, 30), -1, np.int8), 30, v, good_casts(), None),
                                "blocks"),
        "column inside direction": (lambda: _kesi.column_inside(v, [(0, 30, 1, -1)], good_casts(), None), "directions"),
        "column inside range": (lambda: _kesi.column_inside(v, [(0, 31, 0, -1)], good_casts(), None), "start <= end"),
        "column inside overlap": (lambda: _kesi.column_inside(v, [(0, 20, 0, -1), (10, 30, 0, -1)], good_casts(), None),
                                  "overlap"),
        # the CVT assignment kernel, host and FFI
        "CVT assign NaN seed": (lambda: assign_moments_host(np.where(v == v[0], np.nan, v), v, np.ones(30)), "NaN"),
        "CVT assign no seeds": (lambda: assign_moments_host(np.zeros((0, 3)), v, np.ones(30)), "seeds"),
        "CVT assign negative weight": (lambda: assign_moments_host(v, v, -np.ones(30)), "weights"),
        "CVT assign tiny seeds": (lambda: assign_moments_host(v * 1e-200, v, np.ones(30)), "below 1e-75"),
        "jit CVT assign NaN weight": (lambda: jax.jit(_assign_moments)(
            v, v, jnp.full(30, jnp.nan), jnp.full(30, 1 << 30, jnp.int32)), "weights"),
        "jit CVT assign Inf sample": (lambda: jax.jit(_assign_moments)(
            v, jnp.full((30, 3), jnp.inf), jnp.ones(30), jnp.zeros(30, jnp.int32)), "NaN or Inf"),
        "raw FFI CVT assign short hint": (lambda: jax.ffi.ffi_call(_kernels.CVT_ASSIGN, (
            jax.ShapeDtypeStruct((30,), jnp.int32), jax.ShapeDtypeStruct((30, 4), jnp.float64),
            jax.ShapeDtypeStruct((30,), jnp.int32), jax.ShapeDtypeStruct((1,), jnp.float64)))(
            jnp.asarray(v), jnp.asarray(v), jnp.ones(30), jnp.zeros(29, jnp.int32)), "shape"),
        "raw FFI CVT assign wrong outputs": (lambda: jax.ffi.ffi_call(_kernels.CVT_ASSIGN, (
            jax.ShapeDtypeStruct((30,), jnp.int32), jax.ShapeDtypeStruct((29, 4), jnp.float64),
            jax.ShapeDtypeStruct((30,), jnp.int32), jax.ShapeDtypeStruct((1,), jnp.float64)))(
            jnp.asarray(v), jnp.asarray(v), jnp.ones(30), jnp.zeros(30, jnp.int32)), "outputs"),
    }
    expect_rejected("spatial", bad, (ValueError, TypeError, jax.errors.JaxRuntimeError))


def _knn_points(rng, kind):
    """Data points for the kNN fuzzing: sets that leave most of a grid empty (surfaces,
    curves, far clusters), duplicates and ties, extreme scales."""
    n = int(rng.integers(0, 400))
    if kind == "uniform":
        s = rng.uniform(-1, 1, (n, 3))
    elif kind == "surface":
        u = rng.normal(size=(n, 3))
        s = u / np.maximum(np.linalg.norm(u, axis=1, keepdims=True), 1e-300)
    elif kind == "curve":
        t = rng.uniform(0, 6.3, n)
        s = np.stack([np.cos(t), np.sin(t), 0.2 * t], axis=1)
    elif kind == "clusters":
        s = rng.normal(size=(n, 3)) * 1e-3 + 10.0 ** rng.integers(0, 8) * rng.integers(0, 2, (n, 1))
    elif kind == "duplicates":
        s = np.repeat(rng.uniform(-1, 1, (int(rng.integers(1, 6)), 3)), 80, axis=0)[: max(n, 1)]
    elif kind == "lattice":
        s = np.round(rng.uniform(-2, 2, (n, 3)))
    elif kind == "flat":
        s = rng.uniform(-1, 1, (n, 3)) * [1, 1, 0]
    else:  # scaled: huge or tiny (sets all below 1e-75 are refused, see the hostile inputs)
        s = rng.uniform(-1, 1, (n, 3)) * 10.0 ** int(rng.integers(-70, 74))
    return s


def run_knn(rng, n_inputs):
    """k nearest neighbours (`csrc/spatial/knn_host.cc`, `knn_ffi.cc`; the grid and the
    kd-tree of far queries) against brute force in the kernel's arithmetic, bit for bit
    (ties by index), host == FFI and across thread counts; then hostile inputs."""
    kinds = ("uniform", "surface", "curve", "clusters", "duplicates", "lattice", "flat", "scaled")
    for i in range(n_inputs):
        kind = kinds[i % len(kinds)]
        label = f"knn/{kind}/{i}"
        s = _knn_points(rng, kind)
        scale = float(np.abs(s).max()) if s.size else 1.0
        lo = s.min(0) if len(s) else np.zeros(3)
        hi = s.max(0) if len(s) else np.ones(3)
        span = np.maximum(hi - lo, scale * 1e-3 + 1e-300)
        m = int(rng.integers(0, 300))
        q = rng.uniform(lo - span, hi + span, (m, 3))  # near, far and beyond the box
        if len(s) and m:
            q[: m // 3] = s[rng.integers(0, len(s), m // 3)]  # on data points
        if m:  # far away, within the accepted 1e75
            q[m // 3: m // 2] *= min(10.0 ** int(rng.integers(0, 6)), 1e74 / max(float(np.abs(q).max()), 1e-300))
        k = int(rng.integers(1, 33))
        dk, ik = voxax.nearest_neighbors(s, q, k, threads=1)
        d2k, i2k = voxax.nearest_neighbors(s, q, k, threads=2)
        jd, ji = jax.jit(lambda s_, q_, k=k: voxax.nearest_neighbors(s_, q_, k))(s, q)
        CALLS["knn"] += 3
        if not (np.array_equal(dk, d2k) and np.array_equal(ik, i2k)):
            fail(f"{label}: kNN differs between 1 and 2 threads")
        if not (np.array_equal(np.asarray(jd), dk) and np.array_equal(np.asarray(ji), ik)):
            fail(f"{label}: kNN FFI differs from the host path")
        ref_d = np.full((m, k), np.inf)
        ref_i = np.full((m, k), -1, np.int32)
        if len(s) and m:
            dx, dy, dz = (s[None, :, a] - q[:, None, a] for a in range(3))
            d2 = dx * dx + dy * dy + dz * dz
            order = np.argsort(d2, axis=1, kind="stable")[:, :k]
            ref_i[:, : order.shape[1]] = order
            ref_d[:, : order.shape[1]] = np.sqrt(np.take_along_axis(d2, order, axis=1))
        if not (np.array_equal(ik, ref_i) and np.array_equal(dk, ref_d)):
            fail(f"{label}: kNN differs from brute force (k = {k}, {len(s)} points, {m} queries)")
        COUNTS["knn"] += 1
    v = rng.uniform(-1, 1, (30, 3))
    bad = {
        "kNN tiny points": (lambda: voxax.nearest_neighbors(v * 1e-90, v, 2), "below 1e-75"),
        "jit kNN tiny points": (lambda: jax.jit(lambda pp: voxax.nearest_neighbors(pp, jnp.zeros((2, 3)), 2))(
            v * 1e-300), "below 1e-75"),
        "kNN k = 40": (lambda: voxax.nearest_neighbors(v, v, 40), "`k` must lie in"),
        "kNN k = 2.7": (lambda: voxax.nearest_neighbors(v, v, 2.7), "`k` must be an int"),
        "kNN k = '2'": (lambda: voxax.nearest_neighbors(v, v, "2"), "`k` must be an int"),
        "kNN bool points": (lambda: voxax.nearest_neighbors(v > 0, v, 2), "`points` must be a real"),
        "kNN complex queries": (lambda: voxax.nearest_neighbors(v, v * 1j, 2), "`queries` must be a real"),
        "kNN NaN queries": (lambda: voxax.nearest_neighbors(v, np.full((2, 3), np.nan), 2), "must be finite"),
        "kNN huge points": (lambda: voxax.nearest_neighbors(v * 1e80, v, 2), "at most 1e75"),
        "jit kNN Inf points": (lambda: jax.jit(lambda pp: voxax.nearest_neighbors(pp, v, 3))(
            jnp.full((4, 3), jnp.inf)), "`points` must be finite"),
        "jit kNN NaN queries": (lambda: jax.jit(lambda qq: voxax.nearest_neighbors(v, qq, 3))(
            jnp.full((4, 3), jnp.nan)), "`queries` must be finite"),
        "raw FFI kNN k = 40": (lambda: jax.ffi.ffi_call(_kernels.KNN, (
            jax.ShapeDtypeStruct((3, 40), jnp.int32), jax.ShapeDtypeStruct((3, 40), jnp.float64)))(
            jnp.asarray(v), jnp.zeros((3, 3))), "`k` must lie in"),
        "raw FFI kNN mismatched outputs": (lambda: jax.ffi.ffi_call(_kernels.KNN, (
            jax.ShapeDtypeStruct((3, 2), jnp.int32), jax.ShapeDtypeStruct((4, 2), jnp.float64)))(
            jnp.asarray(v), jnp.zeros((3, 3))), "shape"),
        "raw FFI kNN queries (3, 2)": (lambda: jax.ffi.ffi_call(_kernels.KNN, (
            jax.ShapeDtypeStruct((3, 2), jnp.int32), jax.ShapeDtypeStruct((3, 2), jnp.float64)))(
            jnp.asarray(v), jnp.zeros((3, 2))), "shape"),
    }
    expect_rejected("knn", bad, (ValueError, TypeError, jax.errors.JaxRuntimeError))


def run_bounds(rng, n_inputs):
    """The sums of the selection's bounds (`csrc/esi/bounds_host.cc`): random inputs
    from empty up, against their definitions and across thread counts, then hostile ones."""
    sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "esi"))
    from _esi_shapes import (
        bound_blocks_reference,
        bound_removals_reference,
        bound_samples_reference,
        random_bound_case,
        random_sample_tables,
    )

    from voxax._kernels import esi as _kesi

    def close(label, got, want):
        for g, w in zip(got, want):
            if np.shape(g) != np.shape(w) or not np.allclose(g, w, rtol=1e-12, atol=1e-12):
                fail(f"bounds {label}: differs from its definition")

    for t in range(n_inputs):
        IN, rows, cols, col_of, s3, wd, wt = random_bound_case(rng, nh=60 if t % 7 == 0 else None)
        for co in [None] + ([col_of] if len(cols) or not len(rows) else []):
            runs = [_kesi.bound_removals(IN, rows, cols, co, s3, wd, wt, th) for th in (1, 2, 3)]
            if any(not all(np.array_equal(a, b) for a, b in zip(runs[0], r)) for r in runs[1:]):
                fail("bounds removals: results depend on the thread count")
            close("removals", runs[0], bound_removals_reference(IN, rows, cols, co, s3, wd, wt))
            COUNTS["bounds"] += 3
            CALLS["esi_bounds"] += 3
        tables = random_sample_tables(rng, IN.shape[0], 40, 40)
        ws = bool(t % 2)
        close("samples", _kesi.bound_samples(*tables, ws), bound_samples_reference(*tables, ws))
        R = IN.shape[1]
        off = np.sort(rng.integers(0, R + 1, int(rng.integers(1, 6))))
        alive = rng.random(R) < 0.5
        close("blocks", [_kesi.bound_blocks(alive, off, wd, wt)], [bound_blocks_reference(alive, off, wd, wt)])
        COUNTS["bounds"] += 2
        CALLS["esi_bounds"] += 2
    IN = np.zeros((4, 10), bool)
    w = np.ones(10)
    D5, B5 = np.zeros((5, 4)), np.zeros((5, 4), bool)
    D6, B6 = np.zeros((5, 5)), np.zeros((5, 5), bool)
    bad = {
        "row": (lambda: _kesi.bound_removals(IN, [10], [0], None, 0, w, w, 2), "outside"),
        "negative row": (lambda: _kesi.bound_removals(IN, [-1], [0], None, 0, w, w, 2), "outside"),
        "column": (lambda: _kesi.bound_removals(IN, [1], [4], None, 0, w, w, 2), "outside"),
        "columns order": (lambda: _kesi.bound_removals(IN, [1], [2, 1], None, 0, w, w, 2), "ascending"),
        "column of a row": (lambda: _kesi.bound_removals(IN, [1], [0], [1], 0, w, w, 2), "outside"),
        "columns of rows order": (lambda: _kesi.bound_removals(IN, [1, 2], [0, 1], [1, 0], 0, w, w, 2), "ascending"),
        "s3": (lambda: _kesi.bound_removals(IN, [1], [0], None, 5, w, w, 2), "s3"),
        "weights": (lambda: _kesi.bound_removals(IN, [1], [0], None, 0, w, np.full(10, np.inf), 2), "finite"),
        "offsets order": (lambda: _kesi.bound_blocks(np.ones(10, bool), [0, 5, 3], w, w), "ascending"),
        "offsets beyond": (lambda: _kesi.bound_blocks(np.ones(10, bool), [-1, 11], w, w), "ascending"),
        "sample row": (lambda: _kesi.bound_samples([7], [0.0], D5, D6, B5, B6, 0, 2, True), "outside"),
        "sample columns": (lambda: _kesi.bound_samples([1], [0.0], D5, D6, B5, B6, 3, 2, True), "c0"),
        "sample shape": (lambda: _kesi.bound_samples([1], [0.0], D5, D5, B5, B6, 0, 2, True), "shape"),
    }
    expect_rejected("bounds", bad, (ValueError,))


def run_rdt(rng, n_inputs):
    """Restricted Delaunay extraction on random, duplicated, coplanar and clustered seeds:
    valid indices, every directed edge used once, thread-count determinism, hostile inputs."""
    from voxax import cvt

    g = voxax.Grid.cube(4)
    for i in range(n_inputs):
        kind = ("random", "duplicates", "coplanar", "cluster", "sphere")[i % 5]
        ns, n_frag = int(rng.integers(3, 60)), int(rng.integers(1, 400))
        s = rng.uniform(-1, 1, (ns, 3))
        if kind == "duplicates":
            s[1::2] = s[0]
        elif kind == "coplanar":
            s[:, 2] = 0.0
        elif kind == "cluster":
            s = s * 1e-9
        elif kind == "sphere":
            s /= np.linalg.norm(s, axis=1, keepdims=True)
        x = rng.uniform(-1, 1, (n_frag, 3))
        n = rng.normal(size=(n_frag, 3))
        frag = cvt.Fragments(x, n, np.ones(n_frag), np.zeros(n_frag, np.int8), np.zeros(n_frag, np.int64),
                             np.ones(n_frag, np.int8), g)
        label = f"rdt/{kind}/{i}"
        try:
            f1, _ = cvt.rdt(frag, s, tau=float(rng.uniform(0, 3)), threads=1)
            f2, _ = cvt.rdt(frag, s, tau=1.0, threads=3)
            f3, _ = cvt.rdt(frag, s, tau=1.0, threads=1)
            CALLS["rdt"] += 3
        except Exception:  # noqa: BLE001
            fail(f"{label}: raised\n" + traceback.format_exc())
            continue
        if f2.tobytes() != f3.tobytes():
            fail(f"{label}: results depend on the thread count")
        for f in (f1, f2):
            if len(f) and (f.min() < 0 or f.max() >= ns):
                fail(f"{label}: face index out of range")
            d = np.concatenate([f[:, [0, 1]], f[:, [1, 2]], f[:, [2, 0]]])
            if len(np.unique(d, axis=0)) != len(d):
                fail(f"{label}: a directed edge is used twice")
        COUNTS["rdt"] += 1
    s = rng.uniform(-1, 1, (10, 3))
    x = rng.uniform(-1, 1, (20, 3))
    frag = cvt.Fragments(x, x, np.ones(20), np.zeros(20, np.int8), np.zeros(20, np.int64), np.ones(20, np.int8), g)
    bad = {
        "two seeds": (lambda: cvt.rdt(frag, s[:2]), "3 seeds"),
        "NaN seed": (lambda: cvt.rdt(frag, np.where(np.arange(30).reshape(10, 3) == 4, np.nan, s)), "NaN or Inf"),
        "huge seed": (lambda: cvt.rdt(frag, s * 1e80), "1e75"),
        "negative tau": (lambda: cvt.rdt(frag, s, tau=-1.0), "tau"),
        "no fragments": (lambda: cvt.rdt(cvt.Fragments(np.zeros((0, 3)), np.zeros((0, 3)), np.zeros(0), np.zeros(0, np.int8),
                                                       np.zeros(0, np.int64), np.zeros(0, np.int8), g), s), "fragments"),
        "max_hole": (lambda: cvt.rdt(frag, s, max_hole=100), "max_hole"),
        "bool seeds": (lambda: cvt.rdt(frag, s > 0), "real"),
        "complex seeds": (lambda: cvt.rdt(frag, s + 1j), "real"),
    }
    # hostile Fragments: every field's length, shape and values, through the public call
    # and (without the Python checks) straight into the host entry point
    from voxax._kernels import cvt as kernels

    def hostile(**fields):
        return frag._replace(**fields)

    for name, short in (("normals", 5), ("weights", 19), ("axis", 0), ("line", 3), ("sign", 1)):
        bad[f"short {name}"] = (lambda name=name, short=short: cvt.rdt(hostile(**{name: getattr(frag, name)[:short]}), s),
                                f"frag.{name}")
    bad["long normals"] = (lambda: cvt.rdt(hostile(normals=np.concatenate([x, x])), s), "frag.normals")
    bad["2D points"] = (lambda: cvt.rdt(hostile(points=x[:, :2]), s), "frag.points")
    bad["NaN normal"] = (lambda: cvt.rdt(hostile(normals=np.where(x == x[2], np.nan, x)), s), "finite")
    bad["bool normals"] = (lambda: cvt.rdt(hostile(normals=x > 0), s), "real")
    bad["negative weight"] = (lambda: cvt.rdt(hostile(weights=-np.ones(20)), s), "weights")
    bad["no grid"] = (lambda: cvt.rdt(hostile(grid=None), s), "grid")
    for short in (0, 1, 5, 19):
        bad[f"kernel: {short} normals for 20 fragments"] = (
            lambda short=short: kernels.rdt(s, x, np.ascontiguousarray(x[:short]), 1.0, 8, 1), "one normal per fragment")
    bad["kernel: 40 normals for 20 fragments"] = (
        lambda: kernels.rdt(s, x, np.concatenate([x, x]), 1.0, 8, 1), "one normal per fragment")
    bad["optimize short weights"] = (lambda: cvt.optimize(hostile(weights=np.ones(3)), s, steps=1), "frag.weights")
    bad["energy short normals"] = (lambda: cvt.energy(s, hostile(normals=x[:2])), "frag.normals")
    bad["remesh short normals"] = (lambda: cvt.remesh(hostile(normals=x[:2]), 5, progress=False), "frag.normals")
    bad["remesh bool mesh"] = (lambda: cvt.remesh((x > 0, np.arange(18).reshape(6, 3)), 5, progress=False), "vertices")
    bad["remesh complex mesh"] = (lambda: cvt.remesh((x + 0j, np.arange(18).reshape(6, 3)), 5, progress=False),
                                  "vertices")
    expect_rejected("rdt", bad, (ValueError, TypeError))
    # the valid neighbours of those cases still run (the checks refuse only what is wrong)
    faces, _ = kernels.rdt(s, x, x, 1.0, 8, 1)
    if len(faces) and (faces.min() < 0 or faces.max() >= len(s)):
        fail("rdt kernel: face index out of range")
    CALLS["rdt"] += 1


def run_line_crossings(rng, n_inputs):
    """Exact line crossings (dexels) on adversarial soups and closed meshes snapped onto
    the grid lines: structural checks, thread-count determinism, and hostile inputs."""
    import ctypes

    from voxax import _kernels, raster
    from voxax._kernels import raster as raster_kernel

    kinds = ("random", "degenerate", "huge", "tiny", "flat", "grid", "closed")
    for i in range(n_inputs):
        kind = kinds[i % len(kinds)]
        if kind == "closed":
            m = voxax.data.icosphere(int(rng.integers(0, 3)))
            v = np.round(np.asarray(m.vertices) * 4) / 4  # vertices on the node lines
            f = np.asarray(m.faces)
        else:
            v, f = _spatial_soup(rng, kind)
        scale = float(np.abs(v).max()) if v.size else 1.0
        grid = voxax.Grid.cube(int(rng.integers(1, 9)), half_width=max(scale, 1e-40))
        axis, lines = int(i % 3), ("centers", "nodes")[i % 2]
        label = f"line_crossings/{kind}/{i}"
        try:
            d = raster.line_crossings(v, f, grid, axis, lines=lines, threads=1)
            d2 = raster.line_crossings(v, f, grid, axis, lines=lines, threads=3)
            CALLS["line_crossings"] += 2
        except ValueError as err:
            if kind == "tiny" and "1e-50" in str(err):
                COUNTS["line_crossings_invalid"] += 1
                continue
            fail(f"{label}: raised\n" + traceback.format_exc())
            continue
        except Exception:  # noqa: BLE001
            fail(f"{label}: raised\n" + traceback.format_exc())
            continue
        if any(a.tobytes() != b.tobytes() for a, b in zip(d[3:], d2[3:])):
            fail(f"{label}: results depend on the thread count")
        if len(d.face) and (d.face.min() < 0 or d.face.max() >= len(f) or not np.all(np.abs(d.sign) == 1)):
            fail(f"{label}: bad face index or sign")
        line = d.line_index()
        if np.any((line[1:] == line[:-1]) & (d.depth[1:] < d.depth[:-1])):
            fail(f"{label}: crossings not sorted along a line")
        if len(d.face):
            z = v[f[d.face]][:, :, axis]
            if np.any(d.depth < z.min(axis=1)) or np.any(d.depth > z.max(axis=1)):
                fail(f"{label}: a depth lies outside its face")
        if kind == "closed" and np.bincount(line, weights=d.sign, minlength=1).any():
            fail(f"{label}: a closed mesh has unbalanced crossings on a line")
        COUNTS["line_crossings"] += 1
    v, f = rng.uniform(-1, 1, (30, 3)), np.arange(30, dtype=np.int32).reshape(10, 3)
    g = voxax.Grid.cube(4)
    lib = _kernels.declare(raster_kernel.SIGNATURES)

    def raw(nv, nf, axis, n0, n1, lines0=None):
        err = _kernels.error_buffer()
        handle = _kernels.VP()
        l0 = np.ascontiguousarray(lines0 if lines0 is not None else np.linspace(-1, 1, max(n0, 1)))
        l1 = np.ascontiguousarray(np.linspace(-1, 1, min(max(n1, 1), 8)))  # only read when n1 <= 8
        vv, ff = np.ascontiguousarray(v), np.ascontiguousarray(f)
        status = lib.voxax_line_crossings(_kernels.pointer(vv, _kernels.D), nv, _kernels.pointer(ff, _kernels.I32), nf, axis,
                                          _kernels.pointer(l0, _kernels.D), n0, _kernels.pointer(l1, _kernels.D), n1, 2,
                                          ctypes.byref(handle), err, _kernels.ERRLEN)
        lib.voxax_crossings_free(handle)
        _kernels.check(status, err)

    bad = {
        "NaN vertex": (lambda: raster.line_crossings(np.where(np.arange(90).reshape(30, 3) == 7, np.nan, v), f, g, 0),
                       "NaN"),
        "index high": (lambda: raster.line_crossings(v, f + 1, g, 1), "range"),
        "huge vertex": (lambda: raster.line_crossings(v * 1e80, f, g, 2), "1e75"),
        "raw axis": (lambda: raw(30, 10, 7, 3, 3), "axis"),
        "raw negative faces": (lambda: raw(30, -4, 0, 3, 3), "faces"),
        "raw too few vertices": (lambda: raw(5, 10, 0, 3, 3), "range"),
        "raw unsorted lines": (lambda: raw(30, 10, 0, 3, 3, np.array([0.0, -1.0, 1.0])), "increasing"),
        "raw negative lines": (lambda: raw(30, 10, 0, -3, 3), "negative"),
        "raw too many lines": (lambda: raw(30, 10, 0, 1, 1 << 40), "2\\^36"),
        "bool vertices": (lambda: raster.line_crossings(v > 0, f, g, 0), "bool"),
        "complex lines": (lambda: raster.line_crossings(v, f, g, 0, lines=([0j, 1j], [0.0])), "real numbers"),
        "tiny line": (lambda: raster.line_crossings(v, f, g, 0, lines=([1e-60], [0.0])), "1e-50"),
    }
    expect_rejected("line_crossings", bad, (ValueError, TypeError))


def run_fc(rng, n_inputs):
    """Faithful Contouring: encode and decode adversarial soups and closed meshes snapped
    onto the grid (structural checks, thread-count determinism), and hostile raw calls."""
    import ctypes
    import dataclasses

    from voxax import _kernels, fc
    from voxax._kernels import fc as fc_kernel

    kinds = ("random", "degenerate", "huge", "tiny", "flat", "grid", "closed")
    for i in range(n_inputs):
        kind = kinds[i % len(kinds)]
        if kind == "closed":
            m = voxax.data.icosphere(int(rng.integers(0, 3)))
            v = np.round(np.asarray(m.vertices) * 4) / 4  # vertices on grid nodes
            f = np.asarray(m.faces)
        else:
            v, f = _spatial_soup(rng, kind)
        scale = 1.25 * float(np.abs(v).max()) if v.size else 1.0  # the mesh strictly inside
        n = tuple(int(x) for x in rng.integers(1, 9, size=3))
        grid = voxax.Grid((-scale,) * 3, (max(scale, 1e-40),) * 3, n) if scale > 0 else voxax.Grid.cube(n)
        label = f"fc/{kind}/{i}"
        mode = (1, "components", "patches")[i % 3]
        try:
            a = fc.encode(v, f, grid, anchors_per_cell=mode, layout=("primal", "dual")[i % 2], threads=1)
            b = fc.encode(v, f, grid, anchors_per_cell=mode, layout=("primal", "dual")[i % 2], threads=3)
            out = fc.decode(a, threads=2)
            CALLS["fc"] += 3
        except ValueError as err:
            if kind == "tiny" and any(m in str(err) for m in ("1e-300", "1e-50", "cell volume")):
                COUNTS["fc_invalid"] += 1
                continue
            fail(f"{label}: raised\n" + traceback.format_exc())
            continue
        except Exception:  # noqa: BLE001
            fail(f"{label}: raised\n" + traceback.format_exc())
            continue
        if not np.array_equal(a.to_array("fct19"), b.to_array("fct19")):
            fail(f"{label}: tokens depend on the thread count")
        if len(a) and (np.any(np.diff(a.index) < 0) or np.abs(a.offsets).max() > 0.5):
            fail(f"{label}: tokens unsorted or anchors outside their cells")
        if out.n_faces and (out.faces.min() < 0 or out.faces.max() >= out.n_vertices):
            fail(f"{label}: decoded face index out of range")
        if kind == "closed" and mode != "components" and out.n_faces:  # components: no promise
            rep = voxax.metrics.manifold_report(out)
            if rep.n_boundary_edges:
                fail(f"{label}: a closed mesh on grid nodes decodes with a boundary")
        COUNTS["fc"] += 1
    lib = _kernels.declare(fc_kernel.SIGNATURES)
    v, f = np.ascontiguousarray(rng.uniform(-1, 1, (30, 3))), np.arange(30, dtype=np.int32).reshape(10, 3)

    def raw_encode(nv, nf, box, shape, params, flags=1, joined=None):
        err, handle = _kernels.error_buffer(), _kernels.VP()
        box, shape = np.ascontiguousarray(box, np.float64), np.ascontiguousarray(shape, np.int64)
        params, sizes = np.ascontiguousarray(params, np.float64), np.zeros(3, np.int64)
        joined = None if joined is None else np.ascontiguousarray(joined, np.int64)
        status = lib.voxax_fc_encode(_kernels.pointer(v, _kernels.D), nv, _kernels.pointer(f, _kernels.I32), nf, None,
                                     _kernels.pointer(box, _kernels.D), _kernels.pointer(shape, _kernels.I64),
                                     _kernels.pointer(params, _kernels.D), flags,
                                     None if joined is None else _kernels.pointer(joined, _kernels.I64),
                                     0 if joined is None else len(joined), 2, ctypes.byref(handle),
                                     _kernels.pointer(sizes, _kernels.I64), err, _kernels.ERRLEN)
        lib.voxax_fc_free(handle)
        _kernels.check(status, err)

    def raw_decode(index, shape, k=None, anchor=0.0, sign=1):
        err, handle = _kernels.error_buffer(), _kernels.VP()
        index = np.ascontiguousarray(index, np.int64)
        k = len(index) if k is None else k
        p = np.full((max(len(index), 1), 3), anchor)
        s = np.full((max(len(index), 1), 12), sign, np.int8)
        shape, count = np.ascontiguousarray(shape, np.int64), np.zeros(1, np.int64)
        status = lib.voxax_fc_decode(_kernels.pointer(index, _kernels.I64), _kernels.pointer(p, _kernels.D),
                                     _kernels.pointer(p, _kernels.D), s.ctypes.data_as(ctypes.POINTER(ctypes.c_int8)), k,
                                     _kernels.pointer(shape, _kernels.I64), 0, 2, ctypes.byref(handle),
                                     _kernels.pointer(count, _kernels.I64), err, _kernels.ERRLEN)
        lib.voxax_fc_free_triangles(handle)
        _kernels.check(status, err)

    def raw_signs(index, shape, edge, sign, k=None, c=None):
        err, handle = _kernels.error_buffer(), _kernels.VP()
        index = np.ascontiguousarray(index, np.int64)
        edge, sign = np.ascontiguousarray(edge, np.int64), np.ascontiguousarray(sign, np.int8)
        k = len(index) if k is None else k
        c = len(edge) if c is None else c
        S = np.zeros((max(len(index), 1), 12), np.int8)
        shape, count = np.ascontiguousarray(shape, np.int64), np.zeros(1, np.int64)
        i8 = ctypes.POINTER(ctypes.c_int8)
        status = lib.voxax_fc_signs(_kernels.pointer(index, _kernels.I64), k, _kernels.pointer(shape, _kernels.I64),
                                    _kernels.pointer(edge, _kernels.I64), sign.ctypes.data_as(i8), c, 2,
                                    S.ctypes.data_as(i8), ctypes.byref(handle), _kernels.pointer(count, _kernels.I64),
                                    err, _kernels.ERRLEN)
        try:
            _kernels.check(status, err)
            pairs = np.zeros((int(count[0]), 2), np.int64)
            lib.voxax_fc_triangles(handle, _kernels.pointer(pairs, _kernels.I64))
        finally:
            lib.voxax_fc_free_triangles(handle)
        return S, pairs

    # A valid raw call: the x edge at node (1, 1, 1) of a 4^3 grid (id 31) with a net flux
    # of +2 goes to its 4 cells, as edges 0 (cell (1, 1, 1)), 1 ((1, 0, 1)), 2 ((1, 0, 0))
    # and 3 ((1, 1, 0)); the cells without a row come back with the crossing they need.
    S, pairs = raw_signs(np.arange(64), [4, 4, 4], [31, 31, 31], [1, 1, -1])
    CALLS["fc"] += 1
    want = np.zeros((64, 12), np.int8)
    for cell, slot in (((1, 1, 1), 0), ((1, 0, 1), 1), ((1, 0, 0), 2), ((1, 1, 0), 3)):
        want[np.ravel_multi_index(cell, (4, 4, 4)), slot] = 1
    if not np.array_equal(S, want) or len(pairs):
        fail("fc raw signs: the signs of one edge are not those of its 4 cells")
    S, pairs = raw_signs([21], [4, 4, 4], [31, 31], [1, 1])
    if not np.array_equal(pairs[:, 0], [16, 17, 20]) or S[0, 0] != 2:
        fail(f"fc raw signs: the cells without a row are wrong: {pairs.tolist()}")

    g = voxax.Grid.cube(4)
    box = [-1, -1, -1, 1, 1, 1]
    tok4 = fc.encode(v, f, g)
    bad = {
        "NaN vertex": (lambda: fc.encode(np.where(np.arange(90).reshape(30, 3) == 7, np.nan, v), f, g), "NaN"),
        "index high": (lambda: fc.encode(v, f + 1, g), "range"),
        "huge vertex": (lambda: fc.encode(v * 1e80, f, g), "1e75"),
        "raw faces out of range": (lambda: raw_encode(5, 10, box, [4, 4, 4], [1, 1e-3, 1]), "range"),
        "raw negative count": (lambda: raw_encode(30, -3, box, [4, 4, 4], [1, 1e-3, 1]), "2\\^31"),
        "raw bad grid": (lambda: raw_encode(30, 10, [1, -1, -1, -1, 1, 1], [4, 4, 4], [1, 1e-3, 1]), "grid"),
        "raw zero shape": (lambda: raw_encode(30, 10, box, [0, 4, 4], [1, 1e-3, 1]), "grid shape"),
        "raw lambda_d": (lambda: raw_encode(30, 10, box, [4, 4, 4], [1, 0.0, 1]), "lambda_d"),
        "raw NaN power": (lambda: raw_encode(30, 10, box, [4, 4, 4], [1, 1e-3, np.nan]), "weight_power"),
        "raw flags": (lambda: raw_encode(30, 10, box, [4, 4, 4], [1, 1e-3, 1], flags=99), "flags"),
        "raw joined unsorted": (lambda: raw_encode(30, 10, box, [4, 4, 4], [1, 1e-3, 1], 3, [5, 2]), "sorted"),
        "raw decode unsorted": (lambda: raw_decode([5, 3], [4, 4, 4]), "sorted"),
        "raw decode index": (lambda: raw_decode([5, 64], [4, 4, 4]), "range"),
        "raw decode shape": (lambda: raw_decode([0], [4, -1, 4]), "shape"),
        "raw decode huge grid": (lambda: raw_decode([0], [1 << 31, 1 << 31, 1 << 31]), "too large"),
        "raw decode huge anchor": (lambda: raw_decode([0, 5], [4, 4, 4], anchor=1e300), "1e75"),
        "raw decode sign -128": (lambda: raw_decode([0, 5], [4, 4, 4], sign=-128), "-127"),
        "decode float signs": (lambda: fc.decode(dataclasses.replace(tok4, edge_signs=tok4.edge_signs * 0.5)),
                               "integers"),
        "decode anchors outside": (lambda: fc.decode(dataclasses.replace(tok4, offsets=tok4.offsets + 1e300)),
                                   "offsets"),
        "encode bool vertices": (lambda: fc.encode(v > 0, f, g), "bool"),
        "encode complex vertices": (lambda: fc.encode(v + 0j, f, g), "complex"),
        "raw signs shape": (lambda: raw_signs([0], [4, 0, 4], [0], [1]), "shape"),
        "raw signs huge shape": (lambda: raw_signs([0], [4, 4, 1 << 40], [0], [1]), "shape"),
        "raw signs edge high": (lambda: raw_signs([0], [4, 4, 4], [3 * 125], [1]), "edge id"),
        "raw signs edge negative": (lambda: raw_signs([0], [4, 4, 4], [-1], [1]), "edge id"),
        "raw signs unsorted": (lambda: raw_signs([5, 3], [4, 4, 4], [0], [1]), "sorted"),
        "raw signs index": (lambda: raw_signs([64], [4, 4, 4], [0], [1]), "sorted cell"),
        "raw signs negative rows": (lambda: raw_signs([0], [4, 4, 4], [0], [1], k=-1), "null"),
        "raw signs negative crossings": (lambda: raw_signs([0], [4, 4, 4], [0], [1], c=-5), "null"),
    }
    expect_rejected("fc", bad, (ValueError, TypeError))


# -- marching cubes ------------------------------------------------------------------------


def run_marching_cubes(rng, count):
    """Fuzzes the marching-cubes kernel: eager (exact size) and FFI (capacity) paths."""
    from voxax._isosurface.stream import _isosurface_streamed
    from voxax._kernels.contour import Count as _Count
    from voxax._kernels.contour import topology as host_topology

    def field(shape, dtype):
        kind = rng.integers(6)
        if kind == 0:
            f = rng.standard_normal(shape)
        elif kind == 1:
            f = rng.integers(-1, 2, size=shape).astype(float)  # exact ties at level 0
        elif kind == 2:
            f = np.zeros(shape)  # everything on the level
        elif kind == 3:
            f = rng.standard_normal(shape) * 1e30
        elif kind == 4:
            f = rng.standard_normal(shape) * 1e-30
        else:
            f = np.where(rng.random(shape) < 0.5, 1.0, -1.0) * rng.random(shape)
        return f.astype(dtype)

    for it in range(count):
        dim = 3 if it % 3 else 2
        shape = tuple(int(x) for x in rng.integers(1, 10, size=dim))
        dtype = (np.float64, np.float32)[it % 2]
        f = field(shape, dtype)
        level = 0.0 if it % 4 else float(rng.standard_normal())
        label = f"marching cubes {dim}D {shape} {np.dtype(dtype).name} level={level}"
        COUNTS["marching_cubes"] += 1
        edges, faces = host_topology(f, level)
        CALLS["mc_host"] += 1
        # The slab sweep's per-slice vertex counts: -1 outside the grid, summing to the total.
        counted = _Count(f, level)
        per_slice = [counted.slice_vertices(i) for i in range(shape[0])]
        outside = [counted.slice_vertices(i) for i in (-1, shape[0], 2**62)]
        counted.fill()
        CALLS["mc_host"] += 1
        if sum(per_slice) != counted.n_vertices or outside != [-1, -1, -1] or min(per_slice) < 0:
            fail(f"{label}: slice vertex counts {per_slice} / {outside} for {counted.n_vertices} vertices")
        if dim == 3 and np.isfinite(f).all():
            grid = Grid((0.0,) * 3, tuple(float(n) for n in shape), shape)
            whole = _isosurface_streamed(f, grid, level, "below", True, planes=10**6)
            for planes in (1, 3):
                part = _isosurface_streamed(f, grid, level, "below", True, planes=planes)
                if not (np.array_equal(np.asarray(part.faces), np.asarray(whole.faces))
                        and np.asarray(part.vertices).tobytes() == np.asarray(whole.vertices).tobytes()):
                    fail(f"{label}: the slab sweep with {planes} planes differs from one sweep")
            CALLS["mc_host"] += 3
        nv, cells = len(edges), f.size
        strides = {int(np.prod(shape[a + 1 :])) for a in range(dim)}
        if nv and (edges.min() < 0 or edges.max() >= cells or not set(np.unique(edges[:, 1] - edges[:, 0])) <= strides):
            fail(f"{label}: bad edges")
        if len(faces) and (faces.min() < 0 or faces.max() >= nv):
            fail(f"{label}: face index out of range")
        pos = f.reshape(-1) >= level
        if nv and np.any(pos[edges[:, 0]] == pos[edges[:, 1]]):
            fail(f"{label}: a vertex on an edge that does not cross the level")
        # closed, oriented output once padded with the outside value
        padded = np.pad(f, 1, constant_values=np.asarray(level + 1.0, dtype))
        pe, pf = host_topology(padded, level)
        CALLS["mc_host"] += 1
        if dim == 3 and len(pf):
            d = np.concatenate([pf[:, [0, 1]], pf[:, [1, 2]], pf[:, [2, 0]]]).astype(np.int64)
            code, rev = d[:, 0] * len(pe) + d[:, 1], d[:, 1] * len(pe) + d[:, 0]
            if len(np.unique(code)) != len(code) or not np.all(np.isin(rev, code)):
                fail(f"{label}: padded output is not closed and oriented")
        if dim == 2 and len(pf):
            if not (np.array_equal(np.sort(pf[:, 0]), np.arange(len(pe))) and np.array_equal(np.sort(pf[:, 1]), np.arange(len(pe)))):
                fail(f"{label}: padded 2D output is not made of closed loops")
        # the capacity path: a fit equals the eager output; too small is refused, naming the
        # capacity needed (nothing written out of bounds)
        for cap in (max(1, nv, len(faces)), max(1, nv), max(1, len(faces)), 1):
            call = jax.ffi.ffi_call(
                _kernels.MARCHING_CUBES,
                (jax.ShapeDtypeStruct((cap, 2), jnp.int32), jax.ShapeDtypeStruct((cap, dim), jnp.int32),
                 jax.ShapeDtypeStruct((2,), jnp.int32)),
                vmap_method="expand_dims",
            )
            CALLS["mc_ffi"] += 1
            fits = cap >= nv and cap >= len(faces)
            try:
                e2, f2, c2 = jax.block_until_ready(call(jnp.asarray(f), level=np.float64(level), dim=np.int64(dim)))
            except Exception as err:  # noqa: BLE001
                need = f"needs capacity=({max(nv, cap)}, {max(len(faces), cap)})"
                if fits or need not in str(err):
                    fail(f"{label}: capacity {cap} for ({nv}, {len(faces)}): {str(err)[:200]}")
                continue
            if not fits:
                fail(f"{label}: capacity {cap} accepted for ({nv}, {len(faces)})")
            if int(c2[0]) != nv or int(c2[1]) != len(faces):
                fail(f"{label}: FFI counts {np.asarray(c2)} differ from the eager ({nv}, {len(faces)})")
            if not np.array_equal(np.asarray(e2)[:nv], edges) or not np.array_equal(np.asarray(f2)[: len(faces)], faces):
                fail(f"{label}: FFI output differs from the eager output")
        # scale invariance: the topology of 2^k f is that of f (exact products in the decider),
        # and the eager mesh's vertices are the same bits (subnormal and huge samples included)
        if f.dtype == np.float64 and level == 0.0 and np.isfinite(f).all():
            q = np.round(f / max(float(np.abs(f).max()), 1e-300) * 2**10) / 2**10
            e0, f0 = host_topology(q, 0.0)
            grid = Grid((0.0,) * dim, tuple(float(n) for n in shape), shape)
            with warnings.catch_warnings():
                warnings.simplefilter("ignore", RuntimeWarning)
                base = voxax.isosurface(q, grid)
                for k in (-1050, -700, 600):
                    ek, fk = host_topology(np.ldexp(q, k), 0.0)
                    CALLS["mc_host"] += 1
                    if not (np.array_equal(ek, e0) and np.array_equal(fk, f0)):
                        fail(f"{label}: the topology of 2^{k} f differs from that of f")
                    iso = voxax.isosurface(np.ldexp(q, k), grid)
                    CALLS["mc_host"] += 1
                    if np.asarray(iso.vertices).tobytes() != np.asarray(base.vertices).tobytes():
                        fail(f"{label}: the vertices of 2^{k} f differ from those of f")
    # invalid input: NaN, Inf, bad attributes and output shapes, another grid's topology,
    # bad arguments of isosurface_fn
    g8, g12 = Grid.cube(8), Grid.cube(12)
    f12 = np.linalg.norm(g12.centers(), axis=-1) - 0.5
    sphere = lambda r, x: jnp.linalg.norm(x, axis=-1) - r  # noqa: E731
    top12 = voxax.isosurface_topology(f12, g12)
    hostile = {
        "topology of another grid": (lambda: voxax.isosurface_vertices(f12[:8, :8, :8], top12, g8), "made on this grid"),
        "topology of another grid (jit)": (lambda: jax.block_until_ready(jax.jit(lambda x: voxax.isosurface_vertices(x, top12, g8))(f12[:8, :8, :8])), "made on this grid"),
        "isosurface_fn chunk -1": (lambda: voxax.isosurface_fn(sphere, 0.5, g8, chunk=-1), "chunk"),
        "isosurface_fn scalar field": (lambda: voxax.isosurface_fn(lambda r, x: jnp.sum(x) - r, 0.5, g8), "one value per point"),
        "isosurface threads 0": (lambda: voxax.isosurface(f12, g12, threads=0), "threads"),
        "isosurface close string": (lambda: voxax.isosurface(f12, g12, close="yes"), "close"),
    }
    for name, (call, match) in hostile.items():
        COUNTS["marching_cubes_invalid"] += 1
        try:
            call()
            fail(f"marching cubes: {name} accepted")
        except Exception as err:  # noqa: BLE001
            if match not in str(err) or "voxax" not in str(err):
                fail(f"marching cubes: {name}: unclear error {str(err)[:200]!r}")
    for bad in (np.nan, np.inf):
        f = np.zeros((4, 4, 4))
        f[1, 2, 3] = bad
        COUNTS["marching_cubes_invalid"] += 1
        try:
            voxax.isosurface(f, Grid.cube(4))
            fail("marching cubes: non-finite values accepted")
        except ValueError:
            pass
    for dim_attr, shapes in ((5, ((3, 2), (3, 3), (2,))), (3, ((3, 3), (3, 3), (2,))), (3, ((3, 2), (3, 2), (2,)))):
        COUNTS["marching_cubes_invalid"] += 1
        call = jax.ffi.ffi_call(_kernels.MARCHING_CUBES, tuple(jax.ShapeDtypeStruct(s, jnp.int32) for s in shapes),
                                vmap_method="expand_dims")
        try:
            jax.block_until_ready(call(jnp.zeros((4, 4, 4)), level=np.float64(0.0), dim=np.int64(dim_attr)))
            fail(f"marching cubes: raw FFI call with dim={dim_attr}, outputs {shapes} accepted")
        except Exception as err:  # noqa: BLE001
            if "voxax.isosurface" not in str(err):
                fail(f"marching cubes: unexpected error {err!r}")
def run_tangent(rng, family, dim, grid_name, grid, dtype):
    """The tangent kernel (forward mode): jvp eagerly or under jit, finite and of the right
    shape, and adjoint to the backward: <u, J t> = <J^T u, t> up to rounding."""
    v, f, nf = make_input(rng, family, dim, grid, dtype)
    mode = "jit" if rng.random() < 0.5 else "eager"
    label = f"tangent/{family}/{dim}D/{grid_name}/{np.dtype(dtype).name}/{mode}"
    t = rng.normal(size=v.shape).astype(dtype)
    u = rng.normal(size=grid.shape).astype(dtype)

    def both(x, tt, uu):
        fn = lambda y: voxax.voxelize(y, f, grid)  # noqa: E731
        _, Jt = jax.jvp(fn, (x,), (tt,))
        return Jt, jax.vjp(fn, x)[1](uu)[0]

    Jt, JTu = (jax.jit(both) if mode == "jit" else both)(jnp.asarray(v), jnp.asarray(t), jnp.asarray(u))
    CALLS[f"{mode}_tangent"] += 1
    CALLS[f"{mode}_backward"] += 1
    Jt, JTu = np.asarray(Jt, np.float64), np.asarray(JTu, np.float64)
    if Jt.shape != grid.shape or not np.all(np.isfinite(Jt)) or not np.all(np.isfinite(JTu)):
        fail(f"{label}: tangent of shape {Jt.shape} (expected {grid.shape}) or non-finite values")
        save_failure(label, v, f, grid)
    else:
        lhs, rhs = float(np.vdot(u, Jt)), float(np.vdot(JTu, t))
        # Rounding is relative to the terms before they cancel (duplicate and flipped
        # faces, slivers with large barycentric weights): the per-corner gradients.
        C = np.asarray(voxax.voxelize_corner_gradients(jnp.asarray(v), jnp.asarray(f), grid, jnp.asarray(u)))
        CALLS["eager_backward"] += 1
        # Slivers: the pieces' areas (clipped in different orders by the two kernels) are
        # known only to rounding times the square of their long edges.
        p = np.asarray(v, np.float64)[np.asarray(f)[:nf]]
        edges = np.stack([p[:, (c + 1) % dim] - p[:, c] for c in range(dim)], axis=1)
        long2 = float(np.sum(np.max(np.sum(edges**2, axis=-1), axis=-1)))
        scale = (np.linalg.norm(u) * np.linalg.norm(Jt) + np.linalg.norm(JTu) * np.linalg.norm(t)
                 + np.abs(C.astype(np.float64)).sum() * np.abs(t).max()
                 + long2 / grid.voxel_volume * np.abs(t).max() * np.abs(u).max())
        tol = (1e-9 if dtype == np.float64 else 1e-3) * scale + 1e-300
        if family != "huge" and not abs(lhs - rhs) <= tol:
            fail(f"{label}: <u, J t> = {lhs!r} but <J^T u, t> = {rhs!r}")
            save_failure(label, v, f, grid)
    COUNTS["tangent"] += 1


def run_raw_tangent_ffi(rng):
    """Hostile direct calls of the tangent kernel: it must reject them cleanly."""
    g = GRIDS_3D["odd"]
    v, f, _ = make_input(rng, "closed", 3, g, np.float64)
    v, f = jnp.asarray(v), jnp.asarray(f)
    attrs = _kernels.grid_attributes(g)
    tc = jnp.ones((f.shape[0], 3, 3))

    def tan(vv, ff, tt, shape=g.shape, dtype=jnp.float64, **over):
        a = dict(attrs)
        a.update(over)
        return jax.ffi.ffi_call(_kernels.TANGENT, jax.ShapeDtypeStruct(shape, dtype))(vv, ff, tt, **a)

    cases = {
        "tangent: shape": lambda: tan(v, f, jnp.ones((f.shape[0], 3, 2))),
        "tangent: F": lambda: tan(v, f, jnp.ones((f.shape[0] + 1, 3, 3))),
        "tangent: rank": lambda: tan(v, f, jnp.ones((f.shape[0], 9))),
        "tangent: dtype": lambda: tan(v, f, tc.astype(jnp.float32)),
        "tangent: output dtype": lambda: tan(v, f, tc, dtype=jnp.float32),
        "tangent: output shape": lambda: tan(v, f, tc, shape=(5, 7, 4)),
        "tangent: batch": lambda: tan(jnp.stack([v] * 2), jnp.stack([f] * 2), jnp.stack([tc] * 3),
                                      shape=(2,) + g.shape),
        "tangent: NaN": lambda: tan(v, f, tc.at[1, 2, 0].set(jnp.nan)),
        "tangent: NaN vertex": lambda: tan(v.at[0, 0].set(jnp.nan), f, tc),
        "tangent: index": lambda: tan(v, f.at[0, 0].set(-3), tc),
        "tangent: nz = 0": lambda: tan(v, f, tc, nz=np.int64(0)),
        "tangent: int faces of 2": lambda: tan(v, f[:, :2], tc),
    }
    for name, fn in cases.items():
        try:
            jax.block_until_ready(fn())
        except Exception:  # noqa: BLE001 - any clean error will do; a crash would abort
            pass
        else:
            fail(f"raw FFI call '{name}' was accepted")
        CALLS["raw_ffi"] += 1
    COUNTS["raw_ffi"] += len(cases)
    dW = np.asarray(jax.block_until_ready(tan(v, f, tc)))
    if not np.all(np.isfinite(dW)):
        fail("raw tangent FFI after errors: non-finite output")
def run_intersections(rng, rounds=60):
    """The exact intersection test: random, degenerate, duplicate, huge/tiny, coplanar and
    touching soups; invalid inputs; hostile raw calls of the C entry point."""
    import ctypes

    from voxax._kernels import intersect as _intersect_kernel

    for k in range(rounds):
        nf = int(rng.integers(1, 120))
        v = rng.normal(size=(3 * nf, 3))
        kind = k % 6
        if kind == 1:  # snapped to a coarse lattice: coplanar and touching faces
            v = np.round(v * 2) / 2
        elif kind == 2:  # degenerate faces
            v[1::3] = v[0::3]
        elif kind == 3:  # huge or tiny, within the accepted magnitudes [1e-50, 1e75]
            v = np.where(np.abs(v) < 1e-3, np.copysign(1e-3, v), v) * 10.0 ** rng.choice([-45, 70])
        f = rng.integers(0, len(v), size=(nf, 3)) if kind == 4 else np.arange(3 * nf).reshape(nf, 3)
        if kind == 5:  # duplicate faces, both orientations
            f = np.concatenate([f, f[:, ::-1]])
        try:
            r1 = voxax.intersections(v, f, threads=1)
            r4 = voxax.intersections(v, f, threads=4)
            r2 = voxax.intersections(v, f[: len(f) // 2 + 1], other=(v, f))
        except Exception as exc:  # noqa: BLE001
            fail(f"intersections raised on a valid input ({kind}): {exc!r}")
            continue
        COUNTS["intersections"] += 1
        p = r1.pairs
        if not np.array_equal(p, r4.pairs):
            fail(f"intersections: thread count changed the result ({kind})")
        if p.size and (np.any(p[:, 0] >= p[:, 1]) or p.min() < 0 or p.max() >= len(f)):
            fail(f"intersections: pairs out of order or range ({kind})")
        if len(p) > 1 and np.any(np.diff(p[:, 0] * len(f) + p[:, 1]) <= 0):
            fail(f"intersections: pairs not sorted and distinct ({kind})")
        if r2.count < 0 or (r2.count and r2.pairs[:, 1].max() >= len(f)):
            fail(f"intersections: two-mesh pairs out of range ({kind})")
    # One large soup, so that the threaded set-up and several worker threads run.
    big = voxax.data.large(20_000)
    v = big.vertices + rng.normal(scale=0.02, size=big.vertices.shape)
    r1 = voxax.intersections(v, big.faces, threads=1)
    r4 = voxax.intersections(v, big.faces, threads=4)
    COUNTS["intersections"] += 1
    if not np.array_equal(r1.pairs, r4.pairs) or r1.count == 0:
        fail("intersections: large soup differs across thread counts or found nothing")
    for case, match in (
        ((np.full((3, 3), np.nan), [[0, 1, 2]]), "NaN"),
        ((np.eye(3), [[0, 1, 7]]), "out of range"),
        ((np.eye(3) * 1e76, [[0, 1, 2]]), "magnitude"),
    ):
        try:
            voxax.intersections(case[0], np.asarray(case[1]))
            fail(f"intersections accepted invalid input ({match})")
        except ValueError as exc:
            if match not in str(exc):
                fail(f"intersections: wrong message {exc}")
        COUNTS["intersections_invalid"] += 1
    # Raw calls that skip the Python checks: the kernel validates on its own.
    lib = _intersect_kernel.library()
    err = ctypes.create_string_buffer(256)
    handle = ctypes.c_void_p()
    bad = np.array([[0, 1, 5]], dtype=np.int32)
    nan = np.full((3, 3), np.nan)
    for args in (
        (None, 3, None, 1, None, 0, None, 0),
        (nan.ctypes.data, 3, bad.ctypes.data, 1, None, 0, None, 0),
        (np.eye(3).ctypes.data, 3, bad.ctypes.data, 1, None, 0, None, 0),
        (np.eye(3).ctypes.data, -1, bad.ctypes.data, 1, None, 0, None, 0),
    ):
        if lib.voxax_intersections(*args, 2, ctypes.byref(handle), err, len(err)) != -1:
            fail("raw intersections call accepted invalid input")
        COUNTS["intersections_raw"] += 1


def run_winding(rng, rounds=40):
    """Winding numbers (the ray path on closed meshes and, with a cap over the boundary, on
    open ones with holes and fins, the boundary hierarchy on soups, its bounded far-field
    expansion at a random accuracy) on adversarial soups, open and closed meshes, against
    the plain solid-angle sum; hostile raw
    calls of the host entry point and of the jit check kernel."""
    import ctypes

    from voxax._kernels import spatial as spk

    closed = [voxax.data.box(), voxax.data.icosphere(1), voxax.data.overlapping_cubes()]
    kinds = ("random", "degenerate", "huge", "tiny", "flat", "grid", "closed", "open")
    sphere = voxax.data.icosphere(3)
    for i in range(rounds):
        kind = kinds[i % len(kinds)]
        if kind == "closed":
            m = closed[i % len(closed)]
            v, f = np.asarray(m.vertices, np.float64), np.asarray(m.faces, np.int32)
            v = v * 10.0 ** float(rng.integers(-20, 20))
        elif kind == "open":  # holes and fins: a small boundary, the capped ray path
            v, f = np.asarray(sphere.vertices, np.float64), np.asarray(sphere.faces, np.int32)
            cent = v[f].mean(1)
            keep = np.ones(len(f), bool)
            for c in v[rng.choice(len(v), int(rng.integers(1, 4)), replace=False)]:
                keep &= np.linalg.norm(cent - c, axis=1) > rng.uniform(0.05, 0.5)
            fins = np.concatenate([f[rng.choice(len(f), 3)][:, :2], rng.integers(0, len(v), (3, 1))], 1)
            f = np.ascontiguousarray(np.concatenate([f[keep], fins, f[keep][:10]]), np.int32)
            v = v * 10.0 ** float(rng.integers(-20, 20))
        else:
            v, f = _spatial_soup(rng, kind)
        scale = float(np.abs(v).max()) if v.size else 1.0
        p = rng.uniform(-1.5, 1.5, (30, 3)) * scale
        k = min(5, len(v))
        p[:k] = v[:k]
        p = np.round(p * 4 / scale) * scale / 4 if i % 2 else p  # lattice points: rays through edges
        label = f"winding/{kind}/{i}"
        try:
            w1, c1, _ = spk.winding_number(np.ascontiguousarray(v), f, p, False, 1)
            w3, _, _ = spk.winding_number(np.ascontiguousarray(v), f, p, False, 3)
            ws, _, _ = spk.winding_number(np.ascontiguousarray(v), f, p, True, 2)
            eps = float(10.0 ** rng.uniform(-8, 0))  # the bounded far-field expansion
            wa1, _, _ = spk.winding_number(np.ascontiguousarray(v), f, p, False, 1, eps)
            wa3, _, _ = spk.winding_number(np.ascontiguousarray(v), f, p, False, 3, eps)
        except Exception as exc:  # noqa: BLE001
            fail(f"{label}: raised on a valid input: {exc!r}")
            continue
        COUNTS["winding"] += 1
        if len(f) and scale < 1e40:  # closest points from far away: finite, batch-independent
            far = p * 10.0 ** float(rng.integers(25, 34))
            both = voxax.closest_points((v, f), far)
            alone = voxax.closest_points((v, f), far[1:2])
            if not np.all(np.isfinite(both.distance)) or not np.all(np.isfinite(both.point)):
                fail(f"{label}: closest points from far away are not finite")
            elif both.distance[1] != alone.distance[0]:
                fail(f"{label}: a far closest point depends on the batch")
        if not np.array_equal(w1, w3):
            fail(f"{label}: thread count changed the winding numbers")
        if not np.all(np.isfinite(w1)) or np.max(np.abs(w1 - ws), initial=0) > 1e-6 * max(1, len(f)):
            fail(f"{label}: winding numbers differ from the plain sum by {np.max(np.abs(w1 - ws), initial=0)}")
        if not np.array_equal(wa1, wa3):
            fail(f"{label}: thread count changed the bounded winding numbers")
        if not np.all(np.isfinite(wa1)) or np.max(np.abs(wa1 - ws), initial=0) > eps + 1e-6 * max(1, len(f)):
            fail(f"{label}: accuracy {eps:.1e} exceeded: {np.max(np.abs(wa1 - ws), initial=0)} from the plain sum")
    lib = spk.library()
    err = ctypes.create_string_buffer(256)
    out = np.zeros(4)
    stats = np.zeros(2, np.int64)
    good_v = np.eye(3)
    bad_f = np.array([[0, 1, 5]], np.int32)
    good_f = np.array([[0, 1, 2]], np.int32)
    nan = np.full((3, 3), np.nan)
    pts = np.zeros((1, 3))
    for v_, nv, f_, nf, p_, n, mode, acc in (
        (nan, 3, good_f, 1, pts, 1, 0, 0.0),
        (good_v, 3, bad_f, 1, pts, 1, 0, 0.0),
        (good_v, 3, good_f, 1, nan, 1, 0, 0.0),
        (good_v, -1, good_f, 1, pts, 1, 0, 0.0),
        (good_v, 3, good_f, 1, pts, 1, 7, 0.0),
        (good_v, 3, good_f, -2, pts, 1, 0, 0.0),
        (good_v, 3, good_f, 1, pts, 1, 0, float("nan")),  # accuracy: NaN, < 0, infinite
        (good_v, 3, good_f, 1, pts, 1, 0, -1e-3),
        (good_v, 3, good_f, 1, pts, 1, 0, float("inf")),
        (good_v, 3, good_f, 1, pts, 1, 1, 0.1),  # the plain sum takes no accuracy
    ):
        status = lib.voxax_winding_number(
            _kernels.pointer(v_, _kernels.D), nv, _kernels.pointer(f_, _kernels.I32), nf,
            _kernels.pointer(p_, _kernels.D), n, mode, acc, 1, _kernels.pointer(out, _kernels.D),
            _kernels.pointer(stats, _kernels.I64), err, len(err),
        )  # fmt: skip
        if status == 0:
            fail("raw winding call accepted invalid input")
        COUNTS["winding_raw"] += 1
    m = voxax.data.box()
    mv, mf = jnp.asarray(m.vertices, jnp.float64), jnp.asarray(m.faces, jnp.int32)
    check = jax.jit(spk.winding_check_ffi)
    bad = {
        "nan vertices": (lambda: check(mv.at[0, 0].set(jnp.nan), mf, jnp.zeros((2, 3))), "NaN"),
        "huge points": (lambda: check(mv, mf, jnp.full((2, 3), 1e80)), "1e75"),
        "face index": (lambda: check(mv, mf.at[3, 1].set(8), jnp.zeros((2, 3))), "out of range"),
        "negative index": (lambda: check(mv, mf.at[0, 0].set(-1), jnp.zeros((2, 3))), "out of range"),
        "int points": (lambda: check(mv, mf, jnp.zeros((2, 3), jnp.int32)), "float32 or float64"),
        "jit int64 faces": (
            lambda: jax.jit(lambda g: voxax.winding_number(mv, g, jnp.zeros((1, 3))))(
                jnp.asarray(m.faces, jnp.int64) + 2**32
            ),
            "out of range",
        ),
    }
    expect_rejected("winding", bad, (ValueError, jax.errors.JaxRuntimeError))
    if int(check(mv, mf, jnp.zeros((2, 3)))) != 0:
        fail("winding check kernel: a valid input did not return 0")


def run_finite_check(rng, rounds=40):
    """The value-check kernel of traced float arrays (csrc/common/check_ffi.cc): random
    shapes (scalars, empty, large) and dtypes with NaN, Inf or huge values at random flat
    positions, under jit and vmap; the first bad index must be reported, valid arrays pass."""
    from voxax._kernels.checks import finite_check_ffi

    check = jax.jit(finite_check_ffi, static_argnames=("where", "name", "max_abs", "positive"))
    shapes = [(), (0,), (1,), (7,), (3, 0, 2), (33, 5), (4, 4, 4), (20_000,)]
    for r in range(rounds):
        shape = shapes[r % len(shapes)]
        dtype = (np.float32, np.float64)[r % 2]
        x = rng.normal(size=shape).astype(dtype)
        max_abs = float(("inf", 10.0)[(r // 2) % 2])
        bad = x.size and r % 3 != 0
        idx = int(rng.integers(x.size)) if bad else -1
        if bad:
            flat = x.reshape(-1)
            flat[idx] = (np.nan, np.inf, -np.inf, 1e30)[r % 4]
            if flat[idx] == 1e30 and max_abs == float("inf"):
                bad, idx = False, -1
        COUNTS["finite_check"] += 1
        try:
            out = int(check(jnp.asarray(x), where="voxax.test", name="x", max_abs=max_abs))
        except (ValueError, jax.errors.JaxRuntimeError) as err:
            if not bad or f"flat index {idx})" not in str(err) or "voxax.test: `x` must" not in str(err):
                fail(f"finite check: wrong rejection of {shape} {dtype.__name__} (bad index {idx}): {err}")
            continue
        if bad or out != 0:
            fail(f"finite check: accepted {shape} {dtype.__name__} with a bad value at {idx} (flag {out})")
    # `positive`: every value > 0; the first one <= 0 (zero, negative, subnormal: XLA's
    # threads see it as 0) is named, after any non-finite one
    for r in range(rounds):
        shape = shapes[r % len(shapes)]
        dtype = (np.float32, np.float64)[r % 2]
        x = np.array(rng.random(size=shape) + 0.5, dtype=dtype)
        bad = x.size and r % 3 != 0
        idx = int(rng.integers(x.size)) if bad else -1
        if bad:
            x.reshape(-1)[idx] = (0.0, -1.0, -0.0, np.finfo(dtype).tiny / 4)[r % 4]
        COUNTS["finite_check"] += 1
        try:
            out = int(check(jnp.asarray(x), where="voxax.test", name="x", positive=True))
        except (ValueError, jax.errors.JaxRuntimeError) as err:
            if not bad or f"must be > 0 (flat index {idx}:" not in str(err):
                fail(f"finite check (positive): wrong rejection of {shape} {dtype.__name__} (index {idx}): {err}")
            continue
        if bad or out != 0:
            fail(f"finite check (positive): accepted {shape} {dtype.__name__} with {x.reshape(-1)[idx]} at {idx}")
    # under vmap: one flag per item, the failing item's value found
    xs = jnp.asarray(rng.normal(size=(5, 9)))
    flags = jax.vmap(lambda v: finite_check_ffi(v, "voxax.test", "x"))(xs)
    if flags.shape != (5,) or int(jnp.abs(flags).sum()) != 0:
        fail(f"finite check under vmap: flags {flags}")
    bad = {
        "vmap NaN": (lambda: jax.vmap(lambda v: finite_check_ffi(v, "voxax.test", "x"))(xs.at[3, 4].set(jnp.nan)),
                     "flat index 4"),
        "int array": (lambda: check(jnp.zeros(3, jnp.int32), where="voxax.test", name="x"), "float32 or float64"),
        "negative bound": (lambda: check(jnp.zeros(3), where="voxax.test", name="x", max_abs=-1.0), "magnitude"),
        "empty names": (lambda: check(jnp.full(3, jnp.nan), where="", name=""), "must be finite"),
    }
    expect_rejected("finite_check", bad, (ValueError, jax.errors.JaxRuntimeError))


def pool_threads():
    """Threads of XLA's CPU pool (the one the kernels run on), by name."""
    try:
        tasks = os.listdir("/proc/self/task")
    except OSError:
        return "unknown"
    names = []
    for t in tasks:
        try:
            with open(f"/proc/self/task/{t}/comm") as fh:
                names.append(fh.read().strip())
        except OSError:
            pass
    return names.count("tf_XLAEigen")


def run_sparse(rng, count):
    """The sparse voxelization kernels (csrc/voxelize/sparse_ffi.cc): random and hostile
    meshes of every family on the 3D grids, eagerly and under jit; to_dense() equal to
    voxelize bit for bit, finite gradients and tangents; then hostile direct calls of the
    three kernels (corrupt boundary cells and counts, wrong shapes and dtypes, overflowing
    capacities), each rejected with a message."""
    from voxax._voxelize import sparse as _sparse

    families = list(FAMILIES)
    grids = list(GRIDS_3D.items())
    for n in range(count):
        family = families[n % len(families)]
        gname, grid = grids[(n // len(families)) % len(grids)]
        dtype = (np.float64, np.float32)[n % 2]
        v, f, _ = make_input(rng, family, 3, grid, dtype)
        label = f"sparse/{family}/{gname}/{np.dtype(dtype).name}"
        try:
            sg = voxax.voxelize_sparse(v, f, grid)
            W = np.asarray(voxax.voxelize(v, f, grid))
            if not np.array_equal(np.asarray(sg.to_dense()), W, equal_nan=False):
                fail(f"{label}: to_dense() differs from voxelize")
                save_failure(label, v, f, grid)
            cap = sg.capacity
            u = rng.normal(size=cap[0]).astype(dtype)
            t = rng.normal(size=v.shape).astype(dtype)
            fn = lambda x, f=f, grid=grid, cap=cap: voxax.voxelize_sparse(x, f, grid, capacity=cap).values  # noqa: E731
            mode = "jit" if n % 3 == 0 else "eager"

            def both(x, tt, uu, fn=fn):
                _, Jt = jax.jvp(fn, (x,), (tt,))
                return Jt, jax.vjp(fn, x)[1](uu)[0]

            Jt, JTu = (jax.jit(both) if mode == "jit" else both)(jnp.asarray(v), jnp.asarray(t), jnp.asarray(u))
            CALLS[f"{mode}_sparse"] += 3
            if not (np.all(np.isfinite(np.asarray(Jt))) and np.all(np.isfinite(np.asarray(JTu)))):
                fail(f"{label}: non-finite sparse tangent or gradient")
                save_failure(label, v, f, grid)
        except Exception as err:  # noqa: BLE001
            fail(f"{label}: raised {type(err).__name__}: {err}")
        COUNTS["sparse"] += 1

    grid = GRIDS_3D["odd"]
    v, f, _ = make_input(rng, "closed", 3, grid, np.float64)
    sg = voxax.voxelize_sparse(v, f, grid)
    vb, fb = jnp.asarray(v)[None], jnp.asarray(f)[None]
    cells, counts = sg.cells[None], sg.counts[None]
    C, R = sg.capacity
    ct = jnp.ones((1, C))
    tc = jnp.zeros((1, f.shape[0], 3, 3))
    attrs = _kernels.grid_attributes(grid)

    def raw_forward(shapes, **over):
        a = dict(attrs, strict=np.int64(1))
        a.update(over)
        out = tuple(jax.ShapeDtypeStruct(s, d) for s, d in shapes)
        return jax.ffi.ffi_call(_kernels.SPARSE_FORWARD, out)(vb, fb, **a)

    good = [((1, C, 3), jnp.int32), ((1, C), jnp.float64), ((1, R, 4), jnp.int32), ((1, R), jnp.float64),
            ((1, 2), jnp.int32)]
    bad = {}
    hostile_cells = {
        "unsorted cells": (cells.at[0, 0].set(cells[0, 1]).at[0, 1].set(cells[0, 0]), counts, "ascending"),
        "cell outside the grid": (cells.at[0, 0, 0].set(grid.shape[0]), counts, "outside the grid"),
        "negative cell": (cells.at[0, 0, 1].set(-1), counts, "outside the grid"),
        "count above capacity": (cells, counts.at[0, 0].set(C + 1), "outside \\[0"),
        "negative count": (cells, counts.at[0, 0].set(-5), "outside \\[0"),
    }
    for name, (c, k, match) in hostile_cells.items():
        bad[f"backward, {name}"] = (lambda c=c, k=k: _sparse.backward(vb, fb, c, ct, k, grid), match)
        bad[f"tangent, {name}"] = (lambda c=c, k=k: _sparse.tangent(vb, fb, tc, c, k, grid), match)
    bad["backward, cotangent of another capacity"] = (
        lambda: _sparse.backward(vb, fb, cells, jnp.ones((1, C + 1)), counts, grid), "cotangent must have shape")
    bad["backward, float32 cotangent"] = (
        lambda: _sparse.backward(vb, fb, cells, ct.astype(jnp.float32), counts, grid), "dtype must match")
    bad["tangent, NaN tangents"] = (lambda: _sparse.tangent(vb, fb, tc.at[0, 0, 0, 0].set(jnp.nan), cells, counts,
                                                            grid), "NaN or Inf")
    bad["forward, capacity overflow (jit)"] = (
        lambda: jax.jit(lambda x: voxax.voxelize_sparse(x, f, grid, capacity=(max(C - 1, 1), R)).values)(
            jnp.asarray(v)), "more than the capacity")
    bad["forward, NaN vertex (jit)"] = (
        lambda: jax.jit(lambda x: voxax.voxelize_sparse(x, f, grid, capacity=(C, R)).values)(
            jnp.asarray(v).at[0, 0].set(jnp.nan)), "NaN|finite")
    bad["forward, face index out of range (jit)"] = (
        lambda: jax.jit(lambda ff: voxax.voxelize_sparse(v, ff, grid, capacity=(C, R)).values)(
            jnp.asarray(f).at[0, 0].set(len(v) + 7)), "out of range|index")
    bad["forward, float32 run values"] = (
        lambda: raw_forward(good[:3] + [((1, R), jnp.float32)] + good[4:]), "dtype must match")
    bad["forward, cells of rank 2"] = (lambda: raw_forward([((C, 3), jnp.int32)] + good[1:]), "cells must have")
    bad["forward, counts of 3"] = (lambda: raw_forward(good[:4] + [((1, 3), jnp.int32)]), "counts must have")
    bad["forward, 2D grid"] = (lambda: raw_forward(good, nz=np.int64(0)), "grid shape")
    bad["eager, 2D mesh"] = (lambda: voxax.voxelize_sparse(np.zeros((3, 2)), np.array([[0, 1], [1, 2], [2, 0]]),
                                                           Grid.cube(4, dim=2)), "3D")
    expect_rejected("sparse", bad, (ValueError, TypeError, jax.errors.JaxRuntimeError))


REFERENCE_FRACTION = 0.1
BATCH = 4  # one batch size, so that batched functions compile once per grid


def run_cpu_features():
    """voxax_cpu_features (csrc/common/cpu_features.cc): buffers of every length up to the
    count (the sanitizer catches a write past one), a null buffer, a negative length; every
    prefix agrees with the full answer."""
    import ctypes

    fn = _kernels.library().voxax_cpu_features
    fn.restype, fn.argtypes = ctypes.c_int, [ctypes.POINTER(ctypes.c_int32), ctypes.c_int]
    count = fn(None, 0)
    if count != fn(None, 5) or count < 1:
        fail(f"voxax_cpu_features: count {count} with n = 0, {fn(None, 5)} with a null buffer of 5")
    full = (ctypes.c_int32 * count)()
    fn(full, count)
    for n in range(-1, count + 1):
        buf = (ctypes.c_int32 * max(n, 1))(*([-7] * max(n, 1)))
        if fn(buf, n) != count:
            fail(f"voxax_cpu_features: wrong count for n = {n}")
        expected = list(full[:n]) if n > 0 else [-7]
        if list(buf) != expected:
            fail(f"voxax_cpu_features: n = {n} wrote {list(buf)}, expected {expected}")
    COUNTS["cpu_features"] += count + 3


def main(argv=None):
    global REFERENCE_FRACTION, ARTIFACTS
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--inputs", type=int, default=4000, help="single-mesh inputs to try (batched ones add more)")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--reference-fraction", type=float, default=0.1)
    parser.add_argument("--spatial-inputs", type=int, default=300, help="inputs for the BVH queries")
    parser.add_argument("--json", help="write the counts to this file")
    parser.add_argument("--artifacts", help="save the inputs of failed checks in this directory")
    args = parser.parse_args(argv)
    REFERENCE_FRACTION = args.reference_fraction
    ARTIFACTS = args.artifacts
    t0 = time.perf_counter()

    lib = str(_kernels.library_path())
    expected = os.environ.get("VOXAX_KERNELS")
    maps = open("/proc/self/maps").read() if os.path.exists("/proc/self/maps") else ""
    sanitized = "libasan" in maps
    print(f"kernels: {lib}; AddressSanitizer runtime loaded: {sanitized}; "
          f"UBSan runtime loaded: {'libubsan' in maps}; NPROC={os.environ.get('NPROC', '(unset)')}", flush=True)
    if expected and os.path.realpath(lib) != os.path.realpath(expected):
        fail(f"loaded {lib}, not VOXAX_KERNELS={expected}")

    rng = np.random.default_rng(args.seed)
    families = list(FAMILIES)
    grids = {3: list(GRIDS_3D.items()), 2: list(GRIDS_2D.items())}
    dtypes = [np.float64, np.float32]
    i = 0
    try:
        for dim in (3, 2):
            for dtype in dtypes:
                run_zero_size(dim, dtype)
        run_raw_ffi(rng)
        run_spatial(rng, args.spatial_inputs)
        run_knn(rng, max(40, args.spatial_inputs // 2))
        run_line_crossings(rng, max(40, args.spatial_inputs // 2))
        run_fc(rng, max(28, args.spatial_inputs // 4))
        run_rdt(rng, max(20, args.spatial_inputs // 4))
        run_bounds(rng, max(20, args.spatial_inputs // 4))
        run_marching_cubes(rng, max(20, args.inputs // 20))
        run_raw_tangent_ffi(rng)
        run_intersections(rng)
        run_cpu_features()
        run_winding(rng, max(21, args.spatial_inputs // 5))
        run_sparse(rng, max(14, args.inputs // 20))
        run_finite_check(rng, max(24, args.spatial_inputs // 4))
        while COUNTS["eager"] + COUNTS["jit"] < args.inputs:
            dim = 3 if i % 3 else 2
            family = families[i % len(families)]
            gname, grid = grids[dim][(i // len(families)) % len(grids[dim])]
            dtype = dtypes[(i // 7) % 2]
            r = i % 10
            t_in = time.perf_counter()
            if r < 7:
                run_single(rng, family, dim, gname, grid, dtype, "jit" if r % 2 else "eager")
            elif r < 9:
                case, match = INVALID[(i // 10) % len(INVALID)]
                run_invalid(rng, dim, gname, grid, dtype, case, match)
            else:
                run_batched(rng, family, dim, gname, grid, dtype, BATCH)
            if r == 3:
                run_tangent(rng, family, dim, gname, grid, dtype)
            TIMES[f"{dim}D/{gname}"] += time.perf_counter() - t_in
            i += 1
    except Exception:  # noqa: BLE001
        fail("driver raised:\n" + traceback.format_exc())

    elapsed = time.perf_counter() - t0
    inputs = sum(COUNTS[k] for k in list(FAMILIES) + ["invalid", "raw_ffi", "zero_size", "tangent"])
    print("\nzero-size batches:")
    for k, val in OBSERVED.items():
        print(f"  {k}: {val}")
    print("\ninputs per family: " + ", ".join(f"{k} {COUNTS[k]}" for k in list(FAMILIES) + ["invalid", "raw_ffi", "zero_size", "marching_cubes", "marching_cubes_invalid"]))
    print("inputs per kind: " + ", ".join(f"{k} {COUNTS[k]}" for k in ("dim3", "dim2", "float64", "float32", "eager", "jit", "batched")))
    print(f"spatial (BVH) inputs: {COUNTS['spatial']}, invalid: {COUNTS['spatial_invalid']}")
    print(f"kNN inputs: {COUNTS['knn']}, invalid: {COUNTS['knn_invalid']}")
    print(f"finite-check inputs: {COUNTS['finite_check']}, invalid: {COUNTS['finite_check_invalid']}")
    print(f"line crossings inputs: {COUNTS['line_crossings']}, invalid: {COUNTS['line_crossings_invalid']}")
    print(f"sparse voxelization inputs: {COUNTS['sparse']}, invalid: {COUNTS['sparse_invalid']}")
    print(f"selection bound sums: {COUNTS['bounds']} calls, invalid: {COUNTS['bounds_invalid']}")
    print("exact intersection test: " + ", ".join(f"{k} {COUNTS[k]}" for k in ("intersections", "intersections_invalid", "intersections_raw")))
    print(f"reference comparisons: {COUNTS['reference_comparisons']}; volume-identity checks: {COUNTS['volume_checks']}")
    print("kernel invocations: " + ", ".join(f"{k} {v}" for k, v in sorted(CALLS.items())) + f" (total {sum(CALLS.values())})")
    print(f"jitted functions compiled: {len(_JIT)}; XLA pool threads: {pool_threads()}")
    print("seconds per grid: " + ", ".join(f"{k} {v:.1f}" for k, v in TIMES.most_common()))
    print(f"INPUTS TRIED: {inputs} in {elapsed:.1f} s; failed checks: {len(FAILURES)}", flush=True)
    if args.json:
        with open(args.json, "w") as fh:
            json.dump({"inputs": inputs, "seconds": elapsed, "counts": dict(COUNTS), "calls": dict(CALLS),
                       "failures": FAILURES, "observed": OBSERVED, "sanitized": sanitized}, fh, indent=1)
    if FAILURES:
        print(f"\nfirst failed checks ({len(FAILURES)} in all):", file=sys.stderr)
        for msg in FAILURES[:20]:
            print("  " + msg.splitlines()[0], file=sys.stderr)
    return 3 if FAILURES else 0


if __name__ == "__main__":
    sys.exit(main())
