"""Look before you leave: the seen-floor grid and its hidden cells (points for
the planner), the tracker's rule that the base does not enter unseen cells,
the gaze's look at them, and the gaze window on the tracker's progress."""

import copy
import dataclasses as dc

import numpy as np
import pytest
from pydrake.systems.analysis import Simulator

from vamg_drake.control.whole_body_tracker import TrackerStatus
from vamg_drake.diagram import DiagramConfig
from vamg_drake.episode import run_episode
from vamg_drake.perception.gaze import GazeOptimizer as GazeCore, decide_fetch_gaze
from vamg_drake.perception.raycast_map import PointMapSnapshot
from vamg_drake.perception.seen_space import (LookGateConfig, _within_radius_of_path, SeenGrid, SeenSpaceConfig, unseen_footprint,
                                              with_hidden_cells)
from vamg_drake.perception.trajectory_sweep import TrajectorySweep
from vamg_drake.planning.motion_messages import PlannedTrajectory
from vamg_drake.planning.trajectory import TimedTrajectory
from vamg_drake.robot import layout
from vamg_drake.robot.head_camera import CameraIntrinsics, HeadCameraConfig
from vamg_drake.systems.gaze_system import GazeOptimizer
from vamg_drake.systems.tracker_system import WholeBodyTracker
from vamg_drake.world.episode_monitor import COLLISION
from vamg_drake.world.rooms import generate_scenario

K = CameraIntrinsics.from_config(HeadCameraConfig())


def _X_WC_down_forward(p_WC, pitch: float) -> np.ndarray:
    """A camera at p_WC looking along +x of W, pitched down by `pitch` [rad]."""
    c, s = np.cos(pitch), np.sin(pitch)
    z = np.array([c, 0.0, -s])  # optical axis
    x = np.array([0.0, -1.0, 0.0])  # image right
    X = np.eye(4)
    X[:3, :3] = np.column_stack([x, np.cross(z, x), z])
    X[:3, 3] = p_WC
    return X


def _grid(seen_at: float = np.inf) -> SeenGrid:
    grid = SeenGrid.around(np.zeros(2), SeenSpaceConfig(half_extent=4.0))
    return dc.replace(grid, first_seen=np.full(grid.shape, seen_at))


def test_cells_are_seen_where_the_ray_reaches_them_and_not_behind_a_surface():
    X_WC = _X_WC_down_forward([0.0, 0.0, 1.1], 0.9)
    grid = _grid()
    free = grid.observe(np.full((K.height, K.width), np.inf, np.float32), X_WC, K, t=1.0)
    ahead, beside, behind = free.cell_of(np.array([[1.0, 0.0], [0.0, 2.0], [-1.0, 0.0]]))
    assert free.seen_by(ahead[None], 1.0)[0] and not free.seen_by(ahead[None], 0.9)[0]
    assert not free.seen_by(np.array([beside, behind]), 10.0).any()
    # A surface 0.4 m in front of the camera hides the floor 1 m ahead ...
    wall = grid.observe(np.full((K.height, K.width), 0.4, np.float32), X_WC, K, t=1.0)
    assert not wall.seen_by(ahead[None], 10.0)[0]
    # ... and a surface just above a cell's probe point is an obstacle in the cell: seen.
    z_probe = np.array([1.0, 0.0, 0.25 - 1.1]) @ X_WC[:3, 2]
    top = grid.observe(np.full((K.height, K.width), 0.9 * z_probe, np.float32), X_WC, K, t=1.0)
    assert top.seen_by(ahead[None], 10.0)[0]
    assert top.hidden[ahead[0], ahead[1]] and top.hidden_points().shape[0] == 3 * top.hidden.sum()
    # Unless the surface is the robot's own base (the ring beside it aside).
    no_ring = SeenGrid.around(np.zeros(2), SeenSpaceConfig(half_extent=4.0, ring_radius=0.32))
    own = no_ring.observe(np.full((K.height, K.width), 0.9 * z_probe, np.float32), X_WC, K, t=1.0,
                          p_WB=np.array([0.65, 0.0]))
    assert not own.seen_by(ahead[None], 10.0)[0]
    # A ray that later reaches the probe frees a hidden cell.
    freed = top.observe(np.full((K.height, K.width), np.inf, np.float32), X_WC, K, t=2.0)
    assert not freed.hidden[ahead[0], ahead[1]] and freed.hidden_revision == top.hidden_revision + 1


