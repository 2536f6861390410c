"""The line-crossing kernel (`csrc/raster/`): exact crossings of a mesh with axis-aligned
lines, through its C entry points.

Arrays in, arrays out: the handle (run, size, copy, free) is released here; the dexels
live in `voxax.raster`.
"""

from __future__ import annotations

import ctypes

import numpy as np

from ._ctypes import ERRLEN, I8, I32, I64, VP, D, declare, error_buffer, pointer
from ._ctypes import threads as _threads

__all__ = ["SIGNATURES", "line_crossings"]

SIGNATURES = {
    "voxax_line_crossings": (
        ctypes.c_int,
        [D, ctypes.c_int64, I32, ctypes.c_int64, ctypes.c_int32, D, ctypes.c_int64, D, ctypes.c_int64, ctypes.c_int32,
         ctypes.POINTER(VP), ctypes.c_char_p, ctypes.c_int64],
    ),
    "voxax_crossings_size": (ctypes.c_int64, [VP]),
    "voxax_crossings_copy": (None, [VP, I64, D, I8, I32]),
    "voxax_crossings_free": (None, [VP]),
}


def line_crossings(vertices, faces, axis, coords0, coords1, threads=None, where="voxax.raster.line_crossings"):
    """The crossings of a mesh with the lines along `axis` through `(coords0[i], coords1[j])`:
    `(offsets, depth, sign, face)` (line `i * len(coords1) + j` holds
    `offsets[l]:offsets[l + 1]`)."""
    v = np.ascontiguousarray(vertices, dtype=np.float64)
    f = np.ascontiguousarray(faces, dtype=np.int32)
    c0 = np.ascontiguousarray(coords0, dtype=np.float64)
    c1 = np.ascontiguousarray(coords1, dtype=np.float64)
    lib = declare(SIGNATURES)
    err = error_buffer()
    handle = VP()
    status = lib.voxax_line_crossings(
        pointer(v, D), len(v), pointer(f, I32), len(f), int(axis), pointer(c0, D), len(c0), pointer(c1, D), len(c1),
        _threads(threads), ctypes.byref(handle), err, ERRLEN,
    )  # fmt: skip
    if status != 0:
        raise ValueError(f"{where}: " + err.value.decode("utf-8", "replace").removeprefix("voxax: "))
    try:
        n = int(lib.voxax_crossings_size(handle))
        offsets = np.empty(len(c0) * len(c1) + 1, np.int64)
        depth = np.empty(n, np.float64)
        sign = np.empty(n, np.int8)
        face = np.empty(n, np.int32)
        lib.voxax_crossings_copy(handle, pointer(offsets, I64), pointer(depth, D), pointer(sign, I8), pointer(face, I32))
    finally:
        lib.voxax_crossings_free(handle)
    return offsets, depth, sign, face
