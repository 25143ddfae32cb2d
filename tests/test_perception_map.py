"""Tests for depth back-projection, the ray-cast map and the trajectory check."""

import logging

import numpy as np
import pytest
from pydrake.geometry import Box, Cylinder
from pydrake.math import RigidTransform

from vamg_drake.perception.depth_points import DepthBackProjector, DepthToPointsConfig, depth_to_points_reference
from vamg_drake.perception.raycast_map import PointMap, RayCastMapConfig
from vamg_drake.perception.shape_depth_render import ShapeDepthRenderer, look_at
from vamg_drake.perception.trajectory_check import first_colliding_waypoint, first_colliding_waypoint_reference
from vamg_drake.robot import layout
from vamg_drake.robot.head_camera import CameraIntrinsics, HeadCameraConfig

K = CameraIntrinsics.from_config(HeadCameraConfig())
FLOOR = (Box(12.0, 12.0, 0.1), RigidTransform([0.0, 0.0, -0.05]))
WALL = (Box(0.1, 12.0, 2.5), RigidTransform([4.0, 0.0, 1.25]))


def _box(center, size):
    return (Box(*size), RigidTransform(np.asarray(center, dtype=float)))


def _count_in_box(points, center, size, pad=0.03):
    half = np.asarray(size) / 2 + pad
    return int(np.all(np.abs(points - np.asarray(center)) <= half, axis=1).sum())


def test_back_projection_matches_reference_and_drops_invalid_pixels():
    rng = np.random.default_rng(0)
    depth = rng.uniform(0.0, 4.0, (K.height, K.width)).astype(np.float32)
    depth[rng.random(depth.shape) < 0.1] = np.nan
    depth[rng.random(depth.shape) < 0.1] = np.inf
    depth[rng.random(depth.shape) < 0.1] = 0.0
    X_WC = look_at([0.3, -0.2, 1.1], [2.0, 0.5, 0.3])
    config = DepthToPointsConfig()
    p = DepthBackProjector(K, config).points_W(depth, X_WC)
    p_ref = depth_to_points_reference(depth, K, X_WC, config)
    np.testing.assert_allclose(p, p_ref, atol=1e-9)
    assert np.all(np.isfinite(p))
    r = np.linalg.norm(p - X_WC[:3, 3], axis=1)
    assert r.max() <= config.crop_radius + 1e-9
    z_C = (p - X_WC[:3, 3]) @ X_WC[:3, 2]
    assert z_C.min() >= config.depth_min - 1e-9
    # Roughly: uniform depths in [0, 4] -> in range [0.2, 2.5 (crop)] about half of the finite pixels.
    assert 0.3 * depth.size < p.shape[0] < 0.7 * depth.size


def test_obstacle_that_leaves_is_carved_once_its_space_is_seen_empty():
    obstacle = ((1.6, 0.0, 0.4), (0.3, 0.3, 0.8))
    X_WC = look_at([0.0, 0.0, 1.1], [2.0, 0.0, 0.5])
    m = PointMap(K)
    m.update(ShapeDepthRenderer(K, [FLOOR, WALL, _box(*obstacle)]).render(X_WC), X_WC)
    assert _count_in_box(m.points, *obstacle) > 50
    # The obstacle moved away: the same view now sees the floor behind it.
    stats = m.update(ShapeDepthRenderer(K, [FLOOR, WALL]).render(X_WC), X_WC)
    assert stats.ok and stats.num_carved > 50
    assert _count_in_box(m.points, *obstacle) == 0


def test_obstacle_hidden_behind_another_stays():
    hidden = ((2.4, 0.0, 0.3), (0.2, 0.2, 0.6))
    blocker = ((1.3, 0.0, 0.6), (0.1, 1.2, 1.2))
    X_WC = look_at([0.0, 0.0, 1.1], [2.4, 0.0, 0.3])
    m = PointMap(K)
    m.update(ShapeDepthRenderer(K, [FLOOR, WALL, _box(*hidden)]).render(X_WC), X_WC)
    n_hidden = _count_in_box(m.points, *hidden)
    assert n_hidden > 20
    # A blocker appears in front, and the hidden box leaves: nothing can tell, so it stays.
    depth = ShapeDepthRenderer(K, [FLOOR, WALL, _box(*blocker)]).render(X_WC)
    m.update(depth, X_WC)
    assert _count_in_box(m.points, *hidden) == n_hidden
    assert _count_in_box(m.points, *blocker) > 50


