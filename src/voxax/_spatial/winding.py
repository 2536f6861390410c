"""Exact generalised winding numbers at arbitrary points (pure JAX).

The generalised winding number of an oriented surface S at a point p is the signed solid
angle S subtends at p, divided by the full solid angle: `w(p) = (1 / 4 pi) sum_t Omega_t(p)`
over the triangles t in 3D, and `w(p) = (1 / 2 pi) sum_s theta_s(p)` over the segments s in
2D. For a closed, outward-oriented surface it is the integer winding number (1 inside, 0
outside, 2 where two parts overlap, -1 inside an inverted part); for an open surface it is
the smooth "generalised" winding number of Jacobson et al. (2013), which does not depend on
any ray direction. Compare `voxax.voxelize`, which averages the +z ray-crossing count over
voxels: both agree for closed surfaces.

Eagerly, for one 3D mesh, the values come from C++ (`csrc/spatial/winding*`): one
watertight ray per point where the faces form a cycle; where they do not but their boundary
is small, one ray through the faces and a cap over the boundary plus the cap's sum;
elsewhere the exact sum (a hierarchy of the faces' boundaries, exact up to rounding), or
with `accuracy` the same hierarchies with error-bounded far-field expansions (Barill et al.
2018, to third order, with a rigorous remainder bound; see `csrc/spatial/winding.h`).
Traced, batched and 2D calls run in JAX (differentiable): every point meets every face, so
the cost is O(points x faces). The points are processed in chunks with
`jax.lax.map`, so the memory is O(chunk_size x faces) for the forward pass and, because
every chunk is rematerialised (`jax.checkpoint`), for the backward pass too.
"""

from __future__ import annotations

import functools
import math

import jax
import jax.numpy as jnp
import numpy as np

from .. import _validate
from .._constants import PAIR_BUDGET
from .._kernels import spatial as kernels

__all__ = ["winding_number", "winding_flat"]


def _safe_norm(x):
    """|x| along the last axis, with a finite (zero) gradient at x = 0."""
    sq = jnp.sum(x * x, axis=-1)
    pos = sq > 0
    return jnp.where(pos, jnp.sqrt(jnp.where(pos, sq, 1)), 0)


def _safe_atan2(y, x):
    """atan2 with a finite gradient where y = x = 0 (the value there is 0)."""
    both = (y == 0) & (x == 0)
    return jnp.where(both, 0, jnp.arctan2(y, jnp.where(both, 1, x)))


def _unit_scale(vertices, points):
    """`vertices` and `points` divided by their largest coordinate where that is so small
    that the angles' cubic terms would underflow (a mesh and points below 1e-90 in float64,
    1e-12 in float32); unchanged elsewhere. The angles do not depend on the scale."""
    m = jnp.maximum(jnp.max(jnp.abs(vertices), initial=0), jnp.max(jnp.abs(points), initial=0))
    tiny = 1e-90 if vertices.dtype == jnp.float64 else 1e-12
    s = jnp.where((m < tiny) & (m > 0), m, 1)
    return vertices / s.astype(vertices.dtype), points / s.astype(points.dtype)


def _angles_3d(corners, p):
    """Signed solid angles / (4 pi) of triangles `corners` (F, 3, 3) at points `p` (P, 3)."""
    a = corners[None, :, 0, :] - p[:, None, :]
    b = corners[None, :, 1, :] - p[:, None, :]
    c = corners[None, :, 2, :] - p[:, None, :]
    la, lb, lc = _safe_norm(a), _safe_norm(b), _safe_norm(c)
    # Van Oosterom & Strackee (1983): tan(Omega / 2) = det[a b c] / denominator.
    num = jnp.sum(a * jnp.cross(b, c), axis=-1)
    den = (
        la * lb * lc
        + jnp.sum(a * b, axis=-1) * lc
        + jnp.sum(a * c, axis=-1) * lb
        + jnp.sum(b * c, axis=-1) * la
    )
    # A point in the plane of a triangle (num == 0) sees it under solid angle 0 (outside
    # it) or +-2 pi (inside it, ambiguous); using 0 for both makes points exactly on a
    # surface get the average of the two sides (1/2 on the faces of a closed mesh).
    omega = jnp.where(num == 0, 0, 2 * _safe_atan2(num, den))
    return jnp.sum(omega, axis=-1) / (4 * math.pi)


