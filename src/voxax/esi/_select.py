"""Axis selection: the DHF axis and up to three HF axes of an ESI, by branch and bound."""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np

from .. import _validate
from ._frames import _canonical, candidates, closed_mesh, unit_direction
from ._problem import _Problem
from ._search import _search

__all__ = ["ESI", "select"]


class ESI(NamedTuple):
    """The selected axes of an explicit surface intersection and their energies.

    - `dhf_axis`: `(3,)` float64 unit axis of the double height field (its sign is
      immaterial).
    - `hf_axes`: `(m, 3)` float64 unit axes of the height fields (`HF(d)` keeps the
      points whose ray along `+d` meets the surface).
    - `energy`: E of the selection (Eq. 1, in the units of the mesh scaled into
      `[-1/1.1, 1/1.1]^3`).
    - `by_m`: `(M,)` float64, the least E found with exactly `m = 0, 1, ...` HFs (the
      search stops at the first `m` that does not lower E by more than `tol`, unless
      `stop_early=False`; that last level only looks for a choice below the previous best
      minus `tol`, and its entry is `nan` when there is none).
    - `dhf_index`, `hf_indices`: indices into the candidate arrays.
    - `chamfer`: the selection's Chamfer `Dist = CD(S, S~) + CD(S~, S)` (same units).
    - `mu`: its uncovered fraction (Eq. 4).
    - `leaves`, `evaluations`: `(M,)` int64, the combinations with `m` HFs and how many of
      them were evaluated in full (the rest were pruned by the lower bound).
    """

    dhf_axis: np.ndarray
    hf_axes: np.ndarray
    energy: float
    by_m: np.ndarray
    dhf_index: int
    hf_indices: tuple
    chamfer: float
    mu: float
    leaves: np.ndarray
    evaluations: np.ndarray

    @property
    def prune_rate(self) -> float:
        """The fraction of combinations with >= 1 HF that were never evaluated in full."""
        leaves = int(self.leaves[1:].sum())
        return 1.0 - int(self.evaluations[1:].sum()) / leaves if leaves else 0.0

    @property
    def axes(self) -> list:
        """The signed ray directions that define the ESI: `+dhf`, `-dhf`, then the HFs."""
        return [self.dhf_axis, -self.dhf_axis] + list(self.hf_axes)


def _prepare(where, vertices, faces, dhf, hf, resolution, n_samples, seed, threads):
    mesh = closed_mesh(where, vertices, faces)
    dhf = np.atleast_2d(np.asarray(dhf, dtype=np.float64))
    hf = np.asarray(hf, dtype=np.float64).reshape(-1, 3)
    dhf = np.stack([unit_direction(where, d) for d in dhf]) if len(dhf) else dhf
    if len(dhf) == 0:
        raise ValueError(f"{where}: needs at least one DHF candidate")
    hf = np.stack([unit_direction(where, d) for d in hf]) if len(hf) else hf.reshape(0, 3)
    seen: dict = {}
    for j, d in enumerate(hf):  # the search counts each HF's floaters once
        i = seen.setdefault(_canonical(d), j)
        if i != j:
            raise ValueError(f"{where}: candidates_hf repeats a direction (rows {i} and {j})")
    res = _validate.positive_int(where, "resolution", resolution, minimum=2)
    ns = _validate.positive_int(where, "n_samples", n_samples)
    prob = _Problem(
        mesh,
        np.concatenate([dhf, -dhf, hf]),
        resolution=res,
        n_samples=ns,
        seed=int(seed),
        threads=threads,
    )
    dk = [(prob.index(d), prob.index(-d)) for d in dhf]
    hk = [prob.index(d) for d in hf]
    return prob, dk, hk


