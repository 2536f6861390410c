"""An independent NumPy float64 implementation of voxelization: the test oracle.

Everything here is written for clarity, not speed, and shares no code or tricks with the
C++ kernels (no difference buffers, no prefix sums, no tiles). Every voxel value is built
from exact convex-polygon clipping:

- `voxelize` computes the box-filtered winding number `W[i, j, k]`, the average over voxel
  `(i, j, k)` of the winding number `w(p)`, where `w(p)` counts the faces crossed by the ray
  from `p` straight up (+z in 3D, +y in 2D), each with the sign of its normal's z (y)
  component. Each face contributes to a voxel the signed volume of the part of the voxel
  that lies *below* the face, inside the face's shadow column.
- `voxelize_backward` is the closed-form gradient of `sum(cotangent * W)` with respect to
  the vertices (the "sub-triangle splat"): each face is clipped in full against every voxel
  it passes through, and each piece pushes the voxel's cotangent onto the face's corners.
- `signed_volume` / `volume_gradient` give the enclosed volume (area in 2D) and its exact
  gradient, for the identity `sum(W) * grid.voxel_volume == signed_volume` of a closed mesh
  inside the grid.
- `winding_number_ray` counts signed ray crossings at points.

Meshes follow trimesh's convention: `vertices` `(V, 3)` float with `faces` `(F, 3)` int
triangles, or `(V, 2)` vertices with `(F, 2)` segments in 2D, oriented so that normals point
outwards (counter-clockwise seen from outside). With that orientation `W` is 1 inside a
closed mesh and 0 outside. A mesh object (`voxax.Mesh`, `trimesh.Trimesh`) may take the
place of `vertices, faces` in every function, e.g. `voxelize(mesh, grid)`.

The +z crossing count equals the generalised winding number only for *closed* surfaces;
for an open surface the value depends on the ray direction. Likewise the backward formula
is the exact derivative of the forward only for closed surfaces (for an open one the
forward also changes through the vertical walls of the shadow, which the splat ignores).
"""

from __future__ import annotations

import numpy as np

from . import _validate
from ._grid import Grid

__all__ = [
    "voxelize",
    "voxelize_backward",
    "signed_volume",
    "volume_gradient",
    "winding_number_ray",
]


# ---------------------------------------------------------------------------------------
# Input checking
# ---------------------------------------------------------------------------------------


def _check_mesh(vertices, faces, dim: int | None = None, where: str = "reference"):
    """Return `(vertices, faces)` as float64 / int64 NumPy arrays after checking them."""
    v, f = _validate.mesh(where, vertices, faces, dim=dim, integer_vertices=True, allow_empty=True)
    return np.asarray(v, dtype=np.float64), np.asarray(f, dtype=np.int64)


def _check_grid(grid, where: str) -> Grid:
    return _validate.grid(where, grid)


# ---------------------------------------------------------------------------------------
# Geometry helpers
# ---------------------------------------------------------------------------------------


def _cross2(u, v):
    """z component of the cross product of two 2D vectors (works on the first two columns)."""
    return u[..., 0] * v[..., 1] - u[..., 1] * v[..., 0]


def _clip(poly: np.ndarray, axis: int, bound: float, keep_below: bool) -> np.ndarray:
    """Clip a convex polygon to a half-space (one Sutherland–Hodgman pass).

    `poly` is `(n, m)`: n vertices in order, m coordinates (the clipping plane is
    `poly[:, axis] == bound`; every other column is interpolated linearly along edges).
    Keeps `poly[:, axis] >= bound`, or `<= bound` when `keep_below`. A polygon lying in the
    plane itself is kept whole. Returns `(n', m)`, with `n' == 0` when nothing of positive
    measure is left.
    """
    if len(poly) == 0:
        return poly
    d = poly[:, axis] - bound
    if keep_below:
        d = -d
    if np.all(d >= 0):
        return poly
    if np.all(d <= 0):
        return poly[:0]
    out = []
    n = len(poly)
    for s in range(n):
        e = (s + 1) % n
        if d[s] >= 0:
            out.append(poly[s])
        if (d[s] > 0 and d[e] < 0) or (d[s] < 0 and d[e] > 0):
            t = d[s] / (d[s] - d[e])
            r = poly[s] + t * (poly[e] - poly[s])
            r[axis] = bound  # exactly on the plane, no rounding
            out.append(r)
    if len(out) < 3:
        return poly[:0]
    return np.array(out)


