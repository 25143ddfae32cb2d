"""The real subgoal samplers (kinematic maps, IK, collision, visibility) in constructed scenes."""

from __future__ import annotations

import dataclasses as dc

import numpy as np
import pytest

from behaviour_stepper import Stepper
from vamg_drake.testing import synthetic_clouds as clouds
from vamg_drake.perception.depth_points import DepthToPointsConfig
from vamg_drake.policy.behaviour_tree import FailureCategory, MotionEvent, Phase, PolicyInputs, SubgoalBehaviour
from vamg_drake.policy.kinematic_maps import KinematicMaps
from vamg_drake.policy.pregrasp_sampler import BaseCostmap, CostmapConfig, PregraspConfig, PregraspSampler
from vamg_drake.policy.subgoal_pipeline import SubgoalPipeline
from vamg_drake.robot import layout
from vamg_drake.robot.head_camera import CameraIntrinsics, HeadCameraConfig
from vamg_drake.robot.kinematics import FetchKinematics


@pytest.fixture(scope="module")
def pipeline() -> SubgoalPipeline:
    return SubgoalPipeline(KinematicMaps.load_or_build(), HeadCameraConfig(), DepthToPointsConfig().depth_max, seed=0)


@pytest.fixture
def fresh_pipeline() -> SubgoalPipeline:
    """A pipeline whose memory (random generator, tried bases) no other test used."""
    return SubgoalPipeline(KinematicMaps.load_or_build(), HeadCameraConfig(), DepthToPointsConfig().depth_max, seed=0)


@pytest.fixture(scope="module")
def scene():
    return clouds.tabletop_scene()


def test_costmap_follows_the_appendix_recipe() -> None:
    cfg = CostmapConfig()
    zs = [0.1, 0.5, 1.0]
    room = clouds.box_surface_cloud([0.0, 0.0, 0.1], [2.0, 2.0, 1.0], spacing=0.05)
    room = room[np.isclose(room[:, 0], 0) | np.isclose(room[:, 0], 2) | np.isclose(room[:, 1], 0) | np.isclose(room[:, 1], 2)]
    divider = np.stack(np.meshgrid(np.arange(0.0, 2.0, 0.05), [0.7], zs, indexing="ij"), -1).reshape(-1, 3)
    divider = divider[np.abs(divider[:, 0] - 1.0) > 0.03]  # a one-cell gap at x = 1.0 ...
    clutter = np.array([[0.5, 1.3, 0.02], [0.5, 1.4, 1.8]])  # ... and points outside 0.05-1.5 m
    points = np.concatenate([room, divider, clutter])
    cm = BaseCostmap.from_points(points, cfg)
    cell, _ = cm.cell_of(np.array([[1.0, 0.7], [0.5, 1.3], [0.5, 1.4]]))
    assert cm.occupied[cell[0, 0], cell[0, 1]]  # the 3x3 closing filled the gap
    assert not cm.occupied[cell[1, 0], cell[1, 1]] and not cm.occupied[cell[2, 0], cell[2, 1]]
    # EDT distances and the exponential cost.
    assert cm.clearance_at(np.array([[1.0, 1.35]]))[0] == pytest.approx(0.65, abs=0.051)
    np.testing.assert_allclose(cm.cost, np.exp(-cm.distance / 2.0))
    # The largest free component (the padded outside ring here) ...
    np.testing.assert_array_equal(cm.navigable_at(np.array([[1.0, -0.3], [1.0, 0.3], [1.0, 1.5]])), [True, False, False])
    # ... unless the robot stands in a free cell: then its own component.
    cm = BaseCostmap.from_points(points, cfg, robot_xy=np.array([1.0, 1.5]))
    np.testing.assert_array_equal(cm.navigable_at(np.array([[1.0, -0.3], [1.0, 0.3], [1.0, 1.5]])), [False, False, True])
    # Samples: navigable, clear, within the radius, facing the target, biased to low cost.
    target = np.array([1.0, 1.2, 0.8])
    rng = np.random.default_rng(0)
    bases = cm.sample_bases(target, 2000, (0.2, 0.8), 0.15, rng)
    assert bases.shape == (2000, 3)
    assert np.all(cm.clearance_at(bases[:, :2]) >= 0.1)
    r = np.linalg.norm(bases[:, :2] - target[:2], axis=1)
    assert np.all((r > 0.15) & (r < 0.85))
    heading = np.stack([np.cos(bases[:, 2]), np.sin(bases[:, 2])], 1)
    to_target = (target[:2] - bases[:, :2]) / r[:, None]
    np.testing.assert_allclose(np.sum(heading * to_target, 1), 1.0, atol=1e-9)
    centers = cm.cell_centers()
    rr = np.linalg.norm(centers - target[:2], axis=-1)
    eligible = cm.navigable & (cm.distance >= 0.15) & (rr >= 0.2) & (rr <= 0.8)
    w_cells = ((1 - cm.cost[eligible]) ** 2).mean()
    w_samples = ((1 - np.exp(-cm.clearance_at(bases[:, :2]) / 2.0)) ** 2).mean()
    assert w_samples > w_cells


