"""Axis selection: the DHF axis and up to three HF axes of an ESI, by branch and bound."""

from __future__ import annotations

import math
import os
from typing import NamedTuple

import numpy as np

from .. import _validate
from ._frames import _canonical, candidates, check_threads, closed_mesh, tuple_values_equal, unit_direction
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
    - `by_m`: `(M,)` float64, the least E with exactly `m = 0, 1, ..., M - 1` HFs. The
      search stops at the first `m` that does not lower E by more than `tol`, unless
      `stop_early=False`; that level only looks for a choice below the best E so far
      minus `tol`, so it has no entry here when there is none (`leaves` and
      `evaluations` count it).
    - `dhf_index`, `hf_indices`: indices into the candidate arrays.
    - `chamfer`: the selection's Chamfer `Dist = CD(S, S~) + CD(S~, S)` (same units).
    - `mu`: its uncovered fraction (Eq. 4).
    - `leaves`, `evaluations`: int64, per level searched (`M` or `M + 1` of them), the
      combinations with `m` HFs and how many of them were evaluated in full (the rest
      were pruned by the lower bound).

    Equality compares every field by value.
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

    __eq__ = tuple_values_equal
    __hash__ = None  # type: ignore[assignment]


def _directions(where: str, name: str, value, allow_empty: bool) -> np.ndarray:
    """`(n, 3)` unit float64 directions from a real array (a single `(3,)` row too)."""
    if isinstance(value, (str, bytes)):
        raise TypeError(f"{where}: `{name}` must be a real (n, 3) array, got {type(value).__name__}")
    try:
        d = np.asarray(value)
    except ValueError:
        raise ValueError(f"{where}: `{name}` must be an (n, 3) array (its rows differ in length)") from None
    if d.dtype.kind not in "fiu" and not (d.size == 0 and d.dtype.kind in "fiuO"):
        raise TypeError(f"{where}: `{name}` must be a real (n, 3) array, got dtype {d.dtype}")
    if d.size == 0:
        if not allow_empty:
            raise ValueError(f"{where}: `{name}` must hold at least one direction")
        return np.zeros((0, 3))
    if d.ndim not in (1, 2) or d.shape[-1] != 3:
        raise ValueError(f"{where}: `{name}` must have shape (n, 3), got {d.shape}")
    return np.stack([unit_direction(where, row, name) for row in np.atleast_2d(d.astype(np.float64))])


def _seed(where: str, key) -> int:
    """The int seed of the sampling from `key`: an int is its own seed, a JAX PRNG key
    seeds one drawn from its key data."""
    if isinstance(key, (int, np.integer)) and not isinstance(key, (bool, np.bool_)):
        return _validate.positive_int(where, "key", key, minimum=0)
    if not hasattr(key, "dtype"):
        raise TypeError(f"{where}: `key` must be an int or a JAX PRNG key, got {type(key).__name__}")
    return int(_validate.numpy_rng(where, key).integers(2**31 - 8))


