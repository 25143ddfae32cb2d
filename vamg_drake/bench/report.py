"""``vamg report DIR``: the paper's tables and plots from a results directory.

Reads ``DIR/results.jsonl`` (a truncated last line is skipped with a warning;
the file is not modified; an episode recorded more than once counts once, by
its latest record) and writes ``DIR/report.md`` (atomically) plus PNG plots:

* the results table (paper Table "Simulation evaluation results"): success and
  each failure category in % per suite and method, with 95 % Wilson intervals;
  statuses outside the paper's categories go to an "other" column;
* SPL (appendix "Path Efficiency Analysis") over episodes with a grid path;
* per-scene spread: min / max / std of per-scene success rates;
* the trigger-distance sweep (success and collision vs. trigger distance);
* the pre-grasp sampling-completeness curve, read from
  ``DIR/bench_subgoal.json`` (the ``--json`` last line of
  ``benchmarks/bench_subgoal.py``) when present;
* the compute-cost breakdown per module (mean ms per call, calls per episode);
* against the paper: each static/dynamic row (procedural rooms, or the
  authors' tasks in `paper_static`/`paper_dynamic`) beside the paper's (appendix
  table, `vamg_drake.bench.paper_results`), and whether the paper's success
  rate lies in the measured 95 % Wilson interval, as a table and a plot;
* where methods ran different numbers of tasks (a full sweep beside baselines
  on its first tasks), the same tables over the tasks every method of a
  suite ran, so that rows compare like with like.

The functions below are what the notebook calls, so notebook and report agree.
"""

import json
import logging
import math
from collections import defaultdict
from pathlib import Path

import matplotlib
import matplotlib.pyplot as plt
import numpy as np

from vamg_drake.bench.methods import PAPER_METHODS
from vamg_drake.bench.metrics import spl, wilson_interval
from vamg_drake.bench.paper_results import PAPER_EPISODES, paper_row
from vamg_drake.bench.results import CATEGORIES, OTHER, RESULTS_FILE, SUCCESS, category_of, latest_records, load_records
from vamg_drake.provenance import atomic_write_text

log = logging.getLogger(__name__)

COLUMNS = CATEGORIES + (OTHER,)
COMPLETENESS_FILE = "bench_subgoal.json"


def method_order(methods) -> list[str]:
    """The paper's row order first, then any other method alphabetically."""
    methods = set(methods)
    return [m for m in PAPER_METHODS if m in methods] + sorted(methods - set(PAPER_METHODS))


def _groups(records: list[dict], *fields: str) -> dict[tuple, list[dict]]:
    out: dict[tuple, list[dict]] = defaultdict(list)
    for r in records:
        out[tuple(r.get(f) for f in fields)].append(r)
    return out


def results_table(records: list[dict]) -> list[dict]:
    """One row per (suite, method): n, % per column, Wilson interval, SPL, per-scene spread."""
    rows = []
    groups = _groups(records, "suite", "method")
    for suite in sorted({k[0] for k in groups}):
        for method in method_order(m for s, m in groups if s == suite):
            rs = groups[(suite, method)]
            n = len(rs)
            counts = {c: 0 for c in COLUMNS}
            for r in rs:
                counts[category_of(r["status"])] += 1
            lo, hi = wilson_interval(counts[SUCCESS], n)
            with_path = [r for r in rs if r.get("shortest_path") is not None]
            spl_value = spl(
                np.array([r["status"] == SUCCESS for r in with_path]),
                np.array([r["shortest_path"] for r in with_path], dtype=float),
                np.array([r.get("path_length", 0.0) for r in with_path], dtype=float),
            ) if with_path else float("nan")
            per_scene = [np.mean([r["status"] == SUCCESS for r in g]) for g in _groups(rs, "scene").values()]
            rows.append({
                "suite": suite, "method": method, "n": n,
                **{c: 100.0 * counts[c] / n for c in COLUMNS},
                "success_ci": (100.0 * lo, 100.0 * hi),
                "spl": 100.0 * spl_value,
                "scenes": len(per_scene),
                "scene_min": 100.0 * float(np.min(per_scene)), "scene_max": 100.0 * float(np.max(per_scene)),
                "scene_std": 100.0 * float(np.std(per_scene)),
                "planning_kinds": dict(sorted(_count(r.get("planning_kind", "") for r in rs if r["status"] == "planning").items())),
            })
    return rows


