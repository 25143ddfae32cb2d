"""The benchmark runner: smoke suite end to end, kill + resume, isolation, bad input, Ray."""

import json
import os
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

import bench_faults
from vamg_drake.bench.methods import load_methods
from vamg_drake.bench.results import CATEGORIES, ERROR, OTHER, load_records
from vamg_drake.bench.runner import episode_specs, run_isolated, run_sweep
from vamg_drake.bench.suites import SUITES, materialize_suite
from vamg_drake.cli import main

ROOT = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="module")
def smoke_root(tmp_path_factory):
    """The smoke suite, built once (2 validated scenarios, 3 s time limit)."""
    root = tmp_path_factory.mktemp("smoke_suite")
    suite = materialize_suite(SUITES["smoke"], root, progress=False)
    assert len(suite.scenarios) == 2
    return root


def _out_with_suite(smoke_root: Path, out: Path) -> Path:
    shutil.copytree(smoke_root / "suites", out / "suites")
    return out


@pytest.mark.slow
def test_smoke_suite_end_to_end_for_two_methods(smoke_root, tmp_path):
    out = _out_with_suite(smoke_root, tmp_path / "run")
    assert main(["bench", "--suite", "smoke", "--methods", "full,velocity_agnostic", "--out", str(out), "--quiet"]) == 0
    records = load_records(out)
    assert sorted(r["key"] for r in records) == sorted(
        f"smoke/{m}/{s}/static/r0" for m in ("full", "velocity_agnostic") for s in ("s0000_t00", "s0001_t00"))
    for r in records:
        assert r["status"] in CATEGORIES or r["status"] == ERROR, r
        assert r["shortest_path"] is not None and r["shortest_path"] > 0
        # Each episode keeps its own log, result and top-down plot beside results.jsonl.
        episode = out / r["episode_dir"]
        assert r["episode_dir"] == "episodes/" + r["key"].replace("/", "__")
        assert json.loads((episode / "episode.json").read_text())["status"] == r["status"]
        assert f"episode {r['scenario']}: {r['status']}" in (episode / "episode.log").read_text()
        assert (episode / "topdown.png").stat().st_size > 0
    assert main(["report", str(out)]) == 0
    report = (out / "report.md").read_text()
    assert "| smoke | velocity_agnostic | 2 |" in report and "| smoke | full | 2 |" in report
    failed = [r for r in records if r["status"] != "success"]
    assert failed, "a 3 s smoke episode cannot succeed"
    for r in failed:
        assert f"| {r['method']} | {r['scenario']} | {r['target']} | {r['status']}" in report
        assert f"[log]({r['episode_dir']}/episode.log)" in report
    for png in ("success_rates.png", "failures.png", "spl.png", "per_scene.png"):
        assert (out / png).stat().st_size > 0


