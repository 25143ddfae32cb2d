"""The state-dependent gaze optimizer (paper: "Active Perception Policy").

The action set A_v is a pan x tilt grid over the head's joint limits (default
8 x 5). A gaze a sees a world point x when x lies in the camera frustum of that
gaze within the depth range (occlusion is ignored, as in the paper). The
chosen gaze maximizes sum_x Phi(x) * V(x, a) over weighted importance points:

* Executing a trajectory xi (variants ``velocity_aware`` / ``velocity_agnostic``):
  the points are the robot's body points (sphere centres) at the waypoints of
  the look-ahead window q_0 .. q_{N-1}, resampled every `waypoint_dt` seconds
  from the current progress, so x is in the swept volume V(xi) by construction.
  A point x swept by waypoint i weighs

      w_safety(x) = gamma^i * w_d(x, q_i) * ||qdot_i||      (velocity_agnostic: no ||qdot_i||)
      w_d(x, q_i) = exp(-1/2 ((d(x, q_i) - d_mid) / sigma)^2),  sigma = max(1, 0.25 N),

  and points swept by several waypoints accumulate (the paper's sum over i).
  With `skip_occupied` (off by default), a swept point that lies inside the
  robot's body now weighs nothing: no obstacle can stand where the robot
  stands, so looking there teaches the map nothing. A base turning in place
  sweeps almost only its own footprint; the weight then goes to the space the
  arm swings into.
  Distance choice: d(x, q_i) is the look-ahead distance from the robot now to
  the waypoint that sweeps x, counted in waypoints (= i). The paper's sigma =
  max(1, 0.25 N) is in waypoints, so this is the reading in which its units are
  consistent; d_mid = `d_mid_fraction` * N waypoints ("too close: no reaction
  time; too far: less immediate threat"). With uniform time resampling, the
  velocity-aware weight is proportional to distance travelled, while the
  velocity-agnostic one is proportional to time spent.
* Planning (no trajectory), and always for ``target_only``: points on a lattice
  filling the ball of radius `target_radius` (eps) around the target p, weight 1.

Ties (e.g. several gazes that all see the whole target ball) go to the gaze
whose optical axis points closest to the weighted centroid of the importance
points, so an unobstructed target is centred as well as the grid allows.
"""


import dataclasses as dc
import logging

import numba
import numpy as np

from vamg_drake.perception.raycast_map import inside_any_sphere
from vamg_drake.robot import layout
from vamg_drake.robot.head_camera import CameraIntrinsics
from vamg_drake.robot.kinematics import FetchKinematics

_log = logging.getLogger(__name__)

VARIANTS = ("velocity_aware", "velocity_agnostic", "target_only")


