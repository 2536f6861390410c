"""The ESI kernels (`csrc/esi/`): the column ray casts of the axis selection
(`columns_host.cc`) and the dense sums of its bounds (`bounds_host.cc`), through ctypes.

Arrays in, arrays out: the selection that uses them lives in `voxax.esi`.
"""

from __future__ import annotations

import ctypes
from typing import NamedTuple

import numpy as np

from ._ctypes import ERRLEN, I32, I64, D, check, declare, error_buffer, pointer
from ._ctypes import threads as _threads

__all__ = [
    "Casts",
    "bound_blocks",
    "bound_removals",
    "bound_samples",
    "column_hits",
    "column_inside",
    "column_known",
    "column_lists",
    "column_test",
]


_COLUMN_SIGNATURES = {
    "voxax_column_test": (
        ctypes.c_int,
        [
            D,
            I64,
            ctypes.c_int64,
            ctypes.c_int64,
            D,
            ctypes.c_int64,
            D,
            ctypes.c_int32,
            ctypes.POINTER(ctypes.c_uint8),
            ctypes.c_char_p,
            ctypes.c_int64,
        ],
    ),
}


def column_test(points, ks, params, G: int, lims, threads) -> np.ndarray:
    """`(n,)` bool: whether point `i`, in the frame of direction `ks[i]` (`params[k]`: the
    frame's axes as a row-major 3 x 3 matrix, its centre in frame coordinates, the
    direction's sign on its line, the grid's half width and cell width), lies over the
    `G x G` grid with `sign * depth < lims[k, cell]` (C++, see `csrc/esi/columns_host.cc`)."""
    p = np.ascontiguousarray(points, np.float64).reshape(-1, 3)
    ks = np.ascontiguousarray(ks, np.int64).reshape(-1)
    if len(ks) != len(p):
        raise ValueError(f"column test: {len(p)} points but {len(ks)} directions")
    params = np.ascontiguousarray(params, np.float64)
    lims = np.ascontiguousarray(lims, np.float64)
    K = len(params)
    if params.shape != (K, 15) or lims.shape != (K, G * G):
        raise ValueError(f"column test: params {params.shape} and lims {lims.shape} for K = {K}, G = {G}")
    out = np.zeros(len(p), np.uint8)
    lib = declare(_COLUMN_SIGNATURES)
    err = error_buffer()
    status = lib.voxax_column_test(
        pointer(p, D),
        pointer(ks, I64),
        len(p),
        K,
        pointer(params, D),
        int(G),
        pointer(lims, D),
        _threads(threads),
        out.ctypes.data_as(ctypes.POINTER(ctypes.c_uint8)),
        err,
        ERRLEN,
    )
    check(status, err)
    return out.view(bool)


VP8 = ctypes.POINTER(ctypes.c_uint8)
# the hot entry points of the selection take plain addresses: `a.ctypes.data` costs a
# quarter of `pointer` (called some 10^5 times per selection)
_P = ctypes.c_void_p


def _addr(a: np.ndarray) -> int:
    """The address of a C-contiguous array's data (for `_P` arguments)."""
    return a.ctypes.data


# the tables of a column ray cast (see `Casts`)
_CAST_ARGS = [ctypes.c_int64, D, D, I64, ctypes.c_int64, ctypes.c_int64, D, I64, I32,
              ctypes.c_int64, D, ctypes.c_int64, ctypes.c_double]  # fmt: skip
