"""Every public callable of voxax appears in the code of at least one hostile case
(tests/hostile/test_*.py), directly or through an alias of its table's setup (`lc =
voxax.raster.line_crossings`), or in the explicit PENDING set below, which must be exact: a
name covered by a case and still listed fails, so the gap stays visible and shrinks."""

from __future__ import annotations

import importlib.util
import re
import sys
from pathlib import Path

from _hostile_driver import SETUP

HERE = Path(__file__).resolve().parent


def _module(path: Path, name: str):
    """The module at `path`, loaded under `name` (tests/test_io.py and
    tests/hostile/test_hostile_io.py share a stem)."""
    if name in sys.modules:
        return sys.modules[name]
    spec = importlib.util.spec_from_file_location(name, path)
    module = importlib.util.module_from_spec(spec)
    sys.modules[name] = module
    spec.loader.exec_module(module)
    return module


CALLABLES = _module(HERE.parent / "test_conventions.py", "_conventions_walk").CALLABLES

# Public callables without a hostile case yet, by system.
PENDING: set = set()


def _aliases(setup: str) -> dict:
    """`{name: expression}` of the setup's one-name assignments (`lc = voxax.raster.line_crossings`,
    `RM = lambda *a, **kw: cvt.remesh(...)`)."""
    out = {}
    for line in setup.splitlines():
        m = re.match(r"([A-Za-z_]\w*)\s*=(?!=)\s*(.+)$", line)
        if m:
            out[m.group(1)] = m.group(2)
    return out


def _expanded(code: str, aliases: dict) -> str:
    """`code` with the expression of every alias it uses appended (to a fixed point: an
    alias may use another), so that a name called through an alias counts."""
    seen, todo = set(), [code]
    while todo:
        text = todo.pop()
        for name, expr in aliases.items():
            if name not in seen and re.search(rf"(?<![\w.]){re.escape(name)}(?!\w)", text):
                seen.add(name)
                todo.append(expr)
    return "\n".join([code] + [aliases[name] for name in sorted(seen)])


def _codes() -> str:
    codes = []
    for path in sorted(HERE.glob("test_*.py")):
        if path.stem == "test_coverage":
            continue
        module = _module(path, f"_hostile_{path.stem}")
        setup = getattr(getattr(module, "test_hostile_input", None), "setup", None) or SETUP
        aliases = _aliases(setup)
        codes += [_expanded(case[2], aliases) for case in module.CASES]
    return "\n".join(codes)


def _covered(name: str, code: str) -> bool:
    """`voxax.ns.fn` is covered by `voxax.ns.fn` or `ns.fn` (a namespace imported by the
    setup) followed by `(`, `.` or a word boundary."""
    parts = name.split(".")
    forms = {name} | ({".".join(parts[-2:])} if len(parts) > 2 else set())
    return any(re.search(re.escape(f) + r"(?![\w])", code) for f in forms)


def uncovered() -> set:
    code = _codes()
    return {name for name, _, _ in CALLABLES if not _covered(name, code)}


def test_every_public_callable_has_a_hostile_case_or_is_pending():
    missing = uncovered()
    assert not missing - PENDING, f"public callables without a hostile case: {sorted(missing - PENDING)}"
    assert not PENDING - missing, f"covered now, remove from PENDING: {sorted(PENDING - missing)}"
