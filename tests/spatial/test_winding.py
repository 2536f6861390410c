"""Tests of `voxax.winding.winding_number`: exact generalised winding numbers at points."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import voxax
from voxax import winding_number


def _uniform(rng, lo, hi, n, d=3):
    return rng.uniform(lo, hi, size=(n, d))


def test_box_inside_outside(rng):
    m = voxax.data.box()
    inside = _uniform(rng, -0.45, 0.45, 200)
    outside = rng.uniform(-2, 2, size=(400, 3))
    outside = outside[np.abs(outside).max(axis=1) > 0.55]
    np.testing.assert_allclose(winding_number(m.vertices, m.faces, inside), 1.0, atol=1e-12)
    np.testing.assert_allclose(winding_number(m.vertices, m.faces, outside), 0.0, atol=1e-12)


def test_overlapping_cubes_and_inverted_parts(rng):
    m = voxax.data.overlapping_cubes()
    both = _uniform(rng, -0.19, 0.19, 100)
    only_a = _uniform(rng, -0.59, -0.21, 100)
    np.testing.assert_allclose(winding_number(m.vertices, m.faces, both), 2.0, atol=1e-12)
    np.testing.assert_allclose(winding_number(m.vertices, m.faces, only_a), 1.0, atol=1e-12)

    m = voxax.data.with_inverted_component(subdivisions=2)
    dirs = rng.normal(size=(100, 3))
    dirs *= rng.uniform(0, 0.8, size=(100, 1)) / np.linalg.norm(dirs, axis=1, keepdims=True)
    main = m.info["center"] + m.info["radius"] * dirs
    inv = m.info["inverted_center"] + m.info["inverted_radius"] * dirs
    np.testing.assert_allclose(winding_number(m.vertices, m.faces, main), 1.0, atol=1e-10)
    np.testing.assert_allclose(winding_number(m.vertices, m.faces, inv), -1.0, atol=1e-10)


def test_half_on_the_faces_of_a_cube(rng):
    m = voxax.data.box()
    pts = []
    for axis in range(3):
        for side in (-0.5, 0.5):
            p = rng.uniform(-0.45, 0.45, size=(20, 3))
            p[:, axis] = side
            pts.append(p)
    pts = np.concatenate(pts)
    np.testing.assert_allclose(winding_number(m.vertices, m.faces, pts), 0.5, atol=1e-6)
    # 2D: on the edges of a square.
    sq = voxax.data.polygon_square()
    p = np.stack([rng.uniform(-0.45, 0.45, 20), np.full(20, 0.5)], axis=1)
    np.testing.assert_allclose(winding_number(sq.vertices, sq.faces, p), 0.5, atol=1e-6)
    np.testing.assert_allclose(winding_number(sq.vertices, sq.faces, p[:, ::-1]), 0.5, atol=1e-6)


@pytest.mark.parametrize(
    "name, n, kwargs",
    [
        ("star_polyline", 64, {}),
        ("overlapping_squares", 50, {}),
        ("torus", 20, {"n_major": 24, "n_minor": 12}),
        ("overlapping_cubes", 10, {}),
    ],
)
def test_agrees_with_voxelize_away_from_the_surface(name, n, kwargs):
    # A voxel whose box-filtered value is an integer is not crossed by the surface, so the
    # winding number at its centre is that integer.
    m = voxax.data.get(name, **kwargs)
    grid = voxax.Grid.cube(n + 1, dim=m.dim)  # odd count: centres off the mesh's planes
    W = np.asarray(voxax.voxelize(m.vertices, m.faces, grid))
    clean = np.abs(W - np.round(W)) < 1e-12
    assert clean.sum() > 0.5 * W.size
    w = np.asarray(winding_number(m.vertices, m.faces, grid.centers()))
    np.testing.assert_allclose(w[clean], W[clean], atol=1e-6)
    if name.startswith("overlapping"):
        assert np.isclose(w, 2.0).sum() > 0


def test_agrees_with_the_ray_count(rng):
    v, f = voxax.data.star_polyline().vertices, voxax.data.star_polyline().faces
    p = rng.uniform(-1, 1, size=(500, 2))
    ray = voxax.reference.winding_number_ray(v, f, p)
    np.testing.assert_allclose(winding_number(v, f, p), ray, atol=1e-9)


def test_shapes_chunks_dtypes_jit_vmap(rng):
    m = voxax.data.icosphere(1)
    pts = rng.uniform(-1, 1, size=(4, 5, 3))
    w = winding_number(m.vertices, m.faces, pts)
    assert w.shape == (4, 5) and w.dtype == jnp.float64
    w7 = winding_number(m.vertices, m.faces, pts, chunk_size=7)  # 20 points: 3 chunks, padded
    np.testing.assert_allclose(w7, w, atol=1e-13)
    w32 = winding_number(m.vertices.astype(np.float32), m.faces, pts.astype(np.float32), chunk_size=3)
    assert w32.dtype == jnp.float32
    np.testing.assert_allclose(w32, w, atol=1e-5)
    wj = jax.jit(lambda v, p: winding_number(v, m.faces, p, chunk_size=6))(m.vertices, pts)
    np.testing.assert_allclose(wj, w, atol=1e-13)
    wv = jax.vmap(lambda s: winding_number(m.vertices * s, m.faces, pts))(jnp.array([1.0, 2.0]))
    np.testing.assert_allclose(wv[0], w, atol=1e-13)
    assert winding_number(m.vertices, m.faces, np.zeros((0, 3))).shape == (0,)


def _fd_check(f, args, eps=1e-6, rtol=1e-6):
    """Compares jax.grad of a scalar f with central finite differences in every input entry."""
    grads = jax.jit(jax.grad(f, argnums=tuple(range(len(args)))))(*args)
    fj = jax.jit(f)
    for i, (x, g) in enumerate(zip(args, grads)):
        basis = np.eye(x.size).reshape((x.size,) + x.shape)

        def shifted(e, i=i):
            return fj(*[a + e if j == i else a for j, a in enumerate(args)])

        fd = (jax.vmap(shifted)(eps * basis) - jax.vmap(shifted)(-eps * basis)) / (2 * eps)
        np.testing.assert_allclose(np.asarray(g).reshape(-1), fd, rtol=rtol, atol=rtol)


def test_gradients_of_open_surfaces():
    # An open surface has a smooth winding number: autodiff must match finite differences,
    # also through the chunked map (with rematerialisation).
    tri = np.array([[0.0, 0.0, 0.0], [1.0, 0.1, 0.0], [0.2, 0.9, 0.3]])
    faces = np.array([[0, 1, 2]])
    pts = np.array([[0.3, 0.3, 0.5], [0.4, -0.2, -0.3], [1.0, 1.0, 1.0]])
    _fd_check(lambda v, p: jnp.sum(winding_number(v, faces, p, chunk_size=2) ** 2), (tri, pts))
    seg = np.array([[0.0, 0.0], [1.0, 0.2], [0.3, 1.0]])
    sfaces = np.array([[0, 1], [1, 2]])
    _fd_check(lambda v, p: jnp.sum(jnp.sin(winding_number(v, sfaces, p))), (seg, np.array([[0.2, 0.5], [2.0, 1.0]])))
    # A closed mesh: w is constant away from the surface, its gradients vanish (and are finite).
    m = voxax.data.box()
    gv, gp = jax.grad(lambda v, p: winding_number(v, m.faces, p).sum(), argnums=(0, 1))(
        jnp.asarray(m.vertices), jnp.array([[0.1, 0.2, 0.3], [0.5, 0.0, 0.0]])
    )
    assert np.all(np.isfinite(gv)) and np.all(np.isfinite(gp))
    assert np.abs(gp[0]).max() < 1e-12
    gv = jax.grad(lambda v: winding_number(v, m.faces, jnp.array([[0.1, 0.2, 0.3]])).sum())(jnp.asarray(m.vertices))
    assert np.abs(gv).max() < 1e-12


def test_bad_input():
    m = voxax.data.box()
    with pytest.raises(ValueError, match="points"):
        winding_number(m.vertices, m.faces, np.zeros((3, 2)))
    with pytest.raises(ValueError, match="face indices"):
        winding_number(m.vertices, m.faces + 8, np.zeros((3, 3)))
    with pytest.raises(TypeError):
        winding_number(m.vertices.astype(int), m.faces, np.zeros((3, 3)))
    with pytest.raises(ValueError, match="segments"):
        winding_number(np.zeros((3, 2)), m.faces, np.zeros((3, 2)))


# --- `accuracy`: the error-bounded far-field expansion of the eager path -------------------


def _solid_angle_sum(v, f, p, block=256):
    """The winding numbers by the plain solid-angle sum, in numpy (an oracle independent of
    the kernels): Van Oosterom and Strackee's tan(Omega / 2), face by face."""
    tri = np.asarray(v, np.float64)[np.asarray(f)]
    out = []
    for s in range(0, len(p), block):
        q = np.asarray(p[s : s + block], np.float64)[:, None, None, :]
        a, b, c = (tri[None, :, k, :] - q[:, :, 0, :] for k in range(3))
        la, lb, lc = (np.linalg.norm(x, axis=-1) for x in (a, b, c))
        num = np.einsum("pfi,pfi->pf", a, np.cross(b, c))
        den = la * lb * lc + (a * b).sum(-1) * lc + (a * c).sum(-1) * lb + (b * c).sum(-1) * la
        out.append(np.where(num == 0, 0.0, 2 * np.arctan2(num, den)).sum(-1) / (4 * np.pi))
    return np.concatenate(out)


