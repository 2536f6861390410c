"""The forward voxelization kernel: against the reference, exact identities, validation."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from conftest import random_polygon, random_star_mesh

import voxax
from voxax import Grid, reference

TOL = {np.float64: 1e-10, np.float32: 1e-5}


def box_mesh(lo, hi):
    m = voxax.data.box(lo, hi)
    return np.asarray(m.vertices), np.asarray(m.faces)


def overlap_fraction(edges, lo, hi):
    return np.clip(np.minimum(edges[1:], hi) - np.maximum(edges[:-1], lo), 0, None) / np.diff(edges)


def exact_box_occupancy(grid, lo, hi):
    out = 1.0
    for a in range(grid.dim):
        frac = overlap_fraction(grid.edges(a), lo[a], hi[a])
        shape = [1] * grid.dim
        shape[a] = -1
        out = out * frac.reshape(shape)
    return out


def random_grid(rng, dim=3):
    lower = rng.uniform(-0.9, -0.5, dim)
    upper = lower + rng.uniform(1.0, 1.6, dim)
    shape = tuple(int(s) for s in rng.integers(3, 12, dim))
    return Grid(tuple(lower), tuple(upper), shape)


# -- agreement with the independent reference --------------------------------------------


@pytest.mark.parametrize("dtype", [np.float64, np.float32])
@pytest.mark.parametrize("seed", range(6))
def test_matches_reference_3d(seed, dtype):
    rng = np.random.default_rng(seed)
    grid = random_grid(rng)
    # Random centres: some meshes straddle the grid boundary, some stick out of it.
    center = rng.uniform(-0.6, 0.6, 3)
    v, f = random_star_mesh(rng, center=center, scale=rng.uniform(0.3, 0.8))
    v = v.astype(dtype)
    W = np.asarray(voxax.voxelize(v, f, grid))
    assert W.dtype == dtype
    expected = reference.voxelize(v.astype(np.float64), f, grid)
    assert np.max(np.abs(W - expected)) <= TOL[dtype]


@pytest.mark.parametrize("dtype", [np.float64, np.float32])
@pytest.mark.parametrize("seed", range(6))
def test_matches_reference_2d(seed, dtype):
    rng = np.random.default_rng(100 + seed)
    grid = random_grid(rng, dim=2)
    v, f = random_polygon(rng, n=11, center=rng.uniform(-0.6, 0.6, 2), scale=rng.uniform(0.3, 0.8))
    v = v.astype(dtype)
    W = np.asarray(voxax.voxelize(v, f, grid))
    expected = reference.voxelize(v.astype(np.float64), f, grid)
    assert np.max(np.abs(W - expected)) <= TOL[dtype]


@pytest.mark.parametrize("name", ["torus", "bent_bar", "with_inverted_component", "hand"])
def test_demo_meshes_match_reference(name):
    mesh = voxax.data.get(name)
    grid = Grid((-0.9, -0.85, -0.8), (0.85, 0.9, 0.7), (9, 8, 7))
    W = np.asarray(voxax.voxelize(mesh.vertices, mesh.faces, grid))
    expected = reference.voxelize(mesh.vertices, mesh.faces, grid)
    assert np.max(np.abs(W - expected)) <= 1e-10


def test_triangle_soup_matches_reference(rng):
    # Random, unrelated triangles (not a closed mesh): the kernel and the reference
    # must still agree on the +z shadow count, including triangles above the grid.
    v = rng.uniform(-1.5, 1.5, (60, 3))
    f = np.arange(60, dtype=np.int32).reshape(20, 3)
    grid = Grid((-1, -1, -1), (1, 1, 1), (6, 7, 5))
    W = np.asarray(voxax.voxelize(v, f, grid))
    assert np.max(np.abs(W - reference.voxelize(v, f, grid))) <= 1e-10


# -- exact identities --------------------------------------------------------------------


@pytest.mark.parametrize("n", [8, 31, 32, 33])
def test_volume_identity(n):
    rng = np.random.default_rng(n)
    v, f = random_star_mesh(rng, n_theta=10, n_phi=8, scale=0.7)
    grid = Grid.cube(n)
    W = np.asarray(voxax.voxelize(v, f, grid))
    vol = reference.signed_volume(v, f)
    assert abs(W.sum() * grid.voxel_volume - vol) <= 1e-10 * abs(vol)


@pytest.mark.parametrize("shape", [(31, 33, 17), (5, 40, 9)])
def test_volume_identity_anisotropic(shape):
    mesh = voxax.data.torus()
    grid = Grid((-0.95, -0.9, -0.4), (0.9, 0.97, 0.3), shape)
    W = np.asarray(voxax.voxelize(mesh.vertices, mesh.faces, grid))
    vol = mesh.signed_volume()
    assert abs(W.sum() * grid.voxel_volume - vol) <= 1e-10 * abs(vol)


@pytest.mark.parametrize("n", [5, 33])
def test_volume_identity_2d(n):
    v, f = random_polygon(np.random.default_rng(n), n=15)
    grid = Grid.cube(n, dim=2)
    W = np.asarray(voxax.voxelize(v, f, grid))
    area = reference.signed_volume(v, f)
    assert abs(W.sum() * grid.voxel_volume - area) <= 1e-10 * abs(area)


@pytest.mark.parametrize(
    "grid",
    [Grid.cube(4), Grid.cube(7), Grid((-0.2, 0.0, 0.25), (1.1, 0.5, 1.0), (5, 3, 9)), Grid((0.3, 0.3, 0.4), (0.5, 0.4, 0.8), (3, 2, 5))],
)
def test_axis_aligned_box_exact_occupancy(grid):
    lo, hi = (0.1, 0.2, 0.3), (0.7, 0.45, 0.9)
    v, f = box_mesh(lo, hi)
    W = np.asarray(voxax.voxelize(v, f, grid))
    np.testing.assert_allclose(W, exact_box_occupancy(grid, lo, hi), rtol=0, atol=1e-13)


def test_axis_aligned_square_exact_occupancy_2d():
    v = np.array([[0.1, 0.2], [0.7, 0.2], [0.7, 0.45], [0.1, 0.45]])
    f = np.array([[0, 1], [1, 2], [2, 3], [3, 0]])
    for grid in [Grid.cube(5, dim=2), Grid((-0.3, 0.1), (0.8, 0.6), (7, 4))]:
        W = np.asarray(voxax.voxelize(v, f, grid))
        np.testing.assert_allclose(W, exact_box_occupancy(grid, (0.1, 0.2), (0.7, 0.45)), rtol=0, atol=1e-13)


def test_box_on_grid_planes_is_exact():
    grid = Grid.cube(8)  # planes at multiples of 0.25
    v, f = box_mesh((-0.5, -0.25, 0.0), (0.5, 0.75, 0.5))
    W = np.asarray(voxax.voxelize(v, f, grid))
    expected = exact_box_occupancy(grid, (-0.5, -0.25, 0.0), (0.5, 0.75, 0.5))
    assert set(np.unique(expected)) == {0.0, 1.0}
    np.testing.assert_array_equal(W, expected)


def test_overlapping_cubes_give_two():
    v1, f1 = box_mesh((-0.5, -0.5, -0.5), (0.25, 0.25, 0.25))
    v2, f2 = box_mesh((-0.25, -0.25, -0.25), (0.5, 0.5, 0.5))
    v = np.concatenate([v1, v2])
    f = np.concatenate([f1, f2 + len(v1)])
    grid = Grid.cube(8)
    W = np.asarray(voxax.voxelize(v, f, grid))
    expected = exact_box_occupancy(grid, (-0.5,) * 3, (0.25,) * 3) + exact_box_occupancy(grid, (-0.25,) * 3, (0.5,) * 3)
    np.testing.assert_allclose(W, expected, atol=1e-13)
    assert W.max() == 2.0
    assert np.all(W[3:5, 3:5, 3:5] == 2.0)


def test_self_intersecting_and_inverted_demo_meshes():
    grid = Grid.cube(32)
    bar = voxax.data.bent_bar()
    W = np.asarray(voxax.voxelize(bar.vertices, bar.faces, grid))
    assert W.max() > 1.5  # the overlap of the bar's ends
    inv = voxax.data.with_inverted_component()
    W = np.asarray(voxax.voxelize(inv.vertices, inv.faces, grid))
    assert W.min() < -0.9 and W.max() > 0.9


def test_flipped_mesh_negates(rng):
    v, f = random_star_mesh(rng)
    grid = Grid.cube(9)
    W = np.asarray(voxax.voxelize(v, f, grid))
    Wf = np.asarray(voxax.voxelize(v, f[:, ::-1], grid))
    np.testing.assert_allclose(Wf, -W, atol=1e-14)
    v2, f2 = random_polygon(rng)
    g2 = Grid.cube(9, dim=2)
    np.testing.assert_allclose(voxax.voxelize(v2, f2[:, ::-1], g2), -voxax.voxelize(v2, f2, g2), atol=1e-14)


def test_translation_with_grid_is_invariant(rng):
    v, f = random_star_mesh(rng, scale=0.6)
    grid = Grid((-1.0, -0.8, -0.9), (0.9, 1.0, 0.8), (7, 9, 8))
    shift = np.array([2.5, -1.25, 0.75])  # exactly representable: planes move exactly
    moved = Grid(tuple(np.add(grid.lower, shift)), tuple(np.add(grid.upper, shift)), grid.shape)
    W = np.asarray(voxax.voxelize(v, f, grid))
    Wm = np.asarray(voxax.voxelize(v + shift, f, moved))
    np.testing.assert_allclose(Wm, W, atol=1e-12)


def test_mesh_above_footprint_outside_grid_gives_zeros():
    # Entirely above the grid and outside its xy footprint: no shadow falls on it.
    v, f = box_mesh((1.5, 1.5, 2.0), (2.0, 2.5, 3.0))
    W = np.asarray(voxax.voxelize(v, f, Grid.cube(6)))
    assert np.all(W == 0.0)
    # Directly above the grid: a closed mesh still gives zeros (its shadows cancel).
    v, f = box_mesh((-0.5, -0.5, 2.0), (0.5, 0.5, 3.0))
    assert np.all(np.asarray(voxax.voxelize(v, f, Grid.cube(6))) == 0.0)
    # Below the grid.
    v, f = box_mesh((-0.5, -0.5, -3.0), (0.5, 0.5, -2.0))
    assert np.all(np.asarray(voxax.voxelize(v, f, Grid.cube(6))) == 0.0)


@pytest.mark.parametrize("seed", range(3))
def test_partly_outside_matches_containing_grid(seed):
    rng = np.random.default_rng(seed)
    v, f = random_star_mesh(rng, n_theta=8, n_phi=6, scale=0.8)
    big = Grid.cube(16)  # contains the mesh
    W = np.asarray(voxax.voxelize(v, f, big))
    # Sub-grids sharing the big grid's planes, cutting through the mesh on every side.
    for (i0, i1), (j0, j1), (k0, k1) in [((3, 9), (5, 13), (2, 11)), ((8, 16), (0, 7), (9, 16)), ((6, 10), (6, 10), (0, 5))]:
        e = [big.edges(a) for a in range(3)]
        sub = Grid((e[0][i0], e[1][j0], e[2][k0]), (e[0][i1], e[1][j1], e[2][k1]), (i1 - i0, j1 - j0, k1 - k0))
        Ws = np.asarray(voxax.voxelize(v, f, sub))
        np.testing.assert_allclose(Ws, W[i0:i1, j0:j1, k0:k1], atol=1e-12)


def test_partly_outside_matches_containing_grid_2d(rng):
    v, f = random_polygon(rng, n=13, scale=0.8)
    big = Grid.cube(16, dim=2)
    W = np.asarray(voxax.voxelize(v, f, big))
    e = [big.edges(a) for a in range(2)]
    sub = Grid((e[0][9], e[1][2]), (e[0][16], e[1][8]), (7, 6))
    np.testing.assert_allclose(voxax.voxelize(v, f, sub), W[9:16, 2:8], atol=1e-12)


@pytest.mark.parametrize("name, expected_values", [("torus", {0, 1}), ("overlapping_cubes", {0, 1, 2}), ("with_inverted_component", {-1, 0, 1})])
def test_fine_grid_centres_match_winding_number(name, expected_values):
    from scipy.ndimage import maximum_filter, minimum_filter

    mesh = voxax.data.get(name)
    grid = Grid.cube(30 if name == "overlapping_cubes" else 23)
    W = np.asarray(voxax.voxelize(mesh.vertices, mesh.faces, grid))
    centres = grid.centers().reshape(-1, 3)
    w = reference.winding_number_ray(mesh.vertices, mesh.faces, centres).reshape(grid.shape)
    # Far from the surface (every neighbour has the same winding number) W is exact.
    uniform = maximum_filter(w, size=3, mode="nearest") == minimum_filter(w, size=3, mode="nearest")
    assert uniform.sum() > 0.5 * w.size
    assert np.max(np.abs(W[uniform] - w[uniform])) < 1e-10
    assert set(np.unique(w[uniform]).round().astype(int)) == expected_values


def test_fine_grid_centres_match_winding_number_2d():
    mesh = voxax.data.overlapping_squares()
    grid = Grid.cube(64, dim=2)
    W = np.asarray(voxax.voxelize(mesh.vertices, mesh.faces, grid))
    w = reference.winding_number_ray(mesh.vertices, mesh.faces, grid.centers().reshape(-1, 2)).reshape(grid.shape)
    from scipy.ndimage import maximum_filter, minimum_filter

    uniform = maximum_filter(w, size=3, mode="nearest") == minimum_filter(w, size=3, mode="nearest")
    assert np.max(np.abs(W[uniform] - w[uniform])) < 1e-12
    assert w.max() == 2


def test_degenerate_faces_contribute_nothing(rng):
    v, f = random_star_mesh(rng)
    grid = Grid.cube(8)
    pad = np.array([[0, 0, 0], [1, 1, 2], [3, 3, 3]], dtype=np.int32)
    W = np.asarray(voxax.voxelize(v, f, grid))
    Wp = np.asarray(voxax.voxelize(v, np.concatenate([f, pad]), grid))
    np.testing.assert_array_equal(W, Wp)


def test_single_cell_and_thin_grids(rng):
    v, f = random_star_mesh(rng, scale=0.6)
    for grid in [Grid((-1, -1, -1), (1, 1, 1), (1, 1, 1)), Grid((-1, -1, -1), (1, 1, 1), (1, 40, 1)), Grid((-1, -0.01, -1), (1, 0.01, 1), (9, 1, 9))]:
        W = np.asarray(voxax.voxelize(v, f, grid))
        np.testing.assert_allclose(W, reference.voxelize(v, f, grid), atol=1e-10)


# -- determinism -------------------------------------------------------------------------

def test_bitwise_deterministic_across_runs():
    """Repeated runs give the same bits (thread counts: test_gradients.py, which also
    checks that the pool size really changed)."""
    mesh = voxax.data.get("hand")
    grid = voxax.Grid.cube(40)
    runs = [np.asarray(voxax.voxelize(mesh.vertices, mesh.faces, grid)).tobytes() for _ in range(3)]
    assert runs[0] == runs[1] == runs[2]


# -- validation --------------------------------------------------------------------------


def _mesh():
    return box_mesh((-0.5, -0.5, -0.5), (0.5, 0.5, 0.5))


@pytest.mark.parametrize("jit", [False, True], ids=["eager", "jit"])
@pytest.mark.parametrize(
    "case, exc, match",
    [
        ("int_vertices", TypeError, "float32 or float64"),
        ("float16_vertices", TypeError, "float32 or float64"),
        ("float_faces", TypeError, "integer"),
        ("vertices_rank", ValueError, r"\(\.\.\., V, 3\)"),
        ("vertices_dim", ValueError, r"\(\.\.\., V, 3\)"),
        ("faces_dim", ValueError, "triangles"),
        ("empty_faces", ValueError, "empty mesh"),
        ("empty_vertices", ValueError, "empty mesh"),
        ("batch_mismatch", ValueError, "broadcast"),
        ("bad_grid", TypeError, "voxax.Grid"),
        ("huge_grid", MemoryError, "memory"),
    ],
)
def test_static_validation(case, exc, match, jit):
    v, f = _mesh()
    grid = Grid.cube(4)
    if case == "int_vertices":
        v = v.astype(np.int64)
    elif case == "float16_vertices":
        v = v.astype(np.float16)
    elif case == "float_faces":
        f = f.astype(np.float64)
    elif case == "vertices_rank":
        v = v.reshape(-1)
    elif case == "vertices_dim":
        v = v[:, :2]
    elif case == "faces_dim":
        f = f[:, :2]
    elif case == "empty_faces":
        f = f[:0]
    elif case == "empty_vertices":
        v, f = v[:0], f[:0]
    elif case == "batch_mismatch":
        v = np.stack([v, v, v])
        f = np.stack([f, f])
    elif case == "bad_grid":
        grid = (4, 4, 4)
    elif case == "huge_grid":
        grid = Grid.cube(40000)
    fn = (lambda a, b: voxax.voxelize(a, b, grid))
    if jit:
        fn = jax.jit(fn)
    with pytest.raises(exc, match=match):
        jax.block_until_ready(fn(v, f))


def _value_case(case):
    v, f = _mesh()
    v = v.copy()
    f = f.copy()
    if case == "nan":
        v[3, 1] = np.nan
    elif case == "inf":
        v[5, 2] = -np.inf
    elif case == "huge":
        v[0, 0] = 1e200
    elif case == "index_high":
        f[4, 2] = len(v)
    elif case == "index_negative":
        f[7, 0] = -1
    return v, f


VALUE_CASES = [
    ("nan", "NaN or Inf"),
    ("inf", "NaN or Inf"),
    ("huge", "1e75"),
    ("index_high", "out of range"),
    ("index_negative", "(negative|out of range)"),
]


@pytest.mark.parametrize("case, match", VALUE_CASES)
def test_value_validation_eager(case, match):
    v, f = _value_case(case)
    with pytest.raises(ValueError, match=match):
        voxax.voxelize(v, f, Grid.cube(4))


@pytest.mark.parametrize("case, match", VALUE_CASES)
def test_value_validation_under_jit_and_recovery(case, match):
    v, f = _value_case(case)
    grid = Grid.cube(4)
    fn = jax.jit(lambda a, b: voxax.voxelize(a, b, grid))
    # Twice: the first call compiles, the second goes through the cached dispatch.
    for _ in range(2):
        with pytest.raises(Exception, match=match) as info:
            jax.block_until_ready(fn(jnp.asarray(v), jnp.asarray(f, dtype=jnp.int32)))
        assert isinstance(info.value, (ValueError, jax.errors.JaxRuntimeError))
    good_v, good_f = _mesh()
    W = fn(jnp.asarray(good_v), jnp.asarray(good_f, dtype=jnp.int32))
    assert float(W.sum()) == pytest.approx(1.0 / Grid.cube(4).voxel_volume)


def test_value_validation_in_gradient_under_jit():
    v, f = _value_case("index_high")
    grid = Grid.cube(4)
    fn = jax.jit(jax.grad(lambda a, b: voxax.voxelize(a, b, grid).sum()))
    with pytest.raises(Exception, match="out of range"):
        jax.block_until_ready(fn(jnp.asarray(v), jnp.asarray(f, dtype=jnp.int32)))


def test_int64_faces_beyond_int32_are_rejected_under_jit():
    v, f = _mesh()
    f = f.astype(np.int64)
    f[0, 0] = 2**33  # would wrap to 0 if cast carelessly
    with pytest.raises(ValueError, match="out of range"):
        voxax.voxelize(v, f, Grid.cube(4))
    fn = jax.jit(lambda a, b: voxax.voxelize(a, b, Grid.cube(4)))
    with pytest.raises(Exception, match="out of range"):
        jax.block_until_ready(fn(jnp.asarray(v), jnp.asarray(f)))


def test_grid_validation():
    with pytest.raises(ValueError, match="upper > lower"):
        Grid((0, 0, 0), (1, -1, 1), (2, 2, 2))
    with pytest.raises(ValueError, match=">= 1"):
        Grid((0, 0, 0), (1, 1, 1), (2, 0, 2))
    with pytest.raises(ValueError, match="finite"):
        Grid((0, 0, np.nan), (1, 1, 1), (2, 2, 2))
    with pytest.raises(TypeError, match="integers"):
        Grid((0, 0, 0), (1, 1, 1), (2.5, 2, 2))
    with pytest.raises(ValueError, match="same length"):
        Grid((0, 0), (1, 1, 1), (2, 2, 2))
