"""A point cloud of a scenario's static geometry: the prior map of ``prior_map: static``.

The paper says the map is unknown at the start; the authors' released runner
nevertheless seeds its collision map with a point cloud of the static
apartment (no YCB objects, no dynamic obstacles). ``static_scene_points``
builds that cloud here: the surfaces of the room's walls, the furniture
primitives and every ReplicaCAD collision piece (and its navmesh walls),
sampled on a regular barycentric grid of ``spacing`` per triangle of each
piece's convex hull, so the same scenario always gives the same cloud.
"""


import math

import numpy as np
from scipy.spatial import ConvexHull, QhullError

from vamg_drake.perception.voxels import first_in_voxel
from vamg_drake.world.primitives import WorldBox
from vamg_drake.world.scenario import Scenario


def _primitive_points(shape) -> np.ndarray:
    """Corner points of a world box, or rim points of a world cylinder."""
    if isinstance(shape, WorldBox):
        signs = np.array([[sx, sy, sz] for sx in (-1, 1) for sy in (-1, 1) for sz in (-1, 1)], float)
        return (signs * shape.half_extents) @ shape.R_WB.T + shape.p_WB
    angles = np.linspace(0.0, 2.0 * math.pi, 24, endpoint=False)
    ring = np.stack([shape.radius * np.cos(angles), shape.radius * np.sin(angles)], axis=1)
    half = 0.5 * shape.length
    local = np.concatenate([np.c_[ring, np.full(24, -half)], np.c_[ring, np.full(24, half)]])
    return local @ shape.R_WC.T + shape.p_WC


def sample_hull_surface(points: np.ndarray, spacing: float) -> np.ndarray:
    """Points (M, 3) on the surface of the convex hull of ``points``, about ``spacing`` apart."""
    points = np.asarray(points, float)
    try:
        hull = ConvexHull(points)
    except (QhullError, ValueError):
        return points.copy()  # flat or degenerate piece: its own points
    samples = [points[hull.vertices]]
    for simplex in hull.simplices:
        a, b, c = points[simplex]
        n = int(math.ceil(max(np.linalg.norm(b - a), np.linalg.norm(c - a), np.linalg.norm(c - b)) / spacing))
        if n < 1:
            continue
        i, j = np.meshgrid(np.arange(n + 1), np.arange(n + 1), indexing="ij")
        keep = (i + j) <= n
        u, v = i[keep] / n, j[keep] / n
        samples.append(a + np.outer(u, b - a) + np.outer(v, c - a))
    return np.concatenate(samples)


def static_scene_points(scenario: Scenario, spacing: float = 0.03, min_height: float = 0.0) -> np.ndarray:
    """The surfaces of the scenario's walls, furniture and ReplicaCAD pieces as (N, 3) points in W.

    Args:
        scenario: the scenario (its objects and dynamic events are left out).
        spacing: sample spacing on each surface [m] (the map's voxel size).
        min_height: points below this height [m] are dropped (the map's ground cut).
    """
    pieces = [_primitive_points(shape) for shape in scenario.room.wall_primitives()]
    for furniture in scenario.furniture:
        pieces.extend(_primitive_points(shape) for shape in furniture.primitives())
    layout = scenario.replicacad_layout()
    if layout is not None:
        pieces.extend(_primitive_points(wall) for wall in layout.walls)
        for body in layout.bodies:
            if not body.floor_covering:
                pieces.extend(body.pieces_W())
    if not pieces:
        return np.zeros((0, 3))
    cloud = np.concatenate([sample_hull_surface(p, spacing) for p in pieces if len(p)])
    cloud = cloud[cloud[:, 2] >= min_height]
    return cloud[np.sort(first_in_voxel(cloud, spacing))]
