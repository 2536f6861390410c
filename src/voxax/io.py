"""Mesh input and output, trimesh interop, normalization and a watertightness check.

Meshes follow trimesh's conventions: `vertices (V, 3)` float, `faces (F, 3)` int,
outward-oriented (counter-clockwise seen from outside); 2D polylines use `vertices (V, 2)`
and segments `faces (F, 2)`. Functions here return [`voxax.data.Mesh`][voxax.Mesh].

>>> from voxax import data, io
>>> mesh = io.normalize(data.cube(3.0))
>>> float(abs(mesh.vertices).max())
0.8
"""

from __future__ import annotations

import os
from typing import Any

import numpy as np

from . import _validate
from ._mesh import Mesh, fit

__all__ = ["load", "save", "normalize", "as_arrays", "is_watertight"]


# --------------------------------------------------------------------------------------
# Conversion
# --------------------------------------------------------------------------------------


@_validate.surface_first
def as_arrays(mesh: Any) -> tuple[Any, Any]:
    """Return `(vertices, faces)` from a voxax `Mesh`, a `trimesh.Trimesh` or a pair.

    - A voxax [`Mesh`][voxax.Mesh] gives its own float64 / int32 arrays.
    - A `trimesh.Trimesh` (or anything with `.vertices` and `.faces`) gives float64
      vertices and int32 faces.
    - A `(vertices, faces)` pair: NumPy arrays and nested lists are converted; floating
      vertices keep their dtype (float32 stays float32, as the voxelizer's output dtype
      follows the vertices), integer vertices become float64, and faces become int32.
      Other array types (JAX arrays, tracers under `jit`/`grad`) are returned unchanged,
      so differentiation keeps working. Vertices may carry leading batch axes
      `(..., V, d)`.

    Shapes and, for NumPy faces, index ranges are checked.

    **Arguments:**

    - `mesh`: `Mesh`, `trimesh.Trimesh`, or `(vertices (..., V, d), faces (F, d))` (or
      `vertices, faces` as two arguments).

    **Returns:** `(vertices (..., V, d), faces (F, d))`.

    **Raises:** `TypeError` for unsupported inputs; `ValueError` for bad shapes or
    out-of-range face indices.

    >>> import numpy as np
    >>> v, f = as_arrays(([[0., 0.], [1., 0.], [0., 1.]], [[0, 1], [1, 2], [2, 0]]))
    >>> v.dtype, f.dtype, f.shape
    (dtype('float64'), dtype('int32'), (3, 2))
    """
    return _validate.mesh_like("voxax.io.as_arrays", mesh)


# --------------------------------------------------------------------------------------
# Watertightness
# --------------------------------------------------------------------------------------


