"""The subgoal policy's behaviour tree (py_trees): Grasp -> Pre-grasp -> Observe -> Fail.

The tree is ticked whenever a new goal is needed (at start, when a subgoal is
reached, after a failed motion, or when the map invalidates the goal)::

    Selector "Subgoal" (memory=False)
    |-- Sequence "Grasp"      : StageAllowed(grasp)     -> GenerateGoal(grasp)
    |-- Sequence "Pre-grasp"  : StageAllowed(pregrasp)  -> GenerateGoal(pregrasp)
    |-- Sequence "Observe"    : StageAllowed(observe)   -> GenerateGoal(observe)
    `-- Fail                  : records the failure category, ends the episode

Each ``GenerateGoal`` calls an injectable sampler (``SubgoalSamplers``); the
first stage whose sampler succeeds sets the goal. Execution of a grasp goal is
a fixed sequence of phases: move to the pre-grasp (planned), linear approach,
close the gripper, pull out (linear, only for a grasp proposed with
``q_pull``: its lift in place was blocked by what overhangs the target), lift
(torso up). A grasp whose fingers close on nothing
(the measured opening ``PolicyInputs.gripper_opening`` below
``empty_gripper_opening`` while closing, pulling or lifting: the object slipped out or
was pushed away) backs off along the approach to its pre-grasp pose and the
tree is ticked again, with that grasp excluded from the candidates
(``PolicyInputs.failed_grasps``), up to ``max_grasp_retries`` times; the last
try lifts whatever it holds and the episode judges it. Runtime recovery
(``MotionEvent``):

* REACHED -- grasp phases advance; a reached pre-grasp or observe goal
  re-ticks the tree (Grasp first, from the new base and the updated map).
* FAILED -- the failed stage's failure count grows: a grasp whose motion
  failed is blocked until the base moves (so the tree falls back to
  Pre-grasp), a stage that failed ``max_motion_failures`` times is skipped;
  more than ``max_total_failures`` failures end the episode (PLANNING).
* INVALIDATED -- the map put the goal in collision: it is resampled from the
  top, without counting a failure or using up the stage's goal budget
  (bounded by ``max_invalidations``).
* REPLANNED -- the map invalidated the trajectory and the planner replanned to
  the same goal: the goal is kept unless a stage above it yields a goal now
  (Grasp during a pre-grasp goal; Grasp or Pre-grasp during an observe goal),
  for at most ``max_kept_replans`` replans, after which it is resampled as an
  invalidated goal.
  Resampling the whole tree on every map update sent the robot to a new,
  randomly drawn base each time: the paper's oscillation without convergence.

Pre-grasp and observe goals are budgeted (``max_pregrasp_goals``,
``max_observe_goals``) so the tree cannot cycle forever; when every stage is
exhausted or fails to sample, Fail ends the episode with a category.

State: `SubgoalBehaviour` is the fixed structure (samplers, config, tree);
everything that changes is a `BehaviourState`, which
`SubgoalBehaviour.step(state, inputs, event) -> (state, command)` advances
(the SubgoalPolicy keeps it in the Context).
"""

import dataclasses as dc
import enum
import traceback
from typing import Callable, Protocol

import numpy as np
import py_trees

from vamg_drake.planning.motion_messages import (
    GRASP_PHASES,
    TERMINAL,
    FailureCategory,
    MotionEvent,
    MotionFeedback,
    Phase,
    SubgoalCommand,
    stage_name,
)
from vamg_drake.robot import layout
from vamg_drake.robot.kinematics import FetchKinematics


class Stage(enum.Enum):
    GRASP = "grasp"
    PREGRASP = "pre_grasp"
    OBSERVE = "observe"


