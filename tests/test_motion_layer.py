"""The motion layer of the WholeBodyPlanner system: linear and hold goals,
planner exceptions, the replanning limit, reaching and settling."""

import dataclasses as dc
import logging

import numpy as np
import pytest
from pydrake.common.value import AbstractValue
from pydrake.systems.analysis import Simulator

from vamg_drake.perception.raycast_map import PointMapSnapshot
from vamg_drake.planning.collision_environment import CollisionEnvironment
from vamg_drake.planning.sphere_collision import SphereCollisionChecker, densify
from vamg_drake.planning.motion_messages import MotionEvent, Phase, SubgoalCommand
from vamg_drake.planning.motion_supervisor import (
    EXCEPTION_REASON,
    REPLAN_LIMIT_REASON,
    MotionInputs,
    MotionSupervisor,
    PlannerSystemConfig,
    arm_floor_clearance,
    linear_trajectory,
    remaining_path,
)
from vamg_drake.planning.whole_body_planner import PlannerConfig, WholeBodyPlanner
from vamg_drake.robot import layout
from vamg_drake.systems.planner_system import PlannerSystem


def _goal(goal_id, q_goal, motion, phase=Phase.PREGRASP):
    return SubgoalCommand(goal_id, np.asarray(q_goal, float), motion, phase, layout.GRIPPER_MAX_OPENING,
                          np.full(2, np.nan))


def _system(config=None):
    system = PlannerSystem(config or PlannerSystemConfig(planner=PlannerConfig(attempt_wall_limit_s=5.0)))
    context = system.CreateDefaultContext()
    system.GetInputPort("point_map").FixValue(
        context, AbstractValue.Make(PointMapSnapshot(np.zeros((0, 3)), np.zeros(0, np.int64), 0.03, 0)))
    return system, context


def test_linear_goal_is_a_straight_joint_space_motion_within_its_speed():
    system, context = _system()
    q0 = layout.stow_configuration(1.0, 2.0, 0.5)
    q1 = q0.copy()
    q1[layout.TORSO] += 0.12
    system.GetInputPort("robot_configuration").FixValue(context, q0)
    system.GetInputPort("goal").FixValue(context, AbstractValue.Make(_goal(3, q1, "linear", Phase.GRASP_LIFT)))
    simulator = Simulator(system, context)
    simulator.AdvanceTo(0.05)
    traj = system.GetOutputPort("trajectory").Eval(context).trajectory
    assert traj is not None
    np.testing.assert_allclose(traj.q[0], q0)
    np.testing.assert_allclose(traj.q[-1], q1)
    # Torso at 0.25 x 0.1 m/s: 0.12 m takes 4.8 s.
    assert traj.duration == pytest.approx(0.12 / (0.25 * layout.V_MAX[layout.TORSO]), rel=1e-6)
    assert traj.max_rate_ratio() <= 0.25 + 1e-9
    # Not reached while the robot stands at q0; reached once it is at q1 after the end.
    system.GetInputPort("robot_configuration").FixValue(context, q1)
    simulator.AdvanceTo(traj.end_time + 0.2)
    feedback = system.GetOutputPort("motion_feedback").Eval(context)
    assert feedback.goal_id == 3 and feedback.event == MotionEvent.REACHED


def test_a_robot_behind_schedule_gets_slack_in_proportion_to_the_motion():
    """The tracker follows the path, not the clock: a robot still short of the
    goal settle_time after the end of a long motion is not failed until
    settle_time + settle_time_fraction * duration; then it is."""
    config = PlannerSystemConfig(planner=PlannerConfig(attempt_wall_limit_s=5.0))
    system, context = _system(config)
    q0 = layout.stow_configuration(1.0, 2.0, 0.5)
    q1 = q0.copy()
    q1[layout.TORSO] += 0.3  # 12 s at 0.25 x 0.1 m/s
    system.GetInputPort("robot_configuration").FixValue(context, q0)
    system.GetInputPort("goal").FixValue(context, AbstractValue.Make(_goal(4, q1, "linear", Phase.GRASP_LIFT)))
    simulator = Simulator(system, context)
    simulator.AdvanceTo(0.05)
    traj = system.GetOutputPort("trajectory").Eval(context).trajectory
    slack = config.settle_time + config.settle_time_fraction * traj.duration
    simulator.AdvanceTo(traj.end_time + config.settle_time + 0.5)
    assert system.GetOutputPort("motion_feedback").Eval(context).event == MotionEvent.NONE
    simulator.AdvanceTo(traj.end_time + slack + 0.2)
    feedback = system.GetOutputPort("motion_feedback").Eval(context)
    assert feedback.goal_id == 4 and feedback.event == MotionEvent.FAILED


