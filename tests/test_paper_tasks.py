"""The paper authors' ReplicaCAD tasks: reading, apartment matching, import, dynamic rules.

Tests that need the authors' task file and the ReplicaCAD apartments read them
from ``../shared`` (or ``$VAMG_PAPER_TASKS`` / ``$VAMG_REPLICACAD_DIR``) and
skip with the reason when they are absent.
"""

import copy
import json
import math
import os
from pathlib import Path

import numpy as np
import pytest

from vamg_drake.cli import main as cli_main
from vamg_drake.systems.dynamic_obstacles import approach_triggered, first_clear_candidate
from vamg_drake.world.paper_tasks import (
    SETTLED_POSE_DECIMALS,
    PaperTaskConfig,
    TaskFileError,
    import_scene,
    match_apartment,
    read_task_file,
)
from vamg_drake.world.primitives import signed_distance_to_polygon
from vamg_drake.world.scenario import AppearAtDistance, AppearAtPhase, load_scenario

SHARED = Path(__file__).resolve().parents[2] / "shared"
TASK_FILE = Path(os.environ.get("VAMG_PAPER_TASKS", SHARED / "paper_benchmark" / "grasp_benchmark_dev.json"))
REPLICACAD = Path(os.environ.get("VAMG_REPLICACAD_DIR", SHARED / "replicacad"))
#: The apartments the shared README lists for the development scenes.
EXPECTED_APARTMENTS = {0: "apt_2", 1: "apt_1", 2: "apt_0", 3: "apt_4", 4: "apt_4",
                       5: "apt_5", 6: "apt_2", 7: "apt_3", 8: "apt_3", 9: "apt_4"}

needs_task_file = pytest.mark.skipif(not TASK_FILE.is_file(), reason=f"the authors' task file is absent ({TASK_FILE})")
needs_apartments = pytest.mark.skipif(
    not (REPLICACAD / "replica_cad_dataset" / "configs" / "scenes" / "apt_0.scene_instance.json").is_file(),
    reason=f"the ReplicaCAD apartments are absent ({REPLICACAD})",
)


def _task(model_id="048_hammer", position=(1.0, 2.0, 0.8)):
    return {"model_id": model_id, "position": list(position), "orientation": [1.0, 0.0, 0.0, 0.0],
            "dynamic_obstacle": {"type": "pedestrian_box", "start_position": [0.5, 0.5, 0.875],
                                 "start_orientation": [1.0, 0.0, 0.0, 0.0], "dimension": [0.2, 0.4, 1.75]}}


def _write(tmp_path, data) -> Path:
    path = tmp_path / "tasks.json"
    path.write_text(json.dumps(data))
    return path


# ------------------------------------------------------------ reading


def test_reads_any_scene_indices(tmp_path):
    path = _write(tmp_path, {"scene_17": {"seed": 17, "grasp_tasks": [_task()]},
                             "scene_3": {"seed": 3, "grasp_tasks": [_task("065-a_cups"), _task("070-a_colored_wood_blocks")]}})
    scenes = read_task_file(path)
    assert [s.index for s in scenes] == [3, 17]
    assert [t.model_id for t in scenes[0].tasks] == ["065-a_cups", "070-a_colored_wood_blocks"]
    assert scenes[1].tasks[0].pedestrian.size == (0.2, 0.4, 1.75)


@pytest.mark.parametrize(
    "mutate, field",
    [
        (lambda t: t.update(model_id="999_unobtainium"), "scene_0.grasp_tasks[0].model_id"),
        (lambda t: t.pop("position"), "scene_0.grasp_tasks[0]: missing key(s) position"),
        (lambda t: t.update(position=[1.0, float("nan"), 0.5]), "scene_0.grasp_tasks[0].position"),
        (lambda t: t.update(orientation=[0.0, 0.0, 0.0, 0.0]), "scene_0.grasp_tasks[0].orientation"),
        (lambda t: t["dynamic_obstacle"].update(dimension=[0.2, -0.4, 1.75]), "scene_0.grasp_tasks[0].dynamic_obstacle.dimension"),
        (lambda t: t["dynamic_obstacle"].pop("start_position"), "dynamic_obstacle: missing key(s) start_position"),
    ],
)
def test_bad_task_file_names_file_and_field(tmp_path, mutate, field):
    task = _task()
    mutate(task)
    path = _write(tmp_path, {"scene_0": {"seed": 0, "grasp_tasks": [task]}})
    with pytest.raises(TaskFileError) as error:
        read_task_file(path)
    assert str(path) in str(error.value) and field in str(error.value)


def test_unknown_model_id_is_named(tmp_path):
    path = _write(tmp_path, {"scene_0": {"grasp_tasks": [_task("999_unobtainium")]}})
    with pytest.raises(TaskFileError, match="999_unobtainium"):
        read_task_file(path)


