"""Forward-mode derivatives of `voxelize`: jvp, jacfwd, linearize, linear_transpose.

Oracles: central finite differences of the forward kernel (an independent computation:
shadow volumes, not the transport theorem), the reverse-mode kernel through the adjoint
identity <u, J t> = <J^T u, t>, and plain Python loops for the batching rules.
"""

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from conftest import random_polygon, random_star_mesh

import voxax
from voxax import Grid

GRID3 = Grid(lower=(-0.83, -0.79, -0.88), upper=(0.81, 0.86, 0.77), shape=(7, 6, 8))
GRID2 = Grid(lower=(-0.83, -0.79), upper=(0.81, 0.86), shape=(9, 8))


def _self_intersecting(rng):
    """Two overlapping star meshes in one mesh (W reaches 2 in the overlap), one of them
    with a vertex pushed through the opposite side (a folded, self-crossing surface)."""
    v1, f1 = random_star_mesh(rng, center=(-0.15, 0.05, 0.0), scale=0.5)
    v2, f2 = random_star_mesh(rng, center=(0.2, -0.05, 0.1), scale=0.45)
    v2 = v2.copy()
    v2[0] = v2[0] - np.array([0.0, 0.0, 1.1])  # the top vertex pokes out through the bottom
    return np.concatenate([v1, v2]), np.concatenate([f1, f2 + len(v1)]).astype(np.int32)


def _box(rng):
    """An axis-aligned box (vertical faces) with corners off the grid planes."""
    m = voxax.data.box((-0.41, -0.37, -0.52), (0.46, 0.33, 0.39))
    return np.asarray(m.vertices), np.asarray(m.faces)


def _meshes_3d():
    rng = np.random.default_rng(7)
    return {
        "star": random_star_mesh(rng, scale=0.6),
        "box_vertical_faces": _box(rng),
        "self_intersecting": _self_intersecting(rng),
        "partly_outside": random_star_mesh(rng, center=(0.5, -0.4, 0.6), scale=0.55),
    }


def _meshes_2d():
    rng = np.random.default_rng(8)
    v1, f1 = random_polygon(rng, n=11, scale=0.6)
    v2, f2 = random_polygon(rng, n=7, center=(0.25, 0.1), scale=0.45)
    v2 = v2.copy()
    v2[0] = -v2[0]  # a vertex dragged across: the loop crosses itself
    square = np.array([[-0.41, -0.37], [0.46, -0.37], [0.46, 0.33], [-0.41, 0.33]])
    sq_f = np.array([[0, 1], [1, 2], [2, 3], [3, 0]], np.int32)
    return {
        "polygon": (v1, f1),
        "square_vertical_segments": (square, sq_f),
        "self_intersecting": (np.concatenate([v1, v2]), np.concatenate([f1, f2 + len(v1)]).astype(np.int32)),
    }


def _cases():
    for name, (v, f) in _meshes_3d().items():
        yield pytest.param(v, f, GRID3, id=f"3d-{name}")
    for name, (v, f) in _meshes_2d().items():
        yield pytest.param(v, f, GRID2, id=f"2d-{name}")


CASES = list(_cases())


def _fn(f, grid):
    return lambda x: voxax.voxelize(x, f, grid)


@pytest.mark.parametrize("v, f, grid", CASES)
def test_jvp_matches_central_differences(v, f, grid):
    rng = np.random.default_rng(11)
    t = rng.normal(size=v.shape)
    fn = _fn(f, grid)
    W, dW = jax.jvp(fn, (jnp.asarray(v),), (jnp.asarray(t),))
    np.testing.assert_array_equal(W, fn(jnp.asarray(v)))
    eps = 1e-7
    fd = (np.asarray(fn(jnp.asarray(v + eps * t))) - np.asarray(fn(jnp.asarray(v - eps * t)))) / (2 * eps)
    assert np.abs(fd).max() > 1e-2  # the direction moves the grid
    assert np.abs(np.asarray(dW) - fd).max() <= 1e-6


@pytest.mark.parametrize("v, f, grid", CASES)
def test_jvp_and_vjp_are_adjoint(v, f, grid):
    rng = np.random.default_rng(12)
    fn = _fn(f, grid)
    x = jnp.asarray(v)
    for _ in range(3):
        t = jnp.asarray(rng.normal(size=v.shape))
        u = jnp.asarray(rng.normal(size=grid.shape))
        _, Jt = jax.jvp(fn, (x,), (t,))
        _, vjp = jax.vjp(fn, x)
        (JTu,) = vjp(u)
        lhs, rhs = float(jnp.vdot(u, Jt)), float(jnp.vdot(JTu, t))
        scale = float(jnp.linalg.norm(u) * jnp.linalg.norm(Jt) + jnp.linalg.norm(JTu) * jnp.linalg.norm(t))
        assert abs(lhs - rhs) <= 1e-12 * scale


