"""The public API's shared conventions: mesh objects in place of `vertices, faces`,
`grid` after the mesh, one batching rule, one validation path, user-defined filter
kernels, importing without starting JAX, and value semantics of the public objects."""

from __future__ import annotations

import copy
import dataclasses
import pickle
import re
import subprocess
import sys

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import voxax
from voxax import Box, Gaussian, Grid, Mesh, data, reference

SQUARE = data.polygon_square((-0.45, -0.3), (0.35, 0.4))
GRID2 = Grid((-0.75, -0.6), (0.75, 0.7), (10, 9))


# -- importing ---------------------------------------------------------------------------------


def test_import_does_not_start_the_xla_backend():
    code = (
        "import voxax\n"
        "from jax._src import xla_bridge\n"
        "assert not xla_bridge._backends, sorted(xla_bridge._backends)\n"
        "import jax\n"
        "jax.config.update('jax_platforms', 'cpu')\n"
        "assert jax.default_backend() == 'cpu'\n"
        "print('ok')\n"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300)
    assert out.returncode == 0, out.stderr[-2000:]
    assert out.stdout.strip() == "ok"


# -- mesh objects in place of (vertices, faces) --------------------------------------------------


def test_mesh_objects_are_accepted_wherever_vertices_and_faces_are():
    mesh = data.torus(n_major=12, n_minor=6)
    tri = mesh.to_trimesh()
    grid = Grid.around(mesh, 6)
    assert grid == Grid.around(mesh.vertices, 6) == Grid.around(tri, 6)
    W = np.asarray(voxax.voxelize(mesh.vertices, mesh.faces, grid))
    for call in (
        lambda: voxax.voxelize(mesh, grid),
        lambda: voxax.voxelize(mesh, grid=grid),
        lambda: voxax.voxelize(tri, grid),
    ):
        np.testing.assert_array_equal(np.asarray(call()), W)
    np.testing.assert_allclose(reference.voxelize(mesh, grid), W, atol=1e-12)
    pts = np.array([[0.75, 0.0, 0.0], [0.0, 0.0, 0.0]])
    np.testing.assert_allclose(voxax.winding_number(mesh, pts), [1.0, 0.0], atol=1e-9)
    np.testing.assert_array_equal(reference.winding_number_ray(mesh, pts), [1.0, 0.0])
    assert reference.signed_volume(mesh) == pytest.approx(mesh.signed_volume(), rel=1e-12)
    key = jax.random.key(0)
    np.testing.assert_array_equal(
        np.asarray(voxax.voxelize_mc(mesh, grid, Box(0.5), key, samples=8)),
        np.asarray(voxax.voxelize_mc(mesh.vertices, mesh.faces, grid, Box(0.5), key, samples=8)),
    )
    assert voxax.io.is_watertight(mesh) and voxax.io.is_watertight(tri)


def test_mesh_overload_is_unambiguous():
    mesh = data.cube()
    with pytest.raises(TypeError, match="voxelize: got a mesh object and `faces`"):
        voxax.voxelize(mesh, mesh.faces, Grid.cube(4))
    with pytest.raises(TypeError, match="voxelize: missing `grid`"):
        voxax.voxelize(mesh)
    with pytest.raises(TypeError, match="winding_number: missing `points`"):
        voxax.winding_number(mesh)


def test_grid_comes_right_after_the_mesh():
    """`voxelize_corner_gradients(vertices, faces, grid, cotangent)`, summed over the corners,
    is `reference.voxelize_backward(vertices, faces, grid, cotangent)`."""
    mesh = data.icosphere(1, radius=0.6)
    grid = Grid((-0.8, -0.7, -0.75), (0.7, 0.8, 0.7), (5, 4, 6))
    cot = np.random.default_rng(0).normal(size=grid.shape)
    corners = np.asarray(voxax.voxelize_corner_gradients(mesh.vertices, mesh.faces, grid, cot))
    summed = np.zeros_like(mesh.vertices)
    np.add.at(summed, mesh.faces.reshape(-1), corners.reshape(-1, 3))
    np.testing.assert_allclose(summed, reference.voxelize_backward(mesh.vertices, mesh.faces, grid, cot), atol=1e-10)
    again = np.asarray(voxax.voxelize_corner_gradients(mesh, grid, cot))
    np.testing.assert_array_equal(again, corners)


# -- one batching rule -------------------------------------------------------------------------


