"""voxelize_sparse: bit-identical to voxelize, its gradients, capacities, validation."""

import os
import subprocess
import sys
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from conftest import random_star_mesh

import voxax
from voxax import Grid

GRIDS = {
    "odd-offcentre": Grid((-0.9, -0.8, -0.7), (0.8, 0.9, 0.75), (7, 5, 9)),
    "anisotropic": Grid((-0.61, -0.55, -0.83), (0.7, 0.52, 0.66), (11, 4, 6)),
    "cube8": Grid.cube(8),
}


def _mesh(name, rng):
    if name == "star":
        return random_star_mesh(rng, n_theta=7, n_phi=6, center=(0.05, -0.1, 0.08), scale=0.6)
    if name == "partly-outside":  # a box sticking out of every side of the grid
        m = voxax.data.box((-1.3, -0.4, -0.95), (0.35, 1.4, 1.2))
    elif name == "above":  # wholly above the grid: a shadow over part of its columns
        m = voxax.data.box((-0.3, -0.2, 1.5), (0.4, 0.5, 2.0))
    elif name == "on-planes":  # faces on grid planes of cube8
        m = voxax.data.box((-0.5, -0.25, -0.75), (0.5, 0.75, 0.25))
    elif name == "overlapping":
        m = voxax.data.overlapping_cubes()
    elif name == "self-intersecting":
        m = voxax.data.bent_bar()
    else:
        m = voxax.data.get(name)
    return np.asarray(m.vertices, np.float64), np.asarray(m.faces, np.int32)


MESHES = ["star", "partly-outside", "above", "on-planes", "overlapping", "self-intersecting", "with_inverted_component"]


def _bits(x):
    x = np.asarray(x)
    return x.view(np.uint32 if x.dtype == np.float32 else np.uint64)


@pytest.mark.parametrize("dtype", [np.float32, np.float64])
@pytest.mark.parametrize("grid", list(GRIDS))
def test_to_dense_bit_identical(grid, dtype):
    g = GRIDS[grid]
    cap = voxax.sparse_capacity(grid=g)  # one capacity: one compiled kernel per grid
    for mesh in MESHES:
        V, F = _mesh(mesh, np.random.default_rng(3))
        V = V.astype(dtype)
        sg = voxax.voxelize_sparse(V, F, g, capacity=cap)
        W = voxax.voxelize(V, F, g)
        assert sg.values.dtype == W.dtype == dtype
        np.testing.assert_array_equal(_bits(sg.to_dense()), _bits(W), err_msg=mesh)
        n, r = (int(x) for x in sg.counts)
        assert 0 < n + r < g.size
    # The eager default: exactly the rows needed.
    sg = voxax.voxelize_sparse(V, F, g)
    assert sg.capacity == tuple(int(x) for x in sg.counts)
    np.testing.assert_array_equal(_bits(sg.to_dense()), _bits(W))


def test_structure_against_dense():
    """Boundary cells are sorted and unique; runs are disjoint, hold one value, and every
    cell outside them and the boundary cells is zero in the dense grid."""
    V, F = _mesh("star", np.random.default_rng(0))
    g = GRIDS["odd-offcentre"]
    sg = voxax.voxelize_sparse(V, F, g)
    W = np.asarray(voxax.voxelize(V, F, g))
    n, r = (int(x) for x in sg.counts)
    cells = np.asarray(sg.cells[:n])
    key = np.ravel_multi_index(cells.T, g.shape)
    assert np.all(np.diff(key) > 0)
    covered = np.zeros(g.shape, bool)
    covered[tuple(cells.T)] = True
    for (i, j, k0, k1), v in zip(np.asarray(sg.runs[:r]), np.asarray(sg.run_values[:r])):
        assert 0 <= k0 < k1 <= g.shape[2]
        assert not covered[i, j, k0:k1].any()
        covered[i, j, k0:k1] = True
        assert np.all(W[i, j, k0:k1] == v)
        assert abs(v - round(v)) < 1e-9  # whole numbers up to rounding
    assert np.all(W[~covered] == 0)


