"""Benchmark: tracking accuracy and per-call cost of the whole-body tracker.

Workload: seeded references (`vamg_drake.testing.tracking_rollout`): straight
lines (1-4 m), forward arcs (radius 0.6-2 m, 0.8-2.5 rad, torso and arm moving) and shortest
Reeds-Shepp paths with a cusp (turning radius 0.4 m, the planner's), all timed
at the layout's rate limits. Each is tracked at 20 Hz from its start with the
real command integrator (10 ms steps). Reported per family: mean and max
cross-track error [m], final base error [m], the fraction that reached the
goal tolerances, the extra time over the trajectory's duration [s]. Two
trackers run on the same workload: the default (lateral correction on) and
the paper's law unchanged (``lateral_gain = 0``, the reference). Cost: the
median and p99 wall time of `command()` [us], and of the literal matrix
formula (np.linalg.solve of (B'QB + R) u = B'Q dx) next to the closed form.

    python benchmarks/bench_tracker.py [--json] [--count 10] [--seed 0]
"""

import argparse
import json
import os
import time

os.environ.setdefault("OMP_NUM_THREADS", "1")

import numpy as np  # noqa: E402

from vamg_drake.testing.tracking_rollout import (  # noqa: E402
    arc_reference,
    cross_track_errors,
    reeds_shepp_reference,
    rollout,
    straight_reference,
)
from vamg_drake.control.whole_body_tracker import (  # noqa: E402
    TrackerConfig,
    WholeBodyTrackerCore,
    one_step_mpc,
    one_step_mpc_reference,
)

FAMILIES = {
    "straight": lambda rng: straight_reference(rng),
    "arc": lambda rng: arc_reference(rng),
    "reeds_shepp": lambda rng: reeds_shepp_reference(rng, radius=0.4),
}


def track_family(name: str, config: TrackerConfig, count: int, seed: int) -> tuple[dict, np.ndarray]:
    """Tracks `count` references of one family; returns (metrics, command costs [us])."""
    ct_mean, ct_max, final, extra, done = [], [], [], [], []
    costs = []
    for k in range(count):
        tr = FAMILIES[name](np.random.default_rng([seed, k]))
        core = WholeBodyTrackerCore(config)
        reason = core.set_trajectory(tr.times, tr.q, tr.q[0])
        if reason:
            raise RuntimeError(f"{name} reference {k} rejected: {reason}")
        ro = rollout(core, tr.q[0], tr.duration + 6.0)
        ct = cross_track_errors(tr.q[:, :2], ro.q[:, :2])
        ct_mean.append(ct.mean())
        ct_max.append(ct.max())
        final.append(float(np.hypot(*(ro.final_q[:2] - tr.q[-1, :2]))))
        extra.append(ro.times[-1] - tr.duration)
        done.append(ro.done)
        costs.append(ro.command_us)
    metrics = {
        "cross_track_mean_m": round(float(np.mean(ct_mean)), 4),
        "cross_track_max_m": round(float(np.max(ct_max)), 4),
        "final_error_mean_m": round(float(np.mean(final)), 4),
        "final_error_max_m": round(float(np.max(final)), 4),
        "reached_fraction": round(float(np.mean(done)), 3),
        "extra_time_mean_s": round(float(np.mean(extra)), 3),
    }
    return metrics, np.concatenate(costs)


def law_cost_us(n: int, seed: int) -> dict:
    """Median cost [us] of the closed form vs the literal matrix formula."""
    config = TrackerConfig()
    q_diag, r_diag = np.asarray(config.q_diag), np.asarray(config.r_diag)
    Q, R = np.diag(q_diag), np.diag(r_diag)
    rng = np.random.default_rng(seed)
    dx, th = rng.normal(size=(n, 11)), rng.uniform(-np.pi, np.pi, n)
    out = {}
    for label, fn in (("closed_form", lambda i: one_step_mpc(dx[i], th[i], q_diag, r_diag)),
                      ("matrix_formula", lambda i: one_step_mpc_reference(dx[i], th[i], Q, R))):
        t = np.empty(n)
        for i in range(n):
            t0 = time.perf_counter()
            fn(i)
            t[i] = time.perf_counter() - t0
        out[f"{label}_us"] = round(1e6 * float(np.median(t)), 2)
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--json", action="store_true", help="print one JSON object as the last line")
    parser.add_argument("--count", type=int, default=10, help="references per family")
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args()

    result = {"benchmark": "tracker", "count": args.count, "seed": args.seed, "rate_hz": 1.0 / TrackerConfig().period}
    all_costs = []
    for label, config in (("default", TrackerConfig()), ("paper_law", TrackerConfig(lateral_gain=0.0))):
        block = {}
        for name in FAMILIES:
            metrics, costs = track_family(name, config, args.count, args.seed)
            block[name] = metrics
            if label == "default":
                all_costs.append(costs)
            if not args.json:
                print(f"{label:9s} {name:11s} {metrics}")
        result[label] = block
    costs = np.concatenate(all_costs)
    result["command_us_median"] = round(float(np.median(costs)), 1)
    result["command_us_p99"] = round(float(np.percentile(costs, 99)), 1)
    result.update(law_cost_us(2000, args.seed))
    if not args.json:
        print(f"command(): median {result['command_us_median']} us, p99 {result['command_us_p99']} us; "
              f"law: closed form {result['closed_form_us']} us, matrix formula {result['matrix_formula_us']} us")
    print(json.dumps(result))


if __name__ == "__main__":
    main()
