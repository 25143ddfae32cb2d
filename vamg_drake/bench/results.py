"""The results file of a sweep: one JSON object per finished episode.

``DIR/results.jsonl`` is only ever appended to, one whole line per episode,
flushed and fsynced as each episode ends, so a killed sweep loses at most the
line being written. Reading repairs a truncated last line (the signature of a
kill): the fragment is moved to ``results.jsonl.corrupt`` (appended, never
dropped) and the file is cut back to its last whole line, so the episode it
belonged to is simply run again on ``--resume``.

A key may appear more than once (an episode run again: ``--retry-errors``,
or a method file edited since); ``latest_records`` keeps the last record of
each key, and the report counts only those. Every record is checked on
reading (``check_record``): a field of the wrong type is a ``ResultsError``
naming the file, the line and the field, never a crash in the report.
``results_lock`` keeps a second sweep out of a results directory in use.

The failure vocabulary is the paper's (appendix "Evaluation Metrics") and is
written down once, here: ``CATEGORIES``. A status outside it (an old policy's
"timeout", a harness "error") is counted as ``OTHER`` by the report.
"""

import contextlib
import dataclasses as dc
import fcntl
import json
import logging
import math
import os
import typing
from dataclasses import asdict, dataclass, field
from pathlib import Path

log = logging.getLogger(__name__)

SUCCESS = "success"
#: Episode statuses of the paper's results table, in its column order.
CATEGORIES = ("success", "collision", "grasp", "ik", "reachability", "perception", "planning")
#: Failure categories only.
FAILURE_CATEGORIES = CATEGORIES[1:]
#: Column for any status outside ``CATEGORIES``.
OTHER = "other"
#: Status recorded by the harness when the worker crashed, hung or raised.
ERROR = "error"

RESULTS_FILE = "results.jsonl"
CORRUPT_SUFFIX = ".corrupt"
LOCK_FILE = ".sweep.lock"


class ResultsError(ValueError):
    """A results file that cannot be read (a bad line that is not the last one)."""


@dataclass
class EpisodeRecord:
    """One line of results.jsonl.

    Attributes:
        key: unique id of the episode in the sweep (suite/method/scenario/run).
        suite: suite name.
        method: method name.
        scene: scene seed (episodes of one scene share the room).
        target_index: the target slot within the scene.
        target: the target object's name.
        trigger_distance: pedestrian trigger distance [m]; None in static suites.
        run_seed: repetition index.
        scenario: scenario name.
        status: the paper's category (``CATEGORIES``) or another status.
        planning_kind: "timeout" | "subgoal" | "time_limit" | "".
        detail: human-readable reason.
        sim_time: simulated time [s].
        wall_time: wall-clock time of the episode [s] (harness-measured).
        path_length: base path length p_i [m].
        shortest_path: l_i [m] (appendix BFS on the inflated grid); None if no path.
        timings: module -> {count, mean_ms, ...}.
        phases: [[time, phase, reason], ...].
        error: harness error (crash, hang, exception); "" otherwise.
        episode_dir: the episode's log, episode.json and top-down plot, relative to
            the results directory ("": none kept).
        method_digest: hash of the method file's content the episode ran with.
        provenance: code and Drake versions, seed and resolved config
            (`vamg_drake.provenance.provenance`).
    """

    key: str
    suite: str
    method: str
    scene: int
    target_index: int
    target: str
    trigger_distance: float | None
    run_seed: int
    scenario: str
    status: str
    planning_kind: str = ""
    detail: str = ""
    sim_time: float = 0.0
    wall_time: float = 0.0
    path_length: float = 0.0
    shortest_path: float | None = None
    timings: dict = field(default_factory=dict)
    phases: list = field(default_factory=list)
    error: str = ""
    episode_dir: str = ""
    method_digest: str = ""
    provenance: dict = field(default_factory=dict)

    def to_json_line(self) -> str:
        """Returns the record as one line of JSON (with the newline)."""
        return json.dumps(asdict(self), allow_nan=True, separators=(",", ":")) + "\n"


