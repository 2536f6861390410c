"""Exact crossings of triangle meshes with axis-aligned grid lines ("dexels").

[`line_crossings`][voxax.raster.line_crossings] intersects a triangle mesh with every line
parallel to one axis that passes through the cell centres (or the nodes) of a grid, in
C++ on all cores. The inside test is exact (orient2d predicates) with one
simulation-of-simplicity rule: the line through `(b, c)` on the two other axes is treated
as passing through `(b + d, c + d^2)` for an infinitesimal `d > 0`. So a line through an
edge or a vertex shared by consistently oriented triangles crosses exactly one of them,
faces parallel to the line are never crossed, and along every line a closed mesh has as
many crossings entering it as leaving it. Crossings are counted with signs, so the winding
number of a closed mesh at a point of a line is `-sum(sign)` over the crossings before it.

Dexels are the shared input of the contouring, meshing and depth-map systems: edge signs
of a grid's lattice, surface samples along the three axes, and boolean operations of
solids on the lines.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from . import _validate as check
from ._constants import MAX_ABS_COORDINATE
from ._grid import Grid
from ._kernels import raster as _kernel

__all__ = ["Dexels", "line_crossings"]

_LINES = ("centers", "nodes")


class Dexels(NamedTuple):
    """The crossings of a mesh with a family of lines parallel to `axis`.

    The lines are indexed by their coordinates on the two other axes `(a0, a1)` (in
    increasing axis order): line `l = i0 * n1 + i1` passes through
    `(line_coords[0][i0], line_coords[1][i1])`.

    - `axis`: int, the axis the lines are parallel to.
    - `lines`: `"centers"`, `"nodes"` or `"custom"`, where the lines come from.
    - `line_coords`: a pair `((n0,), (n1,))` of float64 arrays.
    - `offsets`: `(n0 * n1 + 1,)` int64; the crossings of line `l` are
      `offsets[l]:offsets[l + 1]`.
    - `depth`: `(C,)` float64, the coordinate along `axis` of each crossing; sorted along
      each line (ties by face index).
    - `sign`: `(C,)` int8, the sign of the face normal's component along `axis`: +1 where
      a closed outward-oriented mesh is left, -1 where it is entered.
    - `face`: `(C,)` int32, the crossed face.
    """

    axis: int
    lines: str
    line_coords: tuple
    offsets: np.ndarray
    depth: np.ndarray
    sign: np.ndarray
    face: np.ndarray

    @property
    def shape(self) -> tuple[int, int]:
        """`(n0, n1)`, the number of lines along the two other axes."""
        return (len(self.line_coords[0]), len(self.line_coords[1]))

    def counts(self) -> np.ndarray:
        """`(n0, n1)` int64, the number of crossings of each line."""
        return np.diff(self.offsets).reshape(self.shape)

    def line_index(self) -> np.ndarray:
        """`(C,)` int64, the line of each crossing."""
        return np.repeat(np.arange(len(self.offsets) - 1, dtype=np.int64), np.diff(self.offsets))

    def points(self) -> np.ndarray:
        """`(C, 3)` float64, the crossing points."""
        line = self.line_index()
        n1 = self.shape[1]
        others = [a for a in range(3) if a != self.axis]
        p = np.empty((len(self.depth), 3), np.float64)
        p[:, self.axis] = self.depth
        p[:, others[0]] = self.line_coords[0][line // n1]
        p[:, others[1]] = self.line_coords[1][line % n1]
        return p

    def winding(self) -> np.ndarray:
        """`(C,)` int64, the winding number just after each crossing along its line.

        It is `-cumsum(sign)` within each line; for a closed outward-oriented mesh it is
        the mesh's winding number on the segment that follows the crossing.
        """
        w = -np.cumsum(self.sign, dtype=np.int64)
        start = self.offsets[:-1]
        base = np.concatenate([[0], w])[start]  # the running sum before each line
        return w - np.repeat(base, np.diff(self.offsets))


def _line_coords(where: str, grid: Grid, axis: int, lines) -> tuple[str, tuple]:
    others = [a for a in range(3) if a != axis]
    if isinstance(lines, str):
        if lines == "centers":
            coords = tuple(
                grid.lower[a] + (np.arange(grid.shape[a], dtype=np.float64) + 0.5) * grid.spacing[a] for a in others
            )
        elif lines == "nodes":
            coords = tuple(grid.edges(a) for a in others)
        else:
            raise ValueError(f"{where}: `lines` must be one of {_LINES} or a pair of arrays, got {lines!r}")
        return lines, coords
    try:
        c0, c1 = lines
    except (TypeError, ValueError):
        raise ValueError(
            f"{where}: `lines` must be one of {_LINES} or a pair of arrays, got {type(lines).__name__}"
        ) from None
    coords = []
    for c in (c0, c1):
        c = np.asarray(c)
        if c.dtype == bool or c.dtype.kind not in "fiu":
            raise TypeError(f"{where}: line coordinates must be real numbers, got dtype {c.dtype}")
        if c.ndim != 1:
            raise ValueError(f"{where}: line coordinates must be 1-D arrays, got shape {c.shape}")
        c = np.ascontiguousarray(c, dtype=np.float64)
        if not np.all(np.isfinite(c)):
            raise ValueError(f"{where}: line coordinates must be finite")
        if len(c) and np.abs(c).max() > MAX_ABS_COORDINATE:
            raise ValueError(f"{where}: line coordinates must have magnitudes <= {MAX_ABS_COORDINATE:g}")
        if np.any(np.diff(c) <= 0):
            raise ValueError(f"{where}: line coordinates must be strictly increasing")
        coords.append(c)
    return "custom", tuple(coords)


@check.host_only("voxax.raster.line_crossings")
def line_crossings(vertices, faces=None, grid=None, axis=None, *, lines="centers", threads=None) -> Dexels:
    """Every crossing of a triangle mesh with the grid lines parallel to `axis`.

    Exact: a crossing is found by exact orientation tests with the tie rule of the module
    docstring, so closed meshes give balanced crossings along every line; the depth is the
    barycentric interpolation on the crossed face (float64, within the face's extent).
    Degenerate faces and faces parallel to the lines are never crossed. Open and
    non-manifold meshes are fine. Eager (NumPy in, NumPy out); the result does not depend
    on the number of threads.

    **Arguments:**

    - `vertices`: `(V, 3)` float, or a mesh object (`voxax.Mesh`, `trimesh.Trimesh`) in
      place of `vertices, faces`.
    - `faces`: `(F, 3)` int.
    - `grid`: a 3D [`Grid`][voxax.Grid]; only its lines matter (crossings anywhere along
      a line are returned, also outside the grid's box).
    - `axis`: 0, 1 or 2.
    - `lines`: `"centers"` (through the cell centres `lower + (i + 0.5) * spacing` of the
      two other axes), `"nodes"` (through the grid nodes, `grid.edges(a)`), or a pair of
      strictly increasing coordinate arrays for the two other axes.
    - `threads`: int or None (all cores, or `VOXAX_NUM_THREADS`).

    **Returns:** [`Dexels`][voxax.raster.Dexels].

    **Example:**

    ```python
    >>> d = voxax.raster.line_crossings(voxax.data.icosphere(3), voxax.Grid.cube(8), 2)
    >>> int(d.sign.sum())  # a closed mesh: as many exits as entries
    0
    ```
    """
    where = "voxax.raster.line_crossings"
    vertices, faces, (grid, axis) = check.unpack_mesh(where, vertices, faces, grid, axis)
    grid = check.grid(where, grid, dim=3)
    if axis is None:
        raise TypeError(f"{where}: missing `axis`")
    if isinstance(axis, bool) or not isinstance(axis, (int, np.integer)) or not 0 <= int(axis) <= 2:
        raise ValueError(f"{where}: `axis` must be 0, 1 or 2, got {axis!r}")
    axis = int(axis)
    vertices, faces = np.asarray(vertices), np.asarray(faces)
    if vertices.dtype == bool:
        raise TypeError(f"{where}: `vertices` must be float32 or float64, got bool")
    vertices, faces = check.mesh(where, vertices, faces, dim=3, allow_empty=True)
    v = np.ascontiguousarray(vertices, dtype=np.float64)
    f = np.ascontiguousarray(faces, dtype=np.int32)
    check.host_threads(where, threads)
    kind, coords = _line_coords(where, grid, axis, lines)
    # The line offsets (here and in C++) and the kernel's per-line lists, before allocating.
    check.check_allocation(where, 40.0 * len(coords[0]) * len(coords[1]), f"{len(coords[0])} x {len(coords[1])} lines")
    offsets, depth, sign, face = _kernel.line_crossings(v, f, axis, coords[0], coords[1], threads)
    return Dexels(axis, kind, coords, offsets, depth, sign, face)
