"""Hostile inputs to the iso-surface entry points (`voxax.isosurface`, `isosurface_fn`,
`isosurface_topology`, `isosurface_vertices`, eager, streamed and under `jax.jit`), each
case in its own process (see `_hostile_driver`)."""

from __future__ import annotations

from _hostile_driver import SETUP
from _table import table

# S: sphere samples on G; T: its topology; SPH: the sphere as a field function.
SETUP_X = SETUP + """
import warnings
S = np.linalg.norm(G.centers(), axis=-1) - 0.5
T = voxax.isosurface_topology(S, G)
SNAN = S.copy(); SNAN[1, 2, 3] = np.nan
SPH = lambda r, x: jnp.linalg.norm(x, axis=-1) - r
def same_mesh(a, b, scale=1.0):
    np.testing.assert_array_equal(np.asarray(a.faces), np.asarray(b.faces))
    np.testing.assert_allclose(np.asarray(a.vertices), np.asarray(b.vertices) * scale, rtol=0, atol=1e-12)
"""

J = "jax.jit(lambda v: voxax.isosurface(v, G, capacity=400).vertices)"

CASES = [
    # isosurface: the samples
    ("isosurface", "complex values", "voxax.isosurface(S + 0j, G)", "TypeError", "real float"),
    ("isosurface", "string values", "voxax.isosurface(S.astype(str), G)", "TypeError", "real float"),
    ("isosurface", "values of another shape", "voxax.isosurface(S[:5], G)", "ValueError", "match the grid"),
    ("isosurface", "0-d values", "voxax.isosurface(0.5, G)", "ValueError", "match the grid"),
    ("isosurface", "NaN values", "voxax.isosurface(SNAN, G)", "ValueError", "finite"),
    ("isosurface", "Inf values", "voxax.isosurface(np.where(S > 0.6, np.inf, S), G)", "ValueError", "finite"),
    ("isosurface", "NaN values, capacity path", "voxax.isosurface(SNAN, G, capacity=400)", "ValueError", "finite"),
    ("isosurface", "NaN values, close=True", "voxax.isosurface(SNAN, G, close=True)", "ValueError", "finite"),
    ("isosurface", "jit NaN values", f"{J}(SNAN).block_until_ready()", "JaxRuntimeError", "NaN or Inf"),
    ("isosurface", "bool values are occupancies",
     "m = voxax.isosurface(S < 0, G, 0.5, inside='above'); assert isinstance(m, voxax.IsoMesh);"
     "same_mesh(m, voxax.isosurface((S < 0) * 1.0, G, 0.5, inside='above'))",
     None, ""),
    ("isosurface", "subnormal samples give the same mesh",
     "same_mesh(voxax.isosurface(S * 1e-310, G), voxax.isosurface(S, G))", None, ""),
    ("isosurface", "subnormal samples, capacity path",
     "same_mesh(voxax.isosurface(S * 1e-310, G, capacity=400), voxax.isosurface(S, G, capacity=400))", None, ""),
    ("isosurface", "jit subnormal samples",
     f"np.testing.assert_allclose({J}(S * 1e-310), {J}(S), rtol=0, atol=1e-12)", None, ""),
    ("isosurface", "1e300 samples give the same mesh",
     "same_mesh(voxax.isosurface(S * 1e300, G), voxax.isosurface(S, G))", None, ""),
    # isosurface: the parameters
    ("isosurface", "NaN level", "voxax.isosurface(S, G, float('nan'))", "ValueError", "`level`"),
    ("isosurface", "string level", "voxax.isosurface(S, G, 'zero')", "TypeError", "`level`"),
    ("isosurface", "bad inside", "voxax.isosurface(S, G, inside='left')", "ValueError", "`inside`"),
    ("isosurface", "grid not a Grid", "voxax.isosurface(S, (6, 6, 6))", "TypeError", "`grid`"),
    ("isosurface", "capacity 0", "voxax.isosurface(S, G, capacity=0)", "ValueError", "capacit"),
    ("isosurface", "float capacity", "voxax.isosurface(S, G, capacity=100.5)", "TypeError", "`capacity`"),
    ("isosurface", "capacity pair of floats", "voxax.isosurface(S, G, capacity=(100.5, 200))", "TypeError",
     "`capacity`"),
    ("isosurface", "bool capacity", "voxax.isosurface(S, G, capacity=True)", "TypeError", "`capacity`"),
    ("isosurface", "capacity beyond int32", "voxax.isosurface(S, G, capacity=2**31)", "ValueError", "capacit"),
    ("isosurface", "jit capacity too small",
     "jax.jit(lambda v: voxax.isosurface(v, G, capacity=3).vertices)(S).block_until_ready()",
     "JaxRuntimeError", "capacity"),
    ("isosurface", "threads 0", "voxax.isosurface(S, G, threads=0)", "ValueError", "`threads`"),
    ("isosurface", "float threads", "voxax.isosurface(S, G, threads=1.5)", "TypeError", "`threads`"),
    ("isosurface", "close NaN", "voxax.isosurface(S, G, close=float('nan'))", "ValueError", "`close`"),
    ("isosurface", "close on the inside", "voxax.isosurface(S, G, close=-1.0)", "ValueError", "`close`"),
    ("isosurface", "close a string", "voxax.isosurface(S, G, close='yes')", "TypeError", "`close`"),
    ("isosurface", "batched values without capacity", "voxax.isosurface(np.stack([S, S]), G)", "ValueError",
     "capacity"),
    ("isosurface", "vmap without capacity", "jax.vmap(lambda v: voxax.isosurface(v, G).vertices)(np.stack([S, S]))",
     "TypeError", "capacity"),
    # isosurface_topology / isosurface_vertices
    ("isosurface_topology", "complex values", "voxax.isosurface_topology(S + 0j, G)", "TypeError", "real float"),
    ("isosurface_topology", "threads -1", "voxax.isosurface_topology(S, G, threads=-1)", "ValueError", "`threads`"),
    ("isosurface_topology", "NaN values", "voxax.isosurface_topology(SNAN, G)", "ValueError", "finite"),
    ("isosurface_vertices", "topology of a finer grid",
     "voxax.isosurface_vertices(S, voxax.isosurface_topology(np.linalg.norm(voxax.Grid.cube(9).centers(), axis=-1) - 0.5,"
     " voxax.Grid.cube(9)), G)", "ValueError", "made on this grid"),
    ("isosurface_vertices", "topology of a coarser grid",
     "voxax.isosurface_vertices(S, voxax.isosurface_topology(np.linalg.norm(voxax.Grid.cube(5).centers(), axis=-1) - 0.5,"
     " voxax.Grid.cube(5)), G)", "ValueError", "made on this grid"),
    ("isosurface_vertices", "topology made with close",
     "voxax.isosurface_vertices(S, voxax.isosurface_topology(S, G, close=True), G)", "ValueError", "made on this grid"),
    ("isosurface_vertices", "jit topology of another grid",
     "T9 = voxax.isosurface_topology(np.linalg.norm(voxax.Grid.cube(9).centers(), axis=-1) - 0.5, voxax.Grid.cube(9));"
     "jax.jit(lambda v: voxax.isosurface_vertices(v, T9, G))(S).block_until_ready()", "ValueError",
     "made on this grid"),
    ("isosurface_vertices", "int64 edges beyond int32",
     "import dataclasses; voxax.isosurface_vertices(S, dataclasses.replace(T, edges=jnp.asarray(T.edges, jnp.int64) + 2**32), G)",
     "ValueError", "made on this grid"),
    ("isosurface_vertices", "samples equal on a topology edge",
     "voxax.isosurface_vertices(np.zeros_like(S) + 1.0, T, G)", "ValueError", "differ"),
    ("isosurface_vertices", "not an IsoMesh", "voxax.isosurface_vertices(S, (V, F), G)", "TypeError", "IsoMesh"),
    ("isosurface_vertices", "NaN values", "voxax.isosurface_vertices(SNAN, T, G)", "ValueError", "finite"),
    ("isosurface_vertices", "subnormal samples",
     "np.testing.assert_allclose(voxax.isosurface_vertices(S * 1e-310, T, G), T.vertices, rtol=0, atol=1e-12)",
     None, ""),
    # isosurface_fn
    ("isosurface_fn", "chunk -1", "voxax.isosurface_fn(SPH, 0.5, G, chunk=-1)", "ValueError", "`chunk`"),
    ("isosurface_fn", "chunk 0", "voxax.isosurface_fn(SPH, 0.5, G, chunk=0)", "ValueError", "`chunk`"),
    ("isosurface_fn", "float chunk", "voxax.isosurface_fn(SPH, 0.5, G, chunk=100.0)", "TypeError", "`chunk`"),
    ("isosurface_fn", "small chunk gives the same mesh",
     "same_mesh(voxax.isosurface_fn(SPH, 0.5, G, chunk=7), voxax.isosurface(S, G))", None, ""),
    ("isosurface_fn", "a field returning a scalar", "voxax.isosurface_fn(lambda p, x: jnp.sum(x), 0.5, G)",
     "ValueError", "one value per point"),
    ("isosurface_fn", "jit field returning a scalar",
     "jax.jit(lambda r: voxax.isosurface_fn(lambda p, x: jnp.sum(x) - p, r, G, capacity=400).vertices)(0.5)",
     "ValueError", "one value per point"),
    ("isosurface_fn", "a field returning complex", "voxax.isosurface_fn(lambda p, x: SPH(p, x) + 0j, 0.5, G)",
     "TypeError", "real values"),
    ("isosurface_fn", "a field returning NaN", "voxax.isosurface_fn(lambda p, x: SPH(p, x) * jnp.nan, 0.5, G)",
     "ValueError", "finite"),
    ("isosurface_fn", "not callable", "voxax.isosurface_fn(S, 0.5, G)", "TypeError", "`fn`"),
    ("isosurface_fn", "bad rule", "voxax.isosurface_fn(SPH, 0.5, G, rule='exact')", "ValueError", "`rule`"),
    ("isosurface_fn", "NaN lipschitz", "voxax.isosurface_fn(SPH, 0.5, G, lipschitz=float('nan'))", "ValueError",
     "`lipschitz`"),
    ("isosurface_fn", "band of another grid", "voxax.isosurface_fn(SPH, 0.5, G, band=np.zeros((5, 5, 5)))",
     "ValueError", "`band`"),
    ("isosurface_fn", "grid beyond memory", "voxax.isosurface_fn(SPH, 0.5, voxax.Grid.cube(100000))",
     "MemoryError", "GiB"),
    ("isosurface_fn", "jit grid beyond memory",
     "jax.jit(lambda r: voxax.isosurface_fn(SPH, r, voxax.Grid.cube(100000), capacity=10).vertices)(0.5)",
     "MemoryError", "GiB"),
    ("isosurface", "traced bool samples under jit (oracle)",
     "m = jax.jit(lambda s: voxax.isosurface(s, G, 0.5, capacity=(400, 800)))(S > 0); e = voxax.isosurface(S > 0, G, 0.5);"
     "assert int(m.n_faces) == len(e.faces) > 0", None, ""),
]


outcomes, test_hostile_input = table(CASES, SETUP_X)
