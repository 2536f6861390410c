"""Spatial queries on triangle meshes: closest points and ray hits through a BVH (C++).

`BVH(mesh)` builds a bounding volume hierarchy (binned surface-area heuristic, float64)
once; its methods answer many queries on all cores, eagerly on NumPy arrays, with results
that do not depend on the number of threads. The module functions
[`closest_points`][voxax.closest_points], [`first_hits`][voxax.first_hits],
[`any_hits`][voxax.any_hits] and [`all_hits`][voxax.all_hits] take a `Mesh`, a
`(vertices, faces)` pair or a `BVH`.

Under `jax.jit` (when the points, rays or vertices are traced), `closest_points` and
`first_hits` run as XLA FFI kernels with static output shapes instead (the BVH is rebuilt
inside every call; float64, so `jax_enable_x64` must be on); their results are then JAX
arrays. Neither path is differentiable.

Exactness: closest points use the exact point-triangle distance (region classification;
degenerate triangles handled as their edges); ray hits use the watertight ray-triangle test
of Woop, Benthin and Wald (2013), with a tie rule that counts a ray through an edge or a
vertex shared by consistently oriented triangles exactly once.
"""

from __future__ import annotations

import weakref
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from .. import _validate
from .._kernels import spatial as kernels
from .._mesh import Mesh

__all__ = [
    "BVH",
    "AllHits",
    "ClosestPoints",
    "RayHits",
    "all_hits",
    "any_hits",
    "closest_points",
    "first_hits",
]



def real_vertices(where: str, x):
    """`x` unchanged, refused unless its dtype is a float or an integer (not bool or complex)."""
    kind = np.dtype(x.dtype).kind if hasattr(x, "dtype") else np.asarray(x).dtype.kind
    if kind not in "fiu":
        dtype = x.dtype if hasattr(x, "dtype") else np.asarray(x).dtype
        raise TypeError(f"{where}: `vertices` must be a float (or integer) array, got {dtype}")
    return x


def as_coords(x, name: str, where: str) -> np.ndarray:
    """Concrete points `(..., 3)` as contiguous float64 (checked by `_validate.coordinates`);
    a traced array is refused in one line (the BVH's queries are eager)."""
    if not _validate.is_concrete(x):
        raise TypeError(f"{where}: `{name}` is traced, but a voxax.BVH answers eagerly on the host: call it "
                        "outside jax.jit / jax.grad / jax.vmap, or use voxax.closest_points / voxax.first_hits")
    return np.ascontiguousarray(_validate.coordinates(where, name, x), dtype=np.float64)


class ClosestPoints(NamedTuple):
    """Closest points on a mesh, one per query point (leading shape `(...)` of the queries).

    - `distance`: `(...)` float64, the exact Euclidean distance (`inf` for an empty mesh).
    - `face`: `(...)` int32, the face holding the closest point (the lowest index on ties;
      -1 for an empty mesh).
    - `barycentric`: `(..., 3)` float64 weights of the face's corners.
    - `point`: `(..., 3)` float64, the closest point.
    """

    distance: np.ndarray
    face: np.ndarray
    barycentric: np.ndarray
    point: np.ndarray


class RayHits(NamedTuple):
    """The first hit of every ray (leading shape `(...)` of the rays).

    - `t`: `(...)` float64 ray parameter of the hit (`origin + t * direction`), `inf` on a miss.
    - `face`: `(...)` int32, -1 on a miss.
    - `barycentric`: `(..., 3)` float64 weights of the face's corners (zeros on a miss).
    - `sign`: `(...)` int8: -1 where the ray crosses against the face normal (it enters a
      closed outward-oriented solid), +1 along it (it exits), 0 on a miss.
    - `hit`: `(...)` bool.
    """

    t: np.ndarray
    face: np.ndarray
    barycentric: np.ndarray
    sign: np.ndarray
    hit: np.ndarray


