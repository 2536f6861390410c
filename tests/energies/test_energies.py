"""Grid energies: mellowmax, silhouettes and the bandsaw cut, self-intersection, tiling,
volume, interpenetration; finite-difference gradients through `voxax.voxelize`."""

import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from conftest import random_star_mesh

import voxax
from voxax import energies as E

# ---------------------------------------------------------------------------------------
# mellowmax
# ---------------------------------------------------------------------------------------


def test_mellowmax_converges_to_the_max(rng):
    x = jnp.asarray(rng.random((5, 17)))
    mx = np.asarray(x.max(-1))
    errors = []
    for w in (10.0, 100.0, 1000.0, 1e4):
        mm = np.asarray(E.mellowmax(x, w))
        gap = mx - mm
        # Between the mean and the max, at most log(N)/w below the max.
        assert np.all(gap >= -1e-12) and np.all(gap <= math.log(17) / w + 1e-12)
        assert np.all(mm >= np.asarray(x.mean(-1)) - 1e-12)
        errors.append(gap.max())
    assert all(a > b for a, b in zip(errors, errors[1:]))
    assert errors[-1] < 3e-4


def test_mellowmax_formula_and_axis(rng):
    x = rng.random((3, 4, 5))
    for axis in (0, 1, 2, -1):
        got = np.asarray(E.mellowmax(x, 7.0, axis=axis))
        want = np.log(np.mean(np.exp(7.0 * x), axis=axis)) / 7.0
        np.testing.assert_allclose(got, want, rtol=1e-12)


@pytest.mark.parametrize("w", [5.0, 100.0, 1e4])
def test_mellowmax_gradient_is_the_softmax(rng, w):
    x = jnp.asarray(rng.random(11))
    g = jax.grad(lambda x: E.mellowmax(x, w))(x)
    np.testing.assert_allclose(np.asarray(g), np.asarray(jax.nn.softmax(w * x)), rtol=1e-10, atol=1e-14)
    # Ties share the gradient.
    g = jax.grad(lambda x: E.mellowmax(x, w))(jnp.array([1.0, 1.0, 0.0]))
    assert float(g[0]) == pytest.approx(float(g[1])) and float(g.sum()) == pytest.approx(1.0)


def test_mellowmax_is_stable_for_large_w_and_values():
    for x in (jnp.array([1e6, -1e6, 3e5]), jnp.array([1e200, 1e199]), jnp.array([-1e8, -1e8 - 1.0])):
        v, g = jax.value_and_grad(lambda x: E.mellowmax(x, 1e4))(x)
        assert np.isfinite(float(v)) and np.all(np.isfinite(np.asarray(g)))
        assert float(v) == pytest.approx(float(x.max()), rel=1e-9)
    x32 = jnp.array([1e4, 3.0, -50.0], jnp.float32)
    v = E.mellowmax(x32, 1e4)
    assert v.dtype == jnp.float32 and np.isfinite(float(v))


# ---------------------------------------------------------------------------------------
# silhouettes, cut shape, bandsaw
# ---------------------------------------------------------------------------------------


def test_silhouettes_shapes_and_values(rng):
    W = jnp.asarray(rng.random((4, 5, 6)))
    Sx, Sy, Sz = E.silhouettes(W, w=1e5)
    assert Sx.shape == (5, 6) and Sy.shape == (4, 6) and Sz.shape == (4, 5)
    np.testing.assert_allclose(np.asarray(Sx), np.asarray(W.max(0)), atol=1e-4)
    np.testing.assert_allclose(np.asarray(Sy), np.asarray(W.max(1)), atol=1e-4)
    np.testing.assert_allclose(np.asarray(Sz), np.asarray(W.max(2)), atol=1e-4)
    S = np.asarray(E.cut_shape(W, w=1e5))
    want = np.einsum("jk,ik,ij->ijk", *(np.asarray(s) for s in (Sx, Sy, Sz)))
    np.testing.assert_allclose(S, want, rtol=1e-12)
    # Batch axes.
    Wb = jnp.stack([W, 2 * W])
    assert E.cut_shape(Wb).shape == (2, 4, 5, 6)
    np.testing.assert_allclose(np.asarray(E.silhouettes(Wb)[1][1]), np.asarray(E.silhouettes(2 * W)[1]), rtol=1e-12)


