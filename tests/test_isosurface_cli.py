"""`voxax mesh`: grids and built-in fields to mesh files."""

import argparse

import numpy as np
import pytest

import voxax
from voxax._cli_mesh import add_mesh_command


def run(argv):
    parser = argparse.ArgumentParser(prog="voxax")
    add_mesh_command(parser.add_subparsers(dest="command", required=True))
    args = parser.parse_args(["mesh", *argv])
    return args.func(args)


def test_mesh_from_voxelized_grid(tmp_path):
    trimesh = pytest.importorskip("trimesh")
    grid = voxax.Grid.cube(24)
    ico = voxax.data.icosphere(3)
    W = np.asarray(voxax.voxelize(ico.vertices * 0.7, ico.faces, grid))
    np.savez(
        tmp_path / "W.npz",
        W=W,
        lower=np.array(grid.lower),
        upper=np.array(grid.upper),
        shape=np.array(grid.shape),
    )
    assert run([str(tmp_path / "W.npz"), "-o", str(tmp_path / "out.ply")]) == 0
    m = trimesh.load(tmp_path / "out.ply", process=False)
    assert m.is_watertight
    assert m.volume == pytest.approx(float(W.sum()) * grid.voxel_volume, rel=0.02)


def test_mesh_from_builtin_sdf(tmp_path):
    trimesh = pytest.importorskip("trimesh")
    assert run(["--sdf", "torus", "-n", "32", "-o", str(tmp_path / "t.ply")]) == 0
    m = trimesh.load(tmp_path / "t.ply", process=False)
    assert m.is_watertight and m.euler_number == 0
    with pytest.raises(SystemExit):
        run(["-o", str(tmp_path / "x.ply")])
