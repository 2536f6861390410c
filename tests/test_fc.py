"""Faithful Contouring: the exact partition of triangles into cell pieces, the QEF anchors,
the edge signs against winding numbers, dual contouring and the token layouts."""

import numpy as np
import pytest

import voxax
from voxax import fc, metrics

ODD = voxax.Grid(lower=(-1.0, -0.7, -1.3), upper=(1.1, 0.9, 1.2), shape=(37, 23, 51))


def _soup(rng, n, grid, scale):
    lo, hi = np.asarray(grid.lower), np.asarray(grid.upper)
    centre = lo + rng.random((n, 1, 3)) * (hi - lo)
    size = scale[rng.integers(len(scale), size=n)][:, None, None] * (hi - lo)
    v = np.clip(centre + (rng.random((n, 3, 3)) - 0.5) * size, lo, hi)
    return v.reshape(-1, 3), np.arange(3 * n, dtype=np.int32).reshape(-1, 3)


@pytest.mark.parametrize("grid", [voxax.Grid.cube(64), ODD], ids=["cube64", "odd"])
def test_pieces_partition_each_triangle(grid):
    rng = np.random.default_rng(1)
    V, F = _soup(rng, 1000, grid, np.array([0.005, 0.05, 0.3, 1.0]))
    p = fc.pieces(V, F, grid)
    a, b, c = V[F[:, 0]], V[F[:, 1]], V[F[:, 2]]
    area = 0.5 * np.linalg.norm(np.cross(b - a, c - a), axis=1)
    moment = area[:, None] * (a + b + c) / 3
    got_area = np.bincount(p.face, p.area, minlength=len(F))
    got_moment = np.stack([np.bincount(p.face, p.area * p.centroid[:, k], minlength=len(F)) for k in range(3)], 1)
    assert np.all(np.abs(got_area - area) <= 1e-12 * area)
    scale = area[:, None] * np.abs(a + b + c).max(axis=1, keepdims=True)
    assert np.all(np.abs(got_moment - moment) <= 1e-12 * scale)
    assert np.all(p.area > 0)
    # Sorted by (cell, face), one piece per pair, every centroid in its closed cell.
    key = p.cell * len(F) + p.face
    assert np.all(np.diff(key) > 0)
    ijk = np.stack(np.unravel_index(p.cell, grid.shape), axis=1)
    for ax in range(3):
        e = grid.edges(ax)
        assert np.all(e[ijk[:, ax]] <= p.centroid[:, ax])
        assert np.all(p.centroid[:, ax] <= e[ijk[:, ax] + 1])


def test_pieces_skip_degenerate_faces():
    V = np.array([[0, 0, 0], [0.5, 0.5, 0.5], [1, 1, 1], [0, 0, 0.1], [0.4, 0, 0.1], [0, 0.4, 0.1]], float)
    F = np.array([[0, 1, 2], [0, 0, 0], [3, 4, 5]], np.int32)
    p = fc.pieces(V, F, voxax.Grid.cube(8))
    assert set(p.face.tolist()) == {2}
    assert abs(p.area.sum() - 0.08) < 1e-15