@pytest.mark.parametrize("text", ["", "not json", "[]", '{"level_1": {}}'])
def test_malformed_task_file(tmp_path, text):
    path = tmp_path / "tasks.json"
    path.write_text(text)
    with pytest.raises(TaskFileError, match=str(path)):
        read_task_file(path)


# ------------------------------------------------------- dynamic rules


@pytest.mark.parametrize(
    "p_base, yaw, expected",
    [
        ((0.0, 0.0), 0.0, True),                # 1.5 m away, heading straight at it
        ((0.0, 0.0), 1.2, True),                # still a positive dot product
        ((0.0, 0.0), math.pi / 2, False),       # heading across: dot product 0
        ((0.0, 0.0), math.pi, False),           # heading away
        ((-0.3, 0.0), 0.0, False),              # heading at it but 1.8 m away
        ((3.0, 0.0), math.pi, True),            # from the other side, heading back
        ((3.0, 0.0), 0.0, False),
    ],
)
def test_pedestrian_trigger_needs_distance_and_heading(p_base, yaw, expected):
    p_box = np.array([1.5, 0.0, 0.875])
    assert approach_triggered(np.array(p_base), yaw, p_box, 1.7, heading_towards=True) == expected


def test_distance_only_trigger_ignores_heading():
    assert approach_triggered(np.zeros(2), math.pi, np.array([1.5, 0.0]), 1.7, heading_towards=False)


def test_box_candidate_keeps_clear_of_robot_links():
    candidates = np.array([[0.0, 0.0, 0.8], [0.25, 0.0, 0.8], [0.6, 0.0, 0.8]])
    links = np.array([[0.0, 0.1, 0.8], [0.3, 0.0, 1.0]])
    assert first_clear_candidate(candidates, links, 0.3) == 2
    assert first_clear_candidate(candidates, links, 0.0) == 0
    assert first_clear_candidate(candidates[:2], links, 0.3) is None


# ----------------------------------------------- on the shared data


@pytest.fixture(scope="module")
def layouts():
    if not REPLICACAD.is_dir():
        pytest.skip(f"the ReplicaCAD apartments are absent ({REPLICACAD})")
    from vamg_drake.world.replicacad import load_replicacad_layout

    return {f"apt_{i}": load_replicacad_layout(f"apt_{i}", REPLICACAD) for i in range(6)}


@needs_task_file
@needs_apartments
def test_scenes_match_the_listed_apartments(layouts):
    config = PaperTaskConfig()
    found = {}
    for scene in read_task_file(TASK_FILE):
        apartment, scores = match_apartment(scene, layouts, config)
        found[scene.index] = apartment
        others = sorted((v for k, v in scores.items() if k != apartment), reverse=True)
        assert scores[apartment] >= 14 and others[0] <= scores[apartment] - config.min_match_lead
    expected = {k: v for k, v in EXPECTED_APARTMENTS.items() if k in found}
    assert {k: found[k] for k in expected} == expected


@needs_task_file
@needs_apartments
def test_no_clear_match_is_an_error(layouts):
    scene = read_task_file(TASK_FILE)[0]
    with pytest.raises(TaskFileError, match="no clear apartment match"):
        match_apartment(scene, {k: v for k, v in layouts.items() if k != "apt_2"}, PaperTaskConfig(min_match_fraction=0.9))


@pytest.fixture(scope="module")
def dynamic_scene():
    if not (TASK_FILE.is_file() and REPLICACAD.is_dir()):
        pytest.skip("the authors' task file or the ReplicaCAD apartments are absent")
    scene = read_task_file(TASK_FILE)[3]
    return scene, import_scene(scene, dynamic=True, dataset_dir=REPLICACAD)


def test_every_object_is_placed_or_reported(dynamic_scene):
    scene, imported = dynamic_scene
    assert len(imported.objects) == len(scene.tasks)
    placed = {o.name for o in imported.objects if o.placed}
    for report in imported.objects:
        assert report.placed != bool(report.reason)
        assert np.isfinite(report.displacement)
        if report.placed:
            assert report.displacement <= PaperTaskConfig().max_displacement and report.support.startswith("rc/")
    assert {i for i, _ in imported.scenarios} | {i for i, _ in imported.excluded} == set(range(len(scene.tasks)))
    for index, scenario in imported.scenarios:
        assert {o.name for o in scenario.objects} == placed
        assert scenario.target == imported.objects[index].name
        assert (scenario.robot_start.x, scenario.robot_start.y, scenario.robot_start.yaw) == (-1.0, 0.0, 0.0)
        assert scenario.replicacad.scene == EXPECTED_APARTMENTS[scene.index]
    for index, reason in imported.excluded:
        assert not imported.objects[index].placed and imported.objects[index].reason in reason


