"""The BVH's closest points and ray hits against brute-force NumPy oracles written here."""

import numpy as np
import pytest
from conftest import brute_distance

import voxax
from voxax import data, fields, metrics

# -- independent oracles ---------------------------------------------------------------------


def brute_hits(o, d, V, F):
    """All (t, face) hits per ray by Moller-Trumbore on every triangle (generic rays)."""
    a, b, c = V[F[:, 0]], V[F[:, 1]], V[F[:, 2]]
    out = []
    for oi, di in zip(o, d):
        e1, e2 = b - a, c - a
        pv = np.cross(di, e2)
        det = np.sum(e1 * pv, -1)
        good = np.abs(det) > 1e-14
        inv = 1 / np.where(good, det, 1)
        tv = oi - a
        u = np.sum(tv * pv, -1) * inv
        qv = np.cross(tv, e1)
        v = np.sum(di * qv, -1) * inv
        t = np.sum(e2 * qv, -1) * inv
        hit = good & (u >= 0) & (v >= 0) & (u + v <= 1) & (t >= 0)
        idx = np.flatnonzero(hit)
        order = np.lexsort((idx, t[idx]))
        out.append((t[idx][order], idx[order]))
    return out


def random_soup(rng, nf=150, degenerate=20):
    V = rng.uniform(-1, 1, (3 * nf, 3))
    F = np.arange(3 * nf).reshape(nf, 3)
    # degenerate faces: a repeated vertex, collinear corners, a point triangle
    k = rng.choice(nf, degenerate, replace=False)
    for j, f in enumerate(k):
        i0, i1, i2 = F[f]
        if j % 3 == 0:
            V[i2] = V[i1]
        elif j % 3 == 1:
            V[i2] = V[i0] + 0.37 * (V[i1] - V[i0])
        else:
            V[i1] = V[i2] = V[i0]
    return V, F


# -- closest points ------------------------------------------------------------------------------


def test_closest_points_random_soup():
    rng = np.random.default_rng(0)
    V, F = random_soup(rng)
    P = np.concatenate(
        [rng.uniform(-1.5, 1.5, (400, 3)), V[:50] + 1e-3 * rng.normal(size=(50, 3))]
    )
    res = voxax.closest_points((V, F), P)
    np.testing.assert_allclose(
        res.distance, brute_distance(P, V, F), rtol=1e-12, atol=1e-14
    )
    # the returned point lies on the returned face at the returned distance
    corners = V[F[res.face]]
    np.testing.assert_allclose(
        np.einsum("pk,pkd->pd", res.barycentric, corners), res.point, atol=1e-13
    )
    np.testing.assert_allclose(
        np.linalg.norm(P - res.point, axis=1), res.distance, rtol=1e-12, atol=1e-15
    )
    assert np.all(res.barycentric >= -1e-12) and np.allclose(
        res.barycentric.sum(1), 1, atol=1e-12
    )
    # leading shapes
    res2 = voxax.closest_points((V, F), P[:12].reshape(3, 4, 3))
    assert res2.distance.shape == (3, 4) and res2.point.shape == (3, 4, 3)
    np.testing.assert_array_equal(res2.distance.ravel(), res.distance[:12])


def test_closest_points_within_a_distance():
    """`max_distance`: the brute-force distances where they are within it (the same bits as
    an unbounded query), `inf` and face -1 beyond, for 1 and 2 threads; a bad bound raises."""
    rng = np.random.default_rng(4)
    V, F = random_soup(rng)
    P = rng.uniform(-1.5, 1.5, (600, 3))
    bvh = voxax.BVH(V, F)
    full = bvh.closest_points(P)
    want = brute_distance(P, V, F)
    for cap in (0.0, 0.05, float(np.median(want)), 10.0):
        for threads in (1, 2):
            got = bvh.closest_points(P, max_distance=cap, threads=threads)
            near = full.distance <= cap
            assert np.array_equal(got.distance[near], full.distance[near])
            assert np.array_equal(got.face[near], full.face[near])
            assert np.all(np.isinf(got.distance[~near])) and np.all(got.face[~near] == -1)
            assert np.array_equal(near, want <= cap) or abs(cap - want).min() < 1e-12
        if cap == float(np.median(want)):
            assert 0 < near.sum() < len(P)
    with pytest.raises(ValueError, match="max_distance"):
        bvh.closest_points(P, max_distance=-1.0)


