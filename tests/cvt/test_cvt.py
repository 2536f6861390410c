"""CVT meshing from surface samples: fragments, the restricted CVT, RDT extraction, remesh."""

import dataclasses

import jax
import numpy as np
import pytest

jax.config.update("jax_enable_x64", True)

import voxax  # noqa: E402
from voxax import cvt, fields, metrics  # noqa: E402
from voxax._kernels import cvt as kernels  # noqa: E402
from voxax.cvt._manifold import problem_edges  # noqa: E402
from voxax.cvt._remesh import line_faults, open_lines, topology_seeds  # noqa: E402


def _mesh_area(m):
    v, f = m.vertices, m.faces
    return 0.5 * np.linalg.norm(np.cross(v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]]), axis=1).sum()


# ------------------------------------------------------------------------------------
# Fragments


@pytest.fixture(scope="module")
def ico_fragments():
    mesh = voxax.data.icosphere(6, radius=0.8)
    return mesh, cvt.fragments(mesh, voxax.Grid.cube(256, half_width=1.0))


def test_mesh_fragments_on_surface_area_and_cap(ico_fragments):
    mesh, fr = ico_fragments
    # on the mesh (exact closest points, an independent BVH query)
    assert np.abs(voxax.closest_points(mesh, fr.points).distance).max() <= 1e-12
    # normals are the crossed faces' normals: unit and outward on a sphere
    assert np.allclose(np.linalg.norm(fr.normals, axis=1), 1.0)
    assert np.all(np.sum(fr.normals * fr.points, axis=1) > 0)
    # every line holds an even number of crossings, alternating enter/exit
    assert open_lines(fr) == 0
    # weights integrate the (exact) area of the mesh
    assert abs(fr.weights.sum() / _mesh_area(mesh) - 1) < 0.005
    # cap z > h (h on a grid plane): Archimedes' centroid (R + h) / 2 of a spherical zone
    R, h = 0.8, 0.25
    sel = fr.points[:, 2] > h
    weighted = np.sum(fr.weights[sel] * fr.points[sel, 2]) / fr.weights[sel].sum()
    unweighted = fr.points[sel, 2].mean()
    assert abs(weighted / ((R + h) / 2) - 1) < 1e-3
    assert abs(unweighted / ((R + h) / 2) - 1) > 1e-2


def test_field_fragments_on_sphere_with_gradient_normals():
    fr = cvt.fragments(fields.sphere, voxax.Grid.cube(48, half_width=1.2))
    r = np.linalg.norm(fr.points, axis=1)
    assert np.abs(r - 1).max() < 1e-12
    assert np.abs(fr.normals - fr.points / r[:, None]).max() < 1e-12
    # each fragment sits on its own cell-centre line
    g = fr.grid
    for a in range(3):
        sel = fr.axis == a
        for b in range(3):
            if b != a:
                idx = (fr.points[sel, b] - g.lower[b]) / g.spacing[b] - 0.5
                assert np.abs(idx - np.round(idx)).max() < 1e-9
    assert abs(fr.weights.sum() / (4 * np.pi) - 1) < 0.01
    assert np.all(fr.sign == np.where(fr.normals[np.arange(fr.size), fr.axis] > 0, 1, -1))


def test_grid_fragments_match_the_field():
    g = voxax.Grid.cube(40, half_width=1.2)
    w = np.asarray(fields.sphere(g.centers().reshape(-1, 3))).reshape(g.shape)
    fr = cvt.fragments((w, 0.0), g)
    # linear interpolation of the distance along the lines: second order in the spacing
    assert np.abs(np.linalg.norm(fr.points, axis=1) - 1).max() < 0.5 * max(g.spacing) ** 2
    assert np.abs(fr.normals - fr.points / np.linalg.norm(fr.points, axis=1)[:, None]).max() < 0.05
    assert abs(fr.weights.sum() / (4 * np.pi) - 1) < 0.01
    occ = -w  # inside above the level
    fr2 = cvt.fragments((occ, 0.0), g, inside="above")
    assert np.allclose(fr2.points, fr.points) and np.allclose(fr2.normals, fr.normals)


def test_dexel_csg_against_the_fields():
    g = voxax.Grid.cube(32, half_width=1.2)
    a = fields.sphere

    def b(p):
        return fields.sphere(p, 0.6, (0.5, 0.0, 0.0))

    pa, pb = cvt.fragments(a, g), cvt.fragments(b, g)
    for op, keep_a, keep_b in [
        ("union", lambda fb: fb > 0, lambda fa: fa > 0),
        ("intersection", lambda fb: fb < 0, lambda fa: fa < 0),
        ("difference", lambda fb: fb > 0, lambda fa: fa < 0),
    ]:
        fr = cvt.fragments(cvt.CSG(op, a, b), g)
        # independent oracle: a fragment of A survives where it is outside/inside B, etc.
        fa_at_b = np.asarray(a(pb.points))
        fb_at_a = np.asarray(b(pa.points))
        expect = np.concatenate([pa.points[keep_a(fb_at_a)], pb.points[keep_b(fa_at_b)]])
        got = fr.points
        assert len(got) == len(expect)
        key = lambda p: np.lexsort(p.T[::-1])  # noqa: E731
        assert np.allclose(got[key(got)], expect[key(expect)])
        assert open_lines(fr) == 0
        # normals: outward of the result (the difference flips B's)
        on_b = np.abs(np.asarray(b(fr.points))) < 1e-9
        if op == "difference":
            center = np.array([0.5, 0, 0])
            assert np.all(np.sum(fr.normals[on_b] * (fr.points[on_b] - center), axis=1) < 0)


