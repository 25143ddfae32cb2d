"""The geometric antipodal grasp sampler and the grasp ranking."""

from __future__ import annotations

import dataclasses as dc

import numpy as np
import pytest
from pydrake.geometry import Box, Mesh
from pydrake.math import RigidTransform, RollPitchYaw

from vamg_drake.bench.grasp_trials import observe
from vamg_drake.perception.depth_points import DepthBackProjector, DepthToPointsConfig
from vamg_drake.perception.shape_depth_render import ShapeDepthRenderer, look_at
from vamg_drake.robot.head_camera import CameraIntrinsics, HeadCameraConfig
from vamg_drake.testing import synthetic_clouds as clouds
from vamg_drake.world.ycb import load_ycb_asset
from vamg_drake.policy.grasp_candidates import (
    AntipodalGraspConfig,
    AntipodalGraspSampler,
    GraspCandidates,
    GripperGeometry,
    gripper_lowest_z,
)
from vamg_drake.policy.grasp_ranking import (
    GraspRankingConfig,
    farthest_pose_sampling,
    near_any_grasp,
    pose_distance,
    pregrasp_poses,
    proximity_weighted_score,
    rank_grasps,
    select_grasp_goal,
)
from vamg_drake.policy.subgoal_pipeline import SubgoalPipelineConfig
from vamg_drake.robot import layout
from vamg_drake.robot.layout import GRIPPER_MAX_OPENING

TABLE_Z = 0.7
CENTER = np.array([1.0, 0.0, TABLE_Z])


def _table() -> np.ndarray:
    return clouds.table_top_cloud(z=TABLE_Z, center_xy=CENTER[:2], size=0.6)


def _objects() -> dict[str, np.ndarray]:
    return {
        "can": clouds.can_cloud(center=CENTER, noise=0.001, seed=1),
        "box": clouds.box_cloud(center=CENTER, yaw=0.4, noise=0.001, seed=2),
        "mug": clouds.mug_cloud(center=CENTER, noise=0.001, seed=3),
    }


def test_small_ball_on_a_table_is_grasped_nearer_the_fingertips() -> None:
    """A 4.7 cm marble (YCB 063-a) on a table: with the contacts mid-pad the
    fingertips or the palm reach into the table top; held back 1-2 cm along
    the approach, top-down grasps clear it."""
    center = np.array([0.0, 0.0, 0.874 + 0.024])
    cloud = np.concatenate([clouds.sphere_cloud(center, 0.024, seed=4),
                            clouds.table_top_cloud(z=0.874, size=0.5, spacing=0.005)])
    mid_pad = AntipodalGraspSampler(AntipodalGraspConfig(contact_offsets=[0.0], top_down_yaws=0)).propose(cloud, center)
    assert len(mid_pad) == 0 and "no finger clearance" in mid_pad.failure_reason
    g = AntipodalGraspSampler().propose(cloud, center)
    assert len(g) > 0, g.failure_reason
    _assert_valid_frames(g)
    # Approaches come from above, and the fingertips (3.1 cm ahead of the pads'
    # middle) stay above the table top.
    assert np.all(g.X_WG[:, 2, 0] < -0.4)
    tips = g.X_WG[:, :3, 3] + 0.031 * g.X_WG[:, :3, 0]
    assert np.all(tips[:, 2] > 0.874)
    with pytest.raises(ValueError, match="contact_offsets"):
        AntipodalGraspConfig(contact_offsets=[])


def test_ball_seen_only_from_above_is_grasped_without_checking_normals() -> None:
    """A 6 cm ball seen only above 30 deg of latitude (a far, high view): the
    points at its extremes along any closing axis are the cap's rim, whose
    normals tilt 30 deg or more out of the pads' friction cone, so no
    candidate passes the first-contact test. The fallback keeps the top-down
    grasps whose first contacts lie inside the fingertips and across the pads
    (the pads' middle at the unseen equator), at half their score."""
    radius = 0.03
    center = np.array([0.0, 0.0, 0.874 + radius])
    ball = clouds.sphere_cloud(center, radius, seed=4)
    cap = ball[ball[:, 2] > center[2] + radius * np.sin(np.radians(30.0))]
    cloud = np.concatenate([cap, clouds.table_top_cloud(z=0.874, size=0.5, spacing=0.005)])
    strict = AntipodalGraspSampler(AntipodalGraspConfig(unchecked_normals_fallback=False)).propose(cloud, center)
    assert len(strict) == 0 and "no finger clearance" in strict.failure_reason
    g = AntipodalGraspSampler().propose(cloud, center)
    assert len(g) > 0, g.failure_reason
    _assert_valid_frames(g)
    assert np.all(g.X_WG[:, 2, 0] < -0.49)  # the top-down family, straight down or tilted
    straight = g.X_WG[:, 2, 0] < -0.99
    assert np.any(straight)
    assert np.all(np.abs(g.X_WG[straight, 2, 3] - center[2]) < 0.01)  # pads' middle at the equator
    assert np.all(g.score <= 0.5 + 1e-9)
    # The fallback only serves where nothing passes: a ball seen whole keeps its full scores.
    whole = AntipodalGraspSampler().propose(np.concatenate([ball, cloud]), center)
    assert len(whole) > 0 and whole.score.max() > 0.5
    with pytest.raises(ValueError, match="unchecked_normals_score_scale"):
        AntipodalGraspConfig(unchecked_normals_score_scale=0.0)