def _count(values) -> dict:
    out: dict = defaultdict(int)
    for v in values:
        out[v or "unspecified"] += 1
    return out


def trigger_sweep(records: list[dict]) -> list[dict]:
    """Success and collision rate per (suite, method, trigger distance), dynamic suites only."""
    rows = []
    dyn = [r for r in records if r.get("trigger_distance") is not None]
    for (suite, method, d), rs in sorted(_groups(dyn, "suite", "method", "trigger_distance").items(), key=lambda kv: (kv[0][0], kv[0][1], kv[0][2])):
        n = len(rs)
        s = sum(r["status"] == SUCCESS for r in rs)
        rows.append({"suite": suite, "method": method, "trigger_distance": d, "n": n, "success": 100.0 * s / n,
                     "success_ci": tuple(100.0 * x for x in wilson_interval(s, n)),
                     "collision": 100.0 * sum(r["status"] == "collision" for r in rs) / n})
    return rows


def summary_lines(records: list[dict]) -> list[dict]:
    """One summary per `results_table` row, as ``vamg report --json`` prints
    them: episodes, successes, the rate with its 95 % Wilson interval [%],
    SPL [%], the failure statuses' counts, and the code versions the episodes
    ran (their provenance's ``code_version``)."""
    groups = _groups(records, "suite", "method")
    out = []
    for row in results_table(records):
        rs = groups[(row["suite"], row["method"])]
        k = sum(r["status"] == SUCCESS for r in rs)
        out.append({
            "suite": row["suite"], "method": row["method"],
            "code": sorted({str((r.get("provenance") or {}).get("code_version", "unknown")) for r in rs}),
            "episodes": row["n"], "success": k, "success_rate": round(k / row["n"], 4),
            "wilson95": [round(x, 1) for x in row["success_ci"]],
            "spl": None if math.isnan(row["spl"]) else round(row["spl"], 1),
            "failures": dict(sorted(_count(r["status"] for r in rs if r["status"] != SUCCESS).items())),
        })
    return out


def paper_comparison(rows: list[dict]) -> list[dict]:
    """The `results_table` rows that the paper also reports, each with the
    paper's percentages (``paper``) and whether its success rate lies in the
    row's 95 % Wilson interval (``paper_in_ci``)."""
    out = []
    for r in rows:
        paper = paper_row(r["suite"], r["method"])
        if paper is not None:
            lo, hi = r["success_ci"]
            out.append({**r, "paper": paper, "paper_in_ci": lo <= paper["success"] <= hi})
    return out


def task_of(record: dict) -> tuple:
    """The task an episode ran, whatever the method: (suite, scene, target
    index, trigger distance, run seed); records of older sweeps without the
    target index fall back on the scenario's name."""
    return (record["suite"], record.get("scene"), record.get("target_index", record.get("scenario")),
            record.get("trigger_distance"), record.get("run_seed", 0))


def common_task_records(records: list[dict]) -> list[dict]:
    """The records of the tasks that every method of their suite ran."""
    by_suite = _groups(records, "suite")
    out = []
    for (suite,), rs in by_suite.items():
        tasks = [{task_of(r) for r in g} for g in _groups(rs, "method").values()]
        common = set.intersection(*tasks)
        out += [r for r in rs if task_of(r) in common]
    return out


def apartment_of_scene(directory: str | Path) -> dict[tuple[str, int], str]:
    """(suite, scene index) -> apartment, from the ``import.json`` of each paper-task suite under ``DIR/suites``."""
    out = {}
    for path in sorted(Path(directory).glob("suites/*/import.json")):
        try:
            data = json.loads(path.read_text())
        except (OSError, json.JSONDecodeError):
            continue
        for scene in data.get("scenes", []):
            key = str(scene.get("scene", ""))
            if key.startswith("scene_") and key[6:].isdigit():
                out[(path.parent.name, int(key[6:]))] = str(scene.get("apartment", ""))
    return out


