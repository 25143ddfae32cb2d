"""Seeded whole-body planning problems: the planner's tests and benchmark workload.

* `room_problem(seed)`: the procedural rooms of `vamg_drake.world.rooms`
  (walls and furniture of `generate_scenario(seed)`), start at the scenario's
  robot pose, goal a whole-body configuration within reach of the target
  object, far away with furniture in between. The benchmark workload.
* `make_problem(seed)`: a small box room (walls, a table and boxes between
  start and goal), cheap to build; for unit tests.
"""

from __future__ import annotations

import dataclasses

import numpy as np
from scipy import ndimage

from vamg_drake.planning.collision_environment import CollisionEnvironment
from vamg_drake.planning.sphere_collision import SphereCollisionChecker
from vamg_drake.robot import layout
from vamg_drake.world.primitives import WorldBox, rotation_z
from vamg_drake.world.rooms import FloorGrid, generate_scenario
from vamg_drake.world.scenario import ROBOT_FOOTPRINT_RADIUS, static_obstacle_shapes


@dataclasses.dataclass(frozen=True, eq=False)
class PlanningProblem:
    """A room (world primitives), a start and a goal configuration (11,).

    `blocked`: the straight base line from start to goal crosses furniture.
    """

    seed: int
    obstacles: tuple
    q_start: np.ndarray
    q_goal: np.ndarray
    blocked: bool = True


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


def make_problem(seed: int, checker: SphereCollisionChecker, min_distance: float = 3.0,
                 max_tries: int = 2000) -> PlanningProblem:
    """A problem whose start and goal are free for `checker` over its current
    environment (set it to the room's primitives first, see `make_problems`)."""
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


def _segment_cells_free(free: np.ndarray, origin: np.ndarray, resolution: float,
                        a: np.ndarray, b: np.ndarray) -> bool:
    """True when every grid cell on the straight segment a->b (xy) is free."""
    n = max(int(np.ceil(np.hypot(*(b - a)) / (0.5 * resolution))), 1) + 1
    pts = a + np.linspace(0.0, 1.0, n)[:, None] * (b - a)
    ij = np.round((pts - origin) / resolution).astype(int)
    ij = np.clip(ij, 0, np.array(free.shape) - 1)
    return bool(np.all(free[ij[:, 0], ij[:, 1]]))


def room_problem(seed: int, checker: SphereCollisionChecker, min_distance: float = 2.5,
                 reach_radius: float = 0.8, max_tries: int = 4000) -> PlanningProblem:
    """A whole-body problem in the procedural room `generate_scenario(seed)`.

    Obstacles: the room's walls and furniture (`static_obstacle_shapes`; the
    YCB objects are left out, they have no primitive geometry). Start: the
    scenario's robot base pose with a random collision-free torso/arm
    configuration. Goal: a base pose within `reach_radius` of the target
    object, facing it (+-0.6 rad), at least `min_distance` from the start and
    in the same connected free region of the floor (base footprint
    `ROBOT_FOOTPRINT_RADIUS` on a 5 cm grid), with a random collision-free
    torso/arm configuration. Goals whose straight line from the start is
    blocked by furniture (for the base footprint) are preferred; such a goal
    is found for most seeds (`PlanningProblem.blocked` says).
    """
    scenario = generate_scenario(seed)
    obstacles = [s for s in static_obstacle_shapes(scenario) if s.z_range()[1] > 0.01]
    rng = np.random.default_rng([seed, 7919])
    cc = checker.with_environment(CollisionEnvironment.from_primitives(obstacles))
    grid = FloorGrid(scenario.room, 0.05)
    occupied = np.zeros_like(grid.inside)
    for shape in obstacles:
        occupied |= grid.cells_in_polygon(shape.footprint())
    free = grid.base_free(ROBOT_FOOTPRINT_RADIUS, occupied)
    labels, _ = ndimage.label(free, structure=np.ones((3, 3)))
    s = scenario.robot_start
    start_xy = np.array([s.x, s.y])
    label = labels[grid.index(start_xy)]
    if label == 0:
        raise RuntimeError(f"room problem seed {seed}: the scenario's start is not on a free floor cell")
    target = next(o for o in scenario.objects if o.name == scenario.target)
    target_xy = np.asarray(target.xyz[:2], float)
    d_target = np.linalg.norm(grid.centers - target_xy, axis=-1)
    d_start = np.linalg.norm(grid.centers - start_xy, axis=-1)
    cand = np.argwhere((labels == label) & (d_target <= reach_radius) & (d_start >= min_distance))
    if cand.shape[0] == 0:
        raise RuntimeError(f"room problem seed {seed}: no free base cell within {reach_radius} m of the target "
                           f"and {min_distance} m from the start")

    def random_arm(q: np.ndarray) -> np.ndarray:
        q = q.copy()
        q[3:] = rng.uniform(layout.SAMPLE_LOWER[3:], layout.SAMPLE_UPPER[3:])
        return q

    q_start = None
    for _ in range(max_tries):
        q = random_arm(np.array([s.x, s.y, s.yaw] + [0.0] * (layout.NQ - 3)))
        if cc.is_free(q[None])[0]:
            q_start = q
            break
    if q_start is None:
        raise RuntimeError(f"room problem seed {seed}: no free start arm configuration in {max_tries} tries")
    q_goal, fallback = None, None
    half_cell = 0.5 * grid.resolution
    for _ in range(max_tries):
        i, j = cand[rng.integers(cand.shape[0])]
        xy = grid.centers[i, j] + rng.uniform(-half_cell, half_cell, 2)
        yaw = float(np.arctan2(*(target_xy - xy)[::-1]) + rng.uniform(-0.6, 0.6))
        q = random_arm(np.concatenate([xy, [layout.wrap_angle(yaw)], np.zeros(layout.NQ - 3)]))
        if not cc.is_free(q[None])[0]:
            continue
        if not _segment_cells_free(free, grid.origin, grid.resolution, start_xy, xy):
            q_goal = q
            break
        if fallback is None:
            fallback = q
    blocked = q_goal is not None
    q_goal = q_goal if blocked else fallback
    if q_goal is None:
        raise RuntimeError(f"room problem seed {seed}: no free goal configuration in {max_tries} tries")
    return PlanningProblem(seed, tuple(obstacles), q_start, q_goal, blocked)