@dc.dataclass(frozen=True)
class PolicyInputs:
    """What a sampler sees: time, configuration, map points, the target and,
    optionally, a dense cloud of the target's surroundings (e.g. the latest depth
    image back-projected around the target, denser than the voxelized map)."""

    time: float
    q: np.ndarray
    p_WM: np.ndarray
    p_WT: np.ndarray
    p_WS: np.ndarray | None = None
    #: The measured gap between the fingers [m] (None: not measured).
    gripper_opening: float | None = None
    #: (K, 4, 4) gripper poses X_WG of this episode's grasps that closed on
    #: nothing (set by the behaviour; the grasp sampler leaves them out).
    failed_grasps: np.ndarray | None = None
    #: (K, 2) base positions xy of this episode's pre-grasp goals whose
    #: motion failed (set by the behaviour; the pre-grasp sampler tries
    #: bases near them last).
    failed_bases: np.ndarray | None = None


@dc.dataclass(frozen=True)
class SubgoalProposal:
    """A sampler's answer.

    Attributes:
        success: a goal was found.
        q_goal: (11,) the configuration to move to (the pre-grasp for grasps).
        q_grasp: (11,) grasp stage only: the grasp configuration (linear approach).
        head: (2,) optional pan/tilt that looks at the target from q_goal.
        failure_reason: why not (empty on success).
        category: the failure category this failure points at.
        lift_height: grasp stage only: how far to raise the torso after
            closing [m] (None: `BehaviourConfig.lift_height`).
        q_pull: grasp stage only: (11,) where the closed gripper pulls the
            object out before the lift (None: it lifts in place).
    """

    success: bool
    q_goal: np.ndarray | None = None
    q_grasp: np.ndarray | None = None
    head: np.ndarray | None = None
    failure_reason: str = ""
    category: FailureCategory = FailureCategory.NONE
    lift_height: float | None = None
    q_pull: np.ndarray | None = None

    @staticmethod
    def failure(reason: str, category: FailureCategory) -> "SubgoalProposal":
        return SubgoalProposal(False, failure_reason=reason, category=category)


SamplerFn = Callable[[PolicyInputs], SubgoalProposal]


class SamplerMemory(Protocol):
    """A sampler whose answers depend on what it did before (a random
    generator, the goals it was told had failed): the behaviour keeps what
    `save_state` returns in its `BehaviourState` and gives it back with
    `load_state` before every step, so the Context holds the sampler's
    memory. A saved state must not change afterwards (the behaviour's states
    share it)."""

    def save_state(self) -> object: ...

    def load_state(self, state: object) -> None: ...


@dc.dataclass
class SubgoalSamplers:
    """The three injectable goal generators, and those of their objects that
    remember something between calls (`SamplerMemory`)."""

    grasp: SamplerFn
    pregrasp: SamplerFn
    observe: SamplerFn
    memory: tuple[SamplerMemory, ...] = ()


@dc.dataclass
class BehaviourConfig:
    """Budgets and execution parameters of the subgoal behaviour."""

    max_motion_failures: int = 3
    max_total_failures: int = 10
    max_pregrasp_goals: int = 6
    max_observe_goals: int = 4
    #: Goal invalidations allowed since the last reached goal (the first views
    #: of the room keep invalidating the first pre-grasp goals, so a budget of
    #: about 10 per episode can end it in seconds; each costs a resample).
    max_invalidations: int = 30
    #: Replans of one goal (`MotionEvent.REPLANNED`) during which the goal is
    #: kept; the next one resamples it like an invalidated goal. Below the
    #: motion layer's own limit (`PlannerSystemConfig.max_replans`, 8),
    #: which would end the goal as a motion failure: while the first views of
    #: an apartment come in, a path is invalidated a dozen times on its way.
    max_kept_replans: int = 4
    #: Base displacement that unblocks the grasp stage after a failed grasp motion [m].
    unblock_distance: float = 0.1
    #: Time the gripper takes to close [s].
    close_duration: float = 1.0
    #: Lift height by the torso after closing [m] (clipped to the torso limit).
    #: Above the monitor's 10 cm success height by 5 cm: held objects settle
    #: 1-3 cm down in the fingers as they leave the table (with a 12 cm lift,
    #: objects such as a pear, a banana or a Lego brick end held at 9.0-9.8 cm).
    lift_height: float = 0.15
    #: A closed gripper narrower than this holds nothing [m]: the thinnest
    #: object the grasp sampler proposes is 4 mm (`AntipodalGraspConfig.min_width`),
    #: and the compliant pads sink up to about a millimetre into a thin wall
    #: they hold (a mug's), while fingers that closed on nothing go on to 0.
    empty_gripper_opening: float = 0.0015
    #: Grasps that closed on nothing retried from their pre-grasp pose (0: the
    #: first grasp is lifted whatever it holds).
    max_grasp_retries: int = 2

    def __post_init__(self) -> None:
        self.validate()

    def validate(self) -> None:
        """Raises ValueError naming the bad field."""
        for f in dc.fields(self):
            if getattr(self, f.name) < 0:
                raise ValueError(f"BehaviourConfig.{f.name} must be >= 0, got {getattr(self, f.name)}")


