"""The Fetch head depth camera (PrimeSense Carmine 1.09): intrinsics and frames.

The native depth stream is 640x480 with a ~58 deg horizontal field of view
(fx = fy = 554.25 px at 640x480). Lower resolutions scale the focal length.
The camera frame ``C`` is the URDF's ``head_camera_depth_optical_frame``:
+z along the optical axis, +x right, +y down in the image.
"""


import dataclasses as dc
import math

import numpy as np

NATIVE_WIDTH = 640
NATIVE_HEIGHT = 480
NATIVE_FOCAL_PX = 554.254691191187


@dc.dataclass
class HeadCameraConfig:
    """Configuration of the simulated head depth camera."""

    width: int = 320
    height: int = 240
    #: Depth rendering range [m] (the sensor's own range; the map crops further).
    depth_min: float = 0.2
    depth_max: float = 5.0
    #: Rendering period [s] (10 Hz in the paper).
    period: float = 0.1

    def __post_init__(self) -> None:
        if self.width <= 0 or self.height <= 0:
            raise ValueError(f"HeadCameraConfig: width/height must be positive, got {self.width}x{self.height}")
        if not 0.0 < self.depth_min < self.depth_max:
            raise ValueError(f"HeadCameraConfig: need 0 < depth_min < depth_max, got {self.depth_min}, {self.depth_max}")


@dc.dataclass(frozen=True)
class CameraIntrinsics:
    """Pinhole intrinsics in pixels."""

    width: int
    height: int
    fx: float
    fy: float
    cx: float
    cy: float

    @staticmethod
    def from_config(config: HeadCameraConfig) -> "CameraIntrinsics":
        scale = config.width / NATIVE_WIDTH
        f = NATIVE_FOCAL_PX * scale
        return CameraIntrinsics(
            width=config.width,
            height=config.height,
            fx=f,
            fy=f,
            cx=config.width / 2.0 - 0.5,
            cy=config.height / 2.0 - 0.5,
        )

    @property
    def fov_y(self) -> float:
        """Vertical field of view [rad]."""
        return 2.0 * math.atan(self.height / (2.0 * self.fy))

    @property
    def fov_x(self) -> float:
        """Horizontal field of view [rad]."""
        return 2.0 * math.atan(self.width / (2.0 * self.fx))

    def matrix(self) -> np.ndarray:
        """The 3x3 camera matrix K."""
        return np.array([[self.fx, 0.0, self.cx], [0.0, self.fy, self.cy], [0.0, 0.0, 1.0]])
