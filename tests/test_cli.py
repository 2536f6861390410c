"""Tests for the `voxax` command line, run in-process through `voxax.cli.main`."""

from __future__ import annotations

import json

import matplotlib
import numpy as np
import pytest

matplotlib.use("Agg")

import voxax  # noqa: E402
from voxax.cli import main  # noqa: E402


def test_demo(tmp_path, capsys):
    out = tmp_path / "demo.png"
    assert main(["demo", "--resolution", "32", "--output", str(out)]) == 0
    text = capsys.readouterr().out
    assert "relative error" in text and out.exists()
    rel = float(text.split("relative error")[1].split()[0])
    assert rel < 1e-9


def test_voxelize(tmp_path):
    out = tmp_path / "W.npy"
    assert main(["voxelize", "torus", "-n", "16", "-o", str(out)]) == 0
    assert np.load(out).shape == (16, 16, 16)


def test_resolve(tmp_path, capsys):
    assert main(["resolve", "bent_bar", "-n", "32", "--out", str(tmp_path), "-q"]) == 0
    assert "resolved" in capsys.readouterr().out
    report = json.loads((tmp_path / "report.json").read_text())
    assert report["resolved"] is True and report["max_w_final"] <= 1.001
    resolved = voxax.io.load(tmp_path / "resolved.ply")
    assert resolved.n_faces == voxax.data.bent_bar().n_faces
    assert (tmp_path / "overlaps.png").exists() and (tmp_path / "history.png").exists()


def test_resolve_reads_mesh_files_and_reports_failure(tmp_path):
    path = tmp_path / "overlap.ply"
    voxax.io.save(voxax.data.overlapping_cubes(), path)
    # Two steps cannot separate the cubes: the command says so with exit status 1.
    assert main(["resolve", str(path), "-n", "16", "--max-steps", "2", "--out", str(tmp_path / "r"), "-q",
                 "--no-figures"]) == 1
    assert not json.loads((tmp_path / "r" / "report.json").read_text())["resolved"]


def test_bandsaw(tmp_path):
    assert main(["bandsaw", "hand", "-n", "24", "--max-steps", "20", "--out", str(tmp_path), "-q"]) == 0
    report = json.loads((tmp_path / "report.json").read_text())
    assert report["steps"] == 20 or report["stop_reason"] == "min_step"
    assert report["relative_improvement"] > 0
    for name in ("input.ply", "optimized.ply", "history.png", "templates_optimized/template_z.svg",
                 "templates_input/cut_solid.ply", "templates_optimized/report.json"):
        assert (tmp_path / name).exists(), name
    assert 0 <= report["exact_waste_fraction_optimized"] < 1


def test_tile(tmp_path):
    argv = ["tile", "icosphere", "cube", "--instances", "2", "1", "-n", "24", "--max-steps", "3",
            "--out", str(tmp_path), "-q", "--separate"]
    assert main(argv) == 0
    report = json.loads((tmp_path / "report.json").read_text())
    assert report["instances"] == 3 and report["mesh_index"] == [0, 0, 1]
    assert np.asarray(report["translations"]).shape == (3, 3)
    assert np.load(tmp_path / "cell.npy").shape == (8, 8, 8)
    tiling = voxax.io.load(tmp_path / "tiling.ply")
    assert tiling.n_faces == 2 * voxax.data.icosphere().n_faces + voxax.data.cube().n_faces
    assert (tmp_path / "instance_02.ply").exists() and (tmp_path / "cell.png").exists()


def test_unknown_mesh_is_a_clear_error(tmp_path):
    with pytest.raises(SystemExit, match="neither a mesh file nor a built-in mesh"):
        main(["resolve", "no-such-mesh", "--out", str(tmp_path)])
