"""Explicit surface intersections (ESI): a closed shape as the intersection of height fields.

A *height field* along a unit direction `d` is the solid `HF(d)` of the points whose ray
along `+d` hits the surface S: below the surface's top depth map seen from `+d`. A
*double height field* hull `DHF(d) = HF(d) ∩ HF(-d)` is bounded by both depth maps along
`d`. An ESI is `DHF(d_0) ∩ HF(d_1) ∩ ... ∩ HF(d_m)` (m <= 3); it always contains S, and for
well-chosen axes it is close to S.

- [`depth_map`][voxax.esi.depth_map]: first and last hits along `d` on an orthographic
  pixel frame (exact BVH ray casts), with the mask and the hit faces' normals.
- [`candidates`][voxax.esi.candidates]: the DHF axes (a half sphere, since `DHF(d) =
  DHF(-d)`) and HF axes (the full sphere), spherical Fibonacci points plus the
  coordinate axes.
- [`select`][voxax.esi.select]: the DHF axis and up to three HF axes minimising the
  energy `E = Dist + min(mu (Dist + eps1), eps2)` (Chamfer distance plus surface coverage)
  by branch and bound.
- [`occupancy`][voxax.esi.occupancy]: exact inside/outside of an ESI at points (ray casts
  against the mesh).
- [`to_mesh`][voxax.esi.to_mesh]: a watertight mesh of the ESI, as the manifold3d
  intersection of height-field solids built from depth maps.

All geometry is float64 and computed eagerly on NumPy arrays through `voxax.BVH`.
"""

from __future__ import annotations

import concurrent.futures
import ctypes
import math
import os
import weakref
from typing import NamedTuple

import numpy as np

from .. import _blas, _kernels, _validate
from .._mesh import Mesh, face_normals
from .._spatial import BVH

__all__ = [
    "DepthMap",
    "ESI",
    "Frame",
    "candidates",
    "closed_mesh",
    "depth_map",
    "energy",
    "esi_gap",
    "height_field_hull",
    "fibonacci_sphere",
    "frame_for",
    "height_field_solid",
    "intersect_solids",
    "occupancy",
    "select",
    "to_mesh",
]


# ----------------------------------------------------------------------------- inputs


def closed_mesh(where: str, vertices, faces=None) -> Mesh:
    """A `Mesh` from a mesh object or `(vertices, faces)`, checked to be a closed,
    consistently oriented, non-empty 3D triangle mesh (every directed edge has exactly one
    reverse). Raises `ValueError` otherwise."""
    if faces is None:
        if _validate.is_mesh_object(vertices):
            v, f = _validate.mesh_object_arrays(where, vertices)
        elif isinstance(vertices, tuple) and len(vertices) == 2:
            v, f = vertices
        else:
            raise TypeError(
                f"{where}: expected a voxax.Mesh, a trimesh.Trimesh or vertices and faces, got {type(vertices).__name__}"
            )
    else:
        v, f = vertices, faces
    v = np.asarray(v)
    f = np.asarray(f)
    if v.dtype.kind not in "fiu":
        raise TypeError(f"{where}: vertices must be a real array, got dtype {v.dtype}")
    if f.dtype.kind not in "iu":
        raise TypeError(f"{where}: faces must be an integer array, got dtype {f.dtype}")
    if v.ndim != 2 or v.shape[1] != 3:
        raise ValueError(f"{where}: vertices must have shape (V, 3), got {v.shape}")
    if f.ndim != 2 or f.shape[1] != 3:
        raise ValueError(f"{where}: faces must have shape (F, 3), got {f.shape}")
    if len(f) == 0:
        raise ValueError(f"{where}: the mesh has no faces")
    if f.min() < 0 or f.max() >= len(v):
        raise ValueError(f"{where}: face indices out of range [0, {len(v)})")
    v = v.astype(np.float64)
    if not np.all(np.isfinite(v)):
        raise ValueError(f"{where}: vertices contain NaN or Inf")
    f = f.astype(np.int64)
    a, b = f.reshape(-1), np.roll(f, -1, axis=1).reshape(-1)
    keep = a != b
    n = len(v)
    fwd = np.sort(a[keep] * n + b[keep])
    rev = np.sort(b[keep] * n + a[keep])
    dup = int(np.count_nonzero(fwd[1:] == fwd[:-1]))
    # closed and consistently oriented: the directed edges are exactly their reverses
    unmatched = int(np.count_nonzero(fwd != rev))
    if dup or unmatched:
        raise ValueError(
            f"{where}: needs a closed, consistently oriented triangle mesh "
            f"({unmatched} edges without a matching reverse edge, {dup} repeated directed edges); "
            "open meshes have no inside"
        )
    mesh = Mesh(v, f.astype(np.int32))
    used = v[_used(len(v), f)]
    if not np.ptp(used, axis=0).max() > 0:
        raise ValueError(f"{where}: the mesh is a single point")
    return mesh


def _used(n: int, faces) -> np.ndarray:
    used = np.zeros(n, bool)
    used[np.asarray(faces).ravel()] = True
    return used


def unit_direction(where: str, direction) -> np.ndarray:
    """`direction` as a unit `(3,)` float64 vector; `ValueError` if it is not a finite,
    non-zero 3-vector."""
    d = np.asarray(direction)
    if d.dtype.kind not in "fiu":
        raise TypeError(f"{where}: direction must be a real 3-vector, got dtype {d.dtype}")
    d = d.astype(np.float64)
    if d.shape != (3,):
        raise ValueError(f"{where}: direction must have shape (3,), got {d.shape}")
    if not np.all(np.isfinite(d)):
        raise ValueError(f"{where}: direction contains NaN or Inf")
    n = float(np.linalg.norm(d))
    if not n > 1e-150:
        raise ValueError(f"{where}: direction is zero (a degenerate direction)")
    return d / n


# ----------------------------------------------------------------------------- depth maps


class Frame(NamedTuple):
    """An orthographic pixel frame perpendicular to a direction.

    - `center`: `(3,)` float64, the centre of the mesh's bounding box.
    - `u`, `v`, `d`: `(3,)` float64, a right-handed orthonormal basis (`u x v = d`); `d` is
      the viewing direction.
    - `radius`: the bounding sphere's radius about `center` (every vertex lies within it).
    - `resolution`: pixels per side. Pixel `(i, j)` is the ray `center + x_i u + y_j v + z d`
      with `x_i = y_i = -radius + (i + 1/2) 2 radius / resolution`.
    """

    center: np.ndarray
    u: np.ndarray
    v: np.ndarray
    d: np.ndarray
    radius: float
    resolution: int

    @property
    def pixel(self) -> float:
        """The pixel size `2 radius / resolution`."""
        return 2.0 * self.radius / self.resolution

    def coords(self) -> np.ndarray:
        """`(resolution,)` float64 pixel-centre coordinates along `u` (and `v`)."""
        i = np.arange(self.resolution, dtype=np.float64)
        return -self.radius + (i + 0.5) * self.pixel

    def points(self, depth) -> np.ndarray:
        """World points `(r, r, 3)` of the pixels at depths `depth (r, r)` along `d`."""
        x = self.coords()
        z = np.asarray(depth, dtype=np.float64)
        return self.center + x[:, None, None] * self.u + x[None, :, None] * self.v + z[..., None] * self.d

    def to_local(self, points) -> np.ndarray:
        """Frame coordinates `(..., 3)` = `(x, y, z)` of world points `(..., 3)`."""
        p = np.asarray(points, dtype=np.float64) - self.center
        return np.stack([p @ self.u, p @ self.v, p @ self.d], axis=-1)


def frame_for(direction, center, radius, resolution) -> Frame:
    """The [`Frame`][voxax.esi.Frame] of a unit direction: `u` is the unit vector of the
    coordinate axis least aligned with `d` (lowest index on ties) made orthogonal to `d`,
    and `v = d x u`."""
    d = np.asarray(direction, dtype=np.float64)
    e = np.zeros(3)
    e[int(np.argmin(np.abs(d)))] = 1.0
    u = e - (e @ d) * d
    u /= np.linalg.norm(u)
    v = np.cross(d, u)
    v /= np.linalg.norm(v)
    return Frame(np.asarray(center, np.float64), u, v, d, float(radius), int(resolution))


class DepthMap(NamedTuple):
    """The first and last hits of a mesh along parallel rays.

    - `first`: `(r, r)` float64, the smallest depth `z` (along `frame.d`, from the frame's
      centre) where the pixel's line meets the surface; `nan` off the mask.
    - `last`: `(r, r)` float64, the largest such depth; `nan` off the mask.
    - `mask`: `(r, r)` bool, the pixels whose line meets the surface (the silhouette).
    - `normal_first`, `normal_last`: `(r, r, 3)` float64 unit outward normals of the faces
      hit (zeros off the mask).
    - `face_first`, `face_last`: `(r, r)` int32 faces hit (-1 off the mask).
    - `frame`: the [`Frame`][voxax.esi.Frame].

    `last` is the height function of `HF(d)`, `first` (negated) that of `HF(-d)`, and the
    pair bounds the double height field `DHF(d)`.
    """

    first: np.ndarray
    last: np.ndarray
    mask: np.ndarray
    normal_first: np.ndarray
    normal_last: np.ndarray
    face_first: np.ndarray
    face_last: np.ndarray
    frame: Frame


def bounding_sphere(mesh: Mesh) -> tuple[np.ndarray, float]:
    """`(center (3,), radius)`: the bounding box centre and the largest vertex distance."""
    used = mesh.vertices[_used(mesh.n_vertices, mesh.faces)]
    c = 0.5 * (used.min(0) + used.max(0))
    r = float(np.sqrt(((used - c) ** 2).sum(1).max()))
    return c, r


def _depth_map(bvh: BVH, frame: Frame, normals: np.ndarray, threads=None) -> DepthMap:
    r = frame.resolution
    x = frame.coords()
    base = (frame.center + x[:, None, None] * frame.u + x[None, :, None] * frame.v).reshape(-1, 3)
    reach = 2.0 * frame.radius
    lo = bvh.first_hits(base - reach * frame.d, frame.d, threads=threads)
    hi = bvh.first_hits(base + reach * frame.d, -frame.d, threads=threads)
    mask = lo.hit & hi.hit
    first = np.where(mask, lo.t - reach, np.nan).reshape(r, r)
    last = np.where(mask, reach - hi.t, np.nan).reshape(r, r)
    ff = np.where(mask, lo.face, -1).astype(np.int32)
    fl = np.where(mask, hi.face, -1).astype(np.int32)
    nf = np.where(mask[:, None], normals[np.maximum(ff, 0)], 0.0).reshape(r, r, 3)
    nl = np.where(mask[:, None], normals[np.maximum(fl, 0)], 0.0).reshape(r, r, 3)
    return DepthMap(first, last, mask.reshape(r, r), nf, nl, ff.reshape(r, r), fl.reshape(r, r), frame)


def depth_map(vertices, faces=None, direction=None, *, resolution: int = 256, threads=None) -> DepthMap:
    """The first and last hits of a closed mesh along `direction` on an orthographic frame.

    The frame (see [`Frame`][voxax.esi.Frame]) is centred on the mesh's bounding box,
    spans its bounding sphere with `resolution x resolution` pixels, and every pixel's
    line is cast exactly against the mesh through a BVH (watertight ray-triangle tests,
    float64), once from each side.

    **Arguments:**

    - `vertices`: `(V, 3)` float, or a `Mesh` (then `direction` moves into the `faces`
      slot: `depth_map(mesh, direction)`), or a [`BVH`][voxax.BVH] of the mesh: depth maps
      along many directions then share one tree (`depth_map(bvh, direction)`; the mesh is
      checked once per tree).
    - `faces`: `(F, 3)` int; the mesh must be closed and consistently oriented.
    - `direction`: `(3,)` float, non-zero (normalised here).
    - `resolution`: pixels per side (>= 1).
    - `threads`: threads for the ray casts (default: all cores).

    **Returns:** a [`DepthMap`][voxax.esi.DepthMap].

    >>> from voxax import data
    >>> dm = depth_map(data.cube(2.0), (0.0, 0.0, 1.0), resolution=4)
    >>> float(dm.first[1, 1]), float(dm.last[1, 1])
    (-1.0, 1.0)
    """
    where = "esi.depth_map"
    if isinstance(vertices, BVH):
        bvh = vertices
        if direction is None:
            faces, direction = None, faces
        elif faces is not None:
            raise TypeError(f"{where}: given a BVH, pass only the direction after it")
        mesh, normals = _checked_tree(where, bvh)
    else:
        vertices, faces, (direction,) = _validate.unpack_mesh(where, vertices, faces, direction)
        mesh = closed_mesh(where, vertices, faces)
        bvh, normals = BVH(mesh), face_normals(mesh.vertices, mesh.faces)
    if direction is None:
        raise TypeError(f"{where}: missing `direction`")
    d = unit_direction(where, direction)
    res = _validate.positive_int(where, "resolution", resolution)
    c, rad = bounding_sphere(mesh)
    frame = frame_for(d, c, rad, res)
    dm = _depth_map(bvh, frame, normals, threads)
    if not dm.mask.any():
        raise ValueError(
            f"{where}: the depth map is empty (no pixel centre of the {res}x{res} frame "
            "meets the mesh); raise the resolution"
        )
    return dm


