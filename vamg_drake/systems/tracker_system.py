"""WholeBodyTracker: the LeafSystem adapter over
`vamg_drake.control.whole_body_tracker.WholeBodyTrackerCore`."""

import copy
import dataclasses as dc
import logging

import numpy as np
from pydrake.common.value import AbstractValue
from pydrake.systems.framework import EventStatus, LeafSystem

from vamg_drake.control.whole_body_tracker import TrackerCommand, TrackerConfig, TrackerStatus, WholeBodyTrackerCore
from vamg_drake.perception.seen_space import LookGateConfig, SeenGrid, unseen_footprint
from vamg_drake.planning.motion_messages import PlannedTrajectory
from vamg_drake.robot import layout
from vamg_drake.systems.robot_command import BASE_VELOCITY_SIZE, JOINT_VELOCITY_SIZE

_log = logging.getLogger(__name__)


class TrackerMemory:
    """The tracker's abstract state: its core (the loaded path and the progress
    along it) and the trajectory object it loaded (compared by identity).

    A copy copies the core's scalars and shares its arrays, which the core
    replaces but never writes, and the trajectory, which is immutable: cloning
    a Context costs a few microseconds.
    """

    def __init__(self, core: WholeBodyTrackerCore, loaded=None) -> None:
        self.core = core
        self.loaded = loaded

    def __deepcopy__(self, memo) -> "TrackerMemory":
        return TrackerMemory(copy.copy(self.core), self.loaded)


@dc.dataclass(frozen=True, eq=False)
class LookGate:
    """The look-before-you-leave state of the loaded trajectory.

    Attributes:
        waited: how long the robot has held for unseen cells on this trajectory [s].
        points: (M, 3) probe points of the unseen cells it holds for now (empty: driving).
    """

    waited: float = 0.0
    points: np.ndarray = dc.field(default_factory=lambda: np.empty((0, 3)))


