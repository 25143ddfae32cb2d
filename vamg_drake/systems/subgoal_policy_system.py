"""SubgoalPolicy: the LeafSystem adapter over `vamg_drake.policy.behaviour_tree`."""

import dataclasses as dc
import logging

import numpy as np
from pydrake.common.value import AbstractValue
from pydrake.systems.framework import BasicVector, EventStatus, LeafSystem

from vamg_drake.perception.raycast_map import PointMapSnapshot
from vamg_drake.planning.motion_messages import MotionEvent, MotionFeedback, SubgoalCommand, stage_name
from vamg_drake.planning.sphere_collision import CollisionCheckerConfig
from vamg_drake.policy.behaviour_tree import BehaviourConfig, BehaviourState, PolicyInputs, SubgoalBehaviour
from vamg_drake.policy.kinematic_maps import KinematicMaps
from vamg_drake.policy.strategies import BEHAVIOURS, StrategyConfig, make_strategy
from vamg_drake.policy.subgoal_pipeline import SubgoalPipeline, SubgoalPipelineConfig
from vamg_drake.robot import layout
from vamg_drake.robot.head_camera import HeadCameraConfig

_log = logging.getLogger(__name__)


@dc.dataclass
class SubgoalPolicyConfig:
    """Parameters of the SubgoalPolicy system."""

    #: Update period [s].
    period: float = 0.1
    #: The policy holds still until this time, so its first goal sees a map
    #: built from a few depth frames rather than an empty one [s].
    start_delay: float = 0.0
    #: Without a motion_feedback input, a goal counts as reached when every joint
    #: of q is within this distance of it [m or rad].
    reach_tolerance: float = 0.03


class SubgoalPolicy(LeafSystem):
    """The subgoal policy pi_g: picks the goal g_t with the behaviour tree.

    .. pydrake_system::

        name: SubgoalPolicy
        input_ports:
        - point_map (PointMapSnapshot or None)
        - robot_configuration (11-vector q)
        - target (3-vector p_WT)
        - motion_feedback (MotionFeedback, optional)
        - target_cloud ((N, 3) array p_WS, optional: a dense cloud around the target for grasp candidates)
        - gripper_opening (1-vector: the measured finger gap [m], optional: without it a grasp is never retried)
        output_ports:
        - goal (SubgoalCommand)
        - phase (str: "grasp" | "pre_grasp" | "observe" | "idle" | "succeeded" | "failed")
        - gripper_command (1-vector: finger gap [m])
        - history (tuple of (time, phase, reason): the behaviour's transitions)

    State: the behaviour's `BehaviourState` (phase, goals, failure counts,
    history, the samplers' random generators) is the Context's abstract state
    ``behaviour``, advanced by `SubgoalBehaviour.step` in the periodic event;
    the ``behaviour`` object is the fixed structure (samplers, tree), so one
    built system runs in any number of Contexts. `behaviour_state` and
    `tree_status` inspect a Context for tests and logs. Without a
    connected ``motion_feedback``, a goal is reached when q is within
    ``reach_tolerance`` of it; motion failures then need the feedback port.
    A sampler that raises ends the policy as FAILED with category ERROR (its
    traceback as the reason; the episode's status is ``error``); bad input is
    logged and the robot holds. It never raises inside an episode.
    """

    def __init__(self, behaviour: SubgoalBehaviour, config: SubgoalPolicyConfig | None = None) -> None:
        super().__init__()
        self._behaviour = behaviour
        self._config = config or SubgoalPolicyConfig()
        self._map_port = self.DeclareAbstractInputPort("point_map", AbstractValue.Make(PointMapSnapshot.empty()))
        self._q_port = self.DeclareVectorInputPort("robot_configuration", layout.NQ)
        self._target_port = self.DeclareVectorInputPort("target", 3)
        self._feedback_port = self.DeclareAbstractInputPort("motion_feedback", AbstractValue.Make(MotionFeedback()))
        self._cloud_port = self.DeclareAbstractInputPort("target_cloud", AbstractValue.Make(np.zeros((0, 3))))
        self._opening_port = self.DeclareVectorInputPort("gripper_opening", 1)
        self._command_index = self.DeclareAbstractState(AbstractValue.Make(SubgoalCommand.initial()))
        self._handled_index = self.DeclareAbstractState(AbstractValue.Make(MotionFeedback()))
        self._gripper_index = self.DeclareDiscreteState(BasicVector([layout.GRIPPER_MAX_OPENING]))
        self._behaviour_index = self.DeclareAbstractState(AbstractValue.Make(behaviour.initial_state()))
        self.DeclareStateOutputPort("goal", self._command_index)
        self.DeclareAbstractOutputPort(
            "phase", lambda: AbstractValue.Make(""), self._calc_phase, {self.abstract_state_ticket(self._command_index)}
        )
        self.DeclareStateOutputPort("gripper_command", self._gripper_index)
        self.DeclareAbstractOutputPort(
            "history", lambda: AbstractValue.Make(()),
            lambda context, value: value.set_value(self.behaviour_state(context).history),
            {self.abstract_state_ticket(self._behaviour_index)})
        self.DeclarePeriodicUnrestrictedUpdateEvent(self._config.period, 0.0, self._update)

    @property
    def behaviour(self) -> SubgoalBehaviour:
        """The behaviour's fixed structure (its state is in the Context)."""
        return self._behaviour

    def behaviour_state(self, context) -> BehaviourState:
        """The behaviour's state in this system's `context`."""
        return context.get_abstract_state(self._behaviour_index).get_value()

    def tree_status(self, context) -> str:
        """The behaviour's progress in `context` (for a tree: its last tick) as text."""
        return self._behaviour.tree_status(self.behaviour_state(context))

    def _calc_phase(self, context, value: AbstractValue) -> None:
        value.set_value(stage_name(context.get_abstract_state(self._command_index).get_value().phase))

    def _event(self, context, q: np.ndarray, command: SubgoalCommand, state) -> MotionEvent:
        if self._feedback_port.HasValue(context):
            feedback: MotionFeedback = self._feedback_port.Eval(context)
            handled: MotionFeedback = context.get_abstract_state(self._handled_index).get_value()
            if feedback.goal_id == command.goal_id and feedback.event != MotionEvent.NONE and feedback != handled:
                state.get_mutable_abstract_state(self._handled_index).set_value(feedback)
                return feedback.event
            return MotionEvent.NONE
        moving = command.motion in ("plan", "linear")
        if moving and np.all(np.abs(layout.wrap_configuration(q - command.q_goal)) <= self._config.reach_tolerance):
            return MotionEvent.REACHED
        return MotionEvent.NONE

    def _update(self, context, state) -> EventStatus:
        command: SubgoalCommand = context.get_abstract_state(self._command_index).get_value()
        q = np.asarray(self._q_port.Eval(context), dtype=float)
        if not np.all(np.isfinite(q)):
            _log.error("SubgoalPolicy: robot_configuration is not finite (%s); holding", q)
            return EventStatus.Succeeded()
        snapshot = self._map_port.Eval(context) if self._map_port.HasValue(context) else None
        p_WM = np.zeros((0, 3)) if snapshot is None else np.asarray(snapshot.points, dtype=float)
        target = np.asarray(self._target_port.Eval(context), dtype=float)
        cloud = np.asarray(self._cloud_port.Eval(context), dtype=float) if self._cloud_port.HasValue(context) else None
        if context.get_time() < self._config.start_delay - 1e-9:
            return EventStatus.Succeeded()
        opening = float(self._opening_port.Eval(context)[0]) if self._opening_port.HasValue(context) else None
        inputs = PolicyInputs(context.get_time(), q, p_WM, target, cloud, opening)
        event = self._event(context, q, command, state)
        behaviour, new_command = self._behaviour.step(self.behaviour_state(context), inputs, event)
        state.get_mutable_abstract_state(self._behaviour_index).set_value(behaviour)
        if new_command.goal_id != command.goal_id or new_command.phase != command.phase:
            _log.info("SubgoalPolicy t=%.2f: %s (%s)", context.get_time(), new_command.phase.value, new_command.reason)
            skipped = {stage: reason for stage, (reason, _) in behaviour.stage_failures.items()}
            if skipped:
                _log.info("SubgoalPolicy t=%.2f: stage failures so far: %s", context.get_time(), skipped)
        state.get_mutable_abstract_state(self._command_index).set_value(new_command)
        state.get_mutable_discrete_state(self._gripper_index).set_value([new_command.gripper_opening])
        return EventStatus.Succeeded()


