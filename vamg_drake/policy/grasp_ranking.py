"""Grasp goal selection: capability filter, FPS diversity, proximity ranking, validation.

The paper's Algorithm "Grasp Goal Sampling" (appendix): keep the candidates the
capability map calls reachable from the current base, pick ``N_diverse = 20`` by
farthest-point sampling in SE(3) with
``d(T1, T2) = ||t1 - t2|| + 0.1 * angle(R1, R2)`` starting from the best score,
sort them by ``score - 0.01 * ||t - t_ee,current||``, and return the first whose
arm-only IK (base and torso fixed) succeeds and whose configuration is
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

    def __post_init__(self) -> None:
        self.validate()

    def validate(self) -> None:
        """Raises ValueError naming the bad field."""
        if self.n_diverse < 1:
            raise ValueError(f"GraspRankingConfig.n_diverse must be >= 1, got {self.n_diverse}")
        for name in ("approach_checks", "lift_checks"):
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


def rotation_angle(R1: np.ndarray, R2: np.ndarray) -> np.ndarray:
    """Geodesic angle between rotations, broadcasting over leading axes."""
    trace = np.einsum("...ij,...ij->...", R1, R2)  # tr(R1^T R2)
    return np.arccos(np.clip(0.5 * (trace - 1.0), -1.0, 1.0))


def pose_distance(X1: np.ndarray, X2: np.ndarray, rotation_weight: float = 0.1) -> np.ndarray:
    """``||t1 - t2|| + rotation_weight * angle(R1, R2)``, broadcasting over leading axes."""
    translation = np.linalg.norm(X1[..., :3, 3] - X2[..., :3, 3], axis=-1)
    return translation + rotation_weight * rotation_angle(X1[..., :3, :3], X2[..., :3, :3])


def near_any_grasp(X: np.ndarray, X_others: np.ndarray, radius: float, angle: float) -> np.ndarray:
    """(K,) True where grasp X[k] (K, 4, 4) lies within `radius` [m] of one of
    `X_others` (M, 4, 4) with its approach axis (+x of G) within `angle` [rad]
    of that one's: the same grasp whatever its roll about the approach."""
    X, X_others = np.asarray(X, float).reshape(-1, 4, 4), np.asarray(X_others, float).reshape(-1, 4, 4)
    if X.shape[0] == 0 or X_others.shape[0] == 0:
        return np.zeros(X.shape[0], dtype=bool)
    close = np.linalg.norm(X[:, None, :3, 3] - X_others[None, :, :3, 3], axis=-1) <= radius
    aligned = np.einsum("ki,mi->km", X[:, :3, 0], X_others[:, :3, 0]) >= np.cos(angle)
    return np.any(close & aligned, axis=1)


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
) -> GraspGoal:
    """The paper's grasp goal sampling: the first IK- and collision-valid ranked grasp.

    `is_free` checks the pre-grasps; `grasp_is_free` (default `is_free`) the
    grasps, the approaches to them and the lifts after them (the torso raised
    by up to `lift_height`; `check_grasp_collision`), which a grasp source may
    have checked for the gripper itself at finer resolution.
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
    # One batched IK call for the pre-grasps; each grasp is then seeded from its pre-grasp.
    q_pre, ok_pre = solve_arm_ik(X_pre, q_current)
    q_grasp = np.tile(np.asarray(q_current, dtype=float), (order.size, 1))
    ok_grasp = np.zeros(order.size, dtype=bool)
    if np.any(ok_pre):
        q_grasp[ok_pre], ok_grasp[ok_pre] = solve_arm_ik(X_grasp[ok_pre], q_pre[ok_pre])
    valid = ok_pre & ok_grasp
    if not np.any(valid):
        why = "" if n_reachable else "; the capability map calls none reachable"
        return fail(f"IK failed for every ranked grasp (base and torso fixed{why})", n_reachable, order.size)
    free = np.zeros(order.size, dtype=bool)
    free[valid] = np.asarray(is_free(q_pre[valid]), dtype=bool)
    if config.check_grasp_collision:
        free[valid] &= np.asarray(grasp_is_free(q_grasp[valid]), dtype=bool)
        for s in np.arange(1, config.approach_checks + 1) / (config.approach_checks + 1):
            check = valid & free
            if not check.any():
                break
            q_mid = q_pre[check] + s * layout.wrap_configuration(q_grasp[check] - q_pre[check])
            free[check] &= np.asarray(grasp_is_free(q_mid), dtype=bool)
    lift = np.full(order.size, np.nan)
    if config.check_grasp_collision and lift_height > 0.0 and config.lift_checks:
        lift[valid & free] = 0.0
        for height in lift_height * np.arange(1, config.lift_checks + 1) / config.lift_checks:
            check = valid & free & (lift >= height - lift_height / config.lift_checks - 1e-12)
            if not check.any():
                break
            ok = np.asarray(grasp_is_free(layout.raised_torso(q_grasp[check], height)), dtype=bool)
            lift[np.flatnonzero(check)[ok]] = height
        # The torso stops at its upper limit: a grasp high up lifts only what is left.
        lift = np.minimum(lift, layout.Q_UPPER[layout.TORSO] - q_grasp[:, layout.TORSO])
        free &= ~(lift < min(config.min_lift_height, lift_height) - 1e-12)
    winners = np.flatnonzero(valid & free)
    if winners.size == 0:
        return fail("every IK-valid ranked grasp is in collision with the map", n_reachable, order.size)
    full = winners[~(lift[winners] < lift_height - 1e-12)]  # NaN (unchecked) counts as full
    i = int(full[0] if full.size else winners[0])
    return GraspGoal(
        True, q_grasp[i], q_pre[i], X_grasp[i], int(order[i]), len(candidates), n_reachable, i + 1,
        lift_height=None if np.isnan(lift[i]) else float(lift[i]),
    )
