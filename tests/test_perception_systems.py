"""The RayCastMap and GazeOptimizer LeafSystems, stepped by a Simulator."""

import numpy as np
from pydrake.geometry import Box
from pydrake.math import RigidTransform
from pydrake.systems.analysis import Simulator
from pydrake.systems.sensors import ImageDepth32F

from vamg_drake.perception.shape_depth_render import ShapeDepthRenderer
from vamg_drake.planning.motion_messages import PlannedTrajectory
from vamg_drake.planning.trajectory import TimedTrajectory
from vamg_drake.robot import layout
from vamg_drake.robot.head_camera import CameraIntrinsics, HeadCameraConfig
from vamg_drake.robot.kinematics import FetchKinematics
from vamg_drake.systems.gaze_system import GazeOptimizer
from vamg_drake.systems.raycast_map_system import RayCastMap

K = CameraIntrinsics.from_config(HeadCameraConfig())


def _image(depth: np.ndarray) -> ImageDepth32F:
    image = ImageDepth32F(K.width, K.height)
    image.mutable_data[:, :, 0] = depth
    return image


def test_raycast_map_system_maps_and_rejects_nan_inputs(caplog):
    q = layout.stow_configuration(0.0, 0.0, 0.0)
    X_WC = FetchKinematics.instance().camera_pose(q, 0.0, 0.6)
    shapes = [(Box(12, 12, 0.1), RigidTransform([0, 0, -0.05])), (Box(0.4, 0.4, 0.8), RigidTransform([1.5, 0, 0.4]))]
    depth = ShapeDepthRenderer(K, shapes).render(X_WC)
    system = RayCastMap(K)
    context = system.CreateDefaultContext()
    system.GetInputPort("depth_image").FixValue(context, _image(depth))
    system.GetInputPort("X_WC").FixValue(context, RigidTransform(X_WC))
    system.GetInputPort("robot_configuration").FixValue(context, q)
    simulator = Simulator(system, context)
    simulator.AdvanceTo(0.25)
    snapshot = system.GetOutputPort("point_map").Eval(context)
    assert snapshot.num_points > 100
    assert snapshot.points[:, 2].min() >= 0.05
    n, revision = snapshot.num_points, snapshot.revision
    bad = X_WC.copy()
    bad[:3, 3] = np.nan
    # A NaN camera pose, then a NaN robot configuration: logged, map unchanged.
    system.GetInputPort("X_WC").FixValue(context, RigidTransform(bad))
    simulator.AdvanceTo(0.35)
    system.GetInputPort("X_WC").FixValue(context, RigidTransform(X_WC))
    system.GetInputPort("robot_configuration").FixValue(context, np.full(layout.NQ, np.nan))
    simulator.AdvanceTo(0.55)
    snapshot = system.GetOutputPort("point_map").Eval(context)
    assert snapshot.num_points == n and snapshot.revision == revision
    assert "camera pose" in caplog.text and "robot spheres" in caplog.text
    assert system.map_core(context).num_points == n
    # A new episode (fresh context, initialized by its simulator) starts from an empty map.
    context2 = system.CreateDefaultContext()
    system.GetInputPort("depth_image").FixValue(context2, _image(np.full_like(depth, np.inf)))
    system.GetInputPort("X_WC").FixValue(context2, RigidTransform(X_WC))
    system.GetInputPort("robot_configuration").FixValue(context2, q)
    Simulator(system, context2).AdvanceTo(0.05)
    assert system.map_core(context2).num_points == 0
    assert system.map_core(context).num_points == n


def test_gaze_system_follows_the_trajectory_then_the_target():
    q0 = layout.stow_configuration(0.0, 0.0, 0.0)
    system = GazeOptimizer(K)
    context = system.CreateDefaultContext()
    system.GetInputPort("robot_configuration").FixValue(context, q0)
    system.GetInputPort("target").FixValue(context, np.array([2.0, -1.5, 0.7]))
    # Planning: no trajectory -> look at the target (to the right).
    simulator = Simulator(system, context)
    simulator.AdvanceTo(0.05)
    pan, tilt = system.GetOutputPort("head_command").Eval(context)
    assert pan < 0.0
    # Executing a trajectory that turns and drives left -> look left.
    trajectory = TimedTrajectory(
        times=np.array([0.0, 1.6, 4.6]) + 0.1,
        q=np.array([q0, layout.stow_configuration(0, 0, np.pi / 2), layout.stow_configuration(0, 3.0, np.pi / 2)]),
    )
    system.GetInputPort("trajectory").FixValue(context, PlannedTrajectory(trajectory=trajectory))
    simulator.AdvanceTo(0.15)
    pan, tilt = system.GetOutputPort("head_command").Eval(context)
    assert pan > 0.3
    assert layout.HEAD_TILT_LIMITS[0] <= tilt <= layout.HEAD_TILT_LIMITS[1]