def test_dexel_csg_with_an_operand_beyond_the_grid():
    # a box reaching far beyond the grid: lines across it start inside it
    from jax.tree_util import Partial

    g = voxax.Grid.cube(24, half_width=0.5)
    a = Partial(fields.sphere, radius=0.4, center=(0.0, 0.0, 0.0))
    b = Partial(fields.box, half_extents=(2.0, 2.0, 2.0), center=(2.2, 0.0, 0.0))
    pa = cvt.fragments(a, g)
    pb = cvt.fragments(b, g)
    for op, keep_a, keep_b in [
        ("intersection", lambda fb: fb < 0, lambda fa: fa < 0),
        ("difference", lambda fb: fb > 0, lambda fa: fa < 0),
    ]:
        fr = cvt.fragments(cvt.CSG(op, a, b), g)
        expect = np.concatenate(
            [pa.points[keep_a(np.asarray(b(pa.points)))], pb.points[keep_b(np.asarray(a(pb.points)))]]
        )
        key = lambda p: np.lexsort(p.T[::-1])  # noqa: E731
        assert len(fr.points) == len(expect) > 0
        assert np.allclose(fr.points[key(fr.points)], expect[key(expect)])
        assert open_lines(fr) == 0  # closed: the cap at x = 0.2 closes the sphere's part
    # a box face through cell centres: lines along y and z run inside the face, where the
    # normal is perpendicular to them; enter/exit comes from the samples' order
    c = g.lower[0] + 15.5 * g.spacing[0]
    fr = cvt.fragments(Partial(fields.box, half_extents=(0.25, 0.3, 0.3), center=(c - 0.25, 0.01, 0.02)), g)
    along = fr.normals[np.arange(fr.size), fr.axis.astype(np.int64)]
    assert np.any(np.abs(along) < 1e-6)  # grazing fragments exist
    assert open_lines(fr) == 0


def test_dexel_csg_with_operands_without_surface():
    # operands (and intermediate results) may have no surface on the grid: a ball between
    # the lines, a box covering the grid, an empty intersection; only the whole must have one
    from jax.tree_util import Partial

    g = voxax.Grid.cube(16, half_width=1.0)
    a = Partial(fields.sphere, radius=0.6)
    ref = cvt.fragments(a, g)
    speck = Partial(fields.sphere, radius=0.01, center=(0.03, 0.05, 0.07))  # no cell centre inside
    cover = Partial(fields.box, half_extents=(3.0, 3.0, 3.0))
    far = Partial(fields.sphere, radius=0.2, center=(0.8, 0.8, 0.8))
    for scene in [
        cvt.CSG("difference", a, speck),
        cvt.CSG("intersection", a, cover),
        cvt.CSG("union", cvt.CSG("intersection", speck, far), a),
    ]:
        fr = cvt.fragments(scene, g)
        assert fr.size == ref.size and np.array_equal(fr.points, ref.points)
    with pytest.raises(ValueError, match="CSG expression has no surface"):
        cvt.fragments(cvt.CSG("intersection", a, far), g)
    with pytest.raises(ValueError, match="CSG expression has no surface"):
        cvt.fragments(cvt.CSG("difference", a, cover), g)


def test_fragments_bad_input():
    g = voxax.Grid.cube(16)
    with pytest.raises(ValueError, match="empty surface"):
        cvt.fragments(lambda p: fields.sphere(p, 5.0), g)
    with pytest.raises(ValueError, match="empty surface"):
        cvt.fragments(voxax.data.icosphere(1, radius=0.1, center=(5.0, 5.0, 5.0)), g)
    with pytest.raises(TypeError):
        cvt.fragments("sphere", g)
    with pytest.raises(ValueError, match="`op` must be"):
        cvt.CSG("xor", fields.sphere, fields.sphere)
    with pytest.raises(ValueError, match="shape"):
        cvt.fragments((np.zeros((4, 4, 4)), 0.5), g)


# ------------------------------------------------------------------------------------
# The restricted CVT


@pytest.fixture(scope="module")
def small():
    fr = cvt.fragments(fields.sphere, voxax.Grid.cube(48, half_width=1.2))
    return fr, cvt.init_seeds(fr, 150, key=1)


def test_energy_gradient_is_eq2_and_brute_force(small):
    from scipy.spatial import cKDTree

    fr, s = small
    g_auto = np.asarray(jax.grad(lambda y: cvt.energy(y, fr))(jax.numpy.asarray(s)))
    g_eq2 = np.asarray(cvt.energy_gradient(s, fr))
    assert np.abs(g_auto - g_eq2).max() <= 1e-12
    # brute force with another nearest-neighbour search
    _, idx = cKDTree(s).query(fr.points)
    w = fr.weights
    ref = np.zeros_like(s)
    np.add.at(ref, idx, 2 * w[:, None] * (s[idx] - fr.points))
    assert np.abs(g_eq2 - ref).max() <= 1e-12
    e = float(cvt.energy(s, fr))
    assert abs(e - np.sum(w * np.sum((fr.points - s[idx]) ** 2, axis=1))) <= 1e-12 * e
    # under jit (the FFI nearest-neighbour kernel)
    e_jit = float(jax.jit(lambda y: cvt.energy(y, fr))(jax.numpy.asarray(s)))
    assert abs(e_jit - e) <= 1e-12 * e


def test_lloyd_monotone_and_lbfgs_faster(small):
    fr, s = small
    lloyd = cvt.optimize(fr, s, method="lloyd", steps=40)
    assert np.all(np.diff(lloyd.energy) <= 1e-13 * lloyd.energy[0])
    # run to the end: an exact fixed point, every seed its region's weighted centroid
    from scipy.spatial import cKDTree

    done = cvt.optimize(fr, lloyd.seeds, method="lloyd", steps=2000)
    assert done.steps < 2000
    _, idx = cKDTree(done.seeds).query(fr.points)
    mass = np.bincount(idx, fr.weights, minlength=len(s))
    cen = np.stack([np.bincount(idx, fr.weights * fr.points[:, a], minlength=len(s)) for a in range(3)], axis=1)
    assert np.abs(cen / mass[:, None] - done.seeds).max() <= 1e-13
    lb = cvt.optimize(fr, s, method="lbfgs", steps=20)
    # the energy L-BFGS reaches within half the iterations is at most Lloyd's
    assert lb.steps <= 20
    assert lb.energy.min() <= lloyd.energy[-1]


