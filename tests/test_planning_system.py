"""The WholeBodyPlanner LeafSystem: plans on a new goal, replans when a map invalidates."""

import numpy as np
import pytest
from pydrake.common.value import AbstractValue
from pydrake.systems.analysis import Simulator

from vamg_drake.perception.raycast_map import PointMap, PointMapSnapshot
from vamg_drake.planning.motion_messages import MotionEvent, Phase, SubgoalCommand
from vamg_drake.planning.motion_supervisor import PlannerSystemConfig
from vamg_drake.planning.whole_body_planner import FailureReason, PlannerConfig
from vamg_drake.robot import layout
from vamg_drake.robot.head_camera import CameraIntrinsics, HeadCameraConfig
from vamg_drake.systems.planner_system import PlannerSystem
from vamg_drake.systems.timing import ModuleTimings


def _snapshot(points: np.ndarray, revision: int) -> PointMapSnapshot:
    return PointMapSnapshot(points, np.zeros(len(points), np.int64), 0.03, revision)


def _box_points(center, half, spacing=0.03):
    axes = [np.arange(c - h, c + h + 1e-9, spacing) for c, h in zip(center, half)]
    return np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1).reshape(-1, 3)


def test_plans_then_replans_when_the_map_blocks_the_path():
    system = PlannerSystem(PlannerSystemConfig(planner=PlannerConfig(attempt_wall_limit_s=5.0)))
    context = system.CreateDefaultContext()
    qs = layout.stow_configuration(0.0, 0.0, 0.0)
    qg = layout.stow_configuration(3.0, 0.0, 0.0)
    goal = SubgoalCommand(1, qg, "plan", Phase.PREGRASP, layout.GRIPPER_MAX_OPENING, np.full(2, np.nan))
    system.GetInputPort("goal").FixValue(context, AbstractValue.Make(goal))
    system.GetInputPort("point_map").FixValue(context, AbstractValue.Make(_snapshot(np.zeros((0, 3)), 0)))
    system.GetInputPort("robot_configuration").FixValue(context, qs)
    simulator = Simulator(system, context)
    simulator.AdvanceTo(0.05)
    plan = system.GetOutputPort("trajectory").Eval(context)
    assert plan.success and plan.goal_id == 1
    first = plan.trajectory
    np.testing.assert_allclose(first.q[0], qs)
    assert abs(first.sample(first.end_time)[1]) < 1e-9  # straight line in the empty map

    # A pillar appears on the straight path: the trajectory is invalidated and replanned.
    pillar = _box_points([1.5, 0.0, 0.6], [0.15, 0.15, 0.6])
    system.GetInputPort("point_map").FixValue(context, AbstractValue.Make(_snapshot(pillar, 1)))
    simulator.AdvanceTo(0.05 + PlannerSystemConfig().recheck_period)  # the next environment refresh
    plan = system.GetOutputPort("trajectory").Eval(context)
    feedback = system.GetOutputPort("motion_feedback").Eval(context)
    assert plan.success and plan.map_revision == 1
    assert feedback.goal_id == 1 and feedback.event == MotionEvent.REPLANNED
    assert plan.trajectory is not first
    assert np.max(np.abs(plan.trajectory.q[:, 1])) > 0.2  # goes around the pillar


def test_goal_in_collision_reports_an_invalidated_goal():
    """The map put the goal in collision: the policy must resample (not count a motion failure)."""
    system = PlannerSystem(PlannerSystemConfig(planner=PlannerConfig(attempt_wall_limit_s=5.0)))
    context = system.CreateDefaultContext()
    qg = layout.stow_configuration(3.0, 0.0, 0.0)
    goal = SubgoalCommand(7, qg, "plan", Phase.PREGRASP, layout.GRIPPER_MAX_OPENING, np.full(2, np.nan))
    system.GetInputPort("goal").FixValue(context, AbstractValue.Make(goal))
    blocker = _box_points([3.0, 0.0, 0.5], [0.3, 0.3, 0.5])
    system.GetInputPort("point_map").FixValue(context, AbstractValue.Make(_snapshot(blocker, 3)))
    system.GetInputPort("robot_configuration").FixValue(context, layout.stow_configuration(0.0, 0.0, 0.0))
    Simulator(system, context).AdvanceTo(0.05)
    plan = system.GetOutputPort("trajectory").Eval(context)
    feedback = system.GetOutputPort("motion_feedback").Eval(context)
    assert not plan.success and plan.reason == "goal_in_collision"
    assert feedback.goal_id == 7 and feedback.event == MotionEvent.INVALIDATED


