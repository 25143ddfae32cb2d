"""DynamicObstacleDriver: makes the scenario's obstacles appear or move.

Per event (see `world.scenario`):
* `AppearAtDistance`: parked below the floor until the robot base is within
  `trigger_distance` (horizontal) of the obstacle (and, with
  `heading_towards`, heading towards it), then raised into place;
* `AppearAtPhase`: parked until the policy reports `phase`, then raised at
  the first of its candidate centres that keeps `min_robot_clearance` from
  every robot link origin (none: it stays parked);
* `MoveAlongPath`: follows its path at its speed from `start_time`.
Appearance is latched. Each obstacle's PD actuators track the output.
"""

from __future__ import annotations

import dataclasses as dc

import numpy as np
from pydrake.common.value import AbstractValue
from pydrake.systems.framework import BasicVector, LeafSystem

from vamg_drake.robot.kinematics import NX, FetchKinematics
from vamg_drake.world.scenario import AppearAtDistance, AppearAtPhase, MoveAlongPath
from vamg_drake.world.scene_geometry import ObstacleHandle


@dc.dataclass(frozen=True)
class ObstacleEvents:
    """Latched appearance times (None = not yet) and positions per obstacle name.

    Attributes:
        appeared_at: (name, time or None) per obstacle.
        placed_at: (name, shape centre) for obstacles that appeared at a
            chosen candidate position; a triggered `AppearAtPhase` obstacle
            without a clear candidate is listed with None (it stays parked).
    """

    appeared_at: tuple[tuple[str, float | None], ...] = ()
    placed_at: tuple[tuple[str, tuple[float, float, float] | None], ...] = ()

    def time_of(self, name: str) -> float | None:
        return dict(self.appeared_at).get(name)

    def position_of(self, name: str) -> tuple[float, float, float] | None:
        return dict(self.placed_at).get(name)


def approach_triggered(p_WB: np.ndarray, yaw: float, p_WO: np.ndarray, distance: float, heading_towards: bool) -> bool:
    """Whether a base at ``p_WB`` (xy) with heading ``yaw`` triggers an obstacle at ``p_WO`` (xy).

    The base must be within ``distance`` (horizontal) and, with
    ``heading_towards``, head towards the obstacle (positive dot product of
    the heading and the direction to the obstacle).
    """
    d = np.asarray(p_WO[:2], float) - np.asarray(p_WB[:2], float)
    if np.hypot(d[0], d[1]) > distance:
        return False
    return not heading_towards or float(d[0] * np.cos(yaw) + d[1] * np.sin(yaw)) > 1e-9


def first_clear_candidate(candidates: np.ndarray, p_W_links: np.ndarray, clearance: float) -> int | None:
    """Index of the first (K, 3) candidate at least ``clearance`` from every (L, 3) link origin, or None."""
    if clearance <= 0.0:
        return 0
    d = np.linalg.norm(candidates[:, None, :] - p_W_links[None, :, :], axis=2).min(axis=1)
    clear = np.flatnonzero(d >= clearance)
    return int(clear[0]) if len(clear) else None


def obstacle_target(
    handle: ObstacleHandle, t: float, appeared: bool, placed: tuple[float, float, float] | None = None
) -> tuple[np.ndarray, np.ndarray]:
    """Desired position and velocity (3,) of an obstacle's x, y, z joints."""
    event = handle.event
    if isinstance(event, MoveAlongPath):
        p = event.position_at(t)
        dt = 1e-3
        return p, (event.position_at(t + dt) - p) / dt
    if appeared:
        return np.asarray(event.xyz if placed is None else placed, float), np.zeros(3)
    return handle.p_W_hidden.copy(), np.zeros(3)


class DynamicObstacleDriver(LeafSystem):
    """Inputs: robot_configuration (15,), phase (str, optional).
    Outputs: one `<name>_desired_state` (6,) per obstacle; `events` (ObstacleEvents)."""

    def __init__(self, obstacles: dict[str, ObstacleHandle], period: float = 0.05):
        super().__init__()
        self._obstacles = dict(obstacles)
        self._configuration_port = self.DeclareVectorInputPort("robot_configuration", NX)
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
        V = self._configuration_port.Eval(context)
        phase = self._phase_port.Eval(context) if self._phase_port.HasValue(context) else ""
        t = context.get_time()
        flags = []
        placed = dict(events.placed_at)
        for name, when in events.appeared_at:
            event = self._obstacles[name].event
            if when is None and name not in placed:
                if isinstance(event, AppearAtDistance):
                    if approach_triggered(V[:2], V[2], np.asarray(event.xyz), event.trigger_distance, event.heading_towards):
                        when = t
                elif isinstance(event, AppearAtPhase):
                    if phase == event.phase:
                        when, placed[name] = self._place(event, V, t)
                elif isinstance(event, MoveAlongPath) and t >= event.start_time:
                    when = t
            flags.append((name, when))
        state.get_mutable_abstract_state(self._events).set_value(ObstacleEvents(tuple(flags), tuple(placed.items())))

    @staticmethod
    def _place(event: AppearAtPhase, V: np.ndarray, t: float) -> tuple[float | None, tuple[float, float, float] | None]:
        candidates = event.candidates()
        links = FetchKinematics.instance().poses_extended(V)[0, :, :3, 3] if event.min_robot_clearance > 0 else np.zeros((0, 3))
        k = first_clear_candidate(candidates, links, event.min_robot_clearance)
        if k is None:
            return None, None
        return t, tuple(float(x) for x in candidates[k])

    def _calc_desired(self, context, output: BasicVector, name: str) -> None:
        events: ObstacleEvents = context.get_abstract_state(self._events).get_value()
        appeared = events.time_of(name) is not None
        p, v = obstacle_target(self._obstacles[name], context.get_time(), appeared, events.position_of(name))
        output.SetFromVector(np.r_[p, v])
