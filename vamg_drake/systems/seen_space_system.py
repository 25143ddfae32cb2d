"""SeenSpace and HiddenCellMap: the LeafSystem adapters over `vamg_drake.perception.seen_space`."""

from __future__ import annotations

import logging

import numpy as np
from pydrake.common.value import AbstractValue
from pydrake.math import RigidTransform
from pydrake.systems.framework import EventStatus, LeafSystem
from pydrake.systems.sensors import ImageDepth32F

from vamg_drake.perception.raycast_map import PointMapSnapshot
from vamg_drake.perception.seen_space import SeenGrid, SeenSpaceConfig, with_hidden_cells
from vamg_drake.robot import layout
from vamg_drake.robot.head_camera import CameraIntrinsics
from vamg_drake.robot.spheres import SphereModel

_log = logging.getLogger(__name__)


class SeenSpace(LeafSystem):
    """Records which floor cells the head camera has seen, at a fixed period.

    .. pydrake_system::

        name: SeenSpace
        input_ports:
        - depth_image (ImageDepth32F)
        - X_WC (RigidTransform, the depth optical frame)
        - robot_configuration (11-vector q, optional: the robot itself is no obstacle)
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

        self._spheres = SphereModel.load()
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
        p_WB = spheres = None
        if self._q_port.HasValue(context):
            q = np.asarray(self._q_port.Eval(context), float)
            if np.all(np.isfinite(q)):
                p_WB, spheres = q[:2], (self._spheres.world_spheres(q), self._spheres.radius)
        new = grid.observe(depth, X_WC, self._intrinsics, context.get_time(), p_WB, spheres)
        if new is not grid:
            state.get_mutable_abstract_state(self._grid_index).set_value(new)
        return EventStatus.Succeeded()


class HiddenCellMap(LeafSystem):
    """The planner's map: the ray-cast map plus points in the hidden cells' columns.

    .. pydrake_system::

        name: HiddenCellMap
        input_ports:
        - point_map (PointMapSnapshot or None)
        - seen_space (SeenGrid or None)
        output_ports:
        - point_map (PointMapSnapshot or None)

    Stateless: the output is `with_hidden_cells` of the inputs (the map itself
    while no cell is hidden), so the base is not planned under a surface whose
    underside the head has not seen.
    """

    def __init__(self):
        super().__init__()
        self._map_port = self.DeclareAbstractInputPort("point_map", AbstractValue.Make(PointMapSnapshot.empty()))
        self._seen_port = self.DeclareAbstractInputPort("seen_space", AbstractValue.Make(SeenGrid.around(np.zeros(2))))
        self.DeclareAbstractOutputPort("point_map", lambda: AbstractValue.Make(PointMapSnapshot.empty()), self._calc)

    def _calc(self, context, output) -> None:
        snapshot = self._map_port.Eval(context) if self._map_port.HasValue(context) else None
        grid = self._seen_port.Eval(context) if self._seen_port.HasValue(context) else None
        output.set_value(with_hidden_cells(snapshot, grid if isinstance(grid, SeenGrid) else None))