def per_apartment(records: list[dict], apartments: dict[tuple[str, int], str]) -> list[dict]:
    """Success and collision rates per (suite, method, apartment) for episodes of paper-task suites."""
    rows = []
    keyed = [dict(r, apartment=apartments[(r["suite"], int(r["scene"]))]) for r in records
             if (r.get("suite"), r.get("scene")) in apartments]
    for (suite, method, apartment), rs in sorted(_groups(keyed, "suite", "method", "apartment").items()):
        n = len(rs)
        rows.append({"suite": suite, "method": method, "apartment": apartment, "n": n,
                     "success": 100.0 * sum(r["status"] == "success" for r in rs) / n,
                     "collision": 100.0 * sum(r["status"] == "collision" for r in rs) / n})
    return rows


def grasp_attempts(records: list[dict]) -> list[dict]:
    """Per (suite, method), from each episode's phase history: the grasps
    closed (``closed``), those that closed on nothing and were retried
    (``retried``), those pulled out before the lift (``pulled``), the
    episodes that ended as grasp failures (``grasp_failures``), and the
    failed grasps per closed grasp (``failed_per_closed``, %: retried plus
    grasp failures over closed). Episodes without phases are not counted."""
    rows = []
    for (suite, method), rs in sorted(_groups([r for r in records if r.get("phases")], "suite", "method").items()):
        phases = [[p[1] for p in r["phases"]] for r in rs]
        closed = sum(ph.count("grasp_close") for ph in phases)
        retried = sum(ph.count("grasp_retreat") for ph in phases)
        failures = sum(r["status"] == "grasp" for r in rs)
        rows.append({"suite": suite, "method": method, "n": len(rs), "closed": closed, "retried": retried,
                     "pulled": sum(ph.count("grasp_pull") for ph in phases), "grasp_failures": failures,
                     "failed_per_closed": 100.0 * (retried + failures) / closed if closed else float("nan")})
    return rows


def compute_cost(records: list[dict]) -> list[dict]:
    """Per (method, module): mean ms per call and calls per episode."""
    rows = []
    for (method,), rs in _groups(records, "method").items():
        total_ms: dict[str, float] = defaultdict(float)
        calls: dict[str, int] = defaultdict(int)
        for r in rs:
            for module, t in (r.get("timings") or {}).items():
                count = int(t.get("count", 0) or 0)
                total = t.get("total_ms")
                if total is None and "mean_ms" in t:
                    total = t["mean_ms"] * count
                if count and total is not None:
                    total_ms[module] += float(total)
                    calls[module] += count
        for module in sorted(total_ms):
            rows.append({"method": method, "module": module, "mean_ms": total_ms[module] / calls[module],
                         "calls_per_episode": calls[module] / len(rs), "ms_per_episode": total_ms[module] / len(rs)})
    order = {m: i for i, m in enumerate(method_order({r["method"] for r in rows}))}
    return sorted(rows, key=lambda r: (order[r["method"]], r["module"]))


def completeness_curve(directory: str | Path) -> dict[int, float] | None:
    """Samples -> success rate from ``DIR/bench_subgoal.json`` (None if absent or unreadable)."""
    path = Path(directory) / COMPLETENESS_FILE
    if not path.is_file():
        return None
    lines = [ln for ln in path.read_text().splitlines() if ln.strip()]
    try:
        curve = json.loads(lines[-1])["completeness_curve"]
    except (IndexError, KeyError, json.JSONDecodeError) as e:
        log.warning("%s: no completeness_curve in its last line (%s); skipped", path, e)
        return None
    return {int(k): v for k, v in sorted(curve.items(), key=lambda kv: int(kv[0])) if v is not None}


# ------------------------------------------------------------------ plots


