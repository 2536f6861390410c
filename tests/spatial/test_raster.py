"""Line crossings (dexels) against independent oracles: the BVH's watertight ray test,
generalised winding numbers, exact point-triangle distances and analytic tie cases."""

import jax
import numpy as np
import pytest
import trimesh

import voxax


def _grid_off_centre():
    # Odd, anisotropic and off-centre, so no line passes through a vertex of the demo meshes.
    return voxax.Grid(lower=(-1.03, -0.97, -1.01), upper=(1.05, 0.99, 1.02), shape=(25, 21, 23))


@pytest.fixture(scope="module")
def meshes():
    return {"torus": voxax.data.torus(), "hand": voxax.data.hand(), "bent_bar": voxax.data.bent_bar()}


@pytest.mark.parametrize("name", ["torus", "hand", "bent_bar"])
@pytest.mark.parametrize("axis", [0, 1, 2])
def test_matches_bvh_ray_hits(meshes, name, axis):
    mesh = meshes[name]
    grid = _grid_off_centre()
    d = voxax.raster.line_crossings(mesh, grid, axis)
    # The same lines as rays from far below, by the BVH's watertight ray-triangle test.
    p = d.points()
    origins = np.zeros((np.prod(d.shape), 3))
    others = [a for a in range(3) if a != axis]
    c0, c1 = np.meshgrid(*d.line_coords, indexing="ij")
    origins[:, others[0]], origins[:, others[1]] = c0.ravel(), c1.ravel()
    origins[:, axis] = -10.0
    direction = np.zeros(3)
    direction[axis] = 1.0
    hits = voxax.all_hits(mesh, origins, np.broadcast_to(direction, origins.shape))
    np.testing.assert_array_equal(np.diff(hits.offsets), np.diff(d.offsets))
    assert len(d.depth) > 100
    np.testing.assert_array_equal(hits.face, d.face)
    np.testing.assert_array_equal(hits.sign, d.sign)
    np.testing.assert_allclose(hits.t - 10.0, d.depth, rtol=0, atol=1e-12)
    # Every crossing lies on its face: exact point-triangle distance.
    cp = voxax.closest_points(mesh, p)
    assert cp.distance.max() <= 1e-12
    # Closed meshes: balanced along every line.
    assert not np.bincount(d.line_index(), weights=d.sign).any()


@pytest.mark.parametrize("name", ["torus", "hand"])
def test_winding_between_crossings(meshes, name):
    """-cumsum(sign) along a line is the generalised winding number there."""
    mesh = meshes[name]
    d = voxax.raster.line_crossings(mesh, _grid_off_centre(), 2, lines="nodes")
    p = d.points()
    line = d.line_index()
    same = line[1:] == line[:-1]
    gaps = np.flatnonzero(same & (d.depth[1:] - d.depth[:-1] > 1e-6))
    mid = 0.5 * (p[gaps] + p[gaps + 1])
    w = np.asarray(voxax.winding_number(mesh, mid))
    np.testing.assert_allclose(w, d.winding()[gaps], atol=1e-6)
    assert len(gaps) > 100 and d.winding().min() >= 0


def test_ties_on_edges_and_vertices():
    """A cube whose faces, edges and corners lie on grid lines: the perturbed line through
    (b + d, c + d^2) is inside the square (-1, 1)^2 exactly when b, c are in {-1, 0}."""
    v = np.array([[x, y, z] for x in (-1.0, 1.0) for y in (-1.0, 1.0) for z in (-1.0, 1.0)])
    hull = trimesh.convex.convex_hull(v)  # triangulated faces with diagonals through (0, 0)
    grid = voxax.Grid.cube(2)  # nodes at -1, 0, 1
    for axis in range(3):
        d = voxax.raster.line_crossings(np.asarray(hull.vertices), np.asarray(hull.faces), grid, axis, lines="nodes")
        counts = d.counts()
        expected = np.zeros((3, 3), int)
        expected[:2, :2] = 2
        np.testing.assert_array_equal(counts, expected)
        assert (d.sign.reshape(-1, 2) == [-1, 1]).all()
        np.testing.assert_array_equal(d.depth.reshape(-1, 2), np.tile([-1.0, 1.0], (4, 1)))