def test_boundary_cells_hold_every_piece_of_the_surface():
    """The dense tangent (forward-mode derivative) is zero outside the boundary cells, for
    random directions: the runs have derivative zero, as the sparse form assumes."""
    V, F = _mesh("partly-outside", None)
    g = GRIDS["odd-offcentre"]
    sg = voxax.voxelize_sparse(V, F, g)
    n = int(sg.count)
    mask = np.zeros(g.shape, bool)
    mask[tuple(np.asarray(sg.cells[:n]).T)] = True
    t = np.random.default_rng(1).normal(size=V.shape)
    _, dW = jax.jvp(lambda v: voxax.voxelize(v, F, g), (jnp.asarray(V),), (jnp.asarray(t),))
    dW = np.asarray(dW)
    assert np.abs(dW[mask]).max() > 0
    assert np.all(dW[~mask] == 0)


def test_batches_and_vmap():
    rng = np.random.default_rng(5)
    V, F = _mesh("star", rng)
    Vb = np.stack([V, V * 0.8 + 0.05, V[::1] * 1.1 - 0.02])
    g = GRIDS["anisotropic"]
    sg = voxax.voxelize_sparse(Vb, F, g)
    assert sg.batch_shape == (3,)
    np.testing.assert_array_equal(_bits(sg.to_dense()), _bits(voxax.voxelize(Vb, F, g)))
    cap = tuple(int(x) for x in np.asarray(sg.counts).max(axis=0))
    dense_v = jax.vmap(lambda v: voxax.voxelize_sparse(v, F, g, capacity=cap).to_dense())(jnp.asarray(Vb))
    np.testing.assert_array_equal(_bits(dense_v), _bits(voxax.voxelize(Vb, F, g)))
    vol = jax.vmap(lambda v: voxax.voxelize_sparse(v, F, g, capacity=cap).volume())(jnp.asarray(Vb))
    np.testing.assert_allclose(vol, voxax.energies.volume(voxax.voxelize(Vb, F, g), g), rtol=1e-12)


def test_volume_exact_and_its_gradient():
    V, F = _mesh("star", np.random.default_rng(2))
    g = GRIDS["odd-offcentre"]
    m = voxax.Mesh(V, F) if hasattr(voxax, "Mesh") else None
    sg = voxax.voxelize_sparse(V, F, g)
    a, b, c = V[F[:, 0]], V[F[:, 1]], V[F[:, 2]]
    exact = np.einsum("ij,ij->i", a, np.cross(b, c)).sum() / 6
    np.testing.assert_allclose(float(sg.volume()), exact, rtol=1e-12)
    # d volume / d v = sum over faces around v of area * n / 3 = cross products / 6.
    N = np.cross(b - a, c - a) / 6
    want = np.zeros_like(V)
    for k in range(3):
        np.add.at(want, F[:, k], N)
    dense = jax.grad(lambda v: voxax.voxelize(v, F, g).sum() * g.voxel_volume)(jnp.asarray(V))
    sparse = jax.grad(lambda v: voxax.voxelize_sparse(v, F, g, capacity=sg.capacity).volume())(jnp.asarray(V))
    scale = np.abs(dense).max()
    assert np.abs(sparse - dense).max() <= 1e-10 * scale
    assert np.abs(sparse - want).max() <= 1e-10 * scale
    del m


@pytest.mark.parametrize("mesh", ["star", "partly-outside", "self-intersecting", "on-planes"])
def test_sum_of_squares_gradient_equals_dense(mesh):
    V, F = _mesh(mesh, np.random.default_rng(4))
    g = GRIDS["cube8"] if mesh == "on-planes" else GRIDS["anisotropic"]
    cap = voxax.voxelize_sparse(V, F, g).capacity

    def sparse_e(v):
        sg = voxax.voxelize_sparse(v, F, g, capacity=cap)
        length = sg.runs[:, 3] - sg.runs[:, 2]
        return jnp.sum(sg.values**2) + jnp.sum(length * sg.run_values**2)

    dense = jax.grad(lambda v: jnp.sum(voxax.voxelize(v, F, g) ** 2))(jnp.asarray(V))
    sparse = jax.grad(sparse_e)(jnp.asarray(V))
    assert np.abs(dense).max() > 0
    assert np.abs(sparse - dense).max() <= 1e-10 * np.abs(dense).max()
    # Under jit too.
    np.testing.assert_allclose(jax.jit(jax.grad(sparse_e))(jnp.asarray(V)), sparse, rtol=0, atol=1e-13)


