"""Tests for the `voxax` command line: the commands (in-process through `voxax.cli.main`)
and every subcommand's error paths (in real subprocesses: exit status 2, one line on
stderr, no traceback)."""

from __future__ import annotations

import argparse
import io
import json
import os
import subprocess
import sys
import time
from pathlib import Path

import matplotlib
import numpy as np
import pytest

matplotlib.use("Agg")

import voxax  # noqa: E402
from voxax import cli  # noqa: E402
from voxax._progress import ProgressBar  # noqa: E402
from voxax.cli import main  # noqa: E402

# -- the commands -----------------------------------------------------------------------------


def test_demo(tmp_path, capsys):
    out = tmp_path / "demo.png"
    assert main(["demo", "--resolution", "32", "--output", str(out)]) == 0
    text = capsys.readouterr().out
    assert "relative error" in text and out.exists()
    rel = float(text.split("relative error")[1].split()[0])
    assert rel < 1e-9


def test_voxelize_writes_npz_with_the_grid(tmp_path, capsys):
    out = tmp_path / "W.npz"
    assert main(["voxelize", "torus", "-n", "16", "-o", str(out)]) == 0
    captured = capsys.readouterr()
    assert captured.err == ""  # the torus lies inside [-1, 1]^3: no warning
    with np.load(out) as z:
        assert set(z.files) == {"W", "lower", "upper", "shape"}
        grid = voxax.Grid(tuple(z["lower"]), tuple(z["upper"]), tuple(int(n) for n in z["shape"]))
        W = z["W"]
    assert grid == voxax.Grid.cube(16)
    mesh = voxax.data.torus()
    np.testing.assert_array_equal(W, np.asarray(voxax.voxelize(mesh.vertices, mesh.faces, grid)))


def test_voxelize_npy_and_fit(tmp_path):
    out = tmp_path / "W.npy"
    assert main(["voxelize", "torus", "-n", "16", "-o", str(out)]) == 0
    assert np.load(out).shape == (16, 16, 16)
    # --fit: the grid is Grid.around(vertices, n), recorded in the .npz.
    out = tmp_path / "fit.npz"
    assert main(["voxelize", "hand", "-n", "12", "--fit", "-o", str(out)]) == 0
    mesh = voxax.data.hand()
    expected = voxax.Grid.around(mesh.vertices, 12)
    with np.load(out) as z:
        np.testing.assert_array_equal(z["lower"], expected.lower)
        np.testing.assert_array_equal(z["upper"], expected.upper)
        assert tuple(z["shape"]) == expected.shape == z["W"].shape
        assert float(z["W"].sum()) * expected.voxel_volume == pytest.approx(mesh.signed_volume(), rel=1e-12)


@pytest.mark.parametrize("offset, expected", [(0.9, "are cut off"), (5.0, "so every voxel is 0")])
def test_voxelize_warns_when_the_mesh_leaves_the_grid(tmp_path, capsys, offset, expected):
    mesh = voxax.data.icosphere(1, radius=0.5)
    path = tmp_path / "moved.ply"
    voxax.io.save(voxax.Mesh(mesh.vertices + offset, mesh.faces), path)
    out = tmp_path / "W.npz"
    assert main(["voxelize", str(path), "-n", "8", "-o", str(out)]) == 0
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("voxax voxelize: warning: ") and expected in err[0]
    assert "--fit" in err[0] and "--normalize" in err[0] and "normalize=True" not in err[0]
    with np.load(out) as z:
        assert (z["W"].max() == 0) == (offset == 5.0)
    # Following the advice removes the warning.
    for option in ("--fit", "--normalize"):
        assert main(["voxelize", str(path), "-n", "8", option, "-o", str(out)]) == 0
        assert capsys.readouterr().err == ""
        with np.load(out) as z:
            assert z["W"].max() == pytest.approx(1.0)


def test_resolve(tmp_path, capsys):
    # The voxel stage alone (--no-refine) removes every overlapping voxel of the 32^3 grid;
    # thin intersections below the voxel size remain, so the exact check reports the mesh as
    # unresolved and the command exits with status 1. (Refinement is tested in test_resolve.py.)
    assert main(["resolve", "bent_bar", "-n", "32", "--no-refine", "--out", str(tmp_path), "-q"]) == 1
    assert "resolved" in capsys.readouterr().out
    report = json.loads((tmp_path / "report.json").read_text())
    assert report["voxel_resolved"] is True and report["max_w_final"] <= 1.001
    assert report["resolved"] is (report["intersections_final"] == 0)
    assert report["intersections_final"] < report["intersections_initial"]
    resolved = voxax.io.load(tmp_path / "resolved.ply")
    assert resolved.n_faces == voxax.data.bent_bar().n_faces
    assert (tmp_path / "overlaps.png").exists() and (tmp_path / "history.png").exists()


