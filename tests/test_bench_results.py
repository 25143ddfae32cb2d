"""results.jsonl: append, truncated-last-line repair (a killed sweep), clear errors."""

import json

import pytest

from vamg_drake.bench.results import (
    CATEGORIES,
    OTHER,
    EpisodeRecord,
    ResultsError,
    ResultsWriter,
    category_of,
    finished_keys,
    load_records,
    repair_truncated_tail,
)


def _record(key: str, status: str = "success") -> EpisodeRecord:
    return EpisodeRecord(key=key, suite="smoke", method="full", scene=0, target_index=0, target="apple",
                         trigger_distance=None, run_seed=0, scenario="s", status=status)


def test_append_and_load(tmp_path):
    path = tmp_path / "results.jsonl"
    with ResultsWriter(path) as w:
        w.append(_record("a"))
        w.append(_record("b", "collision"))
    records = load_records(tmp_path)
    assert [r["key"] for r in records] == ["a", "b"]
    assert finished_keys(path) == {"a", "b"}


def test_truncated_last_line_is_moved_aside_not_lost(tmp_path):
    path = tmp_path / "results.jsonl"
    with ResultsWriter(path) as w:
        w.append(_record("a"))
        w.append(_record("b"))
    whole = path.read_bytes()
    fragment = _record("c").to_json_line()[:40]
    with open(path, "a") as f:
        f.write(fragment)
    # Reading without repair skips it (the report does not modify files).
    assert [r["key"] for r in load_records(path)] == ["a", "b"]
    assert path.read_bytes() == whole + fragment.encode()
    # Resuming repairs: the file is cut back to its whole lines, the fragment kept.
    assert finished_keys(path) == {"a", "b"}
    assert path.read_bytes() == whole
    assert (tmp_path / "results.jsonl.corrupt").read_text() == fragment + "\n"
    assert repair_truncated_tail(path) == ""


def test_whole_record_missing_only_its_newline_is_kept(tmp_path):
    path = tmp_path / "results.jsonl"
    path.write_text(_record("a").to_json_line() + _record("b").to_json_line().rstrip("\n"))
    assert finished_keys(path) == {"a", "b"}
    assert path.read_text().endswith("\n")
    assert not (tmp_path / "results.jsonl.corrupt").exists()


def test_bad_line_in_the_middle_names_file_and_line(tmp_path):
    path = tmp_path / "results.jsonl"
    path.write_text(_record("a").to_json_line() + "{oops\n" + _record("b").to_json_line())
    with pytest.raises(ResultsError, match=r"results.jsonl:2: not a JSON record"):
        load_records(path)
    path.write_text(json.dumps({"key": "x"}) + "\n")
    with pytest.raises(ResultsError, match="'key' and 'status'"):
        load_records(path)
    with pytest.raises(FileNotFoundError, match="no results file"):
        load_records(tmp_path / "missing")


def test_categories_are_the_papers():
    assert CATEGORIES == ("success", "collision", "grasp", "ik", "reachability", "perception", "planning")
    assert category_of("planning") == "planning"
    assert category_of("timeout") == OTHER
    assert category_of("error") == OTHER
