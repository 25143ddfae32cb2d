"""What the robot must not touch: a distance field and/or exact world primitives.

`CollisionEnvironment` is any union of a `DistanceField` (from the map's
points or occupancy) and exact boxes and cylinders
(`vamg_drake.world.primitives`, the ground truth), plus the grasp target's
ball whose points only the gripper may touch. `voxelized` rasterizes the
primitives into a conservative field.
"""

import dataclasses
import math

import numba
import numpy as np

from vamg_drake.perception.point_clusters import support_height
from vamg_drake.planning.distance_field import SQRT3, DistanceField
from vamg_drake.world.primitives import WorldBox, WorldCylinder


@dataclasses.dataclass(frozen=True, eq=False)
class CollisionEnvironment:
    """What the robot must not touch: a distance field and/or exact primitives.

    Attributes:
        field: optional `DistanceField` (from the map).
        box_p: (K, 3) box centres; box_R (K, 3, 3); box_half (K, 3) half extents.
        cyl_p: (C, 3) cylinder centres; cyl_R (C, 3, 3) (axis = column 2);
            cyl_radius (C,), cyl_half_length (C,).
        grasp_target: (3,) centre of the grasp target's ball: the field's
            points within `grasp_target_radius` of it and above
            `grasp_target_floor` are the object to grasp,
            which the gripper's spheres may touch and the rest of the robot
            may not (0 radius: no such ball).
        grasp_target_radius: [m].
        grasp_target_floor: height of the surface the target stands on [m]:
            points at or below it are the support (a table top), which the
            gripper must not touch either.
    """

    field: DistanceField | None = None
    box_p: np.ndarray = dataclasses.field(default_factory=lambda: np.zeros((0, 3)))
    box_R: np.ndarray = dataclasses.field(default_factory=lambda: np.zeros((0, 3, 3)))
    box_half: np.ndarray = dataclasses.field(default_factory=lambda: np.zeros((0, 3)))
    cyl_p: np.ndarray = dataclasses.field(default_factory=lambda: np.zeros((0, 3)))
    cyl_R: np.ndarray = dataclasses.field(default_factory=lambda: np.zeros((0, 3, 3)))
    cyl_radius: np.ndarray = dataclasses.field(default_factory=lambda: np.zeros(0))
    cyl_half_length: np.ndarray = dataclasses.field(default_factory=lambda: np.zeros(0))
    grasp_target: np.ndarray = dataclasses.field(default_factory=lambda: np.zeros(3))
    grasp_target_radius: float = 0.0
    grasp_target_floor: float = -np.inf

    @property
    def is_empty(self) -> bool:
        no_field = self.field is None or self.field.num_occupied == 0
        return no_field and self.box_p.shape[0] == 0 and self.cyl_p.shape[0] == 0

    @staticmethod
    def from_points(points: np.ndarray, resolution: float = 0.03, grasp_target: np.ndarray | None = None,
                    grasp_target_radius: float = 0.0) -> "CollisionEnvironment":
        """The map's points as a distance field; points within
        `grasp_target_radius` of `grasp_target` may touch the gripper only."""
        env = CollisionEnvironment(field=DistanceField.from_points(points, resolution))
        if grasp_target is None or not grasp_target_radius > 0.0:
            return env
        return env.with_grasp_target(grasp_target, grasp_target_radius)

    def with_grasp_target(self, grasp_target: np.ndarray, radius: float) -> "CollisionEnvironment":
        """The same obstacles, the field's points within `radius` of
        `grasp_target` (above their support, `support_height`) allowed to the
        gripper; the field is shared, not rebuilt."""
        grasp_target = np.asarray(grasp_target, dtype=float).reshape(3)
        if not np.all(np.isfinite(grasp_target)):
            raise ValueError(f"grasp_target must be finite, got {grasp_target}")
        points = self.field.points if self.field is not None else np.zeros((0, 3))
        return dataclasses.replace(self, grasp_target=grasp_target, grasp_target_radius=float(radius),
                                   grasp_target_floor=support_height(points, grasp_target, radius))

    @staticmethod
    def from_occupancy(occupied: np.ndarray, origin: np.ndarray, resolution: float) -> "CollisionEnvironment":
        return CollisionEnvironment(field=DistanceField.from_occupancy(occupied, origin, resolution))

    @staticmethod
    def from_primitives(primitives, min_top_z: float = 0.01) -> "CollisionEnvironment":
        """Exact boxes/cylinders (`vamg_drake.world.primitives`) as the environment.

        Primitives whose top is below `min_top_z` (the floor) are skipped.
        """
        boxes = [p for p in primitives if isinstance(p, WorldBox) and p.z_range()[1] > min_top_z]
        cyls = [p for p in primitives if isinstance(p, WorldCylinder)]
        return CollisionEnvironment(
            box_p=np.array([b.p_WB for b in boxes], float).reshape(-1, 3),
            box_R=np.array([b.R_WB for b in boxes], float).reshape(-1, 3, 3),
            box_half=np.array([b.half_extents for b in boxes], float).reshape(-1, 3),
            cyl_p=np.array([c.p_WC for c in cyls], float).reshape(-1, 3),
            cyl_R=np.array([c.R_WC for c in cyls], float).reshape(-1, 3, 3),
            cyl_radius=np.array([c.radius for c in cyls], float),
            cyl_half_length=np.array([0.5 * c.length for c in cyls], float),
        )

    def voxelized(self, resolution: float = 0.03, z_max: float = 2.2) -> "CollisionEnvironment":
        """The primitives rasterized into a conservative distance field.

        A cell is occupied when its centre is within (sqrt(3)/2) h of a
        primitive, so every primitive point lies in an occupied cell and the
        field's bound holds.
        """
        if self.box_p.shape[0] == 0 and self.cyl_p.shape[0] == 0:
            return CollisionEnvironment(field=DistanceField.from_points(np.zeros((0, 3)), resolution))
        corners = []
        for p, R, h in zip(self.box_p, self.box_R, self.box_half):
            corners.append(p + np.abs(R) @ h)
            corners.append(p - np.abs(R) @ h)
        for p, R, r, hl in zip(self.cyl_p, self.cyl_R, self.cyl_radius, self.cyl_half_length):
            ext = np.abs(R[:, 2]) * hl + r
            corners.append(p + ext)
            corners.append(p - ext)
        corners = np.array(corners)
        lo = np.floor(corners.min(axis=0) / resolution) * resolution - resolution
        hi = corners.max(axis=0) + resolution
        hi[2] = min(hi[2], z_max)
        shape = np.maximum(np.ceil((hi - lo) / resolution).astype(int), 1)
        origin = lo + 0.5 * resolution
        g = [origin[i] + resolution * np.arange(shape[i]) for i in range(3)]
        centres = np.stack(np.meshgrid(*g, indexing="ij"), axis=-1).reshape(-1, 3)
        d = primitive_distances(centres, self)
        occ = (d <= 0.5 * SQRT3 * resolution).reshape(shape)
        return CollisionEnvironment(field=DistanceField.from_occupancy(occ, origin, resolution))