_LIST_SIGNATURES = {
    "voxax_column_lists": (
        ctypes.c_int,
        [D, ctypes.c_int64, I64, ctypes.c_int64, ctypes.c_int64, D, ctypes.c_int64, ctypes.c_double,
         ctypes.c_int32, I64, I32, ctypes.c_int64, D, D, ctypes.c_int32, ctypes.c_char_p,
         ctypes.c_int64],
    ),
    "voxax_column_hits": (
        ctypes.c_int,
        [D, I64, ctypes.c_int64] + _CAST_ARGS + [ctypes.c_int32, VP8, ctypes.c_char_p, ctypes.c_int64],
    ),
    "voxax_column_inside": (
        ctypes.c_int,
        [D, ctypes.c_int64, I64, ctypes.c_int64]
        + _CAST_ARGS
        + [ctypes.c_int32, VP8, I64, ctypes.c_char_p, ctypes.c_int64],
    ),
    "voxax_column_known": (
        ctypes.c_int,
        [_P, ctypes.c_int64, _P, ctypes.c_int64, ctypes.c_int64, ctypes.c_int64, _P, _P,
         _P, _P, ctypes.c_int64, ctypes.c_int64, _P]
        + _CAST_ARGS
        + [ctypes.c_int32, _P, ctypes.c_char_p, ctypes.c_int64],
    ),
}


def column_lists(vertices, faces, frames, G: int, delta: float, threads):
    """For each line's frame (`frames[l]`, 15 numbers as in `column_test`), the triangles
    of the mesh `(vertices, faces)` listed per cell of a `G x G` grid (`offsets`, `(L G^2 + 1,)` into `entries`)
    and each cell's least and largest triangle depth (`lo`, `hi`, `(L, G^2)`), in two C++
    calls (counts, then the lists; see `csrc/esi/columns_host.cc`)."""
    V = np.ascontiguousarray(vertices, np.float64)
    F = np.ascontiguousarray(faces, np.int64)
    frames = np.ascontiguousarray(frames, np.float64).reshape(-1, 15)
    L, GG = len(frames), int(G) * int(G)
    lib = declare(_LIST_SIGNATURES)
    err = error_buffer()

    def call(fill, counts, entries, lo, hi):
        status = lib.voxax_column_lists(
            pointer(V, D), len(V), pointer(F, I64), len(F), L,
            pointer(frames, D), int(G), float(delta), fill, pointer(counts, I64),
            pointer(entries, I32), len(entries), pointer(lo, D), pointer(hi, D),
            _threads(threads), err, ERRLEN,
        )  # fmt: skip
        check(status, err)

    counts = np.zeros(L * GG + 1, np.int64)
    none = np.zeros(1)
    call(0, counts, np.zeros(1, np.int32), none, none)
    offsets = np.zeros(L * GG + 1, np.int64)
    np.cumsum(counts[:-1], out=offsets[1:])
    entries = np.zeros(int(offsets[-1]), np.int32)
    lo, hi = np.zeros((L, GG)), np.zeros((L, GG))
    call(1, offsets, entries, lo, hi)
    return offsets, entries, lo, hi


class Casts(NamedTuple):
    """The tables of the column ray casts (C++, `csrc/esi/columns_host.cc`): per signed
    direction `k` its frame (`params[k]`, 15 numbers as in `column_test`), its direction,
    its line and its column test limits (`lims[k]`, `G^2`); per line the triangles listed
    over each cell (`offsets`, `(L G^2 + 1,)` into `entries`); the corners of each
    triangle (`tris`, `(F, 9)`); rays count hits beyond `t_min`."""

    params: np.ndarray
    dirs: np.ndarray
    line_of: np.ndarray
    G: int
    lims: np.ndarray
    offsets: np.ndarray
    entries: np.ndarray
    tris: np.ndarray
    t_min: float
    #: the tables as arguments of the C++ entry points (made once: ctypes pointers are slow
    #: to make)
    args: list

    @classmethod
    def make(cls, params, dirs, line_of, G, lims, offsets, entries, tris, t_min) -> Casts:
        params = np.ascontiguousarray(params, np.float64)
        K, G = len(params), int(G)
        c = cls(
            params,
            np.ascontiguousarray(dirs, np.float64),
            np.ascontiguousarray(line_of, np.int64),
            G,
            np.ascontiguousarray(lims, np.float64),
            np.ascontiguousarray(offsets, np.int64),
            np.ascontiguousarray(entries, np.int32),
            np.ascontiguousarray(tris, np.float64).reshape(-1, 9),
            float(t_min),
            [],
        )
        L = (len(c.offsets) - 1) // max(G * G, 1)
        if (
            params.shape != (K, 15)
            or c.dirs.shape != (K, 3)
            or c.line_of.shape != (K,)
            or c.lims.shape != (K, G * G)
            or len(c.offsets) != L * G * G + 1
        ):
            raise ValueError("column ray casts: inconsistent table shapes")
        # the lists are ordered by depth along each frame's third axis: a ray must run along it
        axis = params[:, [2, 5, 8]] * params[:, 12:13]
        if K and not np.allclose(c.dirs, axis, rtol=0.0, atol=1e-12):
            raise ValueError("column ray casts: each direction must be its frame's third axis times its sign")
        c.args.extend([
            K, pointer(c.params, D), pointer(c.dirs, D), pointer(c.line_of, I64),
            L, G, pointer(c.lims, D), pointer(c.offsets, I64),
            pointer(c.entries, I32), len(c.entries), pointer(c.tris, D), len(c.tris), c.t_min,
        ])  # fmt: skip
        return c