def test_warm_started_runs_are_the_cold_runs(small):
    from scipy.spatial import cKDTree

    from voxax.cvt._optimize import run, run_hinted

    fr, s = small
    lb, hint = run_hinted(fr, s, "lbfgs", 10, True)
    _, ref = cKDTree(lb.seeds).query(fr.points)  # the returned assignment is that of the seeds returned
    assert np.array_equal(np.asarray(hint)[: fr.size], ref)
    cold = run(fr, lb.seeds, "lloyd", 500, True)
    warm, hint = run_hinted(fr, lb.seeds, "lloyd", 500, True, hint=hint)
    assert warm.steps == cold.steps < 500  # an exact fixed point
    assert warm.seeds.tobytes() == cold.seeds.tobytes() and warm.energy.tobytes() == cold.energy.tobytes()
    _, ref = cKDTree(warm.seeds).query(fr.points)
    assert np.array_equal(np.asarray(hint)[: fr.size], ref)
    d = fr.points - warm.seeds[ref]
    e = np.sum(fr.weights * np.sum(d * d, axis=1))
    assert abs(warm.energy[-1] - e) <= 1e-12 * e  # the fixed point's energy, not a stale one
    # a hint of other fragments (another padded size) is not used
    other, _ = run_hinted(fr, lb.seeds, "lloyd", 3, True, hint=jax.numpy.zeros(7, jax.numpy.int32))
    assert other.seeds.tobytes() == run(fr, lb.seeds, "lloyd", 3, True).seeds.tobytes()


def test_stopping_tolerances_truncate_the_runs(small):
    from voxax.cvt._optimize import run_hinted, spacing

    fr, s = small
    # L-BFGS: the stop ends the run before the cap; a run capped at the steps it took,
    # without the stop, gives the same bits (the stop only truncates)
    full, _ = run_hinted(fr, s, "lbfgs", 60, True)
    assert full.steps == 60 and full.info == "max_steps"
    for tol in (1e-4, 1e-3):
        early, _ = run_hinted(fr, s, "lbfgs", 60, True, stop_tol=tol)
        assert early.info == "tol" and 3 <= early.steps < 60
        capped, _ = run_hinted(fr, s, "lbfgs", early.steps, True)
        assert capped.seeds.tobytes() == early.seeds.tobytes()
        assert np.array_equal(capped.energy, full.energy[: early.steps + 1])
        # the last two steps moved the seeds and each lowered the energy by less than tol
        e = early.energy
        assert np.all((e[-3:-1] - e[-2:]) < tol * e[-3:-1]) and np.all(e[-2:] < e[-3:-1])
    # Lloyd: the stop ends at the first step whose largest move is below tol edges
    lb, hint = run_hinted(fr, s, "lbfgs", 20, True)
    fixed, _ = run_hinted(fr, lb.seeds, "lloyd", 500, True, hint=hint)
    assert fixed.info == "fixed point"
    early, _ = run_hinted(fr, lb.seeds, "lloyd", 500, True, hint=hint, stop_tol=0.02)
    assert early.info == "tol" and 1 <= early.steps < fixed.steps
    reach = 0.02 * spacing(fr, len(s))
    y, moves = lb.seeds, []
    for _ in range(early.steps):
        step, _ = run_hinted(fr, y, "lloyd", 1, True)
        moves.append(np.linalg.norm(step.seeds - y, axis=1).max())
        y = step.seeds
    assert moves[-1] < reach and all(m >= reach for m in moves[:-1])
    assert y.tobytes() == early.seeds.tobytes()


def test_remesh_stops_early_and_tol_0_runs_every_step():
    mesh = voxax.data.icosphere(3)
    kw = dict(progress=False, threads=2)
    off = cvt.remesh(mesh, 300, tol=0, polish_tol=0, **kw)
    assert off.steps == 60 and off.tol == 0 and off.polish_tol == 0
    on = cvt.remesh(mesh, 300, **kw)
    assert on.steps < 60 and on.polish_steps <= 40 and on.tol == 1e-4 and on.polish_tol == 0.02
    assert on.closed and on.euler_characteristic == 2
    assert on.quality_mean > off.quality_mean - 0.005
    # the stops only truncate: the caps set to the steps that ran give the same mesh
    again = cvt.remesh(mesh, 300, steps=on.steps, polish=on.polish_steps, tol=0, polish_tol=0, **kw)
    assert again.mesh == on.mesh and again.steps == on.steps and again.polish_steps == on.polish_steps
    # Lloyd as the optimiser ignores `tol`
    kl = dict(method="lloyd", steps=5, relax=0, **kw)
    assert cvt.remesh(mesh, 80, tol=0.5, **kl).mesh == cvt.remesh(mesh, 80, tol=0, **kl).mesh


def _brute_nearest(s, x):
    """The nearest seed by (squared distance, index), all pairs in numpy."""
    d2 = np.sum((s[None, :, :] - x[:, None, :]) ** 2, axis=2)
    return np.lexsort((np.broadcast_to(np.arange(len(s)), d2.shape), d2), axis=1)[:, 0]


