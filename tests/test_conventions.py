"""The API's rules (docs/conventions.md, "The API's rules"), checked on every public callable.

The static checks walk every public function and class of every namespace; the dynamic
checks call every function that takes a surface with each surface form (a `voxax.Mesh`, a
`trimesh.Trimesh`, a `(vertices, faces)` pair, and vertices and faces as two arguments)
and require equal results, typed results and messages that name the function.
"""

from __future__ import annotations

import dataclasses
import inspect

import numpy as np
import pytest
import trimesh

import voxax

NAMESPACES = (
    "voxax", "voxax.apps", "voxax.baselines", "voxax.curves", "voxax.cvt", "voxax.data", "voxax.energies",
    "voxax.esi", "voxax.fabricate", "voxax.fc", "voxax.fields", "voxax.io", "voxax.metrics", "voxax.nesi",
    "voxax.plot", "voxax.raster", "voxax.reference",
)

# Callables whose first parameter is named like a surface but is not one: value types built
# from arrays, and energies of a deformation (deformed and rest vertices on fixed faces).
NOT_SURFACE_ARGUMENTS = {
    "voxax.Mesh", "voxax.IsoMesh", "voxax.curves.Curve", "voxax.cvt.RemeshResult",
    "voxax.energies.arap", "voxax.energies.arap_rotations", "voxax.energies.cotangent_weights",
}

def _params(entries, name_of=lambda e: e[0]):
    return [pytest.param(e, id=name_of(e)) for e in entries]


# The drivers that run longer than a second: each takes `progress`.
LONG_DRIVERS = (
    "voxax.minimize", "voxax.apps.resolve_self_intersections", "voxax.apps.optimize_for_bandsaw",
    "voxax.apps.optimize_tiling", "voxax.apps.optimize_for_molding", "voxax.cvt.remesh", "voxax.esi.select",
    "voxax.nesi.fit",
)


def _public_callables():
    seen, out = set(), []
    for ns in NAMESPACES:
        module = voxax if ns == "voxax" else getattr(voxax, ns.split(".", 1)[1])
        for name in getattr(module, "__all__", ()):
            obj = getattr(module, name, None)
            if obj is None or inspect.ismodule(obj) or not callable(obj) or id(obj) in seen:
                continue
            seen.add(id(obj))
            try:
                sig = inspect.signature(obj)
            except (TypeError, ValueError):
                continue
            out.append((f"{ns}.{name}", obj, sig))
    return out


CALLABLES = _public_callables()


def test_the_walk_covers_every_namespace():
    assert len(CALLABLES) > 150
    for ns in NAMESPACES:
        assert any(name.rsplit(".", 1)[0] == ns for name, _, _ in CALLABLES), ns


@pytest.mark.parametrize("entry", _params(CALLABLES))
def test_randomness_is_key(entry):
    """`key` names the randomness; `seed` only survives as a deprecated alias (default None)."""
    name, _, sig = entry
    if "seed" in sig.parameters:
        assert "key" in sig.parameters, f"{name} takes `seed` but no `key`"
        assert sig.parameters["seed"].default is None, f"{name}: the deprecated `seed` must default to None"


@pytest.mark.parametrize("entry", _params(CALLABLES))
def test_threads_has_one_meaning(entry):
    name, _, sig = entry
    if "threads" in sig.parameters:
        assert sig.parameters["threads"].default is None, f"{name}: `threads` must default to None"


@pytest.mark.parametrize("entry", _params(CALLABLES))
def test_progress_has_one_default(entry):
    name, _, sig = entry
    if "progress" in sig.parameters:
        assert sig.parameters["progress"].default is True, f"{name}: `progress` must default to True"


@pytest.mark.parametrize("name", LONG_DRIVERS)
def test_long_drivers_take_progress(name):
    sig = dict((n, s) for n, _, s in CALLABLES)[name]
    assert "progress" in sig.parameters


@pytest.mark.parametrize("entry", _params(CALLABLES))
def test_a_surface_argument_takes_every_form(entry):
    """A first parameter `vertices` is followed by `faces=None`; a first parameter `mesh` also
    accepts `faces` (the two-argument form, through `_validate.surface_first`)."""
    name, _, sig = entry
    params = list(sig.parameters.values())
    if not params or name in NOT_SURFACE_ARGUMENTS:
        return
    if params[0].name == "vertices":
        assert len(params) > 1 and params[1].name == "faces" and params[1].default is None, (
            f"{name}{sig}: `vertices` must be followed by `faces=None`"
        )
    elif params[0].name == "mesh":
        assert "faces" in sig.parameters, f"{name}{sig}: a `mesh` argument must also take `vertices, faces`"


