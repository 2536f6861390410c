"""The restricted Delaunay triangulation of seeds, read off fragments (C++ host code)."""

from __future__ import annotations

import ctypes
import os
from typing import NamedTuple

import numpy as np

from . import _ffi
from ._cvt_fragments import Fragments

__all__ = ["RdtReport", "rdt"]

_ERRLEN = 512
_D = ctypes.POINTER(ctypes.c_double)
_I32 = ctypes.POINTER(ctypes.c_int32)
_I64 = ctypes.POINTER(ctypes.c_int64)
_VP = ctypes.c_void_p
_SETUP = False


def _lib():
    global _SETUP
    lib = _ffi.library()
    if not _SETUP:
        i64, i32, dbl = ctypes.c_int64, ctypes.c_int32, ctypes.c_double
        lib.voxax_rdt_run.restype = ctypes.c_int
        lib.voxax_rdt_run.argtypes = [_D, i64, _D, _D, i64, dbl, dbl, i32, i32, ctypes.POINTER(_VP), ctypes.c_char_p, i64]
        lib.voxax_rdt_size.restype = i64
        lib.voxax_rdt_size.argtypes = [_VP]
        lib.voxax_rdt_copy.restype = None
        lib.voxax_rdt_copy.argtypes = [_VP, _I32, _I64]
        lib.voxax_rdt_free.restype = None
        lib.voxax_rdt_free.argtypes = [_VP]
        _SETUP = True
    return lib


class RdtReport(NamedTuple):
    """Counts from [`rdt`][voxax.cvt.rdt].

    - `candidates`: distinct candidate triangles reported by fragments.
    - `greedy`: triangles taken from the candidates.
    - `filled`: triangles added to close holes of co-spherical seeds (`max_hole` edges at most).
    - `flipped`: triangles flipped by the per-component orientation vote.
    - `boundary_edges`: directed edges without an opposite one at the end (0 for a closed
      2-manifold-edged mesh).
    - `components`: edge-connected components.
    """

    candidates: int
    greedy: int
    filled: int
    flipped: int
    boundary_edges: int
    components: int

    @property
    def from_candidates(self) -> float:
        """The fraction of triangles taken directly from fragment reports (not hole fans)."""
        total = self.greedy + self.filled
        return self.greedy / total if total else 0.0


def _threads(threads) -> int:
    if threads is None:
        env = os.environ.get("VOXAX_NUM_THREADS")
        return int(env) if env else 0
    threads = int(threads)
    if threads < 1:
        raise ValueError(f"threads must be >= 1 (or None for all cores), got {threads}")
    return threads


def rdt(frag: Fragments, seeds, *, tau: float | None = None, eps: float | None = None, max_hole: int = 8, threads=None):
    """Triangles of the restricted Delaunay triangulation of `seeds` over the fragments.

    Each fragment proposes the triangles among its four nearest seeds whose farthest seed
    is within `tau` of the nearest (a fragment at a Voronoi vertex proposes its three seeds
    with score 0); triangles are accepted greedily by score so that every directed edge is
    used once (each edge has at most two triangles, oriented consistently by the witnesses'
    normals); loops of up to `max_hole` boundary edges (co-spherical seeds) are fanned; each
    component is finally oriented by a majority vote of its witness normals. Deterministic.

    **Arguments:**

    - `frag`: [`Fragments`][voxax.cvt.Fragments].
    - `seeds`: `(n, 3)` float, `3 <= n < 2^21`.
    - `tau`: candidate tolerance (default `2 sqrt(3) d`, `d` the grid spacing).
    - `max_hole`: the longest boundary loop that is fanned (3..64).
    - `threads`: threads for the nearest-seed search (default all cores).

    **Returns:** `(faces (F, 3) int32, RdtReport)`; faces index `seeds`.
    """
    if not isinstance(frag, Fragments):
        raise TypeError(f"cvt.rdt: expected Fragments, got {type(frag).__name__}")
    s = np.ascontiguousarray(np.asarray(seeds, np.float64))
    if s.ndim != 2 or s.shape[1] != 3:
        raise ValueError(f"cvt.rdt: seeds must have shape (n, 3), got {s.shape}")
    if eps is None:
        eps = np.sqrt(3.0) * frag.spacing
    if tau is None:
        tau = 2.0 * np.sqrt(3.0) * frag.spacing
    x = np.ascontiguousarray(frag.points, np.float64)
    nrm = np.ascontiguousarray(frag.normals, np.float64)
    lib = _lib()
    handle = _VP()
    err = ctypes.create_string_buffer(_ERRLEN)
    status = lib.voxax_rdt_run(
        s.ctypes.data_as(_D), len(s), x.ctypes.data_as(_D), nrm.ctypes.data_as(_D), len(x),
        float(tau), float(eps), int(max_hole), _threads(threads), ctypes.byref(handle), err, _ERRLEN,
    )
    if status != 0:
        raise ValueError(err.value.decode("utf-8", "replace"))
    try:
        nf = int(lib.voxax_rdt_size(handle))
        faces = np.empty((nf, 3), np.int32)
        stats = np.zeros(6, np.int64)
        lib.voxax_rdt_copy(handle, faces.ctypes.data_as(_I32), stats.ctypes.data_as(_I64))
    finally:
        lib.voxax_rdt_free(handle)
    return faces, RdtReport(*(int(v) for v in stats))
