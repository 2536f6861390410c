"""What an ESI gives: exact occupancy, a watertight mesh (manifold3d intersections of
height-field solids) and the energy of one choice of axes."""

from __future__ import annotations

import numpy as np

from .. import _validate
from .._mesh import Mesh, face_normals
from .._spatial import BVH
from ._depth import _depth_map, height_field_solid
from ._frames import _canonical, bounding_sphere, closed_mesh, frame_for, unit_direction
from ._select import ESI, _prepare

__all__ = ["energy", "intersect_solids", "occupancy", "to_mesh"]


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