@dc.dataclass
class GazeConfig:
    """Parameters of the gaze optimizer (paper values unless noted)."""

    #: One of "velocity_aware" (default), "velocity_agnostic" (ablation), "target_only".
    variant: str = "velocity_aware"
    num_pan: int = 8
    num_tilt: int = 5
    pan_min: float = layout.HEAD_PAN_LIMITS[0]
    pan_max: float = layout.HEAD_PAN_LIMITS[1]
    tilt_min: float = layout.HEAD_TILT_LIMITS[0]
    tilt_max: float = layout.HEAD_TILT_LIMITS[1]
    #: Visibility depth range [m] (the map's range).
    depth_min: float = 0.2
    depth_max: float = 3.0
    #: Temporal decay per look-ahead waypoint.
    gamma: float = 0.999
    #: Look-ahead window: at most this many waypoints, `waypoint_dt` apart.
    lookahead_waypoints: int = 50
    waypoint_dt: float = 0.1
    #: d_mid as a fraction of the window length N (in waypoints).
    d_mid_fraction: float = 0.25
    #: sigma = max(sigma_min, sigma_fraction * N) (paper: 1.0, 0.25).
    sigma_min: float = 1.0
    sigma_fraction: float = 0.25
    #: eps [m]: radius of the importance ball around the target while planning.
    target_radius: float = 0.15
    #: Lattice spacing [m] of the points filling the target ball.
    target_spacing: float = 0.05
    #: Looking at requested points, a gaze that sees at least this fraction of the best
    #: gaze's points and lies closer to the current head command wins (the head moves at
    #: its rate limit: swinging across for a few more points costs more than it sees).
    look_score_fraction: float = 0.8
    #: Swept points inside the robot's spheres at the window's first waypoint (where the
    #: robot is now) get no weight: that space holds the robot, not an unseen obstacle.
    #: Off by default until its closed-loop A/B on the paper tasks is complete.
    skip_occupied: bool = False

    def __post_init__(self) -> None:
        self.validate()

    def validate(self) -> None:
        """Raises ValueError naming the first bad field (yaml_load_typed skips __post_init__)."""
        if self.variant not in VARIANTS:
            raise ValueError(f"GazeConfig.variant must be one of {VARIANTS}, got {self.variant!r}")
        if self.num_pan < 1 or self.num_tilt < 1:
            raise ValueError(f"GazeConfig: num_pan/num_tilt must be >= 1, got {self.num_pan}, {self.num_tilt}")
        if not (self.pan_min <= self.pan_max and self.tilt_min <= self.tilt_max):
            raise ValueError("GazeConfig: pan_min/tilt_min must not exceed pan_max/tilt_max")
        if not 0.0 <= self.depth_min < self.depth_max:
            raise ValueError(f"GazeConfig: need 0 <= depth_min < depth_max, got {self.depth_min}, {self.depth_max}")
        if not 0.0 < self.gamma <= 1.0:
            raise ValueError(f"GazeConfig.gamma must be in (0, 1], got {self.gamma}")
        if self.lookahead_waypoints < 1 or not self.waypoint_dt > 0.0:
            raise ValueError("GazeConfig: lookahead_waypoints must be >= 1 and waypoint_dt > 0")
        if not (self.target_radius >= 0.0 and self.target_spacing > 0.0):
            raise ValueError("GazeConfig: target_radius must be >= 0 and target_spacing > 0")
        if not 0.0 < self.look_score_fraction <= 1.0:
            raise ValueError(f"GazeConfig.look_score_fraction must be in (0, 1], got {self.look_score_fraction}")


@dc.dataclass(frozen=True, eq=False)
class ImportanceField:
    """Weighted importance points: points (M, 3) in W, weights (M,) >= 0."""

    points: np.ndarray
    weights: np.ndarray

    @property
    def total(self) -> float:
        return float(self.weights.sum())


@dc.dataclass(frozen=True, eq=False)
class GazeDecision:
    """The chosen gaze. `scores` (K,) are per candidate, in `GazeOptimizer.candidates` order."""

    index: int
    pan: float
    tilt: float
    score: float
    scores: np.ndarray
    #: False when no candidate sees any importance (the decision then only follows the centroid).
    sees_importance: bool


