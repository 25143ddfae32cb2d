"""The paper's baselines and system-level comparisons as subgoal strategies.

Every method of the paper shares the world, the map, the whole-body planner,
the tracker and the gaze optimizer; they differ in how the subgoals are chosen
(``DiagramConfig.strategy``) and in a few system settings that each
method's YAML file states (``vamg_drake/bench/methods/``). Each strategy is a behaviour
with the interface of `SubgoalBehaviour` (``initial_state``, ``step(state,
inputs, event) -> (state, command)``; its progress is in the
`BehaviourState`) and reuses its grasp execution (GRASP_MOVE planned to
the pre-grasp pose -> GRASP_APPROACH linear -> GRASP_CLOSE -> (GRASP_PULL) -> GRASP_LIFT, and
GRASP_RETREAT from a grasp that closed on nothing) and its command building. Only the choice
of goals differs; no py_trees tree is ticked.

Strategies (paper "Baselines" and appendix "System-Level Comparisons"):

* ``subgoal_tree`` -- the full system, `SubgoalBehaviour` itself.
* ``direct_grasping`` -- a fixed sequence observe -> navigate (whole-body
  pre-grasp) -> grasp. Each stage's goal is sampled once: no adaptive goal
  resampling. The planner still replans the path to the same goal when the
  map invalidates it; a goal the map has put in collision, a motion failure or
  a failed sample ends the episode. No gaze optimization (the gaze looks at
  the target only: ``gaze.variant: target_only`` in its method file).
* ``nav_and_manip`` -- navigation and manipulation decoupled: drive with the
  arm stowed to a base pose at a fixed distance from the target
  (``StrategyConfig.nav_standoff``), facing it, collision-free and seeing it in
  the current map; closed loop (the planner replans on invalidation), the base
  pose resampled after a failed drive (a pose that failed is not proposed
  again). From the reached base, arm-only planning to a grasp (Algorithm 1,
  base and torso fixed); no grasp from there ends the episode with the grasp
  sampler's category (no base repositioning), a failed arm motion resamples the
  grasp from the same base (at most ``max_motion_failures`` times).
* ``capmap_placement`` -- like ``nav_and_manip``, but the base pose is the base
  part of the pre-grasp sampler's whole-body configuration (capability map,
  torso map, IK, collision; paper Algorithm 3). The arm is stowed while
  driving; the torso keeps the sampled height (``capmap_keep_torso``) because
  the sampled reachability holds for that height only.
* ``closed_loop_replanning`` -- no stages: sample the whole-body pre-grasp
  configuration and replan continuously towards it (the planner's
  ``replan_period``, 1 s in its method file, which says why) until it is
  reached, then grasp from there. A failed motion, a pre-grasp
  the map has put in collision, or no grasp from the reached pre-grasp
  resamples the pre-grasp (at most ``max_pregrasp_goals`` samples;
  invalidations do not count).

For every strategy the navigation goal runs in the PREGRASP phase (the phase
the scenario's table-top obstacles key on) and the observe goal in OBSERVE.

Failure categories come from what happened: a sampler's own category when a
sample ends the episode (PERCEPTION, REACHABILITY, IK, SUBGOAL), PLANNING
after motion failures (including the ``max_total_failures`` and
``max_invalidations`` limits of `BehaviourConfig`), SUBGOAL when a goal budget
is used up by samples that could not be reached.
"""

import dataclasses as dc
import time
import traceback
from typing import Callable

import numpy as np

from vamg_drake.policy.behaviour_tree import (
    GRASP_PHASES,
    BehaviourConfig,
    BehaviourState,
    FailureCategory,
    Phase,
    PolicyInputs,
    SamplerFn,
    SamplerMemory,
    Stage,
    SubgoalBehaviour,
    SubgoalProposal,
    SubgoalSamplers,
)
from vamg_drake.policy.observe_sampler import ObserveConfig, ObserveSampler
from vamg_drake.policy.subgoal_pipeline import SubgoalPipeline
from vamg_drake.robot import layout


