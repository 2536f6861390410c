"""Mesh metrics: surface sampling, Chamfer distances in each paper's convention, Hausdorff
distances with exact point-to-triangle distances, F-score, triangle quality, topology
(Euler characteristic, manifoldness, boundaries, orientation) and volumetric IoU.

Meshes are `voxax.Mesh` or `trimesh.Trimesh` values or `(vertices, faces)` pairs of
triangles (functions of one mesh also take `vertices, faces` as two arguments). Functions
that compare two surfaces take either meshes (sampled here, deterministically per `key`) or
point clouds `(N, 3)`. Point-to-point nearest neighbours use `scipy.spatial.cKDTree`;
point-to-surface distances are exact, through [`voxax.BVH`][voxax.BVH].

>>> from voxax import data, metrics
>>> metrics.euler_characteristic(data.icosphere(2))
2
"""

from __future__ import annotations

import dataclasses
from typing import NamedTuple

import numpy as np

from . import _validate
from ._grid import Grid
from ._mesh import Mesh
from ._spatial import BVH
from ._spatial.bvh import real_vertices

__all__ = [
    "CHAMFER_CONVENTIONS",
    "ManifoldReport",
    "SurfaceSamples",
    "chamfer",
    "directed_hausdorff",
    "euler_characteristic",
    "f_score",
    "hausdorff",
    "iou",
    "manifold_report",
    "sample_surface",
    "triangle_quality",
]


def _mesh(mesh, name: str = "mesh", where: str = "voxax.metrics", finite: bool = True) -> Mesh:
    """A 3D triangle mesh with finite vertices from any surface form (or a BVH's mesh)."""
    if isinstance(mesh, Mesh):
        m = mesh
    elif isinstance(mesh, BVH):
        m = mesh.mesh
    else:
        if _validate.is_mesh_pair(mesh):
            real_vertices(where, mesh[0])
        m = Mesh(*_validate.mesh_like(f"{where}: `{name}`", mesh))
    if m.dim != 3:
        raise ValueError(f"{where}: `{name}` must be a 3D triangle mesh, got a 2D polyline")
    if m.vertices.dtype.kind != "f":
        raise TypeError(f"{where}: `{name}` must have float vertices, got {m.vertices.dtype}")
    if finite and m.vertices.size:
        _validate.coordinates(where, f"{name}.vertices", m.vertices)
    return m


def _rng(key, where: str) -> np.random.Generator:
    """The sampling generator of `key`: an int seed, or a jax.random key (two of its bits)."""
    if key is None or isinstance(key, (bool, int, np.integer)):
        return _validate.numpy_rng(where, 0 if key is None else key)
    import jax

    bits = np.asarray(jax.random.bits(_validate.key(where, key), (2,), dtype=np.uint32))
    return np.random.default_rng([int(b) for b in bits])


def _key_b(key, where: str):
    """The key of the second surface's samples: `key + 1` for an int, else drawn from `key`."""
    if key is None or isinstance(key, (bool, int, np.integer)):
        return (0 if key is None else int(key)) + 1
    return int(_rng(key, where).integers(2**31))


def _count(where: str, n) -> int:
    return _validate.positive_int(where, "n", n)


def _face_geometry(m: Mesh):
    a, b, c = (m.vertices[m.faces[:, k]] for k in range(3))
    n = np.cross(b - a, c - a)
    norm = np.linalg.norm(n, axis=1)
    return a, b, c, n, norm


class SurfaceSamples(NamedTuple):
    """Points sampled on a surface.

    - `points`: `(n, 3)` float64.
    - `faces`: `(n,)` int64 index of the face each point lies on.
    - `normals`: `(n, 3)` float64 unit normals of those faces.
    - `barycentric`: `(n, 3)` float64 weights of the faces' corners, so that
      `points = einsum("nk,nkd->nd", barycentric, vertices[faces[face_ids]])`; with JAX
      vertices this recomputes the same points differentiably.
    """

    points: np.ndarray
    faces: np.ndarray
    normals: np.ndarray
    barycentric: np.ndarray


