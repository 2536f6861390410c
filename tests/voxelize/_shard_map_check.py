"""shard_map check for `voxax.voxelize`, run in a subprocess by tests/voxelize/test_transforms.py.

JAX must see several CPU devices, which needs `XLA_FLAGS=--xla_force_host_platform_device_count`
before JAX starts; that is why this is a separate script and not a test.

Usage: python _shard_map_check.py {forward|grad|shared|replication} [n_devices ...]

- forward: a batch of meshes (B, V, 3) sharded along the batch over the devices, faces
  replicated; the sharded W must equal the unsharded `voxelize` bit for bit.
- grad: jax.grad of an energy of the sharded W with respect to the sharded vertices must
  equal the unsharded gradient.
- shared: one vertex set, replicated, with per-device translations: the gradient with
  respect to the replicated vertices needs a sum across devices (psum in the transpose).
- replication: the output computed from batch-sharded vertices is typed as varying along
  the mesh axis, so `out_specs=P()` (a claim that it is replicated) is rejected as for any
  JAX op; from replicated inputs the output is replicated.

Prints one line per check and exits with status 1 if any check fails (with the error).
"""

import os
import sys
import traceback

_N_MAX = 4
os.environ["XLA_FLAGS"] = (
    os.environ.get("XLA_FLAGS", "") + f" --xla_force_host_platform_device_count={_N_MAX}"
).strip()

import jax  # noqa: E402

jax.config.update("jax_enable_x64", True)

import jax.numpy as jnp  # noqa: E402
import numpy as np  # noqa: E402
from jax.sharding import Mesh, NamedSharding  # noqa: E402
from jax.sharding import PartitionSpec as P  # noqa: E402

import voxax  # noqa: E402

shard_map = getattr(jax, "shard_map", None)
if shard_map is None:  # older JAX
    from jax.experimental.shard_map import shard_map  # noqa: E402

GRID = voxax.Grid(lower=(-0.9, -1.0, -0.8), upper=(1.0, 0.9, 1.1), shape=(7, 8, 6))
B = 8


def inputs():
    rng = np.random.default_rng(0)
    m = voxax.data.icosphere(1, radius=0.6)
    scale = rng.uniform(0.7, 1.3, (B, 1, 1))
    shift = rng.uniform(-0.25, 0.25, (B, 1, 3))
    vertices = m.vertices[None] * scale + shift + 1e-3 * rng.uniform(-1, 1, (B,) + m.vertices.shape)
    c = rng.normal(size=(B,) + GRID.shape)
    return vertices, np.asarray(m.faces, np.int32), c


def energy(W, c):
    return jnp.sum(jnp.sin(W) * c) + jnp.sum(W**2)


def make_mesh(n):
    devices = jax.devices()
    if len(devices) < n:
        raise RuntimeError(f"need {n} CPU devices, JAX sees {len(devices)}: {devices}")
    return Mesh(np.array(devices[:n]), ("b",))


def put(mesh, x, spec):
    return jax.device_put(x, NamedSharding(mesh, spec))


def check_forward(n):
    v, f, _ = inputs()
    mesh = make_mesh(n)
    fn = jax.jit(shard_map(lambda vb, fb: voxax.voxelize(vb, fb, GRID), mesh=mesh,
                           in_specs=(P("b"), P()), out_specs=P("b")))
    W = np.asarray(fn(put(mesh, v, P("b")), put(mesh, f, P())))
    expected = np.asarray(voxax.voxelize(v, f, GRID))
    one_by_one = np.stack([np.asarray(voxax.voxelize(v[i], f, GRID)) for i in range(B)])
    assert W.shape == (B,) + GRID.shape, W.shape
    assert np.array_equal(W, expected), f"max diff {np.abs(W - expected).max()}"
    assert np.array_equal(W, one_by_one)


