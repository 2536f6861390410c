"""The restricted Delaunay triangulation of seeds, read off fragments (C++ host code)."""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from .._kernels import cvt as _kernels
from ._fragments import Fragments

__all__ = ["RdtReport", "rdt"]

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
    faces, stats = _kernels.rdt(s, frag.points, frag.normals, float(tau), int(max_hole), threads)
    return faces, RdtReport(*(int(v) for v in stats))
