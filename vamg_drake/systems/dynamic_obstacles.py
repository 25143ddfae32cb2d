"""DynamicObstacleDriver: makes the scenario's obstacles appear or move.

Per event (see `world.scenario`):
* `AppearAtDistance`: parked below the floor until the robot base is within
  `trigger_distance` (horizontal) of the obstacle, then raised into place;
* `AppearAtPhase`: parked until the policy reports `phase`, then raised;
* `MoveAlongPath`: follows its path at its speed from `start_time`.
Appearance is latched. Each obstacle's PD actuators track the output.
"""

from __future__ import annotations

import dataclasses as dc

import numpy as np
from pydrake.common.value import AbstractValue
from pydrake.systems.framework import BasicVector, LeafSystem

from vamg_drake.robot.kinematics import NX
from vamg_drake.world.scenario import AppearAtDistance, AppearAtPhase, MoveAlongPath
from vamg_drake.world.scene_geometry import ObstacleHandle


@dc.dataclass(frozen=True)
class ObstacleEvents:
    """Latched appearance flags and times (None = not yet) per obstacle name."""

    appeared_at: tuple[tuple[str, float | None], ...] = ()

    def time_of(self, name: str) -> float | None:
        return dict(self.appeared_at).get(name)


def obstacle_target(handle: ObstacleHandle, t: float, appeared: bool) -> tuple[np.ndarray, np.ndarray]:
    """Desired position and velocity (3,) of an obstacle's x, y, z joints."""
    event = handle.event
    if isinstance(event, MoveAlongPath):
        p = event.position_at(t)
        dt = 1e-3
        return p, (event.position_at(t + dt) - p) / dt
    if appeared:
        return np.asarray(event.xyz, float), np.zeros(3)
    return handle.p_W_hidden.copy(), np.zeros(3)


class DynamicObstacleDriver(LeafSystem):
    """Inputs: robot_configuration (15,), phase (str, optional).
    Outputs: one `<name>_desired_state` (6,) per obstacle; `events` (ObstacleEvents)."""

    def __init__(self, obstacles: dict[str, ObstacleHandle], period: float = 0.05):
        super().__init__()
        self._obstacles = dict(obstacles)
        self.DeclareVectorInputPort("robot_configuration", NX)
        self._phase_port = self.DeclareAbstractInputPort("phase", AbstractValue.Make(""))
        self._events = self.DeclareAbstractState(
            AbstractValue.Make(ObstacleEvents(tuple((n, None) for n in self._obstacles)))
        )
        self.DeclarePeriodicUnrestrictedUpdateEvent(period, 0.0, self._update)
        for name in self._obstacles:
            self.DeclareVectorOutputPort(
                f"{name}_desired_state", 6, lambda c, o, name=name: self._calc_desired(c, o, name)
            )
        self.DeclareStateOutputPort("events", self._events)

    def _update(self, context, state) -> None:
        events: ObstacleEvents = context.get_abstract_state(self._events).get_value()
        V = self.get_input_port(0).Eval(context)
        phase = self._phase_port.Eval(context) if self._phase_port.HasValue(context) else ""
        t = context.get_time()
        flags = []
        for name, when in events.appeared_at:
            event = self._obstacles[name].event
            if when is None:
                if isinstance(event, AppearAtDistance):
                    if np.hypot(V[0] - event.xyz[0], V[1] - event.xyz[1]) <= event.trigger_distance:
                        when = t
                elif isinstance(event, AppearAtPhase):
                    if phase == event.phase:
                        when = t
                elif isinstance(event, MoveAlongPath) and t >= event.start_time:
                    when = t
            flags.append((name, when))
        state.get_mutable_abstract_state(self._events).set_value(ObstacleEvents(tuple(flags)))

    def _calc_desired(self, context, output: BasicVector, name: str) -> None:
        events: ObstacleEvents = context.get_abstract_state(self._events).get_value()
        p, v = obstacle_target(self._obstacles[name], context.get_time(), events.time_of(name) is not None)
        output.SetFromVector(np.r_[p, v])
