"""Seeded whole-body planning problems in furnished box rooms.

A fixed, reproducible workload for the planner's tests and benchmark: a
walled room, a table (and a few boxes) between the start and the goal, the
start with the arm stowed on one side, the goal a random collision-free
whole-body configuration on the other side (the base at least
`min_distance` away).
"""

from __future__ import annotations

import dataclasses

import numpy as np

from vamg_drake.planning.collision import CollisionChecker
from vamg_drake.robot import layout
from vamg_drake.world.primitives import WorldBox, rotation_z


@dataclasses.dataclass(frozen=True, eq=False)
class PlanningProblem:
    """A room (world boxes), a start and a goal configuration (11,)."""

    seed: int
    obstacles: tuple
    q_start: np.ndarray
    q_goal: np.ndarray


def _box(name, center, size, yaw=0.0) -> WorldBox:
    return WorldBox(name, np.asarray(center, float), rotation_z(yaw), 0.5 * np.asarray(size, float))


def furnished_room(rng: np.random.Generator, width: float = 6.0, depth: float = 5.0) -> list[WorldBox]:
    """Walls around [0, width] x [0, depth], a table in the middle, 2-3 boxes."""
    t, h = 0.1, 1.0
    boxes = [
        _box("wall/0", [width / 2, -t / 2, h / 2], [width + 2 * t, t, h]),
        _box("wall/1", [width / 2, depth + t / 2, h / 2], [width + 2 * t, t, h]),
        _box("wall/2", [-t / 2, depth / 2, h / 2], [t, depth, h]),
        _box("wall/3", [width + t / 2, depth / 2, h / 2], [t, depth, h]),
    ]
    cx = width / 2 + rng.uniform(-0.3, 0.3)
    cy = depth / 2 + rng.uniform(-0.8, 0.8)
    tw, td = rng.uniform(0.6, 1.0), rng.uniform(1.2, 2.2)
    boxes.append(_box("table/top", [cx, cy, 0.72], [tw, td, 0.04], rng.uniform(-0.3, 0.3)))
    boxes.append(_box("table/base", [cx, cy, 0.35], [0.5 * tw, 0.5 * td, 0.7], 0.0))
    for k in range(int(rng.integers(2, 4))):
        size = [rng.uniform(0.3, 0.6), rng.uniform(0.3, 0.6), rng.uniform(0.3, 1.2)]
        c = [rng.uniform(1.8, width - 1.8), rng.choice([rng.uniform(0.3, 1.0), rng.uniform(depth - 1.0, depth - 0.3)]),
             size[2] / 2]
        boxes.append(_box(f"box_{k}/body", c, size, rng.uniform(-np.pi, np.pi)))
    return boxes


def make_problem(seed: int, checker: CollisionChecker, min_distance: float = 3.0,
                 max_tries: int = 2000) -> PlanningProblem:
    """A problem whose start and goal are free for `checker` over its current
    environment (set it to the room's primitives first, see `make_problems`)."""
    from vamg_drake.planning.collision import CollisionEnvironment

    rng = np.random.default_rng(seed)
    width, depth = 6.0, 5.0
    obstacles = furnished_room(rng, width, depth)
    cc = checker.with_environment(CollisionEnvironment.from_primitives(obstacles))
    q_start = None
    for _ in range(max_tries):
        q = rng.uniform(layout.SAMPLE_LOWER, layout.SAMPLE_UPPER)
        q[0] = rng.uniform(0.5, 1.3)
        q[1] = rng.uniform(0.5, depth - 0.5)
        if cc.is_free(q[None])[0]:
            q_start = q
            break
    q_goal = None
    for _ in range(max_tries):
        q = rng.uniform(layout.SAMPLE_LOWER, layout.SAMPLE_UPPER)
        q[0] = rng.uniform(width - 1.3, width - 0.5)
        q[1] = rng.uniform(0.5, depth - 0.5)
        if np.hypot(*(q[:2] - q_start[:2])) < min_distance:
            continue
        if cc.is_free(q[None])[0]:
            q_goal = q
            break
    if q_start is None or q_goal is None:
        raise RuntimeError(f"problem seed {seed}: no free start/goal found in {max_tries} tries")
    return PlanningProblem(seed, tuple(obstacles), q_start, q_goal)