def category_of(status: str) -> str:
    """Maps an episode status onto a table column (``CATEGORIES`` or ``OTHER``)."""
    return status if status in CATEGORIES else OTHER


class ResultsWriter:
    """Appends records to a results file, one fsynced line each."""

    def __init__(self, path: str | Path):
        self.path = Path(path)
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self._file = open(self.path, "a", encoding="utf-8")

    def append(self, record: EpisodeRecord) -> None:
        """Writes one record and forces it to disk."""
        self._file.write(record.to_json_line())
        self._file.flush()
        os.fsync(self._file.fileno())

    def close(self) -> None:
        self._file.close()

    def __enter__(self) -> "ResultsWriter":
        return self

    def __exit__(self, *exc) -> None:
        self.close()


def repair_truncated_tail(path: str | Path) -> str:
    """Cuts an unterminated or unparsable last line off ``path``.

    The fragment is appended to ``path + ".corrupt"``; nothing is dropped.

    Returns:
        The fragment that was moved ("" if the file was whole).
    """
    path = Path(path)
    if not path.is_file():
        return ""
    data = path.read_bytes()
    if not data:
        return ""
    cut = data.rfind(b"\n", 0, len(data) - 1) + 1 if data.endswith(b"\n") else data.rfind(b"\n") + 1
    last = data[cut:]
    try:
        json.loads(last)
    except json.JSONDecodeError:
        pass
    else:
        if not last.endswith(b"\n"):  # whole record, only its newline was lost
            with open(path, "ab") as f:
                f.write(b"\n")
        return ""
    fragment = last.decode("utf-8", errors="replace")
    with open(str(path) + CORRUPT_SUFFIX, "a", encoding="utf-8") as f:
        f.write(fragment if fragment.endswith("\n") else fragment + "\n")
    with open(path, "r+b") as f:
        f.truncate(cut)
    log.warning("%s: last line was cut off (a killed sweep?); moved %d bytes to %s%s, that episode will run again",
                path, len(last), path.name, CORRUPT_SUFFIX)
    return fragment


def load_records(path: str | Path, repair: bool = False) -> list[dict]:
    """Reads every record of a results file.

    Args:
        path: results.jsonl (or a directory holding one).
        repair: cut a truncated last line off the file (see ``repair_truncated_tail``);
            without it, a truncated last line is skipped with a warning.

    Raises:
        FileNotFoundError: no such file.
        ResultsError: a line other than the last is not JSON (names file and line).
    """
    path = Path(path)
    if path.is_dir():
        path = path / RESULTS_FILE
    if not path.is_file():
        raise FileNotFoundError(f"{path}: no results file")
    if repair:
        repair_truncated_tail(path)
    lines = path.read_text(encoding="utf-8").split("\n")
    records = []
    for number, line in enumerate(lines, start=1):
        if not line.strip():
            continue
        try:
            record = json.loads(line)
        except json.JSONDecodeError as e:
            is_last = all(not rest.strip() for rest in lines[number:])
            if is_last:
                log.warning("%s:%d: skipping a truncated last line (%s)", path, number, e.msg)
                continue
            raise ResultsError(f"{path}:{number}: not a JSON record ({e.msg}); fix or remove that line") from None
        if not isinstance(record, dict) or "key" not in record or "status" not in record:
            raise ResultsError(f"{path}:{number}: a record needs at least 'key' and 'status'")
        problems = check_record(record)
        if problems:
            raise ResultsError(f"{path}:{number}: {problems[0]}; fix or remove that line")
        records.append(record)
    return records


_REQUIRED = ("key", "status")


