"""RobotStateSelector: the robot's extended configuration and rates from the plant state."""

from __future__ import annotations

import numpy as np
from pydrake.systems.framework import BasicVector, LeafSystem

from vamg_drake.robot import layout
from vamg_drake.robot.kinematics import FINGER_SLICE, NX


class RobotStateSelector(LeafSystem):
    """Input: plant_state (full). Outputs: configuration (15,), velocity (15,),
    whole_body_configuration (11,), gripper_opening (1,).

    The first two in `kinematics.EXTENDED_JOINTS` order: q (11), head (2),
    fingers (2); whole_body_configuration is q alone
    (`layout.WHOLE_BODY_JOINTS`); gripper_opening is the measured gap between
    the fingers (the sum of the two finger joints) [m].
    """

    def __init__(self, num_positions: int, num_velocities: int, position_index: np.ndarray, velocity_index: np.ndarray):
        super().__init__()
        self._nq = num_positions
        self._qi = np.asarray(position_index, dtype=int)
        self._vi = np.asarray(velocity_index, dtype=int)
        self._state_port = self.DeclareVectorInputPort("plant_state", num_positions + num_velocities)
        self.DeclareVectorOutputPort("configuration", NX, self._calc_q)
        self.DeclareVectorOutputPort("velocity", NX, self._calc_v)
        self.DeclareVectorOutputPort("whole_body_configuration", layout.NQ, self._calc_q11)
        self.DeclareVectorOutputPort("gripper_opening", 1, self._calc_opening)

    def _calc_q(self, context, output: BasicVector) -> None:
        output.SetFromVector(self._state_port.Eval(context)[self._qi])

    def _calc_q11(self, context, output: BasicVector) -> None:
        output.SetFromVector(self._state_port.Eval(context)[self._qi[: layout.NQ]])

    def _calc_opening(self, context, output: BasicVector) -> None:
        fingers = self._state_port.Eval(context)[self._qi[FINGER_SLICE]]
        output.SetFromVector([float(np.sum(fingers))])

    def _calc_v(self, context, output: BasicVector) -> None:
        output.SetFromVector(self._state_port.Eval(context)[self._nq + self._vi])