class GazeOptimizer:
    """Chooses a head (pan, tilt) from the candidate grid; no Drake systems."""

    def __init__(self, intrinsics: CameraIntrinsics, config: GazeConfig | None = None):
        self.config = config or GazeConfig()
        self.config.validate()
        self.intrinsics = intrinsics
        c = self.config
        pans = np.linspace(c.pan_min, c.pan_max, c.num_pan)
        tilts = np.linspace(c.tilt_min, c.tilt_max, c.num_tilt)
        #: (K, 2) candidate (pan, tilt), pan-major.
        self.candidates = np.array([(p, t) for p in pans for t in tilts])
        r = c.target_radius
        g = np.arange(-r, r + 1e-12, c.target_spacing)
        g = g - g.mean()
        lattice = np.stack(np.meshgrid(g, g, g, indexing="ij"), -1).reshape(-1, 3)
        lattice = lattice[np.linalg.norm(lattice, axis=1) <= r + 1e-12]
        self._ball = lattice if lattice.shape[0] else np.zeros((1, 3))

    @property
    def num_candidates(self) -> int:
        return int(self.candidates.shape[0])

    # ---- importance fields ---------------------------------------------------------
    def target_importance(self, p_WT: np.ndarray) -> ImportanceField:
        """Phi = 1[x in B_eps(p)]: lattice points in the ball around the target, weight 1."""
        p = np.asarray(p_WT, dtype=float).reshape(3)
        if not np.all(np.isfinite(p)):
            raise ValueError(f"gaze target p_WT is not finite: {p}")
        pts = self._ball + p
        return ImportanceField(points=pts, weights=np.ones(pts.shape[0]))

    def lookahead_window(self, times: np.ndarray, q: np.ndarray, t_now: float) -> tuple[np.ndarray, np.ndarray]:
        """Resamples the remaining trajectory: (q_i (N, 11), ||qdot_i|| (N,)) from time t_now.

        Args:
            times: (T,) strictly increasing waypoint times of the trajectory.
            q: (T, 11) waypoints (continuous joints unwrapped).
            t_now: the current progress, on the same clock as `times`.
        """
        times = np.asarray(times, dtype=float).reshape(-1)
        q = np.asarray(q, dtype=float)
        c = self.config
        t0 = float(np.clip(t_now, times[0], times[-1]))
        n = int(min(c.lookahead_waypoints, np.floor((times[-1] - t0) / c.waypoint_dt + 1e-9) + 1))
        t = t0 + c.waypoint_dt * np.arange(max(n, 1))
        qs = np.empty((t.shape[0], q.shape[1]))
        for j in range(q.shape[1]):
            qs[:, j] = np.interp(t, times, q[:, j])
        if times.shape[0] > 1:
            qd = np.diff(q, axis=0) / np.diff(times)[:, None]
            k = np.clip(np.searchsorted(times, t, side="right") - 1, 0, times.shape[0] - 2)
            speed = np.linalg.norm(qd[k], axis=1)
            speed[t >= times[-1]] = 0.0
        else:
            speed = np.zeros(t.shape[0])
        return qs, speed

    def trajectory_importance(self, body_points_W: np.ndarray, speeds: np.ndarray,
                              radii: np.ndarray | None = None) -> ImportanceField:
        """w_safety weights for body points (N, S, 3) at the N look-ahead waypoints with speeds (N,).

        With the body's sphere `radii` (S,) and `GazeConfig.skip_occupied`, the points
        inside the spheres of waypoint 0 (the robot now) weigh nothing.
        """
        pts = np.asarray(body_points_W, dtype=float)
        speeds = np.asarray(speeds, dtype=float).reshape(-1)
        if pts.ndim != 3 or pts.shape[2] != 3 or pts.shape[0] != speeds.shape[0]:
            raise ValueError(
                f"trajectory_importance: body_points_W must be (N, S, 3) with N = len(speeds) = "
                f"{speeds.shape[0]}, got {pts.shape}"
            )
        c = self.config
        n = pts.shape[0]
        i = np.arange(n, dtype=float)
        sigma = max(c.sigma_min, c.sigma_fraction * n)
        d_mid = c.d_mid_fraction * n
        w = c.gamma**i * np.exp(-0.5 * ((i - d_mid) / sigma) ** 2)
        if c.variant == "velocity_aware":
            w = w * speeds
        weights = np.repeat(w, pts.shape[1])
        flat = pts.reshape(-1, 3)
        if c.skip_occupied and radii is not None and n > 0:
            radii = np.asarray(radii, dtype=float).reshape(-1)
            if radii.shape[0] != pts.shape[1]:
                raise ValueError(f"trajectory_importance: radii must be ({pts.shape[1]},), got {radii.shape}")
            occupied = inside_any_sphere(np.ascontiguousarray(flat), np.ascontiguousarray(pts[0]), radii)
            weights = np.where(occupied, 0.0, weights)
        return ImportanceField(points=flat, weights=weights)

    # ---- selection -----------------------------------------------------------------
    def scores(self, field: ImportanceField, X_WC: np.ndarray) -> np.ndarray:
        """(K,) visible importance per candidate camera pose X_WC (K, 4, 4)."""
        X = _check_poses(X_WC, self.num_candidates)
        i = self.intrinsics
        return _frustum_scores(
            np.ascontiguousarray(field.points, dtype=float), np.ascontiguousarray(field.weights, dtype=float),
            X, i.fx, i.fy, i.cx, i.cy, i.width, i.height, self.config.depth_min, self.config.depth_max,
        )

    def choose(self, field: ImportanceField, X_WC: np.ndarray) -> GazeDecision:
        """The candidate that sees the most importance (ties: axis closest to the weighted centroid)."""
        X = _check_poses(X_WC, self.num_candidates)
        s = self.scores(field, X)
        w = field.weights
        if field.points.shape[0] and w.sum() > 0:
            centroid = (field.points * w[:, None]).sum(0) / w.sum()
            to_c = centroid[None, :] - X[:, :3, 3]
            to_c /= np.maximum(np.linalg.norm(to_c, axis=1, keepdims=True), 1e-12)
            alignment = np.einsum("kj,kj->k", X[:, :3, 2], to_c)
        else:
            alignment = -np.abs(self.candidates).sum(1)  # nothing to see: the most neutral gaze
        best = s.max()
        sees = bool(best > 0.0)
        tied = np.flatnonzero(s >= best - 1e-9 * max(abs(best), 1.0)) if sees else np.arange(s.shape[0])
        k = int(tied[np.argmax(alignment[tied])])
        return GazeDecision(
            index=k, pan=float(self.candidates[k, 0]), tilt=float(self.candidates[k, 1]),
            score=float(s[k]), scores=s, sees_importance=sees,
        )


    def choose_near(self, field: ImportanceField, X_WC: np.ndarray, head: np.ndarray) -> GazeDecision:
        """Among the candidates that see at least `look_score_fraction` of the best
        score, the one closest (max-norm) to the head command `head` (pan, tilt)."""
        decision = self.choose(field, X_WC)
        if not decision.sees_importance:
            return decision
        s = decision.scores
        good = np.flatnonzero(s >= self.config.look_score_fraction * s.max())
        k = int(good[np.argmin(np.abs(self.candidates[good] - np.asarray(head, float)[None]).max(axis=1))])
        return GazeDecision(index=k, pan=float(self.candidates[k, 0]), tilt=float(self.candidates[k, 1]),
                            score=float(s[k]), scores=s, sees_importance=True)


