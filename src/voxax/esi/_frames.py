"""The inputs of an ESI and the frames of its axes: closed meshes, unit directions,
orthographic pixel frames, bounding spheres and the candidate axes."""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np

from .. import _kernels, _validate
from .._mesh import Mesh
from .._values import values_equal

__all__ = [
    "Candidates",
    "Frame",
    "bounding_sphere",
    "candidates",
    "closed_mesh",
    "fibonacci_sphere",
    "frame_for",
    "unit_direction",
]


#: The largest coordinate magnitude accepted (the BVH's bound; every computation is
#: scale-invariant below it).
MAX_COORDINATE = 1e75
#: The least extent accepted: below it coordinates are subnormal floats.
MIN_EXTENT = 2.0**-960


def closed_mesh(where: str, vertices, faces=None) -> Mesh:
    """A `Mesh` from any surface form (a `voxax.Mesh`, a `trimesh.Trimesh`, a `(vertices,
    faces)` pair or `vertices, faces`, through `voxax._validate.unpack_mesh`), checked to be
    a closed, consistently oriented, non-empty 3D triangle mesh (every directed edge has
    exactly one reverse) with finite coordinates of magnitude at most `1e75`. Raises
    `TypeError` or `ValueError` naming `where` and the argument otherwise."""
    v, f, _ = _validate.unpack_mesh(where, vertices, faces)
    v = np.asarray(v)
    f = np.asarray(f)
    if v.dtype.kind not in "fiu":
        raise TypeError(f"{where}: `vertices` must be a real array, got dtype {v.dtype}")
    if f.dtype.kind not in "iu":
        raise TypeError(f"{where}: `faces` must be an integer array, got dtype {f.dtype}")
    if v.ndim != 2 or v.shape[1] != 3:
        raise ValueError(f"{where}: `vertices` must have shape (V, 3), got {v.shape}")
    if f.ndim != 2 or f.shape[1] != 3:
        raise ValueError(f"{where}: `faces` must have shape (F, 3), got {f.shape}")
    if len(f) == 0:
        raise ValueError(f"{where}: `faces` must not be empty (the mesh has no faces)")
    if f.min() < 0 or f.max() >= len(v):
        raise ValueError(f"{where}: `faces` must index the vertices, in [0, {len(v)}); got [{f.min()}, {f.max()}]")
    v = v.astype(np.float64)
    if not np.all(np.isfinite(v)):
        raise ValueError(f"{where}: `vertices` must be finite (they contain NaN or Inf)")
    if np.abs(v).max() > MAX_COORDINATE:
        raise ValueError(f"{where}: `vertices` must have coordinates of magnitude at most 1e75, got {np.abs(v).max():.3g}")
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
            f"{where}: the mesh must be closed and consistently oriented "
            f"({unmatched} edges without a matching reverse edge, {dup} repeated directed edges); "
            "open meshes have no inside"
        )
    mesh = Mesh(v, f.astype(np.int32))
    used = v[_used(len(v), f)]
    extent = float(np.ptp(used, axis=0).max())
    if not extent > 0:
        raise ValueError(f"{where}: the mesh must have extent (it is a single point)")
    if extent < MIN_EXTENT:
        raise ValueError(f"{where}: the mesh must have an extent of at least 1e-289, got {extent:.3g} (subnormal floats)")
    return mesh


def tuple_values_equal(self, other) -> bool:
    """`==` of the named tuples of results: the same type and every field equal by value
    (arrays element by element, see `voxax._values.values_equal`)."""
    if type(other) is not type(self):
        return NotImplemented
    return all(values_equal(a, b) for a, b in zip(self, other))


def exact_scale(radius: float) -> float:
    """A power of two `s` (exact to multiply by) that brings a shape of bounding radius
    `radius` to about unit size, or 1 when it is already within `2^-20 .. 2^20`: the ray
    casts then run on `s * vertices`, the same bits as at unit size (a watertight ray test
    is exact under scaling by powers of two) and far from the BVH's coordinate bound."""
    if 2.0**-20 <= radius <= 2.0**20:
        return 1.0
    return math.ldexp(1.0, -math.frexp(radius)[1])


def check_threads(where: str, threads) -> None:
    """Checks `threads` (`None` or an int >= 1, resolved by `voxax._kernels.threads`) with
    a message naming `where`."""
    try:
        _kernels.threads(threads)
    except (TypeError, ValueError) as e:
        raise type(e)(f"{where}: {e}") from None


def _used(n: int, faces) -> np.ndarray:
    used = np.zeros(n, bool)
    used[np.asarray(faces).ravel()] = True
    return used


