"""`nearest_neighbors` against brute force in the kernel's own float64 arithmetic (so results
must match bit for bit, ties by index) and scipy's cKDTree, on random and adversarial inputs;
thread-count determinism; hostile input refused eagerly and under jit."""

import concurrent.futures

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import voxax


def brute(S, Q, k):
    """The k smallest (squared distance, index) pairs per query, the squared distance as
    `dx * dx + dy * dy + dz * dz` with `dx = x - q` in IEEE float64 (NumPy's elementwise
    operations round each step); missing neighbours are index -1 at distance inf."""
    S, Q = np.asarray(S, np.float64), np.asarray(Q, np.float64)
    m, n = len(Q), len(S)
    dist = np.full((m, k), np.inf)
    idx = np.full((m, k), -1, np.int32)
    if n:
        dx, dy, dz = (S[None, :, a] - Q[:, None, a] for a in range(3))
        d2 = dx * dx + dy * dy + dz * dz
        order = np.argsort(d2, axis=1, kind="stable")[:, :k]  # stable: ties by index
        kk = order.shape[1]
        idx[:, :kk] = order
        dist[:, :kk] = np.sqrt(np.take_along_axis(d2, order, axis=1))
    return dist, idx


def assert_exact(S, Q, k, **kw):
    d, i = voxax.nearest_neighbors(S, Q, k, **kw)
    rd, ri = brute(S, Q, k)
    assert d.shape == i.shape == (len(Q), k) and d.dtype == np.float64 and i.dtype == np.int32
    np.testing.assert_array_equal(i, ri)
    np.testing.assert_array_equal(d, rd)
    return d, i


def _sphere(rng, n, r=0.8):
    u = rng.normal(size=(n, 3))
    return r * u / np.linalg.norm(u, axis=1, keepdims=True)


def _point_sets():
    rng = np.random.default_rng(7)
    t = rng.uniform(0, 2 * np.pi, 1500)
    few = rng.uniform(-1, 1, (6, 3))
    return {
        "uniform": rng.uniform(-1, 1, (2000, 3)),
        "clustered": np.concatenate([rng.normal(size=(500, 3)) * 0.01, rng.uniform(-1, 1, (100, 3))]),
        "flat": rng.normal(size=(800, 3)) * [1, 1, 1e-9],
        "lattice ties": np.round(rng.uniform(-1, 1, (600, 3)) * 2) / 2,
        "few": rng.uniform(-1, 1, (5, 3)),
        "one point": np.zeros((1, 3)),
        # points on a surface and on a curve: most cells of a volume grid stay empty, and
        # queries in the volume are far from every point (the kd-tree's queries)
        "sphere surface": _sphere(rng, 3000),
        "circle": np.stack([np.cos(t), np.sin(t), 0.3 * np.cos(3 * t)], axis=1),
        "two far clusters": np.concatenate([rng.normal(size=(300, 3)) * 1e-3, 1e3 + rng.normal(size=(300, 3))]),
        "line": np.outer(rng.uniform(-1, 1, 700), [1.0, 2.0, -0.5]),
        "all identical": np.full((400, 3), 0.25),
        "duplicates": np.repeat(few, 60, axis=0)[rng.permutation(360)],
    }


@pytest.mark.parametrize("name", list(_point_sets()))
def test_exact_against_brute_force_and_ckdtree(name):
    from scipy.spatial import cKDTree

    S = _point_sets()[name]
    rng = np.random.default_rng(abs(hash(name)) % 2**32)
    lo, hi = S.min(0), S.max(0)
    span = np.maximum(hi - lo, 1.0)
    Q = np.concatenate([
        rng.uniform(lo - 0.5 * span, hi + 0.5 * span, (250, 3)),  # around and beyond the box
        S[:20],  # on data points (a zero distance, ties among duplicates)
        S[rng.integers(0, len(S), 60)] + rng.normal(size=(60, 3)) * 1e-3 * span,  # near the data
        [[0, 0, 5.0], [-9, 3, 0], [1e6, -1e6, 3e5], [0.0, 0.0, -1e70]],  # far away
    ])
    for k in (1, 2, 3, 4, 5, 8, 32):  # each k the search compiles for, and two it does not
        d, _ = assert_exact(S, Q, k)
        kk = min(k, len(S))
        dr, _ = cKDTree(S).query(Q, kk)
        np.testing.assert_allclose(d[:, :kk], np.asarray(dr).reshape(len(Q), kk), rtol=1e-13, atol=1e-300)


def test_points_all_far_away_and_k_beyond_the_count():
    rng = np.random.default_rng(3)
    S = 1e6 + rng.uniform(-1, 1, (50, 3))  # a small cloud far from every query
    Q = rng.uniform(-1, 1, (200, 3))
    assert_exact(S, Q, 5)
    assert_exact(S[:3], Q, 8)  # k > N: three neighbours, then -1 at inf
    d, i = voxax.nearest_neighbors(S[:3], Q, 8)
    assert np.all(i[:, 3:] == -1) and np.all(np.isinf(d[:, 3:])) and np.all(i[:, :3] >= 0)
    d, i = voxax.nearest_neighbors(np.zeros((0, 3)), np.ones((2, 3)), 3)
    assert np.all(i == -1) and np.all(np.isinf(d))
    d, i = voxax.nearest_neighbors(S, np.zeros((0, 3)), 2)
    assert d.shape == i.shape == (0, 2)


