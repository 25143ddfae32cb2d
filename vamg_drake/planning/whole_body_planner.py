"""The real-time whole-body planner (the paper's motion policy pi_r).

Hierarchical, after the paper: a base path from Hybrid A* (global guidance)
with Reeds-Shepp connections; arm motions from RRT-Connect at fixed base
placements; base and arm discretized separately and synchronized into
whole-body states that are validated in batches by the sphere checker.

One attempt:
  0. (Once per plan, deterministic, expansion-capped) base path start->goal
     (`HybridAStar`, which first tries one Reeds-Shepp curve) on a two-band
     2D clearance map (`base_costmap`, exact distances to the primitives,
     cached per environment), with exact whole-body pose checks where the
     2D discs are in doubt and near a parked start/goal.
  1. The base path shortened by randomized Reeds-Shepp shortcuts.
  2. Whole body, cheapest first: (a) the arm interpolated start->goal in sync
     with the whole base path; (b) fold to the travel pose over the first
     part of the path (or after driving off holding the start arm) and
     unfold over the last part (or before approaching holding the goal
     arm), along the straight joint-space line or the arm roadmap's
     self-collision-free path to the travel pose (`ArmRoadmap`), no search;
     (c) RRT-Connect over (progress along the base path, torso + arm), for
     its first `along_path_first_iterations`; (d) as (b) with fixed-base
     searches at the start placement and at or before the goal (the
     roadmap searched lazily, then RRT-Connect); (c) resumed up to its
     iteration cap; (e) fold/unfold with fixed-base searches for other
     carry poses.
  3. Refinement of the fixed-base arm pieces: randomized shortcutting and
     B-spline smoothing (kept only where valid, after its own dense check);
     the checked pieces joined (they must meet exactly) and re-interpolated
     at the checker's motion resolution.
  4. Time parametrization within `layout.V_MAX`.
Budget, deterministic so that a plan (and an episode) does not depend on the
machine's speed or load: `PlannerConfig.attempt_budget_iterations`
RRT-Connect iterations per attempt over all its searches (the other stages
are bounded by their own counts), `max_attempts` attempts, each with its own
seeded generator. `attempt_wall_limit_s` is only a safety net against a
pathological attempt; when it fires the plan depends on the machine, so it is
logged and counted (`PlanResult.wall_limit_hits`, `WholeBodyPlanner.wall_limit_hits`).

Start and goal inside the padding. The checker inflates every sphere by half
the motion resolution (+ `extra_padding`) so that straight motions between
checked states are free, and by `self_padding` in the self-collision tests
(a tracking margin). A configuration is *in collision* only when the
unpadded spheres (radius + `extra_padding`) penetrate the environment, two
unpadded spheres of a self-collision pair overlap (or a sphere enters a body
primitive), or a joint is outside its limits (`SphereCollisionChecker.unpadded`). A start (goal) that is free but inside the
padding (in closed loop: tracking error, or map points appearing as the robot
approaches furniture) is accepted: the path first leaves the padding by the
shortest short motion that reaches a padded-free configuration (the base
straight back/forward along its heading, a turn in place, the torso/arm
toward the travel pose, or base + arm together), and the plan proper starts
there (for the goal: ends there, followed by the motion into the goal).
Such an end piece is checked with the unpadded spheres at
`end_check_resolution` (states that close, so a sphere may pass between two
checked states by at most half that spacing, which the sphere model's slack
over the robot's geometry covers). The same rule validates any path
(`path_is_valid`, used by `trajectory_is_valid`): padded-colliding states are
allowed only in a leading piece (leaving the start) and a trailing piece
(reaching the goal), and those pieces must be free for the unpadded spheres.
The subgoal sampler checks goals with the padded checker, a stricter test, so
every goal it returns is accepted here.
"""

import dataclasses
import logging
import math
import time

import numba
import numpy as np

from vamg_drake.planning import smoothing, whole_body_rrt
from vamg_drake.planning.arm_roadmap import ArmRoadmap
from vamg_drake.planning.base_costmap import base_costmap
from vamg_drake.planning.collision_environment import CollisionEnvironment
from vamg_drake.planning.sphere_collision import CollisionCheckerConfig, SphereCollisionChecker, densify, densify_indexed
from vamg_drake.planning.hybrid_astar import Footprint2D, HybridAStar, HybridAStarConfig
from vamg_drake.planning.trajectory import TimedTrajectory
from vamg_drake.planning.whole_body_rrt import KernelRRTConfig, RRTConnectSearch, WholeBodySearchSpace
from vamg_drake.robot import layout

log = logging.getLogger(__name__)


class FailureReason:
    """Why a plan failed (`PlanResult.reason`)."""

    NONE = ""
    INVALID_INPUT = "invalid_input"
    START_IN_COLLISION = "start_in_collision"
    GOAL_IN_COLLISION = "goal_in_collision"
    NO_BASE_PATH = "no_base_path"
    NO_ARM_PATH = "no_arm_path"
    TIMEOUT = "timeout"


