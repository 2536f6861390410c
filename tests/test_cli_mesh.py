"""`voxax mesh`: a grid file or a built-in field to a mesh file; its error paths run in real
subprocesses (exit status 2, one line on stderr, no traceback)."""

from __future__ import annotations

import math
import os
import subprocess
import sys

import numpy as np
import pytest

import voxax
from voxax.cli import main


def test_mesh_from_a_voxelized_grid(tmp_path, capsys):
    sphere = voxax.data.icosphere(3, radius=0.6)
    W = tmp_path / "W.npz"
    assert main(["voxelize", str(_save(sphere, tmp_path / "s.ply")), "-n", "32", "-o", str(W)]) == 0
    out = tmp_path / "out.ply"
    assert main(["mesh", str(W), "-o", str(out)]) == 0
    assert "Euler characteristic 2" in capsys.readouterr().out
    mesh = voxax.io.load(out)
    assert voxax.metrics.euler_characteristic(mesh) == 2
    # against scikit-image's marching cubes of the same grid at the same level
    measure = pytest.importorskip("skimage.measure")
    with np.load(W) as z:
        grid = voxax.Grid(tuple(z["lower"]), tuple(z["upper"]), tuple(z["shape"].tolist()))
        verts, faces, _, _ = measure.marching_cubes(z["W"], 0.5, spacing=grid.spacing)
    verts = verts + np.asarray(grid.lower) + 0.5 * np.asarray(grid.spacing)
    expected = abs(voxax.Mesh(verts, faces.astype(np.int32)).signed_volume())
    assert mesh.signed_volume() == pytest.approx(expected, rel=1e-3)  # triangulations of ambiguous cells differ
    # and, loosely (one cell is 1/16 of the radius), the volume of the voxelized sphere
    assert mesh.signed_volume() == pytest.approx(sphere.signed_volume(), rel=0.02)


def test_mesh_of_a_builtin_field(tmp_path):
    out = tmp_path / "torus.obj"
    assert main(["mesh", "--sdf", "torus", "-r", "32", "-o", str(out)]) == 0
    mesh = voxax.io.load(out)
    assert voxax.metrics.euler_characteristic(mesh) == 0
    assert mesh.signed_volume() == pytest.approx(2 * math.pi**2 * 0.5 * 0.2**2, rel=0.03)


def _save(mesh, path):
    voxax.io.save(mesh, path)
    return path


_DRIVER = r"""
import json, os, sys
from voxax.cli import main

out = []
for argv in json.loads(sys.argv[1]):
    r, w = os.pipe()
    pid = os.fork()
    if pid == 0:
        os.dup2(w, 2)
        try:
            code = main(argv)
        except SystemExit as e:
            code = e.code if isinstance(e.code, int) else 1
        except BaseException:
            import traceback
            traceback.print_exc()
            code = 1
        sys.stderr.flush()
        os._exit(code)
    os.close(w)
    err = os.fdopen(r).read()
    _, status = os.waitpid(pid, 0)
    out.append([os.waitstatus_to_exitcode(status), err])
print(json.dumps(out))
"""

ERRORS = [
    ((), "exactly one"),
    (("x.npz", "--sdf", "sphere"), "exactly one"),
    (("missing.npz",), "no such grid file"),
    (("bad.npz",), "must be a .npz with arrays W"),
    (("--sdf", "teapot"), "invalid choice"),
    (("--sdf", "sphere", "-r", "1"), "at least 2"),
    (("--sdf", "sphere", "-o", "no/such/folder/m.ply"), "does not exist"),
]


@pytest.fixture(scope="module")
def error_runs(tmp_path_factory):
    import json
    from pathlib import Path

    tmp = tmp_path_factory.mktemp("mesh_errors")
    np.savez(tmp / "bad.npz", X=np.zeros(3))
    env = dict(os.environ, PYTHONPATH=os.pathsep.join(
        [str(Path(voxax.__file__).resolve().parents[1]), os.environ.get("PYTHONPATH", "")]))
    cases = [["mesh", *a] for a, _ in ERRORS]
    proc = subprocess.run([sys.executable, "-c", _DRIVER, json.dumps(cases)], check=False, cwd=tmp, env=env,
                          capture_output=True, text=True, timeout=600)
    assert proc.returncode == 0, proc.stderr[-4000:]
    return json.loads(proc.stdout.strip().splitlines()[-1])


@pytest.mark.parametrize("case", range(len(ERRORS)), ids=[" ".join(a) or "(none)" for a, _ in ERRORS])
def test_mesh_errors(error_runs, case):
    code, err = error_runs[case]
    lines = err.strip().splitlines()
    assert code == 2, err
    assert len(lines) == 1 and ERRORS[case][1] in lines[0] and "Traceback" not in err, err
