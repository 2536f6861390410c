"""`voxax.voxelize` under JAX transformations: jit, grad, vjp, vmap, shard_map, forward mode,
and a jit-compiled optax loop."""

import os
import subprocess
import sys
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import optax
import pytest
from conftest import random_polygon, random_star_mesh

import voxax
from voxax import Grid, reference

GRID3 = Grid(lower=(-0.9, -1.0, -0.8), upper=(1.0, 0.9, 1.1), shape=(7, 8, 6))
GRID2 = Grid(lower=(-0.9, -1.0), upper=(1.0, 0.9), shape=(9, 8))


def mesh(dim, rng, **kw):
    if dim == 3:
        return random_star_mesh(rng, **kw)
    return random_polygon(rng, **kw)


def grid_for(dim):
    return GRID3 if dim == 3 else GRID2


def batch_of(dim, rng, b):
    """`b` random deformations of one mesh: vertices (b, V, d), shared faces (F, d)."""
    v, f = mesh(dim, rng, scale=0.55)
    vs = np.stack([v * rng.uniform(0.7, 1.3) + rng.uniform(-0.2, 0.2, dim) for _ in range(b)])
    return vs, f


def energy(W, c):
    return jnp.sum(jnp.sin(W) * c) + jnp.sum(W**2)


def same(a, b):
    """Bit-for-bit equality (shapes and dtypes included)."""
    a, b = np.asarray(a), np.asarray(b)
    return a.shape == b.shape and a.dtype == b.dtype and np.array_equal(a, b)


# ---------------------------------------------------------------------------------------
# jit, grad, vjp, value_and_grad
# ---------------------------------------------------------------------------------------


@pytest.mark.parametrize("dim", [2, 3])
def test_jit_equals_eager(dim):
    rng = np.random.default_rng(dim)
    v, f = mesh(dim, rng, scale=0.6)
    g = grid_for(dim)
    c = jnp.asarray(rng.normal(size=g.shape))
    x = jnp.asarray(v)

    W = voxax.voxelize(x, f, g)
    assert same(jax.jit(voxax.voxelize, static_argnums=2)(x, jnp.asarray(f), g), W)
    assert same(jax.jit(lambda y: voxax.voxelize(y, f, g))(x), W)

    E = lambda y: energy(voxax.voxelize(y, f, g), c)  # noqa: E731
    grad = jax.grad(E)(x)
    assert np.any(np.asarray(grad) != 0)
    np.testing.assert_allclose(jax.jit(jax.grad(E))(x), grad, rtol=1e-13, atol=1e-15)
    value, vg = jax.value_and_grad(E)(x)
    jvalue, jvg = jax.jit(jax.value_and_grad(E))(x)
    np.testing.assert_allclose(value, E(x), rtol=1e-14)
    np.testing.assert_allclose(jvalue, value, rtol=1e-13)
    assert same(vg, grad)
    np.testing.assert_allclose(jvg, grad, rtol=1e-13, atol=1e-15)

    # The raw VJP: eager and jitted agree bit for bit, and match the reference.
    cot = jnp.asarray(rng.normal(size=g.shape))
    W2, vjp = jax.vjp(lambda y: voxax.voxelize(y, f, g), x)
    assert same(W2, W)
    (dv,) = vjp(cot)
    (jdv,) = jax.jit(lambda y, ct: jax.vjp(lambda z: voxax.voxelize(z, f, g), y)[1](ct))(x, cot)
    assert same(jdv, dv)
    ref = reference.voxelize_backward(v, f, g, np.asarray(cot))
    assert np.max(np.abs(np.asarray(dv) - ref)) < 1e-10 * np.max(np.abs(ref))


