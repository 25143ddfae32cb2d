"""One integration step of the robot's velocity commands into its desired configuration.

The `RobotCommandIntegrator` system applies it every command period; the
tracker's closed-loop rollouts apply the same step, so that a rollout tracks
exactly what the diagram's robot would be commanded.
"""

import math

import numpy as np

from vamg_drake.robot import layout
from vamg_drake.robot.kinematics import FINGER_SLICE, HEAD_SLICE, NX


def integrate_command(
    V: np.ndarray, base_velocity: np.ndarray, joint_velocity: np.ndarray, head: np.ndarray, opening: float, dt: float
) -> tuple[np.ndarray, np.ndarray]:
    """One step of the desired extended configuration V (15,) under the commands.

    Commands are clamped to the tracker limits (layout), positions to the joint
    limits; head and fingers move towards their targets at their rate limits.

    Returns:
        (V_next, Vdot) the next desired configuration and its velocity.
    """
    V = V.copy()
    Vdot = np.zeros(NX)
    v = float(np.clip(base_velocity[0], -layout.TRACKER_BASE_V, layout.TRACKER_BASE_V))
    w = float(np.clip(base_velocity[1], -layout.TRACKER_BASE_W, layout.TRACKER_BASE_W))
    theta_mid = V[layout.THETA] + 0.5 * w * dt
    Vdot[0] = v * math.cos(theta_mid)
    Vdot[1] = v * math.sin(theta_mid)
    Vdot[layout.THETA] = w
    qdot = np.clip(joint_velocity, -layout.V_MAX[layout.TORSO_ARM], layout.V_MAX[layout.TORSO_ARM])
    Vdot[layout.TORSO_ARM] = qdot
    head_target = np.clip(head, [layout.HEAD_PAN_LIMITS[0], layout.HEAD_TILT_LIMITS[0]],
                          [layout.HEAD_PAN_LIMITS[1], layout.HEAD_TILT_LIMITS[1]])
    Vdot[HEAD_SLICE] = np.clip((head_target - V[HEAD_SLICE]) / dt, -layout.HEAD_VELOCITY, layout.HEAD_VELOCITY)
    finger_target = np.clip(0.5 * opening, *layout.FINGER_LIMITS)
    Vdot[FINGER_SLICE] = np.clip((finger_target - V[FINGER_SLICE]) / dt, -layout.FINGER_VELOCITY, layout.FINGER_VELOCITY)
    V_next = V + Vdot * dt
    # Joint limits: stop at the limit (and zero the rate there).
    lo = np.r_[layout.Q_LOWER, layout.HEAD_PAN_LIMITS[0], layout.HEAD_TILT_LIMITS[0], layout.FINGER_LIMITS[0], layout.FINGER_LIMITS[0]]
    hi = np.r_[layout.Q_UPPER, layout.HEAD_PAN_LIMITS[1], layout.HEAD_TILT_LIMITS[1], layout.FINGER_LIMITS[1], layout.FINGER_LIMITS[1]]
    clipped = np.clip(V_next, lo, hi)
    Vdot[clipped != V_next] = 0.0
    return clipped, Vdot
