"""Connected clusters of points: an object's own points among its neighbours',
and the completion of an object's unseen side by mirroring its seen points."""

import dataclasses as dc

import numpy as np
from scipy.spatial import cKDTree


def connected_component(points: np.ndarray, seed: int, link: float) -> np.ndarray:
    """(N,) bool: the points linked to `points[seed]` by steps of at most `link` [m]
    (breadth-first over a k-d tree; the seed included)."""
    points = np.asarray(points, dtype=float).reshape(-1, 3)
    member = np.zeros(points.shape[0], dtype=bool)
    if points.shape[0] == 0:
        return member
    tree = cKDTree(points)
    member[seed] = True
    frontier = np.array([seed])
    while frontier.size:
        linked = np.unique(np.concatenate([np.asarray(n, dtype=np.int64) for n in tree.query_ball_point(points[frontier], link)]))
        linked = linked[~member[linked]]
        member[linked] = True
        frontier = linked
    return member


def component_nearest(points: np.ndarray, p: np.ndarray, link: float) -> np.ndarray:
    """(N,) bool: the connected component (`connected_component`) of the point nearest p."""
    points = np.asarray(points, dtype=float).reshape(-1, 3)
    if points.shape[0] == 0:
        return np.zeros(0, dtype=bool)
    seed = int(np.argmin(np.linalg.norm(points - np.asarray(p, dtype=float).reshape(3), axis=1)))
    return connected_component(points, seed, link)


def support_height(points: np.ndarray, p_WT: np.ndarray, radius: float, bin_size: float = 0.01,
                   clearance: float = 0.005) -> float:
    """The top [m] of the surface a target at p_WT stands on, plus `clearance`
    for sensor noise: the median height of the most populated `bin_size`
    height bin of the points within `radius` horizontally and up to `radius`
    below the target (a table top is a plane of many points; the object's own
    points spread over its height). -inf when that bin's points do not spread
    out under the target like a surface (std < 0.3 `radius` along x or y) or
    there are none. (The median, not the bin's upper edge plus a margin: that
    can lie up to 2 cm over the table, above the middle of a 2 cm Lego brick.)
    """
    p = np.asarray(points, dtype=float).reshape(-1, 3)
    near = p[(np.linalg.norm(p[:, :2] - p_WT[:2], axis=1) <= radius) & (p[:, 2] <= p_WT[2])
             & (p[:, 2] >= p_WT[2] - radius)]
    if near.shape[0] == 0:
        return -np.inf
    bins = np.floor(near[:, 2] / bin_size).astype(np.int64)
    values, counts = np.unique(bins, return_counts=True)
    top = values[counts == counts.max()].max()
    plane = near[bins == top]
    if np.min(np.std(plane[:, :2], axis=0)) < 0.3 * radius:
        return -np.inf  # no plane spreads under the target: only the object's own points
    return float(np.median(plane[:, 2]) + clearance)


@dc.dataclass
class MirrorCompletionConfig:
    """Completion of the target's unseen side by symmetry.

    Attributes:
        enabled: complete the target by mirroring it about its vertical axis.
        object_radius: horizontal radius around the target holding the object [m].
        support_clearance: object points lie this far above the support surface [m].
        object_link: the object's points are linked to its point nearest the
            target by steps of at most this [m] (what is mirrored).
    """

    enabled: bool = True
    object_radius: float = 0.12
    support_clearance: float = 0.008
    object_link: float = 0.015


def mirrored_object_points(p_WS: np.ndarray, p_WT: np.ndarray, config: MirrorCompletionConfig) -> np.ndarray:
    """The object's points mirrored about the vertical axis through p_WT: those
    within `object_radius` horizontally, above the support plane, and connected by
    steps of at most `object_link` to the point nearest p_WT. A neighbouring
    object, or the furniture behind the target, is not the target: mirrored, it
    would stand in front of it and block every grasp."""
    p_WS = np.asarray(p_WS, dtype=float).reshape(-1, 3)
    horizontal = np.linalg.norm(p_WS[:, :2] - p_WT[:2], axis=1)
    near = p_WS[horizontal <= config.object_radius]
    if near.shape[0] == 0:
        return near
    # The support is the plane under the target (`support_height`), not the
    # lowest points: near a table's edge those are its front face, and from
    # there the table top would join the target to every object on it.
    floor = support_height(near, p_WT, config.object_radius, clearance=config.support_clearance)
    if not np.isfinite(floor):  # no plane spreads under the target (a narrow support)
        floor = np.percentile(near[:, 2], 2.0) + config.support_clearance
    obj = near[near[:, 2] >= floor]
    obj = obj[component_nearest(obj, p_WT, config.object_link)]
    mirrored = obj.copy()
    mirrored[:, :2] = 2.0 * p_WT[:2] - obj[:, :2]
    return mirrored
