"""The whole-body path tracker: core convergence, validation, swaps, LeafSystem, world."""

import logging
import math
from pathlib import Path

import numpy as np
import pytest
from pydrake.common.value import AbstractValue
from pydrake.common.yaml import yaml_load_typed
from pydrake.systems.analysis import Simulator
from pydrake.systems.framework import DiagramBuilder
from pydrake.systems.primitives import ConstantValueSource, ConstantVectorSource, Demultiplexer

from scenes import box_room_scenario
from vamg_drake.testing.tracking_rollout import (
    arc_reference,
    cross_track_errors,
    reeds_shepp_reference,
    rollout,
    straight_reference,
)
from vamg_drake.control.whole_body_tracker import (
    U_LIMITS,
    TrackerConfig,
    TrackerStatus,
    WholeBodyTrackerCore,
    one_step_mpc,
    one_step_mpc_reference,
    state_error,
)
from vamg_drake.planning.motion_messages import PlannedTrajectory
from vamg_drake.planning.smoothing import time_parametrize
from vamg_drake.planning.trajectory import TimedTrajectory
from vamg_drake.robot import layout
from vamg_drake.robot.spheres import SphereModel
from vamg_drake.systems.robot_command import MAX_JOINT_LEAD, RobotCommandIntegrator
from vamg_drake.systems.robot_state import RobotStateSelector
from vamg_drake.systems.tracker_system import WholeBodyTracker
from vamg_drake.world.world_builder import WorldConfig, build_world, initial_robot_configuration


def _core(**overrides) -> WholeBodyTrackerCore:
    return WholeBodyTrackerCore(TrackerConfig(**overrides))


def _assert_reached(core: WholeBodyTrackerCore, tr: TimedTrajectory, q: np.ndarray) -> None:
    cfg = core.config
    dx = state_error(tr.q[-1], q)
    assert math.hypot(dx[0], dx[1]) <= cfg.goal_position_tolerance
    assert abs(dx[2]) <= cfg.goal_heading_tolerance
    assert np.max(np.abs(dx[3:])) <= cfg.goal_joint_tolerance


def _arc_poses(x0, y0, th0, radius, angle, step=0.03):
    """Base poses (N, 3) along a left arc starting at (x0, y0, th0)."""
    phi = np.linspace(0.0, angle, int(np.ceil(radius * angle / step)) + 1)
    cx, cy = x0 - radius * np.sin(th0), y0 + radius * np.cos(th0)
    th = th0 + phi
    return np.stack([cx + radius * np.sin(th), cy - radius * np.cos(th), th], axis=1)


def _whole_body(poses: np.ndarray) -> np.ndarray:
    joints = layout.stow_configuration(0.0, 0.0, 0.0)[layout.TORSO_ARM]
    return np.concatenate([poses, np.broadcast_to(joints, (poses.shape[0], 8))], axis=1)


# --- the control law ---------------------------------------------------------


def test_closed_form_matches_the_papers_matrix_formula():
    rng = np.random.default_rng(0)
    for _ in range(20):
        q_diag = rng.uniform(1.0, 30.0, layout.NQ)  # also unequal x / y weights
        r_diag = rng.uniform(0.1, 2.0, 10)
        dx, theta = rng.normal(size=layout.NQ), rng.uniform(-4.0, 4.0)
        np.testing.assert_allclose(
            one_step_mpc(dx, theta, q_diag, r_diag),
            one_step_mpc_reference(dx, theta, np.diag(q_diag), np.diag(r_diag)),
            rtol=1e-12, atol=1e-12,
        )


def test_reference_behind_gives_reverse_motion():
    core = _core()
    q0 = layout.stow_configuration(0.0, 0.0, 0.3)
    poses = np.stack([-np.linspace(0.0, 1.0, 34) * math.cos(0.3), -np.linspace(0.0, 1.0, 34) * math.sin(0.3),
                      np.full(34, 0.3)], axis=1)
    tr = time_parametrize(_whole_body(poses))
    assert core.set_trajectory(tr.times, tr.q, q0) == ""
    cmd = core.command(q0)
    assert cmd.base_velocity[0] < -0.1 and abs(cmd.base_velocity[1]) < 1e-9


