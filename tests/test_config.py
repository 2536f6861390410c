"""`voxax.__version__` (from the package metadata, or the checkout's pyproject.toml) and
`voxax.show_config()` / `voxax --version --verbose`, checked against independent sources:
tomllib's reading of pyproject.toml, the jax modules, the kernel loader and the Linux
kernel's /proc/cpuinfo."""

from __future__ import annotations

import io
import os
import platform
import re
import sys
from importlib import metadata
from pathlib import Path

import jax
import jaxlib
import pytest
import tomllib

import voxax
from voxax import _version, cli

ROOT = Path(__file__).resolve().parents[1]
PACKAGE = Path(voxax.__file__).resolve().parent
FROM_SOURCE = PACKAGE == (ROOT / "src" / "voxax").resolve()


def _pyproject_version() -> str:
    with open(ROOT / "pyproject.toml", "rb") as fh:
        return tomllib.load(fh)["project"]["version"]


def _config() -> dict[str, str]:
    out = io.StringIO()
    voxax.show_config(file=out)
    lines = out.getvalue().splitlines()
    assert lines[0] == f"voxax {voxax.__version__}"
    rows = {}
    for line in lines[1:]:
        match = re.fullmatch(r"  (\S+(?: \S+)?) {2,}(.+)", line)
        assert match, line
        rows[match.group(1)] = match.group(2)
    return rows


# -- __version__ ------------------------------------------------------------------------------


def test_version_is_the_projects():
    expected = _pyproject_version() if FROM_SOURCE else metadata.version("voxax")
    assert voxax.__version__ == expected
    assert re.fullmatch(r"\d+\.\d+\.\d+([.-]?\w+)*", voxax.__version__)


def test_changelog_has_a_section_for_the_version():
    text = (ROOT / "CHANGELOG.md").read_text(encoding="utf-8")
    assert re.search(rf"^## \[{re.escape(_pyproject_version())}\]", text, re.MULTILINE)


def _dist(site: Path, version: str) -> metadata.Distribution:
    info = site / f"voxax-{version}.dist-info"
    info.mkdir(parents=True)
    (info / "METADATA").write_text(f"Metadata-Version: 2.1\nName: voxax\nVersion: {version}\n", encoding="utf-8")
    return metadata.PathDistribution(info)


def test_version_prefers_metadata_of_this_copy(tmp_path, monkeypatch):
    site = tmp_path / "site-packages"
    (site / "voxax").mkdir(parents=True)
    (site / "voxax" / "__init__.py").write_text("", encoding="utf-8")
    dist = _dist(site, "9.8.7")
    monkeypatch.setattr(_version, "_installed", lambda: dist)
    # The installed files are the package imported: the metadata's version.
    monkeypatch.setattr(_version, "_PACKAGE", (site / "voxax").resolve())
    assert _version.version() == "9.8.7"
    # The package is imported from a checkout, not the installed copy: the checkout's version.
    monkeypatch.setattr(_version, "_PACKAGE", (ROOT / "src" / "voxax").resolve())
    assert _version.version() == _pyproject_version()
    # Neither: the installed version is the best guess.
    (tmp_path / "elsewhere" / "voxax").mkdir(parents=True)
    monkeypatch.setattr(_version, "_PACKAGE", (tmp_path / "elsewhere" / "voxax").resolve())
    assert _version.version() == "9.8.7"


def test_version_without_metadata(tmp_path, monkeypatch):
    monkeypatch.setattr(_version, "_installed", lambda: None)
    monkeypatch.setattr(_version, "_PACKAGE", (ROOT / "src" / "voxax").resolve())
    assert _version.version() == _pyproject_version()
    # A src/voxax whose pyproject.toml is another project's is not taken for voxax's.
    other = tmp_path / "other"
    (other / "src" / "voxax").mkdir(parents=True)
    (other / "pyproject.toml").write_text('[project]\nname = "other"\nversion = "5.0"\n', encoding="utf-8")
    monkeypatch.setattr(_version, "_PACKAGE", (other / "src" / "voxax").resolve())
    assert _version.version() == "0+unknown"