def select(
    vertices,
    faces=None,
    *,
    candidates_dhf=None,
    candidates_hf=None,
    n_dhf: int = 50,
    n_hf: int = 80,
    max_hf: int = 3,
    n_samples: int = 10_000,
    resolution: int = 128,
    eps1: float = 1e-4,
    eps2: float = 1e-3,
    angle: float = 85.0,
    tol: float | None = None,
    stop_early: bool = True,
    exhaustive: bool = False,
    seed: int = 0,
    threads=None,
) -> ESI:
    """Select the DHF axis and up to `max_hf` HF axes of an ESI by branch and bound.

    The energy of a choice of axes is `E = Dist + min(mu (Dist + eps1), eps2)` (Eq. 1) on
    the mesh scaled into `[-1/1.1, 1/1.1]^3`, with:

    - `Dist = CD(S, S~) + CD(S~, S)`, L1 Chamfer distances between `n_samples` area
      samples `P` of the surface S and area samples of the ESI's surface S~.
      `CD(S, S~)` is exact per sample: a point of S lies inside every height field, so
      its distance to the boundary of their intersection is the least distance to the
      boundary of one of them (0 when the point is visible along that axis).
      `CD(S~, S)` uses exact point-to-mesh distances of the height-field boundary samples
      that lie inside all the other height fields (exact ray casts).
    - `mu`, the mean over S~'s samples of `min_k On(p, d_k)` with `On = max(1 - v, T)`
      (Eq. 3-4): `v` is 1 when the ray from `p` along `d_k` misses S, `T(theta) =
      tanh(theta - angle)/2 + 1/2` of the angle in degrees between the sample's normal
      and `d_k`.

    Each height field's boundary comes from a `resolution^2` depth map (exact hits at
    pixel centres, linear in between). `m = 0, 1, ...` HFs are tried in turn; for each,
    every combination of a DHF candidate and `m` HF candidates is a leaf of a search tree,
    explored best first. A partial choice (the DHF and some HFs) is bounded below over
    every combination that completes it: `CD(S, S~)` with the best remaining candidates,
    and `CD(S~, S)` and `mu` from what no further HF can change, namely the floaters of the
    DHF, of the chosen HFs and of the next one that the remaining HFs cannot all remove,
    the visible surface samples (at distance 0) that they can at most add, and the later
    HFs' floaters, each farther from S than the on-surface distance. The children of the
    last inner level are leaves: their energies are computed together, and only those
    within the bound are evaluated one by one (with `energy`'s own arithmetic, so to the
    bit). Every ray is cast exactly (a watertight test) against the triangles listed over
    its cell of a grid in its direction's frame, after a test of the cell's depth range
    that rejects most rays that cannot meet S; a ray of a boundary sample along an HF
    candidate is cast at most once for all DHFs. Most leaves are never evaluated
    (`ESI.prune_rate`), and the result is the exhaustive optimum. The search stops
    at the first `m` whose best E is not lower than that of `m - 1` by more than `tol`
    (default `eps1`: an extra height field must be worth more than the noise of the
    sampled energy); that level only looks for a choice below that threshold.

    **Arguments:**

    - `vertices`, `faces`: a closed, consistently oriented mesh (or a `Mesh` alone).
    - `candidates_dhf`, `candidates_hf`: `(n, 3)` candidate axes (default
      [`candidates(n_dhf, n_hf)`][voxax.esi.candidates]).
    - `max_hf`: the most HFs (0-3 in the paper).
    - `n_samples`, `resolution`, `eps1`, `eps2`, `angle`, `tol`: as above.
    - `stop_early`: `False` computes `by_m` for every `m <= max_hf`.
    - `exhaustive`: evaluate every leaf (for checking the search).
    - `seed`: the sampling seed (the energy is a sampled estimate; fix it).
    - `threads`: threads for the ray casts.

    **Returns:** an [`ESI`][voxax.esi.ESI].
    """
    where = "esi.select"
    if faces is not None and not hasattr(faces, "shape") and not isinstance(faces, (list, tuple)):
        raise TypeError(f"{where}: faces must be an array")
    if candidates_dhf is None or candidates_hf is None:
        cd, ch = candidates(n_dhf, n_hf)
        candidates_dhf = cd if candidates_dhf is None else candidates_dhf
        candidates_hf = ch if candidates_hf is None else candidates_hf
    max_hf = int(max_hf)
    if not 0 <= max_hf <= 8:
        raise ValueError(f"{where}: max_hf must be in [0, 8], got {max_hf}")
    tol = float(eps1 if tol is None else tol)
    prob, dk, hk = _prepare(where, vertices, faces, candidates_dhf, candidates_hf, resolution, n_samples, seed, threads)
    return _select(prob, dk, hk, candidates_dhf, candidates_hf, max_hf, eps1, eps2, angle, tol, stop_early, exhaustive)


def _select(prob, dk, hk, cdhf, chf, max_hf, eps1, eps2, angle, tol, stop_early, exhaustive):
    cdhf = np.asarray(cdhf, np.float64).reshape(-1, 3)
    chf = np.asarray(chf, np.float64).reshape(-1, 3)
    results, leaves, evals = [], [], []
    chosen = None
    for m in range(max_hf + 1):
        if m > len(hk):
            break
        # with the early stop, level m only matters if it beats the chosen level by more
        # than tol: what is not below that is pruned from the start
        cap = results[chosen][0] - tol if stop_early and chosen is not None and not exhaustive else math.inf
        # the DHF of the best choice with one HF less first: a good incumbent early
        first = results[-1][1] if results and results[-1][1] != math.inf else None
        best, n_leaves, n_eval = _search(prob, dk, hk, m, eps1, eps2, angle, exhaustive, cap=cap, first=first)
        if best[1] == math.inf:  # nothing below the cap
            best = [math.nan, math.inf, ()]
        results.append(best)
        leaves.append(n_leaves)
        evals.append(n_eval)
        if chosen is None or (best[1] != math.inf and best[0] < results[chosen][0] - tol):
            chosen = m
        elif stop_early:
            break
    E, i, hs = results[chosen]
    ks = [dk[i][0], dk[i][1]] + [hk[j] for j in hs]
    info = prob.energy(ks, eps1, eps2, angle)
    d0 = cdhf[i] / np.linalg.norm(cdhf[i])
    hfa = np.array([chf[j] / np.linalg.norm(chf[j]) for j in hs]).reshape(-1, 3)
    return ESI(
        d0,
        hfa,
        float(E),
        np.array([r[0] for r in results]),
        int(i),
        tuple(int(j) for j in hs),
        float(info["dist"]),
        float(info["mu"]),
        np.array(leaves, np.int64),
        np.array(evals, np.int64),
    )
