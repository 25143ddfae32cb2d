"""Starts and goals inside the collision padding (closed loop: tracking error,
map points appearing near the robot) are planned from; penetrating ones fail."""

import math

import numpy as np
import pytest

from vamg_drake.planning.collision_environment import CollisionEnvironment
from vamg_drake.planning.sphere_collision import densify
from vamg_drake.planning.whole_body_planner import FailureReason, PlannerConfig, WholeBodyPlanner
from vamg_drake.robot import layout
from vamg_drake.world.primitives import WorldBox

CONFIG = PlannerConfig(attempt_wall_limit_s=5.0)
Q_START = layout.stow_configuration(0.0, 0.0, 0.0)
Q_GOAL = layout.stow_configuration(-2.5, 0.5, 0.0)


def _front_of_robot(planner: WholeBodyPlanner, q: np.ndarray) -> float:
    """The largest x reached by the robot's spheres (the sphere model's own
    radii, no padding or margin) at q (facing +x)."""
    checker = planner.checker
    c = checker.sphere_centers(q[None])[0]
    keep = checker.check_env
    return float(np.max(c[keep, 0] + checker.base_radius[keep]))


def _wall_at(x_face: float) -> WorldBox:
    """A 1 m high wall whose face toward the robot is the plane x = x_face."""
    return WorldBox("wall/front", np.array([x_face + 0.05, 0.0, 0.5]), np.eye(3), np.array([0.05, 1.5, 0.5]))


@pytest.fixture(scope="module")
def planner():
    return WholeBodyPlanner.for_fetch(CollisionEnvironment(), CONFIG)


def test_start_one_centimetre_from_a_wall_plans_and_is_free_in_drake(planner):
    from vamg_drake.testing.drake_reference import DrakeCollisionWorld

    wall = _wall_at(_front_of_robot(planner, Q_START) + 0.01)
    planner.set_environment(CollisionEnvironment.from_primitives([wall]))
    assert planner.checker.padding > 0.01
    assert not planner.checker.is_free(Q_START[None])[0]  # inside the padding
    result = planner.plan(Q_START, Q_GOAL)
    assert result.success, result.message
    traj = result.trajectory
    np.testing.assert_array_equal(traj.q[0], Q_START)
    np.testing.assert_allclose(layout.wrap_configuration(traj.q[-1]), Q_GOAL, atol=1e-9)
    assert planner.trajectory_is_valid(traj)
    assert planner.trajectory_is_valid(traj, from_time=0.5 * traj.duration)
    drake = DrakeCollisionWorld([wall])
    dense = densify(traj.q, planner.checker, resolution=0.01)
    assert [i for i, q in enumerate(dense) if drake.in_collision(q)] == []
    # The path leaves the padding once and never re-enters it.
    free = planner.checker.is_free(densify(traj.q, planner.checker))
    first = int(np.argmax(free))
    assert first > 0 and free[first:].all()


def test_penetrating_start_and_goal_are_in_collision(planner):
    wall = _wall_at(_front_of_robot(planner, Q_START) - 0.01)
    planner.set_environment(CollisionEnvironment.from_primitives([wall]))
    r = planner.plan(Q_START, Q_GOAL)
    assert not r.success and r.reason == FailureReason.START_IN_COLLISION and r.trajectory is None
    r = planner.plan(Q_GOAL, Q_START)
    assert not r.success and r.reason == FailureReason.GOAL_IN_COLLISION and r.trajectory is None


def test_goal_one_centimetre_from_a_wall_is_reached_exactly(planner):
    wall = _wall_at(_front_of_robot(planner, Q_START) + 0.01)
    planner.set_environment(CollisionEnvironment.from_primitives([wall]))
    result = planner.plan(Q_GOAL, Q_START)
    assert result.success, result.message
    traj = result.trajectory
    np.testing.assert_array_equal(traj.q[0], Q_GOAL)
    np.testing.assert_allclose(layout.wrap_configuration(traj.q[-1]), Q_START, atol=1e-9)
    assert planner.trajectory_is_valid(traj)
    free = planner.checker.is_free(densify(traj.q, planner.checker))
    last = free.shape[0] - 1 - int(np.argmax(free[::-1]))
    assert last < free.shape[0] - 1 and free[:last + 1].all()


