"""Reproducibility and speed of full-system episodes, on an idle and a loaded machine.

Workload: fixed episodes of the real diagram (`vamg_drake.episode.run_episode`,
`DiagramConfig(seed=--seed)`, the full policy, no recording):
  * the README demo scenario (`vamg_drake/scenarios/demo.yaml`, static
    benchmark scene 3: a Rubik's cube on a shelf 4.3 m from the start);
  * a dynamic procedural room, `generate_scenario(--room-seed,
    RoomGeneratorConfig(dynamic=True))` (a pedestrian on the path, a box
    appearing beside the target at pre-grasp).
Each episode runs twice: plain, then with `--busy` processes spinning NumPy
beside it (`vamg_drake.bench.busy.busy_cpu`). The same scenario, config and
code must give the same episode at any load; the two records are compared
field by field (status, kind, detail, sim time, path length, phases, depth
frames, planner calls). `--time-limit` shortens the episodes (sim seconds) for
quick runs. `--scenario FILE` adds scenario files (for example a paper task
from a `vamg bench --suite paper_static` suite: an apartment with 20 objects).

`--reference DIR` also runs every episode (plain) with the code of another
source tree (a `git worktree` of the previous commit), in a subprocess with
`PYTHONPATH=DIR`, and reports its real-time factors, the speed-up and
whether it ended each episode the same way (`same_as_reference`).

Reports `identical_across_runs` (every pair equal) with the differing fields
per scenario, `real_time_factor_median` over all runs, the per-module wall
time medians over all runs (each run's median call, from `timings`), and
`planner_wall_limit_hits`: attempts the planner's wall-clock safety net
stopped (nonzero: those episodes depend on the machine by construction).
An untimed warm-up episode (the demo, 2 s) first loads numba's caches (of the
reference tree too: they are per source tree, and compiling would count as
the reference's episode time).

Each episode runs on one core: numba's parallel kernels, Mesa's software
rasterizer and OpenMP run one thread (``NUMBA_NUM_THREADS``, ``LP_NUM_THREADS``
and ``OMP_NUM_THREADS`` default to 1 here and in the reference's subprocess;
set them to measure otherwise). The busy processes use the other cores.

With --json the last line is one JSON object of the metrics.
"""

from __future__ import annotations

import argparse
import dataclasses as dc
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

#: One thread per episode process (read by numba and Mesa when they load, so set before the imports below).
THREAD_VARIABLES = ("NUMBA_NUM_THREADS", "LP_NUM_THREADS", "OMP_NUM_THREADS")
for _variable in THREAD_VARIABLES:
    os.environ.setdefault(_variable, "1")

import numpy as np  # noqa: E402

from vamg_drake.bench.busy import busy_cpu  # noqa: E402
from vamg_drake.diagram import DiagramConfig  # noqa: E402
from vamg_drake.episode import EpisodeResult, run_episode  # noqa: E402
from vamg_drake.scenarios import DEMO_SCENARIO  # noqa: E402
from vamg_drake.world.rooms import RoomGeneratorConfig, generate_scenario  # noqa: E402
from vamg_drake.world.scenario import load_scenario, save_scenario  # noqa: E402

#: The fields of an episode that must not depend on the machine.
COMPARED = ("status", "kind", "detail", "sim_time", "path_length", "phases", "depth_frames", "planner_calls")


def episode_record(result: EpisodeResult) -> dict:
    """The machine-independent fields of an episode result (`COMPARED`)."""
    return dict(status=result.status, kind=result.kind, detail=result.detail, sim_time=result.sim_time,
                path_length=result.path_length, phases=result.phases, depth_frames=result.depth_frames,
                planner_calls=result.timings.get("planner", {}).get("count", 0))


def differing_fields(a: dict, b: dict) -> list[str]:
    """The fields of two `episode_record`s that differ."""
    return [k for k in COMPARED if a.get(k) != b.get(k)]


#: Runs one episode with whatever `vamg_drake` is importable; prints its record and real-time factor.
_REFERENCE_EPISODE = """
import json, sys
from vamg_drake.diagram import DiagramConfig
from vamg_drake.episode import run_episode
from vamg_drake.world.scenario import load_scenario, save_scenario
r = run_episode(load_scenario(sys.argv[1]), DiagramConfig(seed=int(sys.argv[2])), record=False, progress=False)
print(json.dumps(dict(status=r.status, kind=r.kind, detail=r.detail, sim_time=r.sim_time, path_length=r.path_length,
                      phases=r.phases, depth_frames=r.depth_frames, real_time_factor=r.real_time_factor)))
"""


