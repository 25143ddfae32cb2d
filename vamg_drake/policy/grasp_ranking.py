"""Grasp goal selection: capability filter, FPS diversity, proximity ranking, validation.

The paper's Algorithm "Grasp Goal Sampling" (appendix): keep the candidates the
capability map calls reachable from the current base, pick ``N_diverse = 20`` by
farthest-point sampling in SE(3) with
``d(T1, T2) = ||t1 - t2|| + 0.1 * angle(R1, R2)`` starting from the best score,
sort them by ``score - 0.01 * ||t - t_ee,current||``, and return the first whose
arm-only IK (base and torso fixed; from random arm seeds when the seeded
solutions all fail) succeeds and whose configuration is
collision-free. Each candidate's pre-grasp (5 cm back along -x of G) is solved
and checked too, since the robot moves there first.
"""

import dataclasses as dc
from typing import Callable

import numpy as np

from vamg_drake.policy.grasp_candidates import GraspCandidates
from vamg_drake.robot import layout

#: Batched IK with base and torso fixed at the seed's:
#: (X_WG (K,4,4), q_seed (11,) or (K,11)) -> (q (K,11), ok (K,)).
ArmIkFn = Callable[[np.ndarray, np.ndarray], tuple[np.ndarray, np.ndarray]]
#: Batched collision check: q (K,11) -> free (K,) bool.
IsFreeFn = Callable[[np.ndarray], np.ndarray]
#: Capability query: X_BG (K,4,4) end-effector poses in the base frame -> reachable (K,) bool.
ReachableFn = Callable[[np.ndarray], np.ndarray]


@dc.dataclass
class GraspRankingConfig:
    """Parameters of grasp goal selection (paper appendix values)."""

    n_diverse: int = 20
    #: lambda of the SE(3) distance (metres per radian).
    rotation_weight: float = 0.1
    #: lambda_d of the proximity-weighted score.
    proximity_weight: float = 0.01
    #: Pre-grasp offset along -x of G [m].
    pregrasp_offset: float = 0.05
    #: Check the grasp configuration itself, and ``approach_checks`` joint-space
    #: interpolants of the approach from the pre-grasp, for collision (the fingers
    #: touch the target, so ``is_free`` must let the gripper near the target).
    check_grasp_collision: bool = False
    approach_checks: int = 3
    #: With `check_grasp_collision`, also this many evenly spaced heights of
    #: the lift after closing (the torso raised by up to the behaviour's
    #: ``lift_height``): the arm above the gripper must not rise into what
    #: overhangs the target (a TV above its stand, a shelf, a stool's seat).
    #: A grasp lifts to its highest free height with every lower one free;
    #: grasps whose full lift is free come first, and one whose free lift is
    #: below `min_lift_height` is not chosen.
    lift_checks: int = 5
    #: The lowest lift a grasp may be given [m]: the episode's success lift
    #: (0.10 m) plus room for the object to slip in the fingers.
    min_lift_height: float = 0.12
    #: When the capability map calls no candidate reachable, try IK on the
    #: ranked candidates anyway (the map's bins are coarser than IK).
    ik_when_unreachable: bool = True
    #: Rounds of IK from random arm seeds for the ranked grasps when no
    #: grasp is IK- and collision-valid from the current configuration's
    #: seed: the 7-joint arm reaches a grasp in many ways, and the first
    #: found may put the elbow or forearm where another would not.
    ik_alternatives: int = 3
    #: A grasp whose lift in place is blocked (under a shelf board, a TV, a
    #: cabinet's top) may instead first pull the object out: back this far
    #: along its approach axis in the horizontal plane, `pull_raise` higher,
    #: then lift from there [m] (0: never).
    pull_distance: float = 0.12
    pull_raise: float = 0.02

    def __post_init__(self) -> None:
        self.validate()

    def validate(self) -> None:
        """Raises ValueError naming the bad field."""
        if self.n_diverse < 1:
            raise ValueError(f"GraspRankingConfig.n_diverse must be >= 1, got {self.n_diverse}")
        for name in ("approach_checks", "lift_checks", "ik_alternatives", "pull_distance", "pull_raise"):
            if getattr(self, name) < 0:
                raise ValueError(f"GraspRankingConfig.{name} must be >= 0, got {getattr(self, name)}")
        if not (np.isfinite(self.min_lift_height) and self.min_lift_height >= 0.0):
            raise ValueError(f"GraspRankingConfig.min_lift_height must be finite and >= 0, got {self.min_lift_height}")