def _open_and_soup(rng):
    m = voxax.data.large(2000)
    v = np.asarray(m.vertices, np.float64)
    f = np.asarray(m.faces)[: len(m.faces) * 9 // 10]  # 10% of the faces cut: open
    sv = rng.uniform(-1, 1, size=(900, 3))
    sv = np.concatenate([sv, sv[:300] + 1e-9])  # also near-duplicate vertices
    sf = rng.integers(0, len(sv), size=(600, 3))  # random triangles (some degenerate)
    sf = np.concatenate([sf, rng.choice(len(sv), size=(40, 3), replace=False)])
    return (v, f), (sv, sf)


def _points_near_and_far(rng, v, n=300):
    lo, hi = v.min(0), v.max(0)
    near = v[rng.integers(0, len(v), n)] + rng.normal(scale=1e-3 * np.abs(hi - lo).max(), size=(n, 3))
    box = rng.uniform(lo - 0.2 * (hi - lo), hi + 0.2 * (hi - lo), size=(n, 3))
    far = rng.normal(size=(n, 3))
    far *= (np.abs(hi - lo).max() * rng.uniform(1.5, 20, size=(n, 1))) / np.linalg.norm(far, axis=1, keepdims=True)
    return np.concatenate([near, v[:20], box, far])


def test_accuracy_bounds_the_error_on_open_surfaces_and_soups(rng):
    for v, f in _open_and_soup(rng):
        p = _points_near_and_far(rng, v)
        exact = _solid_angle_sum(v, f, p)
        np.testing.assert_allclose(winding_number(v, f, p), exact, atol=1e-11)
        errors = {}
        for eps in (0.3, 1e-2, 1e-4, 1e-7):
            w = np.asarray(winding_number(v, f, p, accuracy=eps))
            err = np.abs(w - exact)
            errors[eps] = err.max()
            assert err.max() <= eps + 1e-11, (eps, err.max(), np.argmax(err))
        # The expansion is used (the bound is not met vacuously by the exact sum): the loose
        # budgets give errors well above rounding, the tight ones much smaller.
        assert errors[0.3] > 1e-6 and errors[1e-2] > 1e-9, errors
        assert errors[1e-7] < errors[0.3]


def test_accuracy_mesh_scales_and_thread_counts(rng):
    (v, f), (sv, sf) = _open_and_soup(rng)
    p = _points_near_and_far(rng, v, 100)
    exact = _solid_angle_sum(v, f, p)
    for s in (1e-60, 1.0, 1e60):  # scale-free: no under- or overflow of the moments
        w = np.asarray(winding_number(v * s, f, p * s, accuracy=1e-3))
        assert np.abs(w - exact).max() <= 1e-3 + 1e-11, s
    # the same bits for any thread count (and an error within the bound)
    q = _points_near_and_far(rng, sv, 700)  # more than one chunk of points
    w1 = np.asarray(winding_number(sv, sf, q, accuracy=1e-3, threads=1))
    for t in (2, 3):
        np.testing.assert_array_equal(np.asarray(winding_number(sv, sf, q, accuracy=1e-3, threads=t)), w1)
    assert np.abs(w1 - _solid_angle_sum(sv, sf, q)).max() <= 1e-3 + 1e-11


def test_accuracy_none_zero_closed_meshes_and_the_jax_path(rng):
    (v, f), _ = _open_and_soup(rng)
    p = _points_near_and_far(rng, v, 50)
    w = np.asarray(winding_number(v, f, p))
    np.testing.assert_array_equal(np.asarray(winding_number(v, f, p, accuracy=None)), w)
    np.testing.assert_array_equal(np.asarray(winding_number(v, f, p, accuracy=0)), w)
    np.testing.assert_array_equal(np.asarray(winding_number(v, f, p, accuracy=np.float32(0.0))), w)
    # A closed mesh keeps its exact rays: integers (1/2 on the faces), whatever the accuracy.
    m = voxax.data.icosphere(2)
    q = rng.uniform(-1.5, 1.5, size=(200, 3))
    np.testing.assert_array_equal(
        np.asarray(winding_number(m.vertices, m.faces, q, accuracy=0.4)), np.asarray(winding_number(m.vertices, m.faces, q))
    )
    # The JAX path (traced, batched, 2D) is exact, which meets any accuracy.
    wj = jax.jit(lambda x: winding_number(v, f, x, accuracy=0.5))(p)
    np.testing.assert_allclose(wj, w, atol=1e-10)
    sq = voxax.data.polygon_square()
    p2 = rng.uniform(-1, 1, size=(20, 2))
    np.testing.assert_array_equal(
        np.asarray(winding_number(sq.vertices, sq.faces, p2, accuracy=0.1)), np.asarray(winding_number(sq.vertices, sq.faces, p2))
    )


@pytest.mark.parametrize(
    "value, error, match",
    [
        (True, TypeError, "`accuracy`"),
        ("0.1", TypeError, "`accuracy`"),
        (1j, TypeError, "`accuracy`"),
        (np.array([0.1, 0.2]), TypeError, "`accuracy`"),
        ([0.1], TypeError, "`accuracy`"),
        (float("nan"), ValueError, "`accuracy`"),
        (float("inf"), ValueError, "`accuracy`"),
        (-1e-3, ValueError, ">= 0"),
    ],
)
def test_accuracy_bad_values(value, error, match):
    m = voxax.data.box()
    with pytest.raises(error, match=match):
        winding_number(m.vertices, m.faces[:10], np.zeros((2, 3)), accuracy=value)


def test_accuracy_traced_is_refused():
    m = voxax.data.box()
    with pytest.raises(TypeError, match="traced"):
        jax.jit(lambda a: winding_number(m.vertices, m.faces, jnp.zeros((2, 3)), accuracy=a))(0.1)


def test_tiny_meshes_do_not_underflow():
    # The cubic terms of the solid angle underflow below about 1e-150 (float64) and 1e-20
    # (float32); the coordinates are then scaled to unit size first (C++: per triangle and
    # point, JAX: per mesh and points): eager, jit, 3D and 2D.
    m, sq = voxax.data.box(), voxax.data.polygon_square()
    p = np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.5, 0.1, 0.1]])
    want = [1.0, 0.0, 0.5]
    for s in (1e-300, 1e-160, 1.0):
        v, q = np.asarray(m.vertices) * s, p * s
        np.testing.assert_allclose(winding_number(v, m.faces, q), want, atol=1e-12)
        np.testing.assert_allclose(winding_number(v, m.faces[:-1], q[:1], accuracy=1e-6), 11 / 12, atol=1e-6)
        np.testing.assert_allclose(jax.jit(lambda v, q: winding_number(v, m.faces, q))(v, q), want, atol=1e-12)
        w2 = jax.jit(lambda v, q: winding_number(v, sq.faces, q))(np.asarray(sq.vertices) * s, p[:, :2] * s)
        np.testing.assert_allclose(w2, want, atol=1e-12)
    v32, q32 = (np.asarray(m.vertices) * 1e-20).astype(np.float32), (p * 1e-20).astype(np.float32)
    np.testing.assert_allclose(jax.jit(lambda v, q: winding_number(v, m.faces, q))(v32, q32), want, atol=1e-5)


