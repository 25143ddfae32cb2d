"""Connected clusters and the mirrored completion of the target's unseen side."""

import numpy as np

from vamg_drake.perception.point_clusters import MirrorCompletionConfig, component_nearest, mirrored_object_points
from vamg_drake.testing import synthetic_clouds as clouds


def test_component_nearest_follows_links_and_stops_at_gaps() -> None:
    line = np.c_[np.arange(0.0, 0.1, 0.01), np.zeros(10), np.zeros(10)]
    far = line + [0.15, 0.0, 0.0]  # 6 cm gap after the first line
    member = component_nearest(np.concatenate([line, far]), np.array([0.0, 0.0, 0.0]), link=0.012)
    assert member.tolist() == [True] * 10 + [False] * 10
    assert component_nearest(np.zeros((0, 3)), np.zeros(3), 0.01).shape == (0,)


def test_only_the_target_itself_is_mirrored() -> None:
    """A can at the target and a box 6 cm beside it, both within `object_radius`
    on a table: the can's points are mirrored about the target's vertical
    axis, the box's are not (mirrored, they would stand on the can's other side)."""
    table_z = 0.7
    p_WT = np.array([1.0, 0.0, table_z + 0.06])
    can = clouds.can_cloud(center=np.array([1.0, 0.0, table_z]), noise=0.0005, seed=1)
    can = can[can[:, 1] < 0.0]  # the half the camera sees
    box = clouds.box_cloud(center=np.array([1.0, -0.11, table_z]), size=(0.04, 0.04, 0.1), noise=0.0005, seed=2)
    table = clouds.table_top_cloud(z=table_z, center_xy=p_WT[:2], size=0.4)
    mirrored = mirrored_object_points(np.concatenate([can, box, table]), p_WT, MirrorCompletionConfig())
    assert len(mirrored) > 0.8 * len(can[can[:, 2] > table_z + 0.008])
    assert np.all(mirrored[:, 1] > 0.0)  # the can's hidden half, nothing of the box (which would be at y = +0.11)
    assert np.all(np.hypot(*(mirrored[:, :2] - p_WT[:2]).T) < 0.06)


def test_a_table_edge_does_not_join_the_target_to_its_neighbours() -> None:
    """A sphere 7 cm from the table's front edge, a tall thin object 9 cm behind
    it, and the edge's front face seen below the top (as a camera in front of a
    table sees it): the support is the table-top plane, not the face's lowest
    points, so the top does not link the sphere to the tall object and only the
    sphere is mirrored. (With the lowest points as the support, the table top
    joined the component and the tall object's mirror image stood between the
    sphere and the robot.)"""
    table_z, edge_x = 0.76, 1.075
    p_WT = np.array([1.0, 0.0, table_z + 0.027])
    sphere = clouds.sphere_cloud(center=p_WT, radius=0.027, seed=3)
    sphere = sphere[sphere[:, 0] > p_WT[0] - 0.005]  # the half facing the camera at +x
    top = clouds.table_top_cloud(z=table_z, center_xy=(edge_x - 0.2, 0.0), size=0.4, spacing=0.005)
    zs, ys = np.meshgrid(np.arange(table_z - 0.1, table_z, 0.005), np.arange(-0.2, 0.2, 0.005), indexing="ij")
    front = np.c_[np.full(zs.size, edge_x), ys.ravel(), zs.ravel()]
    tall = clouds.box_cloud(center=np.array([0.91, 0.0, table_z]), size=(0.04, 0.04, 0.3), noise=0.0005, seed=4)
    tall = tall[tall[:, 0] > 0.905]
    mirrored = mirrored_object_points(np.concatenate([sphere, top, front, tall]), p_WT, MirrorCompletionConfig())
    assert len(mirrored) > 0.5 * len(sphere)
    assert np.all(np.hypot(*(mirrored[:, :2] - p_WT[:2]).T) < 0.04)  # the sphere's far half, nothing else
    assert np.all(mirrored[:, 2] > table_z)