@pytest.mark.parametrize("shift", [0.0, 1e3])
def test_closest_points_on_a_smooth_mesh_far_and_near(shift):
    # a smooth surface is where the nodes' flat-cylinder bounds prune: points far from it
    # (whole caps of triangles at nearly the same distance) and within 1e-9..1e-2 of it,
    # also translated far from the origin, against the brute-force distance
    m = data.torus(48, 24)
    V = m.vertices + shift
    F = np.asarray(m.faces)
    rng = np.random.default_rng(3)
    s = metrics.sample_surface(m, 150, key=2)
    eps = 10.0 ** rng.uniform(-9, -2, (150, 1)) * rng.choice([-1, 1], (150, 1))
    P = np.concatenate([rng.uniform(-2.5, 2.5, (250, 3)), s.points + eps * s.normals]) + shift
    res = voxax.closest_points((V, F), P)
    np.testing.assert_allclose(
        res.distance, brute_distance(P, V, F), rtol=1e-12, atol=1e-12 * (1 + shift)
    )
    np.testing.assert_allclose(
        np.linalg.norm(P - res.point, axis=1), res.distance, rtol=1e-12, atol=1e-12 * (1 + shift)
    )


def test_closest_points_on_a_box_is_the_exact_box_distance():
    cube = data.box((-0.3, -0.5, -0.2), (0.3, 0.5, 1.2))
    lo, hi = cube.bounds
    rng = np.random.default_rng(1)
    P = rng.uniform(-2, 2, (3000, 3))
    d = voxax.closest_points(cube, P).distance
    exact = np.abs(np.asarray(fields.box(P, (hi - lo) / 2, center=(hi + lo) / 2)))
    np.testing.assert_allclose(d, exact, rtol=1e-12, atol=1e-14)


def test_closest_points_sphere_distances():
    # points on rays through the vertices of an icosphere, beyond the surface: the closest
    # point is the vertex itself (the vertex region), distance |p| - r exactly
    s = data.icosphere(2, radius=0.8)
    r = np.linalg.norm(s.vertices, axis=1)
    P = s.vertices * (1 + 0.5 / r)[:, None]
    res = voxax.closest_points(s, P)
    np.testing.assert_allclose(res.distance, 0.5, rtol=1e-12)
    np.testing.assert_allclose(res.point, s.vertices, atol=1e-13)


def test_empty_mesh_and_degenerate_only():
    res = voxax.closest_points(
        (np.zeros((0, 3)), np.zeros((0, 3), int)), np.zeros((2, 3))
    )
    assert np.all(np.isinf(res.distance)) and np.all(res.face == -1)
    V = np.array([[0, 0, 0], [1, 0, 0], [2, 0, 0.0]])
    res = voxax.closest_points((V, [[0, 1, 2]]), [[1.5, 1.0, 0.0], [3.0, 0.0, 0.0]])
    np.testing.assert_allclose(res.distance, [1.0, 1.0], rtol=1e-15)
    hits = voxax.first_hits((V, [[0, 1, 2]]), [[1.0, -1.0, 0.0]], [[0.0, 1.0, 0.0]])
    assert not hits.hit[0]


# -- rays -------------------------------------------------------------------------------------------


