"""The hostile-input driver: each case in its own process.

One Python process imports voxax (without starting XLA) and forks a child per case; the
child builds the case's inputs, calls the entry point and reports what happened. A case
passes when the child exits normally (no crash), within its time limit (no hang), and
either raised the stated exception with a one-line message that names the function
(`voxax.<ns>.<fn>: ...`, or the kernel's `voxax: ...` under `jax.jit`) and contains the
stated words, or, for a case whose expected exception is `None`, returned (such a case's
code checks its own result against an oracle with `assert`): never a silent result, never
a raw message from deep inside.

The tables live in `tests/hostile/test_hostile_<system>.py`, as tuples
`(system, label, code, exception type or None, words its message contains)`.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import voxax

# Inputs every case may use (built in the child): V, F a closed mesh; G a grid; P points.
SETUP = """
import jax, jax.numpy as jnp, numpy as np
jax.config.update("jax_enable_x64", True)
import voxax
BALL = voxax.data.icosphere(1, radius=0.5)
V, F = np.asarray(BALL.vertices), np.asarray(BALL.faces)
G = voxax.Grid.cube(6)
P = np.zeros((3, 3))
VNAN = V.copy(); VNAN[2, 1] = np.nan
"""

_MARK = "@@voxax-hostile-outcome@@"

_DRIVER = r"""
import json, sys
from _forked import run_forked
setup, cases, limit, mark = sys.argv[1], json.loads(sys.argv[2]), float(sys.argv[3]), sys.argv[4]
import voxax  # imported once; XLA starts in each child

def case(code):
    def body():
        try:
            env = {}
            exec(setup, env)
            exec(code, env)
            out = {"status": "returned"}
        except BaseException as err:
            out = {"status": "raised", "type": type(err).__name__, "message": str(err)}
        print("\n" + mark + json.dumps(out), flush=True)  # the last line of the child's stdout
        return 0
    return body

results = []
for code in cases:
    status, _, stdout, _ = run_forked(case(code), limit)
    if status is None:
        results.append({"status": "hang"})
    elif status != 0 or mark not in stdout:
        results.append({"status": "crash", "exit": status})
    else:
        results.append(json.loads(stdout[stdout.rindex(mark) + len(mark):]))
print(json.dumps(results))
"""


def child_env() -> dict:
    """The environment of a driver script: voxax and `_forked` importable."""
    import _forked

    paths = [str(Path(voxax.__file__).resolve().parents[1]), _forked.FOLDER, os.environ.get("PYTHONPATH", "")]
    return dict(os.environ, PYTHONPATH=os.pathsep.join(paths))


def run_cases(cases, cwd, setup=SETUP, limit=120.0):
    """Runs every case's code in its own forked child; one outcome dict per case."""
    proc = subprocess.run([sys.executable, "-c", _DRIVER, setup, json.dumps([c[2] for c in cases]), str(limit), _MARK],
                          cwd=cwd, env=child_env(), capture_output=True, text=True, timeout=3600)
    assert proc.returncode == 0, proc.stderr[-4000:]
    results = json.loads(proc.stdout.strip().splitlines()[-1])
    assert len(results) == len(cases)
    return results


def check(case, got):
    """Asserts that one case's outcome is what its table row states."""
    system, label, code, kind, words = case
    if kind is None:
        assert got["status"] == "returned", f"{label}: {got} (expected a correct result)"
        return
    assert got["status"] == "raised", f"{label}: {got} (expected {kind})"
    assert got["type"] == kind, f"{label}: {got['type']}: {got['message']}"
    first = got["message"].strip().splitlines()[0] if got["message"].strip() else ""
    prefix = "voxax" if kind == "JaxRuntimeError" else "voxax."
    assert prefix in first and words in got["message"], f"{label}: {got['message']}"
    if kind != "JaxRuntimeError":
        assert first.startswith("voxax."), f"{label}: the message does not name the function: {first}"


def ids(cases):
    return [f"{c[0]}: {c[1]}" for c in cases]
