"""`resolve_self_intersections` finishes: exact verification, local refinement, volume.

Small cases only (a 32^3 working grid); `benchmarks/resolve.py` runs the full set (bent
bar, overlapping letters, torus knot, three deformed hands) at higher resolutions.
"""

from __future__ import annotations

import numpy as np
import pytest
from _resolve_cases import deformed_hand, overlapping_letters, torus_knot_tube

import voxax
import voxax.apps as apps

RES = 32


def _beyond_the_grid(out, report, resolution):
    """The largest voxel value on grids at 1x, 2x, 4x the working resolution and on the
    working grid shifted by half a voxel (working frame)."""
    work = (out.vertices - report.centre) * report.scale
    h = 2.0 / resolution
    grids = [
        voxax.Grid.cube(resolution),
        voxax.Grid.cube(2 * resolution),
        voxax.Grid.cube(4 * resolution),
        voxax.Grid(lower=(-1 + h / 2,) * 3, upper=(1 + h / 2,) * 3, shape=(resolution,) * 3),
    ]
    return [float(np.max(voxax.voxelize(work, out.faces, g))) for g in grids]


def _small_bar():
    return voxax.data.bent_bar(n_along=60, n_around=12)


@pytest.fixture(scope="module")
def bent_bar_resolved():
    mesh = _small_bar()
    out, report = apps.resolve_self_intersections(mesh, resolution=RES, progress=False)
    return mesh, out, report


def test_bent_bar_has_no_intersection_left(bent_bar_resolved):
    mesh, out, report = bent_bar_resolved
    assert report.intersections_initial == voxax.intersections(mesh).count > 0
    # Resolved means: the exact test, run again on the returned mesh, finds nothing.
    assert report.resolved and report.intersections_final == 0
    assert voxax.intersections(out).count == 0
    # Beyond the working grid: finer and shifted grids see no overlap either.
    for w in _beyond_the_grid(out, report, RES):
        assert w <= 1 + 1e-3
    np.testing.assert_array_equal(out.faces, mesh.faces)
    print(f"\nbent_bar {RES}^3: {report.intersections_initial} -> {report.intersections_after_voxel_stage} -> 0 "
          f"pairs, {report.refinement_rounds} rounds, {report.refinement_steps} steps, "
          f"{report.refinement_seconds:.1f} s; enclosed volume {report.enclosed_volume_initial:.5f} -> "
          f"{report.volume_final:.5f}")


def test_bent_bar_keeps_its_enclosed_volume(bent_bar_resolved):
    mesh, out, report = bent_bar_resolved
    # The input's enclosed volume: the signed volume counts the overlap twice.
    assert report.enclosed_volume_initial < mesh.signed_volume()
    # The resolved mesh's signed volume is its enclosed volume (no overlap left).
    assert abs(out.signed_volume() / report.enclosed_volume_initial - 1) < 0.02
    if report.volume_steps:  # the verified Newton steps reach their tolerance (0.5%)
        assert abs(out.signed_volume() / report.enclosed_volume_initial - 1) <= 0.005 + 1e-9


def test_exhausted_budget_is_reported_unresolved():
    # Too few steps and one one-step refinement round: reported unresolved, with the
    # count left (recomputed here on the returned mesh).
    mesh = _small_bar()
    out, report = apps.resolve_self_intersections(
        mesh, resolution=RES, max_steps=2, max_rounds=1, round_steps=1, progress=False
    )
    assert not report.resolved and report.refinement_rounds == 1 and report.refinement_steps == 1
    assert report.intersections_final == voxax.intersections(out).count > 0


def test_test_cases_really_intersect():
    # The benchmark's cases are self-intersecting inputs (checked exactly and by voxels).
    for mesh in (overlapping_letters(), torus_knot_tube(0.7), deformed_hand(2), deformed_hand(3), deformed_hand(5)):
        assert voxax.intersections(mesh).count > 0
        assert voxax.io.is_watertight(mesh.vertices, mesh.faces)


def test_bad_budget_arguments():
    with pytest.raises(ValueError, match="max_rounds"):
        apps.resolve_self_intersections(voxax.data.cube(), max_rounds=-1, progress=False)
    with pytest.raises(ValueError, match="time_budget"):
        apps.resolve_self_intersections(voxax.data.cube(), time_budget=0.0, progress=False)


# -- bandsaw and tiling, checked beyond the working grid -----------------------------------


def test_bandsaw_report_on_finer_and_shifted_grids():
    import voxax.energies as E

    mesh = voxax.data.icosphere(1)
    out, report = apps.optimize_for_bandsaw(mesh, resolution=16, max_steps=2, progress=False)
    h = 2.0 / 16
    grids = {
        "fine": voxax.Grid.cube(32),
        "shifted": voxax.Grid(lower=(-1 + h / 2,) * 3, upper=(1 + h / 2,) * 3, shape=(16,) * 3),
    }
    for name, g in grids.items():
        for which, m in (("initial", mesh), ("final", out)):
            W = voxax.voxelize((m.vertices - report.centre) * report.scale, m.faces, g)
            cut = float(E.bandsaw_cut(W, report.w))
            waste = float(np.sum(np.maximum(E.cut_shape(W, report.w) - W, 0))) * g.voxel_volume / report.scale**3
            assert getattr(report, f"cut_{name}_{which}") == pytest.approx(cut, rel=1e-9)
            assert getattr(report, f"waste_volume_{name}_{which}") == pytest.approx(waste, rel=1e-9, abs=1e-15)
        assert getattr(report, f"relative_improvement_{name}") == pytest.approx(
            1 - getattr(report, f"cut_{name}_final") / getattr(report, f"cut_{name}_initial")
        )


@pytest.mark.parametrize("x1, expected", [(0.3, False), (0.2, True)])
def test_tiling_reports_exact_instance_intersections(x1, expected):
    # Two small cubes (side 0.1) in a periodic cell of period 2/3: 0.8 apart they are 0.133
    # apart modulo the period (clear); 0.7 apart, 0.033 modulo the period (overlapping only
    # through the periodic copy).
    cube = voxax.data.cube(0.1)
    _, report = apps.optimize_tiling(
        cube, instances=2, resolution=12, max_steps=0, deform=False, fill_volume=False,
        translations=[[-0.5, 0.0, 0.0], [x1, 0.0, 0.0]], angles=np.zeros((2, 3)), progress=False,
    )  # fmt: skip
    assert report.instances_intersect is expected
    assert (report.intersecting_instance_pairs > 0) is expected
    assert 0 <= report.coverage_fine_final <= 1 and 0 <= report.coverage_shifted_final <= 1
