"""Tests for voxax.apps: the paper's three applications, end to end at small resolutions."""

from __future__ import annotations

import dataclasses
import json

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import voxax
from voxax import apps, energies


def _working(mesh, report):
    """The mesh's vertices in the app's working (normalized) frame."""
    return (mesh.vertices - report.centre) * report.scale


# --------------------------------------------------------------------------------------
# Self-intersections
# --------------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def resolved_bent_bar():
    mesh = voxax.data.bent_bar()
    out, report = apps.resolve_self_intersections(mesh, resolution=64, progress=False)
    return mesh, out, report


def test_resolve_removes_every_overlapping_voxel(resolved_bent_bar):
    mesh, out, report = resolved_bent_bar
    grid = voxax.Grid.cube(64)
    # The input really overlaps itself at this resolution ...
    W0 = voxax.voxelize(_working(mesh, report), mesh.faces, grid)
    assert float(W0.max()) > 1.9 and report.overlap_voxels_initial > 100
    # ... and, recomputed independently, no voxel of the result exceeds 1 + 1e-3.
    W1 = np.asarray(voxax.voxelize(_working(out, report), out.faces, grid))
    print(f"\nbent_bar 64^3: {report.steps} steps ({report.stop_reason}), max W {W1.max():.5f}, "
          f"ARAP {report.arap_final:.4f}, max displacement {report.max_displacement:.4f}, "
          f"volume {report.volume_initial:.4f} -> {report.volume_final:.4f}")
    assert W1.max() <= 1 + 1e-3
    assert report.resolved and report.stop_reason == "max_w"
    assert report.overlap_voxels_final == 0
    assert report.max_w_final == pytest.approx(float(W1.max()), abs=1e-9)
    np.testing.assert_array_equal(out.faces, mesh.faces)


def test_resolve_keeps_the_shape(resolved_bent_bar):
    mesh, out, report = resolved_bent_bar
    rest = jnp.asarray(_working(mesh, report))
    # ARAP stays below that of a uniform 25% scaling of the whole mesh ...
    arap_scaled = float(energies.arap(1.25 * rest, rest, mesh.faces))
    arap = float(energies.arap(jnp.asarray(_working(out, report)), rest, mesh.faces))
    assert arap == pytest.approx(report.arap_final, rel=1e-9)
    assert 0 < arap < arap_scaled
    # ... no vertex moves more than 15% of the bounding box diagonal, and the volume
    # changes by less than a quarter.
    diagonal = float(np.linalg.norm(np.ptp(mesh.vertices, axis=0)))
    assert report.max_displacement < 0.15 * diagonal
    assert abs(report.volume_final / report.volume_initial - 1) < 0.25


def test_resolve_accepts_trimesh_and_arrays_and_maps_back():
    mesh = voxax.data.overlapping_cubes()
    kwargs = dict(resolution=16, max_steps=3, refine=False, progress=False)
    a, ra = apps.resolve_self_intersections(mesh, **kwargs)
    b, rb = apps.resolve_self_intersections(mesh.to_trimesh(), **kwargs)
    c, rc = apps.resolve_self_intersections((mesh.vertices, mesh.faces), **kwargs)
    np.testing.assert_allclose(a.vertices, b.vertices, atol=1e-12)
    np.testing.assert_allclose(a.vertices, c.vertices, atol=1e-12)
    assert ra.steps == rb.steps == rc.steps == 3 and ra.stop_reason == "max_steps"
    # The result is in the input's frame: a zero-step run returns the input.
    d, rd = apps.resolve_self_intersections(mesh, resolution=16, max_steps=0, refine=False, progress=False)
    np.testing.assert_allclose(d.vertices, mesh.vertices, atol=1e-12)
    assert rd.steps == 0 and not rd.resolved


def test_resolve_stops_at_once_without_overlaps():
    out, report = apps.resolve_self_intersections(voxax.data.icosphere(2), resolution=24, progress=False)
    assert report.resolved and report.steps <= 1 and report.stop_reason == "max_w"
    assert report.max_displacement < 1e-12


