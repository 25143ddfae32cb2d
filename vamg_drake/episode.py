"""Running one episode headless: simulate, judge, and write the results.

Everything from building the diagram to writing the outputs runs inside
one recorded-error path: an exception anywhere in it (a Drake assertion
included, which arrives as ``SystemExit``) ends the episode with status
``error`` and its traceback, and ``episode.json`` is still written.

`run_episode` writes into its output directory:
* `episode.json` — outcome category (and planning kind), the phase timeline,
  sim and wall time, base path length, per-module timings, the provenance
  (code and Drake versions, seed, resolved config) and, for status
  ``error``, the traceback; written atomically, paths relative to the
  output directory;
* `episode.log` — the systems' log (planner failures with tracebacks, phases);
* `replay.html` — a self-contained Meshcat recording (open it in a browser);
* `topdown.png` — the room, furniture, target and the robot's path.
"""

import dataclasses as dc
import json
import logging
import time
import traceback
from pathlib import Path

import numpy as np
from pydrake.geometry import StartMeshcat
from pydrake.systems.analysis import Simulator
from tqdm import tqdm

from vamg_drake.diagram import DiagramConfig, EpisodeDiagram, build_diagram
from vamg_drake.provenance import atomic_write_text, provenance
from vamg_drake.world.episode_monitor import PLANNING, EpisodeOutcome
from vamg_drake.world.scenario import Scenario
from vamg_drake.world.topdown import plot_topdown

log = logging.getLogger(__name__)


@dc.dataclass
class EpisodeResult:
    """What one episode produced (episode.json)."""

    scenario: str
    seed: int
    policy: str
    status: str
    detail: str
    method: str = ""
    kind: str = ""
    sim_time: float = 0.0
    wall_time: float = 0.0
    real_time_factor: float = 0.0
    path_length: float = 0.0
    depth_frames: int = 0
    timings: dict = dc.field(default_factory=dict)
    #: [[time, phase, reason], ...] from the subgoal policy.
    phases: list = dc.field(default_factory=list)
    #: For status ERROR: the traceback of the exception that ended the episode.
    error: str = ""
    #: Output files, relative to the output directory.
    outputs: dict = dc.field(default_factory=dict)
    #: `vamg_drake.provenance.provenance` of this episode.
    provenance: dict = dc.field(default_factory=dict)

    def to_json(self) -> str:
        return json.dumps(dc.asdict(self), indent=2, default=str)


def _start_meshcat():
    try:
        return StartMeshcat()
    except Exception as e:  # noqa: BLE001  (no free port, sandbox, ...)
        log.warning("Meshcat unavailable, no replay.html: %s", e)
        return None


#: Status of an episode that raised (the traceback is in `EpisodeResult.error` and episode.log).
ERROR = "error"
#: What a crash inside the episode may arrive as: a Drake assertion is a SystemExit.
_EPISODE_ERRORS = (Exception, SystemExit)


def run_episode(
    scenario: Scenario,
    config: DiagramConfig | None = None,
    out_dir: str | Path | None = None,
    record: bool = True,
    progress: bool = True,
    chunk: float = 0.1,
) -> EpisodeResult:
    """Simulates `scenario` until the monitor ends it (or its time limit)."""
    config = config or DiagramConfig()
    out = Path(out_dir) if out_dir else None
    handler = None
    if out:
        out.mkdir(parents=True, exist_ok=True)
        handler = logging.FileHandler(out / "episode.log", mode="w")
        handler.setFormatter(logging.Formatter("%(levelname)s %(name)s: %(message)s"))
        handler.setLevel(logging.INFO)
        root = logging.getLogger()
        root.addHandler(handler)
        previous_level = root.level
        root.setLevel(min(previous_level, logging.INFO) if previous_level else logging.INFO)
    try:
        return _run_recorded(scenario, config, out, record, progress, chunk)
    finally:
        if handler is not None:
            logging.getLogger().removeHandler(handler)
            logging.getLogger().setLevel(previous_level)
            handler.close()


def _error_result(scenario: Scenario, config: DiagramConfig, e: BaseException, tb: str,
                  wall: float) -> EpisodeResult:
    return EpisodeResult(
        scenario=scenario.name, seed=scenario.seed, policy=config.policy, status=ERROR,
        detail=f"{type(e).__name__}: {e}",
        method=config.method if config.policy == "full" else config.policy, wall_time=wall, error=tb,
    )


def _run_recorded(scenario: Scenario, config: DiagramConfig, out: Path | None, record: bool, progress: bool,
                  chunk: float) -> EpisodeResult:
    """`_run` with every exception turned into an ERROR result whose episode.json is still written."""
    wall0 = time.perf_counter()
    try:
        result = _run(scenario, config, out, record, progress, chunk)
    except _EPISODE_ERRORS as e:  # noqa: BLE001 - a crash is a recorded outcome, not a lost episode
        tb = traceback.format_exc()
        log.error("episode %s: raised:\n%s", scenario.name, tb)
        result = _error_result(scenario, config, e, tb, time.perf_counter() - wall0)
    result.provenance = provenance(config, seed={"scenario": scenario.seed, "config": config.seed})
    if out:
        result.outputs.setdefault("log", "episode.log")
        result.outputs["episode"] = "episode.json"
        atomic_write_text(out / "episode.json", result.to_json())
    return result


@dc.dataclass
class SimulatedEpisode:
    """What `simulate_episode` produced: the record and the robot's base path.

    Attributes:
        result: the episode's record (no provenance nor outputs yet).
        outcome: the monitor's final outcome.
        path: the base pose (x, y, yaw) after each chunk, (N, 3).
        configuration: the robot's configuration at the end (the robot state
            selector's ``configuration`` output).
    """

    result: EpisodeResult
    outcome: EpisodeOutcome
    path: np.ndarray
    configuration: np.ndarray