@_validate.host_only("voxax.metrics.sample_surface")
@_validate.surface_first
def sample_surface(mesh, n: int, key=None, *, seed=None) -> SurfaceSamples:
    """`n` points uniformly distributed over the area of a triangle mesh.

    Faces are drawn with probability proportional to their area (degenerate faces are
    never drawn) and points uniformly inside them (`a (1 - sqrt r1) + b sqrt r1 (1 - r2) +
    c sqrt r1 r2`). The same `key` gives the same bits.

    **Arguments:**

    - `mesh`: a `Mesh`, a `trimesh.Trimesh`, a `(vertices (V, 3), faces (F, 3))` pair, or
      `vertices, faces` as two arguments.
    - `n`: number of points (>= 0).
    - `key`: an int (default 0) or a `jax.random` key. `seed` is its deprecated old name.

    **Returns:** [`SurfaceSamples`][voxax.metrics.SurfaceSamples] `(points, faces, normals)`.

    >>> from voxax import data
    >>> s = sample_surface(data.cube(2.0), 1000, key=1)
    >>> bool(abs(abs(s.points).max() - 1) < 1e-12), s.points.shape
    (True, (1000, 3))
    """
    where = "voxax.metrics.sample_surface"
    key = _validate.key_or_seed(where, key, seed)
    m = _mesh(mesh, where=where)
    n = _validate.positive_int(where, "n", n, minimum=0)
    _validate.check_allocation(where, 120.0 * n, f"{n} surface samples", "use fewer samples")
    a, b, c, nrm, norm = _face_geometry(m)
    area = 0.5 * norm
    total = float(area.sum())
    if n > 0 and not total > 0:
        raise ValueError(f"{where}: cannot sample a surface of zero area")
    rng = _rng(key, where)
    cdf = np.cumsum(area)
    faces = np.searchsorted(
        cdf, rng.random(n) * cdf[-1] if n else np.zeros(0), side="right"
    )
    faces = np.minimum(faces, len(area) - 1).astype(np.int64)
    r1, r2 = rng.random(n), rng.random(n)
    s1 = np.sqrt(r1)
    w = np.stack([1 - s1, s1 * (1 - r2), s1 * r2], axis=1)
    pts = w[:, :1] * a[faces] + w[:, 1:2] * b[faces] + w[:, 2:] * c[faces]
    normals = nrm[faces] / np.where(norm[faces] > 0, norm[faces], 1)[:, None]
    return SurfaceSamples(pts, faces, normals, w)


def _cloud(x, n: int, key, name: str, where: str) -> tuple[np.ndarray, Mesh | None]:
    if isinstance(x, (Mesh, BVH)) or _validate.is_mesh_object(x) or _validate.is_mesh_pair(x):
        m = _mesh(x, name, where)
        return sample_surface(m, n, key).points, m
    p = np.asarray(_validate.typed_array(where, name, x, "fiu", "a mesh or a float point cloud (N, 3)"), np.float64)
    if p.ndim != 2 or p.shape[1] != 3:
        raise ValueError(f"{where}: `{name}` must be a mesh or a point cloud (N, 3), got shape {p.shape}")
    if not np.all(np.isfinite(p)):
        raise ValueError(f"{where}: `{name}` contains NaN or Inf")
    if len(p) == 0:
        raise ValueError(f"{where}: `{name}` is an empty point cloud")
    return p, None


def _nearest(src: np.ndarray, dst: np.ndarray) -> np.ndarray:
    from scipy.spatial import cKDTree

    d, _ = cKDTree(dst).query(src, k=1, workers=-1)
    return d


def _distances(
    src: np.ndarray, dst: np.ndarray, dst_mesh: Mesh | None, to_surface: bool, where: str = "voxax.metrics.chamfer"
) -> np.ndarray:
    if to_surface:
        if dst_mesh is None:
            raise ValueError(f"{where}: `to_surface=True` needs meshes, not point clouds")
        return BVH(dst_mesh).closest_points(src).distance
    return _nearest(src, dst)


#: The Chamfer variants of [`chamfer`][voxax.metrics.chamfer], by name.
CHAMFER_CONVENTIONS = ("l2", "l1_bbox", "g2p")


