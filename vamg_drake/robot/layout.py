"""The Fetch joint layout: one place for joint order, limits and rates.

The planning configuration ``q`` is the 11-D whole-body vector used by the
planner, the tracker and the policy::

    q = [base_x, base_y, base_theta, torso_lift, shoulder_pan, shoulder_lift,
         upperarm_roll, elbow_flex, forearm_roll, wrist_flex, wrist_roll]

The head (pan, tilt) and the gripper (two prismatic fingers) are commanded
separately. Position and velocity limits are the Fetch's (fetch_description
URDF); the base limits are the tracker's clamps (DESIGN.md).
"""

from __future__ import annotations

import numpy as np

BASE_JOINTS: tuple[str, ...] = ("base_x", "base_y", "base_theta")
TORSO_JOINT = "torso_lift_joint"
ARM_JOINTS: tuple[str, ...] = (
    "shoulder_pan_joint",
    "shoulder_lift_joint",
    "upperarm_roll_joint",
    "elbow_flex_joint",
    "forearm_roll_joint",
    "wrist_flex_joint",
    "wrist_roll_joint",
)
HEAD_JOINTS: tuple[str, ...] = ("head_pan_joint", "head_tilt_joint")
FINGER_JOINTS: tuple[str, ...] = ("l_gripper_finger_joint", "r_gripper_finger_joint")

WHOLE_BODY_JOINTS: tuple[str, ...] = BASE_JOINTS + (TORSO_JOINT,) + ARM_JOINTS
NQ = len(WHOLE_BODY_JOINTS)  # 11

# Index helpers into q.
BASE = slice(0, 3)
BASE_XY = slice(0, 2)
THETA = 2
TORSO = 3
ARM = slice(4, 11)
TORSO_ARM = slice(3, 11)

_INF = np.inf
# Position limits. Continuous joints (theta, upperarm/forearm/wrist roll) are
# unbounded here and wrapped into [-pi, pi] by `wrap_configuration`.
Q_LOWER = np.array(
    [-_INF, -_INF, -_INF, 0.0, -1.6056, -1.221, -_INF, -2.251, -_INF, -2.16, -_INF]
)
Q_UPPER = np.array(
    [_INF, _INF, _INF, 0.38615, 1.6056, 1.518, _INF, 2.251, _INF, 2.16, _INF]
)
IS_CONTINUOUS = np.array(
    [False, False, True, False, False, False, True, False, True, False, True]
)
# Joint-space sampling bounds (finite everywhere) for planners and maps.
SAMPLE_LOWER = np.where(np.isfinite(Q_LOWER), Q_LOWER, -np.pi)
SAMPLE_UPPER = np.where(np.isfinite(Q_UPPER), Q_UPPER, np.pi)

# Real Fetch joint velocity limits (URDF), clamped by the tracker's limits
# (DESIGN.md: torso 0.1 m/s, arm 1.0 rad/s). Base: v [m/s], w [rad/s].
URDF_ARM_VELOCITY = np.array([1.256, 1.454, 1.571, 1.521, 1.571, 2.268, 2.268])
TRACKER_BASE_V = 1.5
TRACKER_BASE_W = 1.0
TRACKER_TORSO_V = 0.1
TRACKER_ARM_V = 1.0
#: Per-coordinate rate limits of q for time parametrization: x and y share the
#: linear speed limit, theta the angular one.
V_MAX = np.concatenate(
    [
        [TRACKER_BASE_V, TRACKER_BASE_V, TRACKER_BASE_W, TRACKER_TORSO_V],
        np.minimum(URDF_ARM_VELOCITY, TRACKER_ARM_V),
    ]
)

HEAD_PAN_LIMITS = (-1.57, 1.57)
HEAD_TILT_LIMITS = (-0.76, 1.45)
HEAD_VELOCITY = 1.57
FINGER_LIMITS = (0.0, 0.05)
FINGER_VELOCITY = 0.05
GRIPPER_MAX_OPENING = 0.10

#: A tucked arm (near the Fetch's own tuck pose, moved to keep >= 2 cm of
#: clearance in the sphere model) that stays inside the base footprint.
Q_ARM_STOW = np.array([1.335, 1.411, -0.279, 1.718, 0.002, 1.584, 0.046])
#: The default torso height while driving.
TORSO_STOW = 0.05


def wrap_angle(a: np.ndarray | float) -> np.ndarray | float:
    """Wraps angles into [-pi, pi)."""
    return (np.asarray(a) + np.pi) % (2.0 * np.pi) - np.pi


def wrap_configuration(q: np.ndarray) -> np.ndarray:
    """Returns q (..., 11) with its continuous joints wrapped into [-pi, pi)."""
    q = np.array(q, dtype=float, copy=True)
    q[..., IS_CONTINUOUS] = wrap_angle(q[..., IS_CONTINUOUS])
    return q


def within_limits(q: np.ndarray, tol: float = 1e-9) -> np.ndarray:
    """True where every joint of q (..., 11) is inside its position limits."""
    q = np.asarray(q, dtype=float)
    return np.all((q >= Q_LOWER - tol) & (q <= Q_UPPER + tol), axis=-1)


def raised_torso(q: np.ndarray, height: float) -> np.ndarray:
    """q (..., 11) with the torso raised by `height` [m], clamped at its upper limit
    (the grasp's lift: the arm keeps its joint angles)."""
    q = np.array(q, dtype=float, copy=True)
    q[..., TORSO] = np.minimum(Q_UPPER[TORSO], q[..., TORSO] + height)
    return q


def stow_configuration(x: float, y: float, theta: float) -> np.ndarray:
    """A whole-body configuration with the arm stowed at base pose (x, y, theta)."""
    return np.concatenate([[x, y, theta, TORSO_STOW], Q_ARM_STOW])
