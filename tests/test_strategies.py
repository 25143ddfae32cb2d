"""The baseline strategies: goal sequences and failure categories with scripted
samplers, the same with the real samplers in synthetic scenes, the per-method
system settings, and every method's diagram stepping for 1 s."""

from __future__ import annotations

import dataclasses as dc

import numpy as np
import pytest
from pydrake.systems.analysis import Simulator

from behaviour_stepper import Stepper
from scenes import box_room_scenario
from vamg_drake.bench.methods import known_methods, load_method
from vamg_drake.diagram import DiagramConfig, build_diagram, load_diagram_config
from vamg_drake.testing import synthetic_clouds as clouds
from vamg_drake.perception.depth_points import DepthToPointsConfig
from vamg_drake.policy.behaviour_tree import (
    BehaviourConfig,
    FailureCategory,
    MotionEvent,
    Phase,
    PolicyInputs,
    SubgoalBehaviour,
    SubgoalProposal,
)
from vamg_drake.policy.kinematic_maps import KinematicMaps
from vamg_drake.policy.strategies import (
    BEHAVIOURS,
    CapmapPlacementBehaviour,
    ClosedLoopReplanningBehaviour,
    DirectGraspingBehaviour,
    NavAndManipBehaviour,
    StrategyConfig,
    StrategySamplers,
    make_strategy,
)
from vamg_drake.policy.subgoal_pipeline import SubgoalPipeline
from vamg_drake.robot import layout
from vamg_drake.robot.head_camera import HeadCameraConfig
from vamg_drake.robot.kinematics import FetchKinematics

TARGET = np.array([1.0, 0.0, 0.8])


class Scripted:
    """A sampler answering from a list (the last answer repeats); records its calls."""

    def __init__(self, name: str, answers: list[bool], category=FailureCategory.SUBGOAL) -> None:
        self.name, self.answers, self.category, self.calls = name, answers, category, 0

    def __call__(self, inputs: PolicyInputs) -> SubgoalProposal:
        ok = self.answers[min(self.calls, len(self.answers) - 1)]
        self.calls += 1
        if not ok:
            return SubgoalProposal.failure(f"{self.name} failed #{self.calls}", self.category)
        q = np.asarray(inputs.q, float).copy()
        q[1] += 0.1 * self.calls  # every sample a different goal
        q[0] += {"grasp": 0.0, "navigate": 1.0, "observe": -1.0}[self.name]
        return SubgoalProposal(True, q, q + 0.01 if self.name == "grasp" else None, np.zeros(2))


def _inputs(t: float = 0.0, q: np.ndarray | None = None) -> PolicyInputs:
    return PolicyInputs(t, layout.stow_configuration(0, 0, 0) if q is None else q, np.zeros((0, 3)), TARGET)


def _scripted(cls, grasp=(True,), navigate=(True,), observe=(True,), grasp_category=FailureCategory.SUBGOAL,
              navigate_category=FailureCategory.SUBGOAL, goal_is_free=None, **cfg):
    rejected = []
    samplers = StrategySamplers(Scripted("grasp", list(grasp), grasp_category),
                                Scripted("navigate", list(navigate), navigate_category),
                                Scripted("observe", list(observe)), goal_is_free, rejected.append)
    return Stepper(cls(samplers, BehaviourConfig(**cfg))), samplers, rejected


def _grasp_to_success(bt, cmd, t: float):
    """Drives the grasp execution phases from GRASP_MOVE to SUCCEEDED."""
    assert cmd.phase == Phase.GRASP_MOVE and cmd.motion == "plan"
    cmd = bt.step(_inputs(t, cmd.q_goal), MotionEvent.REACHED)
    assert cmd.phase == Phase.GRASP_APPROACH and cmd.motion == "linear"
    cmd = bt.step(_inputs(t + 1, cmd.q_goal), MotionEvent.REACHED)
    assert cmd.phase == Phase.GRASP_CLOSE and cmd.gripper_opening == 0.0
    cmd = bt.step(_inputs(t + 2.5, cmd.q_goal))
    assert cmd.phase == Phase.GRASP_LIFT
    return bt.step(_inputs(t + 4, cmd.q_goal), MotionEvent.REACHED)


# -- scripted samplers --------------------------------------------------------


