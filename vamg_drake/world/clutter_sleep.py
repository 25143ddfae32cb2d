"""Resting clutter away from the target sleeps: the episode's biggest physics saving.

An apartment task holds 20 YCB objects resting on furniture made of hundreds
of convex pieces; their compliant-hydroelastic contact with those pieces is
most of the plant's cost, although the objects away from the target never
move. Point contact is no substitute: with one contact point per pair,
resting objects rock, and one rolled off its table within 10 s.

Every object farther than ``awake_radius`` from the target is built asleep
(``sleeping_objects`` decides, ``scene_geometry.add_scene`` builds): instead
of a free body it is anchored geometry on the world body at its settled pose.
It cannot move, SceneGraph never pairs it with the (also anchored) furniture,
floor or other sleeping objects, and its contact with the robot, the target,
the obstacles and the awake objects stays, so the episode monitor still sees
the robot touch it, which ends the episode as a collision (a non-finger link)
as it would if the object were free. Objects near the target, which the
fingers or the lifted target may touch, stay awake as free bodies.

Sleeping objects are exactly where the scenario puts them (the settled
poses), so the robot sees the same scene. The decision is part of the built
diagram: every Context of it, and ``Simulator.Initialize`` again, simulates
the same world.
"""

from dataclasses import dataclass

import numpy as np


@dataclass
class ClutterSleepConfig:
    """Attributes:
        enabled: build clutter away from the target asleep.
        awake_radius: objects whose centroid lies within this distance [m]
            of the target's stay awake (the fingers open 10 cm around it
            and the target is lifted 10-15 cm).
    """

    enabled: bool = True
    awake_radius: float = 0.5


def sleeping_objects(scenario, config: ClutterSleepConfig | None = None) -> list[str]:
    """Names of the scenario's objects (never the target) that are built asleep."""
    config = config or ClutterSleepConfig()
    if not config.enabled:
        return []
    p_WT = np.asarray(next(o.xyz for o in scenario.objects if o.name == scenario.target), dtype=float)
    return sorted(
        o.name for o in scenario.objects
        if o.name != scenario.target and np.linalg.norm(np.asarray(o.xyz, dtype=float) - p_WT) > config.awake_radius
    )
