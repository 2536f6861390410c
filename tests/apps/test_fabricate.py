"""Tests for voxax.fabricate: silhouettes, SVG templates and exact cut solids."""

from __future__ import annotations

import json
import math
import xml.etree.ElementTree as ET

import numpy as np
import pytest

import voxax
from voxax import energies, fabricate


def _area(polygons) -> float:
    """Signed area of polygons (outer boundaries counter-clockwise, holes clockwise)."""
    total = 0.0
    for p in polygons:
        x, y = p[:, 0], p[:, 1]
        total += 0.5 * float(np.sum(x * np.roll(y, -1) - np.roll(x, -1) * y))
    return total


@pytest.fixture(scope="module")
def hand():
    return voxax.data.hand()


@pytest.fixture(scope="module")
def hand_cut(hand):
    return fabricate.cut_solid(hand)


# --------------------------------------------------------------------------------------
# Silhouettes
# --------------------------------------------------------------------------------------


def test_box_silhouettes_are_exact_rectangles():
    box = voxax.data.box((0.1, -0.2, -0.3), (0.5, 0.6, 0.4))
    sx, sy, sz = fabricate.silhouette_polygons(box)
    for polys, (w, h) in zip((sx, sy, sz), ((0.8, 0.7), (0.4, 0.7), (0.4, 0.8))):
        assert len(polys) == 1
        assert _area(polys) == pytest.approx(w * h, rel=1e-7)
    # Plane coordinates: along x the plane is (y, z).
    np.testing.assert_allclose(sx[0].min(axis=0), [-0.2, -0.3], atol=1e-7)
    np.testing.assert_allclose(sx[0].max(axis=0), [0.6, 0.4], atol=1e-7)
    assert fabricate.silhouette_polygons(box, axis=2)[0].shape[1] == 2


def test_torus_silhouette_along_z_has_a_hole():
    torus = voxax.data.torus()
    polys = fabricate.silhouette_polygons(torus, axis=2)
    areas = sorted(_area([p]) for p in polys)
    assert len(polys) == 2 and areas[0] < 0 < areas[1]  # a hole (clockwise) in an outer ring
    # The annulus between the outer and inner polygonal circles, from the mesh's own rings.
    r = np.linalg.norm(torus.vertices[:, :2], axis=1)
    n = len(np.unique(np.round(np.arctan2(torus.vertices[:, 1], torus.vertices[:, 0]), 9)))
    ring = 0.5 * n * math.sin(2 * math.pi / n)  # area of a regular n-gon of circumradius 1
    assert _area(polys) == pytest.approx(ring * (r.max() ** 2 - r.min() ** 2), rel=1e-6)


def test_grid_silhouette_of_an_aligned_box():
    # Faces on voxel boundaries: W is 0 or 1, and the 0.5 contour runs along the faces,
    # except that marching squares cuts each corner by a triangle with legs h / 2.
    box = voxax.data.box((-0.5, -0.25, -0.75), (0.25, 0.5, 0.5))
    grid = voxax.Grid.cube(8)
    h = grid.spacing[0]
    W = voxax.voxelize(box.vertices, box.faces, grid)
    for axis in range(3):
        exact = fabricate.silhouette_polygons(box, axis)
        voxel = fabricate.silhouette_polygons(W, axis, grid=grid)
        assert len(voxel) == 1 and len(voxel[0]) == 8  # a rectangle with chamfered corners
        assert _area(voxel) == pytest.approx(_area(exact) - 4 * (h / 2) ** 2 / 2, rel=1e-7)
        np.testing.assert_allclose(np.concatenate(voxel).min(0), np.concatenate(exact).min(0), atol=1e-7)
        np.testing.assert_allclose(np.concatenate(voxel).max(0), np.concatenate(exact).max(0), atol=1e-7)


def test_silhouette_errors():
    box = voxax.data.cube()
    with pytest.raises(ValueError, match="axis"):
        fabricate.silhouette_polygons(box, axis=3)
    with pytest.raises(ValueError, match="shape"):
        fabricate.silhouette_polygons(np.zeros((4, 4, 5)), 0, grid=voxax.Grid.cube(4))
    with pytest.raises(TypeError, match="Grid"):
        fabricate.silhouette_polygons(np.zeros((4, 4, 4)), 0, grid=(4, 4, 4))


# --------------------------------------------------------------------------------------
# Cut solid
# --------------------------------------------------------------------------------------


def test_cut_solid_of_a_box_is_the_box():
    box = voxax.data.box((-0.3, -0.2, -0.1), (0.4, 0.2, 0.3))
    cut = fabricate.cut_solid(box)
    assert voxax.io.is_watertight(cut.vertices, cut.faces, strict=True)
    assert cut.signed_volume() == pytest.approx(box.signed_volume(), rel=1e-7)
    np.testing.assert_allclose(cut.bounds, box.bounds, atol=1e-7)


