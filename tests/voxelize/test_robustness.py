"""Robustness: hostile inputs inside jit-compiled loops, recovery, memory, known failures.

The documented errors (see docs/robustness.md) must come out of `jax.lax.fori_loop`,
`scan` and `while_loop` bodies too, where the Python-side checks cannot see the values
and the kernels' own validation has to catch them; afterwards the process keeps working.

The tests under "Edge cases" pin down behaviour at the edges of the input domain (inputs
on grid lines, empty batches, unsigned indices, huge and sliver triangles, extreme cell
sizes), each with the exact expected result.
"""

from __future__ import annotations

import ctypes
import gc
import sys

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from conftest import random_star_mesh

import voxax
from voxax import Grid, _kernels, reference

GRID = Grid.cube(6)


def _box():
    m = voxax.data.box((-0.5, -0.5, -0.5), (0.5, 0.5, 0.5))
    return jnp.asarray(m.vertices), jnp.asarray(m.faces, dtype=jnp.int32)


def _assert_still_works(fn=None):
    """A valid call after an error gives the right answer."""
    v, f = _box()
    W = (fn or (lambda a, b: voxax.voxelize(a, b, GRID)))(v, f)
    assert float(jnp.sum(W)) * GRID.voxel_volume == pytest.approx(1.0, abs=1e-12)


# -- errors from inside jit-compiled loops --------------------------------------------------

BAD_VALUES = [
    (np.nan, "NaN or Inf"),
    (np.inf, "NaN or Inf"),
    (-np.inf, "NaN or Inf"),
    (1e200, "1e75"),
]


def _loop_over_vertices(kind, n_steps=5, bad_step=3):
    """A jitted loop whose carry is the vertices; at step `bad_step` the carry is replaced
    by `bad` (broadcast into one coordinate), and every step voxelizes the carry."""
    v0, f = _box()

    def body(i, carry):
        v, acc, bad = carry
        v = jnp.where(i == bad_step, v.at[2, 1].set(bad), v * 1.01)
        return v, acc + jnp.sum(voxax.voxelize(v, f, GRID)), bad

    if kind == "fori_loop":
        run = lambda v, bad: jax.lax.fori_loop(0, n_steps, body, (v, 0.0, bad))[1]  # noqa: E731
    elif kind == "scan":

        def run(v, bad):
            def step(carry, i):
                return body(i, carry), None

            return jax.lax.scan(step, (v, 0.0, bad), jnp.arange(n_steps))[0][1]

    else:  # while_loop

        def run(v, bad):
            def cond(c):
                return c[0] < n_steps

            def wbody(c):
                i, carry = c
                return i + 1, body(i, carry)

            return jax.lax.while_loop(cond, wbody, (0, (v, 0.0, bad)))[1][1]

    return jax.jit(run), v0


@pytest.mark.parametrize("kind", ["fori_loop", "scan", "while_loop"])
@pytest.mark.parametrize("bad, match", BAD_VALUES)
def test_bad_vertices_inside_jitted_loops(kind, bad, match):
    run, v0 = _loop_over_vertices(kind)
    for _ in range(2):  # the compiled loop raises every time, and stays usable
        with pytest.raises(Exception, match=match) as info:
            jax.block_until_ready(run(v0, bad))
        assert isinstance(info.value, (ValueError, jax.errors.JaxRuntimeError))
    # The same compiled loop with a harmless value (0.3 at step 3) runs to the end.
    total = float(run(v0, 0.3))
    assert np.isfinite(total) and total > 0
    _assert_still_works()


@pytest.mark.parametrize("kind", ["fori_loop", "scan"])
@pytest.mark.parametrize("bad, match", [(8, "out of range"), (10**6, "out of range"), (-1, "out of range"),
                                        (-(2**31), "out of range")])
def test_bad_face_indices_inside_jitted_loops(kind, bad, match):
    v, f0 = _box()

    def body(i, carry):
        f, acc = carry
        f = jnp.where(i == 2, f.at[5, 1].set(bad), f)
        return f, acc + jnp.sum(voxax.voxelize(v, f, GRID))

    if kind == "fori_loop":
        run = jax.jit(lambda f: jax.lax.fori_loop(0, 4, body, (f, 0.0))[1])
    else:
        run = jax.jit(lambda f: jax.lax.scan(lambda c, i: (body(i, c), None), (f, 0.0), jnp.arange(4))[0][1])
    with pytest.raises(Exception, match=match) as info:
        jax.block_until_ready(run(f0))
    assert isinstance(info.value, (ValueError, jax.errors.JaxRuntimeError))
    _assert_still_works()


