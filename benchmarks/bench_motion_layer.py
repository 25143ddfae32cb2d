"""Benchmark: the motion layer's cost per map revision, incremental re-check vs full rebuild.

Workload (seeded): a 6 x 6 m walled room with six random tables, revealed to
the `PlannerSystem` as a growing `PointMap`: half the points first, then the
rest in `--revisions` chunks, one per `recheck_period`, with a pillar on the
robot's straight way to its goal in the middle of the sequence. The robot
stands still while its trajectory is re-checked at every revision; the pillar
invalidates it and the system replans. Two systems run on the same sequence:
the default (``incremental_check``: the new points alone in a small distance
field, the planning environment rebuilt only to plan) and the reference that
rebuilds the room's distance field at every revision.

Reported per mode: the wall time per revision of the map handling (the
`ModuleTimings` of environment builds, the new-point diff and the trajectory
checks) [ms], the number of environment builds, and the revision at which the
trajectory was invalidated (both modes must agree: ``verdicts_agree``).
Also per room: the whole room's distance-field transform (`edt_3d`) against
SciPy's `distance_transform_edt` on the same padded grid (``field_edt_ms``,
``field_edt_scipy_ms``; ``field_edt_equal``: the same float32 distances).

    python benchmarks/bench_motion_layer.py [--json] [--count 5] [--revisions 30] [--seed 0]
"""

import argparse
import json
import os

os.environ.setdefault("OMP_NUM_THREADS", "1")

import time  # noqa: E402

import numpy as np  # noqa: E402
from scipy import ndimage  # noqa: E402
from pydrake.common.value import AbstractValue  # noqa: E402
from pydrake.systems.analysis import Simulator  # noqa: E402

from vamg_drake.perception.raycast_map import PointMap  # noqa: E402
from vamg_drake.planning.distance_field import DistanceField, edt_3d  # noqa: E402
from vamg_drake.planning.whole_body_planner import PlannerConfig  # noqa: E402
from vamg_drake.testing import synthetic_clouds as clouds  # noqa: E402
from vamg_drake.policy.behaviour_tree import MotionEvent, Phase, SubgoalCommand  # noqa: E402
from vamg_drake.robot import layout  # noqa: E402
from vamg_drake.robot.head_camera import CameraIntrinsics, HeadCameraConfig  # noqa: E402
from vamg_drake.systems.planner_system import PlannerSystem, PlannerSystemConfig  # noqa: E402
from vamg_drake.systems.timing import ModuleTimings  # noqa: E402

MAP_MODULES = ("planner_environment", "planner_new_points", "trajectory_check")


def room(rng: np.random.Generator) -> np.ndarray:
    """Walls and six tables away from the robot's straight way (y = 0)."""
    parts = [clouds.room_walls_cloud(3.0, spacing=0.03)]
    for _ in range(6):
        x = rng.uniform(-2.5, 2.5)
        y = rng.choice([-1.0, 1.0]) * rng.uniform(1.0, 2.2)
        sx, sy, h = rng.uniform(0.4, 1.0), rng.uniform(0.4, 0.8), rng.uniform(0.4, 1.0)
        parts.append(clouds.box_surface_cloud([x - sx / 2, y - sy / 2, 0.0], [x + sx / 2, y + sy / 2, h]))
    return np.concatenate(parts)


def pillar() -> np.ndarray:
    axes = [np.arange(c - h, c + h + 1e-9, 0.03) for c, h in zip([0.5, 0.0, 0.6], [0.15, 0.15, 0.6])]
    return np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1).reshape(-1, 3)


