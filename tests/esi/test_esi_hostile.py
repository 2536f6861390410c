"""Hostile input to esi / nesi: every case is a clear error naming the function and the
argument, eagerly and under jit where jit applies; valid extreme input (coordinates from
1e-280 to 1e75) gives the result it gives at unit size."""

import math
import warnings

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import voxax
from voxax import data, energies, esi, nesi

CUBE = data.cube(1.0)
V, F = CUBE.vertices, CUBE.faces
Z, X = (0.0, 0.0, 1.0), (1.0, 0.0, 0.0)
AX = (Z, [X])
SEL = dict(n_dhf=2, n_hf=2, max_hf=1, n_samples=200, resolution=16, progress=False)


@pytest.fixture(scope="module")
def net():
    return nesi.fit((Z, [X]), CUBE, steps=0, n_samples=300, progress=False)


def _nan_vertices():
    return np.where(V == V[0], np.nan, V)


# (call, exception, the message's start or a part of it)
HOSTILE = {
    # surfaces
    "bool vertices": (lambda: esi.select(V.astype(bool), F, **SEL), TypeError, "voxax.esi.select: `vertices` must be a real"),
    "complex vertices": (lambda: esi.depth_map(V.astype(complex), F, Z), TypeError, "`vertices` must be a real"),
    "NaN vertices": (lambda: esi.select(_nan_vertices(), F, **SEL), ValueError, "`vertices` must be finite"),
    "1e80 vertices": (lambda: esi.select(V * 1e80, F, **SEL), ValueError, "magnitude at most 1e75"),
    "subnormal mesh": (lambda: esi.select(V * 1e-310, F, **SEL), ValueError, "extent of at least"),
    "faces beyond V": (lambda: esi.depth_map(V, F.astype(np.int64) + 2**32, Z), ValueError, "`faces` must index"),
    "open mesh": (lambda: esi.select(V, F[:-1], **SEL), ValueError, "must be closed"),
    "fit with bool vertices": (lambda: nesi.fit(AX, V.astype(bool), F, steps=0), TypeError, "voxax.nesi.fit: `vertices`"),
    "fit with the mesh first": (lambda: nesi.fit(CUBE, AX, steps=0), TypeError, "the ESI comes first"),
    "to_mesh with the mesh first": (lambda: esi.to_mesh(CUBE, AX), TypeError, "voxax.esi.to_mesh: `esi` must be"),
    "energy in the old order": (lambda: esi.energy(CUBE, Z, []), TypeError, "voxax.esi.energy: `esi` must be"),
    # select's parameters
    "no HF candidates": (lambda: esi.select(CUBE, **{**SEL, "max_hf": 3}, candidates_hf=np.zeros((0, 3))),
                         ValueError, "`candidates_hf` must hold at least one direction"),
    "no DHF candidates": (lambda: esi.select(CUBE, **SEL, candidates_dhf=np.zeros((0, 3))), ValueError,
                          "`candidates_dhf` must hold"),
    "ragged candidates": (lambda: esi.select(CUBE, **SEL, candidates_dhf=[[1, 0, 0], [0, 1]]), ValueError,
                          "`candidates_dhf` must be an \\(n, 3\\) array"),
    "complex candidates": (lambda: esi.select(CUBE, **SEL, candidates_hf=np.eye(3) * 1j), TypeError,
                           "`candidates_hf` must be a real"),
    "negative tol": (lambda: esi.select(CUBE, **SEL, tol=-1e-3), ValueError, "voxax.esi.select: `tol` must be finite"),
    "NaN tol": (lambda: esi.select(CUBE, **SEL, tol=math.nan), ValueError, "`tol` must be finite"),
    "NaN angle": (lambda: esi.select(CUBE, **SEL, angle=math.nan), ValueError, "`angle` must be finite"),
    "angle 200": (lambda: esi.select(CUBE, **SEL, angle=200.0), ValueError, "`angle` must be finite and in \\[0, 180\\]"),
    "negative eps1": (lambda: esi.select(CUBE, **SEL, eps1=-1.0), ValueError, "`eps1` must be"),
    "infinite eps2": (lambda: esi.select(CUBE, **SEL, eps2=math.inf), ValueError, "`eps2` must be"),
    "max_hf 1.5": (lambda: esi.select(CUBE, **{**SEL, "max_hf": 1.5}), TypeError, "`max_hf` must be an int"),
    "max_hf 9": (lambda: esi.select(CUBE, **{**SEL, "max_hf": 9}), ValueError, "`max_hf` must be in \\[0, 8\\]"),
    "n_samples 0": (lambda: esi.select(CUBE, **{**SEL, "n_samples": 0}), ValueError, "`n_samples` must be at least 1"),
    "n_dhf -1": (lambda: esi.select(CUBE, **{**SEL, "n_dhf": -1}), ValueError, "`n_dhf` must be at least 0"),
    "resolution 1e6": (lambda: esi.select(CUBE, **{**SEL, "resolution": 10**6}), MemoryError, "`resolution`"),
    "key -1": (lambda: esi.select(CUBE, **SEL, key=-1), ValueError, "`key` must be"),
    "key 2.5": (lambda: esi.select(CUBE, **SEL, key=2.5), TypeError, "`key` must be"),
    "key 'a'": (lambda: esi.select(CUBE, **SEL, key="a"), TypeError, "`key` must be"),
    "threads 0": (lambda: esi.select(CUBE, **SEL, threads=0), ValueError, "voxax.esi.select: `threads` must be >= 1"),
    "stop_early 'no'": (lambda: esi.select(CUBE, **SEL, stop_early="no"), TypeError, "`stop_early` must be a bool"),
    # depth maps, occupancy, meshing
    "zero direction": (lambda: esi.depth_map(CUBE, (0, 0, 0)), ValueError, "voxax.esi.depth_map: `direction` must be non-zero"),
    "complex direction": (lambda: esi.depth_map(CUBE, np.array([0, 0, 1j])), TypeError, "`direction` must be a real"),
    "depth map 1e6 pixels a side": (lambda: esi.depth_map(CUBE, Z, resolution=10**6), MemoryError, "`resolution`"),
    "NaN points": (lambda: esi.occupancy(AX, CUBE, [[math.nan, 0, 0]]), ValueError, "voxax.esi.occupancy: `points` must be finite"),
    "bool points": (lambda: esi.occupancy(AX, CUBE, np.ones((2, 3), bool)), TypeError, "`points` must be a real"),
    "NaN HF axis": (lambda: esi.occupancy((Z, [[math.nan, 0, 0]]), CUBE, [[0, 0, 0]]), ValueError, "`esi` must be finite"),
    "HF axes of 2": (lambda: esi.occupancy((Z, [[1, 0]]), CUBE, [[0, 0, 0]]), ValueError, "`esi` must hold HF axes"),
    "to_mesh resolution 1": (lambda: esi.to_mesh(AX, CUBE, resolution=1), ValueError, "`resolution` must be at least 2"),
    "solid sign 0": (lambda: esi.height_field_solid(esi.depth_map(CUBE, Z, resolution=4), 0), ValueError, "`sign` must be"),
    "no solids": (lambda: esi.intersect_solids([]), ValueError, "voxax.esi.intersect_solids: `solids` must hold"),
    "open solid": (lambda: esi.intersect_solids([voxax.Mesh(V, F[:-1])]), ValueError, "`solids` must be closed"),
    "frame of a zero direction": (lambda: esi.frame_for((0, 0, 0), (0, 0, 0), 1.0, 4), ValueError, "`direction` must be"),
    "candidates 2.5": (lambda: esi.candidates(2.5, 3), TypeError, "voxax.esi.candidates: `n_dhf` must be an int"),
    # the grid energies
    "hull axis 2.5": (lambda: energies.height_field_hull(np.zeros((2, 2, 2)), 2.5), TypeError, "`axis` must be an int"),
    "hull of NaN": (lambda: energies.height_field_hull(np.full((2, 2, 2), np.nan)), ValueError, "`W` must be finite"),
    "hull w inf": (lambda: energies.height_field_hull(np.zeros((2, 2, 2)), 2, math.inf), ValueError, "`w` must be finite"),
    "gap axes '2'": (lambda: energies.esi_gap(np.zeros((2, 2, 2)), "2"), TypeError, "voxax.energies.esi_gap: `axes`"),
    # nesi
    "negative eps": (lambda: nesi.fit(AX, CUBE, steps=1, eps=-0.1), ValueError, "voxax.nesi.fit: `eps` must be finite"),
    "NaN learning rate": (lambda: nesi.fit(AX, CUBE, steps=1, learning_rate=math.nan), ValueError, "`learning_rate` must"),
    "zero learning rate": (lambda: nesi.fit(AX, CUBE, steps=1, learning_rate=0.0), ValueError, "`learning_rate` must"),
    "n_samples -1": (lambda: nesi.fit(AX, CUBE, steps=0, n_samples=-1), ValueError, "`n_samples` must be at least 1"),
    "steps 2.5": (lambda: nesi.fit(AX, CUBE, steps=2.5), TypeError, "`steps` must be an int"),
    "lod True": (lambda: nesi.fit(AX, CUBE, lod=True, steps=0), TypeError, "`lod` must be an int"),
    "normal_start -1": (lambda: nesi.fit(AX, CUBE, steps=0, normal_start=-1), ValueError, "`normal_start` must be"),
    "NaN grazing": (lambda: nesi.training_data(AX, CUBE, grazing=math.nan), ValueError, "`grazing` must be finite"),
}  # fmt: skip


