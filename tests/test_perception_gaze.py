"""Tests for the velocity-aware gaze optimizer (with the Fetch's kinematics and spheres)."""

import numpy as np
import pytest

from vamg_drake.perception.gaze import (
    GazeConfig,
    GazeOptimizer,
    ImportanceField,
    decide_fetch_gaze,
    frustum_scores_reference,
)
from vamg_drake.perception.trajectory_sweep import TrajectorySweep
from vamg_drake.robot import layout
from vamg_drake.robot.head_camera import CameraIntrinsics, HeadCameraConfig
from vamg_drake.robot.kinematics import FetchKinematics

K = CameraIntrinsics.from_config(HeadCameraConfig())
Q0 = layout.stow_configuration(0.0, 0.0, 0.0)


def test_candidate_grid_spans_the_head_limits():
    g = GazeOptimizer(K)
    assert g.num_candidates == 40
    assert g.candidates[:, 0].min() == pytest.approx(layout.HEAD_PAN_LIMITS[0])
    assert g.candidates[:, 0].max() == pytest.approx(layout.HEAD_PAN_LIMITS[1])
    assert g.candidates[:, 1].min() == pytest.approx(layout.HEAD_TILT_LIMITS[0])
    assert g.candidates[:, 1].max() == pytest.approx(layout.HEAD_TILT_LIMITS[1])
    with pytest.raises(ValueError, match="variant"):
        GazeConfig(variant="clairvoyant")


def test_weights_follow_the_papers_formula():
    g = GazeOptimizer(K)
    n, s = 20, 3
    body = np.random.default_rng(0).normal(size=(n, s, 3))
    speed = np.linspace(0.1, 2.0, n)
    field = g.trajectory_importance(body, speed)
    i = np.arange(n)
    sigma = max(1.0, 0.25 * n)
    expected = 0.999**i * np.exp(-0.5 * ((i - 0.25 * n) / sigma) ** 2) * speed
    np.testing.assert_allclose(field.weights.reshape(n, s), np.repeat(expected[:, None], s, 1))
    agnostic = GazeOptimizer(K, GazeConfig(variant="velocity_agnostic")).trajectory_importance(body, speed)
    np.testing.assert_allclose(agnostic.weights.reshape(n, s)[:, 0], expected / speed)


def test_points_inside_the_robot_now_weigh_nothing():
    g = GazeOptimizer(K, GazeConfig(skip_occupied=True))
    n = 10
    body = np.zeros((n, 2, 3))
    body[:, 1, 0] = np.linspace(0.0, 2.0, n)  # sphere 1 moves away along x; sphere 0 stays
    speed = np.ones(n)
    radii = np.array([0.5, 0.1])
    plain = g.trajectory_importance(body, speed).weights.reshape(n, 2)
    skipped = g.trajectory_importance(body, speed, radii).weights.reshape(n, 2)
    inside = body[:, 1, 0] <= 0.5  # within sphere 0 of waypoint 0
    assert np.all(skipped[:, 0] == 0.0)  # the sphere that does not move
    np.testing.assert_array_equal(skipped[inside, 1], 0.0)
    np.testing.assert_allclose(skipped[~inside, 1], plain[~inside, 1])
    off = GazeOptimizer(K, GazeConfig(skip_occupied=False)).trajectory_importance(body, speed, radii)
    np.testing.assert_allclose(off.weights.reshape(n, 2), plain)
    with pytest.raises(ValueError, match="radii"):
        g.trajectory_importance(body, speed, np.ones(3))


def test_an_arm_swing_during_a_turn_in_place_draws_the_gaze_to_the_arm():
    # The base turns in place while the torso rises and the arm swings out on the left:
    # the base sweeps its own footprint, so the new space is where the arm goes.
    q1 = layout.stow_configuration(0.0, 0.0, -0.6)
    q1[layout.TORSO] = 0.3
    q1[layout.TORSO_ARM][1:] = [1.3, -0.5, 0.0, 1.0, 0.0, 0.5, 0.0]
    sweep = TrajectorySweep(np.array([0.0, 2.0]), np.array([Q0, q1]))
    target = np.array([1.0, -1.0, 0.7])
    with_skip = decide_fetch_gaze(GazeOptimizer(K, GazeConfig(skip_occupied=True)), Q0, target, sweep, 0.0)
    without = decide_fetch_gaze(GazeOptimizer(K), Q0, target, sweep, 0.0)
    assert without.tilt > 1.3  # down at the base's own footprint
    assert with_skip.sees_importance
    assert with_skip.pan > 0.3 and with_skip.tilt < 1.0  # out to the left, where the arm swings


def test_frustum_scores_match_the_numpy_reference():
    g = GazeOptimizer(K)
    X_WC = FetchKinematics.instance().camera_poses_for_gazes(Q0, g.candidates)
    rng = np.random.default_rng(3)
    field = ImportanceField(rng.uniform([-3, -3, 0], [3, 3, 2], (2000, 3)), rng.random(2000))
    ref = frustum_scores_reference(field.points, field.weights, X_WC, K, 0.2, 3.0)
    np.testing.assert_allclose(g.scores(field, X_WC), ref)
    assert np.count_nonzero(ref) > 10


def test_candidate_cameras_match_full_kinematics():
    from vamg_drake.perception.gaze import FetchGazeCameras

    g = GazeOptimizer(K)
    cams = FetchGazeCameras(g.candidates)
    q = np.array([1.0, 2.0, -2.5, 0.1, 0.2, 0.3, 0.4, 0.5, 0.6, 0.7, 0.8])
    np.testing.assert_allclose(cams.poses(q), FetchKinematics.instance().camera_poses_for_gazes(q, g.candidates), atol=1e-9)


