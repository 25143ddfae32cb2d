"""TargetCloud: a dense cloud of the target's surroundings from the depth images.

The ray-cast map keeps points at its voxel size (3 cm), too coarse for small
objects' grasp candidates; this system back-projects every depth image at full
resolution and accumulates the points within `radius` of the target (merged
on a fine voxel grid), for the SubgoalPolicy's optional ``target_cloud`` input.

Points stay, however old, until an image sees through them (the object moved,
or they were never there): the policy may choose a grasp from an earlier,
closer view while the head looks elsewhere. The completion of the object's
unseen side is the grasp cloud's business (`SubgoalPipeline`).
"""

import dataclasses as dc

import numpy as np
from pydrake.common.value import AbstractValue
from pydrake.math import RigidTransform
from pydrake.systems.framework import EventStatus, LeafSystem
from pydrake.systems.sensors import ImageDepth32F

from vamg_drake.perception.depth_points import DepthBackProjector, validate_pose, within_distance
from vamg_drake.perception.raycast_map import inside_any_sphere, points_not_seen_through
from vamg_drake.perception.voxels import first_in_voxel
from vamg_drake.robot import layout
from vamg_drake.robot.head_camera import CameraIntrinsics
from vamg_drake.robot.spheres import SphereModel


@dc.dataclass
class TargetCloudConfig:
    """Parameters of the target cloud.

    Attributes:
        radius: points within this distance of the target are kept [m].
        voxel_size: accumulated points are merged on this grid [m].
        max_points: the accumulated cloud is capped (oldest dropped first).
        carve_tolerance: a kept point that the camera now sees through, more
            than this in front of the measured depth, is dropped [m] (the
            object moved, or was never there); points out of view, or behind
            what the camera sees, stay however old they are, so that a grasp
            can still be chosen from an earlier, closer view while the head
            looks elsewhere.
        carve_footprint_px: half-width of the min-depth window of that test
            [px], so that the silhouette of an object does not carve it.
        self_margin: points within this distance of the robot's spheres are dropped [m].
        period: update period [s].
    """

    radius: float = 0.3
    voxel_size: float = 0.004
    max_points: int = 30000
    carve_tolerance: float = 0.01
    carve_footprint_px: int = 2
    self_margin: float = 0.02
    period: float = 0.1


def merge_on_grid(points: np.ndarray, voxel: float) -> np.ndarray:
    """One point per voxel of its xyz (extra columns ride along), the newest (last) one winning."""
    newest_first = points[::-1]
    return newest_first[first_in_voxel(newest_first, voxel)][::-1]


class TargetCloud(LeafSystem):
    """Inputs: depth_image (ImageDepth32F), X_WC (RigidTransform), target (3).
    Input: robot_configuration (11): points inside the robot's spheres (plus
    `self_margin`) are the robot itself and are dropped.
    Output: target_cloud ((N, 3) array p_WS around the target; empty until seen).

    A bad pose or depth image is skipped (the previous cloud is kept). The
    accumulated points never expire: objects that move near the target after
    being seen leave stale points (the map's carving handles those; this cloud
    only feeds grasp candidates).
    """

    def __init__(self, intrinsics: CameraIntrinsics, config: TargetCloudConfig | None = None):
        super().__init__()
        self._config = config or TargetCloudConfig()
        self._intrinsics = intrinsics
        self._projector = DepthBackProjector(intrinsics)
        self._depth_port = self.DeclareAbstractInputPort(
            "depth_image", AbstractValue.Make(ImageDepth32F(intrinsics.width, intrinsics.height)))
        self._pose_port = self.DeclareAbstractInputPort("X_WC", AbstractValue.Make(RigidTransform()))
        self._target_port = self.DeclareVectorInputPort("target", 3)
        self._q_port = self.DeclareVectorInputPort("robot_configuration", layout.NQ)

        self._spheres = SphereModel.load()
        self._cloud = self.DeclareAbstractState(AbstractValue.Make(np.zeros((0, 3))))  # oldest first
        self.DeclareStateOutputPort("target_cloud", self._cloud)
        self.DeclarePeriodicUnrestrictedUpdateEvent(self._config.period, 0.0, self._update)

    def _update(self, context, state) -> EventStatus:
        cfg = self._config
        p_WT = np.asarray(self._target_port.Eval(context), dtype=float)
        if not np.all(np.isfinite(p_WT)):
            return EventStatus.Succeeded()
        try:
            X_WC = validate_pose(self._pose_port.Eval(context).GetAsMatrix4())
            depth = self._depth_port.Eval(context).data[:, :, 0]
            p_WS = self._projector.points_W(depth, X_WC)
        except ValueError:
            return EventStatus.Succeeded()
        new = p_WS[within_distance(p_WS, p_WT, cfg.radius)]
        q = np.asarray(self._q_port.Eval(context), dtype=float)
        if new.shape[0] and np.all(np.isfinite(q)):
            new = new[~inside_any_sphere(new, self._spheres.world_spheres(q), self._spheres.radius + cfg.self_margin)]
        kept = context.get_abstract_state(self._cloud).get_value()
        cloud = kept
        if kept.shape[0]:
            cloud = kept[points_not_seen_through(kept, depth, X_WC, self._intrinsics, cfg.carve_tolerance,
                                                 cfg.carve_footprint_px, True, self._projector.config)]
        if new.shape[0] == 0 and cloud.shape[0] == kept.shape[0]:
            return EventStatus.Succeeded()
        cloud = merge_on_grid(np.concatenate([cloud, new]), cfg.voxel_size)[-cfg.max_points:]
        state.get_mutable_abstract_state(self._cloud).set_value(cloud)
        return EventStatus.Succeeded()
