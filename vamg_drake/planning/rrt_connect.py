"""RRT-Connect (Kuffner & LaValle 2000) over a box of joint space.

Generic: the caller gives a motion validity function (qa, qb) -> bool that
checks the straight segment (in batches, see `SphereCollisionChecker.motion_free`)
and the sampling bounds. Used for the torso + 7-joint arm at a fixed base.
"""

import dataclasses
from typing import Callable

import numpy as np


@dataclasses.dataclass
class RRTConnectConfig:
    """Attributes:
        step: maximum extension per step (max-norm over joints) [rad or m].
        max_iterations: iteration limit.
        goal_bias: probability of sampling the other tree's root.
    """

    step: float = 0.6
    max_iterations: int = 4000
    goal_bias: float = 0.05


class _Tree:
    def __init__(self, root: np.ndarray, capacity: int = 256):
        self.q = np.empty((capacity, root.shape[0]))
        self.parent = np.empty(capacity, dtype=np.int64)
        self.n = 0
        self.add(root, -1)

    def add(self, q: np.ndarray, parent: int) -> int:
        if self.n == self.q.shape[0]:
            self.q = np.concatenate([self.q, np.empty_like(self.q)])
            self.parent = np.concatenate([self.parent, np.empty_like(self.parent)])
        self.q[self.n] = q
        self.parent[self.n] = parent
        self.n += 1
        return self.n - 1

    def nearest(self, q: np.ndarray, weights: np.ndarray) -> int:
        d = np.abs(self.q[: self.n] - q) * weights
        return int(np.argmin(d.max(axis=1)))

    def path_to_root(self, i: int) -> list[np.ndarray]:
        out = []
        while i >= 0:
            out.append(self.q[i].copy())
            i = int(self.parent[i])
        return out


def rrt_connect(
    start: np.ndarray,
    goal: np.ndarray,
    motion_free: Callable[[np.ndarray, np.ndarray], bool],
    lower: np.ndarray,
    upper: np.ndarray,
    rng: np.random.Generator,
    config: RRTConnectConfig | None = None,
    weights: np.ndarray | None = None,
) -> tuple[np.ndarray | None, str]:
    """Plans start->goal; returns (path (N, d), "") or (None, reason).

    Args:
        start, goal: (d,) configurations (assumed valid by the caller).
        motion_free: validity of the straight segment between two configurations.
        lower, upper: (d,) sampling bounds.
        rng: random generator (the same seed gives the same path).
        weights: (d,) per-joint distance weights (default ones).
    """
    config = config or RRTConnectConfig()
    start = np.asarray(start, float)
    goal = np.asarray(goal, float)
    w = np.ones_like(start) if weights is None else np.asarray(weights, float)
    if motion_free(start, goal):
        return np.stack([start, goal]), ""
    trees = [_Tree(start), _Tree(goal)]
    step = config.step

    def steer(frm: np.ndarray, to: np.ndarray) -> np.ndarray:
        d = to - frm
        m = float(np.max(np.abs(d) * w))
        if m <= step:
            return to.copy()
        return frm + d * (step / m)

    for it in range(config.max_iterations):
        a, b = trees[it % 2], trees[(it + 1) % 2]
        if rng.random() < config.goal_bias:
            target = b.q[0].copy()
        else:
            target = rng.uniform(lower, upper)
        # Extend a toward the sample.
        ia = a.nearest(target, w)
        qn = steer(a.q[ia], target)
        if not motion_free(a.q[ia], qn):
            continue
        new_a = a.add(qn, ia)
        # Connect b toward the new node.
        ib = b.nearest(qn, w)
        while True:
            qb = steer(b.q[ib], qn)
            if not motion_free(b.q[ib], qb):
                break
            ib = b.add(qb, ib)
            if np.array_equal(qb, qn):
                pa = a.path_to_root(new_a)[::-1]
                pb = b.path_to_root(ib)[1:]
                path = np.array(pa + pb)
                if a is trees[1]:
                    path = path[::-1]
                return path, ""
    return None, "no arm path (iteration limit)"
