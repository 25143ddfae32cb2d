"""The quickstart notebook builds, draws, steps and replays the demo episode."""

from pathlib import Path

import nbformat
import pytest
from nbclient import NotebookClient

ROOT = Path(__file__).resolve().parents[1]


@pytest.mark.slow
def test_quickstart_notebook_runs_the_demo_episode_to_success(tmp_path, monkeypatch):
    monkeypatch.setenv("VAMG_QUICKSTART_OUT", str(tmp_path))
    monkeypatch.setenv("MPLBACKEND", "Agg")
    nb = nbformat.read(ROOT / "notebooks" / "quickstart.ipynb", as_version=4)
    NotebookClient(nb, timeout=900, kernel_name="python3", resources={"metadata": {"path": str(ROOT / "notebooks")}}).execute()
    outputs = [o for cell in nb.cells if cell.cell_type == "code" for o in cell.get("outputs", [])]
    assert not [o for o in outputs if o.output_type == "error"]
    text = "".join(o.get("text", "") for o in outputs if o.output_type == "stream")
    assert "success at" in text, text
    images = [o for o in outputs if o.output_type == "display_data" and "image/png" in o.get("data", {})]
    assert len(images) == 1  # the four panels of logged signals
    tables = "".join(o["data"].get("text/markdown", "") for o in outputs if o.output_type == "display_data")
    assert "| depth_render |" in tables
    if "replay:" in text:  # Meshcat found a free port
        assert (tmp_path / "replay.html").stat().st_size > 1e5
