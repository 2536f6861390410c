"""Hostile inputs to the energies, the fields, the bundled data and the sharded / exported
calls, each case in its own process (see `_hostile_driver`)."""

from __future__ import annotations

from _table import table

E, FL, D = "voxax.energies", "voxax.fields", "voxax.data"
W = "np.full((4, 4, 4), 0.5)"
CASES = [
    ("energies", "volume of a full grid on [-1, 1]^3 (oracle)", f"v = float({E}.volume(jnp.ones((6, 6, 6)), G)); assert np.isclose(v, 8.0), v",
     None, ""),
    ("energies", "mellowmax of 1e30 (oracle)", f"m = float({E}.mellowmax(jnp.array([1e30, 1e30]))); assert np.isclose(m, 1e30), m",
     None, ""),
    ("energies", "self_intersection of zeros (oracle)", f"assert float({E}.self_intersection(jnp.zeros((4, 4, 4)))) == 0",
     None, ""),
    ("energies", "height_field_hull axis 2.5", f"{E}.height_field_hull({W}, 2.5)", "TypeError", "`axis`"),
    ("energies", "height_field_hull NaN W", f"{E}.height_field_hull(np.full((2, 2, 2), np.nan))", "ValueError", "`W`"),
    ("energies", "height_field_hull NaN W under jit",
     f"jax.jit({E}.height_field_hull)(jnp.full((2, 2, 2), jnp.nan)).block_until_ready()", "JaxRuntimeError",
     "`W` must be finite"),
    ("energies", "esi_gap Inf W under jit", f"jax.jit({E}.esi_gap)(jnp.full((2, 2, 2), jnp.inf)).block_until_ready()",
     "JaxRuntimeError", "`W` must be finite"),
    ("energies", "height_field_hull under jit and grad (oracle)",
     f"W = jnp.zeros((1, 1, 5)).at[0, 0, 1].set(1.0).at[0, 0, 3].set(1.0);"
     f"h = jax.jit(lambda x: {E}.height_field_hull(x, 2, 1e4))(W); assert np.allclose(h.ravel(), [0, 1, 1, 1, 0], atol=1e-3), h;"
     f"g = jax.grad(lambda x: jax.jit({E}.height_field_hull)(x).sum())(W); assert np.isfinite(np.asarray(g)).all()",
     None, ""),
    ("energies", "objective of no terms", f"{E}.objective({{}})", "ValueError", "`terms`"),
    ("energies", "objective with a NaN weight", f"{E}.objective({{'a': lambda y, a: y}}, weights={{'a': np.nan}})",
     "ValueError", "weights"),
    ("energies", "objective with a term that is not a function", f"{E}.objective({{'a': 1.0}})", "TypeError",
     "`terms`"),
    ("energies", "silhouettes of a NaN grid", f"np.asarray({E}.silhouettes(np.where(np.eye(4)[:, :, None] > 0, np.nan, 0.5))[0])",
     "JaxRuntimeError", "`W` must be finite"),
    ("energies", "bandsaw_cut of an Inf grid", f"float({E}.bandsaw_cut(np.full((3, 3, 3), np.inf)))", "JaxRuntimeError",
     "`W` must be finite"),
    ("energies", "cut_shape of a complex grid", f"{E}.cut_shape(np.zeros((3, 3, 3)) + 0j)", "TypeError", "`W`"),
    ("energies", "interpenetration of grids of two shapes",
     f"{E}.interpenetration(np.zeros((3, 3, 3)), np.zeros((4, 4, 4)))", "ValueError", "`W_a` and `W_b`"),
    ("energies", "tiling with blocks that do not divide", f"{E}.tiling(np.zeros((1, 4, 4, 4)))", "ValueError",
     "voxax.energies.tiling: `W_instances`"),
    ("energies", "the bandsaw, cut shape, overlap and tiling energies of a box (oracle)",
     f"B = np.zeros((6, 6, 6)); B[1:5, 2:4, 1:3] = 1.0; S = np.asarray({E}.cut_shape(B, 1e4));"
     f"assert np.allclose(S, B, atol=1e-3) and float({E}.bandsaw_cut(B, 1e4)) < 1e-6;"
     f"sx, sy, sz = {E}.silhouettes(B, 1e4); assert np.allclose(sz, B.max(2), atol=1e-3);"
     f"assert np.isclose({E}.interpenetration(B, B), B.sum() / B.size);"
     f"assert float({E}.tiling(np.full((1, 3, 3, 3), 1 / 27), blocks=3)) < 1e-20", None, ""),
    ("energies", "arap with rest vertices of another shape", f"{E}.arap(V, V[:-1], F)", "ValueError",
     "voxax.energies.arap: `rest_vertices`"),
    ("energies", "esi_gap axes '2'", f"{E}.esi_gap({W}, '2')", "TypeError", "`axes`"),
    ("energies", "fold_periodic blocks 0", f"{E}.fold_periodic({W}, blocks=0)", "ValueError", "`blocks`"),
    ("energies", "cotangent weights of a sphere (oracle)",
     f"w = np.asarray({E}.cotangent_weights(V, F)); assert np.all(np.isfinite(w)) and w.min() > 0", None, ""),
    ("energies", "arap at rest (oracle)",
     f"e = float({E}.arap(jnp.asarray(V), jnp.asarray(V), F)); assert abs(e) < 1e-12, e;"
     f"r = np.asarray({E}.arap_rotations(V, V, F)); assert np.allclose(r, np.eye(3), atol=1e-9)", None, ""),
    ("fields", "sphere at 1e30 (oracle)",
     f"d = np.asarray({FL}.sphere(np.array([[1e30, 0, 0]]), 1.0)); assert np.isclose(d, 1e30).all(), d", None, ""),
    ("fields", "sphere of complex points", f"{FL}.sphere(np.zeros((2, 3)) + 0j)", "TypeError", "`points`"),
    ("fields", "box of bool points", f"{FL}.box(np.zeros((2, 3), bool))", "TypeError", "`points`"),
    ("fields", "torus of string points", f"{FL}.torus(np.zeros((2, 3)).astype(str))", "TypeError", "`points`"),
    ("fields", "Siren with a float key", f"{FL}.Siren(key=0.5)", "TypeError", "`key`"),
    ("fields", "Siren of depth 0", f"{FL}.Siren(depth=0, key=jax.random.key(0))", "ValueError", "`depth`"),
    ("fields", "deepsdf_loss with a shape index beyond the codes",
     f"m = {FL}.DeepSDF(2, 4, 8, 3, key=jax.random.key(0)); {FL}.deepsdf_loss(m, np.zeros((3, 3)), np.zeros(3), index=7)",
     "ValueError", "`index`"),
    ("fields", "deepsdf_loss with one target short",
     f"m = {FL}.DeepSDF(2, 4, 8, 3, key=jax.random.key(0)); {FL}.deepsdf_loss(m, np.zeros((3, 3)), np.zeros(2))",
     "ValueError", "`sdf`"),
    ("fields", "deepsdf_loss of zero codes on their own targets (oracle)",
     f"m = {FL}.DeepSDF(2, 4, 8, 3, key=jax.random.key(0), code_std=0.0); p = np.zeros((5, 3));"
     f"l = float({FL}.deepsdf_loss(m, p, np.clip(np.asarray(m(p, 1)), -0.1, 0.1), index=1)); assert abs(l) < 1e-12, l",
     None, ""),
    ("fields", "chebyshev degree -1", f"{FL}.chebyshev_polynomial(jnp.zeros(3), -1)", "ValueError", "`degree`"),
    ("fields", "DeepSDF with 0 shapes", f"{FL}.DeepSDF(0, key=jax.random.key(0))", "ValueError", "`n_shapes`"),
    ("fields", "union of nothing", f"{FL}.union()", "ValueError", "`values`"),
    ("data", "icosphere -1 subdivisions", f"{D}.icosphere(-1)", "ValueError", "`subdivisions`"),
    ("data", "icosphere NaN radius", f"{D}.icosphere(1, radius=float('nan'))", "ValueError", "`radius`"),
    ("data", "cube of size 0", f"{D}.cube(0.0)", "ValueError", "`upper`"),
    ("data", "a torus thicker than its ring", f"{D}.torus(major=0.5, minor=0.6)", "ValueError", "`minor`"),
    ("data", "concatenating no meshes", "voxax.Mesh.concatenate()", "ValueError", "voxax.Mesh.concatenate: `meshes`"),
    ("data", "an unknown name", f"{D}.get('nope')", "ValueError", "nope"),
    ("data", "every named mesh is closed (oracle)",
     f"for n in {D}.names(3):\n m = {D}.get(n); assert voxax.io.is_watertight(m.vertices, m.faces) or n, n", None, ""),
    ("data", "every generator gives a valid mesh (oracle)",
     "gens = (voxax.data.box, voxax.data.torus, voxax.data.bent_bar, voxax.data.with_inverted_component,"
     " voxax.data.overlapping_cubes, voxax.data.mug, voxax.data.hand, voxax.data.overlapping_squares,"
     " voxax.data.circle_polyline, voxax.data.star_polyline, lambda: voxax.data.large(2000))\n"
     "for g in gens:\n m = g(); v, f = np.asarray(m.vertices), np.asarray(m.faces);"
     " assert np.isfinite(v).all() and f.min() >= 0 and f.max() < len(v) and len(f) > 0, g", None, ""),
    ("fields", "the primitives and their combinations at 1e30 (oracle)",
     "q = np.array([[1e30, 0.0, 0.0], [0.1, 0.0, 0.0]]); fields = voxax.fields;"
     "vals = [fields.box(q), fields.torus(q), fields.gyroid(q), fields.blob(q), fields.chebyshev(q)];"
     "assert all(np.isfinite(np.asarray(x)[1]) for x in vals);"
     "a, b = fields.sphere(q, 0.5), fields.box(q); assert np.allclose(fields.difference(a, b), np.maximum(a, -b));"
     "assert np.allclose(fields.intersection(a, b), np.maximum(a, b));"
     "assert (np.asarray(fields.smooth_union(a, b)) <= np.minimum(a, b) + 1e-12).all();"
     "t = fields.translated(lambda p: fields.sphere(p, 0.5), jnp.array([1.0, 0, 0])); assert np.isclose(t(jnp.array([[1.0, 0, 0]]))[0], -0.5);"
     "s2 = fields.scaled(lambda p: fields.sphere(p, 0.5), 2.0); assert np.isclose(s2(jnp.array([[0.0, 0, 0]]))[0], -1.0)",
     None, ""),
    # sharded and exported calls
    ("sharded", "sharded NaN vertices",
     "m = jax.sharding.Mesh(np.array(jax.devices()), ('x',)); voxax.voxelize_sharded(VNAN, F, G, m, 'x')",
     "ValueError", "NaN or Inf"),
    ("export", "closest_points with symbolic counts",
     "from jax import export; export.export(jax.jit(lambda v: voxax.closest_points((v, F), P).distance),"
     " disabled_checks=voxax.export_safety_checks())(jax.ShapeDtypeStruct(export.symbolic_shape('n, 3'), jnp.float64))",
     "ValueError", "symbolic shapes"),
    ("export", "closest_points with concrete counts (oracle)",
     "from jax import export; e = export.export(jax.jit(lambda p: voxax.closest_points(BALL, p).distance),"
     " disabled_checks=voxax.export_safety_checks())(jax.ShapeDtypeStruct((3, 3), jnp.float64));"
     "d = np.asarray(e.call(jnp.asarray(P))); assert np.allclose(d, voxax.closest_points(BALL, P).distance)", None, ""),
    ("export", "winding_number with symbolic counts",
     "from jax import export; export.export(jax.jit(lambda v: voxax.winding_number(v, F, P)),"
     " disabled_checks=voxax.export_safety_checks())(jax.ShapeDtypeStruct(export.symbolic_shape('n, 3'), jnp.float64))",
     "ValueError", "symbolic shapes"),
    # found by fuzzing: non-numeric weights, static arguments and sizes get one line naming them
    ("energies", "mellowmax with w '3'", f"{E}.mellowmax(jnp.ones(3), '3')", "TypeError",
     "voxax.energies.mellowmax: `w` must be a real number or array"),
    ("energies", "silhouettes with w None", f"{E}.silhouettes({W}, None)", "TypeError", "voxax.energies.silhouettes: `w`"),
    ("energies", "volume of a string", f"{E}.volume('3', G)", "TypeError", "voxax.energies.volume: `W`"),
    ("energies", "arap of string vertices", f"{E}.arap(V.astype(str), V, F)", "TypeError",
     "voxax.energies.arap: `vertices`"),
    ("energies", "cotangent_weights of float faces", f"{E}.cotangent_weights(V, F.astype(float))", "TypeError",
     "voxax.energies.cotangent_weights: `faces`"),
    ("energies", "fold_periodic with blocks [3]", f"{E}.fold_periodic({W}, blocks=[3])", "TypeError",
     "voxax.energies.fold_periodic: `blocks`"),
    ("energies", "mellowmax of a nested list (oracle)",
     f"m = float({E}.mellowmax([[0.0, 1.0]], w=1e4)[0]); assert abs(m - (1 - np.log(2) / 1e4)) < 1e-9, m", None, ""),
    ("fields", "sphere of radius '3'", f"{FL}.sphere(P, '3')", "TypeError", "voxax.fields.sphere: `radius`"),
    ("fields", "sphere of radius [1]", f"{FL}.sphere(P, [1])", "TypeError", "voxax.fields.sphere: `radius`"),
    ("fields", "gyroid of period None", f"{FL}.gyroid(P, None)", "TypeError", "voxax.fields.gyroid: `period`"),
    ("fields", "chebyshev degree 1e80", f"{FL}.chebyshev_polynomial(jnp.zeros(3), 1e80)", "TypeError", "`degree`"),
    ("fields", "chebyshev degree 2^31", f"{FL}.chebyshev_polynomial(jnp.zeros(3), 2**31)", "ValueError",
     "`degree` must be at most 10000"),
    ("fields", "Siren of depth 2^40", f"{FL}.Siren(depth=2**40, key=jax.random.key(0))", "MemoryError",
     "voxax.fields.Siren: a Siren of depth"),
    ("fields", "DeepSDF of 2^40 shapes", f"{FL}.DeepSDF(2**40, key=jax.random.key(0))", "MemoryError",
     "voxax.fields.DeepSDF"),
    ("data", "icosphere of 2^31 subdivisions", f"{D}.icosphere(2**31)", "ValueError", "`subdivisions` must be at most 12"),
    ("data", "a large mesh of 2^40 faces", f"{D}.large(2**40)", "MemoryError", "voxax.data.large: `n_faces_target`"),
    ("data", "a large mesh of 2.5 faces", f"{D}.large(2.5)", "TypeError", "voxax.data.large: `n_faces_target` must be an int"),
    ("data", "a torus of major radius '3'", f"{D}.torus(major='3')", "TypeError", "voxax.data.torus: `major`"),
    ("energies", "mellowmax with w 0 (a division by zero)", f"{E}.mellowmax(jnp.ones(3), 0)", "ValueError",
     "voxax.energies.mellowmax: `w` must be > 0 and finite"),
    ("energies", "silhouettes with w inf", f"{E}.silhouettes({W}, float('inf'))", "ValueError",
     "voxax.energies.silhouettes: `w` must be > 0"),
    ("energies", "mellowmax with a traced NaN w",
     f"jax.jit(lambda s: {E}.mellowmax(jnp.ones(3), s))(jnp.nan).block_until_ready()", "JaxRuntimeError",
     "voxax.energies.mellowmax: `w` must be finite"),
    # a traced sharpness <= 0 divided by zero (NaN) before the value check took `positive`
    ("energies", "mellowmax with a traced w 0",
     f"jax.jit(lambda s: {E}.mellowmax(jnp.ones(3), s))(0.0).block_until_ready()", "JaxRuntimeError",
     "voxax.energies.mellowmax: `w` must be > 0"),
    ("energies", "silhouettes with a traced negative w",
     f"jax.jit(lambda s: {E}.silhouettes({W}, s)[0])(-1.0).block_until_ready()", "JaxRuntimeError",
     "voxax.energies.silhouettes: `w` must be > 0"),
    ("energies", "bandsaw_cut with a traced w 0",
     f"jax.jit(lambda s: {E}.bandsaw_cut({W}, s))(0.0).block_until_ready()", "JaxRuntimeError",
     "voxax.energies.bandsaw_cut: `w` must be > 0"),
    ("energies", "mellowmax differentiated in w under jit (oracle)",
     f"g = float(jax.jit(jax.grad(lambda w: {E}.mellowmax(jnp.array([0.0, 1.0]), w)))(10.0));"
     "x = np.array([0.0, 1.0]); f = lambda w: np.log(np.mean(np.exp(w * x))) / w;"
     "assert abs(g - (f(10.0 + 1e-6) - f(10.0 - 1e-6)) / 2e-6) < 1e-6, g", None, ""),
    # found by tools/fuzz_api.py: raw messages from inside
    ("energies", "silhouettes of a grid without cells", f"{E}.silhouettes({W}[:0])", "ValueError",
     "voxax.energies.silhouettes: `W` must have at least one cell along each grid axis"),
    ("energies", "fold_periodic of a grid without cells", f"{E}.fold_periodic({W}[:0], 2)", "ValueError",
     "voxax.energies.fold_periodic: `W` must have at least one cell"),
    ("energies", "bandsaw_cut with a list w", f"{E}.bandsaw_cut({W}, [1.0, 2.0])", "TypeError",
     "voxax.energies.bandsaw_cut: `w` must be a scalar"),
    ("energies", "self_intersection with a list eps", f"{E}.self_intersection({W}, [1e-3, 2.0])", "TypeError",
     "voxax.energies.self_intersection: `eps` must be a scalar"),
    ("fields", "gyroid of period 0", "voxax.fields.gyroid(P, 0)", "ValueError", "voxax.fields.gyroid: `period` must be non-zero"),
    ("energies", "self_intersection of an empty grid", f"{E}.self_intersection(np.zeros((0, 4, 4)))", "ValueError",
     "voxax.energies.self_intersection: `W` must not be empty"),
    ("energies", "interpenetration of empty grids (0 / 0)",
     f"{E}.interpenetration(np.zeros((0, 4, 4)), np.zeros((0, 4, 4)))", "ValueError",
     "voxax.energies.interpenetration: `W_a` must not be empty"),
]

outcomes, test_hostile_input = table(CASES)
