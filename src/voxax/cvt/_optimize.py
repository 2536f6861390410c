"""The discrete restricted centroidal Voronoi tessellation of fragments: energy, Lloyd, L-BFGS.

Each fragment `x_j` (weight `w_j`) belongs to the region of its nearest seed `s_a(j)`; the
energy is `F(S) = sum_j w_j |x_j - s_a(j)|^2` and, the assignment being piecewise constant
(and the energy continuous across its switches), its gradient is
`dF/ds_i = 2 (W_i s_i - sum_{j in region i} w_j x_j)` with `W_i` the region's weight
(Eq. 2 with weights). Lloyd's step moves every seed to its region's weighted centroid.
"""

from __future__ import annotations

import dataclasses
from typing import Any

import numpy as np

from .. import _validate
from .._kernels import cvt as _kernels
from ._fragments import Fragments, checked, checked_key

__all__ = [
    "CVTResult",
    "assign",
    "energy",
    "energy_gradient",
    "init_seeds",
    "lloyd_step",
    "optimize",
]


def _frag(frag, where: str) -> Fragments:
    return checked(where, frag)


def _seeds(seeds, where: str):
    import jax.numpy as jnp

    s = jnp.asarray(seeds)
    if not (jnp.issubdtype(s.dtype, jnp.floating) or jnp.issubdtype(s.dtype, jnp.integer)):
        raise TypeError(f"{where}: `seeds` must be a real (float or integer) array, got {s.dtype}")
    if s.ndim != 2 or s.shape[1] != 3 or s.shape[0] < 1:
        raise ValueError(f"{where}: `seeds` must have shape (n, 3) with n >= 1, got {s.shape}")
    if not jnp.issubdtype(s.dtype, jnp.floating):
        s = s.astype(jnp.float64)
    if _validate.is_concrete(s) and not bool(jnp.all(jnp.isfinite(s))):  # under jit: the kernels check
        raise ValueError(f"{where}: `seeds` must be finite (they contain NaN or Inf)")
    return s


def _w(frag: Fragments, weighted: bool):
    return frag.weights if weighted else np.ones(frag.size)


def assign(seeds, frag: Fragments):
    """The index of each fragment's nearest seed (ties: the smaller index), `(P,)` int32.

    Exact (uniform-grid k-nearest-neighbour search); under `jax.jit` it runs as an FFI
    kernel (float64: needs `jax_enable_x64`).
    """
    from .._spatial import nearest_neighbors

    frag = _frag(frag, "voxax.cvt.assign")
    s = _seeds(seeds, "voxax.cvt.assign")
    _, idx = nearest_neighbors(s, frag.points, k=1)
    return idx[:, 0]


def energy(seeds, frag: Fragments, *, weighted: bool = True):
    """The CVT energy `sum_j w_j |x_j - s_a(j)|^2` of `seeds (n, 3)` over the fragments.

    Pure JAX (the assignment is a constant of the autodiff), so `jax.grad(energy)` is
    Eq. 2, `2 (W_i s_i - sum_j w_j x_j)`; works under `jit`. `weighted=False` gives every
    fragment weight 1 (the paper's energy).

    **Returns:** scalar float64.
    """
    import jax
    import jax.numpy as jnp

    frag = _frag(frag, "voxax.cvt.energy")
    s = _seeds(seeds, "voxax.cvt.energy")
    idx = assign(jax.lax.stop_gradient(s), frag)
    x = jnp.asarray(frag.points)
    w = jnp.asarray(_w(frag, weighted))
    d = x - s[idx]
    return jnp.sum(w * jnp.sum(d * d, axis=-1))


def _moments(seeds, frag: Fragments, weighted: bool, where: str):
    import jax
    import jax.numpy as jnp

    s = _seeds(seeds, where)
    idx = assign(jax.lax.stop_gradient(s), frag)
    w = jnp.asarray(_w(frag, weighted))
    x = jnp.asarray(frag.points)
    n = s.shape[0]
    mass = jax.ops.segment_sum(w, idx, num_segments=n)
    first = jax.ops.segment_sum(w[:, None] * x, idx, num_segments=n)
    return s, idx, mass, first


