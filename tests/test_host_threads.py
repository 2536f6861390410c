"""One `threads` argument for every eager host entry point: an int >= 1 or None; the same
bits for any thread count and when several Python threads call at once, system by system
(spatial queries, raster, intersections, iso-surfaces, ESI / NESI, CVT, fc), and for the
XLA entry points (voxelization) under concurrent Python threads."""

import dataclasses

import jax
import numpy as np
import pytest

import voxax

MESH = voxax.data.icosphere(1, radius=0.5)
G6 = voxax.Grid.cube(6)
AX = (np.array([0.0, 0.0, 1.0]), [np.array([1.0, 0.0, 0.0])])  # an ESI: a DHF along z, an HF along x
P = np.random.default_rng(0).uniform(-0.8, 0.8, (50, 3))
D = np.tile([[0.0, 0.3, 1.0]], (50, 1))
S = np.asarray(voxax.fields.sphere(np.asarray(G6.centers()).reshape(-1, 3), 0.5)).reshape(G6.shape)


def _cvt_inputs():
    fr = voxax.cvt.fragments(MESH, voxax.Grid.cube(12))
    return fr, voxax.cvt.init_seeds(fr, 20, 0)


CALLS = {
    "closest_points": lambda t: voxax.closest_points(MESH, np.zeros((2, 3)), threads=t),
    "first_hits": lambda t: voxax.first_hits(MESH, P, D, threads=t),
    "any_hits": lambda t: voxax.any_hits(MESH, P, D, threads=t),
    "all_hits": lambda t: voxax.all_hits(MESH, P, D, threads=t),
    "winding_number": lambda t: voxax.winding_number(MESH, P, threads=t),
    "nearest_neighbors": lambda t: voxax.nearest_neighbors(np.eye(3), np.zeros((2, 3)), threads=t),
    "raster.line_crossings": lambda t: voxax.raster.line_crossings(MESH, voxax.Grid.cube(4), 0, threads=t),
    "intersections": lambda t: voxax.intersections(MESH.vertices, MESH.faces, threads=t),
    "isosurface": lambda t: voxax.isosurface(S, G6, threads=t),
    "isosurface_topology": lambda t: voxax.isosurface_topology(S, G6, threads=t),
    "isosurface_fn": lambda t: voxax.isosurface_fn(lambda p, x: voxax.fields.sphere(x, p), 0.5, G6, threads=t),
    "esi.depth_map": lambda t: voxax.esi.depth_map(MESH, (0.3, 0.2, 1.0), resolution=8, threads=t),
    "esi.occupancy": lambda t: voxax.esi.occupancy(AX, MESH, P, threads=t),
    "esi.to_mesh": lambda t: voxax.esi.to_mesh(AX, MESH, resolution=8, threads=t),
    "esi.energy_terms": lambda t: voxax.esi.energy_terms(AX, MESH, n_samples=100, resolution=8, threads=t),
    "nesi.training_data": lambda t: voxax.nesi.training_data(AX, MESH, n_samples=100, threads=t),
    "cvt.fragments": lambda t: voxax.cvt.fragments(MESH, G6, threads=t),
    "cvt.rdt": lambda t: voxax.cvt.rdt(*_cvt_inputs(), threads=t),
    "fc.encode": lambda t: voxax.fc.encode(MESH, voxax.Grid.cube(4), threads=t),
    "fc.pieces": lambda t: voxax.fc.pieces(MESH, G6, threads=t),
    "fc.decode": lambda t: voxax.fc.decode(voxax.fc.encode(MESH, G6), threads=t),
}


def _arrays(result, depth=0):
    """Every array and number in a result (tuples, dicts, dataclasses, named tuples,
    meshes), as NumPy arrays, in a fixed order."""
    if depth > 6:
        return []
    if isinstance(result, (np.ndarray, jax.Array, float, int, np.generic)):
        return [np.asarray(result)]
    if isinstance(result, dict):
        return [a for k in sorted(result) for a in _arrays(result[k], depth + 1)]
    if isinstance(result, (tuple, list)):
        return [a for x in result for a in _arrays(x, depth + 1)]
    if dataclasses.is_dataclass(result):
        return [a for f in dataclasses.fields(result) for a in _arrays(getattr(result, f.name), depth + 1)]
    if hasattr(result, "vertices") and hasattr(result, "faces"):
        return _arrays((result.vertices, result.faces), depth + 1)
    return []


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
    "esi.energy", "esi.select", "nesi.fit",  # tests/esi (energy is energy_terms' total)
    "cvt.remesh",  # tests/cvt
    "fc.roundtrip",  # tests/fc
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


# XLA entry points (no `threads`: they run on XLA's pool, whose size tests/voxelize varies
# with NPROC): Python threads calling one compiled function at once get the bits of one call.
XLA_CALLS = {
    "voxelize": jax.jit(lambda v: voxax.voxelize(v, MESH.faces, G6)),
    "voxelize_mc": jax.jit(lambda v: voxax.voxelize_mc(v, MESH.faces, G6, voxax.Box(), jax.random.key(0), samples=4,
                                                       surface_samples=4)),
    "winding_number": jax.jit(lambda v: voxax.winding_number(v, MESH.faces, P)),
    "closest_points": jax.jit(lambda v: voxax.closest_points((v, MESH.faces), P).distance),
    "voxelize gradient": jax.jit(jax.grad(lambda v: (voxax.voxelize(v, MESH.faces, G6) ** 2).sum())),
}


@pytest.mark.parametrize("name", sorted(XLA_CALLS))
def test_xla_entry_points_in_concurrent_python_threads(name):
    import concurrent.futures

    fn = XLA_CALLS[name]
    v = jax.numpy.asarray(MESH.vertices)
    alone = np.asarray(fn(v))
    with concurrent.futures.ThreadPoolExecutor(4) as pool:
        results = list(pool.map(lambda _: np.asarray(fn(v)), range(8)))
    for got in results:
        np.testing.assert_array_equal(got, alone)
