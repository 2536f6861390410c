"""Hostile inputs to the applications (`voxax.apps`) and their report types, each case in
its own process (see `_hostile_driver`).

A real run of an application costs seconds, so every case here is refused before the run
or works on a report built by hand: `R(cls, **changes)` (set up below) builds a report of
type `cls` with a valid value for every field (by its annotation) and `changes` on top.
"""

from __future__ import annotations

from _hostile_driver import SETUP
from _table import table

SETUP_APPS = SETUP + """
import copy, dataclasses, json, pickle, typing
SPHERE = lambda p, x: voxax.fields.sphere(x, p)
def R(cls, **changes):
    hints = typing.get_type_hints(cls)
    good = {bool: False, int: 3, float: 0.25, str: "max_steps", np.ndarray: np.zeros(3)}
    kw = {f.name: good.get(hints[f.name], {"energy": np.array([3.0, 2.0, 1.0])}) for f in dataclasses.fields(cls)}
    return cls(**(kw | changes))
"""

BS, MO, SI, TI, IM = ("voxax.apps.optimize_for_bandsaw", "voxax.apps.optimize_for_molding",
                      "voxax.apps.resolve_self_intersections", "voxax.apps.optimize_tiling",
                      "voxax.apps.optimize_implicit")
REPORTS = ("voxax.apps.Report", "voxax.apps.BandsawReport", "voxax.apps.MoldingReport", "voxax.apps.SelfIntersectionReport", "voxax.apps.TilingReport",
           "voxax.apps.ImplicitReport")

