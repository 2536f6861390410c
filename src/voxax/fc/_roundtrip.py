"""Encode, decode and measure: the round trip's report, and the edge topology of large meshes."""

from __future__ import annotations

import dataclasses
import time
import warnings

import numpy as np

from .. import _kernels
from .. import _validate as check
from .._grid import Grid
from .._mesh import Mesh
from .._values import ValueEquality
from ._decode import decode
from ._encode import encode


@dataclasses.dataclass(frozen=True, eq=False)
class EdgeTopology(ValueEquality):
    """The edge counts of a triangle mesh, as [`voxax.metrics.manifold_report`][voxax.metrics.manifold_report]
    defines them (vertices by index; the counts of its fields of the same names).

    - `n_vertices` (referenced by faces), `n_edges`, `n_faces`, `euler_characteristic`,
      `n_components` (faces connected through shared edges);
    - `n_boundary_edges` (one face), `n_boundary_loops` (components of the boundary edges);
    - `n_nonmanifold_edges` (more than two faces);
    - `n_misoriented_edges` (directed edges traversed twice in the same direction);
    - `closed`: no boundary and no non-manifold edge; `oriented`: no misoriented edge and no
      edge from a vertex to itself.
    """

    n_vertices: int
    n_edges: int
    n_faces: int
    euler_characteristic: int
    n_components: int
    n_boundary_edges: int
    n_boundary_loops: int
    n_nonmanifold_edges: int
    n_misoriented_edges: int
    closed: bool
    oriented: bool


def _runs(keys):
    """Sorted `keys`, the start of each run of equal keys, and the runs' lengths."""
    s = np.sort(keys)
    start = np.flatnonzero(np.concatenate([[True], s[1:] != s[:-1]])) if len(s) else np.zeros(0, np.int64)
    return s, start, np.diff(np.append(start, len(s)))


def edge_topology(vertices, faces=None) -> EdgeTopology:
    """The edge counts of a triangle mesh ([`EdgeTopology`][voxax.fc.EdgeTopology]): the
    same numbers as the fields of [`voxax.metrics.manifold_report`][voxax.metrics.manifold_report]
    of the same names, from sorted int64 edge keys (about a second for a million faces).

    >>> import voxax
    >>> voxax.fc.edge_topology(voxax.data.torus()).euler_characteristic
    0
    """
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    where = "voxax.fc.edge_topology"
    V, F, _ = check.unpack_mesh(where, vertices, faces)
    V, F = check.mesh(where, V, F, dim=3, allow_empty=True, finite=False)
    F = np.asarray(F, np.int64)
    if not len(F):
        return EdgeTopology(0, 0, 0, 0, 0, 0, 0, 0, 0, True, True)
    nv = np.int64(F.max() + 1)
    a, b = F.reshape(-1), np.roll(F, -1, axis=1).reshape(-1)
    ukey = np.minimum(a, b) * nv + np.maximum(a, b)
    order = np.argsort(ukey, kind="stable")
    und = ukey[order]
    first = np.concatenate([[True], und[1:] != und[:-1]])
    start = np.flatnonzero(first)
    count = np.diff(np.append(start, len(und)))
    # Components: faces joined through their shared edges.
    edge_of = np.empty(len(und), np.int64)
    edge_of[order] = np.cumsum(first) - 1
    nf = len(F)
    g = coo_matrix((np.ones(3 * nf), (np.repeat(np.arange(nf), 3), nf + edge_of)), shape=(nf + len(start),) * 2)
    labels = connected_components(g, directed=False)[1][:nf]
    n_comp = int(np.count_nonzero(np.bincount(labels)))
    _, _, dcount = _runs(a * nv + b)
    used = np.zeros(int(nv), bool)
    used[a] = True
    n_used = int(np.count_nonzero(used))
    boundary = count == 1
    n_mis = int(np.count_nonzero(dcount > 1))
    bkeys = und[start[boundary]]
    bu, bv = np.divmod(bkeys, nv)
    ok = bu != bv
    loops = 0
    if ok.any():
        nodes, local = np.unique(np.concatenate([bu[ok], bv[ok]]), return_inverse=True)
        m = int(ok.sum())
        g = coo_matrix((np.ones(m), (local[:m], local[m:])), shape=(len(nodes), len(nodes)))
        loops = int(connected_components(g, directed=False)[0])
    n_nm = int(np.count_nonzero(count > 2))
    n_b = int(np.count_nonzero(boundary))
    oriented = n_mis == 0 and not np.any(a == b)
    return EdgeTopology(
        n_used, len(start), nf, n_used - len(start) + nf, n_comp, n_b, loops, n_nm, n_mis, n_nm == 0 and n_b == 0,
        bool(oriented),
    )  # fmt: skip


