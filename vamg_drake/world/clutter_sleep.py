"""Resting clutter away from the target sleeps: the episode's biggest physics saving.

An apartment task holds 20 YCB objects resting on furniture made of hundreds
of convex pieces; their compliant-hydroelastic contact with those pieces is
most of the plant's cost, although the objects away from the target never
move. Point contact is no substitute: with one contact point per pair,
resting objects rock, and one rolled off its table within 10 s.

Every object whose hull stays farther than ``awake_gap`` from the target's
is built asleep (``sleeping_objects`` decides, ``scene_geometry.add_scene``
builds; the gap is measured between the objects' bounding spheres, so a
hammer beside a golf ball stays awake where two golf balls as far apart
sleep): instead
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

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from vamg_drake.world.ycb import load_ycb_asset


@dataclass
class ClutterSleepConfig:
    """Attributes:
        enabled: build clutter away from the target asleep.
        awake_gap: objects whose bounding sphere comes within this distance
            [m] of the target's stay awake. The open fingers reach about
            6 cm beyond the target's surface and come in along a 10 cm
            approach; the palm and the rest of the arm touching any object
            ends the episode anyway. The lifted target rises 10-15 cm,
            clear of objects beside it.
    """

    enabled: bool = True
    awake_gap: float = 0.2


def sleeping_objects(scenario, config: ClutterSleepConfig | None = None,
                     bounding_radius: Callable[[str], float] | None = None) -> list[str]:
    """Names of the scenario's objects (never the target) that are built asleep.

    ``bounding_radius(model)`` is the radius [m] of a model's bounding sphere
    about its frame O (default: the converted YCB hull's,
    `YcbAsset.bounding_radius`)."""
    config = config or ClutterSleepConfig()
    if not config.enabled:
        return []
    radius = bounding_radius or (lambda model: load_ycb_asset(model).bounding_radius)
    target = next(o for o in scenario.objects if o.name == scenario.target)
    p_WT, r_T = np.asarray(target.xyz, dtype=float), radius(target.model or target.name)
    return sorted(
        o.name for o in scenario.objects
        if o.name != scenario.target
        and np.linalg.norm(np.asarray(o.xyz, dtype=float) - p_WT) - r_T - radius(o.model or o.name) > config.awake_gap
    )