def _square_batch():
    v = np.stack([SQUARE.vertices, SQUARE.vertices * 0.8, SQUARE.vertices + 0.05])  # (3, V, 2)
    f = np.stack([SQUARE.faces, SQUARE.faces[:, ::-1]])[:, None]  # (2, 1, F, 2): the second inverted
    return v, f


def test_voxelize_mc_broadcasts_vertices_and_faces_like_voxelize():
    v, f = _square_batch()
    key = jax.random.key(3)
    out = np.asarray(voxax.voxelize_mc(v, f, GRID2, Gaussian(0.8), key, samples=16))
    assert out.shape == (2, 3) + GRID2.shape
    exact = np.asarray(voxax.voxelize(v, f, GRID2))
    assert exact.shape == out.shape
    for i, j in ((0, 0), (1, 2)):
        one = voxax.voxelize_mc(v[j], f[i, 0], GRID2, Gaussian(0.8), key, samples=16)
        np.testing.assert_allclose(out[i, j], one, atol=1e-12)
    mapped = jax.vmap(lambda vv: voxax.voxelize_mc(vv, f[1, 0], GRID2, Gaussian(0.8), key, samples=16))(v)
    np.testing.assert_allclose(mapped, out[1], atol=1e-12)
    np.testing.assert_allclose(out[1], -out[0], atol=1e-12)  # inverted faces: negated winding


def test_voxelize_mc_tangent_broadcasts():
    v, f = _square_batch()
    key = jax.random.key(4)
    t = np.random.default_rng(1).normal(size=v.shape)
    out = np.asarray(voxax.voxelize_mc_tangent(v, f, GRID2, Box(1.0), key, t, surface_samples=8))
    assert out.shape == (2, 3) + GRID2.shape
    one = voxax.voxelize_mc_tangent(v[2], f[0, 0], GRID2, Box(1.0), key, t[2], surface_samples=8)
    np.testing.assert_allclose(out[0, 2], one, atol=1e-12)


def test_winding_number_batches_meshes_over_shared_points():
    v, f = _square_batch()
    pts = np.random.default_rng(2).uniform(-0.7, 0.7, size=(4, 5, 2))
    out = np.asarray(voxax.winding_number(v, f, pts))
    assert out.shape == (2, 3, 4, 5)
    for i in range(2):
        for j in range(3):
            ray = reference.winding_number_ray(v[j], f[i, 0], pts.reshape(-1, 2)).reshape(4, 5)
            np.testing.assert_allclose(out[i, j], ray, atol=1e-9)
    mapped = jax.vmap(lambda vv: voxax.winding_number(vv, f[0, 0], pts))(v)
    np.testing.assert_allclose(mapped, out[0], atol=1e-12)


def test_point_sampled_batches():
    v, f = _square_batch()
    out = np.asarray(voxax.baselines.point_sampled(v, f, GRID2, supersample=2))
    assert out.shape == (2, 3) + GRID2.shape
    np.testing.assert_array_equal(out[1, 2], voxax.baselines.point_sampled(v[2], f[1, 0], GRID2, supersample=2))
    np.testing.assert_array_equal(out[0, 0], voxax.baselines.point_sampled(SQUARE, GRID2, supersample=2))


def test_arap_batches_like_a_loop():
    m = data.icosphere(1)
    v = np.stack([m.vertices * 1.1, m.vertices @ np.diag([1.0, 1.2, 0.9])])
    e = np.asarray(voxax.energies.arap(v, m.vertices, m.faces))
    assert e.shape == (2,)
    loop = [float(voxax.energies.arap(x, m.vertices, m.faces)) for x in v]
    np.testing.assert_allclose(e, loop, rtol=1e-12)
    mapped = jax.vmap(lambda x: voxax.energies.arap(x, m.vertices, m.faces))(v)
    np.testing.assert_allclose(mapped, loop, rtol=1e-12)
    # Scaling by 1.1: every edge 10% too long, zero rotation: 3 x area-averaged 0.1^2 per
    # face corner cell, i.e. E = sum_f sum_edges w |0.1 e|^2 * 3 / area (a closed form).
    w = np.asarray(voxax.energies.cotangent_weights(m.vertices, m.faces))
    c = m.vertices[m.faces]
    edges = c[:, [2, 0, 1]] - c[:, [1, 2, 0]]
    area = 0.5 * np.linalg.norm(np.cross(c[:, 1] - c[:, 0], c[:, 2] - c[:, 0]), axis=-1).sum()
    expected = 3 * np.sum(w * np.sum((0.1 * edges) ** 2, axis=-1)) / area
    assert e[0] == pytest.approx(expected, rel=1e-9)
    R = voxax.energies.arap_rotations(v, m.vertices, m.faces)
    assert R.shape == (2, m.n_vertices, 3, 3)


