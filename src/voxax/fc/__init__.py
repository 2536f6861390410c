"""Faithful Contouring: a triangle mesh as sparse surface tokens on a grid, and back.

[`encode`][voxax.fc.encode] clips every triangle into the cells it meets (exactly, with
the voxelizer's clipping), and gives every active cell a *token*: an anchor point solved
from a quadratic error function (QEF) over the cell's pieces, a normal, and the signs of
the surface's net crossings of the cell's 12 edges. [`decode`][voxax.fc.decode] turns
tokens back into a triangle mesh by dual contouring: one vertex per token, one quad per
crossed lattice edge. No signed distance field, no watertight repair: open, non-manifold
and hollow surfaces keep their topology, and sharp edges and corners are kept by the QEF.

The anchor of a cell minimizes, in cell-local coordinates `u = (x - centre) / h`,

    sum_i w_i [lambda_n (n_i . (u - c_i))^2 + lambda_d |u - c_i|^2],   w_i = A_i^p / sum A^p

over the cell's pieces `i` (area `A_i`, area centroid `c_i`, the triangle's normal `n_i`,
normals taken in local coordinates). When the minimizer leaves the cell, it is clamped to
the cell and moved to the closest point of the cell's own pieces. Beyond the paper: open
boundaries of the mesh add their lines to the QEF (`open_boundaries=True`), so open sheets
keep their extent; by default (`anchors_per_cell="patches"`) a cell that several separate
surface patches cross (decided from its edge signs alone, as marching cubes joins them) gets
one anchor per patch, so closed meshes decode to closed 2-manifolds where one vertex per cell
would glue the sheets of a thin part together; with `anchors_per_cell="components"` every connected component of a
cell's pieces (faces joined by a mesh edge through the cell) gets its own anchor, so nearby
sheets are no longer merged into one vertex; and the decoder joins anchors that no quad uses (sharp tips
thinner than a cell) to the surface.

Edge signs are the net flux of the surface through each lattice edge: the sum over the
crossings of the edge (exact, from `voxax.raster.line_crossings` through the grid nodes)
of +1 where the surface normal points along the edge's axis and -1 where it points against
it (int8, clipped to [-127, 127]; the decoder uses its sign). For a closed mesh it is the
winding number at the edge's lower end minus the one at its upper end. Nodes on the
surface are decided exactly as if every node were moved to `p + (e_x, e_y, e_z)` with
`e_x >> e_y >> e_z > 0` (the perturbation that the lines' tie rule applies), the same for
all three axes, so meshes through grid nodes still decode closed.

Edge order in a token: edges 0-3 run along x through the cell's corners at (y, z) offsets
(0, 0), (1, 0), (1, 1), (0, 1); edges 4-7 along y at (x, z) offsets in the same order;
edges 8-11 along z at (x, y) offsets in the same order.

>>> import voxax
>>> tok = voxax.fc.encode(voxax.data.cube(1.2), voxax.Grid.cube(16))
>>> mesh = voxax.fc.decode(tok)
>>> voxax.metrics.euler_characteristic(mesh)
2
"""

from ._decode import decode
from ._encode import Pieces, encode, pieces
from ._lattice import dual_grid as dual_grid
from ._roundtrip import EdgeTopology, RoundtripReport, edge_topology, roundtrip
from ._tokens import EDGE_AXIS as EDGE_AXIS
from ._tokens import EDGE_OFFSETS, Tokens, merge, select
from ._tokens import FORMATS as FORMATS

__all__ = [
    "EDGE_OFFSETS",
    "EdgeTopology",
    "Pieces",
    "RoundtripReport",
    "Tokens",
    "decode",
    "edge_topology",
    "encode",
    "merge",
    "pieces",
    "roundtrip",
    "select",
]
