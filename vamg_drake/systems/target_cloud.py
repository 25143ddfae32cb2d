"""TargetCloud: a dense cloud of the target's surroundings from the latest depth image.

The ray-cast map keeps points at its voxel size (3 cm), too coarse for small
objects' grasp candidates; this system back-projects the depth image at full
resolution and keeps the points within `radius` of the target, for the
SubgoalPolicy's optional ``target_cloud`` input.
"""

import numpy as np
from pydrake.common.value import AbstractValue
from pydrake.math import RigidTransform
from pydrake.systems.framework import EventStatus, LeafSystem
from pydrake.systems.sensors import ImageDepth32F

from vamg_drake.perception.depth_points import DepthBackProjector, validate_pose
from vamg_drake.robot.head_camera import CameraIntrinsics


class TargetCloud(LeafSystem):
    """Inputs: depth_image (ImageDepth32F), X_WC (RigidTransform), target (3).
    Output: target_cloud ((N, 3) array p_WS, the latest view with at least
    `min_points` points near the target; empty until then).

    A bad pose or depth image is skipped (the previous cloud is kept).
    """

    def __init__(self, intrinsics: CameraIntrinsics, radius: float = 0.3, min_points: int = 30, period: float = 0.1):
        super().__init__()
        self._projector = DepthBackProjector(intrinsics)
        self._radius = radius
        self._min_points = min_points
        self.DeclareAbstractInputPort("depth_image",
                                      AbstractValue.Make(ImageDepth32F(intrinsics.width, intrinsics.height)))
        self.DeclareAbstractInputPort("X_WC", AbstractValue.Make(RigidTransform()))
        self.DeclareVectorInputPort("target", 3)
        self._cloud = self.DeclareAbstractState(AbstractValue.Make(np.zeros((0, 3))))
        self.DeclareStateOutputPort("target_cloud", self._cloud)
        self.DeclarePeriodicUnrestrictedUpdateEvent(period, 0.0, self._update)

    def _update(self, context, state) -> EventStatus:
        p_WT = np.asarray(self.get_input_port(2).Eval(context), dtype=float)
        if not np.all(np.isfinite(p_WT)):
            return EventStatus.Succeeded()
        try:
            X_WC = validate_pose(self.get_input_port(1).Eval(context).GetAsMatrix4())
            depth = self.get_input_port(0).Eval(context).data[:, :, 0]
            p_WS = self._projector.points_W(depth, X_WC)
        except ValueError:
            return EventStatus.Succeeded()
        near = p_WS[np.linalg.norm(p_WS - p_WT, axis=1) <= self._radius]
        if near.shape[0] >= self._min_points:
            state.get_mutable_abstract_state(self._cloud).set_value(near)
        return EventStatus.Succeeded()
