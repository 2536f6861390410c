"""Hostile inputs to voxax.metrics beyond the core's table (tests/hostile/test_hostile_core.py),
each case in its own process (see `_hostile_driver`)."""

from __future__ import annotations

from _table import table

M = "voxax.metrics"
CASES = [
    ("metrics.sample_surface", "bool vertices", f"{M}.sample_surface((V > 0, F), 10)", "TypeError", "`vertices`"),
    ("metrics.sample_surface", "complex vertices", f"{M}.sample_surface((V + 0j, F), 10)", "TypeError", "complex"),
    ("metrics.sample_surface", "n = 0 gives no samples (oracle)", f"assert {M}.sample_surface(BALL, 0).points.shape == (0, 3)",
     None, ""),
    ("metrics.sample_surface", "n = -1", f"{M}.sample_surface(BALL, -1)", "ValueError", "`n`"),
    ("metrics.sample_surface", "faces past the vertices", f"{M}.sample_surface((V, F + len(V)), 5)", "ValueError",
     "out of range"),
    ("metrics.sample_surface", "points on the surface (oracle)",
     f"s = {M}.sample_surface(BALL, 200, key=1); assert isinstance(s, {M}.SurfaceSamples);"
     "r = voxax.closest_points(BALL, s.points); assert r.distance.max() < 1e-12", None, ""),
    ("metrics.triangle_quality", "1e80 vertices", f"{M}.triangle_quality((V * 1e80, F))", "ValueError", "1e75"),
    ("metrics.triangle_quality", "Inf vertices", f"{M}.triangle_quality((V + np.inf, F))", "ValueError", "NaN"),
    ("metrics.triangle_quality", "scale-free at 1e70 (oracle)",
     f"q = {M}.triangle_quality((V * 1e70, F)); q0 = {M}.triangle_quality(BALL);"
     "assert np.all(np.isfinite(q)) and np.allclose(q, q0, rtol=1e-9)", None, ""),
    ("metrics.hausdorff", "n = 0: the vertices alone (oracle)",
     f"h = {M}.hausdorff(BALL, (V * 2, F), n=0); assert np.isclose(h, np.linalg.norm(V, axis=1).max() * 1, rtol=1e-12), h",
     None, ""),
    ("metrics.hausdorff", "1e80 mesh", f"{M}.hausdorff((V * 1e80, F), BALL)", "ValueError", "1e75"),
    ("metrics.hausdorff", "at 1e30 (oracle)",
     f"h = {M}.hausdorff((V * 1e30, F), (V * 2e30, F), n=2000);"
     "r = np.linalg.norm(V, axis=1).max() * 1e30; assert np.isfinite(h) and 0.8 * r < h <= r * 1.0000001, h", None, ""),
    ("metrics.directed_hausdorff", "n = -1", f"{M}.directed_hausdorff(BALL, BALL, n=-1)", "ValueError", "`n`"),
    ("metrics.directed_hausdorff", "NaN mesh", f"{M}.directed_hausdorff((VNAN, F), BALL)", "ValueError", "NaN"),
    ("metrics.directed_hausdorff", "a mesh to itself (oracle)",
     f"h = {M}.directed_hausdorff(BALL, BALL, n=500); assert h < 1e-12, h", None, ""),
    ("metrics.chamfer", "unknown convention", f"{M}.chamfer(BALL, BALL, convention='l3')", "ValueError",
     "`convention`"),
    ("metrics.chamfer", "NaN cloud", f"{M}.chamfer(P + np.nan, BALL)", "ValueError", "NaN"),
    ("metrics.chamfer", "complex cloud", f"{M}.chamfer(P + 0j, BALL)", "TypeError", "complex"),
    ("metrics.chamfer", "two clouds (oracle)",
     f"a = np.zeros((1, 3)); b = np.array([[3.0, 4.0, 0.0]]) * 1e30; c = {M}.chamfer(a, b); c2 = {M}.chamfer(b, a);"
     f"assert np.isfinite(c) and c > 0 and c == c2 and {M}.chamfer(a, a) == 0, (c, c2)",
     None, ""),
    ("metrics.f_score", "negative threshold", f"{M}.f_score(BALL, BALL, -0.1)", "ValueError", "`threshold`"),
    ("metrics.f_score", "NaN threshold", f"{M}.f_score(BALL, BALL, float('nan'))", "ValueError", "`threshold`"),
    ("metrics.f_score", "a mesh with itself (oracle)", f"f = {M}.f_score(BALL, BALL, 0.2, n=500); assert f == 1.0, f",
     None, ""),
    ("metrics.iou", "1e80 mesh", f"{M}.iou(BALL, (V * 1e80, F), G)", "ValueError", "1e75"),
    ("metrics.iou", "NaN threshold", f"{M}.iou(BALL, BALL, G, soft=False, threshold=float('nan'))",
     "ValueError", "`threshold`"),
    ("metrics.iou", "a mesh with itself (oracle)",
     f"i = float({M}.iou(BALL, BALL, G)); assert np.isclose(i, 1.0), i", None, ""),
    ("metrics.euler_characteristic", "float faces", f"{M}.euler_characteristic((V, F * 1.0))", "TypeError", "integer"),
    ("metrics.euler_characteristic", "a sphere (oracle)", f"assert {M}.euler_characteristic(BALL) == 2", None, ""),
    ("metrics.manifold_report", "faces past the vertices", f"{M}.manifold_report((V, F + len(V)))", "ValueError",
     "out of range"),
    ("metrics.manifold_report", "a sphere (oracle)",
     f"r = {M}.manifold_report(BALL); assert isinstance(r, {M}.ManifoldReport) and r.closed and r.genus == 0", None, ""),
    ("metrics", "sample_surface of 2^40 points", "voxax.metrics.sample_surface(BALL, 2**40)", "MemoryError",
     "voxax.metrics.sample_surface: 1099511627776 surface samples"),
    ("metrics", "sample_surface with the key '3'", "voxax.metrics.sample_surface(BALL, 5, '3')", "TypeError",
     "voxax.metrics.sample_surface: `key`"),
    # host functions under jit: one line that says so (found by tools/fuzz_api.py)
    ("metrics", "hausdorff under jit", "jax.jit(lambda v: voxax.metrics.hausdorff((v, F), BALL))(V)", "TypeError",
     "voxax.metrics.hausdorff: computes eagerly on the host"),
    ("metrics", "triangle_quality of a traced Mesh", "jax.jit(lambda v: voxax.metrics.triangle_quality(voxax.Mesh(v, F)))(V)",
     "TypeError", "voxax.Mesh: holds NumPy arrays and cannot take traced values"),
]

outcomes, test_hostile_input = table(CASES)
