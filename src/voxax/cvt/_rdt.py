"""The restricted Delaunay triangulation of seeds, read off fragments (C++ host code)."""

from __future__ import annotations

import ctypes
from typing import NamedTuple

import numpy as np

from .. import _kernels
from ._fragments import Fragments

__all__ = ["RdtReport", "rdt"]

_SIGNATURES = {
    "voxax_rdt_run": (
        ctypes.c_int,
        [
            _kernels.D,
            ctypes.c_int64,
            _kernels.D,
            _kernels.D,
            ctypes.c_int64,
            ctypes.c_double,
            ctypes.c_int32,
            ctypes.c_int32,
            ctypes.POINTER(_kernels.VP),
            ctypes.c_char_p,
            ctypes.c_int64,
        ],
    ),
    "voxax_rdt_size": (ctypes.c_int64, [_kernels.VP]),
    "voxax_rdt_copy": (None, [_kernels.VP, _kernels.I32, _kernels.I64]),
    "voxax_rdt_free": (None, [_kernels.VP]),
}


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


def rdt(frag: Fragments, seeds, *, tau: float | None = None, max_hole: int = 8, threads=None):
    """Triangles of the restricted Delaunay triangulation of `seeds` over the fragments.

    Each fragment proposes the triangles of its nearest seed with two of its next three
    seeds whose farthest seed is within `tau` of the nearest, scored by how far the
    fragment is from being a Voronoi vertex of the three (spread of the distances) less
    the clearance of the next seed (an empty-ball margin); triangles are accepted greedily by score so that every directed edge is
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
    if tau is None:
        tau = 2.0 * np.sqrt(3.0) * frag.spacing
    x = np.ascontiguousarray(frag.points, np.float64)
    nrm = np.ascontiguousarray(frag.normals, np.float64)
    lib = _kernels.declare(_SIGNATURES)
    handle = _kernels.VP()
    err = _kernels.error_buffer()
    status = lib.voxax_rdt_run(
        _kernels.pointer(s, _kernels.D),
        len(s),
        _kernels.pointer(x, _kernels.D),
        _kernels.pointer(nrm, _kernels.D),
        len(x),
        float(tau),
        int(max_hole),
        _kernels.threads(threads),
        ctypes.byref(handle),
        err,
        _kernels.ERRLEN,
    )
    _kernels.check(status, err)
    try:
        nf = int(lib.voxax_rdt_size(handle))
        faces = np.empty((nf, 3), np.int32)
        stats = np.zeros(6, np.int64)
        lib.voxax_rdt_copy(handle, _kernels.pointer(faces, _kernels.I32), _kernels.pointer(stats, _kernels.I64))
    finally:
        lib.voxax_rdt_free(handle)
    return faces, RdtReport(*(int(v) for v in stats))