def test_cut_solid_is_closed_and_contains_the_shape(hand, hand_cut):
    assert voxax.io.is_watertight(hand_cut.vertices, hand_cut.faces, strict=True)
    assert hand_cut.signed_volume() > hand.signed_volume()  # the hand is far from cuttable
    for n in (32, 48):
        grid = voxax.Grid.cube(n)
        W_shape = np.asarray(voxax.voxelize(hand.vertices, hand.faces, grid))
        W_cut = np.asarray(voxax.voxelize(hand_cut.vertices, hand_cut.faces, grid))
        # Containment, voxel by voxel (manifold3d works in ~1e-8 fixed precision).
        assert (W_cut - W_shape).min() >= -1e-6
        assert W_cut.max() <= 1 + 1e-6  # the cut solid does not overlap itself
        # The cut solid is strictly larger somewhere (fingers bent towards -z).
        assert (W_cut - W_shape).max() > 0.5


def test_cut_solid_volume_matches_the_voxel_cut_shape(hand, hand_cut):
    volume = hand_cut.signed_volume()
    area = float(hand_cut.to_trimesh().area)
    errors = []
    for n in (32, 64):
        grid = voxax.Grid.cube(n)
        W = voxax.voxelize(hand.vertices, hand.faces, grid)
        voxel_volume = float(np.sum(energies.cut_shape(W, 1000.0)) * grid.voxel_volume)
        errors.append(abs(voxel_volume - volume))
        # Within the grid's resolution: less than a quarter-voxel layer over the surface.
        assert errors[-1] <= 0.25 * area * grid.spacing[0], (n, voxel_volume, volume)
    print(f"\nhand cut solid volume {volume:.5f}; |voxel cut shape - exact| at 32^3, 64^3: "
          f"{errors[0]:.5f}, {errors[1]:.5f} (surface area x h/4: {0.25 * area * 2 / 64:.5f} at 64^3)")
    assert errors[1] < errors[0]  # and it converges


def test_cut_solid_from_silhouettes_and_from_a_grid(hand, hand_cut):
    sil = fabricate.silhouette_polygons(hand)
    again = fabricate.cut_solid(sil)
    assert again.signed_volume() == pytest.approx(hand_cut.signed_volume(), rel=1e-6)
    grid = voxax.Grid.cube(64)
    W = voxax.voxelize(hand.vertices, hand.faces, grid)
    from_grid = fabricate.cut_solid(W, grid=grid)
    assert voxax.io.is_watertight(from_grid.vertices, from_grid.faces)
    assert from_grid.signed_volume() == pytest.approx(hand_cut.signed_volume(), rel=0.05)


def test_cut_solid_of_an_empty_grid_is_empty():
    grid = voxax.Grid.cube(4)
    empty = fabricate.cut_solid(np.zeros(grid.shape), grid=grid)
    assert empty.n_faces == 0


# --------------------------------------------------------------------------------------
# SVG and templates
# --------------------------------------------------------------------------------------


def test_write_svg_is_to_scale(tmp_path):
    square = np.array([[0.0, 0.0], [2.0, 0.0], [2.0, 1.0], [0.0, 1.0]])
    hole = square[::-1] * 0.25 + [0.5, 0.25]
    path = fabricate.write_svg([square, hole], tmp_path / "t.svg", mm_per_unit=30.0, margin_mm=5.0,
                               title="test & <title>", axis_labels=("y", "z"))
    root = ET.parse(path).getroot()
    ns = "{http://www.w3.org/2000/svg}"
    assert root.get("width").endswith("mm") and root.get("height").endswith("mm")
    width = float(root.get("width")[:-2])
    assert float(root.get("viewBox").split()[2]) == pytest.approx(width)
    rect = root.find(f"{ns}rect")
    assert float(rect.get("width")) == pytest.approx(60.0) and float(rect.get("height")) == pytest.approx(30.0)
    (shape,) = [p for p in root.findall(f"{ns}path") if p.get("fill-rule") == "evenodd"]
    assert shape.get("d").count("M ") == 2
    texts = [t.text for t in root.findall(f"{ns}text")]
    assert "test & <title>" in texts and any(t.endswith(" mm") for t in texts)
    with pytest.raises(ValueError):
        fabricate.write_svg([], tmp_path / "empty.svg")


def test_bandsaw_templates(tmp_path, hand, hand_cut):
    result = fabricate.bandsaw_templates(hand, tmp_path / "out", size_mm=120.0)
    for p in (*result.svg_paths, result.solid_path, result.report_path):
        assert (tmp_path / "out" / p.split("/")[-1]).exists()
    assert result.mm_per_unit * float(np.ptp(hand.vertices, axis=0).max()) == pytest.approx(120.0)
    assert result.volume_shape == pytest.approx(hand.signed_volume())
    assert result.volume_cut == pytest.approx(hand_cut.signed_volume(), rel=1e-7)
    assert result.waste_volume == pytest.approx(result.volume_cut - result.volume_shape)
    assert 0.05 < result.waste_fraction < 0.5
    saved = voxax.io.load(result.solid_path)
    assert saved.signed_volume() == pytest.approx(result.volume_cut, rel=1e-9)
    report = json.loads((tmp_path / "out" / "report.json").read_text())
    assert report["waste_volume"] == pytest.approx(result.waste_volume)
    assert report["views"] == ["+x", "-y", "+z"]
    # A box wastes nothing.
    box = fabricate.bandsaw_templates(voxax.data.box(), tmp_path / "box", prefix="box_")
    assert abs(box.waste_volume) < 1e-6 and box.svg_paths[0].endswith("box_template_x.svg")