def energy_gradient(seeds, frag: Fragments, *, weighted: bool = True):
    """Eq. 2 in closed form: `2 (W_i s_i - sum_{j in region i} w_j x_j)`, `(n, 3)`."""
    frag = _frag(frag, "voxax.cvt.energy_gradient")
    s, _, mass, first = _moments(seeds, frag, weighted, "voxax.cvt.energy_gradient")
    return 2.0 * (mass[:, None] * s - first)


def lloyd_step(seeds, frag: Fragments, *, weighted: bool = True):
    """One Lloyd step: every seed moves to its region's (weighted) centroid; seeds with an
    empty region stay. **Returns:** `(seeds (n, 3), region sizes (n,) int)`."""
    import jax
    import jax.numpy as jnp

    frag = _frag(frag, "voxax.cvt.lloyd_step")
    s, idx, mass, first = _moments(seeds, frag, weighted, "voxax.cvt.lloyd_step")
    new = jnp.where(mass[:, None] > 0, first / jnp.where(mass > 0, mass, 1.0)[:, None], s)
    count = jax.ops.segment_sum(jnp.ones(idx.shape, jnp.int32), idx, num_segments=s.shape[0])
    return new, count


def _assign_moments(s, x, w, hint):
    """The nearest-seed assignment of the fragments with their regions' moments, one FFI
    call (`csrc/cvt/assign.h`): `hint (P,) int32` is any earlier assignment (it only speeds
    the search; out-of-range entries mean none). **Returns:** `(idx (P,) int32, moments
    (n, 4) [weight, weighted first moment], count (n,) int32 of weight > 0, energy ())`."""
    import jax

    idx, mom, count, e = _kernels.assign(jax.lax.stop_gradient(s), x, w, hint)
    return idx, mom, count, e[0]


def _lloyd_arrays(s, x, w, hint):
    """A Lloyd step on plain arrays (fragments passed as arguments, not as constants, so
    one compilation serves every call of the same shapes); also returns the energy of the
    seeds it starts from and their assignment (the next step's hint)."""
    import jax.numpy as jnp

    idx, mom, count, e = _assign_moments(s, x, w, hint)
    mass, first = mom[:, 0], mom[:, 1:]
    new = jnp.where(mass[:, None] > 0, first / jnp.where(mass > 0, mass, 1.0)[:, None], s)
    return new, count, e, idx  # padding has w = 0: not counted


def _energy_arrays(s, args):
    """`scale * sum_j w_j |x_j - s_a(j)|^2` with `args = (x, w, scale, hint)` (traced
    arrays), and the assignment. Its gradient is Eq. 2, `2 scale (W_i s_i - sum_j w_j x_j)`,
    from the kernel's moments (a constant plus a term that is zero but carries it)."""
    import jax
    import jax.numpy as jnp

    x, w, scale, hint = args
    idx, mom, _, e = _assign_moments(s, x, w, hint)
    s0 = jax.lax.stop_gradient(s)
    g = jax.lax.stop_gradient(2.0 * scale * (mom[:, :1] * s0 - mom[:, 1:]))
    return scale * e + jnp.sum(g * (s - s0)), idx


_JITTED: dict = {}


def _jitted(name: str, fn):
    import jax

    if name not in _JITTED:
        _JITTED[name] = jax.jit(fn)
    return _JITTED[name]