def test_bandsaw_cut_is_small_for_cuttable_shapes_and_large_otherwise():
    box = np.zeros((8, 8, 8))
    box[2:6, 1:7, 3:5] = 1.0
    assert float(E.bandsaw_cut(box, w=1e4)) < 1e-6
    # An L-shaped prism is cuttable (extrusion of its silhouette along z) ...
    L = np.zeros((8, 8, 8))
    L[1:7, 1:3, 2:6] = 1.0
    L[1:3, 1:7, 2:6] = 1.0
    assert float(E.bandsaw_cut(L, w=1e4)) < 1e-6
    # ... a checkerboard of four voxels in a 2^3 block is not: cutting leaves the whole block.
    C = np.zeros((4, 4, 4))
    for i, j, k in [(0, 0, 0), (1, 1, 0), (1, 0, 1), (0, 1, 1)]:
        C[1 + i, 1 + j, 1 + k] = 1.0
    S = np.asarray(E.cut_shape(C, w=1e4))
    np.testing.assert_allclose(S[1:3, 1:3, 1:3], 1.0, atol=1e-3)
    assert S.sum() == pytest.approx(8.0, abs=1e-2)
    assert float(E.bandsaw_cut(C, w=1e4)) == pytest.approx(4 / 64, rel=1e-2)


# ---------------------------------------------------------------------------------------
# self-intersection
# ---------------------------------------------------------------------------------------


def test_self_intersection_values():
    W = np.zeros((4, 4, 4))
    W[0, 0, 0] = 2.0
    W[1, 0, 0] = 1.0005  # below 1 + eps: ignored
    W[2, 0, 0] = 1.5
    assert float(E.self_intersection(W)) == pytest.approx((4.0 + 2.25) / 64)
    assert float(E.self_intersection(W, eps=0.0)) == pytest.approx((4.0 + 2.25 + 1.0005**2) / 64)
    grid = voxax.Grid.cube(16)
    for name, positive in (("overlapping_cubes", True), ("bent_bar", True), ("icosphere", False), ("cube", False)):
        m = voxax.data.get(name)
        W = voxax.voxelize(m.vertices, m.faces, grid)
        assert (float(E.self_intersection(W)) > 0) == positive, name


# ---------------------------------------------------------------------------------------
# periodic folding and tiling
# ---------------------------------------------------------------------------------------


def test_fold_periodic_conserves_the_sum_and_is_periodic(rng):
    W = rng.random((2, 3, 12, 9, 15))
    cell = E.fold_periodic(W, blocks=3)
    assert cell.shape == (4, 3, 5)
    assert float(cell.sum()) == pytest.approx(W.sum(), rel=1e-13)
    assert float(E.fold_periodic(W[0, 0], blocks=1).sum()) == pytest.approx(W[0, 0].sum(), rel=1e-13)
    # Moving content by whole blocks leaves the cell unchanged.
    V = np.zeros((12, 12, 12))
    V[1:3, 2:5, 0:2] = rng.random((2, 3, 2))
    moved = np.zeros_like(V)
    moved[5:7, 10:12, 8:10] = V[1:3, 2:4, 0:2]
    moved[5:7, 0:1, 8:10] = V[1:3, 4:5, 0:2]  # wrapped round the periodic cell
    np.testing.assert_allclose(np.asarray(E.fold_periodic(moved, 3)), np.asarray(E.fold_periodic(V, 3)), rtol=1e-13)
    with pytest.raises(ValueError):
        E.fold_periodic(np.zeros((10, 9, 9)), 3)