def test_direct_grasping_is_a_fixed_sequence_sampled_once() -> None:
    bt, s, _ = _scripted(DirectGraspingBehaviour)
    cmd = bt.step(_inputs())
    assert cmd.phase == Phase.OBSERVE and cmd.motion == "plan"
    cmd = bt.step(_inputs(1.0, cmd.q_goal), MotionEvent.REACHED)
    assert cmd.phase == Phase.PREGRASP and cmd.motion == "plan"
    cmd = bt.step(_inputs(2.0, cmd.q_goal), MotionEvent.REACHED)
    cmd = _grasp_to_success(bt, cmd, 3.0)
    assert cmd.phase == Phase.SUCCEEDED
    assert (s.observe.calls, s.navigate.calls, s.grasp.calls) == (1, 1, 1)
    assert bt.goals_issued == {"grasp": 1, "pre_grasp": 1, "observe": 1}


@pytest.mark.parametrize("stage_events", [0, 1, 2])
def test_direct_grasping_ends_on_the_first_motion_failure(stage_events: int) -> None:
    bt, s, _ = _scripted(DirectGraspingBehaviour)
    cmd = bt.step(_inputs())
    for k in range(stage_events):
        cmd = bt.step(_inputs(1.0 + k, cmd.q_goal), MotionEvent.REACHED)
    failing = cmd.phase
    cmd = bt.step(_inputs(5.0, cmd.q_goal), MotionEvent.FAILED)
    assert cmd.phase == Phase.FAILED and cmd.failure == FailureCategory.PLANNING, failing
    assert "does not resample" in cmd.reason
    assert s.observe.calls + s.navigate.calls + s.grasp.calls == stage_events + 1


def test_direct_grasping_ends_with_the_sampler_category() -> None:
    bt, s, _ = _scripted(DirectGraspingBehaviour, navigate=[False], navigate_category=FailureCategory.REACHABILITY)
    cmd = bt.step(_inputs())
    cmd = bt.step(_inputs(1.0, cmd.q_goal), MotionEvent.REACHED)
    assert cmd.phase == Phase.FAILED and cmd.failure == FailureCategory.REACHABILITY
    assert s.navigate.calls == 1 and s.grasp.calls == 0
    assert bt.stage_failures["pre_grasp"] == ("navigate failed #1", "reachability")
    # A grasp that cannot be sampled from the reached base: its category, no retry.
    bt, s, _ = _scripted(DirectGraspingBehaviour, grasp=[False], grasp_category=FailureCategory.PERCEPTION)
    cmd = bt.step(_inputs())
    cmd = bt.step(_inputs(1.0, cmd.q_goal), MotionEvent.REACHED)
    cmd = bt.step(_inputs(2.0, cmd.q_goal), MotionEvent.REACHED)
    assert cmd.phase == Phase.FAILED and cmd.failure == FailureCategory.PERCEPTION and s.grasp.calls == 1


def test_invalidated_goal_is_replanned_when_still_free_else_per_strategy() -> None:
    free = {"value": True}
    check = lambda inputs, q_goal: free["value"]  # noqa: E731
    for cls in (DirectGraspingBehaviour, NavAndManipBehaviour, ClosedLoopReplanningBehaviour):
        bt, s, _ = _scripted(cls, goal_is_free=check)
        free["value"] = True
        cmd = bt.step(_inputs())
        calls = s.navigate.calls + s.observe.calls
        again = bt.step(_inputs(1.0), MotionEvent.INVALIDATED)
        # The same goal under a new id: the planner plans again, nothing is resampled.
        assert again.goal_id == cmd.goal_id + 1 and again.phase == cmd.phase
        np.testing.assert_array_equal(again.q_goal, cmd.q_goal)
        assert s.navigate.calls + s.observe.calls == calls
        free["value"] = False
        after = bt.step(_inputs(2.0), MotionEvent.INVALIDATED)
        if cls is DirectGraspingBehaviour:
            assert after.phase == Phase.FAILED and after.failure == FailureCategory.SUBGOAL, cls
        else:
            assert after.phase == cmd.phase and not np.array_equal(after.q_goal, cmd.q_goal), cls
            assert bt.goals_issued["pre_grasp"] == 1  # an invalidated goal does not use up the budget
    # A goal the samplers call free but the planner keeps invalidating is
    # replanned once (max_same_goal_replans), then resampled.
    for cls in (NavAndManipBehaviour, ClosedLoopReplanningBehaviour):
        bt, s, _ = _scripted(cls, goal_is_free=lambda i, q: True)
        cmd = bt.step(_inputs())
        again = bt.step(_inputs(1.0), MotionEvent.INVALIDATED)
        np.testing.assert_array_equal(again.q_goal, cmd.q_goal)
        after = bt.step(_inputs(2.0), MotionEvent.INVALIDATED)
        assert after.phase == cmd.phase and not np.array_equal(after.q_goal, cmd.q_goal), cls
        newer = bt.step(_inputs(3.0), MotionEvent.INVALIDATED)  # the new goal gets its own replan
        np.testing.assert_array_equal(newer.q_goal, after.q_goal)
    # Invalidations are bounded.
    bt, _, _ = _scripted(NavAndManipBehaviour, goal_is_free=lambda i, q: True, max_invalidations=3)
    bt.step(_inputs())
    for k in range(4):
        cmd = bt.step(_inputs(1.0 + k), MotionEvent.INVALIDATED)
    assert cmd.phase == Phase.FAILED and cmd.failure == FailureCategory.PLANNING


