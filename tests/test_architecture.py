"""docs/architecture.md lists every module of the package and every folder of csrc/, and
nothing that does not exist."""

from __future__ import annotations

import re
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
PACKAGE = ROOT / "src" / "voxax"
DOC = (ROOT / "docs" / "architecture.md").read_text()
ROWS = [line for line in DOC.splitlines() if line.startswith("|")]


def _modules() -> list[str]:
    return sorted(p.relative_to(PACKAGE).as_posix() for p in PACKAGE.rglob("*.py"))


def _listed(rel: str) -> bool:
    """Listed by its path (`esi/_select.py`), or by its name in the row of its package (`cvt/`)."""
    if f"`{rel}`" in DOC:
        return True
    folder, _, name = rel.rpartition("/")
    in_row = name == "__init__.py" or any(f"`{folder}/`" in row and f"`{name}`" in row for row in ROWS)
    return bool(folder) and in_row and any(f"`{folder}/`" in row for row in ROWS)


def test_every_module_is_in_the_architecture_doc():
    missing = [rel for rel in _modules() if not _listed(rel)]
    assert not missing, f"docs/architecture.md does not list: {missing}"


def test_the_architecture_doc_lists_no_module_that_does_not_exist():
    first_cells = " ".join(row.split("|")[1] for row in ROWS if row.count("|") > 2)
    named = set(re.findall(r"`((?:_?[a-z_]+/)*_?[a-z_]+\.py)`", first_cells))
    stale = sorted(rel for rel in named if "/" in rel and not (PACKAGE / rel).is_file())
    stale += sorted(rel for rel in named if "/" not in rel and not any(PACKAGE.rglob(rel)))
    assert not stale, f"docs/architecture.md names modules that do not exist: {stale}"


def test_every_csrc_folder_is_in_the_architecture_doc():
    folders = sorted(p.name for p in (ROOT / "csrc").iterdir() if p.is_dir())
    missing = [name for name in folders if f"`{name}`" not in DOC and f"csrc/{name}/" not in DOC]
    assert not missing, f"docs/architecture.md does not name the csrc/ folders {missing}"


def test_only_the_kernels_package_knows_the_c_abi():
    """ctypes, FFI calls and C signatures appear in `voxax._kernels` only."""
    offenders = []
    for path in PACKAGE.rglob("*.py"):
        rel = path.relative_to(PACKAGE).as_posix()
        if rel.startswith("_kernels/"):
            continue
        text = path.read_text()
        for pattern in ("import ctypes", "jax.ffi.ffi_call", "argtypes", ".restype"):
            if pattern in text:
                offenders.append(f"{rel}: {pattern}")
    assert not offenders, "the C ABI outside voxax._kernels:\n" + "\n".join(sorted(offenders))


def test_csrc_suffixes_say_what_a_file_holds():
    """`*_ffi.cc` holds FFI handlers and no C entry points; `*_host.cc` the reverse."""
    wrong = []
    for path in (ROOT / "csrc").rglob("*.cc"):
        text = path.read_text()
        handlers, entry_points = "XLA_FFI_DEFINE_HANDLER" in text, 'extern "C"' in text
        if path.name.endswith("_ffi.cc") and entry_points:
            wrong.append(f"{path.name}: C entry points in an FFI file")
        if path.name.endswith("_host.cc") and handlers:
            wrong.append(f"{path.name}: FFI handlers in a host file")
    assert not wrong, wrong
