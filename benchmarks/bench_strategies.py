"""Cost and outcome of each method's goal decisions, with ideal motion execution.

Workload (seeded): the table-top problems of ``bench_subgoal.make_problem``
(a walled room, a table with a can and clutter, furniture, a stowed robot at a
random free start >= 1.5 m from the target). Per problem and strategy, the
behaviour is stepped from the start; every planned goal is then "reached"
exactly (the robot's q becomes the goal), so what is measured is the policy
alone: how many goals it needs before a grasp goal (GRASP_MOVE) and how often
it gets there, or the failure category it ends with, and the wall time of each
decision (one ``step`` that samples a goal). The map is the scene's full point
cloud (no occlusion), the same for every strategy.

Reference in the same run: ``subgoal_tree`` (the full system's behaviour tree).

Usage: python benchmarks/bench_strategies.py [--json] [--problems N]
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

from vamg_drake.perception.depth_points import DepthToPointsConfig
from vamg_drake.policy.behaviour_tree import MotionEvent, Phase, PolicyInputs
from vamg_drake.policy.kinematic_maps import KinematicMaps
from vamg_drake.policy.strategies import BEHAVIOURS, make_strategy
from vamg_drake.policy.subgoal_pipeline import SubgoalPipeline
from vamg_drake.robot.head_camera import HeadCameraConfig

sys.path.insert(0, str(Path(__file__).parent))
from bench_subgoal import make_problem  # noqa: E402  (the shared seeded workload)

#: Goals a strategy may issue before the run counts as not converged.
MAX_GOALS = 8


def run_strategy(strategy: str, problems, maps: KinematicMaps, seed: int) -> dict:
    """Steps ``strategy`` on every problem with ideal execution; returns its metrics."""
    decision_ms, goals_to_grasp, outcomes = [], [], {}
    for i, (points, target, q0) in enumerate(problems):
        pipeline = SubgoalPipeline(maps, HeadCameraConfig(), DepthToPointsConfig().depth_max, seed=seed + i)
        behaviour = make_strategy(strategy, pipeline)
        state = behaviour.initial_state()
        q, t, event, outcome = q0, 0.0, MotionEvent.NONE, "not_converged"
        for _ in range(MAX_GOALS):
            t0 = time.perf_counter()
            state, cmd = behaviour.step(state, PolicyInputs(t, q, points, target), event)
            decision_ms.append(1e3 * (time.perf_counter() - t0))
            if cmd.phase == Phase.GRASP_MOVE:
                goals_to_grasp.append(sum(state.goals_issued.values()))
                outcome = "grasp_goal"
                break
            if cmd.phase == Phase.FAILED:
                outcome = cmd.failure.value
                break
            q, t, event = cmd.q_goal, t + 1.0, MotionEvent.REACHED
        outcomes[outcome] = outcomes.get(outcome, 0) + 1
    n = len(problems)
    return {
        "grasp_goal_rate": outcomes.get("grasp_goal", 0) / n,
        "goals_to_grasp_mean": float(np.mean(goals_to_grasp)) if goals_to_grasp else None,
        "decision_ms_median": float(np.median(decision_ms)),
        "decision_ms_p90": float(np.percentile(decision_ms, 90)),
        "outcomes": dict(sorted(outcomes.items())),
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--json", action="store_true")
    parser.add_argument("--problems", type=int, default=12)
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args()
    rng = np.random.default_rng(args.seed)
    problems = [make_problem(rng) for _ in range(args.problems)]
    maps = KinematicMaps.load_or_build()
    points, target, q0 = problems[0]
    for strategy in BEHAVIOURS:  # warm-up: JIT compilation is not a decision's cost
        behaviour = make_strategy(strategy, SubgoalPipeline(maps, HeadCameraConfig(), DepthToPointsConfig().depth_max))
        behaviour.step(behaviour.initial_state(), PolicyInputs(0.0, q0, points, target))
    result = {"problems": args.problems, "seed": args.seed, "max_goals": MAX_GOALS}
    for strategy in BEHAVIOURS:  # subgoal_tree (the reference) first
        result[strategy] = run_strategy(strategy, problems, maps, args.seed)
        if not args.json:
            print(f"{strategy:24s} {result[strategy]}", flush=True)
    print(json.dumps(result))


if __name__ == "__main__":
    main()