def _clip_slab(poly: np.ndarray, axis: int, lo: float, hi: float, last: bool) -> np.ndarray:
    """Clip a convex polygon to the slab `lo <= x[axis] <= hi`.

    Cells are treated as half-open, `[lo, hi)`, except the last one of the grid, which is
    closed: a polygon lying exactly in the plane `x[axis] == hi` belongs to the next cell
    (so that a face lying in a grid plane is counted exactly once by the backward pass).
    """
    poly = _clip(_clip(poly, axis, lo, keep_below=False), axis, hi, keep_below=True)
    if len(poly) and not last and np.all(poly[:, axis] == hi):
        return poly[:0]
    return poly


def _cells(edges: np.ndarray, lo: float, hi: float) -> np.ndarray:
    """Indices of the cells `[edges[i], edges[i+1]]` that meet the closed interval `[lo, hi]`."""
    return np.nonzero((edges[:-1] <= hi) & (edges[1:] >= lo))[0]


def _area_and_moment(poly: np.ndarray) -> tuple[float, float]:
    """Signed xy area of a polygon and the integral of its (linear) z over that area.

    `poly` is `(n, 3)` with columns x, y, z; the area is positive for counter-clockwise
    order in the xy plane. The polygon is fanned from its first vertex; over each fan
    triangle the integral of a linear function is area times the mean of its three values.
    """
    p0 = poly[0]
    u = poly[1:-1] - p0
    v = poly[2:] - p0
    areas = 0.5 * _cross2(u, v)
    means = (p0[2] + poly[1:-1, 2] + poly[2:, 2]) / 3.0
    return float(areas.sum()), float((areas * means).sum())


def _ramp_integral(poly: np.ndarray, c: float) -> float:
    """Integral over the (signed) xy area of `poly` of `max(z - c, 0)`, exactly."""
    z = poly[:, 2]
    if c >= z.max():
        return 0.0
    if c > z.min():
        poly = _clip(poly, 2, c, keep_below=False)
        if len(poly) == 0:
            return 0.0
    area, moment = _area_and_moment(poly)
    return moment - c * area


def _column_profile(poly: np.ndarray, ez: np.ndarray) -> np.ndarray:
    """Per-slab contributions of one column piece of a face (before dividing by |voxel|).

    `poly` is the face clipped to one column cell, `(n, 3)` with z as a linear attribute;
    its signed xy area carries the face's sign. Slab k gets the integral over the piece of
    `clamp(z(x, y) - ez[k], 0, ez[k+1] - ez[k])`, the signed volume of the part of the
    voxel below the face. Writing `clamp(z - a, 0, b - a) = ramp(z - a) - ramp(z - b)`
    with `ramp(t) = max(t, 0)`, it is the difference of two ramp integrals, each computed
    exactly by clipping the piece at one height.
    """
    nz = len(ez) - 1
    out = np.zeros(nz)
    zmin, zmax = poly[:, 2].min(), poly[:, 2].max()
    area, _ = _area_and_moment(poly)
    # Slabs entirely below the piece: the whole slab height lies under the face.
    under = ez[1:] <= zmin
    out[under] = area * (ez[1:][under] - ez[:-1][under])
    # Slabs cut by the piece's height range. (Slabs entirely above it get nothing.)
    for k in np.nonzero(~under & (ez[:-1] < zmax))[0]:
        out[k] = _ramp_integral(poly, ez[k]) - _ramp_integral(poly, ez[k + 1])
    return out


def _segment_interval(a, u, axis: int, lo: float, hi: float, last: bool, t0: float, t1: float):
    """Narrow the parameter range `[t0, t1]` of the segment `a + t u` to `lo <= x[axis] <= hi`.

    Uses the same half-open cell rule as `_clip_slab` for segments lying in a grid line.
    Returns `(t0, t1)`; the piece is empty when `t1 <= t0`.
    """
    if u[axis] == 0.0:
        x = a[axis]
        if x < lo or x > hi or (x == hi and not last):
            return 0.0, 0.0
        return t0, t1
    ta = (lo - a[axis]) / u[axis]
    tb = (hi - a[axis]) / u[axis]
    if ta > tb:
        ta, tb = tb, ta
    return max(t0, ta), min(t1, tb)