def _with_failures(inputs: PolicyInputs, state: "BehaviourState") -> PolicyInputs:
    """`inputs` with the episode's failed grasps and failed pre-grasp bases
    (`PolicyInputs.failed_grasps`, `failed_bases`) from `state`."""
    if state.failed_grasps:
        inputs = dc.replace(inputs, failed_grasps=np.stack(state.failed_grasps))
    if state.failed_bases:
        inputs = dc.replace(inputs, failed_bases=np.stack(state.failed_bases))
    return inputs


def _stage_counts() -> dict:
    return {s: 0 for s in Stage}


@dc.dataclass
class BehaviourState:
    """Everything a behaviour remembers between steps: the SubgoalPolicy's
    abstract state in the Context.

    A step never mutates the state it is given: it works on a `copy` and
    returns that. Copies of a state may therefore share it, and
    ``copy.deepcopy`` (how Drake clones an abstract state value) returns the
    state itself: cloning a Context costs nothing here.

    Attributes:
        phase, goal_id, q_goal, head, reason: the current goal (see `SubgoalCommand`).
        q_pregrasp, q_grasp, q_pull, q_lift: the pre-grasp, grasp, pull-out
            (None: none) and lift configurations of the grasp being executed.
        failed_grasps: gripper poses X_WG (4, 4) of the grasps that closed on nothing.
        failed_bases: base positions (2,) of the pre-grasp goals whose motion failed.
        close_started: when the gripper began to close [s].
        total_failures: motion failures so far.
        invalidations: goal invalidations since the last reached goal.
        goal_replans: replans of the current goal kept (`max_kept_replans`).
        history: (time, phase, reason) of every transition.
        last_failures: the last failure (reason, category) of each `Stage`.
        motion_failures, goals_issued: per `Stage`.
        grasp_blocked_at: the base xy from which a grasp motion failed (the
            grasp stage waits until the base moved `unblock_distance`).
        failure, failure_reason: the failure category and reason once FAILED.
        error: the traceback of a sampler that raised ("" if none did).
        stage_index, refund, same_goal_replans, grasp_sampling_since: the
            baseline strategies' progress (`vamg_drake.policy.strategies`).
        samplers: the samplers' saved memory (`SamplerMemory.save_state`).
        inputs, proposal, proposal_stage: the step in progress (None between steps).
    """

    phase: Phase = Phase.IDLE
    goal_id: int = 0
    q_goal: np.ndarray | None = None
    q_pregrasp: np.ndarray | None = None
    q_grasp: np.ndarray | None = None
    q_pull: np.ndarray | None = None
    q_lift: np.ndarray | None = None
    failed_grasps: tuple[np.ndarray, ...] = ()
    failed_bases: tuple[np.ndarray, ...] = ()
    head: np.ndarray = dc.field(default_factory=lambda: np.full(2, np.nan))
    close_started: float | None = None
    reason: str = ""
    total_failures: int = 0
    invalidations: int = 0
    goal_replans: int = 0
    history: tuple[tuple[float, str, str], ...] = ()
    last_failures: dict = dc.field(default_factory=dict)
    motion_failures: dict = dc.field(default_factory=_stage_counts)
    goals_issued: dict = dc.field(default_factory=_stage_counts)
    grasp_blocked_at: np.ndarray | None = None
    failure: FailureCategory = FailureCategory.NONE
    failure_reason: str = ""
    error: str = ""
    stage_index: int = 0
    refund: bool = False
    same_goal_replans: int = 0
    grasp_sampling_since: float | None = None
    samplers: tuple = ()
    inputs: PolicyInputs | None = None
    proposal: SubgoalProposal | None = None
    proposal_stage: Stage | None = None

    def copy(self) -> "BehaviourState":
        """A copy that a step may change (the arrays are replaced, never written, by a step)."""
        return dc.replace(self, last_failures=dict(self.last_failures), motion_failures=dict(self.motion_failures),
                          goals_issued=dict(self.goals_issued))

    def __deepcopy__(self, memo) -> "BehaviourState":
        return self  # immutable once a step returned it (see the class docstring)

    @property
    def stage_failures(self) -> dict[str, tuple[str, str]]:
        """The last failure reason and category of each stage, by name (for logs)."""
        return {s.value: (r, c.value) for s, (r, c) in self.last_failures.items()}

    @property
    def motion_failure_counts(self) -> dict[str, int]:
        """`motion_failures` by stage name."""
        return {s.value: n for s, n in self.motion_failures.items()}

    @property
    def goals_issued_counts(self) -> dict[str, int]:
        """`goals_issued` by stage name."""
        return {s.value: n for s, n in self.goals_issued.items()}