def _angles_2d(corners, p):
    """Signed angles / (2 pi) of segments `corners` (F, 2, 2) at points `p` (P, 2)."""
    a = corners[None, :, 0, :] - p[:, None, :]
    b = corners[None, :, 1, :] - p[:, None, :]
    cross = a[..., 0] * b[..., 1] - a[..., 1] * b[..., 0]
    dot = jnp.sum(a * b, axis=-1)
    # Points on the line of a segment get 0 (on the segment itself that is the average of
    # the two sides, +-pi, so points on a closed curve get 1/2).
    theta = jnp.where(cross == 0, 0, _safe_atan2(cross, dot))
    return jnp.sum(theta, axis=-1) / (2 * math.pi)


@functools.partial(jax.jit, static_argnums=(3,))
def winding_flat(vertices, faces, points, chunk_size: int):
    """Winding numbers of one mesh `(V, d)`, `(F, d)` at `points` (P, d), `chunk_size` points
    at a time (the last chunk padded). Unchecked: the building block of `winding_number`
    and `voxelize_mc`."""
    d = vertices.shape[-1]
    vertices, points = _unit_scale(vertices, points)
    corners = vertices[faces]  # (F, d, d)
    fn = _angles_3d if d == 3 else _angles_2d
    n = points.shape[0]
    if n <= chunk_size:
        return fn(corners, points)
    n_chunks = -(-n // chunk_size)
    pad = n_chunks * chunk_size - n
    # Pad with copies of the last point (any finite point will do; they are dropped).
    padded = jnp.concatenate([points, jnp.broadcast_to(points[-1:], (pad, d))], axis=0)
    body = jax.checkpoint(lambda q: fn(corners, q))
    out = jax.lax.map(body, padded.reshape(n_chunks, chunk_size, d))
    return out.reshape(-1)[:n]


def _auto_chunk(n_faces: int, n_points: int) -> int:
    return int(max(1, min(max(n_points, 1), PAIR_BUDGET // max(n_faces, 1))))


def _checked_under_jit(out, vertices, faces, points):
    """`out`, with the kernel's checks of the (traced) input run first: under jit a NaN or
    out-of-range input raises there instead of giving NaN. Face indices beyond int32 are
    clipped to -1 or 2^31 - 1 (out of range either way) before the cast."""
    kind = np.dtype(faces.dtype).kind
    f32 = jnp.clip(faces, -1 if kind == "i" else 0, _validate.INT32_MAX).astype(jnp.int32)
    pts = jax.lax.stop_gradient(jnp.asarray(points).astype(out.dtype))
    flag = kernels.winding_check_ffi(jax.lax.stop_gradient(vertices), f32, pts)
    return jnp.where(flag == 0, out, jnp.nan)


def _accuracy(where: str, value) -> float:
    """The error bound `accuracy`: None (exact) or a finite real number >= 0, as a float
    (0.0 for exact)."""
    if value is None:
        return 0.0
    if isinstance(value, jax.core.Tracer):
        raise TypeError(
            f"{where}: `accuracy` must be a concrete number, not a traced value (it bounds the error of the "
            "eager C++ path; traced calls compute the exact sum)"
        )
    if isinstance(value, (np.ndarray, jax.Array, list, tuple)) and np.ndim(value) != 0:
        raise TypeError(f"{where}: `accuracy` must be one real number (None for exact), got an array")
    out = _validate.finite_number(where, "accuracy", value, " (None for exact)")
    if out < 0:
        raise ValueError(f"{where}: `accuracy` must be >= 0 (None or 0 for exact), got {value}")
    return out


def winding_number(
    vertices,
    faces=None,
    points=None,
    *,
    accuracy: float | None = None,
    chunk_size: int | None = None,
    threads: int | None = None,
) -> jax.Array:
    """The exact generalised winding number of a mesh (or polyline) at points.

    3D: the sum of the signed solid angles of the triangles, by the formula of Van Oosterom
    and Strackee (1983), divided by 4 pi. 2D: the sum of the signed angles of the segments,
    divided by 2 pi. For a closed, outward-oriented mesh this is 1 inside, 0 outside, 2 in
    overlaps, -1 inside inverted parts; on the surface itself (a point exactly in the plane
    of the triangle / on the line of the segment containing it) the containing face counts
    0, which gives the average of the two sides (1/2 on the faces of a closed mesh, 1/4 on
    a cube's edges). For open surfaces it is the generalised winding number, which is not
    an integer.

    Two paths compute the same values:

    - **Eager, one 3D mesh** (no argument traced, no batch axes): C++ in float64, by
      one of three paths, chosen from the mesh:

      - *Closed meshes* (every edge used as often in each direction: also non-manifold
        ones, or ones with faces paired with their reverses): the sum is the signed
        crossing count of one watertight ray per point, O(log F) per point and exactly
        the integer. The rays all run along one fixed direction, so they go through a
        tree over the triangles projected along it (a point query per ray).
      - *Open meshes with a small boundary* (the edges whose uses do not cancel, at most a
        quarter as many as the faces: surfaces with holes, a tube cut open): a cap `C`
        over the boundary (its closed walks, each triangulated by halving its vertex
        range) has the same boundary as the surface `S`, so `S - C` is closed and
        `w_S(p) = w_{S-C}(p) + w_C(p)`: the integer crossing count of one ray through `S`
        and the reversed cap, plus the cap's own solid-angle sum (few triangles). The
        cap may cross the surface: `S - C` is a cycle all the same.
      - *Other meshes* (soups, boundaries as large as the mesh): a hierarchy of the faces'
        boundaries (Jacobson et al. 2013): seen from outside a node's box, a patch has
        the winding number of the fan over its boundary edges, so a node costs its
        boundary's edges and only the nodes around the point descend to their triangles.

      On the first two paths the points whose ray meets an edge or a vertex exactly, or
      that lie within rounding of a face or of the cap, take the exact sum instead (so
      points on the surface still get 1/2); every value is the solid-angle sum's up to
      rounding (no approximation). With `accuracy = eps > 0` the hierarchies (the cap's
      on the second path, the faces' on the third and for the points a ray leaves
      unclear) also replace the nodes far enough from a point by the third-order
      expansion of their area-weighted normals about their centre (the "fast winding
      numbers" of Barill et al. 2018), where a rigorous bound on the expansion's
      remainder allows it: at most `q^6 (5 m4 + q m5 (6 - 5 q) / (1 - q)^2) / (4 pi)` for
      a node of radius `R` about its centre at distance `rho` from the point,
      `q = R / rho`, where `m4`, `m5` bound the integrals of `|x - c|^4`, `|x - c|^5` over
      its triangles in units of `R` (from the Legendre series of the dipole kernel). The
      point's budget `eps` is shared out over the nodes by area as the traversal goes (a
      node may spend its area's share of what is left) and the nodes whose bound does not
      fit take their exact boundary fan or descend, down to the exact triangles, so
      **every value is within `eps` of the exact solid-angle sum** (plus rounding, as in
      the exact path). On a capped mesh only the cap is expanded (its area is small, so
      the expansions are admissible almost everywhere). The bound is a worst case: the
      errors seen are typically 10 to 100 times smaller. It pays on large meshes and for
      points far from the surface; on small meshes near the surface the exact paths are
      about as fast. Closed meshes keep the exact ray path (exact, and faster); only the
      points a ray leaves unclear take the bounded hierarchy. On all cores (`threads`),
      the same bits for any thread count; the result is cast to the input's float dtype.
    - **JAX** (under `jax.jit`, `jax.grad`, `jax.vmap`, for batch axes and for 2D): the
      sum in plain JAX, differentiable in `vertices` and `points` by autodiff (away from
      the surface the gradient of a closed mesh's winding number is zero, up to rounding).
      Leading axes of `vertices` and `faces` are batch axes that broadcast against each
      other, as for `voxax.voxelize`, and every mesh of the batch is evaluated at all the
      points. The cost is O(points x faces); the points are processed `chunk_size` at a
      time, so the memory is O(chunk_size x faces) also when differentiating (every chunk
      is recomputed in the backward pass). Under jit a kernel checks the input first
      (NaN, Inf or coordinates beyond 1e75, face indices out of range raise).

    **Arguments:**

    - `vertices`: `(..., V, 3)` or `(..., V, 2)` float32 or float64.
    - `faces`: `(..., F, 3)` int triangles or `(..., F, 2)` int segments, outward-oriented
      (or a mesh object in place of `vertices, faces`: `winding_number(mesh, points)`).
    - `points`: `(..., d)` float (or int), any leading shape; finite, magnitude <= 1e75.
    - `accuracy`: None (default) or 0 for the exact values; a finite `eps > 0` lets the
      eager path (one 3D mesh) return values within `eps` of the exact sum, faster where
      many nodes are far from the points (far points, large meshes, loose `eps`). The
      JAX path (traced, batched or 2D calls) always computes the exact sum, which meets
      any `eps`; a traced `accuracy` is refused (`TypeError`).
    - `chunk_size`: points per chunk of the JAX path; by default about 2^20 / F (at least 1).
    - `threads`: threads of the eager path (default: all cores, or `VOXAX_NUM_THREADS`).

    **Returns:**

    `batch + points.shape[:-1]` array of the promoted float dtype of `vertices` and
    `points`, where `batch` is the broadcast of the mesh's batch axes (none for one mesh).

    **Example:**

    ```python
    >>> mesh = voxax.data.box()                    # the cube [-0.5, 0.5]^3
    >>> w = winding_number(mesh.vertices, mesh.faces, [[0.0, 0.0, 0.0], [2.0, 0.0, 0.0], [0.5, 0.1, 0.2]])
    >>> np.round(np.asarray(w), 6).tolist()         # inside, outside, on a face
    [1.0, 0.0, 0.5]
    >>> disc = voxax.data.icosphere(2)             # an open surface: the upper half of a sphere
    >>> up = np.asarray(disc.faces)[np.asarray(disc.vertices)[np.asarray(disc.faces)].mean(1)[:, 2] > 0]
    >>> q = [[0.0, 0.0, 0.5], [3.0, 1.0, 2.0]]
    >>> exact = np.asarray(winding_number(disc.vertices, up, q))
    >>> near = np.asarray(winding_number(disc.vertices, up, q, accuracy=1e-6))
    >>> bool(np.all(np.abs(near - exact) <= 1e-6))
    True

    ```
    """
    where = "voxax.winding_number"
    vertices, faces, (points,) = _validate.unpack_mesh(where, vertices, faces, points)
    vertices, faces = _validate.mesh(where, vertices, faces, batch=True)
    d = vertices.shape[-1]
    if points is None:
        raise TypeError(f"{where}: missing `points`")
    points = _validate.coordinates(where, "points", points, d)
    eps = _accuracy(where, accuracy)
    nthreads = _validate.host_threads("voxax.winding_number", threads)
    pdtype = points.dtype if jnp.issubdtype(points.dtype, jnp.floating) else vertices.dtype
    dtype = jax.dtypes.canonicalize_dtype(np.result_type(vertices.dtype, pdtype))
    batch = tuple(np.broadcast_shapes(vertices.shape[:-2], faces.shape[:-2]))
    lead = tuple(points.shape[:-1])
    traced = not all(_validate.is_concrete(x) for x in (vertices, faces, points))
    if not traced and d == 3 and vertices.ndim == 2 and faces.ndim == 2:
        v = np.ascontiguousarray(vertices, dtype=np.float64)
        f = np.ascontiguousarray(faces, dtype=np.int32)  # in range: checked above
        p = np.ascontiguousarray(points, dtype=np.float64).reshape(-1, 3)
        out, _, _ = kernels.winding_number(v, f, p, False, nthreads, eps)
        return jnp.asarray(out.astype(jax.dtypes.canonicalize_dtype(dtype)).reshape(lead))
    vertices = jnp.asarray(vertices).astype(dtype)
    faces = jnp.asarray(faces)
    points = jnp.asarray(points)
    flat = points.astype(dtype).reshape(-1, d)
    if flat.shape[0] == 0:
        return jnp.zeros(batch + lead, dtype)
    if chunk_size is None:
        chunk_size = _auto_chunk(faces.shape[-2], flat.shape[0])
    chunk_size = _validate.positive_int(where, "chunk_size", chunk_size)
    one = lambda v, f: winding_flat(v, f, flat, chunk_size)
    out = jnp.vectorize(one, signature="(n,d),(m,k)->(p)")(vertices, faces)
    out = out.reshape(batch + lead)
    if traced:
        out = _checked_under_jit(out, vertices, faces, points)
    return out