@pytest.mark.parametrize("cls", [NavAndManipBehaviour, CapmapPlacementBehaviour])
def test_nav_and_manip_navigates_then_grasps_from_the_reached_base(cls) -> None:
    bt, s, rejected = _scripted(cls)
    cmd = bt.step(_inputs())
    assert cmd.phase == Phase.PREGRASP
    # A failed drive: the base pose is resampled and the failed one rejected.
    first = cmd.q_goal
    cmd = bt.step(_inputs(1.0), MotionEvent.FAILED)
    assert cmd.phase == Phase.PREGRASP and s.navigate.calls == 2
    np.testing.assert_array_equal(rejected[0], first)
    cmd = bt.step(_inputs(2.0, cmd.q_goal), MotionEvent.REACHED)
    assert cmd.phase == Phase.GRASP_MOVE and s.grasp.calls == 1
    # Failed arm motions resample the grasp from the same base, max_motion_failures times.
    for k in range(bt.config.max_motion_failures):
        cmd = bt.step(_inputs(3.0 + k, cmd.q_goal), MotionEvent.FAILED)
        assert cmd.phase == Phase.GRASP_MOVE and s.grasp.calls == k + 2
    cmd = bt.step(_inputs(9.0, cmd.q_goal), MotionEvent.FAILED)
    assert cmd.phase == Phase.FAILED and cmd.failure == FailureCategory.PLANNING
    assert s.navigate.calls == 2  # never back to navigation


def test_nav_and_manip_grasp_failure_ends_the_episode_with_its_category() -> None:
    bt, s, _ = _scripted(NavAndManipBehaviour, grasp=[False], grasp_category=FailureCategory.REACHABILITY)
    patience = StrategyConfig().grasp_patience
    cmd = bt.step(_inputs())
    q_base = cmd.q_goal
    cmd = bt.step(_inputs(1.0, q_base), MotionEvent.REACHED)
    # Grasps are resampled from the reached base for `grasp_patience` seconds...
    assert cmd.phase == Phase.IDLE and s.grasp.calls == 1
    cmd = bt.step(_inputs(1.0 + 0.5 * patience, q_base))
    assert cmd.phase == Phase.IDLE and s.grasp.calls == 2
    # ...then the failure ends the episode with the sampler's category.
    cmd = bt.step(_inputs(1.1 + patience, q_base))
    assert cmd.phase == Phase.FAILED and cmd.failure == FailureCategory.REACHABILITY
    assert s.navigate.calls == 1 and s.grasp.calls == 3
    # A grasp found on a later tick is executed.
    bt, s, _ = _scripted(NavAndManipBehaviour, grasp=[False, True])
    cmd = bt.step(_inputs())
    cmd = bt.step(_inputs(1.0, cmd.q_goal), MotionEvent.REACHED)
    cmd = bt.step(_inputs(1.1, cmd.q_goal))
    assert cmd.phase == Phase.GRASP_MOVE and s.grasp.calls == 2
    # Navigation goals are budgeted: repeated failed drives end as PLANNING.
    bt, s, _ = _scripted(NavAndManipBehaviour, max_pregrasp_goals=3)
    cmd = bt.step(_inputs())
    for k in range(3):
        cmd = bt.step(_inputs(1.0 + k), MotionEvent.FAILED)
    assert cmd.phase == Phase.FAILED and cmd.failure == FailureCategory.PLANNING and s.navigate.calls == 3


