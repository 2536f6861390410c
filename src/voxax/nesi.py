"""Neural explicit surface intersections (NESI): an ESI's height fields as small SIRENs.

An [`ESI`][voxax.esi.ESI] bounds a shape by a double height field along `d_0` and up to
three height fields along `d_k`. `fit` stores each as a SIREN from the plane to heights
(equinox, through [`voxax.fields.Siren`][voxax.fields.Siren]):

- the DHF as one network `(x, y) -> (f_a, f_b)` with five hidden layers; its domain is
  implicit (`f_b < f_a` inside the silhouette, `f_b >= f_a` outside);
- each HF as a height network `(x, y) -> f_k` (five hidden layers) and a mask network
  `(x, y) -> logit` (three hidden layers of width 16) for its silhouette; the heights are
  learned only where the earlier explicits do not cover the surface well (the restricted
  domain), and are only pushed above the surface elsewhere.

Widths by level of detail 1-4: DHF 32/48/72/96, HF 16/24/36/48, as in the paper's
appendix. Each explicit works in its own frame `(u, v, d)` (see
[`voxax.esi.frame_for`][voxax.esi.frame_for]) on the mesh scaled so that its bounding
sphere has radius `1/1.1`: every frame then sees the shape inside `[-1/1.1, 1/1.1]^3`
(scaling the bounding box instead would let rotated frames leave `[-1, 1]^3`).

Training minimises the paper's losses (Eq. 6-14: L1 heights, the domain hinges, the
normal cosine term switched on after `normal_start` steps, the mask's binary cross
entropy) with Adam and a cosine-decayed learning rate through
[`voxax.minimize`][voxax.minimize], on training points computed exactly from the mesh
(BVH ray casts). [`occupancy`][voxax.nesi.occupancy], [`raytrace`][voxax.nesi.raytrace]
and [`to_mesh`][voxax.nesi.to_mesh] work on the networks alone.
"""

from __future__ import annotations

from typing import NamedTuple

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from . import _validate
from . import esi as _esi
from ._mesh import Mesh, face_normals
from ._spatial import BVH
from .esi._frames import bounding_sphere, check_threads, exact_scale, tuple_values_equal
from .esi._mesh import _esi_axes
from .esi._nesi_eval import _occupancy_eager, _real_points, _traced_points
from .esi._select import _seed
from .esi._siren import _apply, _apply_with_gradient, _cos32, _sin32  # noqa: F401  (also nesi's names)
from .fields import Siren

__all__ = [
    "DHF_WIDTHS",
    "HF_WIDTHS",
    "MASK_WIDTH",
    "NESI",
    "Training",
    "TrainingData",
    "fit",
    "occupancy",
    "param_count",
    "raytrace",
    "to_mesh",
    "training_data",
]

#: Hidden widths of the DHF network by level of detail 1-4 (five hidden layers).
DHF_WIDTHS = (32, 48, 72, 96)
#: Hidden widths of an HF height network by level of detail 1-4 (five hidden layers).
HF_WIDTHS = (16, 24, 36, 48)
#: Hidden width of an HF mask network (three hidden layers).
MASK_WIDTH = 16

_DEPTH, _MASK_DEPTH = 5, 3


class NESI(eqx.Module):
    """A neural ESI: the DHF network, the HF height and mask networks and their frames.

    - `dhf`: `Siren(2 -> 2)`, `(f_a, f_b)` in the DHF's frame.
    - `heights`, `masks`: tuples of `Siren(2 -> 1)`, one per HF.
    - `frames`: `((u, v, d), ...)` per explicit (DHF first), as static tuples.
    - `center`, `scale`: world point `p` has normalised coordinates `scale * (p - center)`.
    """

    dhf: Siren
    heights: tuple
    masks: tuple
    frames: tuple = eqx.field(static=True)
    center: tuple = eqx.field(static=True)
    scale: float = eqx.field(static=True)

    @property
    def n_hf(self) -> int:
        """Number of height fields."""
        return len(self.heights)


def param_count(net: NESI) -> int:
    """The number of trainable parameters (all array leaves).

    For width `w` the DHF has `4 w^2 + 9 w + 2` parameters and an HF
    `4 w^2 + 8 w + 1 + 609` (height plus mask network).

    Works on a network or on its shape (`equinox.filter_eval_shape`).
    """
    if not isinstance(net, NESI):
        raise TypeError(f"voxax.nesi.param_count: `net` must be a voxax.nesi.NESI, got {type(net).__name__}")
    n = 0
    for x in jax.tree_util.tree_leaves(net):
        dt = getattr(x, "dtype", None)
        if dt is not None and jnp.issubdtype(dt, jnp.inexact):
            n += int(np.prod(x.shape))
    return n


