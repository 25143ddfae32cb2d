"""Bad input is one line naming the file and the field, never a traceback or a crash.

Scenario files, DiagramConfig files (``vamg run --config``, bench methods) and
CLI arguments; the CLI cases that could crash the interpreter (a NaN yaw
reached Drake's geometry and segfaulted) run in a subprocess.
"""

import copy
import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

from scenes import box_room_scenario
from vamg_drake.bench.methods import MethodError, load_method
from vamg_drake.config_validation import InputError, diagram_config_problems, load_typed_file
from vamg_drake.diagram import DiagramConfig, load_diagram_config
from vamg_drake.world.scenario import (
    Box,
    MoveAlongPath,
    Part,
    ScenarioError,
    load_scenario,
    save_scenario,
    scenario_to_yaml,
    validate_scenario,
)

ROOT = Path(__file__).resolve().parents[1]


def _problems(scenario) -> list[str]:
    with pytest.raises(ScenarioError) as info:
        validate_scenario(scenario, "bad.yaml")
    return info.value.problems


def _one(scenario, field: str) -> str:
    """The one problem of ``scenario``, which must name the file and ``field``."""
    problems = _problems(scenario)
    assert len(problems) == 1, problems
    assert problems[0].startswith(f"bad.yaml: {field}"), problems
    return problems[0]


# ------------------------------------------------------------- scenarios


def test_the_base_scenario_is_valid():
    validate_scenario(box_room_scenario(with_pedestrian=True), "good.yaml")


@pytest.mark.parametrize("field", ["x", "y", "yaw"])
def test_non_finite_robot_start(field):
    for value in (float("nan"), float("inf")):
        s = box_room_scenario()
        setattr(s.robot_start, field, value)
        assert "finite" in _one(s, f"robot_start.{field}")


@pytest.mark.parametrize("field", ["x", "y", "yaw"])
def test_non_finite_furniture_pose(field):
    s = box_room_scenario()
    setattr(s.furniture[0].pose, field, float("nan"))
    assert "finite" in _one(s, f"furniture[0].pose.{field}")


def test_furniture_through_a_wall():
    s = box_room_scenario()
    s.furniture[0].pose.x = s.room.polygon()[:, 0].max() - 0.1  # the table's half width pokes out
    message = _one(s, "furniture[0].pose")
    assert "through the room's walls" in message


def test_support_floating_above_its_body():
    s = box_room_scenario()
    top = next(p for p in s.furniture[0].parts if p.support)
    top.xyz[2] += 2.0
    problems = _problems(s)
    assert any(p.startswith("bad.yaml: furniture[0].parts[") and "floats 2.0" in p for p in problems), problems


def test_huge_part():
    s = box_room_scenario()
    s.furniture[0].parts.append(Part("slab", Box([1e30, 1.0, 0.1]), [0.0, 0.0, 0.05]))
    assert "exceeds" in _one(s, f"furniture[0].parts[{len(s.furniture[0].parts) - 1}].shape.size")


@pytest.mark.parametrize("speed, message", [(1e300, "exceeds"), (float("inf"), "finite"), (0.0, "positive")])
def test_move_along_path_speed(speed, message):
    s = box_room_scenario()
    s.dynamic_events = [MoveAlongPath("walker", waypoints=[[1.0, 1.0, 0.85], [2.0, 1.0, 0.85]], speed=speed)]
    assert message in _one(s, "dynamic_events[0].speed")


@pytest.mark.parametrize("value", [float("nan"), float("inf"), -1.0, 0.0])
def test_time_limit(value):
    s = box_room_scenario()
    s.time_limit = value
    _one(s, "time_limit")


def _write(tmp_path: Path, data: bytes | str, name: str = "scenario.yaml") -> Path:
    path = tmp_path / name
    path.write_bytes(data.encode() if isinstance(data, str) else data)
    return path


@pytest.mark.parametrize("text, message", [
    ("", "is empty"),
    ("# only a comment\n", "is empty"),
    ("- 1\n- 2\n", "top level must be a mapping"),
    ("name: [\n", "not valid YAML"),
])
def test_scenario_file_not_a_scenario(tmp_path, text, message):
    with pytest.raises(ScenarioError) as info:
        load_scenario(_write(tmp_path, text))
    assert len(info.value.problems) == 1 and info.value.problems[0].startswith("scenario.yaml: ")
    assert message in info.value.problems[0]


def test_binary_scenario_file(tmp_path):
    with pytest.raises(ScenarioError, match=r"^scenario.yaml: is a binary file"):
        load_scenario(_write(tmp_path, bytes(range(256))))