def test_grid_is_static_and_hashable():
    """Equal grids (different objects) hit the jit cache: one trace, not two."""
    traces = []

    @jax.jit
    def run(x, f):
        traces.append(1)
        return voxax.voxelize(x, f, Grid.cube(6)).sum()

    rng = np.random.default_rng(0)
    v, f = random_star_mesh(rng)
    run(jnp.asarray(v), jnp.asarray(f))
    run(jnp.asarray(v) * 1.1, jnp.asarray(f))
    assert len(traces) == 1
    other = []

    def counted(x, f, grid):
        other.append(1)
        return voxax.voxelize(x, f, grid)

    fn = jax.jit(counted, static_argnames="grid")
    a = fn(jnp.asarray(v), jnp.asarray(f), grid=Grid.cube(6))
    b = fn(jnp.asarray(v), jnp.asarray(f), grid=Grid(lower=(-1, -1, -1), upper=(1, 1, 1), shape=(6, 6, 6)))
    assert same(a, b)
    assert len(other) == 1
    fn(jnp.asarray(v), jnp.asarray(f), grid=Grid.cube(7))  # a different grid does retrace
    assert len(other) == 2


def test_float32_under_jit_and_grad():
    rng = np.random.default_rng(5)
    v, f = random_star_mesh(rng, scale=0.6)
    x = jnp.asarray(v, jnp.float32)
    E = lambda y: jnp.sum(voxax.voxelize(y, f, GRID3) ** 2)  # noqa: E731
    W = jax.jit(lambda y: voxax.voxelize(y, f, GRID3))(x)
    assert W.dtype == jnp.float32
    g = jax.jit(jax.grad(E))(x)
    assert g.dtype == jnp.float32
    g64 = jax.grad(E)(jnp.asarray(x, jnp.float64))
    assert np.max(np.abs(np.asarray(g) - np.asarray(g64))) < 1e-4 * np.max(np.abs(np.asarray(g64)))


# ---------------------------------------------------------------------------------------
# vmap and leading batch axes
# ---------------------------------------------------------------------------------------


@pytest.mark.parametrize("dim", [2, 3])
def test_vmap_shared_faces_matches_one_by_one(dim):
    rng = np.random.default_rng(10 + dim)
    vs, f = batch_of(dim, rng, 4)
    g = grid_for(dim)
    cs = jnp.asarray(rng.normal(size=(4,) + g.shape))
    x = jnp.asarray(vs)

    one = lambda y: voxax.voxelize(y, f, g)  # noqa: E731
    loop_W = jnp.stack([one(x[i]) for i in range(4)])
    assert same(jax.vmap(one)(x), loop_W)
    assert same(jax.jit(jax.vmap(one))(x), loop_W)
    # Leading batch axes passed directly, without vmap.
    assert same(voxax.voxelize(x, f, g), loop_W)

    E = lambda y, c: energy(one(y), c)  # noqa: E731
    loop_g = jnp.stack([jax.grad(E)(x[i], cs[i]) for i in range(4)])
    assert same(jax.vmap(jax.grad(E))(x, cs), loop_g)
    # The gradient of a batched energy through the direct batched call.
    direct = jax.grad(lambda y: energy(voxax.voxelize(y, f, g), cs))(x)
    np.testing.assert_allclose(direct, loop_g, rtol=1e-13, atol=1e-15)
    # The gradient of the sum of energies through vmap.
    summed = jax.grad(lambda y: jax.vmap(E)(y, cs).sum())(x)
    np.testing.assert_allclose(summed, loop_g, rtol=1e-13, atol=1e-15)


@pytest.mark.parametrize("dim", [3])
def test_nested_vmap(dim):
    rng = np.random.default_rng(20 + dim)
    vs, f = batch_of(dim, rng, 6)
    g = grid_for(dim)
    x = jnp.asarray(vs).reshape((2, 3) + vs.shape[1:])
    cs = jnp.asarray(rng.normal(size=(2, 3) + g.shape))
    one = lambda y: voxax.voxelize(y, f, g)  # noqa: E731
    loop = jnp.stack([jnp.stack([one(x[i, j]) for j in range(3)]) for i in range(2)])
    assert same(jax.vmap(jax.vmap(one))(x), loop)
    assert same(voxax.voxelize(x, f, g), loop)  # two leading axes directly

    E = lambda y, c: energy(one(y), c)  # noqa: E731
    loop_g = jnp.stack([jnp.stack([jax.grad(E)(x[i, j], cs[i, j]) for j in range(3)]) for i in range(2)])
    assert same(jax.vmap(jax.vmap(jax.grad(E)))(x, cs), loop_g)
    # vmap of a function that itself gets a leading batch axis.
    assert same(jax.vmap(one)(x), loop)
    assert same(jax.vmap(jax.grad(lambda y, c: energy(one(y), c)))(x, cs), loop_g)