def test_closed_loop_resamples_the_pregrasp_on_failures_within_budget() -> None:
    bt, s, _ = _scripted(ClosedLoopReplanningBehaviour, grasp=[False, True], grasp_category=FailureCategory.REACHABILITY)
    cmd = bt.step(_inputs())
    assert cmd.phase == Phase.PREGRASP and s.observe.calls == 0
    # No grasp from the reached pre-grasp: a new pre-grasp at once.
    cmd = bt.step(_inputs(1.0, cmd.q_goal), MotionEvent.REACHED)
    assert cmd.phase == Phase.PREGRASP and s.navigate.calls == 2 and s.grasp.calls == 1
    cmd = bt.step(_inputs(2.0, cmd.q_goal), MotionEvent.REACHED)
    assert cmd.phase == Phase.GRASP_MOVE
    # A failed grasp motion goes back to a new pre-grasp too.
    cmd = bt.step(_inputs(3.0, cmd.q_goal), MotionEvent.FAILED)
    assert cmd.phase == Phase.PREGRASP and s.navigate.calls == 3
    cmd = bt.step(_inputs(4.0, cmd.q_goal), MotionEvent.REACHED)
    assert _grasp_to_success(bt, cmd, 5.0).phase == Phase.SUCCEEDED
    # Every pre-grasp reached, no grasp from any: the grasp's category once the budget is used.
    bt, s, _ = _scripted(ClosedLoopReplanningBehaviour, grasp=[False], grasp_category=FailureCategory.REACHABILITY,
                         max_pregrasp_goals=3)
    cmd = bt.step(_inputs())
    for k in range(3):
        cmd = bt.step(_inputs(1.0 + k, cmd.q_goal), MotionEvent.REACHED)
    assert cmd.phase == Phase.FAILED and cmd.failure == FailureCategory.REACHABILITY and s.navigate.calls == 3


def test_total_motion_failures_and_sampler_exceptions() -> None:
    bt, _, _ = _scripted(ClosedLoopReplanningBehaviour, max_total_failures=2, max_pregrasp_goals=10)
    cmd = bt.step(_inputs())
    for k in range(3):
        cmd = bt.step(_inputs(1.0 + k), MotionEvent.FAILED)
    assert cmd.phase == Phase.FAILED and cmd.failure == FailureCategory.PLANNING
    assert "3 motion failures" in cmd.reason

    def broken(inputs):
        raise ZeroDivisionError("injected")

    samplers = StrategySamplers(broken, broken, broken)
    for cls in (DirectGraspingBehaviour, NavAndManipBehaviour, ClosedLoopReplanningBehaviour):
        cmd = Stepper(cls(samplers)).step(_inputs())
        assert cmd.phase == Phase.FAILED and cmd.failure == FailureCategory.ERROR  # a bug, not a subgoal failure
        assert "ZeroDivisionError" in cmd.reason and "Traceback" in cmd.reason


# -- the real samplers in synthetic scenes -------------------------------------


@pytest.fixture(scope="module")
def maps() -> KinematicMaps:
    return KinematicMaps.load_or_build()


@pytest.fixture(scope="module")
def pipeline(maps) -> SubgoalPipeline:
    return SubgoalPipeline(maps, HeadCameraConfig(), DepthToPointsConfig().depth_max, seed=0)


@pytest.fixture(scope="module")
def scene():
    return clouds.tabletop_scene()


def _facing(q: np.ndarray, target: np.ndarray) -> float:
    to_target = (target[:2] - q[:2]) / np.linalg.norm(target[:2] - q[:2])
    return float(np.cos(q[layout.THETA]) * to_target[0] + np.sin(q[layout.THETA]) * to_target[1])


def _arm_only(goal: np.ndarray, q_base: np.ndarray) -> None:
    np.testing.assert_allclose(goal[: layout.TORSO + 1], q_base[: layout.TORSO + 1])


