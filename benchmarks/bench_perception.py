"""Speed of the perception cycle: map update, gaze choice, remaining-trajectory check.

Workload (seeded): a 10 m x 10 m room with walls and random furniture boxes,
rendered at 320x240 by VTK from the Fetch's head camera while the robot drives
through it with a sweeping head. The map is pre-filled with the room's surfaces
sampled at the voxel size (>= 100k points) and then updated frame by frame.
Per frame we time (rendering excluded):

* map_update: `PointMap.update` (back-projection, ground and self filter with
  the sphere model at q, carving, voxel merge);
* gaze: `decide_fetch_gaze` on the trajectory's `TrajectorySweep` (candidate
  camera poses, look-ahead window, weights, frustum scores);
* traj_check: `TrajectorySweep.first_collision` of the whole map against the
  remaining trajectory (0.05 s grid).
The sweeps (sphere FK + index, once per new trajectory) are timed separately
as sweep_setup_ms.

Each has a straightforward reference in the same run (NumPy map with a Python
set of voxel keys; per-cycle FK + NumPy frustum scores; per-cycle FK + SciPy
k-d tree check), and the reference map must end with the same points as the
fast one. A second part
measures the ground-height trade-off (floor leaking into the map vs low
obstacles lost) with and without a Kinect-like depth noise model.

Usage: python benchmarks/bench_perception.py [--json] [--frames N]
"""

from __future__ import annotations

import argparse
import json
import time

import numpy as np
from pydrake.geometry import Box, Cylinder
from pydrake.math import RigidTransform

from vamg_drake.perception.depth_points import DepthToPointsConfig, depth_to_points_reference
from vamg_drake.perception.gaze import (
    FetchGazeCameras,
    GazeConfig,
    GazeOptimizer,
    decide_fetch_gaze,
    frustum_scores_reference,
)
from vamg_drake.perception.raycast_map import PointMap, RayCastMapConfig
from vamg_drake.perception.shape_depth_render import ShapeDepthRenderer, look_at
from vamg_drake.perception.trajectory_check import first_colliding_waypoint_reference
from vamg_drake.perception.trajectory_sweep import TrajectorySweep
from vamg_drake.robot import layout
from vamg_drake.robot.head_camera import CameraIntrinsics, HeadCameraConfig
from vamg_drake.robot.kinematics import FetchKinematics
from vamg_drake.robot.spheres import SphereModel

K = CameraIntrinsics.from_config(HeadCameraConfig())


# ---- workload --------------------------------------------------------------------
def make_room(rng: np.random.Generator):
    """Boxes (center (3,), size (3,)) of a room: floor, 4 walls, furniture off the corridor y in [-0.8, 0.8]."""
    boxes = [((0, 0, -0.05), (10, 10, 0.1))]
    for sx, sy in ((1, 0), (-1, 0), (0, 1), (0, -1)):
        boxes.append(((5.0 * sx, 5.0 * sy, 1.25), (0.1 if sx else 10, 0.1 if sy else 10, 2.5)))
    while len(boxes) < 5 + 30:
        size = rng.uniform([0.3, 0.3, 0.3], [1.2, 1.2, 1.8])
        c = rng.uniform([-4.5, -4.5], [4.5, 4.5])
        if abs(c[1]) - size[1] / 2 < 0.8:
            continue
        boxes.append(((c[0], c[1], size[2] / 2), tuple(size)))
    return [(np.asarray(c, float), np.asarray(s, float)) for c, s in boxes]


def sample_box_surfaces(boxes, spacing: float) -> np.ndarray:
    """Points on the faces of the boxes (not the floor's), `spacing` apart."""
    out = []
    for c, s in boxes[1:]:
        for axis in range(3):
            others = [a for a in range(3) if a != axis]
            g = [np.arange(-s[a] / 2, s[a] / 2 + 1e-9, spacing) for a in others]
            uu, vv = np.meshgrid(*g, indexing="ij")
            for sign in (-1, 1):
                p = np.zeros((uu.size, 3))
                p[:, others[0]], p[:, others[1]] = uu.ravel(), vv.ravel()
                p[:, axis] = sign * s[axis] / 2
                out.append(p + c)
    return np.vstack(out)