@_validate.host_only("voxax.metrics.chamfer", instead="voxax.metrics.chamfer_loss on point sets")
def chamfer(
    a, b, *, convention: str = "l2", n: int = 10_000, key=None, to_surface: bool = False, seed=None
) -> float:
    """The Chamfer distance between two surfaces, in one of three published conventions.

    With `P` the samples of `a` (the prediction) and `Q` those of `b` (the reference), and
    `d(x, Y) = min_{y in Y} |x - y|`:

    - `"l2"` -- MeshSDF's CD-l2 (its Eq. 18): `sum_{p in P} d(p, Q)^2 + sum_{q in Q} d(q, P)^2`,
      a *sum* over the samples (the paper uses 2048 points per shape, on shapes scaled to
      the unit sphere), so it grows with `n`.
    - `"l1_bbox"` -- NESI's Chamfer-L1 x 1000 relative to the bounding box:
      `1000 * (mean_{p} d(p, Q) + mean_{q} d(q, P)) / diag(b)`, with `diag(b)` the diagonal of
      the reference's bounding box (of `b`'s points for a cloud).
    - `"g2p"` -- Faithful Contouring's one-sided CD (G->P): `mean_{q in Q} d(q, P)^2`, from the
      ground truth `b` to the prediction `a` only. (The source does not say whether the
      distance is squared; its magnitudes, 1e-6 next to a Hausdorff distance of 1e-3,
      point to squared distances.)

    **Arguments:**

    - `a`, `b`: meshes (a `Mesh`, a `trimesh.Trimesh` or a `(vertices, faces)` pair),
      sampled with `n` points each, or point clouds `(N, 3)`.
    - `convention`: one of `"l2"`, `"l1_bbox"`, `"g2p"`.
    - `n`: samples per mesh (>= 1); `key`: the sampling key, an int (default 0; `b` uses
      `key + 1`) or a `jax.random` key. `seed` is its deprecated old name.
    - `to_surface`: measure `d(x, Y)` to the other *mesh* exactly (BVH) instead of to its
      samples (point to surface; needs meshes).

    **Returns:** a Python float.

    >>> from voxax import data
    >>> s = data.icosphere(3)
    >>> chamfer(s, s.translated((0.1, 0, 0)), convention="l1_bbox", to_surface=True) > 0
    True
    """
    where = "voxax.metrics.chamfer"
    key = _validate.key_or_seed(where, key, seed)
    if convention not in CHAMFER_CONVENTIONS:
        raise ValueError(f"{where}: `convention` must be one of {CHAMFER_CONVENTIONS}, got {convention!r}")
    n = _count(where, n)
    P, ma = _cloud(a, n, key, "a", where)
    Q, mb = _cloud(b, n, _key_b(key, where), "b", where)
    d_qp = _distances(Q, P, ma, to_surface, where)
    if convention == "g2p":
        return float(np.mean(d_qp**2))
    d_pq = _distances(P, Q, mb, to_surface, where)
    if convention == "l2":
        return float(np.sum(d_pq**2) + np.sum(d_qp**2))
    ref = mb.vertices[np.unique(mb.faces)] if mb is not None else Q
    diag = float(np.linalg.norm(ref.max(0) - ref.min(0)))
    if not diag > 0:
        raise ValueError(f"{where}: the reference's bounding box has a zero diagonal")
    return float(1000.0 * (np.mean(d_pq) + np.mean(d_qp)) / diag)


def chamfer_loss(p, q, *, squared: bool = True, chunk_size: int = 1024):
    """A differentiable Chamfer distance between two point sets, in JAX.

    `mean_{x in p} d(x, q)^e + mean_{y in q} d(y, p)^e` with `e = 2` (`squared=True`,
    the loss MeshSDF minimises, up to its sums being means here) or `e = 1`. Brute force
    (every pair), in chunks of `chunk_size` points of `p` with `jax.lax.map`, so memory
    stays `O(chunk_size x len(q))`; fine for a few thousand points per side. Works under
    `jit`, `grad` and `vmap`; the gradient flows through the nearest pairs.

    **Arguments:**

    - `p`: `(N, d)` float; `q`: `(M, d)` float (JAX or NumPy arrays).
    - `squared`: squared (default) or plain Euclidean distances.
    - `chunk_size`: points of `p` per chunk.

    **Returns:** a JAX scalar.

    >>> import jax.numpy as jnp
    >>> float(chamfer_loss(jnp.array([[0.0, 0.0, 0.0]]), jnp.array([[0.0, 0.0, 2.0]])))
    8.0
    """
    import jax
    import jax.numpy as jnp

    p, q = jnp.asarray(p), jnp.asarray(q)
    if p.ndim != 2 or q.ndim != 2 or p.shape[1] != q.shape[1]:
        raise ValueError(
            f"p and q must have shapes (N, d) and (M, d), got {p.shape} and {q.shape}"
        )
    if p.shape[0] == 0 or q.shape[0] == 0:
        raise ValueError("voxax.metrics.chamfer_loss: `p` and `q` must be non-empty point sets")
    n = p.shape[0]
    c = max(1, min(int(chunk_size), n))
    pad = (-n) % c
    pp = jnp.concatenate([p, jnp.broadcast_to(p[:1], (pad, p.shape[1]))]).reshape(
        -1, c, p.shape[1]
    )

    def chunk(x):
        d2 = jnp.sum((x[:, None, :] - q[None, :, :]) ** 2, axis=-1)  # (c, M)
        return jnp.min(d2, axis=1), jnp.min(d2, axis=0)

    rows, cols = jax.lax.map(chunk, pp)
    rows = rows.reshape(-1)[:n]
    cols = jnp.min(cols, axis=0)

    def power(d2):
        if squared:
            return d2
        pos = d2 > 0
        return jnp.where(pos, jnp.sqrt(jnp.where(pos, d2, 1)), 0)

    return jnp.mean(power(rows)) + jnp.mean(power(cols))


