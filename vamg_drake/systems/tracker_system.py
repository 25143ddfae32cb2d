"""WholeBodyTracker: the LeafSystem adapter over
`vamg_drake.control.whole_body_tracker.WholeBodyTrackerCore`."""

import logging

import numpy as np
from pydrake.common.value import AbstractValue
from pydrake.systems.framework import EventStatus, LeafSystem

from vamg_drake.control.whole_body_tracker import TrackerCommand, TrackerConfig, TrackerStatus, WholeBodyTrackerCore
from vamg_drake.robot import layout
from vamg_drake.systems.robot_command import BASE_VELOCITY_SIZE, JOINT_VELOCITY_SIZE

_log = logging.getLogger(__name__)


def _unwrap_trajectory(value):
    """The TimedTrajectory-like object inside a port value (or None).

    Accepts a `TimedTrajectory` (anything with `.times` and `.q`), None, or a
    container with a `.trajectory` attribute (the planner's `PlannedTrajectory`),
    so the planner's `trajectory` port can be connected directly.
    """
    if value is None or (hasattr(value, "times") and hasattr(value, "q")):
        return value
    if hasattr(value, "trajectory"):
        return _unwrap_trajectory(value.trajectory)
    return value


class WholeBodyTracker(LeafSystem):
    """The 20 Hz whole-body path tracker (closed-form one-step MPC).

    .. pydrake_system::

        name: WholeBodyTracker
        input_ports:
        - trajectory (TimedTrajectory, PlannedTrajectory or None)
        - robot_configuration (11-vector q)
        output_ports:
        - base_velocity (2-vector (v, w))
        - joint_velocity (8-vector: torso + 7 arm rates)
        - tracking (TrackerCommand)

    Every `config.period` seconds a periodic unrestricted update reads q, loads
    the trajectory when its identity changed (`set_trajectory`; a rejected one
    is logged and stops the robot: zero command, status ``rejected`` with the
    reason), and stores the core's command; the outputs hold it between ticks
    (zero-order hold). `base_velocity` and `joint_velocity` connect to the
    `RobotCommandIntegrator`'s ports of the same names. An unconnected
    trajectory port, or None, means no trajectory: zero command, ``idle``.

    The core (the loaded path and its progress) lives in the system object:
    use one Context per system instance. It is reset by the initialization event.
    """

    def __init__(self, config: TrackerConfig | None = None):
        super().__init__()
        self._config = config or TrackerConfig()
        self._core = WholeBodyTrackerCore(self._config)
        self._trajectory_port = self.DeclareAbstractInputPort("trajectory", AbstractValue.Make(None))
        self._q_port = self.DeclareVectorInputPort("robot_configuration", layout.NQ)
        self._u_index = self.DeclareDiscreteState(BASE_VELOCITY_SIZE + JOINT_VELOCITY_SIZE)
        self._tracking_index = self.DeclareAbstractState(AbstractValue.Make(TrackerCommand()))
        self.DeclareStateOutputPort("tracking", self._tracking_index)
        self.DeclareVectorOutputPort("base_velocity", BASE_VELOCITY_SIZE, self._calc_base_velocity)
        self.DeclareVectorOutputPort("joint_velocity", JOINT_VELOCITY_SIZE, self._calc_joint_velocity)
        self.DeclareInitializationUnrestrictedUpdateEvent(self._initialize)
        self.DeclarePeriodicUnrestrictedUpdateEvent(self._config.period, 0.0, self._update)
        self._loaded = None  # the trajectory object loaded into the core (identity)

    @property
    def core(self) -> WholeBodyTrackerCore:
        return self._core

    @property
    def config(self) -> TrackerConfig:
        return self._config

    def _initialize(self, context, state) -> EventStatus:
        self._core.clear()
        self._loaded = None
        return EventStatus.Succeeded()

    def _load(self, trajectory, q: np.ndarray) -> None:
        """Hands a new trajectory object to the core (None clears it)."""
        self._loaded = trajectory
        if trajectory is None:
            self._core.clear()
            return
        try:
            times, q_path = trajectory.times, trajectory.q
        except AttributeError:
            times = q_path = None
        if times is None or q_path is None:
            reason = f"trajectory value of type {type(trajectory).__name__} has no .times/.q"
            self._core.reject(reason)
        else:
            reason = self._core.set_trajectory(times, q_path, q, getattr(trajectory, "stops", ()))
        if reason:
            _log.warning("WholeBodyTracker rejected a trajectory: %s", reason)

    def _update(self, context, state) -> EventStatus:
        q = np.asarray(self._q_port.Eval(context), dtype=float)
        value = self._trajectory_port.Eval(context) if self._trajectory_port.HasValue(context) else None
        trajectory = _unwrap_trajectory(value)
        if trajectory is not self._loaded:
            self._load(trajectory, q)
        previous = context.get_abstract_state(self._tracking_index).get_value()
        command = self._core.command(q)
        if command.status == TrackerStatus.INVALID_STATE and previous.status != TrackerStatus.INVALID_STATE:
            _log.warning("WholeBodyTracker: %s; commanding zero", command.reason)
        state.get_mutable_discrete_state(self._u_index).set_value(command.u)
        state.get_mutable_abstract_state(self._tracking_index).set_value(command)
        return EventStatus.Succeeded()

    def _calc_base_velocity(self, context, output) -> None:
        output.SetFromVector(context.get_discrete_state(self._u_index).get_value()[:BASE_VELOCITY_SIZE])

    def _calc_joint_velocity(self, context, output) -> None:
        output.SetFromVector(context.get_discrete_state(self._u_index).get_value()[BASE_VELOCITY_SIZE:])
