"""Runs every script in examples/ at a tiny resolution through its `main(argv)`."""

from __future__ import annotations

import importlib.util
import pathlib

import matplotlib
import pytest

matplotlib.use("Agg")

EXAMPLES = pathlib.Path(__file__).resolve().parent.parent / "examples"


def _load(name: str):
    spec = importlib.util.spec_from_file_location(f"voxax_example_{name}", EXAMPLES / f"{name}.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_the_application_examples_exist():
    assert {"voxelize_mesh", "self_intersection", "bandsaw", "tiling", "bounded_minimize"} <= {p.stem for p in EXAMPLES.glob("*.py")}


def test_voxelize_mesh(tmp_path, capsys):
    assert _load("voxelize_mesh").main(["torus", "--resolution", "16", "--out", str(tmp_path)]) == 0
    assert (tmp_path / "W.npy").exists() and (tmp_path / "slices.png").exists()
    assert "volume gradient" in capsys.readouterr().out


def test_self_intersection(tmp_path):
    # The voxel stage alone at 32^3 (the full run with refinement is the example's default, and
    # tests/apps/test_resolve.py covers refinement): the script exits 1 because thin intersections remain.
    argv = ["--resolution", "32", "--max-rounds", "0", "--out", str(tmp_path), "--quiet"]
    assert _load("self_intersection").main(argv) == 1
    for name in ("input.ply", "resolved.ply", "overlaps.png", "history.png"):
        assert (tmp_path / name).exists(), name


def test_bandsaw(tmp_path, capsys):
    argv = ["--resolution", "24", "--max-steps", "15", "--out", str(tmp_path), "--quiet"]
    assert _load("bandsaw").main(argv) == 0
    for name in ("input.ply", "optimized.ply", "silhouettes.png", "history.png",
                 "templates_input/template_x.svg", "templates_optimized/cut_solid.ply"):
        assert (tmp_path / name).exists(), name
    assert "relative improvement" in capsys.readouterr().out


@pytest.mark.parametrize("meshes", [["icosphere"], ["icosphere", "cube"]])
def test_tiling(tmp_path, meshes):
    argv = [*meshes, "--instances", "4", "--resolution", "24", "--max-steps", "4", "--out", str(tmp_path), "--quiet"]
    assert _load("tiling").main(argv) == 0
    for name in ("tiling.ply", "tiled_2x2x2.ply", "cell.png", "history.png", "report.json"):
        assert (tmp_path / name).exists(), name


@pytest.mark.parametrize("solver", ["adam", "lbfgsb"])
def test_bounded_minimize(tmp_path, capsys, solver):
    argv = ["--resolution", "16", "--max-steps", "10", "--solver", solver, "--out", str(tmp_path)]
    assert _load("bounded_minimize").main(argv) == 0
    out = capsys.readouterr().out
    assert "every vertex inside the build volume: True" in out
    assert (tmp_path / "inflated.ply").exists()


def test_meshsdf_topology(capsys):
    assert _load("meshsdf_topology").main(["--small", "--skip-deepsdf"]) == 0
    out = capsys.readouterr().out
    assert "Euler characteristic 2@0 -> 0@" in out and "(target_euler)" in out
