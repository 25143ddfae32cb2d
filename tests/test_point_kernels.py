"""The numba point kernels give exactly what their NumPy definitions give."""

import numpy as np

from vamg_drake.perception.depth_points import within_distance
from vamg_drake.perception.voxels import first_in_voxel


def _first_in_voxel_by_sorting(p: np.ndarray, voxel: float) -> np.ndarray:
    keys = np.floor(p[:, :3] / voxel).astype(np.int64)
    _, index = np.unique(keys, axis=0, return_index=True)
    return np.sort(index)


def test_first_in_voxel_keeps_the_first_point_of_every_cell():
    rng = np.random.default_rng(3)
    for n in (1, 2, 17, 5000):
        for scale in (0.01, 1.0, 1e4):
            p = rng.normal(size=(n, 4)) * scale - 2.0
            p[n // 2:, :3] = p[: n - n // 2, :3]  # repeated cells, later in the array
            for voxel in (0.003, 0.05):
                np.testing.assert_array_equal(first_in_voxel(p, voxel), _first_in_voxel_by_sorting(p, voxel))
    assert first_in_voxel(np.zeros((0, 3)), 0.1).shape == (0,)
    # Points on both sides of a cell boundary are in different cells.
    np.testing.assert_array_equal(first_in_voxel(np.array([[0.0999, 0, 0], [0.1, 0, 0], [0.05, 0, 0]]), 0.1), [0, 1])


def test_within_distance_rounds_as_numpy_norm():
    rng = np.random.default_rng(4)
    p = rng.normal(size=(200000, 3)) * np.array([1e-3, 1.0, 1e3])
    c = rng.normal(size=3)
    d = np.linalg.norm(p - c, axis=1)
    for r in np.sort(d)[::997]:  # radii equal to a point's distance: the boundary is included
        np.testing.assert_array_equal(within_distance(p, c, r), d <= r)
