"""Walls rebuilt from a navmesh (scenes without their stage mesh), on a hand-made navmesh.

The walkable floor is the rectangle [0, 3] x [0, 2], three quads side by
side, eroded by an agent radius of 0.3 m; a table stands beyond the middle
third of the top edge. The top edge's outer thirds and the other sides are
walls; the middle third is explained by the table.
"""

from pathlib import Path

import numpy as np
import pytest

from vamg_drake.world.primitives import signed_distance_to_polygon
from vamg_drake.world.replicacad import ReplicaCadConfig, navmesh_walls
from vamg_drake.world.replicacad_navmesh import NavMesh

R = 0.3
TABLE = np.array([[1.0, 2.3], [2.0, 2.3], [2.0, 2.9], [1.0, 2.9]])


def _navmesh() -> NavMesh:
    xs, ys = [0.0, 1.0, 2.0, 3.0], [0.0, 2.0]
    vertices = np.array([[x, y, 0.0] for y in ys for x in xs])  # index = 4 * row + column
    polygons = tuple(np.array([c, c + 1, 5 + c, 4 + c]) for c in range(3))
    edges = []
    for c in range(3):
        edges.append((vertices[c], vertices[c + 1]))  # bottom
        edges.append((vertices[5 + c], vertices[4 + c]))  # top
    edges.append((vertices[4], vertices[0]))  # left
    edges.append((vertices[3], vertices[7]))  # right
    return NavMesh(Path("hand-made"), vertices, polygons, np.array(edges), R, 1.5)


def _ends(wall) -> np.ndarray:
    """The two ends of a wall box's centre line (2, 2)."""
    u = wall.R_WB[:2, 0]
    return wall.p_WB[:2] + np.outer([-1.0, 1.0], wall.half_extents[0] * u)


@pytest.fixture(scope="module")
def walls():
    return navmesh_walls(_navmesh(), [TABLE], ReplicaCadConfig())


def test_edges_explained_by_furniture_are_not_walls(walls):
    # 3 bottom, left, right, and the top's two outer thirds.
    assert len(walls) == 7
    for w in walls:
        assert signed_distance_to_polygon(w.p_WB[None, :2], TABLE)[0] > 0.0


def test_wall_ends_reach_into_corners_but_not_into_furniture(walls):
    t = ReplicaCadConfig().wall_thickness
    y_top = 2.0 + R + 0.5 * t
    top = [w for w in walls if abs(w.p_WB[1] - y_top) < 1e-9]
    assert len(top) == 2
    left, right = sorted(top, key=lambda w: w.p_WB[0])
    # The room's corners are closed: the top walls reach R past the corner vertices.
    assert np.sort(_ends(left)[:, 0])[0] == pytest.approx(-R)
    assert np.sort(_ends(right)[:, 0])[1] == pytest.approx(3.0 + R)
    # Next to the table the walls stop where the navmesh edge turns: they do
    # not reach R on into the table's side of the room.
    assert np.sort(_ends(left)[:, 0])[1] == pytest.approx(1.0)
    assert np.sort(_ends(right)[:, 0])[0] == pytest.approx(2.0)
    for w in (left, right):
        corners = w.footprint()
        assert np.all(signed_distance_to_polygon(corners, TABLE) >= -1e-9)


def test_side_walls_close_the_corners(walls):
    t = ReplicaCadConfig().wall_thickness
    x_left = -(R + 0.5 * t)
    side = [w for w in walls if abs(w.p_WB[0] - x_left) < 1e-9]
    assert len(side) == 1
    ys = np.sort(_ends(side[0])[:, 1])
    assert ys == pytest.approx([-R, 2.0 + R])
