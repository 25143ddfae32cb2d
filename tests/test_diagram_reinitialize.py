"""One built diagram runs the same episode again and again (issue 20).

Every mutable piece of the policy, the motion layer and the monitor lives in
the Context, so the diagram built once runs an episode from a fresh Context
(`Diagram.CreateDefaultContext`), from a second fresh Context, and from a
used Context reset to the defaults (`Diagram.SetDefaultContext`, time 0) and
re-initialized (`Simulator.Initialize`); each record equals the record of a
freshly built diagram. A system that kept state in its Python object (the
behaviour tree's phase and history, the planner's environment revision, the
motion supervisor's retreat history, the judge, a sampler's random
generator) would start the second episode where the first one ended.

Four short demo episodes (the demo's room, 5 s of simulated time: the sweep,
the first goals and the first planned motion): about two minutes on two cores.
"""

import numpy as np
import pytest
from pydrake.systems.analysis import Simulator

from vamg_drake.diagram import DiagramConfig, build_diagram
from vamg_drake.episode import SimulatedEpisode, simulate_episode
from vamg_drake.scenarios import DEMO_SCENARIO
from vamg_drake.world.scenario import load_scenario

TIME_LIMIT = 5.0


def _record(episode: SimulatedEpisode) -> dict:
    """The fields of an episode that do not depend on the machine or the wall clock."""
    r = episode.result
    return dict(status=r.status, kind=r.kind, detail=r.detail, sim_time=r.sim_time, path_length=r.path_length,
                phases=r.phases, planner_calls=r.timings.get("planner", {}).get("count", 0),
                depth_frames=r.depth_frames, configuration=episode.configuration.tolist())


@pytest.mark.slow
def test_one_diagram_runs_the_same_episode_from_fresh_and_reinitialized_contexts():
    scenario = load_scenario(DEMO_SCENARIO)
    scenario.time_limit = TIME_LIMIT
    config = DiagramConfig()

    reference_diagram = build_diagram(scenario, config)
    reference = _record(simulate_episode(reference_diagram, scenario, Simulator(reference_diagram.diagram)))
    assert reference["phases"], "the episode reached no policy phase: too short to compare"
    assert reference["planner_calls"] > 0, "the episode planned no motion: too short to compare"
    assert reference["path_length"] > 0.0, "the robot did not move: too short to compare"

    ed = build_diagram(scenario, config)
    records = []
    for _ in range(2):
        simulator = Simulator(ed.diagram, ed.diagram.CreateDefaultContext())
        records.append(_record(simulate_episode(ed, scenario, simulator)))
    # The used Context of the last run, reset to the defaults and the start time, and initialized again.
    used = simulator.get_mutable_context()
    ed.diagram.SetDefaultContext(used)
    used.SetTime(0.0)
    records.append(_record(simulate_episode(ed, scenario, simulator)))

    for name, record in zip(("first fresh Context", "second fresh Context", "re-initialized Context"), records):
        for key, value in reference.items():
            if key == "configuration":
                np.testing.assert_array_equal(record[key], value, err_msg=f"{name}: {key}")
            else:
                assert record[key] == value, f"{name}: {key}: {record[key]!r} != {value!r}"