def is_watertight(vertices: Any, faces: Any = None, *, strict: bool = False) -> bool:
    """Whether a triangle mesh (3D) or segment polyline (2D) is closed and consistently oriented.

    By default this checks the condition under which winding numbers (and hence the
    voxelization) are well defined and independent of the ray direction: the mesh has no
    boundary. In 3D every undirected edge is traversed as often in one direction as in
    the other by the faces using it; in 2D every vertex has as many incoming as outgoing
    segments. Open surfaces, holes and faces with inconsistent orientation fail it.

    With `strict=True` the mesh must moreover be manifold along edges: in 3D every edge
    is shared by exactly two faces, with opposite directions; in 2D every used vertex has
    exactly one incoming and one outgoing segment. (Several closed meshes touching along
    an edge or at a vertex pass the default check but not the strict one.)

    Faces that repeat a vertex index (such as the degenerate `(0, 0, 0)` faces used to pad
    batches) are ignored; a mesh without any other face counts as closed.

    **Arguments:**

    - `vertices`: `(..., V, d)` array; only its shape is used (so tracers are fine); or a
      mesh object (`voxax.Mesh`, `trimesh.Trimesh`) in place of `vertices, faces`.
    - `faces`: `(F, 3)` triangles or `(F, 2)` segments; must be concrete (not traced).
    - `strict`: also require manifold edges (3D) / vertices (2D).

    **Returns:** `bool`.

    >>> from voxax import data
    >>> m = data.cube()
    >>> is_watertight(m.vertices, m.faces), is_watertight(m.vertices, m.faces[1:])
    (True, False)
    """
    where = "voxax.io.is_watertight"
    vertices, faces, _ = _validate.unpack_mesh(where, vertices, faces)
    faces = np.asarray(faces)
    if faces.size == 0 and faces.ndim < 2:
        faces = faces.astype(np.int32).reshape(0, 3 if vertices is None else np.shape(vertices)[-1])
    if faces.ndim != 2 or faces.shape[1] not in (2, 3):
        raise ValueError(f"{where}: `faces` must have shape (F, 3) or (F, 2), got {faces.shape}")
    if vertices is None:
        vertices = np.zeros((int(faces.max()) + 1 if faces.size else 0, faces.shape[1]))
    # Only the shape of the vertices is used (tracers are fine): check it with dummy values.
    shape_only = np.broadcast_to(np.zeros((), np.float64), np.shape(vertices))
    _validate.mesh(where, shape_only, faces, batch=True, allow_empty=True, finite=False)
    faces = faces.astype(np.int64)
    k = faces.shape[1]

    # Drop index-degenerate faces (padding): they have no area and no boundary.
    if k == 3:
        keep = (faces[:, 0] != faces[:, 1]) & (faces[:, 1] != faces[:, 2]) & (faces[:, 2] != faces[:, 0])
    else:
        keep = faces[:, 0] != faces[:, 1]
    faces = faces[keep]
    if len(faces) == 0:
        return True
    n = int(faces.max()) + 1

    if k == 2:
        out_deg = np.bincount(faces[:, 0], minlength=n)
        in_deg = np.bincount(faces[:, 1], minlength=n)
        if not np.array_equal(out_deg, in_deg):
            return False
        if strict:
            used = (out_deg + in_deg) > 0
            return bool(np.all(out_deg[used] == 1))
        return True

    a = faces.reshape(-1)
    b = faces[:, [1, 2, 0]].reshape(-1)
    lo, hi = np.minimum(a, b), np.maximum(a, b)
    key = lo * n + hi
    sign = np.where(a < b, 1, -1)
    uniq, inverse, counts = np.unique(key, return_inverse=True, return_counts=True)
    balance = np.bincount(inverse.reshape(-1), weights=sign, minlength=len(uniq))
    if np.any(balance != 0):
        return False
    if strict:
        return bool(np.all(counts == 2))
    return True


# --------------------------------------------------------------------------------------
# Normalization
# --------------------------------------------------------------------------------------


@_validate.host_only("voxax.io.normalize")
@_validate.surface_first
def normalize(mesh: Any, max_abs: float = 0.8, *, return_transform: bool = False):
    """Centre the bounding box at the origin and scale uniformly so that `max |v| == max_abs`.

    This is the paper's preprocessing (with `max_abs = 0.8` the mesh sits well inside
    the default grid `[-1, 1]^d`). Orientation and face indices are unchanged. The box is
    that of the vertices that some face uses: unused vertices move along but do not
    change the fit.

    **Arguments:**

    - `mesh`: `Mesh`, `trimesh.Trimesh` or `(vertices (V, d), faces (F, d))`.
    - `max_abs`: the largest absolute coordinate after normalization (> 0).
    - `return_transform`: also return `centre (d,)` and `scale` such that
      `new_vertices = (old_vertices - centre) * scale`.

    **Returns:** the normalized `Mesh`, or `(mesh, centre, scale)` if `return_transform`.

    >>> from voxax import data
    >>> m, centre, scale = normalize(data.box((0, 0, 0), (2, 1, 1)), 1.0, return_transform=True)
    >>> m.bounds.tolist(), centre.tolist(), scale
    ([[-1.0, -0.5, -0.5], [1.0, 0.5, 0.5]], [1.0, 0.5, 0.5], 1.0)
    """
    max_abs = _validate.positive_float("voxax.io.normalize", "max_abs", max_abs)
    m = mesh if isinstance(mesh, Mesh) else Mesh(*_validate.mesh_like("voxax.io.normalize", mesh))
    with np.errstate(over="ignore", invalid="ignore"):  # an underflowing extent is refused just below
        vertices, centre, scale = fit(m.vertices, float(max_abs), m.faces)
    if not (np.isfinite(scale) and np.isfinite(np.asarray(vertices)).all()):
        raise ValueError(f"voxax.io.normalize: the mesh is too small to scale to `max_abs` {max_abs:g} (its extent "
                         f"underflows: {float(np.ptp(np.asarray(m.vertices, np.float64))):.3g}); scale it first")
    out = Mesh(vertices, m.faces, m.info)
    return (out, centre, scale) if return_transform else out




