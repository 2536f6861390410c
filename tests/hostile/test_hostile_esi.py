"""Hostile inputs to esi (explicit height-field selection) and nesi (its neural form), each
case in its own process (see `_hostile_driver`). The in-process table
`tests/esi/test_esi_hostile.py` covers more parameters; these are the ones that reach the
kernels, jit or the training loop."""

from __future__ import annotations

from _hostile_driver import SETUP
from _table import table

ESI_SETUP = SETUP + """
from voxax import esi, nesi, energies
CUBE = voxax.data.cube(1.0)
CV, CF = np.asarray(CUBE.vertices), np.asarray(CUBE.faces)
Z, X = (0.0, 0.0, 1.0), (1.0, 0.0, 0.0)
AX = (Z, [X])
SEL = dict(n_dhf=2, n_hf=2, max_hf=1, n_samples=200, resolution=16, progress=False)
def NET():
    return nesi.fit(AX, CUBE, steps=0, n_samples=300, progress=False)
"""

CASES = [
    # selection
    ("esi.select", "bool vertices", "esi.select(CV > 0, CF, **SEL)", "TypeError", "`vertices` must be a real"),
    ("esi.select", "complex vertices", "esi.select(CV + 0j, CF, **SEL)", "TypeError", "`vertices` must be a real"),
    ("esi.select", "NaN vertices", "v = CV.copy(); v[0, 0] = np.nan; esi.select(v, CF, **SEL)", "ValueError",
     "`vertices` must be finite"),
    ("esi.select", "1e80 vertices", "esi.select(CV * 1e80, CF, **SEL)", "ValueError", "1e75"),
    ("esi.select", "int64 faces beyond int32", "esi.select(CV, CF.astype(np.int64) + 2**32, **SEL)", "ValueError",
     "`faces` must index"),
    ("esi.select", "open mesh", "esi.select(CV, CF[:-1], **SEL)", "ValueError", "must be closed"),
    ("esi.select", "negative tol", "esi.select(CUBE, **SEL, tol=-1e-3)", "ValueError", "`tol` must be finite"),
    ("esi.select", "NaN angle", "esi.select(CUBE, **SEL, angle=float('nan'))", "ValueError", "`angle` must be finite"),
    ("esi.select", "n_samples 0", "esi.select(CUBE, **{**SEL, 'n_samples': 0})", "ValueError", "`n_samples`"),
    ("esi.select", "zero candidate direction", "esi.select(CUBE, **SEL, candidates_dhf=np.zeros((2, 3)))",
     "ValueError", "`candidates_dhf`"),
    ("esi.select", "NaN candidates", "esi.select(CUBE, **SEL, candidates_hf=np.full((2, 3), np.nan))",
     "ValueError", "`candidates_hf`"),
    ("esi.select", "the same axes at 1e30 and 1e-30 (oracle)",
     "r0 = esi.select(CUBE, **SEL); assert isinstance(r0, esi.ESI)\n"
     "for s in (1e30, 1e-30):\n r = esi.select((CV * s, CF), **SEL); assert np.isfinite(r.energy), (s, r);"
     " assert np.allclose(r.dhf_axis, r0.dhf_axis) and np.allclose(r.hf_axes, r0.hf_axes), (s, r, r0)", None, ""),
    ("esi.energy", "NaN HF axis", "esi.energy((Z, [[np.nan, 0, 0]]), CUBE, n_samples=100, resolution=8)",
     "ValueError", "`esi` must be finite"),
    ("esi.energy_terms", "n_samples 0", "esi.energy_terms(AX, CUBE, n_samples=0)", "ValueError", "`n_samples`"),
    ("esi.depth_map", "zero direction", "esi.depth_map(CUBE, (0, 0, 0))", "ValueError", "`direction` must be non-zero"),
    ("esi.depth_map", "NaN direction", "esi.depth_map(CUBE, (np.nan, 0, 1))", "ValueError", "`direction`"),
    ("esi.depth_map", "resolution 0", "esi.depth_map(CUBE, Z, resolution=0)", "ValueError", "`resolution`"),
    ("esi.depth_map", "a cube's depths (oracle)",
     "dm = esi.depth_map(CUBE, Z, resolution=8); assert isinstance(dm, esi.DepthMap) and dm.mask.any();"
     "assert np.ptp(dm.last[dm.mask] - dm.first[dm.mask]) < 1e-9", None, ""),
    ("esi.occupancy", "NaN points", "esi.occupancy(AX, CUBE, [[np.nan, 0, 0]])", "ValueError",
     "`points` must be finite"),
    ("esi.occupancy", "string points", "esi.occupancy(AX, CUBE, np.zeros((2, 3)).astype(str))", "TypeError",
     "`points`"),
    ("esi.occupancy", "inside and outside a cube (oracle)",
     "o = esi.occupancy(AX, CUBE, [[0, 0, 0], [2.0, 0, 0], [0, 0, 1e30]]); assert o.tolist() == [True, False, False], o",
     None, ""),
    ("esi.to_mesh", "resolution 1", "esi.to_mesh(AX, CUBE, resolution=1)", "ValueError", "`resolution`"),
    ("esi.height_field_solid", "sign 0", "esi.height_field_solid(esi.depth_map(CUBE, Z, resolution=4), 0)",
     "ValueError", "`sign`"),
    ("esi.intersect_solids", "no solids", "esi.intersect_solids([])", "ValueError", "`solids`"),
    ("esi.frame_for", "zero direction", "esi.frame_for((0, 0, 0), (0, 0, 0), 1.0, 4)", "ValueError", "`direction`"),
    ("esi.frame_for", "NaN radius", "esi.frame_for(Z, (0, 0, 0), float('nan'), 4)", "ValueError", "`radius`"),
    ("esi.candidates", "n_dhf 2.5", "esi.candidates(2.5, 3)", "TypeError", "`n_dhf`"),
    ("esi.candidates", "unit candidate axes (oracle)",
     "c = esi.candidates(5, 7); assert isinstance(c, esi.Candidates) and len(c.dhf) >= 5 and len(c.hf) >= 7;"
     "assert all(np.allclose(np.linalg.norm(a, axis=1), 1) for a in (c.dhf, c.hf))", None, ""),
    ("esi.frame_for", "an orthonormal frame (oracle)",
     "f = esi.frame_for(Z, (0, 0, 0), 1.0, 4); assert isinstance(f, esi.Frame) and f.resolution == 4;"
     "m = np.stack([f.u, f.v, f.d]); assert np.allclose(m @ m.T, np.eye(3)) and np.allclose(f.d, [0, 0, 1])", None, ""),
    ("esi.height_field_solid", "a cube's height-field solid is closed (oracle)",
     "h = esi.height_field_solid(esi.depth_map(CUBE, Z, resolution=4), 1); assert isinstance(h, esi.HeightFieldSolid);"
     "assert voxax.metrics.manifold_report(h.boundary).closed and h.boundary.signed_volume() > 0", None, ""),
    ("esi.energy_terms", "a cube's terms (oracle)",
     "t = esi.energy_terms(AX, CUBE, n_samples=100, resolution=8); assert isinstance(t, esi.EnergyTerms);"
     "assert np.isclose(t.dist, t.cd_st + t.cd_ts) and t.E >= t.dist >= 0", None, ""),
    ("nesi.training_data", "points of a cube (oracle)",
     "t = nesi.training_data(AX, CUBE, n_samples=200); assert isinstance(t, nesi.Training);"
     "assert isinstance(t.data, nesi.TrainingData) and np.isfinite(np.asarray(t.data.p0)).all() and t.scale > 0",
     None, ""),
    ("esi.fibonacci_sphere", "n = -1", "esi.fibonacci_sphere(-1)", "ValueError", "`n`"),
    ("esi.fibonacci_sphere", "unit directions (oracle)",
     "d = esi.fibonacci_sphere(50, hemisphere=True); assert d.shape == (50, 3);"
     "assert np.allclose(np.linalg.norm(d, axis=1), 1) and (d[:, 2] >= 0).all()", None, ""),
    ("esi.closed_mesh", "open mesh", "esi.closed_mesh('voxax.esi.closed_mesh', CV, CF[:-1])", "ValueError", "closed"),
    ("esi.esi_gap", "NaN W", "esi.esi_gap(np.full((2, 2, 2), np.nan))", "ValueError", "`W` must be finite"),
    ("esi.esi_gap", "zero height fields (oracle)",
     "g = float(esi.esi_gap(np.zeros((3, 3, 3)))); assert np.isfinite(g) and abs(g) < 1e-9, g", None, ""),
    ("nesi.fit", "negative eps", "nesi.fit(AX, CUBE, steps=1, eps=-0.1, progress=False)", "ValueError", "`eps`"),
    ("nesi.fit", "NaN learning rate", "nesi.fit(AX, CUBE, steps=1, learning_rate=float('nan'), progress=False)",
     "ValueError", "`learning_rate`"),
    ("nesi.fit", "n_samples -1", "nesi.fit(AX, CUBE, steps=0, n_samples=-1, progress=False)", "ValueError",
     "`n_samples`"),
    ("nesi.fit", "NaN vertices", "v = CV.copy(); v[1, 1] = np.nan; nesi.fit(AX, v, CF, steps=0, progress=False)",
     "ValueError", "`vertices` must be finite"),
    ("nesi.fit", "steps -1", "nesi.fit(AX, CUBE, steps=-1, progress=False)", "ValueError", "`steps`"),
    ("nesi.training_data", "NaN grazing", "nesi.training_data(AX, CUBE, grazing=float('nan'))", "ValueError",
     "`grazing`"),
    ("nesi.training_data", "ray_points 0", "nesi.training_data(AX, CUBE, ray_points=0)", "ValueError", "`ray_points`"),
    ("nesi.raytrace", "NaN origins", "nesi.raytrace(NET(), [[np.nan, 0, 3]], [0, 0, -1.0])", "ValueError",
     "`origins` must be finite"),
    ("nesi.raytrace", "zero directions", "nesi.raytrace(NET(), [[0, 0, 3.0]], [0, 0, 0.0])", "ValueError",
     "`directions` must be non-zero"),
    ("nesi.raytrace", "n_steps 0", "nesi.raytrace(NET(), [[0, 0, 3.0]], [0, 0, -1.0], n_steps=0)", "ValueError",
     "`n_steps`"),
    ("nesi.raytrace", "refine -1", "nesi.raytrace(NET(), [[0, 0, 3.0]], [0, 0, -1.0], refine=-1)", "ValueError",
     "`refine`"),
    ("nesi.occupancy", "bool points", "nesi.occupancy(NET(), np.ones((2, 3), bool))", "TypeError", "`points`"),
    ("nesi.to_mesh", "resolution 1", "nesi.to_mesh(NET(), resolution=1)", "ValueError", "`resolution`"),
    ("nesi.param_count", "not a network", "nesi.param_count('net')", "TypeError", "`net`"),
    ("nesi.param_count", "an untrained network (oracle)",
     "n = NET(); c = nesi.param_count(n); assert isinstance(n, nesi.NESI) and c == sum("
     "x.size for x in jax.tree_util.tree_leaves(n) if hasattr(x, 'size') and jnp.issubdtype(x.dtype, jnp.floating)), c",
     None, ""),
    ("esi.fibonacci_sphere", "2^40 directions", "esi.fibonacci_sphere(2**40)", "MemoryError",
     "voxax.esi.fibonacci_sphere: `n` = 1099511627776"),
    ("esi.candidates", "2^40 DHF directions", "esi.candidates(2**40)", "MemoryError", "voxax.esi.candidates: `n_dhf`"),
    ("esi.energy", "2^40 samples", "esi.energy(AX, CUBE, n_samples=2**40, resolution=8)", "MemoryError",
     "voxax.esi.energy: `n_samples`"),
    ("nesi.training_data", "2^40 samples", "nesi.training_data(AX, CUBE, n_samples=2**40)", "MemoryError",
     "voxax.nesi.training_data: `n_samples`"),
    ("esi", "depth_map under jit", "jax.jit(lambda v: voxax.esi.depth_map(v, F, [0.0, 0.0, 1.0]).first)(V)",
     "TypeError", "voxax.esi.depth_map: computes eagerly on the host"),
]

outcomes, test_hostile_input = table(CASES, ESI_SETUP)
