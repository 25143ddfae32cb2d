"""Pre-grasp configuration sampling (paper appendix "Pre-Grasp Configuration Sampling").

Three proposal distributions and three constraint checks, by rejection:

* ``p_geo`` -- base poses from a 2D costmap of the map points (`BaseCostmap`,
  exactly the appendix's recipe: height filter 0.05-1.5 m, XY projection,
  0.05 m cells, 3x3 binary closing, largest free connected component,
  Euclidean distance transform, ``c = exp(-d / 2.0)``, sample proportional to
  ``(1 - c)^2`` among cells within manipulation radius of the target), the
  yaw facing the target;
* ``p_torso`` -- the torso height map's best height for the target's position
  in the sampled base frame;
* ``p_ee`` -- pre-grasp end-effector poses on the 10 cm sphere around the
  target, approach (+x of G) pointing at the target, random roll about the
  approach, filtered by the capability map;

then arm-only IK (base and torso fixed, `FastIk`), collision (an ``is_free``
callable, e.g. `SphereCollisionChecker.is_free`) and self-occlusion of the target
from the head camera (`TargetVisibility`). Bases are visited one at a time
(``samples_per_base`` end-effector samples each, as one batch) and the first
valid configuration is returned, as in the paper's Algorithm.
"""

import dataclasses as dc
import time
from typing import Callable

import numpy as np
from scipy import ndimage

from vamg_drake.planning.hybrid_astar import grid_distances
from vamg_drake.policy.arm_chain import base_poses
from vamg_drake.policy.ik import FastIk
from vamg_drake.policy.kinematic_maps import KinematicMaps
from vamg_drake.policy.visibility import TargetVisibility
from vamg_drake.robot import layout

IsFreeFn = Callable[[np.ndarray], np.ndarray]


@dc.dataclass
class CostmapConfig:
    """The 2D base costmap of ``p_geo`` (paper values)."""

    z_min: float = 0.05
    z_max: float = 1.5
    resolution: float = 0.05
    #: d_max of c = exp(-d / d_max) [m].
    decay_distance: float = 2.0
    #: Binary closing kernel (cells).
    closing_size: int = 3
    #: Margin added around the points' extent [m].
    padding: float = 0.5
    #: Smallest obstacle distance of a base cell [m] (the base footprint radius plus margin).
    base_clearance: float = 0.35

    def __post_init__(self) -> None:
        self.validate()

    def validate(self) -> None:
        """Raises ValueError naming the bad field."""
        if not 0.0 <= self.z_min < self.z_max:
            raise ValueError(f"CostmapConfig: need 0 <= z_min < z_max, got {self.z_min}, {self.z_max}")
        if self.resolution <= 0 or self.decay_distance <= 0:
            raise ValueError("CostmapConfig: resolution and decay_distance must be > 0")