def test_tiling_energy():
    full = np.ones((27, 12, 12, 12)) / 27.0**2  # 27 instances x 27 blocks
    assert float(E.tiling(full)) == pytest.approx(0.0, abs=1e-20)
    assert float(E.tiling(np.zeros((12, 12, 12)))) == pytest.approx(64.0)
    assert float(E.tiling(np.zeros((12, 12, 12)), normalize=True)) == pytest.approx(1.0)
    two = np.zeros((2, 6, 6, 6))
    two[0, 0:2, 0:3, 0:3] = 1.0  # two thirds of the periodic cell ...
    two[1, 5:6, 3:6, 0:3] = 1.0  # ... and the last third, in another block
    assert float(E.tiling(two, blocks=2)) == pytest.approx(0.0)
    assert float(E.tiling(two[:1], blocks=2)) == pytest.approx(9.0)


# ---------------------------------------------------------------------------------------
# volume and interpenetration
# ---------------------------------------------------------------------------------------


def signed_volume(V, F):
    a, b, c = V[F[:, 0]], V[F[:, 1]], V[F[:, 2]]
    return np.einsum("ij,ij->i", a, np.cross(b, c)).sum() / 6.0


def test_volume_matches_the_mesh_volume(rng):
    V, F = random_star_mesh(rng, scale=0.6)
    grid = voxax.Grid(lower=(-1, -1.1, -0.9), upper=(1, 1.2, 1), shape=(9, 11, 10))
    W = voxax.voxelize(V, F, grid)
    assert float(E.volume(W, grid)) == pytest.approx(signed_volume(V, F), rel=1e-10)
    Ws = jnp.stack([W, 2 * W])
    np.testing.assert_allclose(np.asarray(E.volume(Ws, grid)), [signed_volume(V, F), 2 * signed_volume(V, F)], rtol=1e-10)


def test_interpenetration(rng):
    grid = voxax.Grid.cube(16)
    Va, Fa = random_star_mesh(rng, center=(-0.45, 0, 0), scale=0.4)
    Vb, Fb = random_star_mesh(rng, center=(0.45, 0, 0), scale=0.4)
    Wa, Wb = voxax.voxelize(Va, Fa, grid), voxax.voxelize(Vb, Fb, grid)
    assert float(E.interpenetration(Wa, Wb)) == 0.0

    def energy(Va, Vb):
        return E.interpenetration(voxax.voxelize(Va, Fa, grid), voxax.voxelize(Vb, Fb, grid))

    Vb2 = Vb - np.array([0.4, 0.0, 0.0])
    assert float(energy(Va, Vb2)) > 0
    ga, gb = jax.grad(energy, argnums=(0, 1))(jnp.asarray(Va), jnp.asarray(Vb2))
    assert float(jnp.abs(ga).max()) > 0 and float(jnp.abs(gb).max()) > 0
    # Moving along the negative gradient separates them: a moves left, b moves right.
    assert float(ga[:, 0].sum()) > 0 and float(gb[:, 0].sum()) < 0


# ---------------------------------------------------------------------------------------
# finite-difference gradients through voxelize
# ---------------------------------------------------------------------------------------


def two_overlapping_stars(rng):
    Va, Fa = random_star_mesh(rng, center=(-0.12, 0.03, 0.02), scale=0.45)
    Vb, Fb = random_star_mesh(rng, center=(0.15, -0.04, 0.05), scale=0.4)
    return np.concatenate([Va, Vb]), np.concatenate([Fa, Fb + len(Va)]).astype(np.int32)


def check_directional_fd(f, V, rng, n_dirs=3, h=1e-6, rtol=1e-5):
    """Checks <grad f(V), D> against central differences along random directions D."""
    V = jnp.asarray(V)
    value, g = jax.jit(jax.value_and_grad(f))(V)
    assert np.isfinite(float(value)) and np.all(np.isfinite(np.asarray(g)))
    assert float(jnp.abs(g).max()) > 0, "gradient is identically zero"
    D = jnp.asarray(rng.normal(size=(n_dirs, *V.shape)))
    fv = jax.jit(jax.vmap(f))
    fd = (fv(V + h * D) - fv(V - h * D)) / (2 * h)
    ad = jnp.sum(D * g, axis=tuple(range(1, D.ndim)))
    np.testing.assert_allclose(np.asarray(ad), np.asarray(fd), rtol=rtol, atol=rtol * float(jnp.abs(fd).max()))