def _padded_meshes(dim, rng):
    """Different meshes padded to common V and F: extra vertices at random places,
    extra faces degenerate ([0, 0, 0] or [0, 0])."""
    if dim == 3:
        meshes = [random_star_mesh(rng, n_theta=nt, n_phi=npf, center=rng.uniform(-0.2, 0.2, 3), scale=0.55)
                  for nt, npf in [(4, 3), (6, 5), (5, 4)]]
    else:
        meshes = [random_polygon(rng, n=n, center=rng.uniform(-0.2, 0.2, 2), scale=0.55) for n in (5, 11, 8)]
    nv = max(len(v) for v, _ in meshes)
    nf = max(len(f) for _, f in meshes)
    V = np.stack([np.concatenate([v, rng.uniform(-0.5, 0.5, (nv - len(v), dim))]) for v, _ in meshes])
    F = np.stack([np.concatenate([f, np.zeros((nf - len(f), dim), np.int32)]) for _, f in meshes])
    return meshes, V, F.astype(np.int32)


@pytest.mark.parametrize("dim", [2, 3])
def test_batched_vertices_and_faces_with_padding(dim):
    rng = np.random.default_rng(30 + dim)
    meshes, V, F = _padded_meshes(dim, rng)
    g = grid_for(dim)
    b = len(meshes)
    cs = jnp.asarray(rng.normal(size=(b,) + g.shape))
    unpadded = [voxax.voxelize(v, f, g) for v, f in meshes]

    # Padding with degenerate faces (and unused vertices) does not change W.
    for i in range(len(meshes)):
        assert same(voxax.voxelize(V[i], F[i], g), unpadded[i])
    expected = jnp.stack(unpadded)
    assert same(jax.vmap(lambda v, f: voxax.voxelize(v, f, g))(jnp.asarray(V), jnp.asarray(F)), expected)
    assert same(voxax.voxelize(jnp.asarray(V), jnp.asarray(F), g), expected)  # directly, (B,V,d) + (B,F,d)

    # Gradients: the real vertices get the unpadded gradient, the padding gets zero.
    grads = jax.vmap(jax.grad(lambda v, f, c: energy(voxax.voxelize(v, f, g), c)))(jnp.asarray(V), jnp.asarray(F), cs)
    direct = jax.grad(lambda v: energy(voxax.voxelize(v, jnp.asarray(F), g), cs))(jnp.asarray(V))
    np.testing.assert_allclose(direct, grads, rtol=1e-13, atol=1e-15)
    for i, (v, f) in enumerate(meshes):
        gi = jax.grad(lambda y, f=f, i=i: energy(voxax.voxelize(y, f, g), cs[i]))(jnp.asarray(v))
        assert same(grads[i, : len(v)], gi)
        assert np.all(np.asarray(grads[i, len(v):]) == 0.0)