def test_resolve_reads_mesh_files_and_reports_failure(tmp_path, capsys):
    path = tmp_path / "overlap.ply"
    cubes = voxax.data.overlapping_cubes()  # in [-0.6, 0.6]^3
    voxax.io.save(voxax.Mesh(cubes.vertices + [0.7, 0.0, 0.0], cubes.faces), path)
    # Two steps cannot separate the cubes: the command says so with exit status 1.
    assert main(["resolve", str(path), "-n", "16", "--max-steps", "2", "--no-refine", "--out", str(tmp_path / "r"), "-q",
                 "--no-figures", "--no-normalize"]) == 1
    assert not json.loads((tmp_path / "r" / "report.json").read_text())["resolved"]
    # The mesh sticks out of [-1, 1]^3: one warning, in command-line words.
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("voxax resolve: warning: parts of the mesh"), err
    assert "drop --no-normalize" in err[0] and "normalize=True" not in err[0]


def test_bandsaw(tmp_path):
    assert main(["bandsaw", "hand", "-n", "24", "--max-steps", "20", "--out", str(tmp_path), "-q"]) == 0
    report = json.loads((tmp_path / "report.json").read_text())
    assert report["steps"] == 20 or report["stop_reason"] == "min_step"
    assert report["relative_improvement"] > 0
    for name in ("input.ply", "optimized.ply", "history.png", "templates_optimized/template_z.svg",
                 "templates_input/cut_solid.ply", "templates_optimized/report.json"):
        assert (tmp_path / name).exists(), name
    assert 0 <= report["exact_waste_fraction_optimized"] < 1


def test_tile(tmp_path, capsys):
    argv = ["tile", "icosphere", "cube", "--instances", "2", "1", "-n", "24", "--max-steps", "3",
            "--out", str(tmp_path), "-q", "--separate"]
    code = main(argv)
    report = json.loads((tmp_path / "report.json").read_text())
    # A tiling whose instances still intersect is reported as such and is not a success.
    assert code == (1 if report["instances_intersect"] else 0)
    out, err = capsys.readouterr()
    assert ("instance pairs still intersect" in out) == report["instances_intersect"]
    assert ("not a valid tiling" in err) == report["instances_intersect"]
    assert report["instances"] == 3 and report["mesh_index"] == [0, 0, 1]
    assert np.asarray(report["translations"]).shape == (3, 3)
    assert np.load(tmp_path / "cell.npy").shape == (8, 8, 8)
    tiling = voxax.io.load(tmp_path / "tiling.ply")
    assert tiling.n_faces == 2 * voxax.data.icosphere().n_faces + voxax.data.cube().n_faces
    assert (tmp_path / "instance_02.ply").exists() and (tmp_path / "cell.png").exists()


# -- structure and help -----------------------------------------------------------------------


def _subparsers(parser):
    action = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
    return action.choices


def test_every_option_of_every_command_has_help():
    parser = cli.build_parser()
    subparsers = _subparsers(parser)
    assert list(subparsers) == [c.name for c in cli.COMMANDS] == ["demo", "voxelize", "resolve", "bandsaw", "tile", "mesh", "fc",
                                                                  "remesh"]
    for name, sub in {"voxax": parser, **subparsers}.items():
        for action in sub._actions:
            assert action.help and action.help.strip(), (name, action.dest)
        text = sub.format_help()  # formats every help string (a stray % would raise here)
        assert "usage:" in text


def test_a_new_command_is_one_table_entry(capsys):
    seen = {}

    def add(p):
        p.add_argument("--count", type=int, default=1, help="how many")

    def run(args):
        seen["count"] = args.count
        return 0

    command = cli.Command("hello", "say hello", add, run)
    parser = cli.build_parser([*cli.COMMANDS, command])
    args = parser.parse_args(["hello", "--count", "3"])
    assert args.run(args) == 0 and seen == {"count": 3}
    assert "hello" in parser.format_help()


