"""The paper's applications of differentiable voxelization, as functions.

- [`resolve_self_intersections`][voxax.apps.resolve_self_intersections]: deform a mesh as
  rigidly as possible until no part of it overlaps another (section 4.2).
- [`optimize_for_bandsaw`][voxax.apps.optimize_for_bandsaw]: deform a mesh so that
  cutting its three axis silhouettes with a bandsaw wastes less material (section 4.3).
- [`optimize_tiling`][voxax.apps.optimize_tiling]: place and deform copies of one or more
  meshes so that they fill space periodically (section 4.4).
- [`optimize_for_molding`][voxax.apps.optimize_for_molding]: deform a mesh towards a
  shape a two-piece mould parting along an axis can cast (its double height field hull).
- [`optimize_implicit`][voxax.apps.optimize_implicit]: optimize the parameters (a latent
  code) of an implicit field so that its extracted iso-surface casts target silhouettes;
  the surface may change topology on the way (MeshSDF, Fig. 3).

Each takes a voxax `Mesh`, a `trimesh.Trimesh` or a `(vertices, faces)` pair, composes
`voxax.voxelize`, `voxax.energies` and `voxax.minimize` with the paper's defaults,
and returns the result together with a frozen report dataclass (energy history, steps,
stop reason and the application's own numbers; `report.summary()` prints them and
`report.plot_history(path)` plots the history).

For turning a shape into bandsaw templates and an exact cut solid, see `voxax.fabricate`.
"""

from ._bandsaw import BandsawReport, optimize_for_bandsaw
from ._common import Report
from ._implicit import ImplicitReport, optimize_implicit
from ._molding import MoldingReport, optimize_for_molding
from ._self_intersection import SelfIntersectionReport, resolve_self_intersections
from ._tiling import COVERAGE_TOLERANCE, TilingReport, optimize_tiling, rotation_matrices

__all__ = [
    "resolve_self_intersections",
    "optimize_for_bandsaw",
    "optimize_tiling",
    "optimize_implicit",
    "optimize_for_molding",
    "MoldingReport",
    "ImplicitReport",
    "rotation_matrices",
    "Report",
    "SelfIntersectionReport",
    "BandsawReport",
    "TilingReport",
    "COVERAGE_TOLERANCE",
]
