"""The combinatorial part of marching cubes: the C++ kernel, eagerly (exact size) or through XLA (capacity)."""

from __future__ import annotations

import numpy as np

from .._kernels import contour
from .._kernels.contour import Count as _Count
from .._kernels.contour import marching_cubes as _ffi_topology

__all__ = ["_Count", "_ffi_topology", "host_topology"]


def host_topology(values: np.ndarray, level: float, threads: int | None = None):
    """Exact-size topology of one field: `edges (V, 2)`, `faces (F, d)` (int32).

    `values` is a NumPy array (float32 or float64) of the grid's shape; `threads`: as in
    `voxax._kernels.threads` (the result does not depend on it). No input checks: see `isosurface`.
    """
    return contour.topology(values, level, threads)
