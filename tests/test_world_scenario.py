"""Scenario dataclasses: YAML round trip and clear errors for bad files."""

import copy
from pathlib import Path

import numpy as np
import pytest

from vamg_drake.world.scenario import (
    AppearAtDistance,
    AppearAtPhase,
    Box,
    Cylinder,
    Doorway,
    Furniture,
    MoveAlongPath,
    Part,
    PlacedObject,
    PlanarPose,
    Room,
    Scenario,
    ScenarioError,
    load_scenario,
    save_scenario,
    scenario_to_yaml,
    static_obstacle_shapes,
    validate_scenario,
)


def _scenario() -> Scenario:
    top = Part("top", Box([1.2, 0.8, 0.04]), [0.0, 0.0, 0.73], support=True)
    leg = Part("pedestal", Cylinder(0.05, 0.71), [0.0, 0.0, 0.355])
    return Scenario(
        name="two_tables",
        seed=3,
        room=Room(outline=[[0, 0], [6, 0], [6, 3], [3, 3], [3, 5], [0, 5]], doorways=[Doorway(edge=0, center=1.0, width=0.9)]),
        furniture=[
            Furniture("table_0", "table", PlanarPose(4.5, 1.5, 0.3), [top, leg]),
            Furniture("table_1", "table", PlanarPose(1.0, 4.0, 0.0), copy.deepcopy([top, leg])),
        ],
        objects=[
            PlacedObject("mug", [4.5, 1.5, 0.79], [0.0, 0.0, 1.0], "table_0/top", 0.75),
            PlacedObject("tennis_ball", [1.2, 4.0, 0.78], [0.0, 0.0, 0.0], "table_1/top", 0.75),
        ],
        target="mug",
        robot_start=PlanarPose(1.0, 1.0, 0.5),
        dynamic_events=[
            AppearAtDistance("pedestrian", xyz=[2.5, 1.5, 0.85]),
            AppearAtPhase("blocker", xyz=[4.6, 1.7, 0.81]),
            MoveAlongPath("walker", waypoints=[[1.0, 2.0, 0.85], [2.0, 2.0, 0.85]]),
        ],
        time_limit=60.0,
    )


def _write(tmp_path: Path, text: str) -> Path:
    path = tmp_path / "scenario.yaml"
    path.write_text(text)
    return path


def test_yaml_round_trip(tmp_path):
    scenario = _scenario()
    validate_scenario(scenario)
    path = tmp_path / "s.yaml"
    save_scenario(scenario, path)
    loaded = load_scenario(path)
    assert loaded == scenario
    assert isinstance(loaded.dynamic_events[2], MoveAlongPath)
    assert isinstance(loaded.furniture[0].parts[1].shape, Cylinder)
    np.testing.assert_allclose(loaded.target_point(), [4.5, 1.5, 0.79])


def test_malformed_yaml_names_the_file(tmp_path):
    path = _write(tmp_path, "name: x\nroom: {outline: [[0, 0], [1, 0]\n")
    with pytest.raises(ScenarioError, match=r"^scenario.yaml: "):
        load_scenario(path)


def test_unknown_field_names_the_field(tmp_path):
    text = scenario_to_yaml(_scenario()).replace("time_limit:", "time_limitt:")
    with pytest.raises(ScenarioError, match=r"scenario.yaml: .*time_limitt"):
        load_scenario(_write(tmp_path, text))


def test_incomplete_yaml_lists_missing_fields(tmp_path):
    with pytest.raises(ScenarioError) as info:
        load_scenario(_write(tmp_path, "name: empty\n"))
    message = str(info.value)
    assert "scenario.yaml: room.outline: needs at least 3" in message
    assert "scenario.yaml: target: missing" in message


def test_unknown_object(tmp_path):
    text = scenario_to_yaml(_scenario()).replace("name: tennis_ball", "name: foo")
    with pytest.raises(ScenarioError, match=r"scenario.yaml: objects\[1\].name: unknown YCB object 'foo' \(known: master_chef_can"):
        load_scenario(_write(tmp_path, text))


def test_start_inside_furniture():
    scenario = _scenario()
    scenario.robot_start = PlanarPose(4.4, 1.4, 0.0)
    with pytest.raises(ScenarioError, match=r"s.yaml: robot_start: footprint .* overlaps furniture 'table_0' \(centre inside it\)"):
        validate_scenario(scenario, "s.yaml")


def test_start_touching_furniture_and_outside_room():
    scenario = _scenario()
    # Table_1 spans x in [0.4, 1.6]; 0.2 m from its edge is inside the 0.32 m footprint.
    scenario.robot_start = PlanarPose(1.0, 4.0 - 0.4 - 0.2, 0.0)
    with pytest.raises(ScenarioError, match="overlaps furniture 'table_1' \\(clearance 0.2"):
        validate_scenario(scenario, "s.yaml")
    scenario.robot_start = PlanarPose(5.0, 4.0, 0.0)  # the L's missing corner
    with pytest.raises(ScenarioError, match="robot_start: .* outside the room"):
        validate_scenario(scenario, "s.yaml")


