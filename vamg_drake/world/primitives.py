"""World-frame primitive shapes and the plain 2D geometry used on them.

No Drake here: these are the shapes that top-down plots, costmaps, ground-truth
checks and the room generator work with. A primitive's *footprint* is the
convex polygon of its projection onto the floor plane (cylinders are
approximated by a circumscribed polygon, so the footprint is conservative).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

#: Vertices of the polygon that circumscribes a circle footprint.
_CIRCLE_SIDES = 24


@dataclass(frozen=True)
class WorldBox:
    """A box in the world frame W.

    Attributes:
        name: "<owner>/<part>", e.g. "table_0/top" or "wall/3".
        p_WB: (3,) box centre.
        R_WB: (3, 3) box orientation.
        half_extents: (3,) half sizes along the box axes.
    """

    name: str
    p_WB: np.ndarray
    R_WB: np.ndarray
    half_extents: np.ndarray

    def corners(self) -> np.ndarray:
        """Returns the (8, 3) corners in W."""
        signs = np.array(
            [[sx, sy, sz] for sx in (-1, 1) for sy in (-1, 1) for sz in (-1, 1)],
            dtype=float,
        )
        return self.p_WB + (signs * self.half_extents) @ self.R_WB.T

    def z_range(self) -> tuple[float, float]:
        """Returns the lowest and highest z of the box."""
        z = self.corners()[:, 2]
        return float(z.min()), float(z.max())

    def footprint(self) -> np.ndarray:
        """Returns the (k, 2) convex footprint polygon, counter-clockwise."""
        return convex_hull_2d(self.corners()[:, :2])


@dataclass(frozen=True)
class WorldCylinder:
    """A cylinder in W; its axis is the z axis of R_WC.

    Attributes:
        name: "<owner>/<part>".
        p_WC: (3,) cylinder centre.
        R_WC: (3, 3) orientation; the axis is R_WC[:, 2].
        radius: cylinder radius.
        length: cylinder length along its axis.
    """

    name: str
    p_WC: np.ndarray
    R_WC: np.ndarray
    radius: float
    length: float

    def _rim_points(self) -> np.ndarray:
        angles = np.arange(_CIRCLE_SIDES) * (2 * np.pi / _CIRCLE_SIDES)
        r = self.radius / np.cos(np.pi / _CIRCLE_SIDES)  # circumscribed
        ring = np.stack([r * np.cos(angles), r * np.sin(angles)], axis=1)
        points = []
        for z in (-0.5 * self.length, 0.5 * self.length):
            p_C = np.column_stack([ring, np.full(len(ring), z)])
            points.append(self.p_WC + p_C @ self.R_WC.T)
        return np.concatenate(points)

    def z_range(self) -> tuple[float, float]:
        """Returns the lowest and highest z of the cylinder (conservative)."""
        z = self._rim_points()[:, 2]
        return float(z.min()), float(z.max())

    def footprint(self) -> np.ndarray:
        """Returns the (k, 2) convex footprint polygon, counter-clockwise."""
        return convex_hull_2d(self._rim_points()[:, :2])


WorldPrimitive = WorldBox | WorldCylinder


def rotation_from_rpy(rpy: np.ndarray | list[float]) -> np.ndarray:
    """Returns R = Rz(yaw) Ry(pitch) Rx(roll), Drake's RollPitchYaw convention."""
    roll, pitch, yaw = (float(a) for a in rpy)
    cr, sr = np.cos(roll), np.sin(roll)
    cp, sp = np.cos(pitch), np.sin(pitch)
    cy, sy = np.cos(yaw), np.sin(yaw)
    Rx = np.array([[1, 0, 0], [0, cr, -sr], [0, sr, cr]])
    Ry = np.array([[cp, 0, sp], [0, 1, 0], [-sp, 0, cp]])
    Rz = np.array([[cy, -sy, 0], [sy, cy, 0], [0, 0, 1]])
    return Rz @ Ry @ Rx


def rotation_z(yaw: float) -> np.ndarray:
    """Returns the rotation about +z by ``yaw``."""
    return rotation_from_rpy([0.0, 0.0, yaw])


def convex_hull_2d(points: np.ndarray) -> np.ndarray:
    """Returns the counter-clockwise convex hull of (N, 2) points (monotone chain)."""
    pts = np.unique(np.round(np.asarray(points, dtype=float), 12), axis=0)
    if len(pts) < 3:
        return pts

    def cross(o, a, b):
        return (a[0] - o[0]) * (b[1] - o[1]) - (a[1] - o[1]) * (b[0] - o[0])

    lower: list[np.ndarray] = []
    for p in pts:
        while len(lower) >= 2 and cross(lower[-2], lower[-1], p) <= 0:
            lower.pop()
        lower.append(p)
    upper: list[np.ndarray] = []
    for p in pts[::-1]:
        while len(upper) >= 2 and cross(upper[-2], upper[-1], p) <= 0:
            upper.pop()
        upper.append(p)
    return np.array(lower[:-1] + upper[:-1])


def polygon_area(polygon: np.ndarray) -> float:
    """Returns the signed area of a (k, 2) polygon (positive if counter-clockwise)."""
    x, y = polygon[:, 0], polygon[:, 1]
    return 0.5 * float(np.dot(x, np.roll(y, -1)) - np.dot(y, np.roll(x, -1)))


def points_in_polygon(points: np.ndarray, polygon: np.ndarray) -> np.ndarray:
    """Even-odd test of (N, 2) points against a simple (k, 2) polygon -> (N,) bool."""
    points = np.atleast_2d(np.asarray(points, dtype=float))
    x, y = points[:, 0:1], points[:, 1:2]
    a = polygon
    b = np.roll(polygon, -1, axis=0)
    straddles = (a[:, 1] > y) != (b[:, 1] > y)
    with np.errstate(divide="ignore", invalid="ignore"):
        x_cross = a[:, 0] + (y - a[:, 1]) * (b[:, 0] - a[:, 0]) / (b[:, 1] - a[:, 1])
    hits = straddles & (x < x_cross)
    return (np.count_nonzero(hits, axis=1) % 2) == 1


def distance_to_polygon_boundary(points: np.ndarray, polygon: np.ndarray) -> np.ndarray:
    """Unsigned distance of (N, 2) points to the edges of a closed (k, 2) polygon."""
    points = np.atleast_2d(np.asarray(points, dtype=float))
    a = polygon[None, :, :]
    ab = (np.roll(polygon, -1, axis=0) - polygon)[None, :, :]
    ap = points[:, None, :] - a
    t = np.clip(
        np.sum(ap * ab, axis=2) / np.maximum(np.sum(ab * ab, axis=2), 1e-18), 0.0, 1.0
    )
    closest = a + t[..., None] * ab
    return np.min(np.linalg.norm(points[:, None, :] - closest, axis=2), axis=1)


def signed_distance_to_polygon(points: np.ndarray, polygon: np.ndarray) -> np.ndarray:
    """Signed distance of (N, 2) points to a simple polygon (negative inside)."""
    d = distance_to_polygon_boundary(points, polygon)
    return np.where(points_in_polygon(points, polygon), -d, d)


def footprint_clearance(points: np.ndarray, primitives: list[WorldPrimitive]) -> np.ndarray:
    """Smallest signed xy distance from (N, 2) points to any primitive footprint.

    Returns +inf for every point when ``primitives`` is empty.
    """
    points = np.atleast_2d(np.asarray(points, dtype=float))
    clearance = np.full(len(points), np.inf)
    for shape in primitives:
        clearance = np.minimum(
            clearance, signed_distance_to_polygon(points, shape.footprint())
        )
    return clearance