def test_travel_distance_goes_around_a_divider() -> None:
    """Path lengths over the costmap from the robot: a cell behind a divider is
    reached through its gap, farther than a cell on the robot's side that is
    nearer in a straight line; the robot's own tight spot does not trap it."""
    walls = clouds.box_surface_cloud([0.0, 0.0, 0.1], [4.0, 3.0, 1.0], spacing=0.05)
    walls = walls[np.isclose(walls[:, 0], 0) | np.isclose(walls[:, 0], 4) | np.isclose(walls[:, 1], 0)
                  | np.isclose(walls[:, 1], 3)]
    divider = np.stack(np.meshgrid(np.arange(0.0, 3.0, 0.05), [1.5], [0.1, 0.5, 1.0], indexing="ij"), -1).reshape(-1, 3)
    cm = BaseCostmap.from_points(np.concatenate([walls, divider]), CostmapConfig(), robot_xy=np.array([0.5, 0.7]))
    north, east = np.array([[0.5, 2.3]]), np.array([[2.5, 0.7]])
    d = cm.travel_distance(np.array([0.5, 0.7]), 0.30)
    assert cm.value_at(d, east)[0] == pytest.approx(2.0, abs=0.1)
    # Around the divider's end at x = 3 (its gap is 1 m wide): at least 2 x 2.5 m + 0.8 m.
    assert cm.value_at(d, north)[0] > 5.5
    assert np.linalg.norm(north - [0.5, 0.7]) < np.linalg.norm(east - [0.5, 0.7])
    # From 0.2 m off a wall (closer than the clearance) the robot still gets out.
    d = cm.travel_distance(np.array([2.0, 0.2]), 0.30)
    assert np.isfinite(cm.value_at(d, east)[0])
    assert np.isinf(cm.value_at(d, np.array([[50.0, 50.0]]), outside=np.inf)[0])


def test_pregrasp_bases_are_visited_nearest_first(pipeline) -> None:
    """A target in the middle of a table is reachable from both long sides; the
    robot east of the table gets an east-side pre-grasp from every seed, while
    the bases in drawn order put it on the far side for some seeds."""
    points, target = clouds.tabletop_scene(object_offset_xy=(0.0, 0.0))  # table x in [0.8, 1.4]
    q0 = layout.stow_configuration(2.4, 0.0, np.pi)
    is_free = pipeline.collision_fn(points, target, q0)
    drawn_order = PregraspSampler(pipeline.maps, pipeline.ik, pipeline.visibility,
                                  dc.replace(pipeline.pregrasp.config, order_bases_by_travel=False))
    assert pipeline.pregrasp.config.order_bases_by_travel
    near, drawn = [], []
    for seed in range(8):
        for sampler, xs in ((pipeline.pregrasp, near), (drawn_order, drawn)):
            r = sampler.sample(points, target, q0, is_free, np.random.default_rng(seed))
            assert r.success, r.failure_reason
            xs.append(r.q[0])
    assert min(near) > 1.4, near
    assert min(drawn) < 0.8, drawn


