"""Encode, decode and measure: the round trip's report."""

from __future__ import annotations

import dataclasses

import numpy as np

from .. import _validate as check
from .._grid import Grid
from .._mesh import Mesh
from ._decode import decode
from ._encode import encode


@dataclasses.dataclass(frozen=True)
class RoundtripReport:
    """What [`roundtrip`][voxax.fc.roundtrip] measured (distances in world units).

    - `grid`, `tokens` (number of rows), `encode_seconds`, `decode_seconds`;
    - `hausdorff`: two-sided Hausdorff distance ([`voxax.metrics.hausdorff`][voxax.metrics.hausdorff]);
    - `chamfer_g2p`: Faithful Contouring's Chamfer (input to output, mean squared);
    - `f_score`: F-score at `threshold`, a fraction in [0, 1];
    - `threshold`: the F-score's distance (by default 0.005 of the grid's longest side: the
      paper's F@0.01 measured on the cube [-1, 1]^3);
    - `manifold`: the output's [`ManifoldReport`][voxax.metrics.ManifoldReport].
    """

    grid: Grid
    tokens: int
    encode_seconds: float
    decode_seconds: float
    hausdorff: float
    chamfer_g2p: float
    f_score: float
    threshold: float
    manifold: object


def roundtrip(
    mesh,
    resolution: int = 512,
    *,
    grid: Grid | None = None,
    samples: int = 100_000,
    threshold: float | None = None,
    **encode_options,
):
    """Encodes `mesh` into tokens at `resolution` and decodes them; measures the result.

    **Arguments:**

    - `mesh`: a `Mesh` (or `(vertices, faces)`).
    - `resolution`: cells along the longest side of `Grid.around(mesh, resolution)`
      (ignored when `grid` is given).
    - `samples`: surface samples per mesh for the metrics.
    - `threshold`: the F-score distance (default: 0.005 of the grid's longest side, the
      paper's F@0.01 on the cube [-1, 1]^3).
    - `**encode_options`: passed to [`encode`][voxax.fc.encode].

    **Returns:** `(Mesh, RoundtripReport)`.
    """
    import time

    from .. import metrics

    where = "voxax.fc.roundtrip"
    V, F = check.mesh_like(where, mesh)
    V = np.asarray(V, np.float64)
    F = np.asarray(F, np.int32)
    if grid is None:
        resolution = check.positive_int(where, "resolution", resolution)
        grid = Grid.around(V, resolution)
    t0 = time.perf_counter()
    tok = encode(V, F, grid, **encode_options)
    t1 = time.perf_counter()
    out = decode(tok)
    t2 = time.perf_counter()
    side = max(u - lo for lo, u in zip(grid.lower, grid.upper))
    thr = 0.005 * side if threshold is None else check.positive_float(where, "threshold", threshold)
    ref = Mesh(V, F)
    if out.n_faces:
        hd = metrics.hausdorff(out, ref, n=samples)
        cd = metrics.chamfer(out, ref, convention="g2p", n=samples, to_surface=True)
        fs = metrics.f_score(out, ref, thr, n=samples, to_surface=True)
    else:
        hd, cd, fs = float("inf"), float("inf"), 0.0
    rep = RoundtripReport(grid, len(tok), t1 - t0, t2 - t1, hd, cd, fs, thr, metrics.manifold_report(out))
    return out, rep