_CHECKED_TREES: weakref.WeakKeyDictionary = weakref.WeakKeyDictionary()


def _checked_tree(where: str, bvh: BVH) -> tuple[Mesh, np.ndarray]:
    """The mesh of `bvh`, checked by `closed_mesh` on first use, and its face normals; both
    kept on the tree so that later depth maps skip the check."""
    cached = _CHECKED_TREES.get(bvh)
    if cached is None:
        mesh = closed_mesh(where, bvh.mesh)
        cached = _CHECKED_TREES[bvh] = (mesh, face_normals(mesh.vertices, mesh.faces))
    return cached


# ----------------------------------------------------------------------------- height-field solids

#: Heights of a height field's off-domain top and of its bottom, in bounding-sphere radii
#: below the centre: both lie outside the bounding sphere, hence outside every DHF.
ON_SURFACE_PIXELS = 0.5
_OFF_TOP = 1.02
_BOTTOM = 1.05


def _grid_faces(r: int) -> np.ndarray:
    i, j = np.meshgrid(np.arange(r - 1), np.arange(r - 1), indexing="ij")
    a = (i * r + j).ravel()
    b, c, d = a + r, a + r + 1, a + 1  # (i+1, j), (i+1, j+1), (i, j+1)
    return np.concatenate([np.stack([a, b, c], 1), np.stack([a, c, d], 1)])


def _border(r: int) -> np.ndarray:
    """Grid indices of the border, counter-clockwise in (u, v)."""
    i = np.arange(r - 1)
    return np.concatenate([i * r, (r - 1) * r + i, (r - 1 - i) * r + r - 1, (r - 1 - i) + 0 * r])


def height_field_solid(dm: DepthMap, sign: int) -> tuple[Mesh, int]:
    """A closed outward mesh of `HF(sign * d)` from a depth map, clipped far below.

    The top is the pixel-centre grid at the height function (`last` for `sign = +1`,
    `first` for `-1`); pixels off the mask drop to `1.02 radius` below the centre, and
    the solid ends `1.05 radius` below it. Returns `(mesh, n_top_wall_faces)`: the faces
    of the top and walls come first (the bottom is outside the bounding sphere).
    """
    fr = dm.frame
    r = fr.resolution
    if r < 2:
        raise ValueError("height-field solids need a depth map with resolution >= 2")
    R = fr.radius
    h = (dm.last if sign > 0 else -dm.first).copy()
    h[~dm.mask] = -_OFF_TOP * R
    # pixels next to the silhouette close the solid at the mean mid-depth of their
    # neighbours on the mask, so a DHF pinches within a pixel instead of a cliff
    mid = np.where(dm.mask, 0.5 * (dm.first + dm.last), 0.0)
    msk = dm.mask.astype(np.float64)
    pm = np.pad(mid, 1)
    pk = np.pad(msk, 1)
    tot = np.zeros_like(mid)
    cnt = np.zeros_like(mid)
    for di in (-1, 0, 1):
        for dj in (-1, 0, 1):
            tot += pm[1 + di : 1 + di + r, 1 + dj : 1 + dj + r]
            cnt += pk[1 + di : 1 + di + r, 1 + dj : 1 + dj + r]
    ring = (~dm.mask) & (cnt > 0)
    h[ring] = sign * tot[ring] / cnt[ring]
    x = fr.coords()
    X, Y = np.meshgrid(x, x, indexing="ij")
    top = np.stack([X.ravel(), Y.ravel(), h.ravel()], 1)
    bot = np.stack([X.ravel(), Y.ravel(), np.full(r * r, -_BOTTOM * R)], 1)
    g = _grid_faces(r)
    b = _border(r)
    nb = np.roll(b, -1)
    n = r * r
    walls = np.concatenate([np.stack([b, b + n, nb + n], 1), np.stack([b, nb + n, nb], 1)])
    faces = np.concatenate([g, walls, g[:, ::-1] + n])
    local = np.concatenate([top, bot])
    world = fr.center + local[:, :1] * fr.u + local[:, 1:2] * fr.v + (sign * local[:, 2:]) * fr.d
    if sign < 0:
        faces = faces[:, ::-1]
    return Mesh(world, faces.astype(np.int32)), len(g) + len(walls)


# ----------------------------------------------------------------------------- candidates


def fibonacci_sphere(n: int, *, hemisphere: bool = False) -> np.ndarray:
    """`n` spherical Fibonacci points `(n, 3)` float64 on the unit sphere (or the upper
    half sphere `z > 0` with `hemisphere=True`), evenly spread by the golden angle."""
    n = int(n)
    if n < 0:
        raise ValueError(f"n must be >= 0, got {n}")
    i = np.arange(n, dtype=np.float64)
    z = 1.0 - (i + 0.5) / n if hemisphere else 1.0 - 2.0 * (i + 0.5) / max(n, 1)
    phi = i * math.pi * (3.0 - math.sqrt(5.0))
    s = np.sqrt(np.maximum(0.0, 1.0 - z * z))
    return np.stack([s * np.cos(phi), s * np.sin(phi), z], 1)


def candidates(n_dhf: int = 50, n_hf: int = 80) -> tuple[np.ndarray, np.ndarray]:
    """Candidate axes for the DHF and the HFs.

    **Arguments:**

    - `n_dhf`: Fibonacci directions on the half sphere for the DHF (`DHF(d) = DHF(-d)`),
      after the three coordinate axes.
    - `n_hf`: Fibonacci directions on the whole sphere for the HFs, after the six signed
      coordinate axes.

    **Returns:** `(dhf (3 + n_dhf, 3), hf (6 + n_hf, 3))` float64 unit vectors.

    >>> dhf, hf = candidates(10, 12)
    >>> dhf.shape, hf.shape
    ((13, 3), (18, 3))
    """
    eye = np.eye(3)
    dhf = np.concatenate([eye, fibonacci_sphere(n_dhf, hemisphere=True)])
    hf = np.concatenate([np.stack([eye[0], -eye[0], eye[1], -eye[1], eye[2], -eye[2]]), fibonacci_sphere(n_hf)])
    return dhf, hf


def _canonical(d: np.ndarray) -> tuple[tuple, int]:
    """A hashable key of the line through `d` and the sign of `d` on it."""
    nz = np.flatnonzero(np.abs(d) > 1e-12)
    s = 1 if d[nz[0]] > 0 else -1
    key = tuple(np.round(s * d, 12) + 0.0)
    return key, s


def _T(theta_deg):
    return 0.5 * np.tanh(theta_deg - 85.0) + 0.5


# ----------------------------------------------------------------------------- selection


_COLUMN_SIGNATURES = {
    "voxax_column_test": (
        ctypes.c_int,
        [
            _kernels.D,
            _kernels.I64,
            ctypes.c_int64,
            ctypes.c_int64,
            _kernels.D,
            ctypes.c_int64,
            _kernels.D,
            ctypes.c_int32,
            ctypes.POINTER(ctypes.c_uint8),
            ctypes.c_char_p,
            ctypes.c_int64,
        ],
    ),
}


def _column_test(points, ks, params, G: int, lims, threads) -> np.ndarray:
    """`(n,)` bool: whether point `i`, in the frame of direction `ks[i]` (`params[k]`: the
    frame's axes as a row-major 3 x 3 matrix, its centre in frame coordinates, the
    direction's sign on its line, the grid's half width and cell width), lies over the
    `G x G` grid with `sign * depth < lims[k, cell]` (C++, see `csrc/esi/columns_host.cc`)."""
    p = np.ascontiguousarray(points, np.float64).reshape(-1, 3)
    ks = np.ascontiguousarray(ks, np.int64).reshape(-1)
    if len(ks) != len(p):
        raise ValueError(f"column test: {len(p)} points but {len(ks)} directions")
    params = np.ascontiguousarray(params, np.float64)
    lims = np.ascontiguousarray(lims, np.float64)
    K = len(params)
    if params.shape != (K, 15) or lims.shape != (K, G * G):
        raise ValueError(f"column test: params {params.shape} and lims {lims.shape} for K = {K}, G = {G}")
    out = np.zeros(len(p), np.uint8)
    lib = _kernels.declare(_COLUMN_SIGNATURES)
    err = _kernels.error_buffer()
    status = lib.voxax_column_test(
        _kernels.pointer(p, _kernels.D),
        _kernels.pointer(ks, _kernels.I64),
        len(p),
        K,
        _kernels.pointer(params, _kernels.D),
        int(G),
        _kernels.pointer(lims, _kernels.D),
        _kernels.threads(threads),
        out.ctypes.data_as(ctypes.POINTER(ctypes.c_uint8)),
        err,
        _kernels.ERRLEN,
    )
    _kernels.check(status, err)
    return out.view(bool)


VP8 = ctypes.POINTER(ctypes.c_uint8)
# the hot entry points of the selection take plain addresses: `a.ctypes.data` costs a
# quarter of `_kernels.pointer` (called some 10^5 times per selection)
_P = ctypes.c_void_p


def _addr(a: np.ndarray) -> int:
    """The address of a C-contiguous array's data (for `_P` arguments)."""
    return a.ctypes.data


# the tables of a column ray cast (see `_Casts`)
_CAST_ARGS = [ctypes.c_int64, _kernels.D, _kernels.D, _kernels.I64, ctypes.c_int64, ctypes.c_int64, _kernels.D, _kernels.I64, _kernels.I32,
              ctypes.c_int64, _kernels.D, ctypes.c_int64, ctypes.c_double]  # fmt: skip
_LIST_SIGNATURES = {
    "voxax_column_lists": (
        ctypes.c_int,
        [_kernels.D, ctypes.c_int64, _kernels.I64, ctypes.c_int64, ctypes.c_int64, _kernels.D, ctypes.c_int64, ctypes.c_double,
         ctypes.c_int32, _kernels.I64, _kernels.I32, ctypes.c_int64, _kernels.D, _kernels.D, ctypes.c_int32, ctypes.c_char_p,
         ctypes.c_int64],
    ),
    "voxax_column_hits": (
        ctypes.c_int,
        [_kernels.D, _kernels.I64, ctypes.c_int64] + _CAST_ARGS + [ctypes.c_int32, VP8, ctypes.c_char_p, ctypes.c_int64],
    ),
    "voxax_column_inside": (
        ctypes.c_int,
        [_kernels.D, ctypes.c_int64, _kernels.I64, ctypes.c_int64]
        + _CAST_ARGS
        + [ctypes.c_int32, VP8, _kernels.I64, ctypes.c_char_p, ctypes.c_int64],
    ),
    "voxax_column_known": (
        ctypes.c_int,
        [_P, ctypes.c_int64, _P, ctypes.c_int64, ctypes.c_int64, ctypes.c_int64, _P, _P,
         _P, _P, ctypes.c_int64, ctypes.c_int64, _P]
        + _CAST_ARGS
        + [ctypes.c_int32, _P, ctypes.c_char_p, ctypes.c_int64],
    ),
}


