"""EpisodeMonitor: the LeafSystem adapter of `EpisodeJudge`."""

from __future__ import annotations

from pydrake.common.value import AbstractValue
from pydrake.geometry import QueryObject
from pydrake.systems.framework import EventStatus, LeafSystem

from vamg_drake.planning.motion_messages import PlannedTrajectory, SubgoalCommand
from vamg_drake.world.episode_monitor import (
    GRASP_INITIATED_PHASES,
    Contact,
    EpisodeJudge,
    EpisodeMonitorConfig,
    EpisodeOutcome,
    PolicyReport,
)
from vamg_drake.world.world_builder import World


class EpisodeMonitor(LeafSystem):
    """Watches the world for collision, success and the time limit.

    Input ports:
        query_object: the scene graph's query object.
        plant_state: the plant's state.
        gripper_command: the commanded opening (closing starts the grasp).
        policy_goal: the SubgoalPolicy's `SubgoalCommand` (optional).
        planner_status: the planner's `PlannedTrajectory` (optional).
    Output ports:
        outcome: `EpisodeOutcome` (AbstractValue).

    When the outcome becomes final, the monitor's `done` event returns
    `EventStatus.ReachedTermination` so `Simulator.AdvanceTo` stops.

    State: the `EpisodeJudge` (its verdict, lift timers and highest lift) is
    the Context's abstract state ``judge``, copied with the Context and reset
    by `Diagram.SetDefaultContext`; the monitor's own plant context is
    scratch that every tick overwrites with the plant's state before use.
    """

    def __init__(self, world: World, time_limit: float, config: EpisodeMonitorConfig | None = None):
        super().__init__()
        self.config = config or EpisodeMonitorConfig()
        self._world = world
        plant = world.plant
        self._plant_context = plant.CreateDefaultContext()
        target = world.scene.target_body
        rest = plant.EvalBodyPoseInWorld(self._plant_context, target).translation()[2]
        self._target = target
        inspector = world.scene_graph.model_inspector()
        self._robot_link: dict = {}
        self._names: dict = {}
        self._owner_is_robot: dict = {}
        self._owner_is_target: dict = {}
        for gid in inspector.GetAllGeometryIds():
            body = plant.GetBodyFromFrameId(inspector.GetFrameId(gid))
            if body is None:
                continue
            self._names[gid] = world.scene.static_geometry_owner.get(gid, body.name())
            self._owner_is_robot[gid] = body.model_instance() == world.robot
            self._owner_is_target[gid] = body.index() == target.index()
        self._query_port = self.DeclareAbstractInputPort("query_object", AbstractValue.Make(QueryObject()))
        self._state_port = self.DeclareVectorInputPort("plant_state", plant.num_multibody_states())
        self._gripper_port = self.DeclareVectorInputPort("gripper_command", 1)
        self._policy_port = self.DeclareAbstractInputPort("policy_goal", AbstractValue.Make(SubgoalCommand.initial()))
        self._planner_port = self.DeclareAbstractInputPort("planner_status", AbstractValue.Make(PlannedTrajectory()))
        self._judge = self.DeclareAbstractState(AbstractValue.Make(EpisodeJudge(rest, time_limit, self.config)))
        self._outcome = self.DeclareAbstractState(AbstractValue.Make(EpisodeOutcome()))
        self._grasp_started = self.DeclareAbstractState(AbstractValue.Make(False))
        self.DeclarePeriodicUnrestrictedUpdateEvent(self.config.period, 0.0, self._tick)
        self.DeclareStateOutputPort("outcome", self._outcome)

    def _report(self, context) -> PolicyReport | None:
        goal = self._policy_port.Eval(context) if self._policy_port.HasValue(context) else None
        if goal is None:
            return None
        plan = self._planner_port.Eval(context) if self._planner_port.HasValue(context) else None
        return PolicyReport(goal.phase.value, goal.failure.value, goal.reason,
                            getattr(plan, "error", "") if plan is not None else "")

    def _tick(self, context, state) -> EventStatus:
        query: QueryObject = self._query_port.Eval(context)
        x = self._state_port.Eval(context)
        opening = float(self._gripper_port.Eval(context)[0])
        report = self._report(context)
        # Grasp initiation: the linear approach from the pre-grasp pose began (or the gripper closes).
        grasp_started = (bool(context.get_abstract_state(self._grasp_started).get_value()) or opening < 0.09
                         or (report is not None and report.phase in GRASP_INITIATED_PHASES))
        plant = self._world.plant
        plant.SetPositionsAndVelocities(self._plant_context, x)
        target_height = plant.EvalBodyPoseInWorld(self._plant_context, self._target).translation()[2]
        contacts = []
        for pair in query.ComputePointPairPenetration():
            a, b = pair.id_A, pair.id_B
            if not (self._owner_is_robot.get(a) or self._owner_is_robot.get(b)):
                continue
            if not self._owner_is_robot.get(a):
                a, b = b, a
            contacts.append(
                Contact(
                    robot_link=self._names[a],
                    other=self._names.get(b, "?"),
                    other_is_target=bool(self._owner_is_target.get(b)),
                    other_is_robot=bool(self._owner_is_robot.get(b)),
                    depth=pair.depth,
                )
            )
        judge: EpisodeJudge = state.get_mutable_abstract_state(self._judge).get_mutable_value()
        outcome = judge.update(context.get_time(), contacts, target_height, grasp_started, report)
        state.get_mutable_abstract_state(self._outcome).set_value(outcome)
        state.get_mutable_abstract_state(self._grasp_started).set_value(grasp_started)
        if outcome.done:
            return EventStatus.ReachedTermination(self, f"episode ended: {outcome.status} ({outcome.detail})")
        return EventStatus.Succeeded()
