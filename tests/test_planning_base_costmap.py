"""The base's 2D clearance layers: lower bounds of the true xy clearance, exact for upright primitives."""

import numpy as np
import pytest

from vamg_drake.planning.base_costmap import base_costmap
from vamg_drake.planning.collision_environment import CollisionEnvironment
from vamg_drake.world.primitives import WorldBox, WorldCylinder, footprint_clearance, rotation_from_rpy, rotation_z

CAP = 0.6


def _scene():
    low = [WorldBox("table/base", np.array([1.0, 0.5, 0.35]), rotation_z(0.4), np.array([0.3, 0.5, 0.35])),
           WorldCylinder("bin", np.array([-0.8, -0.6, 0.3]), np.eye(3), 0.2, 0.6)]
    high = [WorldBox("shelf", np.array([-0.5, 1.2, 1.0]), rotation_z(-1.1), np.array([0.4, 0.15, 0.1]))]
    tilted = [WorldBox("plank", np.array([0.3, -1.0, 0.3]), rotation_from_rpy([0.0, 0.5, 0.3]),
                       np.array([0.5, 0.05, 0.05]))]
    return low, high, tilted


def _clearance(p, prims):
    """Exact xy clearance of points p (N, 2): polygons for boxes, discs for
    upright cylinders (their `footprint()` is a circumscribed polygon)."""
    boxes = [s for s in prims if isinstance(s, WorldBox)]
    d = footprint_clearance(p, boxes)
    for c in prims:
        if isinstance(c, WorldCylinder):
            d = np.minimum(d, np.linalg.norm(p - c.p_WC[:2], axis=1) - c.radius)
    return np.maximum(d, 0.0)


def _cell_centres(cm):
    nx, ny = cm.shape
    g = np.stack(np.meshgrid(cm.origin[0] + cm.resolution * np.arange(nx),
                             cm.origin[1] + cm.resolution * np.arange(ny), indexing="ij"), axis=-1)
    return g.reshape(-1, 2)


def test_primitive_layers_are_exact_for_upright_shapes_and_lower_bounds_otherwise():
    low, high, tilted = _scene()
    env = CollisionEnvironment.from_primitives(low + high + tilted)
    bands = [(-10.0, 0.6), (0.8, 1.4)]
    cm = base_costmap(env, bands, 0.05, CAP)
    p = _cell_centres(cm)
    assert cm.margin == pytest.approx(0.5 * np.sqrt(2) * 0.05, abs=1e-5)
    # Band 1 (0.8-1.4 m) holds only the shelf: exact, capped.
    exact = np.minimum(_clearance(p, high), CAP)
    np.testing.assert_allclose(cm.layers[1].reshape(-1), exact, atol=1e-5)
    # Band 0: the table base and the bin exactly, the tilted plank by its xy
    # bounding box (never more than its true clearance).
    true = np.minimum(_clearance(p, low + tilted), CAP)
    layer = cm.layers[0].reshape(-1)
    assert np.all(layer <= true + 1e-5)
    upright_only = np.minimum(_clearance(p, low), CAP)
    c = tilted[0].corners()[:, :2]
    far_from_plank = np.linalg.norm(np.maximum(np.maximum(c.min(axis=0) - p, p - c.max(axis=0)), 0.0), axis=1) > CAP
    np.testing.assert_allclose(layer[far_from_plank], upright_only[far_from_plank], atol=1e-5)


def test_grid_covers_obstacles_and_the_requested_box():
    low, high, tilted = _scene()
    env = CollisionEnvironment.from_primitives(low)
    cm = base_costmap(env, [(-10.0, 2.0)], 0.05, CAP, cover_xy=(np.array([4.0, 4.0]), np.array([5.0, 5.0])))
    hi = cm.origin + cm.resolution * (np.array(cm.shape) - 1)
    lo_obstacles = np.concatenate([s.footprint() for s in low]).min(axis=0)
    assert np.all(hi >= 5.0) and np.all(cm.origin <= lo_obstacles - 1.0 + cm.resolution)
    empty = base_costmap(CollisionEnvironment(), [(-10.0, 2.0)], 0.05, CAP)
    assert np.all(empty.layers == np.float32(CAP))


def test_map_layers_are_lower_bounds_of_the_clearance():
    low, high, _ = _scene()
    env = CollisionEnvironment.from_primitives(low + high).voxelized(0.03)
    cm = base_costmap(env, [(-10.0, 0.6), (0.8, 1.4)], 0.05, CAP)
    assert cm.resolution == pytest.approx(0.03)  # the field's own grid
    p = _cell_centres(cm)
    for layer, prims in zip(cm.layers, (low, high)):
        true = _clearance(p, prims)
        assert np.all(layer.reshape(-1) <= true + 1e-5)
        # ... and not far below it (the voxel bound).
        near = true < CAP - 0.1
        assert np.all(layer.reshape(-1)[near] >= true[near] - 2 * 0.03 - 1e-5)


def test_bad_arguments_name_the_field():
    with pytest.raises(ValueError, match="bands"):
        base_costmap(CollisionEnvironment(), [], 0.05, CAP)
    with pytest.raises(ValueError, match="resolution"):
        base_costmap(CollisionEnvironment(), [(0.0, 1.0)], 0.0, CAP)