def test_unseen_footprint_lists_the_unseen_cells_of_the_next_stretch_of_path():
    config = LookGateConfig(lookahead_distance=0.8, footprint_radius=0.35, max_bearing=1.75, settle_time=0.25)
    path = np.column_stack([np.linspace(0.0, 2.0, 101), np.zeros(101), np.zeros(101)])
    q_base = np.array([0.0, 0.0, 0.0])
    points = unseen_footprint(_grid(), path, q_base, 5.0, config)
    assert points.shape[0] > 50 and points.shape[1] == 3
    assert np.all(points[:, 0] <= 0.8 + 0.35 + 1e-9)  # only the next 0.8 m of travel
    assert np.all(np.hypot(points[:, 0], points[:, 1]) > 0.45)  # not under the robot nor in its blind ring
    assert np.all(np.abs(points[:, 1]) <= 0.35 + 1e-9)
    # Seen long enough ago: nothing to wait for; just seen: the map and the planner go first.
    assert unseen_footprint(_grid(seen_at=1.0), path, q_base, 5.0, config).shape[0] == 0
    assert unseen_footprint(_grid(seen_at=4.9), path, q_base, 5.0, config).shape[0] == points.shape[0]
    # Reversing: the cells behind the robot cannot be seen by the head, so are not waited for.
    assert unseen_footprint(_grid(), -path, q_base, 5.0, config).shape[0] == 0
    # Turning in place: the footprint stays where the robot stands; the path after
    # the turn is checked once the robot has turned towards it.
    turn_then_left = np.vstack([np.column_stack([np.zeros(10), np.zeros(10), np.linspace(0.0, np.pi / 2, 10)]),
                                np.column_stack([np.zeros(50), np.linspace(0.0, 1.0, 50), np.full(50, np.pi / 2)])])
    assert unseen_footprint(_grid(), turn_then_left, q_base, 5.0, config).shape[0] == 0
    turned = unseen_footprint(_grid(), turn_then_left[8:], np.array([0.0, 0.0, 1.3]), 5.0, config)
    assert turned.shape[0] > 50 and np.all(turned[:, 1] > 0.0)


def _straight_trajectory() -> TimedTrajectory:
    x = np.linspace(0.0, 2.0, 21)
    return TimedTrajectory(times=2.0 * x, q=np.array([layout.stow_configuration(xi, 0.0, 0.0) for xi in x]))


def _tracker_after(grid: SeenGrid | None, look: LookGateConfig, t: float = 0.3):
    tracker = WholeBodyTracker(look=look)
    context = tracker.CreateDefaultContext()
    tracker.GetInputPort("trajectory").FixValue(context, PlannedTrajectory(trajectory=_straight_trajectory()))
    tracker.GetInputPort("robot_configuration").FixValue(context, layout.stow_configuration(0.0, 0.0, 0.0))
    if grid is not None:
        tracker.GetInputPort("seen_space").FixValue(context, grid)
    simulator = Simulator(tracker, context)
    simulator.AdvanceTo(t)
    return tracker, context


def test_tracker_holds_while_the_path_ahead_is_unseen_and_asks_the_gaze_to_look():
    look = LookGateConfig(max_wait=1.0)
    tracker, context = _tracker_after(_grid(), look)
    command = tracker.GetOutputPort("tracking").Eval(context)
    assert command.status == TrackerStatus.WAITING
    assert np.all(tracker.GetOutputPort("base_velocity").Eval(context) == 0.0)
    assert tracker.GetOutputPort("look_request").Eval(context).shape[0] > 0
    assert tracker.GetOutputPort("trajectory_time").Eval(context)[0] == pytest.approx(0.0, abs=0.05)
    # Seen: it drives, and asks for nothing.
    tracker, context = _tracker_after(_grid(seen_at=0.0), look)
    assert tracker.GetOutputPort("base_velocity").Eval(context)[0] > 0.0
    assert tracker.GetOutputPort("look_request").Eval(context).shape[0] == 0
    # A cell that stays hidden holds the robot at most max_wait per trajectory.
    tracker, context = _tracker_after(_grid(), look, t=1.3)
    assert tracker.GetOutputPort("tracking").Eval(context).status == TrackerStatus.TRACKING
    assert tracker.GetOutputPort("base_velocity").Eval(context)[0] > 0.0
    # Without a seen-space input (or with the rule off) it drives at once.
    tracker, context = _tracker_after(None, look)
    assert tracker.GetOutputPort("base_velocity").Eval(context)[0] > 0.0
    tracker, context = _tracker_after(_grid(), LookGateConfig(enabled=False))
    assert tracker.GetOutputPort("base_velocity").Eval(context)[0] > 0.0


def test_gaze_looks_down_at_the_requested_cells_beside_the_base():
    core = GazeCore(K)
    q0 = layout.stow_configuration(0.0, 0.0, 0.0)
    look = np.array([[x, y, 0.25] for x in (0.3, 0.4, 0.5) for y in (0.35, 0.45)])
    decision = decide_fetch_gaze(core, q0, np.array([3.0, -1.0, 0.8]), None, 0.0, look_points=look)
    assert decision.sees_importance and decision.tilt > 0.8 and decision.pan > 0.0
    seen = np.array([[0.5, 0.0, 0.25]])
    assert decide_fetch_gaze(core, q0, None, None, 0.0, look_points=seen).scores.max() > 0


