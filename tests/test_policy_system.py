"""The SubgoalPolicy LeafSystem in a small diagram (injected samplers)."""

from __future__ import annotations

import numpy as np
from pydrake.common.value import AbstractValue
from pydrake.systems.analysis import Simulator
from pydrake.systems.framework import DiagramBuilder
from pydrake.systems.primitives import ConstantValueSource, ConstantVectorSource

from vamg_drake.perception.depth_points import DepthToPointsConfig
from vamg_drake.perception.raycast_map import PointMapSnapshot
from vamg_drake.policy.behaviour_tree import (
    MotionEvent,
    Phase,
    PolicyInputs,
    SubgoalBehaviour,
    SubgoalProposal,
    SubgoalSamplers,
    FailureCategory,
)
from vamg_drake.robot import layout
from vamg_drake.robot.head_camera import HeadCameraConfig
from vamg_drake.systems.subgoal_policy_system import MotionFeedback, SubgoalPolicy

Q0 = layout.stow_configuration(0.0, 0.0, 0.0)


def _samplers(grasp_ok: bool, log: list) -> SubgoalSamplers:
    def grasp(inputs: PolicyInputs) -> SubgoalProposal:
        log.append(("grasp", inputs.p_WM.shape[0], tuple(inputs.p_WT)))
        if not grasp_ok:
            return SubgoalProposal.failure("out of reach", FailureCategory.REACHABILITY)
        return SubgoalProposal(True, inputs.q.copy(), inputs.q.copy(), np.zeros(2))

    def pregrasp(inputs: PolicyInputs) -> SubgoalProposal:
        log.append(("pregrasp",))
        q = inputs.q.copy()
        q[0] += 1.0
        return SubgoalProposal(True, q, head=np.zeros(2))

    def observe(inputs: PolicyInputs) -> SubgoalProposal:
        return SubgoalProposal.failure("nothing", FailureCategory.SUBGOAL)

    return SubgoalSamplers(grasp, pregrasp, observe)


def _diagram(behaviour: SubgoalBehaviour, feedback: MotionFeedback | None):
    builder = DiagramBuilder()
    policy = builder.AddSystem(SubgoalPolicy(behaviour))
    points = np.array([[1.0, 0.0, 0.7], [1.0, 0.1, 0.7]])
    snapshot = PointMapSnapshot(points, np.floor(points / 0.03).astype(np.int64), 0.03, 1)
    m = builder.AddSystem(ConstantValueSource(AbstractValue.Make(snapshot)))
    q = builder.AddSystem(ConstantVectorSource(Q0))
    t = builder.AddSystem(ConstantVectorSource(np.array([1.0, 0.0, 0.76])))
    builder.Connect(m.get_output_port(), policy.GetInputPort("point_map"))
    builder.Connect(q.get_output_port(), policy.GetInputPort("robot_configuration"))
    builder.Connect(t.get_output_port(), policy.GetInputPort("target"))
    if feedback is not None:
        f = builder.AddSystem(ConstantValueSource(AbstractValue.Make(feedback)))
        builder.Connect(f.get_output_port(), policy.GetInputPort("motion_feedback"))
    return builder.Build(), policy


def test_policy_system_ports_and_fallback() -> None:
    log: list = []
    diagram, policy = _diagram(SubgoalBehaviour(_samplers(False, log)), None)
    sim = Simulator(diagram)
    sim.AdvanceTo(0.25)
    ctx = policy.GetMyContextFromRoot(sim.get_context())
    goal = policy.GetOutputPort("goal").Eval(ctx)
    assert goal.phase == Phase.PREGRASP and goal.motion == "plan"
    assert policy.GetOutputPort("phase").Eval(ctx) == "pre_grasp"
    np.testing.assert_allclose(goal.q_goal[0], Q0[0] + 1.0)
    assert policy.GetOutputPort("gripper_command").Eval(ctx)[0] == layout.GRIPPER_MAX_OPENING
    assert log[0] == ("grasp", 2, (1.0, 0.0, 0.76))
    assert "Pre-grasp" in policy.tree_status(ctx)