def _column_lists(mesh: Mesh, frames, G: int, delta: float, threads):
    """For each line's frame (`frames[l]`, 15 numbers as in `_column_test`), the triangles
    of `mesh` listed per cell of a `G x G` grid (`offsets`, `(L G^2 + 1,)` into `entries`)
    and each cell's least and largest triangle depth (`lo`, `hi`, `(L, G^2)`), in two C++
    calls (counts, then the lists; see `csrc/esi/columns_host.cc`)."""
    V = np.ascontiguousarray(mesh.vertices, np.float64)
    F = np.ascontiguousarray(mesh.faces, np.int64)
    frames = np.ascontiguousarray(frames, np.float64).reshape(-1, 15)
    L, GG = len(frames), int(G) * int(G)
    lib = _kernels.declare(_LIST_SIGNATURES)
    err = _kernels.error_buffer()

    def call(fill, counts, entries, lo, hi):
        status = lib.voxax_column_lists(
            _kernels.pointer(V, _kernels.D), len(V), _kernels.pointer(F, _kernels.I64), len(F), L,
            _kernels.pointer(frames, _kernels.D), int(G), float(delta), fill, _kernels.pointer(counts, _kernels.I64),
            _kernels.pointer(entries, _kernels.I32), len(entries), _kernels.pointer(lo, _kernels.D), _kernels.pointer(hi, _kernels.D),
            _kernels.threads(threads), err, _kernels.ERRLEN,
        )  # fmt: skip
        _kernels.check(status, err)

    counts = np.zeros(L * GG + 1, np.int64)
    none = np.zeros(1)
    call(0, counts, np.zeros(1, np.int32), none, none)
    offsets = np.zeros(L * GG + 1, np.int64)
    np.cumsum(counts[:-1], out=offsets[1:])
    entries = np.zeros(int(offsets[-1]), np.int32)
    lo, hi = np.zeros((L, GG)), np.zeros((L, GG))
    call(1, offsets, entries, lo, hi)
    return offsets, entries, lo, hi


class _Casts(NamedTuple):
    """The tables of the column ray casts (C++, `csrc/esi/columns_host.cc`): per signed
    direction `k` its frame (`params[k]`, 15 numbers as in `_column_test`), its direction,
    its line and its column test limits (`lims[k]`, `G^2`); per line the triangles listed
    over each cell (`offsets`, `(L G^2 + 1,)` into `entries`); the corners of each
    triangle (`tris`, `(F, 9)`); rays count hits beyond `t_min`."""

    params: np.ndarray
    dirs: np.ndarray
    line_of: np.ndarray
    G: int
    lims: np.ndarray
    offsets: np.ndarray
    entries: np.ndarray
    tris: np.ndarray
    t_min: float
    #: the tables as arguments of the C++ entry points (made once: ctypes pointers are slow
    #: to make)
    args: list

    @classmethod
    def make(cls, params, dirs, line_of, G, lims, offsets, entries, tris, t_min) -> _Casts:
        params = np.ascontiguousarray(params, np.float64)
        K, G = len(params), int(G)
        c = cls(
            params,
            np.ascontiguousarray(dirs, np.float64),
            np.ascontiguousarray(line_of, np.int64),
            G,
            np.ascontiguousarray(lims, np.float64),
            np.ascontiguousarray(offsets, np.int64),
            np.ascontiguousarray(entries, np.int32),
            np.ascontiguousarray(tris, np.float64).reshape(-1, 9),
            float(t_min),
            [],
        )
        L = (len(c.offsets) - 1) // max(G * G, 1)
        if (
            params.shape != (K, 15)
            or c.dirs.shape != (K, 3)
            or c.line_of.shape != (K,)
            or c.lims.shape != (K, G * G)
            or len(c.offsets) != L * G * G + 1
        ):
            raise ValueError("column ray casts: inconsistent table shapes")
        # the lists are ordered by depth along each frame's third axis: a ray must run along it
        axis = params[:, [2, 5, 8]] * params[:, 12:13]
        if K and not np.allclose(c.dirs, axis, rtol=0.0, atol=1e-12):
            raise ValueError("column ray casts: each direction must be its frame's third axis times its sign")
        c.args.extend([
            K, _kernels.pointer(c.params, _kernels.D), _kernels.pointer(c.dirs, _kernels.D), _kernels.pointer(c.line_of, _kernels.I64),
            L, G, _kernels.pointer(c.lims, _kernels.D), _kernels.pointer(c.offsets, _kernels.I64),
            _kernels.pointer(c.entries, _kernels.I32), len(c.entries), _kernels.pointer(c.tris, _kernels.D), len(c.tris), c.t_min,
        ])  # fmt: skip
        return c


def _column_hits(points, ks, casts: _Casts, threads) -> np.ndarray:
    """`(n,)` uint8: bit 0, whether the ray from point `i` along direction `ks[i]` meets the
    mesh beyond `t_min`; bit 1, whether it passed the column test and so looked at the
    triangles listed over its cell (C++, exact and watertight)."""
    p = np.ascontiguousarray(points, np.float64).reshape(-1, 3)
    ks = np.ascontiguousarray(ks, np.int64).reshape(-1)
    if len(ks) != len(p):
        raise ValueError(f"column ray casts: {len(p)} points but {len(ks)} directions")
    out = np.zeros(len(p), np.uint8)
    lib = _kernels.declare(_LIST_SIGNATURES)
    err = _kernels.error_buffer()
    status = lib.voxax_column_hits(
        _kernels.pointer(p, _kernels.D), _kernels.pointer(ks, _kernels.I64), len(p), *casts.args, _kernels.threads(threads),
        _kernels.pointer(out, VP8), err, _kernels.ERRLEN,
    )  # fmt: skip
    _kernels.check(status, err)
    return out


def _column_inside(points, blocks, casts: _Casts, threads) -> tuple[np.ndarray, int]:
    """For each block `(start, end, k1, k2)` of `blocks`: whether the rays of the points
    `start <= i < end` along directions `k1` and `k2` (`-1`: `k1` alone) both meet the mesh
    (`(n,)` bool, False outside the blocks), and the number of casts that looked at
    triangles (C++)."""
    p = np.ascontiguousarray(points, np.float64).reshape(-1, 3)
    blocks = np.ascontiguousarray(blocks, np.int64).reshape(-1, 4)
    out = np.zeros(len(p), np.uint8)
    n_cast = np.zeros(1, np.int64)
    lib = _kernels.declare(_LIST_SIGNATURES)
    err = _kernels.error_buffer()
    status = lib.voxax_column_inside(
        _kernels.pointer(p, _kernels.D), len(p), _kernels.pointer(blocks, _kernels.I64), len(blocks), *casts.args,
        _kernels.threads(threads), _kernels.pointer(out, VP8), _kernels.pointer(n_cast, _kernels.I64), err, _kernels.ERRLEN,
    )  # fmt: skip
    _kernels.check(status, err)
    return out.view(bool), int(n_cast[0])


def _column_known(pairs, off, IN, gid, hk, ghit, gn, gpts, casts: _Casts, threads) -> int:
    """For every `(b, c)` of `pairs`, fill `IN[c, r]` for the rows `r` of block `b`
    (`off[b] <= r < off[b + 1]`) from the registry `ghit[c, gid[r]]` (the ray of point
    `gpts[gid[r]]` along direction `hk[c]`), or by a cast recorded there (C++, in place);
    the number of casts that looked at triangles."""
    pairs = np.ascontiguousarray(pairs, np.int64).reshape(-1, 2)
    off = np.ascontiguousarray(off, np.int64)
    nh, R = IN.shape
    if IN.dtype != np.bool_ or not IN.flags.c_contiguous or ghit.dtype != np.int8 or not ghit.flags.c_contiguous:
        raise ValueError("known ray casts: IN must be C-contiguous bool (nh, R), ghit int8")
    gid = np.ascontiguousarray(gid, np.int64)
    hk = np.ascontiguousarray(hk, np.int64)
    if gid.shape != (R,) or hk.shape != (nh,) or ghit.shape[0] != nh or len(gpts) < gn or off.ndim != 1:
        raise ValueError("known ray casts: inconsistent shapes")
    gpts = np.ascontiguousarray(gpts, np.float64)
    n_cast = np.zeros(1, np.int64)
    lib = _kernels.declare(_LIST_SIGNATURES)
    err = _kernels.error_buffer()
    status = lib.voxax_column_known(
        _addr(pairs), len(pairs), _addr(off), len(off) - 1, R, nh,
        _addr(IN), _addr(gid), _addr(hk),
        _addr(ghit), ghit.shape[1], int(gn), _addr(gpts), *casts.args,
        _kernels.threads(threads), _addr(n_cast), err, _kernels.ERRLEN,
    )  # fmt: skip
    _kernels.check(status, err)
    return int(n_cast[0])


_BOUND_SIGNATURES = {
    "voxax_bound_samples": (
        ctypes.c_int,
        [_P, ctypes.c_int64, ctypes.c_int64, ctypes.c_int64, _P, _P, _P, _P, _P,
         ctypes.c_int64, ctypes.c_int64, ctypes.c_int32, _P, _P, _P, _P, _P,
         ctypes.c_char_p, ctypes.c_int64],
    ),
    "voxax_bound_removals": (
        ctypes.c_int,
        [_P, ctypes.c_int64, ctypes.c_int64, _P, ctypes.c_int64, _P, ctypes.c_int64, _P,
         ctypes.c_int64, _P, _P, ctypes.c_int32, _P, _P, _P, ctypes.c_char_p,
         ctypes.c_int64],
    ),
    "voxax_bound_blocks": (
        ctypes.c_int,
        [_P, ctypes.c_int64, _P, ctypes.c_int64, _P, _P, ctypes.c_int32, _P, ctypes.c_char_p, ctypes.c_int64],
    ),
}  # fmt: skip


def _c_table(x: np.ndarray, dtype, shape, what: str) -> np.ndarray:
    """`x` as a C-contiguous array of `dtype` and `shape` (bools as uint8), or a ValueError."""
    x = np.asarray(x)
    if x.shape != tuple(shape):
        raise ValueError(f"{what}: shape {x.shape}, expected {tuple(shape)}")
    if x.dtype == np.bool_:
        x = x.view(np.uint8)
    return np.ascontiguousarray(x, dtype)


def _bound_samples(rr, cur, Dr, suf, Vr, sufv, c0: int, nc: int, with_suf: bool):
    """The sums of the bounds over a node's hidden surface samples `rr` for the HF columns
    `c0 <= j < c0 + nc` (C++, `csrc/esi/bounds_host.cc`): `C[i, c] = min(cur[i],
    Dr[rr[i], j])` and `Vn[i, c] = Vr[rr[i], j]`, `(n, nc)`; `cd[c]`, the sum of
    `C[:, c]` (with `with_suf`, of `min(C[:, c], suf[rr, j + 1])`); `vn[c]`, the visible
    ones; `vmax[c]`, those visible or visible along a later column (`sufv[rr, j + 1]`)."""
    rr = np.ascontiguousarray(rr, np.int64)
    rows, nh = Dr.shape
    n = len(rr)
    cur = _c_table(cur, np.float64, (n,), "bound sums")
    Dr = _c_table(Dr, np.float64, (rows, nh), "bound sums")
    suf = _c_table(suf, np.float64, (rows, nh + 1), "bound sums")
    Vr = _c_table(Vr, np.uint8, (rows, nh), "bound sums")
    sufv = _c_table(sufv, np.uint8, (rows, nh + 1), "bound sums")
    C = np.empty((n, nc))
    Vn = np.empty((n, nc), np.uint8)
    cd = np.empty(nc)
    vn = np.empty(nc, np.int64)
    vmax = np.empty(nc, np.int64)
    lib = _kernels.declare(_BOUND_SIGNATURES)
    err = _kernels.error_buffer()
    status = lib.voxax_bound_samples(
        _addr(rr), n, rows, nh, _addr(cur), _addr(Dr),
        _addr(suf), _addr(Vr), _addr(sufv), int(c0), int(nc),
        int(bool(with_suf)), _addr(C), _addr(Vn), _addr(cd),
        _addr(vn), _addr(vmax), err, _kernels.ERRLEN,
    )  # fmt: skip
    _kernels.check(status, err)
    return C, Vn.view(bool), cd, vn, vmax