class StageAllowed(py_trees.behaviour.Behaviour):
    """SUCCESS when the stage may be tried now (budgets and blocks)."""

    def __init__(self, stage: Stage, owner: "SubgoalBehaviour") -> None:
        super().__init__(name=f"{stage.value} allowed?")
        self.stage = stage
        self.owner = owner

    def update(self) -> py_trees.common.Status:
        reason = self.owner._stage_block_reason(self.stage)
        if reason:
            self.feedback_message = reason
            self.owner._s.last_failures.setdefault(self.stage, (reason, FailureCategory.NONE))
            return py_trees.common.Status.FAILURE
        self.feedback_message = "allowed"
        return py_trees.common.Status.SUCCESS


class GenerateGoal(py_trees.behaviour.Behaviour):
    """Calls a sampler; SUCCESS (and the goal recorded) when it finds one."""

    def __init__(self, stage: Stage, sampler: SamplerFn, owner: "SubgoalBehaviour") -> None:
        super().__init__(name=f"{stage.value} goal")
        self.stage = stage
        self.sampler = sampler
        self.owner = owner

    def update(self) -> py_trees.common.Status:
        state = self.owner._s
        try:
            proposal = self.sampler(state.inputs)
        except Exception as e:  # noqa: BLE001 - a sampler bug ends the episode as a recorded error
            state.error = state.error or f"{self.stage.value} sampler raised:\n{traceback.format_exc()}"
            proposal = SubgoalProposal.failure(f"{self.stage.value} sampler raised {type(e).__name__}: {e}",
                                               FailureCategory.ERROR)
        if proposal.success:
            state.proposal, state.proposal_stage = proposal, self.stage
            self.feedback_message = "goal found"
            return py_trees.common.Status.SUCCESS
        state.last_failures[self.stage] = (proposal.failure_reason, proposal.category)
        self.feedback_message = proposal.failure_reason
        return py_trees.common.Status.FAILURE


class FailLeaf(py_trees.behaviour.Behaviour):
    """Every stage failed: decides the failure category and ends the episode."""

    def __init__(self, owner: "SubgoalBehaviour") -> None:
        super().__init__(name="Fail")
        self.owner = owner

    def update(self) -> py_trees.common.Status:
        state = self.owner._s
        state.failure, state.failure_reason = self.owner._failure_category()
        self.feedback_message = f"{state.failure.value}: {state.failure_reason}"
        return py_trees.common.Status.FAILURE


