"""The notebooks in notebooks/: stored without outputs, in sync with their generator, and
each runs top to bottom (at small sizes) in a kernel of the current interpreter."""

import importlib.util
import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

nbformat = pytest.importorskip("nbformat")
nbclient = pytest.importorskip("nbclient")
pytest.importorskip("ipykernel")

ROOT = Path(__file__).resolve().parents[1]
NOTEBOOK_DIR = ROOT / "notebooks"
NOTEBOOKS = sorted(NOTEBOOK_DIR.glob("*.ipynb"))
CELL_TIMEOUT = 300  # seconds per cell

# The small sizes every notebook runs at here, injected after its `parameters` cell.
SMALL = {
    "01_quickstart": {"RESOLUTION": 24},
    "02_gradients": {"RESOLUTION": 16},
    "03_self_intersections": {"RESOLUTION": 32, "MAX_STEPS": 40, "MAX_ROUNDS": 1},
    "04_bandsaw": {"RESOLUTION": 24, "MAX_STEPS": 15},
    "05_tiling": {"RESOLUTION": 24, "MAX_STEPS": 10},
    "06_batches": {"RESOLUTION": 16, "FAMILY": 4},
    "07_meshsdf": {"RESOLUTION": 16},
    "08_faithful_contouring": {"RESOLUTION": 32, "SAMPLES": 10_000},
    "09_cvt": {"N_SEEDS": 200, "METHOD": "lloyd", "STEPS": 10},
    "10_explicit_surfaces": {"RESOLUTION": 32, "N_DHF": 4, "N_HF": 4, "MAX_HF": 1, "N_SAMPLES": 1000,
                             "N_POINTS": 2000, "MOLD_RESOLUTION": 16, "MOLD_STEPS": 5},
}


def _load_generator():
    spec = importlib.util.spec_from_file_location("make_notebooks", NOTEBOOK_DIR / "make_notebooks.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_the_notebooks_are_all_there_and_in_sync_with_the_generator():
    assert [p.stem for p in NOTEBOOKS] == sorted(SMALL)
    built = _load_generator().build()
    assert sorted(built) == [p.name for p in NOTEBOOKS]
    for path in NOTEBOOKS:
        stored = json.loads(path.read_text(encoding="utf-8"))
        fresh = json.loads(nbformat.writes(built[path.name]))
        assert stored == fresh, f"{path.name} differs from notebooks/make_notebooks.py: run it to regenerate"


@pytest.mark.parametrize("path", NOTEBOOKS, ids=[p.stem for p in NOTEBOOKS])
def test_notebook_is_stored_without_outputs_and_has_one_parameters_cell(path):
    nb = nbformat.read(path, as_version=4)
    code = [c for c in nb.cells if c.cell_type == "code"]
    for cell in code:
        assert cell.outputs == [] and cell.execution_count is None, f"{path.name}: strip the outputs"
    tagged = [c for c in code if "parameters" in c.metadata.get("tags", [])]
    assert len(tagged) == 1, f"{path.name}: needs exactly one cell tagged 'parameters'"
    for name in SMALL[path.stem]:
        assert f"\n{name} = " in "\n" + tagged[0].source
    assert 'importlib.util.find_spec("voxax")' in code[0].source  # the Colab-style install cell
    if path.stem == "06_batches":  # devices are simulated before JAX is imported
        assert "xla_force_host_platform_device_count" in code[0].source
        assert "import jax" not in code[0].source


def _kernel_manager(folder: Path):
    """A kernel running this very interpreter (no user-level kernelspec needed)."""
    from jupyter_client.kernelspec import KernelSpecManager
    from jupyter_client.manager import KernelManager

    spec_dir = folder / "kernels" / "voxax-test"
    spec_dir.mkdir(parents=True, exist_ok=True)
    (spec_dir / "kernel.json").write_text(json.dumps({
        "argv": [sys.executable, "-m", "ipykernel_launcher", "-f", "{connection_file}"],
        "display_name": "voxax test kernel",
        "language": "python",
    }))
    ksm = KernelSpecManager(kernel_dirs=[str(folder / "kernels")])
    return KernelManager(kernel_name="voxax-test", kernel_spec_manager=ksm)


def execute(source: str, target: str, work: str, parameters: str) -> int:
    """Runs the notebook `source` in the folder `work` with `parameters` (JSON) injected
    after its parameters cell, and writes the executed notebook to `target`.

    Runs in a subprocess of the test (`python tests/test_notebooks.py ...`), so that the
    kernel's sockets and event loops stay out of the pytest process.
    """
    nb = nbformat.read(source, as_version=4)
    index = next(i for i, c in enumerate(nb.cells) if "parameters" in c.metadata.get("tags", []))
    values = "\n".join(f"{k} = {v!r}" for k, v in json.loads(parameters).items())
    injected = nbformat.v4.new_code_cell("# Injected by tests/test_notebooks.py\n" + values)
    injected.metadata["tags"] = ["injected-parameters"]
    nb.cells.insert(index + 1, injected)
    client = nbclient.NotebookClient(
        nb, km=_kernel_manager(Path(target).parent), timeout=CELL_TIMEOUT, resources={"metadata": {"path": work}}
    )
    status = 0
    try:
        client.execute()
    except nbclient.exceptions.CellExecutionError as err:
        print(err, file=sys.stderr)
        status = 1
    nbformat.write(nb, target)
    return status


@pytest.mark.parametrize("path", NOTEBOOKS, ids=[p.stem for p in NOTEBOOKS])
def test_notebook_runs(path, tmp_path):
    # The kernel inherits the environment: make PYTHONPATH absolute (the notebooks run in
    # a temporary folder, where their output files go); let the kernel pick its backend.
    env = dict(os.environ)
    paths = [p for p in env.get("PYTHONPATH", "").split(os.pathsep) if p]
    if paths:
        env["PYTHONPATH"] = os.pathsep.join(os.path.abspath(p) for p in paths)
    for name in ("MPLBACKEND", "XLA_FLAGS"):
        env.pop(name, None)
    env.update(JUPYTER_PLATFORM_DIRS="1", PYDEVD_DISABLE_FILE_VALIDATION="1")
    work = tmp_path / "run"
    work.mkdir()
    target = tmp_path / path.name
    proc = subprocess.run(
        [sys.executable, __file__, str(path), str(target), str(work), json.dumps(SMALL[path.stem])],
        env=env, capture_output=True, text=True, timeout=CELL_TIMEOUT * 4,
    )
    assert proc.returncode == 0, f"{path.name} failed:\n{proc.stdout[-4000:]}\n{proc.stderr[-8000:]}"

    nb = nbformat.read(target, as_version=4)
    outputs = [o for c in nb.cells if c.cell_type == "code" for o in c.outputs]
    assert not [o for o in outputs if o.output_type == "error"]
    assert [o for o in outputs if "image/png" in o.get("data", {})], f"{path.name} showed no figure"
    assert all(c.execution_count is not None for c in nb.cells if c.cell_type == "code")


if __name__ == "__main__":
    sys.exit(execute(*sys.argv[1:]))