def _type_ok(value, hint) -> bool:
    if value is None:
        return type(None) in typing.get_args(hint) or hint is type(None)
    origin = typing.get_origin(hint)
    options = [a for a in typing.get_args(hint) if a is not type(None)] if origin is not None and origin not in (list, dict) else [hint]
    for option in options:
        base = typing.get_origin(option) or option
        if base is float and isinstance(value, (int, float)) and not isinstance(value, bool):
            return True
        if base is int and isinstance(value, int) and not isinstance(value, bool):
            return True
        if base in (str, dict, list) and isinstance(value, base):
            return True
    return False


def check_record(record: dict) -> list[str]:
    """Problems of one parsed record ("<field>: <message>"); fills missing optional fields in place.

    Every field of ``EpisodeRecord`` that is present must have its type
    (``timings`` a mapping of mappings); ``key`` and ``status`` must be
    present; any other missing field gets its default ("" for the names,
    0 for the indices), so the report never meets a hole.
    """
    problems = []
    hints = typing.get_type_hints(EpisodeRecord)
    for f in dc.fields(EpisodeRecord):
        if f.name not in record:
            if f.name in _REQUIRED:
                problems.append(f"{f.name}: missing")
            elif f.default is not dc.MISSING:
                record[f.name] = f.default
            elif f.default_factory is not dc.MISSING:
                record[f.name] = f.default_factory()
            else:
                record[f.name] = None if f.name == "trigger_distance" else ("" if hints[f.name] is str else 0)
            continue
        value = record[f.name]
        if not _type_ok(value, hints[f.name]):
            problems.append(f"{f.name}: expected {getattr(hints[f.name], '__name__', hints[f.name])}, got {value!r:.60}")
    if not problems:
        for module, t in record["timings"].items():
            if not isinstance(t, dict) or not all(isinstance(v, (int, float)) for v in t.values()):
                problems.append(f"timings.{module}: expected a mapping of numbers, got {t!r:.60}")
                break
        for name in ("shortest_path", "trigger_distance"):
            value = record[name]
            if value is not None and not math.isfinite(value):
                problems.append(f"{name}: must be a finite number or null, got {value}")
    return problems


def latest_records(records: list[dict]) -> list[dict]:
    """The last record of each key (an episode run again replaces its earlier record)."""
    latest: dict[str, dict] = {}
    for record in records:
        latest.pop(record["key"], None)
        latest[record["key"]] = record
    return list(latest.values())


class SweepLockedError(RuntimeError):
    """Another sweep is writing the same results directory."""


@contextlib.contextmanager
def results_lock(directory: str | Path):
    """Holds an exclusive lock on a results directory (``DIR/.sweep.lock``).

    The lock is the kernel's (``flock``): it goes with the process that holds
    it, so a killed sweep leaves no stale lock behind.

    Raises:
        SweepLockedError: another process holds it (names that process).
    """
    directory = Path(directory)
    directory.mkdir(parents=True, exist_ok=True)
    path = directory / LOCK_FILE
    with open(path, "a+", encoding="utf-8") as f:
        try:
            fcntl.flock(f.fileno(), fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            f.seek(0)
            holder = f.read().strip() or "another process"
            raise SweepLockedError(f"{directory}: another sweep ({holder}) is writing these results; "
                                   "wait for it to finish or use another --out") from None
        f.seek(0)
        f.truncate()
        f.write(f"pid {os.getpid()}")
        f.flush()
        try:
            yield
        finally:
            f.seek(0)
            f.truncate()
            fcntl.flock(f.fileno(), fcntl.LOCK_UN)


def finished_keys(path: str | Path) -> set[str]:
    """Keys of the episodes already recorded in ``path`` (empty if absent)."""
    return set(recorded(path))


def recorded(path: str | Path) -> dict[str, dict]:
    """The latest record of each key in ``path`` (empty if absent); repairs a truncated tail."""
    path = Path(path)
    if not path.is_file():
        return {}
    return {r["key"]: r for r in latest_records(load_records(path, repair=True))}