@dataclasses.dataclass(frozen=True, eq=False)
class RoundtripReport(ValueEquality):
    """What [`roundtrip`][voxax.fc.roundtrip] measured (distances in world units).

    - `grid`, `tokens` (number of rows), `encode_seconds`, `decode_seconds`,
      `measure_seconds`;
    - `hausdorff`: two-sided Hausdorff distance ([`voxax.metrics.hausdorff`][voxax.metrics.hausdorff]);
    - `chamfer_g2p`: Faithful Contouring's Chamfer (input to output, mean squared);
    - `f_score`: F-score at `threshold`, a fraction in [0, 1];
    - `threshold`: the F-score's distance (by default 0.005 of the grid's longest side: the
      paper's F@0.01 measured on the cube [-1, 1]^3);
    - `manifold`: the output's [`EdgeTopology`][voxax.fc.EdgeTopology] (Euler characteristic,
      boundary loops, non-manifold and misoriented edges); `input`: the input's.
    """

    grid: Grid
    tokens: int
    encode_seconds: float
    decode_seconds: float
    measure_seconds: float
    hausdorff: float
    chamfer_g2p: float
    f_score: float
    threshold: float
    manifold: EdgeTopology
    input: EdgeTopology


def _seeds(where, key):
    """The sampling seeds: `key` and `key + 1` for an int (as the metrics take them), two
    draws of the generator of a JAX key."""
    if isinstance(key, (int, np.integer)) and not isinstance(key, bool):
        k = check.positive_int(where, "key", key, minimum=0)
        return k, k + 1
    rng = check.numpy_rng(where, key)
    return tuple(int(s) for s in rng.integers(2**31, size=2))


def _referenced(mesh: Mesh) -> np.ndarray:
    """The vertices that faces reference, in index order (`vertices[np.unique(faces)]`)."""
    used = np.zeros(mesh.n_vertices, bool)
    used[np.asarray(mesh.faces).reshape(-1)] = True
    return np.asarray(mesh.vertices)[used]


def _measure(out: Mesh, ref: Mesh, samples: int, threshold: float, seeds, threads):
    """Hausdorff, Chamfer (g2p) and F-score of `out` against `ref`: the values of
    `voxax.metrics.hausdorff(out, ref, n=samples, seed=s0)`, `chamfer(out, ref, "g2p",
    to_surface=True)` and `f_score(..., to_surface=True)` (seeds s0 and s0 + 1), from one
    BVH per mesh and the samples each of them draws."""
    from .. import metrics
    from .._spatial import BVH

    s0, s1 = seeds
    out_bvh, ref_bvh = BVH(out), BVH(ref)
    out_s0 = metrics.sample_surface(out, samples, s0).points
    ref_s0 = metrics.sample_surface(ref, samples, s0).points
    ref_s1 = metrics.sample_surface(ref, samples, s1).points
    out_v, ref_v = _referenced(out), _referenced(ref)
    # Against the output: the input's vertices and samples (Hausdorff), its second samples
    # (Chamfer, recall); against the input: the output's vertices and samples.
    to_out = out_bvh.closest_points(np.concatenate([ref_v, ref_s0, ref_s1]), threads=threads).distance
    to_ref = ref_bvh.closest_points(np.concatenate([out_v, out_s0]), threads=threads).distance
    d_h1, d_cd = to_out[: len(ref_v) + samples], to_out[len(ref_v) + samples :]
    hd = float(max(to_ref.max(), d_h1.max()))
    cd = float(np.mean(d_cd**2))
    precision = float(np.mean(to_ref[len(out_v) :] <= threshold))
    recall = float(np.mean(d_cd <= threshold))
    fs = 0.0 if precision + recall == 0 else 2 * precision * recall / (precision + recall)
    return hd, cd, fs