# --------------------------------------------------------------------------------------
# Files
# --------------------------------------------------------------------------------------


def _geometry_arrays(obj) -> tuple[np.ndarray, np.ndarray]:
    """Concatenate every triangle mesh in a trimesh Scene (with transforms) or a Trimesh."""
    import trimesh

    if isinstance(obj, trimesh.Trimesh):
        return np.asarray(obj.vertices, dtype=np.float64), np.asarray(obj.faces, dtype=np.int64)
    if isinstance(obj, trimesh.Scene):
        vs, fs, offset = [], [], 0
        for node in obj.graph.nodes_geometry:
            transform, geom_name = obj.graph[node]
            geom = obj.geometry.get(geom_name)
            if not isinstance(geom, trimesh.Trimesh) or len(geom.faces) == 0:
                continue
            transform = np.asarray(transform, dtype=np.float64)
            v = np.asarray(geom.vertices, dtype=np.float64) @ transform[:3, :3].T + transform[:3, 3]
            f = np.asarray(geom.faces, dtype=np.int64)
            if np.linalg.det(transform[:3, :3]) < 0:  # a mirroring transform flips orientation
                f = f[:, ::-1]
            vs.append(v)
            fs.append(f + offset)
            offset += len(v)
        if vs:
            return np.concatenate(vs), np.concatenate(fs)
        return np.zeros((0, 3)), np.zeros((0, 3), dtype=np.int64)
    return np.zeros((0, 3)), np.zeros((0, 3), dtype=np.int64)


def _merge_exact_duplicates(vertices: np.ndarray, faces: np.ndarray):
    """Merge bitwise-identical vertices, keeping first-occurrence order."""
    _, first, inverse = np.unique(vertices, axis=0, return_index=True, return_inverse=True)
    order = np.argsort(first)
    rank = np.empty_like(order)
    rank[order] = np.arange(len(order))
    return vertices[first[order]], rank[inverse.reshape(-1)][faces]


_PLY_SIZES = {"char": 1, "uchar": 1, "int8": 1, "uint8": 1, "short": 2, "ushort": 2, "int16": 2, "uint16": 2,
              "int": 4, "uint": 4, "int32": 4, "uint32": 4, "float": 4, "float32": 4, "double": 8, "float64": 8}