def _fetch_shapes(q):
    """The Fetch's collision primitives at q, as Drake shapes in W."""
    from vamg_drake.robot.kinematics import FetchKinematics
    from vamg_drake.robot.spheres import collision_primitives

    kin = FetchKinematics.instance()
    X_WL = kin.link_poses(q)[0]
    shapes, solids = [], []
    for prim in collision_primitives():
        X_WS = X_WL[kin.link_index(prim["link"])] @ prim["X_LS"]
        if prim["kind"] == "box":
            shapes.append((Box(*(2 * prim["half"])), RigidTransform(X_WS)))
            solids.append(("box", X_WS, prim["half"]))
        else:
            shapes.append((Cylinder(prim["radius"], prim["length"]), RigidTransform(X_WS)))
            solids.append(("cylinder", X_WS, (prim["radius"], prim["length"] / 2)))
    return shapes, solids


def _near_solid(points, solid, pad):
    kind, X_WS, size = solid
    p_S = (points - X_WS[:3, 3]) @ X_WS[:3, :3]
    if kind == "box":
        return np.all(np.abs(p_S) <= np.asarray(size) + pad, axis=1)
    r, half_len = size
    return (np.hypot(p_S[:, 0], p_S[:, 1]) <= r + pad) & (np.abs(p_S[:, 2]) <= half_len + pad)


def test_floor_and_the_robots_own_arm_never_enter_the_map():
    from vamg_drake.robot.kinematics import FetchKinematics
    from vamg_drake.robot.spheres import SphereModel

    # Arm stretched forward and down, in front of the head camera looking down at it.
    q = np.concatenate([[0.0, 0.0, 0.0, 0.3], [0.0, 0.6, 0.0, 0.9, 0.0, 0.6, 0.0]])
    pan, tilt = 0.0, 0.7
    robot_shapes, solids = _fetch_shapes(q)
    table = ((1.3, 0.0, 0.35), (0.6, 1.0, 0.7))
    renderer = ShapeDepthRenderer(K, [FLOOR, _box(*table), *robot_shapes])
    X_WC = FetchKinematics.instance().camera_pose(q, pan, tilt)
    depth = renderer.render(X_WC)
    spheres = SphereModel.load()
    centers = spheres.world_spheres(q, head=np.array([[pan, tilt]]))
    m = PointMap(K)
    stats = m.update(depth, X_WC, centers, spheres.radius)
    assert stats.num_self > 500, "the arm should fill part of the image"
    assert stats.num_ground > 500, "the floor should be in view"
    pts = m.points
    assert _count_in_box(pts, *table) > 100
    assert pts[:, 2].min() >= m.config.ground_height
    near_robot = np.zeros(len(pts), dtype=bool)
    for solid in solids:
        near_robot |= _near_solid(pts, solid, pad=0.02)
    assert near_robot.sum() == 0
    # Without the self-filter the arm would be in the map: the test can fail.
    unfiltered = PointMap(K)
    unfiltered.update(depth, X_WC)
    assert sum(_near_solid(unfiltered.points, s, 0.02).sum() for s in solids) > 30


def test_map_stays_bounded_over_100_observations():
    shapes = [FLOOR, WALL, _box((1.5, 0.5, 0.4), (0.4, 0.4, 0.8)), _box((2.0, -0.6, 0.6), (0.5, 0.3, 1.2))]
    renderer = ShapeDepthRenderer(K, shapes)
    rng = np.random.default_rng(1)
    m = PointMap(K)
    X0 = look_at([0.0, 0.0, 1.1], [2.0, 0.0, 0.5])
    m.update(renderer.render(X0), X0)
    n_first = m.num_points
    counts = []
    for _ in range(100):
        X_WC = look_at(np.array([0.0, 0.0, 1.1]) + rng.normal(0, 0.02, 3), [2.0, 0.0, 0.5] + rng.normal(0, 0.05, 3))
        m.update(renderer.render(X_WC), X_WC)
        counts.append(m.num_points)
    # Each voxel holds at most one point: the map can only fill the surfaces' voxels.
    assert len(np.unique(m.occupied_voxels(), axis=0)) == m.num_points
    assert max(counts) < 1.5 * n_first
    assert max(counts[50:]) <= 1.1 * max(counts[:50])
    # Repeating exactly the same observation changes nothing.
    depth = renderer.render(X0)
    m.update(depth, X0)
    n = m.num_points
    stats = m.update(depth, X0)
    assert stats.num_added == 0 and stats.num_carved == 0 and m.num_points == n


def test_bad_inputs_log_and_leave_the_map_unchanged(caplog):
    X_WC = look_at([0.0, 0.0, 1.1], [2.0, 0.0, 0.5])
    m = PointMap(K)
    # Empty map, all-NaN image.
    with caplog.at_level(logging.WARNING):
        stats = m.update(np.full((K.height, K.width), np.nan, dtype=np.float32), X_WC)
    assert m.num_points == 0 and "no valid pixel" in caplog.text
    depth = ShapeDepthRenderer(K, [FLOOR, WALL]).render(X_WC)
    m.update(depth, X_WC)
    before, rev = m.points.copy(), m.revision
    caplog.clear()
    with caplog.at_level(logging.WARNING):
        stats = m.update(np.full((K.height, K.width), np.nan, dtype=np.float32), X_WC)
    assert stats.ok and stats.num_carved == 0 and "no valid pixel" in caplog.text
    bad_pose = X_WC.copy()
    bad_pose[0, 3] = np.nan
    caplog.clear()
    with caplog.at_level(logging.ERROR):
        stats = m.update(depth, bad_pose)
    assert not stats.ok and "camera pose" in caplog.text and "NaN" in stats.message
    stats = m.update(depth[:10], X_WC)
    assert not stats.ok and "shape" in stats.message
    stats = m.update(depth, X_WC, np.full((3, 3), np.nan), np.ones(3))
    assert not stats.ok and "robot spheres" in stats.message
    np.testing.assert_array_equal(m.points, before)
    assert m.revision == rev


