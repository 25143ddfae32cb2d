"""RRT-Connect for the torso + arm with the collision check inside Numba.

The same algorithm as `vamg_drake.planning.rrt_connect` (Kuffner & LaValle
2000: alternate trees, extend toward a sample, greedy connect), specialised to
the two searches of the whole-body planner so that the whole inner loop
(nearest neighbour by brute force over preallocated node arrays, steering,
motion checks with forward kinematics fused into the sphere tests) runs in one
compiled kernel:

* `FixedBaseSpace`: x = torso + 7 arm joints (8,), the base held at a pose.
* `AlongPathSpace`: x = (u, torso + arm) (9,), u the base's progress along a
  base path in seconds of travel at the tracker's limits (the base pose is
  interpolated on the path; u may go back: the base reverses on its curve).

Motions are checked like `SphereCollisionChecker.motion_free`: states at a spacing
where no sphere centre moves more than the checker's motion resolution (the
per-coordinate lever bounds), coarse-to-fine, early exit.

Random numbers are drawn up front from the caller's generator, so the same
seed gives the same tree. The iteration cap bounds the work (deterministic);
an optional wall-clock deadline, the planner's safety net, is checked between
chunks of iterations.
"""

import dataclasses
import math
import time

import numba
import numpy as np

from vamg_drake.planning.sphere_checks import config_free_data
from vamg_drake.planning.sphere_collision import SphereCollisionChecker
from vamg_drake.robot import layout


@numba.njit(cache=True, inline="always")
def _state_free(data):
    """Validity of data[0][0] (the (1, 11) scratch configuration)."""
    return config_free_data(data)


@numba.njit(cache=True)
def _set_state(x, along, base, poses, cum, dt, q):
    """q (11,) = the whole-body configuration of search state x."""
    if along:
        u = x[0]
        last = poses.shape[0] - 2
        i = np.searchsorted(cum, u, side="right") - 1
        i = min(max(i, 0), last)
        f = (u - cum[i]) / max(dt[i], 1e-12)
        f = min(max(f, 0.0), 1.0)
        for a in range(3):
            q[a] = poses[i, a] + f * (poses[i + 1, a] - poses[i, a])
        for a in range(1, x.shape[0]):
            q[2 + a] = x[a]
    else:
        for a in range(3):
            q[a] = base[a]
        for a in range(x.shape[0]):
            q[3 + a] = x[a]


@numba.njit(cache=True)
def _motion_free(xa, xb, along, base, poses, cum, dt, lever, res, xs, data):
    """Straight motion xa -> xb free (xa itself is assumed checked)."""
    d = xa.shape[0]
    bound = 0.0
    for a in range(d):
        bound += abs(xb[a] - xa[a]) * lever[a]
    n = max(int(math.ceil(bound / res)), 1)  # segments; states 1..n
    q = data[0][0]
    # Coarse to fine: the end state, then the odd multiples of halving strides
    # (every state 1..n-1 once).
    if not _check_at(n, n, xa, xb, along, base, poses, cum, dt, xs, q, data):
        return False
    stride = 1
    while stride * 2 <= n - 1:
        stride *= 2
    while stride >= 1 and n > 1:
        k = stride
        while k < n:
            if not _check_at(k, n, xa, xb, along, base, poses, cum, dt, xs, q, data):
                return False
            k += 2 * stride
        stride //= 2
    return True


@numba.njit(cache=True)
def _segment_free(xa, xb, along, base, poses, cum, dt, lever, res, xs, data):
    """xa itself and the straight motion xa -> xb are free (one compiled call
    from Python: each call passes the ~50 arrays of `data`, ~8 us)."""
    _set_state(xa, along, base, poses, cum, dt, data[0][0])
    if not _state_free(data):
        return False
    return _motion_free(xa, xb, along, base, poses, cum, dt, lever, res, xs, data)


