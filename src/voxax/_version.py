"""voxax's version: the installed distribution's metadata, or the source tree's
pyproject.toml when the package is imported from a checkout (`PYTHONPATH=src`)."""

from __future__ import annotations

import re
from importlib import metadata
from pathlib import Path

__all__ = ["version"]

_PACKAGE = Path(__file__).resolve().parent


def _installed() -> metadata.Distribution | None:
    try:
        return metadata.distribution("voxax")
    except metadata.PackageNotFoundError:
        return None


def _is_this_package(dist: metadata.Distribution) -> bool:
    """Whether the distribution's files are the package being imported (not another copy)."""
    try:
        return Path(dist.locate_file("voxax/__init__.py")).resolve() == _PACKAGE / "__init__.py"
    except (OSError, TypeError, ValueError):
        return False


def _source_tree() -> str | None:
    """The `[project]` version of the checkout holding this package (src/voxax), if any."""
    pyproject = _PACKAGE.parent.parent / "pyproject.toml"
    if _PACKAGE.parent.name != "src" or not pyproject.is_file():
        return None
    text = pyproject.read_text(encoding="utf-8")
    project = re.search(r"^\[project\]\s*$(.*?)(?=^\[|\Z)", text, re.MULTILINE | re.DOTALL)
    if project is None or not re.search(r'^name\s*=\s*"voxax"\s*$', project.group(1), re.MULTILINE):
        return None
    found = re.search(r'^version\s*=\s*"([^"]+)"\s*$', project.group(1), re.MULTILINE)
    return found.group(1) if found else None


def version() -> str:
    """The version of the imported voxax.

    The installed distribution's metadata when it describes this copy of the package;
    else the version in the pyproject.toml of the source tree the package is imported
    from; else the metadata of whatever voxax is installed; else `"0+unknown"`.
    """
    dist = _installed()
    if dist is not None and _is_this_package(dist):
        return dist.version
    tree = _source_tree()
    if tree is not None:
        return tree
    return dist.version if dist is not None else "0+unknown"