# ---------------------------------------------------------------------------------------
# Forward
# ---------------------------------------------------------------------------------------


def _voxelize_3d(v: np.ndarray, f: np.ndarray, grid: Grid) -> np.ndarray:
    ex, ey, ez = (grid.edges(a) for a in range(3))
    nx, ny, _ = grid.shape
    out = np.zeros(grid.shape)
    for tri in v[f]:
        a, b, c = tri
        if _cross2(b - a, c - a) == 0.0:
            continue  # vertical or degenerate: no shadow
        for i in _cells(ex, tri[:, 0].min(), tri[:, 0].max()):
            strip = _clip_slab(tri, 0, ex[i], ex[i + 1], last=i == nx - 1)
            if len(strip) == 0:
                continue
            for j in _cells(ey, strip[:, 1].min(), strip[:, 1].max()):
                piece = _clip_slab(strip, 1, ey[j], ey[j + 1], last=j == ny - 1)
                if len(piece) == 0:
                    continue
                out[i, j, :] += _column_profile(piece, ez)
    return out / grid.voxel_volume


def _voxelize_2d(v: np.ndarray, f: np.ndarray, grid: Grid) -> np.ndarray:
    ex, ey = grid.edges(0), grid.edges(1)
    nx, _ = grid.shape
    out = np.zeros(grid.shape)
    for a, b in v[f]:
        u = b - a
        if u[0] == 0.0:
            continue  # vertical or degenerate: no shadow
        for i in _cells(ex, min(a[0], b[0]), max(a[0], b[0])):
            t0, t1 = _segment_interval(a, u, 0, ex[i], ex[i + 1], i == nx - 1, 0.0, 1.0)
            if t1 <= t0:
                continue
            # The piece runs over t in [t0, t1]; along it dx = u.x dt and the face's sign is
            # sign(a.x - b.x), so the signed x-measure is -u.x dt. y(t) = a.y + t u.y.
            scale = -u[0]

            def ramp(c, t0=t0, t1=t1, a=a, u=u):
                # integral over [t0, t1] of max(y(t) - c, 0) dt, exactly
                if u[1] == 0.0:
                    return (t1 - t0) * max(a[1] - c, 0.0)
                tc = (c - a[1]) / u[1]
                lo, hi = (max(t0, tc), t1) if u[1] > 0 else (t0, min(t1, tc))
                if hi <= lo:
                    return 0.0
                return (hi - lo) * (a[1] + 0.5 * (lo + hi) * u[1] - c)

            ya, yb = a[1] + t0 * u[1], a[1] + t1 * u[1]
            ymin, ymax = min(ya, yb), max(ya, yb)
            for j in range(grid.shape[1]):
                if ey[j + 1] <= ymin:
                    out[i, j] += scale * (t1 - t0) * (ey[j + 1] - ey[j])
                elif ey[j] < ymax:
                    out[i, j] += scale * (ramp(ey[j]) - ramp(ey[j + 1]))
    return out / grid.voxel_volume


def voxelize(vertices, faces=None, grid: Grid | None = None) -> np.ndarray:
    """Box-filtered winding numbers of a mesh on a grid, exactly, in float64.

    `W[i, j, k]` is the average over voxel `(i, j, k)` of the winding number `w(p)`, where
    `w(p)` sums `sign(N_t.z)` over the triangles `t` (normal `N_t = (b - a) x (c - a)`) that
    lie above `p` and whose xy-projection contains `p`. Each triangle is clipped to every
    column cell it shadows; within a column its contribution to voxel `k` is the exact
    integral of `clamp(z(x, y) - z_k, 0, z_{k+1} - z_k)` over the clipped projection, so
    the mesh may lie anywhere in space (parts above the grid fill whole columns, parts
    below or beside it contribute nothing). Vertical triangles contribute nothing.

    In 2D the faces are segments, rays go up (+y) and a segment `a -> b` counts with sign
    `sign(a.x - b.x)` (the y-component of its outward normal `(dy, -dx)`).

    For a closed, outward-oriented mesh `W` is 1 inside and 0 outside; for an open surface
    it depends on the ray direction.

    **Arguments:**

    - `vertices`: `(V, 3)` float (or `(V, 2)` in 2D), the vertex positions.
    - `faces`: `(F, 3)` int triangles (or `(F, 2)` int segments in 2D), indexing `vertices`.
    - `grid`: a 3D (or 2D) `voxax.Grid`.

    **Returns:**

    `(*grid.shape)` float64, the voxel averages `W[i, j, k]` (x, then y, then z).
    """
    vertices, faces, (grid,) = _validate.unpack_mesh("voxax.reference.voxelize", vertices, faces, grid)
    grid = _check_grid(grid, "voxax.reference.voxelize")
    v, f = _check_mesh(vertices, faces, grid.dim, "voxax.reference.voxelize")
    if grid.dim == 3:
        return _voxelize_3d(v, f, grid)
    return _voxelize_2d(v, f, grid)


