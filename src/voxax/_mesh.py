"""`Mesh`: a triangle mesh (3D) or segment polyline (2D) as plain NumPy arrays."""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np

from . import _validate

__all__ = ["Mesh", "fit", "from_manifold"]


class _FrozenDict(dict):
    """A read-only dict that pickles and deep-copies like a plain one."""

    def _readonly(self, *args, **kwargs):
        raise TypeError("Mesh.info is read-only; build a new Mesh with the changed info")

    __setitem__ = __delitem__ = clear = pop = popitem = setdefault = update = _readonly  # type: ignore[assignment]

    def __reduce__(self):
        return (_FrozenDict, (dict(self),))

    def __deepcopy__(self, memo):
        import copy

        return _FrozenDict(copy.deepcopy(dict(self), memo))


def _readonly_array(x: np.ndarray) -> np.ndarray:
    x = np.array(x, copy=True, order="C")
    x.setflags(write=False)
    return x


@dataclasses.dataclass(frozen=True, eq=False)
class Mesh:
    """A triangle mesh (3D) or a segment polyline (2D) as plain NumPy arrays.

    The arrays are copied on construction into read-only, C-contiguous arrays: vertices as
    float64, faces as int32. Construction checks shapes and that every face index is in
    range. A `Mesh` is a value: it pickles, deep-copies, and compares with `==` by its
    vertices, faces and `info` (exactly, bit for bit). It is not hashable (its arrays are
    not). A `Mesh` unpacks like a tuple, so `vertices, faces = mesh` works, and every voxax
    function that takes `vertices, faces` also takes a `Mesh` in their place
    (`voxax.voxelize(mesh, grid)`).

    **Arguments:**

    - `vertices`: `(V, d)` float array, `d` = 2 or 3.
    - `faces`: `(F, d)` integer array: triangles `(F, 3)` for `d = 3`, segments `(F, 2)`
      for `d = 2`, outward-oriented (counter-clockwise seen from outside).
    - `info`: optional read-only metadata, for example the overlap box of
      [`overlapping_cubes`][voxax.data.overlapping_cubes]. Not part of the geometry.

    >>> import numpy as np
    >>> m = Mesh(np.array([[0., 0.], [1., 0.], [0., 1.]]), np.array([[0, 1], [1, 2], [2, 0]]))
    >>> m.dim, m.n_faces, m.signed_volume()
    (2, 3, 0.5)
    """

    vertices: np.ndarray
    faces: np.ndarray
    info: Mapping[str, Any] = dataclasses.field(default_factory=dict, repr=False)

    def __post_init__(self) -> None:
        if not (_validate.is_concrete(self.vertices) and _validate.is_concrete(self.faces)):
            raise TypeError("voxax.Mesh: holds NumPy arrays and cannot take traced values: under jax.jit pass "
                            "`vertices, faces` (or a (vertices, faces) pair) to the function instead")
        vertices = np.asarray(self.vertices)
        if vertices.dtype.kind in "fiub":
            vertices = vertices.astype(np.float64)
        faces_in = np.asarray(self.faces)
        if faces_in.size == 0 and vertices.ndim == 2:  # e.g. np.zeros((0, 3)) or []: an empty mesh
            faces_in = np.zeros((0, vertices.shape[1]), dtype=np.int32)
        vertices, faces_in = _validate.mesh("voxax.Mesh", vertices, faces_in, allow_empty=True, finite=False)
        object.__setattr__(self, "vertices", _readonly_array(vertices))
        object.__setattr__(self, "faces", _readonly_array(faces_in.astype(np.int32)))
        object.__setattr__(self, "info", _FrozenDict(self.info))

    # -- value semantics -------------------------------------------------------------

    def __eq__(self, other: object) -> bool:
        if not isinstance(other, Mesh):
            return NotImplemented
        return (
            self.vertices.shape == other.vertices.shape
            and self.faces.shape == other.faces.shape
            and bool(np.array_equal(self.vertices, other.vertices))
            and bool(np.array_equal(self.faces, other.faces))
            and _info_equal(self.info, other.info)
        )

    __hash__ = None  # type: ignore[assignment]

    def __reduce__(self):
        return (Mesh, (np.array(self.vertices), np.array(self.faces), dict(self.info)))

    def __deepcopy__(self, memo):
        import copy

        return Mesh(np.array(self.vertices), np.array(self.faces), copy.deepcopy(dict(self.info), memo))

    # -- basic properties -------------------------------------------------------------

    @property
    def dim(self) -> int:
        """Spatial dimension `d` (2 or 3)."""
        return int(self.vertices.shape[1])

    @property
    def n_vertices(self) -> int:
        """Number of vertices `V`."""
        return int(self.vertices.shape[0])

    @property
    def n_faces(self) -> int:
        """Number of faces `F` (triangles in 3D, segments in 2D)."""
        return int(self.faces.shape[0])

    @property
    def bounds(self) -> np.ndarray:
        """Axis-aligned bounding box as a `(2, d)` array `[lower, upper]`."""
        return np.stack([self.vertices.min(axis=0), self.vertices.max(axis=0)])

    def __iter__(self):
        yield self.vertices
        yield self.faces

    def __repr__(self) -> str:
        kind = "triangles" if self.dim == 3 else "segments"
        return f"Mesh(dim={self.dim}, n_vertices={self.n_vertices}, n_faces={self.n_faces} {kind})"

    # -- geometry ---------------------------------------------------------------------

    def face_normals(self) -> np.ndarray:
        """`(F, 3)` float64 unit normals of the triangles (zeros for degenerate ones)."""
        return face_normals(self.vertices, self.faces)

    def signed_volume(self) -> float:
        """Exact signed volume (3D) or signed area (2D) enclosed by the mesh.

        Computed with the divergence theorem, `sum over faces det(a, b, c) / 6` in 3D and
        the shoelace formula `sum (x_a y_b - x_b y_a) / 2` in 2D. Positive for a closed,
        outward-oriented mesh; it equals the integral of the winding number over space,
        so overlapping parts count twice and inverted parts negatively.

        **Returns:** a Python float.

        >>> from voxax import data
        >>> round(data.cube(2.0).signed_volume(), 12)
        8.0
        """
        v = self.vertices[self.faces]
        if self.dim == 3:
            a, b, c = v[:, 0], v[:, 1], v[:, 2]
            return float(np.einsum("ij,ij->", a, np.cross(b, c)) / 6.0)
        a, b = v[:, 0], v[:, 1]
        return float(np.sum(a[:, 0] * b[:, 1] - b[:, 0] * a[:, 1]) / 2.0)

    def flipped(self) -> Mesh:
        """The same mesh with reversed orientation (inward normals).

        Reverses the vertex order of every face, which negates the winding number
        everywhere (and the signed volume).

        **Returns:** a new `Mesh`.

        >>> from voxax import data
        >>> data.cube().flipped().signed_volume()
        -1.0
        """
        return Mesh(self.vertices, self.faces[:, ::-1], self.info)

    def translated(self, offset: Sequence[float]) -> Mesh:
        """The mesh moved by `offset` (shape `(d,)`).

        >>> from voxax import data
        >>> data.cube().translated((1, 0, 0)).bounds[0].tolist()
        [0.5, -0.5, -0.5]
        """
        offset = np.asarray(offset, dtype=np.float64).reshape(self.dim)
        return Mesh(self.vertices + offset, self.faces, self.info)

    def to_trimesh(self):
        """Convert a 3D mesh to a `trimesh.Trimesh` (no processing, no vertex merging).

        **Returns:** `trimesh.Trimesh` with copies of this mesh's vertices and faces.

        >>> from voxax import data
        >>> data.cube().to_trimesh().is_watertight
        True
        """
        if self.dim != 3:
            raise ValueError("voxax.Mesh.to_trimesh: needs a 3D triangle mesh; this is a 2D polyline")
        import trimesh

        return trimesh.Trimesh(
            vertices=np.array(self.vertices), faces=np.array(self.faces), process=False, validate=False
        )

    @classmethod
    def from_trimesh(cls, mesh) -> Mesh:
        """A `Mesh` from a `trimesh.Trimesh` (vertex order and faces kept as they are).

        >>> import trimesh
        >>> Mesh.from_trimesh(trimesh.creation.box()).n_faces
        12
        """
        vertices = getattr(mesh, "vertices", None)
        faces = getattr(mesh, "faces", None)
        if vertices is None or faces is None:
            raise TypeError(f"voxax.Mesh.from_trimesh: `mesh` must be a trimesh.Trimesh, got {type(mesh).__name__}")
        return cls(np.asarray(vertices, dtype=np.float64), np.asarray(faces))

    @staticmethod
    def concatenate(*meshes: Mesh) -> Mesh:
        """Concatenate meshes of one dimension into one (no boolean union).

        Overlapping parts stay overlapping, so their winding numbers add.

        >>> from voxax import data
        >>> Mesh.concatenate(data.cube(), data.cube().translated((2, 0, 0))).n_faces
        24
        """
        if not meshes:
            raise ValueError("voxax.Mesh.concatenate: `meshes` must hold at least one mesh")
        dims = {m.dim for m in meshes}
        if len(dims) != 1:
            raise ValueError(f"voxax.Mesh.concatenate: `meshes` must share one dimension, got {sorted(dims)}")
        offsets = np.cumsum([0] + [m.n_vertices for m in meshes[:-1]])
        return Mesh(
            np.concatenate([m.vertices for m in meshes]),
            np.concatenate([m.faces + o for m, o in zip(meshes, offsets)]),
        )