def test_bad_values_in_the_backward_inside_a_scan():
    """jax.grad of a scan whose body voxelizes: the error surfaces, later calls work."""
    v0, f = _box()
    cot = jnp.asarray(np.random.default_rng(0).normal(size=GRID.shape))

    def loss(v, bad):
        def step(v, i):
            v = jnp.where(i == 2, v.at[0, 0].set(bad), v + 1e-3)
            return v, jnp.sum(cot * voxax.voxelize(v, f, GRID))

        return jnp.sum(jax.lax.scan(step, v, jnp.arange(4))[1])

    grad = jax.jit(jax.grad(loss))
    with pytest.raises(Exception, match="NaN or Inf"):
        jax.block_until_ready(grad(v0, jnp.nan))
    g = grad(v0, 0.1)
    assert bool(jnp.all(jnp.isfinite(g)))


def test_bad_values_in_a_vmapped_loop_name_the_batch_item():
    v0, f = _box()
    vs = jnp.stack([v0, v0, v0.at[4, 2].set(jnp.inf)])

    def body(i, carry):
        v, acc = carry
        return v * 0.99, acc + jnp.sum(voxax.voxelize(v, f, GRID))

    run = jax.jit(jax.vmap(lambda v: jax.lax.fori_loop(0, 3, body, (v, 0.0))[1]))
    with pytest.raises(Exception, match=r"NaN or Inf \(batch item 2"):
        jax.block_until_ready(run(vs))
    assert bool(jnp.all(jnp.isfinite(run(vs[:2]))))


@pytest.mark.parametrize(
    "vdtype, fdtype, match",
    [
        (jnp.float16, jnp.int32, "float32 or float64"),
        (jnp.bfloat16, jnp.int32, "float32 or float64"),
        (jnp.int32, jnp.int32, "float32 or float64"),
        (jnp.complex64, jnp.int32, "float32 or float64"),
        (jnp.float64, jnp.float32, "integer"),
        (jnp.float64, jnp.bool_, "integer"),
    ],
)
def test_wrong_dtypes_inside_jitted_loops(vdtype, fdtype, match):
    v0, f0 = _box()

    def body(i, carry):
        v, acc = carry
        return v, acc + jnp.sum(voxax.voxelize(v, f0.astype(fdtype), GRID)).real.astype(jnp.float64)

    run = jax.jit(lambda v: jax.lax.fori_loop(0, 3, body, (v, 0.0))[1])
    with pytest.raises(TypeError, match=match):
        run(v0.astype(vdtype) if vdtype != jnp.int32 else jnp.round(v0).astype(vdtype))
    _assert_still_works()


def test_many_errors_then_valid_calls():
    """Errors do not leak state: 200 alternating bad and good calls under jit."""
    v, f = _box()
    fn = jax.jit(lambda a, b: voxax.voxelize(a, b, GRID))
    expected = np.asarray(fn(v, f))
    bad_v = v.at[1, 1].set(jnp.nan)
    bad_f = f.at[0, 0].set(100)
    for i in range(100):
        with pytest.raises(Exception, match="NaN or Inf|out of range"):
            jax.block_until_ready(fn(bad_v, f) if i % 2 else fn(v, bad_f))
        np.testing.assert_array_equal(np.asarray(fn(v, f)), expected)


def test_raw_ffi_calls_with_hostile_attributes_raise():
    """Bypassing the Python API, the kernels reject bad grids and shapes with an error."""
    v, f = _box()
    attrs = _kernels.grid_attributes(GRID)
    out = jax.ShapeDtypeStruct(GRID.shape, jnp.float64)
    cases = [
        dict(nx=np.int64(0)),
        dict(nz=np.int64(-3)),
        dict(x0=np.float64(np.nan)),
        dict(y1=np.float64(-np.inf)),
        dict(x1=np.float64(-2.0)),
        dict(nx=np.int64(7)),  # does not match the output shape
        dict(nx=np.int64(2**62)),  # an absurd plane table: rejected, not allocated
    ]
    for over in cases:
        a = dict(attrs, **over)
        with pytest.raises(jax.errors.JaxRuntimeError):
            jax.block_until_ready(jax.ffi.ffi_call(_kernels.FORWARD, out)(v, f, **a))
    _assert_still_works()


