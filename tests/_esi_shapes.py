"""Test shapes for the explicit-surface-intersection tests."""

import numpy as np

from voxax import Mesh
from voxax.data import mug  # noqa: F401 - the shared test shape


def rotation(seed: int) -> np.ndarray:
    """A random rotation matrix (QR of a Gaussian matrix, sign-fixed)."""
    q, r = np.linalg.qr(np.random.default_rng(seed).normal(size=(3, 3)))
    q = q * np.sign(np.diag(r))
    if np.linalg.det(q) < 0:
        q[:, 0] = -q[:, 0]
    return q


def brute_force_depths(mesh: Mesh, origins: np.ndarray, d: np.ndarray, margin: float = 1e-9):
    """Smallest and largest ray parameter where lines `origins + t d` (all t) meet the
    triangles, by plane intersection and barycentric signs, plus a flag for lines whose
    hits all lie at least `margin` inside their triangles (robust to any tie rule)."""
    v = mesh.vertices[mesh.faces]  # (F, 3, 3)
    a, b, c = v[:, 0], v[:, 1], v[:, 2]
    n = np.cross(b - a, c - a)
    lo = np.full(len(origins), np.inf)
    hi = np.full(len(origins), -np.inf)
    robust = np.ones(len(origins), bool)
    for s in range(0, len(origins), 256):
        o = origins[s : s + 256, None, :]
        den = n @ d  # (F,)
        ok = np.abs(den) > 1e-300
        t = np.einsum("fk,rfk->rf", n, a[None] - o) / np.where(ok, den, 1.0)
        q = o + t[..., None] * d
        area = np.linalg.norm(n, axis=1)
        w0 = np.einsum("fk,rfk->rf", n, np.cross(b - q, c - q)) / area**2
        w1 = np.einsum("fk,rfk->rf", n, np.cross(c - q, a - q)) / area**2
        w2 = 1.0 - w0 - w1
        wmin = np.minimum(np.minimum(w0, w1), w2)
        hit = ok[None] & (wmin >= -margin)
        near = ok[None] & (np.abs(wmin) < margin)
        robust[s : s + 256] = ~near.any(1)
        lo[s : s + 256] = np.where(hit, t, np.inf).min(1)
        hi[s : s + 256] = np.where(hit, t, -np.inf).max(1)
    return lo, hi, robust
