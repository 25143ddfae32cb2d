"""GazeOptimizer: the LeafSystem adapter over `vamg_drake.perception.gaze`."""

from __future__ import annotations

import logging

import numpy as np
from pydrake.common.value import AbstractValue
from pydrake.systems.framework import BasicVector, EventStatus, LeafSystem

from vamg_drake.perception.gaze import GazeConfig, GazeOptimizer as GazeOptimizerCore, decide_fetch_gaze
from vamg_drake.robot import layout
from vamg_drake.robot.head_camera import CameraIntrinsics

_log = logging.getLogger(__name__)


class GazeOptimizer(LeafSystem):
    """Chooses the head (pan, tilt) command at a fixed period.

    .. pydrake_system::

        name: GazeOptimizer
        input_ports:
        - trajectory (TimedTrajectory or None; None while planning)
        - trajectory_time (1-vector, optional: progress on the trajectory's clock)
        - target (3-vector p_WT, optional; NaN = no target)
        - robot_configuration (11-vector q)
        output_ports:
        - head_command (2-vector: pan, tilt [rad])

    Progress defaults to the context time (the planner's trajectories are
    shifted onto the simulation clock). A rejected input (NaN configuration,
    malformed trajectory) is logged and the previous command is held.
    """

    def __init__(self, intrinsics: CameraIntrinsics, config: GazeConfig | None = None, period: float = 0.1):
        super().__init__()
        self._core = GazeOptimizerCore(intrinsics, config)
        self._trajectory_port = self.DeclareAbstractInputPort("trajectory", AbstractValue.Make(None))
        self._time_port = self.DeclareVectorInputPort("trajectory_time", 1)
        self._target_port = self.DeclareVectorInputPort("target", 3)
        self._q_port = self.DeclareVectorInputPort("robot_configuration", layout.NQ)
        self._command_index = self.DeclareDiscreteState(BasicVector([0.0, 0.0]))
        self.DeclareStateOutputPort("head_command", self._command_index)
        self.DeclarePeriodicDiscreteUpdateEvent(period, 0.0, self._update)

    @property
    def core(self) -> GazeOptimizerCore:
        return self._core

    def _update(self, context, discrete_state) -> EventStatus:
        q = np.asarray(self._q_port.Eval(context), dtype=float)
        target = None
        if self._target_port.HasValue(context):
            p = np.asarray(self._target_port.Eval(context), dtype=float)
            target = p if np.all(np.isfinite(p)) else None
        t_now = float(self._time_port.Eval(context)[0]) if self._time_port.HasValue(context) else context.get_time()
        trajectory = self._trajectory_port.Eval(context) if self._trajectory_port.HasValue(context) else None
        times = traj_q = None
        if trajectory is not None:
            times, traj_q = trajectory.times, trajectory.q
        try:
            decision = decide_fetch_gaze(self._core, q, target, times, traj_q, t_now)
        except ValueError as e:
            _log.error("GazeOptimizer: input rejected, holding the previous head command: %s", e)
            return EventStatus.Succeeded()
        discrete_state.get_mutable_vector(self._command_index).SetFromVector([decision.pan, decision.tilt])
        return EventStatus.Succeeded()