def mesh_from_trusted(vertices: np.ndarray, faces: np.ndarray) -> Mesh:
    """A `Mesh` of arrays that a voxax routine built itself, without `Mesh`'s checks.

    For producers whose output is valid by construction (shapes, dtypes and face indices
    in range): the arrays are taken over, not copied, and made read-only, so the caller
    must not keep writing to them. Everything else builds a `Mesh` with its checks.

    **Arguments:**

    - `vertices`: `(V, d)` float64 C-contiguous; `faces`: `(F, d)` int32 C-contiguous,
      indices in `[0, V)`.

    **Returns:** a [`Mesh`][voxax.Mesh] with empty `info`.
    """
    if not (
        isinstance(vertices, np.ndarray)
        and isinstance(faces, np.ndarray)
        and vertices.dtype == np.float64
        and faces.dtype == np.int32
        and vertices.ndim == 2
        and faces.ndim == 2
        and vertices.shape[1] in (2, 3)
        and faces.shape[1] == vertices.shape[1]
        and vertices.flags.c_contiguous
        and faces.flags.c_contiguous
    ):
        raise ValueError("mesh_from_trusted: expected (V, d) float64 and (F, d) int32 C-contiguous arrays")
    mesh = object.__new__(Mesh)
    for name, value in (("vertices", vertices), ("faces", faces)):
        value.setflags(write=False)
        object.__setattr__(mesh, name, value)
    object.__setattr__(mesh, "info", _FrozenDict())
    return mesh