#: Goal validity under the current map: (inputs, q_goal (11,)) -> collision-free?
GoalCheckFn = Callable[[PolicyInputs, np.ndarray], bool]


@dc.dataclass
class StrategyConfig:
    """Parameters of the baseline strategies (the budgets are `BehaviourConfig`'s).

    Attributes:
        nav_standoff: nav_and_manip's base-to-target distances [m], tried in
            order: the first is the fixed distance, the others are fallbacks
            when no base pose at it is navigable.
        nav_num_angles: base poses tried on each standoff circle.
        avoid_radius: a navigation goal within this distance of one whose
            motion failed is not proposed again [m].
        capmap_keep_torso: capmap_placement drives with the sampled torso height,
            at least the stowed one (else the stowed torso).
        capmap_tries: pre-grasp samples tried for a base whose stowed
            configuration is collision-free.
        grasp_patience: nav_and_manip and capmap_placement keep sampling grasps
            from the reached base for this long while the head looks at the
            target, before a failed sample ends the episode: on arrival the
            map has seen the target from afar only, and its sparse, noisy
            points can put every IK-valid ranked grasp in collision until
            closer views arrive [s].
        max_same_goal_replans: an invalidated goal that the samplers still call
            free is replanned this many times in a row, then resampled: the
            planner's check is the stricter one, and replanning the same goal
            without limit can spend the whole invalidation budget on a goal
            the planner keeps calling "in collision".
    """

    nav_standoff: list[float] = dc.field(default_factory=lambda: [0.8, 0.7, 0.9])
    nav_num_angles: int = 36
    avoid_radius: float = 0.15
    capmap_keep_torso: bool = True
    capmap_tries: int = 3
    grasp_patience: float = 2.0
    max_same_goal_replans: int = 1

    def __post_init__(self) -> None:
        self.validate()

    def validate(self) -> None:
        """Raises ValueError naming the bad field."""
        if not self.nav_standoff or min(self.nav_standoff) <= 0:
            raise ValueError(f"StrategyConfig.nav_standoff must be positive distances, got {self.nav_standoff}")
        for name in ("nav_num_angles", "capmap_tries"):
            if getattr(self, name) < 1:
                raise ValueError(f"StrategyConfig.{name} must be >= 1, got {getattr(self, name)}")
        if self.max_same_goal_replans < 0:
            raise ValueError(f"StrategyConfig.max_same_goal_replans must be >= 0, got {self.max_same_goal_replans}")
        if self.grasp_patience < 0:
            raise ValueError(f"StrategyConfig.grasp_patience must be >= 0, got {self.grasp_patience}")
        if self.avoid_radius < 0:
            raise ValueError(f"StrategyConfig.avoid_radius must be >= 0, got {self.avoid_radius}")


@dc.dataclass
class StrategySamplers:
    """The goal generators a strategy uses.

    Attributes:
        grasp: grasp goal from the current base (Algorithm 1, base and torso fixed).
        navigate: the navigation goal: the whole-body pre-grasp (direct grasping,
            closed-loop replanning) or a stowed-arm base pose (nav_and_manip,
            capmap_placement).
        observe: the observe goal (direct grasping).
        goal_is_free: whether a goal is still collision-free in the current map
            (None: an invalidated goal is always treated as in collision).
        reject: tells ``navigate`` that the motion to this goal failed, so it
            proposes another (None: the sampler is random enough by itself).
        memory: the samplers' objects that remember something between calls
            (`SamplerMemory`: a random generator, the rejected goals).
    """

    grasp: SamplerFn
    navigate: SamplerFn
    observe: SamplerFn
    goal_is_free: GoalCheckFn | None = None
    reject: Callable[[np.ndarray], None] | None = None
    memory: tuple[SamplerMemory, ...] = ()


