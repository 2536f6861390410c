"""Bandsaw fabrication: silhouettes, printable SVG templates and exact cut solids.

A bandsaw (or a hot-wire foam cutter) cutting a block along three orthogonal directions
can only produce *cut shapes*: the intersection of three silhouettes, each extruded along
its axis (paper section 4.3, Fig. 8). This module turns a mesh into that recipe:

- [`silhouette_polygons`][voxax.fabricate.silhouette_polygons]: the silhouettes along x, y
  and z as polygons. From a mesh they are exact (the union of the projected triangles,
  computed with manifold3d's `CrossSection`); from a voxel grid they are the 0.5 contour of
  the grid's maximum along the axis (marching squares via contourpy).
- [`write_svg`][voxax.fabricate.write_svg]: a printable template in millimetres with the
  block outline and a scale bar.
- [`cut_solid`][voxax.fabricate.cut_solid]: the exact cut shape as a mesh (extrude each
  silhouette through the bounding box, intersect the three with manifold3d).
- [`bandsaw_templates`][voxax.fabricate.bandsaw_templates]: all of the above written to a
  folder, with the waste volume `volume(cut solid) - volume(shape)`.

**Plane coordinates.** The silhouette along axis `a` lives in the plane of the two other
axes in increasing order (`PLANE_AXES`): along x the plane is (y, z), along y it is
(x, z), along z it is (x, y) -- the same order as `voxax.energies.silhouettes`. Drawn with
the first plane axis to the right and the second up, the x template is the view from +x,
the y template the view from -y and the z template the view from +z (`VIEWS`): glue each
template on that face of the block.

>>> from voxax import data, fabricate
>>> polys = fabricate.silhouette_polygons(data.box((0, 0, 0), (1, 2, 3)), axis=0)
>>> len(polys), sorted(map(tuple, polys[0].round(6).tolist()))
(1, [(0.0, 0.0), (0.0, 3.0), (2.0, 0.0), (2.0, 3.0)])
"""

from __future__ import annotations

import dataclasses
import json
import math
import os
from collections.abc import Sequence
from typing import Any
from xml.sax.saxutils import escape

import numpy as np

from . import _validate
from ._grid import Grid
from ._mesh import Mesh, from_manifold
from ._values import ValueEquality

__all__ = [
    "PLANE_AXES",
    "VIEWS",
    "silhouette_polygons",
    "write_svg",
    "cut_solid",
    "bandsaw_templates",
    "BandsawTemplates",
]

#: The plane axes of the silhouette along each axis: `PLANE_AXES[axis] = (right, up)`.
PLANE_AXES = {0: (1, 2), 1: (0, 2), 2: (0, 1)}
#: The side each template is seen from, with `PLANE_AXES[axis]` to the right and up.
VIEWS = {0: "+x", 1: "-y", 2: "+z"}
_NAMES = "xyz"


# --------------------------------------------------------------------------------------
# Silhouettes
# --------------------------------------------------------------------------------------


def _check_axis(axis, where: str) -> int:
    if isinstance(axis, bool) or not isinstance(axis, (int, np.integer)) or int(axis) not in (0, 1, 2):
        raise ValueError(f"{where}: `axis` must be 0, 1 or 2 (x, y, z), got {axis!r}")
    return int(axis)


def _is_grid_input(shape, grid, where: str) -> bool:
    if grid is None:
        return False
    _validate.grid(where, grid, dim=3)
    return True


def _as_grid_values(W, grid: Grid, where: str) -> np.ndarray:
    if isinstance(W, Mesh) or hasattr(W, "faces"):
        raise TypeError(f"{where}: `grid` goes with a voxel grid W (nx, ny, nz); pass a mesh without `grid`")
    W = np.asarray(_validate.typed_array(where, "shape", W, "fiub", "a mesh or a real grid W"), np.float64)
    if W.shape != grid.shape:
        raise ValueError(f"{where}: `shape` (a grid W) must have the grid's shape {grid.shape}, got {W.shape}")
    if not np.all(np.isfinite(W)):
        raise ValueError(f"{where}: `shape` (a grid W) must be finite (it contains NaN or Inf)")
    return W