def test_assignment_kernel_with_hints_is_exact():
    rng = np.random.default_rng(5)
    # seeds on a sphere on a coarse lattice of directions (many ties), points on and near it
    s = np.round(rng.normal(size=(300, 3)), 1)
    s /= np.linalg.norm(s, axis=1, keepdims=True)
    s = np.concatenate([s, s[:7]])  # duplicate seeds: ties broken by the smaller index
    x = rng.normal(size=(3000, 3))
    x /= np.linalg.norm(x, axis=1, keepdims=True)
    x = np.concatenate([x * rng.uniform(0.97, 1.03, (3000, 1)), s[:20]])  # points on seeds
    w = rng.uniform(0.0, 2.0, len(x))
    w[::17] = 0.0
    ref = _brute_nearest(s, x)
    mass = np.bincount(ref, w, minlength=len(s))
    first = np.stack([np.bincount(ref, w * x[:, a], minlength=len(s)) for a in range(3)], axis=1)
    energy = np.sum(w * np.sum((x - s[ref]) ** 2, axis=1))
    moved = s + rng.normal(scale=0.02, size=s.shape)
    hints = {
        "none": None,
        "exact": ref,
        "from moved seeds": _brute_nearest(moved, x),
        "one seed": np.zeros(len(x)),
        "garbage": rng.integers(-3, len(s) + 3, len(x)),
    }
    runs = []
    for name, hint in hints.items():
        for threads in (1, 2):
            idx, mom, count, e = kernels.assign_host(s, x, w, hint, threads=threads)
            assert np.array_equal(idx, ref), name
            assert np.abs(mom[:, 0] - mass).max() <= 1e-12 and np.abs(mom[:, 1:] - first).max() <= 1e-12
            assert np.array_equal(count, np.bincount(ref, w > 0, minlength=len(s)))
            assert abs(e - energy) <= 1e-12 * energy
            runs.append((mom.tobytes(), e))
    assert len(set(runs)) == 1  # same bits for any hint and thread count
    # the FFI kernel under jit: the same bits
    out = jax.jit(kernels.assign)(s, x, w, jax.numpy.asarray(ref, jax.numpy.int32))
    assert np.array_equal(np.asarray(out[0]), ref) and np.asarray(out[1]).tobytes() == runs[0][0]
    with pytest.raises(ValueError, match="NaN"):
        kernels.assign_host(np.full((3, 3), np.nan), x, w)
    with pytest.raises(ValueError, match="weights"):
        kernels.assign_host(s, x, -w)


def test_optimizer_energy_gradient_is_eq2(small):
    from scipy.spatial import cKDTree

    from voxax.cvt._optimize import _energy_arrays

    fr, s = small
    x, w = jax.numpy.asarray(fr.points), jax.numpy.asarray(fr.weights)
    hint = jax.numpy.zeros(fr.size, jax.numpy.int32)
    (e, idx), g = jax.jit(jax.value_and_grad(_energy_arrays, has_aux=True))(jax.numpy.asarray(s), (x, w, 0.5, hint))
    _, ref_idx = cKDTree(s).query(fr.points)
    assert np.array_equal(np.asarray(idx), ref_idx)
    d = fr.points - s[ref_idx]
    assert abs(float(e) - 0.5 * np.sum(fr.weights * np.sum(d * d, axis=1))) <= 1e-12 * float(e)
    ref = np.zeros_like(s)
    np.add.at(ref, ref_idx, fr.weights[:, None] * (s[ref_idx] - fr.points))  # 0.5 * 2 (W s - sum w x)
    assert np.abs(np.asarray(g) - ref).max() <= 1e-12


def test_init_seeds_and_respawn(small):
    fr, _ = small
    s = cvt.init_seeds(fr, 50, key=3)
    assert s.shape == (50, 3) and np.all(np.isin(s.view("f8,f8,f8"), fr.points.view("f8,f8,f8")))
    with pytest.raises(ValueError, match="fragments"):
        cvt.init_seeds(fr, fr.size + 1)
    far = np.concatenate([s, [[10.0, 10.0, 10.0]]])  # an empty region
    _, count = cvt.lloyd_step(far, fr)
    assert int(count[-1]) == 0
    moved, n = cvt.respawn(far, fr, count)
    assert n == 1 and np.abs(np.linalg.norm(moved[-1]) - 1) < 1e-12


# ------------------------------------------------------------------------------------
# RDT


@pytest.fixture(scope="module")
def sphere_rdt():
    fr = cvt.fragments(fields.sphere, voxax.Grid.cube(100, half_width=1.1))
    res = cvt.optimize(fr, cvt.init_seeds(fr, 600, key=0), method="lbfgs", steps=60)
    faces, rep = cvt.rdt(fr, res.seeds)
    return fr, res.seeds, faces, rep


def test_sphere_rdt_is_the_convex_hull(sphere_rdt):
    from scipy.spatial import ConvexHull

    fr, seeds, faces, rep = sphere_rdt
    m = voxax.Mesh(seeds, faces)
    mr = metrics.manifold_report(m)
    assert mr.closed and mr.edge_manifold and mr.vertex_manifold and mr.oriented
    assert metrics.euler_characteristic(m) == 2
    c = np.cross(seeds[faces[:, 1]] - seeds[faces[:, 0]], seeds[faces[:, 2]] - seeds[faces[:, 0]])
    assert np.all(np.sum(c * seeds[faces].mean(axis=1), axis=1) > 0)  # outward
    q = metrics.triangle_quality(m)
    assert q.mean() >= 0.85 and q.min() >= 0.5
    hull = ConvexHull(seeds / np.linalg.norm(seeds, axis=1, keepdims=True))
    ours = {tuple(sorted(f)) for f in faces.tolist()}
    theirs = {tuple(sorted(f)) for f in hull.simplices.tolist()}
    assert len(ours & theirs) >= 0.99 * len(theirs)
    assert rep.from_candidates >= 0.95


def test_rdt_deterministic_across_threads(sphere_rdt):
    fr, seeds, faces, _ = sphere_rdt
    f1, _ = cvt.rdt(fr, seeds, threads=1)
    f2, _ = cvt.rdt(fr, seeds, threads=2)
    assert np.array_equal(f1, f2) and np.array_equal(f1, faces)