def test_the_target_exempts_the_gripper_only_around_it():
    """The planning environment keeps the target's points for the gripper too
    (every phase); only a grasp-move that starts with the open gripper around
    the target is planned with the gripper allowed its points."""
    from vamg_drake.robot.kinematics import FetchKinematics

    system, context = _system()
    q_pre = np.array([2.0, 2.0, 0.0, 0.3, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0])  # arm straight out
    X_WG = FetchKinematics.instance().gripper_pose(q_pre)
    target = X_WG[:3, 3] + 0.05 * X_WG[:3, 0]
    d = np.random.default_rng(0).normal(size=(300, 3))
    ball = target + 0.025 * d / np.linalg.norm(d, axis=1, keepdims=True)
    system.GetInputPort("point_map").FixValue(context, AbstractValue.Make(
        PointMapSnapshot(ball, np.zeros(len(ball), np.int64), 0.03, 1)))
    system.GetInputPort("target").FixValue(context, target)
    system.GetInputPort("robot_configuration").FixValue(context, q_pre)
    simulator = Simulator(system, context)
    q_grasp_move = q_pre.copy()
    q_grasp_move[-1] += 0.1  # a wrist roll at the pre-grasp
    plans = {}
    for goal_id, phase in ((1, Phase.OBSERVE), (2, Phase.GRASP_MOVE)):
        system.GetInputPort("goal").FixValue(context, AbstractValue.Make(_goal(goal_id, q_grasp_move, "plan", phase)))
        simulator.AdvanceTo(context.get_time() + 0.1)
        assert system.planner.checker.env.grasp_target_radius == 0.0, phase
        plans[phase] = system.GetOutputPort("trajectory").Eval(context)
    assert not plans[Phase.OBSERVE].success  # the gripper starts inside the target's points
    assert plans[Phase.GRASP_MOVE].success and plans[Phase.GRASP_MOVE].approach_index == 0

def test_arm_floor_clearance_sees_the_gripper_on_the_floor():
    """The floor is not in the map: the motion layer measures how low the arm's
    spheres go (the base's own spheres, which reach below the floor, excluded)."""
    checker = SphereCollisionChecker.for_fetch(CollisionEnvironment())
    q = layout.stow_configuration(0.0, 0.0, 0.0)
    assert arm_floor_clearance(checker, q[None]) > 0.2
    down = q.copy()
    down[layout.TORSO] = 0.0
    down[layout.ARM] = [0.0, 1.5, 0.0, 0.0, 0.0, 0.0, 0.0]  # shoulder lifted down: the arm points at the floor
    assert arm_floor_clearance(checker, np.stack([q, down])) < 0.0


def test_the_planners_checker_keeps_the_arm_above_the_floor():
    """The map holds no floor points, but the planner's checker rejects an arm
    below ``arm_floor_clearance`` (padded spheres), the base's spheres exempt.
    Between two low arm configurations whose straight motion sweeps the
    forearm 12 cm through the floor of an empty map, the plan keeps the
    unpadded arm at least the motion layer's clearance above it; without the
    floor test the planner takes the straight motion."""
    q = layout.stow_configuration(0.0, 0.0, 0.0)
    down = q.copy()
    down[layout.TORSO] = 0.0
    down[layout.ARM] = [0.0, 0.9, 0.0, 0.5, 0.0, 0.5, 0.0]  # the gripper below the floor
    checker = SphereCollisionChecker.for_fetch(CollisionEnvironment())
    assert checker.is_free(q[None])[0] and not checker.is_free(down[None])[0]
    assert checker.drive_free(np.array([[0.5, 0.2, 0.3]]), q[3:])[0]  # the base's own spheres reach below z = 0
    no_floor_config = PlannerConfig(attempt_wall_limit_s=5.0, arm_floor_clearance=None)
    assert SphereCollisionChecker.for_fetch(CollisionEnvironment(), no_floor_config.checker_config()).is_free(down[None])[0]

    a = np.array([0.0, 0.0, 0.0, 0.02, 0.37, 0.93, -1.32, 0.94, 0.1, 0.67, 1.47])
    b = np.array([0.0, 0.0, 0.0, 0.04, -1.56, 0.88, 0.96, -0.58, 2.74, 0.0, -2.03])
    needed = PlannerSystemConfig().floor_clearance
    plans = {}
    for name, config in (("floor", PlannerConfig(attempt_wall_limit_s=5.0)), ("no floor", no_floor_config)):
        planner = WholeBodyPlanner.for_fetch(CollisionEnvironment(), config)
        assert min(arm_floor_clearance(planner.checker, a[None]), arm_floor_clearance(planner.checker, b[None])) > 0.05
        result = planner.plan(a, b)
        assert result.success, (name, result.message)
        plans[name] = arm_floor_clearance(planner.checker, densify(result.trajectory.q, planner.checker, 0.005))
    assert plans["floor"] >= needed, plans
    assert plans["no floor"] < 0.0, plans