def test_target_not_on_support():
    scenario = _scenario()
    scenario.objects[0].xyz = [4.5, 1.5, 1.5]  # floating 75 cm above the table
    with pytest.raises(ScenarioError, match=r"objects\[0\].xyz: 'mug' .* is not on support 'table_0/top'"):
        validate_scenario(scenario, "s.yaml")
    scenario = _scenario()
    scenario.objects[0].support = "table_9/top"
    with pytest.raises(ScenarioError, match=r"objects\[0\].support: no support surface 'table_9/top'"):
        validate_scenario(scenario, "s.yaml")
    scenario = _scenario()
    scenario.target = "banana"
    with pytest.raises(ScenarioError, match="target: 'banana' is not one of the objects"):
        validate_scenario(scenario, "s.yaml")


def test_bad_events_and_furniture():
    scenario = _scenario()
    scenario.dynamic_events[1].phase = "dancing"
    scenario.dynamic_events[2].waypoints = [[0.0, 0.0, 0.0]]
    scenario.furniture[1].kind = "piano"
    with pytest.raises(ScenarioError) as info:
        validate_scenario(scenario, "s.yaml")
    assert len(info.value.problems) == 3
    assert "dynamic_events[1].phase: unknown phase 'dancing'" in str(info.value)
    assert "dynamic_events[2].waypoints" in str(info.value)
    assert "furniture[1].kind: unknown kind 'piano'" in str(info.value)


def test_walls_leave_doorway_gap_and_close_corners():
    scenario = _scenario()
    walls = scenario.room.wall_primitives()
    # 6 outline edges, edge 0 split by the doorway into two pieces.
    assert len(walls) == 7
    shapes = static_obstacle_shapes(scenario)
    assert len(shapes) == 7 + 4
    from vamg_drake.world.primitives import footprint_clearance

    door_centre = np.array([[1.0, -0.05]])
    assert footprint_clearance(door_centre, walls)[0] >= 0.45 - 1e-9
    wall_point = np.array([[3.0, -0.05]])
    assert footprint_clearance(wall_point, walls)[0] < 0.0
    corner = np.array([[-0.05, -0.05]])  # the outer corner square is covered
    assert footprint_clearance(corner, walls)[0] < 0.0


def test_move_along_path_positions():
    event = MoveAlongPath("w", waypoints=[[0, 0, 1], [2, 0, 1], [2, 1, 1]], speed=0.5, start_time=1.0, loop=True)
    np.testing.assert_allclose(event.position_at(0.0), [0, 0, 1])
    np.testing.assert_allclose(event.position_at(3.0), [1, 0, 1])
    np.testing.assert_allclose(event.position_at(1.0 + 2.5 / 0.5), [2, 0.5, 1])
    np.testing.assert_allclose(event.position_at(1.0 + 4.5 / 0.5), [1.5, 0, 1])  # on the way back (path length 3)
    event.loop = False
    np.testing.assert_allclose(event.position_at(100.0), [2, 1, 1])


def test_readme_example_loads():
    import re

    readme = Path(__file__).parents[1] / "vamg_drake" / "world" / "README.md"
    example = re.findall(r"```yaml\n(.*?)```", readme.read_text(), re.S)[0]
    from vamg_drake.world.scenario import scenario_from_yaml

    scenario = scenario_from_yaml(example, "README.md")
    assert [type(e) for e in scenario.dynamic_events] == [AppearAtDistance, AppearAtPhase, MoveAlongPath]
    np.testing.assert_allclose(scenario.target_point(), [4.5, 1.5, 0.793])


def test_bad_room_outlines():
    scenario = _scenario()
    scenario.room.outline = [[0, 0], [6, 0], [0, 5], [6, 5]]  # a bow tie
    with pytest.raises(ScenarioError, match=r"room.outline: edges 1 and 3 cross"):
        validate_scenario(scenario, "s.yaml")
    scenario.room.outline = [[0, 0], [6, 0], [6, 0], [0, 5]]
    with pytest.raises(ScenarioError, match=r"room.outline: edge 1 has zero length"):
        validate_scenario(scenario, "s.yaml")
    scenario = _scenario()
    scenario.room.doorways = [Doorway(edge=9, center=1.0, width=0.9), Doorway(edge=1, center=2.8, width=0.9)]
    with pytest.raises(ScenarioError) as info:
        validate_scenario(scenario, "s.yaml")
    assert "room.doorways[0].edge: 9 is not an outline edge" in str(info.value)
    assert "room.doorways[1]: gap" in str(info.value)
