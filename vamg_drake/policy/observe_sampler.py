"""Observe goal sampling: a base pose from which the head camera sees the target.

The paper's fallback when manipulation is blocked: N base poses on a circle of
fixed standoff distance around the target, facing it, with the arm stowed (a
safe configuration). A pose is valid when its base cell is navigable in the 2D
costmap with the footprint clearance, the whole configuration is
collision-free, and the target is inside the field of view with a line of
sight free of the robot and of map points. The valid pose nearest to the
current base wins.
"""

import dataclasses as dc
import time
from typing import Callable

import numpy as np

from vamg_drake.policy.pregrasp_sampler import BaseCostmap, CostmapConfig
from vamg_drake.policy.visibility import TargetVisibility
from vamg_drake.robot import layout

IsFreeFn = Callable[[np.ndarray], np.ndarray]


@dc.dataclass
class ObserveConfig:
    """Parameters of the observe sampler."""

    costmap: CostmapConfig = dc.field(default_factory=CostmapConfig)
    #: Standoff distances from the target tried in order [m].
    standoff: list[float] = dc.field(default_factory=lambda: [1.2, 1.6, 0.9])
    #: Base poses per standoff circle.
    num_angles: int = 36
    #: Weight of the yaw change against the distance when choosing the nearest [m/rad].
    yaw_weight: float = 0.2

    def __post_init__(self) -> None:
        self.validate()

    def validate(self) -> None:
        """Raises ValueError naming the bad field (the costmap's too)."""
        self.costmap.validate()
        if self.num_angles < 1 or not self.standoff or min(self.standoff) <= 0:
            raise ValueError("ObserveConfig: num_angles >= 1 and positive standoff distances required")


@dc.dataclass(frozen=True)
class ObserveResult:
    """Outcome of observe sampling (q and head are NaN on failure)."""

    success: bool
    q: np.ndarray
    head: np.ndarray
    num_samples: int
    elapsed_s: float
    failure_reason: str = ""


class ObserveSampler:
    """Samples a safe observation configuration for a target."""

    def __init__(self, visibility: TargetVisibility, config: ObserveConfig | None = None) -> None:
        self.visibility = visibility
        self.config = config or ObserveConfig()

    def sample(
        self,
        p_WM: np.ndarray,
        p_WT: np.ndarray,
        q_current: np.ndarray,
        is_free: IsFreeFn,
        rng: np.random.Generator | None = None,
        costmap: BaseCostmap | None = None,
    ) -> ObserveResult:
        t0 = time.perf_counter()
        cfg = self.config
        rng = rng if rng is not None else np.random.default_rng(0)
        p_WT = np.asarray(p_WT, dtype=float).reshape(3)
        q_current = np.asarray(q_current, dtype=float).reshape(layout.NQ)
        nan = lambda n: np.full(n, np.nan)  # noqa: E731
        if not np.all(np.isfinite(p_WT)):
            return ObserveResult(False, nan(layout.NQ), nan(2), 0, time.perf_counter() - t0, f"target is not finite: {p_WT}")
        if costmap is None:
            costmap = BaseCostmap.from_points(
                p_WM, cfg.costmap, include_xy=np.stack([p_WT[:2], q_current[:2]]), robot_xy=q_current[:2]
            )
        tried = 0
        for standoff in cfg.standoff:
            angles = (np.arange(cfg.num_angles) + rng.uniform()) * (2 * np.pi / cfg.num_angles)
            xy = p_WT[:2] + standoff * np.stack([np.cos(angles), np.sin(angles)], axis=1)
            tried += len(angles)
            ok = costmap.navigable_at(xy) & (costmap.clearance_at(xy) >= cfg.costmap.base_clearance)
            if not ok.any():
                continue
            xy = xy[ok]
            yaw = np.arctan2(p_WT[1] - xy[:, 1], p_WT[0] - xy[:, 0])
            q = np.array([layout.stow_configuration(x, y, th) for (x, y), th in zip(xy, yaw)])
            free = np.asarray(is_free(q), dtype=bool)
            if not free.any():
                continue
            q = q[free]
            visible, head = self.visibility.check(q, p_WT, p_WM)
            if not visible.any():
                continue
            q, head = q[visible], head[visible]
            dyaw = np.abs(layout.wrap_angle(q[:, layout.THETA] - q_current[layout.THETA]))
            cost = np.linalg.norm(q[:, layout.BASE_XY] - q_current[layout.BASE_XY], axis=1) + cfg.yaw_weight * dyaw
            i = int(np.argmin(cost))
            return ObserveResult(True, q[i], head[i], tried, time.perf_counter() - t0)
        return ObserveResult(
            False, nan(layout.NQ), nan(2), tried, time.perf_counter() - t0,
            f"no navigable, collision-free base pose sees the target at standoffs {cfg.standoff} m",
        )
