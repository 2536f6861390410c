"""One `threads` argument for every eager host entry point: an int >= 1 or None."""

import numpy as np
import pytest

import voxax

MESH = voxax.data.icosphere(1, radius=0.5)
CALLS = {
    "closest_points": lambda t: voxax.closest_points(MESH, np.zeros((2, 3)), threads=t),
    "nearest_neighbors": lambda t: voxax.nearest_neighbors(np.eye(3), np.zeros((2, 3)), threads=t),
    "line_crossings": lambda t: voxax.raster.line_crossings(MESH, voxax.Grid.cube(4), 0, threads=t),
    "intersections": lambda t: voxax.intersections(MESH.vertices, MESH.faces, threads=t),
    "fc.encode": lambda t: voxax.fc.encode(MESH, voxax.Grid.cube(4), threads=t),
}


def _arrays(result):
    fields = result if isinstance(result, tuple) else vars(result).values()
    return [np.asarray(x) for x in fields if isinstance(x, np.ndarray)]


@pytest.mark.parametrize("name", sorted(CALLS))
def test_threads_argument(name):
    call = CALLS[name]
    one, two = _arrays(call(1)), _arrays(call(np.int64(2)))
    assert one and len(one) == len(two)
    for a, b in zip(one, two):
        np.testing.assert_array_equal(a, b)  # the same bits for any thread count
    for bad in (2.5, True, "2"):
        with pytest.raises(TypeError, match="`threads` must be an int or None"):
            call(bad)
    for bad in (0, -1):
        with pytest.raises(ValueError, match="`threads` must be >= 1"):
            call(bad)
