"""The restricted Delaunay triangulation of seeds, read off fragments (C++ host code)."""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from .. import _validate
from .._constants import MAX_ABS_COORDINATE
from .._kernels import cvt as _kernels
from ._fragments import Fragments, checked, checked_threads, real_array

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
    where = "voxax.cvt.rdt"
    frag = checked(where, frag)
    s = real_array(where, "seeds", seeds)
    if s.ndim != 2 or s.shape[1] != 3:
        raise ValueError(f"{where}: `seeds` must have shape (n, 3), got {s.shape}")
    if not 3 <= len(s) < 1 << 21:
        raise ValueError(f"{where}: `seeds` must hold at least 3 seeds and fewer than 2^21, got {len(s)}")
    if not np.all(np.isfinite(s)):
        raise ValueError(f"{where}: `seeds` must be finite (they contain NaN or Inf)")
    if np.max(np.abs(s)) > MAX_ABS_COORDINATE:
        raise ValueError(f"{where}: `seeds` coordinates must have magnitude <= 1e75")
    tau = 2.0 * np.sqrt(3.0) * frag.spacing if tau is None else _validate.positive_float(where, "tau", tau, allow_zero=True)
    max_hole = _validate.positive_int(where, "max_hole", max_hole, minimum=3)
    if max_hole > 64:
        raise ValueError(f"{where}: `max_hole` must lie in [3, 64], got {max_hole}")
    faces, stats = _kernels.rdt(s, frag.points, frag.normals, tau, max_hole, checked_threads(where, threads))
    return faces, RdtReport(*(int(v) for v in stats))
