"""SeenSpace: the LeafSystem adapter over `vamg_drake.perception.seen_space.SeenGrid`."""

from __future__ import annotations

import logging

import numpy as np
from pydrake.common.value import AbstractValue
from pydrake.math import RigidTransform
from pydrake.systems.framework import EventStatus, LeafSystem
from pydrake.systems.sensors import ImageDepth32F

from vamg_drake.perception.seen_space import SeenGrid, SeenSpaceConfig
from vamg_drake.robot import layout
from vamg_drake.robot.head_camera import CameraIntrinsics

_log = logging.getLogger(__name__)


class SeenSpace(LeafSystem):
    """Records which floor cells the head camera has seen, at a fixed period.

    .. pydrake_system::

        name: SeenSpace
        input_ports:
        - depth_image (ImageDepth32F)
        - X_WC (RigidTransform, the depth optical frame)
        - robot_configuration (11-vector q, optional: the robot's own base is no obstacle)
        output_ports:
        - seen_space (SeenGrid)

    The grid (centred on `center_xy`, the robot's start) is the Context's
    abstract state; each update replaces it by `SeenGrid.observe` of the
    current image (the same object when nothing new was seen). A rejected
    image (wrong size, non-finite pose) is logged and leaves the grid unchanged.
    """

    def __init__(self, intrinsics: CameraIntrinsics, center_xy: np.ndarray, config: SeenSpaceConfig | None = None,
                 period: float = 0.1):
        super().__init__()
        self._intrinsics = intrinsics
        self._config = config or SeenSpaceConfig()
        self._config.validate()
        self._center = np.asarray(center_xy, float).reshape(2)
        self._depth_port = self.DeclareAbstractInputPort(
            "depth_image", AbstractValue.Make(ImageDepth32F(intrinsics.width, intrinsics.height)))
        self._pose_port = self.DeclareAbstractInputPort("X_WC", AbstractValue.Make(RigidTransform()))
        self._q_port = self.DeclareVectorInputPort("robot_configuration", layout.NQ)
        self._grid_index = self.DeclareAbstractState(AbstractValue.Make(SeenGrid.around(self._center, self._config)))
        self.DeclareStateOutputPort("seen_space", self._grid_index)
        self.DeclareInitializationUnrestrictedUpdateEvent(self._initialize)
        self.DeclarePeriodicUnrestrictedUpdateEvent(period, 0.0, self._update)

    def _initialize(self, context, state) -> EventStatus:
        state.get_mutable_abstract_state(self._grid_index).set_value(SeenGrid.around(self._center, self._config))
        return EventStatus.Succeeded()

    def _update(self, context, state) -> EventStatus:
        grid: SeenGrid = context.get_abstract_state(self._grid_index).get_value()
        depth = self._depth_port.Eval(context).data
        X_WC = self._pose_port.Eval(context).GetAsMatrix4()
        if not np.all(np.isfinite(X_WC)) or depth.size != self._intrinsics.width * self._intrinsics.height:
            _log.error("SeenSpace: rejected image %s or pose; grid unchanged", depth.shape)
            return EventStatus.Succeeded()
        p_WB = np.asarray(self._q_port.Eval(context)[:2], float) if self._q_port.HasValue(context) else None
        new = grid.observe(depth, X_WC, self._intrinsics, context.get_time(), p_WB)
        if new is not grid:
            state.get_mutable_abstract_state(self._grid_index).set_value(new)
        return EventStatus.Succeeded()