# -- dynamic: every surface form gives the same result --------------------------------------------

BALL = voxax.data.icosphere(1, radius=0.6)
GRID = voxax.Grid((-0.8, -0.7, -0.75), (0.75, 0.8, 0.7), (5, 6, 7))
POINTS = np.array([[0.0, 0.0, 0.0], [0.5, 0.1, -0.2], [0.9, 0.9, 0.9]])
RAYS = (np.array([[0.0, 0.0, -2.0], [0.1, 0.2, 2.0]]), np.array([[0.0, 0.0, 1.0], [0.0, 0.0, -1.0]]))

# (name, positional arguments after the surface): one call per surface form.
SURFACE_CALLS = [
    ("voxax.voxelize", (GRID,)),
    ("voxax.voxelize_sparse", (GRID,)),
    ("voxax.winding_number", (POINTS,)),
    ("voxax.intersections", ()),
    ("voxax.closest_points", (POINTS,)),
    ("voxax.first_hits", RAYS),
    ("voxax.baselines.point_sampled", (GRID,)),
    ("voxax.reference.voxelize", (GRID,)),
    ("voxax.reference.signed_volume", ()),
    ("voxax.io.is_watertight", ()),
    ("voxax.io.normalize", ()),
    ("voxax.metrics.sample_surface", (50,)),
    ("voxax.metrics.triangle_quality", ()),
    ("voxax.metrics.euler_characteristic", ()),
    ("voxax.metrics.manifold_report", ()),
    ("voxax.raster.line_crossings", (GRID, 2)),
    ("voxax.fc.encode", (voxax.Grid.around(BALL, 6),)),
    ("voxax.fc.pieces", (voxax.Grid.around(BALL, 6),)),
    ("voxax.fc.edge_topology", ()),
    ("voxax.esi.depth_map", ((0.0, 0.0, 1.0),)),
]


def _resolve(name):
    obj = voxax
    for part in name.split(".")[1:]:
        obj = getattr(obj, part)
    return obj


def _same(a, b) -> bool:
    """Equality by value through arrays, tuples, named tuples, dataclasses and meshes."""
    if isinstance(a, (voxax.Mesh,)):
        return _same((a.vertices, a.faces), (b.vertices, b.faces))
    if dataclasses.is_dataclass(a) and not isinstance(a, type):
        return type(a) is type(b) and all(
            _same(getattr(a, f.name), getattr(b, f.name)) for f in dataclasses.fields(a)
        )
    if isinstance(a, (tuple, list)):
        return type(a) is type(b) and len(a) == len(b) and all(_same(x, y) for x, y in zip(a, b))
    if isinstance(a, dict):
        return a.keys() == b.keys() and all(_same(a[k], b[k]) for k in a)
    if hasattr(a, "shape") or isinstance(a, (int, float, np.number, bool)):
        return np.array_equal(np.asarray(a), np.asarray(b), equal_nan=True)
    return a == b


def _forms():
    v, f = np.asarray(BALL.vertices), np.asarray(BALL.faces)
    tm = trimesh.Trimesh(v, f, process=False)
    return {"mesh": ((BALL,), {}), "trimesh": ((tm,), {}), "pair": (((v, f),), {}), "arrays": ((v, f), {})}


@pytest.mark.parametrize("call", _params(SURFACE_CALLS))
def test_every_surface_form_gives_the_same_result(call):
    name, args = call
    fn = _resolve(name)
    results = {form: fn(*lead, *args, **kw) for form, (lead, kw) in _forms().items()}
    first = results["mesh"]
    assert not isinstance(first, dict), f"{name} returns a bare dict"
    for form, value in results.items():
        assert _same(first, value), f"{name}: the {form} form gives another result"


@pytest.mark.parametrize("call", _params(SURFACE_CALLS))
def test_errors_name_the_function(call):
    """A mesh whose faces index past its vertices is refused with "voxax.<ns>.<fn>: ..."."""
    name, args = call
    fn = _resolve(name)
    bad = (np.asarray(BALL.vertices), np.asarray(BALL.faces) + BALL.n_vertices)
    with pytest.raises(ValueError) as info:
        fn(bad, *args)
    assert str(info.value).startswith(f"{name}:"), str(info.value)