# --- open meshes with a small boundary: the cap, the ray through S - C and w_C ---------------


def _grid(n, origin, u, w, bump=0.0):
    """An n x n grid of the parallelogram origin + [0, 1] u + [0, 1] w (oriented along u x w),
    bumped by `bump` along u x w in its middle."""
    s = np.linspace(0, 1, n + 1)
    a, b = np.meshgrid(s, s, indexing="ij")
    nrm = np.cross(u, w)
    h = bump * np.sin(np.pi * a) * np.sin(np.pi * b)
    v = np.asarray(origin) + a[..., None] * u + b[..., None] * w + h[..., None] * nrm
    idx = np.arange((n + 1) ** 2).reshape(n + 1, n + 1)
    q = np.stack([idx[:-1, :-1], idx[1:, :-1], idx[1:, 1:], idx[:-1, 1:]], -1).reshape(-1, 4)
    f = np.concatenate([q[:, [0, 1, 2]], q[:, [0, 2, 3]]])
    return v.reshape(-1, 3), f


def _merge(parts):
    """One mesh from (vertices, faces) parts, vertices at equal (rounded) positions merged."""
    vs, fs, off = [], [], 0
    for v, f in parts:
        vs.append(v)
        fs.append(f + off)
        off += len(v)
    v, f = np.concatenate(vs), np.concatenate(fs)
    _, first, inv = np.unique(np.round(v, 12), axis=0, return_index=True, return_inverse=True)
    return v[first], inv.reshape(-1)[f]