# -- memory --------------------------------------------------------------------------------


def _rss_mib() -> float:
    with open("/proc/self/status") as fh:
        for line in fh:
            if line.startswith("VmRSS:"):
                return int(line.split()[1]) / 1024
    raise RuntimeError("no VmRSS")


def _trim():
    gc.collect()
    try:
        ctypes.CDLL("libc.so.6").malloc_trim(0)
    except (OSError, AttributeError):
        pass


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="reads /proc/self/status")
def test_rss_stays_flat_over_repeated_jitted_calls():
    """300 jitted forward+backward calls on varying meshes (3 sizes and grids cycling) do
    not grow the resident memory (see benchmarks/stress.py for 10,000 calls)."""
    rng = np.random.default_rng(0)
    setups = []
    for n, grid in [((6, 5), Grid.cube(16)), ((10, 8), Grid.cube(20)), ((8, 6), Grid((-1, -0.8, -1.2), (1, 0.9, 1), (18, 15, 21)))]:
        v, f = random_star_mesh(rng, n_theta=n[0], n_phi=n[1], scale=0.6)
        cot = jnp.asarray(rng.normal(size=grid.shape))

        def loss(x, f=f, grid=grid, cot=cot):
            return jnp.sum(cot * voxax.voxelize(x, f, grid))

        setups.append((jax.jit(jax.value_and_grad(loss)), v))

    def call(i):
        fn, v = setups[i % len(setups)]
        val, g = fn(v + 0.01 * np.sin(i + np.arange(v.size)).reshape(v.shape))
        return float(val) + float(g[0, 0])

    for i in range(60):  # warm-up: compile and settle the allocators
        call(i)
    _trim()
    start = _rss_mib()
    for i in range(300):
        call(i)
    _trim()
    growth = _rss_mib() - start
    assert growth < 50, f"RSS grew by {growth:.1f} MiB over 300 calls"


# -- Edge cases: exact results at the edges of the input domain -----------------------------


def test_2d_horizontal_edge_on_a_grid_line_is_counted_once():
    """A horizontal segment lying exactly on an interior grid line y = const belongs to
    the top of the pixel below it and to the bottom of the pixel above it; it is counted
    once, so a square whose top and bottom edges are grid lines gives exactly 1 inside
    and 0 outside."""
    grid = Grid.cube(4, dim=2)
    m = voxax.data.polygon_square((-0.5, -0.5), (0.5, 0.5))
    W = np.asarray(voxax.voxelize(m.vertices, m.faces, grid))
    expected = np.zeros((4, 4))
    expected[1:3, 1:3] = 1.0
    np.testing.assert_allclose(W, expected, atol=1e-12)
    np.testing.assert_allclose(W, reference.voxelize(m.vertices, m.faces, grid), atol=1e-12)


def test_2d_single_horizontal_segment_on_a_grid_line_is_counted_once():
    """The minimal case: one segment on the line y = 0 of a 4 x 4 grid on [-1, 1]^2 gives
    1 in every pixel below it."""
    grid = Grid.cube(4, dim=2)
    v = np.array([[0.9, 0.0], [-0.9, 0.0]])
    f = np.array([[0, 1]], dtype=np.int32)
    W = np.asarray(voxax.voxelize(v, f, grid))
    np.testing.assert_allclose(W, reference.voxelize(v, f, grid), atol=1e-12)
    assert W[1, 0] == pytest.approx(1.0)  # column x in [-0.5, 0], fully under the segment


def test_zero_size_faces_batch_gives_an_empty_result_eagerly_and_under_jit():
    """Faces with a zero-size batch axis, (0, F, 3), give an empty (0, *grid.shape)
    result, eagerly and under jit, as vertices (0, V, 3) do (the index range check skips
    empty arrays)."""
    v, f = _box()
    f0 = np.zeros((0,) + f.shape, np.int32)
    W_jit = jax.jit(lambda a, b: voxax.voxelize(a, b, GRID))(v, f0)
    assert W_jit.shape == (0,) + GRID.shape
    W = voxax.voxelize(np.asarray(v), f0, GRID)
    assert W.shape == (0,) + GRID.shape