def test_a_bag_of_marbles_is_grasped_with_the_rough_surface_band() -> None:
    """The YCB bag of marbles on a table, seen once by the head camera: its
    sensed surface is a heap of 2 cm bumps, so the points within
    ``contact_band`` of its extremes along any closing axis are one bump's
    cap, never across the pads' middle, and the first-contact test rejects
    every grasp. The rough-surface fallback takes the first contacts within
    ``rough_contact_band`` instead, at a lower score."""
    asset = load_ycb_asset("marbles_a")
    X_WO = RigidTransform(RollPitchYaw(0.0, 0.0, 0.0), [0.0, 0.0, TABLE_Z - asset.bounds_O[0, 2]])
    intrinsics = CameraIntrinsics.from_config(HeadCameraConfig())
    renderer = ShapeDepthRenderer(intrinsics, [(Mesh(str(asset.visual_path)), X_WO),
                                               (Box(0.6, 0.5, 0.05), RigidTransform([0.0, 0.0, TABLE_Z - 0.025]))])
    p_WT = X_WO.translation()
    p_WC = p_WT + np.array([0.9 * np.cos(0.3), 0.9 * np.sin(0.3), 0.0])
    p_WC[2] = 1.3
    cloud = observe(renderer, DepthBackProjector(intrinsics, DepthToPointsConfig()), [look_at(p_WC, p_WT)], 0.001,
                    np.random.default_rng(0))
    cloud = cloud[np.linalg.norm(cloud - p_WT, axis=1) <= 0.3]
    without = AntipodalGraspSampler().propose(cloud, p_WT)
    assert len(without) == 0 and "no finger clearance" in without.failure_reason
    rough = AntipodalGraspConfig(rough_contact_band=0.01)
    g = AntipodalGraspSampler(rough).propose(cloud, p_WT)
    assert len(g) > 0, g.failure_reason
    # The policy's grasp source has the level on; the sampler's own default
    # (the grasp trials') has it off.
    policy = AntipodalGraspSampler(SubgoalPipelineConfig().grasps).propose(cloud, p_WT)
    np.testing.assert_array_equal(policy.X_WG, g.X_WG)
    _assert_valid_frames(g)
    assert np.all(g.score <= rough.rough_surface_score_scale + 1e-9)
    assert np.all(g.width <= GRIPPER_MAX_OPENING)
    with pytest.raises(ValueError, match="rough_surface_score_scale"):
        AntipodalGraspConfig(rough_surface_score_scale=0.0)


def test_low_brick_gets_top_down_grasps_along_its_axes() -> None:
    """A 6.4 x 3.2 x 2 cm brick on a table, turned 0.5 rad (a Lego
    brick): the top-down family closes across its short and its long side,
    fingertips above the table, where the antipodal pairs alone find few."""
    z_table = 0.94
    center = np.array([0.0, 0.0, z_table + 0.01])
    brick = clouds.box_cloud(center=center, size=(0.064, 0.032, 0.02), yaw=0.5, noise=0.001, seed=5)
    cloud = np.concatenate([brick, clouds.table_top_cloud(z=z_table, size=0.5, spacing=0.005)])
    g = AntipodalGraspSampler().propose(cloud, center)
    _assert_valid_frames(g)
    down = g.X_WG[:, 2, 0] < -0.999
    assert down.sum() >= 2, g.failure_reason
    closing = np.abs(np.arctan2(g.X_WG[down, 1, 1], g.X_WG[down, 0, 1]) - 0.5) % np.pi
    across = np.minimum(closing, np.pi - closing)  # 0: along the long side, pi/2: across it
    assert np.any(across < 0.05) and np.any(np.abs(across - np.pi / 2) < 0.05)
    tips = g.X_WG[down, :3, 3] + 0.031 * g.X_WG[down, :3, 0]
    assert np.all(tips[:, 2] > z_table)
    pairs_only = AntipodalGraspSampler(AntipodalGraspConfig(top_down_yaws=0)).propose(cloud, center)
    assert np.count_nonzero(pairs_only.X_WG[:, 2, 0] < -0.999) < down.sum()


def _pad_coverage(X_WG: np.ndarray, center: np.ndarray, yaw: float, half: float) -> np.ndarray:
    """Per grasp: the largest fraction of the pad's width (z of G, 2.6 cm) that
    lies over a cube (centre, yaw, half size), over contact depths 0-2 cm."""
    c, s_ = np.cos(yaw), np.sin(yaw)
    R_WB = np.array([[c, -s_, 0.0], [s_, c, 0.0], [0.0, 0.0, 1.0]])
    z = np.linspace(-0.013, 0.013, 9)
    best = np.zeros(len(X_WG))
    for depth in (0.0, 0.01, 0.02):
        p = (X_WG[:, None, :3, 3] + depth * X_WG[:, None, :3, 0] + z[None, :, None] * X_WG[:, None, :3, 2])
        p_B = (p - center) @ R_WB
        best = np.maximum(best, np.mean(np.all(np.abs(p_B) <= half + 0.002, axis=2), axis=1))
    return best


def test_no_grasp_holds_a_cube_with_half_a_pad() -> None:
    """Grasps on a 5.7 cm cube keep most of each pad's width over the cube
    (with the pads' middle 2.9 cm off the cube's centre, on its edge, they
    close on air); without the pad-balance test some grasps hang over the edge."""
    yaw, half = 0.3, 0.0285
    cube = clouds.box_cloud(center=CENTER, size=(2 * half,) * 3, yaw=yaw, n=3000, noise=0.0005, seed=5)
    center = CENTER + np.array([0.0, 0.0, half])
    cloud = np.concatenate([cube, _table()])
    g = AntipodalGraspSampler(AntipodalGraspConfig(max_candidates=10**6)).propose(cloud, center)
    assert len(g) > 0, g.failure_reason
    assert np.min(_pad_coverage(g.X_WG, center, yaw, half)) >= 0.6

    # The mechanism itself: a top-down grasp across the cube, its pads' middle
    # over the centre is kept; shifted 2.9 cm sideways (over the edge) it is not.
    sampler = AntipodalGraspSampler()
    R = np.array([[0.0, 0.0, 1.0], [0.0, 1.0, 0.0], [-1.0, 0.0, 0.0]])  # x down, y across
    R = np.array([[np.cos(yaw), -np.sin(yaw), 0.0], [np.sin(yaw), np.cos(yaw), 0.0], [0.0, 0.0, 1.0]]) @ R
    X = np.tile(np.eye(4), (2, 1, 1))
    X[:, :3, :3] = R
    X[0, :3, 3] = center + np.array([0.0, 0.0, 0.01])
    X[1, :3, 3] = X[0, :3, 3] + 0.029 * R[:, 2]
    sampler._margin = sampler.config.margin
    assert sampler._clearance_ok(cube, X, np.full(2, 2 * half)).tolist() == [True, False]
    sampler.config.min_pad_span = 0.0
    assert sampler._clearance_ok(cube, X, np.full(2, 2 * half)).tolist() == [True, True]