def _bound_removals(IN, rows, cols, col_of, s3: int, wd, wt, threads):
    """The floater sums of the bounds (C++): row `i` counts in column `c` where
    `IN[cols[c], rows[i]]` (`col_of` None) or where `col_of[i] == c` (`cols` and `col_of`
    ascending). Returns `sums` `(3, nc)` (the sums of `wd`, `wt` and 1 over the rows
    counting in each column) and `Md`, `Mt` `(nh - s3, nc)`: the sums of `wd`, `wt` over
    the rows counting in column `c` that HF `h = s3 + j` removes (`IN[h, row]` False), for
    `h > cols[c]` (0 elsewhere)."""
    nh, R = IN.shape
    if IN.dtype != np.bool_ or not IN.flags.c_contiguous:
        raise ValueError("bound sums: IN must be C-contiguous bool (nh, R)")
    rows = np.ascontiguousarray(rows, np.int64)
    cols = np.ascontiguousarray(cols, np.int64)
    n, nc = len(rows), len(cols)
    wd = _c_table(wd, np.float64, (R,), "bound sums")
    wt = _c_table(wt, np.float64, (R,), "bound sums")
    if col_of is not None:
        col_of = _c_table(col_of, np.int64, (n,), "bound sums")
    sums = np.empty((3, nc))
    Md = np.empty((nh - s3, nc)) if 0 <= s3 <= nh else np.empty(0)
    Mt = np.empty_like(Md)
    lib = _kernels.declare(_BOUND_SIGNATURES)
    err = _kernels.error_buffer()
    status = lib.voxax_bound_removals(
        _addr(IN.view(np.uint8)), nh, R, _addr(rows), n,
        _addr(cols), nc, None if col_of is None else _addr(col_of), int(s3),
        _addr(wd), _addr(wt), _kernels.threads(threads), _addr(sums),
        _addr(Md), _addr(Mt), err, _kernels.ERRLEN,
    )  # fmt: skip
    _kernels.check(status, err)
    return sums, Md, Mt


def _bound_blocks(alive, off, wd, wt, sums: bool = True) -> np.ndarray:
    """`(3, nb)`: the sums of `alive`, `alive * wd` and `alive * wt` over each block
    `off[b] <= row < off[b + 1]` (C++; the last two 0 without `sums`)."""
    R = len(alive)
    alive = _c_table(alive, np.uint8, (R,), "bound sums")
    off = np.ascontiguousarray(off, np.int64)
    wd = _c_table(wd, np.float64, (R,), "bound sums")
    wt = _c_table(wt, np.float64, (R,), "bound sums")
    nb = len(off) - 1
    if nb < 0:
        raise ValueError("bound sums: the block offsets need at least one entry")
    out = np.empty((3, nb))
    lib = _kernels.declare(_BOUND_SIGNATURES)
    err = _kernels.error_buffer()
    status = lib.voxax_bound_blocks(
        _addr(alive), R, _addr(off), nb, _addr(wd), _addr(wt), int(bool(sums)), _addr(out), err, _kernels.ERRLEN,
    )  # fmt: skip
    _kernels.check(status, err)
    return out


class _Problem:
    """Everything precomputed for the energy of any combination of candidate axes.

    Height fields are indexed by signed direction `k`; a DHF along a line is the pair of
    its two signed directions. The mesh is scaled into `[-1/1.1, 1/1.1]^3` first.
    """

    def __init__(self, mesh: Mesh, dirs: np.ndarray, *, resolution, n_samples, seed, threads):
        from ..metrics import sample_surface

        used = mesh.vertices[_used(mesh.n_vertices, mesh.faces)]
        lo, hi = used.min(0), used.max(0)
        self.center = 0.5 * (lo + hi)
        self.scale = (1.0 / 1.1) / float(0.5 * (hi - lo).max())
        self.mesh = Mesh((mesh.vertices - self.center) * self.scale, mesh.faces)
        self.threads = threads
        self.bvh = BVH(self.mesh)
        c, rad = bounding_sphere(self.mesh)
        self.sphere = (c, rad)
        self.eps = 1e-9 * rad
        normals = face_normals(self.mesh.vertices, self.mesh.faces)
        area_s = (
            0.5
            * np.linalg.norm(
                np.cross(
                    self.mesh.vertices[self.mesh.faces[:, 1]] - self.mesh.vertices[self.mesh.faces[:, 0]],
                    self.mesh.vertices[self.mesh.faces[:, 2]] - self.mesh.vertices[self.mesh.faces[:, 0]],
                ),
                axis=1,
            ).sum()
        )
        S = sample_surface(self.mesh, n_samples, seed)
        self.P = S.points
        self.Pn = S.normals
        self.n_samples = n_samples
        # signed directions, grouped by line so that one depth map serves both signs
        lines: dict = {}
        self.dirs = []  # (line, sign) per signed direction
        keys: dict = {}
        for d in dirs:
            lk, s = _canonical(d)
            if lk not in lines:
                lines[lk] = len(lines)
            kk = (lines[lk], s)
            if kk not in keys:
                keys[kk] = len(keys)
                self.dirs.append(kk)
        self.key = keys
        self._lines = lines
        line_dirs = [None] * len(lines)
        for lk, li in lines.items():
            line_dirs[li] = np.asarray(lk)
        self.vec = np.array([s * line_dirs[li] for li, s in self.dirs])
        K = len(self.dirs)
        self.D = np.zeros((n_samples, K))
        self.visP = np.zeros((n_samples, K), bool)
        pixel = 2.0 * rad / resolution
        #: height-field samples this close to S count as on S (the depth maps are linear
        #: between pixels); the surface samples stand for them
        self.on_surface = max(5e-4, ON_SURFACE_PIXELS * pixel)
        self.B, self.Bn, self.Bd = [], [], []
        # one line (then one direction) per thread, each single-threaded (the BVH builds of
        # the height-field solids are; the results do not depend on the order), and one
        # BLAS thread (see `voxax._blas`)
        workers = max(1, min(_kernels.threads(threads) or (os.cpu_count() or 1), K))
        inner = 1 if workers > 1 else threads
        frames = [frame_for(ld / np.linalg.norm(ld), c, rad, resolution) for ld in line_dirs]
        rng = np.random.default_rng(seed + 7)
        seeds = [int(rng.integers(2**31)) for _ in self.dirs]

        def terms(k):
            li, s = self.dirs[k]
            solid, n_tw = height_field_solid(self.maps[li], s)
            hit = (_column_hits(self.P, np.full(n_samples, k), self._casts, inner) & 1) == 1
            # distances to the height field's boundary, needed only where S is hidden: to its
            # top and walls, or straight down to its bottom (a point of S projects inside it)
            tw = Mesh(solid.vertices, solid.faces[:n_tw])
            dist = np.zeros(n_samples)
            if hit.any():
                fr = self.maps[li].frame
                below = (self.P[hit] - fr.center) @ fr.d * s + _BOTTOM * fr.radius
                dist[hit] = np.minimum(BVH(tw).closest_points(self.P[hit], threads=inner).distance, below)
            a_tw = (
                0.5
                * np.linalg.norm(
                    np.cross(
                        tw.vertices[tw.faces[:, 1]] - tw.vertices[tw.faces[:, 0]],
                        tw.vertices[tw.faces[:, 2]] - tw.vertices[tw.faces[:, 0]],
                    ),
                    axis=1,
                ).sum()
            )
            nb = int(round(n_samples * a_tw / area_s))
            bs = sample_surface(tw, nb, seeds[k])
            inside = ((bs.points - c) ** 2).sum(1) <= (rad * (1 + 1e-9)) ** 2
            pts, nrm = bs.points[inside], bs.normals[inside]
            # which samples lie off S: a search pruned just beyond the on-surface distance
            # (most samples lie farther: their distances are taken when needed, `distances`)
            bd = self.bvh.closest_points(pts, threads=inner, max_distance=self.on_surface * (1 + 1e-9)).distance
            off = bd > self.on_surface
            return dist, hit, pts[off], nrm[off], np.full(int(off.sum()), np.nan)

        with concurrent.futures.ThreadPoolExecutor(workers) as pool, _blas.single_threaded():
            self.maps = dict(enumerate(pool.map(lambda fr: _depth_map(self.bvh, fr, normals, inner), frames)))
            self._casts = self._column_casts()
            for k, (dist, hit, b, bn, bd) in enumerate(pool.map(terms, range(K))):
                self.D[:, k] = dist
                self.visP[:, k] = ~hit
                self.B.append(b)
                self.Bn.append(bn)
                self.Bd.append(bd)
        self._hit: dict = {}
        self._T: dict = {}
        self._TP: dict = {}
        self._maybe: dict = {}
        self._terms: dict = {}
        self._registries: dict = {}
        self._samples = None  # see `samples`
        self.n_full = 0
        self.n_rays = 0

    def registry(self, hk) -> np.ndarray:
        """`(len(hk), n)` int8: whether the ray of boundary sample `g` (of `samples()`)
        along HF candidate `hk[c]` meets S (-1: not cast yet); one per list of candidates,
        shared by all DHFs (a sample's ray along a direction is the same ray for each)."""
        key = tuple(int(k) for k in hk)
        reg = self._registries.get(key)
        if reg is None:
            reg = self._registries[key] = np.full((len(key), len(self.samples()[0])), -1, np.int8)
        return reg

    def _column_casts(self) -> _Casts:
        """The tables of the selection's exact ray casts (C++, `csrc/esi/columns_host.cc`),
        for every line at once: the lists of the triangles over each cell of a `G x G` grid
        of the line's frame, ordered by their top depth (cells about a third of the mesh's
        mean edge wide or a depth-map pixel, the smaller, `G <= 512`), and the column test's
        table: per signed direction the frame (`params`, 15 numbers) and the depth limits per
        cell as `sign * depth < limit` (`lims`, `G^2`), from the least and largest depth of
        the triangles whose `(x, y)` bounding box (widened by a margin) meets the cell. A ray
        along `+d` from a point above its cell's largest depth (or along `-d` below the
        least) cannot meet S: its hit would be a point of a triangle over that cell. The
        others look at the cell's triangles (`cast`)."""
        nl = len(self.maps)
        # cells about a third of a mean edge wide (a few triangles per cell), and no coarser
        # than the depth maps' pixels
        V, F = self.mesh.vertices, self.mesh.faces
        edge = float(np.linalg.norm(V[F[:, 1]] - V[F[:, 0]], axis=1).mean()) if len(F) else 1.0
        fine = np.ceil(3.0 * self.maps[0].frame.radius / max(edge, 1e-12))
        G = int(np.clip(max(fine, self.maps[0].frame.resolution), 16, 512))
        K = len(self.dirs)
        frames = np.zeros((nl, 15))
        for li in range(nl):
            fr = self.maps[li].frame
            R = fr.radius * (1 + 1e-6)
            M = np.stack([fr.u, fr.v, fr.d], 1)
            frames[li] = np.concatenate([M.ravel(), fr.center @ M, [1.0, R, 2.0 * R / G]])
        delta = 1e-6 * self.maps[0].frame.radius
        offsets, entries, lo, hi = _column_lists(self.mesh, frames, G, delta, self.threads)
        params = np.zeros((K, 15))
        lims = np.zeros((K, G * G))
        line_of = np.zeros(K, np.int64)
        for k, (li, s) in enumerate(self.dirs):
            params[k] = frames[li]
            params[k, 12] = float(s)
            lims[k] = hi[li] if s > 0 else -lo[li]
            line_of[k] = li
        tris = self.mesh.vertices[self.mesh.faces].reshape(-1, 9)
        return _Casts.make(params, self.vec, line_of, G, lims, offsets, entries, tris, self.eps)

    def distances(self, k: int, idx: np.ndarray) -> np.ndarray:
        """The distances to S of the boundary samples `idx` of HF k (exact closest points,
        taken once, when first asked for)."""
        return self.distances_many([(k, idx)])[0]

    def distances_many(self, items) -> list:
        """`distances(k, idx)` of every `(k, idx)` of `items`, in one call."""
        need = [(k, idx[np.isnan(self.Bd[k][idx])]) for k, idx in items]
        need = [(k, i) for k, i in need if len(i)]
        if need:
            d = self.bvh.closest_points(np.concatenate([self.B[k][i] for k, i in need]), threads=self.threads).distance
            at = 0
            for k, i in need:
                self.Bd[k][i] = d[at : at + len(i)]
                at += len(i)
        return [self.Bd[k][idx] for k, idx in items]

    def samples(self) -> tuple[np.ndarray, np.ndarray]:
        """Every height field's boundary samples stacked (`B[k]` is rows `off[k]:off[k + 1]`)."""
        if self._samples is None:
            self._samples = (np.concatenate(self.B), np.concatenate([[0], np.cumsum([len(b) for b in self.B])]))
        return self._samples

    def cast(self, points: np.ndarray, ks: np.ndarray) -> np.ndarray:
        """Whether the ray from each point along its direction `ks[i]` meets S (exact, C++:
        the triangles listed over the point's cell, after the column test)."""
        ks = np.ascontiguousarray(ks, np.int64)
        if not len(ks):
            return np.zeros(0, bool)
        out = _column_hits(points, ks, self._casts, self.threads)
        self.n_rays += int(np.count_nonzero(out & 2))
        return (out & 1).astype(bool)

    def may_hit(self, points: np.ndarray, k2: int) -> np.ndarray:
        """`(n,)` bool: False where the ray from a point along direction k2 certainly misses
        S (by `columns`), True where it may hit."""
        return self.may_hit_many(points, np.full(len(points), k2))

    def may_hit_many(self, points: np.ndarray, ks: np.ndarray) -> np.ndarray:
        """`may_hit` of each point along its own direction `ks[i]` (C++)."""
        ks = np.ascontiguousarray(ks, np.int64)
        if not len(ks):
            return np.zeros(0, bool)
        c = self._casts
        return _column_test(points, ks, c.params, c.G, c.lims, self.threads)

    def _maybe_bits(self, k: int, k2: int) -> np.ndarray:
        """`maybe` of every boundary sample of HF k along k2, as packed bits (kept)."""
        bits = self._maybe.get((k, k2))
        if bits is None:
            bits = self._maybe[(k, k2)] = np.packbits(self.may_hit(self.B[k], k2))
        return bits

    def maybe(self, k: int, k2: int, idx) -> np.ndarray:
        """`(len(idx),)` bool: False where the ray of boundary sample `idx` (None: all) of
        HF k along direction k2 certainly misses S (by `columns`), True where it may hit."""
        bits = self._maybe_bits(k, k2)
        if idx is None:
            return np.unpackbits(bits, count=len(self.B[k])).view(bool)
        idx = np.asarray(idx)
        return ((bits[idx >> 3] >> (7 - (idx & 7)).astype(np.uint8)) & 1).astype(bool)

    def index(self, d) -> int:
        """The signed-direction index of a candidate direction."""
        lk, s = _canonical(np.asarray(d, np.float64))
        return self.key[(self._lines[lk], s)]

    def hit(self, k: int, k2: int, idx=None) -> np.ndarray:
        """Whether the rays from the boundary samples `idx` (default: all) of HF k along
        direction k2 hit S (cast once per sample and direction, then cached)."""
        idx = np.arange(len(self.B[k])) if idx is None else idx
        self._ensure([(k, k2, idx)])
        return self._hit[(k, k2)][idx] == 1

    def _ensure(self, requests) -> None:
        """Cast, in one call, the rays of `(k, k2, idx)` requests not cast yet."""
        todo: dict = {}
        for k, k2, idx in requests:
            h = self._hit.get((k, k2))
            if h is None:
                h = self._hit[(k, k2)] = np.full(len(self.B[k]), -1, np.int8)
            miss = idx[h[idx] < 0]
            if not len(miss):
                continue
            mb = self.maybe(k, k2, miss)
            h[miss[~mb]] = 0
            miss = miss[mb]
            if not len(miss):
                continue
            if (k, k2) in todo:  # several requests: the union, ascending
                mark = np.zeros(len(h), bool)
                mark[todo[(k, k2)]] = True
                mark[miss] = True
                miss = np.flatnonzero(mark)
            todo[(k, k2)] = miss
        if not todo:
            return
        keys = list(todo)
        sel = [todo[key] for key in keys]
        origins = np.concatenate([self.B[k][i] for (k, _), i in zip(keys, sel)])
        ks = np.repeat(np.array([k2 for _, k2 in keys], np.int64), [len(i) for i in sel])
        res = self.cast(origins, ks)
        at = 0
        for key, i in zip(keys, sel):
            self._hit[key][i] = res[at : at + len(i)]
            at += len(i)

    def floaters(self, k: int, others) -> np.ndarray:
        """The indices (ascending) of HF k's boundary samples inside every HF of `others`:
        the rays along each of them hit S. Filtered one direction at a time (in the order
        given), so later directions cast only the rays of the samples still inside."""
        idx = self._may_float(k, others)
        for k2 in others:
            if not len(idx):
                break
            idx = idx[self.hit(k, k2, idx)]
        return idx

    def _may_float(self, k: int, others) -> np.ndarray:
        """The indices of HF k's boundary samples whose rays along all of `others` may hit
        S (`maybe`): a superset of the floaters, found without casting rays."""
        if not len(others):
            return np.arange(len(self.B[k]))
        bits = self._maybe_bits(k, others[0])
        for k2 in others[1:]:
            bits = bits & self._maybe_bits(k, k2)
        return np.flatnonzero(np.unpackbits(bits, count=len(self.B[k])))

    def filter_many(self, items) -> list:
        """`floaters(k, others)` of every `(k, others)` in `items`, casting the rays of all
        of them in one call per filtering step."""
        alive = [self._may_float(k, others) for k, others in items]
        step = 0
        while True:
            live = [t for t, (_, others) in enumerate(items) if step < len(others) and len(alive[t])]
            if not live:
                return alive
            self._ensure([(items[t][0], items[t][1][step], alive[t]) for t in live])
            for t in live:
                k, k2 = items[t][0], items[t][1][step]
                alive[t] = alive[t][self._hit[(k, k2)][alive[t]] == 1]
            step += 1

    def prefetch(self, combos) -> None:
        """Cast the rays that `energy` needs for every combination in `combos`, in one call
        per filtering step instead of one per pair of directions."""
        items = {}
        for ks in combos:
            ks = sorted(set(ks))
            for k in ks:
                items[(k, tuple(k2 for k2 in ks if k2 != k))] = None
        self.filter_many(list(items))

    def cd_st(self, ks) -> float:
        return float(self.D[:, list(ks)].min(1).mean())

    def T(self, k: int, k2: int, angle: float) -> np.ndarray:
        """T of the angle between the normals of HF k's boundary samples and direction k2."""
        t = self._T.get((k, k2, angle))
        if t is None:
            t = _T_of(self.Bn[k] @ self.vec[k2], angle)
            self._T[(k, k2, angle)] = t
        return t

    def TP(self, k: int, angle: float) -> np.ndarray:
        """On of the surface samples for direction k: T where visible, 1 elsewhere."""
        t = self._TP.get((k, angle))
        if t is None:
            t = np.where(self.visP[:, k], _T_of(self.Pn @ self.vec[k], angle), 1.0)
            self._TP[(k, angle)] = t
        return t

    def TPall(self, angle: float) -> np.ndarray:
        """`(K, N)`: `TP` of every direction."""
        t = self._TP.get(("all", angle))
        if t is None:
            t = self._TP[("all", angle)] = np.stack([self.TP(k, angle) for k in range(len(self.dirs))])
        return t

    def visT(self) -> np.ndarray:
        """`(K, N)`: `visP` transposed (rows are contiguous)."""
        t = self._TP.get("visT")
        if t is None:
            t = self._TP["visT"] = np.ascontiguousarray(self.visP.T)
        return t

    def TPmin(self, angle: float) -> np.ndarray:
        """The least On of each surface sample over every direction."""
        t = self._TP.get(("min", angle))
        if t is None:
            t = self.TP(0, angle)
            for k in range(1, len(self.dirs)):
                t = np.minimum(t, self.TP(k, angle))
            self._TP[("min", angle)] = t
        return t

    def _visible_terms(self, ks, angle: float) -> tuple[float, int]:
        """The surface samples visible along one of the directions `ks` (sorted): the sum of
        their On values (the least over the directions) and their count."""
        vis = self.visP[:, ks].any(1)
        on_p = np.ones(self.n_samples)
        for k in ks:
            on_p = np.minimum(on_p, self.TP(k, angle))
        return float(on_p[vis].sum()), int(vis.sum())

    def energy(self, ks, eps1: float, eps2: float, angle: float = 85.0) -> dict:
        """E (Eq. 1-5) of the ESI bounded by the signed directions `ks`.

        S~'s surface is the part of S visible along one of the directions (sampled by the
        surface samples themselves, at distance 0) and the "floaters": boundary samples of
        a height field that are off S and inside all the other height fields.
        """
        ks = sorted(set(ks))
        self.n_full += 1
        tot_on, n = self._visible_terms(ks, angle)
        tot_d = 0.0
        for k in ks:
            keep = self.floaters(k, [k2 for k2 in ks if k2 != k])
            if not len(keep):
                continue
            # a floater is inside every other height field, so its rays along their axes
            # hit S (v = 0, On = 1 there): only its own axis can cover it
            on = self.T(k, k, angle)[keep]
            tot_on += float(on.sum())
            tot_d += float(self.distances(k, keep).sum())
            n += len(keep)
        cd_st = self.cd_st(ks)
        if n == 0:
            return dict(E=math.inf, dist=math.inf, cd_st=cd_st, cd_ts=math.inf, mu=1.0)
        cd_ts = tot_d / n
        mu = tot_on / n
        dist = cd_st + cd_ts
        E = dist + min(mu * (dist + eps1), eps2)
        return dict(E=E, dist=dist, cd_st=cd_st, cd_ts=cd_ts, mu=mu)


