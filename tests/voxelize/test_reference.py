"""Checks of the NumPy reference voxelizer against exact, hand-computable answers.

The reference is the oracle the C++ kernels are compared with, so everything here is
checked against quantities derived independently of it: products of 1D overlap lengths for
axis-aligned boxes, the enclosed volume and its gradient, and finite differences.
"""

import numpy as np
import pytest

from voxax import Grid
from voxax.reference import (
    signed_volume,
    volume_gradient,
    voxelize,
    voxelize_backward,
    winding_number_ray,
)

# ---------------------------------------------------------------------------------------
# Meshes built by hand
# ---------------------------------------------------------------------------------------


def box_mesh(lo, hi):
    """An axis-aligned box as 8 vertices and 12 outward-oriented triangles."""
    lo, hi = np.asarray(lo, float), np.asarray(hi, float)
    vertices = np.array([[(hi if (n >> a) & 1 else lo)[a] for a in range(3)] for n in range(8)])
    faces = np.array(
        [
            [0, 2, 1], [1, 2, 3],  # z = lo
            [4, 5, 6], [5, 7, 6],  # z = hi
            [0, 1, 4], [1, 5, 4],  # y = lo
            [2, 6, 3], [3, 6, 7],  # y = hi
            [0, 4, 2], [2, 4, 6],  # x = lo
            [1, 3, 5], [3, 7, 5],  # x = hi
        ]
    )
    return vertices, faces


def box_occupancy(grid, lo, hi):
    """Exact fraction of each cell inside the box: the product of 1D overlap fractions."""
    fractions = []
    for axis in range(grid.dim):
        e = grid.edges(axis)
        overlap = np.clip(np.minimum(e[1:], hi[axis]) - np.maximum(e[:-1], lo[axis]), 0.0, None)
        fractions.append(overlap / np.diff(e))
    out = fractions[0]
    for fr in fractions[1:]:
        out = np.multiply.outer(out, fr)
    return out


def star_mesh(rng, center=(0.0, 0.0, 0.0), radius=0.5, jitter=0.3, subdivide=True):
    """A closed, star-shaped (generally non-convex) triangle mesh, outward-oriented.

    An octahedron, optionally subdivided once (18 vertices, 32 faces), with every vertex
    pushed along its direction by a random factor.
    """
    # Vertex 2 * axis + (0 for +, 1 for -) is the unit vector +-e_axis.
    vertices = np.array([np.eye(3)[a] * s for a in range(3) for s in (1, -1)], float)
    faces = []
    for sx in (0, 1):
        for sy in (0, 1):
            for sz in (0, 1):
                i, j, k = sx, 2 + sy, 4 + sz
                faces.append([i, j, k] if (sx + sy + sz) % 2 == 0 else [i, k, j])
    faces = np.array(faces)
    if subdivide:
        midpoint = {}
        vs = list(vertices)

        def mid(p, q):
            key = (min(p, q), max(p, q))
            if key not in midpoint:
                m = vs[p] + vs[q]
                vs.append(m / np.linalg.norm(m))
                midpoint[key] = len(vs) - 1
            return midpoint[key]

        new_faces = []
        for a, b, c in faces:
            ab, bc, ca = mid(a, b), mid(b, c), mid(c, a)
            new_faces += [[a, ab, ca], [ab, b, bc], [ca, bc, c], [ab, bc, ca]]
        vertices, faces = np.array(vs), np.array(new_faces)
    r = radius * (1.0 + jitter * rng.uniform(-1, 1, size=(len(vertices), 1)))
    return np.asarray(center) + r * vertices, faces


def tetrahedron(rng, scale=0.6, center=(0.0, 0.0, 0.0)):
    """A randomly perturbed regular tetrahedron, outward-oriented."""
    v = np.array([[1, 1, 1], [1, -1, -1], [-1, 1, -1], [-1, -1, 1]], float) / np.sqrt(3)
    v = np.asarray(center) + scale * (v + 0.25 * rng.uniform(-1, 1, size=v.shape))
    f = np.array([[0, 1, 2], [0, 2, 3], [0, 3, 1], [1, 3, 2]])
    if signed_volume(v, f) < 0:
        f = f[:, ::-1]
    return v, f


def polygon(points):
    """A closed polyline through `points` in order, as vertices and segments."""
    v = np.asarray(points, float)
    n = len(v)
    return v, np.stack([np.arange(n), (np.arange(n) + 1) % n], axis=1)


