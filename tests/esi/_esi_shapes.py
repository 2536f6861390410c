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


def bound_samples_reference(rr, cur, Dr, suf, Vr, sufv, c0, nc, with_suf):
    """The sample sums of the selection's bounds, straight from their definition
    (`voxax._kernels.esi.bound_samples`)."""
    j = np.arange(c0, c0 + nc)
    C = np.minimum(cur[:, None], Dr[np.ix_(rr, j)])
    cd = (np.minimum(C, suf[np.ix_(rr, j + 1)]) if with_suf else C).sum(0)
    Vn = Vr[np.ix_(rr, j)]
    return C, Vn, cd, Vn.sum(0), (Vn | sufv[np.ix_(rr, j + 1)]).sum(0)


def bound_removals_reference(IN, rows, cols, col_of, s3, wd, wt):
    """The floater sums of the selection's bounds, one entry at a time
    (`voxax._kernels.esi.bound_removals`)."""
    nh = IN.shape[0]
    nc = len(cols)
    member = np.zeros((len(rows), nc), bool)
    if col_of is None:
        member = IN[np.ix_(cols, rows)].T.copy()
    else:
        member[np.arange(len(rows)), col_of] = True
    w1, w2 = wd[rows], wt[rows]
    sums = np.array([[w1[member[:, c]].sum() for c in range(nc)], [w2[member[:, c]].sum() for c in range(nc)],
                     member.sum(0)], float).reshape(3, nc)  # fmt: skip
    Md = np.zeros((nh - s3, nc))
    Mt = np.zeros((nh - s3, nc))
    for j, h in enumerate(range(s3, nh)):
        for c in range(nc):
            if h > cols[c]:
                k = member[:, c] & ~IN[h, rows]
                Md[j, c], Mt[j, c] = w1[k].sum(), w2[k].sum()
    return sums, Md, Mt


def bound_blocks_reference(alive, off, wd, wt):
    """The block sums of the selection's bounds (`voxax._kernels.esi.bound_blocks`)."""
    out = np.zeros((3, len(off) - 1))
    for b in range(len(off) - 1):
        a = alive[off[b] : off[b + 1]]
        out[:, b] = a.sum(), wd[off[b] : off[b + 1]][a].sum(), wt[off[b] : off[b + 1]][a].sum()
    return out


def random_bound_case(rng, nh=None, R=None):
    """Random inputs of the bound sums: `IN` (nh, R), rows, ascending columns, one column
    per row (ascending), s3, weights."""
    nh = int(rng.integers(1, 30)) if nh is None else nh
    R = int(rng.integers(0, 400)) if R is None else R
    IN = rng.random((nh, R)) < rng.random()
    n = int(rng.integers(0, R + 1))
    rows = np.sort(rng.choice(R, n, replace=False)) if rng.random() < 0.7 else rng.choice(R, n, replace=False)
    cols = np.sort(rng.choice(nh, int(rng.integers(0, nh + 1)), replace=False))
    col_of = np.sort(rng.integers(0, len(cols), n)) if len(cols) else np.zeros(0, np.int64)
    s3 = int(rng.integers(0, nh + 1))
    wd, wt = rng.random(R), rng.random(R) * 3
    return IN, rows.astype(np.int64), cols.astype(np.int64), col_of.astype(np.int64), s3, wd, wt


def random_sample_tables(rng, nh, max_rows=60, max_samples=50):
    """Random inputs of the bounds' sample sums for `nh` HF candidates: `rr`, `cur`, `Dr`,
    `suf`, `Vr`, `sufv`, `c0`, `nc` (as `voxax._kernels.esi.bound_samples` takes them)."""
    nrow = int(rng.integers(1, max_rows))
    Dr, suf = rng.random((nrow, nh)), rng.random((nrow, nh + 1))
    Vr, sufv = rng.random((nrow, nh)) < 0.3, rng.random((nrow, nh + 1)) < 0.5
    rr = rng.integers(0, nrow, int(rng.integers(0, max_samples)))
    c0 = int(rng.integers(0, nh + 1))
    return rr, rng.random(len(rr)), Dr, suf, Vr, sufv, c0, int(rng.integers(0, nh - c0 + 1))