def _T_of(cos, angle):
    theta = np.degrees(np.arccos(np.clip(cos, -1.0, 1.0)))
    return 0.5 * np.tanh(theta - angle) + 0.5


class ESI(NamedTuple):
    """The selected axes of an explicit surface intersection and their energies.

    - `dhf_axis`: `(3,)` float64 unit axis of the double height field (its sign is
      immaterial).
    - `hf_axes`: `(m, 3)` float64 unit axes of the height fields (`HF(d)` keeps the
      points whose ray along `+d` meets the surface).
    - `energy`: E of the selection (Eq. 1, in the units of the mesh scaled into
      `[-1/1.1, 1/1.1]^3`).
    - `by_m`: `(M,)` float64, the least E found with exactly `m = 0, 1, ...` HFs (the
      search stops at the first `m` that does not lower E by more than `tol`, unless
      `stop_early=False`; that last level only looks for a choice below the previous best
      minus `tol`, and its entry is `nan` when there is none).
    - `dhf_index`, `hf_indices`: indices into the candidate arrays.
    - `chamfer`: the selection's Chamfer `Dist = CD(S, S~) + CD(S~, S)` (same units).
    - `mu`: its uncovered fraction (Eq. 4).
    - `leaves`, `evaluations`: `(M,)` int64, the combinations with `m` HFs and how many of
      them were evaluated in full (the rest were pruned by the lower bound).
    """

    dhf_axis: np.ndarray
    hf_axes: np.ndarray
    energy: float
    by_m: np.ndarray
    dhf_index: int
    hf_indices: tuple
    chamfer: float
    mu: float
    leaves: np.ndarray
    evaluations: np.ndarray

    @property
    def prune_rate(self) -> float:
        """The fraction of combinations with >= 1 HF that were never evaluated in full."""
        leaves = int(self.leaves[1:].sum())
        return 1.0 - int(self.evaluations[1:].sum()) / leaves if leaves else 0.0

    @property
    def axes(self) -> list:
        """The signed ray directions that define the ESI: `+dhf`, `-dhf`, then the HFs."""
        return [self.dhf_axis, -self.dhf_axis] + list(self.hf_axes)


_CHUNK = 8  # leaves whose rays are cast together (exhaustive search)


def _top_sums(c: np.ndarray, r: int) -> list:
    """`out[s][j]` = the sum of the `s` largest of `c[j:]` (`s <= r`), with `out[s][len(c)] = 0`."""
    n = len(c)
    out = [np.zeros(n + 1) for _ in range(r + 1)]
    if r == 1 and n:  # the suffix maxima (of values >= 0 and the 0 past the end)
        out[1][:n] = np.maximum.accumulate(np.asarray(c, np.float64)[::-1])[::-1]
        return out
    top: list = []
    for j in range(n - 1, -1, -1):
        top = sorted(top + [float(c[j])], reverse=True)[:r]
        for s in range(1, r + 1):
            out[s][j] = sum(top[:s])
    return out