def test_start_inside_the_padding_of_map_points_plans(planner):
    """A point-cloud wall: the start is placed where the unpadded spheres are
    free but the padded ones are not (found by bisection along x)."""
    ys, zs = np.meshgrid(np.arange(-1.5, 1.5, 0.01), np.arange(0.0, 1.0, 0.01))
    wall = np.column_stack([np.full(ys.size, 1.0), ys.ravel(), zs.ravel()])
    planner.set_environment(CollisionEnvironment.from_points(wall, resolution=0.03))
    bare = planner.checker.unpadded()

    def last_free_x(is_free) -> float:
        lo, hi = -1.0, 1.0  # free at lo, in collision at hi
        for _ in range(40):
            mid = 0.5 * (lo + hi)
            lo, hi = (mid, hi) if is_free(layout.stow_configuration(mid, 0.0, 0.0)[None])[0] else (lo, mid)
        return lo

    x_padded, x_bare = last_free_x(planner.checker.is_free), last_free_x(bare.is_free)
    assert x_bare > x_padded + 0.005
    q_start = layout.stow_configuration(0.5 * (x_padded + x_bare), 0.0, 0.0)
    assert bare.is_free(q_start[None])[0] and not planner.checker.is_free(q_start[None])[0]
    result = planner.plan(q_start, layout.stow_configuration(-2.0, -0.5, 0.0))
    assert result.success, result.message
    np.testing.assert_array_equal(result.trajectory.q[0], q_start)
    assert planner.trajectory_is_valid(result.trajectory)
    # Further into the wall: the unpadded spheres penetrate.
    r = planner.plan(layout.stow_configuration(x_bare + 0.01, 0.0, 0.0), layout.stow_configuration(-2.0, -0.5, 0.0))
    assert r.reason == FailureReason.START_IN_COLLISION


def test_path_may_enter_the_padding_only_at_its_ends(planner):
    wall = _wall_at(_front_of_robot(planner, Q_START) + 0.01)
    planner.set_environment(CollisionEnvironment.from_primitives([wall]))
    away = layout.stow_configuration(-0.5, 0.0, 0.0)
    assert planner.path_is_valid(np.stack([Q_START, away]))
    assert planner.path_is_valid(np.stack([away, Q_START]))
    # Passing through the padding in the middle of a path is not allowed.
    assert not planner.path_is_valid(np.stack([away, Q_START, away]))


def test_start_inside_the_self_collision_padding_plans():
    """Tracking error can bring the arm within the self-collision margin; the
    start is accepted when the unpadded spheres are apart, and the path leaves
    the margin at once."""
    from vamg_drake.planning.sphere_collision import CollisionCheckerConfig, SphereCollisionChecker

    checker = SphereCollisionChecker.for_fetch(CollisionEnvironment(), CollisionCheckerConfig(self_padding=0.015))
    planner = WholeBodyPlanner(checker, CONFIG)
    bare = checker.unpadded()
    rng = np.random.default_rng(4)
    Q = rng.uniform(layout.SAMPLE_LOWER, layout.SAMPLE_UPPER, (5000, layout.NQ))
    Q[:, :3] = 0.0
    marginal = Q[bare.is_free(Q) & ~checker.is_free(Q)]
    assert marginal.shape[0] > 0
    q_start = marginal[0]
    result = planner.plan(q_start, layout.stow_configuration(2.0, 0.0, 0.0))
    assert result.success, result.message
    np.testing.assert_array_equal(result.trajectory.q[0], q_start)
    assert planner.trajectory_is_valid(result.trajectory)
    # Overlapping unpadded spheres: in collision.
    overlapping = Q[~bare.is_free(Q) & layout.within_limits(Q)]
    r = planner.plan(overlapping[0], layout.stow_configuration(2.0, 0.0, 0.0))
    assert r.reason == FailureReason.START_IN_COLLISION


