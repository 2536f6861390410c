"""Sharded voxelization on several CPU devices, run in a subprocess by tests/voxelize/test_sharded.py
(JAX must see several devices, which needs XLA_FLAGS before JAX starts).

Prints one line per check and exits with status 1 if any check fails.
"""

import os
import sys
import traceback

os.environ["XLA_FLAGS"] = (os.environ.get("XLA_FLAGS", "") + " --xla_force_host_platform_device_count=4").strip()

import jax  # noqa: E402

jax.config.update("jax_enable_x64", True)

import jax.numpy as jnp  # noqa: E402
import numpy as np  # noqa: E402
from jax.sharding import Mesh, NamedSharding  # noqa: E402
from jax.sharding import PartitionSpec as P  # noqa: E402

import voxax  # noqa: E402

GRID = voxax.Grid(lower=(-0.9, -1.0, -0.8), upper=(1.0, 0.9, 1.1), shape=(16, 9, 11))


def inputs():
    rng = np.random.default_rng(0)
    m = voxax.data.icosphere(2, radius=0.7)
    # Partly outside the grid along x, and overlapping itself: a shifted copy added.
    v = np.concatenate([m.vertices + [0.5, 0.1, 0.0], m.vertices - [0.2, 0.0, 0.1]])
    v = v + 1e-3 * rng.normal(size=v.shape)
    f = np.concatenate([m.faces, m.faces + len(m.vertices)]).astype(np.int32)
    c = rng.normal(size=GRID.shape)
    return jnp.asarray(v), f, jnp.asarray(c)


def rel(a, b):
    a, b = np.asarray(a), np.asarray(b)
    return float(np.abs(a - b).max() / max(np.abs(b).max(), 1e-300))


def check(n):
    mesh = Mesh(np.array(jax.devices()[:n]), ("x",))
    v, f, c = inputs()
    W1 = voxax.voxelize(v, f, GRID)
    W = voxax.voxelize_sharded(v, f, GRID, mesh, "x")
    assert isinstance(W.sharding, NamedSharding) and W.sharding.spec[0] == "x", W.sharding
    assert len(W.addressable_shards) == n
    assert all(s.data.shape == (16 // n, 9, 11) for s in W.addressable_shards)
    np.testing.assert_array_equal(W, W1)  # the slabs hold the full grid's values bit for bit
    Wj = jax.jit(lambda x: voxax.voxelize_sharded(x, f, GRID, mesh, "x"))(v)
    np.testing.assert_array_equal(Wj, W)
    # Gradient of an energy of the sharded grid, under jit, with sharding annotations.
    cs = jax.device_put(c, NamedSharding(mesh, P("x")))
    e1 = lambda x: jnp.sum(c * jnp.sin(voxax.voxelize(x, f, GRID)))  # noqa: E731
    en = lambda x, cc: jnp.sum(cc * jnp.sin(voxax.voxelize_sharded(x, f, GRID, mesh, "x")))  # noqa: E731
    g1 = jax.grad(e1)(v)
    gn = jax.jit(jax.grad(en))(v, cs)
    assert rel(gn, g1) <= 1e-13, rel(gn, g1)
    # Forward mode.
    t = jnp.asarray(np.cos(np.arange(v.size)).reshape(v.shape))
    d1 = jax.jvp(lambda x: voxax.voxelize(x, f, GRID), (v,), (t,))[1]
    dn = jax.jvp(lambda x: voxax.voxelize_sharded(x, f, GRID, mesh, "x"), (v,), (t,))[1]
    np.testing.assert_array_equal(dn, d1)
    # Inside the user's own shard_map.
    sm = jax.shard_map(lambda x: voxax.voxelize_slab(x, f, GRID, "x"), mesh=mesh, in_specs=P(),
                       out_specs=P("x"))
    np.testing.assert_array_equal(jax.jit(sm)(v), W)
    gs = jax.grad(lambda x: jnp.sum(c * jnp.sin(sm(x))))(v)
    assert rel(gs, g1) <= 1e-13, rel(gs, g1)
    # A batch of meshes.
    vb = jnp.stack([v, 0.9 * v])
    Wb = voxax.voxelize_sharded(vb, f, GRID, mesh, "x")
    assert Wb.shape == (2,) + GRID.shape
    np.testing.assert_array_equal(Wb[1], voxax.voxelize(vb[1], f, GRID))
    return rel(W, W1), rel(gn, g1)


def check_errors():
    mesh = Mesh(np.array(jax.devices()[:3]), ("x",))
    v, f, _ = inputs()
    for call in (lambda: voxax.voxelize_sharded(v, f, GRID, mesh, "x"),
                 lambda: jax.jit(lambda x: voxax.voxelize_sharded(x, f, GRID, mesh, "x"))(v)):
        try:
            call()
        except ValueError as err:
            assert "do not divide" in str(err), err
        else:
            raise AssertionError("3 devices for 16 cells were accepted")
    mesh4 = Mesh(np.array(jax.devices()[:4]), ("d",))
    for call in (lambda: voxax.voxelize_sharded(v, f, GRID, mesh4, "x"),
                 lambda: jax.jit(lambda x: voxax.voxelize_sharded(x, f, GRID, mesh4, "x"))(v)):
        try:
            call()
        except ValueError as err:
            assert "no axis named 'x'" in str(err), err
        else:
            raise AssertionError("a mesh without the axis was accepted")
    try:
        jax.shard_map(lambda x: voxax.voxelize_slab(x, f, GRID, "x"), mesh=mesh4, in_specs=P(), out_specs=P("d"))(v)
    except ValueError as err:
        assert "'x'" in str(err), err
    else:
        raise AssertionError("voxelize_slab accepted an unknown axis")


def main():
    ok = True
    for n in (2, 4):
        try:
            fw, gr = check(n)
            print(f"sharded on {n} devices: ok (forward {fw:.2e}, gradient {gr:.2e} relative)")
        except Exception:  # noqa: BLE001
            ok = False
            print(f"sharded on {n} devices: FAILED\n{traceback.format_exc()}")
    try:
        check_errors()
        print("errors: ok")
    except Exception:  # noqa: BLE001
        ok = False
        print(f"errors: FAILED\n{traceback.format_exc()}")
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