@numba.njit(cache=True)
def _check_at(k, n, xa, xb, along, base, poses, cum, dt, xs, q, data):
    s = k / n
    for a in range(xa.shape[0]):
        xs[a] = xa[a] + s * (xb[a] - xa[a])
    _set_state(xs, along, base, poses, cum, dt, q)
    return _state_free(data)


@numba.njit(cache=True)
def _nearest(nodes, count, x, w):
    best, bi = np.inf, 0
    for i in range(count):
        m = 0.0
        for a in range(x.shape[0]):
            v = abs(nodes[i, a] - x[a]) * w[a]
            if v > m:
                m = v
        if m < best:
            best, bi = m, i
    return bi


@numba.njit(cache=True)
def _steer(frm, to, w, step, out):
    m = 0.0
    for a in range(frm.shape[0]):
        v = abs(to[a] - frm[a]) * w[a]
        if v > m:
            m = v
    if m <= step:
        out[:] = to
        return True
    for a in range(frm.shape[0]):
        out[a] = frm[a] + (to[a] - frm[a]) * (step / m)
    return False


@numba.njit(cache=True)
def _rrt_connect_kernel(nodes, parent, count, it0, it1, rand, lo, hi, w, step, goal_bias,
                        along, base, poses, cum, dt, lever, res, data, result):
    """Iterations it0..it1-1 of RRT-Connect on trees nodes[0] (start) and
    nodes[1] (goal). Returns 1 when connected (result = [tree of the new
    node, its index, index of the node reached in the other tree]), 2 when
    a tree is full, 0 otherwise."""
    d = lo.shape[0]
    cap = nodes.shape[1]
    target = np.empty(d)
    qn = np.empty(d)
    qb = np.empty(d)
    xs = np.empty(d)
    for it in range(it0, it1):
        ta = it % 2
        tb = 1 - ta
        if count[0] >= cap or count[1] >= cap:
            return 2
        if rand[it, 0] < goal_bias:
            target[:] = nodes[tb, 0]
        else:
            for a in range(d):
                target[a] = lo[a] + rand[it, 1 + a] * (hi[a] - lo[a])
        ia = _nearest(nodes[ta], count[ta], target, w)
        _steer(nodes[ta, ia], target, w, step, qn)
        if not _motion_free(nodes[ta, ia], qn, along, base, poses, cum, dt, lever, res, xs, data):
            continue
        new_a = count[ta]
        nodes[ta, new_a] = qn
        parent[ta, new_a] = ia
        count[ta] += 1
        ib = _nearest(nodes[tb], count[tb], qn, w)
        while count[tb] < cap:
            reached = _steer(nodes[tb, ib], qn, w, step, qb)
            if not _motion_free(nodes[tb, ib], qb, along, base, poses, cum, dt, lever, res, xs, data):
                break
            nodes[tb, count[tb]] = qb
            parent[tb, count[tb]] = ib
            ib = count[tb]
            count[tb] += 1
            if reached:
                result[0] = ta
                result[1] = new_a
                result[2] = ib
                return 1
    return 0


@dataclasses.dataclass
class KernelRRTConfig:
    """Attributes:
        step: maximum extension per step (weighted max-norm).
        max_iterations: iteration cap (bounds the work deterministically).
        goal_bias: probability of sampling the other tree's root.
        capacity: nodes per tree.
        chunk: iterations between wall-clock deadline checks.
    """

    step: float = 0.6
    max_iterations: int = 400
    goal_bias: float = 0.05
    capacity: int = 8192
    chunk: int = 32


