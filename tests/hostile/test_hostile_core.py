"""Hostile inputs to the core's public entry points (the voxelizer, grids and meshes, io,
metrics, the applications), each case in its own process (see `_hostile_driver`)."""

from __future__ import annotations

from _table import table

# (system, label, code, exception type, words its message contains). `jit` in the label:
# the error comes from the kernel, through XLA.
CASES = [
    # the core voxelizer
    ("voxelize", "bool vertices", "voxax.voxelize(V > 0, F, G)", "TypeError", "`vertices` must be float"),
    ("voxelize", "complex vertices", "voxax.voxelize(V + 0j, F, G)", "TypeError", "complex128"),
    ("voxelize", "NaN vertices", "voxax.voxelize(VNAN, F, G)", "ValueError", "NaN or Inf"),
    ("voxelize", "1e80 vertices", "voxax.voxelize(V * 1e80, F, G)", "ValueError", "1e75"),
    ("voxelize", "faces past the vertices", "voxax.voxelize(V, F + len(V), G)", "ValueError", "out of range"),
    ("voxelize", "float faces", "voxax.voxelize(V, F * 1.0, G)", "TypeError", "integer array"),
    ("voxelize", "2D grid for 3D mesh", "voxax.voxelize(V, F, voxax.Grid.cube(4, dim=2))", "ValueError", "2D grid"),
    ("voxelize", "no grid", "voxax.voxelize(V, F)", "TypeError", "missing `grid`"),
    ("voxelize", "grid first", "voxax.voxelize(G, BALL)", "TypeError", "the mesh comes first"),
    ("voxelize", "a path", "voxax.voxelize('bunny.obj', G)", "TypeError", "voxax.io.load"),
    ("voxelize", "a trimesh.Scene", "import trimesh; voxax.voxelize(trimesh.Scene(), G)", "TypeError", "dump"),
    ("voxelize", "grid beyond memory", "voxax.voxelize(V, F, voxax.Grid.cube(60000))", "MemoryError", "GiB"),
    ("voxelize", "jit NaN vertices", "jax.jit(lambda v: voxax.voxelize(v, F, G))(VNAN).block_until_ready()",
     "JaxRuntimeError", "NaN or Inf"),
    ("voxelize", "jit int64 faces beyond int32",
     "jax.jit(lambda f: voxax.voxelize(V, f, G))(F.astype(np.int64) + 2**32).block_until_ready()",
     "JaxRuntimeError", "out of range"),
    ("voxelize", "sharded int64 faces beyond int32",
     "m = jax.sharding.Mesh(np.array(jax.devices()), ('x',));"
     "voxax.voxelize_sharded(V, F.astype(np.int64) + 2**32, G, m, 'x')", "ValueError", "out of range"),
    ("voxelize", "export with symbolic counts",
     "from jax import export;"
     "export.export(jax.jit(lambda v: voxax.voxelize(v, F, G)), disabled_checks=voxax.export_safety_checks())"
     "(jax.ShapeDtypeStruct(export.symbolic_shape('n, 3'), jnp.float64))", "ValueError", "symbolic shapes"),
    ("voxelize", "Monte Carlo float key", "voxax.voxelize_mc(BALL, G, voxax.Box(0.5), 0.5)", "TypeError", "`key`"),
    ("voxelize", "Monte Carlo zero samples", "voxax.voxelize_mc(BALL, G, voxax.Box(0.5), 0, samples=0)",
     "ValueError", "`samples`"),
    ("voxelize", "box filter factor 0", "voxax.box_filter(np.ones((4, 4, 4)), 0)", "ValueError", "factor"),
    ("grid", "float shape", "voxax.Grid((0, 0, 0), (1, 1, 1), (4.5, 4, 4))", "TypeError", "`shape`"),
    ("grid", "inverted box", "voxax.Grid((0, 0, 0), (-1, 1, 1), (4, 4, 4))", "ValueError", "upper > lower"),
    ("grid", "around NaN", "voxax.Grid.around(VNAN, 8)", "ValueError", "NaN"),
    ("mesh", "NaN and faces past", "voxax.Mesh(V, F + 100)", "ValueError", "out of range"),
    # io
    ("io", "save NaN vertices", "voxax.io.save((VNAN, F), 'x.ply')", "ValueError", "NaN or Inf"),
    ("io", "load a missing file", "voxax.io.load('missing.ply')", "FileNotFoundError", "no such file"),
    ("io", "load garbage", "open('g.ply', 'wb').write(b'ply\\nnot a mesh\\x00'); voxax.io.load('g.ply')",
     "ValueError", "cannot read"),
    ("io", "normalize to zero", "voxax.io.normalize(BALL, 0.0)", "ValueError", "max_abs"),
    # metrics
    ("metrics", "chamfer with n = 0", "voxax.metrics.chamfer(BALL, BALL, n=0)", "ValueError", "`n`"),
    ("metrics", "f-score with n = 0", "voxax.metrics.f_score(BALL, BALL, 0.1, n=0)", "ValueError", "`n`"),
    ("metrics", "sample a NaN mesh", "voxax.metrics.sample_surface((VNAN, F), 10)", "ValueError", "NaN"),
    ("metrics", "quality of a NaN mesh", "voxax.metrics.triangle_quality((VNAN, F))", "ValueError", "NaN"),
    ("metrics", "hausdorff of a NaN mesh", "voxax.metrics.hausdorff((VNAN, F), BALL)", "ValueError", "NaN"),
    ("metrics", "chamfer bool cloud", "voxax.metrics.chamfer(P > 0, BALL)", "TypeError", "float point cloud"),
    ("metrics", "sample with a float n", "voxax.metrics.sample_surface(BALL, 2.5)", "TypeError", "`n`"),
    ("metrics", "both key and seed", "voxax.metrics.sample_surface(BALL, 5, key=1, seed=1)", "TypeError", "not both"),
    # the applications
    ("apps", "inside-out mesh", "voxax.apps.optimize_for_bandsaw(V, F[:, ::-1], resolution=8, progress=False)",
     "ValueError", "inside out"),
    ("apps", "resolution 0", "voxax.apps.resolve_self_intersections(BALL, resolution=0, progress=False)", "ValueError",
     "resolution"),
    ("apps", "2D mesh", "voxax.apps.optimize_for_bandsaw(voxax.data.polygon_square(), progress=False)",
     "ValueError", "3D"),
    ("apps", "tiling with a float key", "voxax.apps.optimize_tiling(BALL, instances=2, resolution=6, key=0.5)",
     "TypeError", "`key`"),
    ("fabricate", "cut solid of NaN", "voxax.fabricate.cut_solid((VNAN, F))", "ValueError", "NaN"),
]


outcomes, test_hostile_input = table(CASES)