def test_policy_system_reached_by_distance_and_closes_gripper() -> None:
    log: list = []
    diagram, policy = _diagram(SubgoalBehaviour(_samplers(True, log)), None)
    sim = Simulator(diagram)
    sim.AdvanceTo(0.45)  # the grasp goal equals q: reached -> approach -> close
    ctx = policy.GetMyContextFromRoot(sim.get_context())
    assert policy.GetOutputPort("goal").Eval(ctx).phase == Phase.GRASP_CLOSE
    assert policy.GetOutputPort("gripper_command").Eval(ctx)[0] == 0.0


def test_policy_system_motion_failure_feedback() -> None:
    log: list = []
    diagram, policy = _diagram(SubgoalBehaviour(_samplers(False, log)), MotionFeedback(goal_id=1, event=MotionEvent.FAILED))
    sim = Simulator(diagram)
    sim.AdvanceTo(0.35)
    ctx = policy.GetMyContextFromRoot(sim.get_context())
    goal = policy.GetOutputPort("goal").Eval(ctx)
    # Goal 1 (pre-grasp) failed once, handled once: a fresh pre-grasp goal 2.
    assert goal.phase == Phase.PREGRASP and goal.goal_id == 2
    assert policy.behaviour_state(ctx).motion_failure_counts["pre_grasp"] == 1


def test_policy_system_handles_each_replan_report() -> None:
    """Two replans of the same goal are two reports (`MotionFeedback.number`):
    the policy counts both and keeps the goal."""
    log: list = []
    diagram, policy = _diagram(SubgoalBehaviour(_samplers(False, log)), None)
    sim = Simulator(diagram)
    sim.AdvanceTo(0.15)
    ctx = policy.GetMyMutableContextFromRoot(sim.get_mutable_context())
    goal = policy.GetOutputPort("goal").Eval(ctx)
    assert goal.phase == Phase.PREGRASP
    for number in (1, 1, 2):
        policy.GetInputPort("motion_feedback").FixValue(ctx, MotionFeedback(goal.goal_id, MotionEvent.REPLANNED, number))
        sim.AdvanceTo(sim.get_context().get_time() + 0.25)
    assert policy.behaviour_state(ctx).goal_replans == 2
    assert policy.GetOutputPort("goal").Eval(ctx).goal_id == goal.goal_id


def test_real_subgoal_policy_in_a_diagram() -> None:
    from vamg_drake.testing import synthetic_clouds
    from vamg_drake.systems.subgoal_policy_system import make_subgoal_policy

    points, target = synthetic_clouds.tabletop_scene()
    q0 = layout.stow_configuration(-1.5, 0.5, 0.0)
    builder = DiagramBuilder()
    policy = builder.AddSystem(make_subgoal_policy(HeadCameraConfig(), DepthToPointsConfig().depth_max))
    snapshot = PointMapSnapshot(points, np.floor(points / 0.03).astype(np.int64), 0.03, 1)
    m = builder.AddSystem(ConstantValueSource(AbstractValue.Make(snapshot)))
    q = builder.AddSystem(ConstantVectorSource(q0))
    t = builder.AddSystem(ConstantVectorSource(target))
    builder.Connect(m.get_output_port(), policy.GetInputPort("point_map"))
    builder.Connect(q.get_output_port(), policy.GetInputPort("robot_configuration"))
    builder.Connect(t.get_output_port(), policy.GetInputPort("target"))
    sim = Simulator(builder.Build())
    sim.AdvanceTo(0.05)
    ctx = policy.GetMyContextFromRoot(sim.get_context())
    goal = policy.GetOutputPort("goal").Eval(ctx)
    assert goal.phase == Phase.PREGRASP and goal.motion == "plan", policy.tree_status(ctx)
    assert np.all(np.isfinite(goal.q_goal)) and np.all(np.isfinite(goal.head))


def test_phase_names_match_the_scenario_vocabulary() -> None:
    from vamg_drake.policy.behaviour_tree import stage_name
    from vamg_drake.world.scenario import POLICY_PHASES

    names = {stage_name(p) for p in Phase}
    assert set(POLICY_PHASES) <= names
    assert stage_name(Phase.GRASP_APPROACH) == "grasp" and stage_name(Phase.PREGRASP) == "pre_grasp"