def simulate_episode(ed: EpisodeDiagram, scenario: Scenario, simulator: Simulator, progress: bool = False,
                     chunk: float = 0.1) -> SimulatedEpisode:
    """Runs one episode of the built diagram `ed` in `simulator`'s Context from its current state.

    The Context holds every piece of the episode's state, so one built diagram
    runs several episodes: from fresh Contexts (`Diagram.CreateDefaultContext`)
    or from a used one reset to the defaults (`Diagram.SetDefaultContext`
    and ``SetTime(0)``).
    This calls `Simulator.Initialize` (the initialization events give the map
    and the tracker their fresh state) and advances in `chunk`s until the
    monitor ends the episode or its time limit. ``ed.timings`` is cleared
    first: the record's timings are this episode's. An exception inside the
    simulation ends the episode with status ``error`` and its traceback.
    """
    config = ed.config
    context = simulator.get_mutable_context()
    robot_ctx = ed.robot_state.GetMyContextFromRoot(context)
    monitor_ctx = ed.monitor.GetMyContextFromRoot(context)
    policy_ctx = ed.policy.GetMyContextFromRoot(context)
    configuration = ed.robot_state.GetOutputPort("configuration")
    ed.timings.clear()
    path = []
    wall0 = time.perf_counter()
    t_end = scenario.time_limit + chunk
    bar = tqdm(
        total=round(scenario.time_limit, 1),
        disable=not progress,
        desc=scenario.name,
        leave=False,
        bar_format="{l_bar}{bar}| {n:.1f}/{total:.1f} sim s [{elapsed}<{remaining}]",
    )
    outcome = EpisodeOutcome()
    try:
        simulator.Initialize()
        while context.get_time() < t_end:
            t_next = min(context.get_time() + chunk, t_end)
            status = simulator.AdvanceTo(t_next)
            path.append(configuration.Eval(robot_ctx)[:3].copy())
            bar.update(round(chunk, 3))
            outcome = ed.monitor.GetOutputPort("outcome").Eval(monitor_ctx)
            if progress and ed.planner is not None:
                bar.set_postfix_str(ed.policy.GetOutputPort("phase").Eval(policy_ctx))
            if outcome.done or status.reason() == status.ReturnReason.kReachedTerminationCondition:
                break
    except _EPISODE_ERRORS as e:  # noqa: BLE001 - a crash is a recorded outcome, not a lost episode
        error = traceback.format_exc()
        log.error("episode %s: simulation raised at t=%.2f:\n%s", scenario.name, context.get_time(), error)
        outcome = EpisodeOutcome(ERROR, context.get_time(), f"{type(e).__name__}: {e}", error=error)
    bar.close()
    wall = time.perf_counter() - wall0
    if not outcome.done:
        outcome = EpisodeOutcome(PLANNING, context.get_time(), "time limit reached", "time_limit")
    path = np.array(path) if path else np.zeros((0, 3))
    length = float(np.sum(np.linalg.norm(np.diff(path[:, :2], axis=0), axis=1))) if len(path) > 1 else 0.0
    sim_time = context.get_time()
    phases = []
    if ed.policy.HasOutputPort("history"):
        history = ed.policy.GetOutputPort("history").Eval(policy_ctx)
        phases = [[round(t, 3), phase, reason] for t, phase, reason in history]
    summary = ed.timings.summary()
    result = EpisodeResult(
        scenario=scenario.name,
        seed=scenario.seed,
        policy=config.policy,
        status=outcome.status,
        detail=outcome.detail,
        method=config.method if config.policy == "full" else config.policy,
        kind=outcome.kind,
        sim_time=sim_time,
        wall_time=wall,
        real_time_factor=sim_time / wall if wall > 0 else float("nan"),
        path_length=length,
        depth_frames=summary.get("depth_render", {}).get("count", 0),
        timings=summary,
        phases=phases,
        error=outcome.error,
    )
    log.info("episode %s: %s%s at %.1f s (%s)", scenario.name, outcome.status,
             f"/{outcome.kind}" if outcome.kind else "", outcome.time, outcome.detail)
    return SimulatedEpisode(result, outcome, path, np.array(configuration.Eval(robot_ctx), dtype=float))


def _run(scenario: Scenario, config: DiagramConfig, out: Path | None, record: bool, progress: bool,
         chunk: float) -> EpisodeResult:
    meshcat = _start_meshcat() if (record and out) else None
    ed = build_diagram(scenario, config, meshcat=meshcat)
    simulator = Simulator(ed.diagram)
    if ed.visualizer is not None:
        ed.visualizer.StartRecording(set_transforms_while_recording=False)
    episode = simulate_episode(ed, scenario, simulator, progress, chunk)
    result, outcome = episode.result, episode.outcome
    if out:
        title = f"{scenario.name}: {outcome.status}{'/' + outcome.kind if outcome.kind else ''} at {outcome.time:.1f} s"
        plot_topdown(scenario, episode.path, out / "topdown.png", title=title)
        result.outputs["topdown"] = "topdown.png"
        if ed.visualizer is not None and meshcat is not None:
            ed.visualizer.StopRecording()
            ed.visualizer.PublishRecording()
            atomic_write_text(out / "replay.html", meshcat.StaticHtml())
            result.outputs["replay"] = "replay.html"
        result.outputs["log"] = "episode.log"
    return result
