"""Neural explicit surface intersections: network sizes, training data, a tiny fit."""

import equinox as eqx
import jax
import numpy as np
import pytest

import voxax
from voxax import data, esi, metrics, nesi

# the appendix's parameter counts (DHF, HF with its mask) for levels of detail 1-4
PAPER = {1: (4390, 1766), 2: (9654, 3110), 3: (21390, 6088), 4: (37734, 10214)}
Z, X = (0.0, 0.0, 1.0), (1.0, 0.0, 0.0)
FRAMES = tuple(((1.0, 0, 0), (0, 1.0, 0), (0, 0, 1.0)) for _ in range(4))


@pytest.mark.parametrize("lod", [1, 2, 3, 4])
def test_parameter_counts_match_the_architecture_and_the_paper(lod):
    key = jax.random.key(0)
    dhf_only = nesi._init(lod, (), key=key, frames=FRAMES[:1])
    three = nesi._init(lod, (X, X, X), key=key, frames=FRAMES)
    w, wh = nesi.DHF_WIDTHS[lod - 1], nesi.HF_WIDTHS[lod - 1]
    # SIREN 2 -> w (5 hidden layers) -> 2, and 2 -> wh -> 1 plus a 2 -> 16 (3 layers) -> 1 mask
    dhf = (2 * w + w) + 4 * (w * w + w) + (2 * w + 2)
    hf = (2 * wh + wh) + 4 * (wh * wh + wh) + (wh + 1) + (2 * 16 + 16) + 2 * (16 * 16 + 16) + 17
    assert nesi.param_count(dhf_only) == dhf
    assert nesi.param_count(three) == dhf + 3 * hf
    p_dhf, p_hf = PAPER[lod]
    assert abs(dhf - p_dhf) <= 6 and abs(hf - p_hf) <= 6


def test_restricted_domain_of_a_cube():
    # DHF along z, one HF along +x: the +x face is seen from z only at 90 degrees
    # (criterion 2), the +-y faces likewise; the +-z faces are covered by the DHF
    cube = data.cube(2.0)
    d, frames, c, s = nesi.training_data((Z, [X]), cube, n_samples=3000, key=1)
    u, v, w = frames[1]
    assert np.allclose(w, X)
    # recover world points of the HF's training samples: normalised (x, y, f) in its frame
    loc = np.concatenate([d.pk[0], d.fk[0][:, None]], 1) / s
    world = c + loc[:, :1] * u + loc[:, 1:2] * v + loc[:, 2:] * w
    # every HF sample lies on the +x face's line of sight: its top hit is the +x face
    np.testing.assert_allclose(world[:, 0], 1.0, atol=1e-12)
    # the DHF's heights are the cube's top and bottom
    np.testing.assert_allclose(d.fa / s, 1.0, atol=1e-12)
    np.testing.assert_allclose(d.fb / s, -1.0, atol=1e-12)
    assert len(d.pbar0) > 0 and np.all(np.abs(d.pbar0 / s).max(1) > 1.0 - 1e-12)


def test_restriction_criteria_on_the_cube_faces():
    # generic axes (no ray runs in a face's plane): the DHF sees +-z well (at 12.6 degrees)
    # and +-x, +-y only beyond 70 degrees; the HF along d1 sees +x, +y and +z, of which
    # +z is already covered, and no point beyond the cube is hidden from +-d0
    cube = data.cube(2.0)
    d0 = np.array([0.2, 0.1, 1.0])
    d1 = np.array([1.0, 0.3, 0.2])
    d, frames, c, s = nesi.training_data((d0, [d1]), cube, n_samples=6000, key=1)
    r = d.restricted[0]
    assert len(r) > 2000
    assert abs((~r).mean() - 1 / 3) < 0.03
    # the restricted samples' lines end on the +x or +y face, the others' on +z
    u, v, w = frames[1]
    loc = np.concatenate([d.pk[0], d.fk[0][:, None]], 1) / s
    world = c + loc[:, :1] * u + loc[:, 1:2] * v + loc[:, 2:] * w
    on_z = np.abs(world[:, 2] - 1) < 1e-9
    assert np.mean(on_z[~r]) > 0.95 and np.mean(on_z[r]) < 0.05


@pytest.fixture(scope="module")
def tiny_fit():
    m = data.icosphere(3, radius=0.8)
    ax = (Z, [X])
    return m, ax, nesi.fit(ax, m, steps=60, normal_start=60, n_samples=1000, learning_rate=3e-3, key=0)


def test_float32_sine_of_the_queries_matches_numpy():
    # occupancy, ray casting and training evaluate float32 networks with fused polynomial
    # sines and cosines; their derivatives (used by the normal loss and its gradient) are
    # each other's, not the polynomials'
    from voxax.nesi import _cos32, _sin32

    x = np.linspace(-120.0, 120.0, 200_001).astype(np.float32)
    x64 = x.astype(np.float64)

    def derivatives(x):
        d1 = jax.vmap(jax.grad(_sin32))(x)
        d2 = jax.vmap(jax.grad(jax.grad(_sin32)))(x)
        return _sin32(x), _cos32(x), d1, d2

    s, c, d1, d2 = (np.asarray(a, np.float64) for a in jax.jit(derivatives)(x))
    assert np.max(np.abs(s - np.sin(x64))) < 3e-7
    assert np.max(np.abs(c - np.cos(x64))) < 3e-7
    np.testing.assert_array_equal(d1, c)
    assert np.max(np.abs(d2 + np.sin(x64))) < 3e-7