def test_directory_as_scenario_file(tmp_path):
    with pytest.raises(ScenarioError, match="is a directory"):
        load_scenario(tmp_path)


@pytest.mark.parametrize("old, new, field, message", [
    ("time_limit: 30.0", "time_limit: soon", "time_limit", "expected a number"),
    ("seed: 0", "seed: 1.5", "seed", "expected an integer"),
    ("wall_height: 2.4", "wall_height: [1, 2]", "room.wall_height", "expected a number"),
    ("name: box_room", "name: {a: 1}", "name", "expected a string"),
    ("time_limit: 30.0", "time_limit: 30.0\ncolour: red", "colour", "unknown field"),
])
def test_wrong_types_name_the_field(tmp_path, old, new, field, message):
    text = scenario_to_yaml(box_room_scenario())
    assert old in text, text
    with pytest.raises(ScenarioError) as info:
        load_scenario(_write(tmp_path, text.replace(old, new, 1)))
    assert len(info.value.problems) == 1, info.value.problems
    assert info.value.problems[0].startswith(f"scenario.yaml: {field}: {message}"), info.value.problems


def test_nan_yaw_in_a_file(tmp_path):
    scenario = box_room_scenario()
    scenario.robot_start.yaw = 0.123
    text = scenario_to_yaml(scenario)
    assert text.count("yaw: 0.123") == 1
    path = _write(tmp_path, text.replace("yaw: 0.123", "yaw: .nan"))
    with pytest.raises(ScenarioError, match=r"^scenario.yaml: robot_start.yaw: must be a finite number"):
        load_scenario(path)


def test_save_scenario_is_atomic_and_validated(tmp_path):
    path = tmp_path / "s.yaml"
    save_scenario(box_room_scenario(), path)
    good = path.read_text()
    bad = copy.deepcopy(box_room_scenario())
    bad.robot_start.yaw = float("nan")
    with pytest.raises(ScenarioError):
        save_scenario(bad, path)
    assert path.read_text() == good  # the old file is untouched
    assert [p.name for p in tmp_path.iterdir()] == ["s.yaml"]  # no temporary file left behind


# --------------------------------------------------------------- configs


@pytest.mark.parametrize("text, field, message", [
    ("world: {time_step: 0}", "world.time_step", "must be positive"),
    ("world: {time_step: .nan}", "world.time_step", "must be a finite number"),
    ("policy_system: {period: 0.0}", "policy_system.period", "must be positive"),
    ("planner: {period: -0.1}", "planner.period", "must be positive"),
    ("map: {voxel_size: -0.03}", "map.voxel_size", "must be positive"),
    ("target_cloud: {voxel_size: 0.0}", "target_cloud.voxel_size", "must be positive"),
    ("planner: {planner: {max_attempts: -3}}", "planner.planner.max_attempts", "must be at least 1"),
    ("seed: -1", "seed", "must not be negative"),
    ("world: {camera: {depth_min: 6.0}}", "world.camera.depth_min", "must be below depth_max"),
    ("world: {time_step: abc}", "world.time_step", "expected a number"),
    ("world: 3", "world", "expected a mapping"),
    ("seed: 1.5", "seed", "expected an integer"),
    ("policy: [full]", "policy", "expected a string"),
    ("world: {gains: {base_xy: [1.0]}}", "world.gains.base_xy", "expected 2 items"),
    ("waypoints: [[1, x]]", "waypoints[0][1]", "expected a number"),
    ("tracker: {q_diag: [1, -2]}", "tracker.q_diag", "must not hold negative"),
    ("nonsense: 1", "nonsense", "unknown field"),
])
def test_bad_config_names_file_and_field(tmp_path, text, field, message):
    path = _write(tmp_path, text + "\n", "cfg.yaml")
    with pytest.raises(InputError) as info:
        load_diagram_config(path)
    problems = info.value.problems
    assert len(problems) == 1, problems
    assert problems[0].startswith(f"{path}: {field}: {message}"), problems
    # The same through the bench's method loader.
    with pytest.raises(MethodError, match=f"method 'cfg' .*: {field.replace('[', '.').replace(']', '.')}"):
        load_method(str(path))


@pytest.mark.parametrize("data, message", [
    (b"", "is empty"), (b"\x00\x01\xff", "binary"), (b"- a\n", "top level must be a mapping"), (b"a: [\n", "not valid YAML"),
])
def test_config_file_not_a_config(tmp_path, data, message):
    path = _write(tmp_path, data, "cfg.yaml")
    with pytest.raises(InputError, match=message):
        load_typed_file(path, DiagramConfig, DiagramConfig())
    with pytest.raises(MethodError, match=message):
        load_method(str(path))


