"""Collision checker: conservative against exact geometry, matches the sphere model."""

import numpy as np
import pytest

from vamg_drake.planning.collision_environment import CollisionEnvironment, support_height
from vamg_drake.planning.distance_field import DistanceField
from vamg_drake.planning.sphere_collision import CollisionCheckerConfig, SphereCollisionChecker, bisection_order, densify
from vamg_drake.robot import layout
from vamg_drake.robot.kinematics import FetchKinematics
from vamg_drake.robot.spheres import SphereModel
from vamg_drake.testing.planning_problems import furnished_room


@pytest.fixture(scope="module")
def room():
    return furnished_room(np.random.default_rng(3))


def _random_configs(rng, n):
    Q = rng.uniform(layout.SAMPLE_LOWER, layout.SAMPLE_UPPER, (n, layout.NQ))
    Q[:, 0] = rng.uniform(0.0, 6.0, n)
    Q[:, 1] = rng.uniform(0.0, 5.0, n)
    return Q


def test_distance_field_bound_is_conservative():
    rng = np.random.default_rng(0)
    points = rng.uniform(-1.0, 1.0, (400, 3))
    field = DistanceField.from_points(points, resolution=0.05)
    centers = rng.uniform(-1.2, 1.2, (3000, 3))
    idx = np.floor((centers - field.origin) / field.resolution + 0.5).astype(int)
    inside = np.all((idx >= 0) & (idx < field.dist.shape), axis=1)
    d_field = field.dist[tuple(idx[inside].T)] - field.margin
    d_true = np.min(np.linalg.norm(centers[inside, None] - points[None], axis=2), axis=1)
    kept = np.isfinite(d_field)
    assert np.all(d_field[kept] <= d_true[kept] + 1e-9)
    assert np.mean(d_true[kept] - d_field[kept]) < 2.0 * field.margin  # and not uselessly loose
    # Only cells beyond the kept distances (the pad) hold +inf.
    assert field.max_distance == 0.5 and not kept.all()
    assert np.all(d_true[~kept] > field.max_distance - field.margin)


def test_map_field_free_implies_exactly_free(room):
    env = CollisionEnvironment.from_primitives(room)
    exact = SphereCollisionChecker.for_fetch(env, CollisionCheckerConfig(motion_resolution=0.0))
    voxel = exact.with_environment(env.voxelized(0.03))
    Q = _random_configs(np.random.default_rng(1), 3000)
    f_exact, f_voxel = exact.is_free(Q), voxel.is_free(Q)
    assert not np.any(f_voxel & ~f_exact)
    assert f_voxel.sum() > 0.7 * f_exact.sum()


def test_self_collision_matches_sphere_model():
    """On an empty map without the floor test, only joint limits and self-collision decide."""
    checker = SphereCollisionChecker.for_fetch(CollisionEnvironment(),
                                         CollisionCheckerConfig(motion_resolution=0.0, self_padding=0.0,
                                                                arm_floor_clearance=None))
    Q = _random_configs(np.random.default_rng(2), 3000)
    expected = SphereModel.load().self_collision_free(Q) & layout.within_limits(Q)
    np.testing.assert_array_equal(checker.is_free(Q), expected)


def test_spheres_free_implies_drake_exact_geometry_free(room):
    from vamg_drake.testing.drake_reference import DrakeCollisionWorld

    env = CollisionEnvironment.from_primitives(room)
    checker = SphereCollisionChecker.for_fetch(env, CollisionCheckerConfig(motion_resolution=0.0))
    drake = DrakeCollisionWorld(room)
    Q = _random_configs(np.random.default_rng(4), 400)
    free = checker.is_free(Q)
    assert free.sum() > 50
    assert not any(drake.in_collision(q) for q in Q[free])