def star_polygon(rng, n=9, center=(0.0, 0.0), radius=0.5, jitter=0.4):
    """A random star-shaped, counter-clockwise polygon."""
    angles = np.sort(rng.uniform(0, 2 * np.pi, n))
    r = radius * (1.0 + jitter * rng.uniform(-1, 1, n))
    return polygon(np.asarray(center) + np.stack([r * np.cos(angles), r * np.sin(angles)], 1))


BOX_LO = np.array([0.1, 0.2, 0.3])
BOX_HI = np.array([0.7, 0.45, 0.9])

GRIDS_3D = [
    Grid.cube(4),
    Grid.cube(5),
    Grid(lower=(-0.3, 0.05, 0.25), upper=(0.95, 0.7, 1.1), shape=(5, 3, 7)),
    Grid(lower=(0.0, 0.0, 0.0), upper=(1.0, 0.5, 2.0), shape=(7, 1, 4)),
    Grid(lower=(0.2, 0.25, 0.4), upper=(0.6, 0.4, 0.8), shape=(3, 2, 3)),  # inside the box
]

# ---------------------------------------------------------------------------------------
# Forward, 3D
# ---------------------------------------------------------------------------------------


@pytest.mark.parametrize("grid", GRIDS_3D, ids=str)
def test_box_gives_exact_fractional_occupancy(grid):
    v, f = box_mesh(BOX_LO, BOX_HI)
    W = voxelize(v, f, grid)
    assert W.shape == grid.shape and W.dtype == np.float64
    np.testing.assert_allclose(W, box_occupancy(grid, BOX_LO, BOX_HI), rtol=0, atol=1e-12)


def test_box_with_faces_on_grid_planes():
    v, f = box_mesh([-0.5] * 3, [0.5] * 3)
    grid = Grid.cube(4)
    expected = np.zeros(grid.shape)
    expected[1:3, 1:3, 1:3] = 1.0
    np.testing.assert_allclose(voxelize(v, f, grid), expected, atol=1e-14)


def test_box_mesh_is_outward():
    v, f = box_mesh(BOX_LO, BOX_HI)
    assert signed_volume(v, f) == pytest.approx(np.prod(BOX_HI - BOX_LO), rel=1e-14)


def test_volume_identity_3d():
    rng = np.random.default_rng(0)
    grid = Grid(lower=(-0.9, -1.0, -0.8), upper=(1.0, 0.85, 0.9), shape=(6, 5, 7))
    for _ in range(3):
        v, f = star_mesh(rng, center=rng.uniform(-0.1, 0.1, 3))
        volume = signed_volume(v, f)
        assert volume > 0
        W = voxelize(v, f, grid)
        assert W.sum() * grid.voxel_volume == pytest.approx(volume, rel=1e-12)
        assert W.min() > -1e-12 and W.max() < 1 + 1e-12


def test_flipped_orientation_negates():
    rng = np.random.default_rng(1)
    v, f = star_mesh(rng)
    grid = Grid.cube(5, half_width=0.8)
    np.testing.assert_allclose(voxelize(v, f[:, ::-1], grid), -voxelize(v, f, grid), atol=1e-14)


def test_overlapping_boxes_add():
    v1, f1 = box_mesh([-0.6, -0.6, -0.6], [0.2, 0.2, 0.2])
    v2, f2 = box_mesh([-0.2, -0.2, -0.2], [0.6, 0.6, 0.6])
    v = np.concatenate([v1, v2])
    f = np.concatenate([f1, f2 + len(v1)])
    grid = Grid.cube(5, half_width=0.75)
    expected = box_occupancy(grid, [-0.6] * 3, [0.2] * 3) + box_occupancy(grid, [-0.2] * 3, [0.6] * 3)
    np.testing.assert_allclose(voxelize(v, f, grid), expected, atol=1e-12)


def test_mesh_partly_outside_matches_larger_grid():
    rng = np.random.default_rng(2)
    v, f = star_mesh(rng, center=(0.3, -0.2, 0.25), radius=0.6)
    # The small grid's planes are a subset of the large grid's (spacing 0.25, exact).
    small = Grid(lower=(-0.5, -0.5, -0.5), upper=(0.5, 0.5, 0.5), shape=(4, 4, 4))
    large = Grid(lower=(-1.5, -1.5, -1.5), upper=(1.5, 1.5, 1.5), shape=(12, 12, 12))
    W_small = voxelize(v, f, small)
    W_large = voxelize(v, f, large)
    np.testing.assert_allclose(W_small, W_large[4:8, 4:8, 4:8], atol=1e-12)
    assert W_large.sum() * large.voxel_volume == pytest.approx(signed_volume(v, f), rel=1e-12)


