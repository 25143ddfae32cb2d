"""The mobile base's 2D clearance map: one layer per height band of obstacles.

`base_costmap(env, bands, resolution, max_clearance)` builds a `Costmap2D`
whose layer b holds, at every cell centre g, a lower bound of the xy distance
from g to the obstacles whose z extent meets band b, capped at
`max_clearance` (the search only compares clearances with the footprint's
radii, so farther values are not needed). Its `margin` is the query term
only: a point p looked up at its nearest cell centre g is within
(sqrt(2)/2) h of it, so clear(p) >= layer(g) - margin.

* Exact primitives (boxes, cylinders): the distance is computed analytically
  at every cell centre within `max_clearance` of a primitive's xy bounding
  box. Upright boxes and cylinders are exact (their footprint rectangle or
  disc); tilted ones use their xy bounding box (a lower bound).
* A distance field (the map's voxels): its occupied voxels in the band are
  projected onto the field's xy grid and an exact EDT gives the distance
  between cell centres; a voxel stands for obstacle points up to
  (sqrt(3)/2) h from its centre (see `CollisionEnvironment.voxelized`), which
  is subtracted. With a field the costmap uses the field's own grid.

The grid covers the obstacles and the `cover_xy` box. Everything is one
compiled pass per input, O(cells touched).
"""

from __future__ import annotations

import math

import numba
import numpy as np

from vamg_drake.planning.collision_environment import CollisionEnvironment
from vamg_drake.planning.distance_field import edt_2d
from vamg_drake.planning.hybrid_astar import Costmap2D

_SQRT2 = math.sqrt(2.0)
_SQRT3 = math.sqrt(3.0)


@numba.njit(cache=True)
def _primitive_clearance_2d(layers, origin, h, band_lo, band_hi, box_p, box_R, box_half, cyl_p, cyl_R, cyl_r,
                            cyl_hl, cap):
    """layers (L, nx, ny) = min(layers, xy distance from each cell centre to
    the primitives meeting band b), visiting only cells within `cap` of each
    primitive's xy bounding box."""
    n_layers, nx, ny = layers.shape
    nb = box_p.shape[0]
    ex = np.empty(3)
    meet = np.empty(n_layers, np.int64)
    for k in range(nb + cyl_p.shape[0]):
        if k < nb:
            for a in range(3):
                ex[a] = 0.0
                for c in range(3):
                    ex[a] += abs(box_R[k, a, c]) * box_half[k, c]
            cx, cy, cz = box_p[k, 0], box_p[k, 1], box_p[k, 2]
            upright = abs(box_R[k, 2, 0]) < 1e-9 and abs(box_R[k, 2, 1]) < 1e-9
        else:
            m = k - nb
            for a in range(3):
                # The cylinder's exact bounding box.
                u = cyl_R[m, a, 2]
                ex[a] = abs(u) * cyl_hl[m] + cyl_r[m] * math.sqrt(max(1.0 - u * u, 0.0))
            cx, cy, cz = cyl_p[m, 0], cyl_p[m, 1], cyl_p[m, 2]
            upright = abs(abs(cyl_R[m, 2, 2]) - 1.0) < 1e-12
        i0 = max(int(math.floor((cx - ex[0] - cap - origin[0]) / h)), 0)
        i1 = min(int(math.ceil((cx + ex[0] + cap - origin[0]) / h)), nx - 1)
        j0 = max(int(math.floor((cy - ex[1] - cap - origin[1]) / h)), 0)
        j1 = min(int(math.ceil((cy + ex[1] + cap - origin[1]) / h)), ny - 1)
        # The layers whose band the primitive meets (the distance is computed
        # once per cell for all of them).
        n_meet = 0
        for b in range(n_layers):
            if not (cz + ex[2] < band_lo[b] or cz - ex[2] > band_hi[b]):
                meet[n_meet] = b
                n_meet += 1
        if n_meet == 0:
            continue
        for i in range(i0, i1 + 1):
            gx = origin[0] + i * h - cx
            for j in range(j0, j1 + 1):
                gy = origin[1] + j * h - cy
                if upright and k < nb:
                    lx = abs(box_R[k, 0, 0] * gx + box_R[k, 1, 0] * gy) - box_half[k, 0]
                    ly = abs(box_R[k, 0, 1] * gx + box_R[k, 1, 1] * gy) - box_half[k, 1]
                elif upright:
                    lx = math.sqrt(gx * gx + gy * gy) - cyl_r[k - nb]
                    ly = 0.0
                else:
                    lx = abs(gx) - ex[0]
                    ly = abs(gy) - ex[1]
                d2 = 0.0
                if lx > 0.0:
                    d2 += lx * lx
                if ly > 0.0:
                    d2 += ly * ly
                d = math.sqrt(d2)
                for m in range(n_meet):
                    b = meet[m]
                    if d < layers[b, i, j]:
                        layers[b, i, j] = d