def frustum_scores_reference(
    points: np.ndarray, weights: np.ndarray, X_WC: np.ndarray, intrinsics: CameraIntrinsics, depth_min: float, depth_max: float
) -> np.ndarray:
    """Plain NumPy frustum scores (K,) (the reference for the numba kernel)."""
    R_CW = np.transpose(X_WC[:, :3, :3], (0, 2, 1))
    p_C = np.einsum("kij,mj->kmi", R_CW, points) - np.einsum("kij,kj->ki", R_CW, X_WC[:, :3, 3])[:, None, :]
    z = p_C[..., 2]
    with np.errstate(divide="ignore", invalid="ignore"):
        u = np.floor(intrinsics.fx * p_C[..., 0] / z + intrinsics.cx + 0.5)
        v = np.floor(intrinsics.fy * p_C[..., 1] / z + intrinsics.cy + 0.5)
    vis = (z >= depth_min) & (z <= depth_max) & (u >= 0) & (u < intrinsics.width) & (v >= 0) & (v < intrinsics.height)
    return vis.astype(float) @ weights


def _check_poses(X_WC: np.ndarray, k: int) -> np.ndarray:
    X = np.ascontiguousarray(np.asarray(X_WC, dtype=float))
    if X.shape != (k, 4, 4):
        raise ValueError(f"candidate camera poses X_WC must have shape ({k}, 4, 4), got {X.shape}")
    if not np.all(np.isfinite(X)):
        raise ValueError("candidate camera poses X_WC contain NaN or inf")
    return X


@numba.njit(cache=True)
def _frustum_scores(points, weights, X_WC, fx, fy, cx, cy, width, height, depth_min, depth_max):
    k_count = X_WC.shape[0]
    m = points.shape[0]
    out = np.zeros(k_count)
    for k in range(k_count):
        R = X_WC[k, :3, :3]
        t = X_WC[k, :3, 3]
        # p_C = R^T (p_W - t)
        acc = 0.0
        for i in range(m):
            dx = points[i, 0] - t[0]
            dy = points[i, 1] - t[1]
            dz = points[i, 2] - t[2]
            z = R[0, 2] * dx + R[1, 2] * dy + R[2, 2] * dz
            if z < depth_min or z > depth_max:
                continue
            x = R[0, 0] * dx + R[1, 0] * dy + R[2, 0] * dz
            u = np.floor(fx * x / z + cx + 0.5)
            if u < 0 or u >= width:
                continue
            y = R[0, 1] * dx + R[1, 1] * dy + R[2, 1] * dz
            v = np.floor(fy * y / z + cy + 0.5)
            if v < 0 or v >= height:
                continue
            acc += weights[i]
        out[k] = acc
    return out