@dc.dataclass(frozen=True)
class GraspGoal:
    """The outcome of grasp goal selection.

    Attributes:
        success: True when a valid grasp was found.
        q_grasp: (11,) configuration at the grasp pose (NaN on failure).
        q_pregrasp: (11,) configuration at the pre-grasp pose (NaN on failure).
        X_WG: (4, 4) the chosen grasp pose (NaN on failure).
        candidate_index: index into the input candidates (-1 on failure).
        num_candidates / num_reachable / num_tried: the funnel, for logs.
        failure_reason: empty on success.
        lift_height: how far the torso may lift this grasp [m] (None: as far
            as the behaviour lifts; the lift was not checked).
        q_pull: (11,) where the closed gripper first pulls the object out
            before lifting (None: it lifts in place; see
            `GraspRankingConfig.pull_distance`).
    """

    success: bool
    q_grasp: np.ndarray
    q_pregrasp: np.ndarray
    X_WG: np.ndarray
    candidate_index: int
    num_candidates: int
    num_reachable: int
    num_tried: int
    failure_reason: str = ""
    lift_height: float | None = None
    q_pull: np.ndarray | None = None


def rotation_angle(R1: np.ndarray, R2: np.ndarray) -> np.ndarray:
    """Geodesic angle between rotations, broadcasting over leading axes."""
    trace = np.einsum("...ij,...ij->...", R1, R2)  # tr(R1^T R2)
    return np.arccos(np.clip(0.5 * (trace - 1.0), -1.0, 1.0))


def pose_distance(X1: np.ndarray, X2: np.ndarray, rotation_weight: float = 0.1) -> np.ndarray:
    """``||t1 - t2|| + rotation_weight * angle(R1, R2)``, broadcasting over leading axes."""
    translation = np.linalg.norm(X1[..., :3, 3] - X2[..., :3, 3], axis=-1)
    return translation + rotation_weight * rotation_angle(X1[..., :3, :3], X2[..., :3, :3])


def same_grasp_pairs(X: np.ndarray, X_others: np.ndarray, radius: float, angle: float,
                     match_roll: bool = False) -> np.ndarray:
    """(K, M) True where grasp X[k] (K, 4, 4) lies within `radius` [m] of
    X_others[m] (M, 4, 4) with its approach axis (+x of G) within `angle`
    [rad] of that one's; with `match_roll`, also its closing axis (+y, up to
    sign: the gripper is symmetric)."""
    X, X_others = np.asarray(X, float).reshape(-1, 4, 4), np.asarray(X_others, float).reshape(-1, 4, 4)
    close = np.linalg.norm(X[:, None, :3, 3] - X_others[None, :, :3, 3], axis=-1) <= radius
    same = close & (np.einsum("ki,mi->km", X[:, :3, 0], X_others[:, :3, 0]) >= np.cos(angle))
    if match_roll:
        same &= np.abs(np.einsum("ki,mi->km", X[:, :3, 1], X_others[:, :3, 1])) >= np.cos(angle)
    return same


def near_any_grasp(X: np.ndarray, X_others: np.ndarray, radius: float, angle: float) -> np.ndarray:
    """(K,) True where grasp X[k] (K, 4, 4) lies within `radius` [m] of one of
    `X_others` (M, 4, 4) with its approach axis (+x of G) within `angle` [rad]
    of that one's: the same grasp whatever its roll about the approach."""
    return np.any(same_grasp_pairs(X, X_others, radius, angle), axis=1)


def farthest_pose_sampling(
    X: np.ndarray, score: np.ndarray, n: int, rotation_weight: float = 0.1
) -> np.ndarray:
    """Indices of up to ``n`` diverse poses: the best-scored first, then each next
    maximizes its minimum ``pose_distance`` to those already chosen."""
    k = X.shape[0]
    if k == 0:
        return np.zeros(0, dtype=int)
    chosen = [int(np.argmax(score))]
    min_dist = pose_distance(X, X[chosen[0]][None], rotation_weight)
    for _ in range(min(n, k) - 1):
        nxt = int(np.argmax(min_dist))
        if min_dist[nxt] <= 0.0:
            break
        chosen.append(nxt)
        min_dist = np.minimum(min_dist, pose_distance(X, X[nxt][None], rotation_weight))
    return np.asarray(chosen, dtype=int)


