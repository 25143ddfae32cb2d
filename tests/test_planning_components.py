"""Hybrid A*, RRT-Connect and smoothing on plain arrays."""

import numpy as np
import pytest

from vamg_drake.planning.hybrid_astar import Costmap2D, HybridAStar, HybridAStarConfig
from vamg_drake.planning.rrt_connect import rrt_connect
from vamg_drake.planning.smoothing import bspline_smooth, shortcut, time_parametrize
from vamg_drake.robot import layout


def _wall_costmap(h=0.05):
    """A 6 x 4 m map with a wall at x = 3 from y = -2 to y = 1 (gap above)."""
    from scipy import ndimage

    xs = -1.0 + h * np.arange(int(6.0 / h))
    ys = -2.0 + h * np.arange(int(4.0 / h))
    occ = (np.abs(xs[:, None] - 2.0) < 0.1) & (ys[None, :] < 1.0)
    dist = ndimage.distance_transform_edt(~occ, sampling=h).astype(np.float32)
    return Costmap2D(dist, np.array([xs[0], ys[0]]), h, np.sqrt(2) * h)


def test_hybrid_astar_goes_around_the_wall():
    cm = _wall_costmap()
    planner = HybridAStar(cm, 0.3, HybridAStarConfig(turning_radius=0.4))
    start, goal = np.array([0.5, -1.0, 0.0]), np.array([3.5, -1.0, 0.0])
    path, why = planner.plan(start, goal)
    assert path is not None, why
    poses = path.poses
    np.testing.assert_allclose(poses[0], start)
    np.testing.assert_allclose(poses[-1, :2], goal[:2], atol=1e-6)
    assert planner.poses_free(poses)
    assert poses[:, 1].max() > 1.0 + 0.3  # passes through the gap
    assert np.max(np.hypot(*np.diff(poses[:, :2], axis=0).T)) <= planner.config.check_step + 1e-9


def test_hybrid_astar_reports_an_enclosed_goal():
    cm = _wall_costmap()
    planner = HybridAStar(cm, 1.2, HybridAStarConfig())  # too wide for the gap
    path, why = planner.plan(np.array([0.5, -1.0, 0.0]), np.array([3.5, -1.0, 0.0]))
    assert path is None and "no base path" in why


def test_rrt_connect_is_generic_and_deterministic():
    def motion_free(a, b):
        s = np.linspace(0.0, 1.0, 50)[:, None]
        p = a + s * (b - a)
        return not np.any((np.abs(p[:, 0]) < 0.1) & (p[:, 1] < 0.7))  # a wall with a gap at the top

    lo, hi = np.array([-1.0, -1.0]), np.array([1.0, 1.0])
    a, b = np.array([-0.8, -0.8]), np.array([0.8, -0.8])
    p1, _ = rrt_connect(a, b, motion_free, lo, hi, np.random.default_rng(3))
    p2, _ = rrt_connect(a, b, motion_free, lo, hi, np.random.default_rng(3))
    assert p1 is not None
    np.testing.assert_array_equal(p1, p2)
    np.testing.assert_allclose(p1[0], a)
    np.testing.assert_allclose(p1[-1], b)
    assert all(motion_free(p1[i], p1[i + 1]) for i in range(len(p1) - 1))
    short = shortcut(p1, motion_free, np.random.default_rng(0), 50)
    assert all(motion_free(short[i], short[i + 1]) for i in range(len(short) - 1))
    length = lambda p: np.sum(np.linalg.norm(np.diff(p, axis=0), axis=1))  # noqa: E731
    assert length(short) <= length(p1) + 1e-9


def test_bspline_keeps_ends_and_time_parametrization_respects_limits():
    path = np.array([layout.stow_configuration(x, 0.2 * x * x, 0.3 * x) for x in np.linspace(0, 2, 6)])
    smooth = bspline_smooth(path, 40)
    np.testing.assert_allclose(smooth[[0, -1]], path[[0, -1]])
    traj = time_parametrize(smooth)
    assert traj.max_rate_ratio() == pytest.approx(1.0)
    assert traj.duration > 0


def test_configs_load_from_yaml():
    from pydrake.common.yaml import yaml_load_typed

    from vamg_drake.systems.planner_system import PlannerSystemConfig

    config = yaml_load_typed(schema=PlannerSystemConfig,
                             data="period: 0.2\nplanner: {seed: 4, attempt_budget_iterations: 800, fold_fractions: [0.5]}")
    assert config.period == 0.2
    assert config.planner.seed == 4 and config.planner.fold_fractions == [0.5]
    assert config.planner.attempt_budget_iterations == 800
    assert config.planner.max_attempts == 3