def test_real_nav_and_manip(pipeline, scene) -> None:
    points, target = scene
    q0 = layout.stow_configuration(-1.5, 0.5, 0.0)
    bt = Stepper(make_strategy("nav_and_manip", pipeline))
    cmd = bt.step(PolicyInputs(0.0, q0, points, target))
    assert cmd.phase == Phase.PREGRASP, bt.tree_status()
    goal = cmd.q_goal
    np.testing.assert_allclose(goal[layout.ARM], layout.Q_ARM_STOW)
    assert np.linalg.norm(goal[:2] - target[:2]) == pytest.approx(StrategyConfig().nav_standoff[0], abs=0.01)
    assert _facing(goal, target) > 0.999
    assert pipeline.collision_fn(points, target, goal)(goal[None])[0]
    assert pipeline.visibility.check(goal[None], target, points)[0][0]
    # A failed drive: the next base pose avoids the failed one.
    cmd = bt.step(PolicyInputs(1.0, q0, points, target), MotionEvent.FAILED)
    assert cmd.phase == Phase.PREGRASP
    assert np.linalg.norm(cmd.q_goal[:2] - goal[:2]) > StrategyConfig().avoid_radius
    # From the reached base: arm-only planning to a grasp near the target.
    q_reached = cmd.q_goal.copy()
    q_reached[:2] += 0.02  # the tracker stops near, not at, the goal
    cmd = bt.step(PolicyInputs(2.0, q_reached, points, target), MotionEvent.REACHED)
    assert cmd.phase == Phase.GRASP_MOVE, bt.tree_status()
    _arm_only(cmd.q_goal, q_reached)
    assert np.linalg.norm(FetchKinematics.instance().gripper_pose(bt.q_grasp)[:3, 3] - target) < 0.12


def test_real_nav_and_manip_failures(pipeline, scene) -> None:
    points, target = scene
    # The base stopped far from the target: no grasp from there, no repositioning.
    bt = Stepper(make_strategy("nav_and_manip", pipeline))
    cmd = bt.step(PolicyInputs(0.0, layout.stow_configuration(-1.5, 0.5, 0.0), points, target))
    cmd = bt.step(PolicyInputs(1.0, layout.stow_configuration(-1.5, 0.5, 0.0), points, target), MotionEvent.REACHED)
    cmd = bt.step(PolicyInputs(1.1 + StrategyConfig().grasp_patience, layout.stow_configuration(-1.5, 0.5, 0.0),
                               points, target))
    assert cmd.phase == Phase.FAILED and cmd.failure == FailureCategory.REACHABILITY, bt.stage_failures
    # A can in the middle of a 2 m x 2 m table: no base pose at the fixed distance.
    table = clouds.box_surface_cloud([0.5, -1.0, 0.0], [2.5, 1.0, 0.6])
    can = clouds.can_cloud(center=(1.5, 0.0, 0.6), seed=3)
    points = np.concatenate([clouds.room_walls_cloud(), table, can])
    bt = Stepper(make_strategy("nav_and_manip", pipeline))
    cmd = bt.step(PolicyInputs(0.0, layout.stow_configuration(-1.0, 0.0, 0.0), points, np.array([1.5, 0.0, 0.66])))
    assert cmd.phase == Phase.FAILED and cmd.failure == FailureCategory.SUBGOAL
    assert "standoffs" in cmd.reason


def test_real_capmap_placement(maps, scene) -> None:
    points, target = scene
    q0 = layout.stow_configuration(-1.5, 0.5, 0.0)
    grasped = 0
    for seed in range(4):  # one base sample per episode: some seeds give no grasp from it
        pipeline = SubgoalPipeline(maps, HeadCameraConfig(), DepthToPointsConfig().depth_max, seed=seed)
        bt = Stepper(make_strategy("capmap_placement", pipeline))
        cmd = bt.step(PolicyInputs(0.0, q0, points, target))
        assert cmd.phase == Phase.PREGRASP, bt.tree_status()
        goal = cmd.q_goal
        np.testing.assert_allclose(goal[layout.ARM], layout.Q_ARM_STOW)
        lo, hi = pipeline.config.pregrasp.base_radius
        assert lo - 0.05 <= np.linalg.norm(goal[:2] - target[:2]) <= hi + 0.05
        assert layout.within_limits(goal) and pipeline.collision_fn(points, target, goal)(goal[None])[0]
        assert goal[layout.TORSO] >= layout.TORSO_STOW  # lower, the stowed arm touches the base
        cmd = bt.step(PolicyInputs(1.0, goal, points, target), MotionEvent.REACHED)
        if cmd.phase == Phase.GRASP_MOVE:
            _arm_only(cmd.q_goal, goal)
            grasped += 1
        else:
            assert cmd.phase == Phase.FAILED and cmd.failure in (FailureCategory.REACHABILITY, FailureCategory.SUBGOAL)
    assert grasped >= 1