def proximity_weighted_score(
    score: np.ndarray, p_WG: np.ndarray, p_WEE_current: np.ndarray, weight: float = 0.01
) -> np.ndarray:
    """``s_hat = s - weight * ||t_G - t_ee,current||``."""
    return score - weight * np.linalg.norm(p_WG - p_WEE_current, axis=-1)


def pregrasp_poses(X_WG: np.ndarray, offset: float) -> np.ndarray:
    """Grasp poses moved ``offset`` back along their approach axis (-x of G)."""
    X = np.array(X_WG, copy=True)
    X[..., :3, 3] -= offset * X[..., :3, 0]
    return X


def rank_grasps(
    candidates: GraspCandidates,
    X_WB: np.ndarray,
    p_WEE_current: np.ndarray,
    reachable: ReachableFn | None,
    config: GraspRankingConfig,
) -> tuple[np.ndarray, int]:
    """Capability filter, FPS diversity and proximity ranking.

    Args:
        candidates: the proposed grasps.
        X_WB: (4, 4) the current base pose (the capability map's frame).
        p_WEE_current: (3,) current end-effector position.
        reachable: capability query in the base frame, or None to skip the filter.
        config: ranking parameters.

    Returns:
        (indices into ``candidates`` in the order to try, number passing the
        capability filter).
    """
    if len(candidates) == 0:
        return np.zeros(0, dtype=int), 0
    keep = np.arange(len(candidates))
    n_reachable = len(candidates)
    if reachable is not None:
        X_BG = np.linalg.inv(X_WB)[None] @ candidates.X_WG
        reach = keep[np.asarray(reachable(X_BG), dtype=bool)]
        n_reachable = int(reach.size)
        # The capability map is a voxelized filter: where it rejects every
        # candidate, IK (the exact test) still decides, if allowed.
        if reach.size or not config.ik_when_unreachable:
            keep = reach
    if keep.size == 0:
        return keep, 0
    diverse = keep[
        farthest_pose_sampling(candidates.X_WG[keep], candidates.score[keep], config.n_diverse, config.rotation_weight)
    ]
    s_hat = proximity_weighted_score(
        candidates.score[diverse], candidates.X_WG[diverse, :3, 3], p_WEE_current, config.proximity_weight
    )
    return diverse[np.argsort(-s_hat, kind="stable")], n_reachable