class SubgoalBehaviour:
    """The subgoal policy's core: a py_trees tree plus the grasp execution phases.

    The object is the behaviour's fixed structure (the samplers, the config and
    the tree); what changes lives in a `BehaviourState` that `step` takes and
    returns. The tree's nodes keep only the statuses of their last tick, for
    `tree_status`: every tick starts at the root (no node has memory, and
    every leaf returns SUCCESS or FAILURE at once), so the tree itself carries
    nothing from one step to the next. Its leaves read and write the state of
    the step in progress.

    Args:
        samplers: the grasp, pre-grasp and observe goal generators.
        config: budgets and execution parameters.
    """

    def __init__(self, samplers: SubgoalSamplers, config: BehaviourConfig | None = None) -> None:
        self.config = config or BehaviourConfig()
        self._memory = tuple(samplers.memory)
        self._initial_samplers = tuple(m.save_state() for m in self._memory)
        self._s: BehaviourState | None = None  # the state of the step in progress
        self.root = py_trees.composites.Selector("Subgoal", memory=False)
        self._stages: dict[Stage, py_trees.composites.Sequence] = {}
        for stage, sampler, name in (
            (Stage.GRASP, samplers.grasp, "Grasp"),
            (Stage.PREGRASP, samplers.pregrasp, "Pre-grasp"),
            (Stage.OBSERVE, samplers.observe, "Observe"),
        ):
            seq = py_trees.composites.Sequence(name, memory=False)
            seq.add_children([StageAllowed(stage, self), GenerateGoal(stage, sampler, self)])
            self._stages[stage] = seq
            self.root.add_child(seq)
        self.root.add_child(FailLeaf(self))
        self.tree = py_trees.trees.BehaviourTree(self.root)

    def initial_state(self) -> BehaviourState:
        """The state before the first step (IDLE, no goal; the samplers as built)."""
        return BehaviourState(samplers=self._initial_samplers)

    # -- inspection ---------------------------------------------------------

    def tree_status(self, state: BehaviourState | None = None) -> str:
        """The tree's last tick as ASCII (statuses and feedback messages)."""
        return py_trees.display.unicode_tree(self.root, show_status=True)

    # -- stepping -----------------------------------------------------------

    def step(self, state: BehaviourState, inputs: PolicyInputs,
             event: MotionEvent = MotionEvent.NONE) -> tuple[BehaviourState, SubgoalCommand]:
        """(the next state, the command): advances the policy with new inputs and optional motion feedback."""
        s = state.copy()
        inputs = s.inputs = _with_failures(inputs, s)
        for memory, saved in zip(self._memory, s.samplers):
            memory.load_state(saved)
        self._s = s
        try:
            command = self._advance(inputs, event)
        finally:
            self._s = None
        s.samplers = tuple(m.save_state() for m in self._memory)
        s.inputs = s.proposal = s.proposal_stage = None
        return s, command

    def _advance(self, inputs: PolicyInputs, event: MotionEvent) -> SubgoalCommand:
        s = self._s
        if s.phase in TERMINAL:
            return self._command(inputs)
        need_goal = s.phase == Phase.IDLE
        if event == MotionEvent.REACHED:
            s.invalidations = 0
            need_goal = self._on_reached(inputs)
        elif event == MotionEvent.FAILED:
            need_goal = self._on_failed(inputs)
        elif event == MotionEvent.INVALIDATED:
            need_goal = self._on_invalidated(inputs)
        elif event == MotionEvent.REPLANNED:
            need_goal = self._on_replanned(inputs)
        if s.phase == Phase.GRASP_CLOSE and s.close_started is not None:
            if not self._retry_empty_grasp(inputs) and inputs.time - s.close_started >= self.config.close_duration:
                if s.q_pull is not None:
                    self._set_goal(inputs, Phase.GRASP_PULL, s.q_pull, "gripper closed: pulling out before the lift")
                else:
                    self._set_goal(inputs, Phase.GRASP_LIFT, s.q_lift, "gripper closed: lifting")
        elif s.phase in (Phase.GRASP_PULL, Phase.GRASP_LIFT):
            self._retry_empty_grasp(inputs)
        if need_goal and s.phase not in TERMINAL:
            self._tick(inputs)
        if s.error and s.phase != Phase.FAILED:
            self._terminate(inputs, FailureCategory.ERROR, s.error)
        return self._command(inputs)

    def _tick(self, inputs: PolicyInputs) -> None:
        state = self._s
        state.proposal, state.proposal_stage = None, None
        self.tree.tick()
        if state.proposal is None:
            self._terminate(inputs, state.failure, state.failure_reason)
            return
        self._issue_proposal(inputs)

    def _issue_proposal(self, inputs: PolicyInputs) -> None:
        """Sets the goal of the step's proposal (`proposal`, `proposal_stage`)."""
        state = self._s
        stage, p = state.proposal_stage, state.proposal
        state.goals_issued[stage] += 1
        self._s.head = np.full(2, np.nan) if p.head is None else np.asarray(p.head, float)
        if stage == Stage.GRASP:
            self._start_grasp(inputs, p, "grasp goal found: moving to the pre-grasp pose")
        elif stage == Stage.PREGRASP:
            self._set_goal(inputs, Phase.PREGRASP, p.q_goal, "pre-grasp goal found")
        else:
            self._set_goal(inputs, Phase.OBSERVE, p.q_goal, "observe goal found")

    def _on_invalidated(self, inputs: PolicyInputs) -> bool:
        """The map invalidated the goal: True when a new goal must be chosen."""
        self._s.invalidations += 1
        if self._s.invalidations > self.config.max_invalidations:
            self._terminate(inputs, FailureCategory.PLANNING, "the map invalidated the goal too often")
            return False
        need_goal = self._s.phase not in (Phase.GRASP_CLOSE, Phase.GRASP_PULL, Phase.GRASP_LIFT, Phase.GRASP_RETREAT)
        # A goal the map invalidated does not use up its stage's goal budget.
        stage = {Phase.PREGRASP: Stage.PREGRASP, Phase.OBSERVE: Stage.OBSERVE}.get(self._s.phase)
        if need_goal and stage is not None and self._s.goals_issued[stage] > 0:
            self._s.goals_issued[stage] -= 1
        self._transition(inputs, self._s.phase, "goal invalidated by the map: resampling")
        return need_goal

    def _on_replanned(self, inputs: PolicyInputs) -> bool:
        """The planner replanned to the current goal on a new map: the stages
        above the current goal's are tried (see the module docstring); the goal
        is kept when none yields one, up to `max_kept_replans` times."""
        state = self._s
        state.goal_replans += 1
        if state.goal_replans > self.config.max_kept_replans:
            return self._on_invalidated(inputs)
        above = {Phase.PREGRASP: (Stage.GRASP,), Phase.OBSERVE: (Stage.GRASP, Stage.PREGRASP)}.get(state.phase, ())
        for stage in above:
            state.proposal, state.proposal_stage = None, None
            self._stages[stage].tick_once()  # the tree's own branch: allowed?, then sample
            if self._stages[stage].status == py_trees.common.Status.SUCCESS:
                self._issue_proposal(inputs)
                return False
        return False

    def _start_grasp(self, inputs: PolicyInputs, p: SubgoalProposal, reason: str) -> None:
        """Starts the grasp execution phases with a grasp proposal (GRASP_MOVE first)."""
        self._s.q_pregrasp = np.asarray(p.q_goal, float)
        self._s.q_grasp = np.asarray(p.q_grasp, float)
        self._s.q_pull = None if p.q_pull is None else np.asarray(p.q_pull, float)
        lift = self.config.lift_height if p.lift_height is None else min(p.lift_height, self.config.lift_height)
        self._s.q_lift = layout.raised_torso(self._s.q_grasp if self._s.q_pull is None else self._s.q_pull, lift)
        # How the gripper comes in, for the log: 0 deg is straight down, 90 level.
        approach = FetchKinematics.instance().gripper_pose(self._s.q_grasp)[:3, 0]
        tilt = np.degrees(np.arccos(np.clip(-approach[2], -1.0, 1.0)))
        self._set_goal(inputs, Phase.GRASP_MOVE, p.q_goal, f"{reason} (approach {tilt:.0f} deg from straight down)")

    def _on_reached(self, inputs: PolicyInputs) -> bool:
        if self._s.phase == Phase.GRASP_MOVE:
            self._set_goal(inputs, Phase.GRASP_APPROACH, self._s.q_grasp, "pre-grasp reached: linear approach")
        elif self._s.phase == Phase.GRASP_APPROACH:
            self._s.close_started = inputs.time
            self._set_goal(inputs, Phase.GRASP_CLOSE, self._s.q_grasp, "grasp pose reached: closing")
        elif self._s.phase == Phase.GRASP_PULL:
            if not self._retry_empty_grasp(inputs):
                self._set_goal(inputs, Phase.GRASP_LIFT, self._s.q_lift, "pulled out: lifting")
        elif self._s.phase == Phase.GRASP_LIFT:
            if not self._retry_empty_grasp(inputs):
                self._transition(inputs, Phase.SUCCEEDED, "lifted")
        elif self._s.phase == Phase.GRASP_RETREAT:
            self._transition(inputs, Phase.IDLE, "backed off from the empty grasp: resampling")
            return True
        elif self._s.phase in (Phase.PREGRASP, Phase.OBSERVE):
            # New base, new views: the grasp stage is worth another try.
            self._s.grasp_blocked_at = None
            if self._s.phase == Phase.OBSERVE:
                self._s.motion_failures[Stage.PREGRASP] = 0
            self._transition(inputs, Phase.IDLE, f"{self._s.phase.value} goal reached")
            return True
        return False

    def _on_failed(self, inputs: PolicyInputs) -> bool:
        stage = {Phase.PREGRASP: Stage.PREGRASP, Phase.OBSERVE: Stage.OBSERVE}.get(self._s.phase, Stage.GRASP)
        state = self._s
        state.motion_failures[stage] += 1
        self._s.total_failures += 1
        if self._s.total_failures > self.config.max_total_failures:
            self._terminate(inputs, FailureCategory.PLANNING, f"{self._s.total_failures} motion failures")
            return False
        if stage == Stage.GRASP:
            state.grasp_blocked_at = np.asarray(inputs.q, float)[layout.BASE_XY].copy()
        if stage == Stage.PREGRASP and state.q_goal is not None:
            state.failed_bases = (*state.failed_bases, np.asarray(state.q_goal, float)[layout.BASE_XY].copy())
            state.inputs = _with_failures(state.inputs, state)  # for this tick
        self._transition(inputs, Phase.IDLE, f"motion to the {stage.value} goal failed: resampling")
        return True

    def _retry_empty_grasp(self, inputs: PolicyInputs) -> bool:
        """When the closing or lifting gripper holds nothing and retries are
        left: records the grasp as failed and backs off to its pre-grasp pose
        (at the torso height reached, so a half-lifted gripper does not sweep
        back down through the object). True when it did."""
        s, cfg = self._s, self.config
        opening = inputs.gripper_opening
        if (opening is None or opening >= cfg.empty_gripper_opening or len(s.failed_grasps) >= cfg.max_grasp_retries
                or s.q_pregrasp is None):
            return False
        s.failed_grasps = (*s.failed_grasps, FetchKinematics.instance().gripper_pose(s.q_grasp))
        q_back = s.q_pregrasp.copy()
        q_back[layout.TORSO] = max(q_back[layout.TORSO], float(np.asarray(inputs.q)[layout.TORSO]))
        self._set_goal(inputs, Phase.GRASP_RETREAT, q_back,
                       f"the gripper closed on nothing ({1000 * opening:.1f} mm): backing off to try another grasp "
                       f"({len(s.failed_grasps)}/{cfg.max_grasp_retries})")
        return True

    # -- tree helpers -------------------------------------------------------

    def _stage_block_reason(self, stage: Stage) -> str:
        state, cfg = self._s, self.config
        if state.motion_failures[stage] >= cfg.max_motion_failures and stage != Stage.GRASP:
            return f"{stage.value}: {state.motion_failures[stage]} motion failures"
        if stage == Stage.GRASP:
            if state.grasp_blocked_at is not None:
                moved = np.linalg.norm(np.asarray(state.inputs.q)[layout.BASE_XY] - state.grasp_blocked_at)
                if moved < cfg.unblock_distance:
                    return "grasp: a grasp motion failed from this base"
                state.grasp_blocked_at = None
            if state.motion_failures[stage] >= cfg.max_motion_failures + 1:
                return f"grasp: {state.motion_failures[stage]} motion failures"
        if stage == Stage.PREGRASP and state.goals_issued[stage] >= cfg.max_pregrasp_goals:
            return f"pre-grasp: budget of {cfg.max_pregrasp_goals} goals used"
        if stage == Stage.OBSERVE and state.goals_issued[stage] >= cfg.max_observe_goals:
            return f"observe: budget of {cfg.max_observe_goals} goals used"
        return ""

    def _failure_category(self) -> tuple[FailureCategory, str]:
        state = self._s
        reasons = "; ".join(f"{s.value}: {r}" for s, (r, _) in state.last_failures.items())
        if any(n >= self.config.max_motion_failures for n in state.motion_failures.values()):
            return FailureCategory.PLANNING, reasons
        grasp_cat = state.last_failures.get(Stage.GRASP, ("", FailureCategory.NONE))[1]
        pre_cat = state.last_failures.get(Stage.PREGRASP, ("", FailureCategory.NONE))[1]
        # A target no pre-grasp sample reaches is out of reach whatever the
        # camera saw of it (a target on a 2.2 m cabinet is also unseen from
        # below: it was reported as perception).
        if pre_cat in (FailureCategory.REACHABILITY, FailureCategory.IK):
            return pre_cat, reasons
        if grasp_cat == FailureCategory.PERCEPTION:
            return FailureCategory.PERCEPTION, reasons
        return FailureCategory.SUBGOAL, reasons

    # -- bookkeeping --------------------------------------------------------

    def _set_goal(self, inputs: PolicyInputs, phase: Phase, q_goal: np.ndarray, reason: str) -> None:
        self._s.goal_id += 1
        self._s.goal_replans = 0
        self._s.q_goal = np.asarray(q_goal, dtype=float).copy()
        self._transition(inputs, phase, reason)

    def _transition(self, inputs: PolicyInputs, phase: Phase, reason: str) -> None:
        self._s.phase = phase
        self._s.reason = reason
        self._s.history = (*self._s.history, (float(inputs.time), phase.value, reason))

    def _terminate(self, inputs: PolicyInputs, category: FailureCategory, reason: str) -> None:
        if self._s.error:  # a sampler raised: whatever else failed, the episode is an error
            category, reason = FailureCategory.ERROR, self._s.error
        self._s.failure = category if category != FailureCategory.NONE else FailureCategory.SUBGOAL
        self._s.failure_reason = reason
        self._s.goal_id += 1
        self._s.q_goal = np.asarray(inputs.q, float).copy()
        self._transition(inputs, Phase.FAILED, f"{self._s.failure.value}: {reason}")

    def _command(self, inputs: PolicyInputs) -> SubgoalCommand:
        closed = self._s.phase in (Phase.GRASP_CLOSE, Phase.GRASP_PULL, Phase.GRASP_LIFT, Phase.SUCCEEDED)
        if self._s.phase in (Phase.IDLE, Phase.FAILED, Phase.SUCCEEDED) or self._s.q_goal is None:
            motion, q_goal = "hold", np.asarray(inputs.q, float).copy() if self._s.q_goal is None else self._s.q_goal
        elif self._s.phase in (Phase.GRASP_APPROACH, Phase.GRASP_PULL, Phase.GRASP_LIFT, Phase.GRASP_RETREAT):
            motion, q_goal = "linear", self._s.q_goal
        elif self._s.phase == Phase.GRASP_CLOSE:
            motion, q_goal = "hold", self._s.q_goal
        else:
            motion, q_goal = "plan", self._s.q_goal
        return SubgoalCommand(
            goal_id=self._s.goal_id,
            q_goal=q_goal.copy(),
            motion=motion,
            phase=self._s.phase,
            gripper_opening=0.0 if closed else layout.GRIPPER_MAX_OPENING,
            head=self._s.head.copy(),
            failure=self._s.failure if self._s.phase == Phase.FAILED else FailureCategory.NONE,
            reason=self._s.reason,
        )