def test_new_points_are_checked_alone_and_the_environment_is_rebuilt_only_to_plan():
    timings = ModuleTimings()
    system = PlannerSystem(PlannerSystemConfig(planner=PlannerConfig(attempt_wall_limit_s=5.0)), timings=timings)
    context = system.CreateDefaultContext()
    point_map = PointMap(CameraIntrinsics.from_config(HeadCameraConfig()))
    point_map.add_points(np.concatenate([_box_points([1.5, y, 0.6], [2.0, 0.03, 0.6]) for y in (-2.0, 2.0)]))
    qs, qg = layout.stow_configuration(0.0, 0.0, 0.0), layout.stow_configuration(3.0, 0.0, 0.0)
    goal = SubgoalCommand(1, qg, "plan", Phase.PREGRASP, layout.GRIPPER_MAX_OPENING, np.full(2, np.nan))
    system.GetInputPort("goal").FixValue(context, AbstractValue.Make(goal))
    system.GetInputPort("point_map").FixValue(context, AbstractValue.Make(point_map.snapshot()))
    system.GetInputPort("robot_configuration").FixValue(context, qs)
    simulator = Simulator(system, context)
    simulator.AdvanceTo(0.05)
    first = system.GetOutputPort("trajectory").Eval(context)
    assert first.success and abs(first.trajectory.sample(first.trajectory.end_time)[1]) < 1e-9
    builds = lambda: timings.summary()["planner_environment"]["count"]  # noqa: E731
    assert builds() == 1
    period = PlannerSystemConfig().recheck_period

    # A box beside the path: checked alone against the rest of the path, no rebuild.
    point_map.add_points(_box_points([1.5, 1.0, 0.3], [0.1, 0.1, 0.3]))
    system.GetInputPort("point_map").FixValue(context, AbstractValue.Make(point_map.snapshot()))
    simulator.AdvanceTo(0.05 + period)
    plan = system.GetOutputPort("trajectory").Eval(context)
    assert plan.trajectory is first.trajectory and plan.map_revision == point_map.snapshot().revision
    assert builds() == 1 and timings.summary()["planner_new_points"]["count"] == 1

    # A pillar on the path: invalidated by the new points; rebuilt once to replan around it.
    point_map.add_points(_box_points([1.5, 0.0, 0.6], [0.15, 0.15, 0.6]))
    system.GetInputPort("point_map").FixValue(context, AbstractValue.Make(point_map.snapshot()))
    simulator.AdvanceTo(0.05 + 2 * period)
    plan = system.GetOutputPort("trajectory").Eval(context)
    feedback = system.GetOutputPort("motion_feedback").Eval(context)
    assert feedback.goal_id == 1 and feedback.event == MotionEvent.REPLANNED
    assert plan.success and builds() == 2
    assert np.max(np.abs(plan.trajectory.q[:, 1])) > 0.2
    # The replanned path keeps clear of the box seen before the rebuild too.
    assert system.planner.path_is_valid(plan.trajectory.q)


def _pregrasp_scene():
    """A goal whose open fingers straddle a small object (its points within the
    gripper's spheres), the target at the object's centre."""
    from vamg_drake.robot.kinematics import FetchKinematics

    q_goal = np.array([0.0, 0.0, 0.0, 0.3, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0])  # arm straight out
    X_WG = FetchKinematics.instance().gripper_pose(q_goal)
    p_WT = X_WG[:3, 3] + 0.05 * X_WG[:3, 0]  # the grasp 5 cm ahead of the pre-grasp
    rng = np.random.default_rng(0)
    d = rng.normal(size=(300, 3))
    obj = p_WT + 0.025 * d / np.linalg.norm(d, axis=1, keepdims=True)
    return q_goal, p_WT, obj