# --- convergence with the real integrator -------------------------------------


@pytest.mark.parametrize("seed", [0, 1])
def test_converges_on_a_straight_reference(seed):
    tr = straight_reference(np.random.default_rng(seed))
    for lateral_gain in (0.0, TrackerConfig().lateral_gain):  # the paper's law, and with lateral correction
        core = _core(lateral_gain=lateral_gain)
        # Start 5 cm behind the path's start: the tracker catches up.
        q0 = tr.q[0].copy()
        q0[:2] -= 0.05 * np.array([math.cos(q0[2]), math.sin(q0[2])])
        assert core.set_trajectory(tr.times, tr.q, q0) == ""
        ro = rollout(core, q0, tr.duration + 5.0)
        assert ro.done, ro.commands[-1]
        _assert_reached(core, tr, ro.final_q)
        after_start = ro.times > 0.5  # (before, the robot is behind the path's first point)
        assert cross_track_errors(tr.q[:, :2], ro.q[after_start, :2]).max() < 0.01
        assert ro.times[-1] < tr.duration + 2.0  # keeps the trajectory's pace


@pytest.mark.parametrize("seed", [0, 3])
def test_converges_on_an_arc_with_moving_arm(seed):
    tr = arc_reference(np.random.default_rng(seed))
    core = _core()
    assert core.set_trajectory(tr.times, tr.q, tr.q[0]) == ""
    ro = rollout(core, tr.q[0], tr.duration + 5.0)
    assert ro.done, ro.commands[-1]
    _assert_reached(core, tr, ro.final_q)
    assert cross_track_errors(tr.q[:, :2], ro.q[:, :2]).max() < 0.02
    assert ro.times[-1] < tr.duration + 2.0


@pytest.mark.parametrize("seed", [0, 2, 5])
def test_converges_on_a_reeds_shepp_path_with_a_cusp(seed):
    tr = reeds_shepp_reference(np.random.default_rng(seed), radius=0.4)
    core = _core()
    assert core.set_trajectory(tr.times, tr.q, tr.q[0]) == ""
    ro = rollout(core, tr.q[0], tr.duration + 6.0)
    v = np.array([c.base_velocity[0] for c in ro.commands])
    assert v.min() < -0.1 and v.max() > 0.1  # reverses and drives forward
    assert ro.done, ro.commands[-1]
    _assert_reached(core, tr, ro.final_q)
    assert cross_track_errors(tr.q[:, :2], ro.q[:, :2]).max() < 0.08


def test_joint_space_reference_converges_within_limits_and_wraps():
    q_start = layout.stow_configuration(0.5, -0.2, 1.0)
    q_start[layout.TORSO] = 0.1
    q_goal = q_start.copy()
    q_goal[layout.TORSO] = 0.3
    q_goal[layout.ARM] = [0.2, -0.3, 2.8, 1.0, 3.6, -0.5, -2.0]  # forearm roll passes +pi (unwrapped path)
    path = q_start + np.linspace(0.0, 1.0, 60)[:, None] * (q_goal - q_start)
    tr = time_parametrize(path)
    core = _core()
    # The robot reports its continuous joints wrapped differently (2 pi apart).
    # It also starts with the torso 0.1 m low, so the torso runs at its clamp.
    q0 = q_start.copy()
    q0[layout.THETA] += 2.0 * math.pi
    q0[8] -= 2.0 * math.pi
    q0[layout.TORSO] -= 0.05
    q_start[layout.TORSO] += 0.05
    assert core.set_trajectory(tr.times, tr.q, q0) == ""
    ro = rollout(core, q0, tr.duration + 5.0)
    assert ro.done, ro.commands[-1]
    _assert_reached(core, tr, ro.final_q)
    u = np.array([c.u for c in ro.commands])
    assert np.all(np.abs(u) <= U_LIMITS + 1e-12)
    assert np.any(np.abs(u[:, 2]) > 0.99 * layout.TRACKER_TORSO_V)  # the torso ran at its clamp
    assert np.all(np.abs(ro.q[:, :2] - q0[:2]) < 1e-12)  # the base stayed put
    assert np.max(np.abs(u[:, :2])) < 1e-9