def test_rdt_bad_input(sphere_rdt):
    fr, seeds, _, _ = sphere_rdt
    with pytest.raises(ValueError, match="at least 3 seeds"):
        cvt.rdt(fr, seeds[:2])
    bad = seeds.copy()
    bad[0, 0] = np.nan
    with pytest.raises(ValueError, match="NaN or Inf"):
        cvt.rdt(fr, bad)
    with pytest.raises(ValueError, match="max_hole"):
        cvt.rdt(fr, seeds, max_hole=2)


# ------------------------------------------------------------------------------------
# remesh


def test_remesh_torus_field():
    g = voxax.Grid.cube(24, half_width=0.9)
    m, rep = cvt.remesh(lambda p: fields.torus(p, 0.55, 0.25), 400, grid=g, method="lloyd", steps=40)
    assert rep["closed"] and rep["manifold"]
    assert rep["euler_characteristic"] == 0
    assert rep["quality_min"] >= 0.3
    # vertices on the torus (projected to the fragments' tangent planes)
    assert np.abs(np.asarray(fields.torus(m.vertices, 0.55, 0.25))).max() < 0.01


def test_remesh_keeps_a_small_component():
    # a ball 0.05 in radius next to one of 0.6: about two seeds' worth of area at 300 seeds,
    # so area-proportional seeding alone often leaves it with too few seeds to close
    from jax.tree_util import Partial

    small_c = np.array([0.8, 0.0, 0.0])
    scene = cvt.CSG("union", Partial(fields.sphere, radius=0.6), Partial(fields.sphere, radius=0.05, center=small_c))
    for key in range(3):
        m, rep = cvt.remesh(scene, 300, grid=voxax.Grid.cube(24, half_width=1.0), method="lloyd", steps=20, key=key)
        assert rep["closed"] and rep["manifold"]
        # two spheres: two components, chi 2 + 2
        assert rep["euler_characteristic"] == 4 and rep["rdt"].components == 2
        v = m.vertices
        on_big = np.abs(np.linalg.norm(v, axis=1) - 0.6) < 0.01
        on_small = np.abs(np.linalg.norm(v - small_c, axis=1) - 0.05) < 0.01
        assert np.all(on_big | on_small) and on_small.sum() >= 4


def test_relax_evens_out_a_mesh_on_the_surface(small):
    from voxax.cvt._relax import relax

    fr, _ = small
    ico = voxax.data.icosphere(3)  # radius 1, like the fixture's sphere
    rng = np.random.default_rng(2)
    v = ico.vertices + rng.normal(scale=0.015, size=ico.vertices.shape)
    v /= np.linalg.norm(v, axis=1, keepdims=True)
    f = np.asarray(ico.faces)
    n0 = np.cross(v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]])
    assert np.all(np.sum(n0 * v[f[:, 0]], axis=1) > 0)  # still oriented outward
    q0 = metrics.triangle_quality(voxax.Mesh(v, f))
    out = relax(v, f, fr, 3)
    q1 = metrics.triangle_quality(voxax.Mesh(out, f))
    assert q1.mean() > q0.mean() + 0.02 and q1.min() > q0.min()
    assert np.abs(np.linalg.norm(out, axis=1) - 1).max() < 2e-3  # on the sphere (tangent planes)
    n1 = np.cross(out[f[:, 1]] - out[f[:, 0]], out[f[:, 2]] - out[f[:, 0]])
    assert np.all(np.sum(n0 * n1, axis=1) > 0)  # no triangle turned over
    # the quality floor: no triangle ends a step below min(floor, its quality before it)
    # (without the floor, some do: the step evens out the mesh as a whole)
    one = relax(v, f, fr, 1)
    assert np.any(metrics.triangle_quality(voxax.Mesh(one, f)) < q0 - 1e-3)
    guarded = relax(v, f, fr, 1, floor=0.99)
    qg = metrics.triangle_quality(voxax.Mesh(guarded, f))
    assert np.all(qg >= np.minimum(0.99, q0)) and not np.array_equal(guarded, v)
    # an open mesh: the vertices of its boundary edges stay
    part = f[:-40]
    kept = relax(v, part, fr, 2)
    edges = np.sort(np.concatenate([part[:, [0, 1]], part[:, [1, 2]], part[:, [2, 0]]]), axis=1)
    uniq, count = np.unique(edges, axis=0, return_counts=True)
    rim = np.unique(uniq[count == 1])
    assert len(rim) > 0 and np.array_equal(kept[rim], v[rim])


def test_remesh_mesh_and_open_mesh_error():
    mesh = voxax.data.icosphere(3)
    m, rep = cvt.remesh(mesh, 300, method="lloyd", steps=40)
    assert rep["closed"] and rep["euler_characteristic"] == 2
    assert metrics.hausdorff(m, mesh) < 0.05
    open_mesh = voxax.Mesh(mesh.vertices, mesh.faces[:-5])
    with pytest.raises(ValueError, match="open"):
        cvt.remesh(open_mesh, 100)
    with pytest.raises(ValueError, match="fragments"):
        cvt.remesh(mesh, 10**6, alpha=0.001)
    with pytest.raises(ValueError, match="polish"):
        cvt.remesh(mesh, 100, polish=-1)
    with pytest.raises(ValueError, match="relax"):
        cvt.remesh(mesh, 100, relax=-1)


def test_cli_remesh(tmp_path, capsys):
    from voxax.cli import main

    out = tmp_path / "r.ply"
    assert main(["remesh", "icosphere", "--seeds", "200", "--method", "lloyd", "--steps", "10", "-o", str(out)]) == 0
    assert "closed 2-manifold" in capsys.readouterr().out
    m = voxax.io.load(str(out))
    assert metrics.euler_characteristic(m) == 2
    assert main(["remesh", "icosphere", "--seeds", "2"]) == 2