def column_hits(points, ks, casts: Casts, threads) -> np.ndarray:
    """`(n,)` uint8: bit 0, whether the ray from point `i` along direction `ks[i]` meets the
    mesh beyond `t_min`; bit 1, whether it passed the column test and so looked at the
    triangles listed over its cell (C++, exact and watertight)."""
    p = np.ascontiguousarray(points, np.float64).reshape(-1, 3)
    ks = np.ascontiguousarray(ks, np.int64).reshape(-1)
    if len(ks) != len(p):
        raise ValueError(f"column ray casts: {len(p)} points but {len(ks)} directions")
    out = np.zeros(len(p), np.uint8)
    lib = declare(_LIST_SIGNATURES)
    err = error_buffer()
    status = lib.voxax_column_hits(
        pointer(p, D), pointer(ks, I64), len(p), *casts.args, _threads(threads),
        pointer(out, VP8), err, ERRLEN,
    )  # fmt: skip
    check(status, err)
    return out


def column_inside(points, blocks, casts: Casts, threads) -> tuple[np.ndarray, int]:
    """For each block `(start, end, k1, k2)` of `blocks`: whether the rays of the points
    `start <= i < end` along directions `k1` and `k2` (`-1`: `k1` alone) both meet the mesh
    (`(n,)` bool, False outside the blocks), and the number of casts that looked at
    triangles (C++)."""
    p = np.ascontiguousarray(points, np.float64).reshape(-1, 3)
    blocks = np.ascontiguousarray(blocks, np.int64).reshape(-1, 4)
    out = np.zeros(len(p), np.uint8)
    n_cast = np.zeros(1, np.int64)
    lib = declare(_LIST_SIGNATURES)
    err = error_buffer()
    status = lib.voxax_column_inside(
        pointer(p, D), len(p), pointer(blocks, I64), len(blocks), *casts.args,
        _threads(threads), pointer(out, VP8), pointer(n_cast, I64), err, ERRLEN,
    )  # fmt: skip
    check(status, err)
    return out.view(bool), int(n_cast[0])


