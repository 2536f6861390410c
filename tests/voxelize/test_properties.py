"""Property-based tests (Hypothesis) of `voxax.voxelize` on random meshes and grids.

Each property draws the structure of an example (dimension, grid shape and corners, mesh
kind, face counts, whether vertices are snapped onto grid planes) with Hypothesis and the
numeric details from a drawn seed, so failures shrink to small, reproducible cases.

Exact vs approximate properties (measured, and asserted accordingly):

- relabelling the vertices (same faces, same corner order) and batching give results
  identical bit for bit;
- flipping the orientation negates W, and reordering the faces (or rotating each face's
  corners) or translating mesh and grid together by whole voxels (with exactly
  representable coordinates) leave W unchanged only up to rounding: the kernel adds the
  pieces of a tile's faces in face order and integrates relative to plane coordinates, so
  the last bits can change. These are asserted to 1e-12 (relative to max |W|).

Examples are derandomized (the same on every run) unless `VOXAX_HYPOTHESIS_RANDOM=1`.
"""

from __future__ import annotations

import os

import jax
import jax.numpy as jnp
import numpy as np
from conftest import random_polygon, random_star_mesh
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

import voxax
from voxax import Grid, reference

RANDOM = os.environ.get("VOXAX_HYPOTHESIS_RANDOM", "") == "1"


def props(n):
    return settings(
        max_examples=n,
        deadline=None,
        database=None,
        derandomize=not RANDOM,
        suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large],
    )


# -- strategies ----------------------------------------------------------------------------


@st.composite
def grids(draw, dim, max_cells=9):
    shape = tuple(draw(st.integers(1, max_cells)) for _ in range(dim))
    lower = tuple(draw(st.floats(-1.0, -0.3)) for _ in range(dim))
    upper = tuple(lo + draw(st.floats(0.8, 2.0)) for lo in lower)
    return Grid(lower, upper, shape)


def _snap(rng, v, grid, p):
    """Moves coordinates exactly onto grid planes (boundary planes included)."""
    v = v.copy()
    for a in range(grid.dim):
        e = grid.edges(a)
        idx = np.clip(np.round((v[:, a] - e[0]) / (e[-1] - e[0]) * (len(e) - 1)), 0, len(e) - 1).astype(int)
        mask = rng.random(len(v)) < p
        v[mask, a] = e[idx[mask]]
    return v


def _star(rng, dim, center, scale):
    if dim == 3:
        return random_star_mesh(rng, n_theta=int(rng.integers(3, 8)), n_phi=int(rng.integers(2, 6)), center=center,
                                scale=scale)
    return random_polygon(rng, n=int(rng.integers(3, 14)), center=center, scale=scale)


def _box(rng, dim, grid, snapped):
    """An axis-aligned box (square), with its faces on grid planes when `snapped`."""
    lo, hi = np.empty(dim), np.empty(dim)
    for a in range(dim):
        e = grid.edges(a)
        if snapped and len(e) > 1:
            i, j = sorted(rng.choice(len(e), size=2, replace=False))
            lo[a], hi[a] = e[i], e[j]
        else:
            lo[a], hi[a] = np.sort(rng.uniform(e[0], e[-1], 2))
            hi[a] = max(hi[a], lo[a] + 1e-3)
    m = voxax.data.box(lo, hi) if dim == 3 else voxax.data.polygon_square(lo, hi)
    return np.asarray(m.vertices, np.float64), np.asarray(m.faces)