def _synchronized_path_reference(poses, W):
    """The NumPy formulation of `WholeBodyPlanner._synchronized_path`."""
    seg = np.abs(np.diff(W, axis=0)).sum(axis=1)
    sa = np.concatenate([[0.0], np.cumsum(seg)])
    sa = sa / sa[-1] if sa[-1] > 0 else np.linspace(0.0, 1.0, W.shape[0])
    d = np.diff(poses, axis=0)
    t = np.maximum(np.hypot(d[:, 0], d[:, 1]) / layout.TRACKER_BASE_V, np.abs(d[:, 2]) / layout.TRACKER_BASE_W)
    sb = np.concatenate([[0.0], np.cumsum(t)])
    sb = sb / sb[-1] if sb[-1] > 0 else np.linspace(0.0, 1.0, poses.shape[0])
    s = np.union1d(sa, sb)
    base = np.column_stack([np.interp(s, sb, poses[:, i]) for i in range(3)])
    arm = np.column_stack([np.interp(s, sa, W[:, i]) for i in range(W.shape[1])])
    return np.concatenate([base, arm], axis=1)


def test_compiled_synchronization_and_held_arm_densification_match_numpy():
    from vamg_drake.planning.collision_environment import CollisionEnvironment
    from vamg_drake.planning.sphere_collision import SphereCollisionChecker, densify
    from vamg_drake.planning.whole_body_planner import WholeBodyPlanner, _densify_poses

    rng = np.random.default_rng(7)
    checker = SphereCollisionChecker.for_fetch(CollisionEnvironment())
    for m, k in [(2, 2), (5, 2), (40, 4), (17, 9), (3, 3)]:
        poses = np.cumsum(rng.normal(0.0, 0.2, (m, 3)), axis=0)
        poses[1] = poses[0] if m > 2 else poses[1]  # a repeated pose (zero-length step)
        W = rng.uniform(layout.SAMPLE_LOWER[3:], layout.SAMPLE_UPPER[3:], (k, 8))
        got = WholeBodyPlanner._synchronized_path(poses, W)
        want = _synchronized_path_reference(poses, W)
        np.testing.assert_allclose(got, want, rtol=0.0, atol=1e-12)
        np.testing.assert_array_equal(got[0], np.r_[poses[0], W[0]])  # the ends exactly
        np.testing.assert_array_equal(got[-1], np.r_[poses[-1], W[-1]])
        arm = W[0]
        Q = np.concatenate([poses, np.repeat(arm[None], m, axis=0)], axis=1)
        dense, index = _densify_poses(poses, float(checker.lever[2]), checker.config.motion_resolution)
        want = densify(Q, checker)
        np.testing.assert_array_equal(dense, want[:, :3])  # the very states `densify` gives
        np.testing.assert_allclose(dense[index], poses, rtol=0.0, atol=1e-12)


def test_one_pass_coarse_free_grid_matches_the_two_pass_one():
    from vamg_drake.planning import hybrid_astar as ha
    from vamg_drake.planning.whole_body_planner import WholeBodyPlanner
    from vamg_drake.planning.collision_environment import CollisionEnvironment
    from vamg_drake.planning.sphere_collision import SphereCollisionChecker
    from vamg_drake.testing.planning_problems import room_problem

    base = SphereCollisionChecker.for_fetch(CollisionEnvironment())
    problem = room_problem(5, base)
    planner = WholeBodyPlanner.for_fetch(CollisionEnvironment.from_primitives(problem.obstacles))
    search = planner._base_planner(problem.q_start[:3], problem.q_goal[:3])
    free = search._free_mask()
    assert 0.1 < free.mean() < 0.9
    for factor in (1, 3, 4, 7):
        np.testing.assert_array_equal(
            ha._coarse_footprint_free(search._layers, search.costmap.margin, search._disc_thresholds(),
                                      search._band, factor),
            ha._coarse_free(free, factor))


def test_grid_dijkstra_matches_scipy():
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import dijkstra

    from vamg_drake.planning.hybrid_astar import grid_distances

    rng = np.random.default_rng(8)
    for _ in range(5):
        nx, ny = rng.integers(5, 40, 2)
        free = rng.random((nx, ny)) > 0.3
        gi, gj = int(rng.integers(0, nx)), int(rng.integers(0, ny))
        free[gi, gj] = True
        rows, cols, w = [], [], []
        for i in range(nx):
            for j in range(ny):
                for di in (-1, 0, 1):
                    for dj in (-1, 0, 1):
                        a, b = i + di, j + dj
                        if (di or dj) and 0 <= a < nx and 0 <= b < ny and free[i, j] and free[a, b]:
                            rows.append(i * ny + j)
                            cols.append(a * ny + b)
                            w.append(0.1 * np.hypot(di, dj))
        graph = coo_matrix((w, (rows, cols)), shape=(nx * ny, nx * ny)).tocsr()
        want = dijkstra(graph, indices=gi * ny + gj).reshape(nx, ny)
        got = grid_distances(free, gi, gj, 0.1)
        np.testing.assert_array_equal(np.isinf(got), np.isinf(want))
        np.testing.assert_allclose(got[np.isfinite(got)], want[np.isfinite(want)], rtol=0.0, atol=1e-9)