@pytest.mark.parametrize("dim", [3])
def test_shared_vertices_gradients_are_summed(dim):
    """One vertex set used by several batch members (different faces and cotangents):
    its gradient is the sum of the members' gradients."""
    rng = np.random.default_rng(40 + dim)
    a = mesh(dim, rng, center=(-0.15,) + (0.0,) * (dim - 1), scale=0.5)
    b = mesh(dim, rng, center=(0.2,) + (0.05,) * (dim - 1), scale=0.45)
    assert a[1].shape == b[1].shape
    v = np.concatenate([a[0], b[0]])
    fa, fb = a[1], b[1] + len(a[0])
    faces = np.stack([fa, fb, fa[:, ::-1], fb]).astype(np.int32)  # (4, F, d); the third is flipped
    g = grid_for(dim)
    cs = jnp.asarray(rng.normal(size=(4,) + g.shape))
    x = jnp.asarray(v)

    individual = [jax.grad(lambda y, i=i: energy(voxax.voxelize(y, faces[i], g), cs[i]))(x) for i in range(4)]
    expected = sum(np.asarray(gi) for gi in individual)
    assert all(np.any(np.asarray(gi) != 0) for gi in individual)

    via_vmap = jax.grad(lambda y: jax.vmap(lambda f, c: energy(voxax.voxelize(y, f, g), c))(jnp.asarray(faces), cs).sum())(x)
    np.testing.assert_allclose(via_vmap, expected, rtol=1e-12, atol=1e-14)
    # Unbatched vertices (V, d) with batched faces (B, F, d) passed directly.
    W = voxax.voxelize(x, jnp.asarray(faces), g)
    assert W.shape == (4,) + g.shape
    direct = jax.grad(lambda y: energy(voxax.voxelize(y, jnp.asarray(faces), g), cs))(x)
    assert direct.shape == x.shape
    np.testing.assert_allclose(direct, expected, rtol=1e-12, atol=1e-14)
    # vmap over the cotangent only, with vertices and faces unbatched: one gradient each.
    per_c = jax.vmap(lambda c: jax.grad(lambda y: energy(voxax.voxelize(y, fa, g), c))(x))(cs)
    for i in range(4):
        gi = jax.grad(lambda y, i=i: energy(voxax.voxelize(y, fa, g), cs[i]))(x)
        np.testing.assert_allclose(per_c[i], gi, rtol=1e-13, atol=1e-15)
    _, vjp = jax.vjp(lambda y: voxax.voxelize(y, fa, g), x)
    batched_vjp = jax.vmap(vjp)(cs)[0]
    for i in range(4):
        assert same(batched_vjp[i], vjp(cs[i])[0])
    # Vertices broadcast along a batch axis of size 1 against batched faces.
    direct1 = jax.grad(lambda y: energy(voxax.voxelize(y[None], jnp.asarray(faces), g), cs))(x)
    np.testing.assert_allclose(direct1, expected, rtol=1e-12, atol=1e-14)


# ---------------------------------------------------------------------------------------
# shard_map (in a subprocess with several simulated CPU devices)
# ---------------------------------------------------------------------------------------


def _run_shard_map_check(check):
    script = Path(__file__).resolve().parent / "_shard_map_check.py"
    pkg_root = str(Path(voxax.__file__).resolve().parent.parent)
    env = dict(os.environ)
    env["PYTHONPATH"] = os.pathsep.join([pkg_root, env.get("PYTHONPATH", "")])
    env["XLA_FLAGS"] = "--xla_force_host_platform_device_count=4"
    proc = subprocess.run([sys.executable, str(script), check, "2", "4"], env=env,
                          capture_output=True, text=True, timeout=300)
    return proc


@pytest.mark.parametrize("check", ["forward", "grad", "shared", "replication"])
def test_shard_map_matches_unsharded(check):
    """A batch sharded over 2 and 4 simulated CPU devices with `jax.shard_map` gives the
    same values (bit for bit) and gradients as the unsharded computation.

    "grad" differentiates w.r.t. sharded vertices; "shared" w.r.t. replicated vertices
    translated per batch member (the transpose sums across devices); "replication" checks
    that the output is typed as varying along the mesh axis when the vertices are sharded
    (see the script's docstring)."""
    proc = _run_shard_map_check(check)
    report = f"exit {proc.returncode}\n--- stdout\n{proc.stdout}\n--- stderr\n{proc.stderr[-6000:]}"
    assert proc.returncode == 0, report
    assert f"{check} on 2 devices: ok" in proc.stdout and f"{check} on 4 devices: ok" in proc.stdout, report


# ---------------------------------------------------------------------------------------
# Forward mode
# ---------------------------------------------------------------------------------------


