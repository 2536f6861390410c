"""`intersections`: the exact triangle-triangle intersection test (self test or two meshes)."""

from __future__ import annotations

import os
from typing import Any, NamedTuple

import numpy as np

from .. import _validate
from .._constants import MAX_ABS_COORDINATE
from .._kernels import intersect as kernels

__all__ = ["Intersections", "intersections", "MIN_ABS_COORDINATE"]

#: Smallest accepted non-zero coordinate magnitude of the exact test (its exact predicates
#: stay clear of underflow above it).
MIN_ABS_COORDINATE = 1e-50


class Intersections(NamedTuple):
    """What [`intersections`][voxax.intersections] returns.

    - `pairs`: `(K, 2) int64`, the intersecting face pairs, sorted lexicographically. In a
      self test each row is `(i, j)` with `i < j`; between two meshes it is
      `(face of mesh, face of other)`.
    - `count`: `K`.
    """

    pairs: np.ndarray
    count: int

    @property
    def faces(self) -> np.ndarray:
        """`(n,) int64`: the distinct faces in `pairs`, for a self test (for a two-mesh
        test, use `pairs[:, 0]` and `pairs[:, 1]` separately)."""
        return np.unique(self.pairs.reshape(-1))


def _arrays(mesh: Any, faces: Any, name: str) -> tuple[np.ndarray, np.ndarray]:
    """The checked `(vertices, faces)` of one mesh argument (the shared checks of
    `voxax._validate.mesh`, then the exact test's range of magnitudes)."""
    if faces is None:
        if isinstance(mesh, (str, os.PathLike)) or not (
            _validate.is_mesh_object(mesh) or isinstance(mesh, (tuple, list)) and len(mesh) == 2
        ):
            _validate.unpack_mesh(name, mesh, None)  # says what to pass instead
        vertices, faces = _validate.mesh_object_arrays(name, mesh) if _validate.is_mesh_object(mesh) else mesh
    else:
        vertices = mesh
    try:
        vertices = vertices if hasattr(vertices, "dtype") else np.asarray(vertices)
        faces = faces if hasattr(faces, "dtype") else np.asarray(faces)
    except ValueError as exc:  # ragged lists and the like
        raise TypeError(f"{name}: `vertices` and `faces` must be arrays ({exc})") from None
    if not (_validate.is_concrete(vertices) and _validate.is_concrete(faces)):
        raise TypeError(f"{name}: the test is eager (NumPy in, NumPy out); call it outside jax.jit")
    if np.dtype(vertices.dtype).kind in "iu":
        vertices = np.asarray(vertices, dtype=np.float64)
    if np.size(faces) == 0 and np.ndim(faces) <= 2:
        faces = np.zeros((0, 3), np.int32)
    vertices, faces = _validate.mesh(name, np.asarray(vertices), np.asarray(faces), dim=3,
                                     allow_empty=True, context="the triangle test is 3D")
    vertices = np.ascontiguousarray(vertices, dtype=np.float64)
    mags = np.abs(vertices)
    if np.any((mags != 0) & (mags < MIN_ABS_COORDINATE)):
        raise ValueError(
            f"{name}: `vertices` coordinates must have magnitude in [{MIN_ABS_COORDINATE:g}, "
            f"{MAX_ABS_COORDINATE:g}] or be 0 (the exact test needs that range; rescale the mesh)"
        )
    return vertices, np.ascontiguousarray(faces, dtype=np.int32)


def _weld(vertices: np.ndarray, faces: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Merges vertices with identical coordinates (so that adjacency is seen by position)."""
    if vertices.shape[0] < 2:
        return vertices, faces
    v = vertices + 0.0  # -0.0 becomes 0.0
    order = np.lexsort((v[:, 2], v[:, 1], v[:, 0]))
    sv = v[order]
    new = np.ones(len(v), dtype=bool)
    new[1:] = np.any(sv[1:] != sv[:-1], axis=1)
    if new.all():
        return vertices, faces
    label = np.cumsum(new) - 1
    inverse = np.empty(len(v), dtype=np.int64)
    inverse[order] = label
    return np.ascontiguousarray(sv[new]), np.ascontiguousarray(inverse[faces], dtype=np.int32)


def intersections(
    vertices: Any,
    faces: Any = None,
    other: Any = None,
    *,
    weld: bool = True,
    threads: int | None = None,
) -> Intersections:
    """All pairs of intersecting triangles of a mesh (self test), or between two meshes.

    The test is exact for the float64 coordinates: every verdict comes from exactly
    evaluated orientation predicates (a floating-point filter with an exact fallback),
    never from a tolerance. Triangles are closed: **touching counts as intersecting** (a
    vertex on another face, an edge on an edge, coplanar faces sharing boundary points),
    because a mesh free of self-intersections should keep a clearance.

    Self test, faces that share vertices (the mesh's own adjacency):

    - sharing an edge: reported when they fold through each other (coplanar, with their
      third corners on the same side of the shared edge);
    - sharing one corner: reported when they meet anywhere besides that corner;
    - sharing all three corners (a duplicate face, in either orientation): reported.

    Vertices with bit-identical coordinates are merged first (`weld=True`), so an unwelded
    mesh has the adjacency of its welded version. Degenerate faces (zero area: collinear or
    repeated corners) are tested as the segments or points they are against faces they
    share no vertex with, and are never reported against faces that share a vertex with
    them. Open meshes are fine (the test looks at faces, not at volumes).

    Between two meshes there is no adjacency: every touching or crossing pair is reported.

    **Arguments:**

    - `vertices`: `(V, 3)` float, or a voxax `Mesh` / `trimesh.Trimesh` /
      `(vertices, faces)` pair (then leave `faces` out).
    - `faces`: `(F, 3)` int.
    - `other`: a second mesh (`Mesh`, `trimesh.Trimesh` or `(vertices, faces)`): test the
      faces of the first against those of the second instead of the self test.
    - `weld`: merge vertices with identical coordinates before the self test.
    - `threads`: worker threads (default: all cores, or `VOXAX_NUM_THREADS`); the result
      does not depend on it.

    **Returns:** [`Intersections`][voxax.Intersections] `(pairs (K, 2) int64, count)`.

    **Raises:** `TypeError` for non-numeric arrays; `ValueError` for bad shapes, NaN or Inf,
    coordinates of magnitude outside `[1e-50, 1e75]` (other than 0), or face indices out
    of range.

    **Example:**

    ```python
    >>> import voxax
    >>> voxax.intersections(voxax.data.icosphere()).count
    0
    >>> pairs, count = voxax.intersections(voxax.data.bent_bar())
    >>> count > 0
    True

    ```
    """
    va, fa = _arrays(vertices, faces, "voxax.intersections")
    if other is not None:
        vb, fb = _arrays(other, None, "voxax.intersections (other)")
    elif weld:
        va, fa = _weld(va, fa)
    other_arrays = (vb, fb) if other is not None else None
    pairs = kernels.intersections(va, fa, other_arrays, _validate.host_threads("voxax.intersections", threads))
    return Intersections(pairs, len(pairs))