@numba.njit(cache=True)
def _primitive_distance_kernel(P, box_p, box_R, box_half, cyl_p, cyl_R, cyl_r, cyl_hl, out):
    for i in range(P.shape[0]):
        best = 1e9
        for k in range(box_p.shape[0]):
            d2 = 0.0
            for a in range(3):
                lc = 0.0
                for b in range(3):
                    lc += box_R[k, b, a] * (P[i, b] - box_p[k, b])
                e = abs(lc) - box_half[k, a]
                if e > 0:
                    d2 += e * e
            d = math.sqrt(d2)
            if d < best:
                best = d
        for k in range(cyl_p.shape[0]):
            lc = np.zeros(3)
            for a in range(3):
                for b in range(3):
                    lc[a] += cyl_R[k, b, a] * (P[i, b] - cyl_p[k, b])
            er = math.sqrt(lc[0] * lc[0] + lc[1] * lc[1]) - cyl_r[k]
            ez = abs(lc[2]) - cyl_hl[k]
            d2 = 0.0
            if er > 0:
                d2 += er * er
            if ez > 0:
                d2 += ez * ez
            d = math.sqrt(d2)
            if d < best:
                best = d
        out[i] = best
    return out


def primitive_distances(points: np.ndarray, env: CollisionEnvironment) -> np.ndarray:
    """Exact distance (0 inside) from each point (N, 3) to the env's primitives."""
    P = np.ascontiguousarray(points, dtype=float).reshape(-1, 3)
    out = np.empty(P.shape[0])
    return _primitive_distance_kernel(
        P, env.box_p, env.box_R, env.box_half, env.cyl_p, env.cyl_R,
        env.cyl_radius, env.cyl_half_length, out,
    )