# -- one validation path -----------------------------------------------------------------------


def _callers():
    grid = Grid.cube(4)
    key = jax.random.key(0)
    pts = np.zeros((2, 3))
    return {
        "voxelize": lambda v, f: voxax.voxelize(v, f, grid),
        "voxelize_corner_gradients": lambda v, f: voxax.voxelize_corner_gradients(v, f, grid, np.ones(grid.shape)),
        "voxelize_mc": lambda v, f: voxax.voxelize_mc(v, f, grid, Box(0.5), key),
        "voxelize_mc_tangent": lambda v, f: voxax.voxelize_mc_tangent(v, f, grid, Box(0.5), key, np.zeros_like(v)),
        "winding_number": lambda v, f: voxax.winding_number(v, f, pts),
        "reference.voxelize": lambda v, f: reference.voxelize(v, f, grid),
        "point_sampled": lambda v, f: voxax.baselines.point_sampled(v, f, grid),
        "reference.signed_volume": lambda v, f: reference.signed_volume(v, f),
        "as_arrays": lambda v, f: voxax.io.as_arrays((v, f)),
        "Mesh": lambda v, f: Mesh(v, f),
        "resolve_self_intersections": lambda v, f: voxax.apps.resolve_self_intersections((v, f), progress=False),
        "silhouette_polygons": lambda v, f: voxax.fabricate.silhouette_polygons((v, f)),
    }


@pytest.mark.parametrize("name", sorted(_callers()))
def test_the_same_mistake_gives_the_same_message(name):
    fn = _callers()[name]
    short = {"point_sampled": "baselines.point_sampled", "as_arrays": "io.as_arrays",
             "resolve_self_intersections": "apps.resolve_self_intersections",
             "silhouette_polygons": "fabricate.silhouette_polygons"}.get(name, name)
    short = re.escape(f"voxax.{short}")
    m = data.cube()
    with pytest.raises(ValueError, match=rf"^{short}: face indices out of range: they must lie in \[0, 8\), got \[0, 8\]$"):
        fn(m.vertices, np.where(m.faces == 7, 8, m.faces))
    with pytest.raises(TypeError, match=rf"^{short}: `faces` must be an integer array, got float64$"):
        fn(m.vertices, m.faces.astype(np.float64))
    with pytest.raises(ValueError, match=rf"^{short}: `faces` of shape \(12, 2\) do not match the vertices"):
        fn(m.vertices, m.faces[:, :2])
    if name not in ("Mesh", "as_arrays"):  # these hold any coordinates
        bad = m.vertices.copy()
        bad[3, 1] = np.nan
        with pytest.raises(ValueError, match=rf"^{short}: `vertices` contain NaN or Inf$"):
            fn(bad, m.faces)


def test_key_and_kernel_messages():
    square = SQUARE
    with pytest.raises(TypeError, match="^voxax.voxelize_mc: `key` must be an int or a JAX PRNG key"):
        voxax.voxelize_mc(square, GRID2, Box(1.0), 0.5)
    # an int key is jax.random.key(int)
    np.testing.assert_array_equal(voxax.voxelize_mc(square, GRID2, Box(1.0), 3, samples=4),
                                  voxax.voxelize_mc(square, GRID2, Box(1.0), jax.random.key(3), samples=4))
    with pytest.raises(TypeError, match="^voxax.voxelize_mc: `kernel` must implement the voxax.Kernel protocol"):
        voxax.voxelize_mc(square, GRID2, "box", jax.random.key(0))
    with pytest.raises(ValueError, match="^voxax.voxelize_mc: `samples` must be at least 1, got 0$"):
        voxax.voxelize_mc(square, GRID2, Box(1.0), jax.random.key(0), samples=0)
    with pytest.raises(TypeError, match="^voxax.voxelize_mc: `kernel` must be hashable"):
        voxax.voxelize_mc(square, GRID2, _Unhashable(), jax.random.key(0))


# -- user-defined kernels ----------------------------------------------------------------------


