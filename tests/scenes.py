"""Small hand-built scenarios for tests (the generator has its own tests)."""

from __future__ import annotations

from vamg_drake.world.scenario import (
    AppearAtDistance,
    Box,
    Cylinder,
    Furniture,
    Part,
    PlacedObject,
    PlanarPose,
    Room,
    Scenario,
)


def table(name: str, x: float, y: float, height: float = 0.75, size=(0.8, 1.2)) -> Furniture:
    top = 0.04
    legs = [
        Part(f"leg{i}", Box([0.05, 0.05, height - top]), [sx * (size[0] / 2 - 0.05), sy * (size[1] / 2 - 0.05), (height - top) / 2])
        for i, (sx, sy) in enumerate([(1, 1), (1, -1), (-1, 1), (-1, -1)])
    ]
    return Furniture(
        name=name,
        kind="table",
        pose=PlanarPose(x, y, 0.0),
        parts=[Part("top", Box([size[0], size[1], top]), [0, 0, height - top / 2], support=True)] + legs,
    )


def box_room_scenario(with_pedestrian: bool = False, time_limit: float = 30.0) -> Scenario:
    """A 6 m x 5 m room, a table at x = 2 with a soup can on it, robot at x = -1.5."""
    events = []
    if with_pedestrian:
        events.append(AppearAtDistance(name="pedestrian", shape=Cylinder(0.3, 1.7), xyz=[0.5, 0.0, 0.85], trigger_distance=1.7))
    return Scenario(
        name="box_room",
        seed=0,
        room=Room(outline=[[-3, -2.5], [3, -2.5], [3, 2.5], [-3, 2.5]]),
        furniture=[table("table_0", 2.0, 0.0)],
        objects=[PlacedObject("tomato_soup_can", [2.0, 0.0, 0.80], [0, 0, 0], "table_0/top", 0.75)],
        target="tomato_soup_can",
        robot_start=PlanarPose(-1.5, 0.0, 0.0),
        dynamic_events=events,
        time_limit=time_limit,
    )
