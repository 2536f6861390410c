"""Encoding: a mesh's cell pieces, QEF rows and edge signs as tokens (one anchor per cell, or
per component), and the dual layout."""

from __future__ import annotations

import dataclasses
from typing import NamedTuple

import numpy as np

from .. import _validate as check
from .._grid import Grid
from .._kernels import fc as _kernel
from .._mesh import face_normals
from ._components import _component_tokens
from ._lattice import _cells_around, _Crossings, _crossings, _edge_geometry, _group, _net_signs, _node_ids, dual_grid
from ._patches import split_patches
from ._tokens import Tokens


def _mesh_args(where, vertices, faces, grid, threads=None):
    vertices, faces, (grid,) = check.unpack_mesh(where, vertices, faces, grid)
    if grid is None:
        raise TypeError(f"{where}: missing `grid` (a voxax.Grid)")
    if np.asarray(vertices).dtype == bool:
        raise TypeError(f"{where}: `vertices` must be a float (or integer) array, got bool")
    vertices, faces = check.mesh(where, vertices, faces, dim=3, integer_vertices=True, allow_empty=True)
    grid = check.grid(where, grid, dim=3)
    check.host_threads(where, threads)
    V, F = np.asarray(vertices, np.float64), np.asarray(faces, np.int32)
    check.check_allocation(where, _bytes_needed(V, F, grid), f"encoding {len(F)} faces on a {grid.shape} grid")
    return V, F, grid


def _bytes_needed(V, F, grid) -> float:
    """About what encoding needs: the node lines of the three axes (their offsets in C++
    and NumPy) and the pieces of the faces (a face of area A and perimeter P meets at most
    about sqrt(3) A / h^2 + 2 P / h + 1 cells of the smallest spacing h), at ~200 bytes a
    piece and its row."""
    n = np.asarray(grid.shape, np.float64) + 1
    lines = n[1] * n[2] + n[0] * n[2] + n[0] * n[1]
    if not len(F):
        return 40.0 * lines
    h = float(min(grid.spacing))
    a, b, c = V[F[:, 0]], V[F[:, 1]], V[F[:, 2]]
    area = 0.5 * np.linalg.norm(np.cross(b - a, c - a), axis=1)
    perim = np.linalg.norm(b - a, axis=1) + np.linalg.norm(c - b, axis=1) + np.linalg.norm(a - c, axis=1)
    pieces = float(np.sum(np.sqrt(3.0) * area / h**2 + 2.0 * perim / h + 1.0))
    return 40.0 * lines + 200.0 * pieces


class Pieces(NamedTuple):
    """The pieces of a mesh clipped into a grid's cells, sorted by (cell, face).

    - `cell`: `(P,)` int64 C-order cell index; `face`: `(P,)` int32 face index.
    - `area`: `(P,)` float64 piece area (> 0; pieces of zero area are left out).
    - `centroid`: `(P, 3)` float64 area centroid (inside the closed cell).
    """

    cell: np.ndarray
    face: np.ndarray
    area: np.ndarray
    centroid: np.ndarray


@check.host_only("voxax.fc.pieces")
def pieces(vertices, faces=None, grid=None, *, threads=None) -> Pieces:
    """Clips every triangle into the cells it meets; the pieces partition each triangle.

    Cells are half-open (`[lower, upper)` per axis, the last one closed), as in
    [`voxax.voxelize`][voxax.voxelize], so every part of a triangle belongs to exactly
    one cell. Degenerate triangles give no pieces.

    **Arguments:**

    - `vertices`: `(V, 3)` float; `faces`: `(F, 3)` int (or a `Mesh` in place of both).
    - `grid`: a 3D [`Grid`][voxax.Grid].
    - `threads`: worker threads (None: all cores); results do not depend on it.

    **Returns:** [`Pieces`][voxax.fc.Pieces].

    >>> import voxax
    >>> p = voxax.fc.pieces(voxax.data.cube(1.0), voxax.Grid.cube(4))
    >>> round(float(p.area.sum()), 12)
    6.0
    """
    where = "voxax.fc.pieces"
    V, F, grid = _mesh_args(where, vertices, faces, grid, threads)
    return Pieces(*_kernel.encode_pieces(where, V, F, grid.lower, grid.upper, grid.shape, threads))


def _rows(
    where, V, F, grid, lambda_n, lambda_d, weight_power, clamp, components, threads, boundaries=True, joined=None
):
    flags = (_kernel.CLAMP if clamp else 0) | (_kernel.RECORD_FACES | _kernel.COMPONENTS if components else 0)
    flags |= _kernel.OPEN_BOUNDARIES if boundaries else 0
    params = (lambda_n, lambda_d, weight_power)
    return _kernel.encode_rows(where, V, F, grid.lower, grid.upper, grid.shape, params, flags, joined, threads)