def _fwd_inputs():
    rng = np.random.default_rng(3)
    v, f = random_star_mesh(rng)
    return jnp.asarray(v), f, Grid.cube(5)


@pytest.mark.parametrize("how", ["jvp", "jacfwd", "linearize"])
def test_forward_mode_agrees_with_reverse_mode(how):
    """Forward mode (jvp, jacfwd, linearize) gives the transpose of reverse mode: the
    directional derivative along t, contracted with u, equals <J^T u, t>."""
    x, f, g = _fwd_inputs()
    fn = lambda y: voxax.voxelize(y, f, g)  # noqa: E731
    rng = np.random.default_rng(4)
    t = jnp.asarray(rng.normal(size=x.shape))
    u = jnp.asarray(rng.normal(size=g.shape))
    JTu = jax.vjp(fn, x)[1](u)[0]
    if how == "jvp":
        Jt = jax.jvp(fn, (x,), (t,))[1]
    elif how == "jacfwd":
        Jt = jnp.tensordot(jax.jacfwd(fn)(x), t, axes=2)
    else:
        _, lin = jax.linearize(fn, x)
        Jt = lin(t)
    assert float(jnp.vdot(u, Jt)) == pytest.approx(float(jnp.vdot(JTu, t)), rel=1e-11)


def test_second_order_raises():
    """Second derivatives are not available: jax.hessian raises a message naming the
    alternative (it does not crash or return silently wrong numbers)."""
    x, f, g = _fwd_inputs()
    with pytest.raises(NotImplementedError, match=r"Gauss-Newton"):
        jax.hessian(lambda y: voxax.voxelize(y, f, g).sum())(x)


# ---------------------------------------------------------------------------------------
# A jit-compiled optimization loop with optax
# ---------------------------------------------------------------------------------------


def test_optax_adam_loop_compiles_once():
    m = voxax.data.icosphere(1, radius=0.6)
    g = Grid.cube(10)
    vol = g.voxel_volume
    faces = jnp.asarray(m.faces)
    x0 = jnp.asarray(m.vertices + 1e-3 * np.random.default_rng(0).uniform(-1, 1, m.vertices.shape))
    target = 0.5 * reference.signed_volume(np.asarray(x0), m.faces)

    def loss(x):
        return (voxax.voxelize(x, faces, g).sum() * vol - target) ** 2

    opt = optax.adam(1e-2)
    traces = []

    @jax.jit
    def step(x, state):
        traces.append(1)  # runs only while tracing
        value, grad = jax.value_and_grad(loss)(x)
        updates, state = opt.update(grad, state, x)
        return optax.apply_updates(x, updates), state, value

    x, state = x0, opt.init(x0)
    values = []
    for _ in range(20):
        x, state, value = step(x, state)
        values.append(float(value))
    final = float(loss(x))
    assert len(traces) == 1, f"step was traced {len(traces)} times"
    assert values[0] > 0
    assert final < 0.5 * values[0], values + [final]
    assert all(b <= a for a, b in zip(values[:5], values[1:6])), values
    # The volume went down towards the target, i.e. the mesh shrank.
    assert float(voxax.voxelize(x, faces, g).sum()) < float(voxax.voxelize(x0, faces, g).sum())


def test_vmap_of_grad_of_linear_energy():
    """A cotangent that does not vary over the batch reaches the kernel with a size-1 axis."""
    mesh = voxax.data.icosphere(1)
    grid = voxax.Grid.cube(12)
    vb = jnp.stack([jnp.asarray(mesh.vertices) * s for s in (0.5, 0.7, 0.9)])
    energy = lambda v: voxax.voxelize(v, mesh.faces, grid).sum()  # noqa: E731
    expected = np.stack([np.asarray(jax.grad(energy)(v)) for v in vb])
    np.testing.assert_array_equal(jax.vmap(jax.grad(energy))(vb), expected)
    np.testing.assert_array_equal(jax.jit(jax.vmap(jax.grad(energy)))(vb), expected)