# ---------------------------------------------------------------------------------------
# Backward
# ---------------------------------------------------------------------------------------


def _backward_3d(v: np.ndarray, f: np.ndarray, grid: Grid, g: np.ndarray) -> np.ndarray:
    ex, ey, ez = (grid.edges(a) for a in range(3))
    nx, ny, nz = grid.shape
    grad = np.zeros_like(v)
    for face, tri in zip(f, v[f]):
        a, b, c = tri
        normal = np.cross(b - a, c - a)  # |normal| = twice the area
        nn = float(normal @ normal)
        if nn == 0.0:
            continue  # degenerate face
        for i in _cells(ex, tri[:, 0].min(), tri[:, 0].max()):
            px = _clip_slab(tri, 0, ex[i], ex[i + 1], last=i == nx - 1)
            if len(px) == 0:
                continue
            for j in _cells(ey, px[:, 1].min(), px[:, 1].max()):
                pxy = _clip_slab(px, 1, ey[j], ey[j + 1], last=j == ny - 1)
                if len(pxy) == 0:
                    continue
                for k in _cells(ez, pxy[:, 2].min(), pxy[:, 2].max()):
                    piece = _clip_slab(pxy, 2, ez[k], ez[k + 1], last=k == nz - 1)
                    if len(piece) == 0 or g[i, j, k] == 0.0:
                        continue
                    # Fan the piece from its first vertex. Each fan triangle's vector area
                    # is parallel to `normal`; its dot with `normal` weighs its centroid.
                    p0 = piece[0]
                    fan = 0.5 * np.cross(piece[1:-1] - p0, piece[2:] - p0)  # (n-2, 3)
                    weights = fan @ normal
                    total = weights.sum()
                    if total <= 0.0:
                        continue  # zero-area piece
                    centroid = (weights[:, None] * (p0 + piece[1:-1] + piece[2:]) / 3.0).sum(0) / total
                    vector_area = fan.sum(0)  # = area3D(piece) * nhat_t
                    beta_a = np.cross(b - centroid, c - centroid) @ normal / nn
                    beta_b = np.cross(c - centroid, a - centroid) @ normal / nn
                    beta = np.array([beta_a, beta_b, 1.0 - beta_a - beta_b])
                    grad[face] += g[i, j, k] * beta[:, None] * vector_area[None, :]
    return grad / grid.voxel_volume


def _backward_2d(v: np.ndarray, f: np.ndarray, grid: Grid, g: np.ndarray) -> np.ndarray:
    ex, ey = grid.edges(0), grid.edges(1)
    nx, ny = grid.shape
    grad = np.zeros_like(v)
    for face, (a, b) in zip(f, v[f]):
        u = b - a
        if u[0] == 0.0 and u[1] == 0.0:
            continue  # degenerate face
        normal = np.array([u[1], -u[0]])  # |normal| = length
        for i in _cells(ex, min(a[0], b[0]), max(a[0], b[0])):
            tx0, tx1 = _segment_interval(a, u, 0, ex[i], ex[i + 1], i == nx - 1, 0.0, 1.0)
            if tx1 <= tx0:
                continue
            for j in _cells(ey, min(a[1], b[1]), max(a[1], b[1])):
                t0, t1 = _segment_interval(a, u, 1, ey[j], ey[j + 1], j == ny - 1, tx0, tx1)
                if t1 <= t0 or g[i, j] == 0.0:
                    continue
                # length(piece) * nhat = (t1 - t0) * normal; beta at the piece's midpoint.
                tm = 0.5 * (t0 + t1)
                w = g[i, j] * (t1 - t0) * normal
                grad[face[0]] += (1.0 - tm) * w
                grad[face[1]] += tm * w
    return grad / grid.voxel_volume