def test_directory_as_config(tmp_path):
    (tmp_path / "d.yaml").mkdir()
    with pytest.raises(InputError, match="is a directory"):
        load_typed_file(tmp_path / "d.yaml", DiagramConfig, DiagramConfig())
    with pytest.raises(MethodError, match="is a directory"):
        load_method(str(tmp_path / "d.yaml"))


def test_configs_built_in_python_are_checked_too():
    config = DiagramConfig()
    config.world.time_step = 0.0
    config.planner.planner.max_attempts = -3
    config.policy_system.period = float("nan")
    assert sorted(p.split(":")[0] for p in diagram_config_problems(config)) == [
        "planner.planner.max_attempts", "policy_system.period", "world.time_step"]
    with pytest.raises(ValueError, match="world.time_step"):
        config.validate()
    assert diagram_config_problems(DiagramConfig()) == []


# ------------------------------------------------------------------- CLI


def _vamg(*args: str, timeout: float = 300) -> subprocess.CompletedProcess:
    """Runs the CLI in its own interpreter: a crash would show as a signal, not kill pytest."""
    return subprocess.run([sys.executable, "-m", "vamg_drake.cli", *args], cwd=ROOT, capture_output=True, text=True,
                          timeout=timeout)


def _assert_one_line_error(proc: subprocess.CompletedProcess, *needles: str) -> None:
    assert proc.returncode == 1, (proc.returncode, proc.stderr[-2000:])
    assert "Traceback" not in proc.stderr, proc.stderr
    for needle in needles:
        assert needle in proc.stderr, proc.stderr


def test_cli_bad_inputs_are_one_line_errors(tmp_path):
    """Several bad inputs in one subprocess each (cheap: nothing is simulated)."""
    scenario = box_room_scenario()
    scenario.furniture[0].pose.yaw = float("nan")
    bad_scenario = tmp_path / "nan_yaw.yaml"
    bad_scenario.write_text(scenario_to_yaml(scenario))
    _assert_one_line_error(_vamg("run", "--scenario", str(bad_scenario), "--out", str(tmp_path / "o")),
                           "nan_yaw.yaml: furniture[0].pose.yaw: must be a finite number")
    for limit in ("-1", "nan", "inf", "1e300"):
        _assert_one_line_error(_vamg("run", "--time-limit", limit, "--out", str(tmp_path / "o")), "--time-limit")
    _assert_one_line_error(_vamg("run", "--seed", "-1", "--out", str(tmp_path / "o")), "--seed")
    config = tmp_path / "hang.yaml"
    config.write_text("world: {time_step: 0}\n")
    _assert_one_line_error(_vamg("run", "--config", str(config), "--out", str(tmp_path / "o")),
                           f"{config}: world.time_step: must be positive")
    _assert_one_line_error(_vamg("run", "--config", str(tmp_path), "--out", str(tmp_path / "o")), "is a directory")
    a_file = tmp_path / "a_file"
    a_file.write_text("x")
    _assert_one_line_error(_vamg("run", "--policy", "scripted", "--out", str(a_file)), "not a directory")
    _assert_one_line_error(_vamg("scenario", "generate", "--seed", "-1", "--out", str(tmp_path / "s.yaml")), "--seed")
    _assert_one_line_error(_vamg("scenario", "generate", "--seed", "0", "--out", str(tmp_path)), "is a directory")


def test_cli_read_only_out(tmp_path):
    # /proc takes no new directories, not even from root.
    _assert_one_line_error(_vamg("run", "--policy", "scripted", "--out", "/proc/vamg_out"), "--out /proc/vamg_out",
                           "not a writable directory")
    if os.geteuid() != 0:  # root writes into read-only directories
        read_only = tmp_path / "ro"
        read_only.mkdir()
        read_only.chmod(0o500)
        try:
            _assert_one_line_error(_vamg("run", "--policy", "scripted", "--out", str(read_only / "x")), "not a writable")
        finally:
            read_only.chmod(0o700)