def test_pregrasp_bases_near_a_tried_base_come_last() -> None:
    """Asked again from the pre-grasp goal it reached (the grasp stage found no
    grasp there), the pipeline proposes a base away from it: nearest first
    alone would return to the same spot and the same views."""
    points, target = clouds.tabletop_scene(object_offset_xy=(0.0, 0.0))
    dense = points[np.linalg.norm(points - target, axis=1) < 0.3]
    q0 = layout.stow_configuration(2.4, 0.0, np.pi)
    radius = PregraspConfig().tried_radius
    for seed in range(3):
        p = SubgoalPipeline(KinematicMaps.load_or_build(), HeadCameraConfig(), DepthToPointsConfig().depth_max,
                            seed=seed)
        first = p.sample_pregrasp(PolicyInputs(0.0, q0, points, target, dense))
        assert first.success, first.failure_reason
        again = p.sample_pregrasp(PolicyInputs(5.0, first.q_goal, points, target, dense))
        assert again.success, again.failure_reason
        assert np.linalg.norm(again.q_goal[:2] - first.q_goal[:2]) > radius
        # The sampler itself: without the tried base, the nearest base is next to it.
        is_free = p.collision_fn(points, target, first.q_goal)
        plain = p.pregrasp.sample(points, target, first.q_goal, is_free, np.random.default_rng(seed))
        assert np.linalg.norm(plain.q[:2] - first.q_goal[:2]) <= radius
        tried = p.pregrasp.sample(points, target, first.q_goal, is_free, np.random.default_rng(seed),
                                  tried_xy=first.q_goal[None, :2])
        assert np.linalg.norm(tried.q[:2] - first.q_goal[:2]) > radius
        # A base whose motion failed (the behaviour's `failed_bases`) comes last too,
        # asked from where the robot still is.
        p = SubgoalPipeline(KinematicMaps.load_or_build(), HeadCameraConfig(), DepthToPointsConfig().depth_max,
                            seed=seed)
        first = p.sample_pregrasp(PolicyInputs(0.0, q0, points, target, dense))
        failed = p.sample_pregrasp(PolicyInputs(5.0, q0, points, target, dense, failed_bases=first.q_goal[None, :2]))
        assert failed.success, failed.failure_reason
        assert np.linalg.norm(failed.q_goal[:2] - first.q_goal[:2]) > radius


def test_pregrasp_samples_are_collision_free_ik_valid_and_see_the_target(pipeline, scene) -> None:
    points, target = scene
    q0 = layout.stow_configuration(-1.5, 0.5, 0.0)
    is_free = pipeline.collision_fn(points, target, q0)
    kin = FetchKinematics.instance()
    intr = CameraIntrinsics.from_config(HeadCameraConfig())
    n_ok = 0
    for seed in range(4):
        r = pipeline.pregrasp.sample(points, target, q0, is_free, np.random.default_rng(seed))
        if not r.success:
            continue
        n_ok += 1
        q = r.q
        assert layout.within_limits(q)
        assert is_free(q[None])[0]
        # The torso leaves room to lift the object.
        assert q[layout.TORSO] <= layout.Q_UPPER[layout.TORSO] - pipeline.config.pregrasp.lift_headroom + 1e-9
        X = kin.gripper_pose(q)
        np.testing.assert_allclose(X[:3, 3], r.X_WG[:3, 3], atol=pipeline.ik.config.position_tolerance)
        assert np.linalg.norm(X[:3, 3] - target) == pytest.approx(0.10, abs=0.005)
        approach = (target - X[:3, 3]) / np.linalg.norm(target - X[:3, 3])
        assert X[:3, 0] @ approach > 0.99
        # The target is in the image, in front of the camera, at the aimed head.
        X_WC = kin.camera_pose(q, *r.head)
        p_C = np.linalg.inv(X_WC) @ np.r_[target, 1.0]
        u = intr.fx * p_C[0] / p_C[2] + intr.cx
        v = intr.fy * p_C[1] / p_C[2] + intr.cy
        assert p_C[2] > 0.2 and 0 <= u < intr.width and 0 <= v < intr.height
        # No robot sphere on the line of sight.
        visible, _ = pipeline.visibility.check(q[None], target)
        assert visible[0]
    assert n_ok >= 3


def test_tree_falls_back_and_recovers_in_a_scene(pipeline, scene) -> None:
    points, target = scene
    bt = Stepper(SubgoalBehaviour(pipeline.samplers()))
    q = layout.stow_configuration(-1.5, 0.5, 0.0)  # 2.5 m from the target: no grasp in place
    cmd = bt.step(PolicyInputs(0.0, q, points, target))
    assert cmd.phase == Phase.PREGRASP, bt.tree_status()
    assert "grasp" in bt.stage_failures
    # Drive to the pre-grasp: from there the grasp stage succeeds.
    cmd = bt.step(PolicyInputs(5.0, cmd.q_goal, points, target), MotionEvent.REACHED)
    assert cmd.phase == Phase.GRASP_MOVE, bt.tree_status()
    X_pre = FetchKinematics.instance().gripper_pose(cmd.q_goal)
    assert np.linalg.norm(X_pre[:3, 3] - target) < 0.2
    np.testing.assert_allclose(cmd.q_goal[:4], bt.q_grasp[:4])  # base and torso fixed while grasping
    # An injected motion failure: the grasp is blocked at this base, back to pre-grasp.
    base = cmd.q_goal
    cmd = bt.step(PolicyInputs(6.0, base, points, target), MotionEvent.FAILED)
    assert cmd.phase == Phase.PREGRASP and bt.motion_failures["grasp"] == 1