@pytest.mark.parametrize("name", list(HOSTILE))
def test_hostile_input_is_a_clear_error(name):
    call, exc, match = HOSTILE[name]
    with pytest.raises(exc, match=match):
        call()


QUERIES = {
    "NaN origins": (lambda n: nesi.raytrace(n, [[math.nan, 0, 3]], [0, 0, -1.0]), "`origins` must be finite"),
    "zero directions": (lambda n: nesi.raytrace(n, [[0, 0, 3.0]], [0, 0, 0.0]), "`directions` must be non-zero"),
    "complex origins": (lambda n: nesi.raytrace(n, np.ones((1, 3), complex), [0, 0, -1.0]), "`origins` must be a real"),
    "no steps": (lambda n: nesi.raytrace(n, [[0, 0, 3.0]], [0, 0, -1.0], n_steps=0), "`n_steps` must be at least 1"),
    "unbroadcastable rays": (lambda n: nesi.raytrace(n, np.ones((2, 3)), np.ones((3, 3))), "must broadcast together"),
    "NaN points": (lambda n: nesi.occupancy(n, [[math.nan, 0, 0]]), "voxax.nesi.occupancy: `points` must be finite"),
    "bool points": (lambda n: nesi.occupancy(n, np.ones((2, 3), bool)), "`points` must be a real"),
    "not a network": (lambda n: nesi.occupancy("net", np.zeros((2, 3))), "`net` must be a voxax.nesi.NESI"),
    "mesh resolution 1": (lambda n: nesi.to_mesh(n, resolution=1), "voxax.nesi.to_mesh: `resolution` must be at least 2"),
}


