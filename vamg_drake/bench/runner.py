"""The benchmark runner: isolated, resumable sweeps of suites x methods x seeds.

Every episode runs in its own process (``multiprocessing`` "spawn") under a
wall-clock limit, so a crash, a hang or an exception becomes a recorded
``status: "error"`` line, never a dead sweep. The parent is the only writer of
``DIR/results.jsonl``: one fsynced line per finished episode (see
``results.py``); ``resume=True`` skips every key already there, so killing a
sweep and resuming it loses and duplicates nothing. ``backend="ray"`` sends
the same isolated episodes to a Ray cluster (``ray.init(address)``; a local
instance when no address is given). Each episode also writes its log, its
``episode.json`` and a top-down plot to ``DIR/episodes/<key>/`` (``/`` in the
key becomes ``__``), so a failure can be read without running it again.

Integrity: a sweep holds ``results_lock`` on its directory (a second sweep
on the same ``--out`` is refused); an episode is done only when its latest
record ran with the current content of its method file (``method_digest``:
an edited method runs again) and, with ``retry_errors``, did not end in
``error``; each worker exits when the sweep process is gone (it watches its
parent), and a sweep stopped by a signal kills its workers first.
"""

import atexit
import contextlib
import dataclasses as dc
import functools
import logging
import multiprocessing as mp
import os
import signal
import threading
import time
import traceback
from collections import defaultdict
from collections.abc import Callable, Iterable
from concurrent.futures import FIRST_COMPLETED, ThreadPoolExecutor, wait
from dataclasses import dataclass
from pathlib import Path

from tqdm import tqdm

from vamg_drake.bench.methods import Method, MethodError, load_method
from vamg_drake.bench.results import ERROR, RESULTS_FILE, SUCCESS, EpisodeRecord, ResultsWriter, recorded, results_lock
from vamg_drake.bench.suites import Suite, with_trigger_distance
from vamg_drake.episode import run_episode
from vamg_drake.policy.kinematic_maps import KinematicMaps
from vamg_drake.provenance import provenance
from vamg_drake.world.scenario import load_scenario

log = logging.getLogger(__name__)

BACKENDS = ("local", "ray")


@dataclass(frozen=True)
class EpisodeSpec:
    """Everything a worker needs to run one episode (picklable).

    Attributes:
        key: unique id in the sweep.
        suite: suite name.
        method: method name.
        method_file: the method's YAML file.
        scenario_file: absolute path of the scenario YAML.
        scenario_id: id within the suite.
        scene: scene seed.
        target_index: target slot.
        target: target object.
        trigger_distance: pedestrian trigger distance [m] (None: as in the file).
        run_seed: repetition index.
        shortest_path: l_i for SPL [m].
        episode_dir: where the episode writes episode.log, episode.json and
            topdown.png ("": nowhere).
        method_digest: hash of the method file's content (``Method.digest``).
    """

    key: str
    suite: str
    method: str
    method_file: str
    scenario_file: str
    scenario_id: str
    scene: int
    target_index: int
    target: str
    trigger_distance: float | None
    run_seed: int
    shortest_path: float | None
    episode_dir: str = ""
    method_digest: str = ""


EPISODES_DIR = "episodes"


def episode_dir_name(key: str) -> str:
    """The directory name of an episode's outputs under ``DIR/episodes``."""
    return key.replace("/", "__")


def episode_specs(suite: Suite, methods: list[Method], seeds: int) -> list[EpisodeSpec]:
    """All episodes of a sweep, in a stable order (scenario-major, so methods interleave)."""
    if seeds < 1:
        raise ValueError(f"seeds: must be >= 1, got {seeds}")
    dynamic = suite.config.dynamic
    specs = []
    for s in suite.scenarios:
        for distance in suite.config.trigger_distances if dynamic else [None]:
            for run in range(seeds):
                for m in methods:
                    d = "static" if distance is None else f"d{distance:g}"
                    specs.append(EpisodeSpec(
                        key=f"{suite.config.name}/{m.name}/{s.id}/{d}/r{run}", suite=suite.config.name, method=m.name,
                        method_file=str(m.source), scenario_file=str((suite.directory / s.file).resolve()), scenario_id=s.id,
                        scene=s.scene, target_index=s.target_index, target=s.target, trigger_distance=distance, run_seed=run,
                        shortest_path=s.shortest_path, method_digest=m.digest,
                    ))
    return specs


