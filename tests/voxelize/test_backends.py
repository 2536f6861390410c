"""The host-callback path used on non-CPU default backends, forced on the CPU."""


import jax
import jax.numpy as jnp
import numpy as np
import pytest

import voxax

_op = voxax


@pytest.fixture
def host_callback():
    _op.use_host_callback(True)
    yield
    _op.use_host_callback(False)


def _energy(mesh, grid):
    return lambda v: jnp.sum(jnp.sin(3.0 * voxax.voxelize(v, mesh.faces, grid)) ** 2)


def test_host_callback_matches_ffi_path(host_callback):
    mesh = voxax.data.torus()
    grid = voxax.Grid((-1, -1, -0.5), (1, 1, 0.5), (12, 11, 7))
    v = jnp.asarray(mesh.vertices)
    _op.use_host_callback(False)
    W_ffi = voxax.voxelize(v, mesh.faces, grid)
    g_ffi = jax.grad(_energy(mesh, grid))(v)
    _op.use_host_callback(True)
    W_cb = jax.jit(lambda x: voxax.voxelize(x, mesh.faces, grid))(v)
    g_cb = jax.jit(jax.grad(_energy(mesh, grid)))(v)
    np.testing.assert_array_equal(W_cb, W_ffi)
    np.testing.assert_array_equal(g_cb, g_ffi)
    # The callback really was used: its lowering contains a host callback, not the FFI target.
    text = jax.jit(lambda x: voxax.voxelize(x, mesh.faces, grid)).lower(v).as_text()
    assert "voxax_forward" not in text and "callback" in text


def test_host_callback_under_vmap_and_2d(host_callback):
    mesh = voxax.data.torus()
    grid = voxax.Grid.cube(8)
    vb = jnp.stack([mesh.vertices, 0.8 * mesh.vertices])
    Wb = jax.jit(jax.vmap(lambda x: voxax.voxelize(x, mesh.faces, grid)))(vb)
    _op.use_host_callback(False)
    for b in range(2):
        np.testing.assert_array_equal(Wb[b], voxax.voxelize(vb[b], mesh.faces, grid))
    _op.use_host_callback(True)
    poly = voxax.data.star_polyline()
    g2 = voxax.Grid.cube(9, dim=2)
    W2 = jax.jit(lambda x: voxax.voxelize(x, poly.faces, g2))(jnp.asarray(poly.vertices))
    area = float(W2.sum()) * g2.voxel_volume
    assert area == pytest.approx(poly.signed_volume(), rel=1e-10)


def test_host_callback_reports_bad_values(host_callback):
    mesh = voxax.data.box()
    grid = voxax.Grid.cube(4)
    v = jnp.asarray(mesh.vertices).at[2, 1].set(jnp.nan)
    fn = jax.jit(lambda x: voxax.voxelize(x, mesh.faces, grid))
    with pytest.raises(Exception, match="NaN or Inf"):
        jax.block_until_ready(fn(v))
    assert float(fn(jnp.asarray(mesh.vertices)).sum()) * grid.voxel_volume == pytest.approx(1.0)


def test_forward_mode_through_host_callback(host_callback):
    mesh = voxax.data.box()
    grid = voxax.Grid.cube(4)
    v = jnp.asarray(mesh.vertices) * 0.9
    t = jnp.asarray(np.random.default_rng(0).normal(size=v.shape))
    fn = lambda x: voxax.voxelize(x, mesh.faces, grid)  # noqa: E731
    dW_cb = jax.jit(lambda x, tt: jax.jvp(fn, (x,), (tt,))[1])(v, t)
    g_cb = jax.jit(jax.grad(lambda x: jnp.sum(fn(x) ** 2)))(v)
    _op.use_host_callback(False)
    np.testing.assert_array_equal(dW_cb, jax.jvp(fn, (v,), (t,))[1])
    np.testing.assert_array_equal(g_cb, jax.grad(lambda x: jnp.sum(fn(x) ** 2))(v))
