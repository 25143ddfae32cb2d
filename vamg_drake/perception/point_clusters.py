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
    within `object_radius` horizontally, above the support, and connected by
    steps of at most `object_link` to the point nearest p_WT. A neighbouring
    object, or the furniture behind the target, is not the target: mirrored, it
    would stand in front of it and block every grasp."""
    p_WS = np.asarray(p_WS, dtype=float).reshape(-1, 3)
    horizontal = np.linalg.norm(p_WS[:, :2] - p_WT[:2], axis=1)
    near = p_WS[horizontal <= config.object_radius]
    if near.shape[0] == 0:
        return near
    support = np.percentile(near[:, 2], 2.0)
    obj = near[near[:, 2] >= support + config.support_clearance]
    obj = obj[component_nearest(obj, p_WT, config.object_link)]
    mirrored = obj.copy()
    mirrored[:, :2] = 2.0 * p_WT[:2] - obj[:, :2]
    return mirrored