def _primitive_xy_box(env: CollisionEnvironment) -> tuple[np.ndarray, np.ndarray] | None:
    lo, hi = [], []
    if env.box_p.shape[0]:
        e = np.einsum("kij,kj->ki", np.abs(env.box_R), env.box_half)
        lo.append((env.box_p - e).min(axis=0))
        hi.append((env.box_p + e).max(axis=0))
    if env.cyl_p.shape[0]:
        e = np.abs(env.cyl_R[:, :, 2]) * env.cyl_half_length[:, None] + env.cyl_radius[:, None]
        lo.append((env.cyl_p - e).min(axis=0))
        hi.append((env.cyl_p + e).max(axis=0))
    if not lo:
        return None
    return np.min(lo, axis=0)[:2], np.max(hi, axis=0)[:2]


def base_costmap(env: CollisionEnvironment, bands: list[tuple[float, float]], resolution: float,
                 max_clearance: float, cover_xy: tuple[np.ndarray, np.ndarray] | None = None,
                 border: float = 1.0) -> Costmap2D:
    """The clearance layers of `env`, one per (z_min, z_max) band (see the module docstring).

    Args:
        env: the collision environment.
        bands: the height bands [m].
        resolution: cell size [m] (a distance field's own cell size wins).
        max_clearance: clearances are capped here [m] (> the largest radius tested).
        cover_xy: (lo (2,), hi (2,)) an xy box the grid must cover as well.
        border: free space around the obstacles' extent [m].
    """
    if not bands:
        raise ValueError("base_costmap: bands is empty")
    if not (resolution > 0 and max_clearance > 0):
        raise ValueError(f"base_costmap: resolution ({resolution}) and max_clearance ({max_clearance}) must be > 0")
    f = env.field
    has_field = f is not None and f.num_occupied > 0
    boxes = [] if not has_field else [(f.origin[:2] - 0.5 * f.resolution,
                                      f.origin[:2] + f.resolution * (np.array(f.dist.shape[:2]) - 0.5))]
    prim_box = _primitive_xy_box(env)
    if prim_box is not None:
        boxes.append(prim_box)
    lo_list = [b[0] - border for b in boxes]
    hi_list = [b[1] + border for b in boxes]
    if cover_xy is not None:
        lo_list.append(np.asarray(cover_xy[0], float))
        hi_list.append(np.asarray(cover_xy[1], float))
    if not lo_list:
        return Costmap2D(np.full((len(bands), 1, 1), np.float32(max_clearance)), np.zeros(2), float(resolution),
                         0.5 * _SQRT2 * resolution)
    lo, hi = np.min(lo_list, axis=0), np.max(hi_list, axis=0)
    if has_field:
        h = float(f.resolution)
        # On the field's grid: origin = field origin + whole cells.
        origin = f.origin[:2] + np.floor((lo - f.origin[:2]) / h) * h
    else:
        h = float(resolution)
        origin = np.floor(lo / h) * h + 0.5 * h
    shape = np.maximum(np.ceil((hi - origin) / h).astype(int) + 1, 1)
    layers = np.full((len(bands), *shape), np.float32(max_clearance))
    band_lo = np.array([b[0] for b in bands], float)
    band_hi = np.array([b[1] for b in bands], float)
    if has_field:
        off = np.rint((f.origin[:2] - origin) / h).astype(int)
        z = f.origin[2] + h * np.arange(f.occupancy.shape[2])
        n = f.occupancy.shape[:2]
        for b, (z0, z1) in enumerate(bands):
            sel = (z >= z0 - 0.5 * h) & (z <= z1 + 0.5 * h)
            if not sel.any():
                continue
            occ = np.zeros(tuple(shape), bool)
            occ[off[0]:off[0] + n[0], off[1]:off[1] + n[1]] = f.occupancy[:, :, sel].any(axis=2)
            if occ.any():
                d = edt_2d(occ, h) - np.float32(0.5 * _SQRT3 * h)
                np.minimum(layers[b], np.maximum(d, 0.0), out=layers[b])
    if prim_box is not None:
        _primitive_clearance_2d(layers, origin, h, band_lo, band_hi, env.box_p, env.box_R, env.box_half,
                                env.cyl_p, env.cyl_R, env.cyl_radius, env.cyl_half_length, float(max_clearance))
    # (+1 um: the float32 rounding of the stored distances)
    return Costmap2D(layers, origin, h, 0.5 * _SQRT2 * h + 1e-6)
