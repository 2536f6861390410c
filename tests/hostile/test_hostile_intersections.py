"""Hostile inputs to the exact triangle-triangle intersection test (`voxax.intersections`,
self test and between two meshes), each case in its own process (see `_hostile_driver`)."""

from __future__ import annotations

from _hostile_driver import SETUP
from _table import table

SETUP_X = SETUP + """
X = voxax.intersections
"""

CASES = [
    ("intersections", "bool vertices", "X(V > 0, F)", "TypeError", "`vertices`"),
    ("intersections", "complex vertices", "X(V + 0j, F)", "TypeError", "`vertices`"),
    ("intersections", "string vertices", "X(V.astype(str), F)", "TypeError", "`vertices`"),
    ("intersections", "float faces", "X(V, F * 1.0)", "TypeError", "`faces`"),
    ("intersections", "NaN vertices", "X(VNAN, F)", "ValueError", "NaN or Inf"),
    ("intersections", "1e80 vertices", "X(V * 1e80, F)", "ValueError", "1e75"),
    ("intersections", "faces past the vertices", "X(V, F + len(V))", "ValueError", "out of range"),
    ("intersections", "int64 faces beyond int32", "X(V, F.astype(np.int64) + 2**32)", "ValueError", "out of range"),
    ("intersections", "2D mesh", "X(voxax.data.polygon_square())", "ValueError", "3"),
    ("intersections", "segments", "X(V, F[:, :2])", "ValueError", "`faces`"),
    ("intersections", "other with NaN", "X(BALL, other=(VNAN, F))", "ValueError", "NaN or Inf"),
    ("intersections", "other with faces past", "X(BALL, other=(V, F + len(V)))", "ValueError", "out of range"),
    ("intersections", "other a string", "X(BALL, other='b.obj')", "TypeError", "voxax.io.load"),
    ("intersections", "threads 0", "X(BALL, threads=0)", "ValueError", "`threads`"),
    ("intersections", "float threads", "X(BALL, threads=2.5)", "TypeError", "`threads`"),
    ("intersections", "a grid", "X(G)", "TypeError", "mesh"),
    ("intersections", "under jit", "jax.jit(lambda v: X(v, F).count)(V)", "TypeError", "jit"),
    # valid but extreme: exact verdicts
    ("intersections", "empty mesh", "r = X(np.zeros((0, 3)), np.zeros((0, 3), int)); assert r.count == 0", None, ""),
    ("intersections", "a closed ball has none", "r = X(BALL); assert isinstance(r, voxax.Intersections) and r.count == 0", None, ""),
    ("intersections", "a duplicated face is reported",
     "r = X(V, np.concatenate([F, F[:1]])); assert r.count >= 1 and [0, len(F)] in r.pairs.tolist()", None, ""),
    ("intersections", "a degenerate face touching nothing",
     "v = np.concatenate([V, [[2.0, 2, 2]] * 3]); f = np.concatenate([F, [[len(V), len(V) + 1, len(V) + 2]]]);"
     "assert X(v, f).count == 0", None, ""),
    ("intersections", "balls 1e-40 apart in scale are the same",
     "a = X(BALL, other=(V + 0.4, F)); s = 2.0**-130; b = X((V * s, F), other=((V + 0.4) * s, F));"
     "assert a.count > 0 and a.pairs.tolist() == b.pairs.tolist()", None, ""),
    ("intersections", "disjoint balls", "assert X(BALL, other=(V + 2.0, F)).count == 0", None, ""),
]


outcomes, test_hostile_input = table(CASES, SETUP_X)