def _top_down(yaw: float, origin: np.ndarray) -> np.ndarray:
    """A top-down grasp frame (x down) with the closing axis at `yaw`."""
    X = np.eye(4)
    c, s_ = np.cos(yaw), np.sin(yaw)
    X[:3, 0] = [0.0, 0.0, -1.0]
    X[:3, 1] = [c, s_, 0.0]
    X[:3, 2] = np.cross(X[:3, 0], X[:3, 1])
    X[:3, 3] = origin
    return X


def _first_contacts_ok(cloud: np.ndarray, X: np.ndarray, width: float) -> bool:
    from vamg_drake.policy.grasp_candidates import estimate_normals

    sampler = AntipodalGraspSampler()
    sampler._margin, sampler._spacing = sampler.config.margin, 0.004
    normals, _ = estimate_normals(cloud, sampler.config.normal_neighbours)
    return bool(sampler._clearance_ok(cloud, X[None], np.array([width]), normals)[0])


def test_first_contacts_of_the_closing_pads_decide():
    """Flat pads touch an object first at its extremes along the closing axis:
    a cube closed across its faces is held; closed 40 deg off them the pads
    first meet two vertical edges (normals far outside the friction cone); a
    ball whose equator lies beyond the fingertips is touched at the tips only."""
    half = 0.03
    cube = clouds.box_cloud(center=CENTER, size=(2 * half,) * 3, yaw=0.0, n=4000, seed=6)
    origin = CENTER + np.array([0.0, 0.0, 2 * half + 0.031 - 0.03])  # fingertips 3 cm down the cube's sides
    assert _first_contacts_ok(cube, _top_down(0.0, origin), 2 * half)
    assert not _first_contacts_ok(cube, _top_down(np.deg2rad(40.0), origin), 2 * half * np.sqrt(2))
    r = 0.025
    center = np.array([1.0, 0.0, 1.0])
    ball = clouds.sphere_cloud(center, r, n=4000, seed=7)
    ball = ball[ball[:, 2] > center[2] - 0.9 * r]
    mid = _top_down(0.0, center)  # equator at the pads' middle
    assert _first_contacts_ok(ball, mid, 2 * r)
    short = _top_down(0.0, center + np.array([0.0, 0.0, 0.036]))  # equator 5 mm beyond the fingertips
    assert not _first_contacts_ok(ball, short, 2 * r * 0.9)


def _assert_valid_frames(g: GraspCandidates) -> None:
    R = g.X_WG[:, :3, :3]
    np.testing.assert_allclose(R @ np.swapaxes(R, 1, 2), np.broadcast_to(np.eye(3), R.shape), atol=1e-9)
    np.testing.assert_allclose(np.linalg.det(R), 1.0, atol=1e-9)


@pytest.mark.parametrize("name", ["can", "box", "mug"])
@pytest.mark.parametrize("with_table", [False, True])
def test_finds_grasps_on_objects(name: str, with_table: bool) -> None:
    obj = _objects()[name]
    cloud = np.concatenate([obj, _table()]) if with_table else obj
    target = obj.mean(axis=0)
    g = AntipodalGraspSampler().propose(cloud, target, np.random.default_rng(0))
    assert len(g) > 0, g.failure_reason
    _assert_valid_frames(g)
    assert np.all(g.width > 0) and np.all(g.width <= GRIPPER_MAX_OPENING)
    # The grasp-frame origin (mid pads) lies near the target, inside the object's
    # extent up to the largest contact offset (the gripper held back).
    back = max(AntipodalGraspConfig().contact_offsets)
    assert np.all(np.linalg.norm(g.X_WG[:, :3, 3] - target, axis=1) <= 0.10 + back + 1e-9)
    lo, hi = obj.min(axis=0) - 0.01 - back, obj.max(axis=0) + 0.01 + back
    assert np.all((g.X_WG[:, :3, 3] >= lo) & (g.X_WG[:, :3, 3] <= hi))
    if with_table:
        # Nothing approaches from below the table top.
        assert np.all(g.X_WG[:, 2, 0] < 0.5)


def test_can_width_matches_diameter() -> None:
    can = clouds.can_cloud(center=CENTER, radius=0.033, seed=4)
    g = AntipodalGraspSampler().propose(can, can.mean(axis=0))
    side = np.abs(g.X_WG[:, 2, 1]) < 0.2  # closing axis horizontal: across the can
    assert side.any()
    np.testing.assert_allclose(np.median(g.width[side]), 0.066, atol=0.004)


def test_no_grasp_on_wall_patch() -> None:
    wall = clouds.wall_patch_cloud(center=(2.0, 0.0, 1.0), normal=(-1.0, 0.0, 0.0), noise=0.001, seed=5)
    g = AntipodalGraspSampler().propose(wall, np.array([2.0, 0.0, 1.0]))
    assert len(g) == 0
    assert "antipodal" in g.failure_reason or "clearance" in g.failure_reason


def test_object_too_wide_has_no_grasp() -> None:
    box = clouds.box_cloud(center=CENTER, size=(0.2, 0.25, 0.2), seed=6)
    g = AntipodalGraspSampler().propose(box, box.mean(axis=0))
    assert len(g) == 0


@pytest.mark.parametrize("n_points", [0, 5])
def test_empty_or_tiny_cloud_gives_reason(n_points: int) -> None:
    cloud = clouds.can_cloud(center=CENTER, n=max(n_points, 1))[:n_points]
    g = AntipodalGraspSampler().propose(cloud, CENTER)
    assert len(g) == 0
    assert "too few observed points" in g.failure_reason


def test_nan_target_gives_reason() -> None:
    g = AntipodalGraspSampler().propose(_objects()["can"], np.array([np.nan, 0.0, 0.0]))
    assert len(g) == 0 and "not finite" in g.failure_reason


def test_config_validation_names_field() -> None:
    with pytest.raises(ValueError, match="friction_coefficient"):
        AntipodalGraspConfig(friction_coefficient=0.0)


# --- ranking ---------------------------------------------------------------


def _poses(t: np.ndarray, yaw: np.ndarray) -> np.ndarray:
    X = np.tile(np.eye(4), (len(t), 1, 1))
    X[:, 0, 0] = X[:, 1, 1] = np.cos(yaw)
    X[:, 0, 1], X[:, 1, 0] = -np.sin(yaw), np.sin(yaw)
    X[:, :3, 3] = t
    return X