def test_overlap_energy_gradient_equals_dense():
    V, F = _mesh("overlapping", None)
    g = Grid.cube(10)
    cap = voxax.voxelize_sparse(V, F, g).capacity
    sparse = jax.grad(
        lambda v: voxax.energies.sparse_self_intersection(voxax.voxelize_sparse(v, F, g, capacity=cap))
    )(jnp.asarray(V))
    dense = jax.grad(lambda v: voxax.energies.self_intersection(voxax.voxelize(v, F, g)))(jnp.asarray(V))
    assert np.abs(dense).max() > 0
    assert np.abs(sparse - dense).max() <= 1e-10 * np.abs(dense).max()


def test_jvp_and_transpose():
    V, F = _mesh("star", np.random.default_rng(6))
    g = GRIDS["odd-offcentre"]
    sg = voxax.voxelize_sparse(V, F, g)
    cap = sg.capacity
    n = int(sg.count)
    t = np.random.default_rng(7).normal(size=V.shape)
    fn = lambda v: voxax.voxelize_sparse(v, F, g, capacity=cap)  # noqa: E731
    out, dsg = jax.jvp(fn, (jnp.asarray(V),), (jnp.asarray(t),))
    _, dW = jax.jvp(lambda v: voxax.voxelize(v, F, g), (jnp.asarray(V),), (jnp.asarray(t),))
    cells = np.asarray(out.cells[:n])
    want = np.asarray(dW)[tuple(cells.T)]
    got = np.asarray(dsg.values[:n])
    assert np.abs(got - want).max() <= 1e-10 * np.abs(want).max()
    assert np.all(np.asarray(dsg.run_values) == 0)
    # <u, J t> == <J^T u, t>: the tangent and the backward are transposes.
    u = np.random.default_rng(8).normal(size=cap[0])
    lhs = float(np.dot(u[:n], got))
    grad = jax.grad(lambda v: jnp.dot(jnp.asarray(u), fn(v).values))(jnp.asarray(V))
    np.testing.assert_allclose(lhs, float(np.sum(np.asarray(grad) * t)), rtol=1e-10)


def test_capacity_overflow_is_an_error():
    V, F = _mesh("star", np.random.default_rng(9))
    g = GRIDS["cube8"]
    need = voxax.voxelize_sparse(V, F, g).capacity
    with pytest.raises(ValueError, match="more than the capacity"):
        voxax.voxelize_sparse(V, F, g, capacity=(need[0] - 1, need[1]))
    f = jax.jit(lambda v: voxax.voxelize_sparse(v, F, g, capacity=(need[0], need[1] - 1)).values)
    with pytest.raises(Exception, match="more than the capacity") as info:
        jax.block_until_ready(f(jnp.asarray(V)))
    assert "pass a larger `capacity`" in str(info.value)
    # Room to spare under jit: padding, the same grid.
    sg = jax.jit(lambda v: voxax.voxelize_sparse(v, F, g, capacity=(need[0] + 5, need[1] + 3)))(jnp.asarray(V))
    assert sg.capacity == (need[0] + 5, need[1] + 3)
    np.testing.assert_array_equal(_bits(sg.to_dense()), _bits(voxax.voxelize(V, F, g)))
    # The default capacity under jit comes from the grid alone.
    sg = jax.jit(lambda v: voxax.voxelize_sparse(v, F, g))(jnp.asarray(V))
    assert sg.capacity == voxax.sparse_capacity(grid=g)
    np.testing.assert_array_equal(_bits(sg.to_dense()), _bits(voxax.voxelize(V, F, g)))