@_validate.host_only("voxax.metrics.directed_hausdorff")
def directed_hausdorff(a, b, *, n: int = 100_000, key=None, seed=None) -> float:
    """The one-sided Hausdorff distance `max_{x in a} d(x, b)` from mesh `a` to mesh `b`.

    `a` is represented by its vertices plus `n` area-uniform samples (so the value is a
    lower bound of the exact one that converges as `n` grows; it is exact whenever the
    farthest point is a vertex); `d(x, b)` is the exact distance to `b`'s triangles.

    **Returns:** a Python float.
    """
    where = "voxax.metrics.directed_hausdorff"
    key = _validate.key_or_seed(where, key, seed)
    ma, mb = _mesh(a, "a", where), _mesh(b, "b", where)
    n = _validate.positive_int(where, "n", n, minimum=0)
    if mb.n_faces == 0:
        raise ValueError(f"{where}: `b` has no faces")
    pts = ma.vertices[np.unique(ma.faces)]
    if n > 0 and ma.n_faces:
        pts = np.concatenate([pts, sample_surface(ma, n, key).points])
    if len(pts) == 0:
        return 0.0
    return float(BVH(mb).closest_points(pts).distance.max())


@_validate.host_only("voxax.metrics.hausdorff")
def hausdorff(a, b, *, n: int = 100_000, key=None, seed=None) -> float:
    """The two-sided Hausdorff distance between two triangle meshes.

    `max(directed_hausdorff(a, b), directed_hausdorff(b, a))`: each surface's vertices and
    `n` area-uniform samples, at exact point-to-triangle distances from the other mesh.

    **Arguments:**

    - `a`, `b`: meshes (a `Mesh`, a `trimesh.Trimesh` or a `(vertices, faces)` pair).
    - `n`: samples per surface (>= 0: 0 uses the vertices alone); `key`: the sampling key
      (an int, default 0, or a `jax.random` key). `seed` is its deprecated old name.

    **Returns:** a Python float.

    >>> from voxax import data
    >>> round(hausdorff(data.icosphere(2, radius=1.0), data.icosphere(2, radius=0.75)), 12)
    0.25
    """
    key = _validate.key_or_seed("voxax.metrics.hausdorff", key, seed)
    return max(directed_hausdorff(a, b, n=n, key=key), directed_hausdorff(b, a, n=n, key=key))


@_validate.host_only("voxax.metrics.f_score")
def f_score(
    a, b, threshold: float, *, n: int = 10_000, key=None, to_surface: bool = False, seed=None
) -> float:
    """The F-score at distance `threshold` between a prediction `a` and a reference `b`.

    Precision is the fraction of `a`'s samples within `threshold` of `b`, recall the
    fraction of `b`'s samples within `threshold` of `a`, and `F = 2 P R / (P + R)` (0 when
    both vanish). A fraction in [0, 1] (papers often print it x 100).

    **Arguments:** as [`chamfer`][voxax.metrics.chamfer], plus `threshold > 0`.

    **Returns:** a Python float.
    """
    where = "voxax.metrics.f_score"
    key = _validate.key_or_seed(where, key, seed)
    threshold = _validate.positive_float(where, "threshold", threshold)
    n = _count(where, n)
    P, ma = _cloud(a, n, key, "a", where)
    Q, mb = _cloud(b, n, _key_b(key, where), "b", where)
    precision = float(np.mean(_distances(P, Q, mb, to_surface, where) <= threshold))
    recall = float(np.mean(_distances(Q, P, ma, to_surface, where) <= threshold))
    if precision + recall == 0:
        return 0.0
    return 2 * precision * recall / (precision + recall)