def plot_success(rows: list[dict], path: str | Path) -> None:
    """Success rate per method and suite with 95 % Wilson error bars."""
    matplotlib.use("Agg")

    suites = sorted({r["suite"] for r in rows})
    methods = method_order({r["method"] for r in rows})
    fig, ax = plt.subplots(figsize=(max(6, 1.2 * len(methods) * len(suites)), 4))
    width = 0.8 / max(1, len(suites))
    for k, suite in enumerate(suites):
        by = {r["method"]: r for r in rows if r["suite"] == suite}
        x = np.array([i for i, m in enumerate(methods) if m in by]) + k * width
        y = np.array([by[m]["success"] for m in methods if m in by])
        lo = y - np.array([by[m]["success_ci"][0] for m in methods if m in by])
        hi = np.array([by[m]["success_ci"][1] for m in methods if m in by]) - y
        ax.bar(x, y, width, yerr=[lo, hi], capsize=3, label=suite)
    ax.set_xticks(np.arange(len(methods)) + 0.4 - width / 2, methods, rotation=20, ha="right")
    ax.set_ylabel("success [%] (95 % Wilson)")
    ax.set_ylim(0, 100)
    ax.legend()
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)


def plot_failures(rows: list[dict], path: str | Path) -> None:
    """Stacked outcome categories per (suite, method)."""
    matplotlib.use("Agg")

    labels = [f"{r['suite']}\n{r['method']}" for r in rows]
    fig, ax = plt.subplots(figsize=(max(6, 1.1 * len(rows)), 4.5))
    bottom = np.zeros(len(rows))
    for column in COLUMNS:
        values = np.array([r[column] for r in rows])
        if np.any(values > 0):
            ax.bar(labels, values, bottom=bottom, label=column)
            bottom += values
    ax.set_ylabel("episodes [%]")
    ax.legend(fontsize=8, ncol=4)
    ax.tick_params(axis="x", labelsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)


def plot_spl(rows: list[dict], path: str | Path) -> None:
    """SPL per (suite, method)."""
    matplotlib.use("Agg")

    fig, ax = plt.subplots(figsize=(max(6, 1.1 * len(rows)), 4))
    ax.bar([f"{r['suite']}\n{r['method']}" for r in rows], [0.0 if math.isnan(r["spl"]) else r["spl"] for r in rows])
    ax.set_ylabel("SPL [%]")
    ax.tick_params(axis="x", labelsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)


def plot_paper_comparison(comparison: list[dict], path: str | Path) -> None:
    """Per suite, each method's success rate (95 % Wilson error bars) beside the paper's."""
    matplotlib.use("Agg")

    suites = sorted({r["suite"] for r in comparison})
    fig, axes = plt.subplots(1, len(suites), figsize=(max(6, 1.3 * len(comparison)), 4), squeeze=False, sharey=True)
    for ax, suite in zip(axes[0], suites):
        rows = [r for r in comparison if r["suite"] == suite]
        x = np.arange(len(rows))
        ours = np.array([r["success"] for r in rows])
        err = np.array([[o - r["success_ci"][0], r["success_ci"][1] - o] for o, r in zip(ours, rows)]).T
        ax.bar(x - 0.2, ours, 0.4, yerr=err, capsize=3, label="measured (95 % Wilson)")
        ax.bar(x + 0.2, [r["paper"]["success"] for r in rows], 0.4, color="0.6", label="paper")
        ax.set_xticks(x, [f"{r['method']}\n(n={r['n']})" for r in rows], rotation=20, ha="right", fontsize=8)
        ax.set_title(suite)
        ax.set_ylim(0, 100)
    axes[0][0].set_ylabel("success [%]")
    axes[0][0].legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)


def plot_per_scene(records: list[dict], path: str | Path) -> None:
    """Per-scene success rates (one dot per scene) per (suite, method)."""
    matplotlib.use("Agg")

    groups = _groups(records, "suite", "method")
    keys = sorted(groups, key=lambda k: (k[0], method_order({m for _, m in groups}).index(k[1])))
    fig, ax = plt.subplots(figsize=(max(6, 1.1 * len(keys)), 4))
    for i, key in enumerate(keys):
        rates = [100.0 * np.mean([r["status"] == SUCCESS for r in g]) for g in _groups(groups[key], "scene").values()]
        ax.scatter(np.full(len(rates), i) + np.linspace(-0.15, 0.15, len(rates)), rates, s=14)
    ax.set_xticks(range(len(keys)), [f"{s}\n{m}" for s, m in keys], fontsize=8)
    ax.set_ylabel("per-scene success [%]")
    ax.set_ylim(-5, 105)
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)