CASES = [
    # -- the report types, built by hand ---------------------------------------------------
    *[("reports", f"{cls.split('.')[-1]}: summary, to_dict, ==, pickle, deepcopy of a report built by hand (oracle)",
       f"r = R({cls}); s = r.summary(); assert s.startswith('{cls.split('.')[-1]}') and 'max_steps' in s, s;"
       f"assert r == R({cls}) and pickle.loads(pickle.dumps(r)) == r and copy.deepcopy(r) == r;"
       f"assert r != R({cls}, steps=4) and r != 'report';"
       f"d = r.to_dict() if hasattr(r, 'to_dict') else None; assert d is None or json.loads(json.dumps(d))['steps'] == 3",
       None, "") for cls in REPORTS],
    ("reports", "reports hold arrays and compare by value, so they are unhashable, like a dict (oracle)",
     "try:\n hash(R(voxax.apps.BandsawReport))\nexcept TypeError:\n pass\nelse:\n raise AssertionError('hashable')", None, ""),
    ("reports", "Report with a string energy history", "R(voxax.apps.Report, energy_history='garbage')", "TypeError",
     "voxax.apps.Report: `energy_history` must be a real array"),
    ("reports", "Report with a 2D energy history", "R(voxax.apps.Report, energy_history=np.zeros((2, 2)))", "ValueError",
     "`energy_history` must be 1D"),
    ("reports", "Report with a history that is a list", "R(voxax.apps.Report, history=[1.0, 2.0])", "TypeError",
     "`history` must be a mapping"),
    ("reports", "Report with a history of strings", "R(voxax.apps.Report, history={'energy': 'abc'})", "TypeError",
     "`history['energy']` must be a real array"),
    ("reports", "Report with steps True", "R(voxax.apps.Report, steps=True)", "TypeError", "`steps` must be an int, got bool"),
    ("reports", "Report with steps 2.5", "R(voxax.apps.Report, steps=2.5)", "TypeError", "`steps` must be an int, got float"),
    ("reports", "Report with a stop reason that is not a string", "R(voxax.apps.Report, stop_reason=3)", "TypeError",
     "`stop_reason` must be a str"),
    ("reports", "BandsawReport with a string cut energy", "R(voxax.apps.BandsawReport, cut_initial='0.5')", "TypeError",
     "voxax.apps.BandsawReport: `cut_initial` must be a real number"),
    ("reports", "BandsawReport with a complex waste volume", "R(voxax.apps.BandsawReport, waste_volume_final=1j)",
     "TypeError", "`waste_volume_final` must be a real number"),
    ("reports", "MoldingReport with axis 2.0", "R(voxax.apps.MoldingReport, axis=2.0)", "TypeError", "`axis` must be an int"),
    ("reports", "MoldingReport with a 2D centre", "R(voxax.apps.MoldingReport, centre=np.zeros(2))", "ValueError",
     "`centre` must have shape (3,)"),
    ("reports", "SelfIntersectionReport with resolved 1", "R(voxax.apps.SelfIntersectionReport, resolved=1)", "TypeError",
     "`resolved` must be a bool"),
    ("reports", "SelfIntersectionReport with an array of max values", "R(voxax.apps.SelfIntersectionReport, max_w_final=np.ones(2))",
     "TypeError", "`max_w_final` must be a real number"),
    ("reports", "TilingReport with complex translations", "R(voxax.apps.TilingReport, translations=np.zeros((2, 3)) + 1j)",
     "TypeError", "voxax.apps.TilingReport: `translations` must be a real array"),
    ("reports", "TilingReport with an object cell", "R(voxax.apps.TilingReport, cell=np.array([None, 1]))", "TypeError",
     "`cell` must be a real array"),
    ("reports", "ImplicitReport with a 2D loss history", "R(voxax.apps.ImplicitReport, loss_history=np.zeros((2, 2)))",
     "ValueError", "voxax.apps.ImplicitReport: `loss_history` must be 1D"),
    ("reports", "ImplicitReport with an Euler characteristic 'two'", "R(voxax.apps.ImplicitReport, euler='two')", "TypeError",
     "`euler` must be an int"),
    ("reports", "a report's fields are converted: NumPy scalars to Python, JAX arrays to NumPy (oracle)",
     "r = R(voxax.apps.BandsawReport, steps=np.int64(5), cut_final=np.float32(0.5), energy_history=jnp.arange(3.0),"
     " history={'energy': jnp.ones(2)});"
     "assert type(r.steps) is int and type(r.cut_final) is float and isinstance(r.energy_history, np.ndarray);"
     "assert isinstance(r.history['energy'], np.ndarray) and '  steps                    5' in r.summary()", None, ""),
    ("reports", "ImplicitReport summary of empty histories (oracle)",
     "r = R(voxax.apps.ImplicitReport, loss_history=np.zeros(0), euler_history=np.zeros(0, int), steps=0);"
     "s = r.summary(); assert s.startswith('ImplicitReport: 0 steps') and 'Euler characteristic 3' in s, s", None, ""),
    ("reports", "ImplicitReport summary names each change of the Euler characteristic (oracle)",
     "r = R(voxax.apps.ImplicitReport, loss_history=np.array([4.0, 2.0, 1.0]), euler_history=np.array([2, 2, 0]), euler=0);"
     "s = r.summary(); assert 'loss 4 -> 0.25' in s and 'Euler characteristic 2@0 -> 0@2 -> 0' in s, s", None, ""),
    ("reports", "TilingReport summary notes intersecting instances (oracle)",
     "s = R(voxax.apps.TilingReport, instances_intersect=True, intersecting_instance_pairs=4).summary();"
     "assert '4 instance pairs still intersect' in s, s", None, ""),
    ("reports", "to_dict excludes one name given as a string, not every name it contains (oracle)",
     "d = R(voxax.apps.Report).to_dict(exclude='energy_history'); assert 'energy_history' not in d and d['energy'] == 0.25, d",
     None, ""),
    ("reports", "to_dict with exclude 5", "R(voxax.apps.Report).to_dict(exclude=5)", "TypeError",
     "voxax.apps.Report.to_dict: `exclude`"),
    ("reports", "plot_history of a report built by hand (oracle)",
     "fig = R(voxax.apps.Report, history={'energy': np.array([3.0, 2.0]), 'max_w': np.array([1.5, 1.0])}).plot_history();"
     "assert [ax.get_ylabel() for ax in fig.axes] == ['energy', 'max_w']", None, ""),
    ("reports", "plot_history to a file of an unknown format", "R(voxax.apps.Report).plot_history('history.qqq')",
     "ValueError", "voxax.plot.history: `path` must end in one of"),
    ("reports", "plot_history into a missing folder", "R(voxax.apps.Report).plot_history('no/such/folder/h.png')",
     "FileNotFoundError", "voxax.plot.history: cannot write"),
    ("reports", "a report where a mesh goes", f"{BS}(R(voxax.apps.BandsawReport), progress=False)", "TypeError",
     "voxax.apps.optimize_for_bandsaw: expected a voxax.Mesh"),
    ("reports", "a report where a mesh goes, to voxelize", "voxax.voxelize(R(voxax.apps.TilingReport), G)", "TypeError",
     "voxax.voxelize: expected a voxax.Mesh"),
    # -- the applications, refused before the run -------------------------------------------
    ("apps", "bandsaw max_steps 1.5", f"{BS}(BALL, resolution=8, max_steps=1.5, progress=False)", "TypeError",
     "voxax.apps.optimize_for_bandsaw: `max_steps` must be an int"),
    ("apps", "bandsaw max_steps -1", f"{BS}(BALL, resolution=8, max_steps=-1, progress=False)", "ValueError",
     "voxax.apps.optimize_for_bandsaw: `max_steps` must be at least 0"),
    ("apps", "bandsaw resolution 10^9", f"{BS}(BALL, resolution=10**9, progress=False)", "MemoryError",
     "voxax.apps.optimize_for_bandsaw: a 1000000000^3 grid"),
    ("apps", "bandsaw callback 3", f"{BS}(BALL, resolution=8, callback=3, progress=False)", "TypeError",
     "`callback` must be None or callable"),
    ("apps", "bandsaw normalize 'no'", f"{BS}(BALL, resolution=8, normalize='no', progress=False)", "TypeError",
     "`normalize` must be True or False"),
    ("apps", "bandsaw progress 3", f"{BS}(BALL, resolution=8, progress=3)", "TypeError",
     "`progress` must be True or False"),
    ("apps", "bandsaw NaN w", f"{BS}(BALL, resolution=8, w=float('nan'), progress=False)", "ValueError", "`w`"),
    ("apps", "bandsaw int32 working dtype", f"{BS}(BALL, resolution=8, dtype='int32', progress=False)", "TypeError",
     "`dtype`"),
    ("apps", "bandsaw of NaN vertices", f"{BS}((VNAN, F), resolution=8, progress=False)", "ValueError", "NaN"),
    ("apps", "molding axis 1.0", f"{MO}(BALL, 1.0, resolution=8, progress=False)", "ValueError", "`axis`"),
    ("apps", "molding learning rate 'fast'", f"{MO}(BALL, resolution=8, learning_rate='fast', progress=False)",
     "TypeError", "`learning_rate` must be a number"),
    ("apps", "self-intersections max_rounds 1.5", f"{SI}(BALL, resolution=8, max_rounds=1.5, progress=False)",
     "TypeError", "voxax.apps.resolve_self_intersections: `max_rounds` must be an int"),
    ("apps", "self-intersections round_steps 0", f"{SI}(BALL, resolution=8, round_steps=0, progress=False)",
     "ValueError", "`round_steps` must be at least 1"),
    ("apps", "self-intersections refine 'yes'", f"{SI}(BALL, resolution=8, refine='yes', progress=False)",
     "TypeError", "`refine` must be True or False"),
    ("apps", "self-intersections NaN eps", f"{SI}(BALL, resolution=8, eps=float('nan'), progress=False)",
     "ValueError", "`eps`"),
    ("apps", "tiling 1.5 instances", f"{TI}(BALL, instances=1.5, resolution=6, progress=False)", "TypeError",
     "voxax.apps.optimize_tiling: `instances` must be an int or a sequence"),
    ("apps", "tiling counts that are not ints", f"{TI}([BALL, BALL], instances=['a', 2], resolution=6, progress=False)",
     "TypeError", "`instances` must be an int"),
    ("apps", "tiling deform 0", f"{TI}(BALL, instances=2, resolution=6, deform=0, progress=False)", "TypeError",
     "`deform` must be True or False"),
    ("apps", "tiling init 'grid'", f"{TI}(BALL, instances=2, resolution=6, init='grid', progress=False)",
     "ValueError", "`init`"),
    ("apps", "implicit learning rate 'a'", f"{IM}(SPHERE, 0.5, BALL, G, learning_rate='a')", "TypeError",
     "voxax.apps.optimize_implicit: `learning_rate` must be a number"),
    ("apps", "implicit NaN w", f"{IM}(SPHERE, 0.5, BALL, G, w=float('nan'))", "ValueError", "`w` must be > 0"),
    ("apps", "implicit string parameters", f"{IM}(SPHERE, 'a', BALL, G)", "TypeError",
     "`params` must be a pytree of real arrays"),
    ("apps", "implicit target_euler '2'", f"{IM}(SPHERE, 0.5, BALL, G, target_euler='2')", "TypeError",
     "`target_euler` must be an int"),
    ("apps", "implicit callback 3", f"{IM}(SPHERE, 0.5, BALL, G, callback=3)", "TypeError",
     "`callback` must be None or callable"),
    ("apps", "implicit NaN target silhouettes", f"{IM}(SPHERE, 0.5, (np.full((6, 6), np.nan),) * 3, G)",
     "ValueError", "`target` must be finite"),
    ("apps", "implicit complex target silhouettes", f"{IM}(SPHERE, 0.5, (np.zeros((6, 6)) + 1j,) * 3, G)",
     "TypeError", "`target` must be a real array"),
    ("apps", "implicit grid that is not a Grid", f"{IM}(SPHERE, 0.5, BALL, 'grid')", "TypeError", "`grid`"),
    ("apps", "implicit target that is a file name", f"{IM}(SPHERE, 0.5, 'ball.obj', G)", "TypeError",
     "voxax.io.load"),
]

outcomes, test_hostile_input = table(CASES, SETUP_APPS)
