"""Every `>>>` example in the docstrings of voxax's modules runs and prints what it shows.

The examples run with the module's own globals plus `voxax`, `np` (NumPy), `jax` and
`jnp` (jax.numpy), in float64 (see conftest.py), with ELLIPSIS and NORMALIZE_WHITESPACE.
"""

import doctest
import importlib
import importlib.util
import os
import pkgutil
import re

import matplotlib

matplotlib.use("Agg")

import jax  # noqa: E402
import jax.numpy as jnp  # noqa: E402
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
import pytest  # noqa: E402

import voxax  # noqa: E402

# Modules that are not part of the documented API (the kernel loader).
_SKIP = {"voxax._kernels._loader"}
_FLAGS = doctest.ELLIPSIS | doctest.NORMALIZE_WHITESPACE


_FENCE = re.compile(r"^[ \t]*```[\w-]*[ \t]*$", re.MULTILINE)


class _MarkdownParser(doctest.DocTestParser):
    """Docstrings are Markdown: examples sit in ```python fences. A fence line becomes a
    blank line (which ends an example's expected output; line numbers stay the same)."""

    def parse(self, string, name="<string>"):
        return super().parse(_FENCE.sub("", string), name)


def _modules():
    names = ["voxax"]
    for info in pkgutil.walk_packages(voxax.__path__, prefix="voxax."):
        spec = importlib.util.find_spec(info.name)
        # Python sources only (not the compiled kernel library).
        if info.name not in _SKIP and spec is not None and str(spec.origin).endswith(".py"):
            names.append(info.name)
    return sorted(names)


def _doctests():
    finder = doctest.DocTestFinder(parser=_MarkdownParser(), exclude_empty=True)
    extra = {"voxax": voxax, "np": np, "jax": jax, "jnp": jnp}
    tests, seen = [], set()
    for name in _modules():
        module = importlib.import_module(name)
        for test in finder.find(module, name, extraglobs=extra):
            if test.examples and test.name not in seen:
                seen.add(test.name)
                tests.append(test)
    return sorted(tests, key=lambda t: t.name)


_TESTS = _doctests()


def test_every_public_module_is_searched():
    modules = set(_modules())
    for name in ("voxax._grid", "voxax._voxelize.api", "voxax._mesh", "voxax.data", "voxax.io", "voxax.plot",
                 "voxax._optimize.minimization", "voxax.energies"):
        assert name in modules
    assert len(_TESTS) >= 20


@pytest.mark.parametrize("test", _TESTS, ids=[t.name for t in _TESTS])
def test_docstring_example(test, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)  # examples that write files write them here
    runner = doctest.DocTestRunner(optionflags=_FLAGS)
    out = []
    try:
        result = runner.run(test, out=out.append, clear_globs=True)
    finally:
        plt.close("all")
    assert result.failed == 0, f"{test.name} ({os.path.relpath(test.filename or '?')}):\n" + "".join(out)