def plot_trigger_sweep(rows: list[dict], path: str | Path) -> None:
    """Success and collision rate vs trigger distance."""
    matplotlib.use("Agg")

    fig, ax = plt.subplots(figsize=(6, 4))
    for (suite, method), rs in _groups(rows, "suite", "method").items():
        d = [r["trigger_distance"] for r in rs]
        ax.plot(d, [r["success"] for r in rs], "o-", label=f"{suite}/{method} success")
        ax.plot(d, [r["collision"] for r in rs], "x--", label=f"{suite}/{method} collision")
    ax.set_xlabel("trigger distance [m]")
    ax.set_ylabel("episodes [%]")
    ax.legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)


def plot_completeness(curve: dict[int, float], path: str | Path) -> None:
    """Pre-grasp sampling success vs number of samples."""
    matplotlib.use("Agg")

    fig, ax = plt.subplots(figsize=(5, 3.5))
    ax.plot(list(curve), [100.0 * v for v in curve.values()], "o-")
    ax.set_xlabel("pre-grasp samples")
    ax.set_ylabel("solved problems [%]")
    ax.set_ylim(0, 105)
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)


def plot_compute_cost(rows: list[dict], path: str | Path) -> None:
    """Mean ms per call per module, one group of bars per method."""
    matplotlib.use("Agg")

    modules = sorted({r["module"] for r in rows})
    methods = method_order({r["method"] for r in rows})
    fig, ax = plt.subplots(figsize=(max(6, 0.9 * len(modules) * max(1, len(methods)) / 2), 4))
    width = 0.8 / max(1, len(methods))
    for k, method in enumerate(methods):
        by = {r["module"]: r["mean_ms"] for r in rows if r["method"] == method}
        ax.bar(np.arange(len(modules)) + k * width, [by.get(m, 0.0) for m in modules], width, label=method)
    ax.set_xticks(np.arange(len(modules)) + 0.4 - width / 2, modules, rotation=20, ha="right")
    ax.set_ylabel("mean per call [ms]")
    ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)


# ------------------------------------------------------------------ report


def _last_line(text: str) -> str:
    """The last non-empty line of an error (a traceback's exception)."""
    lines = [line.strip() for line in text.strip().splitlines() if line.strip()]
    return lines[-1] if lines else ""


def _pct(x: float) -> str:
    return "–" if math.isnan(x) else f"{x:.2f}"


def _table_line(row: dict) -> str:
    lo, hi = row["success_ci"]
    return (f"| {row['suite']} | {row['method']} | {row['n']} | {_pct(row['success'])} | [{lo:.1f}, {hi:.1f}] | "
            + " | ".join(_pct(row[c]) for c in COLUMNS[1:]) + f" | {_pct(row['spl'])} |")


def failed_episode_lines(records: list[dict], directory: Path) -> list[str]:
    """The report's list of failed episodes: status, reason, and a link to the log where one was kept."""
    failed = [r for r in records if r["status"] != SUCCESS]
    if not failed:
        return []
    lines = ["## Failed episodes", "", "| method | scenario | target | status | at [s] | detail | log |", "|---|---|---|---|---:|---|---|"]
    for r in sorted(failed, key=lambda r: (r.get("method", ""), r.get("scenario", ""))):
        status = r["status"] + (f"/{r['planning_kind']}" if r.get("planning_kind") else "")
        detail = " ".join(str(r.get("detail", "")).split()).replace("|", "/")[:120]
        episode_dir = r.get("episode_dir", "")
        link = f"[log]({episode_dir}/episode.log)" if episode_dir and (directory / episode_dir / "episode.log").is_file() else ""
        lines.append(f"| {r.get('method', '')} | {r.get('scenario', '')} | {r.get('target', '')} | {status} | "
                     f"{float(r.get('sim_time', 0.0)):.1f} | {detail} | {link} |")
    return lines + [""]