@pytest.mark.parametrize("jit", [False, True], ids=["eager", "jit"])
def test_uint64_faces_are_accepted(jit):
    """Valid uint64 face indices are accepted like signed ones, eagerly and under jit:
    clamping them to the int32 range keeps every valid index (an unsigned array has no
    -1, so the lower clamp bound must not wrap around to 2**64 - 1)."""
    v, f = _box()
    fn = jax.jit(lambda a, b: voxax.voxelize(a, b, GRID)) if jit else (lambda a, b: voxax.voxelize(a, b, GRID))
    W = fn(v, np.asarray(f).astype(np.uint64))
    assert float(jnp.sum(W)) * GRID.voxel_volume == pytest.approx(1.0)


@pytest.mark.parametrize("L", [1e60, 1e70, 1e74, 4.9e74])
def test_backward_of_huge_triangles_is_exact(L):
    """Coordinates up to 1e75 are accepted (the bound keeps |N|^2 of the unnormalized
    normal, a fourth power of the coordinates, finite), and both the forward and the
    backward handle a huge triangle crossing the grid exactly: the gradient of a
    horizontal triangle through a unit grid does not depend on its size."""
    grid = Grid.cube(2)
    f = np.array([[0, 1, 2]], dtype=np.int32)
    v = np.array([[-L, -L, 0.1], [L, -L, 0.1], [0.0, L, 0.1]])
    W = np.asarray(voxax.voxelize(v, f, grid))
    np.testing.assert_allclose(W[..., 1], 0.1, atol=1e-12)
    np.testing.assert_allclose(W[..., 0], 1.0, atol=1e-12)
    corners = np.asarray(voxax.voxelize_corner_gradients(v, f, grid, np.ones(grid.shape)))[0]
    # sum over corners of dL/dz = (area of the triangle inside the grid) / voxel volume = 4
    assert corners[:, 2].sum() == pytest.approx(4.0, rel=1e-9)


@pytest.mark.parametrize("eps", [1e-6, 1e-8, 1e-10, 1e-12, 0.0])
@pytest.mark.parametrize("dtype", [np.float64, np.float32])
def test_backward_of_sliver_triangles_is_finite_and_exact(eps, dtype):
    """Slivers (one corner `eps` away from the opposite edge) and rounding-collinear
    triangles get finite corner gradients that match the reference. The barycentric map
    uses |N|^2 with N = e1 x e2, and r1 = (e2 x N) / |N|^2, r2 = (N x e1) / |N|^2, which
    stay accurate for slivers (the equivalent |e1|^2 |e2|^2 - (e1 . e2)^2 would cancel
    catastrophically and give NaN)."""
    grid = Grid.cube(4)
    f = np.array([[0, 1, 2], [3, 4, 5]], dtype=np.int32)
    a, b = np.array([-0.9, -0.3, 0.1]), np.array([0.9, -0.3, 0.2])
    v = np.array([a, b, b + [0.0, eps, 0.0],
                  a, b, a + 0.3 * (b - a)])  # a collinear triangle, up to rounding
    v = v.astype(dtype)
    C = np.asarray(voxax.voxelize_corner_gradients(v, f, grid, np.ones(grid.shape, dtype)))
    assert np.all(np.isfinite(C))
    R = reference.voxelize_backward(v.astype(np.float64), f, grid, np.ones(grid.shape))
    dv = np.zeros_like(R)
    np.add.at(dv, f.reshape(-1), C.reshape(-1, 3).astype(np.float64))
    np.testing.assert_allclose(dv, R, atol=1e-12 if dtype == np.float64 else 1e-6)


@pytest.mark.parametrize("scale", [1e-120, 1e-105, 1e105, 1e120])
def test_extreme_cell_sizes_give_finite_exact_results_or_a_clear_error(scale):
    """Grids whose cell volume would under- or overflow double precision (1 / |voxel| is
    needed) are refused by `Grid` with a clear error; all others give exact values."""
    try:
        grid = Grid.cube(2, half_width=scale)
        m = voxax.data.box((-0.75 * scale,) * 3, (0.75 * scale,) * 3)
        W = np.asarray(voxax.voxelize(m.vertices, m.faces, grid))
    except ValueError as err:
        assert "cell volume" in str(err)  # a clear refusal is fine
        return
    np.testing.assert_allclose(W, np.full(grid.shape, 0.75**3), rtol=1e-12)