@dataclasses.dataclass
class PlannerConfig:
    """Whole-body planner parameters (loadable with `yaml_load_typed`).

    Attributes:
        attempt_budget_iterations: RRT-Connect iterations one attempt may
            run over all its searches (along-path and fixed-base); used up,
            the attempt ends with TIMEOUT. A work budget, not a time budget,
            so that the plan is the same on any machine at any load. Most
            plans of the 50 bench problems need none (the cheap stages
            succeed) or 32-64; an attempt whose every search fails uses 1200
            (~0.1 s on an idle machine); the cap stops the few attempts that
            would run all twelve fixed-base searches to their limits.
        attempt_wall_limit_s: wall-clock safety net of one attempt [s] (10x
            the 0.2 s time budget this planner had before): past it the
            attempt stops (or skips its B-spline smoothing) and the plan is
            no longer reproducible, which is logged and counted.
        max_attempts: attempts (each with fresh random samples).
        seed: random seed; the same seed, problem and map give the same plan.
        turning_radius: minimum turning radius of the base curves [m].
        costmap_resolution: cell size of the base's 2D clearance map [m].
        motion_resolution: max sphere displacement between checked states [m].
        extra_padding: extra sphere inflation [m].
        base_extra_padding: further inflation of the base's spheres while
            planning [m] (`CollisionCheckerConfig.base_extra_padding`): 3 cm,
            the base's lateral tracking error next to furniture.
        occupied_cells: the arm's spheres test a map's occupied cells, not
            its points (`CollisionCheckerConfig.occupied_cells`).
        base_shortcut_iterations: Reeds-Shepp shortcut tries on the base path.
        arm_shortcut_iterations: shortcut tries on each fixed-base arm path.
        along_path_shortcut_iterations: shortcut tries on an arm path found
            along the base path (its motions are long: ~2 ms per try).
        bspline_samples: samples of the smoothed fixed-base arm paths.
        rrt_step: RRT-Connect extension step (max-norm) [rad].
        rrt_max_iterations: RRT-Connect iteration limit per arm motion.
        along_path_first_iterations: iterations of the along-path search (c)
            before the fixed-base searches (d) are tried; it resumes after
            them up to `rrt_max_iterations`.
        arm_floor_clearance: the arm's (padded) spheres stay this far above
            the floor at every checked state [m]; the map has no floor points
            (`CollisionCheckerConfig.arm_floor_clearance`). None: no floor.
        placement_fractions: where along the base path (fraction of its
            length) the arm may start unfolding; 1.0 = at the goal placement.
        fold_fractions: fractions of the base path over which the arm may fold
            into the travel pose; 0.0 = fold at the start placement.
        hybrid_astar_max_expansions: search limit of the base planner (the
            50 procedural bench problems need at most ~1400, a detour around
            a table in a ReplicaCAD apartment 13000-16000; a hopeless search
            costs ~30 us per expansion, so the cap bounds a failure to ~1.2 s
            of wall time; planning takes no simulated time).
        end_check_resolution: max sphere displacement [m] between states
            checked with the unpadded spheres, on the end pieces of a path
            that leave (reach) a start (goal) inside the padding.
        escape_distance: longest base motion [m] tried to leave the padding.
        footprint_split_z: the base's 2D footprint is two discs: the robot's
            parts reaching below this height [m] (the base) against the
            obstacles of their height band, the rest (torso, travel arm)
            against theirs; see `WholeBodyPlanner._travel_footprint`.
        travel_torso_arm: torso + 7 arm joints (8,) held while driving. Inside
            the base footprint like `layout.Q_ARM_STOW`, but raised and folded
            with free space around it (the stow pose sits in a tight pocket of
            self-collision space that sampling-based arm planning rarely leaves):
            5 cm from self-collision (unpadded spheres, head sweep included),
            within the base's 0.35 m radius.
    """

    attempt_budget_iterations: int = 1500
    attempt_wall_limit_s: float = 2.0
    max_attempts: int = 3
    seed: int = 0
    turning_radius: float = 0.4
    costmap_resolution: float = 0.025
    motion_resolution: float = 0.03
    extra_padding: float = 0.0
    base_extra_padding: float = 0.03
    occupied_cells: bool = True
    arm_floor_clearance: float | None = 0.02
    base_shortcut_iterations: int = 15
    arm_shortcut_iterations: int = 25
    along_path_shortcut_iterations: int = 6
    bspline_samples: int = 25
    rrt_step: float = 0.6
    rrt_max_iterations: int = 400
    along_path_first_iterations: int = 64
    placement_fractions: list[float] = dataclasses.field(default_factory=lambda: [0.5, 0.7, 0.85, 1.0])
    fold_fractions: list[float] = dataclasses.field(default_factory=lambda: [0.15, 0.3, 0.0])
    hybrid_astar_max_expansions: int = 40000
    end_check_resolution: float = 0.005
    escape_distance: float = 0.3
    footprint_split_z: float = 0.3
    travel_torso_arm: list[float] = dataclasses.field(
        default_factory=lambda: [0.167, 0.43, 1.214, -0.738, 1.461, -0.093, 1.597, -1.9])

    def checker_config(self) -> CollisionCheckerConfig:
        """The sphere collision checker's parameters (its padding) of this
        planner; the subgoal samplers check their goals with the same."""
        return CollisionCheckerConfig(motion_resolution=self.motion_resolution, extra_padding=self.extra_padding,
                                      base_extra_padding=self.base_extra_padding,
                                      occupied_cells=self.occupied_cells,
                                      arm_floor_clearance=self.arm_floor_clearance)


@dataclasses.dataclass(frozen=True, eq=False)
class PlanResult:
    """The outcome of a planning request.

    Attributes:
        success: True when `trajectory` is valid.
        reason: a `FailureReason` value ("" on success).
        trajectory: the timed whole-body trajectory (times from 0), or None.
        timings: milliseconds per stage ("base", "arm", "refine", "total").
        attempts: attempts used.
        message: a human-readable detail of the failure.
        rrt_iterations: RRT-Connect iterations run over all attempts.
        wall_limit_hits: attempts stopped or cut short by the wall-clock
            safety net (`PlannerConfig.attempt_wall_limit_s`); nonzero means
            this result depends on the machine's speed.
    """

    success: bool
    reason: str
    trajectory: TimedTrajectory | None
    timings: dict
    attempts: int = 0
    message: str = ""
    rrt_iterations: int = 0
    wall_limit_hits: int = 0


@dataclasses.dataclass(frozen=True)
class _BasePlan:
    poses: np.ndarray
    expansions: int


class _Timeout(Exception):
    pass


class _AttemptBudget:
    """The work one attempt may do: RRT-Connect iterations over all its
    searches (deterministic), and a wall-clock safety net whose firing is
    remembered (`wall_hit`) because the outcome then depends on the machine."""

    def __init__(self, iterations: int, wall_limit_s: float):
        self.left = int(iterations)
        self.used = 0
        self.wall_deadline = time.perf_counter() + wall_limit_s
        self.wall_hit = False

    def past_wall_limit(self) -> bool:
        """Whether the safety net has fired (remembered in `wall_hit`)."""
        if not self.wall_hit and time.perf_counter() > self.wall_deadline:
            self.wall_hit = True
        return self.wall_hit

    def check(self) -> None:
        """Raises `_Timeout` when the iterations are used up or past the safety net."""
        if self.left <= 0 or self.past_wall_limit():
            raise _Timeout()

    def run(self, search: RRTConnectSearch, iterations: int | None = None) -> np.ndarray | None:
        """`search.run` for up to `iterations` more iterations (None: up to
        its cap) within the budget: the path, or None (no path within its cap,
        or paused after `iterations`); raises `_Timeout` when the budget ran
        out first."""
        cap = search.config.max_iterations - search.iteration
        wanted = cap if iterations is None else min(iterations, cap)
        allowed = min(wanted, max(self.left, 0))
        before = search.iteration
        path, why = search.run(allowed, self.wall_deadline)
        spent = search.iteration - before
        self.left -= spent
        self.used += spent
        if path is not None:
            return path
        if why == "timeout":
            self.wall_hit = True
            raise _Timeout()
        if why == "iteration limit" and allowed < wanted:
            raise _Timeout()
        return None


def _unwrap_toward(q_from: np.ndarray, q_to: np.ndarray) -> np.ndarray:
    """q_to with continuous joints shifted to the nearest equivalent of q_from."""
    out = np.array(q_to, float, copy=True)
    c = layout.IS_CONTINUOUS
    out[c] = q_from[c] + layout.wrap_angle(q_to[c] - q_from[c])
    return out