def test_clip_mode_also_respects_limits():
    tr = arc_reference(np.random.default_rng(1))
    core = _core(uniform_clamp=False, gain=10.0)
    assert core.set_trajectory(tr.times, tr.q, tr.q[0]) == ""
    ro = rollout(core, tr.q[0], 1.0)
    u = np.array([c.u for c in ro.commands])
    assert np.all(np.abs(u) <= U_LIMITS + 1e-12) and np.any(np.abs(u) >= U_LIMITS - 1e-9)


def test_progress_is_monotone_on_a_self_crossing_path():
    # A full loop plus a bit: the path crosses its own start.
    poses = _arc_poses(0.0, 0.0, 0.0, 0.8, 2.0 * math.pi + 1.0)
    tr = time_parametrize(_whole_body(poses))
    core = _core()
    assert core.set_trajectory(tr.times, tr.q, tr.q[0]) == ""
    ro = rollout(core, tr.q[0], tr.duration + 5.0)
    t_near = np.array([c.nearest_time for c in ro.commands])
    assert np.all(np.diff(t_near) >= 0.0)
    assert ro.done and not any(c.done for c in ro.commands[:-1])
    assert ro.times[-1] > 0.9 * tr.duration  # no shortcut to the end


def test_an_in_place_turn_with_position_jitter_is_one_turn_not_many_cusps():
    """Drive 1 m, then turn 0.8 rad in place while the base position wobbles
    by 0.2 mm (as planned paths do): the turn is no chain of cusps, and the
    robot finishes it (seed 0: it stopped with 0.79 rad of the turn left)."""
    s = np.linspace(0.0, 1.0, 34)
    drive = np.stack([s, np.zeros_like(s), np.zeros_like(s)], axis=1)
    a = np.linspace(0.0, -0.8, 40)[1:]
    rng = np.random.default_rng(0)
    turn = np.stack([1.0 + rng.normal(0, 2e-4, a.size), rng.normal(0, 2e-4, a.size), a], axis=1)
    tr = time_parametrize(_whole_body(np.concatenate([drive, turn])))
    core = _core()
    assert core.set_trajectory(tr.times, tr.q, tr.q[0]) == ""
    assert len(core._stops) == 1  # the final waypoint only
    ro = rollout(core, tr.q[0], tr.end_time + 3.0)
    assert abs(ro.final_q[2] - tr.q[-1, 2]) < 0.05


def test_a_three_point_turn_with_a_lateral_offset_at_the_cusp_is_finished():
    """The seed-0 pre-grasp motion (recorded in tests/data): it ends in a
    reverse-forward turn; the robot reached the first cusp 3.3 cm away along
    the path but not across it, and crept there until the motion timed out.
    Cusps are passed on the along-track error (the unicycle cannot remove the
    lateral one there)."""
    data = np.load(Path(__file__).parent / "data" / "seed0_three_point_turn.npz")
    times, q = data["times"], data["q"]
    finish = {}
    for tolerance in (1e-3, TrackerConfig().cusp_lateral_tolerance):
        # Corners off and the paper's gain at stops: this is about the cusp tolerance alone.
        core = WholeBodyTrackerCore(TrackerConfig(cusp_lateral_tolerance=tolerance, corner_angle=np.pi, stop_gain=1.0))
        assert core.set_trajectory(times, q, q[0]) == ""
        ro = rollout(core, q[0], times[-1] + 8.0)
        assert ro.done
        finish[tolerance] = ro.times[-1]
    assert finish[TrackerConfig().cusp_lateral_tolerance] < finish[1e-3] - 1.0


