"""The analysis notebook runs on a small committed results directory."""

import os
from pathlib import Path

import nbformat
from nbclient import NotebookClient

ROOT = Path(__file__).resolve().parents[1]


def test_analysis_notebook_executes(tmp_path, monkeypatch):
    monkeypatch.setenv("VAMG_RESULTS_DIR", str(ROOT / "tests" / "data" / "bench_small"))
    monkeypatch.setenv("MPLBACKEND", "Agg")
    nb = nbformat.read(ROOT / "notebooks" / "analysis.ipynb", as_version=4)
    NotebookClient(nb, timeout=300, kernel_name="python3", resources={"metadata": {"path": str(ROOT / "notebooks")}}).execute()
    outputs = [o for cell in nb.cells if cell.cell_type == "code" for o in cell.get("outputs", [])]
    assert not [o for o in outputs if o.output_type == "error"]
    text = "".join(o.get("text", "") for o in outputs if o.output_type == "stream")
    assert "8 episodes" in text
    images = [o for o in outputs if o.output_type == "display_data" and "image/png" in o.get("data", {})]
    assert len(images) >= 5  # success, failures, SPL, per-scene, compute cost
    tables = "".join(o["data"].get("text/markdown", "") for o in outputs if o.output_type == "display_data")
    assert "| smoke | full | 2 |" in tables