class StrategyBehaviour(SubgoalBehaviour):
    """A fixed sequence of stages over the `SubgoalBehaviour` grasp execution.

    Subclasses set ``STAGES`` and decide, per stage, what a failed sample, a
    failed motion and an invalid goal lead to.

    Args:
        samplers: the goal generators.
        config: budgets and grasp execution parameters.
    """

    NAME = ""
    STAGES: tuple[Stage, ...] = ()
    #: What the navigate sampler proposes (for logs).
    NAVIGATION_GOAL = "whole-body pre-grasp"

    def __init__(self, samplers: StrategySamplers, config: BehaviourConfig | None = None,
                 strategy_config: StrategyConfig | None = None) -> None:
        super().__init__(SubgoalSamplers(samplers.grasp, samplers.navigate, samplers.observe, samplers.memory),
                         config)
        self.samplers = samplers
        self.strategy_config = strategy_config or StrategyConfig()

    # -- inspection ---------------------------------------------------------

    @property
    def stage(self) -> Stage:
        """The stage of the step in progress."""
        return self.STAGES[self._s.stage_index]

    def tree_status(self, state: BehaviourState | None = None) -> str:
        """The strategy's stage sequence and the progress of ``state`` (there is no tree)."""
        state = state or self.initial_state()
        marks = ["[*]" if i == state.stage_index else "[ ]" for i in range(len(self.STAGES))]
        stages = " -> ".join(f"{m} {s.value}" for m, s in zip(marks, self.STAGES))
        return f"{self.NAME}: {stages}; phase {state.phase.value}; {state.reason}"

    # -- SubgoalBehaviour hooks -----------------------------------------------

    def _tick(self, inputs: PolicyInputs) -> None:
        stage = self.stage
        budget_reason = self._budget_reason(stage)
        if budget_reason:
            self._terminate(inputs, self._exhausted_category(), budget_reason)
            return
        p = self._sample(inputs, stage)
        if p.success:
            self._issue(inputs, stage, p)
        else:
            self._on_sample_failed(inputs, stage, p)

    def _on_reached(self, inputs: PolicyInputs) -> bool:
        if self._s.phase in GRASP_PHASES:
            return super()._on_reached(inputs)
        done = self.stage
        self._s.stage_index = min(self._s.stage_index + 1, len(self.STAGES) - 1)
        self._transition(inputs, Phase.IDLE, f"{done.value} goal reached: next {self.stage.value}")
        return True

    def _on_failed(self, inputs: PolicyInputs) -> bool:
        stage = self.stage
        self._s.motion_failures[stage] += 1
        self._s.total_failures += 1
        if self._s.total_failures > self.config.max_total_failures:
            self._terminate(inputs, FailureCategory.PLANNING, f"{self._s.total_failures} motion failures")
            return False
        if stage != Stage.GRASP and self.samplers.reject is not None and self._s.q_goal is not None:
            self.samplers.reject(self._s.q_goal)
        return self._after_motion_failure(inputs, stage)

    def _on_replanned(self, inputs: PolicyInputs) -> bool:
        # The baselines treat a replanned trajectory as an invalidated one:
        # their own same-goal rule (`max_same_goal_replans`) decides.
        return self._on_invalidated(inputs)

    def _on_invalidated(self, inputs: PolicyInputs) -> bool:
        self._s.invalidations += 1
        if self._s.invalidations > self.config.max_invalidations:
            self._terminate(inputs, FailureCategory.PLANNING, "the map invalidated the goal too often")
            return False
        if self._s.phase not in (Phase.PREGRASP, Phase.OBSERVE, Phase.GRASP_MOVE):
            self._transition(inputs, self._s.phase, "map update during a linear or holding phase: continuing")
            return False
        if self._s.same_goal_replans < self.strategy_config.max_same_goal_replans and self._goal_still_free(inputs):
            # Replanning to the same goal: a new goal id makes the planner plan afresh.
            self._s.same_goal_replans += 1
            self._set_goal(inputs, self._s.phase, self._s.q_goal,
                           "path invalidated by the map: replanning to the same goal")
            return False
        return self._after_goal_invalid(inputs, self.stage)

    # -- per-strategy decisions (defaults: resample within the budgets) --------

    def _budget(self, stage: Stage) -> int:
        """How many goals the stage may issue."""
        cfg = self.config
        return {Stage.PREGRASP: cfg.max_pregrasp_goals, Stage.OBSERVE: cfg.max_observe_goals,
                Stage.GRASP: cfg.max_motion_failures + 1}[stage]

    def _on_sample_failed(self, inputs: PolicyInputs, stage: Stage, p: SubgoalProposal) -> None:
        self._terminate(inputs, self._sample_failure_category(p), f"{stage.value}: {p.failure_reason}")

    def _after_motion_failure(self, inputs: PolicyInputs, stage: Stage) -> bool:
        self._transition(inputs, Phase.IDLE, f"motion to the {stage.value} goal failed: resampling")
        return True

    def _after_goal_invalid(self, inputs: PolicyInputs, stage: Stage) -> bool:
        self._s.refund = True
        self._transition(inputs, Phase.IDLE, f"the map put the {stage.value} goal in collision: resampling")
        return True

    # -- helpers --------------------------------------------------------------

    def _sample(self, inputs: PolicyInputs, stage: Stage) -> SubgoalProposal:
        sampler = {Stage.GRASP: self.samplers.grasp, Stage.PREGRASP: self.samplers.navigate,
                   Stage.OBSERVE: self.samplers.observe}[stage]
        try:
            p = sampler(inputs)
        except Exception as e:  # noqa: BLE001 - a sampler bug ends the episode as a recorded error
            self._s.error = self._s.error or f"{stage.value} sampler raised:\n{traceback.format_exc()}"
            p = SubgoalProposal.failure(f"{stage.value} sampler raised {type(e).__name__}: {e}", FailureCategory.ERROR)
        if not p.success:
            self._s.last_failures[stage] = (p.failure_reason, p.category)
        return p

    def _issue(self, inputs: PolicyInputs, stage: Stage, p: SubgoalProposal) -> None:
        self._s.same_goal_replans = 0
        if not self._s.refund:
            self._s.goals_issued[stage] += 1
        self._s.refund = False
        self._s.head = np.full(2, np.nan) if p.head is None else np.asarray(p.head, float)
        if stage == Stage.GRASP:
            self._start_grasp(inputs, p, f"{self.NAME}: grasp goal found: moving to the pre-grasp pose")
        elif stage == Stage.PREGRASP:
            self._set_goal(inputs, Phase.PREGRASP, p.q_goal, f"{self.NAME}: {self.NAVIGATION_GOAL} goal found")
        else:
            self._set_goal(inputs, Phase.OBSERVE, p.q_goal, f"{self.NAME}: observe goal found")

    def _budget_reason(self, stage: Stage) -> str:
        if self._s.refund:
            return ""
        n, budget = self._s.goals_issued[stage], self._budget(stage)
        return f"{stage.value}: budget of {budget} goals used" if n >= budget else ""

    def _goal_still_free(self, inputs: PolicyInputs) -> bool:
        if self.samplers.goal_is_free is None or self._s.q_goal is None:
            return False
        try:
            return bool(self.samplers.goal_is_free(inputs, self._s.q_goal))
        except Exception:  # noqa: BLE001 - a failing check counts as "not free"
            return False

    def _motion_failed_often(self) -> bool:
        return any(n >= self.config.max_motion_failures for n in self._s.motion_failures.values())

    def _sample_failure_category(self, p: SubgoalProposal) -> FailureCategory:
        """PLANNING after repeated motion failures, else the sampler's own category."""
        if self._motion_failed_often():
            return FailureCategory.PLANNING
        return p.category if p.category != FailureCategory.NONE else FailureCategory.SUBGOAL

    def _exhausted_category(self) -> FailureCategory:
        return FailureCategory.PLANNING if self._s.total_failures > 0 else FailureCategory.SUBGOAL