def test_tree_falls_back_to_observe_when_the_target_is_out_of_reach(pipeline) -> None:
    # A can in the middle of a 2 m deep table: visible from afar, out of the arm's reach.
    table = clouds.box_surface_cloud([0.5, -1.0, 0.0], [2.5, 1.0, 0.6])
    can = clouds.can_cloud(center=(1.5, 0.0, 0.6), seed=3)
    points = np.concatenate([clouds.room_walls_cloud(), table, can])
    target = np.array([1.5, 0.0, 0.66])
    bt = Stepper(SubgoalBehaviour(pipeline.samplers()))
    cmd = bt.step(PolicyInputs(0.0, layout.stow_configuration(-1.0, 0.0, 0.0), points, target))
    assert cmd.phase == Phase.OBSERVE, bt.tree_status()
    d = np.linalg.norm(cmd.q_goal[:2] - target[:2])
    assert min(pipeline.config.observe.standoff) - 0.01 <= d <= max(pipeline.config.observe.standoff) + 0.01
    np.testing.assert_allclose(cmd.q_goal[layout.ARM], layout.Q_ARM_STOW)
    visible, _ = pipeline.visibility.check(cmd.q_goal[None], target, points)
    assert visible[0] and pipeline.collision_fn(points, target, cmd.q_goal)(cmd.q_goal[None])[0]
    # The nearest valid standoff pose: at least as close to the start as any other valid one.
    start = np.array([-1.0, 0.0])
    assert np.linalg.norm(cmd.q_goal[:2] - start) <= np.linalg.norm(target[:2] - start) + 0.1


def test_target_outside_the_room_fails_with_reachability(pipeline, scene) -> None:
    points, _ = scene
    target = np.array([4.5, 0.0, 0.8])  # beyond the wall at x = 3
    bt = Stepper(SubgoalBehaviour(pipeline.samplers()))
    cmd = bt.step(PolicyInputs(0.0, layout.stow_configuration(0.0, 0.0, 0.0), points, target))
    assert cmd.phase == Phase.FAILED
    assert cmd.failure in (FailureCategory.REACHABILITY, FailureCategory.PERCEPTION, FailureCategory.SUBGOAL)
    assert "navigable" in bt.stage_failures["pre_grasp"][0]


def test_target_inside_furniture_fails_with_perception(pipeline) -> None:
    cabinet = clouds.box_surface_cloud([1.0, -0.4, 0.0], [1.6, 0.4, 0.9], spacing=0.02)
    points = np.concatenate([clouds.room_walls_cloud(), cabinet])
    target = np.array([1.3, 0.0, 0.45])  # the cabinet's solid inside
    bt = Stepper(SubgoalBehaviour(pipeline.samplers()))
    cmd = bt.step(PolicyInputs(0.0, layout.stow_configuration(-1.0, 0.0, 0.0), points, target))
    assert cmd.phase == Phase.FAILED and cmd.failure == FailureCategory.PERCEPTION
    assert "enclosed" in cmd.reason


def test_empty_cloud_around_the_target(pipeline) -> None:
    points = clouds.room_walls_cloud()  # nothing observed near the target yet
    target = np.array([1.0, 0.0, 0.8])
    proposal = pipeline.sample_grasp(PolicyInputs(0.0, layout.stow_configuration(0.5, 0.0, 0.0), points, target))
    assert not proposal.success and proposal.category == FailureCategory.PERCEPTION
    assert "too few observed points" in proposal.failure_reason
    # An empty map altogether is not an error either.
    proposal = pipeline.sample_grasp(PolicyInputs(0.0, layout.stow_configuration(0.5, 0.0, 0.0), np.zeros((0, 3)), target))
    assert not proposal.success and "too few" in proposal.failure_reason


def test_non_finite_target(pipeline, scene) -> None:
    points, _ = scene
    for sample in (pipeline.sample_grasp, pipeline.sample_pregrasp, pipeline.sample_observe):
        p = sample(PolicyInputs(0.0, layout.stow_configuration(0, 0, 0), points, np.array([np.nan, 0.0, 1.0])))
        assert not p.success and "finite" in p.failure_reason