class AllHits(NamedTuple):
    """Every hit of every ray, flattened and sorted by ray, then `t`, then face.

    - `offsets`: `(R + 1,)` int64; the hits of ray `r` (in C order of the rays' leading
      shape) are `offsets[r]:offsets[r + 1]`.
    - `ray`: `(H,)` int64 ray index of each hit; `t`, `face`, `barycentric (H, 3)`,
      `sign` as in [`RayHits`][voxax.RayHits].
    """

    offsets: np.ndarray
    ray: np.ndarray
    t: np.ndarray
    face: np.ndarray
    barycentric: np.ndarray
    sign: np.ndarray

    def counts(self) -> np.ndarray:
        """Number of hits per ray, `(R,)` int64."""
        return np.diff(self.offsets)


class BVH:
    """A bounding volume hierarchy over a triangle mesh, for closest points and ray hits.

    Built once in C++ (binned surface-area heuristic over float64 triangles; about a
    second for a million faces), then queried from NumPy on all cores. Degenerate faces are
    allowed (they are found by closest-point queries as their edges and never hit by rays).

    **Arguments:**

    - `vertices`: `(V, 3)` float, or a `Mesh` (then leave `faces` out).
    - `faces`: `(F, 3)` int.

    >>> from voxax import data
    >>> bvh = BVH(data.cube(2.0))
    >>> bvh.closest_points([[3.0, 0.0, 0.0]]).distance.tolist()
    [2.0]
    >>> bvh.first_hits([[0.0, 0.0, -5.0]], [[0.0, 0.0, 1.0]]).t.tolist()
    [4.0]
    """

    def __init__(self, vertices, faces=None, *, where: str = "voxax.BVH"):
        if _validate.holds_tracer(vertices) or _validate.holds_tracer(faces):
            raise TypeError(f"{where}: the tree is built eagerly on the host and cannot take traced values: build "
                            "it outside jax.jit / jax.grad / jax.vmap; under a trace use voxax.closest_points or "
                            "voxax.first_hits")
        if isinstance(vertices, Mesh) and faces is None:
            mesh = vertices
        else:
            v, f, _ = _validate.unpack_mesh(where, vertices, faces)
            mesh = Mesh(*_validate.mesh_like(where, (real_vertices(where, v), f)))
        if mesh.dim != 3:
            raise ValueError(f"{where}: needs a 3D triangle mesh, got a 2D polyline")
        v = as_coords(mesh.vertices, "vertices", where)
        f = np.ascontiguousarray(mesh.faces, dtype=np.int32)
        try:
            handle = kernels.bvh_build(v, f)
        except ValueError as err:  # the kernel's own checks (coordinates all below 1e-75): name the caller
            raise ValueError(str(err).replace("voxax: ", f"{where}: ", 1)) from None
        self._handle = handle
        self._finalizer = weakref.finalize(self, kernels.bvh_free, handle)
        self.mesh = mesh

    @property
    def n_faces(self) -> int:
        """Number of faces indexed."""
        return self.mesh.n_faces

    @property
    def n_nodes(self) -> int:
        """Number of tree nodes."""
        return kernels.bvh_stats(self._handle)[0]

    def __repr__(self) -> str:
        return f"BVH(n_faces={self.n_faces}, n_nodes={self.n_nodes})"

    def closest_points(
        self, points, *, threads: int | None = None, max_distance: float | None = None
    ) -> ClosestPoints:
        """The closest point on the mesh to every query point, with exact distances.

        **Arguments:**

        - `points`: `(..., 3)` float.
        - `threads`: number of threads (default: all cores, or `VOXAX_NUM_THREADS`).
        - `max_distance`: look no farther: a point whose closest point lies farther away
          gets distance `inf`, face `-1` and zeros (the search prunes at that distance, so
          far points cost little). The others get the same answer as without it.

        **Returns:** [`ClosestPoints`][voxax.ClosestPoints] with leading shape `(...)`.
        """
        return self._closest(points, threads, max_distance, "voxax.BVH.closest_points")

    def _closest(self, points, threads, max_distance, where: str) -> ClosestPoints:
        p = as_coords(points, "points", where)
        lead = p.shape[:-1]
        p = p.reshape(-1, 3)
        cap = (np.inf if max_distance is None or (isinstance(max_distance, (int, float)) and max_distance == np.inf)
               else _validate.positive_float(where, "max_distance", max_distance, True))  # inf: no limit
        dist, face, bary, point = kernels.bvh_closest(self._handle, p, cap, _validate.host_threads(where, threads))
        return ClosestPoints(
            dist.reshape(lead),
            face.reshape(lead),
            bary.reshape(lead + (3,)),
            point.reshape(lead + (3,)),
        )

    def _rays(self, origins, directions, t_min, t_max, where):
        o = as_coords(origins, "origins", where)
        d = as_coords(directions, "directions", where)
        lead = ray_shape(where, o.shape, d.shape)
        o = np.ascontiguousarray(np.broadcast_to(o, lead + (3,)).reshape(-1, 3))
        d = np.ascontiguousarray(np.broadcast_to(d, lead + (3,)).reshape(-1, 3))
        zero = (d[:, 0] == 0) & (d[:, 1] == 0) & (d[:, 2] == 0)
        if zero.any():
            raise ValueError(f"{where}: `directions` must be non-zero, but direction {int(np.flatnonzero(zero)[0])} is zero")
        t_min, t_max = _validate.ray_interval(where, t_min, t_max)
        return o, d, lead, t_min, t_max

    def _first(self, origins, directions, t_min, t_max, any_hit, threads, where):
        o, d, lead, t_min, t_max = self._rays(origins, directions, t_min, t_max, where)
        t, face, bary, sign = kernels.bvh_first_hits(self._handle, o, d, t_min, t_max, any_hit,
                                                 _validate.host_threads(where, threads))
        return RayHits(
            t.reshape(lead),
            face.reshape(lead),
            bary.reshape(lead + (3,)),
            sign.reshape(lead),
            (face >= 0).reshape(lead),
        )

    def first_hits(
        self,
        origins,
        directions,
        *,
        t_min: float = 0.0,
        t_max: float = np.inf,
        threads: int | None = None,
    ) -> RayHits:
        """The nearest hit of every ray `origin + t * direction`, `t` in `[t_min, t_max]`.

        Directions need not be unit vectors (`t` is in units of the direction's length).
        Ties in `t` go to the lowest face index.

        **Arguments:**

        - `origins`, `directions`: `(..., 3)` float, broadcast against each other; no
          direction may be zero.
        - `t_min`, `t_max`: the ray interval.
        - `threads`: number of threads (default: all cores).

        **Returns:** [`RayHits`][voxax.RayHits].
        """
        return self._first(origins, directions, t_min, t_max, False, threads, "voxax.BVH.first_hits")

    def any_hits(
        self,
        origins,
        directions,
        *,
        t_min: float = 0.0,
        t_max: float = np.inf,
        threads: int | None = None,
    ) -> np.ndarray:
        """Whether each ray hits the mesh within `[t_min, t_max]` (stops at the first hit
        found, so it is cheaper than `first_hits`). **Returns:** `(...)` bool."""
        return self._first(origins, directions, t_min, t_max, True, threads, "voxax.BVH.any_hits").hit

    def all_hits(
        self,
        origins,
        directions,
        *,
        t_min: float = 0.0,
        t_max: float = np.inf,
        threads: int | None = None,
    ) -> AllHits:
        """Every hit of every ray within `[t_min, t_max]`, sorted by ray, `t` and face.

        A ray through an edge or vertex shared by consistently oriented faces is counted
        once, so summing `-sign` along a ray through a closed mesh gives its winding number
        change. Rays in the plane of a face never hit it.

        **Returns:** [`AllHits`][voxax.AllHits] (ray indices in C order of the rays' shape).
        """
        return self._all(origins, directions, t_min, t_max, threads, "voxax.BVH.all_hits")

    def _all(self, origins, directions, t_min, t_max, threads, where: str) -> AllHits:
        o, d, _, t_min, t_max = self._rays(origins, directions, t_min, t_max, where)
        n = len(o)
        counts, t, face, bary, sign = kernels.bvh_all_hits(self._handle, o, d, t_min, t_max,
                                                              _validate.host_threads(where, threads))
        offsets = np.concatenate([[0], np.cumsum(counts)]).astype(np.int64)
        ray = np.repeat(np.arange(n, dtype=np.int64), counts)
        return AllHits(offsets, ray, t, face, bary, sign)