def test_ball_fragments_and_union_are_exact():
    from voxax.cvt._fragments import ball_fragments, union_all

    g = voxax.Grid.cube(40, half_width=1.0)
    c = np.array([[0.1, 0.0, 0.0], [0.5, 0.1, 0.0]])
    r = np.array([0.4, 0.3])
    balls = ball_fragments(c, r, g)
    # each crossing lies on one of the spheres
    d = np.abs(np.linalg.norm(balls.points[:, None] - c[None], axis=2) - r[None])
    assert d.min(axis=1).max() < 1e-12
    u = union_all([balls])
    # survivors are outside the other ball, and the union is closed on every line
    inside_any = (np.linalg.norm(u.points[:, None] - c[None], axis=2) < r[None] - 1e-9).any(axis=1)
    assert not inside_any.any() and open_lines(u) == 0
    # and every crossing outside the other ball survives (an independent count)
    dist = np.linalg.norm(balls.points[:, None] - c[None], axis=2)
    outside = (dist > r[None] - 1e-9).all(axis=1)
    assert u.size == int(outside.sum())


def test_problem_edges_match_manifold_report():
    mesh = voxax.data.icosphere(2)
    assert len(problem_edges(np.asarray(mesh.faces), mesh.n_vertices)) == 0
    holed = np.asarray(mesh.faces[1:])
    bad = problem_edges(holed, mesh.n_vertices)
    assert len(bad) == metrics.manifold_report(voxax.Mesh(mesh.vertices, holed)).n_boundary_edges == 3
    # two tetrahedra sharing one vertex: a non-manifold vertex, all its edges reported
    v = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1], [-1, 0, 0], [0, -1, 0], [0, 0, -1.0]])
    t = np.array([[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]])
    f = np.concatenate([t, np.where(t == 0, 0, t + 3)])
    bad = problem_edges(f, len(v))
    assert metrics.manifold_report(voxax.Mesh(v, f)).n_nonmanifold_vertices == 1
    assert len(bad) == 6 and np.all((bad == 0).any(axis=1))


def _volume(m):
    v, f = m.vertices, m.faces
    return float(np.einsum("ij,ij->i", v[f[:, 0]], np.cross(v[f[:, 1]], v[f[:, 2]])).sum() / 6)


@pytest.mark.slow
def test_remesh_csg_volume_against_manifold3d():
    manifold3d = pytest.importorskip("manifold3d")
    box_c, box_h = (0.5, 0.5, 0.5), 0.45
    scene = cvt.CSG("difference", fields.sphere, lambda p: fields.box(p, box_h, box_c))
    m, rep = cvt.remesh(scene, 1200, grid=voxax.Grid.cube(24, half_width=1.1), steps=20)
    assert rep["closed"] and rep["manifold"] and rep["euler_characteristic"] == 2
    ball = manifold3d.Manifold.sphere(1.0, 512)
    cube = manifold3d.Manifold.cube((2 * box_h,) * 3, center=True).translate(box_c)
    exact = (ball - cube).volume()
    assert abs(_volume(m) / exact - 1) < 0.02


@pytest.mark.slow
def test_remesh_hand_is_manifold():
    m, rep = cvt.remesh(voxax.data.hand(), 3000, max_rounds=30)
    assert rep["closed"] and rep["manifold"] and rep["rounds"] <= 30
    assert rep["euler_characteristic"] == metrics.euler_characteristic(voxax.data.hand())


@pytest.mark.slow
def test_remesh_thin_plate_is_a_closed_sphere():
    # a 1 x 1 x 0.02 box: both faces are closer than the seed spacing (about 0.035)
    v = np.array([[x, y, z] for x in (-0.5, 0.5) for y in (-0.5, 0.5) for z in (-0.01, 0.01)])
    f = np.array(
        [0, 1, 3, 0, 3, 2, 4, 6, 7, 4, 7, 5, 0, 4, 5, 0, 5, 1, 2, 3, 7, 2, 7, 6, 0, 2, 6, 0, 6, 4, 1, 5, 7, 1, 7, 3]
    )
    f = f.reshape(-1, 3)
    plate = voxax.Mesh(v, f)
    assert metrics.manifold_report(plate).closed and _volume(plate) > 0
    # the seed spacing is 1.7 times the thickness: a seeding may still end with a wrong
    # handle (both faces' seeds joined); most give the sphere's topology
    spheres = 0
    for key in range(3):
        m, rep = cvt.remesh(plate, 2000, key=key)
        assert rep["closed"] and rep["manifold"]
        assert metrics.hausdorff(m, plate) < 0.05
        spheres += rep["euler_characteristic"] == 2
    assert spheres >= 2


@pytest.mark.slow
def test_sphere_4k_seeds():
    from scipy.spatial import ConvexHull

    fr = cvt.fragments(fields.sphere, voxax.Grid.cube(256, half_width=1.1))  # alpha ~ 64
    res = cvt.optimize(fr, cvt.init_seeds(fr, 4000, key=0), method="lbfgs", steps=100)
    faces, rep = cvt.rdt(fr, res.seeds)
    m = voxax.Mesh(res.seeds, faces)
    mr = metrics.manifold_report(m)
    assert mr.closed and mr.edge_manifold and mr.vertex_manifold and mr.euler_characteristic == 2
    q = metrics.triangle_quality(m)
    assert q.mean() >= 0.85 and q.min() >= 0.5
    hull = ConvexHull(res.seeds / np.linalg.norm(res.seeds, axis=1, keepdims=True))
    ours = {tuple(sorted(f)) for f in faces.tolist()}
    assert len(ours & {tuple(sorted(f)) for f in hull.simplices.tolist()}) >= 0.99 * len(hull.simplices)


# ------------------------------------------------------------------------------------
# The API: the typed result, surface forms, bad input