def check_grad(n):
    v, f, c = inputs()
    mesh = make_mesh(n)

    def sharded_loss(vb, fb, cb):
        W = shard_map(lambda x, y: voxax.voxelize(x, y, GRID), mesh=mesh,
                      in_specs=(P("b"), P()), out_specs=P("b"))(vb, fb)
        return energy(W, cb)

    value, grad = jax.jit(jax.value_and_grad(sharded_loss))(
        put(mesh, v, P("b")), put(mesh, f, P()), put(mesh, c, P("b")))
    e_value, e_grad = jax.value_and_grad(lambda x: energy(voxax.voxelize(x, f, GRID), c))(jnp.asarray(v))
    grad, e_grad = np.asarray(grad), np.asarray(e_grad)
    assert np.allclose(float(value), float(e_value), rtol=1e-13, atol=0), (float(value), float(e_value))
    err = np.abs(grad - e_grad).max() / np.abs(e_grad).max()
    assert err < 1e-13, f"relative gradient error {err}"


def check_shared(n):
    v, f, c = inputs()
    base = v[0]
    shifts = np.random.default_rng(1).uniform(-0.2, 0.2, (B, 1, 3))
    mesh = make_mesh(n)

    def sharded_loss(x, t, cb):
        W = shard_map(lambda xv, tv: voxax.voxelize(xv[None] + tv, f, GRID), mesh=mesh,
                      in_specs=(P(), P("b")), out_specs=P("b"))(x, t)
        return energy(W, cb)

    grad = jax.jit(jax.grad(sharded_loss))(put(mesh, base, P()), put(mesh, shifts, P("b")), put(mesh, c, P("b")))
    e_grad = jax.grad(lambda x: energy(voxax.voxelize(x[None] + shifts, f, GRID), c))(jnp.asarray(base))
    grad, e_grad = np.asarray(grad), np.asarray(e_grad)
    err = np.abs(grad - e_grad).max() / np.abs(e_grad).max()
    assert err < 1e-12, f"relative gradient error {err}"


def check_replication(n):
    v, f, _ = inputs()
    mesh = make_mesh(n)
    # Per-device results typed as varying: claiming they are replicated must be rejected,
    # as it is for any ordinary JAX op (otherwise device 0's shard is silently returned).
    ordinary = shard_map(lambda vb: vb * 2.0, mesh=mesh, in_specs=P("b"), out_specs=P())
    voxelized = shard_map(lambda vb: voxax.voxelize(vb, f, GRID), mesh=mesh, in_specs=P("b"), out_specs=P())
    for name, fn in (("vb * 2", ordinary), ("voxelize", voxelized)):
        try:
            out = jax.jit(fn)(put(mesh, v, P("b")))
        except ValueError as err:
            assert "out_specs" in str(err), err
            continue
        raise AssertionError(
            f"shard_map accepted out_specs=P() for `{name}` of batch-sharded vertices (per-device "
            f"values claimed replicated; got shape {out.shape}): the result is typed invariant "
            f"across the mesh axis although it varies"
        )
    # Replicated inputs give a replicated (invariant) result, which out_specs=P() accepts.
    rep = shard_map(lambda vb: voxax.voxelize(vb, f, GRID), mesh=mesh, in_specs=P(), out_specs=P())
    W = np.asarray(jax.jit(rep)(put(mesh, v[:2], P())))
    assert np.array_equal(W, np.asarray(voxax.voxelize(v[:2], f, GRID)))


CHECKS = {"forward": check_forward, "grad": check_grad, "shared": check_shared, "replication": check_replication}


def main(argv):
    if not argv or argv[0] not in CHECKS:
        print(__doc__)
        return 2
    counts = [int(a) for a in argv[1:]] or [2, 4]
    print(f"jax {jax.__version__}, devices: {len(jax.devices())}")
    failed = 0
    for n in counts:
        try:
            CHECKS[argv[0]](n)
            print(f"{argv[0]} on {n} devices: ok")
        except Exception as err:  # noqa: BLE001 - report every failure, then exit non-zero
            failed += 1
            print(f"{argv[0]} on {n} devices: FAILED: {type(err).__name__}: {err}")
            traceback.print_exc()
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