def test_tiny_fit_agrees_with_the_exact_esi(tiny_fit):
    m, ax, net = tiny_fit
    p = np.random.default_rng(0).uniform(-1.0, 1.0, (20_000, 3))
    occ = np.asarray(nesi.occupancy(net, p))
    ref = esi.occupancy(ax, m, p)
    assert (occ == ref).mean() > 0.92  # measured 0.947 after 60 full-batch steps
    # rays from above: the traced entry depth against the exact first hit
    o = np.random.default_rng(1).uniform(-0.4, 0.4, (100, 3))
    o[:, 2] = 3.0
    t, hit = nesi.raytrace(net, o, np.array([0.0, 0.0, -1.0]))
    ex = voxax.first_hits(m, o, np.array([0.0, 0.0, -1.0]))
    t, hit = np.asarray(t), np.asarray(hit)
    assert hit.mean() > 0.95 and np.all(ex.hit)
    assert np.median(np.abs(t[hit] - ex.t[hit])) < 0.1  # measured 0.067


def test_tiny_fit_meshes_watertight(tiny_fit):
    m, ax, net = tiny_fit
    tm = nesi.to_mesh(net, resolution=48)
    assert metrics.manifold_report(tm).watertight
    assert tm.signed_volume() > 0


def test_nesi_rejects_bad_input():
    cube = data.cube(1.0)
    with pytest.raises(ValueError, match="voxax.nesi.fit: `lod` must be 1, 2, 3 or 4"):
        nesi.fit((Z, []), cube, lod=5)
    with pytest.raises(ValueError, match="closed"):
        nesi.fit((Z, []), cube.vertices, cube.faces[:-1], steps=0)
    with pytest.raises(ValueError, match="`esi` must be non-zero"):
        nesi.fit(((0, 0, 0), []), cube, steps=0)
    net = nesi.fit((Z, []), cube, steps=0, n_samples=500)
    with pytest.raises(ValueError, match="voxax.nesi.occupancy: `points` must have shape"):
        nesi.occupancy(net, np.zeros((3, 2)))
    with pytest.raises(ValueError, match="voxax.nesi.to_mesh: `resolution` must be at least 2"):
        nesi.to_mesh(net, resolution=1)


def _reference_losses(net, d, alpha, eps):
    """Eq. 6-14 written point by point: each network called on one point, its input
    gradient by reverse-mode autodiff (`jax.grad`), XLA's sine."""
    import jax.numpy as jnp

    def cos_term(g, sign, ngt):
        n = jnp.concatenate([sign * g, -sign * jnp.ones(1)])
        return 1.0 - n @ ngt / jnp.maximum(jnp.linalg.norm(n) * jnp.linalg.norm(ngt), 1e-8)

    dhf = net.dhf._single
    fa = jax.vmap(lambda p: dhf(p)[0])(d["p0"])
    fb = jax.vmap(lambda p: dhf(p)[1])(d["p0"])
    ga = jax.vmap(jax.grad(lambda p: dhf(p)[0]))(d["p0"])
    gb = jax.vmap(jax.grad(lambda p: dhf(p)[1]))(d["p0"])
    ob = jax.vmap(dhf)(d["pbar0"])
    total = jnp.mean(jnp.abs(fa - d["fa"]) + jnp.abs(fb - d["fb"]))
    total += jnp.mean(jnp.maximum(ob[:, 0] - ob[:, 1] + eps, 0.0))
    na = jax.vmap(lambda g, n: cos_term(g, -1.0, n))(ga, d["na"])
    nb = jax.vmap(lambda g, n: cos_term(g, 1.0, n))(gb, d["nb"])
    total += alpha * (jnp.mean(na) + jnp.mean(nb))
    for k in range(net.n_hf):
        h, mask = net.heights[k]._single, net.masks[k]._single
        p, r = d["pk"][k], d["restricted"][k]
        f = jax.vmap(h)(p)
        g = jax.vmap(jax.grad(h))(p)
        nk = jax.vmap(lambda g, n: cos_term(g, -1.0, n))(g, d["nk"][k])
        total += jnp.sum(jnp.where(r, jnp.abs(f - d["fk"][k]), 0.0)) / jnp.maximum(jnp.sum(r), 1)
        total += jnp.sum(jnp.where(r, 0.0, jnp.maximum(d["fk"][k] - f + eps, 0.0))) / jnp.maximum(jnp.sum(~r), 1)
        total += alpha * jnp.sum(jnp.where(r, nk, 0.0)) / jnp.maximum(jnp.sum(r), 1)
        inside, outside = jax.vmap(mask)(p), jax.vmap(mask)(d["pbark"][k])
        bce = jnp.concatenate([jax.nn.softplus(-inside), jax.nn.softplus(outside)])
        total += jnp.mean(bce)
    return total