def test_bad_input():
    V, F = _mesh("star", np.random.default_rng(10))
    g = GRIDS["cube8"]
    bad = V.copy()
    bad[3, 1] = np.nan
    with pytest.raises(ValueError, match="NaN|finite"):
        voxax.voxelize_sparse(bad, F, g)
    Fb = F.copy()
    Fb[2, 0] = len(V)
    with pytest.raises(ValueError, match="out of range|index"):
        voxax.voxelize_sparse(V, Fb, g)
    with pytest.raises(TypeError):
        voxax.voxelize_sparse(V.astype(np.int64), F, g)
    with pytest.raises(ValueError, match="3D"):
        voxax.voxelize_sparse(np.zeros((3, 2)), np.array([[0, 1], [1, 2], [2, 0]]), Grid.cube(4, dim=2))
    with pytest.raises(ValueError, match="capacity"):
        voxax.voxelize_sparse(V, F, g, capacity=0)
    with pytest.raises(ValueError, match="capacity"):
        voxax.voxelize_sparse(V, F, g, capacity=(1, 2, 3))
    # Under jit the kernel checks the values.
    f = jax.jit(lambda v: voxax.voxelize_sparse(v, F, g, capacity=100).values)
    with pytest.raises(Exception, match="NaN|finite"):
        jax.block_until_ready(f(jnp.asarray(bad)))


def test_kernel_rejects_hostile_cells():
    """The backward and tangent kernels check the boundary cells they are given."""
    from voxax._voxelize import sparse as _sparse

    V, F = _mesh("star", np.random.default_rng(11))
    g = GRIDS["cube8"]
    sg = voxax.voxelize_sparse(V, F, g)
    v, f = jnp.asarray(V)[None], jnp.asarray(F)[None]
    cells, counts = sg.cells[None], sg.counts[None]
    ct = jnp.ones((1, sg.capacity[0]))
    base = _sparse.backward(v, f, cells, ct, counts, g)
    assert np.isfinite(np.asarray(base)).all()
    swapped = cells.at[0, 0].set(cells[0, 1]).at[0, 1].set(cells[0, 0])
    outside = cells.at[0, 0, 2].set(8)
    for c, n, msg in [
        (swapped, counts, "ascending"),
        (outside, counts, "outside the grid"),
        (cells, counts.at[0, 0].set(sg.capacity[0] + 1), "outside \\[0"),
        (cells, counts.at[0, 0].set(-1), "outside \\[0"),
    ]:
        with pytest.raises(Exception, match=msg):
            jax.block_until_ready(_sparse.backward(v, f, c, ct, n, g))
        tc = jnp.zeros((1, F.shape[0], 3, 3))
        with pytest.raises(Exception, match=msg):
            jax.block_until_ready(_sparse.tangent(v, f, tc, c, n, g))


def test_accessors_against_dense():
    V, F = _mesh("self-intersecting", None)
    g = GRIDS["odd-offcentre"]
    sg = voxax.voxelize_sparse(V, F, g)
    W = np.asarray(voxax.voxelize(V, F, g))
    idx = np.stack(np.meshgrid(*[np.arange(n) for n in g.shape], indexing="ij"), -1).reshape(-1, 3)
    np.testing.assert_array_equal(np.asarray(sg.values_at(idx)).reshape(g.shape), W)
    np.testing.assert_array_equal(np.asarray(jax.jit(sg.values_at)(idx[:17])), W.reshape(-1)[:17])
    np.testing.assert_array_equal(np.asarray(sg.window((1, 2, 3), (6, 5, 8))), W[1:6, 2:5, 3:8])
    np.testing.assert_array_equal(np.asarray(sg.slab(1, 3, axis=2)), W[:, :, 1:3])
    np.testing.assert_array_equal(np.asarray(sg.occupancy(0.5)), W > 0.5)
    n, r = sg.capacity
    assert sg.nbytes == n * (12 + 8) + r * (16 + 8) + 2 * 4
    with pytest.raises(ValueError, match="window"):
        sg.window((0, 0, 0), (8, 5, 9))
    # The FC cells: where the surface has pieces (fc.pieces), all boundary cells.
    if hasattr(voxax.fc, "pieces"):
        pieces = voxax.fc.pieces(V, F, g)
        cell_index = np.unique(np.asarray(getattr(pieces, "cell", getattr(pieces, "index", None))))
        assert np.isin(cell_index, sg.fc_cells()).all()
    iso = sg.isosurface(0.5, (0, 0, 0), g.shape)
    ref = voxax.isosurface(jnp.asarray(W), g, 0.5)
    np.testing.assert_allclose(np.asarray(iso.vertices), np.asarray(ref.vertices), atol=1e-12)