class _Node(NamedTuple):
    """A partial choice of HFs `hs` (ascending candidate indices) below one DHF."""

    hs: tuple
    rr: np.ndarray  # indices into `_Dhf.rows` of the surface samples hidden from every axis so far
    cur: np.ndarray  # their least distance to the boundary of one of the height fields so far
    n_vis: int  # surface samples visible along one of the axes so far
    vis: np.ndarray  # (N,) bool: which
    base: np.ndarray  # (N,) the least On of each surface sample over the axes so far
    alive: np.ndarray  # (R,) bool: the candidate floaters inside every HF of `hs` (but their own)


class _Dhf:
    """Everything one DHF fixes of E, for the exact energies and lower bounds of E of its
    choices of HFs (the nodes of its search tree).

    With the DHF along `(kp, km)` and HFs from the candidates `hk`:

    - `CD(S, S~)` sums `min(D)` over the surface samples hidden from the DHF (`rows`);
    - the visible surface samples count at distance 0;
    - the *candidate floaters* are the boundary samples that can be floaters of some choice
      of HFs: for each HF candidate `j` those of `HF(j)` inside both sides of the DHF
      (block `j`), and those of each side of the DHF inside the other (the last two
      blocks). `IN[j, row]` says whether a row's ray along HF candidate `j` hits S (cast
      as needed, a block at a time; `BK` says which blocks are known along which
      candidates). The floaters of a choice of HFs are the rows of its blocks that lie
      inside all of its other HFs.
    """

    def __init__(self, prob: _Problem, kp: int, km: int, hk, angle: float):
        self.prob, self.kp, self.km, self.angle = prob, kp, km, angle
        self.hk = hk = list(hk)
        self.nh = len(hk)
        visd = prob.visP[:, kp] | prob.visP[:, km]
        self.rows = np.flatnonzero(~visd)
        self.cur = np.minimum(prob.D[self.rows, kp], prob.D[self.rows, km])
        self.Dr = prob.D[np.ix_(self.rows, hk)]
        self.Vr = prob.visP[np.ix_(self.rows, hk)]
        inf = np.full((len(self.rows), 1), np.inf)
        self.suf = np.concatenate([np.minimum.accumulate(self.Dr[:, ::-1], axis=1)[:, ::-1], inf], 1)
        self.sufv = np.concatenate(
            [np.logical_or.accumulate(self.Vr[:, ::-1], axis=1)[:, ::-1], np.zeros_like(inf, bool)], 1
        )
        self.visd = visd
        self.base = np.minimum(prob.TP(kp, angle), prob.TP(km, angle))
        self.tpmin = prob.TPmin(angle)
        self.same = np.array([k in (kp, km) for k in hk], bool)
        self.built = False

    def _build(self) -> None:
        """The candidate floaters: the boundary samples of every HF candidate inside both
        sides of the DHF, and those of each side inside the other (one C++ call)."""
        prob, kp, km, nh = self.prob, self.kp, self.km, self.nh
        bk = list(self.hk) + [kp, km]
        pts, soff = prob.samples()
        blocks = [(soff[k], soff[k + 1], kp, km) for j, k in enumerate(self.hk) if not self.same[j]]
        blocks += [(soff[kp], soff[kp + 1], km, -1), (soff[km], soff[km + 1], kp, -1)]
        inside, n_cast = _column_inside(pts, blocks, prob._casts, prob.threads)
        prob.n_rays += n_cast
        empty = np.zeros(0, np.int64)
        bidx = [
            empty if j < nh and self.same[j] else np.flatnonzero(inside[soff[k] : soff[k + 1]])
            for j, k in enumerate(bk)
        ]
        sizes = np.array([len(i) for i in bidx])
        self.off = np.concatenate([[0], np.cumsum(sizes)])
        R = int(self.off[-1])
        self.R = R
        self.gid = np.concatenate([soff[k] + i for k, i in zip(bk, bidx)]).astype(np.int64)
        self.hkarr = np.asarray(self.hk, np.int64)
        self.wd = np.concatenate(prob.distances_many(list(zip(bk, bidx))))
        self.wt = np.concatenate([prob.T(k, k, self.angle)[i] for k, i in zip(bk, bidx)])
        self.IN = np.zeros((nh, R), bool)
        # which blocks' rows are known along which HF candidates (BK[b, j]): a height field
        # along the DHF's own line changes nothing; a block is not filtered by its own
        # height field
        self.BK = np.zeros((nh + 2, nh), bool)
        self.IN[self.same] = True
        self.BK[:, self.same] = True
        for j in range(nh):
            self.IN[j, self.off[j] : self.off[j + 1]] = True
            self.BK[j, j] = True
        self.brows = [np.arange(self.off[b], self.off[b + 1]) for b in range(nh + 2)]
        self.built = True

    def ensure(self, blocks, cols) -> None:
        """Know `IN` of the rows of `blocks` along the HF candidates `cols`, a whole block
        along a candidate at a time, casting the rays not cast yet through the problem's
        registry (a boundary sample's ray along a direction is the same ray for every
        DHF), in one C++ call."""
        blocks = np.asarray(blocks, np.int64)
        cols = np.asarray(cols, np.int64)
        if not len(blocks) or not len(cols):
            return
        bi, ci = np.nonzero(~self.BK[np.ix_(blocks, cols)])
        if not len(bi):
            return
        prob = self.prob
        pairs = np.stack([blocks[bi], cols[ci]], 1)
        reg, pts = prob.registry(self.hk), prob.samples()[0]
        prob.n_rays += _column_known(
            pairs, self.off, self.IN, self.gid, self.hkarr, reg, reg.shape[1], pts, prob._casts, prob.threads
        )
        self.BK[pairs[:, 0], pairs[:, 1]] = True

    def root_cd(self) -> float:
        """The `CD(S, S~)` bound of the DHF with the best of every HF."""
        return float(np.minimum(self.cur, self.suf[:, 0]).sum() / self.prob.n_samples) * (1 - 1e-9)

    def root(self) -> _Node:
        if not self.built:
            self._build()
        n_vis = self.prob.n_samples - len(self.rows)
        return _Node((), np.arange(len(self.rows)), self.cur, n_vis, self.visd, self.base, np.ones(self.R, bool))

    def _blocks(self, hs) -> list:
        """The blocks of the DHF and of the HFs `hs`."""
        return [self.nh, self.nh + 1] + [j for j in hs if not self.same[j]]

    def children(self, node: _Node, m: int, eps1: float, eps2: float, best: float = math.inf):
        """Lower bounds of E over the subtrees of the children of `node` (each adds one HF
        `h` after the node's; `r - 1` more follow), as `(H, bounds, state)`. When the
        children are leaves (`r = 1`) the bounds are their energies, summed in another
        order and scaled by `1 - 1e-9`. Children whose bound exceeds `best` are left out."""
        prob, nh, N = self.prob, self.nh, self.prob.n_samples
        hs, rr, cur, n_vis = node.hs, node.rr, node.cur, node.n_vis
        r = m - len(hs)
        start = hs[-1] + 1 if hs else 0
        H = np.arange(start, nh - r + 1)
        # the hidden surface samples' sums (C++): `C`, their distances with child `h`;
        # `cd`, `CD(S, S~)` with the best of the HFs after it too; `vn` and `vmax`, how many
        # turn visible with child `h`, and with it or an HF after it
        C, Vn, cd, vn, vmax = _bound_samples(rr, cur, self.Dr, self.suf, self.Vr, self.sufv, start, len(H), r > 1)
        cd = cd / N

        def prune(E, *arrays):
            keep = E <= best
            if keep.all():
                return (E,) + arrays
            return (E[keep],) + tuple(a[..., keep] for a in arrays)

        # (the children's columns of `C` and `Vn` are `pos`: pruning does not copy them)
        pos = np.arange(len(H))
        cd, H, pos, vn, vmax = prune(cd * (1 - 1e-9), cd, H, pos, vn, vmax)[1:]  # the cheap part first
        if not len(H):
            return H, cd, None
        blocks = self._blocks(hs)
        nr = np.concatenate([self.brows[b] for b in blocks])
        nr = nr[node.alive[nr]]
        self.ensure(blocks, np.arange(H[0], nh) if r > 1 else H)
        # the node's candidate floaters that child `h` keeps (C++): the sums of their
        # distances `td`, On values `tt` and count `nd`; below, with more HFs to come,
        # `Md[h3 - s3, h]` (`Mt`) sums the distances (On values) of those that HF `h3`
        # would remove (only the HFs after the first child, h3 > H[0], can follow a child)
        s3 = int(H[0]) + 1
        (td, tt, nd), Md, Mt = _bound_removals(self.IN, nr, H, None, s3 if r > 1 else nh, self.wd, self.wt, prob.threads)
        # each block's rows inside the node's HFs: count, distances, On values
        # (the blocks before `start` play no part)
        cnt, bwd, bwt = np.zeros((3, nh))
        cnt[start:], bwd[start:], bwt[start:] = _bound_blocks(
            node.alive, self.off[start : nh + 1], self.wd, self.wt, r == 1
        )
        a = prob.on_surface
        on_vis = float(np.minimum(node.base, self.tpmin)[node.vis].sum())
        if r == 1:
            # exact: every term of E; first with the On of the visible surface samples
            # bounded below, then exactly for the children still within the bound
            td = td + bwd[H]
            tt = tt + bwt[H]
            nd = nd + cnt[H]
            n = n_vis + vn + nd

            def energy(on):
                with np.errstate(divide="ignore", invalid="ignore"):
                    cd_ts = np.where(n > 0, td / np.maximum(n, 1), np.inf)
                    mu = np.where(n > 0, (on + tt) / np.maximum(n, 1), 1.0)
                dist = cd + cd_ts
                E = dist + np.minimum(mu * (dist + eps1), eps2)
                E = E * (1 - 1e-9)
                E[~np.isfinite(dist)] = np.inf
                return E

            E, H, pos, cd, td, tt, n = prune(energy(on_vis), H, pos, cd, td, tt, n)
            if not len(H):
                return H, E, None
            hkH = [self.hk[j] for j in H]
            TP = prob.TPall(self.angle)
            z = np.flatnonzero(node.vis & (node.base > 0))
            on = np.minimum(node.base[z][None, :], TP[np.ix_(hkH, z)]).sum(1)
            on = on + (Vn[:, pos] * TP[np.ix_(hkH, self.rows[rr])].T).sum(0)
            return H, energy(on), (node, H, C, Vn, pos)
        # the next r - 1 HFs can remove at most the floaters of their r - 1 best
        lat = np.arange(s3, nh)[:, None] > H[None, :]
        vmax = n_vis + vmax
        topc = _top_sums(cnt, r - 1)[r - 1]

        def bound(td, tt, nd, Md, Mt, lat, vmax, cd, xm):
            top = max(len(Md) - (r - 1), 0)
            td = np.maximum(td - np.sort(np.where(lat, Md, 0.0), axis=0)[top:].sum(0), 0.0)
            tt = np.maximum(tt - np.sort(np.where(lat, Mt, 0.0), axis=0)[top:].sum(0), 0.0)
            n0 = vmax + nd
            with np.errstate(divide="ignore", invalid="ignore"):
                r1 = np.where(n0 > 0, td / np.maximum(n0, 1), np.inf)
                r2 = np.where(n0 + xm > 0, (td + a * xm) / np.maximum(n0 + xm, 1), np.inf)
                mu = np.where(n0 + xm > 0, (on_vis + tt) / np.maximum(n0 + xm, 1), 0.0)
            dist = cd + np.minimum(r1, r2)
            E = dist + np.minimum(mu * (dist + eps1), eps2)
            E = E * (1 - 1e-9)
            E[~np.isfinite(dist)] = np.inf
            return E

        # first with the floaters of the child and of the HFs after it unknown (at most
        # their blocks' rows inside the node's HFs, each farther from S than `a`)
        E = bound(td, tt, nd, Md, Mt, lat, vmax, cd, cnt[H] + topc[H + 1])
        E, H, pos, cd, td, tt, nd, Md, Mt, lat, vmax = prune(E, H, pos, cd, td, tt, nd, Md, Mt, lat, vmax)
        if not len(H) or not hs:
            # (at the root this would cast the rays of nearly every candidate floater along
            # every HF: measured slower on the knot)
            return H, E, (node, H, C, Vn, pos)
        # then, below the root, with the child's own rows inside the node's HFs known, less what the HFs
        # after it can remove (their rays are cast for the children still within the bound)
        rc = np.concatenate([self.brows[h] for h in H])
        col = np.repeat(np.arange(len(H)), self.off[H + 1] - self.off[H])
        keep = node.alive[rc]
        rc, col = rc[keep], col[keep]
        self.ensure(H, np.arange(H[0] + 1, nh))
        (od, ot, _), rd, rt = _bound_removals(self.IN, rc, H, col, s3, self.wd, self.wt, prob.threads)
        E2 = bound(td + od, tt + ot, nd + cnt[H], Md + rd, Mt + rt, lat, vmax, cd, topc[H + 1])
        return H, np.maximum(E, E2), (node, H, C, Vn, pos)

    def child(self, state, o: int) -> _Node:
        """The node of child `o` of a `children` result. Its candidate floaters are the rows
        of its own blocks and of the blocks after its last HF that lie inside its HFs (the
        rays along the new HF are cast here)."""
        node, H, C, Vn, pos = state
        c = int(pos[o])
        prob, h, nh = self.prob, int(H[o]), self.nh
        k = self.hk[h]
        blocks = self._blocks(node.hs + (h,)) + list(range(h + 1, nh))
        mine = np.zeros(self.R, bool)
        mine[self.off[h + 1] :] = True  # the blocks after h, then the DHF's two
        for j in node.hs + (h,):
            if not self.same[j]:
                mine[self.off[j] : self.off[j + 1]] = True
        self.ensure(blocks, [h])
        alive = node.alive & mine & self.IN[h]
        keep = ~Vn[:, c]
        return _Node(
            node.hs + (h,),
            node.rr[keep],
            C[keep, c],
            node.n_vis + int(Vn[:, c].sum()),
            node.vis | prob.visT()[k],
            np.minimum(node.base, prob.TP(k, self.angle)),
            alive,
        )

    def leaf_energy(self, state, o: int, eps1: float, eps2: float) -> float:
        """E of leaf `o` of a `children` result with `r = 1`: the arithmetic of
        `_Problem.energy`, term for term and in its order, so the same value to the bit."""
        node, H, C, Vn, pos = state
        c = int(pos[o])
        prob, nh, h = self.prob, self.nh, int(H[o])
        k = self.hk[h]
        prob.n_full += 1
        vis = node.vis | prob.visT()[k]
        on_p = np.minimum(node.base, prob.TP(k, self.angle))
        tot_on, n = float(on_p[vis].sum()), int(vis.sum())
        blocks = {self.kp: nh, self.km: nh + 1}
        for j in node.hs + (h,):
            if not self.same[j]:
                blocks[self.hk[j]] = j
        tot_d = 0.0
        for kk in sorted(blocks):
            b = blocks[kk]
            sl = slice(self.off[b], self.off[b + 1])
            keep = node.alive[sl] & self.IN[h, sl]
            if not keep.any():
                continue
            tot_on += float(self.wt[sl][keep].sum())
            tot_d += float(self.wd[sl][keep].sum())
            n += int(keep.sum())
        z = np.zeros(prob.n_samples)
        keep = ~Vn[:, c]
        z[self.rows[node.rr[keep]]] = C[keep, c]
        cd_st = float(z.mean())
        if n == 0:
            return math.inf
        cd_ts = tot_d / n
        mu = tot_on / n
        dist = cd_st + cd_ts
        return dist + min(mu * (dist + eps1), eps2)