def test_rays_random_soup_vs_brute_force():
    rng = np.random.default_rng(2)
    V, F = random_soup(rng, nf=120)
    o = rng.uniform(-1.5, 1.5, (300, 3))
    d = rng.normal(size=(300, 3))
    bvh = voxax.BVH(V, F)
    ref = brute_hits(o, d, V, F)
    first = bvh.first_hits(o, d)
    allh = bvh.all_hits(o, d)
    anyh = bvh.any_hits(o, d)
    for i, (t, f) in enumerate(ref):
        assert anyh[i] == (len(t) > 0)
        if len(t):
            assert first.face[i] == f[0]
            np.testing.assert_allclose(first.t[i], t[0], rtol=1e-10)
            hit_point = np.einsum("k,kd->d", first.barycentric[i], V[F[first.face[i]]])
            np.testing.assert_allclose(hit_point, o[i] + first.t[i] * d[i], atol=1e-10)
        else:
            assert first.face[i] == -1 and np.isinf(first.t[i])
        s = slice(allh.offsets[i], allh.offsets[i + 1])
        np.testing.assert_array_equal(allh.face[s], f)
        np.testing.assert_allclose(allh.t[s], t, rtol=1e-10)
    assert np.all(allh.ray == np.repeat(np.arange(300), allh.counts()))
    # the interval [t_min, t_max] restricts hits
    limited = bvh.all_hits(o, d, t_min=0.5, t_max=1.0)
    assert np.all((limited.t >= 0.5) & (limited.t <= 1.0))
    assert limited.t.size == np.sum((allh.t >= 0.5) & (allh.t <= 1.0))
    # sign: -1 against the normal
    n = np.cross(
        V[F[allh.face, 1]] - V[F[allh.face, 0]], V[F[allh.face, 2]] - V[F[allh.face, 0]]
    )
    np.testing.assert_array_equal(allh.sign, np.sign(np.sum(n * d[allh.ray], 1)))


def ray_avx2(bvh):
    """Whether the BVH's first hits take the AVX2 traversal (else the baseline one)."""
    import ctypes

    from voxax._kernels._loader import library

    fn = library().voxax_bvh_ray_avx2
    fn.restype, fn.argtypes = ctypes.c_int32, [ctypes.c_void_p]
    return bool(fn(bvh._handle))


@pytest.fixture(params=["avx2", "baseline"])
def ray_path(request, monkeypatch):
    """Each first-hit traversal in turn: the AVX2 one (where the CPU has AVX2) and the
    baseline (SSE2) one, forced by VOXAX_NO_AVX2=1, which a BVH reads when it is built."""
    from voxax._kernels.cpu import cpu_features

    if request.param == "baseline":
        monkeypatch.setenv("VOXAX_NO_AVX2", "1")
    else:
        monkeypatch.delenv("VOXAX_NO_AVX2", raising=False)
        if not cpu_features()["cpu"]["avx2"]:
            pytest.skip("this CPU has no AVX2")
    return request.param


def path_bvh(ray_path, *mesh):
    bvh = voxax.BVH(*mesh)
    assert ray_avx2(bvh) == (ray_path == "avx2")
    return bvh


@pytest.mark.parametrize("nf", [1, 3, 5, 9, 17, 40])
def test_first_hits_of_small_trees_and_axis_rays_vs_brute_force(nf, ray_path):
    # small soups give four-wide records with two, three and four children (and a leaf as
    # the root); rays with one or two zero direction components take the scalar box test
    rng = np.random.default_rng(nf)
    V, F = random_soup(rng, nf=nf, degenerate=0)
    o = rng.uniform(-1.5, 1.5, (240, 3))
    d = rng.normal(size=(240, 3))
    d[np.arange(80, 160), rng.integers(0, 3, 80)] = 0.0
    for i in range(160, 240):
        keep = rng.integers(0, 3)
        d[i] = 0.0
        d[i, keep] = rng.choice([-1.0, 1.0])
    bvh = path_bvh(ray_path, V, F)
    first = bvh.first_hits(o, d)
    anyh = bvh.any_hits(o, d)
    for i, (t, f) in enumerate(brute_hits(o, d, V, F)):
        assert anyh[i] == (len(t) > 0)
        if len(t):
            assert first.face[i] == f[0]
            np.testing.assert_allclose(first.t[i], t[0], rtol=1e-10)
        else:
            assert first.face[i] == -1 and np.isinf(first.t[i])


def float_records(bvh):
    """The number of the BVH's float records for first hits (0: the float64 test only)."""
    import ctypes

    from voxax._kernels._loader import library

    fn = library().voxax_bvh_float_records
    fn.restype, fn.argtypes = ctypes.c_int64, [ctypes.c_void_p]
    return fn(bvh._handle)


def first_of_all_hits(bvh, o, d, **interval):
    """Each ray's smallest (t, face) hit among all of its hits (the float64 test of every
    box met, nothing culled), as first_hits' (t, face, barycentric, sign)."""
    h = bvh.all_hits(o, d, **interval)
    n = len(o)
    t, face = np.full(n, np.inf), np.full(n, -1, np.int32)
    bary, sign = np.zeros((n, 3)), np.zeros(n, np.asarray(h.sign).dtype)
    hit = np.flatnonzero(h.counts() > 0)
    first = h.offsets[hit]
    t[hit], face[hit], bary[hit], sign[hit] = h.t[first], h.face[first], h.barycentric[first], h.sign[first]
    return t, face, bary, sign