def test_base_extra_padding_inflates_only_the_base_spheres_and_only_while_planning():
    """A base pose 3 cm from a low wall is free without base padding and
    rejected with 4 cm of it; the arm's spheres and the unpadded test
    (whether a configuration penetrates) are unchanged."""
    plain = WholeBodyPlanner.for_fetch(CollisionEnvironment(), PlannerConfig(attempt_wall_limit_s=5.0,
                                                                             base_extra_padding=0.0))
    wide = WholeBodyPlanner.for_fetch(CollisionEnvironment(), PlannerConfig(attempt_wall_limit_s=5.0,
                                                                            base_extra_padding=0.04))
    assert PlannerConfig().base_extra_padding == 0.03  # the default: the base's tracking error
    is_base = wide.checker.is_base
    assert is_base.any() and not is_base.all()
    np.testing.assert_allclose(wide.checker.sph_r - plain.checker.sph_r, 0.04 * is_base)
    np.testing.assert_allclose(wide.checker.unpadded().sph_r, plain.checker.unpadded().sph_r)
    # A low wall (0.3 m, below the stowed arm) 3 cm in front of the base's spheres.
    bare = plain.checker.unpadded()
    c = bare.sphere_centers(Q_START[None])[0]
    x_face = float(np.max(c[is_base, 0] + bare.sph_r[is_base])) + 0.03
    low_wall = WorldBox("wall/low", np.array([x_face + 0.05, 0.0, 0.15]), np.eye(3), np.array([0.05, 1.5, 0.15]))
    env = CollisionEnvironment.from_primitives([low_wall])
    assert plain.checker.with_environment(env).is_free(Q_START[None])[0]
    assert not wide.checker.with_environment(env).is_free(Q_START[None])[0]
    assert wide.checker.with_environment(env).unpadded().is_free(Q_START[None])[0]


def test_the_arm_tests_occupied_cells_and_the_gripper_and_base_test_points():
    """A map cell keeps one point of the surface crossing it; the surface may
    reach anywhere in the cell along itself. An arm sphere 1 cm from the edge
    of a wall of points, inside the cells that hold the edge, is free when it
    tests the points and in collision when it tests the cells (the default).
    Across the wall, the wall is where its points are: a sphere 1 cm in front
    of it is free for both tests."""
    from vamg_drake.planning.sphere_checks import TEST_CELLS, TEST_POINTS, TEST_TARGET_POINTS

    cells = WholeBodyPlanner.for_fetch(CollisionEnvironment(), CONFIG).checker
    points = WholeBodyPlanner.for_fetch(CollisionEnvironment(),
                                        PlannerConfig(attempt_wall_limit_s=5.0, occupied_cells=False)).checker
    test = cells.env_test
    assert set(test[cells.is_gripper]) == {TEST_TARGET_POINTS}
    assert set(test[cells.is_base]) == {TEST_POINTS}
    assert set(test[~cells.is_gripper & ~cells.is_base]) == {TEST_CELLS}
    assert set(points.env_test) == {TEST_POINTS, TEST_TARGET_POINTS}

    h = 0.03
    q = layout.stow_configuration(0.0, 0.0, 0.0)
    c = cells.sphere_centers(q[None])[0]
    r = cells.unpadded().sph_r
    arm = (test == TEST_CELLS) & cells.check_env
    front = int(np.argmax(np.where(arm, c[:, 0] + r, -np.inf)))
    # Move the robot so that the sphere reaches 2 mm into a cell; the points
    # nearest it lie 1 cm further, in the same cell.
    dx = math.ceil((c[front, 0] + r[front]) / h) * h + 0.002 - (c[front, 0] + r[front])
    q = layout.stow_configuration(dx, 0.0, 0.0)
    c = cells.sphere_centers(q[None])[0]
    x_points = c[front, 0] + r[front] + 0.01
    # A wall in the plane y = c_y whose edge faces the sphere along x.
    xs, zs = np.meshgrid(x_points + np.arange(5) * h, np.arange(-0.06, 0.07, h) + c[front, 2])
    edge_on = np.stack([xs.ravel(), np.full(xs.size, c[front, 1]), zs.ravel()], axis=1)
    env = CollisionEnvironment.from_points(edge_on, h)
    assert points.with_environment(env).unpadded().is_free(q[None])[0]
    assert not cells.with_environment(env).unpadded().is_free(q[None])[0]
    # A wall in the plane x = x_points, facing the sphere.
    ys, zs = np.meshgrid(np.arange(-0.06, 0.07, h) + c[front, 1], np.arange(-0.06, 0.07, h) + c[front, 2])
    facing = np.stack([np.full(ys.size, x_points), ys.ravel(), zs.ravel()], axis=1)
    env = CollisionEnvironment.from_points(facing, h)
    assert points.with_environment(env).unpadded().is_free(q[None])[0]
    assert cells.with_environment(env).unpadded().is_free(q[None])[0]