def _check_lod(lod, where: str = "voxax.nesi.fit") -> int:
    lod = _validate.positive_int(where, "lod", lod)
    if lod not in (1, 2, 3, 4):
        raise ValueError(f"{where}: `lod` must be 1, 2, 3 or 4, got {lod}")
    return lod


def _real(where: str, name: str, value, lo: float = 0.0, strict: bool = False) -> float:
    """A finite real number `>= lo` (`> lo` with `strict`)."""
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, (int, float, np.integer, np.floating)):
        raise TypeError(f"{where}: `{name}` must be a real number, got {type(value).__name__}")
    x = float(value)
    if not (np.isfinite(x) and (x > lo if strict else x >= lo)):
        raise ValueError(f"{where}: `{name}` must be finite and {'>' if strict else '>='} {lo:g}, got {value}")
    return x


def _flag(where: str, name: str, value) -> bool:
    if not isinstance(value, (bool, np.bool_)):
        raise TypeError(f"{where}: `{name}` must be a bool, got {type(value).__name__}")
    return bool(value)


def _siren(in_size, out_size, width, depth, rng, dtype) -> Siren:
    """A `Siren` with its own initialisation (uniform weights and biases with the bounds
    documented there) drawn by NumPy: building a network then compiles nothing, where
    `jax.random` compiles one sampler per array shape (seconds per network)."""
    shape = eqx.filter_eval_shape(Siren, in_size, out_size, width, depth, key=jax.random.key(0), dtype=dtype)
    sizes = [in_size] + [width] * depth + [out_size]
    dt = np.dtype(dtype or jnp.result_type(float))
    ws, bs = [], []
    for i, (n_in, n_out) in enumerate(zip(sizes[:-1], sizes[1:])):
        bound = 1.0 / n_in if i == 0 else np.sqrt(6.0 / n_in) / shape.omega_0
        ws.append(jnp.asarray(rng.uniform(-bound, bound, (n_out, n_in)).astype(dt)))
        bs.append(jnp.asarray(rng.uniform(-1.0, 1.0, n_out).astype(dt) / np.sqrt(n_in).astype(dt)))
    return eqx.tree_at(lambda n: (n.weights, n.biases), shape, (ws, bs))


def _init(lod, hf_axes, *, key, frames, center=(0.0, 0.0, 0.0), scale=1.0, dtype=None) -> NESI:
    lod = _check_lod(lod)
    raw = jax.random.key_data(key) if jnp.issubdtype(key.dtype, jax.dtypes.prng_key) else key
    rng = np.random.default_rng(np.asarray(raw).ravel().tolist())
    dhf = _siren(2, 2, DHF_WIDTHS[lod - 1], _DEPTH, rng, dtype)
    hs, ms = [], []
    for _ in hf_axes:
        hs.append(_siren(2, 1, HF_WIDTHS[lod - 1], _DEPTH, rng, dtype))
        ms.append(_siren(2, 1, MASK_WIDTH, _MASK_DEPTH, rng, dtype))
    fr = tuple(tuple(tuple(float(c) for c in row) for row in f) for f in frames)
    return NESI(dhf, tuple(hs), tuple(ms), fr, tuple(float(c) for c in center), float(scale))


# ----------------------------------------------------------------------------- training data


class TrainingData(NamedTuple):
    """Training points of every explicit, in normalised frame coordinates.

    DHF: `p0 (n, 2)`, `fa, fb (n,)`, `na, nb (n, 3)` local normals of the top and bottom
    hits, `pbar0 (n', 2)` points whose lines miss the shape.
    HFs (lists, one entry per HF): `pk` (lines visible along `d_k`), `fk` heights,
    `nk` normals, `restricted` bool (the restricted domain, criteria 1-3), `pbark`.
    """

    p0: np.ndarray
    fa: np.ndarray
    fb: np.ndarray
    na: np.ndarray
    nb: np.ndarray
    pbar0: np.ndarray
    pk: list
    fk: list
    nk: list
    restricted: list
    pbark: list

    __eq__ = tuple_values_equal
    __hash__ = None  # type: ignore[assignment]


