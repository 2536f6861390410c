"""Depth maps (exact first and last hits along parallel rays) and the height-field solids
built from them."""

from __future__ import annotations

import weakref
from typing import NamedTuple

import numpy as np

from .. import _validate
from .._mesh import Mesh, face_normals
from .._spatial import BVH
from ._frames import (
    Frame,
    bounding_sphere,
    check_threads,
    closed_mesh,
    exact_scale,
    frame_for,
    tuple_values_equal,
    unit_direction,
)

__all__ = ["DepthMap", "HeightFieldSolid", "depth_map", "height_field_solid"]


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

    __eq__ = tuple_values_equal
    __hash__ = None  # type: ignore[assignment]


class HeightFieldSolid(NamedTuple):
    """The closed outward mesh bounding a height field (`boundary`), whose first
    `n_top_wall_faces` faces are its top and walls (the rest, its bottom, lie outside the
    bounding sphere)."""

    boundary: Mesh
    n_top_wall_faces: int

    __eq__ = tuple_values_equal
    __hash__ = None  # type: ignore[assignment]


def _depth_map(bvh: BVH, frame: Frame, normals: np.ndarray, threads=None, scale: float = 1.0) -> DepthMap:
    """The depth map of `frame` by casts against `bvh`, a tree of the mesh scaled by the
    power of two `scale` (see `exact_scale`; the depths come back in the frame's units)."""
    r = frame.resolution
    x = frame.coords()
    base = (frame.center + x[:, None, None] * frame.u + x[None, :, None] * frame.v).reshape(-1, 3)
    reach = 2.0 * frame.radius
    lo = bvh.first_hits((base - reach * frame.d) * scale, frame.d, threads=threads)
    hi = bvh.first_hits((base + reach * frame.d) * scale, -frame.d, threads=threads)
    mask = lo.hit & hi.hit
    first = np.where(mask, lo.t / scale - reach, np.nan).reshape(r, r)
    last = np.where(mask, reach - hi.t / scale, np.nan).reshape(r, r)
    ff = np.where(mask, lo.face, -1).astype(np.int32)
    fl = np.where(mask, hi.face, -1).astype(np.int32)
    nf = np.where(mask[:, None], normals[np.maximum(ff, 0)], 0.0).reshape(r, r, 3)
    nl = np.where(mask[:, None], normals[np.maximum(fl, 0)], 0.0).reshape(r, r, 3)
    return DepthMap(first, last, mask.reshape(r, r), nf, nl, ff.reshape(r, r), fl.reshape(r, r), frame)


def scaled_tree(mesh: Mesh) -> tuple[BVH, float]:
    """A BVH of `mesh` scaled by `exact_scale` of its bounding radius, and that scale."""
    scale = exact_scale(bounding_sphere(mesh)[1])
    return (BVH(mesh) if scale == 1.0 else BVH(Mesh(mesh.vertices * scale, mesh.faces))), scale


@_validate.host_only("voxax.esi.depth_map")
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
    - `threads`: threads for the ray casts (`None`: `VOXAX_NUM_THREADS` or every core).

    **Returns:** a [`DepthMap`][voxax.esi.DepthMap].

    >>> from voxax import data
    >>> dm = depth_map(data.cube(2.0), (0.0, 0.0, 1.0), resolution=4)
    >>> float(dm.first[1, 1]), float(dm.last[1, 1])
    (-1.0, 1.0)
    """
    where = "voxax.esi.depth_map"
    if isinstance(vertices, BVH):
        bvh = vertices
        if direction is None:
            faces, direction = None, faces
        elif faces is not None:
            raise TypeError(f"{where}: given a BVH, pass only `direction` after it")
        mesh, normals, bvh, scale = _checked_tree(where, bvh)
    else:
        vertices, faces, (direction,) = _validate.unpack_mesh(where, vertices, faces, direction)
        mesh = closed_mesh(where, vertices, faces)
        (bvh, scale), normals = scaled_tree(mesh), face_normals(mesh.vertices, mesh.faces)
    if direction is None:
        raise TypeError(f"{where}: `direction` must be given (a (3,) vector)")
    d = unit_direction(where, direction)
    res = _validate.positive_int(where, "resolution", resolution)
    from ._select import _check_pixels

    _check_pixels(where, res, 1)
    c, rad = bounding_sphere(mesh)
    frame = frame_for(d, c, rad, res)
    check_threads(where, threads)
    dm = _depth_map(bvh, frame, normals, threads, scale)
    if not dm.mask.any():
        raise ValueError(
            f"{where}: `resolution` must be higher: the depth map is empty (no pixel centre of "
            f"the {res}x{res} frame meets the mesh)"
        )
    return dm


_CHECKED_TREES: weakref.WeakKeyDictionary = weakref.WeakKeyDictionary()


def _checked_tree(where: str, bvh: BVH) -> tuple[Mesh, np.ndarray, BVH, float]:
    """The mesh of `bvh`, checked by `closed_mesh` on first use, its face normals and the
    tree to cast against with its scale (`bvh` itself unless the mesh is far from unit
    size, see `scaled_tree`); kept on the tree so that later depth maps skip the check."""
    cached = _CHECKED_TREES.get(bvh)
    if cached is None:
        mesh = closed_mesh(where, bvh.mesh)
        tree, scale = (bvh, 1.0) if exact_scale(bounding_sphere(mesh)[1]) == 1.0 else scaled_tree(mesh)
        cached = _CHECKED_TREES[bvh] = (mesh, face_normals(mesh.vertices, mesh.faces), tree, scale)
    return cached



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


def height_field_solid(dm: DepthMap, sign: int) -> HeightFieldSolid:
    """A closed outward mesh of `HF(sign * d)` from a depth map, clipped far below.

    The top is the pixel-centre grid at the height function (`last` for `sign = +1`,
    `first` for `-1`); pixels off the mask drop to `1.02 radius` below the centre, and
    the solid ends `1.05 radius` below it. Returns a
    [`HeightFieldSolid`][voxax.esi.HeightFieldSolid] `(boundary, n_top_wall_faces)`: the faces
    of the top and walls come first (the bottom is outside the bounding sphere).
    """
    if not isinstance(dm, DepthMap):
        raise TypeError(f"voxax.esi.height_field_solid: `dm` must be a DepthMap, got {type(dm).__name__}")
    if sign not in (1, -1) or isinstance(sign, bool):
        raise ValueError(f"voxax.esi.height_field_solid: `sign` must be 1 or -1, got {sign!r}")
    fr = dm.frame
    r = fr.resolution
    if r < 2:
        raise ValueError("voxax.esi.height_field_solid: `dm` must have resolution >= 2")
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
    return HeightFieldSolid(Mesh(world, faces.astype(np.int32)), len(g) + len(walls))