def dyadic_squares(rng, n=60):
    """Axis-aligned unit squares (two triangles each) at multiples of 1/8 in [-2, 2]^3: flat
    boxes whose bounds are exact grid points of every quantisation, met by rays at their
    planes' distance exactly."""
    V, F = [], []
    for k in range(n):
        axis = rng.integers(0, 3)
        c = rng.integers(-16, 9, 3) / 8.0
        u, w = np.eye(3)[(axis + 1) % 3], np.eye(3)[(axis + 2) % 3]
        corners = [c, c + u, c + u + w, c + w]
        V.extend(corners)
        F.extend([[4 * k, 4 * k + 1, 4 * k + 2], [4 * k, 4 * k + 2, 4 * k + 3]])
    return np.array(V), np.array(F)


def grazing_rays(rng, V, F, n):
    """Random rays, rays aimed at vertices and edge midpoints (met at t far from round
    values, so that each bound's distance rounds its own way in float), and rays that start on a
    vertex's coordinate plane (a box bound) and run along it or nearly so, with direction
    components of 0, 1e-17 (|1 / d| near 2^57), 1e-19 (beyond 2^60), 5e-324 (its
    reciprocal infinite) and 1e70 (its reciprocal below 2^-60)."""
    lo, hi = V.min(0), V.max(0)
    pad = 0.2 * (hi - lo)
    o = rng.uniform(lo - pad, hi + pad, (4 * n, 3))
    d = rng.normal(size=(4 * n, 3))
    tips = V[rng.integers(0, len(V), n)]
    d[n : 2 * n] = tips - o[n : 2 * n]
    e = F[rng.integers(0, len(F), n)]
    d[2 * n : 3 * n] = 0.5 * (V[e[:, 0]] + V[e[:, 1]]) - o[2 * n : 3 * n]
    d[n : 3 * n] *= rng.uniform(0.1, 3.0, (2 * n, 1))  # the distance to the target not 1
    g = slice(3 * n, 4 * n)
    axis = rng.integers(0, 3, n)
    o[g][np.arange(n), axis] = V[rng.integers(0, len(V), n), axis]
    small = rng.choice([0.0, 1e-17, -1e-17, 1e-19, 5e-324, 1e70], n)
    dg = d[g]
    dg[np.arange(n), axis] = small * np.where(small == 1e70, 1.0, np.linalg.norm(dg, axis=1))
    d[g] = dg
    return o, d


@pytest.mark.parametrize(
    "scale, shift, float_path",
    [
        ("squares", 0.0, True),
        ("squares", 1e6, True),
        (1.0, 0.0, True),
        (1.0, 1e6, True),  # far from the origin: bounds relative to the root box's centre
        (1e-12, 1e3, True),  # tiny against its offset (one float ulp wider than the mesh)
        (3e-3, -7.5, True),
        (1e-30, 0.0, True),  # the float widening too wide to prune: each ray falls back
        (1e20, 0.0, False),  # bounds beyond 2^60: no float records
    ],
)
def test_first_hits_equal_the_exhaustive_float64_hits(scale, shift, float_path, ray_path):
    # The float records' test is conservative: every first hit (t, face, barycentrics,
    # sign) is the smallest (t, face) of all hits, bit for bit, for rays that graze box
    # bounds, aim at vertices and edges, carry zero, tiny, subnormal or huge direction
    # components, and over limited intervals; vertices at float32 values and their float64
    # neighbours put box bounds on float rounding boundaries.
    rng = np.random.default_rng(12)
    if scale == "squares":
        V, F = dyadic_squares(rng)
        V, scale = V + shift, 1.0
    else:
        V, F = random_soup(rng, nf=150, degenerate=10)
        V = V.astype(np.float32).astype(np.float64)
        bump = rng.integers(-1, 2, V.shape)
        V = np.where(bump > 0, np.nextafter(V, np.inf), np.where(bump < 0, np.nextafter(V, -np.inf), V))
        V = V * scale + shift
    o, d = grazing_rays(rng, V, F, 150)
    bvh = path_bvh(ray_path, V, F)
    assert (float_records(bvh) > 0) == float_path
    size = scale * 2.0
    for interval in [{}, {"t_min": -0.3 * size, "t_max": 1.5 * size}, {"t_min": 0.1 * size}]:
        first = bvh.first_hits(o, d, **interval, threads=1)
        ref = first_of_all_hits(bvh, o, d, **interval)
        for x, y in zip((first.t, first.face, first.barycentric, first.sign), ref):
            np.testing.assert_array_equal(np.asarray(x), y)
        assert np.any(first.face >= 0)
        again = bvh.first_hits(o, d, **interval, threads=2)
        for x, y in zip(first, again):
            assert np.array_equal(x, y)
    if scale == 1.0 and shift == 0.0 and len(F) == 150:  # generic rays, independent brute force
        first = bvh.first_hits(o[:150], d[:150])
        for i, (t, f) in enumerate(brute_hits(o[:150], d[:150], V, F)):
            assert first.face[i] == (f[0] if len(t) else -1)