def test_open_and_degenerate():
    v = np.array([[0.0, 0.0, 0.5], [1.0, 0.0, 0.5], [0.0, 1.0, 0.5], [0.3, 0.3, 0.0], [0.3, 0.3, 1.0]])
    f = np.array([[0, 1, 2], [3, 4, 4], [0, 0, 0]])  # a triangle, a segment and a point
    d = voxax.raster.line_crossings(v, f, voxax.Grid(lower=(0, 0, 0), upper=(1, 1, 1), shape=(4, 4, 4)), 2)
    # Centres at 0.125 + 0.25 k: inside x + y < 1 for the 6 lines with i + j <= 2.
    i, j = np.meshgrid(range(4), range(4), indexing="ij")
    np.testing.assert_array_equal(d.counts(), i + j <= 2)
    assert d.counts().sum() == 6 and set(d.face) == {0} and (d.sign == 1).all()
    np.testing.assert_array_equal(d.depth, 0.5)
    empty = voxax.raster.line_crossings(np.zeros((0, 3)), np.zeros((0, 3), int), voxax.Grid.cube(3), 1)
    assert len(empty.depth) == 0 and empty.offsets.shape == (10,) and not empty.offsets.any()


def test_deterministic_across_threads(meshes):
    grid = voxax.Grid.around(meshes["hand"], 40)
    a = voxax.raster.line_crossings(meshes["hand"], grid, 0, threads=1)
    b = voxax.raster.line_crossings(meshes["hand"], grid, 0, threads=2)
    for x, y in zip(a[3:], b[3:]):
        assert x.tobytes() == y.tobytes()


def test_custom_lines_and_points():
    mesh = voxax.data.icosphere(3)
    d = voxax.raster.line_crossings(mesh, voxax.Grid.cube(4), 1, lines=([0.01, 0.2], [-0.3]))
    assert d.lines == "custom" and d.shape == (2, 1)
    p = d.points()
    np.testing.assert_array_equal(p[:, 0], np.repeat([0.01, 0.2], 2))
    np.testing.assert_array_equal(p[:, 2], -0.3)
    assert (p[0::2, 1] < 0).all() and (p[1::2, 1] > 0).all()


@pytest.mark.parametrize(
    "args, kwargs, error, match",
    [
        ((voxax.Grid.cube(4), 3), {}, ValueError, "axis"),
        ((voxax.Grid.cube(4), None), {}, TypeError, "axis"),
        ((voxax.Grid.cube(4, dim=2), 0), {}, ValueError, "3D"),
        ((voxax.Grid.cube(4), 0), {"lines": "corners"}, ValueError, "lines"),
        ((voxax.Grid.cube(4), 0), {"lines": ([0.0, 0.0], [1.0])}, ValueError, "increasing"),
        ((voxax.Grid.cube(4), 0), {"threads": 0}, ValueError, "threads"),
    ],
)
def test_bad_arguments(args, kwargs, error, match):
    with pytest.raises(error, match=match):
        voxax.raster.line_crossings(voxax.data.icosphere(1), *args, **kwargs)


def test_bad_meshes():
    g = voxax.Grid.cube(4)
    v = np.asarray(voxax.data.icosphere(1).vertices).copy()
    f = np.asarray(voxax.data.icosphere(1).faces)
    with pytest.raises(ValueError, match="out of range"):
        voxax.raster.line_crossings(v, f + len(v), g, 0)
    bad = v.copy()
    bad[3, 1] = np.nan
    with pytest.raises(ValueError, match="NaN"):
        voxax.raster.line_crossings(bad, f, g, 0)
    bad = v.copy()
    bad[3, 1] = 1e-60
    with pytest.raises(ValueError, match="1e-50"):
        voxax.raster.line_crossings(bad, f, g, 0)
    with pytest.raises(ValueError, match="3D grid|shape"):
        voxax.raster.line_crossings(v[:, :2], f, g, 0)
    assert not isinstance(voxax.raster.line_crossings(v, f, g, 0).depth, jax.Array)