class DirectGraspingBehaviour(StrategyBehaviour):
    """Observe -> navigate -> grasp, each goal sampled once (see the module docstring)."""

    NAME = "direct_grasping"
    STAGES = (Stage.OBSERVE, Stage.PREGRASP, Stage.GRASP)

    def _budget(self, stage: Stage) -> int:
        return 1

    def _after_motion_failure(self, inputs: PolicyInputs, stage: Stage) -> bool:
        self._terminate(inputs, FailureCategory.PLANNING,
                        f"motion to the {stage.value} goal failed (direct grasping does not resample goals)")
        return False

    def _after_goal_invalid(self, inputs: PolicyInputs, stage: Stage) -> bool:
        self._terminate(inputs, FailureCategory.SUBGOAL,
                        f"the map put the {stage.value} goal in collision (direct grasping does not resample goals)")
        return False


class NavAndManipBehaviour(StrategyBehaviour):
    """Navigate (arm stowed) to a base pose, then arm-only grasp planning."""

    NAME = "nav_and_manip"
    STAGES = (Stage.PREGRASP, Stage.GRASP)
    NAVIGATION_GOAL = "base pose (arm stowed)"

    def _on_sample_failed(self, inputs: PolicyInputs, stage: Stage, p: SubgoalProposal) -> None:
        # No grasp from the reached base ends the episode: navigation and
        # manipulation are decoupled, the base is not repositioned. The grasp
        # is resampled on the next ticks for `grasp_patience` seconds first,
        # while the head looks at the target from close by.
        if stage == Stage.GRASP:
            since = self._s.grasp_sampling_since
            if since is None:
                self._s.grasp_sampling_since = since = float(inputs.time)
            if float(inputs.time) - since < self.strategy_config.grasp_patience:
                return
        self._terminate(inputs, self._sample_failure_category(p), f"{stage.value}: {p.failure_reason}")

    def _on_reached(self, inputs: PolicyInputs) -> bool:
        if self._s.phase not in GRASP_PHASES:
            self._s.grasp_sampling_since = None  # a new base: a new grasp-sampling window
        return super()._on_reached(inputs)

    def _after_motion_failure(self, inputs: PolicyInputs, stage: Stage) -> bool:
        if stage == Stage.GRASP and self._s.motion_failures[stage] > self.config.max_motion_failures:
            self._terminate(inputs, FailureCategory.PLANNING,
                            f"{self._s.motion_failures[stage]} arm motions from the reached base failed")
            return False
        what = "grasp from the same base" if stage == Stage.GRASP else "base pose"
        self._transition(inputs, Phase.IDLE, f"motion to the {stage.value} goal failed: resampling the {what}")
        return True