@pytest.mark.parametrize("name", list(QUERIES))
def test_hostile_queries_of_a_nesi_are_clear_errors(net, name):
    call, match = QUERIES[name]
    with pytest.raises((TypeError, ValueError), match=match):
        call(net)


def test_hostile_queries_of_a_nesi_fail_under_jit_too(net):
    """Under `jax.jit` the values are unknown at trace time: the checks run with the
    computation and raise with the same message (never a silent NaN or miss)."""
    down = jnp.array([0.0, 0.0, -1.0])
    occ = jax.jit(lambda p: nesi.occupancy(net, p))
    ray = jax.jit(lambda o, d: nesi.raytrace(net, o, d, n_steps=4, refine=1))
    assert not bool(occ(jnp.zeros((2, 3))).any())  # the cube's networks are untrained: empty
    with pytest.raises(Exception, match="voxax.nesi.occupancy: `points` must be finite"):
        jax.block_until_ready(occ(jnp.array([[jnp.nan, 0.0, 0.0]])))
    with pytest.raises(Exception, match="`origins` must be finite"):
        jax.block_until_ready(ray(jnp.array([[jnp.inf, 0.0, 3.0]]), down))
    with pytest.raises(Exception, match="`directions` must be non-zero"):
        jax.block_until_ready(ray(jnp.array([[0.0, 0.0, 3.0]]), jnp.zeros(3)))
    with pytest.raises(TypeError, match="`points` must be a real"):
        jax.jit(lambda p: nesi.occupancy(net, p))(jnp.ones((2, 3), bool))