GRID = voxax.Grid(lower=(-1.0, -0.97, -1.03), upper=(1.01, 1.0, 0.98), shape=(12, 13, 14))


@pytest.mark.parametrize(
    "name, energy",
    [
        ("self_intersection", lambda W: E.self_intersection(W)),
        ("bandsaw_cut", lambda W: E.bandsaw_cut(W, w=5.0)),
        ("silhouettes", lambda W: sum(jnp.sum(s * (1 + jnp.arange(s.size).reshape(s.shape) % 3)) for s in E.silhouettes(W, w=5.0))),
        ("cut_shape", lambda W: jnp.sum(E.cut_shape(W, w=5.0) ** 2)),
        ("volume", lambda W: E.volume(W, GRID) ** 2),
        ("mellowmax", lambda W: jnp.sum(E.mellowmax(W, 5.0, axis=1) ** 2)),
    ],
)
def test_grid_energy_gradients_through_voxelize(rng, name, energy):
    V, F = two_overlapping_stars(rng)
    V = V + 1e-3 * rng.normal(size=V.shape)
    check_directional_fd(lambda X: energy(voxax.voxelize(X, F, GRID)), V, rng)


def test_tiling_gradient_through_voxelize(rng):
    grid = voxax.Grid.cube(15)  # 3 x 3 x 3 blocks of 5^3
    V, F = random_star_mesh(rng, scale=0.5)  # sticks out of the middle block
    Vs = np.stack([V + np.array([0.11, -0.07, 0.05]), V @ np.diag([1.0, -1.0, -1.0]) - 0.13])
    Vs = Vs + 1e-3 * rng.normal(size=Vs.shape)
    f = lambda X: E.tiling(jax.vmap(lambda v: voxax.voxelize(v, F, grid))(X))
    check_directional_fd(f, Vs, rng)


def test_interpenetration_gradient_through_voxelize(rng):
    Va, Fa = random_star_mesh(rng, center=(-0.2, 0.0, 0.03), scale=0.45)
    Vb, Fb = random_star_mesh(rng, center=(0.2, 0.02, -0.01), scale=0.45)
    f = lambda X: E.interpenetration(voxax.voxelize(X[0], Fa, GRID), voxax.voxelize(X[1], Fb, GRID))
    check_directional_fd(f, np.stack([Va, Vb]), rng)


def test_energies_under_jit_and_vmap(rng):
    W = jnp.asarray(rng.random((3, 6, 6, 6)))
    for fn in (E.bandsaw_cut, E.self_intersection, lambda W: E.tiling(W, blocks=2)):
        batched = jax.jit(jax.vmap(fn))(W)
        np.testing.assert_allclose(np.asarray(batched), [float(fn(w)) for w in W], rtol=1e-12)


def test_objective_helper(rng):
    V, F = random_star_mesh(rng)
    grid = voxax.Grid.cube(12)
    fn = E.objective(
        {"vol": lambda y, a: E.volume(voxax.voxelize(y, F, a), a), "arap": lambda y, a: E.arap(y, V, F)},
        weights={"arap": 0.5},
        extras=lambda y, a: {"n": jnp.asarray(3.0)},
    )
    y = V * 1.1
    total, aux = jax.jit(fn, static_argnums=1)(y, grid)
    assert set(aux) == {"vol", "arap", "n"}
    assert float(total) == pytest.approx(float(aux["vol"]) + 0.5 * float(aux["arap"]))
    with pytest.raises(ValueError):
        E.objective({"a": lambda y, a: 0.0}, weights={"b": 1.0})
