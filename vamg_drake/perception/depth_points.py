"""Depth image -> world-frame points (the first stage of the ray-cast map).

A depth pixel (u, v) with depth z (along the optical axis, metres) back-projects
to p_CP = z * ((u - cx) / fx, (v - cy) / fy, 1) in the camera optical frame C
(+z forward, +x right, +y down; `vamg_drake.robot.head_camera`), and to
p_WP = X_WC * p_CP in the world. Pixels that are NaN, +-inf or <= 0 carry no
surface (Drake's RgbdSensor writes +inf for "too far" and 0 for "too close")
and are dropped, as are depths outside [depth_min, depth_max] and points
farther than `crop_radius` from the camera centre.
"""


import dataclasses as dc
import math

import numba
import numpy as np

from vamg_drake.robot.head_camera import CameraIntrinsics


@dc.dataclass
class DepthToPointsConfig:
    """Which depth pixels become map points (paper: 0.2-3.0 m, 2.5 m crop)."""

    depth_min: float = 0.2
    depth_max: float = 3.0
    #: Keep points within this distance [m] of the camera centre.
    crop_radius: float = 2.5

    def __post_init__(self) -> None:
        self.validate()

    def validate(self) -> None:
        """Raises ValueError naming the first bad field (yaml_load_typed skips __post_init__)."""
        if not 0.0 <= self.depth_min < self.depth_max:
            raise ValueError(
                f"DepthToPointsConfig: need 0 <= depth_min < depth_max, got "
                f"depth_min={self.depth_min}, depth_max={self.depth_max}"
            )
        if not self.crop_radius > 0.0:
            raise ValueError(f"DepthToPointsConfig.crop_radius must be positive, got {self.crop_radius}")


def validate_pose(X_WC: np.ndarray, name: str = "X_WC") -> np.ndarray:
    """Returns X_WC as a float (4, 4) array or raises ValueError naming `name`.

    A pose is valid when it is finite, its last row is [0, 0, 0, 1] and its
    rotation block is orthonormal (to 1e-6).
    """
    X = np.asarray(X_WC, dtype=float)
    if X.shape != (4, 4):
        raise ValueError(f"{name} must be a (4, 4) homogeneous transform, got shape {X.shape}")
    if not np.all(np.isfinite(X)):
        raise ValueError(f"{name} contains NaN or inf")
    R = X[:3, :3]
    if np.abs(R.T @ R - np.eye(3)).max() > 1e-6 or np.abs(X[3] - (0.0, 0.0, 0.0, 1.0)).max() > 1e-12:
        raise ValueError(f"{name} is not a rigid transform (rotation not orthonormal or bad last row)")
    return X


class DepthBackProjector:
    """Back-projects depth images of one camera; the per-pixel rays are cached."""

    def __init__(self, intrinsics: CameraIntrinsics, config: DepthToPointsConfig | None = None):
        self.intrinsics = intrinsics
        self.config = config or DepthToPointsConfig()
        u = (np.arange(intrinsics.width) - intrinsics.cx) / intrinsics.fx
        v = (np.arange(intrinsics.height) - intrinsics.cy) / intrinsics.fy
        # Ray direction per pixel with unit z, scaled by depth gives p_CP.
        self._ray_x = np.ascontiguousarray(np.broadcast_to(u[None, :], (intrinsics.height, intrinsics.width)))
        self._ray_y = np.ascontiguousarray(np.broadcast_to(v[:, None], (intrinsics.height, intrinsics.width)))

    def check_depth(self, depth: np.ndarray) -> np.ndarray:
        """Returns depth as a C-contiguous float32 (H, W) image or raises ValueError."""
        d = np.asarray(depth)
        if d.ndim == 3 and d.shape[2] == 1:
            d = d[:, :, 0]
        expected = (self.intrinsics.height, self.intrinsics.width)
        if d.shape != expected:
            raise ValueError(f"depth image has shape {d.shape}, the camera intrinsics say {expected} (H, W)")
        return np.ascontiguousarray(d, dtype=np.float32)

    def points_W(self, depth: np.ndarray, X_WC: np.ndarray) -> np.ndarray:
        """World points p_WP (M, 3) of the valid pixels of `depth` seen from X_WC."""
        d = self.check_depth(depth)
        X = np.ascontiguousarray(validate_pose(X_WC))
        c = self.config
        return _back_project(
            d, self._ray_x, self._ray_y, X, float(c.depth_min), float(c.depth_max), float(c.crop_radius)
        )


def depth_to_points_reference(
    depth: np.ndarray, intrinsics: CameraIntrinsics, X_WC: np.ndarray, config: DepthToPointsConfig
) -> np.ndarray:
    """Plain NumPy back-projection (the reference the numba kernel is checked against)."""
    d = np.asarray(depth, dtype=np.float64).reshape(intrinsics.height, intrinsics.width)
    vv, uu = np.mgrid[0 : intrinsics.height, 0 : intrinsics.width]
    with np.errstate(invalid="ignore"):
        ok = np.isfinite(d) & (d > 0) & (d >= config.depth_min) & (d <= config.depth_max)
    z = d[ok]
    p_C = np.stack([(uu[ok] - intrinsics.cx) / intrinsics.fx * z, (vv[ok] - intrinsics.cy) / intrinsics.fy * z, z], 1)
    p_C = p_C[np.einsum("ij,ij->i", p_C, p_C) <= config.crop_radius**2]
    return p_C @ X_WC[:3, :3].T + X_WC[:3, 3]


@numba.njit(cache=True)
def _back_project(depth, ray_x, ray_y, X_WC, depth_min, depth_max, crop_radius):
    h, w = depth.shape
    out = np.empty((h * w, 3))
    r2 = crop_radius * crop_radius
    n = 0
    for v in range(h):
        for u in range(w):
            z = depth[v, u]
            # NaN fails every comparison; +inf fails z <= depth_max; 0 fails z > 0.
            if not (z > 0.0 and z >= depth_min and z <= depth_max):
                continue
            x = ray_x[v, u] * z
            y = ray_y[v, u] * z
            if x * x + y * y + z * z > r2:
                continue
            for k in range(3):
                out[n, k] = X_WC[k, 0] * x + X_WC[k, 1] * y + X_WC[k, 2] * z + X_WC[k, 3]
            n += 1
    return out[:n].copy()


@numba.njit(cache=True)
def within_distance(points, center, radius):
    """(N,) bool: whether |p - center| <= radius for each point (N, 3), with the
    distance rounded as `np.linalg.norm(points - center, axis=1)` rounds it."""
    n = points.shape[0]
    out = np.empty(n, dtype=np.bool_)
    for i in range(n):
        dx = points[i, 0] - center[0]
        dy = points[i, 1] - center[1]
        dz = points[i, 2] - center[2]
        out[i] = math.sqrt(dx * dx + dy * dy + dz * dz) <= radius
    return out
