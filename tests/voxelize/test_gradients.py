"""Gradients of `voxax.voxelize`: exact identities, finite differences, the reference, determinism.

Everything runs in float64 (enabled by conftest) unless a test says float32. Vertices are
randomly perturbed so that no vertex, edge or face lies in a grid plane: there the
voxelization is only piecewise smooth and a finite difference would straddle a kink.

Errors are measured as `max |got - expected| / max |expected|` ("relative to the largest
entry"), which is stable when some entries of a gradient are (close to) zero.
"""

import os
import subprocess
import sys
import zlib
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from conftest import random_polygon, random_star_mesh
from jax.test_util import check_grads

import voxax
from voxax import Grid, reference

# ---------------------------------------------------------------------------------------
# Helpers
# ---------------------------------------------------------------------------------------


def stable_seed(*parts):
    """A seed derived from test parameters, the same in every process (unlike hash())."""
    return zlib.crc32(repr(parts).encode())


def rel_err(got, expected):
    got, expected = np.asarray(got, np.float64), np.asarray(expected, np.float64)
    scale = np.max(np.abs(expected))
    assert scale > 0, "the expected value is identically zero; the comparison would be vacuous"
    return float(np.max(np.abs(got - expected)) / scale)


def jitter(rng, v, amount=1e-3):
    """Moves every vertex by a small random amount, away from grid planes."""
    return np.asarray(v, np.float64) + amount * rng.uniform(-1.0, 1.0, np.shape(v))


def concat(*meshes):
    """Concatenates `(vertices, faces)` pairs into one mesh (no union: overlaps add up)."""
    vs, fs, offset = [], [], 0
    for v, f in meshes:
        vs.append(np.asarray(v, np.float64))
        fs.append(np.asarray(f) + offset)
        offset += len(v)
    return np.concatenate(vs), np.concatenate(fs).astype(np.int32)


def rotated_box(rng, half=(0.3, 0.25, 0.35)):
    """An axis-aligned box rotated about z only (so its four side faces stay vertical),
    randomly translated."""
    m = voxax.data.box(tuple(-h for h in half), half)
    t = rng.uniform(0, 2 * np.pi)
    c, s = np.cos(t), np.sin(t)
    rz = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
    v = m.vertices @ rz.T + rng.uniform(-0.3, 0.3, 3)
    return v, m.faces


def translated_rectangle(rng):
    """An axis-aligned rectangle (two vertical segments), randomly placed and sized."""
    lo = rng.uniform(-0.7, -0.2, 2)
    hi = rng.uniform(0.1, 0.7, 2)
    m = voxax.data.polygon_square(lo, hi)
    return m.vertices, m.faces


def volume_grad(vertices, faces, grid):
    """d/dv of `sum(W) * |voxel|` through the kernels."""
    vol = grid.voxel_volume
    return np.asarray(jax.grad(lambda v: voxax.voxelize(v, faces, grid).sum() * vol)(jnp.asarray(vertices)))


def fd_grad(energy, vertices, faces, grid, eps=1e-6):
    """Central finite differences of `energy(voxelize(v))` per vertex coordinate.

    All `2 * V * d` perturbed meshes are voxelized in one batched kernel call."""
    v = np.asarray(vertices, np.float64)
    n = v.size
    steps = (np.eye(n) * eps).reshape(n, *v.shape)
    batch = np.concatenate([v[None] + steps, v[None] - steps])
    W = voxax.voxelize(batch, faces, grid)
    e = np.asarray(jax.vmap(energy)(W))
    return ((e[:n] - e[n:]) / (2 * eps)).reshape(v.shape)


ANISO3 = Grid(lower=(-0.9, -1.1, -0.8), upper=(1.2, 0.95, 1.05), shape=(5, 8, 11))
ANISO2 = Grid(lower=(-0.9, -1.1), upper=(1.2, 0.95), shape=(5, 11))