def _plan_around_target(q: np.ndarray, q_goal: np.ndarray, phase: Phase, p_WT: np.ndarray, obj: np.ndarray,
                        retreat: float = 0.10):
    """(system, plan): a planner system's plan from q to the goal q_goal of
    `phase`, the map the object's points `obj`, the target at p_WT."""
    system = PlannerSystem(PlannerSystemConfig(approach_retreat=retreat,
                                               planner=PlannerConfig(attempt_wall_limit_s=5.0)))
    context = system.CreateDefaultContext()
    goal = SubgoalCommand(1, q_goal, "plan", phase, layout.GRIPPER_MAX_OPENING, np.full(2, np.nan))
    system.GetInputPort("goal").FixValue(context, AbstractValue.Make(goal))
    system.GetInputPort("point_map").FixValue(context, AbstractValue.Make(_snapshot(obj, 0)))
    system.GetInputPort("robot_configuration").FixValue(context, q)
    system.GetInputPort("target").FixValue(context, p_WT)
    Simulator(system, context).AdvanceTo(0.05)
    return system, system.GetOutputPort("trajectory").Eval(context)


def _plan_to_pregrasp(q: np.ndarray, retreat: float):
    """(system, plan): a planner system's plan from q to `_pregrasp_scene`'s goal."""
    q_goal, p_WT, obj = _pregrasp_scene()
    return _plan_around_target(q, q_goal, Phase.PREGRASP, p_WT, obj, retreat)


def test_pregrasp_goal_straddling_the_target_is_approached_straight_from_behind():
    q_goal, p_WT, obj = _pregrasp_scene()
    qs = layout.stow_configuration(-1.5, 0.0, 0.0)
    outcomes = {retreat: _plan_to_pregrasp(qs, retreat) for retreat in (0.10, 0.0)}
    system, plan = outcomes[0.10]
    assert plan.success and plan.approach_index > 0, plan.reason
    np.testing.assert_allclose(plan.trajectory.q[-1], q_goal, atol=1e-6)
    # Up to the approach, the path keeps the gripper off the target's points too;
    # the approach itself is the gripper's straight 10 cm advance.
    assert system.planner.path_is_valid(plan.trajectory.q[: plan.approach_index + 1])
    assert not system.planner.path_is_valid(plan.trajectory.q[plan.approach_index:])
    from vamg_drake.robot.kinematics import FetchKinematics

    kin = FetchKinematics.instance()
    p_entry = kin.gripper_pose(plan.trajectory.q[plan.approach_index])[:3, 3]
    assert np.linalg.norm(p_entry - kin.gripper_pose(q_goal)[:3, 3]) == pytest.approx(0.10, abs=0.01)
    # The tracker must reach the entry before it starts the straight part.
    assert plan.approach_index in plan.trajectory.stops
    # Without the approach the goal is in collision for the planner.
    _, strict = outcomes[0.0]
    assert not strict.success and strict.reason == FailureReason.GOAL_IN_COLLISION


def test_a_replan_on_the_approach_goes_straight_in_from_where_the_robot_is():
    """Planned again with the gripper halfway along its straight approach (a
    periodic replan, or the map's), the motion continues the approach; it does
    not back out to the entry and start it again (which, replanned every
    second, never arrives)."""
    from vamg_drake.robot.kinematics import FetchKinematics

    q_goal, _, _ = _pregrasp_scene()
    _, first = _plan_to_pregrasp(layout.stow_configuration(-1.5, 0.0, 0.0), 0.10)
    assert first.success and first.approach_index > 0
    kin = FetchKinematics.instance()
    p_goal = kin.gripper_pose(q_goal)[:3, 3]
    approach = first.trajectory.q[first.approach_index:]
    gaps = np.array([np.linalg.norm(kin.gripper_pose(q)[:3, 3] - p_goal) for q in approach])
    q_mid = approach[np.flatnonzero(gaps >= 0.05)[-1]]  # the gripper 5 cm from its goal, coming in
    start_gap = np.linalg.norm(kin.gripper_pose(q_mid)[:3, 3] - p_goal)

    _, again = _plan_to_pregrasp(q_mid, 0.10)
    assert again.success and again.approach_index == 0, again.reason
    np.testing.assert_allclose(again.trajectory.q[0], q_mid, atol=1e-9)
    np.testing.assert_allclose(again.trajectory.q[-1], q_goal, atol=1e-6)
    gaps = [np.linalg.norm(kin.gripper_pose(q)[:3, 3] - p_goal) for q in again.trajectory.q]
    assert max(gaps) <= start_gap + 1e-6  # never backs away from the goal