def _bucket(size: int) -> int:
    """`size` rounded up to one of 8 sizes per octave (at most 1/8 more): the fragment
    arrays are padded to it, so problems of similar size share one compilation."""
    if size <= 1024:
        return 1024
    step = 1 << (int(size).bit_length() - 4)
    return -(-size // step) * step


def _padded(frag: Fragments, weighted: bool):
    """The fragment points and weights as device arrays padded to `_bucket(P)` with copies
    of the first point at weight 0 (which change no sum, energy or region count)."""
    import jax.numpy as jnp

    p = frag.size
    size = _bucket(p)
    x = np.empty((size, 3))
    x[:p] = frag.points
    x[p:] = frag.points[0]
    w = np.zeros(size)
    w[:p] = _w(frag, weighted)
    return jnp.asarray(x), jnp.asarray(w)


def _lbfgs_init(solver, y, args):
    import jax
    import jax.numpy as jnp

    f_struct = jax.ShapeDtypeStruct((), jnp.float64)
    aux_struct = jax.ShapeDtypeStruct(args[3].shape, jnp.int32)
    return solver.init(_energy_arrays, y, args, {}, f_struct, aux_struct, frozenset())


def _lbfgs_step(solver, y, state, args):
    y_new, state, _ = solver.step(_energy_arrays, y, args, {}, state, frozenset())
    done, result = solver.terminate(_energy_arrays, y_new, args, {}, state, frozenset())
    # `y_new` is the last accepted iterate, and the solver keeps its energy (no second
    # nearest-seed search per step) and its assignment (the next search's hint)
    return y_new, state, state.f_info.f, state.aux, done, result


def _lbfgs(y, args, steps: int, rtol: float, step_done=None, ftol: float = 0.0):
    """optimistix L-BFGS driven step by step from Python (one energy evaluation per step), with its
    init and step compiled once per problem shape (the solver and the energy are static,
    the seeds and fragments arguments). With `ftol > 0` it also stops after two accepted
    steps in a row that each lower the energy by less than `ftol` of it (relative
    decrease), once a step has lowered it by `ftol` or more: the first steps that move
    the seeds are gradient steps of the solver's initial length (no curvature pairs yet,
    and tiny: the energy is scaled by the total weight), whose decrease is small far from
    convergence. Steps that leave the energy as it was (the first, which evaluates the
    start, and those whose line search rejects the point tried: the iterate stays) are
    not counted."""
    import equinox as eqx
    import optimistix as optx

    init = _JITTED.setdefault("lbfgs_init", eqx.filter_jit(_lbfgs_init))
    step = _JITTED.setdefault("lbfgs_step", eqx.filter_jit(_lbfgs_step))
    solver = optx.LBFGS(rtol=rtol, atol=0.0)
    state = init(solver, y, args)
    hist = []
    reason = "max_steps"
    armed = False  # a step has lowered the energy by ftol or more
    small = 0  # accepted steps in a row below ftol since
    for _ in range(steps):
        y_new, state, e, hint, done, result = step(solver, y, state, args)
        args = (*args[:3], hint)
        e = float(e)
        if not np.isfinite(e):
            reason = "nonfinite"
            break
        # the relative decrease of an accepted step (the iterate moved: the energy changed)
        if ftol > 0 and len(hist) > 0 and e != hist[-1]:
            below = hist[-1] - e < ftol * abs(hist[-1])
            armed = armed or not below
            small = small + 1 if below and armed else 0
        hist.append(e)
        y = y_new
        if step_done is not None:
            step_done(e)
        if bool(done):
            reason = "converged" if result == optx.RESULTS.successful else f"failed: {optx.RESULTS[result]}"
            break
        if small >= 2:
            reason = "tol"
            break
    return y, hist, reason


def init_seeds(frag: Fragments, n: int, key=0) -> np.ndarray:
    """`n` seeds drawn at distinct fragments with probability proportional to their weight
    (so uniformly by area). `key`: an int seed or a `jax.random` key. **Returns:** `(n, 3)`."""
    where = "voxax.cvt.init_seeds"
    frag = _frag(frag, where)
    n = _validate.positive_int(where, "n", n)
    if n > frag.size:
        raise ValueError(f"{where}: `n` must be at most the number of fragments: {n} seeds but only {frag.size} "
                         "fragments; use a finer grid or fewer seeds")
    rng = _validate.numpy_rng(where, checked_key(where, key))
    total = frag.weights.sum()
    if not total > 0:
        raise ValueError(f"{where}: `frag.weights` must not all be zero")
    pick = rng.choice(frag.size, size=n, replace=False, p=frag.weights / total)
    return frag.points[np.sort(pick)].copy()


def respawn(seeds, frag: Fragments, count) -> tuple[np.ndarray, int]:
    """Moves the seeds with empty regions onto the fragments farthest from their own seed
    (largest first, ties by index): deterministic. **Returns:** `(seeds, moved)`."""
    frag = _frag(frag, "voxax.cvt.respawn")
    s = np.array(_seeds(seeds, "voxax.cvt.respawn"), np.float64)
    count = np.asarray(count)
    if count.shape != (len(s),):
        raise ValueError(f"voxax.cvt.respawn: `count` must have shape ({len(s)},) (one per seed), got {count.shape}")
    return _respawn(s, frag, count)


def _respawn(s: np.ndarray, frag: Fragments, count) -> tuple[np.ndarray, int]:
    from .._spatial import nearest_neighbors

    empty = np.nonzero(np.asarray(count) == 0)[0]
    if len(empty) == 0:
        return s, 0
    s = s.copy()
    _, idx = nearest_neighbors(s, frag.points, k=1)
    idx = np.asarray(idx[:, 0])
    d = np.sum((frag.points - s[idx]) ** 2, axis=1)
    far = np.lexsort((np.arange(len(d)), -d))[: len(empty)]
    s[empty[: len(far)]] = frag.points[far]
    return s, len(empty)


@dataclasses.dataclass(frozen=True)
class CVTResult:
    """What [`optimize`][voxax.cvt.optimize] returns.

    - `seeds`: `(n, 3)` float64, the optimised seeds.
    - `energy`: `(steps + 1,)` float64, the energy before the first step and after each.
    - `steps`: int, steps taken.
    - `respawned`: int, seeds moved out of empty regions.
    - `method`: `"lloyd"` or `"lbfgs"`.
    - `info`: why the steps ended: `"max_steps"`, `"tol"`, `"fixed point"` (Lloyd),
      `"converged"` or `"failed: ..."` (L-BFGS, optimistix's own test) or `"nonfinite"`.
    """

    seeds: np.ndarray
    energy: np.ndarray
    steps: int
    respawned: int
    method: str
    info: Any = None


def optimize(
    frag: Fragments, seeds, *, method: str = "lloyd", steps: int = 50, weighted: bool = True, tol: float = 0.0
) -> CVTResult:
    """Optimises the seeds towards a restricted CVT of the fragments.

    **Arguments:**

    - `frag`: [`Fragments`][voxax.cvt.Fragments].
    - `seeds`: `(n, 3)` float initial seeds (e.g. [`init_seeds`][voxax.cvt.init_seeds]).
    - `method`: `"lloyd"` (centroid steps; empty regions are respawned after each step;
      stops early at an exact fixed point, where a step returns the seeds it was given) or
      `"lbfgs"` (optimistix L-BFGS on [`energy`][voxax.cvt.energy], stepped from Python like
      [`voxax.minimize`][voxax.minimize]; empty regions are respawned at the end, followed by
      a Lloyd step).
    - `steps`: maximum number of steps.
    - `weighted`: use the fragment weights (uniform density by area).
    - `tol`: stop when the relative energy decrease of a step is below this.

    **Returns:** [`CVTResult`][voxax.cvt.CVTResult].
    """
    import jax

    where = "voxax.cvt.optimize"
    frag = _frag(frag, where)
    if not jax.config.jax_enable_x64:
        raise ValueError(f"{where} computes in float64: enable jax_enable_x64")
    s = np.array(_seeds(seeds, where), np.float64)
    if len(s) > frag.size:
        raise ValueError(f"{where}: `seeds` must be at most as many as the fragments: {len(s)} seeds but only "
                         f"{frag.size} fragments")
    steps = _validate.positive_int(where, "steps", steps, minimum=0)
    tol = _validate.positive_float(where, "tol", tol, allow_zero=True)
    if method not in ("lloyd", "lbfgs"):
        raise ValueError(f'{where}: `method` must be "lloyd" or "lbfgs", got {method!r}')
    return run(frag, s, method, steps, weighted, tol)


def run(frag: Fragments, s: np.ndarray, method: str, steps: int, weighted: bool, tol: float = 0.0,
        step_done=None) -> CVTResult:
    """[`optimize`][voxax.cvt.optimize] on checked arguments; `step_done(energy)` is called
    after every step (a progress bar's hook)."""
    return run_hinted(frag, s, method, steps, weighted, tol, step_done)[0]


def spacing(frag: Fragments, n: int) -> float:
    """The edge length of `n` seeds spread evenly over the fragments' area (equilateral
    triangles, two per seed): the scale of `run_hinted`'s `stop_tol` for Lloyd steps."""
    return float(np.sqrt(4.0 * float(np.sum(frag.weights)) / (np.sqrt(3.0) * n)))


def run_hinted(frag: Fragments, s: np.ndarray, method: str, steps: int, weighted: bool, tol: float = 0.0,
               step_done=None, hint=None, stop_tol: float = 0.0) -> tuple[CVTResult, Any]:
    """`run` warm-started: `hint` is the fragments' assignment (padded, as returned here)
    from an earlier run on the same fragments, or None. It only speeds the first
    nearest-seed search (the results are the same bits). `stop_tol` (0: off) stops
    early: L-BFGS after two steps in a row that move the seeds and lower the energy by
    less than `stop_tol` of it, after a first one that lowered it by more (`_lbfgs`);
    Lloyd after the first step whose largest seed move is below `stop_tol` times the
    seeds' `spacing`. **Returns:** `(result, the assignment of the last search)`."""
    import jax.numpy as jnp

    x, w = _padded(frag, weighted)
    if hint is None or hint.shape != (x.shape[0],):
        hint = jnp.full(x.shape[0], -1, jnp.int32)
    if method == "lloyd":
        step = _jitted("lloyd", _lloyd_arrays)
        en = _jitted("energy", _energy_arrays)
        one = jnp.asarray(1.0)
        hist = []
        moved = 0
        taken = 0
        fixed = False
        reach = stop_tol * spacing(frag, len(s)) if stop_tol > 0 else 0.0
        reason = "max_steps"
        for _ in range(steps):
            new, count, e, hint = step(jnp.asarray(s), x, w, hint)
            hist.append(float(e))
            if tol > 0 and len(hist) > 1 and hist[-2] - hist[-1] <= tol * abs(hist[-2]):
                hist.pop()
                reason = "tol"
                break
            new, m = _respawn(np.array(new, np.float64), frag, count)
            moved += m
            fixed = m == 0 and np.array_equal(new, s)
            small = reach > 0 and float(np.max(np.sqrt(np.sum((new - s) ** 2, axis=1)))) < reach
            s = new
            taken += 1
            if step_done is not None:
                step_done(hist[-1])
            if fixed:  # an exact fixed point: every further step would return these seeds
                reason = "fixed point"
                break
            if small:
                reason = "tol"
                break
        if fixed:  # the last step started from these seeds: its energy is theirs
            hist.append(hist[-1])
        else:
            e, hint = en(jnp.asarray(s), (x, w, one, hint))
            hist.append(float(e))
        return CVTResult(s, np.array(hist), taken, moved, "lloyd", info=reason), hint
    if method == "lbfgs":
        args = (x, w, jnp.asarray(1.0 / float(jnp.sum(w))), hint)
        scale = float(args[2])
        e0, hint = _jitted("energy", _energy_arrays)(jnp.asarray(s), args)
        e0 = float(e0) / scale
        y, hist, reason = _lbfgs(jnp.asarray(s), (*args[:3], hint), steps, max(tol, 1e-12), step_done, stop_tol)
        y = np.asarray(y, np.float64)
        _, count, _, hint = _jitted("lloyd", _lloyd_arrays)(jnp.asarray(y), x, w, hint)
        y, moved = _respawn(y, frag, count)
        hist = np.concatenate([[e0], np.asarray(hist) / scale])
        return CVTResult(y, hist, len(hist) - 1, moved, "lbfgs", info=reason), hint
    raise AssertionError(method)  # checked above
