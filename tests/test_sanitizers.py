"""The C++ kernels under AddressSanitizer and UBSan, on thousands of hostile inputs.

Runs `tests/sanitize/run_sanitized.py` (which builds the kernels with `-DVOXAX_SANITIZE=ON`
and runs `tests/sanitize/driver.py` with the sanitizer runtimes preloaded) once per
session, in a subprocess. A few minutes on 2 cores, the build of every kernel included; `run_sanitized.py --inputs N` fuzzes longer.
Marked `sanitize`: not in the default suite, but a step of its own in CI
(`python -m pytest -m sanitize`).
"""

from __future__ import annotations

import importlib.util
import re
import subprocess
import sys
from pathlib import Path

import pytest

SANITIZE = Path(__file__).resolve().parent / "sanitize"
RUNNER = SANITIZE / "run_sanitized.py"
REPORT = re.compile(r"ERROR: AddressSanitizer|runtime error:|ERROR: LeakSanitizer|UndefinedBehaviorSanitizer")
MIN_INPUTS = 450

pytestmark = pytest.mark.sanitize


def _runner_module():
    spec = importlib.util.spec_from_file_location("voxax_run_sanitized", RUNNER)
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def _require_tools():
    missing = _runner_module().missing_tools()
    if missing:
        pytest.skip("the sanitizer build needs " + ", ".join(missing) + ", which are not installed")


def _run(*args, timeout=1200):
    return subprocess.run([sys.executable, str(RUNNER), *args], capture_output=True, text=True, timeout=timeout)


@pytest.fixture(scope="module")
def fuzz_run():
    _require_tools()
    return _run("--inputs", "220", "--spatial-inputs", "110", "--seed", "0")


def _tail(proc, n=6000):
    return f"exit status {proc.returncode}\n--- stdout ---\n{proc.stdout[-n:]}\n--- stderr ---\n{proc.stderr[-n:]}"


def test_no_sanitizer_findings(fuzz_run):
    proc = fuzz_run
    assert not REPORT.search(proc.stderr) and not REPORT.search(proc.stdout), _tail(proc)
    # 0: all checks passed; 3: a value check failed (see the next test). A sanitizer
    # finding aborts the driver (SIGABRT) instead.
    assert proc.returncode in (0, 3), _tail(proc)
    assert "AddressSanitizer runtime loaded: True; UBSan runtime loaded: True" in proc.stdout, _tail(proc)
    tried = re.search(r"INPUTS TRIED: (\d+)", proc.stdout)
    assert tried and int(tried.group(1)) >= MIN_INPUTS, _tail(proc)


def test_fuzzed_results_pass_the_value_checks(fuzz_run):
    """Finite, bounded results, eager == jit and batched == single bit for bit, the volume
    identity for closed meshes inside the grid and agreement with the reference."""
    proc = fuzz_run
    failed = re.search(r"failed checks: (\d+)", proc.stdout)
    assert failed is not None, _tail(proc)
    assert int(failed.group(1)) == 0 and proc.returncode == 0, _tail(proc)


def test_sanitized_runs_report_a_deliberate_overflow():
    """The harness is armed: a heap overflow under the same set-up is reported."""
    _require_tools()
    proc = _run("--canary", timeout=900)
    assert proc.returncode != 0, _tail(proc)
    assert "ERROR: AddressSanitizer: heap-buffer-overflow" in proc.stderr, _tail(proc)