def test_gripper_stays_near_a_curved_whole_body_path():
    """Seed 0's motion to a pre-grasp (1202 waypoints, the base turning while
    the arm unfolds). With the paper's law the gripper cut the path's corners
    by 12 cm and touched the wall behind the counter; the path-error gain,
    corner stops and stop gain halve that and finish no later."""
    data = np.load(Path(__file__).parent / "data" / "seed0_pregrasp_motion.npz")
    times, q, q0 = data["times"], data["q"], data["q0"]
    spheres = SphereModel.load()

    def gripper(qs):
        return np.array([spheres.world_spheres(x)[spheres.is_gripper].mean(axis=0) for x in qs])

    planned = gripper(q)
    deviation, finish = {}, {}
    paper = TrackerConfig(path_error_gain=1.0, corner_angle=np.pi, stop_gain=1.0)
    for name, config in (("paper", paper), ("default", TrackerConfig())):
        core = WholeBodyTrackerCore(config)
        assert core.set_trajectory(times, q, q0) == ""
        ro = rollout(core, q0, times[-1] - times[0] + 8.0)
        assert ro.done
        actual = gripper(ro.q[::2])
        deviation[name] = np.max(np.min(np.linalg.norm(actual[:, None] - planned[None], axis=2), axis=1))
        finish[name] = ro.times[-1]
    assert deviation["paper"] > 0.10
    assert deviation["default"] < 0.075
    assert finish["default"] <= finish["paper"]


def test_a_drive_then_an_arm_motion_has_a_corner_stop_that_is_reached():
    """Where a base drive meets an arm motion the path turns by 90 degrees in
    joint space: the reference waits at the corner, so the arm does not start
    unfolding while the base is still short of the corner."""
    s = np.linspace(0.0, 1.0, 34)
    drive = _whole_body(np.stack([s, np.zeros_like(s), np.zeros_like(s)], axis=1))
    unfold = drive[-1] + np.linspace(0.0, 1.0, 30)[1:, None] * np.r_[np.zeros(4), -1.2, -0.8, np.zeros(5)][None]
    tr = time_parametrize(np.concatenate([drive, unfold]))
    corner = drive.shape[0] - 1
    arm_started_early = {}
    for angle in (np.pi, TrackerConfig().corner_angle):
        core = WholeBodyTrackerCore(TrackerConfig(corner_angle=angle))
        assert core.set_trajectory(tr.times, tr.q, tr.q[0]) == ""
        assert len(core._stops) == (1 if angle == np.pi else 2)
        ro = rollout(core, tr.q[0], tr.duration + 5.0)
        assert ro.done
        short = ro.q[:, 0] < tr.q[corner, 0] - 0.03  # the base still 3 cm short of the corner
        arm_started_early[angle] = float(np.max(np.abs(ro.q[short, 4] - tr.q[0, 4])))
    assert arm_started_early[np.pi] > 0.05
    assert arm_started_early[TrackerConfig().corner_angle] < 0.01