# ---------------------------------------------------------------------------------------
# The volume identity and its exact gradient (closed meshes inside the grid)
# ---------------------------------------------------------------------------------------


def _closed_mesh_3d(kind, rng):
    if kind == "star":
        return random_star_mesh(rng, center=rng.uniform(-0.15, 0.15, 3), scale=0.5)
    if kind == "icosphere":
        m = voxax.data.icosphere(1, radius=0.6)
        return jitter(rng, m.vertices, 1e-2), m.faces
    if kind == "overlapping_cubes":
        m = voxax.data.overlapping_cubes()
        return jitter(rng, m.vertices, 1e-2), m.faces
    if kind == "two_stars":
        return concat(
            random_star_mesh(rng, center=(-0.15, 0.05, 0.0), scale=0.45),
            random_star_mesh(rng, center=(0.15, -0.05, 0.1), scale=0.45),
        )
    raise ValueError(kind)


def _closed_mesh_2d(kind, rng):
    if kind == "polygon":
        return random_polygon(rng, n=11, center=rng.uniform(-0.15, 0.15, 2), scale=0.5)
    if kind == "overlapping_squares":
        m = voxax.data.overlapping_squares()
        return jitter(rng, m.vertices, 1e-2), m.faces
    if kind == "star_polyline":
        m = voxax.data.star_polyline()
        return jitter(rng, m.vertices, 1e-2), m.faces
    raise ValueError(kind)


GRIDS_3D = [Grid.cube(7), Grid.cube(8), Grid.cube(9), ANISO3]
GRIDS_2D = [Grid.cube(7, dim=2), Grid.cube(8, dim=2), Grid.cube(9, dim=2), ANISO2]


@pytest.mark.parametrize("kind", ["star", "icosphere", "overlapping_cubes", "two_stars"])
@pytest.mark.parametrize("grid", GRIDS_3D, ids=lambda g: "x".join(map(str, g.shape)))
def test_volume_gradient_identity_3d(kind, grid):
    """For a closed mesh inside the grid, sum(W)*|voxel| is the signed volume, and its
    gradient at vertex v is sum over the faces t around v of area_t * nhat_t / 3."""
    rng = np.random.default_rng(stable_seed((kind, grid.shape)))
    v, f = _closed_mesh_3d(kind, rng)
    lo, hi = np.array(grid.lower), np.array(grid.upper)
    assert np.all(v > lo) and np.all(v < hi)
    W = voxax.voxelize(v, f, grid)
    assert abs(float(W.sum()) * grid.voxel_volume - reference.signed_volume(v, f)) < 1e-12
    expected = reference.volume_gradient(v, f)
    assert rel_err(volume_grad(v, f, grid), expected) < 1e-10


@pytest.mark.parametrize("kind", ["polygon", "overlapping_squares", "star_polyline"])
@pytest.mark.parametrize("grid", GRIDS_2D, ids=lambda g: "x".join(map(str, g.shape)))
def test_volume_gradient_identity_2d(kind, grid):
    """2D: sum(W)*|pixel| is the signed area; its gradient is sum of length * nhat / 2."""
    rng = np.random.default_rng(stable_seed((kind, grid.shape)))
    v, f = _closed_mesh_2d(kind, rng)
    assert np.all(v > np.array(grid.lower)) and np.all(v < np.array(grid.upper))
    W = voxax.voxelize(v, f, grid)
    assert abs(float(W.sum()) * grid.voxel_volume - reference.signed_volume(v, f)) < 1e-12
    assert rel_err(volume_grad(v, f, grid), reference.volume_gradient(v, f)) < 1e-10


def test_volume_gradient_identity_float32():
    """The identity holds to float32 accuracy with float32 vertices."""
    rng = np.random.default_rng(7)
    v, f = random_star_mesh(rng, scale=0.55)
    g = Grid.cube(9)
    got = volume_grad(v.astype(np.float32), f, g)
    assert got.dtype == np.float32
    assert rel_err(got, reference.volume_gradient(v.astype(np.float32), f)) < 1e-4