@pytest.mark.parametrize(
    "dim",
    [3, 2],
)
def test_jacfwd_equals_jacrev(dim):
    rng = np.random.default_rng(13)
    if dim == 3:
        v, f = random_star_mesh(rng, n_theta=4, n_phi=3, scale=0.6)
        grid = Grid(lower=(-0.7, -0.6, -0.65), upper=(0.65, 0.7, 0.6), shape=(4, 3, 5))
    else:
        v, f = random_polygon(rng, n=6, scale=0.6)
        grid = Grid(lower=(-0.7, -0.6), upper=(0.65, 0.7), shape=(5, 4))
    fn = _fn(f, grid)
    x = jnp.asarray(v)
    Jf = np.asarray(jax.jacfwd(fn)(x))
    Jr = np.asarray(jax.jacrev(fn)(x))
    assert Jf.shape == grid.shape + v.shape
    assert np.abs(Jf).max() > 0.1
    np.testing.assert_allclose(Jf, Jr, rtol=0, atol=1e-13 * np.abs(Jr).max())
    # Under jit as well.
    np.testing.assert_array_equal(jax.jit(jax.jacfwd(fn))(x), Jf)


def test_vmap_of_jvp_equals_loop_bit_for_bit():
    rng = np.random.default_rng(14)
    v, f = _meshes_3d()["self_intersecting"]
    fn = _fn(f, GRID3)
    ts = jnp.asarray(rng.normal(size=(4,) + v.shape))
    vs = jnp.asarray(v[None] + 0.02 * rng.normal(size=(4,) + v.shape))
    jvp_t = lambda t: jax.jvp(fn, (jnp.asarray(v),), (t,))[1]  # noqa: E731
    jvp_vt = lambda x, t: jax.jvp(fn, (x,), (t,))[1]  # noqa: E731
    loop_t = np.stack([np.asarray(jvp_t(ts[i])) for i in range(4)])
    loop_vt = np.stack([np.asarray(jvp_vt(vs[i], ts[i])) for i in range(4)])
    np.testing.assert_array_equal(jax.vmap(jvp_t)(ts), loop_t)
    np.testing.assert_array_equal(jax.jit(jax.vmap(jvp_t))(ts), loop_t)
    np.testing.assert_array_equal(jax.vmap(jvp_vt)(vs, ts), loop_vt)
    np.testing.assert_array_equal(jax.jit(jax.vmap(jvp_vt))(vs, ts), loop_vt)
    # Nested: a batch of meshes, each with a batch of tangents.
    nested = jax.vmap(lambda x, tt: jax.vmap(lambda t: jvp_vt(x, t))(tt))(vs, jnp.stack([ts] * 4))
    for i in range(4):
        for j in range(4):
            np.testing.assert_array_equal(nested[i, j], jvp_vt(vs[i], ts[j]))


def test_batched_vertices_and_faces_with_jvp():
    """Leading batch axes on vertices broadcast against the faces in forward mode too."""
    rng = np.random.default_rng(15)
    v, f = random_star_mesh(rng, scale=0.6)
    vs = jnp.asarray(v[None] * np.array([1.0, 0.9, 1.1])[:, None, None])
    ts = jnp.asarray(rng.normal(size=vs.shape))
    _, dW = jax.jvp(_fn(f, GRID3), (vs,), (ts,))
    for i in range(3):
        np.testing.assert_array_equal(dW[i], jax.jvp(_fn(f, GRID3), (vs[i],), (ts[i],))[1])


def test_linearize_and_linear_transpose():
    rng = np.random.default_rng(16)
    v, f = _meshes_3d()["star"]
    fn = _fn(f, GRID3)
    x = jnp.asarray(v)
    t = jnp.asarray(rng.normal(size=v.shape))
    u = jnp.asarray(rng.normal(size=GRID3.shape))
    _, lin = jax.linearize(fn, x)
    np.testing.assert_array_equal(lin(t), jax.jvp(fn, (x,), (t,))[1])
    lin_t = jax.linear_transpose(lin, x)
    (JTu,) = lin_t(u)
    np.testing.assert_array_equal(JTu, jax.vjp(fn, x)[1](u)[0])
    # The transpose of the transpose is the linear map again.
    lin_tt = jax.linear_transpose(lambda c: lin_t(c)[0], u)
    np.testing.assert_array_equal(lin_tt(t)[0], lin(t))
    # grad of a linear function of the jvp: the backward kernel through the transpose.
    g = jax.grad(lambda tt: jnp.vdot(u, lin(tt)))(t)
    np.testing.assert_array_equal(g, JTu)


def test_float32_jvp_matches_float64():
    rng = np.random.default_rng(17)
    v, f = _meshes_3d()["star"]
    t = rng.normal(size=v.shape)
    fn = _fn(f, GRID3)
    d64 = jax.jvp(fn, (jnp.asarray(v),), (jnp.asarray(t),))[1]
    d32 = jax.jvp(fn, (jnp.asarray(v, jnp.float32),), (jnp.asarray(t, jnp.float32),))[1]
    assert d32.dtype == jnp.float32
    np.testing.assert_allclose(d32, d64, rtol=0, atol=1e-5 * float(jnp.abs(d64).max()))