def _mesh_arrays(mesh, where: str) -> tuple[np.ndarray, np.ndarray]:
    vertices, faces = _validate.mesh_like(where, mesh)
    vertices, faces = _validate.mesh(where, vertices, faces, dim=3, context="a 3D triangle mesh")
    return np.asarray(vertices, dtype=np.float64), np.asarray(faces)


def _mesh_cross_section(vertices: np.ndarray, faces: np.ndarray, axis: int):
    """The exact silhouette: union of the triangles projected along `axis`."""
    from manifold3d import CrossSection, FillRule

    p, q = PLANE_AXES[axis]
    tri = vertices[faces][:, :, [p, q]]  # (F, 3, 2)
    e1, e2 = tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]
    area2 = e1[:, 0] * e2[:, 1] - e1[:, 1] * e2[:, 0]
    extent = float(np.ptp(vertices[:, [p, q]], axis=0).max()) or 1.0
    keep = np.abs(area2) > 1e-14 * extent * extent  # edge-on triangles add no area
    tri = tri[keep]
    flip = area2[keep] < 0
    tri[flip] = tri[flip][:, ::-1]  # every triangle counter-clockwise
    if len(tri) == 0:
        return CrossSection()
    return CrossSection([np.ascontiguousarray(t) for t in tri], FillRule.Positive)


def _grid_cross_section(W: np.ndarray, grid: Grid, axis: int, threshold: float):
    """The silhouette of a voxel grid: the `threshold` contour of `max over axis of W`."""
    import contourpy
    from manifold3d import CrossSection, FillRule

    p, q = PLANE_AXES[axis]
    S = W.max(axis=axis)  # (n_p, n_q)
    S = np.pad(S, 1, constant_values=min(0.0, float(S.min())))  # close contours at the border
    cp, cq = _centres_1d(grid, p), _centres_1d(grid, q)
    hp, hq = grid.spacing[p], grid.spacing[q]
    cp = np.concatenate([[cp[0] - hp], cp, [cp[-1] + hp]])
    cq = np.concatenate([[cq[0] - hq], cq, [cq[-1] + hq]])
    gen = contourpy.contour_generator(cp, cq, S.T, line_type=contourpy.LineType.Separate)
    loops = []
    for line in gen.lines(float(threshold)):
        line = np.asarray(line, dtype=np.float64)
        if len(line) > 1 and np.array_equal(line[0], line[-1]):
            line = line[:-1]
        if len(line) >= 3:
            loops.append(np.ascontiguousarray(line))
    if not loops:
        return CrossSection()
    # Drop the collinear points marching squares leaves along straight runs.
    return CrossSection(loops, FillRule.EvenOdd).simplify(1e-6 * min(hp, hq))


def _centres_1d(grid: Grid, axis: int) -> np.ndarray:
    e = grid.edges(axis)
    return (e[:-1] + e[1:]) / 2.0


def _polygons_cross_section(polygons, where: str = "voxax.fabricate.cut_solid"):
    from manifold3d import CrossSection, FillRule

    if hasattr(polygons, "to_polygons"):  # already a CrossSection
        return polygons
    loops = []
    for poly in polygons:
        poly = np.asarray(poly, dtype=np.float64)
        if poly.ndim != 2 or poly.shape[1] != 2:
            raise ValueError(f"{where}: each polygon must be an (n, 2) array, got shape {poly.shape}")
        if not np.all(np.isfinite(poly)):
            raise ValueError(f"{where}: the polygons must be finite (they contain NaN or Inf)")
        if len(poly) >= 3:
            loops.append(np.ascontiguousarray(poly))
    return CrossSection(loops, FillRule.EvenOdd) if loops else CrossSection()