@st.composite
def meshes(draw, grid, kinds=("star", "soup", "box"), inside=False):
    """A mesh for `grid`: a closed star-shaped mesh, a triangle/segment soup or a box.

    With `inside=True` only closed meshes lying inside the grid are drawn.
    """
    dim = grid.dim
    kind = draw(st.sampled_from([k for k in kinds if not (inside and k == "soup")]))
    snap = draw(st.sampled_from([0.0, 0.0, 0.5, 1.0]))
    rng = np.random.default_rng(draw(st.integers(0, 2**32 - 1)))
    lo, hi = np.array(grid.lower), np.array(grid.upper)
    ext = hi - lo
    if kind == "box":
        return _box(rng, dim, grid, snapped=snap > 0)
    if kind == "star":
        if inside:
            center = lo + ext * rng.uniform(0.4, 0.6, dim)
            scale = float(np.min(ext)) * rng.uniform(0.05, 0.25)
        else:
            center = lo + ext * rng.uniform(-0.2, 1.2, dim)
            scale = float(np.max(ext)) * rng.uniform(0.05, 0.6)
        v, f = _star(rng, dim, center, scale)
    else:
        n = draw(st.integers(1, 12))
        v = rng.uniform(lo - 0.3 * ext, hi + 0.3 * ext, size=(n * dim, dim))
        f = np.arange(n * dim).reshape(n, dim)
    if snap:
        v = _snap(rng, v, grid, snap)
        if inside:
            v = np.clip(v, lo, hi)
    return v, np.asarray(f, np.int32)


@st.composite
def grid_and_mesh(draw, dims=(2, 3), **kw):
    dim = draw(st.sampled_from(dims))
    grid = draw(grids(dim))
    return grid, draw(meshes(grid, **kw))


def W_of(v, f, grid):
    return np.asarray(voxax.voxelize(v, f, grid))


def close(a, b, rel=1e-12):
    scale = max(1.0, float(np.max(np.abs(a))) if a.size else 1.0)
    return float(np.max(np.abs(a - b))) <= rel * scale


# -- properties ----------------------------------------------------------------------------


@props(40)
@given(grid_and_mesh())
def test_matches_reference_float64(case):
    grid, (v, f) = case
    W = W_of(v, f, grid)
    expected = reference.voxelize(v, f, grid)
    err = float(np.max(np.abs(W - expected)))
    assert err <= 1e-10, f"max |W - reference| = {err:.3g}"


@props(25)
@given(grid_and_mesh(kinds=("star", "box")))
def test_matches_reference_float32(case):
    grid, (v, f) = case
    v32 = v.astype(np.float32)
    W = W_of(v32, f, grid)
    assert W.dtype == np.float32
    expected = reference.voxelize(v32.astype(np.float64), f, grid)
    assert float(np.max(np.abs(W - expected))) <= 1e-5


@props(40)
@given(grid_and_mesh(inside=True), st.integers(0, 2))
def test_volume_identity_closed_meshes(case, copies):
    """sum(W) * voxel volume is the signed volume of any closed mesh inside the grid
    (also unions of overlapping copies, where W reaches 2, 3, ...)."""
    grid, (v, f) = case
    if copies:  # add shifted copies, overlapping the first one
        rng = np.random.default_rng(copies)
        parts_v, parts_f = [v], [f]
        for c in range(copies):
            lo, hi = v.min(axis=0), v.max(axis=0)
            room_lo, room_hi = np.array(grid.lower) - lo, np.array(grid.upper) - hi
            shift = rng.uniform(np.minimum(room_lo, 0), np.maximum(room_hi, 0)) * 0.5
            parts_v.append(v + shift)
            parts_f.append(f + len(v) * (c + 1))
        v, f = np.concatenate(parts_v), np.concatenate(parts_f)
    W = W_of(v, f, grid)
    vol = reference.signed_volume(v, f)
    box = float(np.prod(np.array(grid.upper) - np.array(grid.lower)))
    assert abs(W.sum() * grid.voxel_volume - vol) <= 1e-12 * box * (1 + copies)


@props(30)
@given(grid_and_mesh())
def test_flip_negates(case):
    grid, (v, f) = case
    W = W_of(v, f, grid)
    Wf = W_of(v, f[:, ::-1], grid)
    assert close(Wf, -W)