def test_seed_is_a_deprecated_key_and_a_jax_key_works():
    r = esi.select(CUBE, **SEL, key=3)
    with pytest.warns(DeprecationWarning, match="voxax.esi.select: `seed` is deprecated"):
        old = esi.select(CUBE, **SEL, seed=3)
    assert old == r  # value equality of the typed result
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", DeprecationWarning)
        with pytest.raises(TypeError, match="not both"):
            esi.select(CUBE, **SEL, key=3, seed=3)
    k = jax.random.key(5)
    assert esi.select(CUBE, **SEL, key=k) == esi.select(CUBE, **SEL, key=k)


def test_energy_is_the_selections_energy_of_its_axes():
    """`energy` / `energy_terms` of the selected axes, with the same settings and key, is
    the E that `select` reports (the same sampling, the same arithmetic)."""
    m = data.torus(n_major=16, n_minor=8)
    kw = dict(n_samples=300, resolution=16, key=2)
    r = esi.select(m, n_dhf=3, n_hf=4, max_hf=1, progress=False, **kw)
    terms = esi.energy_terms(r, m, **kw)
    assert terms.E == r.energy == esi.energy(r, m, **kw)
    assert terms.dist == r.chamfer and terms.mu == r.mu and terms.dist == terms.cd_st + terms.cd_ts
    assert not np.isnan(r.by_m).any()


def test_every_scale_gives_the_unit_result():
    """Coordinates from 1e-271 to 1e75 are accepted: the selection and the training points
    are the same bits at every power-of-two scale (the computations run at about unit
    size), and at 1e30 the same choice of axes; depth maps, occupancy and meshes are the
    unit ones scaled (exactly, for powers of two)."""
    m = data.torus(n_major=16, n_minor=8)
    kw = dict(n_dhf=3, n_hf=4, max_hf=1, n_samples=300, resolution=16, progress=False)
    r = esi.select(m, **kw)

    def scaled(s):
        return voxax.Mesh(m.vertices * s, m.faces)

    for s in (2.0**240, 2.0**-900):
        assert esi.select(scaled(s), **kw) == r
    for s in (1e30, 1e75 / 1.3):
        big = esi.select(scaled(s), **kw)
        assert (big.dhf_index, big.hf_indices) == (r.dhf_index, r.hf_indices)
        assert math.isfinite(big.energy) and abs(big.energy - r.energy) <= 1e-9 * max(r.energy, 1e-12)
    tiny = 2.0**-900
    dm, dms = esi.depth_map(m, (0.3, 0.2, 1.0), resolution=12), esi.depth_map(scaled(tiny), (0.3, 0.2, 1.0), resolution=12)
    assert np.array_equal(dms.first, dm.first * tiny, equal_nan=True) and np.array_equal(dms.mask, dm.mask)
    t, ts = esi.to_mesh(r, m, resolution=12), esi.to_mesh(r, scaled(tiny), resolution=12)
    assert np.array_equal(ts.vertices, t.vertices * tiny) and np.array_equal(ts.faces, t.faces)
    p = np.random.default_rng(0).uniform(-1.2, 1.2, (500, 3))
    occ = esi.occupancy(r, m, p)
    assert np.array_equal(esi.occupancy(r, scaled(tiny), p * tiny), occ)
    assert np.array_equal(esi.occupancy(r, scaled(1e30), p * 1e30), occ)
    # a point beyond every bounding sphere is outside, however far
    assert not esi.occupancy(r, m, [[1e300, 0.0, 0.0]])[0]
    tr = nesi.training_data((r.dhf_axis, r.hf_axes), m, n_samples=300)
    trs = nesi.training_data((r.dhf_axis, r.hf_axes), scaled(2.0**200), n_samples=300)
    assert trs.data == tr.data and trs.scale * 2.0**200 == tr.scale


