"""Every notebook in notebooks/ runs top to bottom without an error (nbclient, a real kernel).

Notebooks read STT_DRAKE_NOTEBOOK_TEST=1 to shorten what they can; figures must render
inline, so the kernel runs without the Agg backend the rest of the suite uses.
"""

from __future__ import annotations

from pathlib import Path

import nbclient
import nbformat
import pytest

NOTEBOOKS = sorted((Path(__file__).resolve().parents[2] / "notebooks").glob("*.ipynb"))


def test_the_case_study_notebooks_exist():
    names = {path.name for path in NOTEBOOKS}
    assert {
        "00_build_your_own_diagram.ipynb",
        "01_omni_hardware_cases.ipynb",
        "02_cluttered_2d.ipynb",
        "03_uav.ipynb",
        "04_franka.ipynb",
    } <= names


@pytest.mark.notebook
@pytest.mark.parametrize("path", NOTEBOOKS, ids=[p.stem for p in NOTEBOOKS])
def test_notebook_runs_and_shows_figures(path, monkeypatch):
    monkeypatch.setenv("STT_DRAKE_NOTEBOOK_TEST", "1")
    monkeypatch.delenv("MPLBACKEND", raising=False)
    notebook = nbformat.read(path, as_version=4)
    nbclient.NotebookClient(
        notebook, timeout=300, kernel_name="python3", resources={"metadata": {"path": path.parent}}
    ).execute()
    outputs = [o for cell in notebook.cells if cell.cell_type == "code" for o in cell.outputs]
    assert not [o for o in outputs if o.output_type == "error"]
    assert any("image/png" in o.get("data", {}) for o in outputs), "no figure was shown"