def roundtrip(
    vertices,
    faces=None,
    grid: Grid | None = None,
    *,
    resolution: int = 512,
    samples: int = 100_000,
    threshold: float | None = None,
    key=0,
    threads: int | None = None,
    progress: bool = True,
    **encode_options,
):
    """Encodes a mesh into tokens on `grid` and decodes them; measures the result.

    Warns (`RuntimeWarning`) when a closed 2-manifold input decodes to an output that is
    not one (edges with more than two faces, or misoriented ones).

    **Arguments:**

    - `vertices`: `(V, 3)` float; `faces`: `(F, 3)` int (or a `Mesh`, a `trimesh.Trimesh`
      or a `(vertices, faces)` pair in place of both).
    - `grid`: a 3D [`Grid`][voxax.Grid]; default `Grid.around(mesh, resolution)`.
    - `resolution`: cells along the longest side of the default grid (an int in the
      place of `grid` is taken as the resolution, the older call form).
    - `samples`: surface samples per mesh for the metrics.
    - `threshold`: the F-score distance (default: 0.005 of the grid's longest side, the
      paper's F@0.01 on the cube [-1, 1]^3).
    - `key`: the samples' seed, an int or a JAX PRNG key.
    - `threads`: worker threads (None: all cores); the result does not depend on it.
    - `progress`: a bar over the three stages (encode, decode, measure) on standard error.
    - `**encode_options`: passed to [`encode`][voxax.fc.encode].

    **Returns:** `(Mesh, RoundtripReport)`.
    """
    where = "voxax.fc.roundtrip"
    if isinstance(faces, (int, np.integer)) and not isinstance(faces, bool):  # roundtrip(mesh, 256)
        resolution, faces = faces, None
    V, F, (grid,) = check.unpack_mesh(where, vertices, faces, grid)
    if isinstance(grid, (int, np.integer)) and not isinstance(grid, bool):
        resolution, grid = grid, None
    V, F = check.mesh(where, V, F, dim=3, integer_vertices=True, allow_empty=True)
    V, F = np.asarray(V, np.float64), np.asarray(F, np.int32)
    if grid is None:
        resolution = check.positive_int(where, "resolution", resolution)
        grid = Grid.around(V, resolution)
    grid = check.grid(where, grid, dim=3)
    samples = check.positive_int(where, "samples", samples)
    side = max(u - lo for lo, u in zip(grid.lower, grid.upper))
    thr = 0.005 * side if threshold is None else check.positive_float(where, "threshold", threshold)
    seeds = _seeds(where, key)
    _kernels.threads(threads)
    from tqdm import tqdm

    with tqdm(total=3, desc="voxax.fc.roundtrip: encode", disable=not progress, leave=False) as bar:
        t0 = time.perf_counter()
        tok = encode(V, F, grid, threads=threads, **encode_options)
        bar.set_description("voxax.fc.roundtrip: decode")
        bar.update()
        t1 = time.perf_counter()
        out = decode(tok, threads=threads)
        bar.set_description("voxax.fc.roundtrip: measure")
        bar.update()
        t2 = time.perf_counter()
        ref = Mesh(V, F)
        if out.n_faces and ref.n_faces:
            hd, cd, fs = _measure(out, ref, samples, thr, seeds, threads)
        else:
            hd, cd, fs = float("inf"), float("inf"), 0.0
        topo, topo_in = edge_topology(out), edge_topology(ref)
        bar.update()
    t3 = time.perf_counter()
    if topo_in.closed and topo_in.oriented and not (topo.closed and topo.oriented):
        warnings.warn(
            f"{where}: the input is a closed 2-manifold but the output has {topo.n_nonmanifold_edges} non-manifold "
            f"and {topo.n_misoriented_edges} misoriented edges, {topo.n_boundary_edges} boundary edges"
            + ("; anchors_per_cell='patches' (the default) keeps it closed" if encode_options.get(
                "anchors_per_cell", "patches") == 1 else ""),
            RuntimeWarning,
            stacklevel=2,
        )
    rep = RoundtripReport(grid, len(tok), t1 - t0, t2 - t1, t3 - t2, hd, cd, fs, thr, topo, topo_in)
    return out, rep