def test_real_direct_grasping(maps, scene) -> None:
    points, target = scene
    q0 = layout.stow_configuration(-1.5, 0.5, 0.0)
    kin = FetchKinematics.instance()
    grasped = 0
    for seed in range(4):  # one pre-grasp sample per episode: some seeds give no grasp
        pipeline = SubgoalPipeline(maps, HeadCameraConfig(), DepthToPointsConfig().depth_max, seed=seed)
        bt = Stepper(make_strategy("direct_grasping", pipeline))
        cmd = bt.step(PolicyInputs(0.0, q0, points, target))
        assert cmd.phase == Phase.OBSERVE, bt.tree_status()
        np.testing.assert_allclose(cmd.q_goal[layout.ARM], layout.Q_ARM_STOW)
        cmd = bt.step(PolicyInputs(1.0, cmd.q_goal, points, target), MotionEvent.REACHED)
        assert cmd.phase == Phase.PREGRASP, bt.tree_status()
        q_pre = cmd.q_goal
        assert np.linalg.norm(kin.gripper_pose(q_pre)[:3, 3] - target) == pytest.approx(0.10, abs=0.01)  # whole body
        cmd = bt.step(PolicyInputs(2.0, q_pre, points, target), MotionEvent.REACHED)
        assert bt.goals_issued["pre_grasp"] == 1 and bt.goals_issued["observe"] == 1
        if cmd.phase == Phase.GRASP_MOVE:
            _arm_only(cmd.q_goal, q_pre)
            grasped += 1
        else:  # no resampling: the grasp sampler's category ends the episode
            assert cmd.phase == Phase.FAILED and cmd.failure.value == bt.stage_failures["grasp"][1]
    assert grasped >= 2


def test_real_closed_loop(pipeline, scene) -> None:
    points, target = scene
    q0 = layout.stow_configuration(-1.5, 0.5, 0.0)
    kin = FetchKinematics.instance()
    bt = Stepper(make_strategy("closed_loop_replanning", pipeline))
    cmd = bt.step(PolicyInputs(0.0, q0, points, target))
    assert cmd.phase == Phase.PREGRASP and bt.goals_issued["observe"] == 0
    assert np.linalg.norm(kin.gripper_pose(cmd.q_goal)[:3, 3] - target) == pytest.approx(0.10, abs=0.01)
    first = cmd.q_goal
    cmd = bt.step(PolicyInputs(1.0, q0, points, target), MotionEvent.FAILED)
    assert cmd.phase == Phase.PREGRASP and not np.allclose(cmd.q_goal, first)
    # Reached pre-grasps without a grasp are resampled until one gives a grasp (within the budget).
    for k in range(bt.config.max_pregrasp_goals):
        q_pre = cmd.q_goal
        cmd = bt.step(PolicyInputs(2.0 + k, q_pre, points, target), MotionEvent.REACHED)
        if cmd.phase != Phase.PREGRASP:
            break
        assert "no grasp from the reached pre-grasp" in bt.history[-2][2]
    assert cmd.phase == Phase.GRASP_MOVE, bt.history
    _arm_only(cmd.q_goal, q_pre)


def test_target_inside_furniture_is_perception_for_every_strategy(pipeline) -> None:
    cabinet = clouds.box_surface_cloud([1.0, -0.4, 0.0], [1.6, 0.4, 0.9], spacing=0.02)
    points = np.concatenate([clouds.room_walls_cloud(), cabinet])
    target = np.array([1.3, 0.0, 0.45])
    for strategy in ("direct_grasping", "nav_and_manip", "capmap_placement", "closed_loop_replanning"):
        cmd = Stepper(make_strategy(strategy, pipeline)).step(
            PolicyInputs(0.0, layout.stow_configuration(-1.0, 0.0, 0.0), points, target))
        assert cmd.phase == Phase.FAILED and cmd.failure == FailureCategory.PERCEPTION, strategy
        assert "enclosed" in cmd.reason


