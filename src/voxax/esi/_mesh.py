"""What an ESI gives: exact occupancy, a watertight mesh (manifold3d intersections of
height-field solids) and the energy of one choice of axes.

Functions of an ESI take it first and then the closed mesh it was selected for (an ESI
holds only its axes): `occupancy(esi, vertices, faces=None, points)`, `to_mesh(esi,
vertices, faces=None, *, resolution)`, `energy(esi, vertices, faces=None, ...)`, like
`voxax.nesi.fit(esi, vertices, faces=None, ...)`; a NESI holds its networks, so
`voxax.nesi.occupancy(net, points)` and `voxax.nesi.to_mesh(net, *, resolution)` need no
mesh.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np

from .. import _validate
from .._mesh import Mesh, face_normals
from .._spatial import BVH
from .._values import ValueEquality
from ._depth import _depth_map, height_field_solid, scaled_tree
from ._frames import _canonical, bounding_sphere, check_threads, closed_mesh, frame_for, unit_direction
from ._select import ESI, _check_energy_settings, _check_pixels, _prepare

__all__ = ["EnergyTerms", "energy", "energy_terms", "intersect_solids", "occupancy", "to_mesh"]


def _esi_axes(where: str, esi) -> tuple[np.ndarray, np.ndarray]:
    if isinstance(esi, ESI):
        d0, hfa = esi.dhf_axis, esi.hf_axes
    elif _validate.is_mesh_object(esi) or _validate.is_mesh_pair(esi):
        raise TypeError(
            f"{where}: `esi` must be an ESI or a (dhf_axis, hf_axes) pair, got a mesh (the ESI comes first, "
            "then the mesh it was selected for)"
        )
    elif isinstance(esi, tuple) and len(esi) == 2:
        d0, hfa = esi
    else:
        raise TypeError(f"{where}: `esi` must be an ESI or a (dhf_axis, hf_axes) pair, got {type(esi).__name__}")
    d0 = unit_direction(where, d0, "esi")
    hfa = np.asarray(hfa)
    if hfa.dtype.kind not in "fiu" and hfa.size:
        raise TypeError(f"{where}: `esi` must hold real HF axes, got dtype {hfa.dtype}")
    if hfa.size % 3:
        raise ValueError(f"{where}: `esi` must hold HF axes of shape (m, 3), got {hfa.shape}")
    hfa = hfa.astype(np.float64).reshape(-1, 3)
    hfa = np.stack([unit_direction(where, d, "esi") for d in hfa]) if len(hfa) else hfa
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
    where = "voxax.esi.occupancy"
    d0, hfa = _esi_axes(where, esi)
    vertices, faces, (points,) = _validate.unpack_mesh(where, vertices, faces, points)
    if points is None:
        raise TypeError(f"{where}: `points` must be given (an (..., 3) array)")
    mesh = closed_mesh(where, vertices, faces)
    check_threads(where, threads)
    p = np.asarray(points)
    if p.dtype.kind not in "fiu":
        raise TypeError(f"{where}: `points` must be a real array, got dtype {p.dtype}")
    p = p.astype(np.float64)
    if p.ndim < 1 or p.shape[-1] != 3:
        raise ValueError(f"{where}: `points` must have shape (..., 3), got {p.shape}")
    if not np.all(np.isfinite(p)):
        raise ValueError(f"{where}: `points` must be finite (they contain NaN or Inf)")
    lead = p.shape[:-1]
    p = p.reshape(-1, 3)
    # a point of the DHF lies between two points of S, so inside S's bounding sphere: the
    # points outside it are outside (and the others are cast at about unit size)
    c, rad = bounding_sphere(mesh)
    with np.errstate(over="ignore"):
        inside = (((p - c) / rad) ** 2).sum(1) <= 1.0 + 1e-6
    bvh, scale = scaled_tree(mesh)
    for d in [d0, -d0, *hfa]:
        idx = np.flatnonzero(inside)
        if len(idx) == 0:
            break
        inside[idx] = bvh.any_hits(p[idx] * scale, d, threads=threads)
    return inside.reshape(lead)


def _to_manifold(where: str, mesh: Mesh):
    from manifold3d import Manifold, Mesh64

    m = Manifold(
        Mesh64(
            vert_properties=np.array(mesh.vertices, dtype=np.float64, order="C"),
            tri_verts=np.array(mesh.faces, dtype=np.uint64, order="C"),
        )
    )
    if m.status().name != "NoError":
        raise ValueError(f"{where}: `solids` must be closed manifold meshes: manifold3d rejected one ({m.status().name})")
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
    where = "voxax.esi.to_mesh"
    d0, hfa = _esi_axes(where, esi)
    mesh = closed_mesh(where, vertices, faces)
    res = _validate.positive_int(where, "resolution", resolution, minimum=2)
    _check_pixels(where, res, 2 + len(hfa))
    check_threads(where, threads)
    # in units where the bounding radius lies in [1/2, 1) (an exact power of two, back at
    # the end): the same solids, hence the same manifold3d intersection, at every scale
    c, rad = bounding_sphere(mesh)
    scale = math.ldexp(1.0, -math.frexp(rad)[1])
    bvh = BVH(Mesh(mesh.vertices * scale, mesh.faces))
    c, rad = c * scale, rad * scale
    normals = face_normals(mesh.vertices, mesh.faces)
    maps = {}
    solids = []
    for d in [d0, -d0, *hfa]:
        lk, sg = _canonical(d)
        if lk not in maps:
            maps[lk] = _depth_map(bvh, frame_for(np.asarray(lk), c, rad, res), normals, threads)
        dm = maps[lk]
        if not dm.mask.any():
            raise ValueError(f"{where}: `resolution` must be higher: the depth map along {d.tolist()} is empty")
        solids.append(height_field_solid(dm, sg).boundary)
    out = _intersect(where, solids)
    return out if scale == 1.0 else Mesh(out.vertices / scale, out.faces)


def intersect_solids(solids) -> Mesh:
    """The manifold3d intersection of closed, outward meshes (e.g. height-field solids
    from [`height_field_solid`][voxax.esi.height_field_solid]), as a float64 `Mesh`."""
    where = "voxax.esi.intersect_solids"
    if isinstance(solids, (str, bytes)) or not hasattr(solids, "__iter__"):
        raise TypeError(f"{where}: `solids` must be a sequence of closed meshes, got {type(solids).__name__}")
    solids = list(solids)
    for m in solids:
        if not isinstance(m, Mesh):
            raise TypeError(f"{where}: `solids` must hold voxax.Mesh objects, got {type(m).__name__}")
    return _intersect(where, solids)


def _intersect(where: str, solids) -> Mesh:
    out = None
    for m in solids:
        solid = _to_manifold(where, m)
        out = solid if out is None else out ^ solid
    if out is None:
        raise ValueError(f"{where}: `solids` must hold at least one solid")
    mg = out.to_mesh64()
    v = np.asarray(mg.vert_properties, dtype=np.float64)[:, :3]
    f = np.asarray(mg.tri_verts, dtype=np.int64)
    return Mesh(v, f.astype(np.int32))


@dataclasses.dataclass(frozen=True, eq=False)
class EnergyTerms(ValueEquality):
    """The terms of the energy E (Eq. 1-5) of one choice of axes, in the units of the mesh
    scaled into `[-1/1.1, 1/1.1]^3`.

    - `E`: `Dist + min(mu (Dist + eps1), eps2)`.
    - `dist`: the Chamfer distance `Dist = CD(S, S~) + CD(S~, S)`.
    - `cd_st`, `cd_ts`: its two terms.
    - `mu`: the uncovered fraction (Eq. 4).
    """

    E: float
    dist: float
    cd_st: float
    cd_ts: float
    mu: float


def energy_terms(
    esi,
    vertices,
    faces=None,
    *,
    n_samples: int = 10_000,
    resolution: int = 128,
    eps1: float = 1e-4,
    eps2: float = 1e-3,
    angle: float = 85.0,
    key=None,
    seed=None,
    threads: int | None = None,
) -> EnergyTerms:
    """The terms of the energy E (Eq. 1-5) of one choice of axes, as
    [`select`][voxax.esi.select] computes them.

    **Arguments:**

    - `esi`: an [`ESI`][voxax.esi.ESI] or `(dhf_axis, hf_axes)`.
    - `vertices`, `faces`: the closed mesh (any surface form).
    - `n_samples`, `resolution`, `eps1`, `eps2`, `angle`, `key`, `threads`: as in
      [`select`][voxax.esi.select] (`seed` is the deprecated name of `key`).

    **Returns:** [`EnergyTerms`][voxax.esi.EnergyTerms].
    """
    return _energy_terms("voxax.esi.energy_terms", esi, vertices, faces, n_samples, resolution, eps1, eps2, angle,
                         key, seed, threads)  # fmt: skip


def energy(
    esi,
    vertices,
    faces=None,
    *,
    n_samples: int = 10_000,
    resolution: int = 128,
    eps1: float = 1e-4,
    eps2: float = 1e-3,
    angle: float = 85.0,
    key=None,
    seed=None,
    threads: int | None = None,
) -> float:
    """The energy E (Eq. 1) of one choice of axes, as [`select`][voxax.esi.select]
    computes it: [`energy_terms`][voxax.esi.energy_terms]`(...).E` (same arguments)."""
    return _energy_terms("voxax.esi.energy", esi, vertices, faces, n_samples, resolution, eps1, eps2, angle,
                         key, seed, threads).E  # fmt: skip


def _energy_terms(where, esi, vertices, faces, n_samples, resolution, eps1, eps2, angle, key, seed, threads):
    d0, hfa = _esi_axes(where, esi)
    vertices, faces, _ = _validate.unpack_mesh(where, vertices, faces)
    eps1, eps2, angle = _check_energy_settings(where, eps1, eps2, angle)
    key = _validate.key_or_seed(where, key, seed)
    n_samples = _validate.positive_int(where, "n_samples", n_samples, bytes_each=512.0)
    prob, dk, hk = _prepare(where, vertices, faces, [d0], hfa, resolution, n_samples, key, threads)
    t = prob.energy([dk[0][0], dk[0][1], *hk], eps1, eps2, angle)
    return EnergyTerms(float(t["E"]), float(t["dist"]), float(t["cd_st"]), float(t["cd_ts"]), float(t["mu"]))