def test_hold_goal_stops_the_robot():
    system, context = _system()
    q0 = layout.stow_configuration(0.0, 0.0, 0.0)
    system.GetInputPort("robot_configuration").FixValue(context, q0)
    system.GetInputPort("goal").FixValue(context, AbstractValue.Make(_goal(1, q0, "hold", Phase.GRASP_CLOSE)))
    Simulator(system, context).AdvanceTo(0.25)
    assert system.GetOutputPort("trajectory").Eval(context).trajectory is None
    assert system.GetOutputPort("motion_feedback").Eval(context).event == MotionEvent.NONE


def test_planner_exception_becomes_a_planning_failure_with_traceback(caplog):
    system, context = _system()

    def broken_plan(q_start, q_goal):
        raise RuntimeError("numba kernel exploded")

    system.planner.plan = broken_plan
    q0 = layout.stow_configuration(0.0, 0.0, 0.0)
    system.GetInputPort("robot_configuration").FixValue(context, q0)
    system.GetInputPort("goal").FixValue(context, AbstractValue.Make(
        _goal(2, layout.stow_configuration(2.0, 0.0, 0.0), "plan")))
    with caplog.at_level(logging.ERROR):
        Simulator(system, context).AdvanceTo(0.05)
    plan = system.GetOutputPort("trajectory").Eval(context)
    assert not plan.success and plan.reason == EXCEPTION_REASON
    assert "numba kernel exploded" in plan.error
    assert system.GetOutputPort("trajectory").Eval(context).trajectory is None
    assert system.GetOutputPort("motion_feedback").Eval(context).event == MotionEvent.FAILED
    assert "Traceback" in caplog.text and "broken_plan" in caplog.text


def _wall(x, y, revision):
    axes = [np.arange(x - 0.05, x + 0.05, 0.03), np.arange(y - 0.6, y + 0.6, 0.03), np.arange(0.05, 1.5, 0.03)]
    p = np.stack(np.meshgrid(*axes, indexing="ij"), -1).reshape(-1, 3)
    return PointMapSnapshot(p, np.zeros(len(p), np.int64), 0.03, revision)


def test_replanning_stops_after_max_replans():
    config = PlannerSystemConfig(max_replans=2, planner=PlannerConfig(attempt_wall_limit_s=5.0))
    system, context = _system(config)
    q0 = layout.stow_configuration(0.0, 0.0, 0.0)
    system.GetInputPort("robot_configuration").FixValue(context, q0)
    system.GetInputPort("goal").FixValue(context, AbstractValue.Make(
        _goal(4, layout.stow_configuration(4.0, 0.0, 0.0), "plan")))
    simulator = Simulator(system, context)
    simulator.AdvanceTo(0.05)
    events, numbers = [], []
    # Each new map puts a short wall across the current path's middle: each plan is invalidated.
    for revision in range(1, 5):
        traj = system.GetOutputPort("trajectory").Eval(context).trajectory
        if traj is None:
            break
        x, y = traj.sample(0.5 * (traj.start_time + traj.end_time))[:2]
        system.GetInputPort("point_map").FixValue(context, AbstractValue.Make(_wall(x, y, revision)))
        simulator.AdvanceTo(context.get_time() + config.recheck_period)
        feedback = system.GetOutputPort("motion_feedback").Eval(context)
        events.append(feedback.event)
        numbers.append(feedback.number)
    plan = system.GetOutputPort("trajectory").Eval(context)
    assert events[:2] == [MotionEvent.REPLANNED, MotionEvent.REPLANNED]
    assert numbers[0] < numbers[1] < numbers[2]  # each replan is its own report to the policy
    assert events[2] == MotionEvent.FAILED and plan.reason == REPLAN_LIMIT_REASON


def test_remaining_path_starts_at_the_robot():
    q0 = layout.stow_configuration(0.0, 0.0, 0.0)
    traj = linear_trajectory(q0, layout.stow_configuration(2.0, 0.0, 0.0), 0.0, 0.5)
    q = traj.sample(0.5 * traj.end_time) + np.r_[0.0, 0.05, np.zeros(9)]
    rest = remaining_path(traj, q)
    np.testing.assert_allclose(rest[0], q)
    assert rest[1, 0] > q[0] and len(rest) < traj.num_waypoints