def test_random_hostile_surfaces_are_refused_or_exact():
    """A small fuzz of the surfaces of `depth_map`, `occupancy` and `select`: random
    dtypes (bool, complex, int, float), NaN / Inf / 1e80 entries and face indices out of
    range or negative. Each call raises a TypeError or ValueError naming the function, or
    (for valid input) returns a finite result."""
    rng = np.random.default_rng(7)
    calls = {
        "voxax.esi.depth_map": lambda v, f: esi.depth_map(v, f, Z, resolution=8).last,
        "voxax.esi.occupancy": lambda v, f: esi.occupancy(AX, v, f, np.zeros((2, 3))),
        "voxax.esi.select": lambda v, f: esi.select(v, f, **{**SEL, "n_samples": 100}).by_m,
    }
    seen = {"error": 0, "result": 0}
    for _ in range(36):
        v, f = V.copy(), F.astype(np.int64).copy()
        kind = rng.integers(6)
        if kind == 0:
            v = v.astype(rng.choice([bool, complex, np.int32]))
        elif kind == 1:
            v.flat[rng.integers(v.size)] = rng.choice([np.nan, np.inf, -np.inf, 1e80])
        elif kind == 2:
            f.flat[rng.integers(f.size)] = rng.choice([-1, len(v), 2**31, 2**32])
        elif kind == 3:
            v = v * float(rng.choice([1e-250, 1e-30, 1e30, 1e70]))
        elif kind == 4:
            f = f[: rng.integers(len(f))]
        name = list(calls)[rng.integers(len(calls))]
        try:
            with np.errstate(all="ignore"):
                out = np.asarray(calls[name](v, f))
        except (TypeError, ValueError) as e:
            assert str(e).startswith(name + ":"), (name, kind, str(e))
            seen["error"] += 1
            continue
        if name == "voxax.esi.depth_map":  # NaN off the mask only, never Inf
            assert not np.isinf(out).any() and np.isfinite(out).any(), kind
        elif out.dtype.kind == "f":
            assert np.all(np.isfinite(out)), (name, kind)
        seen["result"] += 1
    assert seen["error"] > 10 and seen["result"] > 5


def test_select_is_the_same_for_every_thread_count_and_in_concurrent_threads():
    import concurrent.futures

    m = data.torus(n_major=16, n_minor=8)
    kw = dict(n_dhf=3, n_hf=4, max_hf=2, n_samples=300, resolution=16, progress=False, stop_early=False)
    one = esi.select(m, threads=1, **kw)
    assert esi.select(m, threads=2, **kw) == one and esi.select(m, **kw) == one
    with concurrent.futures.ThreadPoolExecutor(2) as pool:
        runs = list(pool.map(lambda t: esi.select(m, threads=t, **kw), [1, 2]))
    assert all(r == one for r in runs)


def test_every_threaded_entry_point_is_the_same_for_every_thread_count():
    """depth_map, occupancy, to_mesh, energy_terms, nesi.training_data and nesi.fit: the
    same bits with 1 and 2 threads (and with the default)."""
    m = data.torus(n_major=16, n_minor=8)
    p = np.random.default_rng(4).uniform(-1.2, 1.2, (400, 3))
    calls = {
        "depth_map": lambda t: esi.depth_map(m, (0.3, 0.2, 1.0), resolution=12, threads=t),
        "occupancy": lambda t: esi.occupancy(AX, m, p, threads=t),
        "to_mesh": lambda t: esi.to_mesh(AX, m, resolution=12, threads=t),
        "energy_terms": lambda t: esi.energy_terms(AX, m, n_samples=200, resolution=12, threads=t),
        "training_data": lambda t: nesi.training_data(AX, m, n_samples=300, threads=t),
        "fit": lambda t: nesi.fit(AX, m, steps=0, n_samples=300, threads=t, progress=False),
    }
    for name, call in calls.items():
        one, two, default = call(1), call(2), call(None)
        if name == "fit":
            one, two, default = (jax.tree_util.tree_leaves(x) for x in (one, two, default))
            assert all(np.array_equal(a, b) and np.array_equal(a, c) for a, b, c in zip(one, two, default)), name
        elif name == "to_mesh":
            assert np.array_equal(one.vertices, two.vertices) and np.array_equal(one.faces, default.faces), name
        else:
            assert one == two == default if not isinstance(one, np.ndarray) else (
                np.array_equal(one, two) and np.array_equal(one, default)
            ), name