def ray_shape(where: str, a: tuple, b: tuple) -> tuple:
    """The broadcast leading shape of ray origins `a (..., 3)` and directions `b (..., 3)`."""
    try:
        return tuple(np.broadcast_shapes(tuple(a[:-1]), tuple(b[:-1])))
    except ValueError:
        raise ValueError(
            f"{where}: `origins` {tuple(a)} and `directions` {tuple(b)} must broadcast to one shape (..., 3)"
        ) from None


def _as_bvh(mesh, where: str) -> BVH:
    if isinstance(mesh, BVH):
        return mesh
    return BVH(mesh, where=where)


def any_traced(*xs) -> bool:
    return any(isinstance(x, jax.core.Tracer) for x in jax.tree_util.tree_leaves(xs))


def _mesh_arrays(mesh, where: str):
    """(vertices (V, 3) f64, faces (F, 3) int32) as JAX arrays, for the FFI path."""
    import jax.numpy as jnp

    if isinstance(mesh, BVH):
        mesh = mesh.mesh
    if _validate.is_mesh_object(mesh):
        v, f = _validate.mesh_object_arrays(where, mesh)
    elif isinstance(mesh, (tuple, list)) and len(mesh) == 2:
        v, f = mesh
    else:
        raise TypeError(f"{where}: `mesh` must be a Mesh, a trimesh.Trimesh, a (vertices, faces) pair or a BVH")
    if not jax.config.jax_enable_x64:
        raise ValueError(f"{where}: under jax.jit the BVH queries compute in float64: enable jax_enable_x64")
    v, f = _validate.mesh(where, real_vertices(where, v), f, dim=3, integer_vertices=True, context="triangles")
    # traced indices beyond int32 become -1 or 2^31 - 1 (out of range, so the kernel refuses
    # them) instead of wrapping into range
    return jnp.asarray(v).astype(jnp.float64), _validate.int32_faces(f)