def test_a_required_stop_is_reached_where_the_look_ahead_would_cut_the_turn():
    """A 45-degree turn of an arm motion is no corner (`corner_angle` 1.2), so
    the look-ahead chord cuts it; a `TimedTrajectory.stops` waypoint there (the
    planner's straight-approach entry) is reached within the stop tolerance."""
    q0 = _whole_body(np.zeros((1, 3)))[0]
    first = q0 + np.linspace(0.0, 1.0, 30)[:, None] * np.r_[np.zeros(4), -1.0, np.zeros(6)][None]
    second = first[-1] + np.linspace(0.0, 1.0, 20)[1:, None] * np.r_[np.zeros(4), -0.5, -0.5, np.zeros(5)][None]
    path = time_parametrize(np.concatenate([first, second]))
    entry = first.shape[0] - 1
    closest = {}
    for stops in ((), (entry,)):
        tr = TimedTrajectory(path.times, path.q, stops=stops)
        core = WholeBodyTrackerCore()
        assert core.set_trajectory(tr.times, tr.q, tr.q[0], tr.stops) == ""
        ro = rollout(core, tr.q[0], tr.duration + 5.0)
        assert ro.done
        closest[stops] = float(np.min(np.max(np.abs(ro.q[:, 4:6] - tr.q[entry, 4:6]), axis=1)))
    assert closest[()] > 0.05
    assert closest[(entry,)] <= TrackerConfig().corner_joint_tolerance + 1e-6
    with pytest.raises(ValueError, match="stops must index waypoints"):
        TimedTrajectory(path.times, path.q, stops=(path.num_waypoints,))
    assert path.shifted(3.0).stops == () and TimedTrajectory(path.times, path.q, stops=(entry,)).shifted(3.0).stops == (entry,)


def test_a_pause_in_the_path_does_not_stall():
    a = np.linspace(0.0, 1.0, 34)
    poses = np.stack([a, np.zeros_like(a), np.zeros_like(a)], axis=1)
    q = _whole_body(poses)
    tr0 = time_parametrize(q)
    # Hold for 2 s in the middle (a duplicate waypoint 2 s later).
    k = 17
    times = np.r_[tr0.times[: k + 1], tr0.times[k] + 2.0, tr0.times[k + 1:] + 2.0]
    qq = np.r_[q[: k + 1], q[k][None], q[k + 1:]]
    core = _core()
    assert core.set_trajectory(times, qq, qq[0]) == ""
    ro = rollout(core, qq[0], times[-1] + 3.0)
    assert ro.done


# --- bad input ----------------------------------------------------------------


def _good():
    return straight_reference(np.random.default_rng(0))


@pytest.mark.parametrize(
    "corrupt, words",
    [
        (lambda t, q: (t, np.where(np.arange(q.shape[0])[:, None] == 10, np.nan, q)), "NaN"),
        (lambda t, q: (np.r_[t[:5], np.inf, t[6:]], q), "times contain NaN"),
        (lambda t, q: (t, np.r_[q[:20], q[20:] + [1.0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0]]), "base jumps"),
        (lambda t, q: (t, np.r_[q[:20], q[20:] + [0, 0, 0, 0, 0, 0, 4.0, 0, 0, 0, 0]]), "wrap-around"),
        (lambda t, q: (t, np.r_[q[:20], q[20:] + [0, 0, 0, 0, 0.9, 0, 0, 0, 0, 0, 0]]), "a jump in time"),
        (lambda t, q: (t, np.r_[q[:20], q[20:] + [0, 0, 0, 0, 0, 1.2, 0, 0, 0, 0, 0]]), "shoulder_lift_joint jumps"),
        (lambda t, q: (t[::-1], q), "increase strictly"),
        (lambda t, q: (t, q[:, :7]), "shape"),
        (lambda t, q: (t[:-1], q), "times must have shape"),
    ],
)
def test_malformed_trajectory_is_rejected_and_stops(corrupt, words):
    tr = _good()
    core = _core()
    assert core.set_trajectory(tr.times, tr.q, tr.q[0]) == ""
    moving = core.command(tr.q[0])
    assert np.linalg.norm(moving.u) > 0.1
    times, q = corrupt(np.array(tr.times), np.array(tr.q))
    reason = core.set_trajectory(times, q, tr.q[0])
    assert words in reason
    cmd = core.command(tr.q[0])
    assert cmd.status == TrackerStatus.REJECTED and cmd.reason == reason
    assert np.all(cmd.u == 0.0) and not cmd.done
    # A valid trajectory is accepted again afterwards.
    assert core.set_trajectory(tr.times, tr.q, tr.q[0]) == ""
    assert core.command(tr.q[0]).status == TrackerStatus.TRACKING


