"""Loads the compiled kernels and registers them as XLA FFI targets."""

from __future__ import annotations

import ctypes
import os
from pathlib import Path

import jax
import numpy as np

__all__ = ["BACKWARD", "FORWARD", "TANGENT", "MARCHING_CUBES", "CLOSEST_POINTS", "FIRST_HITS", "KNN", "TARGETS",
           "CVT_ASSIGN", "WINDING_CHECK", "FINITE_CHECK", "SPARSE_FORWARD", "SPARSE_BACKWARD", "SPARSE_TANGENT", "grid_attributes",
           "kernel_constants", "library", "library_path"]

FORWARD = "voxax_forward"
BACKWARD = "voxax_backward"
TANGENT = "voxax_tangent"
MARCHING_CUBES = "voxax_marching_cubes"
CLOSEST_POINTS = "voxax_closest_points"
FIRST_HITS = "voxax_first_hits"
KNN = "voxax_knn"
CVT_ASSIGN = "voxax_cvt_assign"
WINDING_CHECK = "voxax_winding_check"
FINITE_CHECK = "voxax_finite_check"
SPARSE_FORWARD = "voxax_sparse_forward"
SPARSE_BACKWARD = "voxax_sparse_backward"
SPARSE_TANGENT = "voxax_sparse_tangent"

# Every FFI target the library exports, by name (each is also the exported symbol). The one
# registry of voxax's custom calls: registration and the export safety checks read it.
TARGETS: tuple[str, ...] = (FORWARD, BACKWARD, TANGENT, MARCHING_CUBES, CLOSEST_POINTS, FIRST_HITS, KNN, CVT_ASSIGN,
                            WINDING_CHECK, SPARSE_FORWARD, SPARSE_BACKWARD, SPARSE_TANGENT, FINITE_CHECK)

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
    for name in TARGETS:
        jax.ffi.register_ffi_target(name, jax.ffi.pycapsule(getattr(lib, name)), platform="cpu")
    lib.voxax_constants.argtypes = [ctypes.POINTER(ctypes.c_double), ctypes.c_int]
    lib.voxax_constants.restype = ctypes.c_int
    return lib


_LIB = _register()

# The order in which `voxax_constants` (csrc/common/constants.cc) writes the bounds.
_CONSTANT_NAMES = ("MAX_ABS_COORDINATE", "MIN_CELL_VOLUME", "MAX_CELL_VOLUME", "MAX_CELLS_PER_AXIS")


def kernel_constants() -> dict[str, float]:
    """The numerical bounds compiled into the kernels, by name.

    **Returns:**

    A dict with `MAX_ABS_COORDINATE`, `MIN_CELL_VOLUME`, `MAX_CELL_VOLUME` (which
    `voxax._constants` must equal) and `MAX_CELLS_PER_AXIS`.
    """
    count = _LIB.voxax_constants(None, 0)
    if count != len(_CONSTANT_NAMES):
        raise RuntimeError(f"voxax: the kernels export {count} constants, expected {len(_CONSTANT_NAMES)}")
    values = (ctypes.c_double * count)()
    _LIB.voxax_constants(values, count)
    return dict(zip(_CONSTANT_NAMES, values))


def library() -> ctypes.CDLL:
    """The loaded kernel library (for the eager host entry points called through ctypes)."""
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
    # A slab of a larger grid (`Grid.slab`) is passed as a window of its frame along x, so
    # that its planes are the frame's bit for bit.
    frame = getattr(grid, "frame", None)
    if frame is None:
        attrs["x_first"], attrs["x_count"] = np.int64(0), np.int64(0)
    else:
        (x0, x1, nx), first = frame
        attrs["x0"], attrs["x1"], attrs["nx"] = np.float64(x0), np.float64(x1), np.int64(nx)
        attrs["x_first"], attrs["x_count"] = np.int64(first), np.int64(grid.shape[0])
    return attrs