def test_kill_and_resume_loses_and_duplicates_nothing(smoke_root, tmp_path):
    out = _out_with_suite(smoke_root, tmp_path / "run")
    results = out / "results.jsonl"
    cmd = [sys.executable, "-m", "vamg_drake.cli", "bench", "--suite", "smoke", "--methods", "scripted,scripted_slow",
           "--out", str(out), "--quiet"]
    proc = subprocess.Popen(cmd, cwd=ROOT, start_new_session=True, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    try:
        deadline = time.time() + 240
        while time.time() < deadline and not (results.is_file() and results.read_text().count("\n") >= 1):
            time.sleep(0.2)
    finally:
        os.killpg(proc.pid, signal.SIGKILL)  # the sweep and its workers
        proc.wait()
    before = results.read_text()
    n_before = before.count("\n")
    assert 1 <= n_before < 4, "the sweep should have been killed part-way"
    # A kill in the middle of a write leaves a fragment; resume must not trip over it.
    fragment = '{"key":"smoke/scripted/s0001_t00/static/r0","suite":"sm'
    with open(results, "a") as f:
        f.write(fragment)
    # Without --resume nothing is overwritten.
    with pytest.raises(SystemExit, match="--resume"):
        main(cmd[3:])
    assert main([*cmd[3:], "--resume"]) == 0
    after = results.read_text()
    assert after.startswith(before)  # finished lines kept byte for byte
    keys = [json.loads(line)["key"] for line in after.splitlines()]
    expected = {f"smoke/{m}/{s}/static/r0" for m in ("scripted", "scripted_slow") for s in ("s0000_t00", "s0001_t00")}
    assert len(keys) == len(set(keys)) == 4 and set(keys) == expected
    assert fragment in (out / "results.jsonl.corrupt").read_text()
    # A resume of a finished sweep runs nothing.
    assert main([*cmd[3:], "--resume"]) == 0
    assert results.read_text() == after


def test_crash_hang_and_exception_become_recorded_errors(smoke_root, tmp_path):
    suite = materialize_suite(SUITES["smoke"], smoke_root, progress=False)
    spec = episode_specs(suite, load_methods(["scripted"]), 1)[0]
    crashed = run_isolated(spec, bench_faults.crashing_episode, wall_limit=120)
    assert crashed.status == ERROR and "exit code 7" in crashed.error
    hung = run_isolated(spec, bench_faults.hanging_episode, wall_limit=6)
    assert hung.status == ERROR and "wall-clock limit 6 s" in hung.error
    raised = run_isolated(spec, bench_faults.raising_episode, wall_limit=120)
    assert raised.status == ERROR and "boom in" in raised.error
    # In a sweep the failures are lines of results.jsonl like any other.
    specs = episode_specs(suite, load_methods(["scripted"]), 1)
    written = run_sweep(specs, tmp_path, episode_fn=bench_faults.crashing_episode, progress=False, workers=2)
    assert [r.status for r in written] == [ERROR, ERROR]
    assert len(load_records(tmp_path)) == 2


def test_the_sweep_prepares_the_episode_caches_once_before_its_episodes(smoke_root, tmp_path, monkeypatch):
    from vamg_drake.bench.runner import prepare_episode_caches
    from vamg_drake.policy.kinematic_maps import KinematicMaps

    suite = materialize_suite(SUITES["smoke"], smoke_root, progress=False)
    specs = episode_specs(suite, load_methods(["scripted"]), 1)
    calls = []
    run_sweep(specs, tmp_path, episode_fn=bench_faults.raising_episode, progress=False, workers=2,
              prepare=lambda: calls.append(len(load_records(tmp_path)) if (tmp_path / "results.jsonl").exists() else 0))
    assert calls == [0]  # once, before any episode was recorded
    run_sweep(specs, tmp_path, episode_fn=bench_faults.raising_episode, progress=False, resume=True,
              prepare=lambda: calls.append("again"))
    assert calls == [0]  # nothing left to run: nothing to prepare
    # The kinematic maps are loaded (or built) for the subgoal policies only.
    loads = []
    monkeypatch.setattr(KinematicMaps, "load_or_build", staticmethod(lambda *a, **k: loads.append(1)))
    prepare_episode_caches(load_methods(["scripted"]))
    assert loads == []
    prepare_episode_caches(load_methods(["scripted", "full", "nav_and_manip"]))
    assert loads == [1]


def test_bad_input_gets_clear_messages(smoke_root, tmp_path):
    out = _out_with_suite(smoke_root, tmp_path / "run")
    with pytest.raises(SystemExit, match=r"unknown method 'nope' \(known: .*full"):
        main(["bench", "--suite", "smoke", "--methods", "full,nope", "--out", str(out)])
    with pytest.raises(SystemExit, match=r"unknown suite 'tiny' \(known: smoke, static, dynamic"):
        main(["bench", "--suite", "tiny", "--methods", "full", "--out", str(out)])
    # A scenario file that fails validation: named with its field; results untouched.
    results = out / "results.jsonl"
    results.write_text('{"key": "earlier", "status": "success"}\n')
    bad = out / "suites" / "smoke" / "scenarios" / "s0001_t00.yaml"
    bad.write_text(bad.read_text().replace("target: ", "target: not_an_object_", 1))
    with pytest.raises(SystemExit, match=r"s0001_t00.yaml: target"):
        main(["bench", "--suite", "smoke", "--methods", "scripted", "--out", str(out), "--resume", "--quiet"])
    assert results.read_text() == '{"key": "earlier", "status": "success"}\n'
    # The report of a directory without results says so.
    with pytest.raises(SystemExit, match="no results file"):
        main(["report", str(tmp_path / "empty")])


def test_ray_backend_runs_the_same_sweep(smoke_root, tmp_path):
    pytest.importorskip("ray", reason="Ray is an optional extra: pip install 'vamg_drake[ray]'")
    suite = materialize_suite(SUITES["smoke"], smoke_root, progress=False)
    specs = episode_specs(suite, load_methods(["scripted"]), 1)
    written = run_sweep(specs, tmp_path, backend="ray", workers=2, progress=False)
    assert sorted(r.key for r in written) == sorted(s.key for s in specs)
    assert all(r.status != ERROR for r in written), [r.error for r in written]
    assert {r["key"] for r in load_records(tmp_path)} == {s.key for s in specs}


# -- sweep integrity ------------------------------------------------------------


def _method_file(tmp_path: Path, text: str) -> Path:
    path = tmp_path / "my_method.yaml"
    path.write_text(text)
    return path


def test_a_second_sweep_on_the_same_directory_is_refused(smoke_root, tmp_path):
    from vamg_drake.bench.results import SweepLockedError, results_lock

    suite = materialize_suite(SUITES["smoke"], smoke_root, progress=False)
    specs = episode_specs(suite, load_methods(["scripted"]), 1)
    with results_lock(tmp_path):  # as a running sweep holds it
        with pytest.raises(SweepLockedError, match=f"pid {os.getpid()}"):
            run_sweep(specs, tmp_path, episode_fn=bench_faults.quick_episode, progress=False)
        assert not (tmp_path / "results.jsonl").exists()
        out = _out_with_suite(smoke_root, tmp_path / "cli")
        with results_lock(out):
            with pytest.raises(SystemExit, match="another sweep .* is writing these results"):
                main(["bench", "--suite", "smoke", "--methods", "scripted", "--out", str(out), "--quiet"])
    # Released: the sweep runs.
    assert len(run_sweep(specs, tmp_path, episode_fn=bench_faults.quick_episode, progress=False)) == 2


def test_an_edited_method_runs_again_and_the_report_counts_it_once(smoke_root, tmp_path):
    from vamg_drake.bench.report import write_report

    suite = materialize_suite(SUITES["smoke"], smoke_root, progress=False)
    method_file = _method_file(tmp_path, "policy: scripted\n")
    specs = episode_specs(suite, load_methods([str(method_file)]), 1)
    out = tmp_path / "out"
    assert len(run_sweep(specs, out, episode_fn=bench_faults.quick_episode, progress=False)) == 2
    # Unchanged: a resume runs nothing.
    assert run_sweep(episode_specs(suite, load_methods([str(method_file)]), 1), out, resume=True,
                     episode_fn=bench_faults.quick_episode, progress=False) == []
    method_file.write_text("policy: scripted\nscripted: {speed: 0.3}\n")
    edited = episode_specs(suite, load_methods([str(method_file)]), 1)
    assert [s.key for s in edited] == [s.key for s in specs]
    assert {s.method_digest for s in edited}.isdisjoint({s.method_digest for s in specs})
    again = run_sweep(edited, out, resume=True, episode_fn=bench_faults.quick_episode, progress=False)
    assert sorted(r.key for r in again) == sorted(s.key for s in specs)
    records = load_records(out)
    assert len(records) == 4 and {r["method_digest"] for r in records[2:]} == {edited[0].method_digest}
    report = write_report(out).read_text()
    assert "| smoke | my_method | 2 |" in report and "2 earlier records" in report
    assert [p.name for p in out.iterdir() if p.name.startswith(".report")] == []  # no temporary file left


def test_resume_retry_errors_reruns_error_records_and_counts_each_key_once(smoke_root, tmp_path):
    from vamg_drake.bench.report import results_table, write_report
    from vamg_drake.bench.results import latest_records

    suite = materialize_suite(SUITES["smoke"], smoke_root, progress=False)
    specs = episode_specs(suite, load_methods(["scripted"]), 1)
    run_sweep(specs, tmp_path, episode_fn=bench_faults.raising_episode, progress=False)
    report = write_report(tmp_path).read_text()
    assert f"- `{specs[0].key}`: RuntimeError: boom in {specs[0].key}" in report  # the exception, not "Traceback"
    # A plain resume treats errors as finished ...
    assert run_sweep(specs, tmp_path, resume=True, episode_fn=bench_faults.quick_episode, progress=False) == []
    # ... --retry-errors runs them again.
    retried = run_sweep(specs, tmp_path, resume=True, retry_errors=True, episode_fn=bench_faults.quick_episode,
                        progress=False)
    assert [r.status for r in retried] == ["collision", "collision"]
    records = load_records(tmp_path)
    assert [r["status"] for r in records] == [ERROR, ERROR, "collision", "collision"]
    (row,) = results_table(latest_records(records))
    assert row["n"] == 2 and row["collision"] == 100.0 and row[OTHER] == 0.0
    write_report(tmp_path)
    # Nothing left to retry.
    assert run_sweep(specs, tmp_path, resume=True, retry_errors=True, episode_fn=bench_faults.quick_episode,
                     progress=False) == []
    with pytest.raises(SystemExit, match="--retry-errors: only with --resume"):
        main(["bench", "--suite", "smoke", "--methods", "scripted", "--out", str(tmp_path), "--retry-errors"])


def test_records_carry_provenance_and_the_method_digest(smoke_root, tmp_path):
    suite = materialize_suite(SUITES["smoke"], smoke_root, progress=False)
    (method,) = load_methods(["scripted"])
    specs = episode_specs(suite, [method], 1)
    for fn in (bench_faults.quick_episode, bench_faults.crashing_episode):
        out = tmp_path / fn.__name__
        run_sweep(specs, out, episode_fn=fn, progress=False)
        for r in load_records(out):
            assert r["method_digest"] == method.digest and len(method.digest) == 10
            p = r["provenance"]
            assert p["code_version"] and p["drake_version"] and p["config"]["policy"] == "scripted", p


def _children(pid: int) -> list[int]:
    """Live processes whose parent is ``pid`` (from /proc)."""
    out = []
    for stat in Path("/proc").glob("[0-9]*/stat"):
        try:
            fields = stat.read_text().rsplit(")", 1)[1].split()
        except OSError:
            continue
        if int(fields[1]) == pid and fields[0] != "Z":
            out.append(int(stat.parent.name))
    return out


def _alive(pid: int) -> bool:
    try:
        state = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0]
    except OSError:
        return False
    return state != "Z"