# ---------------------------------------------------------------------------------------
# Meshes partly outside the grid
# ---------------------------------------------------------------------------------------

OUTSIDE_3D = [
    ("top_x", (0.75, 0.1, 0.8)),  # through the top and the +x side
    ("bottom_corner", (-0.85, -0.8, -0.9)),  # through the bottom and a corner
    ("side_y", (0.05, 0.95, 0.0)),  # half outside along +y
]


@pytest.mark.parametrize("name,center", OUTSIDE_3D, ids=[c[0] for c in OUTSIDE_3D])
@pytest.mark.parametrize("grid", [Grid.cube(8), ANISO3], ids=["cube8", "aniso"])
def test_partly_outside_gradient_3d(name, center, grid):
    """For a closed mesh partly outside the grid box B, sum(W) * |voxel| is the volume of
    (inside of the mesh) ∩ B, so only the part of the surface inside B moves it:

        d/dv_m [sum(W) |voxel|] = sum over faces t around m, over the part P = t ∩ B,
                                  of area(P) * nhat_t * beta_m(centroid of P)

    (beta the barycentric coordinates within t). This is *not* `volume_gradient` (which
    counts the whole surface). Checked against the reference splat with cotangent
    ones * |voxel| and against central differences of the kernel's own forward."""
    rng = np.random.default_rng(stable_seed((name, grid.shape)))
    v, f = random_star_mesh(rng, n_theta=7, n_phi=5, center=center, scale=0.55)
    lo, hi = np.array(grid.lower), np.array(grid.upper)
    assert np.any(v < lo) or np.any(v > hi), "the mesh should stick out of the grid"
    got = volume_grad(v, f, grid)
    expected = reference.voxelize_backward(v, f, grid, np.full(grid.shape, grid.voxel_volume))
    assert rel_err(got, expected) < 1e-10
    vol = grid.voxel_volume
    fd = fd_grad(lambda W: W.sum() * vol, v, f, grid)
    assert rel_err(got, fd) < 1e-6
    # The whole-surface gradient is different: the clipped part matters.
    assert rel_err(reference.volume_gradient(v, f), got) > 1e-2


@pytest.mark.parametrize("center", [(0.8, 0.75), (-0.85, 0.1), (0.0, -0.9)])
def test_partly_outside_gradient_2d(center):
    """2D version: only the parts of the segments inside the grid rectangle count."""
    grid = Grid(lower=(-1.0, -0.9), upper=(1.1, 1.0), shape=(9, 8))
    rng = np.random.default_rng(int(1000 * (center[0] + 3 * center[1])) % 2**32)
    v, f = random_polygon(rng, n=12, center=center, scale=0.55)
    assert np.any(v < np.array(grid.lower)) or np.any(v > np.array(grid.upper))
    got = volume_grad(v, f, grid)
    expected = reference.voxelize_backward(v, f, grid, np.full(grid.shape, grid.voxel_volume))
    assert rel_err(got, expected) < 1e-10
    vol = grid.voxel_volume
    assert rel_err(got, fd_grad(lambda W: W.sum() * vol, v, f, grid)) < 1e-6
    assert rel_err(reference.volume_gradient(v, f), got) > 1e-2


@pytest.mark.parametrize("dim", [2, 3])
def test_enclosing_mesh_has_zero_gradient(dim):
    """A closed mesh enclosing the whole grid: W == 1 everywhere, and no part of the
    surface is in the grid, so the gradient is exactly zero."""
    rng = np.random.default_rng(dim)
    if dim == 3:
        m = voxax.data.icosphere(1, radius=3.0)
        v, f = jitter(rng, m.vertices, 1e-2), m.faces
    else:
        v, f = random_polygon(rng, n=9, scale=3.0, jitter=0.2)
    grid = Grid.cube(6, dim=dim)
    np.testing.assert_allclose(np.asarray(voxax.voxelize(v, f, grid)), 1.0, atol=1e-12)
    c = rng.normal(size=grid.shape)
    g = jax.grad(lambda x: (c * voxax.voxelize(x, f, grid)).sum())(jnp.asarray(v))
    np.testing.assert_array_equal(np.asarray(g), 0.0)