def column_known(pairs, off, IN, gid, hk, ghit, gn, gpts, casts: Casts, threads) -> int:
    """For every `(b, c)` of `pairs`, fill `IN[c, r]` for the rows `r` of block `b`
    (`off[b] <= r < off[b + 1]`) from the registry `ghit[c, gid[r]]` (the ray of point
    `gpts[gid[r]]` along direction `hk[c]`), or by a cast recorded there (C++, in place);
    the number of casts that looked at triangles."""
    pairs = np.ascontiguousarray(pairs, np.int64).reshape(-1, 2)
    off = np.ascontiguousarray(off, np.int64)
    nh, R = IN.shape
    if IN.dtype != np.bool_ or not IN.flags.c_contiguous or ghit.dtype != np.int8 or not ghit.flags.c_contiguous:
        raise ValueError("known ray casts: IN must be C-contiguous bool (nh, R), ghit int8")
    gid = np.ascontiguousarray(gid, np.int64)
    hk = np.ascontiguousarray(hk, np.int64)
    if gid.shape != (R,) or hk.shape != (nh,) or ghit.shape[0] != nh or len(gpts) < gn or off.ndim != 1:
        raise ValueError("known ray casts: inconsistent shapes")
    gpts = np.ascontiguousarray(gpts, np.float64)
    n_cast = np.zeros(1, np.int64)
    lib = declare(_LIST_SIGNATURES)
    err = error_buffer()
    status = lib.voxax_column_known(
        _addr(pairs), len(pairs), _addr(off), len(off) - 1, R, nh,
        _addr(IN), _addr(gid), _addr(hk),
        _addr(ghit), ghit.shape[1], int(gn), _addr(gpts), *casts.args,
        _threads(threads), _addr(n_cast), err, ERRLEN,
    )  # fmt: skip
    check(status, err)
    return int(n_cast[0])


_BOUND_SIGNATURES = {
    "voxax_bound_samples": (
        ctypes.c_int,
        [_P, ctypes.c_int64, ctypes.c_int64, ctypes.c_int64, _P, _P, _P, _P, _P,
         ctypes.c_int64, ctypes.c_int64, ctypes.c_int32, _P, _P, _P, _P, _P,
         ctypes.c_char_p, ctypes.c_int64],
    ),
    "voxax_bound_removals": (
        ctypes.c_int,
        [_P, ctypes.c_int64, ctypes.c_int64, _P, ctypes.c_int64, _P, ctypes.c_int64, _P,
         ctypes.c_int64, _P, _P, ctypes.c_int32, _P, _P, _P, ctypes.c_char_p,
         ctypes.c_int64],
    ),
    "voxax_bound_blocks": (
        ctypes.c_int,
        [_P, ctypes.c_int64, _P, ctypes.c_int64, _P, _P, ctypes.c_int32, _P, ctypes.c_char_p, ctypes.c_int64],
    ),
}  # fmt: skip


def _c_table(x: np.ndarray, dtype, shape, what: str) -> np.ndarray:
    """`x` as a C-contiguous array of `dtype` and `shape` (bools as uint8), or a ValueError."""
    x = np.asarray(x)
    if x.shape != tuple(shape):
        raise ValueError(f"{what}: shape {x.shape}, expected {tuple(shape)}")
    if x.dtype == np.bool_:
        x = x.view(np.uint8)
    return np.ascontiguousarray(x, dtype)


def bound_samples(rr, cur, Dr, suf, Vr, sufv, c0: int, nc: int, with_suf: bool):
    """The sums of the bounds over a node's hidden surface samples `rr` for the HF columns
    `c0 <= j < c0 + nc` (C++, `csrc/esi/bounds_host.cc`): `C[i, c] = min(cur[i],
    Dr[rr[i], j])` and `Vn[i, c] = Vr[rr[i], j]`, `(n, nc)`; `cd[c]`, the sum of
    `C[:, c]` (with `with_suf`, of `min(C[:, c], suf[rr, j + 1])`); `vn[c]`, the visible
    ones; `vmax[c]`, those visible or visible along a later column (`sufv[rr, j + 1]`)."""
    rr = np.ascontiguousarray(rr, np.int64)
    rows, nh = Dr.shape
    n = len(rr)
    cur = _c_table(cur, np.float64, (n,), "bound sums")
    Dr = _c_table(Dr, np.float64, (rows, nh), "bound sums")
    suf = _c_table(suf, np.float64, (rows, nh + 1), "bound sums")
    Vr = _c_table(Vr, np.uint8, (rows, nh), "bound sums")
    sufv = _c_table(sufv, np.uint8, (rows, nh + 1), "bound sums")
    C = np.empty((n, nc))
    Vn = np.empty((n, nc), np.uint8)
    cd = np.empty(nc)
    vn = np.empty(nc, np.int64)
    vmax = np.empty(nc, np.int64)
    lib = declare(_BOUND_SIGNATURES)
    err = error_buffer()
    status = lib.voxax_bound_samples(
        _addr(rr), n, rows, nh, _addr(cur), _addr(Dr),
        _addr(suf), _addr(Vr), _addr(sufv), int(c0), int(nc),
        int(bool(with_suf)), _addr(C), _addr(Vn), _addr(cd),
        _addr(vn), _addr(vmax), err, ERRLEN,
    )  # fmt: skip
    check(status, err)
    return C, Vn.view(bool), cd, vn, vmax


