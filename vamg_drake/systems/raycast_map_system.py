"""RayCastMap: the LeafSystem adapter over `vamg_drake.perception.raycast_map.PointMap`."""

from __future__ import annotations

import logging
import time

import numpy as np
from pydrake.common.value import AbstractValue
from pydrake.math import RigidTransform
from pydrake.systems.framework import EventStatus, LeafSystem
from pydrake.systems.sensors import ImageDepth32F

from vamg_drake.perception.raycast_map import PointMap, RayCastMapConfig
from vamg_drake.robot import layout
from vamg_drake.robot.head_camera import CameraIntrinsics
from vamg_drake.robot.spheres import SphereModel
from vamg_drake.systems.timing import ModuleTimings

_log = logging.getLogger(__name__)


class SharedPointMap:
    """A handle to a `PointMap` whose copies share the map (see `RayCastMap`)."""

    def __init__(self, point_map: PointMap):
        self.map = point_map

    def __copy__(self) -> "SharedPointMap":
        return SharedPointMap(self.map)

    def __deepcopy__(self, memo) -> "SharedPointMap":
        return SharedPointMap(self.map)


class RayCastMap(LeafSystem):
    """Integrates head depth images into the ray-cast map M_t at a fixed period.

    .. pydrake_system::

        name: RayCastMap
        input_ports:
        - depth_image (ImageDepth32F)
        - X_WC (RigidTransform, the depth optical frame)
        - robot_configuration (11-vector q, for self-filtering)
        output_ports:
        - point_map (PointMapSnapshot)

    The map core lives in the context's abstract state; each periodic update
    reads the three inputs, runs `PointMap.update` with the robot's spheres at
    q, and publishes a fresh immutable `PointMapSnapshot` (only when the map
    changed). Rejected inputs are logged by the core and leave the map unchanged.

    Copy semantics: the state holds a `SharedPointMap` handle, and copies of the
    handle share one map. Drake copies abstract state twice per unrestricted
    update, and a deep copy of a 400k-point map costs ~30 ms; sharing keeps the
    update at the core's cost. An initialization event gives every simulated
    context a fresh map, so separate episodes never share one; a context cloned
    mid-episode does share its map with the original.
    """

    def __init__(
        self,
        intrinsics: CameraIntrinsics,
        config: RayCastMapConfig | None = None,
        period: float = 0.1,
        self_filter: bool = True,
        timings: ModuleTimings | None = None,
        prior_points: np.ndarray | None = None,
    ):
        super().__init__()
        self._intrinsics = intrinsics
        self._config = config or RayCastMapConfig()
        #: Points every fresh map starts with (``prior_map: static``); None: an empty map.
        self._prior = None if prior_points is None else np.ascontiguousarray(prior_points, dtype=float).reshape(-1, 3)
        self._timings = timings
        self._spheres = None
        if self_filter:
            self._spheres = SphereModel.load()
        self._depth_port = self.DeclareAbstractInputPort(
            "depth_image", AbstractValue.Make(ImageDepth32F(intrinsics.width, intrinsics.height))
        )
        self._pose_port = self.DeclareAbstractInputPort("X_WC", AbstractValue.Make(RigidTransform()))
        self._q_port = self.DeclareVectorInputPort("robot_configuration", layout.NQ)
        core = PointMap(intrinsics, self._config)
        self._core_index = self.DeclareAbstractState(AbstractValue.Make(SharedPointMap(core)))
        self._snapshot_index = self.DeclareAbstractState(AbstractValue.Make(core.snapshot()))
        self.DeclareStateOutputPort("point_map", self._snapshot_index)
        self.DeclareInitializationUnrestrictedUpdateEvent(self._initialize)
        self.DeclarePeriodicUnrestrictedUpdateEvent(period, 0.0, self._update)

    def map_core(self, context) -> PointMap:
        """The live map of `context` (for tests and diagnostics; do not mutate)."""
        return context.get_abstract_state(self._core_index).get_value().map

    def _initialize(self, context, state) -> EventStatus:
        core = PointMap(self._intrinsics, self._config)
        if self._prior is not None:
            core.add_points(self._prior)
        state.get_mutable_abstract_state(self._core_index).set_value(SharedPointMap(core))
        state.get_mutable_abstract_state(self._snapshot_index).set_value(core.snapshot())
        return EventStatus.Succeeded()

    def _update(self, context, state) -> EventStatus:
        core: PointMap = state.get_mutable_abstract_state(self._core_index).get_mutable_value().map
        t0 = time.perf_counter()
        depth = self._depth_port.Eval(context).data  # renders the camera image
        t1 = time.perf_counter()
        X_WC = self._pose_port.Eval(context).GetAsMatrix4()
        centers = radii = None
        if self._spheres is not None:
            q = np.asarray(self._q_port.Eval(context), dtype=float)
            if np.all(np.isfinite(q)):
                centers, radii = self._spheres.world_spheres(q), self._spheres.radius
            else:
                centers, radii = np.full((1, 3), np.nan), np.ones(1)  # the core logs and rejects
        stats = core.update(depth, X_WC, centers, radii)
        if self._timings is not None:
            self._timings.add("depth_render", 1e3 * (t1 - t0))
            self._timings.add("map_update", 1e3 * (time.perf_counter() - t1))
        if stats.ok and (stats.num_added or stats.num_carved):
            state.get_mutable_abstract_state(self._snapshot_index).set_value(core.snapshot())
        return EventStatus.Succeeded()
