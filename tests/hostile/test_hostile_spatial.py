"""Hostile inputs to the spatial queries (the BVH, closest points, rays, winding numbers,
nearest neighbours), each case in its own process (see `_hostile_driver`). A case whose
exception is None returns a result its code checks against an oracle."""

from __future__ import annotations

from _table import table

I64 = "F.astype(np.int64) + 2**32"
# A far query along a vertex of a sphere of radius 0.6: its closest point is that vertex.
FAR = ("S = voxax.data.icosphere(2, radius=0.6); V0 = np.asarray(S.vertices); Q = V0[[0, 33]] * {s};"
       "want = np.linalg.norm(Q[:, None] - V0[None], axis=-1).min(1);")
BRUTE_KNN = ("rng = np.random.default_rng(0); X = rng.normal(size=(300, 3)) * {s}; Y = rng.normal(size=(20, 3)) * {s};"
             "D = np.linalg.norm(Y[:, None] - X[None], axis=-1); order = np.lexsort((np.arange(300)[None].repeat(20, 0), D))[:, :4];")

CASES = [
    # the BVH
    ("bvh", "bool vertices", "voxax.BVH(V > 0, F)", "TypeError", "`vertices` must be"),
    ("bvh", "complex vertices", "voxax.BVH(V + 0j, F)", "TypeError", "complex"),
    ("bvh", "string vertices", "voxax.BVH(V.astype(str), F)", "TypeError", "`vertices`"),
    ("bvh", "NaN vertices", "voxax.BVH(VNAN, F)", "ValueError", "NaN or Inf"),
    ("bvh", "1e80 vertices", "voxax.BVH(V * 1e80, F)", "ValueError", "1e75"),
    ("bvh", "faces past the vertices", "voxax.BVH(V, F + len(V))", "ValueError", "out of range"),
    ("bvh", "int64 faces beyond int32", f"voxax.BVH(V, {I64})", "ValueError", "out of range"),
    ("bvh", "float faces", "voxax.BVH(V, F * 1.0)", "TypeError", "integer array"),
    ("bvh", "2D vertices", "voxax.BVH(V[:, :2], F)", "ValueError", "`faces`"),
    ("bvh", "bool query points", "voxax.BVH(BALL).closest_points(P > 0)", "TypeError", "`points`"),
    ("bvh", "NaN query points", "voxax.BVH(BALL).closest_points(P + np.nan)", "ValueError", "NaN"),
    ("bvh", "negative max_distance", "voxax.BVH(BALL).closest_points(P, max_distance=-1.0)", "ValueError",
     "`max_distance`"),
    ("bvh", "NaN max_distance", "voxax.BVH(BALL).closest_points(P, max_distance=float('nan'))", "ValueError",
     "`max_distance`"),
    ("bvh", "zero ray direction", "voxax.BVH(BALL).first_hits(P, P)", "ValueError", "zero"),
    ("bvh", "complex ray origins", "voxax.BVH(BALL).any_hits(P + 0j, P + 1)", "TypeError", "`origins`"),
    ("bvh", "inverted ray interval", "voxax.BVH(BALL).all_hits(P, P + 1, t_min=2.0, t_max=1.0)", "ValueError",
     "t_min"),
    ("bvh", "far query with max_distance (oracle)",
     FAR.format(s="1e30") + "r = voxax.BVH(S).closest_points(Q, max_distance=1e31);"
     "assert np.allclose(r.distance, want, rtol=1e-12), r.distance", None, ""),
    # closest points
    ("closest_points", "bool points", "voxax.closest_points(BALL, P > 0)", "TypeError", "`points`"),
    ("closest_points", "complex points", "voxax.closest_points(BALL, P + 0j)", "TypeError", "`points`"),
    ("closest_points", "string points", "voxax.closest_points(BALL, P.astype(str))", "TypeError", "`points`"),
    ("closest_points", "bool vertices", "voxax.closest_points((V > 0, F), P)", "TypeError", "`vertices`"),
    ("closest_points", "points (N, 2)", "voxax.closest_points(BALL, P[:, :2])", "ValueError", "(..., 3)"),
    ("closest_points", "Inf points", "voxax.closest_points(BALL, P + np.inf)", "ValueError", "NaN or Inf"),
    ("closest_points", "1e80 points", "voxax.closest_points(BALL, P + 1e80)", "ValueError", "1e75"),
    ("closest_points", "far queries 1e30 (oracle)",
     FAR.format(s="1e30") + "r = voxax.closest_points(S, Q); assert np.allclose(r.distance, want, rtol=1e-12), r.distance;"
     "assert isinstance(r, voxax.ClosestPoints) and np.all(np.isfinite(r.point))", None, ""),
    ("closest_points", "far queries 5e29, 2e30, 1e32, 1e75 (oracle)",
     "for s in (5e29, 2e30, 1e32, 1e60, 1e75):\n " + FAR.format(s="s") +
     " r = voxax.closest_points(S, Q); assert np.allclose(r.distance, want, rtol=1e-12), (s, r.distance)",
     None, ""),
    ("closest_points", "jit far queries 1e30 (oracle)",
     FAR.format(s="1e30") + "r = jax.jit(lambda q: voxax.closest_points(S, q))(Q);"
     "assert np.allclose(np.asarray(r.distance), want, rtol=1e-12), r.distance", None, ""),
    ("closest_points", "tiny mesh 1e-70 (oracle)",
     "r = voxax.closest_points((V * 1e-70, F), np.array([[0.0, 0.0, 1e-69]]));"
     "assert np.isclose(r.distance[0], 1e-69 - np.abs(V[:, 2]).max() * 1e-70, rtol=1e-6), r.distance", None, ""),
    ("closest_points", "jit NaN points", "jax.jit(lambda p: voxax.closest_points(BALL, p).distance)(P + np.nan)"
     ".block_until_ready()", "JaxRuntimeError", "NaN"),
    ("closest_points", "jit int64 faces beyond int32",
     f"jax.jit(lambda f: voxax.closest_points((V, f), P).distance)({I64}).block_until_ready()",
     "JaxRuntimeError", "out of range"),
    ("closest_points", "jit faces past the vertices",
     "jax.jit(lambda f: voxax.closest_points((V, f), P).distance)(F + len(V)).block_until_ready()",
     "JaxRuntimeError", "out of range"),
    ("closest_points", "jit bool points", "jax.jit(lambda p: voxax.closest_points(BALL, p).distance)(P > 0)",
     "TypeError", "`points`"),
    # rays
    ("first_hits", "bool origins", "voxax.first_hits(BALL, P > 0, P + 1)", "TypeError", "`origins`"),
    ("first_hits", "complex directions", "voxax.first_hits(BALL, P, P + 1j)", "TypeError", "`directions`"),
    ("first_hits", "NaN origins", "voxax.first_hits(BALL, P + np.nan, P + 1)", "ValueError", "NaN"),
    ("first_hits", "1e80 directions", "voxax.first_hits(BALL, P, P + 1e80)", "ValueError", "1e75"),
    ("first_hits", "zero direction", "voxax.first_hits(BALL, P, P)", "ValueError", "zero"),
    ("first_hits", "shapes that do not broadcast", "voxax.first_hits(BALL, np.zeros((3, 3)), np.ones((2, 3)))",
     "ValueError", "broadcast"),
    ("first_hits", "NaN t_max", "voxax.first_hits(BALL, P, P + 1, t_max=float('nan'))", "ValueError", "t_min"),
    ("first_hits", "string t_min", "voxax.first_hits(BALL, P, P + 1, t_min='0')", "TypeError", "`t_min`"),
    ("first_hits", "far rays 1e12 (oracle)",
     "c = voxax.data.cube(2.0); o = np.array([[-1e12, 0.0, 0.0], [0.0, 0.0, 1e12]]);"
     "r = voxax.first_hits(c, o, -o / 1e12); assert isinstance(r, voxax.RayHits) and r.hit.all();"
     "assert np.allclose(r.t, 1e12 - 1.0, rtol=0, atol=1e-3), r.t", None, ""),
    ("first_hits", "jit NaN origins", "jax.jit(lambda o: voxax.first_hits(BALL, o, P + 1).t)(P + np.nan)"
     ".block_until_ready()", "JaxRuntimeError", "NaN"),
    ("first_hits", "jit zero direction", "jax.jit(lambda d: voxax.first_hits(BALL, P, d).t)(P)"
     ".block_until_ready()", "JaxRuntimeError", "zero"),
    ("first_hits", "jit int64 faces beyond int32",
     f"jax.jit(lambda f: voxax.first_hits((V, f), P, P + 1).t)({I64}).block_until_ready()",
     "JaxRuntimeError", "out of range"),
    ("first_hits", "jit rays (oracle)",
     "c = voxax.data.cube(2.0); r = jax.jit(lambda o: voxax.first_hits(c, o, jnp.ones_like(o) * jnp.array([1.0, 0, 0])))"
     "(jnp.zeros((2, 3))); assert np.allclose(np.asarray(r.t), 1.0), r.t", None, ""),
    ("any_hits", "zero direction", "voxax.any_hits(BALL, P, P)", "ValueError", "zero"),
    ("any_hits", "bool directions", "voxax.any_hits(BALL, P, P > 0)", "TypeError", "`directions`"),
    ("all_hits", "NaN directions", "voxax.all_hits(BALL, P, P + np.nan)", "ValueError", "NaN"),
    ("all_hits", "a cube along z (oracle)",
     "h = voxax.all_hits(voxax.data.cube(2.0), [[0.0, 0.0, -5.0]], [[0.0, 0.0, 1.0]]);"
     "assert isinstance(h, voxax.AllHits) and h.t.tolist() == [4.0, 6.0], h.t", None, ""),
    # winding numbers
    ("winding_number", "bool points", "voxax.winding_number(V, F, P > 0)", "TypeError", "`points`"),
    ("winding_number", "complex vertices", "voxax.winding_number(V + 0j, F, P)", "TypeError", "complex"),
    ("winding_number", "bool vertices", "voxax.winding_number(V > 0, F, P)", "TypeError", "`vertices`"),
    ("winding_number", "NaN points", "voxax.winding_number(V, F, P + np.nan)", "ValueError", "NaN"),
    ("winding_number", "1e80 points", "voxax.winding_number(V, F, P + 1e80)", "ValueError", "1e75"),
    ("winding_number", "NaN vertices", "voxax.winding_number(VNAN, F, P)", "ValueError", "NaN"),
    ("winding_number", "points (N, 2) for 3D", "voxax.winding_number(V, F, P[:, :2])", "ValueError", "`points`"),
    ("winding_number", "no points", "voxax.winding_number(V, F)", "TypeError", "`points`"),
    ("winding_number", "chunk_size 0 under jit", "jax.jit(lambda p: voxax.winding_number(V, F, p, chunk_size=0))(P)",
     "ValueError", "`chunk_size`"),
    ("winding_number", "jit NaN points", "jax.jit(lambda p: voxax.winding_number(V, F, p))(P + np.nan)"
     ".block_until_ready()", "JaxRuntimeError", "NaN"),
    ("winding_number", "jit NaN vertices", "jax.jit(lambda v: voxax.winding_number(v, F, P))(VNAN)"
     ".block_until_ready()", "JaxRuntimeError", "NaN"),
    ("winding_number", "jit 1e80 points", "jax.jit(lambda p: voxax.winding_number(V, F, p))(P + 1e80)"
     ".block_until_ready()", "JaxRuntimeError", "1e75"),
    ("winding_number", "jit int64 faces beyond int32",
     f"jax.jit(lambda f: voxax.winding_number(V, f, P))({I64}).block_until_ready()", "JaxRuntimeError",
     "out of range"),
    ("winding_number", "jit bool points", "jax.jit(lambda p: voxax.winding_number(V, F, p))(P > 0)",
     "TypeError", "`points`"),
    ("winding_number", "far and tiny points (oracle)",
     "p = np.array([[0.0, 0, 0], [1e30, 0, 0], [0, 0, -1e75], [1e-300, 0, 0]]);"
     "w = np.asarray(voxax.winding_number(V, F, p)); wj = np.asarray(jax.jit(lambda q: voxax.winding_number(V, F, q))(p));"
     "assert np.allclose(w, [1, 0, 0, 1], atol=1e-9) and np.allclose(wj, w, atol=1e-9), (w, wj)", None, ""),
    ("winding_number", "accuracy True", "voxax.winding_number(V, F[:-3], P, accuracy=True)", "TypeError", "`accuracy`"),
    ("winding_number", "accuracy '0.1'", "voxax.winding_number(V, F[:-3], P, accuracy='0.1')", "TypeError",
     "`accuracy`"),
    ("winding_number", "accuracy NaN", "voxax.winding_number(V, F[:-3], P, accuracy=float('nan'))", "ValueError",
     "`accuracy`"),
    ("winding_number", "accuracy -1e-3", "voxax.winding_number(V, F[:-3], P, accuracy=-1e-3)", "ValueError", ">= 0"),
    ("winding_number", "accuracy an array", "voxax.winding_number(V, F[:-3], P, accuracy=np.array([0.1, 0.2]))",
     "TypeError", "`accuracy`"),
    ("winding_number", "traced accuracy", "jax.jit(lambda a: voxax.winding_number(V, F[:-3], P, accuracy=a))(0.1)",
     "TypeError", "traced"),
    ("winding_number", "accuracy on an open ball at 1e-300 to 1e70 (oracle)",
     "rng = np.random.default_rng(0); q = rng.normal(size=(200, 3)) * rng.uniform(0.2, 20, (200, 1));"
     "e = np.asarray(voxax.winding_number(V, F[:-3], q));\n"
     "for s in (1e-300, 1.0, 1e70):\n"
     " w = np.asarray(voxax.winding_number(V * s, F[:-3], q * s, accuracy=1e-3)); d = np.abs(w - e).max();"
     " assert d <= 1e-3, (s, d)", None, ""),
    # nearest neighbours
    ("nearest_neighbors", "k = 2.7", "voxax.nearest_neighbors(V, P, k=2.7)", "TypeError", "`k`"),
    ("nearest_neighbors", "k = '2'", "voxax.nearest_neighbors(V, P, k='2')", "TypeError", "`k`"),
    ("nearest_neighbors", "k = NaN", "voxax.nearest_neighbors(V, P, k=float('nan'))", "TypeError", "`k`"),
    ("nearest_neighbors", "k = True", "voxax.nearest_neighbors(V, P, k=True)", "TypeError", "`k`"),
    ("nearest_neighbors", "k = 0", "voxax.nearest_neighbors(V, P, k=0)", "ValueError", "`k`"),
    ("nearest_neighbors", "traced k", "jax.jit(lambda k: voxax.nearest_neighbors(V, P, k=k))(2)", "TypeError",
     "traced"),
    ("nearest_neighbors", "bool points", "voxax.nearest_neighbors(V > 0, P)", "TypeError", "`points`"),
    ("nearest_neighbors", "complex queries", "voxax.nearest_neighbors(V, P + 0j)", "TypeError", "`queries`"),
    ("nearest_neighbors", "NaN queries", "voxax.nearest_neighbors(V, P + np.nan)", "ValueError", "`queries`"),
    ("nearest_neighbors", "1e80 points", "voxax.nearest_neighbors(V * 1e80, P)", "ValueError", "1e75"),
    ("nearest_neighbors", "points (N, 2)", "voxax.nearest_neighbors(V[:, :2], P)", "ValueError", "`points`"),
    ("nearest_neighbors", "jit NaN queries", "jax.jit(lambda q: voxax.nearest_neighbors(V, q)[0])(P + np.nan)"
     ".block_until_ready()", "JaxRuntimeError", "NaN"),
    ("nearest_neighbors", "k beyond the points (oracle)",
     "d, i = voxax.nearest_neighbors(V[:2], P[:1], k=4); assert i[0, 2:].tolist() == [-1, -1] and np.isinf(d[0, 2:]).all()",
     None, ""),
    ("nearest_neighbors", "brute force at 1e30 and 1e-30 (oracle)",
     "for s in (1e30, 1e-30):\n " + BRUTE_KNN.format(s="s") + " d, i = voxax.nearest_neighbors(X, Y, k=4);"
     " assert (i == order).all(), s; assert np.allclose(d, np.take_along_axis(D, order, 1), rtol=1e-12)",
     None, ""),
    ("nearest_neighbors", "jit brute force (oracle)",
     BRUTE_KNN.format(s="1.0") + "d, i = jax.jit(lambda x, y: voxax.nearest_neighbors(x, y, k=4))(X, Y);"
     "assert (np.asarray(i) == order).all()", None, ""),
    # found by fuzzing: the kernel's own messages and `threads` name the function; traced intervals
    ("spatial", "closest_points of subnormal vertices", "voxax.closest_points((V * 1e-310, F), P)", "ValueError",
     "voxax.closest_points: vertices are all below 1e-75"),
    ("spatial", "a BVH of subnormal vertices", "voxax.BVH(V * 1e-310, F)", "ValueError", "voxax.BVH: vertices are all below"),
    # found by tools/fuzz_api.py: a pair with a flat array went to np.ndim of a ragged tuple
    ("spatial", "a (vertices, faces) pair with flat vertices", "voxax.closest_points((V.reshape(-1), F), P)",
     "ValueError", "voxax.closest_points: a (vertices, faces) pair needs two arrays of rank 2"),
    ("spatial", "a (vertices, faces) pair with flat faces", "voxax.first_hits((V, F.reshape(-1)), P, P + 1)",
     "ValueError", "voxax.first_hits: a (vertices, faces) pair needs two arrays of rank 2"),
    # XLA's CPU threads treat subnormal operands as zero: the kernels read the bits
    ("spatial", "jit closest_points of subnormal vertices",
     "jax.jit(lambda v: voxax.closest_points((v, F), P * 1e-310).distance)(V * 1e-310).block_until_ready()",
     "JaxRuntimeError", "vertices are all below 1e-75 in magnitude"),
    ("spatial", "jit first_hits of subnormal vertices",
     "jax.jit(lambda v: voxax.first_hits((v, F), P * 0, P + 1).t)(V * 1e-310).block_until_ready()",
     "JaxRuntimeError", "vertices are all below 1e-75 in magnitude"),
    ("nearest_neighbors", "jit subnormal points",
     "jax.jit(lambda s: voxax.nearest_neighbors(s, P * 1e-310)[0])(V * 1e-310).block_until_ready()",
     "JaxRuntimeError", "`points` must not all be below 1e-75"),
    ("spatial", "first_hits with 0 threads", "voxax.first_hits(BALL, P, P + 1, threads=0)", "ValueError",
     "voxax.first_hits: `threads` must be >= 1"),
    ("spatial", "closest_points with 2.5 threads", "voxax.closest_points(BALL, P, threads=2.5)", "TypeError",
     "voxax.closest_points: `threads` must be an int"),
    ("spatial", "winding_number with '2' threads", "voxax.winding_number(V, F, P, threads='2')", "TypeError",
     "voxax.winding_number: `threads` must be an int"),
    ("spatial", "first_hits with a traced t_max",
     "jax.jit(lambda s: voxax.first_hits(BALL, P, P + 1, t_max=s).t)(1.0)", "TypeError",
     "voxax.first_hits: `t_max` must be a concrete number"),
    ("spatial", "any_hits under jit", "jax.jit(lambda o: voxax.any_hits(BALL, o, o + 1))(P)", "TypeError",
     "voxax.any_hits: computes eagerly on the host"),
    ("spatial", "a BVH of traced vertices", "jax.jit(lambda v: voxax.BVH(v, F).closest_points(P).distance)(V)",
     "TypeError", "voxax.BVH: the tree is built eagerly on the host"),
    ("spatial", "a BVH's closest points of traced points",
     "b = voxax.BVH(V, F); jax.jit(lambda p: b.closest_points(p).distance)(P)", "TypeError",
     "voxax.BVH.closest_points: `points` is traced"),
]

outcomes, test_hostile_input = table(CASES)