def bound_removals(IN, rows, cols, col_of, s3: int, wd, wt, threads):
    """The floater sums of the bounds (C++): row `i` counts in column `c` where
    `IN[cols[c], rows[i]]` (`col_of` None) or where `col_of[i] == c` (`cols` and `col_of`
    ascending). Returns `sums` `(3, nc)` (the sums of `wd`, `wt` and 1 over the rows
    counting in each column) and `Md`, `Mt` `(nh - s3, nc)`: the sums of `wd`, `wt` over
    the rows counting in column `c` that HF `h = s3 + j` removes (`IN[h, row]` False), for
    `h > cols[c]` (0 elsewhere)."""
    nh, R = IN.shape
    if IN.dtype != np.bool_ or not IN.flags.c_contiguous:
        raise ValueError("bound sums: IN must be C-contiguous bool (nh, R)")
    rows = np.ascontiguousarray(rows, np.int64)
    cols = np.ascontiguousarray(cols, np.int64)
    n, nc = len(rows), len(cols)
    wd = _c_table(wd, np.float64, (R,), "bound sums")
    wt = _c_table(wt, np.float64, (R,), "bound sums")
    if col_of is not None:
        col_of = _c_table(col_of, np.int64, (n,), "bound sums")
    sums = np.empty((3, nc))
    Md = np.empty((nh - s3, nc)) if 0 <= s3 <= nh else np.empty(0)
    Mt = np.empty_like(Md)
    lib = declare(_BOUND_SIGNATURES)
    err = error_buffer()
    status = lib.voxax_bound_removals(
        _addr(IN.view(np.uint8)), nh, R, _addr(rows), n,
        _addr(cols), nc, None if col_of is None else _addr(col_of), int(s3),
        _addr(wd), _addr(wt), _threads(threads), _addr(sums),
        _addr(Md), _addr(Mt), err, ERRLEN,
    )  # fmt: skip
    check(status, err)
    return sums, Md, Mt


def bound_blocks(alive, off, wd, wt, sums: bool = True) -> np.ndarray:
    """`(3, nb)`: the sums of `alive`, `alive * wd` and `alive * wt` over each block
    `off[b] <= row < off[b + 1]` (C++; the last two 0 without `sums`)."""
    R = len(alive)
    alive = _c_table(alive, np.uint8, (R,), "bound sums")
    off = np.ascontiguousarray(off, np.int64)
    wd = _c_table(wd, np.float64, (R,), "bound sums")
    wt = _c_table(wt, np.float64, (R,), "bound sums")
    nb = len(off) - 1
    if nb < 0:
        raise ValueError("bound sums: the block offsets need at least one entry")
    out = np.empty((3, nb))
    lib = declare(_BOUND_SIGNATURES)
    err = error_buffer()
    status = lib.voxax_bound_blocks(
        _addr(alive), R, _addr(off), nb, _addr(wd), _addr(wt), int(bool(sums)), _addr(out), err, ERRLEN,
    )  # fmt: skip
    check(status, err)
    return out
