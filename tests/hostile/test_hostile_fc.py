"""Hostile inputs to Faithful Contouring (`voxax.fc`: `encode`, `pieces`, `decode`,
`roundtrip`, `select`, `merge`, `edge_topology`, `Tokens.from_array`), each case in its own
process (see `_hostile_driver`). The in-process table `tests/fc/test_fc_hostile.py` holds
the finer cases of the token fields."""

from __future__ import annotations

from _hostile_driver import SETUP
from _table import table

# G8 a grid around the ball; TOK its tokens; ed(**fields) the tokens with fields replaced.
SETUP_X = SETUP + """
import dataclasses
fc = voxax.fc
G8 = voxax.Grid.cube(8)
TOK = fc.encode(BALL, G8)
ed = lambda **kw: dataclasses.replace(TOK, **kw)
"""

CASES = [
    # encode / pieces: the mesh
    ("fc.encode", "bool vertices", "fc.encode(V > 0, F, G8)", "TypeError", "`vertices`"),
    ("fc.encode", "complex vertices", "fc.encode(V + 0j, F, G8)", "TypeError", "`vertices`"),
    ("fc.encode", "string vertices", "fc.encode(V.astype(str), F, G8)", "TypeError", "`vertices`"),
    ("fc.encode", "NaN vertices", "fc.encode(VNAN, F, G8)", "ValueError", "NaN or Inf"),
    ("fc.encode", "1e80 vertices", "fc.encode(V * 1e80, F, G8)", "ValueError", "1e75"),
    ("fc.encode", "faces past the vertices", "fc.encode(V, F + len(V), G8)", "ValueError", "out of range"),
    ("fc.encode", "negative faces", "fc.encode(V, F - len(V), G8)", "ValueError", "out of range"),
    ("fc.encode", "int64 faces beyond int32", "fc.encode(V, F.astype(np.int64) + 2**32, G8)", "ValueError",
     "out of range"),
    ("fc.encode", "float faces", "fc.encode(V, F * 1.0, G8)", "TypeError", "`faces`"),
    ("fc.encode", "segments for a 3D mesh", "fc.encode(V, F[:, :2], G8)", "ValueError", "`faces`"),
    ("fc.encode", "2D grid", "fc.encode(V, F, voxax.Grid.cube(8, dim=2))", "ValueError", "3D"),
    ("fc.encode", "grid beyond memory", "fc.encode(V, F, voxax.Grid.cube(20000))", "MemoryError", "GiB"),
    ("fc.encode", "bad layout", "fc.encode(V, F, G8, layout='both')", "ValueError", "`layout`"),
    ("fc.encode", "NaN lambda_n", "fc.encode(V, F, G8, lambda_n=float('nan'))", "ValueError", "`lambda_n`"),
    ("fc.encode", "negative lambda_d", "fc.encode(V, F, G8, lambda_d=-1.0)", "ValueError", "`lambda_d`"),
    ("fc.encode", "string weight_power", "fc.encode(V, F, G8, weight_power='1')", "TypeError", "`weight_power`"),
    ("fc.encode", "threads 0", "fc.encode(V, F, G8, threads=0)", "ValueError", "`threads`"),
    ("fc.encode", "degenerate faces give no tokens",
     "t = fc.encode(V * 0 + 0.1, F, G8); assert len(t) == 0 and fc.decode(t).n_faces == 0", None, ""),
    ("fc.encode", "scaled by 2^-60 gives the same tokens",
     "s = 2.0**-60; g = voxax.Grid(tuple(np.array(G8.lower) * s), tuple(np.array(G8.upper) * s), G8.shape);"
     "t = fc.encode(V * s, F, g); np.testing.assert_array_equal(t.index, TOK.index);"
     "np.testing.assert_array_equal(t.edge_signs, TOK.edge_signs);"
     "np.testing.assert_allclose(t.offsets, TOK.offsets, rtol=0, atol=1e-9)", None, ""),
    ("fc.pieces", "complex vertices", "fc.pieces(V + 0j, F, G8)", "TypeError", "`vertices`"),
    ("fc.pieces", "faces past the vertices", "fc.pieces(V, F + len(V), G8)", "ValueError", "out of range"),
    # decode: the token fields
    ("fc.decode", "float signs", "fc.decode(ed(edge_signs=TOK.edge_signs * 0.5))", "TypeError", "edge_signs"),
    ("fc.decode", "signs 300", "fc.decode(ed(edge_signs=TOK.edge_signs.astype(np.int64) * 300))", "ValueError",
     "-127, 127"),
    ("fc.decode", "offsets 1e300", "fc.decode(ed(offsets=TOK.offsets * 0 + 1e300))", "ValueError", "offsets"),
    ("fc.decode", "NaN normals", "fc.decode(ed(normals=TOK.normals * np.nan))", "ValueError", "normals"),
    ("fc.decode", "index beyond int32", "fc.decode(ed(index=TOK.index + 2**32))", "ValueError", "index"),
    ("fc.decode", "negative index", "fc.decode(ed(index=TOK.index - 10**6))", "ValueError", "index"),
    ("fc.decode", "short normals", "fc.decode(ed(normals=TOK.normals[:3]))", "ValueError", "shape"),
    ("fc.decode", "bad split", "fc.decode(TOK, split='longest')", "ValueError", "`split`"),
    ("fc.decode", "not tokens", "fc.decode((V, F))", "TypeError", "`tokens`"),
    ("fc.decode", "threads -1", "fc.decode(TOK, threads=-1)", "ValueError", "`threads`"),
    # the token utilities
    ("fc.select", "mask of another length", "fc.select(TOK, np.ones(3, bool))", "ValueError", "mask"),
    ("fc.select", "float mask", "fc.select(TOK, np.ones(len(TOK)))", "TypeError", "mask"),
    ("fc.select", "rows out of range", "fc.select(TOK, [len(TOK) + 5])", "ValueError", "mask"),
    ("fc.merge", "tokens of another grid", "fc.merge(TOK, fc.encode(BALL, voxax.Grid.cube(6)))", "ValueError",
     "same grid"),
    ("fc.Tokens.from_array", "NaN rows", "fc.Tokens.from_array(np.full((2, 19), np.nan), G8)", "ValueError", "finite"),
    ("fc.roundtrip", "resolution 0", "fc.roundtrip(BALL, resolution=0, progress=False)", "ValueError", "`resolution`"),
    ("fc.roundtrip", "float resolution", "fc.roundtrip(BALL, resolution=8.5, progress=False)", "TypeError",
     "`resolution`"),
    ("fc.roundtrip", "NaN threshold", "fc.roundtrip(BALL, G8, threshold=float('nan'), progress=False)", "ValueError",
     "`threshold`"),
    ("fc.roundtrip", "NaN vertices", "fc.roundtrip((VNAN, F), G8, progress=False)", "ValueError", "NaN"),
    ("fc.edge_topology", "faces past the vertices", "fc.edge_topology(V, F + len(V))", "ValueError", "out of range"),
    ("fc.edge_topology", "a closed ball's edges (oracle)",
     "e = fc.edge_topology(V, F); assert isinstance(e, fc.EdgeTopology);"
     "assert (e.n_edges, e.euler_characteristic, e.n_boundary_edges, e.closed) == (3 * len(F) // 2, 2, 0, True), e",
     None, ""),
    ("fc.pieces", "the pieces add up to the ball's area (oracle)",
     "p = fc.pieces(V, F, G8); assert isinstance(p, fc.Pieces); a = np.cross(V[F[:, 1]] - V[F[:, 0]], V[F[:, 2]] - V[F[:, 0]]);"
     "assert np.isclose(p.area.sum(), 0.5 * np.linalg.norm(a, axis=1).sum()) and set(p.face.tolist()) == set(range(len(F)))",
     None, ""),
    ("fc.roundtrip", "a ball's round trip stays closed (oracle)",
     "m, r = fc.roundtrip(BALL, G8, progress=False); assert isinstance(r, fc.RoundtripReport);"
     "assert r.manifold.closed and r.manifold.euler_characteristic == 2 and r.hausdorff < 2 * max(G8.spacing), r",
     None, ""),
    ("fc", "encode under jit", "jax.jit(lambda v: voxax.fc.encode(v, F, G))(V)", "TypeError",
     "voxax.fc.encode: computes eagerly on the host"),
]


outcomes, test_hostile_input = table(CASES, SETUP_X)