def robot_path(n: int) -> tuple[np.ndarray, np.ndarray]:
    """(times, q) of the Fetch driving along y = 0 from x = -4 to x = 4 at 0.5 m/s."""
    x = np.linspace(-4.0, 4.0, n)
    q = np.array([layout.stow_configuration(xi, 0.0, 0.0) for xi in x])
    return np.linspace(0.0, 16.0, n), q


# ---- straightforward references ---------------------------------------------------
class ReferencePointMap:
    """The ray-cast map written plainly: NumPy arrays and a Python set of voxel keys."""

    def __init__(self, config: RayCastMapConfig):
        self.config = config
        self.points = np.empty((0, 3))
        self.keys: set[tuple[int, int, int]] = set()

    def _key_rows(self, p):
        return [tuple(k) for k in np.floor(p * (1.0 / self.config.voxel_size)).astype(np.int64).tolist()]

    def add_points(self, p):
        new = []
        for row, key in zip(p, self._key_rows(p)):
            if key not in self.keys:
                self.keys.add(key)
                new.append(row)
        if new:
            self.points = np.vstack([self.points, new])

    def update(self, depth, X_WC, centers, radii):
        c = self.config
        new = depth_to_points_reference(depth, K, X_WC, c.depth)
        new = new[new[:, 2] >= c.ground_height]
        d2 = ((new[:, None, :] - centers[None]) ** 2).sum(-1)
        new = new[~np.any(d2 <= (radii + c.self_filter_margin) ** 2, axis=1)]
        if len(self.points):
            z = depth.astype(float).copy()
            z[~(z > 0)] = 0.0
            r = c.carve_footprint_px
            pad = np.pad(z, r, constant_values=np.inf)
            z = np.min([pad[i : i + K.height, j : j + K.width] for i in range(2 * r + 1) for j in range(2 * r + 1)], 0)
            X_CW = np.linalg.inv(X_WC)
            p_C = self.points @ X_CW[:3, :3].T + X_CW[:3, 3]
            with np.errstate(divide="ignore", invalid="ignore"):
                u = np.floor(K.fx * p_C[:, 0] / p_C[:, 2] + K.cx + 0.5)
                v = np.floor(K.fy * p_C[:, 1] / p_C[:, 2] + K.cy + 0.5)
            inside = (p_C[:, 2] >= c.depth.depth_min) & (p_C[:, 2] <= c.depth.depth_max)
            inside &= (u >= 0) & (u < K.width) & (v >= 0) & (v < K.height)
            carve = np.zeros(len(self.points), dtype=bool)
            idx = np.flatnonzero(inside)
            carve[idx] = p_C[idx, 2] < z[v[idx].astype(int), u[idx].astype(int)] - c.carve_tolerance
            if carve.any():
                self.points = self.points[~carve]
                self.keys = set(self._key_rows(self.points))
        self.add_points(new)