def _info_equal(a: Mapping, b: Mapping) -> bool:
    if a.keys() != b.keys():
        return False
    for key in a:
        x, y = a[key], b[key]
        if isinstance(x, np.ndarray) or isinstance(y, np.ndarray):
            if not np.array_equal(np.asarray(x), np.asarray(y)):
                return False
        elif x != y:
            return False
    return True


def used_vertices(vertices: np.ndarray, faces) -> np.ndarray:
    """The vertices that some face uses (all of them when `faces` is None or empty)."""
    if faces is None or np.size(faces) == 0:
        return vertices
    return vertices[np.unique(np.asarray(faces))]


def fit(vertices: np.ndarray, max_abs: float, faces=None) -> tuple[np.ndarray, np.ndarray, float]:
    """Centre the bounding box at the origin and scale so that max |v| == max_abs.

    With `faces`, the box is that of the vertices some face uses (unused vertices are moved
    along but do not change the fit). Returns `(new_vertices, centre, scale)` with
    `new = (old - centre) * scale`.
    """
    if len(vertices) == 0:
        raise ValueError("voxax.Mesh.normalize: cannot normalize a mesh without vertices")
    box = used_vertices(vertices, faces)
    if not np.all(np.isfinite(box)):
        raise ValueError("voxax.Mesh.normalize: cannot normalize a mesh with NaN or Inf vertex coordinates")
    if not max_abs > 0:
        raise ValueError(f"voxax.Mesh.normalize: `max_abs` must be > 0, got {max_abs}")
    lo, hi = box.min(axis=0), box.max(axis=0)
    centre = (lo + hi) / 2.0
    centred = vertices - centre
    extent = np.abs(box - centre).max()
    if not extent > 0:
        raise ValueError("voxax.Mesh.normalize: cannot normalize a mesh whose vertices all coincide")
    scale = float(max_abs) / float(extent)
    return centred * scale, centre, scale


def from_manifold(manifold) -> tuple[np.ndarray, np.ndarray]:
    """Vertex and face arrays of a manifold3d Manifold (float64 where available)."""
    to_mesh = getattr(manifold, "to_mesh64", None) or manifold.to_mesh
    mesh = to_mesh()
    vertices = np.asarray(mesh.vert_properties, dtype=np.float64)[:, :3]
    faces = np.asarray(mesh.tri_verts, dtype=np.int64)
    # Properties can split vertices; merge exact duplicates so the mesh is index-watertight.
    uniq, inverse = np.unique(vertices, axis=0, return_inverse=True)
    faces = inverse.reshape(-1)[faces]
    return uniq, faces


def face_normals(vertices, faces) -> np.ndarray:
    """`(F, 3)` float64 unit normals of triangles `faces` of `vertices` (right-hand rule;
    zeros for degenerate triangles)."""
    v = np.asarray(vertices, np.float64)
    f = np.asarray(faces)
    if len(f) == 0:
        return np.zeros((0, 3))
    n = np.cross(v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]])
    length = np.linalg.norm(n, axis=1, keepdims=True)
    return n / np.where(length > 0, length, 1.0)
