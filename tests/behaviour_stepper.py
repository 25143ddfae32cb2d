"""A behaviour and its state, stepped the way the SubgoalPolicy steps them in a Context."""

from vamg_drake.planning.motion_messages import MotionEvent, SubgoalCommand
from vamg_drake.policy.behaviour_tree import BehaviourConfig, BehaviourState, PolicyInputs, SubgoalBehaviour


class Stepper:
    """Holds one `BehaviourState` of `behaviour` and advances it with `step`."""

    def __init__(self, behaviour: SubgoalBehaviour) -> None:
        self.behaviour = behaviour
        self.state: BehaviourState = behaviour.initial_state()

    def step(self, inputs: PolicyInputs, event: MotionEvent = MotionEvent.NONE) -> SubgoalCommand:
        self.state, command = self.behaviour.step(self.state, inputs, event)
        return command

    @property
    def config(self) -> BehaviourConfig:
        return self.behaviour.config

    def tree_status(self) -> str:
        return self.behaviour.tree_status(self.state)

    @property
    def history(self) -> tuple:
        return self.state.history

    @property
    def stage_failures(self) -> dict:
        return self.state.stage_failures

    @property
    def motion_failures(self) -> dict:
        return self.state.motion_failure_counts

    @property
    def goals_issued(self) -> dict:
        return self.state.goals_issued_counts

    @property
    def total_failures(self) -> int:
        return self.state.total_failures

    @property
    def q_grasp(self):
        return self.state.q_grasp