def _cross_sections(shape, axes, grid, threshold, where):
    if _is_grid_input(shape, grid, where):
        W = _as_grid_values(shape, grid, where)
        threshold = _validate.finite_number(where, "threshold", threshold)
        return [_grid_cross_section(W, grid, a, threshold) for a in axes]
    vertices, faces = _mesh_arrays(shape, where)
    return [_mesh_cross_section(vertices, faces, a) for a in axes]


def silhouette_polygons(shape: Any, axis: int | None = None, *, grid: Grid | None = None, threshold: float = 0.5):
    """The silhouette(s) of a shape along the coordinate axes, as polygons.

    From a mesh the silhouette is exact: the union of all triangles projected along the
    axis (manifold3d `CrossSection`, which works in fixed precision of about 1e-8 of the
    coordinates). From a voxel grid `W` (with `grid`) it is the `threshold` contour of
    `W.max(axis)`, the hard-max silhouette of the voxelized shape, found by marching
    squares (contourpy) with linear interpolation between voxel centres.

    **Arguments:**

    - `shape`: a closed triangle mesh (voxax `Mesh`, `trimesh.Trimesh`,
      `(vertices (V, 3), faces (F, 3))`), or a grid `W (nx, ny, nz)` together with `grid`.
    - `axis`: 0, 1 or 2 for the silhouette along x, y or z; `None` for all three.
    - `grid`: the `voxax.Grid` of `W` (only for grid input).
    - `threshold`: the contour level for grid input.

    **Returns:** for one axis, a list of `(n, 2)` float64 polygons in the plane coordinates
    `PLANE_AXES[axis]` (outer boundaries counter-clockwise, holes clockwise); for
    `axis=None`, a tuple of three such lists (along x, y, z).
    """
    axes = (0, 1, 2) if axis is None else (_check_axis(axis, "voxax.fabricate.silhouette_polygons"),)
    sections = _cross_sections(shape, axes, grid, threshold, "voxax.fabricate.silhouette_polygons")
    polys = [[np.asarray(p, dtype=np.float64) for p in cs.to_polygons()] for cs in sections]
    return tuple(polys) if axis is None else polys[0]


# --------------------------------------------------------------------------------------
# Cut solid
# --------------------------------------------------------------------------------------


def _polygon_bounds(sections) -> np.ndarray:
    """Bounding box (2, 3) of the shape implied by three silhouettes."""
    lo = np.full(3, np.inf)
    hi = np.full(3, -np.inf)
    for a, cs in enumerate(sections):
        if cs.is_empty():
            continue
        b = np.asarray(cs.bounds(), dtype=np.float64).reshape(-1)  # (min u, min v, max u, max v)
        for k, ax in enumerate(PLANE_AXES[a]):
            lo[ax] = min(lo[ax], b[k])
            hi[ax] = max(hi[ax], b[k + 2])
    return np.stack([lo, hi])


def _extrude(cs, axis: int, lo: float, hi: float):
    """Extrudes a cross-section in the plane `PLANE_AXES[axis]` along `axis` over [lo, hi]."""
    p, q = PLANE_AXES[axis]
    solid = cs.extrude(hi - lo).translate((0.0, 0.0, lo))
    m = np.zeros((3, 4))
    m[p, 0] = m[q, 1] = m[axis, 2] = 1.0  # local (x, y, z) -> world (p, q, axis)
    solid = solid.transform(m)
    if solid.volume() < 0:  # pragma: no cover - manifold3d keeps orientation under mirroring
        raise RuntimeError("cut_solid: extrusion came out inverted")
    return solid