@pytest.mark.parametrize(
    "offset, field",
    [
        ([0, 0.5, 0], "max_start_position_error"),  # (in the path's frame: 0.5 m to the left)
        ([-0.5, 0, 0], "max_start_position_error"),  # 0.5 m behind the start
        ([0, 0, 1.0], "max_start_heading_error"),
        ([0, 0, 0, 0, 0, 0.5], "max_start_joint_error"),
    ],
)
def test_start_far_from_the_robot_is_rejected(offset, field):
    tr = _good()
    q_now = tr.q[0].copy()
    c, s = math.cos(q_now[2]), math.sin(q_now[2])
    offset = np.r_[offset, np.zeros(layout.NQ - len(offset))]
    q_now[:2] += [c * offset[0] - s * offset[1], s * offset[0] + c * offset[1]]
    q_now[2:] += offset[2:]
    core = _core()
    reason = core.set_trajectory(tr.times, tr.q, q_now)
    assert field in reason
    assert np.all(core.command(q_now).u == 0.0)


def test_invalid_robot_configuration_gives_zero_command():
    tr = _good()
    core = _core()
    assert core.set_trajectory(tr.times, tr.q, tr.q[0]) == ""
    bad = tr.q[0].copy()
    bad[4] = np.nan
    for q in (bad, tr.q[0][:7], "junk"):
        cmd = core.command(q)
        assert cmd.status == TrackerStatus.INVALID_STATE and np.all(cmd.u == 0.0)
    assert core.command(tr.q[0]).status == TrackerStatus.TRACKING  # the trajectory survives


def test_config_loads_from_yaml_and_validates():
    config = yaml_load_typed(schema=TrackerConfig, data="{period: 0.1, lookahead_time: 0.3, q_diag: [1,1,1,1,1,1,1,1,1,1,1]}")
    assert config.period == 0.1 and config.q_diag == [1.0] * 11 and config.r_diag == TrackerConfig().r_diag
    WholeBodyTrackerCore(config)
    with pytest.raises(ValueError, match="q_diag"):
        WholeBodyTrackerCore(TrackerConfig(q_diag=[1.0] * 3))
    with pytest.raises(ValueError, match="lookahead_time"):
        WholeBodyTrackerCore(TrackerConfig(lookahead_time=-1.0))
    with pytest.raises(ValueError, match="period"):
        WholeBodyTrackerCore(TrackerConfig(period=float("nan")))


# --- mid-execution swap ----------------------------------------------------------


def test_swapping_trajectories_mid_execution_keeps_the_command_continuous():
    tr = arc_reference(np.random.default_rng(2))
    core = _core()
    assert core.set_trajectory(tr.times, tr.q, tr.q[0]) == ""
    ro = rollout(core, tr.q[0], 1.0, stop_when_done=False)
    q_now = ro.final_q
    before = core.command(q_now)
    # A replanned trajectory from the robot's current state that rejoins the
    # rest of the old path (as a planner replanning from q_now would produce).
    t_rest = np.r_[np.arange(before.nearest_time, tr.end_time - 1e-6, 0.05), tr.end_time]
    rest = tr.sample_many(t_rest)
    new_q = np.r_[q_now[None], rest[1:]]
    new_times = 5.0 + np.r_[0.0, t_rest[1:] - t_rest[0]]
    assert core.set_trajectory(new_times, new_q, q_now) == ""
    after = core.command(q_now)
    assert after.status == TrackerStatus.TRACKING
    assert np.max(np.abs(after.u - before.u) / U_LIMITS) < 0.1, (before.u, after.u)
    # And it still finishes.
    ro2 = rollout(core, q_now, tr.duration + 5.0)
    assert ro2.done
    _assert_reached(core, tr, ro2.final_q)


# --- the LeafSystem --------------------------------------------------------------