# ---- timing ------------------------------------------------------------------------
def run_cycle(frames: int, seed: int) -> dict:
    rng = np.random.default_rng(seed)
    boxes = make_room(rng)
    renderer = ShapeDepthRenderer(K, [(Box(*s), RigidTransform(c)) for c, s in boxes])
    kin, spheres = FetchKinematics.instance(), SphereModel.load()
    times, path = robot_path(161)
    config = RayCastMapConfig()
    fast, ref = PointMap(K, config), ReferencePointMap(config)
    # Obstacles that have left since they were mapped (in the prior, not rendered): carving removes them.
    ghosts = [(np.array([x, y, 0.5]), np.array([0.4, 0.4, 1.0])) for x in (-2.5, -0.5, 1.5) for y in (-1.1, 1.1)]
    prior = sample_box_surfaces([boxes[0], *boxes[1:], *ghosts], config.voxel_size)
    fast.add_points(prior)
    ref.add_points(prior)
    n_prefill = fast.num_points
    gaze = GazeOptimizer(K, GazeConfig())
    cameras = FetchGazeCameras(gaze.candidates)
    t_setup = time.perf_counter()
    gaze_sweep = TrajectorySweep(times, path, dt=gaze.config.waypoint_dt)
    check_sweep = TrajectorySweep(times, path, dt=0.05)
    t_setup = time.perf_counter() - t_setup
    TrajectorySweep(times, path, dt=0.05)  # JIT warm
    t_setup = time.perf_counter()
    gaze_sweep = TrajectorySweep(times, path, dt=gaze.config.waypoint_dt)
    check_sweep = TrajectorySweep(times, path, dt=0.05)
    t_setup = time.perf_counter() - t_setup
    target = np.array([4.5, 0.0, 0.8])
    steps = np.linspace(0, len(times) - 30, frames).astype(int)
    pans = 1.2 * np.sin(np.linspace(0, 4 * np.pi, frames))
    data = []
    for k, (i, pan) in enumerate(zip(steps, pans)):
        X_WC = kin.camera_pose(path[i], pan, 0.5)
        data.append((i, X_WC, renderer.render(X_WC)))
    n_ghost = sum(int(np.all(np.abs(fast.points - c) <= s / 2 + 0.02, axis=1).sum()) for c, s in ghosts)
    t_map, t_map_ref, t_gaze, t_gaze_ref, t_check, t_check_ref = ([] for _ in range(6))
    collisions = []
    for k, (i, X_WC, depth) in enumerate(data):
        q = path[i]
        t0 = time.perf_counter()
        fast.update(depth, X_WC, spheres.world_spheres(q), spheres.radius)
        t1 = time.perf_counter()
        ref.update(depth, X_WC, spheres.world_spheres(q), spheres.radius)
        t2 = time.perf_counter()
        decide_fetch_gaze(gaze, q, target, gaze_sweep, times[i], cameras)
        t3 = time.perf_counter()
        hit = check_sweep.first_collision(fast.points, times[i])
        t4 = time.perf_counter()
        k0 = check_sweep.grid_index(times[i])
        hit_ref = first_colliding_waypoint_reference(
            ref.points, spheres.world_spheres(check_sweep.q[k0:]), spheres.radius
        )
        hit_ref = hit_ref if hit_ref < 0 else hit_ref + k0
        t5 = time.perf_counter()
        # Gaze reference: the same decision with NumPy frustum scores.
        X_cand = kin.camera_poses_for_gazes(q, gaze.candidates)
        q_win, speed = gaze.lookahead_window(times, path, times[i])
        field = gaze.trajectory_importance(spheres.world_spheres(q_win), speed)
        frustum_scores_reference(field.points, field.weights, X_cand, K, 0.2, 3.0).argmax()
        t6 = time.perf_counter()
        if k == 0:
            continue  # JIT warm-up
        t_map.append(t1 - t0)
        t_map_ref.append(t2 - t1)
        t_gaze.append(t3 - t2)
        t_gaze_ref.append(t6 - t5)
        t_check.append(t4 - t3)
        t_check_ref.append(t5 - t4)
        collisions.append((hit, hit_ref))
    same_map = fast.num_points == len(ref.points) and set(map(tuple, fast.occupied_voxels().tolist())) == ref.keys
    n_ghost_left = sum(int(np.all(np.abs(fast.points - c) <= s / 2 + 0.02, axis=1).sum()) for c, s in ghosts)
    ms = lambda v: round(1e3 * float(np.median(v)), 3)  # noqa: E731
    cycle = np.add(np.add(t_map, t_gaze), t_check)
    cycle_ref = np.add(np.add(t_map_ref, t_gaze_ref), t_check_ref)
    return {
        "frames": frames - 1,
        "image": f"{K.width}x{K.height}",
        "map_points_prefill": n_prefill,
        "map_points_final": fast.num_points,
        "departed_obstacle_points_before_after": [n_ghost, n_ghost_left],
        "map_update_ms_median": ms(t_map),
        "gaze_ms_median": ms(t_gaze),
        "traj_check_ms_median": ms(t_check),
        "cycle_ms_median": ms(cycle),
        "sweep_setup_ms": round(1e3 * t_setup, 3),
        "ref_map_update_ms_median": ms(t_map_ref),
        "ref_gaze_ms_median": ms(t_gaze_ref),
        "ref_traj_check_ms_median": ms(t_check_ref),
        "ref_cycle_ms_median": ms(cycle_ref),
        "speedup_map_update": round(float(np.median(t_map_ref) / np.median(t_map)), 1),
        "speedup_traj_check": round(float(np.median(t_check_ref) / np.median(t_check)), 1),
        "speedup_cycle": round(float(np.median(cycle_ref) / np.median(cycle)), 1),
        "reference_map_identical": bool(same_map),
        "traj_check_agrees": all(a == b for a, b in collisions),
    }