def reference_episode(tree: Path, scenario, seed: int) -> dict:
    """The episode run by the code in source tree ``tree`` (a subprocess with ``PYTHONPATH=tree``)."""
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "scenario.yaml"
        save_scenario(scenario, path)
        env = dict(os.environ, PYTHONPATH=str(tree))
        out = subprocess.run([sys.executable, "-c", _REFERENCE_EPISODE, str(path), str(seed)], env=env, cwd=tree,
                             capture_output=True, text=True, check=True)
    return json.loads(out.stdout.strip().splitlines()[-1])


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--time-limit", type=float, default=None,
                        help="episode time limit [sim s] (default: each scenario's own)")
    parser.add_argument("--room-seed", type=int, default=1, help="seed of the dynamic procedural room")
    parser.add_argument("--seed", type=int, default=0, help="DiagramConfig.seed (samplers, planner)")
    parser.add_argument("--busy", type=int, default=1, help="spinning processes beside the loaded run")
    parser.add_argument("--no-warm-up", action="store_true")
    parser.add_argument("--scenario", action="append", default=[], help="another scenario file to run (repeatable)")
    parser.add_argument("--reference", type=Path, default=None,
                        help="source tree of the reference code (e.g. a worktree of the previous commit)")
    parser.add_argument("--json", action="store_true")
    args = parser.parse_args()

    scenarios = [load_scenario(DEMO_SCENARIO), generate_scenario(args.room_seed, RoomGeneratorConfig(dynamic=True))]
    scenarios += [load_scenario(f) for f in args.scenario]
    if args.time_limit is not None:
        for s in scenarios:
            s.time_limit = args.time_limit
    config = DiagramConfig(seed=args.seed)
    if not args.no_warm_up:
        run_episode(dc.replace(scenarios[0], time_limit=2.0), config, record=False, progress=False)
        if args.reference is not None:  # numba's caches are per source tree: warm the reference's too
            reference_episode(args.reference.resolve(), dc.replace(scenarios[0], time_limit=2.0), args.seed)

    runs, per_scenario = [], {}
    for scenario in scenarios:
        records = {}
        for load in ("plain", "busy"):
            t0 = time.perf_counter()
            if load == "busy":
                with busy_cpu(args.busy):
                    result = run_episode(scenario, config, record=False, progress=False)
            else:
                result = run_episode(scenario, config, record=False, progress=False)
            records[load] = episode_record(result)
            runs.append(dict(scenario=scenario.name, load=load, wall_s=time.perf_counter() - t0,
                             real_time_factor=result.real_time_factor, timings=result.timings,
                             load_average=os.getloadavg()[0], **records[load]))
            if not args.json:
                print(json.dumps({k: v for k, v in runs[-1].items() if k != "timings"}), flush=True)
        per_scenario[scenario.name] = dict(
            status=records["plain"]["status"], sim_time=records["plain"]["sim_time"],
            differing_fields=differing_fields(records["plain"], records["busy"]))
        if args.reference is not None:
            ref = reference_episode(args.reference.resolve(), scenario, args.seed)
            plain_rtf = next(r["real_time_factor"] for r in reversed(runs) if r["load"] == "plain")
            per_scenario[scenario.name].update(
                reference_real_time_factor=ref["real_time_factor"], real_time_factor=plain_rtf,
                speedup=plain_rtf / ref["real_time_factor"],
                reference_differing_fields=[k for k in COMPARED if k in ref and ref[k] != records["plain"][k]])
            if not args.json:
                print(json.dumps({"reference": scenario.name, **per_scenario[scenario.name]}), flush=True)

    modules = sorted({m for r in runs for m in r["timings"]})
    metrics = dict(
        workload="demo.yaml + generate_scenario(room_seed, dynamic=True) + --scenario files, each plain and with busy CPU processes",
        scenario_files=args.scenario,
        time_limit=args.time_limit,
        room_seed=args.room_seed,
        seed=args.seed,
        busy_processes=args.busy,
        episodes=len(runs),
        identical_across_runs=all(not s["differing_fields"] for s in per_scenario.values()),
        scenarios=per_scenario,
        real_time_factor_median=float(np.median([r["real_time_factor"] for r in runs])),
        real_time_factor_plain_median=float(np.median([r["real_time_factor"] for r in runs if r["load"] == "plain"])),
        real_time_factor_busy_median=float(np.median([r["real_time_factor"] for r in runs if r["load"] == "busy"])),
        module_median_ms={m: round(float(np.median([r["timings"][m]["median_ms"] for r in runs if m in r["timings"]])), 3)
                          for m in modules if m != "planner_wall_limit"},
        planner_wall_limit_hits=int(sum(r["timings"].get("planner_wall_limit", {}).get("count", 0) for r in runs)),
        load_average=os.getloadavg()[0],
        threads={v: os.environ[v] for v in THREAD_VARIABLES},
    )
    if args.reference is not None:
        refs = list(per_scenario.values())
        metrics.update(
            reference=str(args.reference),
            reference_real_time_factor_median=float(np.median([r["reference_real_time_factor"] for r in refs])),
            speedup_median=float(np.median([r["speedup"] for r in refs])),
            same_as_reference=all(not r["reference_differing_fields"] for r in refs),
        )
    print(json.dumps(metrics))


if __name__ == "__main__":
    main()