def test_in_process_errors_return_2_with_one_line(tmp_path, capsys):
    assert main(["resolve", "no-such-mesh", "--out", str(tmp_path)]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "neither a mesh file nor a built-in mesh" in err
    assert err.startswith("voxax resolve: error: ")
    with pytest.raises(cli.UsageError, match="neither a mesh file"):
        main(["--traceback", "resolve", "no-such-mesh", "--out", str(tmp_path)])


def test_progress_bar_ignores_the_compiling_step_and_ends_at_the_stop():
    out = io.StringIO()
    bar = ProgressBar(1000, "minimize", file=out)
    assert "compiling" in bar.bar.desc
    after_compiling = time.time()
    bar.update({"E": "1.0"})
    # The clock (rate, ETA) starts after the first, compiling step.
    assert bar.bar.start_t >= after_compiling and bar.bar.desc.startswith("minimize")
    for _ in range(9):
        bar.update({"E": "0.5"})
    bar.bar.refresh()
    running = out.getvalue().rstrip().split("\r")[-1]
    assert "10/1000" in running and "at most" in running  # the time left is an upper bound
    bar.close("min_step")
    last = out.getvalue().rstrip().split("\r")[-1]
    assert "10/10" in last and "100%" in last and "stop: min_step" in last and "E=0.5" in last
    assert "at most" not in last
    # A run that uses every step ends at total/total.
    out = io.StringIO()
    bar = ProgressBar(3, "minimize", file=out)
    for _ in range(3):
        bar.update()
    bar.close("max_steps")
    assert "3/3" in out.getvalue().split("\r")[-1]


def test_minimize_progress_bar_total_is_max_steps_and_ends_at_the_stop(capsys):
    import jax.numpy as jnp

    quad = lambda y, args: jnp.sum((y - 1.0) ** 2)  # noqa: E731
    r = voxax.minimize(quad, jnp.zeros(3), learning_rate=0.5, solver="bfgs",
                       stop=voxax.StopRules(max_steps=500))
    assert r.steps < 500
    err = capsys.readouterr().err
    last = err.rstrip().split("\r")[-1]
    assert f"{r.steps}/{r.steps}" in last and f"stop: {r.stop_reason}" in last, last
    assert "/500" in err  # the total shown while running is max_steps


# -- error paths, each in a subprocess ------------------------------------------------------------

ERRORS = [
    # (arguments, words the one-line message must contain)
    ([], "required: COMMAND"),
    (["frobnicate"], "invalid choice"),
    (["demo", "--mesh", "no_such_mesh"], "neither a mesh file nor a built-in mesh"),
    (["demo", "-n", "0"], "at least 1"),
    (["voxelize", "{tmp}/missing.ply"], "no such mesh file"),
    (["voxelize", "{tmp}/garbage.ply"], "cannot read the mesh file"),
    (["voxelize", "torus", "-o", "{tmp}/W.txt"], "must end in .npz or .npy"),
    (["voxelize", "torus", "-n", "ten"], "expected an integer"),
    (["voxelize", "torus", "--bogus"], "unrecognized arguments: --bogus"),
    (["voxelize", "torus", "-n", "100000", "-o", "{tmp}/W.npz"], "more than the"),  # memory
    (["resolve", "no_such_mesh", "-o", "{tmp}/r"], "neither a mesh file"),
    (["resolve", "bent_bar", "--lr", "-1"], "expected a number > 0"),
    (["resolve", "bent_bar", "--eps", "nan"], "finite"),
    (["resolve", "--traceback", "bent_bar"], "unrecognized arguments: --traceback"),  # an option of voxax
    (["bandsaw"], "required: mesh"),
    (["bandsaw", "star_polyline", "-o", "{tmp}/b"], "2D mesh"),
    (["bandsaw", "hand", "--w", "0"], "expected a number > 0"),
    (["tile", "-n", "32", "torus"], "multiple of 3"),
    (["tile", "torus", "cube", "--instances", "1", "2", "3"], "3 counts for 2 meshes"),
    (["tile", "torus", "--init", "grid"], "invalid choice"),
    (["fc", "no_such_mesh"], "neither a mesh file"),
    (["fc", "torus", "-r", "0"], "at least 2"),
    (["fc", "torus", "-o", "{tmp}/out.txt"], "must end in .ply"),
    (["remesh", "{tmp}/missing.ply"], "no such mesh file"),
    (["remesh", "torus", "--seeds", "2"], "expected an integer >= 4"),
    (["remesh", "torus", "-o", "{tmp}/out.npz"], "must end in .ply"),
    (["voxelize", "torus", "--fit", "-o", "{tmp}/W.npy"], "a .npy file cannot hold"),
    (["resolve", "{tmp}/inside_out.ply", "-o", "{tmp}/r"], "inside out"),
    (["bandsaw", "{tmp}/inside_out.ply", "-o", "{tmp}/b"], "pass --flip"),
    (["tile", "{tmp}/inside_out.ply", "-o", "{tmp}/t"], "inside out"),
    (["mesh", "{tmp}/negative.npz", "-o", "{tmp}/m.ply"], "inside-out mesh"),
    (["mesh", "{tmp}/float_shape.npz", "-o", "{tmp}/m.ply"], "'shape' must be 3 integers"),
    (["mesh", "{tmp}/negative.npz", "--level", "7", "-o", "{tmp}/m.ply"], "does not cross the field"),
    (["voxelize", "{tmp}/nan.ply"], "NaN or Inf"),
]


# One Python process imports voxax once and forks a child per case; each child runs the
# command the way the `voxax` entry point does (`sys.exit(main())`: an uncaught exception
# prints a traceback and exits 1) with its own stdout and stderr, and exits.
_DRIVER = r"""
import json, sys
from _forked import run_forked
from voxax.cli import main

results = []
for argv in json.loads(sys.argv[1]):
    status, _, stdout, stderr = run_forked(lambda argv=argv: main(argv))
    results.append([status, stdout, stderr])
print(json.dumps(results))
"""


@pytest.fixture(scope="module")
def error_runs(tmp_path_factory):
    """Every case of ERRORS, each in its own process (see `_DRIVER`)."""
    if not hasattr(os, "fork"):
        pytest.skip("needs os.fork")
    tmp = tmp_path_factory.mktemp("cli_errors")
    (tmp / "garbage.ply").write_bytes(b"ply\nthis is not a mesh\n\x00\x01")
    ball = voxax.data.icosphere(1, radius=0.5)
    voxax.io.save(voxax.Mesh(ball.vertices, ball.faces[:, ::-1]), tmp / "inside_out.ply")
    grid = voxax.Grid.cube(8)
    negative = -np.asarray(voxax.voxelize(ball, grid))
    np.savez(tmp / "negative.npz", W=negative, lower=grid.lower, upper=grid.upper, shape=grid.shape)
    np.savez(tmp / "float_shape.npz", W=negative, lower=grid.lower, upper=grid.upper, shape=[8.0, 8.5, 8.0])
    (tmp / "nan.ply").write_text("ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\n"
                                 "property float z\nelement face 1\nproperty list uchar int vertex_indices\n"
                                 "end_header\n0 0 0\nnan 1 0\n0 0 1\n3 0 1 2\n")
    forked = Path(__file__).resolve().parent / "hostile"  # `_forked`, the fork per case
    env = dict(os.environ, PYTHONPATH=os.pathsep.join(
        [str(Path(voxax.__file__).resolve().parents[1]), str(forked), os.environ.get("PYTHONPATH", "")]))
    cases = [[a.replace("{tmp}", str(tmp)) for a in argv] for argv, _ in ERRORS]
    proc = subprocess.run([sys.executable, "-c", _DRIVER, json.dumps(cases)], cwd=tmp, env=env,
                          capture_output=True, text=True, timeout=600)
    assert proc.returncode == 0, proc.stderr[-4000:]
    results = json.loads(proc.stdout.strip().splitlines()[-1])
    assert len(results) == len(ERRORS)
    return results


@pytest.mark.parametrize("case", range(len(ERRORS)), ids=[" ".join(a) or "(none)" for a, _ in ERRORS])
def test_error_paths_exit_2_with_one_line_and_no_traceback(error_runs, case):
    argv, words = ERRORS[case]
    returncode, stdout, stderr = error_runs[case]
    assert returncode == 2, (returncode, stdout, stderr)
    assert "Traceback" not in stderr and "Traceback" not in stdout
    lines = stderr.strip().splitlines()
    assert len(lines) == 1, stderr
    command = argv[0] if argv and argv[0] in {c.name for c in cli.COMMANDS} else None
    assert lines[0].startswith(f"voxax {command}: error: " if command else "voxax: error: "), lines[0]
    assert words in lines[0], lines[0]