# -- configuration -------------------------------------------------------------


def test_strategy_registry_and_bad_input(pipeline) -> None:
    for strategy in BEHAVIOURS:  # the one list of strategies serves the diagram config too
        DiagramConfig(strategy=strategy).validate()
    with pytest.raises(ValueError, match="DiagramConfig.strategy: unknown strategy 'teleport'.*capmap_placement"):
        DiagramConfig(strategy="teleport").validate()
    assert type(make_strategy("subgoal_tree", pipeline)) is SubgoalBehaviour
    with pytest.raises(ValueError, match="unknown strategy 'teleport'.*nav_and_manip"):
        make_strategy("teleport", pipeline)
    from vamg_drake.systems.subgoal_policy_system import make_subgoal_policy

    with pytest.raises(ValueError, match="make_subgoal_policy: unknown strategy"):
        make_subgoal_policy(HeadCameraConfig(), DepthToPointsConfig().depth_max, strategy="teleport")
    for bad in (dict(nav_standoff=[]), dict(nav_standoff=[0.8, -1.0]), dict(capmap_tries=0), dict(avoid_radius=-0.1)):
        with pytest.raises(ValueError, match="StrategyConfig"):
            StrategyConfig(**bad)


def test_method_files_state_their_system_settings() -> None:
    expected = {"direct_grasping": ("target_only", 0.0), "closed_loop_replanning": ("velocity_aware", 1.0),
                "velocity_agnostic": ("velocity_agnostic", 0.0)}
    for name in ("full", "velocity_agnostic", "direct_grasping", "closed_loop_replanning", "nav_and_manip",
                 "capmap_placement"):
        config = load_method(name).config
        variant, replan_period = expected.get(name, ("velocity_aware", 0.0))
        assert (config.gaze.variant, config.planner.replan_period) == (variant, replan_period), name


@pytest.mark.parametrize("strategy, yaml_setting", [
    ("direct_grasping", "gaze: {variant: velocity_aware}"),
    ("closed_loop_replanning", "planner: {replan_period: 0.0}"),
])
def test_explicit_settings_equal_to_the_defaults_are_built_unchanged(strategy: str, yaml_setting: str) -> None:
    config = load_diagram_config("explicit.yaml", text=f"policy: full\nstrategy: {strategy}\n{yaml_setting}\n")
    assert config.gaze.variant == "velocity_aware" and config.planner.replan_period == 0.0
    before = dc.asdict(config)
    ed = build_diagram(box_room_scenario(), config)
    assert dc.asdict(config) == before and dc.asdict(ed.config) == before
    assert ed.gaze.core.config.variant == "velocity_aware"
    assert ed.planner.config.replan_period == 0.0


@pytest.mark.parametrize("name", known_methods())
def test_every_method_builds_and_steps_one_second(name: str) -> None:
    method = load_method(name)
    ed = build_diagram(box_room_scenario(), method.config)
    sim = Simulator(ed.diagram)
    sim.Initialize()
    sim.AdvanceTo(1.0)
    if method.config.policy != "full":
        return
    assert type(ed.policy.behaviour) is BEHAVIOURS[method.config.strategy]
    assert ed.gaze.core.config.variant == method.config.gaze.variant
    assert ed.planner.config.replan_period == method.config.planner.replan_period
    policy_context = ed.policy.GetMyContextFromRoot(sim.get_context())
    goal = ed.policy.GetOutputPort("goal").Eval(policy_context)
    assert goal.goal_id > 0 and goal.phase != Phase.FAILED, ed.policy.behaviour_state(policy_context).history


def test_a_raising_sampler_is_an_error_in_every_strategy():
    def broken(inputs):
        raise ZeroDivisionError("injected sampler fault")

    for cls in (DirectGraspingBehaviour, NavAndManipBehaviour, CapmapPlacementBehaviour,
                ClosedLoopReplanningBehaviour):
        bt, samplers, _ = _scripted(cls)
        samplers.grasp = samplers.navigate = samplers.observe = broken
        cmd = bt.step(_inputs())
        assert cmd.phase == Phase.FAILED and cmd.failure == FailureCategory.ERROR, cls
        assert "ZeroDivisionError: injected sampler fault" in cmd.reason, cls
