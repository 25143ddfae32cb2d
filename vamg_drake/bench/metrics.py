"""Benchmark metrics: Wilson intervals, SPL and its shortest-path baseline.

SPL follows the appendix ("Path Efficiency Analysis"):
``SPL = 1/N sum_i S_i l_i / max(p_i, l_i)``, with l_i the shortest
collision-free base path on a 2D occupancy grid: every scene part whose
vertical extent meets [0.06, 1.5] m is projected onto the floor at 0.05 m,
obstacles (and walls: cells outside the room outline) are inflated by the base
radius 0.29 m, and the shortest 8-connected path runs from the start cell to
the reachable cell nearest the target. The grid is the generator's
``FloorGrid`` (one place for the grid); the search is Dijkstra with unit and
sqrt(2) steps, i.e. BFS with metric diagonal steps, giving metres.
"""

import math
from dataclasses import dataclass, field

import numpy as np
from scipy import ndimage

from vamg_drake.world.rooms import FloorGrid, shortest_grid_path
from vamg_drake.world.scenario import Scenario, static_obstacle_shapes

#: 95 % two-sided normal quantile.
Z_95 = 1.959963984540054


def wilson_interval(successes: int, n: int, z: float = Z_95) -> tuple[float, float]:
    """Wilson score interval of a binomial proportion.

    Args:
        successes: number of successes (0..n).
        n: number of trials.
        z: normal quantile (default: 95 %).

    Returns:
        (low, high) in [0, 1]; (0, 1) when n == 0.
    """
    if n < 0 or not 0 <= successes <= n:
        raise ValueError(f"wilson_interval: need 0 <= successes <= n, got successes={successes}, n={n}")
    if n == 0:
        return 0.0, 1.0
    p = successes / n
    z2 = z * z
    centre = (p + z2 / (2 * n)) / (1 + z2 / n)
    half = z / (1 + z2 / n) * math.sqrt(p * (1 - p) / n + z2 / (4 * n * n))
    return max(0.0, centre - half), min(1.0, centre + half)


def spl(success: np.ndarray, shortest: np.ndarray, taken: np.ndarray) -> float:
    """Success weighted by path length, ``1/N sum S_i l_i / max(p_i, l_i)``.

    Args:
        success: (N,) booleans S_i.
        shortest: (N,) l_i [m]; an episode with l_i = 0 (start at the goal) counts S_i.
        taken: (N,) p_i [m].

    Raises:
        ValueError: mismatched lengths, negative or non-finite lengths.
    """
    success = np.asarray(success, dtype=bool)
    shortest = np.asarray(shortest, dtype=float)
    taken = np.asarray(taken, dtype=float)
    if not (success.shape == shortest.shape == taken.shape) or success.ndim != 1:
        raise ValueError(f"spl: success, shortest and taken must be equal-length vectors, got {success.shape}, {shortest.shape}, {taken.shape}")
    if len(success) == 0:
        return float("nan")
    if np.any(~np.isfinite(shortest)) or np.any(shortest < 0) or np.any(~np.isfinite(taken)) or np.any(taken < 0):
        raise ValueError("spl: path lengths must be finite and >= 0")
    denom = np.maximum(taken, shortest)
    ratio = np.where(denom > 0, shortest / np.where(denom > 0, denom, 1.0), 1.0)
    return float(np.mean(success * ratio))


@dataclass
class ShortestPathConfig:
    """The appendix's SPL grid.

    Attributes:
        resolution: grid cell [m].
        height_range: parts meeting this z range are obstacles [m].
        robot_radius: base radius used to inflate obstacles [m].
    """

    resolution: float = 0.05
    height_range: list[float] = field(default_factory=lambda: [0.06, 1.5])
    robot_radius: float = 0.29


def shortest_base_path(scenario: Scenario, config: ShortestPathConfig | None = None) -> float | None:
    """l_i: shortest collision-free base path from the start to the target [m].

    Returns:
        The path length, or None when the start cell is blocked.
    """
    config = config or ShortestPathConfig()
    grid = FloorGrid(scenario.room, config.resolution)
    occupied = np.zeros_like(grid.inside)
    lo, hi = config.height_range
    for shape in static_obstacle_shapes(scenario):
        z0, z1 = shape.z_range()
        if z1 >= lo and z0 <= hi:
            occupied |= grid.cells_in_polygon(shape.footprint())
    clearance = grid.clearance(occupied)
    # Inflation by the base radius; the start cell itself is always admitted
    # (a start touching the inflated border is valid in the scenario).
    free = clearance >= config.robot_radius
    start = grid.index([scenario.robot_start.x, scenario.robot_start.y])
    if not (0 <= start[0] < free.shape[0] and 0 <= start[1] < free.shape[1]) or not grid.inside[start]:
        return None
    free[start] = True
    labels, _ = ndimage.label(free, structure=np.ones((3, 3)))
    reachable = labels == labels[start]
    target_xy = scenario.target_point()[:2]
    d = np.linalg.norm(grid.centers - target_xy, axis=-1)
    d[~reachable] = np.inf
    goal = np.zeros_like(free)
    goal[np.unravel_index(int(np.argmin(d)), d.shape)] = True
    path = shortest_grid_path(grid, free, start, goal)
    if path is None:
        return None
    return float(np.sum(np.linalg.norm(np.diff(path, axis=0), axis=1)))