def test_cli_error_episode_exits_non_zero_with_episode_json(tmp_path):
    """A component that raises inside the episode: `vamg run` records it and exits 1.

    A scripted waypoint with one coordinate passes the config's type check
    (a list of numbers) and makes the real ScriptedDriver raise IndexError
    inside the simulation (no mock). Should waypoints get a length check,
    pick another fault that passes validation.
    """
    out = tmp_path / "run"
    config = tmp_path / "raise.yaml"
    config.write_text(RAISING_CONFIG)
    proc = _vamg("run", "--policy", "scripted", "--config", str(config), "--time-limit", "2", "--no-replay", "--quiet",
                 "--out", str(out))
    assert proc.returncode == 1, (proc.returncode, proc.stderr[-3000:])
    episode = json.loads((out / "episode.json").read_text())
    assert episode["status"] == "error" and "Traceback" in episode["error"], episode
    assert episode["outputs"]["episode"] == "episode.json"
    assert episode["provenance"]["drake_version"] and episode["provenance"]["code_version"]
    assert episode["provenance"]["config"]["policy"] == "scripted"
    assert "ended in error" in proc.stderr


#: A config that passes validation but makes a component raise in the episode.
RAISING_CONFIG = "waypoints: [[1.0]]\n"


@pytest.mark.parametrize("data, message", [
    (b"", "is empty"), (b"\x00\x01", "is a binary file"), (b"scenes: abc\n", "scenes: expected an integer"),
    (b"scenes: [\n", "not valid YAML"), (None, "is a directory"),
])
def test_bad_suite_files_name_the_file_and_field(tmp_path, data, message):
    from vamg_drake.bench.suites import SuiteError, suite_config

    path = tmp_path / "my_suite.yaml"
    if data is None:
        path.mkdir()
    else:
        path.write_bytes(data)
    with pytest.raises(SuiteError, match=f"^suite file {path}: {message}"):
        suite_config(str(path))


def test_bench_arguments_are_checked_before_any_work(tmp_path):
    from vamg_drake.cli import main

    for args, message in [(["--seeds", "0"], "--seeds and --workers"), (["--workers", "0"], "--seeds and --workers"),
                          (["--wall-limit", "nan"], "--wall-limit"), (["--wall-limit", "-5"], "--wall-limit")]:
        with pytest.raises(SystemExit, match=message):
            main(["bench", "--suite", "smoke", "--methods", "scripted", "--out", str(tmp_path / "o"), *args])
    assert not (tmp_path / "o" / "suites").exists()  # nothing was generated


def test_a_drake_assertion_while_building_is_a_recorded_error(tmp_path):
    """Drake's failed conditions arrive as SystemExit; building the diagram is
    inside the recorded-error path, so episode.json still gets the traceback.
    (A scenario built in Python skips the file validation: Drake's Box() check fires.)"""
    from vamg_drake.episode import run_episode

    scenario = box_room_scenario()
    scenario.furniture[0].parts[0].shape = Box([-1.0, 1.0, 0.1])
    result = run_episode(scenario, DiagramConfig(policy="scripted"), out_dir=tmp_path, record=False, progress=False)
    assert result.status == "error" and result.detail.startswith("SystemExit: Failure at")
    episode = json.loads((tmp_path / "episode.json").read_text())
    assert episode["status"] == "error" and "shape_specification" in episode["error"]
    assert "Traceback" in (tmp_path / "episode.log").read_text()


def test_furniture_spanning_the_corner_of_an_l_shaped_room():
    """Every corner of the part lies inside the room, but the wall corner lies inside the part."""
    from vamg_drake.world.scenario import Furniture, PlanarPose, Room

    s = box_room_scenario()
    s.room = Room(outline=[[-3, -2.5], [3, -2.5], [3, 1], [0, 1], [0, 2.5], [-3, 2.5]])
    validate_scenario(s, "good.yaml")
    s.furniture.append(Furniture("cabinet_0", "cabinet", PlanarPose(-0.05, 0.95, 0.785),
                                 [Part("body", Box([1.1, 1.1, 0.5]), [0.0, 0.0, 0.25])]))
    assert "through the room's walls" in _one(s, "furniture[1].pose")


def test_time_limit_has_an_upper_bound(tmp_path):
    s = box_room_scenario()
    s.time_limit = 1e12
    assert "up to 86400" in _one(s, "time_limit")


@pytest.mark.parametrize("value", [float("nan"), -0.1, 1.5])
def test_colours_are_checked(value):
    s = box_room_scenario()
    s.furniture[0].parts[0].rgba = [0.5, value, 0.5, 1.0]
    assert "in [0, 1]" in _one(s, "furniture[0].parts[0].rgba")


def test_a_part_below_the_floor():
    s = box_room_scenario()
    s.furniture[0].parts.append(Part("root", Box([0.2, 0.2, 0.2]), [0.0, 0.0, -0.5]))
    problems = _problems(s)
    assert any(p.startswith(f"bad.yaml: furniture[0].parts[{len(s.furniture[0].parts) - 1}]:") and "below the floor" in p
               for p in problems), problems