def test_closed_mesh_outside_grid_gives_zero():
    v, f = box_mesh([-0.5, -0.5, 2.0], [0.5, 0.5, 3.0])  # above the grid
    np.testing.assert_allclose(voxelize(v, f, Grid.cube(3)), 0.0, atol=1e-14)
    v, f = box_mesh([-0.5, -0.5, -3.0], [0.5, 0.5, -2.0])  # below
    np.testing.assert_allclose(voxelize(v, f, Grid.cube(3)), 0.0, atol=1e-14)


def test_open_sheet_above_grid_fills_its_shadow():
    # A horizontal, upward-facing rectangle [x0, x1] x [-5, 5] at z = 7: its shadow
    # column holds +1 everywhere below it.
    x0, x1 = -0.2, 0.6
    v = np.array([[x0, -5, 7], [x1, -5, 7], [x1, 5, 7], [x0, 5, 7]], float)
    f = np.array([[0, 1, 2], [0, 2, 3]])
    grid = Grid.cube(5)
    fx = box_occupancy(grid, [x0, -9, -9], [x1, 9, 9])  # the x-overlap fraction
    np.testing.assert_allclose(voxelize(v, f, grid), fx, atol=1e-12)
    np.testing.assert_allclose(voxelize(v, f[:, ::-1], grid), -fx, atol=1e-12)
    # Below the grid, it contributes nothing.
    v[:, 2] = -7
    np.testing.assert_allclose(voxelize(v, f, grid), 0.0, atol=1e-14)


def test_translation_with_grid_leaves_values_unchanged():
    rng = np.random.default_rng(3)
    v, f = star_mesh(rng, subdivide=False)
    grid = Grid(lower=(-0.75, -0.75, -0.75), upper=(0.75, 0.75, 0.75), shape=(3, 5, 4))
    shift = np.array([0.5, -0.25, 1.0])  # exactly representable
    moved = Grid(lower=tuple(np.add(grid.lower, shift)), upper=tuple(np.add(grid.upper, shift)), shape=grid.shape)
    np.testing.assert_allclose(voxelize(v + shift, f, moved), voxelize(v, f, grid), atol=1e-12)


def test_vertical_and_degenerate_faces_do_nothing():
    v = np.array([[0.125, 0.125, -0.5], [0.375, 0.5, -0.5], [0.25, 0.3125, 0.6], [0.5, 0.5, 0.5]], float)
    f = np.array([[0, 1, 2], [3, 3, 3], [0, 0, 1]])  # vertical, and two degenerate triangles
    np.testing.assert_array_equal(voxelize(v, f, Grid.cube(4)), 0.0)
    np.testing.assert_array_equal(voxelize_backward(v, f[1:], Grid.cube(4), np.ones((4, 4, 4))), 0.0)


def test_winding_number_ray_3d():
    v, f = box_mesh(BOX_LO, BOX_HI)
    rng = np.random.default_rng(4)
    p = rng.uniform(0, 1, size=(500, 3))
    inside = np.all((p > BOX_LO) & (p < BOX_HI), axis=1)
    np.testing.assert_array_equal(winding_number_ray(v, f, p), inside.astype(float))
    # Rays through the shared diagonal edge and the corners of the top/bottom faces.
    q = np.array([[0.4, 0.325, 0.5], [0.1, 0.2, 0.5], [0.7, 0.45, 0.5], [0.1, 0.45, 0.5]])
    assert winding_number_ray(v, f, q[:1]) == 1.0
    assert set(winding_number_ray(v, f, q[1:])) <= {0.0, 1.0}
    np.testing.assert_array_equal(winding_number_ray(v, f[:, ::-1], p), -inside.astype(float))


def test_winding_number_ray_averages_to_voxel_values():
    # The midpoint rule on a fine sub-grid converges to W (a cheap independent check).
    rng = np.random.default_rng(5)
    v, f = star_mesh(rng, subdivide=False)
    grid = Grid.cube(2, half_width=0.8)
    n = 24
    W = voxelize(v, f, grid)
    fine = Grid.cube(2 * n, half_width=0.8).centers().reshape(-1, 3)
    w = winding_number_ray(v, f, fine).reshape(2, n, 2, n, 2, n).mean(axis=(1, 3, 5))
    np.testing.assert_allclose(w, W, atol=0.02)