def test_resolve_rejects_bad_arguments():
    with pytest.raises(ValueError, match="resolution"):
        apps.resolve_self_intersections(voxax.data.cube(), resolution=1, progress=False)
    with pytest.raises(ValueError, match="learning_rate"):
        apps.resolve_self_intersections(voxax.data.cube(), learning_rate=-1.0, progress=False)
    with pytest.raises(ValueError, match="3D"):
        apps.resolve_self_intersections(voxax.data.circle_polyline(), progress=False)
    with pytest.warns(RuntimeWarning, match="not closed"):
        m = voxax.data.cube()
        apps.resolve_self_intersections((m.vertices, m.faces[1:]), resolution=8, max_steps=0, progress=False)


# --------------------------------------------------------------------------------------
# Bandsaw
# --------------------------------------------------------------------------------------


def test_bandsaw_hand_improves_by_at_least_20_percent():
    mesh = voxax.data.hand()
    out, report = apps.optimize_for_bandsaw(mesh, resolution=64, progress=False)
    grid = voxax.Grid.cube(64)
    # Recompute the cut energies independently of the report.
    e0 = float(energies.bandsaw_cut(voxax.voxelize(_working(mesh, report), mesh.faces, grid), 1000.0))
    e1 = float(energies.bandsaw_cut(voxax.voxelize(_working(out, report), out.faces, grid), 1000.0))
    improvement = 1 - e1 / e0
    print(f"\nhand 64^3: {report.steps} steps ({report.stop_reason}), relative improvement "
          f"{improvement:.1%}, ARAP {report.arap_final:.4f}, max displacement {report.max_displacement:.4f}, "
          f"waste volume {report.waste_volume_initial:.4f} -> {report.waste_volume_final:.4f}")
    assert report.cut_initial == pytest.approx(e0, rel=1e-9)
    assert report.cut_final == pytest.approx(e1, rel=1e-9)
    assert report.relative_improvement == pytest.approx(improvement, rel=1e-9)
    assert improvement >= 0.20
    assert report.waste_volume_final < report.waste_volume_initial
    assert report.stop_reason in ("min_step", "max_steps")
    # A deformation, not a different shape: vertices move by a few percent of the size.
    assert report.max_displacement < 0.1 * float(np.linalg.norm(np.ptp(mesh.vertices, axis=0)))
    assert report.energy_history.shape == (report.steps,)
    assert report.history["cut"][0] == pytest.approx(e0, rel=1e-9)


def test_bandsaw_report_is_frozen_and_serialisable():
    _, report = apps.optimize_for_bandsaw(voxax.data.icosphere(1), resolution=16, max_steps=2, progress=False)
    with pytest.raises(dataclasses.FrozenInstanceError):
        report.steps = 5
    data = json.loads(json.dumps(report.to_dict()))
    assert data["type"] == "BandsawReport" and data["steps"] == 2
    assert "relative_improvement" in report.summary()
    fig = report.plot_history()
    assert len(fig.axes) >= 3  # energy, step size, cut, arap


# --------------------------------------------------------------------------------------
# Tiling
# --------------------------------------------------------------------------------------


def test_tiling_lowers_the_fill_energy_by_30_percent():
    mesh = voxax.data.icosphere(2)
    placed, report = apps.optimize_tiling(
        mesh, instances=8, resolution=48, max_steps=60, min_step=None, progress=False
    )
    assert len(placed) == 8 and report.instances == 8 and report.steps == 60
    # Recompute the fill energy of the returned instances with one batched voxelization.
    grid = voxax.Grid.cube(48)
    W = voxax.voxelize(jnp.stack([m.vertices for m in placed]), mesh.faces, grid)
    assert W.shape == (8, 48, 48, 48)
    fill = float(energies.tiling(W))
    cell = np.asarray(energies.fold_periodic(W))
    coverage = float(np.mean(np.abs(cell - 1) < 0.5))
    print(f"\n8 icospheres 48^3: fill {report.fill_initial:.1f} -> {fill:.1f} "
          f"({1 - fill / report.fill_initial:.1%} lower), covered once {report.coverage_initial:.1%} -> "
          f"{coverage:.1%}, ARAP {report.arap_final:.3f}")
    assert fill == pytest.approx(report.fill_final, rel=1e-9)
    assert coverage == pytest.approx(report.coverage_final)
    np.testing.assert_allclose(cell, report.cell, atol=1e-12)
    assert 1 - fill / report.fill_initial >= 0.30
    assert report.coverage_final > report.coverage_initial
    # Each instance is placed by its reported rotation and translation (of its offsets' shape).
    assert report.rotations.shape == (8, 3, 3) and report.translations.shape == (8, 3)
    for R in report.rotations:
        np.testing.assert_allclose(R @ R.T, np.eye(3), atol=1e-12)
        assert np.linalg.det(R) == pytest.approx(1.0)