def load_latest_records(directory: str | Path) -> tuple[list[dict], int]:
    """The latest record of each episode in ``DIR/results.jsonl``, and how
    many earlier records of episodes run again it leaves out.

    Raises:
        FileNotFoundError: no results file, or no finished episode in it.
        ResultsError: a bad line that is not the last.
    """
    path = Path(directory) / RESULTS_FILE
    all_records = load_records(path)
    records = latest_records(all_records)
    if not records:
        raise FileNotFoundError(f"{path}: no finished episodes yet")
    return records, len(all_records) - len(records)


def write_report(directory: str | Path, loaded: tuple[list[dict], int] | None = None) -> Path:
    """Writes ``DIR/report.md`` and its PNG plots; returns the report's path.

    Args:
        loaded: `load_latest_records` of ``directory`` when the caller has
            read it already (default: read here).

    Raises:
        FileNotFoundError: no results file.
        ResultsError: a bad line that is not the last.
    """
    directory = Path(directory)
    records, superseded = loaded if loaded is not None else load_latest_records(directory)
    rows = results_table(records)
    sweep = trigger_sweep(records)
    cost = compute_cost(records)
    curve = completeness_curve(directory)
    plots = {"success": "success_rates.png", "failures": "failures.png", "spl": "spl.png", "per_scene": "per_scene.png"}
    plot_success(rows, directory / plots["success"])
    plot_failures(rows, directory / plots["failures"])
    plot_spl(rows, directory / plots["spl"])
    plot_per_scene(records, directory / plots["per_scene"])
    lines = [f"# Benchmark report: {directory.name}", "",
             f"{len(records)} episodes from `{RESULTS_FILE}`"
             + (f" ({superseded} earlier records of episodes run again not counted)." if superseded else "."), ""]
    lines += ["## Results (paper table; all values %)", "",
              "| suite | method | n | success | 95 % Wilson | " + " | ".join(COLUMNS[1:]) + " | SPL |",
              "|---|---|---:|---:|---|" + "---:|" * len(COLUMNS[1:]) + "---:|"]
    lines += [_table_line(r) for r in rows]
    lines += ["", f"Categories: {', '.join(CATEGORIES)}; `{OTHER}` counts any other status (harness errors, old vocabularies).",
              "Planning failures by kind: " + "; ".join(f"{r['suite']}/{r['method']}: {r['planning_kinds']}" for r in rows if r["planning_kinds"]) or "none", "",
              f"![success]({plots['success']})", "", f"![failures]({plots['failures']})", "", f"![SPL]({plots['spl']})", ""]
    common = common_task_records(records)
    common_rows = results_table(common) if len(common) < len(records) else []
    if common_rows:
        lines += ["## All methods on the same tasks", "",
                  "The methods of a suite ran different numbers of tasks; these rows keep only the tasks every method "
                  "of the suite ran (" + ", ".join(f"{suite}: {len({task_of(r) for r in common if r['suite'] == suite})}"
                                                  for suite in sorted({r['suite'] for r in common})) + ").", "",
                  "| suite | method | n | success | 95 % Wilson | " + " | ".join(COLUMNS[1:]) + " | SPL |",
                  "|---|---|---:|---:|---|" + "---:|" * len(COLUMNS[1:]) + "---:|"]
        lines += [_table_line(r) for r in common_rows] + [""]
    comparison = paper_comparison(rows)
    common_comparison = paper_comparison(common_rows)
    if comparison:
        lines += ["## Against the paper", "",
                  f"Each cell: measured % / the paper's % ({PAPER_EPISODES} episodes per row, appendix table).", ""]
        for title, table in (("", comparison), ("On the tasks every method ran:", common_comparison)):
            if not table:
                continue
            if title:
                lines += [title, ""]
            lines += ["| suite | method | n | " + " | ".join(CATEGORIES) + " | paper's success in our 95 % interval |",
                      "|---|---|---:|" + "---:|" * len(CATEGORIES) + "---|"]
            lines += [f"| {r['suite']} | {r['method']} | {r['n']} | "
                      + " | ".join(f"{r[c]:.1f} / {r['paper'][c]:.2f}" for c in CATEGORIES)
                      + f" | {'yes' if r['paper_in_ci'] else 'no'} |" for r in table]
            lines.append("")
        plot_paper_comparison(common_comparison or comparison, directory / "paper_comparison.png")
        lines += ["![against the paper](paper_comparison.png)", ""]
    apartments = per_apartment(records, apartment_of_scene(directory))
    if apartments:
        lines += ["## Per apartment (the paper authors' tasks)", "", "| suite | method | apartment | n | success | collision |",
                  "|---|---|---|---:|---:|---:|"]
        lines += [f"| {r['suite']} | {r['method']} | {r['apartment']} | {r['n']} | {r['success']:.1f} | {r['collision']:.1f} |"
                  for r in apartments]
        lines.append("")
    attempts = grasp_attempts(records)
    if attempts:
        lines += ["## Grasp attempts", "",
                  "From each episode's phases: grasps closed, those that closed on nothing and were retried, those "
                  "pulled out from under an overhang before the lift, episodes ending as grasp failures, and failed "
                  "grasps (retried + grasp failures) per closed grasp.", "",
                  "| suite | method | n | closed | retried | pulled out | grasp failures | failed per closed % |",
                  "|---|---|---:|---:|---:|---:|---:|---:|"]
        lines += [f"| {r['suite']} | {r['method']} | {r['n']} | {r['closed']} | {r['retried']} | {r['pulled']} | "
                  f"{r['grasp_failures']} | {_pct(r['failed_per_closed'])} |" for r in attempts]
        lines.append("")
    lines += ["## Per-scene spread", "", "| suite | method | scenes | min | max | std |", "|---|---|---:|---:|---:|---:|"]
    for r in rows:
        lines.append(f"| {r['suite']} | {r['method']} | {r['scenes']} | {r['scene_min']:.1f} | {r['scene_max']:.1f} | {r['scene_std']:.1f} |")
    lines += ["", f"![per-scene]({plots['per_scene']})", ""]
    lines += ["## Trigger-distance sweep", ""]
    if sweep:
        plot_trigger_sweep(sweep, directory / "trigger_sweep.png")
        lines += ["| suite | method | trigger [m] | n | success | collision |", "|---|---|---:|---:|---:|---:|"]
        lines += [f"| {r['suite']} | {r['method']} | {r['trigger_distance']:g} | {r['n']} | {r['success']:.1f} | {r['collision']:.1f} |" for r in sweep]
        lines += ["", "![trigger sweep](trigger_sweep.png)", ""]
    else:
        lines += ["No dynamic episodes in these results.", ""]
    lines += ["## Pre-grasp sampling completeness", ""]
    if curve:
        plot_completeness(curve, directory / "completeness.png")
        lines += ["| samples | " + " | ".join(str(k) for k in curve) + " |", "|---|" + "---:|" * len(curve),
                  "| solved % | " + " | ".join(f"{100 * v:.1f}" for v in curve.values()) + " |", "", "![completeness](completeness.png)", ""]
    else:
        lines += [f"Not measured here: put the last line of `python benchmarks/bench_subgoal.py --json` into `{COMPLETENESS_FILE}`.", ""]
    lines += ["## Compute cost per module", ""]
    if cost:
        plot_compute_cost(cost, directory / "compute_cost.png")
        lines += ["| method | module | mean ms/call | calls/episode | ms/episode |", "|---|---|---:|---:|---:|"]
        lines += [f"| {r['method']} | {r['module']} | {r['mean_ms']:.2f} | {r['calls_per_episode']:.1f} | {r['ms_per_episode']:.1f} |" for r in cost]
        lines += ["", "![compute cost](compute_cost.png)", ""]
    else:
        lines += ["No module timings in these results.", ""]
    lines += failed_episode_lines(records, directory)
    errors = [r for r in records if r.get("error")]
    if errors:
        lines += ["## Errors", "", "Episodes that raised (a bug, not a paper category; the traceback is in `results.jsonl` "
                  "and the episode's `episode.json`):", ""]
        lines += [f"- `{r['key']}`: {_last_line(r['error'])}" for r in errors[:50]] + [""]
    out = directory / "report.md"
    atomic_write_text(out, "\n".join(lines))
    return out