def voxelize_backward(vertices, faces=None, grid: Grid | None = None, cotangent=None) -> np.ndarray:
    """Gradient of `L = sum(cotangent * voxelize(vertices, faces, grid))` w.r.t. the vertices.

    The closed form of the transport theorem (the "sub-triangle splat"): every face is
    clipped in full against every voxel box it passes through (vertical faces included),
    and each piece `P` in voxel `v` adds

        cotangent[v] / |voxel| * area(P) * nhat_t * beta_m(centroid of P)

    to each corner `m` of its face `t`, where `nhat_t` is the unit outward normal and
    `beta` the barycentric coordinates (within `t`) of the piece's area centroid. In 2D a
    piece of segment `a -> b` weighs `length(P) * nhat * beta(midpoint)` with
    `nhat = (dy, -dx) / length`. Pieces outside the grid and degenerate faces contribute
    nothing. Cells are half-open (the grid's last cell closed), so a face lying exactly in a
    grid plane is counted once.

    For a closed mesh this is the exact derivative of `voxelize` (wherever it exists).

    **Arguments:**

    - `vertices`: `(V, 3)` float (or `(V, 2)` in 2D), the vertex positions.
    - `faces`: `(F, 3)` int triangles (or `(F, 2)` int segments in 2D).
    - `grid`: a 3D (or 2D) `voxax.Grid`.
    - `cotangent`: `(*grid.shape)` float, the gradient of `L` with respect to `W`.

    **Returns:**

    `(V, 3)` float64 (or `(V, 2)`), `dL / d vertices`.
    """
    vertices, faces, (grid, cotangent) = _validate.unpack_mesh("voxax.reference.voxelize_backward", vertices, faces, grid, cotangent)
    grid = _check_grid(grid, "voxax.reference.voxelize_backward")
    v, f = _check_mesh(vertices, faces, grid.dim, "voxax.reference.voxelize_backward")
    g = np.asarray(cotangent, dtype=np.float64)
    if g.shape != grid.shape:
        raise ValueError(f"voxax.reference.voxelize_backward: `cotangent` must have shape {grid.shape}, got {g.shape}")
    if grid.dim == 3:
        return _backward_3d(v, f, grid, g)
    return _backward_2d(v, f, grid, g)


# ---------------------------------------------------------------------------------------
# Volume, and winding numbers at points
# ---------------------------------------------------------------------------------------


def signed_volume(vertices, faces=None) -> float:
    """The signed volume enclosed by a closed triangle mesh (signed area of closed polylines in 2D).

    3D: `sum over triangles of det(a, b, c) / 6`; 2D: `sum over segments of cross(a, b) / 2`.
    Positive for outward (counter-clockwise) orientation.

    **Arguments:**

    - `vertices`: `(V, 3)` float (or `(V, 2)`).
    - `faces`: `(F, 3)` int triangles (or `(F, 2)` int segments).

    **Returns:**

    float, the signed volume (area).
    """
    vertices, faces, _ = _validate.unpack_mesh("voxax.reference.signed_volume", vertices, faces)
    v, f = _check_mesh(vertices, faces, None, "voxax.reference.signed_volume")
    if v.shape[1] == 3:
        a, b, c = v[f[:, 0]], v[f[:, 1]], v[f[:, 2]]
        return float(np.einsum("ij,ij->i", a, np.cross(b, c)).sum() / 6.0)
    a, b = v[f[:, 0]], v[f[:, 1]]
    return float(_cross2(a, b).sum() / 2.0)


def volume_gradient(vertices, faces=None) -> np.ndarray:
    """Exact gradient of `signed_volume` with respect to the vertices.

    3D: each triangle adds `area * nhat / 3 = N_t / 6` to each of its corners, with
    `N_t = (b - a) x (c - a)`; 2D: each segment adds `length * nhat / 2 = (dy, -dx) / 2` to
    each endpoint. For a closed mesh this equals the derivative of `signed_volume`.

    **Arguments:**

    - `vertices`: `(V, 3)` float (or `(V, 2)`).
    - `faces`: `(F, 3)` int triangles (or `(F, 2)` int segments).

    **Returns:**

    `(V, 3)` float64 (or `(V, 2)`).
    """
    vertices, faces, _ = _validate.unpack_mesh("voxax.reference.volume_gradient", vertices, faces)
    v, f = _check_mesh(vertices, faces, None, "voxax.reference.volume_gradient")
    grad = np.zeros_like(v)
    if v.shape[1] == 3:
        a, b, c = v[f[:, 0]], v[f[:, 1]], v[f[:, 2]]
        per_corner = np.cross(b - a, c - a) / 6.0
    else:
        u = v[f[:, 1]] - v[f[:, 0]]
        per_corner = np.stack([u[:, 1], -u[:, 0]], axis=1) / 2.0
    for m in range(f.shape[1]):
        np.add.at(grad, f[:, m], per_corner)
    return grad