def run_scenario_episode(spec: EpisodeSpec):
    """The real episode: load scenario and method, simulate headless (no recording).

    Returns:
        ``vamg_drake.episode.EpisodeResult``.
    """
    scenario = with_trigger_distance(load_scenario(spec.scenario_file), spec.trigger_distance)
    config = load_method(spec.method_file).config
    if hasattr(config, "seed"):
        config.seed = spec.run_seed
    return run_episode(scenario, config, out_dir=spec.episode_dir or None, record=False, progress=False)


EpisodeFn = Callable[[EpisodeSpec], object]


@functools.cache
def _method_provenance(method_file: str, run_seed: int) -> dict:
    """Provenance for a record whose worker sent none (it died or raised)."""
    try:
        config = load_method(method_file).config
    except MethodError:
        config = None
    return provenance(config, seed={"run": run_seed})


def _record(spec: EpisodeSpec, status: str, wall: float, result: dict | None = None, error: str = "") -> EpisodeRecord:
    result = result or {}
    if not error and status == ERROR:
        error = result.get("error", "") or ""
    return EpisodeRecord(
        key=spec.key, suite=spec.suite, method=spec.method, scene=spec.scene, target_index=spec.target_index,
        target=spec.target, trigger_distance=spec.trigger_distance, run_seed=spec.run_seed,
        scenario=result.get("scenario", spec.scenario_id), status=status,
        planning_kind=result.get("kind", "") or "", detail=result.get("detail", "") or "",
        sim_time=float(result.get("sim_time", 0.0) or 0.0), wall_time=wall,
        path_length=float(result.get("path_length", 0.0) or 0.0), shortest_path=spec.shortest_path,
        timings=result.get("timings", {}) or {}, phases=result.get("phases", []) or [], error=error,
        episode_dir=f"{EPISODES_DIR}/{episode_dir_name(spec.key)}" if spec.episode_dir else "",
        method_digest=spec.method_digest,
        provenance=result.get("provenance") or _method_provenance(spec.method_file, spec.run_seed),
    )


def _child(conn, episode_fn: EpisodeFn, spec: EpisodeSpec, parent: int) -> None:
    # Warnings to the sweep's stderr; the episode's own INFO log goes to its file.
    stderr = logging.StreamHandler()
    stderr.setLevel(logging.WARNING)
    logging.basicConfig(level=logging.WARNING, handlers=[stderr])
    threading.Thread(target=_exit_with_parent, args=(parent,), daemon=True).start()
    try:
        result = episode_fn(spec)
        payload = dc.asdict(result) if dc.is_dataclass(result) else dict(result)
        conn.send(("ok", payload))
    except BaseException:  # noqa: BLE001  everything becomes a recorded failure
        conn.send(("error", traceback.format_exc(limit=8)))
    finally:
        conn.close()


def _exit_with_parent(parent: int, poll: float = 1.0) -> None:
    """Ends this worker when the sweep that started it is gone (killed, even
    by SIGKILL, which runs no handler in the parent). ``parent`` is the pid
    the sweep passed, so a sweep killed while this worker was still starting
    is noticed too."""
    while os.getppid() == parent:
        time.sleep(poll)
    os._exit(70)


#: Workers in flight in this process (killed when the sweep stops early).
_LIVE_WORKERS: set = set()
_LIVE_LOCK = threading.Lock()


def _kill_live_workers() -> None:
    """Kills every worker still running (a sweep stopped by a signal or an exception)."""
    with _LIVE_LOCK:
        workers = list(_LIVE_WORKERS)
    for process in workers:
        if process.is_alive():
            process.kill()
    for process in workers:
        process.join(5.0)


atexit.register(_kill_live_workers)


def run_isolated(spec: EpisodeSpec, episode_fn: EpisodeFn = run_scenario_episode, wall_limit: float = 900.0) -> EpisodeRecord:
    """Runs one episode in a fresh process; never raises for the episode's sake.

    A crash (the process dies), a hang (``wall_limit`` seconds) or an exception
    gives ``status="error"`` with the reason in ``error``.
    """
    ctx = mp.get_context("spawn")
    recv, send = ctx.Pipe(duplex=False)
    process = ctx.Process(target=_child, args=(send, episode_fn, spec, os.getpid()), daemon=True)
    t0 = time.perf_counter()
    process.start()
    with _LIVE_LOCK:
        _LIVE_WORKERS.add(process)
    send.close()
    message = None
    deadline = t0 + wall_limit
    while message is None:
        remaining = deadline - time.perf_counter()
        if remaining <= 0:
            break
        if recv.poll(min(remaining, 1.0)):
            try:
                message = recv.recv()
            except EOFError:  # the child died without a word
                break
        elif not process.is_alive() and not recv.poll(0.1):
            break
    wall = time.perf_counter() - t0
    if process.is_alive():
        process.join(5.0 if message is not None else 0.0)
    if process.is_alive():
        process.kill()
        process.join()
    with _LIVE_LOCK:
        _LIVE_WORKERS.discard(process)
    recv.close()
    if message is None:
        if wall >= wall_limit:
            return _record(spec, ERROR, wall, error=f"wall-clock limit {wall_limit:g} s exceeded; worker killed")
        return _record(spec, ERROR, wall, error=f"worker died (exit code {process.exitcode})")
    kind, payload = message
    if kind == "error":
        return _record(spec, ERROR, wall, error=f"exception in episode:\n{payload}")
    return _record(spec, str(payload.get("status", ERROR)), wall, result=payload)


