"""Every notebook in notebooks/ runs top to bottom with the quick settings (CI check).

``GPJAX_NOTEBOOK_QUICK=1`` makes each notebook use tiny settings (population 40, 1–2
generations, one seed, two intervals); the committed outputs come from the full settings.
"""

from pathlib import Path

import nbclient
import nbformat
import pytest

NOTEBOOKS = Path(__file__).resolve().parents[1] / "notebooks"
PATHS = sorted(NOTEBOOKS.glob("*.ipynb"))
#: Largest committed notebook, in bytes (outputs must stay small).
MAX_BYTES = 1_000_000


def test_notebooks_are_small_state_a_question_and_end_with_findings():
    assert len(PATHS) >= 4
    for path in PATHS:
        assert path.stat().st_size < MAX_BYTES, f"{path.name} is {path.stat().st_size} bytes"
        cells = nbformat.read(path, as_version=4).cells
        assert "**Question.**" in cells[0].source, f"{path.name} states no question first"
        assert "Full settings take" in cells[0].source, (
            f"{path.name} does not state how long its full settings take")
        assert cells[-1].cell_type == "markdown" and cells[-1].source.startswith(
            "## What it found"), f"{path.name} does not end with its findings"


@pytest.mark.slow
@pytest.mark.parametrize("path", PATHS, ids=[p.stem for p in PATHS])
def test_notebook_runs_with_quick_settings(path, monkeypatch):
    monkeypatch.setenv("GPJAX_NOTEBOOK_QUICK", "1")
    monkeypatch.setenv("JAX_PLATFORMS", "cpu")
    notebook = nbformat.read(path, as_version=4)
    client = nbclient.NotebookClient(notebook, timeout=600, kernel_name="python3",
                                     resources={"metadata": {"path": str(NOTEBOOKS)}})
    client.execute()
    kinds = {output.get("output_type") for cell in notebook.cells
             for output in cell.get("outputs", [])}
    assert "error" not in kinds
    images = sum("image/png" in output.get("data", {}) for cell in notebook.cells
                 for output in cell.get("outputs", []))
    assert images >= 1, f"{path.name} shows no plot"