def test_input_validation():
    v, f = box_mesh(BOX_LO, BOX_HI)
    with pytest.raises(ValueError):
        voxelize(v[:, :2], f, Grid.cube(4))
    with pytest.raises(ValueError):
        voxelize(v, f[:, :2], Grid.cube(4))
    with pytest.raises(ValueError):
        voxelize(v, f + 8, Grid.cube(4))
    with pytest.raises(TypeError):
        voxelize(v, f.astype(float), Grid.cube(4))
    with pytest.raises(ValueError):
        voxelize_backward(v, f, Grid.cube(4), np.ones((4, 4)))
    assert np.all(voxelize(v, np.zeros((0, 3), int), Grid.cube(2)) == 0)


# ---------------------------------------------------------------------------------------
# Forward, 2D
# ---------------------------------------------------------------------------------------


def test_square_2d_exact():
    lo, hi = np.array([-0.35, 0.1]), np.array([0.55, 0.8])
    v, f = polygon([lo, [hi[0], lo[1]], hi, [lo[0], hi[1]]])
    assert signed_volume(v, f) == pytest.approx(np.prod(hi - lo), rel=1e-14)
    for grid in [Grid.cube(4, dim=2), Grid((-0.6, 0.0), (0.7, 1.3), (5, 7)), Grid((-1, -1), (1, 1), (1, 3))]:
        W = voxelize(v, f, grid)
        np.testing.assert_allclose(W, box_occupancy(grid, lo, hi), atol=1e-12)
        np.testing.assert_allclose(voxelize(v, f[:, ::-1], grid), -W, atol=1e-14)


def test_triangle_2d_exact():
    v, f = polygon([[0, 0], [1, 0], [0, 1]])
    grid = Grid((0, 0), (1, 1), (2, 2))
    # [0,.5]^2 lies inside x + y <= 1; the two off-diagonal pixels are cut in half along
    # their diagonal; [.5,1]^2 only touches the triangle at a point.
    np.testing.assert_allclose(voxelize(v, f, grid), [[1.0, 0.5], [0.5, 0.0]], atol=1e-14)
    grid = Grid((-1, -1), (2, 2), (3, 3))
    np.testing.assert_allclose(voxelize(v, f, grid), [[0, 0, 0], [0, 0.5, 0], [0, 0, 0]], atol=1e-14)


def test_area_identity_and_partial_2d():
    rng = np.random.default_rng(6)
    v, f = star_polygon(rng, center=(0.1, -0.05))
    area = signed_volume(v, f)
    assert area > 0
    grid = Grid((-0.9, -0.85), (0.8, 0.95), (7, 6))
    W = voxelize(v, f, grid)
    assert W.sum() * grid.voxel_volume == pytest.approx(area, rel=1e-12)
    small = Grid((-0.5, -0.25), (0.25, 0.5), (3, 3))  # spacing .25, cuts through the polygon
    large = Grid((-1.0, -1.0), (1.0, 1.0), (8, 8))
    np.testing.assert_allclose(voxelize(v, f, small), voxelize(v, f, large)[2:5, 3:6], atol=1e-12)


def test_winding_number_ray_2d():
    v, f = polygon([[0, 0], [1, 0], [0, 1]])
    p = np.array([[0.2, 0.2], [0.8, 0.8], [0.0, 0.5], [0.5, -0.1], [-0.1, 0.2]])
    np.testing.assert_array_equal(winding_number_ray(v, f, p), [1, 0, 1, 0, 0])


# ---------------------------------------------------------------------------------------
# Backward
# ---------------------------------------------------------------------------------------


def _volume_gradient_via_backward(v, f, grid):
    return voxelize_backward(v, f, grid, np.full(grid.shape, grid.voxel_volume))


@pytest.mark.parametrize("subdivide", [False, True])
def test_backward_gives_volume_gradient_3d(subdivide):
    rng = np.random.default_rng(7)
    v, f = star_mesh(rng, subdivide=subdivide)
    grid = Grid(lower=(-0.9, -1.0, -0.8), upper=(1.0, 0.85, 0.9), shape=(5, 4, 6))
    expected = volume_gradient(v, f)
    got = _volume_gradient_via_backward(v, f, grid)
    np.testing.assert_allclose(got, expected, rtol=0, atol=1e-10 * np.abs(expected).max())