def as_rows(x, name: str, where: str):
    """Points `(..., 3)` (traced or not) as float64 JAX arrays (checked by `_validate.coordinates`)."""
    import jax.numpy as jnp

    return jnp.asarray(_validate.coordinates(where, name, x)).astype(jnp.float64)


def _safe_div(num, den):
    ok = den != 0
    return jnp.where(ok, num / jnp.where(ok, den, 1.0), 0.0)


@jax.jit
def _local_closest(corners, q, bary):
    """`(distance, barycentric, point)` of the closest point of triangles `corners (n, 3, 3)`
    to `q (n, 3)`, in the region that the kernel's weights `bary (n, 3)` name (three
    non-zero weights: the face; two: the edge between them; one: that corner), as smooth
    functions of the corners and the query: their derivatives are the closest point's
    wherever the region does not change (and, by the envelope theorem, the distance's
    everywhere it is differentiable)."""
    a, b, c = corners[:, 0], corners[:, 1], corners[:, 2]
    nonzero = bary != 0
    count = jnp.sum(nonzero, axis=-1)
    # face: the projection onto the plane, with its barycentric weights
    n = jnp.cross(b - a, c - a)
    n2 = jnp.sum(n * n, axis=-1)
    pf = q - n * _safe_div(jnp.sum((q - a) * n, axis=-1), n2)[:, None]
    wb = _safe_div(jnp.sum(jnp.cross(pf - a, c - a) * n, axis=-1), n2)
    wc = _safe_div(jnp.sum(jnp.cross(b - a, pf - a) * n, axis=-1), n2)
    wf = jnp.stack([1.0 - wb - wc, wb, wc], axis=-1)
    # edge: from corner k + 1 to corner k + 2, where k is the corner of weight 0
    k = jnp.argmin(nonzero, axis=-1)
    i, j = (k + 1) % 3, (k + 2) % 3
    x = jnp.take_along_axis(corners, i[:, None, None], axis=1)[:, 0]
    y = jnp.take_along_axis(corners, j[:, None, None], axis=1)[:, 0]
    e = y - x
    t = _safe_div(jnp.sum((q - x) * e, axis=-1), jnp.sum(e * e, axis=-1))
    pe = x + t[:, None] * e
    we = (jax.nn.one_hot(i, 3, dtype=q.dtype) * (1.0 - t)[:, None] + jax.nn.one_hot(j, 3, dtype=q.dtype) * t[:, None])
    # corner: the one of weight 1
    m = jnp.argmax(nonzero, axis=-1)
    pv = jnp.take_along_axis(corners, m[:, None, None], axis=1)[:, 0]
    wv = jax.nn.one_hot(m, 3, dtype=q.dtype)
    face, edge = (count == 3)[:, None], (count == 2)[:, None]
    point = jnp.where(face, pf, jnp.where(edge, pe, pv))
    weights = jnp.where(face, wf, jnp.where(edge, we, wv))
    diff = q - point
    sq = jnp.sum(diff * diff, axis=-1)
    pos = sq > 0
    dist = jnp.where(pos, jnp.sqrt(jnp.where(pos, sq, 1.0)), 0.0)
    return dist, weights, point