def cut_solid(shape: Any, *, grid: Grid | None = None, threshold: float = 0.5, bounds=None) -> Mesh:
    """The shape a bandsaw leaves when cutting a block along the three silhouettes.

    Each silhouette is extruded along its axis through the bounding box and the three
    prisms are intersected (manifold3d), giving a closed, outward-oriented, watertight
    mesh of the cut shape. It contains the input shape (exactly, up to manifold3d's
    ~1e-8 fixed precision, for mesh input) and its volume minus the shape's is the waste
    that the cuts cannot remove.

    **Arguments:**

    - `shape`: a closed triangle mesh (exact silhouettes); a grid `W (nx, ny, nz)` with
      `grid` (contour silhouettes, see `silhouette_polygons`); or the three silhouettes
      as a sequence of three lists of `(n, 2)` polygons in the plane coordinates
      `PLANE_AXES[axis]` (even-odd rule, any orientation), as returned by
      `silhouette_polygons(mesh)`.
    - `grid`: the `voxax.Grid` of `W` (only for grid input).
    - `threshold`: the contour level for grid input.
    - `bounds`: optional `(2, 3)` box `[lower, upper]` to extrude through (default: the
      bounding box of the silhouettes, slightly enlarged).

    **Returns:** the cut solid as a `Mesh` (empty if a silhouette is empty).
    """
    from manifold3d import Manifold, OpType

    if (
        grid is None
        and isinstance(shape, (list, tuple))
        and len(shape) == 3
        and not isinstance(shape, Mesh)
    ):
        sections = [_polygons_cross_section(s) for s in shape]
    else:
        sections = _cross_sections(shape, (0, 1, 2), grid, threshold, "voxax.fabricate.cut_solid")
    if any(cs.is_empty() for cs in sections):
        return Mesh(np.zeros((0, 3)), np.zeros((0, 3), dtype=np.int32))
    box = _polygon_bounds(sections) if bounds is None else np.asarray(bounds, dtype=np.float64).reshape(2, 3)
    pad = 0.01 * float(np.max(box[1] - box[0])) + 1e-9
    prisms = [_extrude(cs, a, box[0, a] - pad, box[1, a] + pad) for a, cs in enumerate(sections)]
    solid = Manifold.batch_boolean(prisms, OpType.Intersect)
    if solid.is_empty():
        return Mesh(np.zeros((0, 3)), np.zeros((0, 3), dtype=np.int32))
    vertices, faces = from_manifold(solid)
    return Mesh(vertices, faces)


# --------------------------------------------------------------------------------------
# SVG templates
# --------------------------------------------------------------------------------------


def _nice_length(limit: float) -> float:
    """The largest 1, 2 or 5 times a power of ten that is at most `limit` (> 0)."""
    if not limit > 0:
        return 1.0
    e = math.floor(math.log10(limit))
    for m in (5.0, 2.0, 1.0):
        if m * 10**e <= limit:
            return m * 10**e
    return 10 ** (e - 1) * 5.0


def _fmt(x: float) -> str:
    return f"{x:.4f}".rstrip("0").rstrip(".")


