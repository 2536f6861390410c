"""Hostile inputs to the CVT remesher (`voxax.cvt`: `remesh`, `fragments`, `rdt`,
`init_seeds`, `optimize`, `energy`, `assign`, `lloyd_step`, `respawn`, `CSG`), each case in
its own process (see `_hostile_driver`). `tests/cvt/test_cvt.py` and the sanitizer driver
hold the finer cases of hand-made `Fragments`."""

from __future__ import annotations

from _hostile_driver import SETUP
from _table import table

# FR the fragments of the ball on G8; SD ten seeds on them; fr(**fields) FR with fields replaced.
SETUP_X = SETUP + """
cvt = voxax.cvt
G8 = voxax.Grid.cube(8)
FR = cvt.fragments(BALL, G8)
SD = np.asarray(cvt.init_seeds(FR, 10, key=0))
fr = lambda **kw: FR._replace(**kw)
RM = lambda *a, **kw: cvt.remesh(*a, progress=False, **kw)
"""

CASES = [
    # remesh: the source
    ("cvt.remesh", "bool vertices", "RM((V > 0, F), 20)", "TypeError", "`vertices`"),
    ("cvt.remesh", "complex vertices", "RM((V + 0j, F), 20)", "TypeError", "`vertices`"),
    ("cvt.remesh", "NaN vertices", "RM((VNAN, F), 20)", "ValueError", "NaN"),
    ("cvt.remesh", "1e80 vertices", "RM((V * 1e80, F), 20)", "ValueError", "1e75"),
    ("cvt.remesh", "faces past the vertices", "RM((V, F + len(V)), 20)", "ValueError", "out of range"),
    ("cvt.remesh", "int64 faces beyond int32", "RM((V, F.astype(np.int64) + 2**32), 20)", "ValueError",
     "out of range"),
    ("cvt.remesh", "inside-out mesh", "RM((V, F[:, ::-1]), 20)", "ValueError", "inside out"),
    ("cvt.remesh", "open mesh", "RM((V, F[1:]), 20)", "ValueError", "closed"),
    ("cvt.remesh", "a string", "RM('ball.obj', 20)", "TypeError", "`source`"),
    ("cvt.remesh", "a field without a grid", "RM(voxax.fields.sphere, 20)", "ValueError", "`grid`"),
    ("cvt.remesh", "a NaN field", "RM(lambda p: voxax.fields.sphere(p) * np.nan, 20, grid=G8)", "ValueError",
     "voxax.cvt.remesh: the field `source` must be finite"),
    ("cvt.remesh", "a field missing the grid", "RM(lambda p: voxax.fields.sphere(p) + 10.0, 20, grid=G8)",
     "ValueError", "voxax.cvt.remesh: the field has no zero crossing"),
    ("cvt.remesh", "all vertices at one point", "RM((np.zeros_like(V), F), 20)", "ValueError",
     "voxax.cvt.remesh: `source` must have an extent"),
    ("cvt.remesh", "every face of zero area", "RM((V, np.stack([F[:, 0], F[:, 0], F[:, 1]], 1)), 20, orient=False)",
     "ValueError", "every face has zero area"),
    ("cvt.remesh", "a flat closed mesh", "RM((V * [1, 1, 0], F), 20)", "ValueError", "the mesh is flat"),
    # remesh: the parameters
    ("cvt.remesh", "alpha inf", "RM(BALL, 20, alpha=float('inf'))", "ValueError", "`alpha`"),
    ("cvt.remesh", "alpha NaN", "RM(BALL, 20, alpha=float('nan'))", "ValueError", "`alpha`"),
    ("cvt.remesh", "alpha 0", "RM(BALL, 20, alpha=0)", "ValueError", "`alpha`"),
    ("cvt.remesh", "alpha a string", "RM(BALL, 20, alpha='50')", "TypeError", "`alpha`"),
    ("cvt.remesh", "a float key", "RM(BALL, 20, key=0.5)", "TypeError", "`key`"),
    ("cvt.remesh", "a negative key", "RM(BALL, 20, key=-1)", "ValueError", "`key`"),
    ("cvt.remesh", "a string key", "RM(BALL, 20, key='0')", "TypeError", "`key`"),
    ("cvt.remesh", "n_seeds 3", "RM(BALL, 3)", "ValueError", "`n_seeds`"),
    ("cvt.remesh", "float n_seeds", "RM(BALL, 20.5)", "TypeError", "`n_seeds`"),
    ("cvt.remesh", "n_seeds beyond 2^21", "RM(BALL, 2**22)", "ValueError", "`n_seeds`"),
    ("cvt.remesh", "seeds beyond memory", "RM(BALL, 2**20, alpha=1e9)", "MemoryError", "GiB"),
    ("cvt.remesh", "steps -1", "RM(BALL, 20, steps=-1)", "ValueError", "`steps`"),
    ("cvt.remesh", "tol NaN", "RM(BALL, 20, tol=float('nan'))", "ValueError", "`tol`"),
    ("cvt.remesh", "tol negative", "RM(BALL, 20, tol=-1e-4)", "ValueError", "`tol`"),
    ("cvt.remesh", "polish_tol inf", "RM(BALL, 20, polish_tol=float('inf'))", "ValueError", "`polish_tol`"),
    ("cvt.remesh", "polish_tol a string", "RM(BALL, 20, polish_tol='0.02')", "TypeError", "`polish_tol`"),
    ("cvt.remesh", "bad method", "RM(BALL, 20, method='adam')", "ValueError", "`method`"),
    ("cvt.remesh", "bad inside", "RM(BALL, 20, inside='left')", "ValueError", "`inside`"),
    ("cvt.remesh", "threads 0", "RM(BALL, 20, threads=0)", "ValueError", "`threads`"),
    ("cvt.remesh", "2D grid", "RM(BALL, 20, grid=voxax.Grid.cube(8, dim=2))", "ValueError", "3D"),
    ("cvt.remesh", "a small ball stays closed",
     "res = RM(BALL, 40, method='lloyd', steps=5, polish=0); assert isinstance(res, cvt.RemeshResult); m, r = res;"
     "assert r.closed and r.euler_characteristic == 2",
     None, ""),
    # fragments
    ("cvt.fragments", "complex vertices", "cvt.fragments((V + 0j, F), G8)", "TypeError", "`vertices`"),
    ("cvt.fragments", "grid beyond memory", "cvt.fragments(BALL, voxax.Grid.cube(200000))", "MemoryError", "GiB"),
    ("cvt.fragments", "iterations 0", "cvt.fragments(voxax.fields.sphere, G8, iterations=0)", "ValueError",
     "`iterations`"),
    ("cvt.fragments", "a field of one value", "cvt.fragments(lambda p: 0.0, G8)", "ValueError", "`source`"),
    ("cvt.fragments", "(values, level) of another shape", "cvt.fragments((np.zeros((4, 4, 4)), 0.0), G8)",
     "ValueError", "shape"),
    ("cvt.fragments", "(values, level) with a NaN level",
     "cvt.fragments((np.zeros(G8.shape), float('nan')), G8)", "ValueError", "level"),
    ("cvt.CSG", "bad op", "cvt.CSG('xor', voxax.fields.sphere, voxax.fields.sphere)", "ValueError", "`op`"),
    # rdt and the steps on hand-made Fragments
    ("cvt.rdt", "fewer normals than points", "cvt.rdt(fr(normals=FR.normals[:5]), SD)", "ValueError",
     "frag.normals"),
    ("cvt.rdt", "no normals", "cvt.rdt(fr(normals=FR.normals[:0]), SD)", "ValueError", "frag.normals"),
    ("cvt.rdt", "more normals than points", "cvt.rdt(fr(normals=np.concatenate([FR.normals] * 2)), SD)",
     "ValueError", "frag.normals"),
    ("cvt.rdt", "bool seeds", "cvt.rdt(FR, SD > 0)", "TypeError", "`seeds`"),
    ("cvt.rdt", "NaN tau", "cvt.rdt(FR, SD, tau=float('nan'))", "ValueError", "`tau`"),
    ("cvt.rdt", "float max_hole", "cvt.rdt(FR, SD, max_hole=8.0)", "TypeError", "`max_hole`"),
    ("cvt.rdt", "not Fragments", "cvt.rdt((V, F), SD)", "TypeError", "`frag`"),
    ("cvt.rdt", "the seeds of a tetrahedron",
     "f, r = cvt.rdt(FR, 0.5 * np.array([[1, 1, 1], [1, -1, -1], [-1, 1, -1], [-1, -1, 1]]) / np.sqrt(3));"
     "assert isinstance(FR, cvt.Fragments) and isinstance(r, cvt.RdtReport) and len(f) == 4 and r.boundary_edges == 0",
     None, ""),
    ("cvt.energy_gradient", "complex seeds", "cvt.energy_gradient(SD + 0j, FR)", "TypeError", "`seeds`"),
    ("cvt.energy_gradient", "against central differences (oracle)",
     "g = np.asarray(cvt.energy_gradient(SD, FR)); d = np.zeros_like(SD); d[3, 1] = 1e-6;"
     "fd = (float(cvt.energy(SD + d, FR)) - float(cvt.energy(SD - d, FR))) / 2e-6;"
     "assert g.shape == SD.shape and np.isclose(g[3, 1], fd, rtol=1e-4, atol=1e-10), (g[3, 1], fd)", None, ""),
    ("cvt.optimize", "Lloyd steps lower the energy (oracle)",
     "r = cvt.optimize(FR, SD, method='lloyd', steps=3); assert isinstance(r, cvt.CVTResult);"
     "e = np.asarray(r.energy); assert e[-1] <= e[0] + 1e-15 and r.seeds.shape == SD.shape, e", None, ""),
    ("cvt.init_seeds", "n 0", "cvt.init_seeds(FR, 0)", "ValueError", "`n`"),
    ("cvt.init_seeds", "more seeds than fragments", "cvt.init_seeds(FR, FR.size + 1)", "ValueError", "`n`"),
    ("cvt.init_seeds", "float n", "cvt.init_seeds(FR, 10.0)", "TypeError", "`n`"),
    ("cvt.optimize", "bad method", "cvt.optimize(FR, SD, method='sgd')", "ValueError", "`method`"),
    ("cvt.optimize", "short weights", "cvt.optimize(fr(weights=FR.weights[:3]), SD, steps=1)", "ValueError",
     "frag.weights"),
    ("cvt.optimize", "NaN tol", "cvt.optimize(FR, SD, tol=float('nan'))", "ValueError", "`tol`"),
    ("cvt.energy", "seeds of shape (n, 2)", "cvt.energy(SD[:, :2], FR)", "ValueError", "`seeds`"),
    ("cvt.energy", "complex seeds", "cvt.energy(SD + 0j, FR)", "TypeError", "`seeds`"),
    ("cvt.assign", "NaN seeds", "cvt.assign(np.where(SD == SD[0, 0], np.nan, SD), FR)", "ValueError", "`seeds`"),
    ("cvt.lloyd_step", "short normals", "cvt.lloyd_step(SD, fr(normals=FR.normals[:2]))", "ValueError",
     "frag.normals"),
    ("cvt.respawn", "counts of another length", "cvt.respawn(SD, FR, np.ones(3, int))", "ValueError", "`count`"),
    ("cvt.fragments", "under jit", "jax.jit(lambda v: voxax.cvt.fragments((v, F), G))(V)", "TypeError",
     "voxax.cvt.fragments: computes eagerly on the host"),
]


outcomes, test_hostile_input = table(CASES, SETUP_X)