class Training(NamedTuple):
    """What [`training_data`][voxax.nesi.training_data] returns: the `data`, the
    explicits' `frames` `((u, v, d), ...)` (DHF first), and the normalisation (`center`,
    `scale`: world point `p` is `scale * (p - center)`)."""

    data: TrainingData
    frames: list
    center: np.ndarray
    scale: float

    __eq__ = tuple_values_equal
    __hash__ = None  # type: ignore[assignment]


def _local_frame(d) -> tuple:
    fr = _esi.frame_for(np.asarray(d, np.float64), np.zeros(3), 1.0, 1)
    return fr.u, fr.v, fr.d


def _lines(bvh, c, R, s, frame, xy, threads=None):
    """Exact top and bottom hits (normalised depths and local normals) of lines at `xy`."""
    u, v, d = frame
    base = c + (xy[:, :1] / s) * u + (xy[:, 1:2] / s) * v
    lo = bvh.first_hits(base - 2 * R * d, d, threads=threads)
    hi = bvh.first_hits(base + 2 * R * d, -d, threads=threads)
    return lo, hi


def training_data(
    esi,
    vertices,
    faces=None,
    *,
    n_samples: int = 20_000,
    grazing: float = 70.0,
    ray_points: int = 12,
    restrict: bool = True,
    key=None,
    seed=None,
    threads: int | None = None,
) -> Training:
    """Training points for [`fit`][voxax.nesi.fit] (Sec. 5.1-5.2), from exact ray casts.

    Surface samples visible along `+d_0` or `-d_0` give the DHF's points; those visible
    along `d_k` give HF k's, restricted (with `restrict=True`) to the samples that (1)
    are hidden from every earlier direction or (2) seen from them only at more than
    `grazing` degrees, or (3) whose ray along `d_k` passes a point hidden from every
    earlier direction (`ray_points` points tried along it). Uniform points of `[-1, 1]^2`
    whose lines miss the shape give the outside of each domain.

    **Arguments:**

    - `esi`: an [`ESI`][voxax.esi.ESI] or `(dhf_axis, hf_axes)`.
    - `vertices`, `faces`: the closed mesh (any surface form; coordinates finite, of
      magnitude at most `1e75`).
    - `n_samples` (>= 1), `grazing` (degrees in `[0, 180]`), `ray_points` (>= 1),
      `restrict`: as above.
    - `key`: an int (default 0) or a JAX PRNG key; `seed` is its deprecated name.
    - `threads`: threads for the ray casts (`None`: `VOXAX_NUM_THREADS` or every core).

    **Returns:** a [`Training`][voxax.nesi.Training] `(data, frames, center, scale)`.
    """
    where = "voxax.nesi.training_data"
    key = _validate.key_or_seed(where, key, seed)
    return _training_data(where, esi, vertices, faces, n_samples, grazing, ray_points, restrict, key, threads)