def select_grasp_goal(
    candidates: GraspCandidates,
    q_current: np.ndarray,
    X_WB: np.ndarray,
    p_WEE_current: np.ndarray,
    solve_arm_ik: ArmIkFn,
    is_free: IsFreeFn,
    reachable: ReachableFn | None,
    config: GraspRankingConfig | None = None,
    grasp_is_free: IsFreeFn | None = None,
    lift_height: float = 0.0,
    rng: np.random.Generator | None = None,
) -> GraspGoal:
    """The paper's grasp goal sampling: the first IK- and collision-valid ranked grasp.

    `is_free` checks the pre-grasps; `grasp_is_free` (default `is_free`) the
    grasps, the approaches to them and the lifts after them (the torso raised
    by up to `lift_height`; `check_grasp_collision`), which a grasp source may
    have checked for the gripper itself at finer resolution. Where the
    seeded IK solution of every ranked grasp fails, up to `ik_alternatives`
    rounds solve the failing ones again from random arm seeds drawn from
    `rng` (default: a generator seeded with 0).
    """
    config = config or GraspRankingConfig()
    grasp_is_free = grasp_is_free or is_free
    nan_q = np.full(q_current.shape, np.nan)
    fail = lambda reason, n_reach=0, n_tried=0: GraspGoal(  # noqa: E731
        False, nan_q, nan_q, np.full((4, 4), np.nan), -1, len(candidates), n_reach, n_tried, reason
    )
    if len(candidates) == 0:
        return fail(f"no grasp candidates ({candidates.failure_reason or 'empty'})")
    order, n_reachable = rank_grasps(candidates, X_WB, p_WEE_current, reachable, config)
    if order.size == 0:
        return fail("no grasp candidate is reachable from the current base (capability map)")
    X_grasp = candidates.X_WG[order]
    X_pre = pregrasp_poses(X_grasp, config.pregrasp_offset)
    check = lambda idx, seeds: _validate_grasps(  # noqa: E731
        X_grasp[idx], X_pre[idx], seeds, solve_arm_ik, is_free, grasp_is_free, config, lift_height)
    q_pre, q_grasp, valid, free, lift, q_pull = check(np.arange(order.size), np.asarray(q_current, dtype=float))
    # The arm is redundant: where the seeded solution of every grasp collides
    # (the forearm over a chair back, the elbow in a shelf), other arm
    # configurations reaching the same grasp may not.
    rng = rng if rng is not None else np.random.default_rng(0)
    for _ in range(config.ik_alternatives):
        if np.any(valid & free):
            break
        redo = np.flatnonzero(~(valid & free))
        seeds = np.tile(np.asarray(q_current, dtype=float), (redo.size, 1))
        seeds[:, layout.ARM] = rng.uniform(layout.SAMPLE_LOWER[layout.ARM], layout.SAMPLE_UPPER[layout.ARM],
                                           (redo.size, seeds[:, layout.ARM].shape[1]))
        alt = check(redo, seeds)
        better = (alt[2] & alt[3]) | (alt[2] & ~valid[redo])
        for mine, theirs in zip((q_pre, q_grasp, valid, free, lift, q_pull), alt):
            mine[redo[better]] = theirs[better]
    if not np.any(valid):
        why = "" if n_reachable else "; the capability map calls none reachable"
        return fail(f"IK failed for every ranked grasp (base and torso fixed{why})", n_reachable, order.size)
    winners = np.flatnonzero(valid & free)
    if winners.size == 0:
        return fail("every IK-valid ranked grasp is in collision with the map", n_reachable, order.size)
    full = winners[~(lift[winners] < lift_height - 1e-12)]  # NaN (unchecked) counts as full
    i = int(full[0] if full.size else winners[0])
    return GraspGoal(
        True, q_grasp[i], q_pre[i], X_grasp[i], int(order[i]), len(candidates), n_reachable, i + 1,
        lift_height=None if np.isnan(lift[i]) else float(lift[i]),
        q_pull=None if np.isnan(q_pull[i, 0]) else q_pull[i],
    )