def _check_pixels(where: str, resolution: int, n_maps: int) -> None:
    """`MemoryError` before allocating depth maps that cannot fit (about 200 bytes per
    pixel with their solids and samples) in the machine's memory."""
    need = 200.0 * n_maps * resolution * resolution
    try:
        have = float(os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES"))
    except (ValueError, OSError, AttributeError):
        have = math.inf
    if need > have:
        raise MemoryError(
            f"{where}: `resolution` = {resolution} needs about {need / 2**30:.0f} GiB for {n_maps} depth maps, "
            f"more than this machine's {have / 2**30:.0f} GiB"
        )


def _prepare(where, vertices, faces, dhf, hf, resolution, n_samples, key, threads, progress=None):
    mesh = closed_mesh(where, vertices, faces)
    dhf = _directions(where, "candidates_dhf", dhf, allow_empty=False)
    hf = _directions(where, "candidates_hf", hf, allow_empty=True)
    seen: dict = {}
    for j, d in enumerate(hf):  # the search counts each HF's floaters once
        i = seen.setdefault(_canonical(d), j)
        if i != j:
            raise ValueError(f"{where}: `candidates_hf` must not repeat a direction (rows {i} and {j} are one)")
    res = _validate.positive_int(where, "resolution", resolution, minimum=2)
    ns = _validate.positive_int(where, "n_samples", n_samples)
    seed = _seed(where, key)
    check_threads(where, threads)
    _check_pixels(where, res, len(dhf) + len(hf))
    prob = _Problem(
        mesh,
        np.concatenate([dhf, -dhf, hf]),
        resolution=res,
        n_samples=ns,
        seed=seed,
        threads=threads,
        progress=progress,
    )
    prob.candidates = (dhf, hf)
    dk = [(prob.index(d), prob.index(-d)) for d in dhf]
    hk = [prob.index(d) for d in hf]
    return prob, dk, hk


def _number(where: str, name: str, value, lo: float = 0.0, hi: float = math.inf) -> float:
    """A finite real number in `[lo, hi]`."""
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, (int, float, np.integer, np.floating)):
        raise TypeError(f"{where}: `{name}` must be a real number, got {type(value).__name__}")
    x = float(value)
    if not (math.isfinite(x) and lo <= x <= hi):
        raise ValueError(f"{where}: `{name}` must be finite and in [{lo:g}, {hi:g}], got {value}")
    return x


