"""Resting clutter sleeps until the robot comes near: the episode's biggest physics saving.

An apartment task holds 20 YCB objects resting on furniture made of hundreds
of convex pieces; their compliant-hydroelastic contact with those pieces is
most of the plant's cost (3.4x the stepping time of point contact on a paper
task), although the objects far from the robot never move. Point contact is
no substitute: with one contact point per pair, resting objects rock, and one
rolled off its table within 10 s.

``ClutterSleep`` keeps every object other than the target asleep: its free
joint is locked (it cannot move) and a transient collision filter removes
its contact with the welded scene (no contact surface is computed), while
contact with the robot, the target, obstacles and other objects stays. An
object wakes for good (unlocked, filter removed) when any robot body origin
comes within ``wake_distance`` of its centroid, before the robot can reach it.
Sleeping objects are exactly where they were settled, so the episode sees
the same scene; only contacts that would not move anything are skipped.

The runner (``vamg_drake.episode``) calls ``update`` between its simulation
chunks; a plain ``Simulator.AdvanceTo`` without it simulates every object
awake (``wake_all`` restores that on a used context).
"""


from dataclasses import dataclass

import numpy as np
from pydrake.geometry import CollisionFilterDeclaration, GeometrySet


@dataclass
class ClutterSleepConfig:
    """Attributes:
        enabled: let the episode runner put clutter to sleep.
        wake_distance: an object wakes when a robot body origin comes this
            close to its centroid [m] (the gripper reaches about 0.25 m past
            its wrist origin; the runner checks every 0.1 s, in which the
            base moves at most 0.15 m).
    """

    enabled: bool = True
    wake_distance: float = 0.8


class ClutterSleep:
    """Locks and filters the non-target objects of a built world in one root context."""

    def __init__(self, world, config: ClutterSleepConfig | None = None):
        self._config = config or ClutterSleepConfig()
        self._plant = world.plant
        self._scene_graph = world.scene_graph
        plant = world.plant
        target = world.scene.target_body
        self._bodies = {name: body for name, body in world.scene.object_bodies.items() if body.index() != target.index()}
        welded = plant.GetBodiesWeldedTo(plant.world_body())
        static_ids = [g for body in welded for g in plant.GetCollisionGeometriesForBody(body)]
        self._static = GeometrySet(static_ids)
        self._robot_bodies = [plant.get_body(i) for i in plant.GetBodyIndices(world.robot)]
        self._filters: dict[str, object] = {}

    @property
    def asleep(self) -> list[str]:
        """Names of the objects asleep now."""
        return sorted(self._filters)

    def sleep_all(self, root_context) -> None:
        """Puts every non-target object to sleep (call after ``Simulator.Initialize``)."""
        if not self._config.enabled:
            return
        plant_context = self._plant.GetMyMutableContextFromRoot(root_context)
        manager = self._scene_graph.collision_filter_manager(self._scene_graph.GetMyMutableContextFromRoot(root_context))
        for name, body in self._bodies.items():
            if name in self._filters:
                continue
            body.Lock(plant_context)
            ids = GeometrySet(self._plant.GetCollisionGeometriesForBody(body))
            self._filters[name] = manager.ApplyTransient(CollisionFilterDeclaration().ExcludeBetween(ids, self._static))

    def update(self, root_context) -> list[str]:
        """Wakes the sleeping objects near the robot; returns their names."""
        if not self._filters:
            return []
        plant_context = self._plant.GetMyMutableContextFromRoot(root_context)
        p_W_robot = np.array([self._plant.EvalBodyPoseInWorld(plant_context, b).translation() for b in self._robot_bodies])
        woken = []
        for name in list(self._filters):
            p = self._plant.EvalBodyPoseInWorld(plant_context, self._bodies[name]).translation()
            if np.min(np.linalg.norm(p_W_robot - p, axis=1)) <= self._config.wake_distance:
                woken.append(name)
        self._wake(root_context, woken)
        return woken

    def wake_all(self, root_context) -> None:
        """Wakes every sleeping object."""
        self._wake(root_context, list(self._filters))

    def _wake(self, root_context, names: list[str]) -> None:
        if not names:
            return
        plant_context = self._plant.GetMyMutableContextFromRoot(root_context)
        manager = self._scene_graph.collision_filter_manager(self._scene_graph.GetMyMutableContextFromRoot(root_context))
        for name in names:
            manager.RemoveDeclaration(self._filters.pop(name))
            self._bodies[name].Unlock(plant_context)