def test_limits_nan_and_batch_shape_are_rejected():
    checker = SphereCollisionChecker.for_fetch(CollisionEnvironment())
    q = layout.stow_configuration(0.0, 0.0, 0.0)
    bad = np.stack([q, q, q])
    bad[1, layout.TORSO] = 1.0
    bad[2, 5] = np.nan
    np.testing.assert_array_equal(checker.is_free(bad), [True, False, False])
    with pytest.raises(ValueError, match="shape"):
        checker.is_free(np.zeros((2, 7)))


def test_densify_respects_motion_resolution():
    checker = SphereCollisionChecker.for_fetch(CollisionEnvironment())
    a = layout.stow_configuration(0.0, 0.0, 0.0)
    b = layout.stow_configuration(1.0, 0.5, 2.0)
    dense = densify(np.stack([a, b]), checker)
    steps = checker.sphere_displacement_bound(np.diff(dense, axis=0))
    assert steps.max() <= checker.config.motion_resolution + 1e-12
    assert sorted(bisection_order(9).tolist()) == list(range(9))


def test_empty_map_is_free():
    env = CollisionEnvironment.from_points(np.zeros((0, 3)))
    checker = SphereCollisionChecker.for_fetch(env)
    assert env.is_empty
    assert checker.is_free(layout.stow_configuration(0.0, 0.0, 0.0)[None])[0]


def test_checker_refuses_a_field_that_keeps_too_short_distances():
    """A field keeps distances up to its pad only; a sphere that reaches past
    that could be called free next to an obstacle, so the checker refuses it."""
    points = np.array([[1.0, 0.0, 0.5]])
    checker = SphereCollisionChecker.for_fetch(CollisionEnvironment(field=DistanceField.from_points(points)))
    assert checker.env.field.max_distance == 0.5
    with pytest.raises(ValueError, match="pad"):
        checker.set_environment(CollisionEnvironment(field=DistanceField.from_points(points, pad=0.2)))


def test_edt_2d_matches_scipy():
    from scipy import ndimage

    from vamg_drake.planning.distance_field import edt_2d

    rng = np.random.default_rng(0)
    for shape, p in [((60, 45), 0.02), ((1, 7), 0.3), ((33, 20), 0.0005)]:
        occ = rng.random(shape) < p
        occ[0, 0] = True
        np.testing.assert_allclose(edt_2d(occ, 0.05), ndimage.distance_transform_edt(~occ, sampling=0.05),
                                   atol=1e-5)
    assert np.all(np.isinf(edt_2d(np.zeros((4, 5), bool), 0.05)))


def test_edt_3d_matches_scipy():
    """The distance field's transform: equal to SciPy's to float32 rounding,
    on grids with thin and unequal axes."""
    from scipy import ndimage

    from vamg_drake.planning.distance_field import edt_3d

    rng = np.random.default_rng(1)
    for shape, p in [((40, 31, 17), 0.01), ((1, 9, 5), 0.2), ((23, 1, 30), 0.05), ((12, 14, 1), 0.0005)]:
        occ = rng.random(shape) < p
        occ[-1, 0, -1] = True
        expected = ndimage.distance_transform_edt(~occ, sampling=0.03).astype(np.float32)
        np.testing.assert_allclose(edt_3d(occ, 0.03), expected, rtol=1e-6)
    assert np.all(np.isinf(edt_3d(np.zeros((3, 4, 5), bool), 0.03)))


