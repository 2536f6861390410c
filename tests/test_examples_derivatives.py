"""Runs examples/derivatives.py (Figs. 2 and 6 of the paper) at a small resolution."""

import importlib.util
import pathlib
import re

EXAMPLE = pathlib.Path(__file__).resolve().parents[1] / "examples" / "derivatives.py"


def _load():
    spec = importlib.util.spec_from_file_location("voxax_example_derivatives", EXAMPLE)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_derivatives_example(tmp_path, capsys):
    out = tmp_path / "derivatives.png"
    assert _load().main(["--resolution", "16", "--out", str(out), "--samples", "256"]) == 0
    assert out.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    printed = capsys.readouterr().out
    assert str(out) in printed
    errors = {}
    case = None
    for line in printed.splitlines():
        if line.endswith(":"):
            case = line[:-1]
        m = re.match(r"\s+(.*?)\s+relative error (\S+)$", line)
        if m:
            errors[(case, m.group(1))] = float(m.group(2))
    assert {c for c, _ in errors} == {"polygon, translation x", "circle, radius"}
    for case in ("polygon, translation x", "circle, radius"):
        assert errors[(case, "voxax vs FD")] < 1e-6
        assert errors[(case, "MC box 3 vs FD of box_filter(W, 3)")] < 0.1
        # The point-sampled baseline's derivatives are zero: relative error exactly 1.
        assert errors[(case, "point-sampled FD vs FD")] == 1.0
        assert errors[(case, "point-sampled AD vs FD")] == 1.0