def _wrap_arm(arm: np.ndarray) -> np.ndarray:
    """Torso + arm (8,) with the continuous joints wrapped into [-pi, pi)."""
    out = np.array(arm, float, copy=True)
    c = layout.IS_CONTINUOUS[3:]
    out[c] = layout.wrap_angle(out[c])
    return out


def _densify_poses(poses: np.ndarray, lever_theta: float, res: float) -> tuple[np.ndarray, np.ndarray]:
    """`densify` of base poses (M, 3) with the torso + arm held (their sphere
    displacement bound is the planar step + |d theta| * lever_theta): the
    dense poses (N, 3) and the dense index (M,) of every pose."""
    return densify_indexed(poses, np.array([0.0, 0.0, lever_theta]), res)


@numba.njit(cache=True)
def _sync_states(poses, W, v_max, w_max):
    """`WholeBodyPlanner._synchronized_path` for M >= 2 poses: the states at
    the union of the base's knots (travel-time fractions) and the arm's
    (fractions of its L1 length), each side interpolated linearly."""
    m, k = poses.shape[0], W.shape[0]
    sa = np.zeros(k)
    for i in range(1, k):
        sa[i] = sa[i - 1]
        for a in range(W.shape[1]):
            sa[i] += abs(W[i, a] - W[i - 1, a])
    sb = np.zeros(m)
    for i in range(1, m):
        t = max(math.hypot(poses[i, 0] - poses[i - 1, 0], poses[i, 1] - poses[i - 1, 1]) / v_max,
                abs(poses[i, 2] - poses[i - 1, 2]) / w_max)
        sb[i] = sb[i - 1] + t
    for knots, n in ((sa, k), (sb, m)):
        total = knots[n - 1]
        for i in range(n):
            knots[i] = knots[i] / total if total > 0 else (i / (n - 1) if n > 1 else 0.0)
    s = np.union1d(sa, sb)
    out = np.empty((s.shape[0], 3 + W.shape[1]))
    _interp_rows(s, sb, poses, out, 0)
    _interp_rows(s, sa, W, out, 3)
    return out


@numba.njit(cache=True)
def _interp_rows(s, knots, values, out, col):
    """out[:, col:col + d] = values (n, d) interpolated at s (sorted, within
    the increasing knots (n,)); a knot gets its own row exactly."""
    n = knots.shape[0]
    j = 0
    for i in range(s.shape[0]):
        x = s[i]
        while j < n - 2 and knots[j + 1] <= x:
            j += 1
        if n == 1 or x <= knots[j]:
            for a in range(values.shape[1]):
                out[i, col + a] = values[j, a]
        elif x >= knots[j + 1]:
            for a in range(values.shape[1]):
                out[i, col + a] = values[j + 1, a]
        else:
            f = (x - knots[j]) / (knots[j + 1] - knots[j])
            for a in range(values.shape[1]):
                out[i, col + a] = values[j, a] + f * (values[j + 1, a] - values[j, a])
    return out


class _HeldArm:
    """The base driving along poses (M, 3) with the torso + arm held at `arm`
    (8,): one batch check of the whole drive, then any stretch of it is
    answered from the prefix sums of colliding states."""

    def __init__(self, planner: "WholeBodyPlanner", poses: np.ndarray, arm: np.ndarray, first: int = 0,
                 last: int | None = None):
        """Only poses first..last (default: all) are checked and may be asked for."""
        checker = planner.checker
        self._first = first
        arm = np.asarray(arm, float)
        poses = poses[first: None if last is None else last + 1]
        self._Q = np.concatenate([poses, np.repeat(arm[None], poses.shape[0], axis=0)], axis=1)
        if poses.shape[0] < 2:
            self._index = np.zeros(1, np.int64)
            self._bad = np.cumsum(~checker.drive_free(poses, arm))
            return
        # The dense states of `densify` (the arm is held: only the base moves),
        # and the dense index of each pose.
        dense, self._index = _densify_poses(np.ascontiguousarray(poses, float), float(checker.lever[2]),
                                            float(checker.config.motion_resolution))
        self._bad = np.cumsum(~checker.drive_free(dense, arm))

    def free(self, a: int, b: int) -> bool:
        """The drive from pose a to pose b (a <= b) is free."""
        i0, i1 = self._index[a - self._first], self._index[b - self._first]
        return bool(self._bad[i1] - (self._bad[i0 - 1] if i0 > 0 else 0) == 0)

    def states(self, a: int, b: int) -> np.ndarray:
        """Whole-body states of the drive from pose a to pose b."""
        return self._Q[a - self._first: b - self._first + 1].copy()


