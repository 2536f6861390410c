"""Loads the compiled kernels and registers them as XLA FFI targets."""

from __future__ import annotations

import ctypes
import os
from pathlib import Path

import jax
import numpy as np

__all__ = ["FORWARD", "BACKWARD", "library_path", "library", "grid_attributes"]

FORWARD = "voxax_forward"
BACKWARD = "voxax_backward"

_NAMES = ("libvoxax_kernels.so", "libvoxax_kernels.dylib", "voxax_kernels.dll")


def library_path() -> Path:
    """The path of the compiled kernel library.

    `VOXAX_KERNELS` overrides the search (used to load a sanitizer build). Otherwise the
    library is looked up in every directory of the `voxax` package's `__path__`, which
    also covers editable installs.
    """
    override = os.environ.get("VOXAX_KERNELS")
    if override:
        path = Path(override)
        if not path.is_file():
            raise ImportError(f"VOXAX_KERNELS={override!r} does not name a file")
        return path
    import voxax

    for folder in voxax.__path__:
        for name in _NAMES:
            candidate = Path(folder) / name
            if candidate.is_file():
                return candidate
    raise ImportError(
        "voxax: the compiled kernels (libvoxax_kernels) were not found next to the package. "
        "Install voxax with `pip install .` from the source tree so that they are built."
    )


def _register() -> ctypes.CDLL:
    lib = ctypes.CDLL(str(library_path()))
    for name in (FORWARD, BACKWARD):
        jax.ffi.register_ffi_target(name, jax.ffi.pycapsule(getattr(lib, name)), platform="cpu")
    return lib


_LIB = _register()


def library() -> ctypes.CDLL:
    """The loaded kernel library (for its plain C entry points, e.g. the exact intersection test)."""
    return _LIB


def grid_attributes(grid) -> dict:
    """The grid as FFI attributes, with the exact scalar types the handlers declare."""
    lower = list(grid.lower) + [0.0] * (3 - grid.dim)
    upper = list(grid.upper) + [1.0] * (3 - grid.dim)
    shape = list(grid.shape) + [1] * (3 - grid.dim)
    attrs = {}
    for axis, name in enumerate("xyz"):
        attrs[f"{name}0"] = np.float64(lower[axis])
        attrs[f"{name}1"] = np.float64(upper[axis])
        attrs[f"n{name}"] = np.int64(shape[axis])
    return attrs
