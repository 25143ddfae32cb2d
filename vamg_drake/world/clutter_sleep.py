"""Resting clutter away from the target sleeps: the episode's biggest physics saving.

An apartment task holds 20 YCB objects resting on furniture made of hundreds
of convex pieces; their compliant-hydroelastic contact with those pieces is
most of the plant's cost (3.4x the stepping time of point contact on a paper
task), although the objects away from the target never move. Point contact
is no substitute: with one contact point per pair, resting objects rock, and
one rolled off its table within 10 s.

``ClutterSleep.sleep`` puts every object farther than ``awake_radius`` from
the target to sleep for the whole episode: its free joint is locked (it
cannot move) and a collision filter removes its contact with the welded
scene (no contact surface is computed). Its contact with the robot, the
target, the obstacles and the other objects stays, so the episode monitor
still sees the robot touch it, which ends the episode as a collision (a
non-finger link) as it would if the object were free. Objects near the target,
which the fingers or the lifted target may touch, stay awake.

Sleeping objects are exactly where they were settled, so the robot sees the
same scene. They never wake: in an apartment, unlocking an object and
removing its filter together made the next steps non-finite (measured on
paper task 3), so the radius decides once.

The runner (``vamg_drake.episode``) calls ``sleep`` after
``Simulator.Initialize``; a plain ``Simulator.AdvanceTo`` without it
simulates every object awake.
"""

from dataclasses import dataclass

import numpy as np
from pydrake.geometry import CollisionFilterDeclaration, GeometrySet


@dataclass
class ClutterSleepConfig:
    """Attributes:
        enabled: let the episode runner put clutter to sleep.
        awake_radius: objects whose centroid lies within this distance [m]
            of the target's stay awake (the fingers open 10 cm around it
            and the target is lifted 10-15 cm).
    """

    enabled: bool = True
    awake_radius: float = 0.5


class ClutterSleep:
    """Locks and filters the non-target objects of a built world that lie away from the target."""

    def __init__(self, world, config: ClutterSleepConfig | None = None):
        self._config = config or ClutterSleepConfig()
        self._plant = world.plant
        self._scene_graph = world.scene_graph
        self._target = world.scene.target_body
        self._bodies = {name: body for name, body in world.scene.object_bodies.items() if body.index() != self._target.index()}
        welded = self._plant.GetBodiesWeldedTo(self._plant.world_body())
        self._static = GeometrySet([g for body in welded for g in self._plant.GetCollisionGeometriesForBody(body)])
        self._asleep: list[str] = []

    @property
    def asleep(self) -> list[str]:
        """Names of the sleeping objects."""
        return sorted(self._asleep)

    def sleep(self, root_context) -> list[str]:
        """Puts the objects away from the target to sleep (after ``Simulator.Initialize``); returns their names."""
        if not self._config.enabled:
            return []
        plant_context = self._plant.GetMyMutableContextFromRoot(root_context)
        p_WT = self._plant.EvalBodyPoseInWorld(plant_context, self._target).translation()
        manager = self._scene_graph.collision_filter_manager(self._scene_graph.GetMyMutableContextFromRoot(root_context))
        for name, body in self._bodies.items():
            if name in self._asleep:
                continue
            p_WO = self._plant.EvalBodyPoseInWorld(plant_context, body).translation()
            if np.linalg.norm(p_WO - p_WT) <= self._config.awake_radius:
                continue
            body.Lock(plant_context)
            ids = GeometrySet(self._plant.GetCollisionGeometriesForBody(body))
            manager.Apply(CollisionFilterDeclaration().ExcludeBetween(ids, self._static))
            self._asleep.append(name)
        return self.asleep
