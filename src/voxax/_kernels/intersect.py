"""The exact triangle-triangle intersection kernel (`csrc/intersect/`): its host entry point.

Arrays in, arrays out: the meshes are checked (and welded) by `voxax._spatial.intersect`.
"""

from __future__ import annotations

import ctypes

import numpy as np

from ._ctypes import ERRLEN, VP, declare, error_buffer

__all__ = ["intersections", "library"]

_SIGNATURES = {
    "voxax_intersections": (ctypes.c_int64, [
        VP, ctypes.c_int64, VP, ctypes.c_int64, VP, ctypes.c_int64, VP, ctypes.c_int64,
        ctypes.c_int64, ctypes.POINTER(VP), ctypes.c_char_p, ctypes.c_int64,
    ]),
    "voxax_intersections_copy": (None, [VP, VP]),
    "voxax_intersections_free": (None, [VP]),
}  # fmt: skip


def library() -> ctypes.CDLL:
    """The kernel library with the intersection test's signatures declared."""
    return declare(_SIGNATURES)


def _ptr(a):
    return a.ctypes.data_as(VP) if a is not None and a.size else None


def intersections(va: np.ndarray, fa: np.ndarray, other, threads: int) -> np.ndarray:
    """The intersecting face pairs `(K, 2) int64`, sorted: of mesh `(va (V, 3) f64, fa (F, 3)
    i32)` with itself (`other` None), or against `other = (vb, fb)`. `threads`: 0 for every
    core."""
    lib = library()
    if other is None:
        args = (_ptr(va), va.shape[0], _ptr(fa), fa.shape[0], None, 0, None, 0)
    else:
        vb, fb = other
        # A non-null pointer marks the two-mesh test even when the other mesh is empty.
        dummy = np.zeros(3)
        pb = _ptr(vb) or dummy.ctypes.data_as(VP)
        args = (_ptr(va), va.shape[0], _ptr(fa), fa.shape[0], pb, vb.shape[0], _ptr(fb), fb.shape[0])
    handle = VP()
    err = error_buffer()
    count = lib.voxax_intersections(*args, int(threads), ctypes.byref(handle), err, ERRLEN)
    if count < 0:
        raise ValueError(err.value.decode("utf-8", "replace"))
    try:
        pairs = np.empty((count, 2), dtype=np.int64)
        if count:
            lib.voxax_intersections_copy(handle, pairs.ctypes.data_as(VP))
    finally:
        lib.voxax_intersections_free(handle)
    return pairs
