"""The WholeBodyPlanner LeafSystem: plans on a new goal, replans when a map invalidates."""

import numpy as np
from pydrake.common.value import AbstractValue
from pydrake.systems.analysis import Simulator

from vamg_drake.perception.raycast_map import PointMapSnapshot
from vamg_drake.planning.whole_body_planner import PlannerConfig
from vamg_drake.policy.behaviour_tree import MotionEvent, Phase, SubgoalCommand
from vamg_drake.robot import layout
from vamg_drake.systems.planner_system import PlannerSystem, PlannerSystemConfig


def _snapshot(points: np.ndarray, revision: int) -> PointMapSnapshot:
    return PointMapSnapshot(points, np.zeros(len(points), np.int64), 0.03, revision)


def _box_points(center, half, spacing=0.03):
    axes = [np.arange(c - h, c + h + 1e-9, spacing) for c, h in zip(center, half)]
    return np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1).reshape(-1, 3)


def test_plans_then_replans_when_the_map_blocks_the_path():
    system = PlannerSystem(PlannerSystemConfig(planner=PlannerConfig(attempt_budget_s=5.0)))
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
    assert feedback.goal_id == 1 and feedback.event == MotionEvent.INVALIDATED
    assert plan.trajectory is not first
    assert np.max(np.abs(plan.trajectory.q[:, 1])) > 0.2  # goes around the pillar


def test_goal_in_collision_reports_an_invalidated_goal():
    """The map put the goal in collision: the policy must resample (not count a motion failure)."""
    system = PlannerSystem(PlannerSystemConfig(planner=PlannerConfig(attempt_budget_s=5.0)))
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