# ---- ground height trade-off --------------------------------------------------------
def kinect_noise(depth: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """Axial depth noise sigma(z) = 1.2 mm + 1.9 mm * (z - 0.4 m)^2 (Nguyen et al. 2012, Kinect)."""
    z = depth.astype(float)
    ok = np.isfinite(z) & (z > 0)
    z[ok] += rng.normal(size=ok.sum()) * (0.0012 + 0.0019 * (z[ok] - 0.4) ** 2)
    return z.astype(np.float32)


def ground_tradeoff(seed: int, thresholds=(0.02, 0.05, 0.1, 0.2, 0.3)) -> dict:
    """Floor points leaking into the map vs low obstacles kept, per ground height."""
    rng = np.random.default_rng(seed)
    low = [  # (kind, center, size): boxes h 5-25 cm and chair legs (r 2 cm, h 45 cm, seen above 0.3 m only in part)
        ("box", (1.4, -0.6, 0.025), (0.3, 0.3, 0.05)),
        ("box", (1.8, 0.0, 0.05), (0.25, 0.25, 0.10)),
        ("box", (2.2, 0.6, 0.1), (0.3, 0.2, 0.20)),
        ("box", (1.6, 0.5, 0.125), (0.4, 0.3, 0.25)),
        ("leg", (2.0, -0.5, 0.225), (0.02, 0.45)),
        ("leg", (2.4, -0.1, 0.225), (0.02, 0.45)),
    ]
    shapes = [(Box(20, 20, 0.1), RigidTransform([0, 0, -0.05]))]
    for kind, c, s in low:
        shapes.append((Box(*s) if kind == "box" else Cylinder(*s), RigidTransform(c)))
    renderer = ShapeDepthRenderer(K, shapes)
    views = [look_at([0.0, y, 1.1], [2.0, y * 0.5, 0.0]) for y in (-0.3, 0.0, 0.3)]
    depths = [renderer.render(X) for X in views]
    result = {}
    for noisy in (False, True):
        imgs = [kinect_noise(d, rng) if noisy else d for d in depths]
        for h in thresholds:
            m = PointMap(K, RayCastMapConfig(ground_height=h))
            for X, d in zip(views, imgs):
                m.update(d, X)
            p = m.points
            on_obstacle = np.zeros(len(p), dtype=bool)
            seen = 0
            for kind, c, s in low:
                half = np.asarray(s) / 2 + 0.03 if kind == "box" else np.array([s[0] + 0.03, s[0] + 0.03, s[1] / 2 + 0.03])
                inside = np.all(np.abs(p - np.asarray(c)) <= half, axis=1)
                on_obstacle |= inside
                seen += bool(inside.sum() >= 3)
            key = f"{'noisy' if noisy else 'exact'}_h{h:g}"
            result[key] = {"floor_points": int((~on_obstacle).sum()), "low_obstacles_seen": f"{seen}/{len(low)}"}
    return result


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--json", action="store_true", help="print one JSON object as the last line")
    parser.add_argument("--frames", type=int, default=31)
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args()
    result = run_cycle(args.frames, args.seed)
    result["ground_tradeoff"] = ground_tradeoff(args.seed)
    if args.json:
        print(json.dumps(result))
    else:
        for k, v in result.items():
            print(f"{k}: {v}")


if __name__ == "__main__":
    main()
