"""The Faithful Contouring kernels (`csrc/fc/`): cell pieces and QEF rows, edge signs,
exact node sides and dual contouring, through their C entry points.

Arrays in, arrays out: every handle the kernels return (run, size, copy, free) is released
here; the algorithm lives in `voxax.fc`.
"""

from __future__ import annotations

import ctypes

import numpy as np

from ._ctypes import ERRLEN, I8, I32, I64, VP, D, check, declare, error_buffer, pointer
from ._ctypes import threads as _threads

__all__ = ["SIGNATURES", "decode", "encode_pieces", "encode_rows", "node_side", "signs"]

_C64, _C32 = ctypes.c_int64, ctypes.c_int32
SIGNATURES = {
    "voxax_fc_encode": (
        ctypes.c_int,
        [D, _C64, I32, _C64, ctypes.POINTER(ctypes.c_uint8), D, I64, D, _C32, I64, _C64, _C32, ctypes.POINTER(VP),
         I64, ctypes.c_char_p, _C64],
    ),
    "voxax_fc_rows": (None, [VP, I64, I32, D, D, D, I32, I64, I32]),
    "voxax_fc_pieces": (None, [VP, I64, I32, D, D]),
    "voxax_fc_free": (None, [VP]),
    "voxax_fc_decode": (
        ctypes.c_int,
        [I64, D, D, I8, _C64, I64, _C32, _C32, ctypes.POINTER(VP), I64, ctypes.c_char_p, _C64],
    ),
    "voxax_fc_triangles": (None, [VP, I64]),
    "voxax_fc_node_side": (ctypes.c_int, [D, _C64, I32, _C64, _C64, I32, D, I32, I8, ctypes.c_char_p, _C64]),
    "voxax_fc_free_triangles": (None, [VP]),
    "voxax_fc_signs": (
        ctypes.c_int,
        [I64, _C64, I64, I64, I8, _C64, _C32, I8, ctypes.POINTER(VP), I64, ctypes.c_char_p, _C64],
    ),
}

_CTYPES = {np.dtype(np.float64): D, np.dtype(np.int32): I32, np.dtype(np.int64): I64}

# Flags of voxax_fc_encode.
CLAMP, COMPONENTS, RECORD_FACES, PIECES, OPEN_BOUNDARIES = 1, 2, 4, 8, 16  # as csrc/fc/fc_host.cc reads them


def _lib():
    return declare(SIGNATURES)


def _raise(status, err, where):
    if status != 0:
        msg = err.value.decode("utf-8", "replace").removeprefix("voxax: ")
        raise ValueError(f"{where}: {msg}")


def _copy_out(copy, handle, free, *specs):
    """Fresh arrays of `specs` (`(shape, dtype)` pairs) filled by `copy(handle, *pointers)`;
    the handle is released by `free(handle)` in any case."""
    try:
        out = [np.empty(shape, dtype) for shape, dtype in specs]
        copy(handle, *(pointer(a, _CTYPES[a.dtype]) for a in out))
    finally:
        free(handle)
    return out


def _encode(where, vertices, faces, lower, upper, shape, params, flags, joined, threads):
    lib = _lib()
    V = np.ascontiguousarray(vertices, dtype=np.float64)
    F = np.ascontiguousarray(faces, dtype=np.int32)
    box = np.ascontiguousarray(np.concatenate([lower, upper]), dtype=np.float64)
    shape = np.ascontiguousarray(shape, dtype=np.int64)
    prm = np.ascontiguousarray(params, dtype=np.float64)
    if joined is not None:
        joined = np.ascontiguousarray(joined, dtype=np.int64)
    handle = VP()
    sizes = np.zeros(3, np.int64)
    err = error_buffer()
    status = lib.voxax_fc_encode(
        pointer(V, D), len(V), pointer(F, I32), len(F), None, pointer(box, D), pointer(shape, I64), pointer(prm, D),
        int(flags), None if joined is None else pointer(joined, I64), 0 if joined is None else len(joined),
        _threads(threads), ctypes.byref(handle), pointer(sizes, I64), err, ERRLEN,
    )  # fmt: skip
    _raise(status, err, where)
    return handle, sizes