def test_settled_poses_are_on_a_micrometre_grid(dynamic_scene):
    # The settling simulation's last bits vary between CPUs; the scenario files
    # (and so a suite rebuilt on another machine) must not.
    _, imported = dynamic_scene
    for _, scenario in imported.scenarios:
        for obj in scenario.objects:
            for v in [*obj.xyz, *obj.rpy]:
                assert v == round(v, SETTLED_POSE_DECIMALS), (obj.name, v)
    for report in imported.objects:
        assert report.lifted == round(report.lifted, SETTLED_POSE_DECIMALS)


def test_dynamic_events_follow_the_protocol(dynamic_scene):
    scene, imported = dynamic_scene
    config = PaperTaskConfig()
    layout_receptacles = None
    for index, scenario in imported.scenarios:
        pedestrian = [e for e in scenario.dynamic_events if isinstance(e, AppearAtDistance)]
        assert len(pedestrian) == 1 and pedestrian[0].heading_towards
        assert pedestrian[0].trigger_distance == 1.7
        assert np.allclose(pedestrian[0].xyz, scene.tasks[index].pedestrian.p_W)
        assert pedestrian[0].shape.size == [0.2, 0.4, 1.75]
        boxes = [e for e in scenario.dynamic_events if isinstance(e, AppearAtPhase)]
        assert len(boxes) <= 5
        target = scenario.object(scenario.target)
        if layout_receptacles is None:
            layout_receptacles = {r.id: r for r in scenario.replicacad_layout().all_receptacles()}
        support = layout_receptacles[target.support]
        for box in boxes:
            assert box.phase == config.box_phase and box.min_robot_clearance == 0.3
            sx, sy, h = box.shape.size
            assert 0.04 <= sx <= 0.10 and 0.04 <= sy <= 0.10 and 0.10 <= h <= 0.30
            for c in box.candidates():
                d = float(np.linalg.norm(c[:2] - np.asarray(target.xyz[:2])))
                assert 0.25 <= d <= 0.70 and d >= 0.12
                assert signed_distance_to_polygon(c[None, :2], support.top)[0] < 0
                assert c[2] == pytest.approx(support.height + 0.5 * h, abs=0.005)
    counts = [sum(isinstance(e, AppearAtPhase) for e in s.dynamic_events) for _, s in imported.scenarios]
    assert max(counts) >= 3


@needs_task_file
@needs_apartments
def test_file_with_only_scenes_3_and_17_imports(tmp_path):
    data = json.loads(TASK_FILE.read_text())
    subset = {"scene_3": data["scene_3"], "scene_17": copy.deepcopy(data["scene_7"])}
    subset["scene_17"]["seed"] = 17
    path = _write(tmp_path, subset)
    scenes = read_task_file(path)
    assert [s.index for s in scenes] == [3, 17]
    # Through the command, into an --out folder that does not exist yet.
    out = tmp_path / "suites" / "subset"
    assert cli_main(["scenario", "import-tasks", str(path), "--out", str(out), "--tasks", "1",
                     "--replicacad-dir", str(REPLICACAD)]) == 0
    report = json.loads((out / "import.json").read_text())
    assert [scene["apartment"] for scene in report["scenes"]] == ["apt_4", "apt_3"]
    written = sorted(p.name for p in out.glob("*.yaml"))
    assert len(written) == 2 and all(load_scenario(out / name).replicacad for name in written)


@needs_task_file
@needs_apartments
def test_paper_suite_materializes_with_its_import_report(tmp_path, monkeypatch):
    from vamg_drake.bench.suites import materialize_suite, suite_config

    monkeypatch.setenv("VAMG_REPLICACAD_DIR", str(REPLICACAD))
    config = suite_config("paper_dynamic", scenes=1, targets=3)
    config.task_file = str(TASK_FILE)
    suite = materialize_suite(config, tmp_path, progress=False)
    assert len(suite.scenarios) + len([e for e in suite.excluded if e.get("task") is not None]) == 3
    for s in suite.scenarios:
        scenario = suite.load(s)
        assert scenario.replicacad.scene == EXPECTED_APARTMENTS[0] and len(scenario.objects) >= 18
        assert any(isinstance(e, AppearAtDistance) and e.heading_towards for e in scenario.dynamic_events)
        assert s.shortest_path is not None and s.shortest_path > 1.0
    report = json.loads((suite.directory / "import.json").read_text())
    assert [scene["apartment"] for scene in report["scenes"]] == [EXPECTED_APARTMENTS[0]]
    # A second call reads the same suite back (resume) without importing again.
    again = materialize_suite(config, tmp_path, progress=False)
    assert [s.id for s in again.scenarios] == [s.id for s in suite.scenarios]