def test_fused_losses_match_pointwise_autodiff():
    # the training step evaluates each network once with its input gradient carried
    # forward through batched products; the loss and its parameter gradient must equal
    # those of the per-point reverse-mode formulation (float64, XLA's sine in both)
    import jax.numpy as jnp

    rng = np.random.default_rng(3)
    n = 40

    def unit(k):
        v = rng.normal(size=(k, 3))
        return v / np.linalg.norm(v, axis=1, keepdims=True)

    d = {
        "p0": rng.uniform(-1, 1, (n, 2)),
        "fa": rng.uniform(0, 0.5, n),
        "fb": rng.uniform(-0.5, 0, n),
        "na": unit(n),
        "nb": unit(n),
        "pbar0": rng.uniform(-1, 1, (n // 2, 2)),
        "pk": (rng.uniform(-1, 1, (n, 2)),),
        "fk": (rng.uniform(-0.5, 0.5, n),),
        "nk": (unit(n),),
        "restricted": (rng.uniform(size=n) < 0.6,),
        "pbark": (rng.uniform(-1, 1, (n // 2, 2)),),
    }
    dt = jnp.dtype("float64")
    d = jax.tree_util.tree_map(lambda a: jnp.asarray(a, None if a.dtype == bool else dt), d)

    def siren(out, width, depth):  # random weights from NumPy (no compilation)
        shape = eqx.filter_eval_shape(voxax.fields.Siren, 2, out, width, depth, key=jax.random.key(0))
        sizes = [2] + [width] * depth + [out]
        w = [jnp.asarray(rng.uniform(-1, 1, (o, i)) / i, dt) for i, o in zip(sizes, sizes[1:])]
        b = [jnp.asarray(rng.uniform(-1, 1, o), dt) for o in sizes[1:]]
        return eqx.tree_at(lambda s: (s.weights, s.biases), shape, (w, b))

    dhf, height, mask = siren(2, 8, 2), siren(1, 6, 2), siren(1, 4, 1)
    net = nesi.NESI(dhf, (height,), (mask,), FRAMES[:2], (0.0,) * 3, 1.0)
    params, static = eqx.partition(net, eqx.is_inexact_array)
    fused = jax.jit(jax.value_and_grad(lambda p: nesi.losses(eqx.combine(p, static), d, 0.1, 0.01)["total"]))
    ref = jax.jit(jax.value_and_grad(lambda p: _reference_losses(eqx.combine(p, static), d, 0.1, 0.01)))
    (v, g), (v_ref, g_ref) = jax.device_get((fused(params), ref(params)))
    g = [np.asarray(x, np.float64) for x in jax.tree_util.tree_leaves(g)]
    g_ref = [np.asarray(x, np.float64) for x in jax.tree_util.tree_leaves(g_ref)]
    assert len(g) == len(g_ref) == 16
    tol = 1e-11
    assert abs(float(v) - float(v_ref)) <= tol * abs(float(v_ref))
    scale = max(np.abs(x).max() for x in g_ref)
    for a, b in zip(g, g_ref):
        np.testing.assert_allclose(a, b, atol=tol * scale, rtol=0)


def test_a_second_fit_of_the_same_sizes_reuses_the_compiled_steps(tiny_fit, monkeypatch):
    """A fit with the settings and sizes of an earlier one hits its compiled step:
    `losses` is traced only by the shape inference, and the result is the same."""
    m, ax, net = tiny_fit
    traces = {"n": 0}
    losses = nesi.losses

    def counted(*a, **k):
        traces["n"] += 1
        return losses(*a, **k)

    monkeypatch.setattr(nesi, "losses", counted)
    again = nesi.fit(ax, m, steps=60, normal_start=60, n_samples=1000, learning_rate=3e-3, key=0)
    assert traces["n"] == 1
    for a, b in zip(jax.tree_util.tree_leaves(net), jax.tree_util.tree_leaves(again), strict=True):
        assert np.array_equal(np.asarray(a), np.asarray(b))


def test_raytrace_is_the_same_at_every_scale_of_the_directions(tiny_fit):
    """Concrete rays are cast in the normalised frame in float64: directions of any length
    give the same entry points (`t` scaled by the inverse length), never a NaN."""
    m, ax, net = tiny_fit
    o = np.random.default_rng(1).uniform(-0.4, 0.4, (50, 3))
    o[:, 2] = 3.0
    down = np.array([0.0, 0.0, -1.0])
    t, hit = (np.asarray(a) for a in nesi.raytrace(net, o, down, n_steps=50))
    assert hit.mean() > 0.9
    for f in (1e-200, 2.0**-600, 1e200):
        ts, hs = (np.asarray(a) for a in nesi.raytrace(net, o, down * f, n_steps=50))
        assert np.array_equal(hs, hit) and not np.isnan(ts).any()
        np.testing.assert_allclose(ts[hit] * f, t[hit], rtol=1e-12, atol=0)
