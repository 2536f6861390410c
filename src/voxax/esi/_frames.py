"""The inputs of an ESI and the frames of its axes: closed meshes, unit directions,
orthographic pixel frames, bounding spheres and the candidate axes."""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np

from .. import _validate
from .._mesh import Mesh

__all__ = [
    "Frame",
    "bounding_sphere",
    "candidates",
    "closed_mesh",
    "fibonacci_sphere",
    "frame_for",
    "unit_direction",
]


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


def bounding_sphere(mesh: Mesh) -> tuple[np.ndarray, float]:
    """`(center (3,), radius)`: the bounding box centre and the largest vertex distance."""
    used = mesh.vertices[_used(mesh.n_vertices, mesh.faces)]
    c = 0.5 * (used.min(0) + used.max(0))
    r = float(np.sqrt(((used - c) ** 2).sum(1).max()))
    return c, r


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