def _tracker_context(trajectory, q):
    system = WholeBodyTracker()
    context = system.CreateDefaultContext()
    system.GetInputPort("robot_configuration").FixValue(context, q)
    if trajectory is not None:
        plan = trajectory if isinstance(trajectory, PlannedTrajectory) else PlannedTrajectory(trajectory=trajectory)
        system.GetInputPort("trajectory").FixValue(context, AbstractValue.Make(plan))
    return system, context


def test_system_ports_and_zero_order_hold():
    tr = arc_reference(np.random.default_rng(0))
    system, context = _tracker_context(tr, tr.q[0])
    assert system.GetOutputPort("base_velocity").size() == 2
    assert system.GetOutputPort("joint_velocity").size() == 8
    assert system.GetInputPort("robot_configuration").size() == layout.NQ
    sim = Simulator(system, context)
    sim.AdvanceTo(0.01)
    tracking = system.GetOutputPort("tracking").Eval(context)
    assert tracking.status == TrackerStatus.TRACKING
    np.testing.assert_allclose(system.GetOutputPort("base_velocity").Eval(context), tracking.base_velocity)
    np.testing.assert_allclose(system.GetOutputPort("joint_velocity").Eval(context), tracking.joint_velocity)
    assert np.linalg.norm(tracking.u) > 0.1


def test_system_accepts_the_planners_planned_trajectory():
    tr = arc_reference(np.random.default_rng(0))
    system, context = _tracker_context(PlannedTrajectory(goal_id=1, trajectory=tr.shifted(3.0), success=True), tr.q[0])
    Simulator(system, context).AdvanceTo(0.01)
    tracking = system.GetOutputPort("tracking").Eval(context)
    assert tracking.status == TrackerStatus.TRACKING and tracking.nearest_time == pytest.approx(3.0)


def test_system_rejects_a_malformed_value_with_a_logged_reason(caplog):
    class Broken:
        times = np.array([0.0, 1.0])
        q = np.full((2, 11), np.nan)

    q0 = layout.stow_configuration(0.0, 0.0, 0.0)
    for value, words in ((Broken(), "NaN"), ({"not": "a trajectory"}, "no .times/.q")):
        system, context = _tracker_context(value, q0)
        with caplog.at_level(logging.WARNING):
            Simulator(system, context).AdvanceTo(0.2)
        tracking = system.GetOutputPort("tracking").Eval(context)
        assert tracking.status == TrackerStatus.REJECTED and words in tracking.reason
        assert words in caplog.text
        assert np.all(system.GetOutputPort("base_velocity").Eval(context) == 0.0)
        assert np.all(system.GetOutputPort("joint_velocity").Eval(context) == 0.0)


def test_system_without_trajectory_is_idle():
    system, context = _tracker_context(None, layout.stow_configuration(0.0, 0.0, 0.0))
    Simulator(system, context).AdvanceTo(0.1)
    assert system.GetOutputPort("tracking").Eval(context).status == TrackerStatus.IDLE
    assert np.all(system.GetOutputPort("base_velocity").Eval(context) == 0.0)


# --- with the real Drake world ----------------------------------------------------