def _open_cube(n):
    """The unit cube [0, 1]^3 without its top face (z = 1), outward, n x n grids: its hole's
    rim is the planar square at z = 1, so its cap lies in that plane."""
    e = np.eye(3)
    sides = [
        ((0, 0, 0), e[1], e[0]), ((0, 0, 0), e[0], e[2]), ((0, 1, 0), e[2], e[0]),
        ((0, 0, 0), e[2], e[1]), ((1, 0, 0), e[1], e[2]),
    ]  # fmt: skip
    return _merge([_grid(n, o, u, w) for o, u, w in sides])


def _capped_cases(rng):
    """Open meshes whose boundary is small (the cap path): name -> (vertices, faces, points)."""
    cases = {}
    m = voxax.data.large(2000)
    v, f = np.asarray(m.vertices, np.float64), np.asarray(m.faces)
    cent = v[f].mean(1)
    # several holes: the faces near five vertices removed
    keep = np.ones(len(f), bool)
    for c in v[rng.choice(len(v), 5, replace=False)]:
        keep &= np.linalg.norm(cent - c, axis=1) > 0.08 * np.ptp(v, 0).max()
    cases["holes"] = (v, f[keep], _points_near_and_far(rng, v, 150))
    # a non-manifold boundary: fins on interior edges (an edge with a net use left on the
    # surface), a strip of faces twice (boundary edges of multiplicity 2), the 10% cut
    g = f[: len(f) * 9 // 10]
    fin_edges = g[rng.choice(len(g), 6, replace=False)][:, :2]
    tips = v[fin_edges].mean(1) + 0.05 * rng.normal(size=(6, 3))
    vf = np.concatenate([v, tips])
    fins = np.concatenate([fin_edges, len(v) + np.arange(6)[:, None]], axis=1)
    nm = np.concatenate([g, fins, g[100:130]])
    cases["non-manifold"] = (vf, nm, np.concatenate([_points_near_and_far(rng, v, 150), tips]))
    # a bowtie: two bumped grids sharing one corner (a boundary walk through it twice)
    a = _grid(12, (0, 0, 0), np.array([1.0, 0, 0]), np.array([0, 1.0, 0]), bump=0.3)
    b = _grid(12, (1, 1, 0), np.array([1.0, 0, 0]), np.array([0, 0.7, 0.5]), bump=-0.2)
    bv, bf = _merge([a, b])
    q = rng.uniform(-0.2, 2.2, size=(300, 3))
    cases["bowtie"] = (bv, bf, np.concatenate([q, bv[::7], [[1.0, 1.0, 0.0]]]))
    # the open cube: points on its cap (the plane z = 1 inside the rim, also on the lattice
    # of the rim's vertices: on the cap's edges) and a sphere poking through the cap
    cv, cf = _open_cube(8)
    sph = voxax.data.icosphere(2)
    sv = np.asarray(sph.vertices) * 0.3 + [0.5, 0.5, 1.0]
    pv = np.concatenate([cv, sv])
    pf = np.concatenate([cf, np.asarray(sph.faces) + len(cv)])
    on_cap = np.concatenate([rng.uniform(0.05, 0.95, size=(60, 3)), np.full((60, 1), 1.0)], 1)[:, [0, 1, 3]]
    lattice = np.stack(np.meshgrid(np.arange(9) / 8, np.arange(9) / 8, [1.0], indexing="ij"), -1).reshape(-1, 3)
    q = np.concatenate([on_cap, lattice, rng.uniform(-0.3, 1.3, size=(200, 3)), lattice + [0, 0, 1e-9]])
    cases["open cube"] = (cv, cf, q)
    cases["cap through a sphere"] = (pv, pf, q)
    return cases


def test_open_meshes_with_small_boundaries_match_the_plain_sum(rng):
    from voxax._kernels import spatial as spk

    loose = []  # the errors at accuracy 1e-2: the caps' expansions are used (not only exact sums)
    for name, (v, f, p) in _capped_cases(rng).items():
        v, f, p = np.ascontiguousarray(v, np.float64), np.ascontiguousarray(f, np.int32), np.asarray(p, np.float64)
        exact = _solid_angle_sum(v, f, p)
        w1, closed, by_ray = spk.winding_number(v, f, p, False, 1)
        assert not closed and by_ray > len(p) // 3, (name, by_ray)  # the cap path decides many points
        np.testing.assert_allclose(w1, exact, atol=1e-9, err_msg=name)
        w2, _, _ = spk.winding_number(v, f, p, False, 2)
        np.testing.assert_array_equal(w2, w1, err_msg=name)
        for eps in (1e-2, 1e-5):
            wa = spk.winding_number(v, f, p, False, 1, eps)[0]
            assert np.abs(wa - exact).max() <= eps + 1e-11, (name, eps)
            np.testing.assert_array_equal(spk.winding_number(v, f, p, False, 2, eps)[0], wa, err_msg=name)
            if eps == 1e-2:
                loose.append(np.abs(wa - exact).max())
    assert max(loose) > 1e-6, loose
    # the public call at huge and tiny scales
    v, f, p = _capped_cases(rng)["holes"]
    exact = _solid_angle_sum(v, f, p)
    for s in (1e-120, 1e70):
        np.testing.assert_allclose(winding_number(v * s, f, p * s), exact, atol=1e-9, err_msg=str(s))
        assert np.abs(np.asarray(winding_number(v * s, f, p * s, accuracy=1e-4)) - exact).max() <= 1e-4 + 1e-11


def test_points_on_the_cap_and_its_edges_take_the_exact_sum(rng):
    from voxax._kernels import spatial as spk

    v, f = _open_cube(8)
    v, f = np.ascontiguousarray(v, np.float64), np.ascontiguousarray(f, np.int32)
    on_cap = np.concatenate([rng.uniform(0.05, 0.95, size=(50, 2)), np.ones((50, 1))], 1)
    _, _, by_ray = spk.winding_number(v, f, on_cap, False, 1)
    assert by_ray == 0  # every point lies in the plane of the cap: unclear for its ray
    np.testing.assert_allclose(winding_number(v, f, on_cap), _solid_angle_sum(v, f, on_cap), atol=1e-12)
    # just inside and just outside the cap: the integer part changes, the sum does not jump
    below, above = on_cap - [0, 0, 1e-7], on_cap + [0, 0, 1e-7]
    np.testing.assert_allclose(winding_number(v, f, below), _solid_angle_sum(v, f, below), atol=1e-9)
    np.testing.assert_allclose(winding_number(v, f, above), _solid_angle_sum(v, f, above), atol=1e-9)
    assert spk.winding_number(v, f, above, False, 1)[2] == len(above)