# ---------------------------------------------------------------------------------------
# jax.test_util.check_grads (reverse mode, float64)
# ---------------------------------------------------------------------------------------


def _energy(name, grid, seed=0):
    c = np.random.default_rng(seed).normal(size=grid.shape)
    if name == "sum_sq":
        return lambda W: jnp.sum(W**2)
    if name == "sin_c":
        return lambda W: jnp.sum(jnp.sin(W) * c)
    if name == "self_intersection":
        return lambda W: jnp.sum(jax.nn.relu(W - 1.0) ** 2)
    raise ValueError(name)


def _check_grads_case(case, rng):
    if case == "star":
        v, f = random_star_mesh(rng, center=(0.05, -0.1, 0.02), scale=0.6)
        return v, f, Grid.cube(8)
    if case == "icosphere":
        m = voxax.data.icosphere(1, radius=0.7)
        return jitter(rng, m.vertices, 1e-2), m.faces, Grid.cube(6)
    if case == "polygon":
        v, f = random_polygon(rng, n=13, scale=0.6)
        return v, f, Grid.cube(9, dim=2)
    if case == "overlapping_cubes":
        m = voxax.data.overlapping_cubes()
        return jitter(rng, m.vertices, 2e-2), m.faces, Grid.cube(10)
    if case == "bent_bar":
        m = voxax.data.bent_bar(n_along=30, n_around=8)
        return jitter(rng, m.vertices, 1e-3), m.faces, Grid.cube(12)
    if case == "overlapping_squares":
        m = voxax.data.overlapping_squares()
        return jitter(rng, m.vertices, 2e-2), m.faces, Grid.cube(10, dim=2)
    raise ValueError(case)


CHECK_GRADS_CASES = [
    ("star", "sum_sq"),
    ("star", "sin_c"),
    ("icosphere", "sum_sq"),
    ("icosphere", "sin_c"),
    ("polygon", "sum_sq"),
    ("polygon", "sin_c"),
    ("overlapping_cubes", "self_intersection"),
    ("bent_bar", "self_intersection"),
    ("overlapping_squares", "self_intersection"),
]


@pytest.mark.parametrize("case,energy", CHECK_GRADS_CASES, ids=[f"{a}-{b}" for a, b in CHECK_GRADS_CASES])
def test_check_grads(case, energy):
    rng = np.random.default_rng(stable_seed((case, energy)))
    v, f, grid = _check_grads_case(case, rng)
    e = _energy(energy, grid)
    fn = lambda x: e(voxax.voxelize(x, f, grid))  # noqa: E731
    x = jnp.asarray(v)
    if energy == "self_intersection":
        assert float(fn(x)) > 0.0, "the self-intersection energy should be active"
    assert np.any(np.asarray(jax.grad(fn)(x)) != 0.0)
    check_grads(fn, (x,), order=1, modes=("rev",), eps=1e-6, atol=1e-7, rtol=1e-7)


# ---------------------------------------------------------------------------------------
# Central finite differences per vertex coordinate
# ---------------------------------------------------------------------------------------


