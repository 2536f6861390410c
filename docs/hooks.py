"""mkdocs hooks: pull generated content into the docs at build time.

- `<!-- benchmark-results -->` (performance.md) becomes the results section of
  `benchmarks/README.md` (between its `<!-- results -->` markers); images it references
  under `benchmarks/results/` are copied into the site.
- `<!-- cli-help -->` (cli.md) becomes the `--help` text of `voxax` and each subcommand,
  from `voxax.cli.build_parser()` (loaded from `src/voxax/cli.py` without importing the
  package, so the docs build without the compiled kernels).
- `<!-- setup-commands -->` (index.md) becomes the README's set-up commands block.
"""

from __future__ import annotations

import importlib.util
import os
import re
import sys

from mkdocs.structure.files import File

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
BENCH = os.path.join(ROOT, "benchmarks")
_IMAGE = re.compile(r"!\[([^\]]*)\]\(([^)\s]+)\)")


def _between(text: str, begin: str, end: str, what: str) -> str:
    """The lines between a line holding only `begin` and the next holding only `end`."""
    match = re.search(rf"^{re.escape(begin)}[ \t]*\n(.*?)^{re.escape(end)}[ \t]*$", text, re.MULTILINE | re.DOTALL)
    if match is None:
        raise ValueError(f"docs/hooks.py: no {begin} ... {end} section (markers on lines of their own) in {what}")
    return match.group(1).strip("\n")


def _benchmark_results() -> tuple[str, list[str]]:
    path = os.path.join(BENCH, "README.md")
    if not os.path.exists(path):
        return "The benchmarks have not been run yet (no `benchmarks/README.md`).", []
    with open(path, encoding="utf-8") as fh:
        block = _between(fh.read(), "<!-- results -->", "<!-- /results -->", "benchmarks/README.md")
    images = []

    def relink(match):
        alt, target = match.groups()
        if "://" in target:
            return match.group(0)
        source = os.path.normpath(os.path.join(BENCH, target))
        if not os.path.exists(source):
            return f"*(figure `{target}` not found)*"
        name = "benchmarks/" + os.path.relpath(source, BENCH).replace(os.sep, "/")
        images.append((name, source))
        return f"![{alt}]({name})"

    return _IMAGE.sub(relink, block), images


def _load_cli():
    spec = importlib.util.spec_from_file_location("_voxax_cli_for_docs", os.path.join(ROOT, "src", "voxax", "cli.py"))
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module  # dataclasses look their module up there
    try:
        spec.loader.exec_module(module)
    finally:
        del sys.modules[spec.name]
    return module


def _cli_help() -> str:
    parser = _load_cli().build_parser()
    os.environ["COLUMNS"] = "100"  # argparse wraps at the terminal width
    parts = [f"```text\n$ voxax --help\n{parser.format_help().rstrip()}\n```"]
    sub = next(a for a in parser._actions if a.__class__.__name__ == "_SubParsersAction")
    for name, p in sub.choices.items():
        parts.append(f"### `voxax {name}`\n\n```text\n$ voxax {name} --help\n{p.format_help().rstrip()}\n```")
    return "\n\n".join(parts)


def _setup_commands() -> str:
    with open(os.path.join(ROOT, "README.md"), encoding="utf-8") as fh:
        return _between(fh.read(), "<!-- setup-commands -->", "<!-- /setup-commands -->", "README.md")


def on_files(files, config):
    for name, source in _benchmark_results()[1]:
        files.append(File.generated(config, name, abs_src_path=source))
    return files


def on_page_markdown(markdown, page, config, files):
    if "<!-- benchmark-results -->" in markdown:
        markdown = markdown.replace("<!-- benchmark-results -->", _benchmark_results()[0])
    if "<!-- cli-help -->" in markdown:
        markdown = markdown.replace("<!-- cli-help -->", _cli_help())
    if "<!-- setup-commands -->" in markdown:
        markdown = markdown.replace("<!-- setup-commands -->", _setup_commands())
    return markdown