def test_pose_distance_metric() -> None:
    X = _poses(np.array([[0, 0, 0], [0.3, 0.4, 0]]), np.array([0.0, np.pi / 2]))
    np.testing.assert_allclose(pose_distance(X[0], X[1], 0.1), 0.5 + 0.1 * np.pi / 2)


def test_fps_starts_at_best_and_spreads() -> None:
    rng = np.random.default_rng(0)
    # Two tight clusters and one outlier: FPS picks one of each first.
    t = np.concatenate([rng.normal(0, 0.002, (10, 3)), rng.normal(1, 0.002, (10, 3)), [[0, 2, 0]]])
    X = _poses(t, np.zeros(21))
    score = np.zeros(21)
    score[3] = 1.0
    idx = farthest_pose_sampling(X, score, 3)
    assert idx[0] == 3
    assert {int(i) // 10 for i in idx} == {0, 1, 2}


def test_proximity_score_is_tiebreaker() -> None:
    s = proximity_weighted_score(np.array([0.8, 0.8, 0.9]), np.array([[1, 0, 0], [0.1, 0, 0], [2, 0, 0]]), np.zeros(3))
    assert np.argmax(s) == 2 and s[1] > s[0]


def test_pregrasp_is_back_along_approach() -> None:
    X = _poses(np.array([[1.0, 0, 0]]), np.array([np.pi / 2]))
    P = pregrasp_poses(X, 0.05)
    np.testing.assert_allclose(P[0, :3, 3], [1.0, -0.05, 0.0], atol=1e-12)


def test_rank_and_select_with_capability_ik_and_collision() -> None:
    t = np.array([[0.5, 0.0, 0.8], [0.6, 0.1, 0.8], [3.0, 0.0, 0.8], [0.55, -0.1, 0.8]])
    cands = GraspCandidates(_poses(t, np.zeros(4)), np.array([0.9, 0.8, 0.99, 0.7]), np.full(4, 0.05))
    reachable = lambda X_BG: np.linalg.norm(X_BG[:, :3, 3], axis=1) < 1.5  # noqa: E731
    order, n_reach = rank_grasps(cands, np.eye(4), np.zeros(3), reachable, GraspRankingConfig())
    assert n_reach == 3 and 2 not in order.tolist()

    calls = []

    def fake_arm_ik(X_WG: np.ndarray, q_seed: np.ndarray):
        calls.append(len(X_WG))
        q = np.tile(np.broadcast_to(q_seed, (len(X_WG), 11))[0], (len(X_WG), 1)).astype(float)
        q[:, 4:7] = X_WG[:, :3, 3]
        return q, X_WG[:, 1, 3] > -0.05  # the grasp at y=-0.1 is "unreachable"

    def is_free(q: np.ndarray) -> np.ndarray:
        return q[:, 5] < 0.05  # configurations reaching y >= 0.05 "collide"

    goal = select_grasp_goal(cands, np.zeros(11), np.eye(4), np.zeros(3), fake_arm_ik, is_free, reachable)
    assert goal.success, goal.failure_reason
    assert goal.candidate_index == 0
    np.testing.assert_allclose(goal.X_WG, cands.X_WG[0])
    np.testing.assert_allclose(goal.q_pregrasp[4:7], [0.45, 0.0, 0.8])

    none = select_grasp_goal(cands, np.zeros(11), np.eye(4), np.zeros(3), fake_arm_ik, lambda q: np.zeros(len(q), bool), reachable)
    assert not none.success and "collision" in none.failure_reason
    empty = select_grasp_goal(GraspCandidates.empty("no points"), np.zeros(11), np.eye(4), np.zeros(3), fake_arm_ik, is_free, None)
    assert not empty.success and "no points" in empty.failure_reason

    # The capability map rejecting every candidate leaves the decision to IK,
    # unless the fallback is off.
    nowhere = lambda X_BG: np.zeros(len(X_BG), bool)  # noqa: E731
    order, n_reach = rank_grasps(cands, np.eye(4), np.zeros(3), nowhere, GraspRankingConfig())
    assert n_reach == 0 and sorted(order.tolist()) == [0, 1, 2, 3]
    assert rank_grasps(cands, np.eye(4), np.zeros(3), nowhere, GraspRankingConfig(ik_when_unreachable=False))[0].size == 0
    goal = select_grasp_goal(cands, np.zeros(11), np.eye(4), np.zeros(3), fake_arm_ik, is_free, nowhere)
    assert goal.success and goal.num_reachable == 0
    unreachable = select_grasp_goal(cands, np.zeros(11), np.eye(4), np.zeros(3),
                                    lambda X, q: (np.zeros((len(X), 11)), np.zeros(len(X), bool)), is_free, nowhere)
    assert not unreachable.success and "capability map calls none reachable" in unreachable.failure_reason


def test_other_arm_solutions_are_tried_when_the_seeded_ones_collide() -> None:
    """The real IK: where the arm configuration found from the current seed
    collides (here: any elbow position near the seeded solution's), another
    solution reaching the same grasp is found from random arm seeds; without
    the extra rounds the grasp is refused."""
    from vamg_drake.policy.ik import FastIk
    from vamg_drake.robot.kinematics import FetchKinematics

    kin = FetchKinematics.instance()
    q0 = layout.stow_configuration(0.0, 0.0, 0.0)
    q0[layout.TORSO] = 0.2
    X_grasp = np.eye(4)
    X_grasp[:3, 3] = [0.75, 0.0, 0.9]  # a horizontal grasp in front of the robot
    cands = GraspCandidates(X_grasp[None], np.ones(1), np.full(1, 0.05))
    q_seeded, ok = FastIk().solve_arm(pregrasp_poses(X_grasp[None], 0.05), q0)
    assert ok[0]
    elbow = lambda q: np.atleast_3d(kin.frame_pose("elbow_flex_link", q))[..., :3, 3]  # noqa: E731
    p_elbow = elbow(q_seeded)[0]

    def is_free(q: np.ndarray) -> np.ndarray:  # a post where the seeded elbow goes
        return np.linalg.norm(elbow(q) - p_elbow, axis=-1) > 0.15

    args = (cands, q0, np.eye(4), np.zeros(3), FastIk().solve_arm, is_free, None)
    refused = select_grasp_goal(*args, GraspRankingConfig(ik_alternatives=0))
    assert not refused.success and "collision" in refused.failure_reason
    goal = select_grasp_goal(*args, GraspRankingConfig(ik_alternatives=3), rng=np.random.default_rng(1))
    assert goal.success, goal.failure_reason
    assert is_free(goal.q_pregrasp[None])[0]
    np.testing.assert_allclose(kin.gripper_pose(goal.q_grasp)[:3, 3], X_grasp[:3, 3], atol=0.003)
    np.testing.assert_array_equal(goal.q_grasp[:4], q0[:4])  # base and torso unchanged
    with pytest.raises(ValueError, match="ik_alternatives"):
        GraspRankingConfig(ik_alternatives=-1)


def test_a_grasp_under_an_overhang_is_pulled_out_before_the_lift() -> None:
    """The real IK: a horizontal grasp under a board 10 cm above the gripper
    cannot lift in place; pulled 12 cm back out from under the board it can,
    and a grasp from above (nowhere to pull to) is refused."""
    from vamg_drake.policy.ik import FastIk
    from vamg_drake.robot.kinematics import FetchKinematics

    kin = FetchKinematics.instance()
    q0 = layout.stow_configuration(0.0, 0.0, 0.0)
    q0[layout.TORSO] = 0.2
    X_grasp = np.eye(4)
    X_grasp[:3, 3] = [0.75, 0.0, 0.8]  # approach along +x of the base
    cands = GraspCandidates(X_grasp[None], np.ones(1), np.full(1, 0.05))
    board_x = 0.68  # the board covers x >= 0.68 from z = 0.9 up

    def is_free(q: np.ndarray) -> np.ndarray:
        p = kin.gripper_pose(np.atleast_2d(q))[:, :3, 3]
        return ~((p[:, 0] >= board_x) & (p[:, 2] + 0.04 >= 0.9))  # the gripper's top against the board

    config = GraspRankingConfig(check_grasp_collision=True, ik_alternatives=0)
    args = (cands, q0, np.eye(4), np.zeros(3), FastIk().solve_arm, is_free, None)
    in_place = select_grasp_goal(*args, dc.replace(config, pull_distance=0.0), lift_height=0.15)
    assert not in_place.success and "collision" in in_place.failure_reason
    goal = select_grasp_goal(*args, config, lift_height=0.15)
    assert goal.success and goal.q_pull is not None and goal.lift_height >= config.min_lift_height
    p_pull = kin.gripper_pose(goal.q_pull)[:3, 3]
    np.testing.assert_allclose(p_pull, X_grasp[:3, 3] + [-config.pull_distance, 0.0, config.pull_raise], atol=0.003)
    assert p_pull[0] < board_x
    np.testing.assert_array_equal(goal.q_pull[:4], goal.q_grasp[:4])  # base and torso: the grasp's
    free_everywhere = select_grasp_goal(cands, q0, np.eye(4), np.zeros(3), FastIk().solve_arm,
                                        lambda q: np.ones(len(q), bool), None, config, lift_height=0.15)
    assert free_everywhere.success and free_everywhere.q_pull is None  # lifts in place where it can
    X_down = np.eye(4)
    X_down[:3, :3] = [[0, 0, 1], [0, 1, 0], [-1, 0, 0]]  # approach straight down
    X_down[:3, 3] = [0.75, 0.0, 0.85]
    down = GraspCandidates(X_down[None], np.ones(1), np.full(1, 0.05))
    assert not select_grasp_goal(down, *args[1:], config, lift_height=0.15).success


@pytest.mark.parametrize("voxel", [0.01, 0.02])
def test_map_resolution_clouds(voxel: float) -> None:
    """Clouds thinned to the map's voxel size still give grasps on objects, none on a wall."""
    from vamg_drake.policy.grasp_candidates import voxel_downsample

    table = clouds.table_top_cloud(z=TABLE_Z, center_xy=CENTER[:2], size=0.6, spacing=voxel)
    for name, obj in _objects().items():
        cloud = voxel_downsample(np.concatenate([obj, table]), voxel)
        assert len(AntipodalGraspSampler().propose(cloud, obj.mean(axis=0))) > 0, (name, voxel)
    wall = voxel_downsample(clouds.wall_patch_cloud(center=(2.0, 0.0, 1.0), normal=(-1, 0, 0), noise=0.002), voxel)
    assert len(AntipodalGraspSampler().propose(wall, np.array([2.0, 0.0, 1.0]))) == 0


def test_approach_interpolants_are_checked() -> None:
    t = np.array([[0.5, 0.0, 0.8], [0.6, 0.1, 0.8]])
    cands = GraspCandidates(_poses(t, np.zeros(2)), np.array([0.9, 0.8]), np.full(2, 0.05))

    def ik(X_WG: np.ndarray, q_seed: np.ndarray):
        q = np.zeros((len(X_WG), 11))
        q[:, 4:7] = X_WG[:, :3, 3]
        return q, np.ones(len(X_WG), bool)

    def blocked_mid_approach(q: np.ndarray) -> np.ndarray:
        return ~((q[:, 4] > 0.46) & (q[:, 4] < 0.49))  # between candidate 0's pre-grasp and grasp

    args = (np.zeros(11), np.eye(4), np.zeros(3), ik, blocked_mid_approach, None)
    assert select_grasp_goal(cands, *args, GraspRankingConfig()).candidate_index == 0
    assert select_grasp_goal(cands, *args, GraspRankingConfig(check_grasp_collision=True)).candidate_index == 1


def test_lift_after_the_grasp_is_checked() -> None:
    """A grasp whose torso lift rises into something overhanging is passed over
    for one whose whole lift is free; a lift that is free only part of the way
    is given that part when it is high enough, and refused when it is not."""
    t = np.array([[0.5, 0.0, 0.8], [0.6, 0.1, 0.8]])
    cands = GraspCandidates(_poses(t, np.zeros(2)), np.array([0.9, 0.8]), np.full(2, 0.05))

    def ik(X_WG: np.ndarray, q_seed: np.ndarray):
        q = np.zeros((len(X_WG), 11))
        q[:, 3] = 0.1
        q[:, 4:7] = X_WG[:, :3, 3]
        return q, np.ones(len(X_WG), bool)

    def overhang(above_0: float, above_1: float):
        """Candidate 0's arm hits something above torso `above_0`, candidate 1's above `above_1`."""
        def is_free(q: np.ndarray) -> np.ndarray:
            limit = np.where(np.abs(q[:, 5]) < 0.01, above_0, above_1)
            return q[:, 3] <= limit + 1e-9
        return is_free

    checked = GraspRankingConfig(check_grasp_collision=True)

    def select(is_free, lift_height, config=checked):
        return select_grasp_goal(cands, np.zeros(11), np.eye(4), np.zeros(3), ik, is_free, None, config,
                                 lift_height=lift_height)

    low_over_0 = overhang(0.2, 1.0)  # candidate 0 may rise 0.10 m, candidate 1 all the way
    unchecked = select(low_over_0, 0.0)
    assert unchecked.candidate_index == 0 and unchecked.lift_height is None  # no lift given: not checked
    short = select(low_over_0, 0.06)
    assert short.candidate_index == 0 and short.lift_height == pytest.approx(0.06)
    full = select(low_over_0, 0.15)
    assert full.candidate_index == 1 and full.lift_height == pytest.approx(0.15)
    # Only part of the way for both: the first high enough gets its highest free height.
    partial = select(overhang(0.1 + 0.125, 0.1 + 0.13), 0.15)
    assert partial.candidate_index == 0 and partial.lift_height == pytest.approx(0.12)
    assert not select(overhang(0.2, 0.2), 0.15).success  # 0.09 m for both: too low
    assert select(low_over_0, 0.15, GraspRankingConfig(check_grasp_collision=True, lift_checks=0)).candidate_index == 0
    # A torso near its upper limit lifts only what is left: too little is refused.
    def ik_high(X_WG: np.ndarray, q_seed: np.ndarray):
        q, ok = ik(X_WG, q_seed)
        q[:, 3] = layout.Q_UPPER[3] - 0.13 + 0.1 * (np.abs(q[:, 5]) < 0.01)  # candidate 0: 3 cm left, 1: 13 cm
        return q, ok

    high = select_grasp_goal(cands, np.zeros(11), np.eye(4), np.zeros(3), ik_high, overhang(1.0, 1.0), None, checked,
                             lift_height=0.15)
    assert high.candidate_index == 1 and high.lift_height == pytest.approx(0.13)
    # The lift the behaviour executes: the torso up, clamped at its limit, the arm as it was.
    q = np.zeros(11)
    q[3], q[4] = 0.3, 1.0
    lifted = layout.raised_torso(q, 0.15)
    assert lifted[3] == layout.Q_UPPER[3] and lifted[4] == 1.0 and q[3] == 0.3
    with pytest.raises(ValueError, match="min_lift_height"):
        GraspRankingConfig(min_lift_height=float("nan"))


def test_verify_rechecks_earlier_grasps_on_a_new_cloud() -> None:
    """A grasp proposed from one view passes `verify` on a new view of the same
    can (other points, other noise); a box in its finger sweep makes it fail."""
    sampler = AntipodalGraspSampler()
    can = clouds.can_cloud(center=CENTER, radius=0.033, seed=4)
    target = can.mean(axis=0)
    g = sampler.propose(np.concatenate([can, _table()]), target, np.random.default_rng(0))
    assert len(g) > 10
    other_view = np.concatenate([clouds.can_cloud(center=CENTER, radius=0.033, seed=9, noise=0.0005), _table()])
    again = sampler.verify(other_view, target, g.X_WG[:10], g.width[:10])
    assert again.mean() >= 0.7
    # A block of points where the first grasp's fingers open (the +y pad's outside).
    X = g.X_WG[0]
    pad = X[:3, 3] + X[:3, 1] * (0.5 * GRIPPER_MAX_OPENING + 0.004)
    block = pad + np.random.default_rng(1).uniform(-0.006, 0.006, (200, 3))
    assert not sampler.verify(np.concatenate([other_view, block]), target, X[None], g.width[:1])[0]
    # Too few points near the target: nothing verifies.
    assert not sampler.verify(_table(), target, g.X_WG[:3], g.width[:3]).any()


def _dense_antipodal_pairs(points, normals, seeds, line_tolerance, min_width, max_width, cos_cone) -> np.ndarray:
    """The pair search written out over all (seed, point) pairs at once: the definition the kernel must match."""
    offset = points[None, :, :] - points[seeds, None, :]
    dist = np.linalg.norm(offset, axis=2)
    along = np.einsum("snk,sk->sn", offset, normals[seeds])
    perp = np.sqrt(np.maximum(dist**2 - along**2, 0.0))
    with np.errstate(invalid="ignore", divide="ignore"):
        cos_j = np.abs(np.einsum("snk,nk->sn", offset / dist[:, :, None], normals))
    valid = ((perp <= line_tolerance) & (dist >= min_width) & (dist <= max_width)
             & (np.abs(along) >= cos_cone * dist) & (cos_j >= cos_cone))
    s, n = np.nonzero(valid)
    width_bin = np.floor(dist[s, n] / 0.01).astype(np.int64)
    _, first = np.unique(np.stack([s, width_bin], 1), axis=0, return_index=True)
    return np.stack([seeds[s[first]], n[first]], axis=1)


@pytest.mark.parametrize("name", ["can", "mug", "box"])
def test_antipodal_pair_kernel_matches_the_dense_search(name: str) -> None:
    from vamg_drake.policy.grasp_candidates import _antipodal_pair_kernel

    cloud = np.concatenate([_table(), _objects()[name]])
    sampler = AntipodalGraspSampler()
    p_WT = _objects()[name].mean(axis=0)
    crop, near = sampler._crop(cloud, p_WT)
    normals = sampler._prepare(crop)
    normals[5] = np.nan  # a degenerate normal fails every test
    seeds = np.random.default_rng(0).choice(np.flatnonzero(near), size=120, replace=False)
    args = (0.004, 0.004, 0.092, float(np.cos(np.arctan(0.4))))
    expected = _dense_antipodal_pairs(crop, normals, seeds, *args)
    pairs = _antipodal_pair_kernel(crop, normals, seeds, *args)
    assert len(expected) > 20
    np.testing.assert_array_equal(pairs, expected)


def test_the_palm_keeps_the_margin_from_a_table() -> None:
    """A side grasp of a block on a table: the palm's lower face 2 mm above
    the table top is too close (the 4 mm margin), 6 mm above it is clear."""
    from vamg_drake.policy.grasp_candidates import _frames_from_axes

    g = np.arange(-0.3, 0.3001, 0.005)
    table = np.stack(np.meshgrid(g, g, [0.0], indexing="ij"), -1).reshape(-1, 3)
    xs, zs = np.arange(-0.02, 0.0201, 0.004), np.arange(0.0, 0.0801, 0.004)
    faces = [np.stack(np.meshgrid(xs, [y], zs, indexing="ij"), -1).reshape(-1, 3) for y in (-0.03, 0.03)]
    cloud = np.concatenate([table, *faces])
    sampler = AntipodalGraspSampler()
    half_palm = sampler.config.gripper.palm_height / 2

    def clear(height: float) -> bool:
        X = _frames_from_axes(np.array([[1.0, 0, 0]]), np.array([[0, 1.0, 0]]), np.array([[0, 0, height]]))
        return bool(sampler._clearance_ok(cloud, X, np.array([0.06]))[0])

    assert not clear(half_palm + 0.002)
    assert clear(half_palm + 0.006)


def _low_can_at_a_table_edge(z_table: float, spacing: float = 0.003) -> np.ndarray:
    """The points of a tuna can (8.6 cm across, 3.3 cm high) standing at the
    +x edge of a table top, as a map of several views holds them: the top
    face, the side facing -x, and the table top up to its edge 2 mm behind
    the can, except under the can."""
    radius, height = 0.043, 0.033
    g = np.arange(-0.3, 0.3 + 1e-9, spacing)
    xy = np.stack(np.meshgrid(g, g, indexing="ij"), -1).reshape(-1, 2)
    top = xy[np.linalg.norm(xy, axis=1) <= radius]
    top = np.column_stack([top, np.full(len(top), z_table + height)])
    a, z = np.meshgrid(np.linspace(0, 2 * np.pi, 90, endpoint=False), np.arange(spacing, height, spacing))
    side = np.column_stack([radius * np.cos(a.ravel()), radius * np.sin(a.ravel()), z_table + z.ravel()])
    side = side[side[:, 0] < 0.0]
    table = xy[(np.linalg.norm(xy, axis=1) > radius) & (xy[:, 0] <= radius + 0.002)]
    return np.concatenate([top, side, np.column_stack([table, np.full(len(table), z_table)])])


def test_the_gripper_stays_above_the_support_of_a_low_object() -> None:
    """A low can at a table edge: its top face and the table top beside it
    have parallel normals and look antipodal, and approached from beyond the
    edge such a grasp meets no point. But its lower finger would pass
    through the table under the can: no candidate's open fingers or palm
    reach below the table top, and every contact lies on the can."""
    z_table = 0.94
    cloud = _low_can_at_a_table_edge(z_table)
    center = np.array([0.0, 0.0, z_table + 0.0165])
    g = AntipodalGraspSampler().propose(cloud, center)
    assert len(g) > 0, g.failure_reason
    _assert_valid_frames(g)
    lowest = gripper_lowest_z(g.X_WG, GripperGeometry(), AntipodalGraspConfig().approach_distance)
    assert np.all(lowest > z_table), np.round(np.sort(lowest)[:5], 3)
    # Straight down, the fingertips are the lowest point.
    down = _top_down(0.3, np.array([0.0, 0.0, 1.0]))
    assert gripper_lowest_z(down[None], GripperGeometry(), 0.05)[0] == pytest.approx(1.0 - GripperGeometry().fingertip_x)
    # Every contact lies on the can, none on the table beside it.
    contacts = g.X_WG[:, None, :3, 3] + np.array([-0.5, 0.5])[None, :, None] * (
        g.width[:, None, None] * g.X_WG[:, None, :3, 1])
    assert np.all(contacts[..., 2] > z_table + 0.005)


def _single_view_brick(z_table: float, size: tuple[float, float, float], yaw: float) -> tuple[np.ndarray, np.ndarray]:
    """(cloud, centre) of a brick on a table as one view from its -x side sees
    it: its top and that side face, and the table top but for the brick's
    footprint and its shadow behind it."""
    center = np.array([0.0, 0.0, z_table])
    brick = clouds.box_cloud(center=center, size=size, yaw=yaw, n=4000, noise=0.0005, seed=8)
    c, s_ = np.cos(yaw), np.sin(yaw)
    R_WB = np.array([[c, -s_, 0.0], [s_, c, 0.0], [0.0, 0.0, 1.0]])
    half = 0.5 * np.asarray(size)
    p_B = (brick - center) @ R_WB
    seen = (p_B[:, 2] >= size[2] - 1e-3) | (p_B[:, 0] <= -half[0] + 1e-3)
    table = clouds.table_top_cloud(z=z_table, size=0.5, spacing=0.004)
    t_B = (table - center) @ R_WB
    hidden = (t_B[:, 0] >= -half[0] - 0.004) & (t_B[:, 0] <= half[0] + 0.05) & (np.abs(t_B[:, 1]) <= half[1] + 0.004)
    return np.concatenate([brick[seen], table[~hidden]]), center + np.array([0.0, 0.0, half[2]])


def test_a_brick_seen_from_one_side_gets_top_down_grasps() -> None:
    """One view of a 4 x 3 x 3.5 cm brick shows its top and its near side; its
    far side is hidden, where the top face's edge is the outermost point the
    far pad meets. Those top-face points (normals along the approach) are left
    out of the first-contact test (``facing_approach_cos`` 0.866, as the grasp
    trials run), so the top-down grasps across the brick are kept; testing
    them (the default: as if the top's edge were the face touched) leaves none,
    and the default's fallback without the normals keeps them at half score."""
    cloud, center = _single_view_brick(0.72, (0.04, 0.03, 0.035), 0.3)
    g = AntipodalGraspSampler(AntipodalGraspConfig(facing_approach_cos=0.866)).propose(cloud, center)
    assert len(g) > 0, g.failure_reason
    _assert_valid_frames(g)
    assert np.count_nonzero(g.X_WG[:, 2, 0] < -0.999) >= 2
    every_point = AntipodalGraspSampler(AntipodalGraspConfig(unchecked_normals_fallback=False)).propose(cloud, center)
    assert np.count_nonzero(every_point.X_WG[:, 2, 0] < -0.999) == 0 if len(every_point) else True
    fallback = AntipodalGraspSampler().propose(cloud, center)
    assert np.count_nonzero(fallback.X_WG[:, 2, 0] < -0.999) >= 2
    assert fallback.score.max() <= 0.5 * g.score.max() + 1e-9


def test_a_long_object_is_grasped_top_down_along_its_length() -> None:
    """An 18 x 3.4 x 3.4 cm bar (a banana's size) on a table: top-down grasps
    close across it at slices along its length, each as wide as the bar,
    not only at its middle."""
    z_table, yaw = 0.45, 0.7
    center = np.array([0.0, 0.0, z_table])
    bar = clouds.box_cloud(center=center, size=(0.18, 0.034, 0.034), yaw=yaw, n=5000, noise=0.0005, seed=9)
    cloud = np.concatenate([bar, clouds.table_top_cloud(z=z_table, size=0.5, spacing=0.004)])
    p_WT = center + np.array([0.0, 0.0, 0.017])
    long_axis = np.array([np.cos(yaw), np.sin(yaw), 0.0])

    def across_centres(config: AntipodalGraspConfig) -> np.ndarray:
        g = AntipodalGraspSampler(config).propose(cloud, p_WT)
        down = g.X_WG[:, 2, 0] < -0.999
        across = np.abs(g.X_WG[:, :3, 1] @ long_axis) < 0.05
        return (g.X_WG[down & across, :3, 3] - p_WT) @ long_axis

    along = across_centres(AntipodalGraspConfig(top_down_max_slices=7, max_candidates=10**4))
    assert np.ptp(along) >= 0.1
    # The antipodal pairs spun to a top-down approach add a few of their own.
    middle_only = across_centres(AntipodalGraspConfig(top_down_max_slices=1, max_candidates=10**4))
    assert along.size >= middle_only.size + 6
    with pytest.raises(ValueError, match="top_down_slice_step"):
        AntipodalGraspConfig(top_down_slice_step=0.0)


def test_a_compact_object_gets_tilted_top_down_grasps_above_the_support() -> None:
    """A 5.5 x 5 x 6 cm box (a cup's size) on a table: with
    ``top_down_tilts_deg`` (the default) each straight-down grasp is also proposed tilted
    by 45 and 60 deg about its level closing axis, in both directions, at
    the lower tilted quality, the fingers and the palm above the table."""
    z_table, yaw = 0.64, 0.3
    center = np.array([0.0, 0.0, z_table])
    box = clouds.box_cloud(center=center, size=(0.055, 0.05, 0.06), yaw=yaw, n=5000, noise=0.0005, seed=11)
    cloud = np.concatenate([box, clouds.table_top_cloud(z=z_table, size=0.5, spacing=0.004)])
    p_WT = center + np.array([0.0, 0.0, 0.03])
    config = AntipodalGraspConfig(top_down_tilts_deg=[45.0, 60.0], max_candidates=10**4)
    g = AntipodalGraspSampler(config).propose(cloud, p_WT)
    _assert_valid_frames(g)
    approach_z = g.X_WG[:, 2, 0]
    assert np.count_nonzero(approach_z < -0.999) >= 2, g.failure_reason
    for tilt in (45.0, 60.0):
        # The closing axis stays level (a spun antipodal pair's is level only nearly).
        tilted = (np.abs(approach_z + np.cos(np.radians(tilt))) < 1e-6) & (np.abs(g.X_WG[:, 2, 1]) < 1e-9)
        assert tilted.sum() >= 2
        # Both directions: the approach leans one way and the opposite way.
        lean = g.X_WG[tilted, :2, 0]
        assert np.min(lean @ lean.T) < -0.5 * np.sin(np.radians(tilt)) ** 2
        assert np.all(g.score[tilted] <= 0.7 * config.top_down_tilted_quality + 0.3 + 1e-9)
    assert np.all(gripper_lowest_z(g.X_WG, config.gripper, config.approach_distance) >= z_table)
    straight_only = AntipodalGraspSampler(AntipodalGraspConfig(top_down_tilts_deg=[], max_candidates=10**4)).propose(
        cloud, p_WT)
    assert not np.any(np.abs(straight_only.X_WG[:, 2, 0] + np.cos(np.radians(45.0))) < 1e-6)
    with pytest.raises(ValueError, match="top_down_tilts_deg"):
        AntipodalGraspConfig(top_down_tilts_deg=[90.0])


def test_near_any_grasp_ignores_the_roll_but_not_the_place_or_the_approach() -> None:
    def pose(p, yaw_about_x=0.0, approach=(1.0, 0.0, 0.0)):
        a = np.asarray(approach, float) / np.linalg.norm(approach)
        helper = np.array([0.0, 0.0, 1.0]) if abs(a[2]) < 0.9 else np.array([0.0, 1.0, 0.0])
        y = np.cross(helper, a)
        y /= np.linalg.norm(y)
        z = np.cross(a, y)
        c, s = np.cos(yaw_about_x), np.sin(yaw_about_x)
        X = np.eye(4)
        X[:3, :3] = np.column_stack([a, c * y + s * z, -s * y + c * z])
        X[:3, 3] = p
        return X

    failed = pose([0, 0, 0])[None]
    X = np.stack([
        pose([0.01, 0, 0], yaw_about_x=1.2),            # same place and approach, other roll: near
        pose([0.05, 0, 0]),                             # 5 cm away: not near
        pose([0, 0, 0], approach=(1.0, 0.0, -1.0)),     # approach tilted 45 deg: not near
        pose([0, 0.01, 0], approach=(1.0, 0.0, -0.3)),  # tilted 17 deg: near
    ])
    np.testing.assert_array_equal(near_any_grasp(X, failed, 0.02, np.radians(30)), [True, False, False, True])
    assert near_any_grasp(X, np.zeros((0, 4, 4)), 0.02, 0.5).tolist() == [False] * 4