def test_remesh_result_is_typed_and_unpacks():
    mesh = voxax.data.icosphere(2)
    res = cvt.remesh(mesh, 80, method="lloyd", steps=5, polish=0, relax=0, progress=False)
    assert isinstance(res, cvt.RemeshResult)
    m, report = res
    assert m is res.mesh and report is res and report["closed"] is res.closed
    assert res.source_euler_characteristic == 2 == metrics.euler_characteristic(mesh)
    with pytest.raises(KeyError):
        res["no such field"]
    with pytest.raises(dataclasses.FrozenInstanceError):
        res.closed = False
    # the same mesh as a (V, F) pair, as vertices and faces, and as a trimesh: the same result
    trimesh = pytest.importorskip("trimesh")
    kw = dict(method="lloyd", steps=5, polish=0, relax=0, progress=False)
    for form in [((mesh.vertices, mesh.faces), 80), (mesh.vertices, mesh.faces, 80),
                 (trimesh.Trimesh(mesh.vertices, mesh.faces, process=False), 80)]:
        other = cvt.remesh(*form, **kw)
        assert other.mesh == res.mesh
    other = cvt.remesh(mesh, n_seeds=80, **kw)
    assert other.mesh == res.mesh
    for threads in (1, 2):  # the same bits on every thread count
        assert cvt.remesh(mesh, 80, threads=threads, **kw).mesh == res.mesh


@pytest.mark.parametrize("kwargs, error, match", [
    (dict(n_seeds=3), ValueError, "`n_seeds` must be at least 4"),
    (dict(n_seeds=2.5), TypeError, "`n_seeds` must be an int"),
    (dict(n_seeds=2**21), ValueError, "`n_seeds` must be below 2\\^21"),
    (dict(n_seeds=2**20, alpha=1e5), MemoryError, "GiB"),
    (dict(alpha=float("inf")), ValueError, "`alpha` must be > 0 and finite"),
    (dict(key="seven"), TypeError, "`key`"),
    (dict(key=-1), ValueError, "`key`"),
    (dict(threads=0), ValueError, "`threads` must be >= 1"),
    (dict(method="newton"), ValueError, "`method`"),
    (dict(steps=-1), ValueError, "`steps`"),
    (dict(tol=-1e-4), ValueError, "`tol` must be >= 0 and finite"),
    (dict(tol=float("nan")), ValueError, "`tol` must be >= 0 and finite"),
    (dict(tol="small"), TypeError, "`tol` must be a number"),
    (dict(polish_tol=-0.02), ValueError, "`polish_tol` must be >= 0 and finite"),
    (dict(polish_tol=float("nan")), ValueError, "`polish_tol` must be >= 0 and finite"),
    (dict(polish_tol=float("inf")), ValueError, "`polish_tol` must be >= 0 and finite"),
    (dict(grid=voxax.Grid((-1.0, -1.0), (1.0, 1.0), (4, 4))), ValueError, "`grid` must be 3D"),
])
def test_remesh_bad_arguments(kwargs, error, match):
    kw = dict(n_seeds=100, progress=False) | kwargs
    with pytest.raises(error, match=match) as info:
        cvt.remesh(voxax.data.icosphere(1), **kw)
    assert str(info.value).startswith("voxax.cvt.remesh: ")


def test_remesh_refuses_bool_and_complex_input():
    mesh = voxax.data.icosphere(1)
    for v in (mesh.vertices > 0, mesh.vertices + 0j):
        with pytest.raises(TypeError, match="`vertices` must be float32 or float64"):
            cvt.remesh((v, mesh.faces), 40, progress=False)
    g = voxax.Grid.cube(8)
    with pytest.raises(TypeError, match="real numbers"):
        cvt.remesh((np.ones(g.shape, complex), 0.5), 40, grid=g, progress=False)
    with pytest.raises(TypeError, match="real values"):
        cvt.fragments(lambda p: fields.sphere(p) + 0j, g)
    fr = cvt.fragments(fields.sphere, voxax.Grid.cube(16, half_width=1.2))
    with pytest.raises(TypeError, match="`seeds` must be a real"):
        cvt.rdt(fr, np.ones((5, 3), bool))
    with pytest.raises(TypeError, match="`seeds` must be a real"):
        cvt.energy(np.ones((5, 3), complex), fr)


def test_hostile_fragments_are_refused_before_the_kernels():
    fr = cvt.fragments(fields.sphere, voxax.Grid.cube(16, half_width=1.2))
    s = cvt.init_seeds(fr, 20, key=0)
    bad = {
        "normals": fr._replace(normals=fr.normals[:5]),  # fewer normals than points (read past the end before)
        "weights": fr._replace(weights=fr.weights[:-1]),
        "points": fr._replace(points=fr.points[:, :2]),
        "sign": fr._replace(sign=fr.sign[:3]),
    }
    for name, frag in bad.items():
        for call, args, kw in ((cvt.rdt, (frag, s), {}), (cvt.optimize, (frag, s), {"steps": 1}),
                               (cvt.energy, (s, frag), {}), (cvt.remesh, (frag, 20), {"progress": False})):
            with pytest.raises(ValueError, match=f"`frag.{name}` must have shape"):
                call(*args, **kw)
    nan = fr.normals.copy()
    nan[3] = np.nan
    with pytest.raises(ValueError, match="`frag.normals` must be finite"):
        cvt.rdt(fr._replace(normals=nan), s)
    # the kernel checks the counts itself (the same call without the Python checks)
    with pytest.raises(ValueError, match="one normal per fragment"):
        kernels.rdt(s, fr.points, fr.normals[:5], 1.0, 8)


# ------------------------------------------------------------------------------------
# Surfaces that bound no solid: the true reason