class _Progress:
    """tqdm bar with running success rates per method."""

    def __init__(self, total: int, done_before: int, enabled: bool):
        self.bar = tqdm(total=total, initial=done_before, desc="bench", disable=not enabled, dynamic_ncols=True)
        self.counts: dict[str, list[int]] = defaultdict(lambda: [0, 0])

    def update(self, record: EpisodeRecord) -> None:
        c = self.counts[record.method]
        c[0] += record.status == SUCCESS
        c[1] += 1
        self.bar.set_postfix_str(" ".join(f"{m} {s}/{n} ({100 * s / n:.0f}%)" for m, (s, n) in sorted(self.counts.items())))
        self.bar.update(1)

    def close(self) -> None:
        self.bar.close()


def prepare_episode_caches(methods) -> None:
    """Loads, or builds once, the kinematic maps' disk cache that every
    episode of a method with the subgoal samplers (every policy but the
    scripted driver) loads; without this, each worker of a fresh machine
    built the same maps at once in its first episode (about 4 minutes each)."""
    if any(m.config.policy != "scripted" for m in methods):
        KinematicMaps.load_or_build()


def run_sweep(
    specs: Iterable[EpisodeSpec],
    out_dir: str | Path,
    workers: int = 1,
    backend: str = "local",
    resume: bool = False,
    episode_fn: EpisodeFn = run_scenario_episode,
    wall_limit: float = 900.0,
    progress: bool = True,
    ray_address: str | None = None,
    keep_episodes: bool = True,
    prepare: Callable[[], None] | None = None,
    retry_errors: bool = False,
) -> list[EpisodeRecord]:
    """Runs the episodes not yet in ``out_dir/results.jsonl`` and appends their records.

    Args:
        specs: the sweep.
        out_dir: results directory.
        workers: episodes in flight at once.
        backend: "local" (process per episode) or "ray".
        resume: skip keys already recorded with the current method file
            (their latest record's ``method_digest``; records from before
            digests were kept count as current); without it, a results file
            that already holds any of these keys is an error (nothing is
            overwritten).
        retry_errors: with ``resume``, run again the episodes whose latest
            record is ``error`` (the new record supersedes it in the report).
        episode_fn: the episode (picklable; a module-level function).
        wall_limit: per-episode wall-clock limit [s].
        progress: show the progress bar.
        ray_address: Ray cluster address (None: start or join a local instance).
        keep_episodes: write each episode's log, episode.json and top-down plot
            to ``out_dir/episodes/<key>/`` (an episode run again overwrites its own).
        prepare: called once in this process before the first episode starts
            (not at all when nothing is left to run): builds what every
            episode would otherwise build at once in each worker, such as the
            kinematic maps' disk cache.

    Returns:
        The records written by this call.

    Raises:
        SweepLockedError: another sweep is writing ``out_dir``.
    """
    if backend not in BACKENDS:
        raise ValueError(f"backend: unknown '{backend}' (known: {', '.join(BACKENDS)})")
    if workers < 1:
        raise ValueError(f"workers: must be >= 1, got {workers}")
    specs = list(specs)
    keys = [s.key for s in specs]
    if len(set(keys)) != len(keys):
        raise ValueError("specs: repeated keys")
    path = Path(out_dir) / RESULTS_FILE
    with results_lock(out_dir), _stop_workers_on_signals():
        latest = recorded(path)
        clash = latest.keys() & set(keys)
        if clash and not resume:
            raise FileExistsError(f"{path} already holds {len(clash)} of these episodes; pass --resume to continue "
                                  "the sweep, or use another --out")
        todo = [s for s in specs if _to_run(s, latest.get(s.key), retry_errors)]
        rerun = [s for s in todo if s.key in latest]
        if rerun:
            changed = sum(1 for s in rerun if latest[s.key].get("status") != ERROR or not retry_errors)
            log.warning("%s: running %d recorded episodes again (%d with an edited method file, %d errors)", path,
                        len(rerun), changed, len(rerun) - changed)
        if keep_episodes:
            episodes = (Path(out_dir) / EPISODES_DIR).resolve()
            todo = [dc.replace(s, episode_dir=str(episodes / episode_dir_name(s.key))) for s in todo]
        if todo and prepare is not None:
            prepare()
        bar = _Progress(len(specs), len(specs) - len(todo), progress)
        written: list[EpisodeRecord] = []
        with ResultsWriter(path) as writer:

            def finish(record: EpisodeRecord) -> None:
                writer.append(record)
                written.append(record)
                bar.update(record)
                if record.status == ERROR:
                    lines = [line for line in record.error.strip().splitlines() if line.strip()]
                    log.warning("%s: error: %s", record.key, lines[-1].strip() if lines else "")

            try:
                if backend == "ray":
                    _run_ray(todo, workers, episode_fn, wall_limit, finish, ray_address)
                else:
                    _run_local(todo, workers, episode_fn, wall_limit, finish)
            finally:
                bar.close()
    return written