def _edge_side(p0, p1, q):
    """Sign (+1 or -1) of `cross(p1 - p0, q - p0)` with `q` perturbed by `(eps, eps^2)`.

    Simulation of simplicity: exact zeros are broken by the perturbation's first non-zero
    order, `-(p1 - p0).y`, then `(p1 - p0).x`, so that every point lies on exactly one side
    of every proper edge, consistently across faces sharing that edge.
    `q` is `(P, 2)`; returns `(P,)`.
    """
    u = p1 - p0
    e = _cross2(u, q - p0)
    tie = -u[1] if u[1] != 0.0 else u[0]
    return np.where(e != 0.0, np.sign(e), np.sign(tie))


def winding_number_ray(vertices, faces=None, points=None) -> np.ndarray:
    """Signed ray-crossing count at points, with the ray going straight up (+z; +y in 2D).

    Each triangle whose xy-projection contains the point and which lies strictly above it
    adds `sign(N_t.z)`; in 2D each segment over the point's x adds `sign(a.x - b.x)`.
    Points whose ray passes exactly through an edge or vertex are resolved by a symbolic
    perturbation of the point by `(eps, eps^2)` in xy (x in 2D), so shared edges are
    counted once. Points lying exactly on the surface get an unspecified value. For a
    closed, outward-oriented mesh this is the winding number (1 inside, 0 outside).

    **Arguments:**

    - `vertices`: `(V, 3)` float (or `(V, 2)`).
    - `faces`: `(F, 3)` int triangles (or `(F, 2)` int segments).
    - `points`: `(P, 3)` float (or `(P, 2)`), the query points.

    **Returns:**

    `(P,)` float64, the crossing counts.
    """
    vertices, faces, (points,) = _validate.unpack_mesh("voxax.reference.winding_number_ray", vertices, faces, points)
    v, f = _check_mesh(vertices, faces, None, "voxax.reference.winding_number_ray")
    d = v.shape[1]
    if points is None:
        raise TypeError("voxax.reference.winding_number_ray: missing `points`")
    q = np.asarray(_validate.coordinates("voxax.reference.winding_number_ray", "points", points, d), dtype=np.float64)
    if q.ndim != 2 or q.shape[1] != d:
        raise ValueError(f"voxax.reference.winding_number_ray: `points` must have shape (P, {d}), got {q.shape}")
    w = np.zeros(len(q))
    if d == 2:
        for a, b in v[f]:
            if a[0] == b[0]:
                continue
            lo, hi = min(a[0], b[0]), max(a[0], b[0])
            # The point's x is perturbed by +eps: it is over the segment for lo <= x < hi.
            over = (q[:, 0] >= lo) & (q[:, 0] < hi)
            y = a[1] + (q[:, 0] - a[0]) / (b[0] - a[0]) * (b[1] - a[1])
            w += np.where(over & (y > q[:, 1]), np.sign(a[0] - b[0]), 0.0)
        return w
    for a, b, c in v[f]:
        nz = _cross2(b - a, c - a)
        if nz == 0.0:
            continue
        s = np.sign(nz)
        inside = (
            (_edge_side(a[:2], b[:2], q[:, :2]) == s)
            & (_edge_side(b[:2], c[:2], q[:, :2]) == s)
            & (_edge_side(c[:2], a[:2], q[:, :2]) == s)
        )
        # Height of the triangle's plane above the point's xy (barycentric interpolation).
        la = _cross2(c[:2] - b[:2], q[:, :2] - b[:2]) / nz
        lb = _cross2(a[:2] - c[:2], q[:, :2] - c[:2]) / nz
        z = la * a[2] + lb * b[2] + (1.0 - la - lb) * c[2]
        w += np.where(inside & (z > q[:, 2]), s, 0.0)
    return w
