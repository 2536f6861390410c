"""ARAP energy (spokes and rims, cotangent weights): invariances, gradients, robustness."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from conftest import random_star_mesh

import voxax
from voxax import energies as E


def random_rotation(rng):
    q, r = np.linalg.qr(rng.normal(size=(3, 3)))
    q = q * np.sign(np.diag(r))
    if np.linalg.det(q) < 0:
        q[:, 0] = -q[:, 0]
    return q


def mesh(name):
    m = voxax.data.get(name)
    return np.asarray(m.vertices, np.float64), np.asarray(m.faces, np.int32)


def arap_numpy(V, rest, F):
    """An independent loop-based implementation (clamped per-face cot/2 weights)."""
    nV = len(V)
    weights = np.zeros(F.shape)
    for f, tri in enumerate(F):
        for k in range(3):
            a, b, c = rest[tri[k]], rest[tri[(k + 1) % 3]], rest[tri[(k + 2) % 3]]
            u, v = b - a, c - a
            cot = np.dot(u, v) / np.linalg.norm(np.cross(u, v))
            weights[f, k] = np.clip(cot / 2, 1e-4, 1e4)
    cells = [[] for _ in range(nV)]
    for f, tri in enumerate(F):
        for k in range(3):
            j, m = tri[(k + 1) % 3], tri[(k + 2) % 3]
            for i in tri:
                cells[i].append((weights[f, k], j, m))
    total = 0.0
    for i in range(nV):
        S = np.zeros((3, 3))
        for w, j, m in cells[i]:
            S += w * np.outer(rest[m] - rest[j], V[m] - V[j])
        U, _, Vt = np.linalg.svd(S)
        R = Vt.T @ U.T
        if np.linalg.det(R) < 0:
            U[:, -1] *= -1
            R = Vt.T @ U.T
        for w, j, m in cells[i]:
            r = (V[m] - V[j]) - R @ (rest[m] - rest[j])
            total += w * r @ r
    area = sum(0.5 * np.linalg.norm(np.cross(rest[b] - rest[a], rest[c] - rest[a])) for a, b, c in F)
    return total / area


@pytest.mark.parametrize("name", ["icosphere", "hand"])
def test_rigid_motions_have_zero_energy(name, rng):
    rest, F = mesh(name)
    for _ in range(2):
        Q = random_rotation(rng)
        V = rest @ Q.T + rng.normal(size=3)
        assert float(E.arap(V, rest, F)) <= 1e-10
        assert float(E.arap(V, rest, F, normalize=False)) <= 1e-10
        R = E.arap_rotations(V, rest, F)
        np.testing.assert_allclose(np.asarray(R), np.broadcast_to(Q, R.shape), atol=1e-8)


@pytest.mark.parametrize("name", ["icosphere", "torus"])
def test_non_rigid_deformations_have_positive_energy(name, rng):
    rest, F = mesh(name)
    cases = {
        "scale": rest * 1.1,
        "stretch": rest * np.array([1.2, 1.0, 1.0]),
        "noise": rest + 0.01 * rng.normal(size=rest.shape),
        "bend": rest + np.stack([np.zeros(len(rest)), 0.3 * rest[:, 0] ** 2, np.zeros(len(rest))], 1),
    }
    for label, V in cases.items():
        assert float(E.arap(V, rest, F)) > 1e-5, label
    # Larger deformations cost more.
    assert float(E.arap(rest * 1.2, rest, F)) > float(E.arap(rest * 1.1, rest, F))


def test_matches_independent_loop_implementation(rng):
    rest, F = random_star_mesh(rng)
    V = rest + 0.05 * rng.normal(size=rest.shape)
    np.testing.assert_allclose(float(E.arap(V, rest, F)), arap_numpy(V, rest, F), rtol=1e-10)


def test_rotations_are_proper_even_for_mirrored_shapes(rng):
    rest, F = mesh("icosphere")
    for V in (rest * np.array([-1.0, 1.0, 1.0]), rest + 0.1 * rng.normal(size=rest.shape)):
        R = np.asarray(E.arap_rotations(V, rest, F))
        np.testing.assert_allclose(np.linalg.det(R), 1.0, atol=1e-10)
        np.testing.assert_allclose(R @ np.swapaxes(R, -1, -2), np.broadcast_to(np.eye(3), R.shape), atol=1e-10)
    # A mirror image is not a rigid motion.
    assert float(E.arap(rest * np.array([-1.0, 1.0, 1.0]), rest, F)) > 1e-3


def test_gradient_matches_finite_differences_with_fixed_rotations(rng):
    rest, F = random_star_mesh(rng)
    V = rest + 0.05 * rng.normal(size=rest.shape)
    R0 = E.arap_rotations(V, rest, F)
    g = np.asarray(jax.grad(E.arap)(jnp.asarray(V), rest, F))
    h = 1e-6
    n = V.size
    dV = (h * np.eye(n)).reshape(n, *V.shape)
    fixed = jax.jit(jax.vmap(lambda X: E.arap(X, rest, F, rotations=R0)))
    full = jax.jit(jax.vmap(lambda X: E.arap(X, rest, F)))
    fd_fixed = np.asarray((fixed(V + dV) - fixed(V - dV)) / (2 * h)).reshape(V.shape)
    fd_full = np.asarray((full(V + dV) - full(V - dV)) / (2 * h)).reshape(V.shape)
    scale = np.abs(fd_fixed).max()
    assert scale > 1e-3
    assert np.abs(g - fd_fixed).max() <= 1e-6 * scale
    # The rotations are optimal, so (envelope theorem) this is also the gradient of the
    # energy minimized over rotations.
    assert np.abs(g - fd_full).max() <= 1e-5 * scale
    # With rotations given explicitly the gradient is the same.
    g_fixed = np.asarray(jax.grad(lambda X: E.arap(X, rest, F, rotations=R0))(jnp.asarray(V)))
    np.testing.assert_allclose(g_fixed, g, atol=1e-12 * scale)


def test_rotations_carry_no_gradient(rng):
    rest, F = random_star_mesh(rng)
    V = jnp.asarray(rest + 0.05 * rng.normal(size=rest.shape))
    J = jax.jacrev(lambda X: E.arap_rotations(X, rest, F))(V)
    assert float(jnp.abs(J).max()) == 0.0


def test_cotangent_weights_known_values_and_degenerate_triangles():
    V = np.array([
        [0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.5, np.sqrt(3) / 2, 0.0],  # equilateral
        [0.0, 0.0, 1.0], [1.0, 0.0, 1.0], [0.0, 1.0, 1.0],              # right angle at 3
        [0.0, 0.0, 2.0], [4.0, 0.0, 2.0], [2.0, 0.1, 2.0],              # obtuse at 8
        [0.0, 0.0, 3.0], [1.0, 0.0, 3.0], [2.0, 0.0, 3.0],              # collinear
        [5.0, 5.0, 5.0],                                                # repeated vertex
    ])
    F = np.array([[0, 1, 2], [3, 4, 5], [6, 7, 8], [9, 10, 11], [12, 12, 0], [12, 12, 12]], np.int32)
    w = np.asarray(E.cotangent_weights(V, F))
    assert np.all(np.isfinite(w))
    np.testing.assert_allclose(w[0], 0.5 / np.sqrt(3), rtol=1e-12)
    np.testing.assert_allclose(w[1], [1e-4, 0.5, 0.5], rtol=1e-12)
    assert w[2, 2] == pytest.approx(1e-4)  # obtuse: clamped up
    assert np.all((w >= 1e-4) & (w <= 1e4))
    # The energy and its gradient stay finite with degenerate triangles around.
    Vd = V + 0.01 * np.arange(V.size).reshape(V.shape) ** 0.5
    e, g = jax.value_and_grad(E.arap)(jnp.asarray(Vd), V, F)
    assert np.isfinite(float(e)) and np.all(np.isfinite(np.asarray(g)))
    assert np.all(np.isfinite(np.asarray(E.arap_rotations(Vd, V, F))))


def test_jit_vmap_and_custom_weights(rng):
    rest, F = mesh("icosphere")
    Vs = rest[None] + 0.02 * rng.normal(size=(3, *rest.shape))
    batched = jax.jit(jax.vmap(lambda V: E.arap(V, rest, F)))(Vs)
    one_by_one = np.array([float(E.arap(V, rest, F)) for V in Vs])
    np.testing.assert_allclose(np.asarray(batched), one_by_one, rtol=1e-12)
    w = E.cotangent_weights(rest, F)
    np.testing.assert_allclose(float(E.arap(Vs[0], rest, F, w)), one_by_one[0], rtol=1e-12)
    uniform = jnp.ones(F.shape)
    assert float(E.arap(Vs[0], rest, F, uniform)) != pytest.approx(one_by_one[0])
    with pytest.raises(ValueError):
        E.arap(Vs[0], rest[:-1], F)
    with pytest.raises(ValueError):
        E.arap(Vs[0], rest, F, jnp.ones((3,)))


def test_float32_rigid_motion(rng):
    rest, F = mesh("torus")
    Q = random_rotation(rng)
    V = (rest @ Q.T + 0.5).astype(np.float32)
    e = E.arap(jnp.asarray(V), rest.astype(np.float32), F)
    assert e.dtype == jnp.float32
    assert float(e) < 1e-8


def test_planar_meshes(rng):
    """2D triangle meshes work too (2x2 rotations)."""
    rest = rng.random((6, 2))
    F = np.array([[0, 1, 2], [1, 3, 2], [2, 3, 4], [3, 5, 4]], np.int32)
    th = 0.7
    Q = np.array([[np.cos(th), -np.sin(th)], [np.sin(th), np.cos(th)]])
    assert float(E.arap(rest @ Q.T + 1.0, rest, F)) <= 1e-10
    assert float(E.arap(rest * np.array([1.3, 1.0]), rest, F)) > 1e-4
