"""Shared test set-up: float64 enabled, small random meshes."""

import jax
import numpy as np
import pytest

jax.config.update("jax_enable_x64", True)

import voxax  # noqa: E402, F401  (imported once x64 is on)


def random_star_mesh(rng, n_theta=6, n_phi=5, center=(0.0, 0.0, 0.0), scale=0.5, jitter=0.35):
    """A closed, outward-oriented, star-shaped (non-convex) mesh with random radii."""
    verts = [(0.0, 0.0, 1.0)]
    for i in range(1, n_phi):
        phi = np.pi * i / n_phi
        for j in range(n_theta):
            th = 2 * np.pi * j / n_theta
            verts.append((np.sin(phi) * np.cos(th), np.sin(phi) * np.sin(th), np.cos(phi)))
    verts.append((0.0, 0.0, -1.0))
    v = np.array(verts)
    r = 1.0 + jitter * (rng.random(len(v)) - 0.5)
    v = v * r[:, None] * scale + np.asarray(center)
    faces = []
    bottom = len(v) - 1
    for j in range(n_theta):
        faces.append((0, 1 + j, 1 + (j + 1) % n_theta))
    for i in range(n_phi - 2):
        a0, b0 = 1 + i * n_theta, 1 + (i + 1) * n_theta
        for j in range(n_theta):
            j1 = (j + 1) % n_theta
            faces.append((a0 + j, b0 + j, b0 + j1))
            faces.append((a0 + j, b0 + j1, a0 + j1))
    last = 1 + (n_phi - 2) * n_theta
    for j in range(n_theta):
        faces.append((bottom, last + (j + 1) % n_theta, last + j))
    return v, np.array(faces, dtype=np.int32)


def random_polygon(rng, n=9, center=(0.0, 0.0), scale=0.5, jitter=0.5):
    """A closed, counter-clockwise, star-shaped polygon with random radii."""
    th = np.sort(rng.random(n)) * 2 * np.pi
    r = scale * (1.0 + jitter * (rng.random(n) - 0.5))
    v = np.stack([r * np.cos(th), r * np.sin(th)], axis=1) + np.asarray(center)
    f = np.stack([np.arange(n), (np.arange(n) + 1) % n], axis=1).astype(np.int32)
    return v, f


@pytest.fixture
def rng():
    return np.random.default_rng(1234)


# -- an independent oracle of point-to-triangle distances (tests/spatial, tests/test_metrics.py) --


def _seg_dist(p, a, b):
    ab = b - a
    L = np.sum(ab * ab, -1)
    t = np.where(L > 0, np.sum((p - a) * ab, -1) / np.where(L > 0, L, 1), 0.0)
    t = np.clip(t, 0, 1)
    return np.linalg.norm(p - (a + t[..., None] * ab), axis=-1)


def brute_distance(p, V, F):
    """Distance from points (P, 3) to a triangle soup: the plane projection when it falls
    inside the triangle, else the nearest of the three edges (zero-area faces: edges only)."""
    a, b, c = (V[F[:, k]][None] for k in range(3))
    q = p[:, None, :]
    n = np.cross(b - a, c - a)
    nn = np.sum(n * n, -1)
    ok = nn > 1e-30
    nhat = n / np.sqrt(np.where(ok, nn, 1))[..., None]
    h = np.sum((q - a) * nhat, -1)
    proj = q - h[..., None] * nhat
    inside = ok.copy() & True
    for u, v in ((a, b), (b, c), (c, a)):
        inside = inside & (np.sum(np.cross(v - u, proj - u) * n, -1) >= 0)
    edges = np.minimum(
        np.minimum(_seg_dist(q, a, b), _seg_dist(q, b, c)), _seg_dist(q, c, a)
    )
    d = np.where(inside, np.abs(h), edges)
    return d.min(axis=1)