@_validate.host_only("voxax.metrics.triangle_quality")
@_validate.surface_first
def triangle_quality(mesh) -> np.ndarray:
    """Per-triangle quality `Q = (6 / sqrt 3) A / (p e_max)`, 1 for equilateral triangles.

    `A` is the area, `p` the half perimeter and `e_max` the longest edge (the radius-ratio
    style measure of Frey and Borouchaki used by CVT meshing papers). `Q` lies in [0, 1];
    degenerate triangles have `Q = 0`.

    **Arguments:** `mesh`: `Mesh` or `(vertices, faces)`.

    **Returns:** `(F,)` float64.

    >>> import numpy as np
    >>> v = np.array([[0, 0, 0], [1, 0, 0], [0.5, np.sqrt(3) / 2, 0]])
    >>> round(float(triangle_quality((v, [[0, 1, 2]]))[0]), 12)
    1.0
    """
    m = _mesh(mesh, where="voxax.metrics.triangle_quality")
    a, b, c, _, norm = _face_geometry(m)
    e = np.stack(
        [
            np.linalg.norm(b - a, axis=1),
            np.linalg.norm(c - b, axis=1),
            np.linalg.norm(a - c, axis=1),
        ],
        1,
    )
    p = 0.5 * e.sum(1)
    emax = e.max(1)
    den = p * emax
    q = np.where(
        den > 0, (6.0 / np.sqrt(3.0)) * (0.5 * norm) / np.where(den > 0, den, 1), 0.0
    )
    return np.clip(q, 0.0, 1.0)


def _unique_rows(a: np.ndarray, *, return_index=False, return_inverse=False, return_counts=False):
    """`np.unique(a, axis=0, ...)` of a 2-D integer array, the same results (rows in
    lexicographic order, first occurrences, inverse, counts): rows of non-negative values
    are packed into one int64 key each, whose order is the rows' lexicographic order, so
    the sort is of integers instead of rows (several times faster); other arrays go to
    `np.unique(axis=0)`."""
    a = np.asarray(a)
    k = a.shape[1] if a.ndim == 2 else 0
    base = int(a.max()) + 1 if a.size else 1
    if k == 0 or not np.issubdtype(a.dtype, np.integer) or (a.size and int(a.min()) < 0) or base ** k >= 1 << 62:
        return np.unique(a, axis=0, return_index=return_index, return_inverse=return_inverse,
                         return_counts=return_counts)
    key = np.zeros(len(a), np.int64)
    for c in range(k):
        key = key * base + a[:, c].astype(np.int64)
    _, first, inv, cnt = np.unique(key, return_index=True, return_inverse=True, return_counts=True)
    out = [a[first]]
    if return_index:
        out.append(first)
    if return_inverse:
        out.append(inv.reshape(-1))
    if return_counts:
        out.append(cnt)
    return tuple(out) if len(out) > 1 else out[0]


def _edges(faces: np.ndarray):
    """Directed half-edges (3F, 2) in face order, and the undirected unique edges with
    inverse indices and counts."""
    he = (
        np.stack([faces, np.roll(faces, -1, axis=1)], axis=2)
        .reshape(-1, 2)
        .astype(np.int64)
    )
    und = np.sort(he, axis=1)
    uniq, inv, cnt = _unique_rows(und, return_inverse=True, return_counts=True)
    return he, uniq, inv.reshape(-1), cnt


@_validate.host_only("voxax.metrics.euler_characteristic")
@_validate.surface_first
def euler_characteristic(mesh) -> int:
    """The Euler characteristic `V - E + F` of a triangle mesh.

    `V` counts the vertices referenced by faces (unreferenced ones are ignored), `E` the
    distinct undirected edges, `F` the faces (degenerate ones included). A closed orientable
    surface of genus `g` has `2 - 2g` per component: sphere 2, torus 0. Vertices are
    identified by index, not position.

    **Returns:** a Python int.
    """
    m = _mesh(mesh, where="voxax.metrics.euler_characteristic", finite=False)
    if m.n_faces == 0:
        return 0
    _, uniq, _, _ = _edges(m.faces)
    return int(len(np.unique(m.faces)) - len(uniq) + m.n_faces)