class WholeBodySearchSpace:
    """A search space of the whole-body planner with compiled motion checks.

    Use `fixed_base` or `along_path`. `to_configurations` maps search states
    (N, d) to whole-body configurations (N, 11).
    """

    def __init__(self, checker: SphereCollisionChecker, along: bool, base: np.ndarray, poses: np.ndarray,
                 cum: np.ndarray, dt: np.ndarray, lever: np.ndarray):
        self.checker = checker
        self.along = along
        self.base = np.ascontiguousarray(base, dtype=float)
        self.poses = np.ascontiguousarray(poses, dtype=float)
        self.cum = np.ascontiguousarray(cum, dtype=float)
        self.dt = np.ascontiguousarray(dt, dtype=float)
        self.lever = np.ascontiguousarray(lever, dtype=float)
        self.res = float(checker.config.motion_resolution)
        self.data = checker.base_pose_check_data(np.zeros(layout.NQ - 3))
        self._xs = np.empty(self.lever.shape[0])

    @staticmethod
    def fixed_base(checker: SphereCollisionChecker, base: np.ndarray) -> "WholeBodySearchSpace":
        """x = torso + arm (8,) at the base pose (3,)."""
        dummy = np.zeros((2, 3))
        return WholeBodySearchSpace(checker, False, np.asarray(base, float), dummy, np.zeros(2), np.ones(1),
                                    checker.lever[3:])

    @staticmethod
    def along_path(checker: SphereCollisionChecker, poses: np.ndarray) -> "WholeBodySearchSpace":
        """x = (u, torso + arm) (9,) along the base path poses (N, 3), N >= 2."""
        d = np.diff(poses, axis=0)
        dt = np.maximum(np.hypot(d[:, 0], d[:, 1]) / layout.TRACKER_BASE_V,
                        np.abs(d[:, 2]) / layout.TRACKER_BASE_W)
        cum = np.concatenate([[0.0], np.cumsum(dt)])
        base_rate = layout.TRACKER_BASE_V + layout.TRACKER_BASE_W * checker.lever[2]
        lever = np.concatenate([[base_rate], checker.lever[3:]])
        return WholeBodySearchSpace(checker, True, np.zeros(3), poses, cum, dt, lever)

    @property
    def duration(self) -> float:
        """Length of the u axis [s] (along_path)."""
        return float(self.cum[-1])

    def motion_free(self, xa: np.ndarray, xb: np.ndarray) -> bool:
        """The straight motion xa -> xb is free (both ends included)."""
        xa = np.ascontiguousarray(xa, dtype=float)
        xb = np.ascontiguousarray(xb, dtype=float)
        return bool(_segment_free(xa, xb, self.along, self.base, self.poses, self.cum, self.dt, self.lever,
                                  self.res, self._xs, self.data))

    def to_configurations(self, X: np.ndarray) -> np.ndarray:
        X = np.atleast_2d(np.asarray(X, float))
        out = np.empty((X.shape[0], layout.NQ))
        for k in range(X.shape[0]):
            _set_state(np.ascontiguousarray(X[k]), self.along, self.base, self.poses, self.cum, self.dt, out[k])
        return out

    def states(self, xa: np.ndarray, xb: np.ndarray) -> np.ndarray:
        """Whole-body states (n, 11) of the motion xa -> xb at the checked spacing, both ends included."""
        bound = float(np.abs(np.asarray(xb) - xa) @ self.lever)
        n = max(int(math.ceil(bound / self.res)), 1) + 1
        X = xa + np.linspace(0.0, 1.0, n)[:, None] * (np.asarray(xb) - xa)
        return self.to_configurations(X)

    def rrt_connect(self, start: np.ndarray, goal: np.ndarray, lower: np.ndarray, upper: np.ndarray,
                    weights: np.ndarray, rng: np.random.Generator, config: KernelRRTConfig,
                    deadline_s: float | None = None) -> tuple[np.ndarray | None, str]:
        """Plans start -> goal (search states, assumed valid); returns
        (path (N, d), "") or (None, "timeout" | "iteration limit" | "tree full")."""
        return RRTConnectSearch(self, start, goal, lower, upper, weights, rng, config).run(None, deadline_s)