def _fd_mesh(kind, rng):
    if kind == "star":
        return random_star_mesh(rng, center=rng.uniform(-0.2, 0.2, 3), scale=0.55)
    if kind == "self_intersecting":
        return concat(
            random_star_mesh(rng, n_theta=5, n_phi=4, center=(-0.2, 0.0, 0.05), scale=0.5),
            random_star_mesh(rng, n_theta=5, n_phi=4, center=(0.15, 0.1, -0.05), scale=0.5),
        )
    if kind == "vertical_faces":
        return rotated_box(rng)
    if kind == "polygon":
        return random_polygon(rng, n=10, center=rng.uniform(-0.2, 0.2, 2), scale=0.55)
    if kind == "self_intersecting_2d":
        return concat(
            random_polygon(rng, n=8, center=(-0.2, 0.05), scale=0.5),
            random_polygon(rng, n=8, center=(0.2, -0.05), scale=0.5),
        )
    if kind == "vertical_faces_2d":
        return translated_rectangle(rng)
    raise ValueError(kind)


FD_CASES = [
    ("star", 8, 0),
    ("self_intersecting", 8, 2),
    ("self_intersecting", (6, 9, 7), 3),
    ("vertical_faces", 8, 4),
    ("vertical_faces", 9, 5),
    ("polygon", 9, 6),
    ("self_intersecting_2d", 8, 7),
    ("self_intersecting_2d", (7, 12), 8),
    ("vertical_faces_2d", 8, 9),
]


@pytest.mark.parametrize("kind,n,seed", FD_CASES, ids=[f"{k}-{n}" for k, n, _ in FD_CASES])
@pytest.mark.parametrize("energy", ["linear", "sum_sq"])
def test_central_differences(kind, n, seed, energy):
    rng = np.random.default_rng(seed)
    v, f = _fd_mesh(kind, rng)
    dim = v.shape[1]
    grid = Grid.cube(n, dim=dim)
    c = rng.normal(size=grid.shape)
    e = (lambda W: jnp.sum(c * W)) if energy == "linear" else (lambda W: jnp.sum(W**2))
    got = jax.grad(lambda x: e(voxax.voxelize(x, f, grid)))(jnp.asarray(v))
    fd = fd_grad(e, v, f, grid)
    assert rel_err(got, fd) <= 1e-6
    if kind.startswith("vertical_faces"):
        # The side faces really are vertical (normal without a z / y component).
        tri = v[f]
        if dim == 3:
            nz = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])[:, 2]
        else:
            nz = tri[:, 0, 0] - tri[:, 1, 0]
        assert np.sum(np.abs(nz) < 1e-12) >= 2


# ---------------------------------------------------------------------------------------
# Agreement with the NumPy reference backward
# ---------------------------------------------------------------------------------------


def _random_case(seed, dim):
    rng = np.random.default_rng(seed)
    lower = -1.0 + rng.uniform(-0.3, 0.3, dim)
    upper = 1.0 + rng.uniform(-0.3, 0.3, dim)
    grid = Grid(lower=tuple(lower), upper=tuple(upper), shape=tuple(rng.integers(5, 14, dim)))
    if dim == 3:
        v, f = random_star_mesh(
            rng, n_theta=int(rng.integers(4, 8)), n_phi=int(rng.integers(3, 6)),
            center=rng.uniform(-0.6, 0.6, 3), scale=rng.uniform(0.3, 0.8),
        )
        if seed % 2:
            v, f = concat((v, f), random_star_mesh(rng, center=rng.uniform(-0.5, 0.5, 3), scale=0.4))
    else:
        v, f = random_polygon(rng, n=int(rng.integers(5, 15)), center=rng.uniform(-0.6, 0.6, 2),
                              scale=rng.uniform(0.3, 0.8))
        if seed % 2:
            v, f = concat((v, f), random_polygon(rng, n=7, center=rng.uniform(-0.5, 0.5, 2), scale=0.4))
    cot = rng.normal(size=grid.shape)
    return v, f, grid, cot


