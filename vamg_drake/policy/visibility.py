"""Can the head camera see the target from a configuration?

`TargetVisibility.check` aims the pan/tilt head at the target (closed form,
per configuration), then requires the target inside the camera's field of view
and the map's depth range, and the line of sight free of the robot's own spheres (the
self-occlusion check of the pre-grasp sampler) and, optionally, of map points
(used by the observe sampler).
"""

import dataclasses as dc

import numpy as np

from vamg_drake.robot import layout
from vamg_drake.robot.head_camera import CameraIntrinsics, HeadCameraConfig
from vamg_drake.robot.kinematics import CAMERA_FRAME, FetchKinematics
from vamg_drake.robot.spheres import SphereModel


@dc.dataclass
class VisibilityConfig:
    """Parameters of the target visibility check (the camera itself is a
    `HeadCameraConfig`, and the depth range the map's `DepthToPointsConfig.depth_max`,
    both given to `TargetVisibility`)."""

    #: Shrink of the field of view on each side [rad].
    fov_margin: float = 0.05
    #: The line of sight stops this short of the target (the target's own surface) [m].
    target_margin: float = 0.04
    #: A map point closer than this to the line of sight blocks it [m].
    point_occlusion_radius: float = 0.03
    #: The robot's spheres block the line of sight with their radii scaled by
    #: this: they cover the links with a bulge (the palm's 5.9 cm spheres cover
    #: a 4 cm half-height box), and a self-occlusion test needs no such margin:
    #: at full radius the bulge can hide the target from every collision-free pre-grasp.
    self_occlusion_radius_scale: float = 0.7
    #: The gripper's own spheres do not block the line of sight: at a
    #: pre-grasp the open hand stands 5 cm from the target, around or above
    #: it, and hides at most part of it (a small object such as a Lego brick
    #: may have only top-down grasps, and the hand above it would make every
    #: such pre-grasp "not visible").
    self_occlusion_ignores_gripper: bool = True
    #: A map point more than this below the line of sight (at its closest
    #: point) does not block it: the table under a small target lies just
    #: below every low view of it (a 2 cm Lego brick on a table: the table top
    #: lies 6 mm under its centre and hides it from every low view). A surface that
    #: crosses the line has map points above it or within this too [m].
    support_tolerance: float = 0.01