def write_svg(
    polygons: Sequence[Any],
    path: str | os.PathLike,
    *,
    mm_per_unit: float | None = None,
    size_mm: float = 100.0,
    margin_mm: float = 10.0,
    frame=None,
    title: str | None = None,
    axis_labels: tuple[str, str] = ("u", "v"),
    scale_bar_mm: float | None = None,
    stroke_mm: float = 0.3,
) -> str:
    """Writes polygons as a printable SVG template in millimetres.

    The drawing is to scale: the SVG's `width`/`height` are in `mm`, so printing at 100%
    gives `mm_per_unit` millimetres per model unit. A scale bar (and its length in mm)
    lets you check the printout. The first plane coordinate points right and the second
    up. Polygons are filled with the even-odd rule, so holes show.

    **Arguments:**

    - `polygons`: a list of `(n, 2)` polygons in model units (e.g. one silhouette from
      `silhouette_polygons`).
    - `path`: the `.svg` file to write.
    - `mm_per_unit`: the print scale; by default chosen so that the larger side of `frame`
      is `size_mm` long.
    - `size_mm`: see `mm_per_unit`.
    - `margin_mm`: blank margin around the frame.
    - `frame`: `(umin, vmin, umax, vmax)` rectangle drawn dashed around the template, e.g.
      the block face (default: the polygons' bounding box).
    - `title`: text written above the scale bar.
    - `axis_labels`: names of the two plane axes, written at the axis arrows.
    - `scale_bar_mm`: scale bar length (default: a round length about a third of the width).
    - `stroke_mm`: outline width.

    **Returns:** `path` as a string.
    """
    where = "voxax.fabricate.write_svg"
    polys = []
    for p in polygons:
        p = np.asarray(_validate.typed_array(where, "polygons", p, "fiu", "real (n, 2) arrays"), np.float64)
        if p.ndim != 2 or p.shape[1] != 2:
            raise ValueError(f"{where}: `polygons` must be (n, 2) arrays, got shape {p.shape}")
        if not np.all(np.isfinite(p)):
            raise ValueError(f"{where}: `polygons` must be finite (they contain NaN or Inf)")
        polys.append(p)
    margin_mm = _validate.positive_float(where, "margin_mm", margin_mm, allow_zero=True)
    stroke_mm = _validate.positive_float(where, "stroke_mm", stroke_mm)
    if scale_bar_mm is not None:
        scale_bar_mm = _validate.positive_float(where, "scale_bar_mm", scale_bar_mm)
    polys = [p for p in polys if len(p) >= 3]
    if frame is None:
        if not polys:
            raise ValueError(f"{where}: `polygons` must hold a polygon of 3 points or more when no `frame` is given")
        pts = np.concatenate(polys)
        frame = (*pts.min(axis=0), *pts.max(axis=0))
    if np.shape(frame) != (4,):
        raise ValueError(f"{where}: `frame` must be (umin, vmin, umax, vmax), got {frame!r}")
    umin, vmin, umax, vmax = (_validate.finite_number(where, "frame", x) for x in frame)
    if not (umax > umin and vmax > vmin):
        raise ValueError(f"{where}: `frame` must have positive width and height, got {frame}")
    if mm_per_unit is None:
        size_mm = _validate.positive_float(where, "size_mm", size_mm)
        mm_per_unit = float(size_mm) / max(umax - umin, vmax - vmin)
    mm_per_unit = _validate.positive_float(where, "mm_per_unit", mm_per_unit)
    margin = float(margin_mm)
    fw, fh = (umax - umin) * mm_per_unit, (vmax - vmin) * mm_per_unit
    bar = float(scale_bar_mm) if scale_bar_mm is not None else _nice_length(max(fw / 3.0, 1.0))
    footer = 16.0
    text_width = 2.0 * len(title or "")  # ~ width of 3.5 mm sans-serif text
    width = max(fw, text_width, bar + 20.0) + 2 * margin
    height = fh + 2 * margin + footer

    def xy(p):
        return margin + (p[:, 0] - umin) * mm_per_unit, margin + (vmax - p[:, 1]) * mm_per_unit

    parts = []
    for p in polys:
        x, y = xy(p)
        parts.append("M " + " L ".join(f"{_fmt(a)} {_fmt(b)}" for a, b in zip(x, y)) + " Z")
    base = margin + fh + margin * 0.5 + 4.0
    s = stroke_mm
    out = [
        '<?xml version="1.0" encoding="UTF-8"?>',
        f'<svg xmlns="http://www.w3.org/2000/svg" width="{_fmt(width)}mm" height="{_fmt(height)}mm" '
        f'viewBox="0 0 {_fmt(width)} {_fmt(height)}">',
        f"<desc>voxax bandsaw template; 1 model unit = {_fmt(mm_per_unit)} mm; print at 100% scale</desc>",
        f'<rect x="{_fmt(margin)}" y="{_fmt(margin)}" width="{_fmt(fw)}" height="{_fmt(fh)}" fill="none" '
        f'stroke="#888" stroke-width="{_fmt(s / 2)}" stroke-dasharray="2 1"/>',
    ]
    if parts:
        out.append(
            f'<path d="{" ".join(parts)}" fill="#d9d9d9" fill-rule="evenodd" stroke="#000" '
            f'stroke-width="{_fmt(s)}" stroke-linejoin="round"/>'
        )
    # Axis arrows at the frame's lower-left corner.
    x0, y0 = margin, margin + fh
    out += [
        f'<path d="M {_fmt(x0)} {_fmt(y0)} h 8 m -1.5 -1 l 1.5 1 l -1.5 1 M {_fmt(x0)} {_fmt(y0)} v -8 '
        f'm -1 1.5 l 1 -1.5 l 1 1.5" fill="none" stroke="#c00" stroke-width="{_fmt(s)}"/>',
        f'<text x="{_fmt(x0 + 9)}" y="{_fmt(y0 + 1)}" font-family="sans-serif" font-size="3" fill="#c00">'
        f"{escape(axis_labels[0])}</text>",
        f'<text x="{_fmt(x0 - 1)}" y="{_fmt(y0 - 9)}" font-family="sans-serif" font-size="3" fill="#c00">'
        f"{escape(axis_labels[1])}</text>",
        # Scale bar with end ticks.
        f'<path d="M {_fmt(margin)} {_fmt(base)} h {_fmt(bar)} M {_fmt(margin)} {_fmt(base - 1.5)} v 3 '
        f'M {_fmt(margin + bar)} {_fmt(base - 1.5)} v 3" stroke="#000" stroke-width="{_fmt(s)}" fill="none"/>',
        f'<text x="{_fmt(margin + bar + 2)}" y="{_fmt(base + 1)}" font-family="sans-serif" font-size="3">'
        f"{_fmt(bar)} mm</text>",
    ]
    if title:
        out.append(
            f'<text x="{_fmt(margin)}" y="{_fmt(base + 7)}" font-family="sans-serif" font-size="3.5">'
            f"{escape(title)}</text>"
        )
    out.append("</svg>")
    path = os.fspath(path)
    with open(path, "w", encoding="utf-8") as fh_:
        fh_.write("\n".join(out) + "\n")
    return path