def _to_run(spec: EpisodeSpec, latest: dict | None, retry_errors: bool) -> bool:
    """Whether an episode still has to run, given its latest record (or None)."""
    if latest is None:
        return True
    digest = latest.get("method_digest", "")
    if digest and spec.method_digest and digest != spec.method_digest:
        return True  # the method file was edited since
    return retry_errors and latest.get("status") == ERROR


class _StopSweep(SystemExit):
    """Raised in the main thread by SIGTERM / SIGHUP: the sweep stops, its
    workers are killed, and the process exits with 128 + the signal number."""


@contextlib.contextmanager
def _stop_workers_on_signals():
    """SIGTERM and SIGHUP stop the sweep like Ctrl-C does; on any way out
    with an exception every worker still running is killed."""
    previous = {}
    if threading.current_thread() is threading.main_thread():
        def stop(signum, frame):
            log.warning("sweep stopped by %s; killing its workers (finished episodes are kept, "
                        "--resume continues)", signal.Signals(signum).name)
            raise _StopSweep(128 + signum)

        for sig in (signal.SIGTERM, signal.SIGHUP):
            previous[sig] = signal.signal(sig, stop)
    try:
        yield
    except BaseException:
        _kill_live_workers()
        raise
    finally:
        for sig, handler in previous.items():
            signal.signal(sig, handler)


def _run_local(todo: list[EpisodeSpec], workers: int, episode_fn: EpisodeFn, wall_limit: float, finish) -> None:
    pool = ThreadPoolExecutor(max_workers=workers)
    try:
        pending = {pool.submit(run_isolated, spec, episode_fn, wall_limit) for spec in todo}
        while pending:
            complete, pending = wait(pending, return_when=FIRST_COMPLETED)
            for future in complete:
                finish(future.result())
    except BaseException:
        # Kill the workers before waiting for their threads (else each waits out its wall limit).
        pool.shutdown(wait=False, cancel_futures=True)
        _kill_live_workers()
        raise
    pool.shutdown()


def _run_ray(todo: list[EpisodeSpec], workers: int, episode_fn: EpisodeFn, wall_limit: float, finish, address: str | None) -> None:
    try:
        import ray
    except ImportError:
        raise RuntimeError("backend 'ray' needs Ray: pip install 'vamg_drake[ray]' (or pip install 'ray>=2.9')") from None
    started = False
    if not ray.is_initialized():
        ray.init(address=address, num_cpus=None if address else workers, include_dashboard=False, log_to_driver=False)
        started = True
    try:
        remote = ray.remote(num_cpus=1, max_retries=0)(run_isolated)
        queue = list(todo)
        in_flight = {}
        while queue or in_flight:
            while queue and len(in_flight) < workers:
                spec = queue.pop(0)
                in_flight[remote.remote(spec, episode_fn, wall_limit)] = spec
            ready, _ = ray.wait(list(in_flight), num_returns=1)
            for ref in ready:
                spec = in_flight.pop(ref)
                try:
                    record = ray.get(ref)
                except Exception as e:  # noqa: BLE001  a lost Ray worker or node
                    record = _record(spec, ERROR, 0.0, error=f"ray task failed: {' '.join(str(e).split())[:500]}")
                finish(record)
    finally:
        if started:
            ray.shutdown()