def test_gaze_window_starts_at_the_trackers_progress_not_the_clock():
    """The robot has not left (progress 0) although the clock says 4 s: the gaze
    looks along the first, straight stretch, not the later turn to the left."""
    q0 = layout.stow_configuration(0.0, 0.0, 0.0)
    trajectory = TimedTrajectory(
        times=np.array([0.0, 4.0, 4.5, 9.0]),
        q=np.array([q0, layout.stow_configuration(2.0, 0.0, 0.0), layout.stow_configuration(2.0, 0.0, np.pi / 2),
                    layout.stow_configuration(2.0, 2.5, np.pi / 2)]))
    system = GazeOptimizer(K)
    core = system.core
    sweep = TrajectorySweep(trajectory.times, trajectory.q, dt=core.config.waypoint_dt)
    at_start = decide_fetch_gaze(core, q0, None, sweep, 0.0)
    at_clock = decide_fetch_gaze(core, q0, None, sweep, 4.0)
    assert at_start.pan != at_clock.pan  # the two windows want different gazes
    context = system.CreateDefaultContext()
    context.SetTime(4.0)
    system.GetInputPort("robot_configuration").FixValue(context, q0)
    system.GetInputPort("trajectory").FixValue(context, PlannedTrajectory(trajectory=trajectory))
    system.GetInputPort("trajectory_time").FixValue(context, [0.0])
    simulator = Simulator(system, context)
    simulator.AdvanceTo(4.05)
    pan, tilt = system.GetOutputPort("head_command").Eval(context)
    assert (pan, tilt) == pytest.approx((at_start.pan, at_start.tilt))
    # NaN progress (no trajectory loaded yet) falls back to the clock.
    system.GetInputPort("trajectory_time").FixValue(context, [np.nan])
    simulator.AdvanceTo(4.15)
    pan, tilt = system.GetOutputPort("head_command").Eval(context)
    assert (pan, tilt) == pytest.approx((at_clock.pan, at_clock.tilt))


def test_gaze_prefers_a_nearly_as_good_gaze_near_the_current_head_command():
    core = GazeCore(K)
    q0 = layout.stow_configuration(0.0, 0.0, 0.0)
    # Cells on both sides of the robot, a few more on the right.
    look = np.array([[x, y, 0.25] for x in (0.3, 0.4) for y in (0.5, 0.55, -0.5, -0.55)] + [[0.35, -0.6, 0.25]])
    free = decide_fetch_gaze(core, q0, None, None, 0.0, look_points=look)
    left = decide_fetch_gaze(core, q0, None, None, 0.0, look_points=look, head_now=np.array([1.2, 1.0]))
    assert free.pan < 0.0 < left.pan
    assert left.score >= core.config.look_score_fraction * free.score


@pytest.mark.slow
def test_robot_looks_at_the_low_cabinet_beside_its_start_before_it_drives(tmp_path):
    """Procedural room 33: a 0.66 m cabinet's corner 0.37 m from the robot's
    start, below the level head's view, on the way to the target. The robot
    drove into it at 1.35 s before it looked at its path first."""
    scenario = generate_scenario(seed=33)
    scenario.time_limit = 6.0
    result = run_episode(scenario, DiagramConfig(), out_dir=tmp_path, record=False, progress=False)
    assert result.status != COLLISION, (result.status, result.detail)
    assert result.path_length > 0.2  # it left after looking
    assert "holding until" in (tmp_path / "episode.log").read_text()


def test_planner_map_gets_points_in_the_hidden_cells_columns():
    points = np.array([[1.0, 1.0, 0.7], [1.2, 1.0, 0.7]])
    snapshot = PointMapSnapshot(points, np.array([1, 2], np.int64), 0.03, revision=5)
    grid = _grid()
    assert with_hidden_cells(snapshot, grid) is snapshot  # nothing hidden: the map itself
    hidden = np.zeros(grid.shape, bool)
    cell = grid.cell_of(np.array([[1.0, 1.0]]))[0]
    hidden[cell[0], cell[1]] = True
    merged = with_hidden_cells(snapshot, dc.replace(grid, hidden=hidden, hidden_revision=2))
    assert merged.num_points == 2 + 3 and merged.revision == 7
    np.testing.assert_allclose(merged.points[2:, 2], [0.1, 0.25, 0.4])
    np.testing.assert_allclose(merged.points[2:, :2], np.repeat(grid.centers(cell[None]), 3, axis=0))
    assert merged.voxel_keys.shape == (5,)


def test_footprint_radius_kernel_gives_the_array_expressions_verdicts():
    """The compiled within-radius test equals NumPy's (C, K, 2) expression, cell for cell."""
    rng = np.random.default_rng(3)
    for _ in range(50):
        xy = rng.uniform(-1, 1, (int(rng.integers(1, 800)), 2))
        section = rng.uniform(-1, 1, (int(rng.integers(1, 200)), 2))
        r = float(rng.uniform(0.05, 0.5))
        expected = ((xy[:, None, :] - section[None, :, :]) ** 2).sum(axis=2).min(axis=1) <= r * r
        assert np.array_equal(_within_radius_of_path(xy, section, r * r), expected)


def test_seen_grid_is_immutable_and_shared_by_context_copies():
    grid = _grid()
    assert copy.deepcopy(grid) is grid
    with pytest.raises(ValueError):
        grid.first_seen[0, 0] = 0.0