@pytest.mark.parametrize("dim", [2, 3])
@pytest.mark.parametrize("seed", range(4))
def test_backward_matches_reference_float64(seed, dim):
    v, f, grid, cot = _random_case(seed, dim)
    W, vjp = jax.vjp(lambda x: voxax.voxelize(x, f, grid), jnp.asarray(v))
    (got,) = vjp(jnp.asarray(cot))
    assert got.dtype == jnp.float64
    expected = reference.voxelize_backward(v, f, grid, cot)
    assert rel_err(got, expected) < 1e-10
    # The forward of this (possibly partly outside, overlapping) mesh matches as well.
    assert rel_err(W, reference.voxelize(v, f, grid)) < 1e-10


@pytest.mark.parametrize("dim", [2, 3])
@pytest.mark.parametrize("seed", range(3))
def test_backward_matches_reference_float32(seed, dim):
    v, f, grid, cot = _random_case(100 + seed, dim)
    v32, cot32 = v.astype(np.float32), cot.astype(np.float32)
    _, vjp = jax.vjp(lambda x: voxax.voxelize(x, f, grid), jnp.asarray(v32))
    (got,) = vjp(jnp.asarray(cot32))
    assert got.dtype == jnp.float32
    expected = reference.voxelize_backward(v32.astype(np.float64), f, grid, cot32.astype(np.float64))
    assert rel_err(got, expected) < 1e-4


@pytest.mark.parametrize("dim", [2, 3])
def test_corner_gradients_sum_to_vertex_gradients(dim):
    """`voxelize_corner_gradients` summed over the corners of each vertex is the VJP."""
    v, f, grid, cot = _random_case(42, dim)
    corners = np.asarray(voxax.voxelize_corner_gradients(jnp.asarray(v), jnp.asarray(f), grid, jnp.asarray(cot)))
    assert corners.shape == (len(f), dim, dim)
    summed = np.zeros_like(v)
    np.add.at(summed, f.reshape(-1), corners.reshape(-1, dim))
    assert rel_err(summed, reference.voxelize_backward(v, f, grid, cot)) < 1e-10


# ---------------------------------------------------------------------------------------
# Determinism
# ---------------------------------------------------------------------------------------


def _determinism_inputs():
    """Inputs big enough that the kernels split their work into many parallel tasks
    (backward: 64 faces per task; forward and tangent: several column tiles, and a batch)."""
    rng = np.random.default_rng(99)
    m = voxax.data.icosphere(3, radius=0.7)
    v3 = np.stack([jitter(rng, m.vertices, 2e-2) for _ in range(3)])
    g3 = Grid(lower=(-0.8, -0.75, -0.85), upper=(0.8, 0.9, 0.75), shape=(48, 40, 44))
    c3 = rng.normal(size=(3,) + g3.shape)
    p = voxax.data.circle_polyline(400, radius=0.7)
    v2 = np.stack([jitter(rng, p.vertices, 1e-2) for _ in range(3)])
    g2 = Grid.cube((300, 280), dim=2)
    c2 = rng.normal(size=(3,) + g2.shape)
    return [(v3, m.faces, g3, c3), (v2, p.faces, g2, c2)]


def _run_all(inputs):
    out = {}
    for i, (v, f, g, c) in enumerate(inputs):
        for dt in (np.float64, np.float32):
            x = jnp.asarray(v.astype(dt))
            W, vjp = jax.vjp(lambda y, f=f, g=g: voxax.voxelize(y, f, g), x)
            (dv,) = vjp(jnp.asarray(c.astype(dt)))
            corners = voxax.voxelize_corner_gradients(x, jnp.asarray(f), g, jnp.asarray(c.astype(dt)))
            tangent = jnp.asarray(np.cos(np.arange(v.size)).reshape(v.shape).astype(dt))
            _, dW = jax.jvp(lambda y, f=f, g=g: voxax.voxelize(y, f, g), (x,), (tangent,))
            key = f"{i}_{np.dtype(dt).name}"
            out["jvp_" + key] = np.asarray(dW)
            out["W_" + key] = np.asarray(W)
            out["dv_" + key] = np.asarray(dv)
            out["corners_" + key] = np.asarray(corners)
    return out