class FetchGazeCameras:
    """Camera poses X_WC of the candidate gazes at any configuration q, with one FK call.

    The head chain hangs off `HEAD_PARENT_LINK`, so X_WC(q, gaze_k) =
    X_WP(q) * X_PC(gaze_k); the X_PC are computed once per candidate set.
    """

    HEAD_PARENT_LINK = "torso_lift_link"

    def __init__(self, candidates: np.ndarray):
        self._kin = FetchKinematics.instance()
        self.candidates = np.asarray(candidates, dtype=float)
        q_ref = layout.stow_configuration(0.0, 0.0, 0.0)
        X_WP = self._kin.frame_pose(self.HEAD_PARENT_LINK, q_ref)
        self._X_PC = np.linalg.inv(X_WP)[None] @ self._kin.camera_poses_for_gazes(q_ref, self.candidates)
        # The composition must reproduce the full FK (it would not if the URDF's head moved).
        q_test = np.array([0.3, -0.2, 0.7, 0.25, 0.4, -0.3, 0.2, 0.8, -0.5, 0.6, 0.1])
        if not np.allclose(self.poses(q_test), self._kin.camera_poses_for_gazes(q_test, self.candidates), atol=1e-9):
            raise RuntimeError(f"FetchGazeCameras: the head is not a child chain of {self.HEAD_PARENT_LINK}")

    def poses(self, q: np.ndarray) -> np.ndarray:
        """(K, 4, 4) X_WC of every candidate gaze at configuration q (11,)."""
        X_WP = self._kin.frame_pose(self.HEAD_PARENT_LINK, np.asarray(q, dtype=float))
        return X_WP[None] @ self._X_PC


def decide_fetch_gaze(
    optimizer: GazeOptimizer,
    q_now: np.ndarray,
    p_WTarget: np.ndarray | None,
    sweep=None,
    t_now: float = 0.0,
    cameras: FetchGazeCameras | None = None,
    look_points: np.ndarray | None = None,
    head_now: np.ndarray | None = None,
) -> GazeDecision:
    """One gaze decision for the Fetch (its kinematics and sphere model).

    Look requests come first, in every variant: while the tracker holds the
    robot for unseen cells on its path (`look_points`, weight 1 each), the
    gaze that sees most of them wins (the robot stands still, so the
    velocity-weighted window would give them no weight), preferring one
    near the current head command `head_now` (`GazeOptimizer.choose_near`).
    Executing (a `TrajectorySweep` is given and the variant is not
    ``target_only``): the body points are the robot's sphere centres along the
    look-ahead window of the sweep, every `waypoint_dt`. Otherwise the target
    ball is the importance; with neither a moving trajectory nor a target,
    every candidate scores 0 and the most neutral gaze wins.

    Args:
        optimizer: the core optimizer.
        q_now: (11,) current whole-body configuration (the head sits on it).
        p_WTarget: (3,) target position, or None.
        sweep: the executing trajectory's `TrajectorySweep`, or None while planning.
        t_now: current progress on the trajectory's clock [s].
        cameras: cached candidate camera poses (made here when None).
        look_points: (M, 3) points the tracker waits to see, or None / empty.
        head_now: (2,) the current head command (pan, tilt), or None.
    """
    q_now = np.asarray(q_now, dtype=float).reshape(layout.NQ)
    if not np.all(np.isfinite(q_now)):
        raise ValueError("decide_fetch_gaze: q_now contains NaN or inf")
    cameras = cameras or FetchGazeCameras(optimizer.candidates)
    X_WC = cameras.poses(q_now)
    if look_points is not None and len(look_points):
        points = np.asarray(look_points, dtype=float).reshape(-1, 3)
        field = ImportanceField(points, np.ones(points.shape[0]))
        decision = optimizer.choose(field, X_WC) if head_now is None else optimizer.choose_near(field, X_WC, head_now)
        if decision.sees_importance:
            return decision
    if sweep is not None and optimizer.config.variant != "target_only":
        stride = max(1, int(round(optimizer.config.waypoint_dt / sweep.dt)))
        body, speed = sweep.window(t_now, optimizer.config.lookahead_waypoints, stride)
        field = optimizer.trajectory_importance(body, speed, sweep.radii)
        if field.total > 0.0 or p_WTarget is None:
            return optimizer.choose(field, X_WC)
        # The window is at rest (e.g. the trajectory has ended): fall back to the target.
    if p_WTarget is None:
        return optimizer.choose(ImportanceField(np.empty((0, 3)), np.empty(0)), X_WC)
    return optimizer.choose(optimizer.target_importance(p_WTarget), X_WC)
