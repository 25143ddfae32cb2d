"""The robot's swept spheres along one trajectory, computed once per trajectory.

Both 10 Hz consumers of the executing trajectory need the robot's sphere
centres along it: the gaze optimizer (importance points of the look-ahead
window) and the remaining-trajectory collision check against the map. A
`TrajectorySweep` samples the trajectory on a fixed time grid (`dt`), runs the
sphere forward kinematics once, and indexes the spheres for point queries, so
the per-cycle work is only a slice (gaze) and a point query (check).
"""

from __future__ import annotations

import numpy as np

from vamg_drake.perception.trajectory_check import SweptSphereIndex
from vamg_drake.robot import layout
from vamg_drake.robot.spheres import SphereModel


class TrajectorySweep:
    """Sphere centres of the Fetch along a trajectory on the grid t_k = times[0] + k * dt.

    Args:
        times: (T,) strictly increasing waypoint times [s].
        q: (T, 11) waypoints (continuous joints unwrapped), linearly interpolated.
        dt: grid step [s] (the last grid point is the trajectory's end).
        margin: added to every sphere radius for the collision check [m].
        sphere_model: a `vamg_drake.robot.spheres.SphereModel` (default: the Fetch's).
    """

    def __init__(self, times: np.ndarray, q: np.ndarray, dt: float = 0.05, margin: float = 0.0, sphere_model=None):
        times = np.asarray(times, dtype=float).reshape(-1)
        q = np.asarray(q, dtype=float)
        if q.ndim != 2 or q.shape[1] != layout.NQ or q.shape[0] != times.shape[0] or times.shape[0] < 1:
            raise ValueError(f"TrajectorySweep: need times (T,) and q (T, {layout.NQ}), got {times.shape}, {q.shape}")
        if not (np.all(np.isfinite(times)) and np.all(np.isfinite(q))):
            raise ValueError("TrajectorySweep: times or q contain NaN or inf")
        if np.any(np.diff(times) <= 0.0):
            raise ValueError("TrajectorySweep: times must be strictly increasing")
        if not dt > 0.0:
            raise ValueError(f"TrajectorySweep.dt must be positive, got {dt}")
        if sphere_model is None:
            sphere_model = SphereModel.load()
        self.dt = float(dt)
        self.t0 = float(times[0])
        n = int(np.ceil((times[-1] - times[0]) / dt - 1e-9)) + 1
        self.times = np.minimum(self.t0 + dt * np.arange(n), times[-1])
        self.q = np.column_stack([np.interp(self.times, times, q[:, j]) for j in range(layout.NQ)])
        if times.shape[0] > 1:
            rates = np.diff(q, axis=0) / np.diff(times)[:, None]
            seg = np.clip(np.searchsorted(times, self.times, side="right") - 1, 0, times.shape[0] - 2)
            self.speeds = np.linalg.norm(rates[seg], axis=1)
            self.speeds[self.times >= times[-1]] = 0.0
        else:
            self.speeds = np.zeros(n)
        #: (G, S, 3) sphere centres on the grid, and (S,) radii.
        self.centers = sphere_model.world_spheres(self.q)
        self.radii = np.asarray(sphere_model.radius, dtype=float)
        self.index = SweptSphereIndex(self.centers, self.radii, margin=margin)

    @property
    def num_samples(self) -> int:
        return int(self.times.shape[0])

    def grid_index(self, t: float) -> int:
        """The grid sample at or just before time t (clamped to the grid)."""
        return int(np.clip(np.floor((t - self.t0) / self.dt + 1e-9), 0, self.num_samples - 1))

    def window(self, t_now: float, count: int, stride: int = 1) -> tuple[np.ndarray, np.ndarray]:
        """Look-ahead (centres (n, S, 3), speeds (n,)): every `stride`-th sample from t_now, n <= count."""
        k = self.grid_index(t_now)
        sl = slice(k, k + count * stride, stride)
        return self.centers[sl], self.speeds[sl]

    def first_collision(self, points_W: np.ndarray, t_now: float) -> int:
        """The first grid sample at or after t_now whose spheres contain a map point, or -1."""
        return self.index.first_collision(points_W, self.grid_index(t_now))
