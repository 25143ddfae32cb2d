"""The `replicacad` benchmark suite on the ReplicaCAD sample beside the repository."""

import os
from pathlib import Path

import pytest

from vamg_drake.bench.suites import SuiteError, materialize_suite, suite_config
from vamg_drake.world.replicacad import ReplicaCadError, find_replicacad_dir

_SAMPLE = Path(__file__).resolve().parents[2] / "shared" / "replicacad"


def _sample_dir():
    try:
        return find_replicacad_dir(os.environ.get("VAMG_REPLICACAD_DIR") or str(_SAMPLE))
    except ReplicaCadError:
        return None


DATASET = _sample_dir()


@pytest.mark.skipif(DATASET is None, reason=f"ReplicaCAD sample not found (set VAMG_REPLICACAD_DIR or provide {_SAMPLE})")
def test_replicacad_suite_materializes_valid_scenarios(tmp_path, monkeypatch):
    monkeypatch.setenv("VAMG_REPLICACAD_DIR", str(DATASET))
    suite = materialize_suite(suite_config("replicacad", scenes=1, targets=1), tmp_path, progress=False)
    assert len(suite.scenarios) == 1, suite.excluded
    for s in suite.scenarios:
        scenario = suite.load(s)  # validates the file
        assert scenario.replicacad is not None and scenario.replicacad.scene == "apt_0"
        assert scenario.name.startswith("replicacad_apt_0_")


def test_replicacad_suite_without_the_dataset_is_a_clear_error(tmp_path, monkeypatch):
    monkeypatch.setenv("VAMG_REPLICACAD_DIR", str(tmp_path / "nowhere"))
    monkeypatch.setenv("MS_ASSET_DIR", str(tmp_path / "nowhere"))
    monkeypatch.setenv("HOME", str(tmp_path))
    with pytest.raises((SuiteError, ReplicaCadError), match="ReplicaCAD"):
        materialize_suite(suite_config("replicacad", scenes=1, targets=1), tmp_path / "out", progress=False)