def test_rigid_tiling_moves_instances_rigidly():
    mesh = voxax.data.box((-0.5, -0.3, -0.2), (0.5, 0.3, 0.2))
    placed, report = apps.optimize_tiling(
        mesh, instances=2, resolution=24, max_steps=5, deform=False, init="lattice", progress=False
    )
    rest = mesh.vertices - mesh.vertices.mean(axis=0)
    rest = rest * report.scales[0]
    for m, R, t in zip(placed, report.rotations, report.translations):
        np.testing.assert_allclose(m.vertices, rest @ R.T + t, atol=1e-12)
    # fill_volume: the instances' volumes add up to the cell's, (2/3)^3.
    assert sum(m.signed_volume() for m in placed) == pytest.approx((2 / 3) ** 3)


def test_tiling_of_several_meshes_pads_them():
    a, b = voxax.data.icosphere(1), voxax.data.cube()
    placed, report = apps.optimize_tiling([a, b], instances=(2, 1), resolution=24, max_steps=2, progress=False)
    assert [m.n_vertices for m in placed] == [a.n_vertices, a.n_vertices, b.n_vertices]
    np.testing.assert_array_equal(report.mesh_index, [0, 0, 1])
    np.testing.assert_array_equal(placed[2].faces, b.faces)
    # The report's cell is the fold of the three instances' voxelizations.
    grid = voxax.Grid.cube(24)
    W = sum(voxax.voxelize(m.vertices, m.faces, grid) for m in placed)
    np.testing.assert_allclose(np.asarray(energies.fold_periodic(W)), report.cell, atol=1e-12)
    # A (vertices, faces) pair is one mesh, not two.
    _, r1 = apps.optimize_tiling((b.vertices, b.faces), instances=2, resolution=12, max_steps=1, progress=False)
    assert r1.instances == 2 and list(r1.mesh_index) == [0, 0]


def test_tiling_rejects_bad_arguments():
    m = voxax.data.cube()
    with pytest.raises(ValueError, match="multiple of 3"):
        apps.optimize_tiling(m, resolution=50, progress=False)
    with pytest.raises(ValueError, match="init"):
        apps.optimize_tiling(m, resolution=12, init="grid", progress=False)
    with pytest.raises(ValueError, match="counts"):
        apps.optimize_tiling([m, m], instances=(1, 2, 3), resolution=12, progress=False)
    with pytest.raises(ValueError, match="translations"):
        apps.optimize_tiling(m, instances=2, resolution=12, translations=np.zeros((3, 3)), progress=False)


def test_rotation_matrices():
    angles = jnp.array([[0.3, 0.0, 0.0], [0.2, -0.4, 1.1]])
    R = np.asarray(apps.rotation_matrices(angles))
    c, s = np.cos(0.3), np.sin(0.3)
    np.testing.assert_allclose(R[0], [[c, -s, 0], [s, c, 0], [0, 0, 1]], atol=1e-15)  # yaw about z
    np.testing.assert_allclose(R[1] @ R[1].T, np.eye(3), atol=1e-14)
    # Derivatives flow through the angles.
    g = jax.grad(lambda a: apps.rotation_matrices(a)[0, 1])(jnp.array([0.3, 0.0, 0.0]))
    np.testing.assert_allclose(g, [-c, 0, 0], atol=1e-14)


@pytest.mark.parametrize("app", ["resolve_self_intersections", "optimize_for_bandsaw", "optimize_for_molding"])
def test_apps_refuse_an_inside_out_mesh_and_take_every_surface_form(app):
    ball = voxax.data.icosphere(1, radius=0.5)
    with pytest.raises(ValueError, match="inside out"):
        getattr(voxax.apps, app)(voxax.Mesh(ball.vertices, ball.faces[:, ::-1]), resolution=8)
    # vertices and faces as two arguments reach the same check
    with pytest.raises(ValueError, match="inside out"):
        getattr(voxax.apps, app)(ball.vertices, ball.faces[:, ::-1], resolution=8)