def test_window_weights_match_direct_resampling():
    times = np.array([0.0, 1.0, 3.0])
    q = np.array([Q0, layout.stow_configuration(1.0, 0, 0), layout.stow_configuration(1.5, 0.5, 0.3)])
    g = GazeOptimizer(K)
    q_win, speed = g.lookahead_window(times, q, 0.4)
    _, sweep_speed = TrajectorySweep(times, q).window(0.4, g.config.lookahead_waypoints, 2)
    np.testing.assert_allclose(sweep_speed, speed)
    assert speed[0] == pytest.approx(1.0) and speed[-1] == 0.0


def test_fast_base_motion_to_the_left_draws_the_gaze_left():
    # Turn in place to face left, then drive 3 m to the left.
    times = np.array([0.0, 1.6, 4.6])
    q = np.array([Q0, layout.stow_configuration(0, 0, np.pi / 2), layout.stow_configuration(0, 3.0, np.pi / 2)])
    target_on_the_right = np.array([2.0, -1.5, 0.7])
    for variant in ("velocity_aware", "velocity_agnostic"):
        d = decide_fetch_gaze(GazeOptimizer(K, GazeConfig(variant=variant)), Q0, target_on_the_right, TrajectorySweep(times, q), 0.0)
        assert d.sees_importance
        assert d.pan > 0.3, variant  # left of the robot's heading
    # target_only ignores the trajectory and looks at the target.
    d = decide_fetch_gaze(GazeOptimizer(K, GazeConfig(variant="target_only")), Q0, target_on_the_right, TrajectorySweep(times, q), 0.0)
    assert d.pan < 0.0


def test_velocity_agnostic_can_choose_differently():
    # A slow 0.25 m creep to the right (2.5 s), then a fast 3.75 m dash to the left (2.5 s).
    times = np.array([0.0, 2.5, 5.0])
    q = np.array([Q0, layout.stow_configuration(0, -0.25, 0), layout.stow_configuration(0, 3.5, 0)])
    sweep = TrajectorySweep(times, q)
    aware = decide_fetch_gaze(GazeOptimizer(K), Q0, None, sweep, 0.0)
    agnostic = decide_fetch_gaze(GazeOptimizer(K, GazeConfig(variant="velocity_agnostic")), Q0, None, sweep, 0.0)
    assert aware.pan > 0.3  # where the robot will move fast
    assert agnostic.pan < 0.0  # where it spends most time
    # Progress matters: once the creep is over, the agnostic variant looks left too.
    late = decide_fetch_gaze(GazeOptimizer(K, GazeConfig(variant="velocity_agnostic")), q[1], None, sweep, 2.5)
    assert late.pan > 0.3


def test_without_a_trajectory_the_gaze_centres_the_target():
    g = GazeOptimizer(K)
    kin = FetchKinematics.instance()
    X_WC = kin.camera_poses_for_gazes(Q0, g.candidates)
    for target in ([1.5, 0.5, 0.7], [1.0, -1.2, 0.4], [0.8, 0.1, 0.2], [2.0, 1.5, 1.2]):
        target = np.asarray(target)
        d = decide_fetch_gaze(g, Q0, target)
        to_target = target - X_WC[:, :3, 3]
        angle = np.arccos(np.einsum("kj,kj->k", X_WC[:, :3, 2], to_target) / np.linalg.norm(to_target, axis=1))
        assert d.sees_importance
        assert d.index == int(np.argmin(angle)), target
    # A trajectory that has ended (the window is at rest) also falls back to the target.
    times, q = np.array([0.0, 1.0]), np.array([Q0, layout.stow_configuration(0.5, 0, 0)])
    d_end = decide_fetch_gaze(g, q[1], np.array([1.5, 0.5, 0.7]), TrajectorySweep(times, q), 5.0)
    assert d_end.index == decide_fetch_gaze(g, q[1], np.array([1.5, 0.5, 0.7])).index


def test_bad_gaze_inputs_raise_clear_errors():
    g = GazeOptimizer(K)
    with pytest.raises(ValueError, match="target"):
        g.target_importance(np.array([np.nan, 0, 0]))
    with pytest.raises(ValueError, match="X_WC"):
        g.choose(g.target_importance(np.ones(3)), np.full((40, 4, 4), np.nan))
    with pytest.raises(ValueError, match="q_now"):
        decide_fetch_gaze(g, np.full(11, np.nan), np.ones(3))
    # Nothing to look at: a neutral gaze, flagged.
    d = decide_fetch_gaze(g, Q0, None)
    assert not d.sees_importance and d.score == 0.0


def test_configs_load_from_yaml_and_are_validated():
    from pydrake.common.yaml import yaml_load_typed

    from vamg_drake.perception.raycast_map import PointMap, RayCastMapConfig

    config = yaml_load_typed(schema=RayCastMapConfig, data="{ground_height: 0.3, depth: {crop_radius: 2.0}}")
    assert config.ground_height == 0.3 and config.depth.crop_radius == 2.0
    gaze = yaml_load_typed(schema=GazeConfig, data="{variant: velocity_agnostic, num_pan: 4}")
    assert GazeOptimizer(K, gaze).num_candidates == 20
    with pytest.raises(ValueError, match="variant"):
        GazeOptimizer(K, yaml_load_typed(schema=GazeConfig, data="{variant: foo}"))
    with pytest.raises(ValueError, match="crop_radius"):
        PointMap(K, yaml_load_typed(schema=RayCastMapConfig, data="{depth: {crop_radius: -1.0}}"))
