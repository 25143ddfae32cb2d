"""Episodes are reproducible (issue 19): the same scenario, config and code give
the same episode whatever the machine's load.

The planner's budget is RRT-Connect iterations (`PlannerConfig.
attempt_budget_iterations`), not wall time; its wall-clock limit is a safety
net that is counted (`planner_wall_limit` in the episode's timings) when it
fires. The first test runs a short demo episode twice, the second time beside
busy processes, and compares the records; a wall-clock budget fails it only
when some plan crosses that budget under the load, so the second test makes
the sensitivity explicit: a planner stopped by wall time (here a tiny
`attempt_wall_limit_s`, as the former 0.2 s budget did on a loaded machine)
changes the episode, and the episode's timings flag it.

Each episode steps the real diagram, so these take about two minutes on two
cores.
"""

import dataclasses as dc

import pytest

from vamg_drake.bench.busy import busy_cpu
from vamg_drake.diagram import DiagramConfig
from vamg_drake.episode import run_episode
from vamg_drake.scenarios import DEMO_SCENARIO
from vamg_drake.world.scenario import load_scenario


def _record(result) -> dict:
    """The fields of an episode that must not depend on the machine."""
    return dict(status=result.status, kind=result.kind, sim_time=result.sim_time, path_length=result.path_length,
                phases=result.phases, planner_calls=result.timings.get("planner", {}).get("count", 0))


def _demo(time_limit: float):
    scenario = load_scenario(DEMO_SCENARIO)
    scenario.time_limit = time_limit
    return scenario


@pytest.mark.slow
def test_the_same_episode_on_an_idle_and_a_loaded_machine():
    scenario = _demo(12.0)
    plain = run_episode(scenario, DiagramConfig(), record=False, progress=False)
    with busy_cpu(2):
        busy = run_episode(scenario, DiagramConfig(), record=False, progress=False)
    for result in (plain, busy):
        assert "planner_wall_limit" not in result.timings, result.timings["planner_wall_limit"]
    assert plain.timings["planner"]["count"] > 0  # the episode planned: the budget mattered
    assert _record(busy) == _record(plain)


@pytest.mark.slow
def test_a_wall_clock_limited_planner_changes_the_episode_and_is_flagged():
    scenario = _demo(3.0)
    config = DiagramConfig()
    plain = run_episode(scenario, config, record=False, progress=False)
    limited = dc.replace(config, planner=dc.replace(
        config.planner, planner=dc.replace(config.planner.planner, attempt_wall_limit_s=1e-6)))
    cut = run_episode(scenario, limited, record=False, progress=False)
    assert "planner_wall_limit" not in plain.timings
    assert cut.timings["planner_wall_limit"]["count"] > 0
    assert _record(cut) != _record(plain)