def test_dense_target_cloud_feeds_the_grasp_candidates(pipeline, scene) -> None:
    points, target = scene
    walls_only = clouds.room_walls_cloud()
    dense = points[np.linalg.norm(points - target, axis=1) < 0.3]
    # From the pre-grasp standpoint of the scene the dense cloud alone yields a grasp.
    q = pipeline.pregrasp.sample(points, target, layout.stow_configuration(-1.5, 0.5, 0.0),
                                 pipeline.collision_fn(points, target, layout.stow_configuration(-1.5, 0.5, 0.0)),
                                 np.random.default_rng(1)).q
    assert np.all(np.isfinite(q))
    without = pipeline.sample_grasp(PolicyInputs(0.0, q, walls_only, target))
    assert not without.success and "too few observed points" in without.failure_reason
    with_dense = pipeline.sample_grasp(PolicyInputs(0.0, q, walls_only, target, dense))
    assert "too few observed points" not in with_dense.failure_reason


def test_pregrasp_accept_prefers_but_does_not_require(pipeline, scene) -> None:
    """`accept` picks among valid samples; when it passes none, the first valid
    sample is still returned (a closer view may bring better grasps)."""
    points, target = scene
    q0 = layout.stow_configuration(-1.5, 0.5, 0.0)
    is_free = pipeline.collision_fn(points, target, q0)
    seen = []
    picky = pipeline.pregrasp.sample(points, target, q0, is_free, np.random.default_rng(0),
                                     accept=lambda q: seen.append(q) or len(seen) == 2)
    assert picky.success and picky.funnel["accepted"] == 1
    np.testing.assert_array_equal(picky.q, seen[1])
    seen.clear()
    none = pipeline.pregrasp.sample(points, target, q0, is_free, np.random.default_rng(0),
                                    accept=lambda q: seen.append(q) or False)
    assert none.success and none.funnel["accepted"] == 0 and len(seen) > 1
    np.testing.assert_array_equal(none.q, seen[0])


def test_support_surface_does_not_hide_a_small_target_but_a_wall_does(pipeline) -> None:
    # A 2 cm brick on a 0.94 m counter, seen from 1.2 m away at a low angle
    # the counter top lies just below the line of sight.
    counter = clouds.box_surface_cloud([0.6, -0.6, 0.0], [1.2, 0.6, 0.94], spacing=0.03)
    target = np.array([0.9, 0.0, 0.946])
    q = layout.stow_configuration(-0.3, 0.0, 0.0)
    vis = pipeline.visibility
    assert vis.check(q[None], target, counter)[0][0]
    strict = type(vis)(vis.camera, vis.max_depth, dc.replace(vis.config, support_tolerance=np.inf))
    assert not strict.check(q[None], target, counter)[0][0]  # every point near the line blocks it
    # A panel standing across the line of sight still hides the target.
    ys, zs = np.meshgrid(np.arange(-0.3, 0.3, 0.03), np.arange(0.9, 1.3, 0.03), indexing="ij")
    panel = np.stack([np.full(ys.size, 0.45), ys.ravel(), zs.ravel()], 1)
    assert not vis.check(q[None], target, np.concatenate([counter, panel]))[0][0]