@dataclasses.dataclass(frozen=True)
class ManifoldReport:
    """Topology of a triangle mesh; see [`manifold_report`][voxax.metrics.manifold_report]."""

    n_vertices: int  #: vertices referenced by faces
    n_edges: int
    n_faces: int
    euler_characteristic: int
    n_components: int  #: face components connected through shared edges
    n_boundary_edges: int  #: edges with one incident face
    n_boundary_loops: int  #: connected components of the boundary edges
    n_nonmanifold_edges: int  #: edges with more than two incident faces
    n_nonmanifold_vertices: int  #: vertices whose incident faces form more than one fan
    n_misoriented_edges: int  #: edges traversed twice in the same direction
    n_duplicate_faces: int  #: faces with the same vertex set as an earlier face
    n_degenerate_faces: int  #: faces with a repeated index or zero area
    edge_manifold: bool
    vertex_manifold: bool
    oriented: bool  #: consistently oriented: no edge traversed twice in one direction
    closed: bool  #: edge-manifold without boundary
    genus: (
        int | None
    )  #: (2 C - chi) / 2 for closed, oriented, 2-manifold meshes, else None

    @property
    def manifold(self) -> bool:
        """Edge- and vertex-manifold."""
        return self.edge_manifold and self.vertex_manifold

    @property
    def watertight(self) -> bool:
        """Closed, 2-manifold and consistently oriented."""
        return self.closed and self.manifold and self.oriented


def _components(n_nodes: int, pairs: np.ndarray) -> tuple[int, np.ndarray]:
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    if n_nodes == 0:
        return 0, np.zeros(0, np.int64)
    pairs = pairs.reshape(-1, 2)
    g = coo_matrix(
        (np.ones(len(pairs)), (pairs[:, 0], pairs[:, 1])), shape=(n_nodes, n_nodes)
    )
    return connected_components(g, directed=False)


@_validate.host_only("voxax.metrics.manifold_report")
@_validate.surface_first
def manifold_report(mesh) -> ManifoldReport:
    """Manifoldness, boundaries, orientation and defects of a triangle mesh.

    - An edge is *manifold* with one or two incident faces; a vertex is manifold when its
      incident faces form a single fan (one component through the edges at the vertex).
    - *Boundary* edges have one incident face; boundary loops are the connected components
      of the boundary edges.
    - *Oriented*: no edge is traversed twice in the same direction (neighbouring faces
      agree on the orientation).
    - *Duplicate* faces repeat an earlier face's vertex set (either orientation);
      *degenerate* faces repeat an index or have zero area.
    - Components are sets of faces connected through shared edges.

    **Arguments:** `mesh`: `Mesh` or `(vertices, faces)`.

    **Returns:** [`ManifoldReport`][voxax.metrics.ManifoldReport].

    >>> from voxax import data
    >>> r = manifold_report(data.torus())
    >>> r.watertight, r.euler_characteristic, r.genus
    (True, 0, 1)
    """
    m = _mesh(mesh, where="voxax.metrics.manifold_report", finite=False)
    F = m.faces.astype(np.int64)
    nf = len(F)
    if nf == 0:
        return ManifoldReport(
            0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, True, True, True, True, None
        )
    he, uniq, inv, cnt = _edges(F)
    used = np.unique(F)
    chi = int(len(used) - len(uniq) + nf)
    # directed-edge duplicates: misorientation
    _, dcnt = _unique_rows(he, return_counts=True)
    self_loops = he[:, 0] == he[:, 1]
    n_mis = int(np.sum(dcnt > 1))
    boundary = cnt == 1
    nonmanifold = cnt > 2
    # boundary loops: components of the graph of boundary edges
    bedges = uniq[boundary & (uniq[:, 0] != uniq[:, 1])]
    if len(bedges):
        nodes, local = np.unique(bedges, return_inverse=True)
        n_loops, _ = _components(len(nodes), local.reshape(-1, 2))
    else:
        n_loops = 0
    # face components through shared edges: connect every face to its edges' nodes
    face_of_he = np.repeat(np.arange(nf), 3)
    pairs = np.stack([face_of_he, nf + inv], 1)
    _, labels = _components(nf + len(uniq), pairs)
    n_comp = len(np.unique(labels[:nf]))
    # vertex fans: nodes are (vertex, neighbour) pairs; face (v, a, b) links (v,a)-(v,b)
    corners = np.concatenate(
        [F, np.roll(F, -1, 1), np.roll(F, -2, 1)], 0
    )  # rows (v, a, b)
    good = (
        (corners[:, 0] != corners[:, 1])
        & (corners[:, 0] != corners[:, 2])
        & (corners[:, 1] != corners[:, 2])
    )
    corners = corners[good]
    va = np.concatenate([corners[:, [0, 1]], corners[:, [0, 2]]], 0)
    keys, kinv = _unique_rows(va, return_inverse=True)
    kinv = kinv.reshape(-1)
    k = len(corners)
    _, lab = _components(len(keys), np.stack([kinv[:k], kinv[k:]], 1))
    fans = _unique_rows(np.stack([keys[:, 0], lab], 1))
    fans_per_vertex = np.bincount(fans[:, 0], minlength=m.n_vertices)
    n_nmv = int(np.sum(fans_per_vertex > 1))
    # duplicates and degenerates
    sorted_faces = np.sort(F, axis=1)
    _, first = _unique_rows(sorted_faces, return_index=True)
    n_dup = int(nf - len(first))
    _, _, _, _, norm = _face_geometry(m)
    repeated = (F[:, 0] == F[:, 1]) | (F[:, 1] == F[:, 2]) | (F[:, 0] == F[:, 2])
    n_deg = int(np.sum(repeated | (norm == 0)))
    edge_manifold = not nonmanifold.any()
    vertex_manifold = edge_manifold and n_nmv == 0
    oriented = n_mis == 0 and not self_loops.any()
    closed = edge_manifold and not boundary.any()
    genus = None
    if closed and vertex_manifold and oriented:
        g2 = 2 * n_comp - chi
        genus = g2 // 2 if g2 % 2 == 0 else None
    return ManifoldReport(
        n_vertices=len(used),
        n_edges=len(uniq),
        n_faces=int(nf),
        euler_characteristic=chi,
        n_components=int(n_comp),
        n_boundary_edges=int(boundary.sum()),
        n_boundary_loops=int(n_loops),
        n_nonmanifold_edges=int(nonmanifold.sum()),
        n_nonmanifold_vertices=n_nmv,
        n_misoriented_edges=n_mis,
        n_duplicate_faces=n_dup,
        n_degenerate_faces=n_deg,
        edge_manifold=bool(edge_manifold),
        vertex_manifold=bool(vertex_manifold),
        oriented=bool(oriented),
        closed=bool(closed),
        genus=genus,
    )