def _encode_primal(where, V, F, grid, lambda_n, lambda_d, weight_power, clamp, mode, threads, boundaries):
    components = mode == "components"
    index, comp, off, nrm, area, fcount, rfaces = _rows(
        where, V, F, grid, lambda_n, lambda_d, weight_power, clamp, components, threads, boundaries
    )
    cr = _crossings(V, F, grid, threads)
    shape = grid.shape
    h = np.asarray(grid.spacing)
    lo = np.asarray(grid.lower)
    if not components:
        signs, missing, src = _net_signs_host(grid, index, cr, threads)
        if len(missing):
            # Cells that a crossing touches without a piece of positive area get a row at
            # the crossing point, so every quad has its four vertices.
            mcells = np.stack(np.unravel_index(missing, shape), axis=1)
            moff = np.clip((cr.point[src] - lo) / h - mcells - 0.5, -0.5, 0.5)
            order = np.argsort(np.concatenate([index, missing]), kind="stable")
            index = np.concatenate([index, missing])[order]
            comp = np.concatenate([comp, np.zeros(len(missing), np.int32)])[order]
            off = np.concatenate([off, moff])[order]
            nrm = np.concatenate([nrm, face_normals(V, F)[cr.face[src]]])[order]
            area = np.concatenate([area, np.zeros(len(missing))])[order]
            signs, missing, _ = _net_signs_host(grid, index, cr, threads)
            assert not len(missing)
        tok = Tokens(grid, index, off, nrm, signs, comp, area)
        if mode == "patches":
            tok = split_patches(tok, V, F, cr, lambda_n, lambda_d, weight_power, threads)
        return tok
    # anchors_per_cell="components": every crossing counts for the rows of its own sheet,
    # so every crossing needs its cells.
    edge = cr.edge
    axis, nodes = _edge_geometry(grid, edge)
    cidx = _cells_around(grid, axis, nodes)
    flat = cidx.reshape(-1)
    forder, fstarts = _group(flat)
    want = flat[forder[fstarts]]
    firsts = forder[fstarts]
    # A cell whose components split the crossings of an edge that one row of a neighbour
    # holds together (two sheets that join just outside the cell) would leave holes: such
    # cells get one anchor for all their pieces, until every edge's crossings are split
    # alike in its 4 cells.
    joined = np.zeros(0, np.int64)
    for _ in range(64):
        tok, bad = _component_tokens(V, F, grid, cr, cidx, want, firsts, index, comp, off, nrm, area, fcount, rfaces)
        bad = np.setdiff1d(bad, joined)
        if not len(bad):
            break
        joined = np.union1d(joined, bad)
        index, comp, off, nrm, area, fcount, rfaces = _rows(
            where, V, F, grid, lambda_n, lambda_d, weight_power, clamp, True, threads, boundaries, joined=joined
        )
    return tok


def _net_signs_host(grid: Grid, index, cr: _Crossings, threads):
    """`(K, 12)` int8 net signs of the rows' edges (one row per cell), and the cells around
    signed edges that have no row with the crossing each takes its row from."""
    S, pairs = _kernel.signs(index, grid.shape, cr.edge, cr.sign, threads)
    return S, pairs[:, 0].copy(), pairs[:, 1].copy()