class CapmapPlacementBehaviour(NavAndManipBehaviour):
    """nav_and_manip with the base pose of the capability-map pre-grasp sampler."""

    NAME = "capmap_placement"


class ClosedLoopReplanningBehaviour(StrategyBehaviour):
    """Continuous replanning towards a sampled pre-grasp, then grasp (no stages)."""

    NAME = "closed_loop_replanning"
    STAGES = (Stage.PREGRASP, Stage.GRASP)

    def _budget(self, stage: Stage) -> int:
        # Grasps are only sampled from reached pre-grasps: the pre-grasp budget bounds both.
        return self.config.max_pregrasp_goals

    def _back_to_pregrasp(self, inputs: PolicyInputs, reason: str) -> bool:
        self._s.stage_index = 0
        self._transition(inputs, Phase.IDLE, reason)
        return True

    def _on_sample_failed(self, inputs: PolicyInputs, stage: Stage, p: SubgoalProposal) -> None:
        if stage == Stage.GRASP and not self._budget_reason(Stage.PREGRASP):
            self._back_to_pregrasp(inputs, f"no grasp from the reached pre-grasp ({p.failure_reason}): resampling it")
            self._tick(inputs)
            return
        self._terminate(inputs, self._sample_failure_category(p), f"{stage.value}: {p.failure_reason}")

    def _after_motion_failure(self, inputs: PolicyInputs, stage: Stage) -> bool:
        return self._back_to_pregrasp(inputs, f"motion to the {stage.value} goal failed: resampling the pre-grasp")

    def _after_goal_invalid(self, inputs: PolicyInputs, stage: Stage) -> bool:
        self._s.refund = True
        return self._back_to_pregrasp(inputs, f"the map put the {stage.value} goal in collision: resampling the pre-grasp")