def test_deterministic_across_runs():
    """Repeated forward and backward runs give identical bits (eagerly and under jit)."""
    inputs = _determinism_inputs()
    first = _run_all(inputs)
    for _ in range(3):
        again = _run_all(inputs)
        for k in first:
            assert np.array_equal(first[k], again[k]), k
    v, f, g, c = inputs[0]
    grad = jax.jit(jax.grad(lambda x: jnp.sum(c * voxax.voxelize(x, f, g))))
    runs = [np.asarray(grad(jnp.asarray(v))) for _ in range(4)]
    for r in runs[1:]:
        assert np.array_equal(runs[0], r)


_SUBPROCESS_DETERMINISM = r"""
import os, sys
import numpy as np
import jax
jax.config.update("jax_enable_x64", True)
sys.path.insert(0, {tests!r})
import test_gradients as t
out = t._run_all(t._determinism_inputs())
# The size of XLA's intra-op pool (the pool the kernels get as ffi::ThreadPool) shows up
# as threads named "tf_XLAEigen".
names = [open(f"/proc/self/task/{{p}}/comm").read().strip() for p in os.listdir("/proc/self/task")]
out["pool_threads"] = np.array(names.count("tf_XLAEigen"))
np.savez({path!r}, **out)
"""


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="reads the thread count from /proc")
def test_deterministic_across_thread_counts(tmp_path):
    """Forward, backward and tangent are bit-for-bit identical whatever the size of XLA's
    CPU thread pool.

    How the pool size is controlled (checked with jax/jaxlib 0.10.2): XLA_FLAGS such as
    `--xla_cpu_multi_thread_eigen=false` and `intra_op_parallelism_threads=1`, and
    `OMP_NUM_THREADS`, do *not* change the intra-op pool that FFI handlers receive
    (`ffi::ThreadPool`). That pool is sized by tsl's `NumSchedulableCPUs`, which honours
    the `NPROC` environment variable (and the CPU affinity mask). So the computation runs
    in subprocesses with `NPROC=1` (the kernels then run serially) and `NPROC=4` (more
    threads than cores on a 2-core machine), and in this process (one thread per core).
    Each subprocess reports its pool size (threads named `tf_XLAEigen`), so the test
    checks that the setting took effect.
    """
    tests_dirs = [str(Path(__file__).resolve().parent), str(Path(__file__).resolve().parents[1])]
    pkg_root = str(Path(voxax.__file__).resolve().parent.parent)
    procs = {}
    for nproc in ("1", "4"):
        env = dict(os.environ)
        env.pop("PJRT_NPROC", None)
        env["NPROC"] = nproc
        env["PYTHONPATH"] = os.pathsep.join([pkg_root, *tests_dirs, env.get("PYTHONPATH", "")])
        path = str(tmp_path / f"nproc{nproc}.npz")
        code = _SUBPROCESS_DETERMINISM.format(tests=tests_dirs[0], path=path)
        proc = subprocess.Popen([sys.executable, "-c", code], env=env, stdout=subprocess.PIPE,
                                stderr=subprocess.PIPE, text=True)
        procs[nproc] = (proc, path)
    # Meanwhile, the same computation in this process.
    here = _run_all(_determinism_inputs())
    results = {}
    for nproc, (proc, path) in procs.items():
        stdout, stderr = proc.communicate(timeout=300)
        assert proc.returncode == 0, f"NPROC={nproc}: exit {proc.returncode}\n{stdout}\n{stderr}"
        with np.load(path) as z:
            results[nproc] = {k: z[k] for k in z.files}
        assert int(results[nproc].pop("pool_threads")) == int(nproc), "NPROC did not set the pool size"
    for nproc, res in results.items():
        assert set(res) == set(here)
        for k in here:
            assert res[k].dtype == here[k].dtype
            assert np.array_equal(res[k], here[k]), f"{k} differs between NPROC={nproc} and this process"