def test_occupancy_grid_and_voxel_lookup_follow_the_points():
    m = PointMap(K, RayCastMapConfig(voxel_size=0.05))
    pts = np.array([[0.01, 0.01, 0.5], [0.02, 0.02, 0.52], [1.0, -1.0, 0.3], [np.nan, 0, 0]])
    assert m.add_points(pts) == 2  # two share a voxel, one is NaN
    grid = m.occupancy_grid()
    assert grid.occupied.sum() == 2
    idx = np.floor((m.points - grid.origin) / grid.voxel_size + 1e-9).astype(int)
    assert np.all(grid.occupied[idx[:, 0], idx[:, 1], idx[:, 2]])
    assert m.contains_voxel_of(np.array([[0.04, 0.04, 0.54], [0.2, 0.2, 0.2]])).tolist() == [True, False]
    snap = m.snapshot()
    assert snap.num_points == 2 and not snap.points.flags.writeable
    np.testing.assert_array_equal(snap.voxel_indices, m.occupied_voxels())
    assert np.all(snap.points >= snap.voxel_indices * 0.05 - 1e-9)
    assert np.all(snap.points <= (snap.voxel_indices + 1) * 0.05 + 1e-9)
    with pytest.raises(ValueError, match="voxel_size"):
        RayCastMapConfig(voxel_size=0.0)


def test_trajectory_check_finds_the_first_colliding_waypoint():
    rng = np.random.default_rng(2)
    points = rng.uniform([-3, -3, 0], [3, 3, 2], (20000, 3))
    # A path of 40 waypoints, 10 spheres each, through a box of points cleared of everything else.
    path = np.linspace([-2.0, 0.0, 0.5], [2.0, 0.0, 0.5], 40)
    offsets = rng.uniform(-0.2, 0.2, (10, 3))
    centers = path[:, None, :] + offsets[None]
    radii = rng.uniform(0.05, 0.15, 10)
    clear = np.all(np.abs(points - [0, 0, 0.5]) < [2.6, 0.6, 0.6], axis=1)
    points = points[~clear]
    assert first_colliding_waypoint(points, centers, radii) == -1
    assert first_colliding_waypoint_reference(points, centers, radii) == -1
    obstacle = centers[25, 3] + np.array([0.0, 0.0, radii[3] * 0.5])
    with_obstacle = np.vstack([points, obstacle])
    expected = first_colliding_waypoint_reference(with_obstacle, centers, radii)
    assert 20 <= expected <= 25
    assert first_colliding_waypoint(with_obstacle, centers, radii) == expected
    assert first_colliding_waypoint(np.empty((0, 3)), centers, radii) == -1
    for seed in range(5):
        pts = np.random.default_rng(seed).uniform([-3, -1, 0], [3, 1, 1], (300, 3))
        assert first_colliding_waypoint(pts, centers, radii, 0.02) == first_colliding_waypoint_reference(
            pts, centers, radii, 0.02
        )
    with pytest.raises(ValueError, match="sphere"):
        first_colliding_waypoint(points, centers[:, :5], radii)


def test_swept_sphere_index_agrees_with_the_reference():
    from vamg_drake.perception.trajectory_check import SweptSphereIndex

    rng = np.random.default_rng(4)
    path = np.linspace([-2.0, -1.0, 0.3], [2.0, 1.0, 1.0], 60)
    centers = path[:, None, :] + rng.uniform(-0.3, 0.3, (12, 3))[None]
    radii = rng.uniform(0.03, 0.3, 12)
    index = SweptSphereIndex(centers, radii, margin=0.01)
    for seed in range(20):
        pts = np.random.default_rng(seed).uniform([-3, -2, 0], [3, 2, 1.5], (int(10 + 30 * seed), 3))
        expected = first_colliding_waypoint_reference(pts, centers, radii, 0.01)
        assert index.first_collision(pts) == expected
        start = 30
        expected_late = first_colliding_waypoint_reference(pts, centers[start:], radii, 0.01)
        assert index.first_collision(pts, start) == (-1 if expected_late < 0 else expected_late + start)
    assert index.first_collision(np.empty((0, 3))) == -1