class RRTConnectSearch:
    """One RRT-Connect run of `WholeBodySearchSpace` that can be stopped
    after some iterations and resumed later (its random numbers, one row per
    iteration up to `config.max_iterations`, are drawn at construction, so
    the result does not depend on where it was paused).

    Args: as `WholeBodySearchSpace.rrt_connect`.
    """

    def __init__(self, space: WholeBodySearchSpace, start: np.ndarray, goal: np.ndarray, lower: np.ndarray,
                 upper: np.ndarray, weights: np.ndarray, rng: np.random.Generator, config: KernelRRTConfig):
        self.space = space
        self.config = config
        self.start = np.asarray(start, float)
        self.goal = np.asarray(goal, float)
        self.iteration = 0
        self._direct: bool | None = None
        self._done: tuple[np.ndarray | None, str] | None = None
        d = self.start.shape[0]
        self._rand = rng.random((config.max_iterations, d + 1))
        self._nodes = np.empty((2, config.capacity, d))
        self._parent = np.empty((2, config.capacity), dtype=np.int64)
        self._count = np.ones(2, dtype=np.int64)
        self._nodes[0, 0], self._nodes[1, 0] = self.start, self.goal
        self._parent[:, 0] = -1
        self._result = np.zeros(3, dtype=np.int64)
        self._lo = np.ascontiguousarray(lower, dtype=float)
        self._hi = np.ascontiguousarray(upper, dtype=float)
        self._w = np.ascontiguousarray(weights, dtype=float)

    def run(self, iterations: int | None = None, deadline_s: float | None = None) -> tuple[np.ndarray | None, str]:
        """Runs up to `iterations` more iterations (None: up to the cap).
        Returns (path, "") when connected, else (None, "timeout" |
        "iteration limit" | "tree full"); "iteration limit" before the cap
        means it may be resumed."""
        if self._done is not None:
            return self._done
        space, config = self.space, self.config
        if self._direct is None:
            self._direct = space.motion_free(self.start, self.goal)
            if self._direct:
                self._done = (np.stack([self.start, self.goal]), "")
                return self._done
        until = config.max_iterations if iterations is None else min(self.iteration + iterations,
                                                                      config.max_iterations)
        while self.iteration < until:
            if deadline_s is not None and time.perf_counter() > deadline_s:
                return None, "timeout"
            it0 = self.iteration
            it1 = min(it0 + config.chunk, until)
            status = _rrt_connect_kernel(self._nodes, self._parent, self._count, it0, it1, self._rand, self._lo,
                                         self._hi, self._w, config.step, config.goal_bias, space.along, space.base,
                                         space.poses, space.cum, space.dt, space.lever, space.res, space.data,
                                         self._result)
            self.iteration = it1
            if status == 1:
                ta, ia, ib = (int(v) for v in self._result)
                path_a = _to_root(self._nodes[ta], self._parent[ta], ia)[::-1]
                path_b = _to_root(self._nodes[1 - ta], self._parent[1 - ta], ib)[1:]
                path = np.concatenate([path_a, path_b])
                self._done = ((path if ta == 0 else path[::-1]), "")
                return self._done
            if status == 2:
                self._done = (None, "tree full")
                return self._done
        if self.iteration >= config.max_iterations:
            self._done = (None, "iteration limit")
        return None, "iteration limit"


def warm_up(space: WholeBodySearchSpace) -> None:
    """Runs the compiled RRT-Connect kernel for two iterations on `space` (numba
    compiles it, or loads it from its cache, on first use: tens of ms even
    when cached), without any search result."""
    d = space.lever.shape[0]
    x = np.zeros(d)
    nodes = np.zeros((2, 4, d))
    parent = np.full((2, 4), -1, dtype=np.int64)
    count = np.ones(2, dtype=np.int64)
    _rrt_connect_kernel(nodes, parent, count, 0, 2, np.full((2, d + 1), 0.5), x, x + 1e-3, np.ones(d), 0.1, 0.0,
                        space.along, space.base, space.poses, space.cum, space.dt, space.lever, space.res,
                        space.data, np.zeros(3, dtype=np.int64))


def _to_root(nodes: np.ndarray, parent: np.ndarray, i: int) -> np.ndarray:
    out = []
    while i >= 0:
        out.append(nodes[i].copy())
        i = int(parent[i])
    return np.array(out)
