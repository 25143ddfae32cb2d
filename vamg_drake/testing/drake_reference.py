"""Drake's exact geometry as the ground truth (and the reference planner's
validity check) for whole-body configurations.

A `MultibodyPlant` with the Fetch URDF (primitive collision geometry) and the
world boxes/cylinders welded to the world; a configuration collides when
`SceneGraph`'s point-pair penetration query reports a robot-vs-world pair, or
a robot-vs-robot pair between links the sphere model tests for
self-collision (Drake's URDF parser filters only parent-child pairs, and
siblings such as the torso links overlap by design).
"""

from __future__ import annotations

import numpy as np
from pydrake.geometry import Box, Cylinder, SceneGraph
from pydrake.math import RigidTransform, RotationMatrix
from pydrake.multibody.parsing import Parser
from pydrake.multibody.plant import CoulombFriction, MultibodyPlant
from pydrake.systems.framework import DiagramBuilder

from vamg_drake.robot import layout
from vamg_drake.robot.kinematics import DEFAULT_FINGER, fetch_urdf_path
from vamg_drake.robot.spheres import SphereModel
from vamg_drake.world.primitives import WorldBox, WorldCylinder


class DrakeCollisionWorld:
    """Exact collision queries for the Fetch among world primitives.

    Args:
        obstacles: `vamg_drake.world.primitives` boxes/cylinders (floor-level
            slabs with top below `min_top_z` are skipped like the planner does).
        self_collision_links: pairs of link names to test for self-collision
            (default: those of the sphere model).
    """

    def __init__(self, obstacles, self_collision_links: set[tuple[str, str]] | None = None,
                 min_top_z: float = 0.01):
        builder = DiagramBuilder()
        plant = MultibodyPlant(0.0)
        scene_graph = SceneGraph()
        plant.RegisterAsSourceForSceneGraph(scene_graph)
        builder.AddSystem(plant)
        builder.AddSystem(scene_graph)
        builder.Connect(plant.get_geometry_pose_output_port(), scene_graph.get_source_pose_port(plant.get_source_id()))
        builder.Connect(scene_graph.get_query_output_port(), plant.get_geometry_query_input_port())
        Parser(plant).AddModels(str(fetch_urdf_path()))
        world = plant.world_body()
        friction = CoulombFriction(0.5, 0.5)
        self._world_geoms = set()
        for k, prim in enumerate(obstacles):
            if isinstance(prim, WorldBox):
                if prim.z_range()[1] <= min_top_z:
                    continue
                X = RigidTransform(RotationMatrix(prim.R_WB), prim.p_WB)
                shape = Box(*(2.0 * np.asarray(prim.half_extents)))
            elif isinstance(prim, WorldCylinder):
                X = RigidTransform(RotationMatrix(prim.R_WC), prim.p_WC)
                shape = Cylinder(prim.radius, prim.length)
            else:
                raise TypeError(f"obstacle {k}: unsupported primitive {type(prim).__name__}")
            self._world_geoms.add(plant.RegisterCollisionGeometry(world, X, shape, f"obstacle_{k}", friction))
        plant.Finalize()
        self.plant = plant
        self.diagram = builder.Build()
        self.context = self.diagram.CreateDefaultContext()
        self.plant_context = plant.GetMyContextFromRoot(self.context)
        self.inspector = scene_graph.model_inspector()
        # Map q (11,) into the plant's positions.
        names = list(layout.WHOLE_BODY_JOINTS)
        self._q_index = np.array([plant.GetJointByName(n).position_start() for n in names])
        self._q0 = plant.GetPositions(self.plant_context).copy()
        for n in layout.FINGER_JOINTS:
            self._q0[plant.GetJointByName(n).position_start()] = DEFAULT_FINGER
        if self_collision_links is None:
            self_collision_links = _sphere_model_link_pairs()
        self._self_pairs = {tuple(sorted(p)) for p in self_collision_links}
        self._body_name = {}
        self._scene_graph = scene_graph

    def _body_of(self, geometry_id) -> str | None:
        if geometry_id in self._world_geoms:
            return None
        name = self._body_name.get(geometry_id)
        if name is None:
            frame = self.inspector.GetFrameId(geometry_id)
            name = self.plant.GetBodyFromFrameId(frame).name()
            self._body_name[geometry_id] = name
        return name

    def set_configuration(self, q: np.ndarray) -> None:
        x = self._q0.copy()
        x[self._q_index] = q
        self.plant.SetPositions(self.plant_context, x)

    def in_collision(self, q: np.ndarray) -> bool:
        """True when q (11,) penetrates the world or itself (tested link pairs)."""
        self.set_configuration(q)
        query = self.plant.get_geometry_query_input_port().Eval(self.plant_context)
        for pair in query.ComputePointPairPenetration():
            a, b = self._body_of(pair.id_A), self._body_of(pair.id_B)
            if a is None or b is None:
                if a is None and b is None:
                    continue
                return True
            if tuple(sorted((a, b))) in self._self_pairs:
                return True
        return False

    def is_valid(self, q: np.ndarray) -> bool:
        """Within joint limits and collision-free."""
        q = np.asarray(q, float)
        return bool(np.all(np.isfinite(q)) and layout.within_limits(q)) and not self.in_collision(q)


def _sphere_model_link_pairs() -> set[tuple[str, str]]:
    m = SphereModel.load()
    names = m.link_names
    li = m.link_index
    pairs = {(names[li[a]], names[li[b]]) for a, b in m.self_collision_pairs}
    for prim in getattr(m, "body_primitives", ()):
        for s in prim.spheres:
            pairs.add((names[prim.link_index], names[li[s]]))
    return {tuple(sorted(p)) for p in pairs if p[0] != p[1]}