def _training_data(where, esi, vertices, faces, n_samples, grazing, ray_points, restrict, key, threads) -> Training:
    from .metrics import sample_surface

    d0, hfa = _axes(where, esi)
    vertices, faces, _ = _validate.unpack_mesh(where, vertices, faces)
    mesh = _esi.closed_mesh(where, vertices, faces)
    n_samples = _validate.positive_int(where, "n_samples", n_samples, bytes_each=2048.0)
    ray_points = _validate.positive_int(where, "ray_points", ray_points)
    grazing = _real(where, "grazing", grazing)
    if grazing > 180:
        raise ValueError(f"{where}: `grazing` must be in [0, 180] degrees, got {grazing}")
    restrict = _flag(where, "restrict", restrict)
    seed = _seed(where, key)
    check_threads(where, threads)
    # the ray casts run on the mesh scaled by an exact power of two to about unit size
    # (the same bits); the normalisation comes back in world units at the end
    pre = exact_scale(bounding_sphere(mesh)[1])
    if pre != 1.0:
        mesh = Mesh(mesh.vertices * pre, mesh.faces)
    c, R = bounding_sphere(mesh)
    s = (1.0 / 1.1) / R
    bvh = BVH(mesh)
    normals = face_normals(mesh.vertices, mesh.faces)
    rng = np.random.default_rng(seed)
    S = sample_surface(mesh, n_samples, seed)
    Q, Qn = S.points, S.normals
    eps = 1e-9 * R
    frames = [_local_frame(d0)] + [_local_frame(d) for d in hfa]

    def loc(frame, p):
        u, v, d = frame
        q = (p - c) * s
        return np.stack([q @ u, q @ v, q @ d], -1)

    def nloc(frame, n):
        u, v, d = frame
        return np.stack([n @ u, n @ v, n @ d], -1)

    def outside(frame, n):
        xy = rng.uniform(-1, 1, (n, 2))
        lo, hi = _lines(bvh, c, R, s, frame, xy, threads)
        return xy[~lo.hit & ~hi.hit]

    vis = {}

    def visible(d, pts=None):
        key = tuple(np.round(d, 14))
        if pts is None:
            if key not in vis:
                vis[key] = ~bvh.any_hits(Q, d, t_min=eps, threads=threads)
            return vis[key]
        return ~bvh.any_hits(pts, d, t_min=eps, threads=threads)

    f0 = frames[0]
    sel = visible(d0) | visible(-d0)
    xy0 = loc(f0, Q[sel])[:, :2]
    lo, hi = _lines(bvh, c, R, s, f0, xy0, threads)
    ok = lo.hit & hi.hit
    xy0 = xy0[ok]
    fb = (lo.t[ok] - 2 * R) * s
    fa = (2 * R - hi.t[ok]) * s
    na = nloc(f0, normals[hi.face[ok]])
    nb = nloc(f0, normals[lo.face[ok]])
    pbar0 = outside(f0, max(len(xy0) // 2, 256))
    pk, fk, nk, restr, pbark = [], [], [], [], []
    earlier = [d0, -d0]
    cos_g = np.cos(np.radians(grazing))
    for k, d in enumerate(hfa):
        fr = frames[k + 1]
        vk = visible(d)
        q, qn = Q[vk], Qn[vk]
        xy = loc(fr, q)[:, :2]
        lo, hi = _lines(bvh, c, R, s, fr, xy, threads)
        ok = hi.hit
        xy, q, qn = xy[ok], q[ok], qn[ok]
        f = (2 * R - hi.t[ok]) * s
        n = nloc(fr, normals[hi.face[ok]])
        if restrict:
            covered = np.zeros(len(q), bool)
            for e in earlier:
                covered |= visible(e)[vk][ok] & (qn @ e > cos_g)
            crit3 = np.zeros(len(q), bool)
            ts = np.linspace(0.0, 2.0 * R, ray_points + 1)[1:]
            for t in ts:
                a = q + t * d
                hidden = np.ones(len(q), bool)
                for e in earlier:
                    hidden &= bvh.any_hits(a, e, t_min=eps, threads=threads)
                crit3 |= hidden
            r = ~covered | crit3
        else:
            r = np.ones(len(q), bool)
        pk.append(xy)
        fk.append(f)
        nk.append(n)
        restr.append(r)
        pbark.append(outside(fr, max(len(xy) // 2, 256)))
        earlier.append(d)
    data = TrainingData(xy0, fa, fb, na, nb, pbar0, pk, fk, nk, restr, pbark)
    return Training(data, frames, c / pre, s * pre)


def _axes(where, esi):
    d0, hfa = _esi_axes(where, esi)
    return d0, list(hfa)


# ----------------------------------------------------------------------------- losses


def _cos_loss(n, ngt, eps=1e-8):
    dot = jnp.sum(n * ngt, -1)
    den = jnp.maximum(jnp.linalg.norm(n, axis=-1) * jnp.linalg.norm(ngt, axis=-1), eps)
    return jnp.mean(1.0 - dot / den)


def losses(net: NESI, data: dict, alpha, eps: float = 0.01) -> dict:
    """The paper's losses (Eq. 6-14) of every explicit, as a dict of scalars.

    `data` holds the [`TrainingData`][voxax.nesi.TrainingData] fields as arrays (the
    HF entries as tuples); `alpha` weighs the normal terms; `eps` is the margin of the
    domain hinges (normalised units).
    """
    out = {}
    normals = not (isinstance(alpha, (int, float)) and alpha == 0)
    p0 = data["p0"]
    if normals:
        o0, g0 = _apply_with_gradient(net.dhf, p0)
        ga, gb = g0[:, 0], g0[:, 1]
    else:
        o0 = _apply(net.dhf, p0)
    fa, fb = o0[:, 0], o0[:, 1]
    out["dhf_height"] = jnp.mean(jnp.abs(fa - data["fa"]) + jnp.abs(fb - data["fb"]))
    ob = _apply(net.dhf, data["pbar0"])
    out["dhf_domain"] = jnp.mean(jnp.maximum(ob[:, 0] - ob[:, 1] + eps, 0.0))
    if normals:
        one = jnp.ones_like(fa)[:, None]
        n_a = jnp.concatenate([-ga, one], -1)
        n_b = jnp.concatenate([gb, -one], -1)
        out["dhf_normal"] = _cos_loss(n_a, data["na"]) + _cos_loss(n_b, data["nb"])
    for k in range(net.n_hf):
        pk, fk, r = data["pk"][k], data["fk"][k], data["restricted"][k]
        if normals:
            f, g = _apply_with_gradient(net.heights[k], pk)
        else:
            f = _apply(net.heights[k], pk)
        w = r.astype(f.dtype)
        nr = jnp.maximum(jnp.sum(w), 1.0)
        nn = jnp.maximum(jnp.sum(1.0 - w), 1.0)
        out[f"hf{k}_height"] = jnp.sum(w * jnp.abs(f - fk)) / nr
        out[f"hf{k}_domain"] = jnp.sum((1.0 - w) * jnp.maximum(fk - f + eps, 0.0)) / nn
        if normals:
            nk = jnp.concatenate([-g, jnp.ones_like(f)[:, None]], -1)
            dot = jnp.sum(nk * data["nk"][k], -1)
            den = jnp.maximum(jnp.linalg.norm(nk, axis=-1) * jnp.linalg.norm(data["nk"][k], axis=-1), 1e-8)
            out[f"hf{k}_normal"] = jnp.sum(w * (1.0 - dot / den)) / nr
        logits = _apply(net.masks[k], jnp.concatenate([pk, data["pbark"][k]]))
        labels = jnp.concatenate(
            [jnp.ones(pk.shape[0], logits.dtype), jnp.zeros(data["pbark"][k].shape[0], logits.dtype)]
        )
        out[f"hf{k}_mask"] = jnp.mean(jax.nn.softplus(logits) - labels * logits)
    total = 0.0
    for name, v in out.items():
        total = total + (alpha * v if name.endswith("normal") else v)
    out["total"] = total
    return out


def fit(
    esi,
    vertices,
    faces=None,
    *,
    lod: int = 1,
    steps: int = 2000,
    learning_rate: float = 1e-3,
    n_samples: int = 20_000,
    normal_start: int | None = None,
    eps: float = 0.01,
    restrict: bool = True,
    key=None,
    seed=None,
    threads: int | None = None,
    progress: bool = True,
) -> NESI:
    """Train a [`NESI`][voxax.nesi.NESI] for an ESI of a closed mesh.

    Full-batch Adam on the training points of
    [`training_data`][voxax.nesi.training_data] with a learning rate cosine-decayed to 0
    over `steps`, through [`voxax.minimize`][voxax.minimize]. The normal terms follow the
    paper's weight `alpha = 0.05 tanh((i - i0)/10) + 0.05`, which is 0 before step `i0 =
    normal_start` and 0.1 after it: training runs in two phases (the second restarts
    Adam's moments), `i0` defaulting to a fifth of `steps` (the paper: 4000).

    Each step is one compiled computation: every network is evaluated once per point set
    as batched matrix products, with the input gradients the normal terms need carried
    forward alongside the activations (no per-point reverse pass, no gradient of a
    gradient), in float32 with polynomial sines and cosines.

    **Arguments:**

    - `esi`: an [`ESI`][voxax.esi.ESI] or `(dhf_axis, hf_axes)`.
    - `vertices`, `faces`: the closed mesh (any surface form: a `voxax.Mesh`, a
      `trimesh.Trimesh`, a `(vertices, faces)` pair or the two arrays).
    - `lod`: level of detail 1-4 (network widths).
    - `steps` (>= 0), `learning_rate` (finite, > 0), `n_samples` (>= 1), `eps` (the
      domain hinges' margin, finite, >= 0), `normal_start` (None or >= 0), `restrict`:
      training settings.
    - `key`: an int (default 0) or a JAX PRNG key, for the training points and the
      initialisation (the same key gives the same network); `seed` is its deprecated name.
    - `threads`: threads for the training points' ray casts (`None`: `VOXAX_NUM_THREADS`
      or every core).
    - `progress`: a bar on standard error per training phase.

    **Returns:** the trained [`NESI`][voxax.nesi.NESI].
    """
    from ._optimize import StopRules, minimize

    where = "voxax.nesi.fit"
    lod = _check_lod(lod, where)
    steps = _validate.positive_int(where, "steps", steps, minimum=0)
    learning_rate = _real(where, "learning_rate", learning_rate, strict=True)
    eps = _real(where, "eps", eps)
    if normal_start is not None:
        normal_start = _validate.positive_int(where, "normal_start", normal_start, minimum=0)
    progress = _flag(where, "progress", progress)
    key = _validate.key_or_seed(where, key, seed)
    _seed(where, key)  # an int or a JAX key
    init_key = _validate.jax_key(where, key)
    data, frames, c, s = _training_data(where, esi, vertices, faces, n_samples, 70.0, 12, restrict, key, threads)
    if len(data.p0) == 0:
        raise ValueError(f"{where}: `n_samples` must be larger: no training points for the DHF")
    d0, hfa = _axes(where, esi)
    net = _init(lod, hfa, key=init_key, frames=frames, center=c, scale=s, dtype=jnp.float32)
    if steps == 0:
        return net
    arrays = {
        "p0": data.p0,
        "fa": data.fa,
        "fb": data.fb,
        "na": data.na,
        "nb": data.nb,
        "pbar0": data.pbar0,
        "pk": tuple(data.pk),
        "fk": tuple(data.fk),
        "nk": tuple(data.nk),
        "restricted": tuple(data.restricted),
        "pbark": tuple(data.pbark),
    }
    arrays = jax.tree_util.tree_map(lambda a: jnp.asarray(a, dtype=None if a.dtype == bool else jnp.float32), arrays)
    params, static = eqx.partition(net, eqx.is_inexact_array)
    i0 = steps // 5 if normal_start is None else min(normal_start, steps)
    for lo_i, hi_i, alpha in ((0, i0, 0.0), (i0, steps, 0.1)):
        if hi_i <= lo_i:
            continue
        # equal settings give the same energy module and optimizer, so that a later fit of
        # the same sizes reuses the compiled step
        opt = _phase_adam(learning_rate, steps, lo_i)
        energy = _PhaseEnergy(static, alpha, eps)
        res = minimize(
            energy,
            params,
            arrays,
            solver=opt,
            stop=StopRules(max_steps=hi_i - lo_i),
            progress=progress,
            rtol=0.0,
            atol=0.0,
        )
        params = res.y
    return eqx.combine(params, static)


class _PhaseEnergy(eqx.Module):
    """The training energy of one phase: the total loss of the parameters `p` combined
    with the network's static part."""

    static: NESI
    alpha: float = eqx.field(static=True)
    eps: float = eqx.field(static=True)

    def __call__(self, p, args):
        return losses(eqx.combine(p, self.static), args, self.alpha, self.eps)["total"]


_PHASE_ADAM: dict = {}


def _phase_adam(learning_rate: float, steps: int, offset: int):
    """Adam on the cosine decay of `learning_rate` over `steps`, from step `offset` on:
    one object per setting (at most 32 kept)."""
    import optax

    key = (learning_rate, steps, offset)
    if key not in _PHASE_ADAM:
        if len(_PHASE_ADAM) >= 32:
            _PHASE_ADAM.clear()
        sched = optax.cosine_decay_schedule(learning_rate, steps)
        _PHASE_ADAM[key] = optax.adam(lambda i: sched(i + offset))
    return _PHASE_ADAM[key]


# ----------------------------------------------------------------------------- queries


def _local(net: NESI, p):
    q = (p - jnp.asarray(net.center, p.dtype)) * net.scale
    fr = jnp.asarray(net.frames, p.dtype)  # (m+1, 3, 3)
    return jnp.einsum("nk,ejk->enj", q, fr)  # (m+1, n, 3)


@eqx.filter_jit
def _occupancy_flat(net: NESI, p):
    loc = _local(net, p)
    box = jnp.all(jnp.abs(loc[0]) <= 1.0, -1)
    out = _apply(net.dhf, loc[0, :, :2])
    inside = box & (loc[0, :, 2] <= out[:, 0]) & (loc[0, :, 2] >= out[:, 1])
    for k in range(net.n_hf):
        xy, z = loc[k + 1, :, :2], loc[k + 1, :, 2]
        inside = inside & (_apply(net.masks[k], xy) > 0) & (z <= _apply(net.heights[k], xy))
    return inside


def occupancy(net: NESI, points) -> jax.Array:
    """Inside/outside of a NESI at world points: inside the DHF (`f_b <= z <= f_a`) and,
    for every HF, inside its mask and below its height. Traceable (jit, vmap).

    Called on concrete points, it evaluates each network only where the answer is still
    open (points outside the DHF's box or volume skip the HFs), in fixed chunks of
    `2^16` points (one compilation per network), with the points' normalised coordinates
    computed in float64 (any finite point); under a trace every network sees every
    point. Float32 networks use a polynomial sine (absolute error < 2e-7).

    **Arguments:** `net`; `points`: `(..., 3)` real, finite (NaN or Inf raise
    `ValueError`, under `jax.jit` too). **Returns:** `(...)` bool.
    """
    where = "voxax.nesi.occupancy"
    _check_net(where, net)
    if not isinstance(points, jax.core.Tracer):
        p = _real_points(where, "points", points)
        lead = p.shape[:-1]
        return jnp.asarray(_occupancy_eager(net, p.reshape(-1, 3))).reshape(lead)
    p = _traced_points(where, "points", points)
    lead = p.shape[:-1]
    return _occupancy_flat(net, p.reshape(-1, 3)).reshape(lead)


def _check_net(where: str, net) -> None:
    if not isinstance(net, NESI):
        raise TypeError(f"{where}: `net` must be a voxax.nesi.NESI, got {type(net).__name__}")


def raytrace(net: NESI, origins, directions, *, n_steps: int = 200, refine: int = 3):
    """First entry of rays into a NESI: `n_steps` uniform steps over the ray's part inside
    the normalised unit sphere, then `refine` bisections of the first step that enters.

    **Arguments:** `origins`, `directions`: `(..., 3)` real, finite (broadcast together),
    directions non-zero: NaN, Inf or zero directions raise `ValueError`, under `jax.jit`
    too; `n_steps` >= 1, `refine` >= 0.

    Called on concrete rays, they are moved into the normalised frame in float64 first, so
    rays and networks of any finite scale work (in float32, a `t` beyond its range reads
    `inf`).

    **Returns:** `(t (...), hit (...) bool)`; `t` is `inf` where the ray misses.
    """
    where = "voxax.nesi.raytrace"
    _check_net(where, net)
    n_steps = _validate.positive_int(where, "n_steps", n_steps)
    refine = _validate.positive_int(where, "refine", refine, minimum=0)
    concrete = not isinstance(origins, jax.core.Tracer) and not isinstance(directions, jax.core.Tracer)
    if concrete:
        o, d = _real_points(where, "origins", origins), _real_points(where, "directions", directions)
        if not np.all(np.abs(d).max(-1) > 0):
            raise ValueError(f"{where}: `directions` must be non-zero")
    else:
        o, d = _traced_points(where, "origins", origins), _traced_points(where, "directions", directions)
        d = eqx.error_if(d, ~jnp.all(jnp.max(jnp.abs(d), -1) > 0), f"{where}: `directions` must be non-zero")
    dt = jnp.result_type(float)
    try:
        o, d = (np if concrete else jnp).broadcast_arrays(o, d)
    except ValueError:
        raise ValueError(
            f"{where}: `origins` and `directions` must broadcast together, got {o.shape} and {d.shape}"
        ) from None
    lead = o.shape[:-1]
    if concrete:
        # in the normalised frame, in float64 (world rays of any finite size), directions
        # scaled to a largest component `k` of 1: `t = t' / (scale k)`
        o64, d64 = np.asarray(o, np.float64).reshape(-1, 3), np.asarray(d, np.float64).reshape(-1, 3)
        k = np.abs(d64).max(-1)
        with np.errstate(over="ignore", invalid="ignore"):
            q = (o64 - np.asarray(net.center)) * net.scale
        unit = NESI(net.dhf, net.heights, net.masks, net.frames, (0.0, 0.0, 0.0), 1.0)
        t, hit = _raytrace(unit, jnp.asarray(q, dt), jnp.asarray(d64 / k[:, None], dt), n_steps, refine)
        with np.errstate(over="ignore"):
            t = np.asarray(t, np.float64) / net.scale / k
        return jnp.asarray(t.reshape(lead), dt), hit.reshape(lead)
    o, d = jnp.asarray(o, dt), jnp.asarray(d, dt)
    t, hit = _raytrace(net, o.reshape(-1, 3), d.reshape(-1, 3), n_steps, refine)
    return t.reshape(lead), hit.reshape(lead)


@eqx.filter_jit
def _raytrace(net, o, d, n_steps, refine):
    c = jnp.asarray(net.center, o.dtype)
    rad = 1.0 / net.scale
    dd = jnp.sum(d * d, -1)
    oc = o - c
    b = jnp.sum(oc * d, -1) / dd
    disc = b * b - (jnp.sum(oc * oc, -1) - rad * rad) / dd
    sq = jnp.sqrt(jnp.maximum(disc, 0.0))
    t0 = jnp.maximum(-b - sq, 0.0)
    t1 = -b + sq
    ts = t0[:, None] + (t1 - t0)[:, None] * jnp.linspace(0.0, 1.0, n_steps)[None]
    pts = o[:, None] + ts[..., None] * d[:, None]
    occ = _occupancy_flat(net, pts.reshape(-1, 3)).reshape(ts.shape) & (disc > 0)[:, None]
    hit = occ.any(1)
    first = jnp.argmax(occ, 1)
    hi_t = jnp.take_along_axis(ts, first[:, None], 1)[:, 0]
    lo_t = jnp.take_along_axis(ts, jnp.maximum(first - 1, 0)[:, None], 1)[:, 0]
    for _ in range(int(refine)):
        mid = 0.5 * (lo_t + hi_t)
        inside = _occupancy_flat(net, o + mid[:, None] * d)
        hi_t = jnp.where(inside, mid, hi_t)
        lo_t = jnp.where(inside, lo_t, mid)
    return jnp.where(hit, hi_t, jnp.inf), hit


def to_mesh(net: NESI, *, resolution: int = 128) -> Mesh:
    """A watertight mesh of a NESI: each explicit's heights on a `resolution^2` pixel grid
    become a height-field solid, and manifold3d intersects them (the paper's App. B).

    Like [`voxax.esi.to_mesh`][voxax.esi.to_mesh]`(esi, vertices, faces, *, resolution)`,
    the representation comes first; a NESI holds its networks, so no mesh follows.

    **Arguments:** `net`; `resolution`: pixels per side (>= 2).

    **Returns:** a `Mesh` in world coordinates.
    """
    where = "voxax.nesi.to_mesh"
    _check_net(where, net)
    r = _validate.positive_int(where, "resolution", resolution, minimum=2)
    if r > 8192:
        raise MemoryError(f"{where}: `resolution` must be at most 8192 (the pixels of every explicit), got {r}")
    c = np.asarray(net.center)
    R = 1.0 / net.scale
    solids = []
    for e, (u, v, d) in enumerate(net.frames):
        fr = _esi.Frame(c, np.asarray(u), np.asarray(v), np.asarray(d), R, r)
        x = fr.coords() * net.scale
        xy = np.stack(np.meshgrid(x, x, indexing="ij"), -1).reshape(-1, 2)
        if e == 0:
            out = np.asarray(net.dhf(jnp.asarray(xy)), np.float64)
            fa, fb = out[:, 0].reshape(r, r) / net.scale, out[:, 1].reshape(r, r) / net.scale
            mask = (fa > fb) & np.all(np.abs(xy) <= 1, -1).reshape(r, r)
            dm = _depth_dummy(fr, np.where(mask, fb, np.nan), np.where(mask, fa, np.nan), mask)
            if not mask.any():
                raise ValueError(f"{where}: `resolution` must be higher: the DHF network is empty at this resolution")
            solids += [_esi.height_field_solid(dm, 1).boundary, _esi.height_field_solid(dm, -1).boundary]
        else:
            h = np.asarray(net.heights[e - 1](jnp.asarray(xy)), np.float64).reshape(r, r) / net.scale
            mask = np.asarray(net.masks[e - 1](jnp.asarray(xy)) > 0).reshape(r, r)
            dm = _depth_dummy(fr, np.where(mask, h, np.nan), np.where(mask, h, np.nan), mask)
            solids.append(_esi.height_field_solid(dm, 1).boundary)
    return _esi.intersect_solids(solids)


def _depth_dummy(frame, first, last, mask) -> _esi.DepthMap:
    r = frame.resolution
    z3 = np.zeros((r, r, 3))
    f = np.full((r, r), -1, np.int32)
    return _esi.DepthMap(first, last, mask, z3, z3, f, f, frame)