@jax.custom_jvp
def _closest_kernel(v, f, p):
    return tuple(kernels.closest_points_ffi(v, f, p))


@_closest_kernel.defjvp
def _closest_kernel_jvp(primals, tangents):
    v, f, p = primals
    dv, _, dp = tangents
    out = _closest_kernel(v, f, p)
    dist, face, bary, point = out
    zero_face = np.zeros(face.shape, dtype=jax.dtypes.float0)
    if f.shape[0] == 0:  # no closest point: nothing moves
        return out, (jnp.zeros_like(dist), zero_face, jnp.zeros_like(bary), jnp.zeros_like(point))
    tri = f[jnp.clip(face, 0)]
    bary0 = jax.lax.stop_gradient(bary)

    def local(v_, p_):
        return _local_closest(v_[tri], p_, bary0)

    _, (dd, db, dq) = jax.jvp(local, (v, p), (dv, dp))
    return out, (dd, zero_face, db, dq)


def _closest_points_ffi(mesh, points) -> ClosestPoints:
    where = "voxax.closest_points"
    v, f = _mesh_arrays(mesh, where)
    p = as_rows(points, "points", where)
    lead = p.shape[:-1]
    flat = p.reshape(-1, 3)
    d, fc, b, q = _closest_kernel(v, f, flat)
    return ClosestPoints(
        d.reshape(lead),
        fc.reshape(lead),
        b.reshape(lead + (3,)),
        q.reshape(lead + (3,)),
    )


