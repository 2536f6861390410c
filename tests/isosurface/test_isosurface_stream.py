"""The eager isosurface swept over slabs of x planes: the same result, bit for bit, as one sweep."""

import jax.numpy as jnp
import numpy as np
import pytest
from _iso_checks import assert_closed_manifold
from scipy.ndimage import gaussian_filter

import voxax
from voxax._isosurface import stream
from voxax._isosurface.checks import _pad
from voxax._isosurface.stream import _close_value, _isosurface_streamed
from voxax._kernels.contour import topology as host_topology


def _same(a, b):
    for name in ("vertices", "faces", "edges", "n_vertices", "n_faces", "min_gap"):
        x, y = np.asarray(getattr(a, name)), np.asarray(getattr(b, name))
        assert x.dtype == y.dtype and x.shape == y.shape, name
        # bit for bit (NaN-free); the byte views also tell -0.0 from 0.0
        assert x.tobytes() == y.tobytes(), name


def _fields(rng):
    g3 = voxax.Grid((-0.7, -1.0, 0.1), (0.9, 0.8, 1.4), (13, 11, 9))
    f = gaussian_filter(rng.standard_normal(g3.shape), 1.2)
    yield g3, (f / f.std()).astype(np.float32), 0.1
    # small integers with many samples exactly at the level (ties)
    yield g3, rng.integers(-2, 3, g3.shape).astype(np.float64), 0.0
    g2 = voxax.Grid((-1.0, -1.0), (1.0, 0.5), (17, 10))
    f2 = gaussian_filter(rng.standard_normal(g2.shape), 1.5)
    yield g2, f2 / f2.std(), -0.2


@pytest.mark.parametrize("close", [False, True, 3.0])
def test_slabs_equal_one_sweep(rng, close):
    for grid, f, level in _fields(rng):
        for inside in ("below", "above"):
            c = -close if close is not True and close is not False and inside == "above" else close
            whole = _isosurface_streamed(f, grid, level, inside, c, planes=10**6)
            assert int(whole.n_faces) > 0
            for planes in (1, 4):
                _same(_isosurface_streamed(f, grid, level, inside, c, planes=planes), whole)
            # one sweep is the C++ kernel on the (padded) grid, independent of the slab code
            if c is False:
                padded, pgrid = f, grid
            else:
                padded, pgrid = _pad(f, grid, level, inside, c)
                pad = _close_value(f, level, inside, c, 2)
                assert padded.flat[0].tobytes() == pad.tobytes()
            edges, faces = host_topology(padded, level)
            assert np.array_equal(np.asarray(whole.edges), edges)
            if inside == "above":
                faces = faces[:, ::-1] if grid.dim == 2 else faces[:, [0, 2, 1]]
            assert np.array_equal(np.asarray(whole.faces), faces)
            if grid.dim == 3 and c is not False:
                assert_closed_manifold(np.asarray(whole.vertices), faces)


def test_automatic_slabs_and_non_contiguous_input(rng, monkeypatch):
    grid = voxax.Grid.cube(12)
    f = gaussian_filter(rng.standard_normal(grid.shape), 1.5)
    whole = voxax.isosurface(f, grid, 0.0, close=True)
    monkeypatch.setattr(stream, "_SLAB_CELLS", 2 * 14 * 14)  # 2 planes of the padded grid
    _same(voxax.isosurface(f, grid, 0.0, close=True), whole)
    # a transposed view is read slab by slab (copied one slab at a time)
    ft = np.ascontiguousarray(f.transpose(2, 1, 0)).transpose(2, 1, 0)
    assert not ft.flags.c_contiguous
    _same(voxax.isosurface(ft, grid, 0.0, close=True), whole)
    batched = voxax.isosurface(f[None], grid, 0.0)
    single = voxax.isosurface(f, grid, 0.0)
    assert batched.vertices.shape == (1,) + single.vertices.shape
    assert np.array_equal(np.asarray(batched.faces[0]), np.asarray(single.faces))


def test_bad_values_in_a_later_slab(rng):
    grid = voxax.Grid.cube(10)
    f = gaussian_filter(rng.standard_normal(grid.shape), 1.5)
    f[8, 3, 3] = np.nan
    for close in (False, True):
        with pytest.raises(ValueError, match="NaN or Inf"):
            _isosurface_streamed(f, grid, 0.0, "below", close, planes=2)
    with pytest.warns(RuntimeWarning, match="does not cross"):
        iso = _isosurface_streamed(np.ones(grid.shape), grid, 0.0, "below", False, planes=3)
    assert int(iso.n_faces) == 0 and float(iso.min_gap) == np.inf


def test_threads_follow_the_one_rule(monkeypatch):
    """`threads` and VOXAX_NUM_THREADS reach the kernel through `voxax._kernels.threads`;
    any count gives the same bits; bad counts are refused naming the function."""
    from voxax._kernels import contour

    grid = voxax.Grid.cube(12)
    f = np.linalg.norm(grid.centers(), axis=-1) - 0.55
    seen = []
    real = contour.resolve_threads
    monkeypatch.setattr(contour, "resolve_threads", lambda t: seen.append((t, real(t))) or real(t))
    one = voxax.isosurface(f, grid, threads=1)
    monkeypatch.setenv("VOXAX_NUM_THREADS", "3")
    env = voxax.isosurface(f, grid, close=True)
    sdf = voxax.isosurface_fn(lambda r, x: jnp.linalg.norm(x, axis=-1) - r, 0.55, grid, threads=2)
    assert seen[0] == (1, 1) and (None, 3) in seen and (2, 2) in seen
    _same(one, voxax.isosurface(f, grid, threads=2))
    assert int(env.n_faces) == int(one.n_faces) == int(sdf.n_faces) > 0
    for bad, err in ((0, ValueError), (-2, ValueError), (1.5, TypeError), (True, TypeError)):
        with pytest.raises(err, match=r"voxax.isosurface: `threads` must be"):
            voxax.isosurface(f, grid, threads=bad)
        with pytest.raises(err, match=r"voxax.isosurface_topology: `threads` must be"):
            voxax.isosurface_topology(f, grid, threads=bad)


def test_concurrent_python_threads_give_the_same_bits():
    """Four Python threads calling at once (ctypes releases the GIL) get the bits of one call."""
    import concurrent.futures

    grid = voxax.Grid.cube(14)
    f = gaussian_filter(np.random.default_rng(3).standard_normal(grid.shape), 1.2)
    alone = voxax.isosurface(f, grid, close=True)
    with concurrent.futures.ThreadPoolExecutor(4) as pool:
        results = list(pool.map(lambda _: voxax.isosurface(f, grid, close=True, threads=2), range(4)))
    for got in results:
        _same(got, alone)