# --------------------------------------------------------------------------------------
# Everything at once
# --------------------------------------------------------------------------------------


@dataclasses.dataclass(frozen=True, eq=False)
class BandsawTemplates(ValueEquality):
    """What [`bandsaw_templates`][voxax.fabricate.bandsaw_templates] produced.

    - `silhouettes`: the three silhouettes (along x, y, z), each a list of `(n, 2)`
      polygons in the plane coordinates `PLANE_AXES[axis]`, model units.
    - `svg_paths`: the three template files (along x, y, z).
    - `solid_path`: the cut solid mesh file; `report_path`: a JSON summary.
    - `cut_solid`: the cut solid as a `Mesh`.
    - `bounds`: `(2, 3)` the shape's bounding box (the block to cut from).
    - `volume_shape`, `volume_cut`: the shape's and the cut solid's volumes.
    - `waste_volume`: `volume_cut - volume_shape`, material the three cuts leave on.
    - `waste_fraction`: `waste_volume / volume_cut`.
    - `mm_per_unit`: the templates' print scale.
    """

    silhouettes: tuple
    svg_paths: tuple
    solid_path: str
    report_path: str
    cut_solid: Mesh
    bounds: np.ndarray
    volume_shape: float
    volume_cut: float
    waste_volume: float
    waste_fraction: float
    mm_per_unit: float


