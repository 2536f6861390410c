"""`voxax fc`: the edge topology of the output in its line and in `--report`, and the warning
when a closed input decodes to an output that is not a closed 2-manifold."""

import json

import pytest

import voxax
from voxax import cli


@pytest.mark.parametrize("anchors, closed", [("patches", True), ("one", False)])
def test_fc_reports_the_output_topology(tmp_path, capsys, anchors, closed):
    report = tmp_path / "r.json"
    argv = ["fc", "mug", "-r", "16", "--anchors", anchors, "-o", str(tmp_path / "o.ply"), "--report", str(report)]
    assert cli.main(argv) == 0
    got = json.loads(report.read_text())
    out = voxax.io.load(tmp_path / "o.ply")
    want = voxax.metrics.manifold_report(out)
    assert got["nonmanifold_edges"] == want.n_nonmanifold_edges and got["input_closed"]
    assert got["misoriented_edges"] == want.n_misoriented_edges
    assert got["closed"] == closed == (want.n_nonmanifold_edges == 0)
    err = capsys.readouterr().err
    assert ("closed 2-manifold but the output is not" in err) == (not closed)
    # Without --report: the same counts on the output line.
    assert cli.main(argv[:-2]) == 0
    captured = capsys.readouterr()
    assert f"{want.n_nonmanifold_edges} non-manifold" in captured.out
    assert ("closed 2-manifold but the output is not" in captured.err) == (not closed)