def unit_direction(where: str, direction, name: str = "direction") -> np.ndarray:
    """`direction` as a unit `(3,)` float64 vector; `TypeError`/`ValueError` naming `name`
    if it is not a finite, non-zero real 3-vector."""
    if isinstance(direction, (str, bytes)):
        raise TypeError(f"{where}: `{name}` must be a real 3-vector, got {type(direction).__name__}")
    d = np.asarray(direction)
    if d.dtype.kind not in "fiu":
        raise TypeError(f"{where}: `{name}` must be a real 3-vector, got dtype {d.dtype}")
    d = d.astype(np.float64)
    if d.shape != (3,):
        raise ValueError(f"{where}: `{name}` must have shape (3,), got {d.shape}")
    if not np.all(np.isfinite(d)):
        raise ValueError(f"{where}: `{name}` must be finite (it contains NaN or Inf)")
    n = float(np.linalg.norm(d))
    if not (1e-150 < n < math.inf):  # tiny or huge: the same direction, rescaled first
        big = float(np.abs(d).max())
        if big == 0.0:
            raise ValueError(f"{where}: `{name}` must be non-zero (a degenerate direction)")
        d = d / big
        n = float(np.linalg.norm(d))
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

    __eq__ = tuple_values_equal
    __hash__ = None  # type: ignore[assignment]

    def to_local(self, points) -> np.ndarray:
        """Frame coordinates `(..., 3)` = `(x, y, z)` of world points `(..., 3)`."""
        p = np.asarray(points, dtype=np.float64) - self.center
        return np.stack([p @ self.u, p @ self.v, p @ self.d], axis=-1)


def frame_for(direction, center, radius, resolution) -> Frame:
    """The [`Frame`][voxax.esi.Frame] of a unit direction: `u` is the unit vector of the
    coordinate axis least aligned with `d` (lowest index on ties) made orthogonal to `d`,
    and `v = d x u`.

    **Arguments:** `direction`: a unit `(3,)` vector; `center`: `(3,)` finite; `radius`:
    finite, `> 0`; `resolution`: pixels per side (>= 1)."""
    where = "voxax.esi.frame_for"
    d = np.asarray(unit_direction(where, direction), dtype=np.float64)
    if abs(float(np.linalg.norm(np.asarray(direction, np.float64))) - 1.0) > 1e-9:
        raise ValueError(f"{where}: `direction` must be a unit vector (normalise it first)")
    d = np.asarray(direction, dtype=np.float64)
    center = np.asarray(center)
    if center.dtype.kind not in "fiu" or center.shape != (3,) or not np.all(np.isfinite(center)):
        raise ValueError(f"{where}: `center` must be a finite real (3,) vector, got {center!r}")
    radius = _validate.positive_float(where, "radius", radius)
    resolution = _validate.positive_int(where, "resolution", resolution)
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
    big = float(np.abs(used - c).max())
    if 1e-100 <= big <= 1e100:
        r = float(np.sqrt(((used - c) ** 2).sum(1).max()))
    elif big > 0:  # squares would underflow or overflow: first scaled by a power of two (exact)
        p2 = math.ldexp(1.0, -math.frexp(big)[1])
        r = float(np.sqrt((((used - c) * p2) ** 2).sum(1).max())) / p2
    else:
        r = 0.0
    return c, r


def fibonacci_sphere(n: int, *, hemisphere: bool = False) -> np.ndarray:
    """`n` spherical Fibonacci points `(n, 3)` float64 on the unit sphere (or the upper
    half sphere `z > 0` with `hemisphere=True`), evenly spread by the golden angle."""
    n = _validate.positive_int("voxax.esi.fibonacci_sphere", "n", n, minimum=0, bytes_each=96.0)
    i = np.arange(n, dtype=np.float64)
    z = 1.0 - (i + 0.5) / n if hemisphere else 1.0 - 2.0 * (i + 0.5) / max(n, 1)
    phi = i * math.pi * (3.0 - math.sqrt(5.0))
    s = np.sqrt(np.maximum(0.0, 1.0 - z * z))
    return np.stack([s * np.cos(phi), s * np.sin(phi), z], 1)


class Candidates(NamedTuple):
    """Candidate axes: `dhf` `(n, 3)` for the DHF, `hf` `(n', 3)` for the HFs (float64
    unit vectors; a named tuple, so `dhf, hf = candidates(...)`)."""

    dhf: np.ndarray
    hf: np.ndarray

    __eq__ = tuple_values_equal
    __hash__ = None  # type: ignore[assignment]


def candidates(n_dhf: int = 50, n_hf: int = 80) -> Candidates:
    """Candidate axes for the DHF and the HFs.

    **Arguments:**

    - `n_dhf`: Fibonacci directions on the half sphere for the DHF (`DHF(d) = DHF(-d)`),
      after the three coordinate axes.
    - `n_hf`: Fibonacci directions on the whole sphere for the HFs, after the six signed
      coordinate axes.

    **Returns:** [`Candidates`][voxax.esi.Candidates] `(dhf (3 + n_dhf, 3), hf (6 + n_hf, 3))`.

    >>> dhf, hf = candidates(10, 12)
    >>> dhf.shape, hf.shape
    ((13, 3), (18, 3))
    """
    where = "voxax.esi.candidates"
    n_dhf = _validate.positive_int(where, "n_dhf", n_dhf, minimum=0, bytes_each=192.0)
    n_hf = _validate.positive_int(where, "n_hf", n_hf, minimum=0, bytes_each=192.0)
    eye = np.eye(3)
    dhf = np.concatenate([eye, fibonacci_sphere(n_dhf, hemisphere=True)])
    hf = np.concatenate([np.stack([eye[0], -eye[0], eye[1], -eye[1], eye[2], -eye[2]]), fibonacci_sphere(n_hf)])
    return Candidates(dhf, hf)


def _canonical(d: np.ndarray) -> tuple[tuple, int]:
    """A hashable key of the line through `d` and the sign of `d` on it."""
    nz = np.flatnonzero(np.abs(d) > 1e-12)
    s = 1 if d[nz[0]] > 0 else -1
    key = tuple(np.round(s * d, 12) + 0.0)
    return key, s
