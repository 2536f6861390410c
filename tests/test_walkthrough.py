"""docs/walkthrough.md: every marked command and snippet runs, in order, in one folder."""

from __future__ import annotations

import os
import re
import subprocess
import sys
from pathlib import Path

import numpy as np

import voxax

DOC = Path(__file__).resolve().parents[1] / "docs" / "walkthrough.md"
BLOCK = re.compile(r"<!-- walkthrough -->\n```(bash|python)\n(.*?)```", re.S)


def _blocks():
    return BLOCK.findall(DOC.read_text())


def test_the_walkthrough_runs(tmp_path):
    blocks = _blocks()
    assert [kind for kind, _ in blocks].count("bash") >= 4 and len(blocks) >= 6
    env = dict(os.environ, MPLBACKEND="Agg", PYTHONPATH=os.pathsep.join(
        [str(Path(voxax.__file__).resolve().parents[1]), os.environ.get("PYTHONPATH", "")]))
    outputs = []
    for kind, text in blocks:
        if kind == "python":
            argv = [sys.executable, "-c", text]
        else:
            (line,) = [s for s in text.strip().splitlines() if s.strip()]
            words = line.split()
            assert words[0] == "voxax", line
            argv = [sys.executable, "-m", "voxax", *words[1:]]
        proc = subprocess.run(argv, cwd=tmp_path, env=env, capture_output=True, text=True, timeout=600)
        assert proc.returncode == 0, f"{text}\n{proc.stdout[-2000:]}\n{proc.stderr[-2000:]}"
        outputs.append(proc.stdout + proc.stderr)
    text = "\n".join(outputs)
    # What the page says happens: stray vertices noted, the inside-out mesh flipped, the volume printed.
    assert "100 of the mesh's" in text and "volume" in text
    for name in ("ball.npz", "flipped.npz", "ball_back.ply", "bandsaw/optimized.ply"):
        assert (tmp_path / name).exists(), name
    ball = voxax.io.load(tmp_path / "ball_back.ply")
    assert voxax.metrics.euler_characteristic(ball) == 2
    assert np.load(tmp_path / "flipped.npz")["W"].min() >= -1e-9  # flipped: no negative values
