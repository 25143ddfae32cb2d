"""Seeded surface point clouds of simple objects, for tests and benchmarks.

Each function returns points ``p_WS (N, 3)`` sampled on the visible-or-not
surface of a primitive object in world coordinates (metres). They stand in for
the segmented cloud around a target when the simulator is not running: a
cylindrical can, a box, a mug (cylindrical shell with a handle) and a flat wall
patch (a surface with no graspable thickness).
"""

from __future__ import annotations

import numpy as np


def _rng(seed: int | np.random.Generator) -> np.random.Generator:
    return seed if isinstance(seed, np.random.Generator) else np.random.default_rng(seed)


def can_cloud(
    center: np.ndarray = (0.0, 0.0, 0.0),
    radius: float = 0.033,
    height: float = 0.12,
    n: int = 1500,
    noise: float = 0.0,
    seed: int | np.random.Generator = 0,
) -> np.ndarray:
    """A closed cylinder standing on its bottom face; ``center`` is the bottom centre."""
    rng = _rng(seed)
    side_area = 2 * np.pi * radius * height
    cap_area = np.pi * radius**2
    n_side = int(n * side_area / (side_area + cap_area))
    phi = rng.uniform(0, 2 * np.pi, n_side)
    z = rng.uniform(0, height, n_side)
    side = np.stack([radius * np.cos(phi), radius * np.sin(phi), z], axis=1)
    n_cap = n - n_side
    r = radius * np.sqrt(rng.uniform(0, 1, n_cap))
    phi = rng.uniform(0, 2 * np.pi, n_cap)
    cap = np.stack([r * np.cos(phi), r * np.sin(phi), np.full(n_cap, height)], axis=1)
    points = np.concatenate([side, cap]) + np.asarray(center, dtype=float)
    return points + rng.normal(0, noise, points.shape) if noise > 0 else points


def sphere_cloud(
    center: np.ndarray = (0.0, 0.0, 0.0),
    radius: float = 0.024,
    n: int = 1500,
    seed: int | np.random.Generator = 0,
) -> np.ndarray:
    """A ball resting on the plane z = center z - radius (the part above it)."""
    rng = _rng(seed)
    v = rng.normal(size=(n, 3))
    v /= np.linalg.norm(v, axis=1, keepdims=True)
    points = np.asarray(center, dtype=float) + radius * v
    return points[points[:, 2] > center[2] - 0.9 * radius]


def box_cloud(
    center: np.ndarray = (0.0, 0.0, 0.0),
    size: np.ndarray = (0.06, 0.09, 0.15),
    yaw: float = 0.0,
    n: int = 2000,
    noise: float = 0.0,
    seed: int | np.random.Generator = 0,
) -> np.ndarray:
    """The four sides and the top of a box resting on its bottom; ``center`` is the bottom centre."""
    rng = _rng(seed)
    sx, sy, sz = np.asarray(size, dtype=float)
    faces = [  # (area, sampler)
        (sy * sz, lambda m: np.stack([np.full(m, sx / 2), rng.uniform(-sy / 2, sy / 2, m), rng.uniform(0, sz, m)], 1)),
        (sy * sz, lambda m: np.stack([np.full(m, -sx / 2), rng.uniform(-sy / 2, sy / 2, m), rng.uniform(0, sz, m)], 1)),
        (sx * sz, lambda m: np.stack([rng.uniform(-sx / 2, sx / 2, m), np.full(m, sy / 2), rng.uniform(0, sz, m)], 1)),
        (sx * sz, lambda m: np.stack([rng.uniform(-sx / 2, sx / 2, m), np.full(m, -sy / 2), rng.uniform(0, sz, m)], 1)),
        (sx * sy, lambda m: np.stack([rng.uniform(-sx / 2, sx / 2, m), rng.uniform(-sy / 2, sy / 2, m), np.full(m, sz)], 1)),
    ]
    total = sum(a for a, _ in faces)
    points = np.concatenate([f(max(1, int(n * a / total))) for a, f in faces])
    c, s = np.cos(yaw), np.sin(yaw)
    R = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
    points = points @ R.T + np.asarray(center, dtype=float)
    return points + rng.normal(0, noise, points.shape) if noise > 0 else points