def test_point_field_decides_the_shell_exactly():
    """A field built from points answers sphere tests exactly against the
    points (the shell D - sqrt(3) h <= r < D + sqrt(3) h is settled by the
    points, not counted as collision); one from bare occupancy stays
    conservative, and so does the arm's test of the occupied cells (the
    default) against the points'."""
    rng = np.random.default_rng(7)
    # A noisy table top at 0.75 m sampled like the map (one point per 3 cm voxel).
    xs, ys = np.meshgrid(np.arange(0.5, 1.5, 0.03), np.arange(-0.5, 0.5, 0.03))
    points = np.stack([xs.ravel(), ys.ravel(), np.full(xs.size, 0.75)], 1) + rng.uniform(-0.01, 0.01, (xs.size, 3))
    env = CollisionEnvironment.from_points(points, resolution=0.03)
    assert env.field.has_points
    checker = SphereCollisionChecker.for_fetch(env, CollisionCheckerConfig(motion_resolution=0.0, self_padding=0.0,
                                                                           occupied_cells=False))
    cells = SphereCollisionChecker.for_fetch(env, CollisionCheckerConfig(motion_resolution=0.0, self_padding=0.0))
    bare = SphereCollisionChecker.for_fetch(
        CollisionEnvironment.from_occupancy(env.field.occupancy, env.field.origin, 0.03),
        CollisionCheckerConfig(motion_resolution=0.0, self_padding=0.0))
    # Whole-body configurations with the gripper swept over and into the top.
    Q = np.tile(np.array([0.0, 0.0, 0.0, 0.3, 0.0, 0.4, 0.0, 1.2, 0.0, 0.9, 0.0]), (600, 1))
    Q[:, 0] = rng.uniform(-0.4, 0.2, 600)
    Q[:, 3] = rng.uniform(0.0, 0.38, 600)
    Q[:, 5] = rng.uniform(-0.2, 0.9, 600)
    self_ok = SphereCollisionChecker.for_fetch(CollisionEnvironment(), checker.config).is_free(Q)
    centers = checker.sphere_centers(Q)
    d = np.linalg.norm(centers[:, :, None, :] - points[None, None], axis=3).min(axis=2)
    truth = self_ok & np.all(d > checker.sph_r[None], axis=1)
    got = checker.is_free(Q)
    np.testing.assert_array_equal(got, truth)
    conservative = bare.is_free(Q)
    assert not np.any(conservative & ~truth)
    by_cells = cells.is_free(Q)
    assert not np.any(by_cells & ~truth) and np.any(truth & ~by_cells)
    # The exact test accepts configurations the bound rejected (the table-side
    # grasps the closed loop needs), and there are collisions among them.
    assert np.sum(got & ~conservative) >= 10
    assert np.sum(~truth & self_ok) >= 10


def test_a_cell_is_a_box_except_across_a_surface():
    """The arm's test of a map cell: the whole cell, except along a surface's
    normal, where the surface lies at its points. A sphere whose bottom
    reaches into a table top's cells above the points is free; the same cells
    on top of a block (occupied cells below them) are solid; the corner
    between a table top and the wall it meets is solid too."""
    from vamg_drake.planning.sphere_checks import _sphere_hits_map

    h = 0.03
    xs, ys = np.meshgrid(np.arange(0.0, 0.3, h) + 0.015, np.arange(0.0, 0.3, h) + 0.015)
    top = np.stack([xs.ravel(), ys.ravel(), np.full(xs.size, 0.705)], axis=1)  # in the cell [0.69, 0.72]
    no_target = np.zeros(4)

    def hits(points, centre, radius, cells=True):
        f = CollisionEnvironment.from_points(points, h).field
        return _sphere_hits_map(*centre, radius, f.dist, f.origin, f.resolution, f.points, f.cell_keys,
                                f.cell_start, False, no_target, 0.0, cells)

    above = (0.15, 0.15, 0.705 + 0.01 + 0.05)  # 1 cm above the top, inside its cells
    assert not hits(top, above, 0.05) and not hits(top, above, 0.05, cells=False)
    assert hits(top, (0.15, 0.15, 0.705 + 0.045), 0.05)  # 5 mm into the top
    block = np.concatenate([top, top - [0.0, 0.0, h]])
    assert hits(block, above, 0.05) and not hits(block, above, 0.05, cells=False)
    # A wall rising from the table's edge x = 0.3: the top's last row of cells
    # meets it; a sphere beside the wall just above the top touches that corner.
    zs, ys2 = np.meshgrid(np.arange(0.735, 0.9, h), np.arange(0.0, 0.3, h) + 0.015)
    wall = np.stack([np.full(zs.size, 0.295), ys2.ravel(), zs.ravel()], axis=1)
    corner = (0.295 - 0.02 - 0.011, 0.15, 0.705 + 0.02 + 0.008)
    assert hits(np.concatenate([top, wall]), corner, 0.02)
    assert not hits(np.concatenate([top, wall]), corner, 0.02, cells=False)