@_validate.surface_first
def bandsaw_templates(
    mesh: Any,
    out_dir: str | os.PathLike,
    *,
    size_mm: float = 100.0,
    mm_per_unit: float | None = None,
    margin_mm: float = 10.0,
    prefix: str = "",
    solid_format: str = "ply",
) -> BandsawTemplates:
    """Writes the three bandsaw templates (SVG), the exact cut solid and a report.

    Files written to `out_dir` (created if needed): `{prefix}template_x.svg`,
    `{prefix}template_y.svg`, `{prefix}template_z.svg` (silhouettes to scale, each inside
    the outline of the block face it is glued on, see `VIEWS`), `{prefix}cut_solid.ply`
    (the cut shape in the mesh's units, see `cut_solid`) and `{prefix}report.json`.

    **Arguments:**

    - `mesh`: a closed triangle mesh (voxax `Mesh`, `trimesh.Trimesh`, `(vertices, faces)`).
    - `out_dir`: the output folder.
    - `size_mm`: the block's largest side on paper (sets `mm_per_unit` unless given).
    - `mm_per_unit`: the print scale in millimetres per model unit.
    - `margin_mm`: margin around each template.
    - `prefix`: prefix of every file name.
    - `solid_format`: file extension of the cut solid (`ply`, `stl`, `obj`, ...).

    **Returns:** a [`BandsawTemplates`][voxax.fabricate.BandsawTemplates] with the paths,
    the cut solid and the waste volume `volume(cut solid) - volume(shape)`.
    """
    from .io import save

    vertices, faces = _mesh_arrays(mesh, "voxax.fabricate.bandsaw_templates")
    shape = Mesh(vertices, faces)
    os.makedirs(out_dir, exist_ok=True)
    bounds = shape.bounds
    extent = bounds[1] - bounds[0]
    where = "voxax.fabricate.bandsaw_templates"
    if mm_per_unit is None:
        size_mm = _validate.positive_float(where, "size_mm", size_mm)
        mm_per_unit = float(size_mm) / float(extent.max())
    mm_per_unit = _validate.positive_float(where, "mm_per_unit", mm_per_unit)
    _validate.positive_float(where, "margin_mm", margin_mm, allow_zero=True)
    sections = [_mesh_cross_section(vertices, faces, a) for a in range(3)]
    silhouettes = tuple([np.asarray(p, dtype=np.float64) for p in cs.to_polygons()] for cs in sections)
    svg_paths = []
    for a in range(3):
        p, q = PLANE_AXES[a]
        path = os.path.join(os.fspath(out_dir), f"{prefix}template_{_NAMES[a]}.svg")
        write_svg(
            silhouettes[a],
            path,
            mm_per_unit=mm_per_unit,
            margin_mm=margin_mm,
            frame=(bounds[0, p], bounds[0, q], bounds[1, p], bounds[1, q]),
            title=(
                f"cut along {_NAMES[a]}: view from {VIEWS[a]}, block "
                f"{extent[p] * mm_per_unit:.1f} x {extent[q] * mm_per_unit:.1f} mm"
            ),
            axis_labels=(_NAMES[p], _NAMES[q]),
        )
        svg_paths.append(path)
    solid = cut_solid(silhouettes, bounds=bounds)
    solid_path = os.path.join(os.fspath(out_dir), f"{prefix}cut_solid.{solid_format.lstrip('.')}")
    save(solid, solid_path)
    volume_shape = shape.signed_volume()
    volume_cut = solid.signed_volume()
    waste = volume_cut - volume_shape
    result = BandsawTemplates(
        silhouettes=silhouettes,
        svg_paths=tuple(svg_paths),
        solid_path=solid_path,
        report_path=os.path.join(os.fspath(out_dir), f"{prefix}report.json"),
        cut_solid=solid,
        bounds=bounds,
        volume_shape=volume_shape,
        volume_cut=volume_cut,
        waste_volume=waste,
        waste_fraction=waste / volume_cut if volume_cut > 0 else 0.0,
        mm_per_unit=float(mm_per_unit),
    )
    with open(result.report_path, "w", encoding="utf-8") as fh:
        json.dump(
            {
                "svg": [os.path.basename(p) for p in svg_paths],
                "views": [VIEWS[a] for a in range(3)],
                "cut_solid": os.path.basename(solid_path),
                "bounds": bounds.tolist(),
                "mm_per_unit": result.mm_per_unit,
                "block_mm": (extent * result.mm_per_unit).tolist(),
                "volume_shape": volume_shape,
                "volume_cut": volume_cut,
                "waste_volume": waste,
                "waste_fraction": result.waste_fraction,
            },
            fh,
            indent=2,
        )
    return result