def make_subgoal_policy(
    camera: HeadCameraConfig,
    max_depth: float,
    pipeline_config: SubgoalPipelineConfig | None = None,
    behaviour_config: BehaviourConfig | None = None,
    config: SubgoalPolicyConfig | None = None,
    maps: KinematicMaps | None = None,
    seed: int = 0,
    timings=None,
    strategy: str = "subgoal_tree",
    strategy_config: StrategyConfig | None = None,
    collision: CollisionCheckerConfig | None = None,
) -> SubgoalPolicy:
    """The SubgoalPolicy over the real samplers (kinematic maps built on first use).

    ``camera`` is the world's head camera, ``max_depth`` the map's depth range
    (`DepthToPointsConfig.depth_max`) and ``collision`` the planner's
    collision check parameters (see `SubgoalPipeline`). ``strategy`` picks the behaviour (`vamg_drake.policy.strategies.BEHAVIOURS`:
    the full system's subgoal tree or a baseline). ``timings`` (a
    `ModuleTimings`) collects the samplers' and the grasp candidates' costs.

    Raises:
        ValueError: an unknown strategy.
    """
    if strategy not in BEHAVIOURS:
        raise ValueError(f"make_subgoal_policy: unknown strategy '{strategy}' (known: {', '.join(BEHAVIOURS)})")
    pipeline = SubgoalPipeline(maps or KinematicMaps.load_or_build(), camera, max_depth, config=pipeline_config,
                               seed=seed, timings=timings, collision=collision,
                               lift_height=(behaviour_config or BehaviourConfig()).lift_height)
    return SubgoalPolicy(make_strategy(strategy, pipeline, behaviour_config, strategy_config), config)
