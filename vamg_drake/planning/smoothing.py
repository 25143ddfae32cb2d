"""Path refinement: randomized shortcutting, B-spline smoothing, and time
parametrization within the robot's rate limits.

These work on plain arrays with a caller-given validity function, so the
whole-body planner can apply them to the parts of a path where straight-line
interpolation is admissible (fixed-base arm motions); base motions keep their
Reeds-Shepp geometry (the base cannot move sideways).
"""

from __future__ import annotations

from typing import Callable

import numpy as np
from scipy import interpolate

from vamg_drake.planning.trajectory import TimedTrajectory
from vamg_drake.robot import layout


def path_length(path: np.ndarray, weights: np.ndarray | None = None) -> float:
    d = np.diff(path, axis=0)
    if weights is not None:
        d = d * weights
    return float(np.sum(np.linalg.norm(d, axis=1)))


def shortcut(
    path: np.ndarray,
    motion_free: Callable[[np.ndarray, np.ndarray], bool],
    rng: np.random.Generator,
    iterations: int = 30,
) -> np.ndarray:
    """Randomized shortcutting: replace a sub-path by a straight segment when free.

    Picks two random points on the path (anywhere along segments, not just at
    waypoints), and keeps the straight connection when it is valid.
    """
    path = np.asarray(path, float)
    for _ in range(iterations):
        n = path.shape[0]
        if n < 3:
            break
        seg_len = np.linalg.norm(np.diff(path, axis=0), axis=1)
        cum = np.concatenate([[0.0], np.cumsum(seg_len)])
        if cum[-1] <= 1e-12:
            break
        s0, s1 = np.sort(rng.uniform(0.0, cum[-1], 2))
        i = int(np.clip(np.searchsorted(cum, s0, side="right") - 1, 0, n - 2))
        j = int(np.clip(np.searchsorted(cum, s1, side="right") - 1, 0, n - 2))
        if j <= i:
            continue
        a = path[i] + (s0 - cum[i]) / max(seg_len[i], 1e-12) * (path[i + 1] - path[i])
        b = path[j] + (s1 - cum[j]) / max(seg_len[j], 1e-12) * (path[j + 1] - path[j])
        if not motion_free(a, b):
            continue
        path = np.concatenate([path[: i + 1], a[None], b[None], path[j + 1:]])
    # drop exact duplicates
    keep = np.concatenate([[True], np.any(np.abs(np.diff(path, axis=0)) > 1e-12, axis=1)])
    return path[keep]


def bspline_smooth(path: np.ndarray, samples: int = 30, degree: int = 3) -> np.ndarray:
    """A cubic B-spline through the path's waypoints (interpolating, so the ends
    and every waypoint are kept), sampled at `samples` points by chord length.

    Returns the input when it has too few points to fit.
    """
    path = np.asarray(path, float)
    n = path.shape[0]
    if n < 3:
        return path.copy()
    k = min(degree, n - 1)
    d = np.linalg.norm(np.diff(path, axis=0), axis=1)
    u = np.concatenate([[0.0], np.cumsum(d)])
    if u[-1] <= 1e-12:
        return path[[0, -1]].copy()
    u /= u[-1]
    keep = np.concatenate([[True], np.diff(u) > 1e-9])
    u, P = u[keep], path[keep]
    if P.shape[0] <= k:
        return path.copy()
    spline = interpolate.make_interp_spline(u, P, k=k)
    uu = np.linspace(0.0, 1.0, max(samples, 2))
    out = spline(uu)
    out[0], out[-1] = path[0], path[-1]
    return out


def smooth_if_free(
    path: np.ndarray,
    path_free: Callable[[np.ndarray], bool],
    samples: int = 30,
) -> np.ndarray:
    """B-spline smoothing, kept only when the smoothed path is valid and in limits."""
    smooth = bspline_smooth(path, samples)
    if smooth.shape[0] == path.shape[0] and np.allclose(smooth, path):
        return path
    if path.shape[1] == layout.NQ and not np.all(layout.within_limits(smooth)):
        return path
    return smooth if path_free(smooth) else path


def time_parametrize(path: np.ndarray, v_max: np.ndarray = layout.V_MAX,
                     min_segment_time: float = 1e-3) -> TimedTrajectory:
    """Times for whole-body waypoints (N, 11): each segment takes the longest
    time any joint needs at its rate limit (base x, y share the planar speed).

    The result moves every coordinate at or below its limit (rate ratio <= 1).
    """
    path = np.asarray(path, float)
    if path.shape[0] == 1:
        return TimedTrajectory(times=np.zeros(1), q=path)
    d = np.abs(np.diff(path, axis=0))
    t = d / v_max[None, :]
    t[:, 0] = np.hypot(d[:, 0], d[:, 1]) / v_max[0]
    t[:, 1] = 0.0
    dt = np.maximum(t.max(axis=1), min_segment_time)
    return TimedTrajectory(times=np.concatenate([[0.0], np.cumsum(dt)]), q=path)