def test_sparse_energies_equal_dense():
    V, F = _mesh("self-intersecting", None)
    g = Grid.cube(12)
    sg = voxax.voxelize_sparse(V, F, g)
    W = voxax.voxelize(V, F, g)
    E = voxax.energies
    np.testing.assert_allclose(E.sparse_self_intersection(sg), E.self_intersection(W), rtol=1e-12)
    assert float(E.sparse_self_intersection(sg)) > 0
    np.testing.assert_allclose(E.sparse_volume(sg), E.volume(W, g), rtol=1e-12)
    for axis in range(3):
        np.testing.assert_allclose(E.sparse_column_sums(sg, axis), W.sum(axis=axis), rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(E.sparse_silhouette_z(sg, 1000.0), E.silhouettes(W, 1000.0)[2], rtol=1e-12,
                               atol=1e-12)


_SUBPROCESS = """
import sys, numpy as np, jax, jax.numpy as jnp
jax.config.update("jax_enable_x64", True)
sys.path.insert(0, {tests!r})
import voxax
from conftest import random_star_mesh
V, F = random_star_mesh(np.random.default_rng(12), n_theta=9, n_phi=7, scale=0.7)
g = voxax.Grid((-0.83, -0.8, -0.77), (0.81, 0.79, 0.84), (13, 11, 40))
sg = voxax.voxelize_sparse(V, F, g)
t = np.random.default_rng(13).normal(size=V.shape)
fn = lambda v: voxax.voxelize_sparse(v, F, g, capacity=sg.capacity)
grad = jax.grad(lambda v: jnp.sum(fn(v).values ** 3))(jnp.asarray(V))
dv = jax.jvp(fn, (jnp.asarray(V),), (jnp.asarray(t),))[1].values
np.savez({path!r}, cells=sg.cells, values=sg.values, runs=sg.runs, run_values=sg.run_values, grad=grad, dv=dv)
"""


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="NPROC sizes XLA's pool on Linux")
def test_deterministic_across_thread_counts(tmp_path):
    """Bit-identical forward, gradient and tangent with one thread (NPROC=1) and with this
    process's pool (see test_gradients.test_deterministic_across_thread_counts)."""
    tests = str(Path(__file__).resolve().parents[1])  # where conftest.py is
    root = str(Path(voxax.__file__).resolve().parent.parent)
    procs = {}
    for nproc in ("1", "3"):
        env = dict(os.environ, NPROC=nproc)
        env.pop("PJRT_NPROC", None)
        env["PYTHONPATH"] = os.pathsep.join([root, tests, env.get("PYTHONPATH", "")])
        path = str(tmp_path / f"n{nproc}.npz")
        code = _SUBPROCESS.format(tests=tests, path=path)
        procs[nproc] = (subprocess.Popen([sys.executable, "-c", code], env=env, stderr=subprocess.PIPE, text=True), path)
    out = {}
    for nproc, (proc, path) in procs.items():
        _, err = proc.communicate(timeout=300)
        assert proc.returncode == 0, err[-2000:]
        with np.load(path) as z:
            out[nproc] = {k: z[k] for k in z.files}
    for k in out["1"]:
        assert np.array_equal(out["1"][k], out["3"][k]), k