def test_grasp_target_points_may_touch_the_gripper_only():
    """Points within the grasp target's ball block the forearm but not the fingers."""
    checker = SphereCollisionChecker.for_fetch(CollisionEnvironment(), CollisionCheckerConfig(motion_resolution=0.0))
    q = np.array([0.0, 0.0, 0.0, 0.3, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0])  # arm straight out
    assert checker.is_free(q[None])[0]
    c = checker.sphere_centers(q[None])[0]
    grip, forearm = np.flatnonzero(checker.is_gripper), checker.sph_link == checker.tree.link_names.index("forearm_roll_link")
    assert grip.size and forearm.any()
    p_grip = c[grip].mean(axis=0)
    p_fore = c[np.flatnonzero(forearm)[0]]
    ball = np.random.default_rng(0).normal(size=(200, 3)) * 0.01
    for p, free_with_exemption in ((p_grip, True), (p_fore, False)):
        env = CollisionEnvironment.from_points(p + ball, 0.03, grasp_target=p, grasp_target_radius=0.1)
        assert bool(checker.with_environment(env).is_free(q[None])[0]) is free_with_exemption
        # Without the exemption the points block both.
        assert not checker.with_environment(CollisionEnvironment.from_points(p + ball, 0.03)).is_free(q[None])[0]
    with pytest.raises(ValueError, match="grasp_target"):
        CollisionEnvironment.from_points(ball, 0.03, grasp_target=[np.nan, 0, 0], grasp_target_radius=0.1)


def test_the_support_under_the_grasp_target_blocks_the_gripper():
    """Table-top points inside the target's ball are the support, not the
    object: the gripper may touch the object's points only."""

    rng = np.random.default_rng(1)
    checker = SphereCollisionChecker.for_fetch(CollisionEnvironment(), CollisionCheckerConfig(motion_resolution=0.0))
    q = np.array([0.0, 0.0, 0.0, 0.3, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0])  # arm straight out
    p_WT = FetchKinematics.instance().gripper_pose(q)[:3, 3]  # the object between the fingers
    obj = p_WT + rng.normal(size=(200, 3)) * 0.005
    c = checker.sphere_centers(q[None])[0]
    z_table = np.min(c[checker.is_gripper, 2] - checker.sph_r[checker.is_gripper]) + 0.01  # cuts the fingers
    xs, ys = np.meshgrid(np.arange(-0.1, 0.1, 0.015), np.arange(-0.1, 0.1, 0.015))
    table = np.column_stack([p_WT[0] + xs.ravel(), p_WT[1] + ys.ravel(), np.full(xs.size, z_table)])
    assert support_height(np.concatenate([table, obj]), p_WT, 0.1) == pytest.approx(z_table, abs=0.021)
    assert support_height(obj, p_WT, 0.1) == -np.inf  # no plane under the object alone
    assert support_height(np.zeros((0, 3)), p_WT, 0.1) == -np.inf
    for points, expect_free in ((obj, True), (np.concatenate([table, obj]), False)):
        env = CollisionEnvironment.from_points(points, 0.03, grasp_target=p_WT, grasp_target_radius=0.1)
        assert bool(checker.with_environment(env).is_free(q[None])[0]) is expect_free


