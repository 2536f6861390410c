"""Marching cubes / squares: validity, oracles, paths, gradients and bad input."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from _iso_checks import (
    area,
    assert_closed_manifold,
    brute_force_vertices,
    closed_report,
    signed_volume,
)
from scipy.ndimage import gaussian_filter

import voxax
from voxax import reference
from voxax._kernels.contour import topology as host_topology


def norm_field(grid, r=0.6):
    return np.linalg.norm(grid.centers(), axis=-1) - r


def torus_field(grid, R=0.5, r=0.2):
    x = grid.centers()
    q = np.linalg.norm(x[..., :2], axis=-1) - R
    return np.sqrt(q**2 + x[..., 2] ** 2) - r


def chebyshev_octic(grid):
    x = grid.centers()
    t8 = 128 * x**8 - 256 * x**6 + 160 * x**4 - 32 * x**2 + 1
    return t8.sum(-1)


def gaussian_field(rng, shape, sigma=2.0):
    f = gaussian_filter(rng.standard_normal(shape), sigma)
    return f / f.std()


def test_checker_detects_defects():
    tet = np.array([[0, 2, 1], [0, 1, 3], [1, 2, 3], [0, 3, 2]])
    v = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1.0]])
    assert closed_report(v, tet)["euler"] == 2
    assert_closed_manifold(v, tet, euler=2)
    # two tetrahedra sharing one vertex: closed and oriented but not vertex-manifold
    two = np.concatenate([tet, tet + 3])
    assert (
        closed_report(np.concatenate([v, v[1:] + 2]), two)["nonmanifold_vertices"] == 1
    )
    assert closed_report(v, tet[1:])["unmatched_edges"] == 3
    assert closed_report(v, np.concatenate([tet, tet[:1]]))["duplicate_faces"] == 1


# -- validity --------------------------------------------------------------------------------


@pytest.mark.parametrize(
    "field, grid, euler",
    [
        (norm_field, voxax.Grid.cube(64), 2),
        (torus_field, voxax.Grid.cube(48), 0),
        (chebyshev_octic, voxax.Grid.cube(44, half_width=1.2), -160),
    ],
)
def test_euler_characteristic(field, grid, euler):
    iso = voxax.isosurface(field(grid), grid)
    m = iso.to_mesh()
    assert_closed_manifold(m.vertices, m.faces, euler=euler)
    assert signed_volume(m.vertices, m.faces) > 0  # outward orientation


def test_sphere_volume_area_and_orientation():
    grid = voxax.Grid.cube(64)
    m = voxax.isosurface(norm_field(grid), grid).to_mesh()
    assert abs(signed_volume(m.vertices, m.faces) / (4 / 3 * np.pi * 0.6**3) - 1) < 2e-3
    assert abs(area(m.vertices, m.faces) / (4 * np.pi * 0.36) - 1) < 5e-3
    # inside="above" on the negated field gives the same surface, still outward.
    m2 = voxax.isosurface(-norm_field(grid), grid, inside="above").to_mesh()
    np.testing.assert_allclose(m2.vertices, m.vertices, rtol=0, atol=1e-15)
    assert signed_volume(m2.vertices, m2.faces) == pytest.approx(
        signed_volume(m.vertices, m.faces), rel=1e-12
    )


def test_random_gaussian_fields_closed_manifold(rng):
    grid = voxax.Grid((-1, -1.1, -0.9), (1, 1.2, 1.0), (32, 32, 32))
    for _ in range(20):
        f = gaussian_field(rng, grid.shape)
        iso = voxax.isosurface(f, grid, close=True)
        m = iso.to_mesh()
        r = assert_closed_manifold(m.vertices, m.faces)
        assert r["euler"] % 2 == 0
        # every vertex on its edge, between the two cell centres
        assert np.all(np.isfinite(m.vertices))


def test_every_derived_cube_case_is_triangulated():
    from voxax import _kernels

    assert _kernels.library().voxax_mc_table_failures() == 0


def test_rough_random_fields_closed_manifold(rng):
    # Unsmoothed noise hits the rare cubes with several ambiguous faces. The topology
    # kernel alone (on fields padded with an outside value, as close=True does).
    for i in range(150):
        f = (
            rng.standard_normal((7, 6, 8))
            if i % 2
            else rng.integers(-2, 3, size=(7, 6, 8)).astype(float)
        )
        edges, faces = host_topology(np.pad(f, 1, constant_values=1.0), 0.0)
        if len(faces):
            assert_closed_manifold(np.zeros((len(edges), 3)), faces)


@pytest.mark.parametrize("level", [0.0, 1.0])
def test_integer_fields_with_exact_ties(rng, level):
    grid = voxax.Grid.cube((12, 10, 11))
    for _ in range(6):
        f = rng.integers(-1, 3, size=grid.shape).astype(np.float64)
        m = voxax.isosurface(f, grid, level, close=True).to_mesh()
        assert_closed_manifold(m.vertices, m.faces)
        # the volume of the closed mesh is positive and finite
        assert signed_volume(m.vertices, m.faces) > 0


def test_saddle_tie_3x2x2():
    # Every x slice is a checkerboard whose face saddle value equals the level exactly.
    f = np.array(
        [
            [[1.0, -1.0], [-1.0, 1.0]],
            [[-1.0, 1.0], [1.0, -1.0]],
            [[1.0, -1.0], [-1.0, 1.0]],
        ]
    )
    grid = voxax.Grid((0, 0, 0), (3, 2, 2), (3, 2, 2))
    for inside in ("below", "above"):
        m = voxax.isosurface(f, grid, 0.0, inside=inside, close=True).to_mesh()
        assert_closed_manifold(m.vertices, m.faces)


# -- oracles ---------------------------------------------------------------------------------


def test_vertices_equal_brute_force_edge_interpolation(rng):
    grid = voxax.Grid((-0.3, 0.1, -2.0), (0.9, 1.0, 1.0), (17, 13, 19))
    f = gaussian_field(rng, grid.shape, 1.5)
    iso = voxax.isosurface(f, grid, 0.2)
    expected = brute_force_vertices(f, grid.lower, grid.spacing, 0.2)
    h = min(grid.spacing)
    assert iso.vertices.shape == expected.shape
    assert float(np.max(np.abs(np.asarray(iso.vertices) - expected))) <= 1e-12 * h


def test_matches_scikit_image(rng):
    skimage_measure = pytest.importorskip("skimage.measure")
    from scipy.spatial import cKDTree

    grid = voxax.Grid((-1.0, -0.5, 0.0), (1.0, 1.5, 1.2), (30, 26, 22))
    h = np.array(grid.spacing)
    for _ in range(3):
        f = gaussian_field(rng, grid.shape).astype(np.float32)
        m = voxax.isosurface(f, grid, 0.1).to_mesh()
        v, faces, _, _ = skimage_measure.marching_cubes(
            f, 0.1, spacing=tuple(h), allow_degenerate=False
        )
        v = v.astype(np.float64) + np.asarray(grid.lower) + 0.5 * h
        dist, idx = cKDTree(m.vertices).query(v)
        # scikit-image interpolates in float32 (t and the position), ours in float64 from the
        # same float32 samples, so general fields agree only to float32 rounding (about 1e-7
        # of a cell per operation; 1e-5 h leaves margin). Fields whose interpolation is exact
        # in float32 are compared to 1e-9 h in test_matches_scikit_image_on_dyadic_fields.
        assert dist.max() <= 1e-5 * h.min()
        assert len(np.unique(idx)) == len(v) == m.n_vertices
        # Per-cube face counts agree wherever the cube has no ambiguity (no face with a
        # checkerboard of signs, not two lone opposite corners): there the rules differ.
        counts = []
        for verts, tris in ((m.vertices, m.faces), (v, faces)):
            cube = np.floor(
                ((verts[tris].mean(1) - np.asarray(grid.lower)) / h) - 0.5
            ).astype(int)
            c = np.zeros(tuple(n - 1 for n in grid.shape), int)
            np.add.at(c, tuple(cube.T), 1)
            counts.append(c)
        pos = f >= 0.1
        corner = [
            pos[dx : dx + 29, dy : dy + 25, dz : dz + 21]
            for dx in (0, 1)
            for dy in (0, 1)
            for dz in (0, 1)
        ]
        ambiguous = np.zeros(counts[0].shape, bool)
        for axis in range(3):
            for side in (0, 1):
                q = [c for i, c in enumerate(corner) if ((i >> (2 - axis)) & 1) == side]
                ambiguous |= (q[0] == q[3]) & (q[1] == q[2]) & (q[0] != q[1])
        npos = np.sum(corner, axis=0)
        for i in range(8):
            lone = corner[i] & corner[7 - i] & ((npos == 2) | (npos == 6))
            ambiguous |= lone | (~corner[i] & ~corner[7 - i] & (npos == 6))
        assert np.array_equal(counts[0][~ambiguous], counts[1][~ambiguous])
        assert abs(len(faces) - m.n_faces) <= 0.01 * len(faces)
        assert area(m.vertices, m.faces) == pytest.approx(area(v, faces), rel=1e-3)
        # scikit-image leaves open boundaries too; compare the enclosed volume of a closed case below
    g = voxax.Grid.cube(40)
    f = norm_field(g).astype(np.float32)
    m = voxax.isosurface(f, g).to_mesh()
    v, faces, _, _ = skimage_measure.marching_cubes(
        f, 0.0, spacing=g.spacing, allow_degenerate=False
    )
    v = v + np.asarray(g.lower) + 0.5 * np.asarray(g.spacing)
    assert abs(signed_volume(m.vertices, m.faces)) == pytest.approx(
        abs(signed_volume(v, faces)), rel=1e-3
    )
    assert area(m.vertices, m.faces) == pytest.approx(area(v, faces), rel=1e-3)


def test_matches_scikit_image_on_dyadic_fields(rng):
    """Samples in {-3, -1, 1, 3}, level 0 and h = 1/4: every crossing parameter is 1/4, 1/2 or
    3/4 and every coordinate a small dyadic number, so scikit-image's float32 arithmetic is
    exact and the vertex sets must agree to 1e-9 h. Lewiner's method adds a vertex inside
    some ambiguous cubes (not on a grid edge); those are set aside, all others must match."""
    skimage_measure = pytest.importorskip("skimage.measure")
    from scipy.spatial import cKDTree

    grid = voxax.Grid((-1.0, -2.0, 0.5), (4.0, 2.5, 4.5), (20, 18, 16))
    h = np.array(grid.spacing)
    assert np.all(h == 0.25)
    g = gaussian_field(rng, grid.shape, 1.5)
    for f in (
        np.where(g >= 0, np.where(g > 0.3, 3, 1), np.where(g < -0.3, -3, -1)).astype(np.float32),
        rng.choice(np.array([-3, -1, 1, 3], np.float32), grid.shape),
    ):
        m = voxax.isosurface(f, grid, 0.0).to_mesh()
        v, _, _, _ = skimage_measure.marching_cubes(f, 0.0, spacing=tuple(h), allow_degenerate=False)
        index = v.astype(np.float64) / h  # index space: integers on two axes for edge vertices
        on_edge = np.sum(index == np.round(index), axis=1) >= 2
        v = v.astype(np.float64) + np.asarray(grid.lower) + 0.5 * h
        dist, idx = cKDTree(m.vertices).query(v[on_edge])
        assert dist.max() <= 1e-9 * h.min()
        assert on_edge.sum() == m.n_vertices == len(np.unique(idx))
        back, _ = cKDTree(v).query(m.vertices)
        assert back.max() <= 1e-9 * h.min()
        # the vertices set aside lie strictly inside cubes, away from every edge
        inner = index[~on_edge]
        assert np.all(np.sum(inner == np.round(inner), axis=1) <= 1)


def test_marching_squares_circle():
    grid = voxax.Grid.cube(48, dim=2)
    f = norm_field(grid)
    m = voxax.isosurface(f, grid).to_mesh()
    seg = m.faces
    # closed loops: every vertex starts exactly one segment and ends exactly one
    assert np.array_equal(np.sort(seg[:, 0]), np.arange(m.n_vertices))
    assert np.array_equal(np.sort(seg[:, 1]), np.arange(m.n_vertices))
    assert m.signed_volume() == pytest.approx(
        np.pi * 0.36, rel=3e-3
    )  # counter-clockwise
    expected = brute_force_vertices(f, grid.lower, grid.spacing, 0.0)
    np.testing.assert_allclose(m.vertices, expected, rtol=0, atol=1e-15)


# -- paths, determinism, transformations ------------------------------------------------------


def test_thread_count_does_not_change_bits(rng):
    f = gaussian_field(rng, (40, 37, 33))
    ref = host_topology(f, 0.0, threads=1)
    for threads in (2, 3, 8):
        out = host_topology(f, 0.0, threads=threads)
        assert np.array_equal(out[0], ref[0]) and np.array_equal(out[1], ref[1])


def test_capacity_path_equals_eager_and_pads(rng):
    grid = voxax.Grid.cube(24)
    f = gaussian_field(rng, grid.shape)
    eager = voxax.isosurface(f, grid)
    nv, nf = eager.vertices.shape[0], eager.faces.shape[0]
    run = jax.jit(lambda x: voxax.isosurface(x, grid, capacity=(nv + 10, nf + 7)))
    out = run(f)
    assert int(out.n_vertices) == nv and int(out.n_faces) == nf
    assert np.array_equal(np.asarray(out.faces[:nf]), np.asarray(eager.faces))
    # jit may fuse the interpolation differently (e.g. into fused multiply-adds)
    np.testing.assert_allclose(
        np.asarray(out.vertices[:nv]), np.asarray(eager.vertices), rtol=0, atol=1e-15
    )
    assert np.all(np.asarray(out.faces[nf:]) == 0) and np.all(
        np.asarray(out.vertices[nv:]) == 0
    )


def test_vmap_over_fields(rng):
    grid = voxax.Grid.cube(16)
    fields = np.stack([gaussian_field(rng, grid.shape) for _ in range(3)])
    out = jax.vmap(lambda x: voxax.isosurface(x, grid, capacity=4000))(
        jnp.asarray(fields)
    )
    for b in range(3):
        single = voxax.isosurface(fields[b], grid)
        nf = int(out.n_faces[b])
        assert nf == single.faces.shape[0]
        assert np.array_equal(np.asarray(out.faces[b, :nf]), np.asarray(single.faces))
        nv = int(out.n_vertices[b])
        np.testing.assert_allclose(
            np.asarray(out.vertices[b, :nv]),
            np.asarray(single.vertices),
            rtol=0,
            atol=1e-15,
        )


def test_capacity_overflow_is_a_clear_error():
    grid = voxax.Grid.cube(16)
    f = norm_field(grid)
    nv, nf = (int(c) for c in (lambda i: (i.n_vertices, i.n_faces))(voxax.isosurface(f, grid)))
    for cap in (50, (nv, nf - 1)):
        with pytest.raises(Exception) as info:
            jax.jit(lambda x, cap=cap: voxax.isosurface(x, grid, capacity=cap).vertices)(
                f
            ).block_until_ready()
        # one line that names the capacity needed
        line = str(info.value).strip()
        assert "\n" not in line and f"needs capacity=({max(nv, 50 if cap == 50 else nv)}, {nf})" in line, line
    # a batch: the largest counts of the items that do not fit
    two = np.stack([f, norm_field(grid, 0.3)])
    with pytest.raises(Exception, match=rf"needs capacity=\({nv}, {nf}\)"):
        jax.vmap(lambda x: voxax.isosurface(x, grid, capacity=(nv - 1, nf)).faces)(two).block_until_ready()


def test_scale_invariance_subnormal_and_huge_fields(rng):
    """A field times 2^k gives the same mesh, bit for bit, for k from -1060 (all samples
    subnormal) to +1000, eagerly and under jit (level 0); the gradient keeps its scale."""
    grid = voxax.Grid.cube(10)
    f = np.round(gaussian_filter(rng.standard_normal(grid.shape), 1.0) * 2**12) / 2**12
    ref = voxax.isosurface(f, grid)
    jit = jax.jit(lambda x: voxax.isosurface(x, grid, capacity=4000))
    rj = jit(f)
    n = int(ref.n_vertices)
    assert n > 50
    ref_fixed = np.asarray(voxax.isosurface_vertices(f, ref, grid)).tobytes()
    for k in (-1060, -1030, -600, 600, 1000):
        g = np.ldexp(f, k)
        assert np.array_equal(np.ldexp(g, -k), f)  # exact: at most 11 significant bits
        iso = voxax.isosurface(g, grid)
        assert np.asarray(iso.vertices).tobytes() == np.asarray(ref.vertices).tobytes(), k
        assert np.array_equal(iso.faces, ref.faces)
        assert float(iso.min_gap) == float(np.ldexp(float(ref.min_gap), k))
        out = jit(g)
        assert int(out.n_vertices) == n and np.array_equal(out.faces, rj.faces), k
        assert np.asarray(out.vertices).tobytes() == np.asarray(rj.vertices).tobytes(), k
        top = voxax.isosurface_topology(g, grid)
        assert np.array_equal(top.edges, ref.edges)
        assert np.asarray(voxax.isosurface_vertices(g, top, grid)).tobytes() == ref_fixed, k
    # float32 samples far below float32's normal range
    g32 = np.ldexp(f, -136).astype(np.float32)
    assert np.all(np.abs(g32) < np.finfo(np.float32).tiny)
    f32, back = voxax.isosurface(g32, grid), voxax.isosurface(np.ldexp(g32.astype(np.float64), 136), grid)
    assert int(f32.n_faces) > 0 and np.array_equal(f32.faces, back.faces)
    assert np.asarray(f32.vertices).tobytes() == np.asarray(back.vertices).tobytes()
    # the kernel's saddle decider compares exact products (underflowing ones included)
    for k in (-700, -520, 520):
        e, fc = host_topology(np.ldexp(f, k), 0.0)
        e0, fc0 = host_topology(f, 0.0)
        assert np.array_equal(e, e0) and np.array_equal(fc, fc0), k


def test_vertices_of_another_grids_topology_are_refused():
    small, big = voxax.Grid.cube(8), voxax.Grid.cube(12)
    f, g = norm_field(small), norm_field(big)
    top = voxax.isosurface_topology(g, big)
    with pytest.raises(ValueError, match="`topology` must be made on this grid"):
        voxax.isosurface_vertices(f, top, small)
    with pytest.raises(Exception, match="`topology` must be made on this grid"):
        jax.jit(lambda x: voxax.isosurface_vertices(x, top, small))(f).block_until_ready()
    with pytest.raises(ValueError, match="`topology` must be made on this grid"):
        voxax.isosurface_vertices(g, voxax.isosurface_topology(g, big, close=True), big)
    with pytest.raises(ValueError, match="2D grid"):
        voxax.isosurface_vertices(f[:, :, 0], voxax.isosurface_topology(f, small), voxax.Grid((-1, -1), (1, 1), (8, 8)))
    with pytest.raises(TypeError, match="IsoMesh"):
        voxax.isosurface_vertices(f, (top.vertices, top.faces), small)
    with pytest.raises(ValueError, match="must differ at the two ends"):
        voxax.isosurface_vertices(np.zeros(big.shape), top, big)
    ok = voxax.isosurface_vertices(g, top, big)
    np.testing.assert_allclose(ok, top.vertices, rtol=0, atol=1e-12)


# -- gradients -------------------------------------------------------------------------------


def test_interpolation_adjoint_matches_finite_differences(rng):
    grid = voxax.Grid.cube(12)
    f = gaussian_field(rng, grid.shape, 1.5)
    iso = voxax.isosurface(f, grid)
    w = rng.standard_normal(iso.vertices.shape)

    def loss(x):
        return jnp.sum(voxax.isosurface(x, grid).vertices * w)

    g = np.asarray(jax.grad(loss)(jnp.asarray(f)))
    edges = np.asarray(iso.edges)
    cells = np.unique(edges)[:: max(1, len(np.unique(edges)) // 12)]
    eps = 1e-6
    for c in cells:
        idx = np.unravel_index(c, grid.shape)
        fp, fm = f.copy(), f.copy()
        fp[idx] += eps
        fm[idx] -= eps
        fd = (float(loss(fp)) - float(loss(fm))) / (2 * eps)
        assert g[idx] == pytest.approx(fd, rel=1e-6, abs=1e-9)
    # cells on no crossed edge get exactly zero
    untouched = np.ones(grid.size, bool)
    untouched[edges.ravel()] = False
    assert np.all(g.reshape(-1)[untouched] == 0)


def test_min_gap_reports_conditioning():
    grid = voxax.Grid.cube(8)
    f = norm_field(grid)
    iso = voxax.isosurface(f, grid)
    e = np.asarray(iso.edges)
    flat = f.reshape(-1)
    assert float(iso.min_gap) == pytest.approx(
        np.min(np.abs(flat[e[:, 1]] - flat[e[:, 0]])), rel=0, abs=0
    )


def test_round_trip_voxelize_isosurface_volume_and_gradient():
    mesh = voxax.data.icosphere(4)
    V = np.asarray(mesh.vertices) * 0.7
    F = np.asarray(mesh.faces)
    grid = voxax.Grid.cube(64)
    exact = reference.signed_volume(V, F)

    def volume(v):
        W = voxax.voxelize(v, F, grid)
        verts, faces = voxax.isosurface(W, grid, 0.5, inside="above")
        a, b, c = verts[faces[:, 0]], verts[faces[:, 1]], verts[faces[:, 2]]
        return jnp.sum(jnp.einsum("ij,ij->i", a, jnp.cross(b, c))) / 6

    val, grad = jax.value_and_grad(volume)(jnp.asarray(V))
    assert abs(float(val) / exact - 1) <= 0.0025
    ref = reference.volume_gradient(V, F)
    cos = float(np.sum(grad * ref) / np.linalg.norm(grad) / np.linalg.norm(ref))
    assert cos >= 0.985


# -- bad input -------------------------------------------------------------------------------


def test_bad_input():
    grid = voxax.Grid.cube(8)
    f = norm_field(grid)
    bad = f.copy()
    bad[2, 3, 4] = np.nan
    with pytest.raises(ValueError, match="NaN"):
        voxax.isosurface(bad, grid)
    with pytest.raises(Exception, match="NaN"):
        jax.jit(lambda x: voxax.isosurface(x, grid, capacity=100).faces)(
            bad
        ).block_until_ready()
    with pytest.raises(ValueError, match="shape"):
        voxax.isosurface(f[:, :, :5], grid)
    with pytest.raises(TypeError, match="Grid"):
        voxax.isosurface(f, (8, 8, 8))
    with pytest.raises(ValueError, match="inside"):
        voxax.isosurface(f, grid, inside="outside")
    with pytest.raises(ValueError, match="finite"):
        voxax.isosurface(f, grid, np.inf)
    with pytest.raises(TypeError, match="capacity"):
        jax.jit(lambda x: voxax.isosurface(x, grid).faces)(f)
    with pytest.raises(TypeError, match="float"):
        voxax.isosurface(f.astype(np.complex128), grid)
    with pytest.raises(ValueError, match="close"):
        voxax.isosurface(f, grid, close=-5.0)
    with pytest.raises(TypeError, match="`close` must be"):
        voxax.isosurface(f, grid, close="yes")
    with pytest.warns(RuntimeWarning, match="does not cross"):
        iso = voxax.isosurface(f, grid, level=10.0)
    assert iso.vertices.shape == (0, 3) and iso.faces.shape == (0, 3)
    assert iso.to_mesh().n_faces == 0