@dc.dataclass(frozen=True)
class BaseCostmap:
    """A 2D costmap on a grid; cell (i, j) centre = origin + (i, j) * resolution.

    Attributes:
        occupied: (nx, ny) obstacle cells after closing.
        navigable: (nx, ny) the largest free connected component.
        distance: (nx, ny) distance to the nearest obstacle cell [m].
        cost: (nx, ny) exp(-distance / decay_distance).
    """

    occupied: np.ndarray
    navigable: np.ndarray
    distance: np.ndarray
    cost: np.ndarray
    origin: np.ndarray
    resolution: float

    @staticmethod
    def from_points(
        p_WM: np.ndarray,
        config: CostmapConfig,
        include_xy: np.ndarray | None = None,
        robot_xy: np.ndarray | None = None,
    ) -> "BaseCostmap":
        """Builds the costmap from world points (N, 3).

        Args:
            p_WM: map points.
            config: costmap parameters.
            include_xy: (K, 2) positions the grid must cover (robot, target).
            robot_xy: the robot's position. The navigable region is the paper's
                largest free component, except that when the robot stands in a
                free cell its own component is used: seen from inside a room,
                the unexplored outside can be the larger one.
        """
        cfg = config
        p = np.asarray(p_WM, dtype=float).reshape(-1, 3)
        p = p[np.all(np.isfinite(p), axis=1)]
        p = p[(p[:, 2] >= cfg.z_min) & (p[:, 2] <= cfg.z_max)]  # (1) height filter
        xy = p[:, :2]  # (2) projection
        extent = [xy] + ([np.reshape(include_xy, (-1, 2))] if include_xy is not None else [])
        extent = np.concatenate(extent) if sum(e.shape[0] for e in extent) else np.zeros((1, 2))
        lo = extent.min(axis=0) - cfg.padding
        hi = extent.max(axis=0) + cfg.padding
        shape = np.ceil((hi - lo) / cfg.resolution).astype(int) + 1
        occupied = np.zeros(shape, dtype=bool)  # (3) rasterize
        idx = np.round((xy - lo) / cfg.resolution).astype(int)
        occupied[idx[:, 0], idx[:, 1]] = True
        if cfg.closing_size > 1:  # (4) closing
            occupied = ndimage.binary_closing(
                occupied, structure=np.ones((cfg.closing_size, cfg.closing_size), bool), border_value=0
            )
        labels, n = ndimage.label(~occupied)  # (5) largest free component
        own = 0
        if robot_xy is not None:
            r = np.round((np.asarray(robot_xy, float)[:2] - lo) / cfg.resolution).astype(int)
            if np.all((r >= 0) & (r < shape)):
                own = int(labels[r[0], r[1]])
        if n == 0:
            navigable = np.zeros_like(occupied)
        elif own > 0:
            navigable = labels == own
        else:
            sizes = np.bincount(labels.ravel())
            sizes[0] = 0
            navigable = labels == int(np.argmax(sizes))
        if occupied.any():  # (6) EDT from obstacle cells
            distance = ndimage.distance_transform_edt(~occupied) * cfg.resolution
        else:
            distance = np.full(shape, np.inf)
        cost = np.exp(-distance / cfg.decay_distance)  # (7) exponential decay
        return BaseCostmap(occupied, navigable, distance, cost, lo, cfg.resolution)

    def cell_centers(self) -> np.ndarray:
        """(nx, ny, 2) world XY of every cell centre."""
        i, j = np.meshgrid(np.arange(self.cost.shape[0]), np.arange(self.cost.shape[1]), indexing="ij")
        return self.origin + np.stack([i, j], -1) * self.resolution

    def cell_of(self, p_xy: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Integer cell indices (K, 2) of XY points and whether they are on the grid."""
        idx = np.round((np.reshape(p_xy, (-1, 2)) - self.origin) / self.resolution).astype(int)
        inside = np.all((idx >= 0) & (idx < np.array(self.cost.shape)), axis=1)
        return np.where(inside[:, None], idx, 0), inside

    def clearance_at(self, p_xy: np.ndarray) -> np.ndarray:
        """Distance to the nearest obstacle cell at XY points (0 off the grid)."""
        return self.value_at(self.distance, p_xy, outside=0.0)

    def navigable_at(self, p_xy: np.ndarray) -> np.ndarray:
        idx, inside = self.cell_of(p_xy)
        return inside & self.navigable[idx[:, 0], idx[:, 1]]

    def travel_distance(self, start_xy: np.ndarray, clearance: float) -> np.ndarray:
        """Grid path lengths [m] from ``start_xy`` (nx, ny) over the navigable
        cells at least ``clearance`` from obstacles, inf where unreachable (all
        inf when the start lies outside the grid). The cells within
        ``clearance`` of the start count as free: a robot parked beside a table
        stands closer to it than ``clearance`` and must still be able to leave."""
        idx, inside = self.cell_of(np.reshape(start_xy, (1, 2)))
        if not inside[0]:
            return np.full(self.distance.shape, np.inf)
        i, j = (int(v) for v in idx[0])
        centers = self.cell_centers()
        near = np.linalg.norm(centers - centers[i, j], axis=-1) <= clearance
        free = self.navigable & ((self.distance >= clearance) | near)
        free[i, j] = True
        return grid_distances(free, i, j, self.resolution)

    def value_at(self, grid: np.ndarray, p_xy: np.ndarray, outside: float = np.inf) -> np.ndarray:
        """``grid``'s (nx, ny) values at positions (K, 2) (``outside`` beyond the grid)."""
        idx, inside = self.cell_of(p_xy)
        return np.where(inside, grid[idx[:, 0], idx[:, 1]], outside)

    def sample_bases(
        self,
        p_WT: np.ndarray,
        n: int,
        radius: tuple[float, float],
        min_clearance: float,
        rng: np.random.Generator,
        weighted: bool = True,
    ) -> np.ndarray:
        """``p_geo``: n base poses (n, 3) [x, y, yaw facing the target] (fewer if none fit).

        Cells must be navigable, at least ``min_clearance`` from obstacles and at a
        horizontal distance in ``radius`` from the target; they are drawn with
        probability proportional to (1 - c)^2 (uniformly when not ``weighted``),
        with a uniform jitter inside the cell.
        """
        centers = self.cell_centers()
        r = np.linalg.norm(centers - np.asarray(p_WT, float)[:2], axis=-1)
        ok = self.navigable & (self.distance >= min_clearance) & (r >= radius[0]) & (r <= radius[1])
        weights = np.where(ok, (1.0 - self.cost) ** 2 if weighted else 1.0, 0.0).ravel()
        total = weights.sum()
        if not total > 0:
            return np.zeros((0, 3))
        pick = rng.choice(weights.size, size=n, p=weights / total)
        xy = centers.reshape(-1, 2)[pick] + rng.uniform(-0.5, 0.5, (n, 2)) * self.resolution
        yaw = np.arctan2(p_WT[1] - xy[:, 1], p_WT[0] - xy[:, 0])
        return np.concatenate([xy, yaw[:, None]], axis=1)


@dc.dataclass
class PregraspConfig:
    """Parameters of the pre-grasp sampler (paper: 20 bases x 128 arm/torso samples)."""

    costmap: CostmapConfig = dc.field(default_factory=CostmapConfig)
    num_bases: int = 20
    samples_per_base: int = 128
    #: Radius of the end-effector sphere around the target [m] (paper: 0.10).
    ee_radius: float = 0.10
    #: Horizontal distance of base samples from the target [m] (the arm's reach).
    base_radius: list[float] = dc.field(default_factory=lambda: [0.35, 1.05])
    #: Use the capability map to filter end-effector samples.
    use_capability: bool = True
    #: Use the torso-height map (else a uniform torso height): an ablation switch.
    use_torso_map: bool = True
    #: Weight base cells by (1 - c)^2 (else uniform over the eligible cells): an ablation switch.
    weight_bases: bool = True
    seed: int = 0
    #: Arm seed of the IK (7 joints; empty = the current arm). From the tucked
    #: stow pose, damped least squares lands in contorted solutions that the
    #: planner then has to unfold to; a reaching "ready" seed gives natural
    #: ones (in a furnished room: 13/20 pre-grasps planned vs 7/20 from stow).
    ik_seed_arm: list[float] = dc.field(default_factory=lambda: [0.0, -0.5, 0.0, 1.2, 0.0, 0.9, 0.0])
    #: Valid, visible samples per base given to ``sample``'s ``accept`` test.
    max_accept_tests: int = 3
    #: Torso travel left free above the pre-grasp's torso [m]: the grasp keeps
    #: the torso and lifts the object with it (`BehaviourConfig.lift_height`);
    #: a torso near its top lifted the object only 8 cm.
    lift_headroom: float = 0.15
    #: Visit the sampled bases nearest first by path length over the costmap
    #: from the robot (else in the order drawn). The first base that yields a
    #: valid pre-grasp wins, so drawn order sent the robot to whichever side
    #: of a table came first, and a goal invalidated by newly seen furniture
    #: was replaced by one across the room; bases near the robot also lie in
    #: space it has seen, so they are invalidated less often.
    order_bases_by_travel: bool = True
    #: Clearance from obstacles of the cells the travel distance runs over [m]
    #: (the base's footprint radius).
    travel_clearance: float = 0.30
    #: Bases within this distance of a tried base (a pre-grasp goal reached
    #: without a grasp: `sample`'s ``tried_xy``) come after all others: from
    #: there the camera sees what it saw, and nearest first would return
    #: to the same side of the target every time [m].
    tried_radius: float = 0.5
    #: A robot within this distance of its last pre-grasp goal's base has reached it [m].
    reached_tolerance: float = 0.15

    def __post_init__(self) -> None:
        self.validate()

    def validate(self) -> None:
        """Raises ValueError naming the bad field (the costmap's too)."""
        self.costmap.validate()
        if self.num_bases < 1 or self.samples_per_base < 1:
            raise ValueError("PregraspConfig: num_bases and samples_per_base must be >= 1")
        if len(self.ik_seed_arm) not in (0, 7):
            raise ValueError(f"PregraspConfig.ik_seed_arm must have 0 or 7 joints, got {len(self.ik_seed_arm)}")
        if len(self.base_radius) != 2 or not 0 <= self.base_radius[0] < self.base_radius[1]:
            raise ValueError(f"PregraspConfig.base_radius must be (min, max) with min < max, got {self.base_radius}")
        for name in ("travel_clearance", "tried_radius", "reached_tolerance"):
            if not getattr(self, name) >= 0.0:
                raise ValueError(f"PregraspConfig.{name} must be >= 0, got {getattr(self, name)}")


@dc.dataclass(frozen=True)
class PregraspResult:
    """Outcome of one pre-grasp sampling call.

    Attributes:
        success: a valid configuration was found.
        q: (11,) the pre-grasp configuration (NaN on failure).
        X_WG: (4, 4) its end-effector pose (NaN on failure).
        head: (2,) pan/tilt that looks at the target from q (NaN on failure).
        num_samples: end-effector samples drawn (incl. the returned one's batch).
        funnel: counts passing each stage (capability, ik, collision, visibility).
        elapsed_s: wall time.
        failure_reason: empty on success.
    """

    success: bool
    q: np.ndarray
    X_WG: np.ndarray
    head: np.ndarray
    num_samples: int
    funnel: dict
    elapsed_s: float
    failure_reason: str = ""


def sample_approach_poses(p_WT: np.ndarray, radius: float, n: int, rng: np.random.Generator) -> np.ndarray:
    """``p_ee``: n poses X_WG on the sphere of ``radius`` around the target, +x pointing at it,
    a uniformly random roll about the approach."""
    u = rng.normal(size=(n, 3))
    u /= np.linalg.norm(u, axis=1, keepdims=True)
    x_axis = -u
    helper = np.where(np.abs(x_axis[:, 2:3]) < 0.9, [[0.0, 0.0, 1.0]], [[1.0, 0.0, 0.0]])
    a = np.cross(x_axis, helper)
    a /= np.linalg.norm(a, axis=1, keepdims=True)
    b = np.cross(x_axis, a)
    roll = rng.uniform(0, 2 * np.pi, n)
    y_axis = np.cos(roll)[:, None] * a + np.sin(roll)[:, None] * b
    X = np.zeros((n, 4, 4))
    X[:, :3, 0] = x_axis
    X[:, :3, 1] = y_axis
    X[:, :3, 2] = np.cross(x_axis, y_axis)
    X[:, :3, 3] = np.asarray(p_WT, float) + radius * u
    X[:, 3, 3] = 1.0
    return X


class PregraspSampler:
    """Rejection sampler of whole-body pre-grasp configurations."""

    def __init__(
        self,
        maps: KinematicMaps,
        ik: FastIk,
        visibility: TargetVisibility,
        config: PregraspConfig | None = None,
    ) -> None:
        self.maps = maps
        self.ik = ik
        self.visibility = visibility
        self.config = config or PregraspConfig()

    def sample(
        self,
        p_WM: np.ndarray,
        p_WT: np.ndarray,
        q_current: np.ndarray,
        is_free: IsFreeFn,
        rng: np.random.Generator | None = None,
        max_samples: int | None = None,
        costmap: BaseCostmap | None = None,
        ee_poses: np.ndarray | None = None,
        accept: Callable[[np.ndarray], bool] | None = None,
        tried_xy: np.ndarray | None = None,
    ) -> PregraspResult:
        """Samples a pre-grasp configuration for target ``p_WT`` under map points ``p_WM``.

        Args:
            p_WM: (N, 3) map points.
            p_WT: (3,) target.
            q_current: (11,) current configuration (the arm seed for IK).
            is_free: batched collision check of configurations (K, 11) -> (K,).
            rng: random generator (seeded from the config when None).
            max_samples: end-effector sample budget (default num_bases x samples_per_base).
            costmap: a prebuilt costmap (built from p_WM when None).
            ee_poses: (K, 4, 4) end-effector poses to draw p_ee from instead of
                the sphere around the target (e.g. the pre-grasp poses of grasp
                candidates, so that the grasp stage succeeds from the result).
            accept: a preference among valid, visible configurations (11,)
                (e.g. "the grasp stage finds a grasp from here"): at most
                `PregraspConfig.max_accept_tests` per base are tested, and the
                first valid, visible sample is returned when none passes (a
                closer view may still bring better grasps).
            tried_xy: (K, 2) bases tried before: with `order_bases_by_travel`,
                drawn bases within `PregraspConfig.tried_radius` of one are
                visited last.
        """
        t0 = time.perf_counter()
        cfg = self.config
        rng = rng if rng is not None else np.random.default_rng(cfg.seed)
        p_WT = np.asarray(p_WT, dtype=float).reshape(3)
        q_current = np.asarray(q_current, dtype=float).reshape(layout.NQ)
        budget = max_samples if max_samples is not None else cfg.num_bases * cfg.samples_per_base
        funnel = {"bases": 0, "samples": 0, "capability": 0, "ik": 0, "collision": 0, "visible": 0}
        if accept is not None:
            funnel["accepted"] = 0
        nan_q = np.full(layout.NQ, np.nan)

        def fail(reason: str) -> PregraspResult:
            return PregraspResult(False, nan_q, np.full((4, 4), np.nan), np.full(2, np.nan),
                                  funnel["samples"], funnel, time.perf_counter() - t0, reason)

        if not np.all(np.isfinite(p_WT)):
            return fail(f"target is not finite: {p_WT}")
        if costmap is None:
            costmap = BaseCostmap.from_points(
                p_WM, cfg.costmap, include_xy=np.stack([p_WT[:2], q_current[:2]]), robot_xy=q_current[:2]
            )
        n_bases = int(np.ceil(budget / cfg.samples_per_base))
        bases = costmap.sample_bases(p_WT, n_bases, cfg.base_radius, cfg.costmap.base_clearance, rng, cfg.weight_bases)
        if bases.shape[0] == 0:
            return fail("no navigable base cell within manipulation radius of the target (costmap)")
        if cfg.order_bases_by_travel:
            travel = costmap.value_at(costmap.travel_distance(q_current[:2], cfg.travel_clearance), bases[:, :2])
            straight = np.linalg.norm(bases[:, :2] - q_current[:2], axis=1)
            tried = np.zeros(len(bases), dtype=bool)
            if tried_xy is not None and len(tried_xy):
                gap = np.linalg.norm(bases[:, None, :2] - np.asarray(tried_xy, float)[None, :, :2], axis=2)
                tried = gap.min(axis=1) <= cfg.tried_radius
            bases = bases[np.lexsort((straight, travel, tried))]  # untried first, then nearest, unreachable last
        seed_arm = np.asarray(cfg.ik_seed_arm, float) if len(cfg.ik_seed_arm) else q_current[layout.ARM]
        fallback: PregraspResult | None = None  # the first valid, visible sample when `accept` passes none
        for base in bases:
            n = min(cfg.samples_per_base, budget - funnel["samples"])
            if n <= 0:
                break
            funnel["bases"] += 1
            funnel["samples"] += n
            q_base = np.concatenate([base, [0.0], seed_arm])
            X_WB = base_poses(q_base)[0]
            X_BW = np.linalg.inv(X_WB)
            p_BT = X_BW[:3, :3] @ p_WT + X_BW[:3, 3]
            if ee_poses is not None and len(ee_poses):
                X_WG = np.asarray(ee_poses, float)[rng.integers(len(ee_poses), size=n)]
            else:
                X_WG = sample_approach_poses(p_WT, cfg.ee_radius, n, rng)
            X_BG = X_BW[None] @ X_WG
            keep = np.ones(n, dtype=bool)
            if cfg.use_capability:
                keep = self.maps.capability.is_reachable(X_BG)
            funnel["capability"] += int(keep.sum())
            if not keep.any():
                continue
            # p_torso: the best torso for the target (per sample: its own EE bin when the target's is empty).
            if cfg.use_torso_map:
                h = self.maps.torso_height.best_torso(p_BT[None])[0]
                torso = np.full(n, h) if np.isfinite(h) else self.maps.torso_height.best_torso(X_BG[:, :3, 3])
            else:
                torso = np.full(n, np.nan)
            missing = ~np.isfinite(torso)
            torso_top = max(layout.Q_UPPER[layout.TORSO] - cfg.lift_headroom, layout.Q_LOWER[layout.TORSO])
            torso[missing] = rng.uniform(layout.Q_LOWER[layout.TORSO], torso_top, missing.sum())
            torso = np.minimum(torso, torso_top)
            seeds = np.tile(q_base, (n, 1))
            seeds[:, layout.TORSO] = torso
            idx = np.flatnonzero(keep)
            q, ok = self.ik.solve(X_WG[idx], seeds[idx], torso_fixed=True)
            funnel["ik"] += int(ok.sum())
            if not ok.any():
                continue
            idx, q = idx[ok], q[ok]
            free = np.asarray(is_free(q), dtype=bool)
            funnel["collision"] += int(free.sum())
            if not free.any():
                continue
            idx, q = idx[free], q[free]
            visible, head = self.visibility.check(q, p_WT)
            funnel["visible"] += int(visible.sum())
            for i in np.flatnonzero(visible)[: cfg.max_accept_tests if accept is not None else 1]:
                if accept is not None:
                    if fallback is None:
                        fallback = PregraspResult(True, q[i], X_WG[idx[i]], head[i], 0, funnel, 0.0)
                    if not accept(q[i]):
                        continue
                    funnel["accepted"] += 1
                return PregraspResult(True, q[i], X_WG[idx[i]], head[i], funnel["samples"], funnel,
                                      time.perf_counter() - t0)
        if fallback is not None:
            return dc.replace(fallback, num_samples=funnel["samples"], elapsed_s=time.perf_counter() - t0)
        accepted = f", accepted {funnel['accepted']}" if accept is not None else ""
        return fail(
            f"no valid pre-grasp in {funnel['samples']} samples "
            f"(capability {funnel['capability']}, IK {funnel['ik']}, collision-free {funnel['collision']}, "
            f"visible {funnel['visible']}{accepted})"
        )