class TargetVisibility:
    """Batched target visibility from the head camera.

    Args:
        camera: the simulated head camera (``WorldConfig.camera``): its field
            of view is the one the depth renderer has.
        max_depth: the largest depth at which the target counts as seen [m]:
            the range within which the map integrates the camera's points
            (`DepthToPointsConfig.depth_max`, the diagram's ``config.map.depth``).
            A target seen farther away adds no points to the map.
        config: the check's margins.
    """

    def __init__(self, camera: HeadCameraConfig, max_depth: float, config: VisibilityConfig | None = None) -> None:
        if not max_depth > camera.depth_min:
            raise ValueError(f"TargetVisibility: max_depth must exceed the camera's depth_min "
                             f"({camera.depth_min} m), got {max_depth}")
        self.config = config or VisibilityConfig()
        self.camera = camera
        #: Largest depth at which the target counts as seen [m] (the map's range).
        self.max_depth = float(max_depth)
        self.kin = FetchKinematics.instance()
        self.spheres = SphereModel.load()
        self.intrinsics = CameraIntrinsics.from_config(self.camera)
        self._pan = self.kin.link_index("head_pan_link")
        self._tilt = self.kin.link_index("head_tilt_link")
        self._camera = self.kin.link_index(CAMERA_FRAME)
        self._body = ~self.spheres.is_head
        if self.config.self_occlusion_ignores_gripper:
            self._body &= ~self.spheres.is_gripper

    def aim_head(self, q: np.ndarray, p_WT: np.ndarray) -> np.ndarray:
        """Pan/tilt (K, 2) pointing the head at the target, clipped to the head limits."""
        q = np.atleast_2d(q)
        K = q.shape[0]
        head = np.zeros((K, 2))
        X = self.kin.link_poses(q, head)[:, self._pan]
        p = np.einsum("kji,kj->ki", X[:, :3, :3], p_WT[None] - X[:, :3, 3])
        head[:, 0] = np.clip(np.arctan2(p[:, 1], p[:, 0]), *layout.HEAD_PAN_LIMITS)
        X = self.kin.link_poses(q, head)[:, self._tilt]
        p = np.einsum("kji,kj->ki", X[:, :3, :3], p_WT[None] - X[:, :3, 3])
        head[:, 1] = np.clip(np.arctan2(-p[:, 2], p[:, 0]), *layout.HEAD_TILT_LIMITS)
        return head

    def check(
        self, q: np.ndarray, p_WT: np.ndarray, p_WM: np.ndarray | None = None
    ) -> tuple[np.ndarray, np.ndarray]:
        """(visible (K,), head (K, 2)) for configurations q (K, 11) and target p_WT (3,).

        Args:
            q: configurations.
            p_WT: the target.
            p_WM: optional map points that may block the line of sight (points
                within ``target_margin`` of the target are ignored).
        """
        cfg = self.config
        q = np.atleast_2d(np.asarray(q, dtype=float))
        p_WT = np.asarray(p_WT, dtype=float).reshape(3)
        head = self.aim_head(q, p_WT)
        X_WL = self.kin.link_poses(q, head)
        X_WC = X_WL[:, self._camera]
        p_C = np.einsum("kji,kj->ki", X_WC[:, :3, :3], p_WT[None] - X_WC[:, :3, 3])
        depth = p_C[:, 2]
        half_x = 0.5 * self.intrinsics.fov_x - cfg.fov_margin
        half_y = 0.5 * self.intrinsics.fov_y - cfg.fov_margin
        with np.errstate(divide="ignore", invalid="ignore"):
            in_fov = (
                (depth > self.camera.depth_min)
                & (depth < self.max_depth)
                & (np.abs(np.arctan2(p_C[:, 0], depth)) < half_x)
                & (np.abs(np.arctan2(p_C[:, 1], depth)) < half_y)
            )
        # Line of sight from the camera to just short of the target.
        a = X_WC[:, :3, 3]
        seg = p_WT[None] - a
        length = np.linalg.norm(seg, axis=1)
        direction = seg / np.maximum(length, 1e-9)[:, None]
        end = np.maximum(length - cfg.target_margin, 0.0)
        centers = self.spheres.world_spheres(q, head, link_poses=X_WL)[:, self._body]  # (K, S, 3)
        radius = cfg.self_occlusion_radius_scale * self.spheres.radius[self._body]
        rel = centers - a[:, None, :]
        t = np.clip(np.einsum("ksi,ki->ks", rel, direction), 0.0, end[:, None])
        closest = a[:, None, :] + t[..., None] * direction[:, None, :]
        blocked = np.any(np.linalg.norm(centers - closest, axis=2) < radius[None], axis=1)
        visible = in_fov & ~blocked
        if p_WM is not None and np.any(visible):
            visible &= ~self._blocked_by_points(a, p_WT, np.asarray(p_WM, float).reshape(-1, 3))
        return visible, head

    def _blocked_by_points(self, a: np.ndarray, p_WT: np.ndarray, p_WM: np.ndarray) -> np.ndarray:
        """Whether map points block the lines of sight from cameras a (K, 3) to
        just short of p_WT: a point within `point_occlusion_radius` of the
        line and not more than `support_tolerance` below it."""
        cfg = self.config
        p_WM = p_WM[np.linalg.norm(p_WM - p_WT, axis=1) > cfg.target_margin + cfg.point_occlusion_radius]
        blocked = np.zeros(a.shape[0], dtype=bool)
        if p_WM.shape[0] == 0:
            return blocked
        r = cfg.point_occlusion_radius
        for k in range(a.shape[0]):
            seg = p_WT - a[k]
            length = np.linalg.norm(seg)
            direction = seg / max(length, 1e-9)
            lo, hi = np.minimum(a[k], p_WT) - r, np.maximum(a[k], p_WT) + r
            p = p_WM[np.all((p_WM >= lo) & (p_WM <= hi), axis=1)]
            if p.shape[0] == 0:
                continue
            t = np.clip((p - a[k]) @ direction, 0.0, max(length - cfg.target_margin, 0.0))
            closest = a[k] + t[:, None] * direction
            near = np.linalg.norm(p - closest, axis=1) < r
            blocked[k] = bool(np.any(near & (p[:, 2] >= closest[:, 2] - cfg.support_tolerance)))
        return blocked
