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
    ("voxelize", "sparse NaN capacity estimate", "voxax.sparse_capacity(VNAN, F, G)", "ValueError", "NaN or Inf"),
    ("voxelize", "sparse grid and energies against the dense ones (oracle)",
     "sg = voxax.voxelize_sparse(V, F, G); W = np.asarray(voxax.voxelize(V, F, G));"
     "assert isinstance(sg, voxax.SparseGrid) and np.allclose(sg.to_dense(), W);"
     "assert np.isclose(voxax.energies.sparse_volume(sg), voxax.energies.volume(W, G));"
     "assert np.allclose(voxax.energies.sparse_column_sums(sg, 0), W.sum(0));"
     "assert np.isclose(voxax.energies.sparse_self_intersection(sg), voxax.energies.self_intersection(W));"
     "assert np.allclose(voxax.energies.sparse_silhouette_z(sg), voxax.energies.silhouettes(W)[2]);"
     "c = voxax.sparse_capacity(V, F, G); assert 1 <= c[0] <= G.size and 1 <= c[1] <= G.size, c", None, ""),
    ("voxelize", "sparse silhouette with w = 0", "voxax.energies.sparse_silhouette_z(voxax.voxelize_sparse(V, F, G), 0.0)",
     "ValueError", "`w`"),
    ("voxelize", "sparse self-intersection with a NaN eps",
     "voxax.energies.sparse_self_intersection(voxax.voxelize_sparse(V, F, G), float('nan'))", "ValueError", "`eps`"),
    ("voxelize", "sparse silhouette with a traced w = 0",
     "sg = voxax.voxelize_sparse(V, F, G);"
     "jax.jit(lambda w: voxax.energies.sparse_silhouette_z(sg, w))(0.0).block_until_ready()", "JaxRuntimeError",
     "voxax.energies.sparse_silhouette_z: `w` must be > 0"),
    ("voxelize", "sparse self-intersection with a traced NaN eps",
     "sg = voxax.voxelize_sparse(V, F, G);"
     "jax.jit(lambda e: voxax.energies.sparse_self_intersection(sg, e))(np.nan).block_until_ready()",
     "JaxRuntimeError", "voxax.energies.sparse_self_intersection: `eps` must be finite"),
    ("voxelize", "slab_grids count 0", "voxax.slab_grids(G, 0)", "ValueError", "voxax.slab_grids: `count`"),
    ("voxelize", "slab_grids count 4 of 6 cells", "voxax.slab_grids(G, 4)", "ValueError", "`count` must divide"),
    ("voxelize", "slab_grids of three (oracle)",
     "s = voxax.slab_grids(G, 3); assert [g.shape for g in s] == [(2, 6, 6)] * 3 and s[0].lower == G.lower", None, ""),
    ("voxelize", "voxelize_slab outside shard_map", "voxax.voxelize_slab(V, F, G)", "ValueError", "shard_map"),
    ("voxelize", "corner gradients with a cotangent of another shape",
     "voxax.voxelize_corner_gradients(V, F, G, np.ones((2, 2)))", "ValueError", "`cotangent`"),
    ("voxelize", "corner gradients add up to the vertex gradient (oracle)",
     "cg = np.asarray(voxax.voxelize_corner_gradients(V, F, G, np.ones(G.shape))); acc = np.zeros_like(V);"
     "np.add.at(acc, F, cg); g = jax.grad(lambda v: voxax.voxelize(v, F, G).sum())(jnp.asarray(V));"
     "assert np.allclose(acc, g, atol=1e-12)", None, ""),
    ("voxelize", "Monte Carlo tangent with 0 surface samples",
     "voxax.voxelize_mc_tangent(V, F, G, voxax.Gaussian(0.5), 0, np.zeros_like(V), surface_samples=0)", "ValueError",
     "`surface_samples`"),
    ("voxelize", "Monte Carlo tangent of a zero tangent (oracle)",
     "k = voxax.Gaussian(0.5); assert isinstance(k, voxax.Kernel);"
     "t = voxax.voxelize_mc_tangent(V, F, G, k, 0, np.zeros_like(V)); assert np.allclose(t, 0) and t.shape == G.shape",
     None, ""),
    ("voxelize", "a negative Gaussian width", "voxax.Gaussian(-1.0)", "ValueError", "sigma"),
    ("voxelize", "use_host_callback('yes')", "voxax.use_host_callback('yes')", "TypeError", "`enabled`"),
    ("voxelize", "the host callback gives the same grid (oracle)",
     "f = jax.jit(lambda v: voxax.voxelize(v, F, G)); a = np.asarray(f(V)); voxax.use_host_callback(True);"
     "b = np.asarray(jax.jit(lambda v: voxax.voxelize(v, F, G) + 0)(V)); voxax.use_host_callback(False);"
     "assert np.array_equal(a, b)", None, ""),
    # optimizers and configuration
    ("optimize", "minimize a quadratic (oracle)",
     "r = voxax.minimize(lambda y, a: jnp.sum((y - 1.0) ** 2), jnp.zeros(3), learning_rate=0.1, progress=False,"
     " stop=voxax.StopRules(max_steps=400)); assert isinstance(r, voxax.MinimizeResult);"
     "assert r.stop_reason == voxax.StopReason.CONVERGED and np.allclose(r.y, 1.0, atol=1e-3), r", None, ""),
    ("optimize", "StopRules max_steps 1.5", "voxax.StopRules(max_steps=1.5)", "TypeError", "`max_steps`"),
    ("optimize", "StopRules min_step NaN", "voxax.StopRules(min_step=np.nan)", "ValueError", "`min_step`"),
    ("optimize", "StopRules patience 0", "voxax.StopRules(patience=0)", "ValueError", "`patience`"),
    ("optimize", "minimize of a number", "voxax.minimize(3, jnp.zeros(2))", "TypeError", "`fn`"),
    ("optimize", "least_squares of a linear residual (oracle)",
     "r = voxax.least_squares(lambda y, a: 2.0 * y - 3.0, jnp.zeros(3)); assert isinstance(r, voxax.LeastSquaresResult);"
     "assert r.converged and np.allclose(r.value, 1.5), r", None, ""),
    ("optimize", "least_squares rtol -1", "voxax.least_squares(lambda y, a: y, jnp.zeros(2), rtol=-1.0)", "ValueError",
     "`rtol`"),
    ("optimize", "least_squares from NaN", "voxax.least_squares(lambda y, a: y, jnp.array([np.nan, 0.0]))",
     "ValueError", "`y0`"),
    ("optimize", "least_squares of a number", "voxax.least_squares(3.0, jnp.zeros(2))", "TypeError", "`residual_fn`"),
    ("config", "show_config to a number", "voxax.show_config(3)", "TypeError", "`file`"),
    ("config", "show_config and the kernel targets (oracle)",
     "import io; b = io.StringIO(); voxax.show_config(b); assert 'kernels' in b.getvalue();"
     "t = voxax.ffi_targets(); assert {'voxax_forward', 'voxax_finite_check'} <= set(t)", None, ""),
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
    ("apps", "tiling with 3 counts for 2 meshes", "voxax.apps.optimize_tiling([BALL, BALL], instances=[1, 2, 3])",
     "ValueError", "voxax.apps.optimize_tiling: `instances`"),
    ("apps", "tiling with a float key", "voxax.apps.optimize_tiling(BALL, instances=2, resolution=6, key=0.5)",
     "TypeError", "`key`"),
    ("apps", "rotation_matrices of 2 angles", "voxax.apps.rotation_matrices(jnp.zeros(2))", "ValueError", "`angles`"),
    ("apps", "rotation_matrices of NaN", "voxax.apps.rotation_matrices(np.array([np.nan, 0, 0]))", "ValueError",
     "NaN"),
    ("apps", "rotation_matrices are rotations (oracle)",
     "R = np.asarray(voxax.apps.rotation_matrices(jnp.array([[0.3, -0.2, 1.1], [0.0, 0.0, 0.0]])));"
     "assert np.allclose(R @ np.swapaxes(R, -1, -2), np.eye(3)) and np.allclose(np.linalg.det(R), 1);"
     "assert np.allclose(R[1], np.eye(3))", None, ""),
    ("apps", "molding along axis 3", "voxax.apps.optimize_for_molding(BALL, 3, resolution=8, progress=False)",
     "ValueError", "`axis`"),
    ("apps", "implicit with steps -1",
     "voxax.apps.optimize_implicit(lambda p, x: voxax.fields.sphere(x, p), 0.5, BALL, G, steps=-1)", "ValueError",
     "`steps`"),
    ("fabricate", "silhouette along axis 5", "voxax.fabricate.silhouette_polygons(BALL, 5)", "ValueError", "`axis`"),
    ("fabricate", "silhouette of a grid with a NaN threshold",
     "voxax.fabricate.silhouette_polygons(np.zeros((4, 4, 4)), 2, grid=voxax.Grid.cube(4), threshold=float('nan'))",
     "ValueError", "`threshold`"),
    ("fabricate", "a unit cube's silhouette (oracle)",
     "p = voxax.fabricate.silhouette_polygons(voxax.data.cube(1.0), 2); assert len(p) == 1;"
     "x, y = p[0][:, 0], p[0][:, 1]; a = 0.5 * (x @ np.roll(y, -1) - y @ np.roll(x, -1)); assert np.isclose(abs(a), 1.0), a",
     None, ""),
    ("fabricate", "write_svg of NaN polygons", "voxax.fabricate.write_svg([np.array([[0, 0], [1, 0], [np.nan, 1]])], 'x.svg')",
     "ValueError", "`polygons`"),
    ("fabricate", "write_svg with size 0", "voxax.fabricate.write_svg([np.array([[0, 0], [1, 0], [0, 1.0]])], 'x.svg', size_mm=0)",
     "ValueError", "`size_mm`"),
    ("fabricate", "bandsaw templates with size -1", "voxax.fabricate.bandsaw_templates(BALL, 'bt', size_mm=-1)",
     "ValueError", "`size_mm`"),
    ("fabricate", "bandsaw templates of a cube waste nothing (oracle)",
     "t = voxax.fabricate.bandsaw_templates(voxax.data.cube(1.0), 'bt'); assert isinstance(t, voxax.fabricate.BandsawTemplates);"
     "assert abs(t.waste_volume) < 1e-6 and all(open(p).read().startswith('<') for p in t.svg_paths), t.waste_volume",
     None, ""),
    # curves, baselines and the reference implementation
    ("curves", "circle of radius -1", "voxax.curves.circle(np.zeros(2), -1.0)", "ValueError", "`radius`"),
    ("curves", "circle at NaN", "voxax.curves.circle(np.array([np.nan, 0.0]), 1.0)", "ValueError", "`center`"),
    ("curves", "a circle's area (oracle)",
     "c = voxax.curves.circle(np.zeros(2), 0.8, 64); assert isinstance(c, voxax.curves.Curve); g = voxax.Grid.cube(16, dim=2);"
     "a = float(voxax.voxelize(*c, g).sum()) * g.voxel_volume; assert np.isclose(a, 32 * 0.64 * np.sin(2 * np.pi / 64)), a;"
     "assert np.allclose(voxax.curves.circle_point(jnp.array([1.0, 2.0, 3.0]), 0.25), [1.0, 5.0])", None, ""),
    ("curves", "circle_point of 2 parameters", "voxax.curves.circle_point(np.zeros(2), 0.5)", "ValueError", "`params`"),
    ("curves", "bezier_closed of NaN", "voxax.curves.bezier_closed(np.full((6, 2), np.nan))", "ValueError",
     "`control_points`"),
    ("curves", "bezier at a string", "voxax.curves.bezier_point(np.zeros((3, 2)), 'a')", "TypeError", "`t`"),
    ("curves", "bezier through its anchors (oracle)",
     "P = np.array([[0, 0], [1, 0], [2, 1], [2, 2], [1, 3], [0, 2.0]]);"
     "assert np.allclose(voxax.curves.bezier_point(P, jnp.array([0.0, 0.5])), P[[0, 3]]);"
     "assert np.allclose(np.asarray(voxax.curves.bezier_closed(P, 4).vertices)[[0, 4]], P[[0, 3]])", None, ""),
    ("curves", "polyline of one segment", "voxax.curves.polyline(voxax.curves.circle_point, jnp.array([0, 0, 1.0]), 1)",
     "ValueError", "`n`"),
    ("curves", "Monte Carlo curve on a 3D grid",
     "voxax.curves.voxelize_curve_mc(voxax.curves.circle_point, jnp.array([0, 0, 0.5]), G, voxax.Gaussian(0.5), 0)",
     "ValueError", "2D"),
    ("baselines", "interpolate at NaN", "voxax.baselines.interpolate(np.zeros((4, 4, 4)), voxax.Grid.cube(4), [[np.nan, 0, 0]])",
     "ValueError", "`points`"),
    ("baselines", "interpolate at the cell centres (oracle)",
     "g = voxax.Grid.cube(4); W = np.random.default_rng(0).random(g.shape);"
     "assert np.allclose(voxax.baselines.interpolate(W, g, g.centers()), W)", None, ""),
    ("baselines", "point sampling with supersample 0", "voxax.baselines.point_sampled(V, F, G, supersample=0)",
     "ValueError", "`supersample`"),
    ("reference", "winding_number_ray at NaN", "voxax.reference.winding_number_ray(V, F, [[np.nan, 0, 0]])",
     "ValueError", "`points`"),
    ("reference", "the reference against the kernels (oracle)",
     "assert np.allclose(voxax.reference.voxelize(V, F, G), voxax.voxelize(V, F, G), atol=1e-12);"
     "assert np.isclose(voxax.reference.signed_volume(V, F), BALL.signed_volume());"
     "assert np.allclose(voxax.reference.volume_gradient(V, F).sum(0), 0);"
     "g = jax.grad(lambda v: voxax.voxelize(v, F, G).sum())(jnp.asarray(V));"
     "assert np.allclose(voxax.reference.voxelize_backward(V, F, G, np.ones(G.shape)), g, atol=1e-10);"
     "assert voxax.reference.winding_number_ray(V, F, [[0.01, 0.02, 0.0], [0.0, 0.0, 2.0]]).tolist() == [1.0, 0.0]", None, ""),
    # plotting
    ("plot", "a NaN mesh", "voxax.plot.mesh((VNAN, F))", "ValueError", "NaN"),
    ("plot", "slices along axis 5", "voxax.plot.slices(np.zeros((4, 4, 4)), axis=5)", "ValueError",
     "voxax.plot.slices: `axis`"),
    ("plot", "silhouettes by an unknown method", "voxax.plot.silhouettes(np.zeros((4, 4, 4)), method='x')",
     "ValueError", "voxax.plot.silhouettes: `method`"),
    ("plot", "projections of a 2D array", "voxax.plot.projections(np.zeros((2, 2)))", "ValueError", "3D grids"),
    ("plot", "history of nothing", "voxax.plot.history({})", "ValueError", "nothing to plot"),
    ("plot", "history of a string", "voxax.plot.history('energy')", "TypeError",
     "voxax.plot.history: expected a MinimizeResult"),
    ("plot", "history of a 2D array", "voxax.plot.history(np.zeros((2, 2)))", "TypeError",
     "voxax.plot.history: expected a MinimizeResult"),
    ("plot", "history with a series of strings", "voxax.plot.history({'energy': np.array(['a', 'b'])})", "TypeError",
     "voxax.plot.history: `series 'energy'` must be a real 1D array"),
    ("plot", "history with a complex series", "voxax.plot.history({'energy': np.ones(3) + 1j})", "TypeError",
     "`series 'energy'` must be a real 1D array"),
    ("plot", "history with a 2D series", "voxax.plot.history({'energy': np.ones((3, 2))})", "ValueError",
     "series 'energy' must be 1D"),
    ("plot", "slices to a file of an unknown format", "voxax.plot.slices(np.zeros((4, 4, 4)), path='s.qqq')",
     "ValueError", "voxax.plot.slices: `path` must end in one of"),
    ("plot", "a mesh into a missing folder", "voxax.plot.mesh(BALL, path='no/such/folder/m.png')", "FileNotFoundError",
     "voxax.plot.mesh: cannot write"),
    ("plot", "plotly into a missing folder", "voxax.plot.mesh_plotly(BALL, path='no/such/folder/m.html')",
     "FileNotFoundError", "voxax.plot.mesh_plotly: cannot write"),
    ("plot", "projections to a path that is a list", "voxax.plot.projections(np.zeros((4, 4, 4)), path=['p.png'])",
     "TypeError", "voxax.plot.projections: `path` must be a file path"),
    ("plot", "gradient_field of a short gradient", "voxax.plot.gradient_field(V, F, np.zeros((3, 3)))", "ValueError",
     "`gradient`"),
    ("plot", "a NaN mesh in plotly", "voxax.plot.mesh_plotly((VNAN, F))", "ValueError", "NaN"),
    ("plot", "a figure of slices (oracle)",
     "plt = voxax.plot.pyplot(); fig = voxax.plot.slices(np.zeros((4, 4, 4)), count=2, path='s.png');"
     "assert isinstance(fig, plt.Figure) and open('s.png', 'rb').read(4) == b'\\x89PNG'", None, ""),
    ("fabricate", "cut solid of NaN", "voxax.fabricate.cut_solid((VNAN, F))", "ValueError", "NaN"),
    # found by fuzzing: counts, sizes and parameters refused with one line before any work
    ("grid", "a cube of 2.5 cells", "voxax.Grid.cube(2.5)", "TypeError", "voxax.Grid.cube: `n` must be an int"),
    ("grid", "a cube of '3' cells", "voxax.Grid.cube('3')", "TypeError", "voxax.Grid.cube: `n`"),
    ("grid", "a cube of half width None", "voxax.Grid.cube(4, half_width=None)", "TypeError", "`half_width`"),
    ("grid", "a ragged shape", "voxax.Grid((0, 0, 0), (1, 1, 1), ([1], 2, 2))", "TypeError",
     "voxax.Grid: `shape` must be a sequence of integers"),
    ("voxelize", "box_filter by 2^31", "voxax.box_filter(np.zeros((6, 6, 6)), 2**31)", "ValueError",
     "voxax.box_filter: `factor` must be at most"),
    ("voxelize", "box_filter by None", "voxax.box_filter(np.zeros((6, 6, 6)), None)", "TypeError",
     "voxax.box_filter: `factor` must be an int"),
    ("voxelize", "a Gaussian of sigma None", "voxax.Gaussian(None)", "TypeError", "voxax.Gaussian: `sigma`"),
    ("voxelize", "voxelize_mc with 2^40 samples",
     "voxax.voxelize_mc(V, F, G, voxax.Box(), jax.random.key(0), samples=2**40)", "MemoryError",
     "voxax.voxelize_mc: a table of"),
    ("voxelize", "voxelize_mc with the key 2^63", "voxax.voxelize_mc(V, F, G, voxax.Box(), 2**63, samples=4)",
     "ValueError", "voxax.voxelize_mc: `key` must be an int in [0, 2^63)"),
    ("voxelize", "sparse_capacity of no faces (oracle)",
     "c = voxax.sparse_capacity(V, np.zeros((0, 3), int), G); assert len(c) == 2 and min(c) >= 1, c", None, ""),
    ("optimize", "minimize with a NaN learning rate",
     "voxax.minimize(lambda y, a: jnp.sum(y ** 2), jnp.ones(2), learning_rate=float('nan'), progress=False)",
     "ValueError", "voxax.minimize: `learning_rate` must be > 0"),
    ("optimize", "minimize with a negative learning rate (ascent)",
     "voxax.minimize(lambda y, a: jnp.sum(y ** 2), jnp.ones(2), learning_rate=-1.0, progress=False)",
     "ValueError", "voxax.minimize: `learning_rate`"),
    ("optimize", "least_squares with max_steps True", "voxax.least_squares(lambda y, a: y - 1, jnp.zeros(2), max_steps=True)",
     "TypeError", "voxax.least_squares: `max_steps` must be an int, got bool"),
    ("optimize", "least_squares with max_steps 2^63",
     "voxax.least_squares(lambda y, a: y - 1, jnp.zeros(2), max_steps=2**63)", "ValueError",
     "voxax.least_squares: `max_steps` must be at most"),
    ("isosurface", "isosurface_fn with string parameters",
     "voxax.isosurface_fn(lambda p, x: voxax.fields.sphere(x, p), '3', G)", "TypeError",
     "voxax.isosurface_fn: `params` must be a real number or array"),
    ("plot", "slices, 2^31 of them", "voxax.plot.slices(np.zeros((4, 4, 4)), count=2**31)", "ValueError",
     "voxax.plot.slices: `count` must be at most 4"),
    ("plot", "slices, 2.5 of them", "voxax.plot.slices(np.zeros((4, 4, 4)), count=2.5)", "TypeError",
     "voxax.plot.slices: `count` must be an int"),
    ("curves", "a circle of 2^40 points", "voxax.curves.circle(np.zeros(2), 0.5, 2**40)", "MemoryError",
     "voxax.curves.circle: `n` = 1099511627776 needs"),
    ("voxelize", "voxelize_mc of Inf vertices under jit",
     "jax.jit(lambda v: voxax.voxelize_mc(v, F, G, voxax.Box(), jax.random.key(0), samples=4))(jnp.asarray(V) + jnp.inf)"
     ".block_until_ready()", "JaxRuntimeError", "voxax.voxelize_mc: `vertices` must be finite"),
    ("voxelize", "voxelize_mc of NaN vertices under jit",
     "jax.jit(lambda v: voxax.voxelize_mc(v, F, G, voxax.Box(), jax.random.key(0), samples=4))(jnp.asarray(VNAN))"
     ".block_until_ready()", "JaxRuntimeError", "voxax.voxelize_mc: `vertices` must be finite"),
]


outcomes, test_hostile_input = table(CASES)