@props(30)
@given(grid_and_mesh(), st.integers(0, 2**32 - 1))
def test_face_order_and_vertex_labels(case, seed):
    grid, (v, f) = case
    rng = np.random.default_rng(seed)
    W = W_of(v, f, grid)
    # Reordering the faces (and, in 3D, rotating each triangle's corners): equal up to rounding.
    g = f[rng.permutation(len(f))]
    if grid.dim == 3:
        g = np.roll(g, int(rng.integers(3)), axis=1)
    assert close(W_of(v, g, grid), W)
    # Relabelling the vertices (same corner order): bit for bit.
    perm = rng.permutation(len(v))
    inv = np.argsort(perm)
    np.testing.assert_array_equal(W_of(v[perm], inv[f].astype(np.int32), grid), W)


@props(30)
@given(st.data())
def test_translation_by_whole_voxels(data):
    """Mesh and grid moved together by whole voxels, all coordinates exactly representable."""
    dim = data.draw(st.sampled_from([2, 3]))
    shape = tuple(data.draw(st.integers(1, 8)) for _ in range(dim))
    h = np.array([2.0 ** -data.draw(st.integers(1, 4)) for _ in range(dim)])
    lower = np.array([data.draw(st.integers(-16, 0)) / 8 for _ in range(dim)])
    grid = Grid(tuple(lower), tuple(lower + h * np.array(shape)), shape)
    v, f = data.draw(meshes(grid))
    v = np.round(v * 2**12) / 2**12  # dyadic, so that the shifted copy is exact
    shift = np.array([data.draw(st.integers(-40, 40)) for _ in range(dim)]) * h
    moved = Grid(tuple(lower + shift), tuple(np.array(grid.upper) + shift), shape)
    assert np.all(v + shift - shift == v)
    assert close(W_of(v + shift, f, moved), W_of(v, f, grid))


@props(30)
@given(st.data())
def test_linearity_in_meshes(data):
    """W of two meshes together is the sum of their W's (here often disjoint, sometimes
    overlapping: W is a sum over faces either way)."""
    dim = data.draw(st.sampled_from([2, 3]))
    grid = data.draw(grids(dim))
    v1, f1 = data.draw(meshes(grid))
    v2, f2 = data.draw(meshes(grid))
    W = W_of(np.concatenate([v1, v2]), np.concatenate([f1, f2 + len(v1)]), grid)
    assert close(W, W_of(v1, f1, grid) + W_of(v2, f2, grid))


@props(25)
@given(grid_and_mesh(), st.integers(1, 4))
def test_batched_equals_one_by_one(case, batch):
    grid, (v, f) = case
    rng = np.random.default_rng(batch)
    vs = np.stack([v + rng.normal(scale=1e-2, size=v.shape) * (b > 0) for b in range(batch)])
    Wb = np.asarray(jax.vmap(lambda x: voxax.voxelize(x, f, grid))(jnp.asarray(vs)))
    for b in range(batch):
        np.testing.assert_array_equal(Wb[b], W_of(vs[b], f, grid))


@props(8)
@given(st.sampled_from([2, 3]), st.integers(0, 2**32 - 1))
def test_gradient_matches_central_differences(dim, seed):
    """d/dt sum(C * W(v + t u)) at t = 0 against a central difference, u random."""
    rng = np.random.default_rng(seed)
    grid = Grid((-1.0,) * dim, (1.0,) * dim, tuple(int(n) for n in rng.integers(3, 9, dim)))
    v, f = _star(rng, dim, rng.uniform(-0.3, 0.3, dim), rng.uniform(0.3, 0.7))
    C = jnp.asarray(rng.normal(size=grid.shape))
    u = rng.normal(size=v.shape)
    energy = lambda x: jnp.sum(C * voxax.voxelize(x, f, grid))  # noqa: E731
    analytic = float(jnp.vdot(jax.grad(energy)(jnp.asarray(v)), u))
    eps = 1e-6
    numeric = (float(energy(v + eps * u)) - float(energy(v - eps * u))) / (2 * eps)
    assert abs(analytic - numeric) <= 1e-5 * (1 + abs(analytic)), (analytic, numeric)
