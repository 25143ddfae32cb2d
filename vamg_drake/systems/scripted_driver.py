"""ScriptedDriver: drives the base through a waypoint list and sweeps the head.

It exercises the world before the planner and the policy exist: a
pure-pursuit unicycle controller turns in place towards the next waypoint,
then drives; the head pans back and forth; the arm holds still; the gripper
stays open.
"""


import dataclasses as dc
import math

import numpy as np
from pydrake.systems.framework import BasicVector, LeafSystem

from vamg_drake.robot import layout
from vamg_drake.robot.kinematics import NX


@dc.dataclass
class ScriptedDriverConfig:
    """Parameters of the scripted driver."""

    speed: float = 0.5
    turn_rate: float = 0.8
    #: Heading error above which the base turns in place [rad].
    turn_in_place: float = 0.35
    waypoint_tolerance: float = 0.1
    head_pan_amplitude: float = 0.8
    head_pan_period: float = 6.0
    head_tilt: float = 0.5


def unicycle_command(
    x: float, y: float, theta: float, goal: np.ndarray, config: ScriptedDriverConfig
) -> tuple[float, float]:
    """(v, w) towards `goal` (2,): turn in place when badly aligned, else drive."""
    dx, dy = goal[0] - x, goal[1] - y
    err = math.atan2(math.sin(math.atan2(dy, dx) - theta), math.cos(math.atan2(dy, dx) - theta))
    w = float(np.clip(2.0 * err, -config.turn_rate, config.turn_rate))
    if abs(err) > config.turn_in_place:
        return 0.0, w
    v = float(min(config.speed, 1.5 * math.hypot(dx, dy)))
    return v, w


class ScriptedDriver(LeafSystem):
    """Input: robot_configuration (15, extended). Outputs: base_velocity,
    joint_velocity, head_command, gripper_command, waypoint_index."""

    def __init__(self, waypoints: np.ndarray, config: ScriptedDriverConfig | None = None):
        super().__init__()
        self.config = config or ScriptedDriverConfig()
        self._waypoints = np.atleast_2d(np.asarray(waypoints, dtype=float))[:, :2]
        self._q_port = self.DeclareVectorInputPort("robot_configuration", NX)
        self._index = self.DeclareDiscreteState(1)
        self.DeclarePeriodicDiscreteUpdateEvent(0.05, 0.0, self._advance)
        self.DeclareVectorOutputPort("base_velocity", 2, self._calc_base)
        self.DeclareVectorOutputPort("joint_velocity", 8, lambda c, o: o.SetZero())
        self.DeclareVectorOutputPort("head_command", 2, self._calc_head)
        self.DeclareVectorOutputPort("gripper_command", 1, lambda c, o: o.SetFromVector([layout.GRIPPER_MAX_OPENING]))

    def _current(self, context) -> int:
        return int(context.get_discrete_state(self._index).get_value()[0])

    def _advance(self, context, discrete_state) -> None:
        i = self._current(context)
        if i < len(self._waypoints):
            V = self._q_port.Eval(context)
            if np.hypot(*(self._waypoints[i] - V[:2])) < self.config.waypoint_tolerance:
                discrete_state.get_mutable_vector(self._index).SetFromVector([i + 1])

    def _calc_base(self, context, output: BasicVector) -> None:
        i = self._current(context)
        if i >= len(self._waypoints):
            output.SetZero()
            return
        V = self._q_port.Eval(context)
        output.SetFromVector(unicycle_command(V[0], V[1], V[2], self._waypoints[i], self.config))

    def _calc_head(self, context, output: BasicVector) -> None:
        t = context.get_time()
        c = self.config
        output.SetFromVector([c.head_pan_amplitude * math.sin(2 * math.pi * t / c.head_pan_period), c.head_tilt])