class WholeBodyTracker(LeafSystem):
    """The 20 Hz whole-body path tracker (closed-form one-step MPC).

    .. pydrake_system::

        name: WholeBodyTracker
        input_ports:
        - trajectory (PlannedTrajectory; its trajectory None: hold still)
        - robot_configuration (11-vector q)
        - seen_space (SeenGrid, optional)
        output_ports:
        - base_velocity (2-vector (v, w))
        - joint_velocity (8-vector: torso + 7 arm rates)
        - tracking (TrackerCommand)
        - trajectory_time (1-vector: trajectory time of the nearest path point; NaN without one)
        - look_request ((M, 3) array: the unseen points the robot waits for; empty while driving)

    Every `config.period` seconds a periodic unrestricted update reads q, loads
    the trajectory when its identity changed (`set_trajectory`; a rejected one
    is logged and stops the robot: zero command, status ``rejected`` with the
    reason), and stores the core's command; the outputs hold it between ticks
    (zero-order hold). `base_velocity` and `joint_velocity` connect to the
    `RobotCommandIntegrator`'s ports of the same names. An unconnected
    trajectory port, or a plan without a trajectory, means no trajectory:
    zero command, ``idle``.

    Look before you leave: with `seen_space` connected and ``look.enabled``,
    the robot holds (zero command, status ``waiting``) while the base footprint
    on the next ``look.lookahead_distance`` of the path covers floor cells the
    camera has not seen (`unseen_footprint`), and `look_request` lists them for
    the gaze. Each trajectory may hold at most ``look.max_wait`` seconds in
    all (a cell can stay occluded). The gate's state is in the Context.

    State: the core (the loaded path and the progress along it) with the
    trajectory it loaded (`TrackerMemory`), the look gate and the command are
    Context abstract state, so one built system runs in any number of Contexts.
    """

    def __init__(self, config: TrackerConfig | None = None, look: LookGateConfig | None = None):
        super().__init__()
        self._config = config or TrackerConfig()
        self._look = look or LookGateConfig()
        self._look.validate()
        self._trajectory_port = self.DeclareAbstractInputPort("trajectory", AbstractValue.Make(PlannedTrajectory()))
        self._q_port = self.DeclareVectorInputPort("robot_configuration", layout.NQ)
        self._seen_port = self.DeclareAbstractInputPort("seen_space", AbstractValue.Make(SeenGrid.around(np.zeros(2))))
        self._u_index = self.DeclareDiscreteState(BASE_VELOCITY_SIZE + JOINT_VELOCITY_SIZE)
        self._tracking_index = self.DeclareAbstractState(AbstractValue.Make(TrackerCommand()))
        self._gate_index = self.DeclareAbstractState(AbstractValue.Make(LookGate()))
        self._memory_index = self.DeclareAbstractState(AbstractValue.Make(TrackerMemory(
            WholeBodyTrackerCore(self._config))))
        self.DeclareStateOutputPort("tracking", self._tracking_index)
        self.DeclareVectorOutputPort("base_velocity", BASE_VELOCITY_SIZE, self._calc_base_velocity,
                                     {self.discrete_state_ticket(self._u_index)})
        self.DeclareVectorOutputPort("joint_velocity", JOINT_VELOCITY_SIZE, self._calc_joint_velocity,
                                     {self.discrete_state_ticket(self._u_index)})
        self.DeclareVectorOutputPort("trajectory_time", 1, self._calc_trajectory_time,
                                     {self.abstract_state_ticket(self._tracking_index)})
        self.DeclareAbstractOutputPort("look_request", lambda: AbstractValue.Make(np.empty((0, 3))),
                                       self._calc_look_request, {self.abstract_state_ticket(self._gate_index)})
        self.DeclarePeriodicUnrestrictedUpdateEvent(self._config.period, 0.0, self._update)

    def core(self, context) -> WholeBodyTrackerCore:
        """The tracker core of this system's `context` (for tests and diagnostics; do not mutate)."""
        return context.get_abstract_state(self._memory_index).get_value().core

    @property
    def config(self) -> TrackerConfig:
        return self._config

    @staticmethod
    def _load(memory: TrackerMemory, trajectory, q: np.ndarray) -> None:
        """Hands a new trajectory object to the core (None clears it)."""
        memory.loaded = trajectory
        if trajectory is None:
            memory.core.clear()
            return
        try:
            times, q_path = trajectory.times, trajectory.q
        except AttributeError:
            times = q_path = None
        if times is None or q_path is None:
            reason = f"trajectory value of type {type(trajectory).__name__} has no .times/.q"
            memory.core.reject(reason)
        else:
            reason = memory.core.set_trajectory(times, q_path, q, getattr(trajectory, "stops", ()))
        if reason:
            _log.warning("WholeBodyTracker rejected a trajectory: %s", reason)

    def _update(self, context, state) -> EventStatus:
        q = np.asarray(self._q_port.Eval(context), dtype=float)
        plan = self._trajectory_port.Eval(context) if self._trajectory_port.HasValue(context) else None
        trajectory = plan.trajectory if plan is not None else None
        gate = context.get_abstract_state(self._gate_index).get_value()
        memory: TrackerMemory = state.get_mutable_abstract_state(self._memory_index).get_mutable_value()
        if trajectory is not memory.loaded:
            self._load(memory, trajectory, q)
            gate = LookGate()
        previous = context.get_abstract_state(self._tracking_index).get_value()
        command = memory.core.command(q)
        if command.status == TrackerStatus.INVALID_STATE and previous.status != TrackerStatus.INVALID_STATE:
            _log.warning("WholeBodyTracker: %s; commanding zero", command.reason)
        gate = self._gate(context, q, command, gate, memory.core)
        if gate.points.shape[0]:
            command = dc.replace(command, base_velocity=np.zeros(BASE_VELOCITY_SIZE),
                                 joint_velocity=np.zeros(JOINT_VELOCITY_SIZE), status=TrackerStatus.WAITING,
                                 reason=f"{gate.points.shape[0]} unseen cells on the path ahead")
        state.get_mutable_abstract_state(self._gate_index).set_value(gate)
        state.get_mutable_discrete_state(self._u_index).set_value(command.u)
        state.get_mutable_abstract_state(self._tracking_index).set_value(command)
        return EventStatus.Succeeded()

    def _gate(self, context, q: np.ndarray, command: TrackerCommand, gate: LookGate,
              core: WholeBodyTrackerCore) -> LookGate:
        """The gate after this tick: the unseen cells to wait for (none once `max_wait` is spent)."""
        look = self._look
        if (not look.enabled or command.status != TrackerStatus.TRACKING or gate.waited >= look.max_wait
                or not self._seen_port.HasValue(context)):
            return LookGate(gate.waited) if gate.points.shape[0] else gate
        grid = self._seen_port.Eval(context)
        if not isinstance(grid, SeenGrid):
            return LookGate(gate.waited)
        points = unseen_footprint(grid, core.base_path_ahead(), q[:3], context.get_time(), look)
        if not points.shape[0]:
            if gate.points.shape[0]:
                _log.info("WholeBodyTracker t=%.2f: the path ahead is seen; driving (held %.2f s on this trajectory)",
                          context.get_time(), gate.waited)
            return LookGate(gate.waited)
        waited = gate.waited + self._config.period
        if waited >= look.max_wait:
            _log.warning("WholeBodyTracker t=%.2f: %d cells on the path ahead still unseen after %.1f s; driving on",
                         context.get_time(), points.shape[0], look.max_wait)
            return LookGate(waited)
        if not gate.points.shape[0]:
            _log.info("WholeBodyTracker t=%.2f: holding until %d unseen cells on the path ahead are seen",
                      context.get_time(), points.shape[0])
        return LookGate(waited, points)

    def _calc_trajectory_time(self, context, output) -> None:
        output.SetAtIndex(0, context.get_abstract_state(self._tracking_index).get_value().nearest_time)

    def _calc_look_request(self, context, output) -> None:
        output.set_value(context.get_abstract_state(self._gate_index).get_value().points)

    def _calc_base_velocity(self, context, output) -> None:
        output.SetFromVector(context.get_discrete_state(self._u_index).get_value()[:BASE_VELOCITY_SIZE])

    def _calc_joint_velocity(self, context, output) -> None:
        output.SetFromVector(context.get_discrete_state(self._u_index).get_value()[BASE_VELOCITY_SIZE:])
