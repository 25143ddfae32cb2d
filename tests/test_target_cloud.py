"""The TargetCloud LeafSystem and its grid merge, against brute-force references."""

import numpy as np
import pytest
from pydrake.math import RigidTransform
from pydrake.systems.analysis import Simulator
from pydrake.systems.sensors import ImageDepth32F

from vamg_drake.perception.depth_points import DepthBackProjector
from vamg_drake.robot import layout
from vamg_drake.robot.head_camera import CameraIntrinsics, HeadCameraConfig
from vamg_drake.robot.spheres import SphereModel
from vamg_drake.systems.target_cloud import TargetCloud, TargetCloudConfig, merge_on_grid

K = CameraIntrinsics.from_config(HeadCameraConfig())


def _merge_reference(points: np.ndarray, voxel: float) -> np.ndarray:
    """Newest (last) point of each voxel, in the order of those newest points."""
    newest = {}
    for i, p in enumerate(points):
        newest[tuple(np.floor(p[:3] / voxel).astype(np.int64))] = i
    return points[np.sort(np.fromiter(newest.values(), np.int64))]


@pytest.mark.parametrize("spread", [0.3, 3.0e6])  # the flat-key path, and the row path (> 2^62 cells)
def test_merge_on_grid_keeps_the_newest_point_of_every_voxel(spread: float) -> None:
    rng = np.random.default_rng(3)
    xyz = rng.uniform(-spread, spread, size=(4000, 3)) * [1.0, 0.2, 1.0]  # unequal extents
    xyz = np.concatenate([xyz, xyz[rng.integers(0, 4000, 3000)] + rng.uniform(0, 1e-3, (3000, 3))])
    points = np.c_[xyz, np.arange(len(xyz), dtype=float)]  # the 4th column is the time stamp
    voxel = 0.004 if spread < 1.0 else 1.0
    merged = merge_on_grid(points, voxel)
    np.testing.assert_array_equal(merged, _merge_reference(points, voxel))
    assert len(merged) < len(points)
    assert merge_on_grid(np.zeros((0, 4)), voxel).shape == (0, 4)


def test_target_cloud_keeps_the_surroundings_and_drops_the_robot() -> None:
    """A wall 1 m in front of the camera, the target on it next to the robot's
    gripper: the cloud is the wall within `radius` of the target, minus the
    points within `self_margin` of any robot sphere, on the voxel grid."""
    spheres = SphereModel.load()
    q = layout.stow_configuration(0.0, 0.0, 0.0)
    centers = spheres.world_spheres(q)
    gripper = int(np.argmax(centers[:, 0]))  # the frontmost sphere
    p_WT = centers[gripper] + [0.0, 0.05, 0.0]
    X_WC = np.eye(4)  # optical z along world x: the camera looks at the sphere from 1 m behind it
    X_WC[:3, :3] = [[0, 0, 1], [-1, 0, 0], [0, -1, 0]]
    X_WC[:3, 3] = centers[gripper] - [1.0, 0.0, 0.0]
    depth = np.ones((K.height, K.width), np.float32)
    config = TargetCloudConfig()

    system = TargetCloud(K, config)
    context = system.CreateDefaultContext()
    image = ImageDepth32F(K.width, K.height)
    image.mutable_data[:, :, 0] = depth
    system.GetInputPort("depth_image").FixValue(context, image)
    system.GetInputPort("X_WC").FixValue(context, RigidTransform(X_WC))
    system.GetInputPort("target").FixValue(context, p_WT)
    system.GetInputPort("robot_configuration").FixValue(context, q)
    Simulator(system, context).AdvanceTo(0.05)  # one update at t = 0
    cloud = system.GetOutputPort("target_cloud").Eval(context)

    p_WS = DepthBackProjector(K).points_W(depth, X_WC)
    near = p_WS[np.linalg.norm(p_WS - p_WT, axis=1) <= config.radius]
    d = np.linalg.norm(near[:, None] - centers[None], axis=2) - spheres.radius[None]
    robot = np.any(d <= config.self_margin, axis=1)
    assert robot.sum() > 50, "the test needs wall points on the gripper sphere"
    expected = _merge_reference(np.c_[near[~robot], np.zeros(int((~robot).sum()))], config.voxel_size)[:, :3]
    np.testing.assert_allclose(cloud, expected)
    d_cloud = np.linalg.norm(cloud[:, None] - centers[None], axis=2) - spheres.radius[None]
    assert d_cloud.min() > config.self_margin


def test_target_cloud_keeps_what_is_out_of_view_and_drops_what_the_camera_sees_through() -> None:
    """Points stay while the head looks elsewhere (however long), and go when a
    later image sees past them (the object moved): a wall 1 m ahead is seen,
    the camera turns away for 10 s, turns back and the wall is now 2 m away."""
    p_WT = np.array([1.0, 0.0, 1.0])
    X_WC = np.eye(4)
    X_WC[:3, :3] = [[0, 0, 1], [-1, 0, 0], [0, -1, 0]]  # optical z along world x
    X_WC[:3, 3] = [0.0, 0.0, 1.0]
    X_away = X_WC.copy()
    X_away[:3, :3] = [[0, 0, -1], [1, 0, 0], [0, -1, 0]]  # optical z along world -x
    system = TargetCloud(K, TargetCloudConfig())
    context = system.CreateDefaultContext()
    q = layout.stow_configuration(-3.0, 0.0, 0.0)  # the robot far behind the camera: nothing self-filtered

    def look(X: np.ndarray, depth_m: float, until: float) -> np.ndarray:
        image = ImageDepth32F(K.width, K.height)
        image.mutable_data[:, :, 0] = depth_m
        system.GetInputPort("depth_image").FixValue(context, image)
        system.GetInputPort("X_WC").FixValue(context, RigidTransform(X))
        simulator.AdvanceTo(until)
        return system.GetOutputPort("target_cloud").Eval(context).copy()

    system.GetInputPort("target").FixValue(context, p_WT)
    system.GetInputPort("robot_configuration").FixValue(context, q)
    simulator = Simulator(system, context)
    first = look(X_WC, 1.0, 0.05)
    assert len(first) > 100 and np.allclose(first[:, 0], 1.0, atol=1e-3)
    np.testing.assert_array_equal(look(X_away, 1.0, 10.0), first)  # out of view: kept
    assert len(look(X_WC, 0.95, 10.15)) >= len(first)  # something in front occludes them: kept
    assert len(look(X_WC, 2.0, 10.3)) == 0  # seen through: dropped (the wall at 2 m is beyond `radius`)

