"""Every abstract port of the episode diagram is declared with a model value of
the type that flows on it (never None): the tracker and the gaze follow the
planner's `PlannedTrajectory`, which says "hold still" with its own field."""

from __future__ import annotations

from pydrake.systems.framework import PortDataType

from scenes import box_room_scenario
from vamg_drake.diagram import build_diagram
from vamg_drake.planning.motion_messages import PlannedTrajectory


def test_no_abstract_port_of_the_episode_diagram_has_a_none_model() -> None:
    ed = build_diagram(box_room_scenario())
    untyped = []
    for system in ed.diagram.GetSystems():
        ports = [system.get_input_port(i) for i in range(system.num_input_ports())]
        ports += [system.get_output_port(i) for i in range(system.num_output_ports())]
        for port in ports:
            if port.get_data_type() == PortDataType.kAbstractValued and port.Allocate().get_value() is None:
                untyped.append(f"{system.get_name()}.{port.get_name()}")
    assert untyped == []
    for system, port in ((ed.tracker, "trajectory"), (ed.gaze, "trajectory")):
        assert isinstance(system.GetInputPort(port).Allocate().get_value(), PlannedTrajectory)