@check.host_only("voxax.fc.encode")
def encode(
    vertices,
    faces=None,
    grid=None,
    *,
    layout: str = "primal",
    lambda_n: float = 1.0,
    lambda_d: float = 1e-3,
    weight_power: float = 1.0,
    clamp: bool = True,
    anchors_per_cell="patches",
    open_boundaries: bool = True,
    threads=None,
) -> Tokens:
    """Encodes a triangle mesh into Faithful Contour Tokens on `grid`.

    **Arguments:**

    - `vertices`: `(V, 3)` float; `faces`: `(F, 3)` int (or a `Mesh` in place of both).
      Open, non-manifold and degenerate faces are allowed.
    - `grid`: a 3D [`Grid`][voxax.Grid] (any shape, cells may be anisotropic).
    - `layout`: `"primal"` (anchors and the 12 edge signs) or `"dual"` (also the dual
      anchors at the cell's 8 corners and the 6 semi-axis signs).
    - `lambda_n`, `lambda_d`: QEF weights of the tangent planes and of the centroids
      (`lambda_d > 0`, in cell units).
    - `weight_power`: `p` in the piece weights `A^p` (0: uniform).
    - `clamp`: move anchors that leave their cell back onto the cell's pieces.
    - `anchors_per_cell`: `"patches"` (the default): one anchor per cell, and one per surface
      patch in the cells that several separate patches cross (a part thinner than a cell,
      two parts closer than one), the patches decided from the cell's edge signs alone as
      marching cubes joins them, so that a closed mesh decodes to a closed 2-manifold (a
      patch's anchor minimizes the QEF over the pieces of the faces that cross its edges). `1`: exactly one anchor per cell (the paper's; sheets that
      share a cell share its vertex, and their edges get four faces). `"components"`: one
      anchor per connected component
      of the cell's pieces (pieces of faces that share a mesh edge passing through the
      cell are joined), so that nearby sheets, and the two faces of a sharp edge that
      passes just outside the cell, get a vertex each. A cell keeps one anchor where its
      components would split the crossings of one of its edges differently from the cells
      around that edge (two sheets that join just outside the cell, or sheets in another
      order along the edge), which would leave holes in the decoded mesh.
    - `open_boundaries`: where an open boundary of the mesh (an edge of one face only)
      passes through a cell, add its lines to the QEF with the weight of the tangent
      planes, so that the anchor lies on the boundary and open sheets keep their extent
      (beyond the paper; no effect on closed meshes).
    - `threads`: worker threads (None: all cores); the result does not depend on it.

    **Returns:** [`Tokens`][voxax.fc.Tokens].
    """
    where = "voxax.fc.encode"
    V, F, grid = _mesh_args(where, vertices, faces, grid, threads)
    if layout not in ("primal", "dual"):
        raise ValueError(f"{where}: `layout` must be 'primal' or 'dual', got {layout!r}")
    if isinstance(anchors_per_cell, bool) or anchors_per_cell not in (1, "patches", "components"):
        raise ValueError(
            f"{where}: `anchors_per_cell` must be 1, 'patches' or 'components', got {anchors_per_cell!r}"
        )
    lambda_n = check.positive_float(where, "lambda_n", lambda_n, allow_zero=True)
    lambda_d = check.positive_float(where, "lambda_d", lambda_d)
    weight_power = check.positive_float(where, "weight_power", weight_power, allow_zero=True)
    if weight_power > 16:
        raise ValueError(f"{where}: `weight_power` must lie in [0, 16], got {weight_power}")
    mode = {1: "one", "patches": "patches", "components": "components"}[anchors_per_cell]
    b = bool(open_boundaries)
    tok = _encode_primal(where, V, F, grid, lambda_n, lambda_d, weight_power, bool(clamp), mode, threads, b)
    if layout == "dual":
        tok = _add_dual(where, tok, V, F, lambda_n, lambda_d, weight_power, bool(clamp), threads, b)
    return tok


def _add_dual(where, tok, V, F, lambda_n, lambda_d, weight_power, clamp, threads, boundaries) -> Tokens:
    grid = tok.grid
    dg = dual_grid(grid)
    index, _, off, nrm, _, _, _ = _rows(
        where, V, F, dg, lambda_n, lambda_d, weight_power, clamp, False, threads, boundaries
    )
    cells = tok.cells.astype(np.int64)
    corners = cells[:, None, :] + np.array(np.unravel_index(np.arange(8), (2, 2, 2))).T[None]
    cid = np.ravel_multi_index(tuple(np.moveaxis(corners, 2, 0)), dg.shape)
    pos = np.clip(np.searchsorted(index, cid), 0, max(len(index) - 1, 0))
    mask = (index[pos] == cid) if len(index) else np.zeros(cid.shape, bool)
    doff = np.where(mask[..., None], off[pos] if len(index) else 0.0, 0.0)
    dnrm = np.where(mask[..., None], nrm[pos] if len(index) else 0.0, 0.0)
    # Semi-axes: dual-grid edges between the cell's centre and its neighbours' centres.
    cr = _crossings(V, F, dg, threads)
    nodes = np.repeat(cells[:, None, :] + 1, 6, axis=1)
    axis = np.repeat(np.arange(3), 2)[None].repeat(len(cells), 0)
    nodes[:, 0::2, :] -= np.eye(3, dtype=np.int64)[None]
    edges = _node_ids(dg, axis, nodes)
    semi = _net_signs(dg, cr, edges)
    return dataclasses.replace(tok, dual_offsets=doff, dual_normals=dnrm, dual_mask=mask, semi_axis=semi)
