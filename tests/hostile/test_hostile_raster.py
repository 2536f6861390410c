"""Hostile inputs to `voxax.raster.line_crossings`, each case in its own process (see
`_hostile_driver`)."""

from __future__ import annotations

from _hostile_driver import SETUP
from _table import table

# CUBE a unit cube [-0.5, 0.5]^3; G8 the grid [-1, 1]^3 of 8^3 cells.
SETUP_X = SETUP + """
lc = voxax.raster.line_crossings
CUBE = voxax.data.cube(1.0)
CV, CF = np.asarray(CUBE.vertices), np.asarray(CUBE.faces)
G8 = voxax.Grid.cube(8)
"""

CASES = [
    ("raster.line_crossings", "bool vertices", "lc(V > 0, F, G8, 0)", "TypeError", "`vertices`"),
    ("raster.line_crossings", "complex vertices", "lc(V + 0j, F, G8, 0)", "TypeError", "`vertices`"),
    ("raster.line_crossings", "string vertices", "lc(V.astype(str), F, G8, 0)", "TypeError", "`vertices`"),
    ("raster.line_crossings", "bool faces", "lc(V, F > 0, G8, 0)", "TypeError", "`faces`"),
    ("raster.line_crossings", "NaN vertices", "lc(VNAN, F, G8, 0)", "ValueError", "NaN or Inf"),
    ("raster.line_crossings", "1e80 vertices", "lc(V * 1e80, F, G8, 0)", "ValueError", "1e75"),
    ("raster.line_crossings", "faces past the vertices", "lc(V, F + len(V), G8, 0)", "ValueError", "out of range"),
    ("raster.line_crossings", "int64 faces beyond int32", "lc(V, F.astype(np.int64) + 2**32, G8, 0)", "ValueError",
     "out of range"),
    ("raster.line_crossings", "axis 3", "lc(V, F, G8, 3)", "ValueError", "`axis`"),
    ("raster.line_crossings", "axis -1", "lc(V, F, G8, -1)", "ValueError", "`axis`"),
    ("raster.line_crossings", "float axis", "lc(V, F, G8, 1.0)", "ValueError", "`axis`"),
    ("raster.line_crossings", "no axis", "lc(V, F, G8)", "TypeError", "`axis`"),
    ("raster.line_crossings", "2D grid", "lc(V, F, voxax.Grid.cube(8, dim=2), 0)", "ValueError", "3D"),
    ("raster.line_crossings", "bad lines", "lc(V, F, G8, 0, lines='corners')", "ValueError", "`lines`"),
    ("raster.line_crossings", "NaN line coordinates", "lc(V, F, G8, 0, lines=([np.nan], [0.0]))", "ValueError",
     "finite"),
    ("raster.line_crossings", "unsorted line coordinates", "lc(V, F, G8, 0, lines=([0.5, 0.1], [0.0]))",
     "ValueError", "increasing"),
    ("raster.line_crossings", "too many lines", "lc(V, F, voxax.Grid.cube(200000), 0)", "MemoryError", "GiB"),
    ("raster.line_crossings", "threads 0", "lc(V, F, G8, 0, threads=0)", "ValueError", "`threads`"),
    ("raster.line_crossings", "a path", "lc('cube.obj', G8, 0)", "TypeError", "voxax.io.load"),
    # valid but extreme: exact results
    ("raster.line_crossings", "a cube: two crossings per inner line",
     "d = lc(CV, CF, G8, 2); assert isinstance(d, voxax.raster.Dexels) and len(d.depth) == 32 and set(np.round(d.depth, 12)) == {-0.5, 0.5};"
     "assert int(d.sign.sum()) == 0 and np.all(d.counts()[d.counts() > 0] == 2)", None, ""),
    ("raster.line_crossings", "lines through the cube's edges count once",
     "d = lc(CV, CF, G8, 0, lines=([-0.5, 0.0, 0.5], [-0.5, 0.0, 0.5])); assert int(d.sign.sum()) == 0;"
     "assert d.counts().sum() % 2 == 0", None, ""),
    ("raster.line_crossings", "empty mesh", "d = lc(np.zeros((0, 3)), np.zeros((0, 3), int), G8, 1); assert len(d.depth) == 0",
     None, ""),
    ("raster.line_crossings", "a mesh scaled by 2^-90",
     "s = 2.0**-90; g = voxax.Grid(tuple(np.array(G8.lower) * s), tuple(np.array(G8.upper) * s), G8.shape);"
     "d = lc(CV * s, CF, g, 2); assert len(d.depth) == 32 and np.all(np.abs(np.abs(d.depth) / s - 0.5) < 1e-12)",
     None, ""),
    ("raster", "line_crossings under jit", "jax.jit(lambda v: voxax.raster.line_crossings(v, F, G, 2).depth)(V)",
     "TypeError", "voxax.raster.line_crossings: computes eagerly on the host"),
]


outcomes, test_hostile_input = table(CASES, SETUP_X)
