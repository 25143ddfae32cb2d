"""Voxel-grid bookkeeping of point sets shared by the perception and policy code."""

import math

import numba
import numpy as np


def first_in_voxel(p: np.ndarray, voxel: float) -> np.ndarray:
    """Sorted indices of the first point of p (N, 3+) in each `voxel`-sized cell.

    One pass with an open-addressing table keyed by the integer cell
    (floor(p / voxel)); no sort, and no limit on the extent of the points.
    The points must be finite.
    """
    p = np.asarray(p, dtype=float)
    if p.shape[0] == 0:
        return np.zeros(0, np.int64)
    return _first_in_voxel(np.ascontiguousarray(p[:, :3]), float(voxel))


@numba.njit(cache=True)
def _first_in_voxel(p, voxel):
    n = p.shape[0]
    cap = 16
    while cap < 2 * n:
        cap *= 2
    mask = cap - 1
    table = np.full(cap, -1, dtype=np.int64)
    keys = np.empty((n, 3), dtype=np.int64)
    out = np.empty(n, dtype=np.int64)
    m = 0
    for i in range(n):
        a = np.int64(math.floor(p[i, 0] / voxel))
        b = np.int64(math.floor(p[i, 1] / voxel))
        c = np.int64(math.floor(p[i, 2] / voxel))
        keys[i, 0] = a
        keys[i, 1] = b
        keys[i, 2] = c
        slot = ((a * 73856093) ^ (b * 19349663) ^ (c * 83492791)) & mask
        while True:
            j = table[slot]
            if j < 0:
                table[slot] = i
                out[m] = i
                m += 1
                break
            if keys[j, 0] == a and keys[j, 1] == b and keys[j, 2] == c:
                break
            slot = (slot + 1) & mask
    return out[:m]