class WholeBodyPlanner:
    """Plans collision-free whole-body trajectories for the Fetch.

    Args:
        checker: the batched `SphereCollisionChecker` (holds the environment).
        config: `PlannerConfig`.
    """

    def __init__(self, checker: SphereCollisionChecker, config: PlannerConfig | None = None):
        config = config or PlannerConfig()
        self.config = config
        self.checker = checker
        self._hybrid: HybridAStar | None = None
        self._bare: SphereCollisionChecker | None = None
        self.travel = np.asarray(config.travel_torso_arm, dtype=float)
        #: attempts of this planner's plans that the wall-clock safety net
        #: stopped or cut short (`PlanResult.wall_limit_hits`, summed).
        self.wall_limit_hits = 0
        # Loaded (or built, once per machine: ~2 s) now, not inside a plan.
        self._roadmap: ArmRoadmap | None = ArmRoadmap.for_checker(checker, self.travel)
        self.footprint, self.bands = self._travel_footprint(checker, self.travel, config.footprint_split_z)
        self.footprint_radius = self.footprint.bounding_radius
        self.robot_top = float(self.bands[-1][1])

    @staticmethod
    def for_fetch(env: CollisionEnvironment, config: PlannerConfig | None = None) -> "WholeBodyPlanner":
        config = config or PlannerConfig()

        cc = SphereCollisionChecker.for_fetch(env, config.checker_config())
        return WholeBodyPlanner(cc, config)

    @staticmethod
    def _travel_footprint(checker: SphereCollisionChecker, travel: np.ndarray, split_z: float):
        """Two discs covering the travel-pose robot's (padded) spheres: those
        reaching below `split_z` (the base) and the rest (torso, arm, head),
        each against the obstacles of its own height band.

        Returns (`Footprint2D`, [(z_min, z_max) of band 0, of band 1]).
        """
        q0 = np.concatenate([[0.0, 0.0, 0.0], travel])
        c = checker.sphere_centers(q0[None])[0]
        r = checker.sph_r
        keep = checker.check_env
        c, r = c[keep], r[keep]
        low = c[:, 2] - r < split_z
        groups = [g for g in (low, ~low) if g.any()]
        discs, bands = [], []
        for b, g in enumerate(groups):
            x, radius = Footprint2D.covering(c[g], r[g])
            discs.append([x, 0.0, radius])
            bands.append((float(np.min(c[g, 2] - r[g])) if b else -10.0, float(np.max(c[g, 2] + r[g]))))
        return Footprint2D(np.array(discs), np.arange(len(discs), dtype=np.int64)), bands

    # -- environment ---------------------------------------------------------

    def set_environment(self, env: CollisionEnvironment) -> None:
        """Replaces the environment (a new map); the base costmap is rebuilt lazily."""
        self.checker.set_environment(env)
        self._hybrid = None

    def _base_planner(self, *poses: np.ndarray) -> HybridAStar:
        """The base planner on the current environment's 2D costmap, which
        covers the obstacles and the given base poses with room to manoeuvre."""
        margin_xy = 1.0
        if self._hybrid is not None and poses:
            cm = self._hybrid.costmap
            lo = cm.origin + margin_xy
            hi = cm.origin + cm.resolution * (np.array(cm.shape) - 1) - margin_xy
            if any(np.any(p[:2] < lo) or np.any(p[:2] > hi) for p in poses):
                self._hybrid = None
        if self._hybrid is None:
            cover = None
            if poses:
                xy = np.array([p[:2] for p in poses])
                cover = (xy.min(axis=0) - margin_xy, xy.max(axis=0) + margin_xy)
            search = HybridAStarConfig(turning_radius=self.config.turning_radius,
                                       max_expansions=self.config.hybrid_astar_max_expansions)
            # Clearances beyond the largest disc + its slack are never compared.
            cap = self.footprint_radius + search.exact_slack + 2.0 * self.config.costmap_resolution + 0.1
            cm = base_costmap(self.checker.env, self.bands, self.config.costmap_resolution, cap, cover)
            self._hybrid = HybridAStar(cm, self.footprint, search, checker=self.checker, travel_arm=self.travel)
        return self._hybrid

    def warm_up(self) -> None:
        """Loads (or compiles) the compiled kernels of every planning stage now:
        numba does so on first use, which inside a plan costs tens of ms even
        from its cache (and seconds to compile). A plan on an easy problem
        does not reach the searches of the later stages."""
        whole_body_rrt.warm_up(WholeBodySearchSpace.fixed_base(self.checker, np.zeros(3)))
        poses = np.array([[0.0, 0.0, 0.0], [0.3, 0.0, 0.2]])
        whole_body_rrt.warm_up(WholeBodySearchSpace.along_path(self.checker, poses))
        self._synchronized_path(poses, np.zeros((2, layout.NQ - 3)))
        self._base_planner(poses[0], poses[1]).warm_up()
        self._warm_up_plan()

    def _warm_up_plan(self) -> None:
        """Plans once around a wall, to a table, in a map made of points (the
        episode's kind of environment): the kernels' specializations for a
        point map are compiled here, not inside an episode's first plan where
        the compile time would fire the wall-clock safety net. The planner's
        environment, counters and configuration are restored."""
        rng = np.random.default_rng(0)
        n = 1500
        wall = np.column_stack([np.full(n, 1.2), rng.uniform(-0.8, 0.8, n), rng.uniform(0.0, 1.4, n)])
        table = np.column_stack([rng.uniform(2.6, 3.2, n), rng.uniform(-0.4, 0.4, n), np.full(n, 0.7)])
        env = CollisionEnvironment.from_points(np.concatenate([wall, table]), resolution=0.05)
        q_start = layout.stow_configuration(0.0, 0.0, 0.0)
        q_goal = layout.stow_configuration(3.0, 0.9, 0.0)
        q_goal[3:] = [0.3, 0.5, -0.3, 0.2, 1.2, 0.1, 0.8, 0.0]
        saved_env, saved_config, saved_hits = self.checker.env, self.config, self.wall_limit_hits
        self.config = dataclasses.replace(saved_config, attempt_wall_limit_s=float("inf"))
        try:
            self.set_environment(env)
            self.plan(q_start, q_goal)
        finally:
            self.config, self.wall_limit_hits = saved_config, saved_hits
            self.set_environment(saved_env)

    # -- validation ------------------------------------------------------------

    def validate_configuration(self, q: np.ndarray, name: str) -> tuple[np.ndarray | None, str]:
        """Returns (q as (11,) float, "") or (None, message)."""
        try:
            q = np.asarray(q, dtype=float).reshape(-1)
        except (TypeError, ValueError):
            return None, f"{name} is not numeric"
        if q.shape[0] != layout.NQ:
            return None, f"{name} must have {layout.NQ} entries, got {q.shape[0]}"
        if not np.all(np.isfinite(q)):
            bad = [layout.WHOLE_BODY_JOINTS[i] for i in np.flatnonzero(~np.isfinite(q))]
            return None, f"{name} has NaN/inf in {bad}"
        if not layout.within_limits(q):
            bad = [layout.WHOLE_BODY_JOINTS[i] for i in
                   np.flatnonzero((q < layout.Q_LOWER) | (q > layout.Q_UPPER))]
            return None, f"{name} is outside the joint limits of {bad}"
        return q, ""

    def trajectory_is_valid(self, trajectory: TimedTrajectory, from_time: float | None = None) -> bool:
        """Re-checks the (remaining part of a) trajectory against the current
        environment (`path_is_valid`)."""
        q = trajectory.q
        if from_time is not None and from_time > trajectory.start_time:
            keep = trajectory.times > from_time
            q = np.concatenate([trajectory.sample(from_time)[None], q[keep]])
        return self.path_is_valid(q)

    def path_is_valid(self, path: np.ndarray, checker: SphereCollisionChecker | None = None) -> bool:
        """The planner's validity rule for a path (N, 11) of straight segments:
        free for the padded spheres at the motion resolution, except for a
        leading and a trailing piece that may be inside the padding but must
        be free for the unpadded spheres (see the module docstring); against
        the planner's environment, or `checker`'s (one of `checker.with_environment`)."""
        own = checker is None
        checker = self.checker if own else checker
        dense = densify(np.asarray(path, dtype=float), checker)
        if checker.first_collision(dense) < 0:
            return True
        bare = self.unpadded_checker() if own else checker.unpadded()
        free = checker.is_free(dense)
        ok = np.flatnonzero(free)
        if ok.size == 0:
            return self._unpadded_path_free(dense, bare)
        i0, i1 = int(ok[0]), int(ok[-1])
        if not free[i0:i1 + 1].all():
            return False
        return ((i0 == 0 or self._unpadded_path_free(dense[:i0 + 1], bare))
                and (i1 == dense.shape[0] - 1 or self._unpadded_path_free(dense[i1:], bare)))

    def unpadded_checker(self) -> SphereCollisionChecker:
        """`SphereCollisionChecker.unpadded` of the planner's checker (cached per environment)."""
        if self._bare is None or self._bare.env is not self.checker.env:
            self._bare = self.checker.unpadded()
        return self._bare

    def _unpadded_path_free(self, path: np.ndarray, bare: SphereCollisionChecker | None = None) -> bool:
        """Path (N, 11) free for the unpadded spheres at `end_check_resolution`."""
        bare = bare or self.unpadded_checker()
        return bare.first_collision(densify(path, bare, resolution=self.config.end_check_resolution)) < 0

    def _escape_candidates(self, q: np.ndarray) -> np.ndarray:
        """Configurations (K, 11) a short motion from q, nearest first: the base
        straight back/forward along its heading, turns in place, the torso/arm
        toward the travel pose, and base + torso/arm together."""
        step = 0.02
        dists = np.arange(step, self.config.escape_distance + 1e-9, step)
        heading = np.array([math.cos(q[2]), math.sin(q[2])])
        travel = _unwrap_toward(q, np.concatenate([q[:3], self.travel]))[3:]
        out = []
        for d in np.concatenate([-dists, dists]):
            qe = q.copy()
            qe[:2] += d * heading
            out.append(qe)
        for a in np.arange(0.05, 0.5 + 1e-9, 0.05):
            for sign in (-1.0, 1.0):
                qe = q.copy()
                qe[2] += sign * a
                out.append(qe)
        fractions = np.arange(0.1, 1.0 + 1e-9, 0.1)
        for f in fractions:
            qe = q.copy()
            qe[3:] += f * (travel - q[3:])
            out.append(qe)
        for d in (-0.3, -0.2, -0.1, -0.05, 0.05, 0.1, 0.2, 0.3):
            for f in (0.25, 0.5, 1.0):
                qe = q.copy()
                qe[:2] += d * heading
                qe[3:] += f * (travel - q[3:])
                out.append(qe)
        Q = np.array(out)
        cost = self.checker.sphere_displacement_bound(Q - q)
        return Q[np.argsort(cost, kind="stable")]

    def _leave_padding(self, q: np.ndarray, max_motions: int = 8) -> np.ndarray | None:
        """The states (2, 11) [q, q_free] of the shortest candidate motion from
        q (free, but inside the padding) to a padded-free configuration that
        is free for the unpadded spheres all along, or None."""
        Q = self._escape_candidates(q)
        free = self.checker.is_free(Q)
        for qe in Q[free][:max_motions]:
            motion = np.stack([q, qe])
            if self._unpadded_path_free(motion):
                return motion
        return None

    # -- planning ----------------------------------------------------------------

    def plan(self, q_start: np.ndarray, q_goal: np.ndarray) -> PlanResult:
        """Plans a whole-body trajectory from q_start to the configuration q_goal."""
        t0 = time.perf_counter()
        timings = {"costmap": 0.0, "base": 0.0, "arm": 0.0, "refine": 0.0, "total": 0.0}

        def fail(reason: str, message: str, attempts: int = 0) -> PlanResult:
            timings["total"] = 1e3 * (time.perf_counter() - t0)
            return PlanResult(False, reason, None, timings, attempts, message)

        qs, msg = self.validate_configuration(q_start, "start")
        if qs is None:
            return fail(FailureReason.INVALID_INPUT, msg)
        qg, msg = self.validate_configuration(q_goal, "goal")
        if qg is None:
            return fail(FailureReason.INVALID_INPUT, msg)
        bare = self.unpadded_checker()
        if not bare.is_free(qs[None])[0]:
            return fail(FailureReason.START_IN_COLLISION,
                        "the start configuration is in collision (the unpadded spheres penetrate the "
                        "environment or each other)")
        if not bare.is_free(qg[None])[0]:
            return fail(FailureReason.GOAL_IN_COLLISION,
                        "the goal configuration is in collision (the unpadded spheres penetrate the "
                        "environment or each other)")
        qg = _unwrap_toward(qs, qg)
        # Ends inside the padding: leave (reach) them by a short motion first.
        head = tail = None
        if not self.checker.is_free(qs[None])[0]:
            head = self._leave_padding(qs)
            if head is None:
                return fail(FailureReason.START_IN_COLLISION,
                            "the start is inside the collision padding and no short motion leaves it")
        if not self.checker.is_free(qg[None])[0]:
            tail = self._leave_padding(qg)
            if tail is None:
                return fail(FailureReason.GOAL_IN_COLLISION,
                            "the goal is inside the collision padding and no short motion reaches it")
            tail = tail[::-1]
        result = self._plan_between(head[-1] if head is not None else qs,
                                    tail[0] if tail is not None else qg, t0, timings)
        if not result.success or (head is None and tail is None):
            return result
        tr = time.perf_counter()
        q = result.trajectory.q
        pieces = [head] if head is not None else []
        pieces.append(q if head is None else q[1:])
        if tail is not None:
            # The plan's end equals tail[0] up to whole turns of continuous joints.
            pieces.append((tail + (q[-1] - tail[0]))[1:])
        traj = smoothing.time_parametrize(np.concatenate(pieces))
        timings["refine"] += 1e3 * (time.perf_counter() - tr)
        timings["total"] = 1e3 * (time.perf_counter() - t0)
        return dataclasses.replace(result, trajectory=traj, timings=timings)

    def _plan_between(self, qs: np.ndarray, qg: np.ndarray, t0: float, timings: dict) -> PlanResult:
        """Plans between padded-free, validated configurations (qg unwrapped toward qs)."""

        iterations = wall_hits = 0

        def fail(reason: str, message: str, attempts: int = 0) -> PlanResult:
            timings["total"] = 1e3 * (time.perf_counter() - t0)
            return PlanResult(False, reason, None, timings, attempts, message, iterations, wall_hits)

        tc = time.perf_counter()
        self._base_planner(qs[:3], qg[:3])
        timings["costmap"] = 1e3 * (time.perf_counter() - tc)
        # The base search is deterministic (expansion-capped): once per plan.
        tb = time.perf_counter()
        base_path = self._base_search(qs, qg)
        timings["base"] += 1e3 * (time.perf_counter() - tb)
        if isinstance(base_path, str):
            return fail(FailureReason.NO_BASE_PATH, base_path, 1)
        reason, message = FailureReason.TIMEOUT, ""
        for attempt in range(self.config.max_attempts):
            rng = np.random.default_rng([self.config.seed, attempt])
            budget = _AttemptBudget(self.config.attempt_budget_iterations, self.config.attempt_wall_limit_s)
            try:
                path, reason, message = self._attempt(qs, qg, base_path, rng, budget, timings)
            except _Timeout:
                path, reason = None, FailureReason.TIMEOUT
                message = (f"attempt stopped by the wall-clock safety net ({self.config.attempt_wall_limit_s} s)"
                           if budget.wall_hit else
                           f"attempt budget of {self.config.attempt_budget_iterations} RRT-Connect iterations used up")
                timings["arm"] += 1e3 * (time.perf_counter() - self._stage_start)
            iterations += budget.used
            if budget.wall_hit:
                wall_hits += 1
                self.wall_limit_hits += 1
                log.warning("WholeBodyPlanner: attempt %d %s by the wall-clock safety net (%.2f s): this plan "
                            "depends on the machine's speed", attempt + 1,
                            "cut short (no B-spline smoothing)" if path is not None else "stopped",
                            self.config.attempt_wall_limit_s)
            if path is not None:
                tr = time.perf_counter()
                traj = smoothing.time_parametrize(path)
                timings["refine"] += 1e3 * (time.perf_counter() - tr)
                timings["total"] = 1e3 * (time.perf_counter() - t0)
                return PlanResult(True, FailureReason.NONE, traj, timings, attempt + 1, "", iterations, wall_hits)
        return fail(reason, message, attempt + 1)

    def _base_search(self, qa: np.ndarray, qb: np.ndarray):
        """The base path from qa to qb (poses (N, 3), theta unwrapped), None
        when the base does not move, or the failure message (str)."""
        a, b = qa[:3], qb[:3]
        if np.hypot(*(b[:2] - a[:2])) <= 1e-3 and abs(b[2] - a[2]) <= 1e-3:
            return None
        if np.hypot(*(b[:2] - a[:2])) <= 1e-3:
            # Pure in-place rotation.
            d = layout.wrap_angle(b[2] - a[2])
            n = max(int(math.ceil(abs(d) / 0.05)), 1) + 1
            th = a[2] + np.linspace(0.0, d, n)
            return _BasePlan(np.column_stack([np.full(n, a[0]), np.full(n, a[1]), th]), 0)
        path, why = self._base_planner(a, b).plan(a, b, start_arm=qa[3:], goal_arm=qb[3:])
        if path is None:
            return why
        return _BasePlan(path.poses, path.expansions)

    def _attempt(self, qs, qg, base_path, rng, budget: _AttemptBudget, timings):
        checker = self.checker
        tb = self._stage_start = time.perf_counter()
        if base_path is None:  # the base does not move
            ta = self._stage_start = time.perf_counter()
            arm = self._arm_motion(qs[:3], qs[3:], qg[3:], rng, budget)
            timings["arm"] += 1e3 * (time.perf_counter() - ta)
            if arm is None:
                return None, FailureReason.NO_ARM_PATH, "no fixed-base arm path"
            return self._refine([arm], timings, rng, budget), "", ""
        poses = base_path.poses
        if base_path.expansions > 0:
            poses = self._base_planner(qs[:3], qg[:3]).shortcut(poses, rng, self.config.base_shortcut_iterations)
        timings["base"] += 1e3 * (time.perf_counter() - tb)
        goal_theta = poses[-1, 2]  # unwrapped heading at the end of the base path
        qg = qg.copy()
        qg[2] = goal_theta
        budget.check()
        ta = self._stage_start = time.perf_counter()
        # (a) arm interpolated in sync with the whole base path.
        Q = self._synchronized(poses, qs[3:], qg[3:])
        # (the arm's straight line alone is checked for self-collision first:
        # short, and independent of the base)
        # (No separate self-collision test of the arm's line first: the
        # coarse-to-fine check of the whole path finds such a collision
        # within a few states, and a free line would pay it twice.)
        if checker.first_collision(densify(Q, checker)) < 0:
            timings["arm"] += 1e3 * (time.perf_counter() - ta)
            return self._refine([Q], timings, rng, budget), "", ""
        # (b) fold into the travel pose while driving, unfold while driving
        # (synchronized pieces only, no search).
        travel = _unwrap_toward(qs, np.concatenate([qs[:3], self.travel]))[3:]
        path = self._via_carry(poses, qs, qg, travel, rng, budget, search=False)
        if path is not None:
            timings["arm"] += 1e3 * (time.perf_counter() - ta)
            return self._refine(path, timings, rng, budget), "", ""
        # (c) RRT-Connect over (progress along the base path, torso + arm),
        # first for `along_path_first_iterations` (it usually connects within
        # a few dozen iterations; the hard problems hit the cap at ~70 us per
        # iteration)...
        along = {}
        path = self._along_base_path(poses, qs[3:], qg[3:], rng, budget, along,
                                     self.config.along_path_first_iterations)
        if path is not None:
            timings["arm"] += 1e3 * (time.perf_counter() - ta)
            return self._refine([path], timings, rng, budget), "", ""
        # (d) the same as (b) with fixed-base arm searches (lazy roadmap, then
        # RRT-Connect) at the start placement and at or before the goal.
        path = self._via_carry(poses, qs, qg, travel, rng, budget)
        if path is not None:
            timings["arm"] += 1e3 * (time.perf_counter() - ta)
            return self._refine(path, timings, rng, budget), "", ""
        # ... (c) resumed up to its iteration cap.
        path = self._along_base_path(poses, qs[3:], qg[3:], rng, budget, along)
        if path is not None:
            timings["arm"] += 1e3 * (time.perf_counter() - ta)
            return self._refine([path], timings, rng, budget), "", ""
        # (e) fold into another carry pose, drive, unfold, with fixed-base
        # arm searches at the start/goal placements: the goal arm (unfold at
        # the start), the start arm (unfold at the goal). Roll joints are
        # taken nearest to the start's so that the whole path stays unwrapped.
        carries = [qg[3:], qs[3:]]
        for carry in carries:
            path = self._via_carry(poses, qs, qg, carry, rng, budget)
            if path is not None:
                timings["arm"] += 1e3 * (time.perf_counter() - ta)
                return self._refine(path, timings, rng, budget), "", ""
        timings["arm"] += 1e3 * (time.perf_counter() - ta)
        return None, FailureReason.NO_ARM_PATH, "no arm connection at any placement along the base path"

    def _via_carry(self, poses, qs, qg, carry, rng, budget: _AttemptBudget,
                   search: bool = True) -> list[np.ndarray] | None:
        """Pieces: fold qs->carry (synchronized over the first part of the base
        path, or at the start placement), drive holding carry, unfold
        carry->qg (synchronized over the last part, or at the goal placement).

        Arm motions, cheapest first: the straight joint-space line and (for
        the travel pose) the arm roadmap's self-collision-free path to it
        (`ArmRoadmap.to_carry`), each synchronized with the base over part of
        its path, or at a fixed placement along it (driving there holding the
        start arm, or from there holding the goal arm); with `search`,
        at the fixed start/goal placement the roadmap searched lazily with
        the whole-body check (`ArmRoadmap.connect`), then RRT-Connect. Roadmap paths end at their target up to whole turns of
        continuous joints (the carry then follows the fold's end)."""
        cfg = self.config
        checker = self.checker

        def free(Q):
            return checker.first_collision(densify(Q, checker)) < 0

        roadmap = self._arm_roadmap() if self._is_travel(carry) else None
        cum = self._fraction_cum(poses)
        pieces = []
        fold_k = 0
        last = poses.shape[0] - 1
        if np.max(np.abs(qs[3:] - carry)) > 1e-9:
            folds = self._arm_lines(roadmap, qs[3:], carry)
            fold = None
            depart = None  # driving off holding the start arm
            for W in folds:
                for f in cfg.fold_fractions:
                    budget.check()
                    k = self._index_at_fraction(poses, f, cum) if f > 0.0 else 0
                    Qf = self._synchronized_path(poses[: k + 1], W)
                    if free(Qf):
                        fold, fold_k = [Qf], k
                        break
                    if k == 0:
                        continue
                    # Or drive off holding the start arm, then fold there.
                    if depart is None:
                        k_max = self._index_at_fraction(poses, max(cfg.fold_fractions), cum)
                        depart = _HeldArm(self, poses, qs[3:], last=k_max)
                    Qf = self._synchronized_path(poses[k: k + 1], W)
                    if depart.free(0, k) and free(Qf):
                        fold, fold_k = [depart.states(0, k), Qf], k
                        break
                if fold is not None:
                    break
            if fold is None:
                budget.check()
                arm = self._arm_motion(poses[0], qs[3:], carry, rng, budget, search=search)
                fold = None if arm is None else [arm]
            if fold is None:
                return None
            pieces += fold
            carry = fold[-1][-1, 3:]
        needs_unfold = np.max(np.abs(qg[3:] - carry)) > 1e-9
        unfolds = self._arm_lines(roadmap, carry, qg[3:]) if needs_unfold else [None]
        fractions = cfg.placement_fractions if needs_unfold else (1.0,)
        hold = _HeldArm(self, poses, carry, first=fold_k)
        approach = None  # holding the goal arm into the goal
        k_min = max(self._index_at_fraction(poses, min(fractions), cum), fold_k)

        def drive_to(k):
            return hold.states(fold_k, k) if hold.free(fold_k, k) else None

        for W in unfolds:
            for f in fractions:
                budget.check()
                k = last if f >= 1.0 else max(self._index_at_fraction(poses, f, cum), fold_k)
                drive = drive_to(k)
                if drive is None:
                    continue
                if W is None:
                    return pieces + [drive]
                Qu = self._synchronized_path(poses[k:], W)
                if free(Qu):
                    return pieces + [drive, Qu]
                if k == last:
                    continue
                # Or unfold there and approach the goal holding its arm.
                if approach is None:
                    approach = _HeldArm(self, poses, qg[3:], first=k_min)
                Qu = self._synchronized_path(poses[k: k + 1], W)
                if approach.free(k, last) and free(Qu):
                    Qa = approach.states(k, last)
                    Qa[:, 3:] += W[-1] - qg[3:]  # whole turns, if W ends so
                    return pieces + [drive, Qu, Qa]
        if needs_unfold and drive_to(last) is not None:
            budget.check()
            arm = self._arm_motion(poses[-1], carry, qg[3:], rng, budget, search=search)
            if arm is not None:
                return pieces + [drive_to(last), arm]
        if needs_unfold and search:
            # Unfold at a placement before the goal (fixed-base search) and
            # approach holding the goal arm.
            if approach is None:
                approach = _HeldArm(self, poses, qg[3:], first=k_min)
            for f in fractions:
                k = max(self._index_at_fraction(poses, f, cum), fold_k)
                if k >= last or not hold.free(fold_k, k) or not approach.free(k, last):
                    continue
                budget.check()
                arm = self._arm_motion(poses[k], carry, qg[3:], rng, budget, search=True)
                if arm is not None:
                    Qa = approach.states(k, last)
                    Qa[:, 3:] += arm[-1, 3:] - qg[3:]  # whole turns, if the arm path ended so
                    return pieces + [drive_to(k), arm, Qa]
        return None

    @staticmethod
    def _arm_lines(roadmap: ArmRoadmap | None, a: np.ndarray, b: np.ndarray):
        """Torso + arm paths a -> b to synchronize with the base, generated
        lazily: the straight line (unless it self-collides, when `roadmap`
        can tell), then the roadmap's path through the travel pose (one end
        must be the travel pose; the path ends at b up to whole turns)."""
        line = np.stack([a, b])
        if roadmap is None:
            yield line
            return
        line_free = roadmap.self_free(line)
        if line_free:
            yield line
        if roadmap.nodes.shape[0] and np.max(np.abs(_wrap_arm(a) - roadmap.nodes[0])) < 1e-9:
            W = roadmap.to_carry(b)  # b -> travel, reversed and shifted to start at a
            W = None if W is None else W[::-1] + (a - W[-1])
        else:
            W = roadmap.to_carry(a)
        # (the roadmap's path shortened to the very line already tried: not again)
        if W is not None and not (line_free and W.shape == line.shape and np.array_equal(W, line)):
            yield W

    def _arm_roadmap(self) -> ArmRoadmap:
        if self._roadmap is None:
            self._roadmap = ArmRoadmap.for_checker(self.checker, self.travel)
        return self._roadmap

    def _is_travel(self, arm: np.ndarray) -> bool:
        """arm (8,) is the travel pose up to whole turns of continuous joints."""
        d = np.asarray(arm, float) - self.travel
        c = layout.IS_CONTINUOUS[3:]
        d[c] = layout.wrap_angle(d[c])
        return bool(np.max(np.abs(d)) < 1e-9)

    @staticmethod
    def _synchronized_path(poses: np.ndarray, W: np.ndarray) -> np.ndarray:
        """Whole-body states along base poses (M, 3) while the torso/arm follows
        the waypoints W (K, 8), both in proportion to their progress (base:
        travel time; arm: length): the states at every base pose and every
        waypoint, so that the straight segments between them are the motion.
        One pose: the arm moves at that fixed base."""
        poses = np.ascontiguousarray(poses, float)
        W = np.ascontiguousarray(W, float)
        if poses.shape[0] == 1:
            return np.concatenate([np.repeat(poses, W.shape[0], axis=0), W], axis=1)
        return _sync_states(poses, W, layout.TRACKER_BASE_V, layout.TRACKER_BASE_W)

    @staticmethod
    def _index_at_fraction(poses: np.ndarray, f: float, cum: np.ndarray | None = None) -> int:
        """The first pose at fraction f of the path's length (`_fraction_cum`,
        given or computed)."""
        cum = WholeBodyPlanner._fraction_cum(poses) if cum is None else cum
        if cum[-1] <= 0:
            return poses.shape[0] - 1
        return int(np.clip(np.searchsorted(cum, f * cum[-1]), 0, poses.shape[0] - 1))

    @staticmethod
    def _fraction_cum(poses: np.ndarray) -> np.ndarray:
        """Cumulative length along poses (M, 3): metres + 0.3 m per radian."""
        d = np.hypot(*np.diff(poses[:, :2], axis=0).T) + 0.3 * np.abs(np.diff(poses[:, 2]))
        return np.concatenate([[0.0], np.cumsum(d)])

    @staticmethod
    def _synchronized(poses: np.ndarray, arm_a: np.ndarray, arm_b: np.ndarray) -> np.ndarray:
        """Whole-body states (M, 11): base poses with the arm interpolated a->b in
        proportion to the base's travel time along them."""
        d = np.diff(poses, axis=0)
        t = np.maximum(np.hypot(d[:, 0], d[:, 1]) / layout.TRACKER_BASE_V,
                       np.abs(d[:, 2]) / layout.TRACKER_BASE_W)
        cum = np.concatenate([[0.0], np.cumsum(t)])
        s = cum / cum[-1] if cum[-1] > 0 else np.linspace(0.0, 1.0, poses.shape[0])
        arm = arm_a + s[:, None] * (arm_b - arm_a)
        return np.concatenate([poses, arm], axis=1)

    def _along_base_path(self, poses: np.ndarray, arm_a: np.ndarray, arm_b: np.ndarray, rng,
                         budget: _AttemptBudget, search: dict, iterations: int | None = None) -> np.ndarray | None:
        """Whole-body states (N, 11) that follow the base path `poses` while
        the torso/arm moves from arm_a to arm_b, or None.

        RRT-Connect over x = (u, torso + arm) where u is the base's progress
        along the path in seconds of travel at the tracker's speed limits (it
        may go back: the base then reverses along its own curve); see
        `WholeBodySearchSpace.along_path`. The search runs `iterations` more
        iterations (None: up to the cap) and is kept in `search` (a dict, empty
        at first) so that a later call resumes it.
        """
        if "rrt" not in search:
            space = WholeBodySearchSpace.along_path(self.checker, poses)
            total = space.duration
            if total <= 0.0:
                search["rrt"] = None
                return None
            lo = np.concatenate([[0.0], layout.SAMPLE_LOWER[3:]])
            hi = np.concatenate([[total], layout.SAMPLE_UPPER[3:]])
            c = np.concatenate([[False], layout.IS_CONTINUOUS[3:]])
            mid = 0.5 * np.concatenate([[0.0], arm_a + arm_b])
            lo = np.where(c, mid - np.pi, lo)
            hi = np.where(c, mid + np.pi, hi)
            w = np.concatenate([[1.0, 5.0], np.ones(7)])  # base seconds; torso metres weigh more
            xa = np.concatenate([[0.0], arm_a])
            xb = np.concatenate([[total], arm_b])
            search["rrt"] = RRTConnectSearch(space, xa, xb, lo, hi, w, rng, self._rrt_config())
        rrt = search["rrt"]
        if rrt is None:
            return None
        path = budget.run(rrt, iterations)
        if path is None:
            return None
        space = rrt.space
        if path.shape[0] > 2:
            path = smoothing.shortcut(path, space.motion_free, rng, self.config.along_path_shortcut_iterations)
        out = [space.states(path[k], path[k + 1])[(1 if k else 0):] for k in range(path.shape[0] - 1)]
        search["rrt"] = None  # used
        return np.concatenate(out)

    def _rrt_config(self) -> KernelRRTConfig:
        return KernelRRTConfig(step=self.config.rrt_step, max_iterations=self.config.rrt_max_iterations)

    def _arm_motion(self, base: np.ndarray, arm_a: np.ndarray, arm_b: np.ndarray, rng, budget: _AttemptBudget,
                    search: bool = True):
        """A fixed-base torso+arm path as whole-body states (N, 11), or None:
        the straight motion; with `search` then the arm roadmap searched
        lazily with the whole-body check at this base (ending at arm_b up to
        whole turns of continuous joints), else RRT-Connect."""
        base = np.asarray(base, float)
        space = WholeBodySearchSpace.fixed_base(self.checker, base)
        if space.motion_free(arm_a, arm_b):
            return space.to_configurations(np.stack([arm_a, arm_b]))

        def state_free(X):
            return self.checker.is_free(np.concatenate([np.repeat(base[None], X.shape[0], axis=0), X], axis=1))

        if not search:
            return None
        path = self._arm_roadmap().connect(arm_a, arm_b, state_free, space.motion_free)
        if path is not None:
            return space.to_configurations(path)
        budget.check()
        lo = layout.SAMPLE_LOWER[3:]
        hi = layout.SAMPLE_UPPER[3:]
        # Continuous joints: one turn around the ends' midpoint (the ends are
        # unwrapped toward each other), so the path stays unwrapped.
        c = layout.IS_CONTINUOUS[3:]
        mid = 0.5 * (arm_a + arm_b)
        lo = np.where(c, mid - np.pi, lo)
        hi = np.where(c, mid + np.pi, hi)
        w = np.where(np.arange(8) == 0, 5.0, 1.0)  # torso metres weigh more
        path = budget.run(RRTConnectSearch(space, arm_a, arm_b, lo, hi, w, rng, self._rrt_config()))
        if path is None:
            return None
        if path.shape[0] > 2:
            path = smoothing.shortcut(path, space.motion_free, rng, self.config.arm_shortcut_iterations)
        return space.to_configurations(path)

    def _refine(self, pieces: list[np.ndarray], timings, rng, budget: _AttemptBudget) -> np.ndarray | None:
        """Smooths fixed-base pieces, joins and densifies.

        Every piece was validated at the checker's motion resolution, and a
        smoothed piece replaces it only after its own dense validation, so the
        joined dense path is valid without a second pass over all of it.
        Past the wall-clock safety net the smoothing is skipped (recorded).
        """
        tr = time.perf_counter()
        checker = self.checker
        out = []
        end = None  # the joined path's last waypoint (a one-waypoint piece adds none)
        for P in pieces:
            fixed_base = np.all(np.abs(P[:, :3] - P[0, :3]) < 1e-12)
            if fixed_base and P.shape[0] > 2 and not budget.past_wall_limit():
                P = smoothing.smooth_if_free(
                    P, lambda S: checker.first_collision(densify(S, checker)) < 0,
                    self.config.bspline_samples)
            if end is not None and np.max(np.abs(P[0] - end)) > 1e-9:
                # Pieces must join where they were checked; a gap is a bug.
                raise RuntimeError(f"whole-body path pieces do not join (gap {np.max(np.abs(P[0] - end))})")
            out.append(P if end is None else P[1:])
            end = P[-1]
        dense = densify(np.concatenate(out), checker)
        timings["refine"] += 1e3 * (time.perf_counter() - tr)
        return dense
