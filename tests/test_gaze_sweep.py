"""The head reaches its rate limit (the URDF's head damping capped it at 0.64 rad/s),
and the optional start sweep looks to both sides."""

import numpy as np
from pydrake.systems.analysis import Simulator

from scenes import box_room_scenario
from vamg_drake.diagram import DiagramConfig, build_diagram
from vamg_drake.robot import layout


def test_start_sweep_turns_the_head_to_both_limits_at_its_rate():
    config = DiagramConfig(start_sweep=3.5)
    config.policy_system.start_delay = 3.5
    ed = build_diagram(box_room_scenario(time_limit=5.0), config)
    simulator = Simulator(ed.diagram)
    simulator.Initialize()
    pans = []
    for t in np.arange(0.1, 3.45, 0.1):
        simulator.AdvanceTo(t)
        V = ed.robot_state.GetOutputPort("configuration").Eval(ed.robot_state.GetMyContextFromRoot(simulator.get_context()))
        pans.append(V[layout.NQ])
    pans = np.array(pans)
    # Right limit within ~1.1 s (1.57 rad at up to 1.57 rad/s plus the PD lag), then the left one.
    assert pans[:12].min() < layout.HEAD_PAN_LIMITS[0] + 0.1
    assert pans.max() > layout.HEAD_PAN_LIMITS[1] - 0.1
    rate = np.max(np.abs(np.diff(pans))) / 0.1
    assert rate > 1.2  # the URDF damping alone capped it at 0.64 rad/s (PD catch-up may exceed 1.57 briefly)