def _validate_grasps(
    X_grasp: np.ndarray,
    X_pre: np.ndarray,
    seeds: np.ndarray,
    solve_arm_ik: ArmIkFn,
    is_free: IsFreeFn,
    grasp_is_free: IsFreeFn,
    config: GraspRankingConfig,
    lift_height: float,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """IK and collision checks of grasps X_grasp (K, 4, 4) and their pre-grasps.

    The pre-grasps are solved from `seeds` ((11,) or (K, 11)), each grasp from
    its pre-grasp. Returns (q_pre (K, 11), q_grasp (K, 11), valid (K,): both
    IK solved, free (K,): collision-free (see `select_grasp_goal`), lift (K,):
    the highest free lift [m], NaN where not checked, q_pull (K, 11): where
    the lift starts after pulling the object out, NaN where it lifts in place).
    """
    K = X_grasp.shape[0]
    q_pre, ok_pre = solve_arm_ik(X_pre, seeds)
    q_pre = np.array(q_pre, dtype=float)
    q_grasp = np.array(np.broadcast_to(seeds, (K, seeds.shape[-1])), dtype=float)
    ok_grasp = np.zeros(K, dtype=bool)
    if np.any(ok_pre):
        q_grasp[ok_pre], ok_grasp[ok_pre] = solve_arm_ik(X_grasp[ok_pre], q_pre[ok_pre])
    valid = np.asarray(ok_pre, dtype=bool) & ok_grasp
    free = np.zeros(K, dtype=bool)
    lift = np.full(K, np.nan)
    q_pull = np.full((K, q_grasp.shape[1]), np.nan)
    if not np.any(valid):
        return q_pre, q_grasp, valid, free, lift, q_pull
    free[valid] = np.asarray(is_free(q_pre[valid]), dtype=bool)
    if config.check_grasp_collision:
        free[valid] &= np.asarray(grasp_is_free(q_grasp[valid]), dtype=bool)
        free[valid & free] = _linear_motion_free(q_pre[valid & free], q_grasp[valid & free], grasp_is_free,
                                                 config.approach_checks)
    if config.check_grasp_collision and lift_height > 0.0 and config.lift_checks:
        lift[valid & free] = _free_lift(q_grasp[valid & free], grasp_is_free, lift_height, config.lift_checks)
        needed = min(config.min_lift_height, lift_height) - 1e-12
        blocked = np.flatnonzero(valid & free & (lift < needed))
        if blocked.size and config.pull_distance > 0.0:
            q_out, out_lift = _pull_out(X_grasp[blocked], q_grasp[blocked], solve_arm_ik, grasp_is_free, config,
                                        lift_height)
            better = out_lift >= needed
            q_pull[blocked[better]], lift[blocked[better]] = q_out[better], out_lift[better]
        free &= ~(lift < needed)
    return q_pre, q_grasp, valid, free, lift, q_pull


def _linear_motion_free(q_from: np.ndarray, q_to: np.ndarray, is_free: IsFreeFn, checks: int) -> np.ndarray:
    """(K,) whether `checks` evenly spaced joint-space interpolants strictly
    between q_from and q_to (K, 11) are free (the end points are not checked)."""
    free = np.ones(q_from.shape[0], dtype=bool)
    for s in np.arange(1, checks + 1) / (checks + 1):
        if not free.any():
            break
        q_mid = q_from[free] + s * layout.wrap_configuration(q_to[free] - q_from[free])
        free[free] = np.asarray(is_free(q_mid), dtype=bool)
    return free


def _free_lift(q: np.ndarray, is_free: IsFreeFn, lift_height: float, checks: int) -> np.ndarray:
    """(K,) the highest of `checks` evenly spaced torso lifts up to
    `lift_height` from q (K, 11) with every lower one free, clipped at the
    torso's upper limit [m]."""
    lift = np.zeros(q.shape[0])
    for height in lift_height * np.arange(1, checks + 1) / checks:
        check = lift >= height - lift_height / checks - 1e-12
        if not check.any():
            break
        ok = np.asarray(is_free(layout.raised_torso(q[check], height)), dtype=bool)
        lift[np.flatnonzero(check)[ok]] = height
    # The torso stops at its upper limit: a grasp high up lifts only what is left.
    return np.minimum(lift, layout.Q_UPPER[layout.TORSO] - q[:, layout.TORSO])


def _pull_out(
    X_grasp: np.ndarray,
    q_grasp: np.ndarray,
    solve_arm_ik: ArmIkFn,
    is_free: IsFreeFn,
    config: GraspRankingConfig,
    lift_height: float,
) -> tuple[np.ndarray, np.ndarray]:
    """Pulling grasps X_grasp (K, 4, 4) out along their horizontal approach
    before the lift (`GraspRankingConfig.pull_distance`). Returns (q_pull
    (K, 11), lift (K,): the free lift from q_pull [m], -1 where the pull is
    impossible: a near-vertical approach, no IK, or a collision on the way)."""
    K = X_grasp.shape[0]
    lift = np.full(K, -1.0)
    back = -X_grasp[:, :3, 0].copy()
    back[:, 2] = 0.0
    norm = np.linalg.norm(back, axis=1)
    ok = norm > 0.3  # within ~70 degrees of vertical there is no "out" to pull to
    X_pull = np.array(X_grasp, copy=True)
    X_pull[ok, :3, 3] += config.pull_distance * back[ok] / norm[ok, None]
    X_pull[:, 2, 3] += config.pull_raise
    q_pull = np.array(q_grasp, dtype=float, copy=True)
    if ok.any():
        q_pull[ok], solved = solve_arm_ik(X_pull[ok], q_grasp[ok])
        ok[ok] = solved
    if ok.any():
        ok[ok] = np.asarray(is_free(q_pull[ok]), dtype=bool)
    if ok.any():
        ok[ok] = _linear_motion_free(q_grasp[ok], q_pull[ok], is_free, max(config.approach_checks, 3))
    if ok.any():
        lift[ok] = _free_lift(q_pull[ok], is_free, lift_height, config.lift_checks)
    return q_pull, lift