def test_ties_go_to_the_smaller_index():
    # the 8 corners of a cube around each query: all at the same distance
    corners = np.array([[x, y, z] for x in (0.0, 1.0) for y in (0.0, 1.0) for z in (0.0, 1.0)])
    S = np.concatenate([corners + off for off in np.arange(5)[:, None] * [3.0, 0, 0]])[::-1].copy()
    Q = np.array([[0.5 + 3 * j, 0.5, 0.5] for j in range(5)] + [[-40.0, 0.5, 0.5]])
    d, i = assert_exact(S, Q, 8)
    for j in range(5):
        assert np.all(d[j] == d[j, 0]) and np.all(np.diff(i[j]) > 0)


def test_same_bits_for_every_thread_count_and_under_jit():
    rng = np.random.default_rng(8)
    S = np.concatenate([_sphere(rng, 4000), rng.uniform(size=(1000, 3))])
    Q = np.concatenate([rng.uniform(-1.5, 1.5, (3000, 3)), S[rng.integers(0, len(S), 3000)] + 1e-3])
    a = voxax.nearest_neighbors(S, Q, 6, threads=1)
    b = voxax.nearest_neighbors(S, Q, 6, threads=2)
    c = voxax.nearest_neighbors(S, Q, 6, threads=3)
    j = jax.jit(lambda s, q: voxax.nearest_neighbors(s, q, 6))(jnp.asarray(S), jnp.asarray(Q))
    with concurrent.futures.ThreadPoolExecutor(3) as pool:
        conc = list(pool.map(lambda t: voxax.nearest_neighbors(S, Q, 6, threads=t), (1, 2, 2)))
    for other in (b, c, j, *conc):
        for x, y in zip(a, other):
            np.testing.assert_array_equal(x, np.asarray(y))
    d, _ = voxax.nearest_neighbors(S, Q[:12].reshape(3, 4, 3), 2)
    assert d.shape == (3, 4, 2)


S3 = np.random.default_rng(1).uniform(size=(10, 3))

# (points, queries, k, exception, message)
HOSTILE = {
    "k float": (S3, S3, 2.7, TypeError, "`k` must be an int"),
    "k integral float": (S3, S3, 2.0, TypeError, "`k` must be an int"),
    "k string": (S3, S3, "2", TypeError, "`k` must be an int"),
    "k bool": (S3, S3, True, TypeError, "`k` must be an int"),
    "k NaN": (S3, S3, float("nan"), TypeError, "`k` must be an int"),
    "k none": (S3, S3, None, TypeError, "`k` must be an int"),
    "k zero": (S3, S3, 0, ValueError, r"`k` must lie in \[1, 32\]"),
    "k 33": (S3, S3, 33, ValueError, r"`k` must lie in \[1, 32\]"),
    "bool points": (S3 > 0.5, S3, 1, TypeError, "`points` must be a real"),
    "complex queries": (S3, S3 + 1j, 1, TypeError, "`queries` must be a real"),
    "string points": ("points", S3, 1, TypeError, "`points` must be a real"),
    "NaN points": (np.where(np.arange(30).reshape(10, 3) == 7, np.nan, S3), S3, 1, ValueError,
                   "`points` must be finite: row 2"),
    "inf queries": (S3, [[0, 0, np.inf]], 1, ValueError, "`queries` must be finite: row 0"),
    "huge queries": (S3, [[0, 1e80, 0]], 1, ValueError, "`queries` must be at most 1e75"),
    "tiny points": (S3 * 1e-90, S3, 1, ValueError, "`points` must not all be below 1e-75"),
    "points rank 1": (S3[0], S3, 1, ValueError, r"`points` must have shape \(N, 3\)"),
    "queries of 2D points": (S3, S3[:, :2], 1, ValueError, r"`queries` must have shape \(\.\.\., 3\)"),
}


@pytest.mark.parametrize("case", list(HOSTILE))
def test_hostile_input_is_refused_eagerly(case):
    s, q, k, exc, match = HOSTILE[case]
    with pytest.raises(exc, match="^voxax.nearest_neighbors: " + match):
        voxax.nearest_neighbors(s, q, k)


@pytest.mark.parametrize("which", ["points", "queries"])
def test_hostile_values_are_refused_under_jit(which):
    good = jnp.asarray(S3)

    def call(x):
        return voxax.nearest_neighbors(x, good, 2) if which == "points" else voxax.nearest_neighbors(good, x, 2)

    for bad, match in ((jnp.full((2, 3), jnp.nan), "must be finite"), (jnp.full((2, 3), 1e80), "must be at most 1e75")):
        with pytest.raises(Exception, match=f"voxax.nearest_neighbors: `{which}` {match}"):
            jax.block_until_ready(jax.jit(call)(bad))
    with pytest.raises(TypeError, match=f"`{which}` must be a real"):
        jax.jit(call)(jnp.ones((2, 3), bool))
    with pytest.raises(TypeError, match="`k` must be a Python int, got a traced value"):
        jax.jit(lambda s, k: voxax.nearest_neighbors(s, s, k))(good, 2)
    if which == "points":
        with pytest.raises(Exception, match="`points` must not all be below 1e-75"):
            jax.block_until_ready(jax.jit(call)(good * 1e-300))
