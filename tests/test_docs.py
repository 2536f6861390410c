"""The documentation site builds with `mkdocs build --strict` (warnings fail the build),
every page of the nav exists, and the build-time inclusions (README set-up commands,
benchmark results, CLI help) work."""

import html
import importlib.util
import os
import re
import subprocess
import sys
from pathlib import Path

import pytest

pytest.importorskip("mkdocs")
pytest.importorskip("material")
pytest.importorskip("mkdocstrings_handlers.python")

ROOT = Path(__file__).resolve().parents[1]


def _build(site: Path) -> subprocess.CompletedProcess:
    env = dict(os.environ, NO_MKDOCS_2_WARNING="1")
    return subprocess.run(
        [sys.executable, "-m", "mkdocs", "build", "--strict", "--config-file", str(ROOT / "mkdocs.yml"),
         "--site-dir", str(site)],
        cwd=ROOT, env=env, capture_output=True, text=True, timeout=600,
    )


@pytest.fixture(scope="module")
def site(tmp_path_factory):
    site = tmp_path_factory.mktemp("site")
    proc = _build(site)
    log = proc.stdout + proc.stderr
    assert proc.returncode == 0, f"mkdocs build --strict failed:\n{log[-8000:]}"
    assert not re.search(r"^(WARNING|ERROR)", log, re.MULTILINE), log[-8000:]
    return site


def _text(site: Path, page: str) -> str:
    """The page's text without tags (code blocks are split into highlighted spans)."""
    raw = (site / page / "index.html").read_text(encoding="utf-8")
    return html.unescape(re.sub(r"<[^>]+>", "", raw))


def test_every_nav_page_is_built(site):
    config = (ROOT / "mkdocs.yml").read_text(encoding="utf-8")
    pages = re.findall(r":\s*([\w/]+)\.md\s*$", config, re.MULTILINE)
    assert {"index", "conventions", "gradients", "differentiation", "applications", "performance", "cli",
            "robustness"} <= set(pages)
    for page in pages:
        out = site / (f"{page}.html" if page.endswith("index") else f"{page}/index.html")
        assert out.exists(), page


def test_api_reference_covers_every_public_module(site):
    modules = ["voxax." + m for m in ("energies", "apps", "fabricate", "data", "io", "plot", "curves", "baselines",
                                      "reference", "fields", "metrics", "raster", "fc", "cvt", "esi", "nesi")]
    html = "".join(p.read_text(encoding="utf-8") for p in (site / "api").rglob("index.html"))
    for name in modules:
        if importlib.util.find_spec(name) is not None:
            assert f'id="{name}' in html, f"{name} is missing from the API reference"
    for name in ("Grid", "Mesh", "voxelize", "use_host_callback", "winding_number", "voxelize_mc", "box_filter",
                 "minimize", "StopRules", "MinimizeResult", "plot.projections", "plot.pyplot"):
        assert f'id="voxax.{name}"' in html, name
    # Docstring examples are rendered as code.
    assert "&gt;&gt;&gt;" in html


def test_included_content(site):
    index = _text(site, "")
    readme = (ROOT / "README.md").read_text(encoding="utf-8")
    block = readme.split("<!-- setup-commands -->")[1].split("<!-- /setup-commands -->")[0]
    for line in block.splitlines():
        if line.startswith(("pip", "python", "voxax")):
            assert line in index, line
    cli = _text(site, "cli")
    for command in ("demo", "voxelize", "resolve", "bandsaw", "tile"):
        assert f"$ voxax {command} --help" in cli
    for page, marker in (("performance", "benchmark-results"), ("cli", "cli-help"), ("", "setup-commands")):
        assert marker not in (site / page / "index.html").read_text(encoding="utf-8"), (page, marker)
    assert (site / "figures" / "grid_layout.png").exists() and (site / "figures" / "orientation.png").exists()


def test_benchmark_results_and_their_plot_are_included(tmp_path, monkeypatch):
    spec = importlib.util.spec_from_file_location("docs_hooks", ROOT / "docs" / "hooks.py")
    hooks = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(hooks)
    bench = tmp_path / "benchmarks"
    (bench / "results").mkdir(parents=True)
    (bench / "results" / "plot.png").write_bytes(b"png")
    (bench / "README.md").write_text(
        "The `<!-- results -->` markers below are rewritten.\n\n## Results\n\n<!-- results -->\n"
        "| case | time |\n|---|---|\n| hand | 1 ms |\n\n![plot](results/plot.png)\n<!-- /results -->\n",
        encoding="utf-8",
    )
    monkeypatch.setattr(hooks, "BENCH", str(bench))
    text, images = hooks._benchmark_results()
    assert text.startswith("| case | time |") and "![plot](benchmarks/results/plot.png)" in text
    assert images == [("benchmarks/results/plot.png", str(bench / "results" / "plot.png"))]