SWEEP_SCRIPT = """
import sys
sys.path.insert(0, {tests!r})
import bench_faults
from vamg_drake.bench.runner import EpisodeSpec, run_sweep
specs = [EpisodeSpec(key=f"k/{{i}}", suite="s", method="m", method_file="", scenario_file="", scenario_id="x", scene=0,
                     target_index=0, target="t", trigger_distance=None, run_seed=0, shortest_path=None) for i in range(2)]
run_sweep(specs, {out!r}, workers=2, episode_fn=bench_faults.hanging_episode, progress=False, keep_episodes=False)
"""


@pytest.mark.parametrize("sig", [signal.SIGKILL, signal.SIGTERM])
def test_a_killed_sweep_leaves_no_worker_running(tmp_path, sig):
    script = SWEEP_SCRIPT.format(tests=str(Path(__file__).parent), out=str(tmp_path))
    proc = subprocess.Popen([sys.executable, "-c", script], cwd=ROOT, start_new_session=True,
                            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    try:
        deadline = time.time() + 120
        workers: list[int] = []
        while time.time() < deadline and len(workers) < 2:
            time.sleep(0.2)
            workers = [p for p in _children(proc.pid)
                       if "spawn_main" in Path(f"/proc/{p}/cmdline").read_bytes().decode(errors="replace")]
        assert len(workers) == 2, "the sweep never started its workers"
        time.sleep(1.0)
        os.kill(proc.pid, sig)  # the sweep only, not its process group
        assert proc.wait(timeout=30) == (-sig if sig == signal.SIGKILL else 128 + sig)
        deadline = time.time() + 15
        while time.time() < deadline and any(_alive(p) for p in workers):
            time.sleep(0.2)
        assert not any(_alive(p) for p in workers), "a worker outlived its sweep"
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
            proc.wait()


def test_a_record_the_report_cannot_read_is_rejected_with_file_line_and_field(tmp_path):
    good = {"key": "a", "suite": "smoke", "method": "full", "scene": 0, "status": "success"}
    for bad, field in [({"method": None}, "method"), ({"scene": [1]}, "scene"), ({"status": 3}, "status"),
                       ({"timings": {"planner": 5}}, "timings.planner"), ({"shortest_path": "far"}, "shortest_path"),
                       ({"trigger_distance": "near"}, "trigger_distance"), ({"sim_time": None}, "sim_time")]:
        (tmp_path / "results.jsonl").write_text(json.dumps(good) + "\n" + json.dumps({**good, "key": "b", **bad}) + "\n")
        with pytest.raises(SystemExit, match=rf"results.jsonl:2: {field}: "):
            main(["report", str(tmp_path)])
    # A minimal record (key and status) gets its defaults and reports.
    (tmp_path / "results.jsonl").write_text(json.dumps({"key": "a", "status": "success"}) + "\n")
    assert main(["report", str(tmp_path)]) == 0


def test_report_json_prints_one_summary_line_per_suite_and_method(tmp_path, capsys):
    def rec(key, method, status, spl_path=None, code="git:abc1234"):
        return {"key": key, "suite": "paper_static", "method": method, "scene": 0, "status": status,
                "provenance": {"code_version": code}, "path_length": 4.0, "shortest_path": spl_path}

    records = [rec("a", "full", "success", 2.0), rec("b", "full", "planning", 2.0), rec("c", "full", "success", 2.0),
               rec("c", "full", "grasp", 2.0, code="git:def5678"),  # run again: the latest record counts
               rec("a2", "nav_and_manip", "reachability")]
    (tmp_path / "results.jsonl").write_text("".join(json.dumps(r) + "\n" for r in records))
    assert main(["report", str(tmp_path), "--json"]) == 0
    lines = [json.loads(l) for l in capsys.readouterr().out.strip().splitlines()]
    assert [(l["suite"], l["method"]) for l in lines] == [("paper_static", "nav_and_manip"), ("paper_static", "full")]
    nav, full = lines
    assert full["episodes"] == 3 and full["success"] == 1 and full["success_rate"] == 0.3333
    assert full["failures"] == {"grasp": 1, "planning": 1}
    assert full["code"] == ["git:abc1234", "git:def5678"]
    assert full["wilson95"] == [6.1, 79.2]
    assert full["spl"] == 16.7  # one success of three, shortest 2 m over 4 m driven
    assert nav["spl"] is None and nav["failures"] == {"reachability": 1}
    assert (tmp_path / "report.md").is_file()


def test_report_json_common_tasks_counts_only_the_tasks_every_method_ran(tmp_path, capsys):
    def rec(method, target, status):
        return {"key": f"{method}/{target}", "suite": "paper_static", "method": method, "scene": 0,
                "target_index": target, "status": status}

    records = [rec("full", t, "success") for t in range(4)] + [rec("nav_and_manip", t, "planning") for t in (1, 3)]
    (tmp_path / "results.jsonl").write_text("".join(json.dumps(r) + "\n" for r in records))
    for flags, full_episodes in (([], 4), (["--common-tasks"], 2)):
        assert main(["report", str(tmp_path), "--json", *flags]) == 0
        lines = {l["method"]: l for l in map(json.loads, capsys.readouterr().out.strip().splitlines())}
        assert lines["full"]["episodes"] == full_episodes and lines["nav_and_manip"]["episodes"] == 2