def _check_energy_settings(where: str, eps1, eps2, angle) -> tuple[float, float, float]:
    return _number(where, "eps1", eps1), _number(where, "eps2", eps2), _number(where, "angle", angle, 0.0, 180.0)


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
    key=None,
    seed=None,
    threads: int | None = None,
    progress: bool = True,
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

    - `vertices`, `faces`: a closed, consistently oriented mesh: a `voxax.Mesh`, a
      `trimesh.Trimesh`, a `(vertices, faces)` pair or the two arrays; coordinates finite
      and of magnitude at most `1e75` (the selection is scale-invariant).
    - `candidates_dhf`, `candidates_hf`: `(n, 3)` candidate axes (default
      [`candidates(n_dhf, n_hf)`][voxax.esi.candidates]).
    - `n_dhf`, `n_hf`: the default candidates' Fibonacci counts (>= 0).
    - `max_hf`: the most HFs (0-8; 0-3 in the paper). With `max_hf > 0`,
      `candidates_hf` must hold at least one direction.
    - `n_samples`, `resolution`: >= 1 and >= 2.
    - `eps1`, `eps2`, `tol`: finite and >= 0; `angle`: degrees in `[0, 180]`.
    - `stop_early`: `False` computes `by_m` for every `m <= max_hf`.
    - `exhaustive`: evaluate every leaf (for checking the search).
    - `key`: the sampling key, an int (default 0) or a JAX PRNG key (the energy is a
      sampled estimate: the same key gives the same bits). `seed` is its deprecated name.
    - `threads`: threads for the ray casts (`None`: `VOXAX_NUM_THREADS` or every core);
      the result is the same for every count.
    - `progress`: a bar on standard error (the height fields prepared, then the levels).

    **Returns:** an [`ESI`][voxax.esi.ESI].
    """
    where = "voxax.esi.select"
    vertices, faces, _ = _validate.unpack_mesh(where, vertices, faces)
    if isinstance(max_hf, (bool, np.bool_)):
        raise TypeError(f"{where}: `max_hf` must be an int, got bool")
    max_hf = _validate.positive_int(where, "max_hf", max_hf, minimum=0)
    if max_hf > 8:
        raise ValueError(f"{where}: `max_hf` must be in [0, 8], got {max_hf}")
    if candidates_dhf is None or candidates_hf is None:
        cd, ch = candidates(
            _validate.positive_int(where, "n_dhf", n_dhf, minimum=0), _validate.positive_int(where, "n_hf", n_hf, minimum=0)
        )
        candidates_dhf = cd if candidates_dhf is None else candidates_dhf
        candidates_hf = ch if candidates_hf is None else candidates_hf
    if max_hf > 0 and np.size(candidates_hf) == 0:
        raise ValueError(f"{where}: `candidates_hf` must hold at least one direction when `max_hf` > 0 "
                         "(pass max_hf=0 for a DHF alone)")  # fmt: skip
    eps1, eps2, angle = _check_energy_settings(where, eps1, eps2, angle)
    tol = eps1 if tol is None else _number(where, "tol", tol)
    key = _validate.key_or_seed(where, key, seed)
    for name, flag in (("stop_early", stop_early), ("exhaustive", exhaustive), ("progress", progress)):
        if not isinstance(flag, (bool, np.bool_)):
            raise TypeError(f"{where}: `{name}` must be a bool, got {type(flag).__name__}")
    with _Bar(where, bool(progress)) as bar:
        prob, dk, hk = _prepare(
            where, vertices, faces, candidates_dhf, candidates_hf, resolution, n_samples, key, threads, bar.start
        )
        return _select(prob, dk, hk, max_hf, eps1, eps2, angle, tol, stop_early, exhaustive, bar)


class _Bar:
    """The progress of `select`: one step per height field prepared, then one per level
    `m` of the search (the levels after an early stop are left out at the end)."""

    def __init__(self, where: str, enabled: bool):
        self.where, self.enabled, self.bar = where, enabled, None

    def __enter__(self) -> _Bar:
        return self

    def start(self, total: int):
        """Called with the number of height fields; returns the per-step callback."""
        if self.enabled:
            from tqdm.auto import tqdm

            self.bar = tqdm(total=total, desc=f"{self.where}: height fields", unit="step", dynamic_ncols=True)
        return self.step

    def step(self, postfix: dict | None = None) -> None:
        if self.bar is not None:
            if postfix:
                self.bar.set_postfix(postfix, refresh=False)
            self.bar.update(1)

    def levels(self, n: int) -> None:
        if self.bar is not None:
            self.bar.total = self.bar.n + n
            self.bar.set_description(f"{self.where}: levels", refresh=False)
            self.bar.refresh()

    def __exit__(self, *exc) -> None:
        if self.bar is not None:
            if exc[0] is None:
                self.bar.total = self.bar.n
                self.bar.refresh()
            self.bar.close()


def _select(prob, dk, hk, max_hf, eps1, eps2, angle, tol, stop_early, exhaustive, bar=None):
    results, leaves, evals = [], [], []
    chosen = None
    levels = min(max_hf, len(hk)) + 1
    if bar is not None:
        bar.levels(levels)
    for m in range(levels):
        # with the early stop, level m only matters if it beats the chosen level by more
        # than tol: what is not below that is pruned from the start
        cap = results[chosen][0] - tol if stop_early and chosen is not None and not exhaustive else math.inf
        # the DHF of the best choice with one HF less first: a good incumbent early
        first = results[-1][1] if results and results[-1][1] != math.inf else None
        best, n_leaves, n_eval = _search(prob, dk, hk, m, eps1, eps2, angle, exhaustive, cap=cap, first=first)
        leaves.append(n_leaves)
        evals.append(n_eval)
        if best[1] == math.inf:  # nothing below the cap: with the early stop, the search ends here
            if cap != math.inf:
                break
            best = [math.inf, math.inf, ()]  # every choice of this level has E = inf
        results.append(best)
        if bar is not None:
            bar.step({"m": m, "E": f"{best[0]:.4g}"})
        if chosen is None or (best[1] != math.inf and best[0] < results[chosen][0] - tol):
            chosen = m
        elif stop_early:
            break
    E, i, hs = results[chosen]
    if i == math.inf:
        raise ValueError("voxax.esi.select: `n_samples` must be larger: no choice of axes has a finite energy")
    ks = [dk[i][0], dk[i][1]] + [hk[j] for j in hs]
    info = prob.energy(ks, eps1, eps2, angle)
    cdhf, chf = prob.candidates
    d0 = cdhf[i].copy()
    hfa = np.array([chf[j] for j in hs]).reshape(-1, 3)
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
