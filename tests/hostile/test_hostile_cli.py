"""Hostile command lines: the `voxax` command (`python -m voxax`) on user mistakes, each
case in its own process.

One Python process imports `voxax.cli` once and forks a child per case; the child runs
`python -m voxax ARGS` the way the interpreter does (`runpy.run_module("voxax",
run_name="__main__")`, so `voxax/__main__.py` and its `sys.exit(main())`), with its own
stdout and stderr. A case passes when the child exits with the stated status in time (no
hang), with no traceback, and, for status 2, exactly one line on stderr that starts with
`voxax <command>: error:` and contains the stated words; for status 0 the words are on
stdout. `test_the_console_entry_point` runs one case through a real `python -m voxax`.

Rows: `(system, label, command line, exit status, words)`; `{tmp}` is a folder with the
files below.
"""

from __future__ import annotations

import json
import os
import shlex
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from _hostile_driver import child_env

import voxax

_LIMIT = 60.0  # seconds a case may run before it counts as a hang
_QUICK = 20.0  # the refusals of outputs beyond memory: before allocating, so quickly

CASES = [
    ("cli", "a missing mesh file", "fc {tmp}/missing.ply", 2, "no such mesh file"),
    ("cli", "a missing grid file", "mesh {tmp}/missing.npz", 2, "no such grid file"),
    ("cli", "a file that is not a mesh", "fc {tmp}/garbage.ply", 2, "cannot read the mesh file"),
    ("cli", "an empty mesh file", "remesh {tmp}/empty.ply", 2, "cannot read the mesh file"),
    ("cli", "a folder for the mesh", "voxelize {tmp}", 2, "is a folder"),
    ("cli", "NaN vertices in the file", "fc {tmp}/nan.ply", 2, "NaN or Inf"),
    ("cli", "a PLY header claiming 10^12 vertices", "remesh {tmp}/huge.ply", 2, "its header claims"),
    ("cli", "a degenerate mesh to remesh", "remesh {tmp}/degenerate.ply -o {tmp}/r.ply", 2, "degenerate"),
    ("cli", "a degenerate mesh to resolve", "resolve {tmp}/degenerate.ply -o {tmp}/r", 2, "vertices all coincide"),
    ("cli", "a degenerate mesh to contour", "fc {tmp}/degenerate.ply -r 8 -o {tmp}/d.ply", 2, "no surface"),
    ("cli", "a level outside the values", "mesh {tmp}/W.npz --level 7 -o {tmp}/m.ply", 2,
     "does not cross the field"),
    ("cli", "a NaN level", "mesh {tmp}/W.npz --level nan", 2, "expected a finite number"),
    ("cli", "a grid shape with a float entry", "mesh {tmp}/float_shape.npz -o {tmp}/m.ply", 2,
     "'shape' must be 3 integers"),
    ("cli", "NaN grid values", "mesh {tmp}/nan.npz -o {tmp}/m.ply", 2, "NaN or Inf"),
    ("cli", "fc -r 100000 (beyond memory)", "fc torus -r 100000 -o {tmp}/f.ply", 2, "GiB"),
    ("cli", "mesh --sdf -n 100000 (beyond memory)", "mesh --sdf sphere -n 100000 -o {tmp}/m.ply", 2, "GiB"),
    ("cli", "an unknown option of a command", "fc torus --bogus", 2, "unrecognized arguments: --bogus"),
    ("cli", "a float resolution", "fc torus -r 2.5", 2, "expected an integer"),
    ("cli", "an output folder that does not exist", "fc torus -r 8 -o {tmp}/nowhere/x.ply", 2, "does not exist"),
    ("cli", "alpha 0", "remesh torus --alpha 0", 2, "expected a number > 0"),
    ("cli", "an unknown command", "frobnicate", 2, "invalid choice"),
    ("cli", "--version (oracle)", "--version", 0, f"voxax {voxax.__version__}"),
]

_DRIVER = r"""
import json, runpy, sys
from _forked import run_forked
import voxax.cli  # imported once; each child runs `python -m voxax`
cases, limit = json.loads(sys.argv[1]), float(sys.argv[2])

def command(argv):
    def body():
        sys.argv = ["voxax", *argv]
        runpy.run_module("voxax", run_name="__main__", alter_sys=True)
        return 0
    return body

print(json.dumps([list(run_forked(command(argv), limit)) for argv in cases]))
"""