@dataclasses.dataclass(frozen=True)
class Epanechnikov:
    """Separable Epanechnikov kernel, `radius` voxels on every axis (no `sample` method)."""

    radius: float = 1.5

    @property
    def support(self):
        return self.radius

    def weight(self, t):
        u = t / self.radius
        return jnp.prod(jnp.where(jnp.abs(u) <= 1, 0.75 * (1 - u * u) / self.radius, 0.0), axis=-1)


@dataclasses.dataclass(frozen=True)
class AnisotropicBox:
    """A box `2 * half[a]` voxels wide along axis a (no `sample` method)."""

    half: tuple = (1.5, 0.5)

    @property
    def support(self):
        return self.half

    def weight(self, t):
        half = jnp.asarray(self.half, t.dtype)
        inside = jnp.all(jnp.abs(t) <= half, axis=-1)
        return jnp.where(inside, 1.0 / float(np.prod([2 * h for h in self.half])), 0.0).astype(t.dtype)


class _Unhashable:
    support = 1.0
    __hash__ = None

    def weight(self, t):
        return jnp.ones(t.shape[:-1], t.dtype)


def _epanechnikov_cdf(u):
    u = np.clip(u, -1.0, 1.0)
    return 0.5 + 0.75 * u - 0.25 * u**3


def test_user_epanechnikov_kernel_matches_its_closed_form_on_a_box():
    """For an axis-aligned rectangle and a separable kernel, W is a product of 1D kernel
    masses: `prod_a [F((hi_a - c_a) / (r h_a)) - F((lo_a - c_a) / (r h_a))]` with the
    Epanechnikov CDF F (an independent, exact oracle)."""
    kernel = Epanechnikov(1.5)
    assert isinstance(kernel, voxax.Kernel)
    W = np.asarray(voxax.voxelize_mc(SQUARE, GRID2, kernel, jax.random.key(5), samples=1024))
    c = GRID2.centers()
    lo, hi = SQUARE.bounds
    r = kernel.radius * np.asarray(GRID2.spacing)
    exact = np.prod(_epanechnikov_cdf((hi - c) / r) - _epanechnikov_cdf((lo - c) / r), axis=-1)
    err = np.abs(W - exact)
    assert err.max() < 0.02, err.max()  # measured 0.008-0.010 over seeds
    assert np.abs(exact).max() == pytest.approx(1.0) and np.count_nonzero((exact > 0.05) & (exact < 0.95)) > 20
    # The gradient (surface samples weighted by the kernel) against finite differences of
    # the closed form for moving the right edge: dW/dx_hi = k1((hi_x - c_x)) * mass_y.
    right = np.isclose(SQUARE.vertices[:, 0], hi[0])
    g = np.random.default_rng(6).normal(size=GRID2.shape)

    def loss(v):
        return jnp.sum(g * voxax.voxelize_mc(v, SQUARE.faces, GRID2, kernel, jax.random.key(5), samples=1, surface_samples=128))

    dv = np.asarray(jax.grad(loss)(jnp.asarray(SQUARE.vertices)))
    ux = (hi[0] - c[..., 0]) / r[0]
    k1 = np.where(np.abs(ux) <= 1, 0.75 * (1 - ux**2), 0.0) / r[0]
    mass_y = _epanechnikov_cdf((hi[1] - c[..., 1]) / r[1]) - _epanechnikov_cdf((lo[1] - c[..., 1]) / r[1])
    expected = float(np.sum(g * k1 * mass_y))
    assert dv[right, 0].sum() == pytest.approx(expected, rel=0.01)  # measured within 0.3%


