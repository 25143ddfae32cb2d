"""The full system in closed loop (issue 6): it grasps in a generated benchmark
room and in the hand-built box room, sees and avoids a pedestrian by
replanning, and ends an unreachable target as `reachability`; a planner
exception is a recorded error (with its traceback), not a planning failure.

These run whole episodes of the real diagram (Drake physics, rendering, map,
policy, planner, tracker), so each takes one to three minutes on two cores.

Episodes are deterministic (planner budgets in iterations, seeded samplers),
so each of these ends the same way on every machine. The unreachable target
must end as reachability, not perception, although the camera cannot see a
target on a 2.2 m cabinet either: no base pose puts it in reach.
"""

import json

import numpy as np
import pytest

from scenes import box_room_scenario, table
from vamg_drake.diagram import DiagramConfig
from vamg_drake.episode import run_episode
from vamg_drake.scenarios import DEMO_SCENARIO
from vamg_drake.world.episode_monitor import COLLISION, PLANNING, REACHABILITY, SUCCESS
from vamg_drake.world.scenario import Box, Furniture, Part, PlanarPose, load_scenario


def _near_table_scenario(time_limit: float = 60.0):
    """The box room with the robot 1 m in front of the table's near edge."""
    scenario = box_room_scenario(time_limit=time_limit)
    scenario.robot_start = PlanarPose(1.0, 0.0, 0.0)
    return scenario


def test_full_system_grasps_and_lifts_the_target(tmp_path):
    result = run_episode(_near_table_scenario(), DiagramConfig(), out_dir=tmp_path, record=False, progress=False)
    assert result.status == SUCCESS, (result.status, result.kind, result.detail, result.phases)
    phases = [p[1] for p in result.phases]
    # The grasp was executed as the paper's sequence, in order (the monitor may
    # end the episode, object 10 cm up and held 2 s, before the 15 cm lift ends).
    order = [phases.index(p) for p in ("grasp_move", "grasp_approach", "grasp_close", "grasp_lift")]
    assert order == sorted(order)
    for module in ("map_update", "gaze", "planner", "grasp_candidates", "subgoal_grasp"):
        assert result.timings[module]["count"] > 0, module
    assert (tmp_path / "episode.json").exists() and (tmp_path / "episode.log").exists()


def test_full_system_grasps_and_lifts_in_a_generated_benchmark_room(tmp_path):
    """Static benchmark scene 3 (`vamg bench --suite static`, generated room,
    oracle-checked; the README demo's default scenario, `DEMO_SCENARIO`): the
    robot starts 4.3 m away, finds the Rubik's cube on a shelf, grasps and lifts it."""
    scenario = load_scenario(DEMO_SCENARIO)
    result = run_episode(scenario, DiagramConfig(), out_dir=tmp_path, record=False, progress=False)
    assert result.status == SUCCESS, (result.status, result.kind, result.detail, result.phases)


def test_unreachable_target_ends_as_reachability(tmp_path):
    """The target stands on a 2.2 m high cabinet top: no base pose puts it in reach."""
    scenario = box_room_scenario(time_limit=90.0)
    scenario.furniture = [Furniture("cabinet_0", "cabinet", PlanarPose(2.0, 0.0, 0.0),
                                    [Part("body", Box([0.5, 0.8, 2.2]), [0, 0, 1.1], support=True)])]
    scenario.objects[0].xyz = [2.0, 0.0, 2.25]
    scenario.objects[0].support = "cabinet_0/body"
    scenario.objects[0].support_height = 2.2
    scenario.robot_start = PlanarPose(0.3, 0.0, 0.0)
    result = run_episode(scenario, DiagramConfig(), out_dir=tmp_path, record=False, progress=False)
    assert result.status == REACHABILITY, (result.status, result.kind, result.detail)


def test_pedestrian_on_the_path_is_seen_and_avoided_by_replanning(tmp_path):
    """A pedestrian appears 1.7 m ahead on the straight way to the table: the
    map sees it, the motion layer replans around it, and nothing is hit."""
    scenario = box_room_scenario(with_pedestrian=True, time_limit=60.0)
    result = run_episode(scenario, DiagramConfig(), out_dir=tmp_path, record=False, progress=False)
    log = (tmp_path / "episode.log").read_text()
    assert result.status != COLLISION, (result.status, result.detail)
    assert "invalidated" in log, "the pedestrian never invalidated the trajectory"
    # Past the pedestrian: the robot reached the table and began the grasp
    # (whether the grasp itself holds is the grasp test's concern).
    assert "grasp_approach" in [p[1] for p in result.phases], (result.status, result.detail, result.phases)


def test_planner_exception_is_a_recorded_error(tmp_path, monkeypatch):
    """Fault injection: the planner raises inside the episode."""
    from vamg_drake.planning.whole_body_planner import WholeBodyPlanner

    def broken(self, q_start, q_goal):
        raise FloatingPointError("injected planner fault")

    monkeypatch.setattr(WholeBodyPlanner, "plan", broken)
    result = run_episode(_near_table_scenario(time_limit=10.0), DiagramConfig(), out_dir=tmp_path, record=False,
                         progress=False)
    assert result.status == "error" and result.kind == ""
    assert "injected planner fault" in result.detail and "Traceback" in result.error
    assert json.loads((tmp_path / "episode.json").read_text())["error"] == result.error
    log = (tmp_path / "episode.log").read_text()
    assert "Traceback" in log and "injected planner fault" in log
