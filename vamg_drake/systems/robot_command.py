"""RobotCommandIntegrator: velocity commands -> PD targets for the Fetch's actuators."""

from __future__ import annotations

import numpy as np
from pydrake.systems.framework import BasicVector, LeafSystem

from vamg_drake.control.command_integration import integrate_command
from vamg_drake.robot import layout
from vamg_drake.robot.kinematics import NX

#: Sizes of the command ports.
BASE_VELOCITY_SIZE = 2  # (v [m/s], w [rad/s]) in the base frame
JOINT_VELOCITY_SIZE = 8  # torso + 7 arm joints
HEAD_COMMAND_SIZE = 2  # (pan, tilt) position targets
GRIPPER_COMMAND_SIZE = 1  # opening between the fingers [m]


#: Anti-windup: the desired torso/arm positions stay within this of the
#: measured ones [m or rad] (see `RobotCommandIntegrator`).
MAX_JOINT_LEAD = np.r_[0.02, np.full(7, 0.1)]


class RobotCommandIntegrator(LeafSystem):
    """Integrates velocity commands into the robot's PD desired state.

    Input ports:
        base_velocity: (v, w) unicycle command in the base frame.
        joint_velocity: torso and 7 arm joint rates.
        head_command: (pan, tilt) position targets.
        gripper_command: finger opening target [m] (0 closed, 0.1 open).
        measured_configuration (optional): the robot's extended configuration
            (15,). When connected, the desired torso and arm positions are kept
            within `MAX_JOINT_LEAD` of it (anti-windup): a joint whose actuator
            saturates (the shoulder pan, 33.8 N m, with the arm unfolded) fell
            0.55 rad behind the integrated target, and the tracker's feedback
            on the measured state then drove it through a limit cycle at the
            rate limits, so that a motion could stall at a joint stop.
    Output ports:
        desired_state: [q_d, v_d] for the robot's actuators, in actuator order.
        desired_configuration: the extended desired configuration (15,).
    """

    def __init__(self, initial_configuration: np.ndarray, actuator_joint_order: np.ndarray, period: float = 0.01):
        super().__init__()
        self._order = np.asarray(actuator_joint_order, dtype=int)
        self._period = period
        self._base_port = self.DeclareVectorInputPort("base_velocity", BASE_VELOCITY_SIZE)
        self._joint_port = self.DeclareVectorInputPort("joint_velocity", JOINT_VELOCITY_SIZE)
        self._head_port = self.DeclareVectorInputPort("head_command", HEAD_COMMAND_SIZE)
        self._gripper_port = self.DeclareVectorInputPort("gripper_command", GRIPPER_COMMAND_SIZE)
        self._measured_port = self.DeclareVectorInputPort("measured_configuration", NX)
        V0 = np.asarray(initial_configuration, dtype=float)
        self._state = self.DeclareDiscreteState(np.r_[V0, np.zeros(NX)])
        self.DeclarePeriodicDiscreteUpdateEvent(period, 0.0, self._update)
        self.DeclareVectorOutputPort("desired_state", 2 * len(self._order), self._calc_desired_state)
        self.DeclareVectorOutputPort("desired_configuration", NX, self._calc_configuration)

    def _update(self, context, discrete_state) -> None:
        x = context.get_discrete_state(self._state).get_value()
        V_next, Vdot = integrate_command(
            x[:NX],
            self._base_port.Eval(context),
            self._joint_port.Eval(context),
            self._head_port.Eval(context),
            float(self._gripper_port.Eval(context)[0]),
            self._period,
        )
        if self._measured_port.HasValue(context):
            measured = np.asarray(self._measured_port.Eval(context), dtype=float)[layout.TORSO_ARM]
            if np.all(np.isfinite(measured)):
                joints = V_next[layout.TORSO_ARM]
                V_next[layout.TORSO_ARM] = np.clip(joints, measured - MAX_JOINT_LEAD, measured + MAX_JOINT_LEAD)
        discrete_state.get_mutable_vector(self._state).SetFromVector(np.r_[V_next, Vdot])

    def _calc_desired_state(self, context, output: BasicVector) -> None:
        x = context.get_discrete_state(self._state).get_value()
        output.SetFromVector(np.r_[x[:NX][self._order], x[NX:][self._order]])

    def _calc_configuration(self, context, output: BasicVector) -> None:
        output.SetFromVector(context.get_discrete_state(self._state).get_value()[:NX])