# -- show_config ------------------------------------------------------------------------------


def test_show_config_names_the_versions_and_the_library():
    rows = _config()
    assert rows["version"] == voxax.__version__
    assert rows["jax"] == jax.__version__ and rows["jaxlib"] == jaxlib.__version__
    assert rows["python"].startswith(platform.python_version())
    assert Path(rows["package"]) == PACKAGE
    kernels = rows["kernels"].split(" -> ")
    assert Path(kernels[0]) == voxax._kernels.library_path()
    assert Path(kernels[-1]).resolve() == voxax._kernels.library_path().resolve()


def _cpuinfo_flags() -> set[str] | None:
    try:
        text = Path("/proc/cpuinfo").read_text(encoding="utf-8")
    except OSError:
        return None
    match = re.search(r"^flags\s*:\s*(.*)$", text, re.MULTILINE)
    return set(match.group(1).split()) if match else None


@pytest.mark.skipif(platform.machine() != "x86_64" or not sys.platform.startswith("linux"),
                    reason="the x86-64 vector paths on Linux")
def test_show_config_vector_paths_match_the_cpu():
    flags = _cpuinfo_flags()
    if flags is None:
        pytest.skip("no /proc/cpuinfo flags")
    rows = _config()
    # The kernels' own CPU checks (__builtin_cpu_supports) against the Linux kernel's list.
    expected = ", ".join(f"{name} {'yes' if key in flags else 'no'}"
                         for name, key in (("sse4.2", "sse4_2"), ("avx", "avx"), ("avx2", "avx2"), ("fma", "fma"),
                                           ("avx512f", "avx512f")))
    assert rows["CPU"] == expected
    # The project's build adds no -march/-m flags: the library is for the baseline.
    assert rows["build"].startswith("portable")
    if os.environ.get("VOXAX_KERNELS"):
        pytest.skip("a kernel library chosen by VOXAX_KERNELS (sanitizer builds have no clones)")
    if "avx2" in flags:
        assert rows["AVX2 clones"] == "compiled in, selected on this CPU (it has AVX2)"
    else:
        assert rows["AVX2 clones"].startswith("compiled in, not selected")


def test_no_build_flag_ties_the_kernels_to_the_build_machine():
    sources = [ROOT / "CMakeLists.txt", *sorted((ROOT / "csrc").rglob("*.cc")), *sorted((ROOT / "csrc").rglob("*.h"))]
    pattern = re.compile(r"-march=|-mtune=native|-mcpu=native|-mavx|-msse4|-mfma|#pragma GCC target")
    found = [str(p.relative_to(ROOT)) for p in sources if pattern.search(p.read_text(encoding="utf-8"))]
    assert found == []


@pytest.mark.parametrize("value, expected", [
    (None, f"VOXAX_NUM_THREADS unset: all {os.cpu_count()} hardware threads"),
    ("3", "VOXAX_NUM_THREADS=3: 3 threads"),
    ("0", f"VOXAX_NUM_THREADS=0: all {os.cpu_count()} hardware threads"),
    ("many", "VOXAX_NUM_THREADS='many' is not an integer: calls without `threads` raise ValueError"),
])
def test_show_config_thread_rule(monkeypatch, value, expected):
    if value is None:
        monkeypatch.delenv("VOXAX_NUM_THREADS", raising=False)
    else:
        monkeypatch.setenv("VOXAX_NUM_THREADS", value)
    assert _config()["threads"].startswith(expected + " (eager host calls without `threads`)")
    if value == "many":  # the rule show_config describes is the one the calls use
        with pytest.raises(ValueError):
            voxax._kernels.threads(None)
    else:
        assert voxax._kernels.threads(None) == (int(value) if value else 0)


def test_cli_version(capsys):
    assert cli.main(["--version"]) == 0
    assert capsys.readouterr().out == f"voxax {voxax.__version__}\n"
    assert cli.main(["--version", "--verbose"]) == 0
    out = capsys.readouterr().out
    text = io.StringIO()
    voxax.show_config(file=text)
    assert out == text.getvalue()
