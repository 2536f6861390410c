"""One `threads` argument for every eager host entry point: an int >= 1 or None."""

import numpy as np
import pytest

import voxax

MESH = voxax.data.icosphere(1, radius=0.5)
CALLS = {
    "closest_points": lambda t: voxax.closest_points(MESH, np.zeros((2, 3)), threads=t),
    "nearest_neighbors": lambda t: voxax.nearest_neighbors(np.eye(3), np.zeros((2, 3)), threads=t),
    "raster.line_crossings": lambda t: voxax.raster.line_crossings(MESH, voxax.Grid.cube(4), 0, threads=t),
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


def _public_threads_callables():
    import inspect

    names = set()
    for ns in ("", "apps", "cvt", "esi", "fc", "metrics", "nesi", "raster"):
        module = voxax if not ns else getattr(voxax, ns)
        for name in getattr(module, "__all__", ()):
            obj = getattr(module, name, None)
            try:
                if callable(obj) and "threads" in inspect.signature(obj).parameters:
                    names.add(f"{ns}.{name}" if ns else name)
            except (TypeError, ValueError):
                pass
    return names


# Entry points with `threads` whose determinism is checked in their own system's tests
# (they need inputs too large or slow for this table).
CHECKED_ELSEWHERE = {
    "esi.depth_map", "esi.energy", "esi.energy_terms", "esi.select", "esi.occupancy", "esi.to_mesh",  # tests/esi
    "nesi.fit", "nesi.training_data",  # tests/esi
    "cvt.fragments", "cvt.rdt", "cvt.remesh",  # tests/cvt
    "fc.pieces", "fc.decode", "fc.roundtrip",  # tests/fc
    "all_hits", "any_hits", "first_hits", "winding_number",  # tests/spatial
    "isosurface", "isosurface_fn", "isosurface_topology",  # tests/isosurface
}


def test_every_threads_argument_is_covered():
    missing = _public_threads_callables() - set(CALLS) - CHECKED_ELSEWHERE
    assert not missing, f"entry points with `threads` and no determinism check: {sorted(missing)}"


@pytest.mark.parametrize("name", sorted(CALLS))
def test_concurrent_python_threads_give_the_same_bits(name):
    """Four Python threads calling at once (ctypes releases the GIL) get the bits of one call."""
    import concurrent.futures

    call = CALLS[name]
    alone = _arrays(call(None))
    with concurrent.futures.ThreadPoolExecutor(4) as pool:
        results = list(pool.map(lambda _: _arrays(call(None)), range(4)))
    for got in results:
        assert len(got) == len(alone)
        for a, b in zip(alone, got):
            np.testing.assert_array_equal(a, b)