def _cube_with_wall():
    """Two unit cubes side by side with their shared square kept once: closed (no boundary
    edge) but the wall's edges have three faces."""
    v = np.array([[x, y, z] for x in (0.0, 1.0, 2.0) for y in (0.0, 1.0) for z in (0.0, 1.0)]) * 0.4 - 0.4
    i = lambda x, y, z: 4 * x + 2 * y + z  # noqa: E731
    quads = [(i(0, 0, 0), i(0, 0, 1), i(0, 1, 1), i(0, 1, 0)), (i(2, 0, 0), i(2, 1, 0), i(2, 1, 1), i(2, 0, 1)),
             (i(1, 0, 0), i(1, 1, 0), i(1, 1, 1), i(1, 0, 1))]  # the two ends and the wall
    for x in (0, 1):
        quads += [(i(x, 0, 0), i(x + 1, 0, 0), i(x + 1, 0, 1), i(x, 0, 1)), (i(x, 1, 0), i(x, 1, 1), i(x + 1, 1, 1), i(x + 1, 1, 0)),
                  (i(x, 0, 0), i(x, 1, 0), i(x + 1, 1, 0), i(x + 1, 0, 0)), (i(x, 0, 1), i(x + 1, 0, 1), i(x + 1, 1, 1), i(x, 1, 1))]
    f = np.array([[a, b, c] for a, b, c, d in quads] + [[a, c, d] for a, b, c, d in quads])
    return voxax.Mesh(v, f)


def test_remesh_names_why_a_surface_bounds_no_solid():
    ico = voxax.data.icosphere(2)
    cases = {
        "inside out": (ico.flipped(), "inside out \\(enclosed volume -"),
        "an inside-out part": (voxax.data.with_inverted_component(subdivisions=2), "parts of the mesh are inside out"),
        "overlapping parts": (voxax.data.overlapping_cubes(), "the surface overlaps itself"),
        "internal wall": (_cube_with_wall(), "closed but not a 2-manifold \\(4 edges have more than two faces"),
        "open": (voxax.Mesh(ico.vertices, ico.faces[:-5]), "the mesh is open"),
    }
    mr = metrics.manifold_report(cases["internal wall"][0])
    assert mr.n_boundary_edges == 0 and mr.n_nonmanifold_edges == 4
    for name, (mesh, match) in cases.items():
        with pytest.raises(ValueError, match=match) as info:
            cvt.remesh(mesh, 100, progress=False)
        assert "orient=False" in str(info.value), name
    # a solid cut by the grid's box: lines that start inside it without a crossing
    with pytest.raises(ValueError, match="240 grid lines start inside it"):
        cvt.remesh(fields.sphere, 50, grid=voxax.Grid.cube(12, half_width=0.8), progress=False)
    # and the line counts behind the messages, on exact fragments
    faults = line_faults(cvt.fragments(voxax.data.overlapping_cubes(), voxax.Grid.cube(16)))
    assert faults["nested"] > 0 and faults["negative"] == 0 and faults["unbalanced"] == 0
    faults = line_faults(cvt.fragments(ico.flipped(), voxax.Grid.cube(16)))
    assert faults["negative"] > 0 and faults["nested"] == 0


def test_cli_remesh_names_its_own_option(tmp_path, capsys):
    from voxax.cli import main

    path = tmp_path / "overlapping.ply"
    voxax.io.save(voxax.data.overlapping_cubes(), str(path))
    assert main(["remesh", str(path), "--seeds", "100", "--method", "lloyd", "--steps", "5"]) == 2
    err = capsys.readouterr().err
    assert "overlaps itself" in err and "pass --open" in err and "orient=False" not in err
    out = tmp_path / "r.ply"
    status = main(["remesh", str(path), "--seeds", "100", "--method", "lloyd", "--steps", "5", "--open", "-o", str(out)])
    assert status in (0, 1) and voxax.io.load(str(out)).n_faces > 0  # 1: the result is not a closed 2-manifold


# ------------------------------------------------------------------------------------
# Topology against the source's


def test_topology_seeds_split_a_region_spanning_two_sheets():
    # two parallel sheets 0.1 apart facing away from each other (a thin plate's faces): 10
    # fragments on top, 4 below; one seed's region holds both, so its mean normal points up
    # and a seed goes at the first fragment below (ties by index)
    xy = np.stack(np.meshgrid(np.linspace(-0.3, 0.3, 5), [0.0, 0.1]), -1).reshape(-1, 2)
    top = np.column_stack([xy, np.full(10, 0.05)])
    bottom = np.column_stack([xy[3:7], np.full(4, -0.05)])
    points = np.concatenate([top, bottom])
    normals = np.repeat([[0.0, 0.0, 1.0], [0.0, 0.0, -1.0]], [10, 4], axis=0)
    n = len(points)
    fr = cvt.Fragments(points, normals, np.ones(n), np.full(n, 2, np.int8), np.arange(n), np.ones(n, np.int8),
                       voxax.Grid.cube(4))
    new = topology_seeds(fr, np.array([[0.0, 0.0, 0.0], [5.0, 5.0, 5.0]]))
    assert np.array_equal(new, bottom[:1])
    # a seed on each sheet: every region faces one way, nothing to add
    assert len(topology_seeds(fr, np.array([[0.0, 0.0, 0.5], [0.0, 0.0, -0.5]]))) == 0


def test_remesh_keeps_the_source_topology_or_warns():
    # a 1 x 1 x 0.05 plate at 300 seeds: the seed spacing (about 0.085) exceeds the
    # thickness, and with key 0 one region spans both faces, which gives the triangulation
    # a handle (chi 0); the topology round adds seeds there and gets the sphere's chi back
    plate = voxax.data.box((-0.5, -0.5, -0.025), (0.5, 0.5, 0.025))
    kw = dict(method="lloyd", steps=20, key=0, progress=False)
    with pytest.warns(UserWarning, match="Euler characteristic is 0, the source's 2"):
        res = cvt.remesh(plate, 300, topology_rounds=0, **kw)
    assert res.closed and res.manifold and res.euler_characteristic == 0 and res.source_euler_characteristic == 2
    res = cvt.remesh(plate, 300, **kw)
    assert res.closed and res.manifold and res.euler_characteristic == 2
    assert res.topology_rounds >= 1 and res.topology_seeds > 0
    assert metrics.hausdorff(res.mesh, plate) < 0.08  # the seed spacing is 0.085: the corners are cut