def encode_rows(where, vertices, faces, lower, upper, shape, params, flags, joined=None, threads=None):
    """The token rows of a mesh on a grid: `(index, component, offsets, normals, area,
    face_count, faces)`, `face_count` and `faces` (the faces of each row, in row order) only
    with `RECORD_FACES` in `flags` (else zeros and empty)."""
    handle, sizes = _encode(where, vertices, faces, lower, upper, shape, params, flags, joined, threads)
    lib = _lib()
    k, nfc = int(sizes[0]), int(sizes[1])
    # The face counts are written only when the faces were recorded.
    fcount_k = k if flags & RECORD_FACES else 0
    specs = ((k, np.int64), (k, np.int32), ((k, 3), np.float64), ((k, 3), np.float64), (k, np.float64))
    specs += ((k, np.int32), (fcount_k, np.int64), (nfc, np.int32))
    index, comp, off, nrm, area, _, fcount, rfaces = _copy_out(lib.voxax_fc_rows, handle, lib.voxax_fc_free, *specs)
    if not flags & RECORD_FACES:
        fcount = np.zeros(k, np.int64)
    return index, comp, off, nrm, area, fcount, rfaces


def encode_pieces(where, vertices, faces, lower, upper, shape, threads=None):
    """The pieces of a mesh clipped into a grid's cells: `(cell, face, area, centroid)`."""
    handle, sizes = _encode(where, vertices, faces, lower, upper, shape, (1.0, 1e-3, 1.0), CLAMP | PIECES, None, threads)
    lib, n = _lib(), int(sizes[2])
    specs = ((n, np.int64), (n, np.int32), (n, np.float64), ((n, 3), np.float64))
    return tuple(_copy_out(lib.voxax_fc_pieces, handle, lib.voxax_fc_free, *specs))


def node_side(vertices, faces, which, nodes, axis) -> np.ndarray:
    """+1 where the crossing of each face `which[i]` with the line along `axis` through
    `nodes[i]` lies above the node, -1 below (exact, nodes perturbed as the lines are)."""
    V = np.ascontiguousarray(vertices, np.float64)
    F = np.ascontiguousarray(faces, np.int32)
    which = np.ascontiguousarray(which, np.int32)
    nodes = np.ascontiguousarray(nodes, np.float64)
    ax = np.full(len(which), axis, np.int32)
    out = np.zeros(len(which), np.int8)
    err = error_buffer()
    status = _lib().voxax_fc_node_side(
        pointer(V, D), len(V), pointer(F, I32), len(F), len(which), pointer(which, I32), pointer(nodes, D),
        pointer(ax, I32), pointer(out, I8), err, ERRLEN,
    )  # fmt: skip
    check(status, err)
    return out


def signs(index, shape, edge, sign, threads=None):
    """`(K, 12)` int8 net signs of the rows' edges (one row per sorted cell `index`) from the
    crossings `(edge, sign)`, and `(M, 2)` int64 pairs `(cell, crossing)`: the cells around
    signed edges that have no row, with the crossing each takes its row from."""
    lib = _lib()
    index = np.ascontiguousarray(index, np.int64)
    edge = np.ascontiguousarray(edge, np.int64)
    sign = np.ascontiguousarray(sign, np.int8)
    shape = np.ascontiguousarray(shape, np.int64)
    S = np.zeros((len(index), 12), np.int8)
    handle = VP()
    count = np.zeros(1, np.int64)
    err = error_buffer()
    status = lib.voxax_fc_signs(
        pointer(index, I64), len(index), pointer(shape, I64), pointer(edge, I64), pointer(sign, I8), len(edge),
        _threads(threads), pointer(S, I8), ctypes.byref(handle), pointer(count, I64), err, ERRLEN,
    )  # fmt: skip
    check(status, err)
    (pairs,) = _copy_out(lib.voxax_fc_triangles, handle, lib.voxax_fc_free_triangles, ((int(count[0]), 2), np.int64))
    return S, pairs


def decode(where, index, anchors, normals, edge_signs, shape, split, threads=None) -> np.ndarray:
    """`(T, 3)` int64 triangles (row indices) of the dual contouring of token rows;
    `split` 0 (normals), 1 (short diagonal) or 2 (first corner)."""
    lib = _lib()
    index = np.ascontiguousarray(index, np.int64)
    P = np.ascontiguousarray(anchors, np.float64)
    N = np.ascontiguousarray(normals, np.float64)
    S = np.ascontiguousarray(edge_signs, np.int8)
    shape = np.ascontiguousarray(shape, np.int64)
    handle = VP()
    count = np.zeros(1, np.int64)
    err = error_buffer()
    status = lib.voxax_fc_decode(
        pointer(index, I64), pointer(P, D), pointer(N, D), pointer(S, I8), len(index), pointer(shape, I64), int(split),
        _threads(threads), ctypes.byref(handle), pointer(count, I64), err, ERRLEN,
    )  # fmt: skip
    if status != 0:
        lib.voxax_fc_free_triangles(handle)
    _raise(status, err, where)
    (tris,) = _copy_out(lib.voxax_fc_triangles, handle, lib.voxax_fc_free_triangles, ((int(count[0]), 3), np.int64))
    return tris
