"""The notebooks in notebooks/: each executes without error in its small (CI) configuration.

Executing them is slow (compilation of every stage they show): those tests are marked ``slow``
and run with ``pytest -m slow``; the check that every notebook is saved clean and uses only the
public API always runs.

Every ``notebooks/*.ipynb`` runs top to bottom in a fresh Jupyter kernel with
``TACTOJAX_NOTEBOOK_SMALL=1``, in a temporary working directory. The kernel is pinned to the
interpreter running pytest (a kernelspec written for ``sys.executable`` first on
``JUPYTER_PATH``), so a user-level ``python3`` kernel of another environment is never used; a
cell appended to the in-memory copy checks that.
"""

import json
import re
import sys
from pathlib import Path

import nbformat
import pytest
from ipykernel.kernelspec import write_kernel_spec
from nbclient import NotebookClient

NOTEBOOK_DIR = Path(__file__).resolve().parent.parent / "notebooks"
NOTEBOOKS = sorted(NOTEBOOK_DIR.glob("*.ipynb"))
CELL_TIMEOUT_S = 300
KERNEL_NAME = "python3"
PRIVATE_IMPORT = re.compile(r"\btactojax(?:\.\w+)*\._(?!_)\w*")  # tactojax.shape._train, not __version__


def test_notebooks_exist():
    assert NOTEBOOKS, f"no notebooks in {NOTEBOOK_DIR}"


@pytest.mark.parametrize("path", NOTEBOOKS, ids=[p.name for p in NOTEBOOKS])
def test_notebook_is_saved_clean_and_uses_public_api(path):
    notebook = nbformat.read(path, as_version=4)
    nbformat.validate(notebook)
    code = [cell for cell in notebook.cells if cell.cell_type == "code"]
    with_outputs = [i for i, cell in enumerate(code) if cell.outputs or cell.execution_count]
    assert not with_outputs, f"{path.name}: clear the outputs of code cells {with_outputs} before saving"
    private = [m.group(0) for cell in code for m in PRIVATE_IMPORT.finditer(cell.source)]
    assert not private, f"{path.name} uses private modules {private}; notebooks import only the public API"
    assert any("TACTOJAX_NOTEBOOK_SMALL" in cell.source for cell in code), \
        f"{path.name} must read TACTOJAX_NOTEBOOK_SMALL to pick its small CI configuration"


@pytest.fixture
def pinned_kernel(tmp_path, monkeypatch):
    """A ``python3`` kernelspec for this interpreter, first on the Jupyter search path."""
    spec_dir = tmp_path / "jupyter" / "kernels" / KERNEL_NAME
    write_kernel_spec(spec_dir)
    argv = json.loads((spec_dir / "kernel.json").read_text())["argv"]
    assert argv[0] == sys.executable
    monkeypatch.setenv("JUPYTER_PATH", str(tmp_path / "jupyter"))
    return KERNEL_NAME


@pytest.mark.slow
@pytest.mark.parametrize("path", NOTEBOOKS, ids=[p.name for p in NOTEBOOKS])
def test_notebook_executes_small(path, tmp_path, monkeypatch, pinned_kernel):
    monkeypatch.setenv("TACTOJAX_NOTEBOOK_SMALL", "1")
    workdir = tmp_path / "run"
    workdir.mkdir()
    notebook = nbformat.read(path, as_version=4)
    notebook.cells.append(nbformat.v4.new_code_cell("import sys; print(sys.executable, end='')"))
    client = NotebookClient(notebook, kernel_name=pinned_kernel, timeout=CELL_TIMEOUT_S,
                            resources={"metadata": {"path": str(workdir)}})
    client.execute()  # raises CellExecutionError, with the traceback, if any cell fails

    errors = [output for cell in notebook.cells if cell.cell_type == "code"
              for output in cell.outputs if output.output_type == "error"]
    assert not errors
    kernel_executable = "".join(output.text for output in notebook.cells[-1].outputs
                                if output.output_type == "stream" and output.name == "stdout")
    assert Path(kernel_executable) == Path(sys.executable), "the notebook ran in another interpreter"