def _search(prob: _Problem, dk, hk, m, eps1, eps2, angle, exhaustive, *, cap=math.inf, first=None):
    """`_search_level` with one BLAS thread (its many mid-sized products run faster so, next
    to the casts' thread pools; see `voxax._blas`)."""
    with _blas.single_threaded():
        return _search_level(prob, dk, hk, m, eps1, eps2, angle, exhaustive, cap=cap, first=first)


def _search_level(prob: _Problem, dk, hk, m, eps1, eps2, angle, exhaustive, *, cap=math.inf, first=None):
    """The least `(E, i, hfs)` over DHF candidates `dk` (pairs of signed indices) and `m`
    HFs from `hk`, by branch and bound on the lower bounds of `_Dhf` (best first),
    counting leaves and full evaluations. With `cap`, only combinations with E <= cap are
    sought (`best` stays `[cap, inf, ()]` when there is none). `first`: the DHF searched
    first (then the others from the least bound of their roots' children up)."""
    n_h = len(hk)
    best = [cap, math.inf, ()]
    leaves = math.comb(n_h, m) * len(dk)
    n0 = prob.n_full

    def consider(E, i, hs):
        if (E, i, hs) < tuple(best):
            best[0], best[1], best[2] = E, i, hs

    if m == 0 or exhaustive:
        import itertools

        combos = list(itertools.combinations(range(n_h), m))
        for i, (kp, km) in enumerate(dk):
            for c0 in range(0, len(combos), _CHUNK):
                chunk = combos[c0 : c0 + _CHUNK]
                prob.prefetch([[kp, km] + [hk[j] for j in hs] for hs in chunk])
                for hs in chunk:
                    consider(prob.energy([kp, km] + [hk[j] for j in hs], eps1, eps2, angle)["E"], i, tuple(hs))
        return best, leaves, prob.n_full - n0
    terms = []
    for kp, km in dk:
        key = (kp, km, tuple(hk), angle)
        t = prob._terms.get(key)
        if t is None:
            t = prob._terms[key] = _Dhf(prob, kp, km, hk, angle)
        terms.append(t)

    def expand(i, node, kids=None):
        t = terms[i]
        H, E, state = t.children(node, m, eps1, eps2, best[0]) if kids is None else kids
        leaf = len(node.hs) + 1 == m
        for o in np.argsort(E, kind="stable"):
            if E[o] > best[0]:
                break  # sorted: the rest is beyond the bound too
            if leaf:
                consider(t.leaf_energy(state, int(o), eps1, eps2), i, node.hs + (int(H[o]),))
            else:
                expand(i, t.child(state, int(o)))

    # the DHF `first` (the best one with m - 1 HFs) gives an incumbent; then every other
    # DHF's root is bounded, and they are searched from the least bound up
    if first is not None:
        expand(first, terms[first].root())
    roots = []
    for i, t in enumerate(terms):
        if i != first and t.root_cd() <= best[0]:
            node = t.root()
            kids = t.children(node, m, eps1, eps2, best[0])
            roots.append((float(kids[1].min()) if len(kids[0]) else math.inf, i, node, kids))
    roots.sort(key=lambda x: x[:2])
    for lb, i, node, kids in roots:
        if lb > best[0]:
            break
        expand(i, node, kids)
    return best, leaves, prob.n_full - n0


def _prepare(where, vertices, faces, dhf, hf, resolution, n_samples, seed, threads):
    mesh = closed_mesh(where, vertices, faces)
    dhf = np.atleast_2d(np.asarray(dhf, dtype=np.float64))
    hf = np.asarray(hf, dtype=np.float64).reshape(-1, 3)
    dhf = np.stack([unit_direction(where, d) for d in dhf]) if len(dhf) else dhf
    if len(dhf) == 0:
        raise ValueError(f"{where}: needs at least one DHF candidate")
    hf = np.stack([unit_direction(where, d) for d in hf]) if len(hf) else hf.reshape(0, 3)
    seen: dict = {}
    for j, d in enumerate(hf):  # the search counts each HF's floaters once
        i = seen.setdefault(_canonical(d), j)
        if i != j:
            raise ValueError(f"{where}: candidates_hf repeats a direction (rows {i} and {j})")
    res = _validate.positive_int(where, "resolution", resolution, minimum=2)
    ns = _validate.positive_int(where, "n_samples", n_samples)
    prob = _Problem(
        mesh,
        np.concatenate([dhf, -dhf, hf]),
        resolution=res,
        n_samples=ns,
        seed=int(seed),
        threads=threads,
    )
    dk = [(prob.index(d), prob.index(-d)) for d in dhf]
    hk = [prob.index(d) for d in hf]
    return prob, dk, hk


def select(
    vertices,
    faces=None,
    *,
    candidates_dhf=None,
    candidates_hf=None,
    n_dhf: int = 50,
    n_hf: int = 80,
    max_hf: int = 3,
    n_samples: int = 10_000,
    resolution: int = 128,
    eps1: float = 1e-4,
    eps2: float = 1e-3,
    angle: float = 85.0,
    tol: float | None = None,
    stop_early: bool = True,
    exhaustive: bool = False,
    seed: int = 0,
    threads=None,
) -> ESI:
    """Select the DHF axis and up to `max_hf` HF axes of an ESI by branch and bound.

    The energy of a choice of axes is `E = Dist + min(mu (Dist + eps1), eps2)` (Eq. 1) on
    the mesh scaled into `[-1/1.1, 1/1.1]^3`, with:

    - `Dist = CD(S, S~) + CD(S~, S)`, L1 Chamfer distances between `n_samples` area
      samples `P` of the surface S and area samples of the ESI's surface S~.
      `CD(S, S~)` is exact per sample: a point of S lies inside every height field, so
      its distance to the boundary of their intersection is the least distance to the
      boundary of one of them (0 when the point is visible along that axis).
      `CD(S~, S)` uses exact point-to-mesh distances of the height-field boundary samples
      that lie inside all the other height fields (exact ray casts).
    - `mu`, the mean over S~'s samples of `min_k On(p, d_k)` with `On = max(1 - v, T)`
      (Eq. 3-4): `v` is 1 when the ray from `p` along `d_k` misses S, `T(theta) =
      tanh(theta - angle)/2 + 1/2` of the angle in degrees between the sample's normal
      and `d_k`.

    Each height field's boundary comes from a `resolution^2` depth map (exact hits at
    pixel centres, linear in between). `m = 0, 1, ...` HFs are tried in turn; for each,
    every combination of a DHF candidate and `m` HF candidates is a leaf of a search tree,
    explored best first. A partial choice (the DHF and some HFs) is bounded below over
    every combination that completes it: `CD(S, S~)` with the best remaining candidates,
    and `CD(S~, S)` and `mu` from what no further HF can change, namely the floaters of the
    DHF, of the chosen HFs and of the next one that the remaining HFs cannot all remove,
    the visible surface samples (at distance 0) that they can at most add, and the later
    HFs' floaters, each farther from S than the on-surface distance. The children of the
    last inner level are leaves: their energies are computed together, and only those
    within the bound are evaluated one by one (with `energy`'s own arithmetic, so to the
    bit). Every ray is cast exactly (a watertight test) against the triangles listed over
    its cell of a grid in its direction's frame, after a test of the cell's depth range
    that rejects most rays that cannot meet S; a ray of a boundary sample along an HF
    candidate is cast at most once for all DHFs. Most leaves are never evaluated
    (`ESI.prune_rate`), and the result is the exhaustive optimum. The search stops
    at the first `m` whose best E is not lower than that of `m - 1` by more than `tol`
    (default `eps1`: an extra height field must be worth more than the noise of the
    sampled energy); that level only looks for a choice below that threshold.

    **Arguments:**

    - `vertices`, `faces`: a closed, consistently oriented mesh (or a `Mesh` alone).
    - `candidates_dhf`, `candidates_hf`: `(n, 3)` candidate axes (default
      [`candidates(n_dhf, n_hf)`][voxax.esi.candidates]).
    - `max_hf`: the most HFs (0-3 in the paper).
    - `n_samples`, `resolution`, `eps1`, `eps2`, `angle`, `tol`: as above.
    - `stop_early`: `False` computes `by_m` for every `m <= max_hf`.
    - `exhaustive`: evaluate every leaf (for checking the search).
    - `seed`: the sampling seed (the energy is a sampled estimate; fix it).
    - `threads`: threads for the ray casts.

    **Returns:** an [`ESI`][voxax.esi.ESI].
    """
    where = "esi.select"
    if faces is not None and not hasattr(faces, "shape") and not isinstance(faces, (list, tuple)):
        raise TypeError(f"{where}: faces must be an array")
    if candidates_dhf is None or candidates_hf is None:
        cd, ch = candidates(n_dhf, n_hf)
        candidates_dhf = cd if candidates_dhf is None else candidates_dhf
        candidates_hf = ch if candidates_hf is None else candidates_hf
    max_hf = int(max_hf)
    if not 0 <= max_hf <= 8:
        raise ValueError(f"{where}: max_hf must be in [0, 8], got {max_hf}")
    tol = float(eps1 if tol is None else tol)
    prob, dk, hk = _prepare(where, vertices, faces, candidates_dhf, candidates_hf, resolution, n_samples, seed, threads)
    return _select(prob, dk, hk, candidates_dhf, candidates_hf, max_hf, eps1, eps2, angle, tol, stop_early, exhaustive)