def _brick_on_counter() -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(map points, dense target cloud, target point) of a 2 cm Lego brick on a 0.94 m counter."""
    z = 0.94
    counter = clouds.box_surface_cloud([0.8, -0.5, 0.0], [1.4, 0.5, z], spacing=0.03)
    base = np.array([1.0, 0.0, z])
    brick = clouds.box_cloud(center=base, size=(0.064, 0.032, 0.02), yaw=0.3, noise=0.001, seed=5)
    dense = np.concatenate([brick, clouds.table_top_cloud(z=z, center_xy=base[:2], size=0.4, spacing=0.005)])
    points = np.concatenate([clouds.room_walls_cloud(), counter, dense[::2]])
    return points, dense, base + np.array([0.0, 0.0, 0.01])


def test_low_brick_on_a_counter_is_grasped_from_its_pregrasp(fresh_pipeline) -> None:
    pipeline = fresh_pipeline
    # A 2 cm Lego brick on a 0.94 m counter. The collision
    # model's finger spheres reach 1 cm past the fingertips into the counter;
    # at the grasp and on the approach the grasp source's finer gripper check
    # decides (`collision_fn(..., grasp=True)`), not the spheres.
    points, dense, target = _brick_on_counter()
    q0 = layout.stow_configuration(-0.5, 0.0, 0.0)
    pre = pipeline.sample_pregrasp(PolicyInputs(0.0, q0, points, target, dense))
    assert pre.success, pre.failure_reason
    grasp = pipeline.sample_grasp(PolicyInputs(1.0, pre.q_goal, points, target, dense))
    assert grasp.success, grasp.failure_reason
    X_WG = FetchKinematics.instance().gripper_pose(grasp.q_grasp)
    # The grasp frame lies up to the largest contact offset behind the contacts.
    assert np.linalg.norm(X_WG[:3, 3] - target) < 0.02 + max(pipeline.config.grasps.contact_offsets)
    # With the spheres deciding at the grasp too, no grasp of the brick is free.
    strict = pipeline.collision_fn(points, target, pre.q_goal)
    assert not np.any(strict(grasp.q_grasp[None]))


def test_pregrasp_proposal_is_the_pregrasp_of_its_accepted_grasp(scene) -> None:
    """The arm goes to the pre-grasp pose of the grasp the proposal was accepted
    for, so the grasp stage's move to its pre-grasp starts where it ends
    (from another candidate's pre-grasp the arm can reconfigure next to the
    target and sweep it over). Off, the grasp stage's grasp is not the
    one the arm was drawn for."""
    points, target = scene
    dense = points[np.linalg.norm(points - target, axis=1) < 0.3]
    q0 = layout.stow_configuration(-1.5, 0.5, 0.0)
    gap = {}
    for aimed in (True, False):
        moves = []
        for seed in range(4):
            p = SubgoalPipeline(KinematicMaps.load_or_build(), HeadCameraConfig(), DepthToPointsConfig().depth_max,
                                seed=seed)
            p.config.pregrasp_at_aimed_grasp = aimed
            pre = p.sample_pregrasp(PolicyInputs(0.0, q0, points, target, dense))
            assert pre.success, pre.failure_reason
            grasp = p.sample_grasp(PolicyInputs(1.0, pre.q_goal, points, target, dense))
            assert grasp.success, grasp.failure_reason
            moves.append(np.max(np.abs(layout.wrap_configuration(grasp.q_goal - pre.q_goal))))
        gap[aimed] = max(moves)
    # The largest joint motion of the grasp-move [rad]: a small correction
    # towards the re-detected grasp (0.03-0.35 over seeds 0-7), not a flip
    # of the wrist by pi.
    assert gap[True] < 0.4
    assert gap[False] > 1.0


def test_a_grasp_that_closed_on_nothing_is_not_proposed_again(fresh_pipeline) -> None:
    pipeline = fresh_pipeline
    # The brick of the test above: the grasp chosen first, reported as one
    # that closed on nothing, gives way to a different grasp (another place or
    # another approach axis), and once every candidate has failed the stage
    # says so instead of proposing a failed grasp again.
    points, dense, target = _brick_on_counter()
    pre = pipeline.sample_pregrasp(PolicyInputs(0.0, layout.stow_configuration(-0.5, 0.0, 0.0), points, target, dense))
    assert pre.success, pre.failure_reason
    first = pipeline.sample_grasp(PolicyInputs(1.0, pre.q_goal, points, target, dense))
    assert first.success, first.failure_reason
    X_first = FetchKinematics.instance().gripper_pose(first.q_grasp)
    retry = pipeline.sample_grasp(PolicyInputs(1.0, pre.q_goal, points, target, dense, failed_grasps=X_first[None]))
    assert retry.success, retry.failure_reason
    X_retry = FetchKinematics.instance().gripper_pose(retry.q_grasp)
    cfg = pipeline.config
    moved = np.linalg.norm(X_retry[:3, 3] - X_first[:3, 3]) > cfg.failed_grasp_radius
    turned = X_retry[:3, 0] @ X_first[:3, 0] < np.cos(np.radians(cfg.failed_grasp_angle))
    assert moved or turned
    candidates = pipeline._grasp_candidates(PolicyInputs(1.0, pre.q_goal, points, target, dense),
                                            pipeline._points(PolicyInputs(1.0, pre.q_goal, points, target)), target)
    every = PolicyInputs(1.0, pre.q_goal, points, target, dense, failed_grasps=candidates.X_WG)
    exhausted = pipeline.sample_grasp(every)
    assert not exhausted.success and "closed on nothing" in exhausted.failure_reason