def test_drive_free_matches_is_free(room):
    """The held-arm drive check (forward kinematics and self-collision once,
    spheres moved rigidly with the base) gives the verdicts of the full
    check, for exact primitives and for a map with a grasp target."""
    rng = np.random.default_rng(21)
    points = np.concatenate([rng.uniform([1.0, 1.0, 0.0], [2.0, 1.5, 0.9], (2000, 3)),
                             rng.uniform([3.5, 2.0, 0.6], [4.5, 3.0, 0.8], (2000, 3))])
    envs = [CollisionEnvironment.from_primitives(room),
            CollisionEnvironment.from_points(points, 0.03, grasp_target=np.array([4.0, 2.5, 0.85]),
                                             grasp_target_radius=0.1)]
    arms = [np.array([0.167, 0.43, 1.214, -0.738, 1.461, -0.093, 1.597, -1.9]),
            np.concatenate([[0.0], layout.Q_ARM_STOW])]
    arms += list(rng.uniform(layout.SAMPLE_LOWER[3:], layout.SAMPLE_UPPER[3:], (6, 8)))
    verdicts = []
    for env in envs:
        checker = SphereCollisionChecker.for_fetch(env)
        for arm in arms:
            poses = np.column_stack([rng.uniform(0.0, 6.0, 2000), rng.uniform(0.0, 5.0, 2000),
                                     rng.uniform(-8.0, 8.0, 2000)])
            Q = np.concatenate([poses, np.repeat(arm[None], poses.shape[0], axis=0)], axis=1)
            expected = checker.is_free(Q)
            np.testing.assert_array_equal(checker.drive_free(poses, arm), expected)
            verdicts.append(expected.mean())
    assert min(verdicts) == 0.0 and max(verdicts) > 0.3  # self-colliding arms and free drives both seen


def test_base_pose_exact_check_matches_is_free(room):
    """`base_pose_free_exact` (the torso + arm's spheres precomputed in the
    base frame, moved rigidly) agrees with the full check."""
    from vamg_drake.planning.sphere_checks import base_pose_free_exact

    rng = np.random.default_rng(22)
    checker = SphereCollisionChecker.for_fetch(CollisionEnvironment.from_primitives(room))
    arms = [np.array([0.167, 0.43, 1.214, -0.738, 1.461, -0.093, 1.597, -1.9])]
    arms += list(rng.uniform(layout.SAMPLE_LOWER[3:], layout.SAMPLE_UPPER[3:], (4, 8)))
    seen = []
    for arm in arms:
        data = checker.base_pose_check_data(arm)
        poses = np.column_stack([rng.uniform(0.0, 6.0, 500), rng.uniform(0.0, 5.0, 500), rng.uniform(-8, 8, 500)])
        got = np.array([base_pose_free_exact(x, y, th, data) for x, y, th in poses])
        Q = np.concatenate([poses, np.repeat(arm[None], poses.shape[0], axis=0)], axis=1)
        Q[:, 2] = layout.wrap_angle(Q[:, 2])
        np.testing.assert_array_equal(got, checker.is_free(Q))
        seen.append(got.mean())
    assert min(seen) < 0.5 < max(seen)


def test_checker_and_sphere_model_compute_the_same_centres():
    """Sphere centres are computed one way: the checker's, the sphere model's
    and those from the link poses of `FetchKinematics` are the same bits."""
    head = np.array([0.3, -0.2])
    checker = SphereCollisionChecker.for_fetch(CollisionEnvironment(),
                                               CollisionCheckerConfig(head_pan=head[0], head_tilt=head[1]))
    model = SphereModel.load()
    rng = np.random.default_rng(11)
    Q = rng.uniform(layout.SAMPLE_LOWER, layout.SAMPLE_UPPER, (40, layout.NQ))
    centres = checker.sphere_centers(Q)
    np.testing.assert_array_equal(centres, model.world_spheres(Q, head=head))
    X_WL = FetchKinematics.instance().link_poses(Q, head)
    np.testing.assert_array_equal(centres, model.world_spheres(Q, link_poses=X_WL))