def test_planner_handles_costmap_bands_on_different_grids():
    """Regression: the box room seen from (-1, 0.5) gave height bands with
    different crops and the planner raised 'costmap layers do not share a grid'."""
    import sys
    from pathlib import Path

    sys.path.insert(0, str(Path(__file__).parent))
    from scenes import box_room_scenario
    from vamg_drake.diagram import DiagramConfig, build_diagram
    from vamg_drake.world.scenario import PlanarPose

    scenario = box_room_scenario(time_limit=5.0)
    scenario.robot_start = PlanarPose(-1.0, 0.5, 0.0)
    config = DiagramConfig(start_sweep=0.0)
    config.policy_system.start_delay = 0.0
    ed = build_diagram(scenario, config)
    simulator = Simulator(ed.diagram)
    simulator.Initialize()
    for t in np.arange(0.1, 1.01, 0.1):
        simulator.AdvanceTo(t)
        plan = ed.planner.GetOutputPort("trajectory").Eval(ed.planner.GetMyContextFromRoot(simulator.get_context()))
        assert plan.reason != EXCEPTION_REASON, plan.error


def test_a_start_put_in_collision_by_the_map_backs_out_along_the_robots_path():
    """The robot drives 1 m along +x; then the map shows a wall through its
    front. Planning from there fails (start in collision): the system backs
    out along the path it came by, to a configuration the padded spheres find
    free, and plans the goal from there."""
    system, context = _system()
    simulator = Simulator(system, context)
    goal = _goal(7, layout.stow_configuration(0.0, 1.5, 0.0), "plan")
    q_port = system.GetInputPort("robot_configuration")
    # The drive (a held "hold" goal: the robot is moved by hand here).
    system.GetInputPort("goal").FixValue(context, AbstractValue.Make(_goal(6, layout.stow_configuration(0, 0, 0),
                                                                           "hold")))
    for x in np.linspace(0.0, 1.0, 21):
        q_port.FixValue(context, layout.stow_configuration(x, 0.0, 0.0))
        simulator.AdvanceTo(context.get_time() + 0.1)
    system.GetInputPort("point_map").FixValue(context, AbstractValue.Make(_wall(1.2, 0.0, 1)))
    system.GetInputPort("goal").FixValue(context, AbstractValue.Make(goal))
    simulator.AdvanceTo(context.get_time() + 0.1)
    plan = system.GetOutputPort("trajectory").Eval(context)
    assert plan.success and plan.retreat, plan.reason
    back = plan.trajectory.q
    assert np.all(np.diff(back[:, 0]) <= 1e-9) and back[-1, 0] < 1.0  # straight back along +x's path
    checker = system.planner.checker
    assert not checker.unpadded().is_free(back[:1])[0] and checker.is_free(back[-1:])[0]
    # At the retreat's end the goal is planned from there.
    q_port.FixValue(context, back[-1])
    simulator.AdvanceTo(plan.trajectory.end_time + 0.2)
    plan = system.GetOutputPort("trajectory").Eval(context)
    assert plan.success and not plan.retreat and plan.goal_id == 7
    np.testing.assert_allclose(plan.trajectory.q[0, :2], back[-1, :2], atol=1e-6)
    np.testing.assert_allclose(plan.trajectory.q[-1], goal.q_goal, atol=1e-6)


def test_the_supervisor_step_is_a_function_of_its_state_and_inputs():
    """The plain core without a simulator: a step leaves the state it is given
    as it was, stepping it again gives the same plan, and the state carries
    the robot's recent configurations (for retreats) and the plan."""
    planner = WholeBodyPlanner.for_fetch(CollisionEnvironment(), PlannerConfig(attempt_wall_limit_s=5.0))
    supervisor = MotionSupervisor(planner, PlannerSystemConfig())
    initial = supervisor.initial_state()
    q0, q1 = layout.stow_configuration(0.0, 0.0, 0.0), layout.stow_configuration(1.5, 0.5, 0.3)
    inputs = MotionInputs(_goal(1, q1, "plan"), q0, 0.0, 0)
    first, event = supervisor.step(initial, inputs)
    again, event_again = supervisor.step(initial, inputs)
    assert initial.plan.goal_id == -1 and initial.history == () and initial.last_replan_time == -np.inf
    assert event == event_again == MotionEvent.NONE
    assert first.plan.success and first.plan.goal_id == 1 and first.last_replan_time == 0.0
    np.testing.assert_array_equal(first.plan.trajectory.q, again.plan.trajectory.q)
    assert len(first.history) == 1 and np.array_equal(first.history[0][1], q0)
    # At the goal after the trajectory's end: REACHED, with the robot's path recorded.
    end = first.plan.trajectory.end_time
    reached, event = supervisor.step(first, MotionInputs(_goal(1, q1, "plan"), q1, end + 0.1, 0))
    assert event == MotionEvent.REACHED and reached.plan is first.plan and len(reached.history) == 2
    assert len(first.history) == 1