def test_user_anisotropic_box_matches_the_exact_box_composition():
    """A box 3 voxels wide in x and 1 in y, centred on voxel centres, averages the exact
    one-voxel voxelization over the 3 voxels along x: `(W[i-1] + W[i] + W[i+1]) / 3` (the
    shape keeps away from the grid border, so the zero padding is exact)."""
    kernel = AnisotropicBox((1.5, 0.5))
    star = data.star_polyline(n_points=5, outer=0.45, inner=0.25)
    grid = Grid((-0.8, -0.7), (0.8, 0.75), (12, 11))
    W1 = np.asarray(voxax.voxelize(star, grid))
    padded = np.pad(W1, ((1, 1), (0, 0)))
    exact = (padded[:-2] + padded[1:-1] + padded[2:]) / 3
    W = np.asarray(voxax.voxelize_mc(star, grid, kernel, jax.random.key(7), samples=1024))
    err = np.abs(W - exact)
    assert err.max() < 0.02, err.max()  # measured 0.006-0.008 over seeds
    # The isotropic box 3 voxels wide is far off (0.24): the test tells them apart.
    W_iso = np.asarray(voxax.voxelize_mc(star, grid, Box(1.5), jax.random.key(7), samples=256))
    assert np.abs(W_iso - exact).max() > 0.1
    # Gradient: the same composition of exact one-voxel gradients.
    g = np.random.default_rng(8).normal(size=grid.shape)
    gp = np.pad(g, ((1, 1), (0, 0)))
    g_spread = (gp[:-2] + gp[1:-1] + gp[2:]) / 3  # the adjoint of the x-average
    exact_dv = reference.voxelize_backward(star, grid, g_spread)
    dv = jax.grad(
        lambda v: jnp.sum(g * voxax.voxelize_mc(v, star.faces, grid, kernel, jax.random.key(7), samples=1, surface_samples=256))
    )(jnp.asarray(star.vertices))
    scale = np.abs(exact_dv).max()
    assert np.abs(np.asarray(dv) - exact_dv).max() < 0.02 * scale  # measured 0.002-0.0035


# -- value semantics ----------------------------------------------------------------------------


def _roundtrips(obj):
    for other in (pickle.loads(pickle.dumps(obj)), copy.deepcopy(obj), copy.copy(obj)):
        assert type(other) is type(obj)
        assert other == obj
        assert not (other != obj)


def test_value_types_pickle_deepcopy_and_compare_equal():
    m = data.overlapping_cubes()
    for obj in (
        m,
        data.polygon_square(),
        Grid.cube(8),
        Grid((0, 0), (1, 2), (3, 4)),
        Box(1.5),
        Gaussian(0.7, truncate=2.5),
        Epanechnikov(2.0),
        AnisotropicBox((1.0, 2.0)),
        voxax.StopRules(max_steps=10, min_step=1e-3),
    ):
        _roundtrips(obj)
    assert Mesh(m.vertices, m.faces) != m.translated((1e-9, 0, 0))


def test_minimize_result_round_trips():
    r = voxax.minimize(lambda y, a: jnp.sum((y - 1.0) ** 2), jnp.zeros((3, 3)), solver="sgd",
                       stop=voxax.StopRules(max_steps=3), progress=False)
    _roundtrips(r)
    other = dataclasses.replace(r, y=r.y + 1e-12)
    assert other != r


def test_mesh_trimesh_round_trip():
    m = data.torus(n_major=10, n_minor=5)
    t = m.to_trimesh()
    np.testing.assert_array_equal(t.vertices, m.vertices)
    np.testing.assert_array_equal(t.faces, m.faces)
    assert Mesh.from_trimesh(t) == m
    assert t.volume == pytest.approx(m.signed_volume(), rel=1e-12)


def _filled(cls, i):
    """An instance of a report dataclass with a value of the right kind in every field."""
    values = {
        "np.ndarray": np.arange(6.0).reshape(2, 3) + i,
        "Mapping[str, np.ndarray]": {"energy": np.arange(3.0) + i, "max_w": np.array([1.5, np.nan])},
        "int": 3 + i,
        "float": 0.25 + i,
        "str": "max_steps",
        "bool": True,
    }
    special = {"centre": np.arange(3.0) + i}  # reports check that centres are 3-vectors and histories 1D
    return cls(**{f.name: special.get(f.name, np.arange(4.0) + i if f.name.endswith("_history") else values[f.type])
                  for f in dataclasses.fields(cls)})


@pytest.fixture(scope="module")
def reports(tmp_path_factory):
    _, rep_i = voxax.apps.resolve_self_intersections(data.overlapping_cubes(), resolution=8, max_steps=2, progress=False)
    templates = voxax.fabricate.bandsaw_templates(data.cube(0.8), tmp_path_factory.mktemp("saw"))
    rep_b = _filled(voxax.apps.BandsawReport, 1)
    rep_t = _filled(voxax.apps.TilingReport, 2)
    return rep_i, rep_b, rep_t, templates


def test_reports_and_templates_round_trip(reports):
    for obj in reports:
        _roundtrips(obj)
    assert reports[1] != _filled(voxax.apps.BandsawReport, 2)
    assert reports[1] != reports[2]
