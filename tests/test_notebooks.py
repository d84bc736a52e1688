"""The notebooks in notebooks/ execute without error and are stored without outputs.

Each notebook synthesises its own small data in a temporary folder, runs the pipeline through the public
API and asserts its results against the synthetic truth inside its cells (an assertion failing in a cell
fails the test). They run in a fresh ``python3`` kernel (ipykernel) with a temporary working directory;
the repository root is put on the kernel's PYTHONPATH so that an uninstalled checkout works too.
"""

from __future__ import annotations

import os
import time
from pathlib import Path

import pytest

nbformat = pytest.importorskip("nbformat")
nbclient = pytest.importorskip("nbclient")
pytest.importorskip("ipykernel")

ROOT = Path(__file__).resolve().parents[1]
NOTEBOOKS = sorted((ROOT / "notebooks").glob("*.ipynb"))
EXPECTED = {"01_calibrate_a_camera.ipynb", "02_survey_photos_to_radiance.ipynb",
            "03_secchi_disk_chlorophyll.ipynb", "04_lamp_tank_experiment.ipynb", "05_sunlit_survey_day.ipynb",
            "06_phone_in_the_field.ipynb"}
TIMEOUT_S = 300.0  # per notebook (all its cells together); each takes ≈ 10-15 s on 2 cores


def test_expected_notebooks_exist():
    assert EXPECTED <= {p.name for p in NOTEBOOKS}


@pytest.mark.parametrize("path", NOTEBOOKS, ids=lambda p: p.stem)
def test_stored_without_outputs(path):
    nb = nbformat.read(path, as_version=4)
    nbformat.validate(nb)
    code = [c for c in nb.cells if c.cell_type == "code"]
    assert code, "a notebook without code"
    for i, cell in enumerate(code):
        assert cell.get("outputs") == [], f"code cell {i} has stored outputs (clear them before committing)"
        assert cell.get("execution_count") is None, f"code cell {i} has an execution count"


@pytest.mark.slow
@pytest.mark.parametrize("path", NOTEBOOKS, ids=lambda p: p.stem)
def test_notebook_executes(path, tmp_path, monkeypatch):
    from nbclient import NotebookClient

    monkeypatch.setenv("PYTHONPATH", os.pathsep.join(filter(None, [str(ROOT), os.environ.get("PYTHONPATH")])))
    monkeypatch.setenv("MPLBACKEND", "module://matplotlib_inline.backend_inline")
    monkeypatch.chdir(tmp_path)
    nb = nbformat.read(path, as_version=4)
    deadline = time.monotonic() + TIMEOUT_S
    # nbclient's timeout is per cell: give each cell what is left of the notebook's budget
    client = NotebookClient(nb, timeout=int(TIMEOUT_S), kernel_name="python3",
                            timeout_func=lambda cell: max(1, int(deadline - time.monotonic())),
                            resources={"metadata": {"path": str(tmp_path)}})
    client.execute()  # raises CellExecutionError (with the cell and the traceback) on any error
    errors = [o for c in nb.cells if c.cell_type == "code" for o in c.outputs if o.output_type == "error"]
    assert not errors
    figures = sum("image/png" in o.get("data", {}) for c in nb.cells if c.cell_type == "code" for o in c.outputs)
    assert figures >= 2, "each notebook shows its results as figures"
    # the notebook wrote only into its own temporary folder
    assert not any(tmp_path.iterdir()), sorted(p.name for p in tmp_path.iterdir())