def test_first_hit_traversals_agree_bit_for_bit(monkeypatch):
    # The AVX2 and the baseline traversals of first hits differ only in how the boxes are
    # tested: the same hits (t, face, barycentrics, sign) bit for bit, each the smallest of
    # all hits (the float64 test of every box met), on 20K faces, for rays with zero
    # direction components, rays starting on faces, and limited intervals.
    from voxax._kernels.cpu import cpu_features

    if not cpu_features()["cpu"]["avx2"]:
        pytest.skip("this CPU has no AVX2")
    mesh = data.large(20_000)
    V, F = np.asarray(mesh.vertices), np.asarray(mesh.faces)
    rng = np.random.default_rng(15)
    n = 3000
    o = rng.uniform(V.min(0), V.max(0), (n, 3))
    d = rng.normal(size=(n, 3))
    d[: n // 6, 0] = 0.0
    d[n // 6 : n // 3, 1:] = 0.0
    f = rng.integers(0, len(F), n // 3)
    w = rng.dirichlet(np.ones(3), n // 3)
    o[n // 3 : 2 * n // 3] = np.einsum("rk,rkd->rd", w, V[F[f]])  # on a face
    o[n // 3 : n // 2] = V[F[f[: n // 6], 0]]  # on a vertex
    monkeypatch.setenv("VOXAX_NO_AVX2", "1")
    base = voxax.BVH(V, F)
    monkeypatch.delenv("VOXAX_NO_AVX2")
    wide = voxax.BVH(V, F)
    assert not ray_avx2(base) and ray_avx2(wide) and float_records(wide) > 0
    for interval in [{}, {"t_min": -0.1, "t_max": 0.5}, {"t_min": 0.05}]:
        a = wide.first_hits(o, d, **interval, threads=2)
        b = base.first_hits(o, d, **interval, threads=1)
        ref = first_of_all_hits(wide, o, d, **interval)
        for x, y, z in zip((a.t, a.face, a.barycentric, a.sign), (b.t, b.face, b.barycentric, b.sign), ref):
            np.testing.assert_array_equal(np.asarray(x), np.asarray(y))
            np.testing.assert_array_equal(np.asarray(x), z)
        assert 0.1 * n < np.sum(a.face >= 0) < n


def test_hits_behind_the_origin_on_a_flat_mesh():
    # a flat mesh (its boxes flat in z) met behind the origin, with t_min < 0: the slab
    # test's far distance is negative there, and raising it by its rounding margin must not
    # shrink it (the boxes were all lost that way)
    g = np.arange(5.0)
    X, Y = np.meshgrid(g, g, indexing="ij")
    V = np.stack([X.ravel(), Y.ravel(), np.zeros(25)], 1)
    k = (np.arange(4)[:, None] * 5 + np.arange(4)[None, :]).ravel()
    F = np.concatenate([np.stack([k, k + 5, k + 6], 1), np.stack([k, k + 6, k + 1], 1)])
    rng = np.random.default_rng(14)
    o = np.concatenate([rng.uniform(0.1, 3.9, (200, 2)), rng.uniform(0.5, 2.0, (200, 1))], 1)
    d = np.concatenate([rng.uniform(-0.05, 0.05, (200, 2)), np.ones((200, 1))], 1)
    expect = -o[:, 2] / d[:, 2]
    inside = np.all((o[:, :2] + expect[:, None] * d[:, :2] > 0) & (o[:, :2] + expect[:, None] * d[:, :2] < 4), 1)
    bvh = voxax.BVH(V, F)
    first = bvh.first_hits(o, d, t_min=-5.0, t_max=5.0)
    assert inside.sum() > 150
    np.testing.assert_allclose(first.t[inside], expect[inside], rtol=1e-12)
    assert np.all(bvh.any_hits(o, d, t_min=-5.0, t_max=5.0)[inside])
    assert np.all(bvh.all_hits(o, d, t_min=-5.0, t_max=5.0).counts()[inside] == 1)
    assert np.all(bvh.first_hits(o, d).face == -1)  # nothing ahead


def test_first_hits_of_a_far_mesh_under_jit_match_the_host_path():
    # XLA's threads flush results below the normal range to zero: the float records' margin
    # covers that, so the jit path's first hits are the host path's
    import jax

    rng = np.random.default_rng(13)
    V, F = random_soup(rng, nf=120)
    for scale, shift in [(1.0, 1e6), (1e-20, 0.0), (1e-3, 0.0)]:
        W = V * scale + shift
        o, d = grazing_rays(rng, W, F, 60)
        host = voxax.first_hits((W, F), o, d)
        jit = jax.jit(lambda v, a, b: voxax.first_hits((v, F), a, b))(W, o, d)
        for x, y in zip(host, jit):
            np.testing.assert_array_equal(np.asarray(y), x)


def test_first_hits_of_a_large_mesh_vs_brute_force():
    # 40k faces: the triangles (over 2 MiB) take the huge-page allocation; 600 rays span
    # three chunks of rays (the last one partial)
    mesh = data.large(40_000)
    V, F = np.asarray(mesh.vertices), np.asarray(mesh.faces)
    rng = np.random.default_rng(7)
    o = rng.uniform(V.min(0), V.max(0), (600, 3))
    d = rng.normal(size=(600, 3))
    bvh = voxax.BVH(V, F)
    first = bvh.first_hits(o, d, threads=1)
    anyh = bvh.any_hits(o, d, threads=1)
    a, b, c = V[F[:, 0]], V[F[:, 1]], V[F[:, 2]]
    n = np.cross(b - a, c - a)
    for i, (t, f) in enumerate(brute_hits(o, d, V, F)):
        assert anyh[i] == (len(t) > 0)
        if len(t):
            assert first.face[i] == f[0]
            np.testing.assert_allclose(first.t[i], t[0], rtol=1e-10)
            assert first.sign[i] == np.sign(n[f[0]] @ d[i])
            hit_point = np.einsum("k,kd->d", first.barycentric[i], V[F[first.face[i]]])
            np.testing.assert_allclose(hit_point, o[i] + first.t[i] * d[i], atol=1e-10)
        else:
            assert first.face[i] == -1 and np.isinf(first.t[i]) and first.sign[i] == 0
    again = bvh.first_hits(o, d, threads=2)
    for x, y in zip(first, again):
        assert np.array_equal(x, y)


def test_watertight_rays_through_edges_and_vertices():
    # axis-aligned rays through a cube's edges, its face diagonals and its centre: every ray
    # strictly inside the footprint crosses exactly twice, entering then exiting
    cube = data.cube(2.0)
    g = np.linspace(-0.75, 0.75, 7)
    X, Y = np.meshgrid(g, g, indexing="ij")
    for axis in range(3):
        o = np.zeros((X.size, 3))
        others = [a for a in range(3) if a != axis]
        o[:, others[0]], o[:, others[1]] = X.ravel(), Y.ravel()
        o[:, axis] = -3.0
        d = np.zeros(3)
        d[axis] = 1.0
        h = voxax.all_hits(cube, o, d)
        assert np.all(h.counts() == 2)
        assert np.all(h.sign.reshape(-1, 2) == [-1, 1])
    # rays from the centre of an icosphere through every vertex and edge midpoint: one hit each
    s = data.icosphere(2)
    F = s.faces
    mids = (s.vertices[F[:, 0]] + s.vertices[F[:, 1]]) / 2
    dirs = np.concatenate([s.vertices, mids])
    h = voxax.all_hits(s, np.zeros(3), dirs)
    assert np.all(h.counts() == 1) and np.all(h.sign == 1)
    # and from outside, through the centre: two hits, in then out
    h = voxax.all_hits(s, -3 * dirs, dirs)
    assert np.all(h.counts() == 2) and np.all(h.sign.reshape(-1, 2) == [-1, 1])


def test_rays_on_a_closed_mesh_have_matching_crossings():
    rng = np.random.default_rng(3)
    m = data.large(2_000)
    o = rng.uniform(-1, 1, (2000, 3))
    d = rng.normal(size=(2000, 3))
    h = voxax.all_hits(m, o, d)
    # the winding number at the origin (from inside/outside along the ray) is 0 or 1:
    # the sum of exit minus entry crossings past the origin
    w = np.zeros(len(o))
    np.add.at(w, h.ray, h.sign)
    assert set(np.unique(w)) <= {0.0, 1.0}
    ref = np.asarray(voxax.winding_number(m.vertices, m.faces, o[:300]))
    np.testing.assert_array_equal(w[:300], np.round(ref))


def test_first_hits_over_two_blocks_of_rays():
    # rays are traced several at a time, each thread's chunk of rays interleaved: a ray's
    # answer is the same in a call of 2^20 + 1500 rays as in a small one, and the brute
    # force's
    rng = np.random.default_rng(11)
    V, F = random_soup(rng, nf=60, degenerate=5)
    bvh = voxax.BVH(V, F)
    n = (1 << 20) + 1500
    o = rng.uniform(-1.2, 1.2, (n, 3))
    d = rng.normal(size=(n, 3))
    full = bvh.first_hits(o, d, threads=2)
    pick = np.concatenate([rng.choice(1 << 20, 300, replace=False), np.arange(1 << 20, n)])
    part = bvh.first_hits(o[pick], d[pick], threads=1)
    for x, y in zip(full, part):
        assert np.array_equal(x[pick], y)
    for k, (t, f) in zip(pick[::10], brute_hits(o[pick[::10]], d[pick[::10]], V, F)):
        assert full.face[k] == (f[0] if len(t) else -1)
        if len(t):
            np.testing.assert_allclose(full.t[k], t[0], rtol=1e-10)


def test_determinism_across_threads():
    rng = np.random.default_rng(4)
    V, F = random_soup(rng, nf=400)
    bvh = voxax.BVH(V, F)
    P = rng.uniform(-1, 1, (3000, 3))
    o, d = rng.uniform(-1, 1, (3000, 3)), rng.normal(size=(3000, 3))
    a, b = bvh.closest_points(P, threads=1), bvh.closest_points(P, threads=2)
    for x, y in zip(a, b):
        assert np.array_equal(x, y)
    a, b = bvh.all_hits(o, d, threads=1), bvh.all_hits(o, d, threads=3)
    for x, y in zip(a, b):
        assert np.array_equal(x, y)


def test_bad_input():
    cube = data.cube()
    bvh = voxax.BVH(cube)
    with pytest.raises(ValueError, match="NaN"):
        bvh.closest_points([[np.nan, 0, 0]])
    with pytest.raises(ValueError, match=r"\(\.\.\., 3\)"):
        bvh.closest_points(np.zeros((4, 2)))
    with pytest.raises(TypeError):
        bvh.closest_points(np.array(["a", "b", "c"]))
    with pytest.raises(ValueError, match="zero"):
        bvh.first_hits(np.zeros(3), [[1, 0, 0], [0, 0, 0]])
    with pytest.raises(ValueError, match="t_min <= t_max"):
        bvh.first_hits(np.zeros(3), [1, 0, 0], t_min=2, t_max=1)
    with pytest.raises(ValueError, match="broadcast"):
        bvh.first_hits(np.zeros((2, 3)), np.ones((3, 3)))
    with pytest.raises(ValueError, match="range"):
        voxax.BVH(np.zeros((3, 3)), [[0, 1, 3]])
    with pytest.raises(ValueError, match="NaN"):
        voxax.BVH(np.full((3, 3), np.nan), [[0, 1, 2]])
    with pytest.raises(ValueError, match="3D"):
        voxax.BVH(data.polygon_square())
    with pytest.raises(ValueError, match="threads"):
        bvh.closest_points(np.zeros((1, 3)), threads=0)


def test_jit_path_matches_the_host_path():
    import jax
    import jax.numpy as jnp

    rng = np.random.default_rng(6)
    V, F = random_soup(rng, nf=200)
    P = rng.uniform(-1, 1, (500, 3))
    o, d = rng.uniform(-1, 1, (500, 3)), rng.normal(size=(500, 3))
    host = voxax.closest_points((V, F), P)
    jit = jax.jit(lambda v, p: voxax.closest_points((v, jnp.asarray(F)), p))(
        jnp.asarray(V), jnp.asarray(P)
    )
    for x, y in zip(host, jit):
        np.testing.assert_array_equal(np.asarray(y), x)
    host = voxax.first_hits((V, F), o, d, t_max=2.0)
    jit = jax.jit(lambda v, a, b: voxax.first_hits((v, F), a, b, t_max=2.0))(V, o, d)
    for x, y in zip(host, jit):
        np.testing.assert_array_equal(np.asarray(y), x)
    # vmap over meshes (a batch of scaled copies)
    vs = jnp.stack([jnp.asarray(V), 2 * jnp.asarray(V)])
    dist = jax.vmap(lambda v: voxax.closest_points((v, F), P[:20]).distance)(vs)
    np.testing.assert_array_equal(
        dist[1], voxax.closest_points((2 * V, F), P[:20]).distance
    )
    # errors under jit carry the same messages
    with pytest.raises(Exception, match="NaN or Inf"):
        jax.jit(lambda p: voxax.closest_points((V, F), p))(jnp.full((2, 3), jnp.nan))
    with pytest.raises(Exception, match="out of range"):
        jax.jit(lambda f: voxax.closest_points((V, f), jnp.zeros((1, 3))))(
            jnp.asarray(F).at[0, 0].set(10**6)
        ).face.block_until_ready()  # (int64 faces: raised when the result is read)
    with pytest.raises(Exception, match="direction 1 is zero"):
        jax.jit(lambda dd: voxax.first_hits((V, F), jnp.zeros((2, 3)), dd))(
            jnp.array([[1.0, 0, 0], [0, 0, 0]])
        )


def test_first_hits_in_large_leaves_vs_brute_force(monkeypatch):
    # 30 triangles whose boxes are all the cube [-1, 1]^3 (on every axis one corner at -1,
    # one at 1, the third inside) share one centroid, which no split separates: they end
    # in leaves of 7 or 8 (halved by position), which the AVX2 traversal tests four
    # triangles at a time (the last group partly filled); next to a random soup.
    from voxax._kernels.cpu import cpu_features

    rng = np.random.default_rng(21)
    cube = np.zeros((30, 3, 3))
    for k in range(30):
        for a in range(3):
            p = rng.permutation(3)
            cube[k, p, a] = -1.0, 1.0, rng.uniform(-0.9, 0.9)
    Vs, Fs = random_soup(rng, nf=100, degenerate=10)
    Vs = 0.5 * Vs + 3.0  # off to one side
    V = np.concatenate([cube.reshape(-1, 3), Vs])
    F = np.concatenate([np.arange(90).reshape(30, 3), Fs + 90]).astype(np.int32)
    n = 2000
    o = rng.uniform(-4, 4, (n, 3))
    d = rng.uniform(-0.8, 0.8, (n, 3)) - o  # most towards the cube
    d[: n // 4] = rng.normal(size=(n // 4, 3))
    bvh = voxax.BVH(V, F)
    res = bvh.first_hits(o, d, threads=2)
    assert np.sum((res.face >= 0) & (res.face < 30)) > n // 2 and np.sum(res.face >= 30) >= 5
    for i, (t, f) in enumerate(brute_hits(o, d, V, F)):
        assert res.face[i] == (f[0] if len(t) else -1), i
        if len(t):
            np.testing.assert_allclose(res.t[i], t[0], rtol=1e-10)
    if cpu_features()["cpu"]["avx2"]:
        monkeypatch.setenv("VOXAX_NO_AVX2", "1")
        base = voxax.BVH(V, F).first_hits(o, d, threads=1)
        for x, y in zip(res, base):
            np.testing.assert_array_equal(np.asarray(x), np.asarray(y))