def test_tracker_drives_the_simulated_robot_along_a_curved_path():
    scenario = box_room_scenario()
    V0 = initial_robot_configuration(scenario)
    q0 = V0[: layout.NQ]
    # A left arc of radius 1 m through 70 degrees from the start pose, arm stowed.
    poses = _arc_poses(q0[0], q0[1], q0[2], 1.0, math.radians(70.0))
    tr = time_parametrize(_whole_body(poses))

    builder = DiagramBuilder()
    world = build_world(builder, scenario, WorldConfig(enable_camera=False))
    plant = world.plant
    robot_state = builder.AddSystem(
        RobotStateSelector(plant.num_positions(), plant.num_velocities(), world.position_index, world.velocity_index)
    )
    builder.Connect(plant.get_state_output_port(), robot_state.GetInputPort("plant_state"))
    split = builder.AddSystem(Demultiplexer([layout.NQ, 4]))
    builder.Connect(robot_state.GetOutputPort("configuration"), split.get_input_port())
    command = builder.AddSystem(RobotCommandIntegrator(V0, world.actuator_joint_order))
    builder.Connect(command.GetOutputPort("desired_state"), plant.get_desired_state_input_port(world.robot))
    builder.Connect(robot_state.GetOutputPort("configuration"), command.GetInputPort("measured_configuration"))
    tracker = builder.AddSystem(WholeBodyTracker())
    source = builder.AddSystem(ConstantValueSource(AbstractValue.Make(PlannedTrajectory(trajectory=tr))))
    builder.Connect(source.get_output_port(), tracker.GetInputPort("trajectory"))
    builder.Connect(split.get_output_port(0), tracker.GetInputPort("robot_configuration"))
    for port in ("base_velocity", "joint_velocity"):
        builder.Connect(tracker.GetOutputPort(port), command.GetInputPort(port))
    head = builder.AddSystem(ConstantVectorSource(np.zeros(2)))
    builder.Connect(head.get_output_port(), command.GetInputPort("head_command"))
    gripper = builder.AddSystem(ConstantVectorSource([layout.GRIPPER_MAX_OPENING]))
    builder.Connect(gripper.get_output_port(), command.GetInputPort("gripper_command"))
    diagram = builder.Build()

    sim = Simulator(diagram)
    sim.Initialize()
    sim.AdvanceTo(tr.duration + 2.0)
    context = sim.get_context()
    q = split.get_output_port(0).Eval(split.GetMyContextFromRoot(context))
    tracking = tracker.GetOutputPort("tracking").Eval(tracker.GetMyContextFromRoot(context))
    assert tracking.done, tracking
    assert np.hypot(*(q[:2] - tr.q[-1, :2])) < 0.05
    assert abs(layout.wrap_angle(q[2] - tr.q[-1, 2])) < 0.08
    assert np.hypot(*(q[:2] - q0[:2])) > 1.0  # it really drove


def test_the_command_integrator_keeps_the_joint_targets_near_the_measured_joints():
    """Anti-windup: with the measured configuration connected, the integrated
    torso/arm targets lead it by at most `MAX_JOINT_LEAD`, however long a rate
    is commanded; without it they integrate freely (and head and base do anyway)."""
    V0 = np.r_[layout.stow_configuration(0.0, 0.0, 0.0), np.zeros(2), np.full(2, 0.04)]
    order = np.arange(V0.shape[0])
    desired = {}
    for connected in (False, True):
        command = RobotCommandIntegrator(V0, order)
        context = command.CreateDefaultContext()
        command.GetInputPort("base_velocity").FixValue(context, [0.2, 0.0])
        command.GetInputPort("joint_velocity").FixValue(context, np.r_[0.05, 0.5, -0.5, np.full(5, 0.5)])
        command.GetInputPort("head_command").FixValue(context, [0.5, 0.0])
        command.GetInputPort("gripper_command").FixValue(context, [layout.GRIPPER_MAX_OPENING])
        if connected:
            command.GetInputPort("measured_configuration").FixValue(context, V0)  # the robot does not move
        Simulator(command, context).AdvanceTo(0.6)
        desired[connected] = command.GetOutputPort("desired_configuration").Eval(context)
    lead = {k: v[layout.TORSO_ARM] - V0[layout.TORSO_ARM] for k, v in desired.items()}
    assert np.all(np.abs(lead[False][1:]) > 0.25)  # 0.6 s at 0.5 rad/s
    np.testing.assert_allclose(np.abs(lead[True]), MAX_JOINT_LEAD, atol=1e-9)
    for k in (False, True):
        assert desired[k][0] == pytest.approx(0.12, abs=0.01) and desired[k][layout.NQ] == pytest.approx(0.5)