#: The behaviour class of each strategy (``subgoal_tree`` is the full system);
#: its keys are the valid values of ``DiagramConfig.strategy``.
BEHAVIOURS: dict[str, type[SubgoalBehaviour]] = {
    "subgoal_tree": SubgoalBehaviour,
    "direct_grasping": DirectGraspingBehaviour,
    "closed_loop_replanning": ClosedLoopReplanningBehaviour,
    "nav_and_manip": NavAndManipBehaviour,
    "capmap_placement": CapmapPlacementBehaviour,
}


# -- samplers over the real pipeline ------------------------------------------


def _finite_points(inputs: PolicyInputs) -> np.ndarray:
    p = np.asarray(inputs.p_WM, dtype=float).reshape(-1, 3)
    return p[np.all(np.isfinite(p), axis=1)]


class StandoffBaseSampler:
    """nav_and_manip's navigation goal: a stowed-arm base pose at a fixed distance
    from the target, facing it, navigable, collision-free and seeing it; the
    one nearest to the current base wins. Poses near a rejected goal are skipped."""

    def __init__(self, pipeline: SubgoalPipeline, config: StrategyConfig) -> None:
        self.pipeline = pipeline
        self.config = config
        self.sampler = ObserveSampler(pipeline.visibility, ObserveConfig(
            costmap=pipeline.config.observe.costmap, standoff=list(config.nav_standoff),
            num_angles=config.nav_num_angles, yaw_weight=pipeline.config.observe.yaw_weight))
        self.rejected: tuple[np.ndarray, ...] = ()  # base xy of the goals whose motion failed

    def reject(self, q_goal: np.ndarray) -> None:
        self.rejected = (*self.rejected, np.asarray(q_goal, float)[layout.BASE_XY].copy())

    def save_state(self) -> tuple[np.ndarray, ...]:
        """`SamplerMemory`: the rejected goals."""
        return self.rejected

    def load_state(self, state: tuple[np.ndarray, ...]) -> None:
        self.rejected = tuple(state)

    def __call__(self, inputs: PolicyInputs) -> SubgoalProposal:
        p_WM, q, p_WT = _finite_points(inputs), np.asarray(inputs.q, float), np.asarray(inputs.p_WT, float)
        problem = self.pipeline.target_problem(p_WM, p_WT)
        if problem:
            return SubgoalProposal.failure(problem, FailureCategory.PERCEPTION)
        is_free = self.pipeline.collision_fn(p_WM, p_WT, q)
        rejected = np.array(self.rejected).reshape(-1, 2)

        def is_free_and_new(Q: np.ndarray) -> np.ndarray:
            Q = np.atleast_2d(Q)
            new = np.ones(len(Q), bool)
            if len(rejected):
                d = np.linalg.norm(Q[:, None, :2] - rejected[None], axis=2)
                new = np.all(d > self.config.avoid_radius, axis=1)
            free = np.zeros(len(Q), bool)
            if new.any():
                free[new] = is_free(Q[new])
            return free

        result = self.sampler.sample(p_WM, p_WT, q, is_free_and_new, self.pipeline.rng)
        if not result.success:
            excluded = f" ({len(self.rejected)} failed poses excluded)" if self.rejected else ""
            return SubgoalProposal.failure(result.failure_reason + excluded, FailureCategory.SUBGOAL)
        return SubgoalProposal(True, result.q, head=result.head)