def test_gauss_newton_product_and_hessian_message():
    rng = np.random.default_rng(18)
    v, f = random_star_mesh(rng, n_theta=4, n_phi=3, scale=0.6)
    grid = Grid(lower=(-0.7, -0.6, -0.65), upper=(0.65, 0.7, 0.6), shape=(4, 3, 5))
    fn = _fn(f, grid)
    x = jnp.asarray(v)
    target = jnp.asarray(rng.uniform(0, 1, grid.shape))
    h = jnp.asarray(rng.uniform(0.5, 2.0, grid.shape))  # diagonal grid-space curvature
    t = jnp.asarray(rng.normal(size=v.shape))
    _, Jt = jax.jvp(fn, (x,), (t,))
    gn = jax.vjp(fn, x)[1](h * Jt)[0]
    J = np.asarray(jax.jacrev(fn)(x)).reshape(grid.size, -1)
    expected = (J.T @ (np.asarray(h).reshape(-1)[:, None] * J)) @ np.asarray(t).reshape(-1)
    np.testing.assert_allclose(np.asarray(gn).reshape(-1), expected, rtol=1e-11, atol=1e-13)
    energy = lambda y: 0.5 * jnp.sum(h * (fn(y) - target) ** 2)  # noqa: E731
    for second in (jax.hessian(energy), jax.jacrev(jax.grad(energy))):
        with pytest.raises(NotImplementedError, match="Gauss-Newton"):
            second(x)
    with pytest.raises(NotImplementedError, match="Gauss-Newton"):
        jax.jit(jax.hessian(energy))(x)


def test_bad_tangents_give_clear_errors():
    v, f = _meshes_3d()["star"]
    fn = _fn(f, GRID3)
    x = jnp.asarray(v)
    jitted = jax.jit(lambda y, t: jax.jvp(fn, (y,), (t,))[1])
    for call in (lambda y, t: jax.jvp(fn, (y,), (t,)), jitted):
        with pytest.raises(ValueError, match="shape"):
            call(x, jnp.ones((len(v), 2)))
        with pytest.raises(TypeError, match="dtype"):
            call(x, jnp.ones(v.shape, jnp.float32))
        with pytest.raises(TypeError, match="dtype"):
            call(x, jnp.ones(v.shape, jnp.int32))
    bad = jnp.ones(v.shape).at[3, 1].set(jnp.nan)
    with pytest.raises(Exception, match="tangents contain NaN or Inf"):
        jax.block_until_ready(jax.jvp(fn, (x,), (bad,))[1])
    with pytest.raises(Exception, match="tangents contain NaN or Inf"):
        jax.block_until_ready(jitted(x, bad))
    # Still fine afterwards.
    assert np.isfinite(np.asarray(jitted(x, jnp.ones(v.shape)))).all()


def test_tangent_kernel_rejects_malformed_calls():
    """The kernel validates shapes and dtypes itself (whatever reaches it directly)."""
    from voxax import _kernels

    v, f = _meshes_3d()["star"]
    x = jnp.asarray(v)
    faces = jnp.asarray(f, jnp.int32)
    attrs = _kernels.grid_attributes(GRID3)
    out = jax.ShapeDtypeStruct(GRID3.shape, jnp.float64)
    call = jax.ffi.ffi_call(_kernels.TANGENT, out)
    good = jnp.zeros((len(f), 3, 3))
    assert float(jnp.abs(call(x, faces, good, **attrs)).max()) == 0.0
    with pytest.raises(Exception, match="corner tangents must have shape"):
        jax.block_until_ready(call(x, faces, jnp.zeros((len(f), 3, 2)), **attrs))
    with pytest.raises(Exception, match="tangent and output dtypes"):
        jax.block_until_ready(call(x, faces, jnp.zeros((len(f), 3, 3), jnp.float32), **attrs))
    with pytest.raises(Exception, match="out of range"):
        jax.block_until_ready(call(x, faces.at[0, 0].set(len(v)), good, **attrs))
    with pytest.raises(Exception, match="does not match the grid"):
        jax.block_until_ready(jax.ffi.ffi_call(_kernels.TANGENT, jax.ShapeDtypeStruct((3, 3, 3), jnp.float64))(x, faces, good, **attrs))


def test_jvp_through_host_callback_matches_ffi():
    v, f = _meshes_3d()["self_intersecting"]
    x = jnp.asarray(v)
    t = jnp.asarray(np.random.default_rng(19).normal(size=v.shape))
    fn = _fn(f, GRID3)
    ref = jax.jvp(fn, (x,), (t,))[1]
    voxax.use_host_callback(True)
    try:
        jitted = jax.jit(lambda y, tt: jax.jvp(fn, (y,), (tt,))[1])
        np.testing.assert_array_equal(jitted(x, t), ref)
        assert "voxax_tangent" not in jitted.lower(x, t).as_text()
    finally:
        voxax.use_host_callback(False)