def iou(a, b, grid: Grid, *, soft: bool = True, threshold: float = 0.5):
    """Volumetric intersection over union of two closed meshes through `voxax.voxelize`.

    With `W_a`, `W_b` the box-filtered winding numbers on `grid` (clipped to [0, 1], so
    overlaps and inverted parts count as plain inside/outside):

    - `soft=True` (default): `sum min(W_a, W_b) / sum max(W_a, W_b)`, the IoU of the
      voxels' occupied fractions. It is differentiable in the vertices (a JAX scalar), and
      converges to the exact volumetric IoU as the grid is refined.
    - `soft=False`: the IoU of the occupancy masks `W > threshold` (default 0.5: a voxel
      counts as inside when more than half of it is), as most papers report it.

    **Arguments:**

    - `a`, `b`: `Mesh`, `(vertices, faces)` with JAX or NumPy arrays (3D).
    - `grid`: a `voxax.Grid` covering both.
    - `soft`, `threshold`: see above.

    **Returns:** a JAX scalar (1 when both are empty).

    >>> from voxax import Grid, data
    >>> round(float(iou(data.cube(1.0), data.cube(1.0), Grid.cube(8))), 12)
    1.0
    """
    import jax.numpy as jnp

    from ._voxelize import voxelize

    def occupancy(x):
        v, f = _validate.mesh_like("iou", x)
        return jnp.clip(voxelize(v, f, grid), 0.0, 1.0)

    wa, wb = occupancy(a), occupancy(b)
    if soft:
        inter, union = jnp.sum(jnp.minimum(wa, wb)), jnp.sum(jnp.maximum(wa, wb))
    else:
        if not 0 <= threshold < 1:
            raise ValueError(f"voxax.metrics.iou: `threshold` must lie in [0, 1), got {threshold}")
        ma, mb = wa > threshold, wb > threshold
        inter, union = jnp.sum(ma & mb), jnp.sum(ma | mb)
    return jnp.where(union > 0, inter / jnp.where(union > 0, union, 1), 1.0)