def _select(prob, dk, hk, cdhf, chf, max_hf, eps1, eps2, angle, tol, stop_early, exhaustive):
    cdhf = np.asarray(cdhf, np.float64).reshape(-1, 3)
    chf = np.asarray(chf, np.float64).reshape(-1, 3)
    results, leaves, evals = [], [], []
    chosen = None
    for m in range(max_hf + 1):
        if m > len(hk):
            break
        # with the early stop, level m only matters if it beats the chosen level by more
        # than tol: what is not below that is pruned from the start
        cap = results[chosen][0] - tol if stop_early and chosen is not None and not exhaustive else math.inf
        # the DHF of the best choice with one HF less first: a good incumbent early
        first = results[-1][1] if results and results[-1][1] != math.inf else None
        best, n_leaves, n_eval = _search(prob, dk, hk, m, eps1, eps2, angle, exhaustive, cap=cap, first=first)
        if best[1] == math.inf:  # nothing below the cap
            best = [math.nan, math.inf, ()]
        results.append(best)
        leaves.append(n_leaves)
        evals.append(n_eval)
        if chosen is None or (best[1] != math.inf and best[0] < results[chosen][0] - tol):
            chosen = m
        elif stop_early:
            break
    E, i, hs = results[chosen]
    ks = [dk[i][0], dk[i][1]] + [hk[j] for j in hs]
    info = prob.energy(ks, eps1, eps2, angle)
    d0 = cdhf[i] / np.linalg.norm(cdhf[i])
    hfa = np.array([chf[j] / np.linalg.norm(chf[j]) for j in hs]).reshape(-1, 3)
    return ESI(
        d0,
        hfa,
        float(E),
        np.array([r[0] for r in results]),
        int(i),
        tuple(int(j) for j in hs),
        float(info["dist"]),
        float(info["mu"]),
        np.array(leaves, np.int64),
        np.array(evals, np.int64),
    )


# ----------------------------------------------------------------------------- occupancy, meshing


def _esi_axes(where: str, esi) -> tuple[np.ndarray, np.ndarray]:
    if isinstance(esi, ESI):
        d0, hfa = esi.dhf_axis, esi.hf_axes
    elif isinstance(esi, tuple) and len(esi) == 2:
        d0, hfa = esi
    else:
        raise TypeError(f"{where}: esi must be an ESI or a (dhf_axis, hf_axes) pair")
    d0 = unit_direction(where, d0)
    hfa = np.asarray(hfa, dtype=np.float64).reshape(-1, 3)
    hfa = np.stack([unit_direction(where, d) for d in hfa]) if len(hfa) else hfa
    return d0, hfa


def occupancy(esi, vertices, faces=None, points=None, *, threads=None) -> np.ndarray:
    """Exact inside/outside of an ESI at points.

    A point is in `HF(d)` when its ray along `+d` meets the mesh (at `t >= 0`, so points
    on the surface are inside), and in the ESI when it is in `HF(d_0)`, `HF(-d_0)` and
    every `HF(d_k)`. The rays are cast exactly through a BVH, so the ESI contains every
    point of the solid (winding number >= 1/2) of a closed mesh.

    **Arguments:**

    - `esi`: an [`ESI`][voxax.esi.ESI] or a pair `(dhf_axis (3,), hf_axes (m, 3))`.
    - `vertices`, `faces`: the closed mesh the ESI was selected for (or a `Mesh`, then
      `points` moves into the `faces` slot).
    - `points`: `(..., 3)` float.

    **Returns:** `(...)` bool.

    >>> import numpy as np
    >>> from voxax import data
    >>> occupancy(((0, 0, 1), ()), data.cube(2.0), [[0.0, 0.0, 0.5], [2.0, 0.0, 0.0]]).tolist()
    [True, False]
    """
    where = "esi.occupancy"
    vertices, faces, (points,) = _validate.unpack_mesh(where, vertices, faces, points)
    if points is None:
        raise TypeError(f"{where}: missing `points`")
    mesh = closed_mesh(where, vertices, faces)
    d0, hfa = _esi_axes(where, esi)
    p = np.asarray(points)
    if p.dtype.kind not in "fiu":
        raise TypeError(f"{where}: points must be a real array, got dtype {p.dtype}")
    p = p.astype(np.float64)
    if p.ndim < 1 or p.shape[-1] != 3:
        raise ValueError(f"{where}: points must have shape (..., 3), got {p.shape}")
    lead = p.shape[:-1]
    p = p.reshape(-1, 3)
    bvh = BVH(mesh)
    inside = np.ones(len(p), bool)
    for d in [d0, -d0, *hfa]:
        idx = np.flatnonzero(inside)
        if len(idx) == 0:
            break
        inside[idx] = bvh.any_hits(p[idx], d, threads=threads)
    return inside.reshape(lead)


def _to_manifold(mesh: Mesh):
    from manifold3d import Manifold, Mesh64

    m = Manifold(
        Mesh64(
            vert_properties=np.array(mesh.vertices, dtype=np.float64, order="C"),
            tri_verts=np.array(mesh.faces, dtype=np.uint64, order="C"),
        )
    )
    if m.status().name != "NoError":
        raise ValueError(f"esi.to_mesh: manifold3d rejected a height-field solid ({m.status().name})")
    return m


def to_mesh(esi, vertices, faces=None, *, resolution: int = 256, threads=None) -> Mesh:
    """A watertight mesh of an ESI: the intersection of height-field solids.

    Every signed axis `d` of the ESI (`+d_0`, `-d_0` and the HF axes) gives a closed solid
    from a `resolution^2` depth map along `d` (the pixel-centre heights joined linearly,
    closed within one pixel outside the silhouette); manifold3d intersects them. The
    result approximates the exact ESI to about a pixel (`2 radius / resolution`).

    **Arguments:**

    - `esi`: an [`ESI`][voxax.esi.ESI] or `(dhf_axis, hf_axes)`.
    - `vertices`, `faces`: the closed mesh (or a `Mesh`).
    - `resolution`: depth-map pixels per side (>= 2).

    **Returns:** a `Mesh` (float64, outward).
    """
    where = "esi.to_mesh"
    mesh = closed_mesh(where, vertices, faces)
    d0, hfa = _esi_axes(where, esi)
    res = _validate.positive_int(where, "resolution", resolution, minimum=2)
    c, rad = bounding_sphere(mesh)
    bvh = BVH(mesh)
    normals = face_normals(mesh.vertices, mesh.faces)
    maps = {}
    solids = []
    for d in [d0, -d0, *hfa]:
        lk, sg = _canonical(d)
        if lk not in maps:
            maps[lk] = _depth_map(bvh, frame_for(np.asarray(lk), c, rad, res), normals, threads)
        dm = maps[lk]
        if not dm.mask.any():
            raise ValueError(f"{where}: the depth map along {d.tolist()} is empty; raise the resolution")
        solids.append(height_field_solid(dm, sg)[0])
    return intersect_solids(solids)


def intersect_solids(solids) -> Mesh:
    """The manifold3d intersection of closed, outward meshes (e.g. height-field solids
    from [`height_field_solid`][voxax.esi.height_field_solid]), as a float64 `Mesh`."""
    out = None
    for m in solids:
        solid = _to_manifold(m)
        out = solid if out is None else out ^ solid
    if out is None:
        raise ValueError("intersect_solids needs at least one solid")
    mg = out.to_mesh64()
    v = np.asarray(mg.vert_properties, dtype=np.float64)[:, :3]
    f = np.asarray(mg.tri_verts, dtype=np.int64)
    return Mesh(v, f.astype(np.int32))


def energy(
    vertices,
    faces=None,
    dhf_axis=None,
    hf_axes=None,
    *,
    n_samples: int = 10_000,
    resolution: int = 128,
    eps1: float = 1e-4,
    eps2: float = 1e-3,
    angle: float = 85.0,
    seed: int = 0,
    threads=None,
) -> dict:
    """The energy E (Eq. 1-5) of one choice of axes, as [`select`][voxax.esi.select]
    computes it.

    **Returns:** a dict with `E`, `dist` (`CD(S, S~) + CD(S~, S)`), `cd_st`, `cd_ts` and
    `mu`, in the units of the mesh scaled into `[-1/1.1, 1/1.1]^3`.
    """
    where = "esi.energy"
    vertices, faces, (dhf_axis, hf_axes) = _validate.unpack_mesh(where, vertices, faces, dhf_axis, hf_axes)
    if dhf_axis is None:
        raise TypeError(f"{where}: missing `dhf_axis`")
    hf_axes = () if hf_axes is None else hf_axes
    prob, dk, hk = _prepare(where, vertices, faces, [dhf_axis], hf_axes, resolution, n_samples, seed, threads)
    return prob.energy([dk[0][0], dk[0][1], *hk], float(eps1), float(eps2), float(angle))


# ----------------------------------------------------------------------------- soft hulls on grids


def height_field_hull(W, axis: int = 2, w: float = 1000.0):
    """A differentiable double-height-field hull of a voxel grid along a grid axis.

    A cell lies in `DHF(axis)` when some occupied cell precedes it (or is it) along its
    column and some occupied cell follows it: `min(P, Q)` with `P` the mellowmax of every
    prefix of the column (`(logcumsumexp(w W) - log n) / w`, the soft "anything so far")
    and `Q` that of every suffix (the minimum, not the product, keeps partly filled
    boundary cells of a height field at their own value). As `w -> inf` it tends to the exact hull of a binary
    grid; the bandsaw's cut shape is the product of the three silhouettes instead, and
    `height_field_hull(W, a) <= silhouette extrusion along a`.

    **Arguments:**

    - `W`: `(..., nx, ny, nz)` float grid (leading axes are batch axes).
    - `axis`: 0, 1 or 2 (x, y, z).
    - `w`: the mellowmax sharpness.

    **Returns:** `(..., nx, ny, nz)`, the soft hull.

    >>> import jax.numpy as jnp
    >>> W = jnp.zeros((1, 1, 5)).at[0, 0, 1].set(1.0).at[0, 0, 3].set(1.0)
    >>> height_field_hull(W, 2, w=1e4).round(2).tolist()
    [[[0.0, 1.0, 1.0, 1.0, 0.0]]]
    """
    import jax
    import jax.numpy as jnp

    axis = int(axis)
    if axis not in (0, 1, 2):
        raise ValueError(f"height_field_hull: axis must be 0, 1 or 2, got {axis}")
    W = jnp.asarray(W)
    if W.ndim < 3:
        raise ValueError(f"height_field_hull: W must have shape (..., nx, ny, nz), got {W.shape}")
    if not jnp.issubdtype(W.dtype, jnp.floating):
        raise TypeError(f"height_field_hull: W must be a float array, got dtype {W.dtype}")
    w = float(w)
    if not w > 0:
        raise ValueError(f"height_field_hull: w must be > 0, got {w}")
    ax = W.ndim - 3 + axis
    n = W.shape[ax]
    shape = [1] * W.ndim
    shape[ax] = n
    logn = jnp.log(jnp.arange(1, n + 1, dtype=W.dtype)).reshape(shape)
    m = jax.lax.stop_gradient(W.max())
    x = w * (W - m)
    pre = m + (jax.lax.cumlogsumexp(x, axis=ax) - logn) / w
    suf = m + (jax.lax.cumlogsumexp(x, axis=ax, reverse=True) - jnp.flip(logn, ax)) / w
    return jnp.clip(jnp.minimum(pre, suf), 0.0, None)


def esi_gap(W, axes=(2,), w: float = 1000.0):
    """`mean((H - W)^2)` with `H` the minimum of the soft double-height-field hulls of `W`
    along the given grid axes ([`height_field_hull`][voxax.esi.height_field_hull]): zero
    exactly when the shape equals the intersection of those hulls (for one axis: when it
    can be cast in a two-piece mould parting perpendicular to the axis)."""
    import jax.numpy as jnp

    axes = tuple(int(a) for a in np.atleast_1d(axes))
    if not axes:
        raise ValueError("esi_gap: needs at least one axis")
    H = height_field_hull(W, axes[0], w)
    for a in axes[1:]:
        H = jnp.minimum(H, height_field_hull(W, a, w))
    return jnp.mean((H - jnp.asarray(W)) ** 2)
