"""GazeOptimizer: the LeafSystem adapter over `vamg_drake.perception.gaze`."""

from __future__ import annotations

import dataclasses as dc
import logging
import time

import numpy as np
from pydrake.common.value import AbstractValue
from pydrake.systems.framework import BasicVector, EventStatus, LeafSystem, ValueProducer

from vamg_drake.perception.gaze import FetchGazeCameras, GazeConfig, GazeOptimizer as GazeOptimizerCore, decide_fetch_gaze
from vamg_drake.perception.trajectory_sweep import TrajectorySweep
from vamg_drake.planning.motion_messages import PlannedTrajectory
from vamg_drake.robot import layout
from vamg_drake.robot.head_camera import CameraIntrinsics
from vamg_drake.systems.timing import ModuleTimings

_log = logging.getLogger(__name__)


@dc.dataclass(frozen=True)
class _Sweep:
    """The GazeOptimizer's cached sweep of the followed trajectory (None: no trajectory to follow)."""

    sweep: TrajectorySweep | None = None


class GazeOptimizer(LeafSystem):
    """Chooses the head (pan, tilt) command at a fixed period.

    .. pydrake_system::

        name: GazeOptimizer
        input_ports:
        - trajectory (PlannedTrajectory, without a trajectory while planning)
        - trajectory_time (1-vector, optional: progress on the trajectory's clock)
        - target (3-vector p_WT, optional; NaN = no target)
        - robot_configuration (11-vector q)
        - look_request ((M, 3) array, optional: unseen points the tracker waits for)
        output_ports:
        - head_command (2-vector: pan, tilt [rad])

    The look-ahead window starts at `trajectory_time`, the tracker's progress
    (the time of its nearest path point): the robot falls behind the clock
    when it waits or slows down, and the window must not run ahead of it.
    Unconnected or NaN, progress is the context time (the planner's
    trajectories are shifted onto the simulation clock). A non-empty
    `look_request` overrides the window (`decide_fetch_gaze`). A rejected
    input (NaN configuration, malformed trajectory) is logged and the
    previous command is held.

    With ``start_sweep`` > 0 the head first looks left, then right (at
    ``sweep_tilt``) for that long, so the first plans know the room beside
    the robot, where an in-place turn sweeps the torso.
    """

    def __init__(self, intrinsics: CameraIntrinsics, config: GazeConfig | None = None, period: float = 0.1,
                 timings: ModuleTimings | None = None, start_sweep: float = 0.0, sweep_tilt: float = 0.8):
        super().__init__()
        self._timings = timings
        self._start_sweep = start_sweep
        self._sweep_tilt = sweep_tilt
        self._core = GazeOptimizerCore(intrinsics, config)
        self._cameras = FetchGazeCameras(self._core.candidates)
        self._trajectory_port = self.DeclareAbstractInputPort("trajectory", AbstractValue.Make(PlannedTrajectory()))
        self._time_port = self.DeclareVectorInputPort("trajectory_time", 1)
        self._target_port = self.DeclareVectorInputPort("target", 3)
        self._q_port = self.DeclareVectorInputPort("robot_configuration", layout.NQ)
        self._look_port = self.DeclareAbstractInputPort("look_request", AbstractValue.Make(np.empty((0, 3))))
        # The trajectory's sweep (sphere FK once per trajectory), recomputed only when the input changes.
        self._sweep_cache = self.DeclareCacheEntry(
            "trajectory_sweep",
            ValueProducer(allocate=lambda: AbstractValue.Make(_Sweep()), calc=self._calc_sweep),
            {self._trajectory_port.ticket()},
        )
        self._command_index = self.DeclareDiscreteState(BasicVector([0.0, 0.0]))
        self.DeclareStateOutputPort("head_command", self._command_index)
        self.DeclarePeriodicDiscreteUpdateEvent(period, 0.0, self._update)

    @property
    def core(self) -> GazeOptimizerCore:
        return self._core

    def _calc_sweep(self, context, value: AbstractValue) -> None:
        plan = self._trajectory_port.Eval(context) if self._trajectory_port.HasValue(context) else None
        trajectory = plan.trajectory if plan is not None else None
        sweep = None
        if trajectory is not None and trajectory.num_waypoints >= 2:
            dt = self._core.config.waypoint_dt
            sweep = TrajectorySweep(trajectory.times, trajectory.q, dt=dt)
        value.set_value(_Sweep(sweep))

    def _update(self, context, discrete_state) -> EventStatus:
        t = context.get_time()
        if t < self._start_sweep:
            pan = layout.HEAD_PAN_LIMITS[0] if t < 0.3 * self._start_sweep else layout.HEAD_PAN_LIMITS[1]
            discrete_state.get_mutable_vector(self._command_index).SetFromVector([pan, self._sweep_tilt])
            return EventStatus.Succeeded()
        q = np.asarray(self._q_port.Eval(context), dtype=float)
        target = None
        if self._target_port.HasValue(context):
            p = np.asarray(self._target_port.Eval(context), dtype=float)
            target = p if np.all(np.isfinite(p)) else None
        t_now = float(self._time_port.Eval(context)[0]) if self._time_port.HasValue(context) else np.nan
        if not np.isfinite(t_now):
            t_now = context.get_time()
        look = self._look_port.Eval(context) if self._look_port.HasValue(context) else None
        t0 = time.perf_counter()
        try:
            sweep = self._sweep_cache.Eval(context).sweep
            head = context.get_discrete_state(self._command_index).get_value()
            decision = decide_fetch_gaze(self._core, q, target, sweep, t_now, self._cameras, look, head)
            if self._timings is not None:
                self._timings.add("gaze", 1e3 * (time.perf_counter() - t0))
        except ValueError as e:
            _log.error("GazeOptimizer: input rejected, holding the previous head command: %s", e)
            return EventStatus.Succeeded()
        discrete_state.get_mutable_vector(self._command_index).SetFromVector([decision.pan, decision.tilt])
        return EventStatus.Succeeded()