def test_backward_volume_gradient_with_faces_on_grid_planes():
    # Faces lying exactly in grid planes must be counted once (half-open cells).
    for lo, hi in [([-0.5] * 3, [0.5] * 3), ([-1.0] * 3, [1.0] * 3), ([0.0] * 3, [0.5, 1.0, 0.25])]:
        v, f = box_mesh(lo, hi)
        got = _volume_gradient_via_backward(v, f, Grid.cube(4))
        np.testing.assert_allclose(got, volume_gradient(v, f), atol=1e-14)


def test_volume_gradient_matches_finite_differences():
    rng = np.random.default_rng(8)
    for v, f in [star_mesh(rng), polygon(rng.uniform(-1, 1, (5, 2)))]:
        h = 1e-6
        fd = np.zeros_like(v)
        for idx in np.ndindex(*v.shape):
            vp, vm = v.copy(), v.copy()
            vp[idx] += h
            vm[idx] -= h
            fd[idx] = (signed_volume(vp, f) - signed_volume(vm, f)) / (2 * h)
        np.testing.assert_allclose(volume_gradient(v, f), fd, atol=1e-8)


def test_backward_gives_volume_gradient_2d():
    rng = np.random.default_rng(9)
    v, f = star_polygon(rng)
    grid = Grid((-0.9, -0.85), (0.8, 0.95), (7, 6))
    expected = volume_gradient(v, f)
    got = _volume_gradient_via_backward(v, f, grid)
    np.testing.assert_allclose(got, expected, rtol=0, atol=1e-10 * np.abs(expected).max())
    # A square on the grid lines.
    v, f = polygon([[-0.5, -0.5], [0.5, -0.5], [0.5, 0.5], [-0.5, 0.5]])
    got = _volume_gradient_via_backward(v, f, Grid.cube(4, dim=2))
    np.testing.assert_allclose(got, volume_gradient(v, f), atol=1e-14)


def _finite_differences(v, f, grid, g, h=1e-6):
    fd = np.zeros_like(v)
    for idx in np.ndindex(*v.shape):
        vp, vm = v.copy(), v.copy()
        vp[idx] += h
        vm[idx] -= h
        fd[idx] = (np.sum(g * voxelize(vp, f, grid)) - np.sum(g * voxelize(vm, f, grid))) / (2 * h)
    return fd


def _assert_gradients_close(got, fd, rel=1e-6):
    scale = np.abs(fd).max()
    assert scale > 0
    np.testing.assert_allclose(got, fd, rtol=0, atol=rel * scale)


@pytest.mark.parametrize("seed", [0, 1])
def test_backward_matches_finite_differences_3d(seed):
    rng = np.random.default_rng(100 + seed)
    # Anisotropic grid; the tetrahedron sticks out of it on some sides.
    grid = Grid(lower=(-0.6, -0.5, -0.55), upper=(0.5, 0.6, 0.45), shape=(5, 4, 6))
    v, f = tetrahedron(rng, scale=0.65, center=rng.uniform(-0.1, 0.1, 3))
    g = rng.normal(size=grid.shape)
    _assert_gradients_close(voxelize_backward(v, f, grid, g), _finite_differences(v, f, grid, g))


def test_backward_matches_finite_differences_3d_nonconvex():
    rng = np.random.default_rng(200)
    grid = Grid(lower=(-0.7, -0.6, -0.5), upper=(0.6, 0.5, 0.7), shape=(4, 5, 3))
    v, f = star_mesh(rng, radius=0.55, jitter=0.4, subdivide=False)
    g = rng.normal(size=grid.shape)
    _assert_gradients_close(voxelize_backward(v, f, grid, g), _finite_differences(v, f, grid, g))


@pytest.mark.parametrize("seed", [0, 1])
def test_backward_matches_finite_differences_2d(seed):
    rng = np.random.default_rng(300 + seed)
    grid = Grid((-0.6, -0.55), (0.55, 0.6), (5, 6))
    v, f = star_polygon(rng, n=7, radius=0.55)
    g = rng.normal(size=grid.shape)
    _assert_gradients_close(voxelize_backward(v, f, grid, g), _finite_differences(v, f, grid, g))