def run(points: np.ndarray, chunks: list[np.ndarray], incremental: bool) -> dict:
    """Feeds the revisions to a fresh PlannerSystem; returns its costs and verdicts."""
    timings = ModuleTimings()
    config = PlannerSystemConfig(incremental_check=incremental, planner=PlannerConfig(attempt_wall_limit_s=5.0))
    system = PlannerSystem(config, timings=timings)
    context = system.CreateDefaultContext()
    point_map = PointMap(CameraIntrinsics.from_config(HeadCameraConfig()))
    point_map.add_points(points)
    goal = SubgoalCommand(1, layout.stow_configuration(2.0, 0.3, 0.0), "plan", Phase.PREGRASP,
                          layout.GRIPPER_MAX_OPENING, np.full(2, np.nan))
    system.GetInputPort("goal").FixValue(context, AbstractValue.Make(goal))
    system.GetInputPort("robot_configuration").FixValue(context, layout.stow_configuration(-2.0, 0.0, 0.0))
    system.GetInputPort("point_map").FixValue(context, AbstractValue.Make(point_map.snapshot()))
    simulator = Simulator(system, context)
    simulator.AdvanceTo(0.05)
    if not system.GetOutputPort("trajectory").Eval(context).success:
        raise RuntimeError("the first plan failed")
    before = {m: v["total_ms"] for m, v in timings.summary().items() if m in MAP_MODULES}
    builds0 = timings.summary()["planner_environment"]["count"]
    invalidated, t = [], 0.05
    for k, chunk in enumerate(chunks):
        point_map.add_points(chunk)
        system.GetInputPort("point_map").FixValue(context, AbstractValue.Make(point_map.snapshot()))
        t += config.recheck_period
        simulator.AdvanceTo(t)
        feedback = system.GetOutputPort("motion_feedback").Eval(context)
        if (feedback.event in (MotionEvent.INVALIDATED, MotionEvent.REPLANNED) and k not in invalidated
                and len(invalidated) == 0):
            invalidated.append(k)
    summary = timings.summary()
    spent = sum(summary[m]["total_ms"] - before.get(m, 0.0) for m in MAP_MODULES if m in summary)
    return {"ms_per_revision": spent / len(chunks),
            "builds": summary["planner_environment"]["count"] - builds0,
            "invalidated_at": invalidated[0] if invalidated else -1,
            "replanned": bool(system.GetOutputPort("trajectory").Eval(context).success)}


def field_transform(points: np.ndarray, repeats: int = 3) -> dict:
    """The best of `repeats` times of the room's field transform, ours and SciPy's."""
    field = DistanceField.from_points(points)  # also compiles (or loads) edt_3d before the timing
    occ = field.occupancy
    ours, scipy_ms = [], []
    for _ in range(repeats):
        t0 = time.perf_counter()
        dist = edt_3d(occ, field.resolution)
        t1 = time.perf_counter()
        reference = ndimage.distance_transform_edt(~occ, sampling=field.resolution).astype(np.float32)
        t2 = time.perf_counter()
        ours.append(1e3 * (t1 - t0))
        scipy_ms.append(1e3 * (t2 - t1))
    return {"cells": int(occ.size), "ms": min(ours), "scipy_ms": min(scipy_ms),
            "equal": bool(np.allclose(dist, reference, rtol=1e-6, atol=0.0))}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--json", action="store_true", help="print one JSON object as the last line")
    parser.add_argument("--count", type=int, default=5, help="seeded rooms")
    parser.add_argument("--revisions", type=int, default=30, help="map revisions after the first plan")
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args()
    rows = {"incremental": [], "rebuild": []}
    fields = []
    agree = True
    for k in range(args.count):
        rng = np.random.default_rng([args.seed, k])
        points = rng.permutation(room(rng))
        first, rest = points[: len(points) // 2], points[len(points) // 2:]
        chunks = list(np.array_split(rest, args.revisions))
        chunks[args.revisions // 2] = np.concatenate([chunks[args.revisions // 2], pillar()])
        fields.append(field_transform(points))
        results = {mode: run(first, chunks, mode == "incremental") for mode in rows}
        agree &= results["incremental"]["invalidated_at"] == results["rebuild"]["invalidated_at"] >= 0
        for mode, r in results.items():
            rows[mode].append(r)
            if not args.json:
                print(f"room {k} {mode:11s} {r}")
    result = {"rooms": args.count, "revisions": args.revisions, "verdicts_agree": bool(agree)}
    for mode, rs in rows.items():
        result[f"{mode}_ms_per_revision_median"] = round(float(np.median([r["ms_per_revision"] for r in rs])), 2)
        result[f"{mode}_builds_mean"] = round(float(np.mean([r["builds"] for r in rs])), 2)
        result[f"{mode}_replanned"] = int(sum(r["replanned"] for r in rs))
    result["speedup"] = round(result["rebuild_ms_per_revision_median"]
                              / max(result["incremental_ms_per_revision_median"], 1e-9), 2)
    result["field_cells_median"] = int(np.median([f["cells"] for f in fields]))
    result["field_edt_ms_median"] = round(float(np.median([f["ms"] for f in fields])), 2)
    result["field_edt_scipy_ms_median"] = round(float(np.median([f["scipy_ms"] for f in fields])), 2)
    result["field_edt_speedup"] = round(result["field_edt_scipy_ms_median"] / max(result["field_edt_ms_median"], 1e-9), 2)
    result["field_edt_equal"] = all(f["equal"] for f in fields)
    if not args.json:
        print(f"map handling per revision: incremental {result['incremental_ms_per_revision_median']} ms, "
              f"rebuild {result['rebuild_ms_per_revision_median']} ms ({result['speedup']}x); field transform "
              f"{result['field_edt_ms_median']} ms vs SciPy {result['field_edt_scipy_ms_median']} ms")
    print(json.dumps(result))


if __name__ == "__main__":
    main()