def _files(tmp: Path) -> None:
    ball = voxax.data.icosphere(1, radius=0.5)
    voxax.io.save(voxax.Mesh(np.zeros_like(np.asarray(ball.vertices)), ball.faces), tmp / "degenerate.ply")
    (tmp / "garbage.ply").write_bytes(b"ply\nthis is not a mesh\n\x00\x01")
    (tmp / "empty.ply").write_bytes(b"")
    header = ("ply\nformat ascii 1.0\nelement vertex {n}\nproperty float x\nproperty float y\nproperty float z\n"
              "element face 1\nproperty list uchar int vertex_indices\nend_header\n")
    (tmp / "nan.ply").write_text(header.format(n=3) + "0 0 0\nnan 1 0\n0 0 1\n3 0 1 2\n")
    (tmp / "huge.ply").write_text(header.format(n=10**12) + "0 0 0\n1 0 0\n0 1 0\n3 0 1 2\n")
    grid = voxax.Grid.cube(8)
    W = np.asarray(voxax.voxelize(ball, grid))
    np.savez(tmp / "W.npz", W=W, lower=grid.lower, upper=grid.upper, shape=grid.shape)
    np.savez(tmp / "float_shape.npz", W=W, lower=grid.lower, upper=grid.upper, shape=[8.0, 8.5, 8.0])
    np.savez(tmp / "nan.npz", W=np.where(W > 0.5, np.nan, W), lower=grid.lower, upper=grid.upper, shape=grid.shape)


@pytest.fixture(scope="module")
def runs(tmp_path_factory):
    """Every case's `[exit status or None (a hang), seconds, stdout, stderr]`."""
    if not hasattr(os, "fork"):
        pytest.skip("needs os.fork")
    tmp = tmp_path_factory.mktemp("hostile_cli")
    _files(tmp)
    argvs = [shlex.split(line.replace("{tmp}", str(tmp))) for _, _, line, _, _ in CASES]
    proc = subprocess.run([sys.executable, "-c", _DRIVER, json.dumps(argvs), str(_LIMIT)], cwd=tmp, env=child_env(),
                          capture_output=True, text=True, timeout=1800)
    assert proc.returncode == 0, proc.stderr[-4000:]
    results = json.loads(proc.stdout.strip().splitlines()[-1])
    assert len(results) == len(CASES)
    return results


def check(case, got):
    _, label, line, status, words = case
    code, seconds, stdout, stderr = got
    assert code is not None, f"{label}: no exit within {_LIMIT:.0f} s (a hang)"
    assert code == status, f"{label}: exit {code}, expected {status}: {stderr[-2000:]}"
    assert "Traceback" not in stdout + stderr, f"{label}: {stderr[-2000:]}"
    if status == 0:
        assert words in stdout and not stderr.strip(), (label, stdout, stderr)
        return
    lines = stderr.strip().splitlines()
    assert len(lines) == 1, f"{label}: {len(lines)} lines on stderr: {stderr[-2000:]}"
    command = line.split()[0]
    prefix = "voxax: error:" if command.startswith("-") or command == "frobnicate" else f"voxax {command}: error:"
    assert lines[0].startswith(prefix), f"{label}: {lines[0]}"
    assert words in lines[0], f"{label}: {lines[0]}"
    if "beyond memory" in label:
        assert seconds < _QUICK, f"{label}: {seconds:.1f} s (expected a refusal before allocating)"


@pytest.mark.parametrize("case", range(len(CASES)), ids=[f"{c[0]}: {c[1]}" for c in CASES])
def test_hostile_command_line(runs, case):
    check(CASES[case], runs[case])


def test_the_console_entry_point(tmp_path):
    """`python -m voxax` itself (not a fork): an unknown option exits 2 with one line."""
    proc = subprocess.run([sys.executable, "-m", "voxax", "fc", "torus", "--bogus"], cwd=tmp_path, env=child_env(),
                          capture_output=True, text=True, timeout=300)
    assert proc.returncode == 2, proc.stderr
    assert proc.stderr.strip().splitlines() == ["voxax fc: error: unrecognized arguments: --bogus (see 'voxax fc "
                                                "--help')"], proc.stderr
