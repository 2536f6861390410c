"""voxax.Grid: construction, derived quantities, use as a static argument."""

import jax
import numpy as np
import pytest

import voxax
from voxax import Grid


def test_cube_and_spacing():
    g = Grid.cube(4)
    assert g.lower == (-1.0,) * 3 and g.upper == (1.0,) * 3 and g.shape == (4, 4, 4)
    assert g.spacing == (0.5, 0.5, 0.5) and g.voxel_volume == 0.125
    g2 = Grid.cube((3, 5), dim=2, half_width=2.0)
    assert g2.shape == (3, 5) and g2.spacing == pytest.approx((4 / 3, 0.8))


def test_anisotropic_centers_and_edges():
    g = Grid((0, -1, 2), (1, 1, 5), (4, 5, 6))
    c = g.centers()
    assert c.shape == (4, 5, 6, 3)
    np.testing.assert_allclose(c[1, 2, 3], [0.375, 0.0, 3.75])
    e = g.edges(2)
    assert e[0] == 2 and e[-1] == 5 and len(e) == 7
    np.testing.assert_allclose(np.diff(e), 0.5)


def test_hashable_and_static_under_jit():
    a = Grid((0, 0, 0), (1, 1, 1), (2, 3, 4))
    b = Grid([0.0, 0.0, 0.0], np.array([1.0, 1.0, 1.0]), [2, 3, 4])
    assert a == b and hash(a) == hash(b)
    with pytest.raises(AttributeError):
        a.shape = (1, 1, 1)
    traces = []

    def f(x, grid):
        traces.append(grid)
        return x * grid.voxel_volume

    f = jax.jit(f, static_argnums=1)
    assert float(f(1.0, a)) == pytest.approx(1 / 24)
    assert float(f(2.0, b)) == pytest.approx(2 / 24)
    assert len(traces) == 1  # equal grids hit the same compiled function


def test_around_fits_vertices():
    mesh = voxax.data.hand()
    g = Grid.around(mesh.vertices, 40, pad=0.1)
    assert max(g.shape) == 40
    np.testing.assert_allclose(g.spacing, g.spacing[0])  # cubic cells
    lo, hi = mesh.vertices.min(0), mesh.vertices.max(0)
    assert np.all(np.array(g.lower) < lo) and np.all(np.array(g.upper) > hi)
    W = voxax.voxelize(mesh.vertices, mesh.faces, g)
    assert float(W.sum()) * g.voxel_volume == pytest.approx(mesh.signed_volume(), rel=1e-10)
    g2 = Grid.around(mesh.vertices, (10, 20, 30), cubic_cells=False)
    assert g2.shape == (10, 20, 30)
    with pytest.raises(ValueError, match="NaN"):
        Grid.around(np.array([[0.0, np.nan, 0.0]]), 8)


def test_around_a_mesh_fits_the_vertices_its_faces_use():
    """Unused vertices (here 100 far away) do not widen the grid, nor io.normalize's box."""
    ball = voxax.data.icosphere(2, radius=0.6)
    far = np.random.default_rng(0).normal(size=(100, 3)) * 50
    padded = voxax.Mesh(np.vstack([ball.vertices, far]), ball.faces)
    assert voxax.Grid.around(padded, 32) == voxax.Grid.around(ball, 32)
    fitted, centre, scale = voxax.io.normalize(padded, return_transform=True)
    _, centre0, scale0 = voxax.io.normalize(ball, return_transform=True)
    np.testing.assert_array_equal(centre, centre0)
    assert scale == scale0
    np.testing.assert_allclose(np.abs(fitted.vertices[: ball.n_vertices]).max(), 0.8, rtol=1e-15)