def _pregrasp(p_WT: np.ndarray, approach, q_seed: np.ndarray) -> np.ndarray:
    """The arm configuration (base and torso of q_seed) with the grasp frame
    5 cm before p_WT along the unit `approach`, closing axis horizontal."""
    from vamg_drake.policy.ik import FastIk

    x = np.asarray(approach, float) / np.linalg.norm(approach)
    y = np.cross([0.0, 0.0, 1.0], x)
    y /= np.linalg.norm(y)
    X = np.eye(4)
    X[:3, :3] = np.stack([x, y, np.cross(x, y)], axis=1)
    X[:3, 3] = p_WT - 0.05 * x
    q, ok = FastIk().solve_arm(X[None], q_seed)
    assert ok[0]
    return q[0]


@pytest.mark.parametrize("turns", [0, 1])
def test_a_grasp_move_from_around_the_target_leaves_along_its_approach_before_moving_on(turns):
    """From a pre-grasp with the open fingers around the target, a grasp-move
    to another grasp's pre-grasp first backs the gripper straight out along
    its approach, then moves on with the target's points as obstacles, and
    comes in straight again: it never sweeps the fingers through the target."""
    from vamg_drake.robot.kinematics import FetchKinematics

    kin = FetchKinematics.instance()
    q_seed = layout.stow_configuration(0.0, 0.0, 0.0)
    q_seed[layout.TORSO] = 0.3
    p_WT = np.array([0.85, 0.0, 0.9])
    d = np.random.default_rng(0).normal(size=(300, 3))
    obj = p_WT + 0.025 * d / np.linalg.norm(d, axis=1, keepdims=True)
    q_start = _pregrasp(p_WT, [1.0, 0.0, 0.0], q_seed)  # from the front
    q_goal = _pregrasp(p_WT, [1.0, -1.0, 0.0], q_seed)  # from the left, 45 degrees round
    # The measured heading may have turned through 2 pi (IK wraps it; the path must not jump).
    q_start[layout.THETA] += 2.0 * np.pi * turns
    system, plan = _plan_around_target(q_start, q_goal, Phase.GRASP_MOVE, p_WT, obj)
    assert plan.success and plan.exit_index > 0 and plan.approach_index > plan.exit_index, plan
    q = plan.trajectory.q
    np.testing.assert_allclose(q[0], q_start, atol=1e-9)
    np.testing.assert_allclose(layout.wrap_configuration(q[-1] - q_goal), 0.0, atol=1e-6)
    X_start = kin.gripper_pose(q_start)
    p_exit = kin.gripper_pose(q[plan.exit_index])[:3, 3]
    back = X_start[:3, 3] - p_exit
    assert np.linalg.norm(np.cross(back, X_start[:3, 0])) <= 0.005  # straight back along the approach ...
    assert back @ X_start[:3, 0] in (pytest.approx(0.10, abs=0.005), pytest.approx(0.05, abs=0.005))  # ... 10 or 5 cm
    assert plan.exit_index in plan.trajectory.stops and plan.approach_index in plan.trajectory.stops
    # Between leaving and coming in again, the target's points are obstacles to the gripper.
    assert system.planner.path_is_valid(q[plan.exit_index: plan.approach_index + 1])
    assert not system.planner.path_is_valid(q[: plan.exit_index + 1])