def _check_ply_header(where: str, name: str) -> dict:
    """Refuses a PLY file whose header claims more elements than the file can hold (at
    least one byte and a separator per ASCII value, the values' sizes in a binary file),
    or more than 2^31 - 1 vertices or faces, before anything is read or allocated. Other
    files, and headers this cannot parse, are left to the reader. Returns the header's
    element counts (`{}` for other files), which `load` compares with what was read."""
    try:
        with open(name, "rb") as fh:
            if fh.read(4) not in (b"ply\n", b"ply\r"):
                return {}
            head = b"ply\n" + fh.read(1 << 16)
        size = os.path.getsize(name)
    except OSError:
        return {}
    end = head.find(b"end_header")
    if end < 0:
        return {}
    stop = head.find(b"\n", end)
    if stop < 0:
        return {}
    body = size - (stop + 1)  # `head` holds the file's first bytes at their own offsets
    fmt, elements = None, []
    for line in head[:end].decode("ascii", "replace").splitlines():
        words = line.split()
        if len(words) >= 2 and words[0] == "format":
            fmt = words[1]
        elif len(words) == 3 and words[0] == "element":
            try:
                elements.append([words[1], int(words[2]), 0])
            except ValueError:
                return {}
        elif len(words) >= 3 and words[0] == "property" and elements:
            if fmt == "ascii":
                elements[-1][2] += 2
            else:
                kind = words[2] if words[1] == "list" else words[1]
                elements[-1][2] += _PLY_SIZES.get(kind, 1)
    counts = {element: count for element, count, _ in elements}
    for element, label in (("vertex", "vertices"), ("face", "faces")):
        if counts.get(element, 0) > _validate.INT32_MAX:
            raise ValueError(f"{where}: {name!r} is too large: its header claims {counts[element]} {label}, more "
                             "than the 2^31 - 1 voxax supports")
    need = sum(count * max(per, 1) for _, count, per in elements) - (1 if fmt == "ascii" else 0)
    if any(count < 0 for _, count, _ in elements) or need > body:
        claims = ", ".join(f"{count} {element}" for element, count, _ in elements)
        raise ValueError(f"{where}: {name!r} is truncated or corrupt: its header claims more elements ({claims}) "
                         f"than the file's {max(body, 0)} bytes after the header can hold")
    return counts


def load(
    path: str | os.PathLike,
    process: bool = False,
    *,
    merge: bool | None = None,
    **kwargs: Any,
) -> Mesh:
    """Load a triangle mesh from a file with trimesh.

    Any format trimesh reads works (`.obj`, `.ply`, `.stl`, `.off`, `.glb`, ...). A file
    holding a scene (several meshes, e.g. glTF) is flattened: every triangle mesh in it is
    transformed to world coordinates and concatenated (not unioned). Non-triangle
    geometry (paths, point clouds) is ignored.

    **Arguments:**

    - `path`: file path.
    - `process`: passed to trimesh. `False` (default) keeps the file's vertices and faces
      exactly; `True` lets trimesh merge vertices and drop degenerate or duplicate faces.
    - `merge`: merge bitwise-identical vertices. `None` (default) does so only for a
      triangle soup (no vertex shared between faces, as in STL files), which could never
      be watertight otherwise; `True` always; `False` never.
    - `**kwargs`: passed on to `trimesh.load` (e.g. `file_type="obj"`).

    **Returns:** `Mesh` with float64 `vertices (V, 3)` and int32 `faces (F, 3)`.

    **Raises:** `FileNotFoundError` for a missing file; `ValueError` if the file cannot be
    read, contains no triangles, has faces that index past its vertices, or vertex
    coordinates that are NaN, infinite or beyond the accepted 1e75.

    >>> import os, tempfile
    >>> from voxax import data
    >>> path = os.path.join(tempfile.mkdtemp(), "cube.ply")
    >>> save(data.cube(), path)
    >>> load(path).n_faces
    12
    """
    import trimesh

    where = "voxax.io.load"
    if not isinstance(path, (str, os.PathLike)):
        raise TypeError(f"{where}: `path` must be a str or os.PathLike, got {type(path).__name__}")
    name = os.fspath(path)
    if not os.path.exists(name):
        raise FileNotFoundError(f"{where}: no such file: {name!r}")
    claims = _check_ply_header(where, name) if os.path.isfile(name) else {}
    try:
        obj = trimesh.load(name, process=process, **kwargs)
        vertices, faces = _geometry_arrays(obj)
    except (OSError, ValueError, KeyError, IndexError, TypeError, AttributeError, MemoryError) as err:
        # trimesh raises many kinds for unreadable or truncated files
        raise ValueError(f"{where}: cannot read {name!r}: {type(err).__name__}: {err}") from err
    if claims and not process and (len(faces) < claims.get("face", 0) or len(vertices) < claims.get("vertex", 0)):
        raise ValueError(f"{where}: {name!r} is truncated or corrupt: its header claims {claims.get('vertex', 0)} "
                         f"vertices and {claims.get('face', 0)} faces, {len(vertices)} and {len(faces)} were read")
    if len(faces) == 0:
        raise ValueError(
            f"{where}: {name!r} contains no triangles (loaded a {type(obj).__name__}); voxax needs a triangle mesh"
        )
    _validate.mesh(f"{where}: {name!r}", vertices, faces, dim=3)
    if merge is None:
        merge = len(np.unique(faces)) == faces.size  # every face has its own vertices
    if merge:
        vertices, faces = _merge_exact_duplicates(vertices, faces)
    return Mesh(vertices, faces)


