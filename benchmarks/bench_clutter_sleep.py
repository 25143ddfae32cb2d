"""Plant stepping with sleeping clutter against all objects awake, in the same run.

Workload: the world of fixed scenarios stepped for ``--sim-time`` seconds by
the scripted driver without the camera (what remains is Drake's plant and the
command systems): the README demo room (a procedural room, one object) and,
when the paper authors' task file and the ReplicaCAD apartments are found
(``$VAMG_PAPER_TASKS``, ``$VAMG_REPLICACAD_DIR``), the first ``--paper-tasks``
tasks of the file's second scene, imported with all 20 objects. Each
scenario runs twice: every object awake (the reference) and with the
objects away from the target built asleep (anchored geometry,
``WorldConfig.clutter_sleep``), as episodes are.

Reports per scenario and as medians: wall time per simulated second for both,
the speed-up, the largest displacement of any free non-target object over
the run (awake ones may creep on convex furniture; sleeping ones are anchored),
and whether the robot's base ended at the same pose (the scripted driver
ignores the clutter, so it must).

With --json the last line is one JSON object of the metrics.
"""

import argparse
import json
import os
import time
from pathlib import Path

import numpy as np
from pydrake.systems.analysis import Simulator

from vamg_drake.diagram import DiagramConfig, build_diagram
from vamg_drake.scenarios import DEMO_SCENARIO
from vamg_drake.world.scenario import load_scenario


def step(scenario, sim_time: float, sleep: bool) -> dict:
    """Steps one world; returns wall ms per sim second, the awake clutter's drift and the final base pose."""
    config = DiagramConfig(policy="scripted")
    config.world.enable_camera = False
    config.world.clutter_sleep.enabled = sleep
    ed = build_diagram(scenario, config)
    simulator = Simulator(ed.diagram)
    simulator.Initialize()
    context = simulator.get_mutable_context()
    plant = ed.world.plant
    plant_context = plant.GetMyContextFromRoot(context)
    clutter = {n: b for n, b in ed.world.scene.object_bodies.items() if n != scenario.target}
    p0 = {n: plant.EvalBodyPoseInWorld(plant_context, b).translation().copy() for n, b in clutter.items()}
    t0 = time.perf_counter()
    while context.get_time() < sim_time - 1e-9:
        simulator.AdvanceTo(min(context.get_time() + 0.1, sim_time))
    wall = time.perf_counter() - t0
    drift = max((np.linalg.norm(plant.EvalBodyPoseInWorld(plant_context, b).translation() - p0[n]) for n, b in clutter.items()),
                default=0.0)
    base = ed.robot_state.GetOutputPort("configuration").Eval(ed.robot_state.GetMyContextFromRoot(context))[:3]
    return {"ms_per_sim_s": 1e3 * wall / sim_time, "max_drift_mm": 1e3 * float(drift), "base": base.copy(),
            "objects": len(scenario.objects), "asleep": len(ed.world.scene.asleep)}


def scenarios(paper_tasks: int) -> list:
    out = [("demo", load_scenario(DEMO_SCENARIO))]
    task_file = Path(os.environ.get("VAMG_PAPER_TASKS", Path(__file__).resolve().parents[2] / "shared/paper_benchmark/grasp_benchmark_dev.json"))
    if paper_tasks > 0 and task_file.is_file():
        from vamg_drake.world.paper_tasks import import_scene, read_task_file
        from vamg_drake.world.replicacad import find_replicacad_dir

        dataset = find_replicacad_dir() or find_replicacad_dir(Path(__file__).resolve().parents[2] / "shared/replicacad")
        if dataset is not None:
            scene = read_task_file(task_file)[1]
            imported = import_scene(scene, dynamic=False, dataset_dir=dataset, tasks=list(range(paper_tasks + 2)))
            out += [(s.name, s) for _, s in imported.scenarios[:paper_tasks]]
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--sim-time", type=float, default=10.0)
    parser.add_argument("--paper-tasks", type=int, default=1, help="paper tasks to add (0: the demo room only)")
    parser.add_argument("--json", action="store_true")
    args = parser.parse_args()
    rows = {}
    for name, scenario in scenarios(args.paper_tasks):
        awake = step(scenario, args.sim_time, sleep=False)
        asleep = step(scenario, args.sim_time, sleep=True)
        rows[name] = {
            "objects": awake["objects"],
            "asleep": asleep["asleep"],
            "awake_ms_per_sim_s": round(awake["ms_per_sim_s"], 1),
            "asleep_ms_per_sim_s": round(asleep["ms_per_sim_s"], 1),
            "speedup": round(awake["ms_per_sim_s"] / asleep["ms_per_sim_s"], 2),
            "awake_max_drift_mm": round(awake["max_drift_mm"], 2),
            "asleep_max_drift_mm": round(asleep["max_drift_mm"], 2),
            "base_equal": bool(np.allclose(awake["base"], asleep["base"], atol=1e-6)),
        }
        if not args.json:
            print(name, rows[name], flush=True)
    metrics = {
        "sim_time": args.sim_time,
        "scenarios": rows,
        "speedup_median": float(np.median([r["speedup"] for r in rows.values()])),
        "asleep_max_drift_mm": max(r["asleep_max_drift_mm"] for r in rows.values()),
        "base_equal": all(r["base_equal"] for r in rows.values()),
        "load_average": round(os.getloadavg()[0], 2),
    }
    print(json.dumps(metrics))


if __name__ == "__main__":
    main()