def mug_cloud(
    center: np.ndarray = (0.0, 0.0, 0.0),
    radius: float = 0.04,
    height: float = 0.10,
    wall: float = 0.005,
    handle_radius: float = 0.03,
    handle_thickness: float = 0.008,
    n: int = 3000,
    noise: float = 0.0,
    seed: int | np.random.Generator = 0,
) -> np.ndarray:
    """An open mug: outer and inner walls, a rim, and a torus-section handle on +x."""
    rng = _rng(seed)
    n_outer, n_inner, n_rim = int(0.45 * n), int(0.3 * n), int(0.05 * n)
    n_handle = n - n_outer - n_inner - n_rim

    def shell(m: int, r: float) -> np.ndarray:
        phi = rng.uniform(0, 2 * np.pi, m)
        z = rng.uniform(0, height, m)
        return np.stack([r * np.cos(phi), r * np.sin(phi), z], axis=1)

    outer = shell(n_outer, radius)
    inner = shell(n_inner, radius - wall)
    inner[:, 2] = np.clip(inner[:, 2], wall, None)
    phi = rng.uniform(0, 2 * np.pi, n_rim)
    r = rng.uniform(radius - wall, radius, n_rim)
    rim = np.stack([r * np.cos(phi), r * np.sin(phi), np.full(n_rim, height)], axis=1)
    # Handle: a half torus in the x-z plane attached to the outer wall at +x.
    u = rng.uniform(-np.pi / 2, np.pi / 2, n_handle)  # around the handle arc
    v = rng.uniform(0, 2 * np.pi, n_handle)  # around the handle tube
    ring = handle_radius + handle_thickness * np.cos(v)
    handle = np.stack(
        [radius + ring * np.cos(u), handle_thickness * np.sin(v), height / 2 + ring * np.sin(u)], axis=1
    )
    points = np.concatenate([outer, inner, rim, handle]) + np.asarray(center, dtype=float)
    return points + rng.normal(0, noise, points.shape) if noise > 0 else points


def wall_patch_cloud(
    center: np.ndarray = (0.0, 0.0, 0.5),
    normal: np.ndarray = (1.0, 0.0, 0.0),
    size: float = 0.4,
    n: int = 2000,
    noise: float = 0.0,
    seed: int | np.random.Generator = 0,
) -> np.ndarray:
    """A flat square patch of a wall (no thickness to grasp), facing ``normal``."""
    rng = _rng(seed)
    nrm = np.asarray(normal, dtype=float)
    nrm = nrm / np.linalg.norm(nrm)
    helper = np.array([0.0, 0.0, 1.0]) if abs(nrm[2]) < 0.9 else np.array([1.0, 0.0, 0.0])
    e1 = np.cross(nrm, helper)
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(nrm, e1)
    a, b = rng.uniform(-size / 2, size / 2, (2, n))
    points = np.asarray(center, dtype=float) + a[:, None] * e1 + b[:, None] * e2
    return points + rng.normal(0, noise, points.shape) if noise > 0 else points


def table_top_cloud(
    z: float = 0.0,
    center_xy: np.ndarray = (0.0, 0.0),
    size: float = 0.5,
    spacing: float = 0.01,
) -> np.ndarray:
    """A regular grid of points on a horizontal table top at height ``z``."""
    g = np.arange(-size / 2, size / 2 + 1e-9, spacing)
    gx, gy = np.meshgrid(g, g, indexing="ij")
    return np.stack([gx.ravel() + center_xy[0], gy.ravel() + center_xy[1], np.full(gx.size, z)], axis=1)


def box_surface_cloud(lower: np.ndarray, upper: np.ndarray, spacing: float = 0.03) -> np.ndarray:
    """Grid points on the six faces of an axis-aligned box."""
    lo, hi = np.asarray(lower, dtype=float), np.asarray(upper, dtype=float)
    faces = []
    for axis in range(3):
        others = [a for a in range(3) if a != axis]
        grids = [np.arange(lo[a], hi[a] + 1e-9, spacing) for a in others]
        A, B = np.meshgrid(*grids, indexing="ij")
        for value in (lo[axis], hi[axis]):
            P = np.empty((A.size, 3))
            P[:, axis] = value
            P[:, others[0]] = A.ravel()
            P[:, others[1]] = B.ravel()
            faces.append(P)
    return np.concatenate(faces)


def room_walls_cloud(half_size: float = 3.0, height: float = 2.0, spacing: float = 0.05) -> np.ndarray:
    """Four 10 cm thick walls around the square [-half_size, half_size]^2."""
    s, t = half_size, 0.1
    return np.concatenate(
        [
            box_surface_cloud([-s, -s - t, 0.0], [s, -s, height], spacing),
            box_surface_cloud([-s, s, 0.0], [s, s + t, height], spacing),
            box_surface_cloud([-s - t, -s, 0.0], [-s, s, height], spacing),
            box_surface_cloud([s, -s, 0.0], [s + t, s, height], spacing),
        ]
    )


def tabletop_scene(
    table_center_xy: tuple[float, float] = (1.1, 0.0),
    table_size: tuple[float, float] = (0.6, 1.0),
    table_height: float = 0.7,
    object_offset_xy: tuple[float, float] = (-0.1, 0.0),
    room_half_size: float = 3.0,
) -> tuple[np.ndarray, np.ndarray]:
    """A walled room with a table and a can on it: (map points (N, 3), target (3,))."""
    cx, cy = table_center_xy
    sx, sy = table_size
    table = box_surface_cloud([cx - sx / 2, cy - sy / 2, 0.0], [cx + sx / 2, cy + sy / 2, table_height])
    can_base = np.array([cx + object_offset_xy[0], cy + object_offset_xy[1], table_height])
    can = can_cloud(center=can_base, seed=11)
    points = np.concatenate([room_walls_cloud(room_half_size), table, can])
    return points, can_base + np.array([0.0, 0.0, 0.06])