def _first_hits_ffi(mesh, origins, directions, t_min, t_max) -> RayHits:
    import jax.numpy as jnp

    where = "voxax.first_hits"
    v, f = _mesh_arrays(mesh, where)
    o, d = as_rows(origins, "origins", where), as_rows(directions, "directions", where)
    lead = ray_shape(where, o.shape, d.shape)
    o = jnp.broadcast_to(o, lead + (3,)).reshape(-1, 3)
    d = jnp.broadcast_to(d, lead + (3,)).reshape(-1, 3)
    t_min, t_max = _validate.ray_interval(where, t_min, t_max)
    t, fc, b, sg = kernels.first_hits_ffi(v, f, o, d, t_min, t_max)
    return RayHits(
        t.reshape(lead),
        fc.reshape(lead),
        b.reshape(lead + (3,)),
        sg.reshape(lead),
        (fc >= 0).reshape(lead),
    )


@_validate.surface_first
def closest_points(mesh, points, *, threads: int | None = None) -> ClosestPoints:
    """The closest point on a triangle mesh to every query point (exact distances).

    **Arguments:**

    - `mesh`: a `Mesh`, a `(vertices, faces)` pair, or a [`BVH`][voxax.BVH] (build one
      to reuse it across calls).
    - `points`: `(..., 3)` float.
    - `threads`: number of threads (default: all cores).

    **Returns:** [`ClosestPoints`][voxax.ClosestPoints] `(distance, face, barycentric, point)`.

    Under `jax.jit` (traced points or vertices) this runs as an FFI kernel and returns JAX
    arrays (`threads` is then XLA's pool).

    >>> from voxax import data
    >>> closest_points(data.cube(2.0), [[0.0, 0.0, 0.5]]).distance.tolist()
    [0.5]
    """
    if any_traced(mesh if isinstance(mesh, tuple) else (), points):
        return _closest_points_ffi(mesh, points)
    return _as_bvh(mesh, "voxax.closest_points")._closest(points, threads, None, "voxax.closest_points")


@_validate.surface_first
def first_hits(
    mesh,
    origins,
    directions,
    *,
    t_min: float = 0.0,
    t_max: float = np.inf,
    threads: int | None = None,
) -> RayHits:
    """The nearest hit of every ray on a triangle mesh; see [`BVH.first_hits`][voxax.BVH.first_hits].

    Under `jax.jit` (traced rays or vertices) this runs as an FFI kernel and returns JAX
    arrays (`sign` as int32).

    >>> from voxax import data
    >>> first_hits(data.cube(2.0), [[0.0, 0.0, 0.0]], [[1.0, 0.0, 0.0]]).t.tolist()
    [1.0]
    """
    if any_traced(mesh if isinstance(mesh, tuple) else (), origins, directions):
        return _first_hits_ffi(mesh, origins, directions, t_min, t_max)
    return _as_bvh(mesh, "voxax.first_hits")._first(origins, directions, t_min, t_max, False, threads, "voxax.first_hits")


@_validate.host_only("voxax.any_hits", instead="voxax.first_hits (its `hit` field)")
@_validate.surface_first
def any_hits(
    mesh,
    origins,
    directions,
    *,
    t_min: float = 0.0,
    t_max: float = np.inf,
    threads: int | None = None,
) -> np.ndarray:
    """Whether each ray hits a triangle mesh; see [`BVH.any_hits`][voxax.BVH.any_hits]."""
    where = "voxax.any_hits"
    return _as_bvh(mesh, where)._first(origins, directions, t_min, t_max, True, threads, where).hit


@_validate.host_only("voxax.all_hits")
@_validate.surface_first
def all_hits(
    mesh,
    origins,
    directions,
    *,
    t_min: float = 0.0,
    t_max: float = np.inf,
    threads: int | None = None,
) -> AllHits:
    """Every hit of every ray on a triangle mesh; see [`BVH.all_hits`][voxax.BVH.all_hits].

    >>> from voxax import data
    >>> all_hits(data.cube(2.0), [[0.0, 0.0, -5.0]], [[0.0, 0.0, 1.0]]).t.tolist()
    [4.0, 6.0]
    """
    return _as_bvh(mesh, "voxax.all_hits")._all(origins, directions, t_min, t_max, threads, "voxax.all_hits")
