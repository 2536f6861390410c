"""optimize_implicit: a sphere turns into a torus by matching the torus's silhouettes."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import voxax


def _mix(z, x):
    s = jax.nn.sigmoid(z)
    return (1 - s) * voxax.fields.sphere(x, 0.6) + s * voxax.fields.torus(x, 0.5, 0.2)


def test_sphere_becomes_torus_by_silhouettes():
    grid = voxax.Grid.cube(16)
    torus = voxax.isosurface(voxax.fields.torus(jnp.asarray(grid.centers()), 0.5, 0.2), grid, close=True).to_mesh()
    assert voxax.metrics.euler_characteristic(torus) == 0
    z, report = voxax.apps.optimize_implicit(_mix, -3.0, torus, grid, steps=200, learning_rate=0.2, target_euler=0)
    assert report.euler_history[0] == 2
    assert report.euler == 0 and report.stop_reason == "target_euler"
    assert report.steps <= 200
    assert report.loss_history[-1] < 0.5 * report.loss_history[0]
    # Independent check: the mixed field is positive at the origin (a hole) iff s > 0.6 / 0.9.
    assert float(jax.nn.sigmoid(z)) > 0.6 / 0.9
    # and the returned parameters really give a closed genus-1 surface
    final = voxax.isosurface(_mix(z, jnp.asarray(grid.centers())), grid, close=True).to_mesh()
    assert voxax.metrics.euler_characteristic(final) == 0


def test_bad_input():
    grid = voxax.Grid.cube(8)
    with pytest.raises(ValueError, match="rule"):
        voxax.apps.optimize_implicit(_mix, 0.0, (np.zeros((8, 8)),) * 3, grid, rule="nope")
    with pytest.raises(ValueError, match="silhouettes must have shapes"):
        voxax.apps.optimize_implicit(_mix, 0.0, (np.zeros((4, 8)),) * 3, grid)
    with pytest.raises(TypeError, match="callable"):
        voxax.apps.optimize_implicit(1.0, 0.0, (np.zeros((8, 8)),) * 3, grid)


def test_a_growing_surface_outgrows_the_first_capacity():
    # A small sphere (r = 0.2) fitted to the silhouettes of a large one (r = 0.8): the face
    # count grows ~16x, past the starting capacity (twice the first mesh).
    grid = voxax.Grid.cube(16)
    big = voxax.isosurface(voxax.fields.sphere(jnp.asarray(grid.centers()), 0.8), grid, close=True).to_mesh()
    r, report = voxax.apps.optimize_implicit(lambda r, x: voxax.fields.sphere(x, r), 0.2, big, grid,
                                             steps=60, learning_rate=0.05)
    assert report.faces_history.max() > 4 * report.faces_history[0]
    assert abs(float(r) - 0.8) < 0.05  # one cell is 0.125
    assert set(report.euler_history.tolist()) == {2}
