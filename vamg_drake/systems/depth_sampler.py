"""DepthSampler: samples the head camera at its rate into a `DepthFrame`."""

from __future__ import annotations

import dataclasses as dc
import time

import numpy as np
from pydrake.common.value import AbstractValue
from pydrake.math import RigidTransform
from pydrake.systems.framework import LeafSystem
from pydrake.systems.sensors import ImageDepth32F

from vamg_drake.systems.timing import ModuleTimings


@dc.dataclass(frozen=True)
class DepthFrame:
    """One depth image with its camera pose.

    Attributes:
        time: sim time of the capture [s] (-1 before the first one).
        depth: (H, W) float32 depth [m]; +inf beyond range, 0 too close.
        X_WC: (4, 4) pose of the depth optical frame C in the world.
    """

    time: float = -1.0
    depth: np.ndarray = dc.field(default_factory=lambda: np.zeros((0, 0), np.float32))
    X_WC: np.ndarray = dc.field(default_factory=lambda: np.full((4, 4), np.nan))

    @property
    def valid(self) -> bool:
        return self.time >= 0.0


class DepthSampler(LeafSystem):
    """Inputs: depth_image (ImageDepth32F), X_WC (RigidTransform). Output: depth_frame.

    Rendering happens when this system samples its input, so the time spent
    here is the depth render time (recorded as "depth_render" in `timings`).
    """

    def __init__(self, period: float, timings: ModuleTimings | None = None):
        super().__init__()
        self._timings = timings
        self._depth_port = self.DeclareAbstractInputPort("depth_image", AbstractValue.Make(ImageDepth32F()))
        self._pose_port = self.DeclareAbstractInputPort("X_WC", AbstractValue.Make(RigidTransform()))
        self._frame = self.DeclareAbstractState(AbstractValue.Make(DepthFrame()))
        self.DeclarePeriodicUnrestrictedUpdateEvent(period, 0.0, self._sample)
        self.DeclareStateOutputPort("depth_frame", self._frame)

    def _sample(self, context, state) -> None:
        t0 = time.perf_counter()
        image = self._depth_port.Eval(context)
        depth = np.array(image.data, dtype=np.float32, copy=True)[:, :, 0]
        if self._timings is not None:
            self._timings.add("depth_render", 1000.0 * (time.perf_counter() - t0))
        X_WC = self._pose_port.Eval(context).GetAsMatrix4()
        state.get_mutable_abstract_state(self._frame).set_value(DepthFrame(context.get_time(), depth, X_WC))