class CapmapBaseSampler:
    """capmap_placement's navigation goal: the base (and torso) of a whole-body
    pre-grasp sample with the arm stowed, collision-free in the current map."""

    def __init__(self, pipeline: SubgoalPipeline, config: StrategyConfig) -> None:
        self.pipeline = pipeline
        self.config = config

    def __call__(self, inputs: PolicyInputs) -> SubgoalProposal:
        p_WM, q, p_WT = _finite_points(inputs), np.asarray(inputs.q, float), np.asarray(inputs.p_WT, float)
        for _ in range(self.config.capmap_tries):
            p = self.pipeline.sample_pregrasp(inputs)
            if not p.success:
                return p
            q_base = layout.stow_configuration(*p.q_goal[layout.BASE])
            if self.config.capmap_keep_torso:
                # Not below the stowed height: the stowed arm touches the base there.
                q_base[layout.TORSO] = max(p.q_goal[layout.TORSO], layout.TORSO_STOW)
            if self.pipeline.collision_fn(p_WM, p_WT, q)(q_base[None])[0]:
                _, head = self.pipeline.visibility.check(q_base[None], p_WT, p_WM)
                return SubgoalProposal(True, q_base, head=head[0])
        return SubgoalProposal.failure(
            f"{self.config.capmap_tries} capability-map base poses collide with the arm stowed", FailureCategory.SUBGOAL)


def _timed(pipeline: SubgoalPipeline, name: str, sampler: SamplerFn) -> SamplerFn:
    def timed(inputs: PolicyInputs) -> SubgoalProposal:
        t0 = time.perf_counter()
        try:
            return sampler(inputs)
        finally:
            if pipeline.timings is not None:
                pipeline.timings.add(name, 1e3 * (time.perf_counter() - t0))
    return timed


def goal_check(pipeline: SubgoalPipeline) -> GoalCheckFn:
    """The pipeline's collision check of one goal under the inputs' map."""
    def goal_is_free(inputs: PolicyInputs, q_goal: np.ndarray) -> bool:
        is_free = pipeline.collision_fn(_finite_points(inputs), np.asarray(inputs.p_WT, float), np.asarray(inputs.q, float))
        return bool(is_free(np.asarray(q_goal, float)[None])[0])
    return goal_is_free


def strategy_samplers(strategy: str, pipeline: SubgoalPipeline, config: StrategyConfig | None = None) -> StrategySamplers:
    """The goal generators of ``strategy`` over the real samplers of ``pipeline``."""
    config = config or StrategyConfig()
    base = pipeline.samplers()
    navigate, reject, memory = base.pregrasp, None, base.memory
    if strategy == "nav_and_manip":
        standoff = StandoffBaseSampler(pipeline, config)
        navigate, reject = _timed(pipeline, "subgoal_navigate", standoff), standoff.reject
        memory = (*memory, standoff)
    elif strategy == "capmap_placement":
        navigate = _timed(pipeline, "subgoal_navigate", CapmapBaseSampler(pipeline, config))
    return StrategySamplers(base.grasp, navigate, base.observe, goal_check(pipeline), reject, memory)


def make_strategy(
    strategy: str,
    pipeline: SubgoalPipeline,
    behaviour_config: BehaviourConfig | None = None,
    config: StrategyConfig | None = None,
) -> SubgoalBehaviour:
    """The behaviour of ``strategy`` (one of `BEHAVIOURS`) over ``pipeline``'s samplers.

    Raises:
        ValueError: an unknown strategy (the message lists the known ones).
    """
    if strategy not in BEHAVIOURS:
        raise ValueError(f"strategy: unknown strategy '{strategy}' (known: {', '.join(BEHAVIOURS)})")
    if strategy == "subgoal_tree":
        return SubgoalBehaviour(pipeline.samplers(), behaviour_config)
    return BEHAVIOURS[strategy](strategy_samplers(strategy, pipeline, config), behaviour_config, config)
