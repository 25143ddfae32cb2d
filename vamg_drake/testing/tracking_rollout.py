"""Kinematic roll-outs of the whole-body tracker (tests and benchmarks).

The tracker runs at its period; between its calls the command is held and
integrated by `vamg_drake.control.command_integration.integrate_command`, the same
integrator (unicycle base, clamped rates, joint limits) the diagram uses.
Also: seeded reference paths (straight, arc, Reeds-Shepp with a cusp).
"""

import dataclasses as dc
import time

import numpy as np

from vamg_drake.control.command_integration import integrate_command
from vamg_drake.control.whole_body_tracker import TrackerCommand, WholeBodyTrackerCore
from vamg_drake.planning import reeds_shepp
from vamg_drake.planning.smoothing import time_parametrize
from vamg_drake.planning.trajectory import TimedTrajectory
from vamg_drake.robot import layout
from vamg_drake.robot.kinematics import NX


@dc.dataclass
class Rollout:
    """The result of `rollout`: configurations at every tracker tick.

    Attributes:
        times: tick times (T,) [s].
        q: configurations (T, 11) at the ticks (before the tick's command).
        commands: the tracker's output at each tick.
        command_us: wall time of each `command` call [us].
    """

    times: np.ndarray
    q: np.ndarray
    commands: list[TrackerCommand]
    command_us: np.ndarray

    @property
    def done(self) -> bool:
        return bool(self.commands) and self.commands[-1].done

    @property
    def final_q(self) -> np.ndarray:
        return self.q[-1]


def rollout(core: WholeBodyTrackerCore, q0: np.ndarray, duration: float, integrator_period: float = 0.01,
            stop_when_done: bool = True) -> Rollout:
    """Simulates `core` from q0 (11,) for `duration` seconds with the real integrator."""
    V = np.zeros(NX)
    V[: layout.NQ] = np.asarray(q0, float)
    substeps = max(1, int(round(core.config.period / integrator_period)))
    n_ticks = int(np.ceil(duration / core.config.period))
    times, qs, commands, costs = [], [], [], []
    head, opening = np.zeros(2), layout.GRIPPER_MAX_OPENING
    for k in range(n_ticks + 1):
        q = V[: layout.NQ].copy()
        t0 = time.perf_counter()
        cmd = core.command(q)
        costs.append(1e6 * (time.perf_counter() - t0))
        times.append(k * core.config.period)
        qs.append(q)
        commands.append(cmd)
        if cmd.done and stop_when_done:
            break
        for _ in range(substeps):
            V, _ = integrate_command(V, cmd.base_velocity, cmd.joint_velocity, head, opening, integrator_period)
    return Rollout(np.asarray(times), np.asarray(qs), commands, np.asarray(costs))


def cross_track_errors(path_xy: np.ndarray, points_xy: np.ndarray) -> np.ndarray:
    """Distance (M,) of each point (M, 2) to the polyline path_xy (N, 2)."""
    a, b = path_xy[:-1], path_xy[1:]
    ab = b - a
    L2 = np.maximum(np.sum(ab * ab, axis=1), 1e-18)
    d = points_xy[:, None, :] - a[None]
    s = np.clip(np.sum(d * ab[None], axis=2) / L2[None], 0.0, 1.0)
    closest = a[None] + s[..., None] * ab[None]
    return np.min(np.linalg.norm(points_xy[:, None, :] - closest, axis=2), axis=1)


def _with_body(poses: np.ndarray, arm_start: np.ndarray, arm_goal: np.ndarray) -> np.ndarray:
    """Whole-body waypoints: base poses (N, 3), torso+arm interpolated start->goal."""
    s = np.linspace(0.0, 1.0, poses.shape[0])[:, None]
    return np.concatenate([poses, arm_start[None] + s * (arm_goal - arm_start)[None]], axis=1)


def _stow_joints() -> np.ndarray:
    return layout.stow_configuration(0.0, 0.0, 0.0)[layout.TORSO_ARM]


def straight_reference(rng: np.random.Generator, length: float | None = None, step: float = 0.03) -> TimedTrajectory:
    """A straight base path (random length 1-4 m unless given) from a random pose, arm stowed."""
    length = rng.uniform(1.0, 4.0) if length is None else length
    x0, y0 = rng.uniform(-2.0, 2.0, 2)
    th = rng.uniform(-np.pi, np.pi)
    s = np.linspace(0.0, length, int(np.ceil(length / step)) + 1)
    poses = np.stack([x0 + s * np.cos(th), y0 + s * np.sin(th), np.full_like(s, th)], axis=1)
    joints = _stow_joints()
    return time_parametrize(_with_body(poses, joints, joints))


def arc_reference(rng: np.random.Generator, radius: float | None = None, angle: float | None = None,
                  step: float = 0.03) -> TimedTrajectory:
    """A forward circular arc (left or right; random radius 0.6-2 m and angle
    0.8-2.5 rad unless given) with the torso rising and the arm moving."""
    radius = rng.uniform(0.6, 2.0) if radius is None else radius
    angle = rng.uniform(0.8, 2.5) if angle is None else angle
    x0, y0 = rng.uniform(-2.0, 2.0, 2)
    th0 = rng.uniform(-np.pi, np.pi)
    sign = rng.choice([-1.0, 1.0])
    phi = np.linspace(0.0, angle, int(np.ceil(radius * angle / step)) + 1)
    cx, cy = x0 - sign * radius * np.sin(th0), y0 + sign * radius * np.cos(th0)
    th = th0 + sign * phi
    poses = np.stack([cx + sign * radius * np.sin(th), cy - sign * radius * np.cos(th), th], axis=1)
    start = _stow_joints()
    goal = start.copy()
    goal[0] = min(start[0] + 0.15, layout.Q_UPPER[layout.TORSO])
    goal[1:] += rng.uniform(-0.3, 0.3, 7)
    goal = np.clip(goal, layout.Q_LOWER[layout.TORSO_ARM] + 0.05, layout.Q_UPPER[layout.TORSO_ARM] - 0.05)
    return time_parametrize(_with_body(poses, start, goal))


def reeds_shepp_reference(rng: np.random.Generator, radius: float = 0.6, step: float = 0.03) -> TimedTrajectory:
    """A shortest Reeds-Shepp path with at least one cusp (reverse segment)."""
    for _ in range(200):
        start = np.array([*rng.uniform(-1.0, 1.0, 2), rng.uniform(-np.pi, np.pi)])
        # A goal mostly beside/behind the start makes reversing the shortest way.
        local = np.array([rng.uniform(-1.2, 0.6), rng.uniform(-1.0, 1.0)])
        c, s = np.cos(start[2]), np.sin(start[2])
        goal = np.array([start[0] + c * local[0] - s * local[1], start[1] + s * local[0] + c * local[1],
                         start[2] + rng.uniform(-1.5, 1.5)])
        types, lengths, _ = reeds_shepp.shortest_path(start, goal, radius)
        signs = np.sign(lengths[np.abs(lengths) > 1e-9])
        if signs.size > 1 and np.any(signs != signs[0]):
            poses = reeds_shepp.sample_path(start, types, lengths, radius, step)
            joints = _stow_joints()
            return time_parametrize(_with_body(poses, joints, joints))
    raise RuntimeError("no Reeds-Shepp path with a cusp found")