def _write_ply64(vertices: np.ndarray, faces: np.ndarray, path: str) -> None:
    """Binary little-endian PLY with float64 vertices (trimesh's writer uses float32)."""
    header = (
        "ply\n"
        "format binary_little_endian 1.0\n"
        "comment written by voxax\n"
        f"element vertex {len(vertices)}\n"
        "property double x\nproperty double y\nproperty double z\n"
        f"element face {len(faces)}\n"
        "property list uchar int vertex_indices\n"
        "end_header\n"
    )
    packed = np.zeros(len(faces), dtype=np.dtype([("n", "u1"), ("idx", "<i4", (3,))]))
    packed["n"] = 3
    packed["idx"] = faces
    with open(path, "wb") as fh:
        fh.write(header.encode("ascii"))
        fh.write(np.ascontiguousarray(vertices, dtype="<f8").tobytes())
        fh.write(packed.tobytes())


@_validate.surface_first
def save(mesh: Any, path: str | os.PathLike, **kwargs: Any) -> None:
    """Write a 3D triangle mesh to a file; the format follows the file extension.

    `.ply` files are written as binary PLY with float64 vertices (lossless); `.obj`
    and `.off` files with 16 decimal places unless `digits` is given; every other format goes
    through `trimesh.Trimesh.export` (which for some formats, such as STL, stores
    float32). Vertices and faces are written as they are, in order.

    **Arguments:**

    - `mesh`: `Mesh`, `trimesh.Trimesh` or `(vertices (V, 3), faces (F, 3))`.
    - `path`: destination file; its extension picks the format.
    - `**kwargs`: passed to `trimesh.Trimesh.export` (not used for `.ply`).

    >>> import os, tempfile
    >>> from voxax import data
    >>> save(data.torus(), os.path.join(tempfile.mkdtemp(), "torus.obj"))
    """
    if _validate.is_mesh_pair(mesh):
        _validate.mesh("voxax.io.save", *mesh, allow_empty=True, finite=False)  # no bool or complex vertices
    vertices, faces = _validate.mesh_like("voxax.io.save", mesh)
    _validate.mesh("voxax.io.save", vertices, faces, allow_empty=True)  # finite, in range: a file holds no NaN
    vertices = np.asarray(vertices, dtype=np.float64)
    faces = np.asarray(faces)
    if vertices.ndim != 2 or vertices.shape[1] != 3:
        raise ValueError(
            f"voxax.io.save: `mesh` must be a single 3D triangle mesh, got vertices of shape {vertices.shape}"
        )
    path = _validate.file_path("voxax.io.save", "path", path)
    ext = os.path.splitext(path)[1].lower()
    if not ext:
        raise ValueError(f"voxax.io.save: `path` must end in a mesh file extension (.ply, .obj, .stl, .off, ...), "
                         f"got {path!r}")
    if ext == ".ply" and not kwargs:
        with _validate.writing("voxax.io.save", path):
            _write_ply64(vertices, faces, path)
        return
    import trimesh

    if ext in (".obj", ".off"):
        kwargs.setdefault("digits", 16)
    if ext == ".obj":
        kwargs.setdefault("include_normals", False)
    tm = trimesh.Trimesh(vertices=vertices, faces=faces, process=False, validate=False)
    try:
        with _validate.writing("voxax.io.save", path):
            tm.export(path, **kwargs)
    except ValueError as err:
        reason = "no exporter for them" if "exporter not available" in str(err) else str(err).splitlines()[0]
        raise ValueError(f"voxax.io.save: cannot write {ext!r} files ({reason})") from None
