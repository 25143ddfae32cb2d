"""Scenario suites: the paper's 20 scenes x 20 targets, validated.

A suite is ``scenes`` procedural rooms (scene seeds ``first_scene_seed`` ...)
times ``targets_per_scene`` target slots. Slot 0 is the generator's own
scenario; slot k re-targets the same room (``rooms.retarget_scenario``) to
the scene's k-th eligible object (cycling when a room holds fewer eligible
objects than slots; every slot gets its own start and dynamic events, drawn
from the seed ``scene * 1000 + k``). Every scenario is validated as the
appendix says: objects were placed by the drop check (in the generator),
``validate_scenario`` passes, and the **oracle grasp check** lifts the target
with a free gripper; objects it cannot lift are excluded (recorded in the
manifest with the reason) and the slot moves to the next eligible object.

``materialize_suite`` writes the scenario files and a manifest under
``DIR/suites/<name>/`` once; a second call (``--resume``) reads them back,
validating every file, and refuses a manifest built with another config.

``paper_static`` and ``paper_dynamic`` are the paper authors' own ReplicaCAD
tasks (their task file, found with ``$VAMG_PAPER_TASKS``), imported with
``vamg_drake.world.paper_tasks``: all objects of a scene in every task, the
authors' start, and in the dynamic suite their pedestrian box and
manipulation boxes; ``import.json`` beside the manifest records each scene's
apartment match and every object's settling displacement.

Dynamic suites get the paper's pedestrian (trigger distance ``trigger_distances``,
default 1.7 m) and table-top box; ``dynamic_moving`` adds an obstacle moving at
0.2 m/s across the room; ``trigger_sweep`` runs every scenario at five trigger
distances (appendix "Obstacle Distance Analysis").
"""

import dataclasses as dc
import json
import logging
import os
from dataclasses import dataclass, field
from pathlib import Path

from tqdm import tqdm

from vamg_drake.bench.metrics import ShortestPathConfig, shortest_base_path
from vamg_drake.bench.oracle_grasp import OracleGraspConfig, check_graspable
from vamg_drake.config_validation import InputError, load_typed_file
from vamg_drake.world.paper_tasks import PaperTaskConfig, TaskFileError, import_scene, read_task_file
from vamg_drake.world.replicacad import ReplicaCadError, find_replicacad_dir
from vamg_drake.world.replicacad_generator import generate_replicacad_scenario
from vamg_drake.world.rooms import GenerationError, RoomGeneratorConfig, generate_scenario, retarget_scenario, target_candidates
from vamg_drake.world.scenario import AppearAtDistance, Scenario, ScenarioError, load_scenario, save_scenario

log = logging.getLogger(__name__)


class SuiteError(ValueError):
    """An unknown suite, a bad suite file, or scenario files that fail validation."""


@dataclass
class SuiteConfig:
    """A benchmark suite.

    Attributes:
        name: suite name (results are grouped by it).
        scenes: number of rooms.
        targets_per_scene: target slots per room.
        first_scene_seed: seed of the first room.
        dynamic: the paper's pedestrian and table-top box.
        moving_obstacle: an obstacle moving at 0.2 m/s.
        trigger_distances: pedestrian trigger distances [m]; each scenario runs at each.
        time_limit: episode time limit [s] (simulated).
        oracle: run the oracle grasp check.
        oracle_config: its parameters.
        room: generator parameters (``dynamic``, ``moving_obstacle`` and
            ``time_limit`` above override its fields).
        shortest_path: the SPL grid.
        replicacad_scenes: ReplicaCAD scene instances to draw the rooms from
            instead of the procedural generator (cycled over ``scenes``; each
            target slot is a fresh generator seed in that scene); the dataset
            is looked up with `vamg_drake.world.replicacad.find_replicacad_dir`.
        paper_tasks: the scenarios are the paper authors' ReplicaCAD tasks
            (``vamg_drake.world.paper_tasks``): the first ``scenes`` scenes of
            the task file, the first ``targets_per_scene`` tasks of each.
        task_file: the authors' task file (empty: ``$VAMG_PAPER_TASKS``).
        paper_task_config: how the tasks are imported (``time_limit`` above overrides its own).
    """

    name: str = ""
    scenes: int = 20
    targets_per_scene: int = 20
    first_scene_seed: int = 0
    dynamic: bool = False
    moving_obstacle: bool = False
    trigger_distances: list[float] = field(default_factory=lambda: [1.7])
    time_limit: float = 120.0
    oracle: bool = True
    oracle_config: OracleGraspConfig = field(default_factory=OracleGraspConfig)
    room: RoomGeneratorConfig = field(default_factory=RoomGeneratorConfig)
    shortest_path: ShortestPathConfig = field(default_factory=ShortestPathConfig)
    replicacad_scenes: list[str] = field(default_factory=list)
    paper_tasks: bool = False
    task_file: str = ""
    paper_task_config: PaperTaskConfig = field(default_factory=PaperTaskConfig)

    def room_config(self) -> RoomGeneratorConfig:
        return dc.replace(self.room, dynamic=self.dynamic, moving_obstacle=self.moving_obstacle, time_limit=self.time_limit)


#: The built-in suites.
SUITES: dict[str, SuiteConfig] = {
    "smoke": SuiteConfig(name="smoke", scenes=2, targets_per_scene=1, time_limit=3.0),
    "static": SuiteConfig(name="static"),
    "dynamic": SuiteConfig(name="dynamic", dynamic=True),
    "dynamic_moving": SuiteConfig(name="dynamic_moving", dynamic=True, moving_obstacle=True),
    "trigger_sweep": SuiteConfig(name="trigger_sweep", dynamic=True, targets_per_scene=5, trigger_distances=[0.5, 1.0, 1.5, 2.0, 2.5]),
    "replicacad": SuiteConfig(name="replicacad", scenes=3, targets_per_scene=5,
                              replicacad_scenes=["apt_0", "v3_sc0_staging_00", "v3_sc1_staging_00"]),
    # The paper's own benchmark: the authors' task file (20 scenes x 20 tasks).
    "paper_static": SuiteConfig(name="paper_static", paper_tasks=True),
    "paper_dynamic": SuiteConfig(name="paper_dynamic", paper_tasks=True, dynamic=True),
}

#: Where ``paper_static`` / ``paper_dynamic`` find the authors' task file when the suite names none.
TASK_FILE_ENV = "VAMG_PAPER_TASKS"


@dataclass(frozen=True)
class SuiteScenario:
    """One validated scenario of a suite.

    Attributes:
        id: "s<scene>_t<slot>", unique in the suite.
        scene: scene seed.
        target_index: target slot.
        target: target object.
        file: scenario YAML, relative to the suite directory.
        shortest_path: l_i for SPL [m] (None: no grid path).
    """

    id: str
    scene: int
    target_index: int
    target: str
    file: str
    shortest_path: float | None


@dataclass
class Suite:
    """A materialized suite: config, directory and scenarios."""

    config: SuiteConfig
    directory: Path
    scenarios: list[SuiteScenario]
    excluded: list[dict]

    def load(self, scenario: SuiteScenario) -> Scenario:
        """Loads (and validates) one scenario file."""
        return load_scenario(self.directory / scenario.file)


def suite_config(name_or_path: str, scenes: int | None = None, targets: int | None = None) -> SuiteConfig:
    """A built-in suite by name, or a ``SuiteConfig`` YAML file; sizes may be overridden.

    Raises:
        SuiteError: unknown name (lists the known ones) or a file that does not load.
    """
    path = Path(name_or_path)
    if name_or_path in SUITES:
        config = dc.replace(SUITES[name_or_path])
    elif path.suffix in (".yaml", ".yml"):
        if not path.exists():
            raise SuiteError(f"suite file {path}: no such file")
        try:
            config = load_typed_file(path, SuiteConfig, SuiteConfig(name=path.stem), source=f"suite file {path}")
        except InputError as e:  # names the file and the field
            raise SuiteError(str(e)) from None
    else:
        raise SuiteError(f"unknown suite '{name_or_path}' (known: {', '.join(SUITES)}; or a .yaml SuiteConfig file)")
    if scenes is not None:
        config.scenes = scenes
    if targets is not None:
        config.targets_per_scene = targets
    problems = []
    if not config.name:
        problems.append("name: empty")
    if config.scenes < 1:
        problems.append(f"scenes: must be >= 1, got {config.scenes}")
    if config.targets_per_scene < 1:
        problems.append(f"targets_per_scene: must be >= 1, got {config.targets_per_scene}")
    if not config.trigger_distances or any(d <= 0 for d in config.trigger_distances):
        problems.append(f"trigger_distances: need positive distances, got {config.trigger_distances}")
    if config.time_limit <= 0:
        problems.append(f"time_limit: must be > 0, got {config.time_limit}")
    if problems:
        raise SuiteError(f"suite '{config.name or name_or_path}': " + "; ".join(problems))
    return config


def with_trigger_distance(scenario: Scenario, distance: float | None) -> Scenario:
    """Sets every appear-at-distance event's trigger distance (None: unchanged)."""
    if distance is not None:
        for event in scenario.dynamic_events:
            if isinstance(event, AppearAtDistance):
                event.trigger_distance = float(distance)
    return scenario


def _manifest_path(directory: Path) -> Path:
    return directory / "manifest.json"


def _config_json(config: SuiteConfig) -> dict:
    return json.loads(json.dumps(dc.asdict(config), default=str))


def materialize_suite(config: SuiteConfig, out_dir: str | Path, progress: bool = True) -> Suite:
    """Builds (or reads back) the suite's scenario files under ``out_dir/suites/<name>``.

    Raises:
        SuiteError: the directory holds this suite built with another config, or
            a scenario file fails validation (every bad file is listed).
    """
    directory = Path(out_dir) / "suites" / config.name
    manifest = _manifest_path(directory)
    if manifest.is_file():
        data = json.loads(manifest.read_text())
        if data["config"] != _config_json(config):
            raise SuiteError(f"{manifest}: suite '{config.name}' was built with another config; use another --out or the same sizes")
        suite = Suite(config, directory, [SuiteScenario(**s) for s in data["scenarios"]], data["excluded"])
        validate_suite_files(suite)
        return suite
    return _build(config, directory, progress)


def validate_suite_files(suite: Suite) -> None:
    """Loads every scenario file of a suite; raises one SuiteError listing all bad ones."""
    problems = []
    for s in suite.scenarios:
        try:
            scenario = suite.load(s)
        except ScenarioError as e:
            problems.append(str(e))
            continue
        if scenario.target != s.target:
            problems.append(f"{s.file}: target: '{scenario.target}' but the manifest says '{s.target}'")
    if problems:
        raise SuiteError(f"suite '{suite.config.name}' in {suite.directory}: scenario files fail validation:\n" + "\n".join(problems))


def _build(config: SuiteConfig, directory: Path, progress: bool) -> Suite:
    if config.paper_tasks:
        return _build_paper_tasks(config, directory, progress)
    if config.replicacad_scenes:
        return _build_replicacad(config, directory, progress)
    room_config = config.room_config()
    (directory / "scenarios").mkdir(parents=True, exist_ok=True)
    scenarios: list[SuiteScenario] = []
    excluded: list[dict] = []
    bar = tqdm(total=config.scenes * config.targets_per_scene, desc=f"suite {config.name}", disable=not progress, leave=False)
    for scene in range(config.first_scene_seed, config.first_scene_seed + config.scenes):
        try:
            base = generate_scenario(scene, room_config)
        except GenerationError as e:
            excluded.append({"scene": scene, "object": None, "reason": str(e)})
            bar.update(config.targets_per_scene)
            continue
        names = [base.target] + [n for n in target_candidates(base, room_config) if n != base.target]
        graspable: dict[str, bool] = {}

        def is_graspable(name: str) -> bool:
            if not config.oracle:
                return True
            if name not in graspable:
                result = check_graspable(base, name, config.oracle_config)
                graspable[name] = result.graspable
                if not result.graspable:
                    excluded.append({"scene": scene, "object": name, "reason": f"oracle grasp check: {result.reason}"})
            return graspable[name]

        usable = [n for n in names if is_graspable(n)]
        for slot in range(config.targets_per_scene):
            bar.update(1)
            if not usable:
                break
            name = usable[slot % len(usable)]
            scenario = base if (slot == 0 and name == base.target) else retarget_scenario(base, name, scene * 1000 + slot, room_config)
            if scenario is None:
                excluded.append({"scene": scene, "object": name, "reason": f"slot {slot}: no start/events fit"})
                continue
            sid = f"s{scene:04d}_t{slot:02d}"
            scenario.name = f"{config.name}_{sid}"
            file = f"scenarios/{sid}.yaml"
            save_scenario(scenario, directory / file)
            scenarios.append(SuiteScenario(sid, scene, slot, name, file, shortest_base_path(scenario, config.shortest_path)))
    bar.close()
    return _write_manifest(config, directory, scenarios, excluded)


def _build_replicacad(config: SuiteConfig, directory: Path, progress: bool) -> Suite:
    """Scenarios in ReplicaCAD scenes: scene k is replicacad_scenes[k % n], slot t is generator seed 1000 k + t."""
    dataset = find_replicacad_dir()
    if dataset is None:
        raise SuiteError(f"suite {config.name}: no ReplicaCAD dataset found (set MS_ASSET_DIR, VAMG_REPLICACAD_DIR, "
                         "or download it with `python -m mani_skill.utils.download_asset ReplicaCAD`)")
    (directory / "scenarios").mkdir(parents=True, exist_ok=True)
    scenarios: list[SuiteScenario] = []
    excluded: list[dict] = []
    bar = tqdm(total=config.scenes * config.targets_per_scene, desc=f"suite {config.name}", disable=not progress, leave=False)
    for scene in range(config.first_scene_seed, config.first_scene_seed + config.scenes):
        scene_name = config.replicacad_scenes[scene % len(config.replicacad_scenes)]
        for slot in range(config.targets_per_scene):
            bar.update(1)
            try:
                scenario = generate_replicacad_scenario(scene_name, scene * 1000 + slot, dataset)
            except (ReplicaCadError, GenerationError) as e:
                excluded.append({"scene": scene, "object": None, "reason": f"{scene_name}: {e}"})
                continue
            scenario.time_limit = config.time_limit
            kept = _keep_graspable(config, directory, scenario, scene, slot, f"{config.name}_{scene_name}", None, excluded)
            if kept is not None:
                scenarios.append(kept)
    bar.close()
    return _write_manifest(config, directory, scenarios, excluded)


def _keep_graspable(config: SuiteConfig, directory: Path, scenario: Scenario, scene: int, slot: int, prefix: str,
                    shortest_path: float | None, excluded: list[dict]) -> SuiteScenario | None:
    """Writes ``scenario`` as slot ``slot`` of ``scene`` if the oracle lifts its target, else records the exclusion."""
    if config.oracle:
        result = check_graspable(scenario, scenario.target, config.oracle_config)
        if not result.graspable:
            excluded.append({"scene": scene, "object": scenario.target, "task": slot,
                             "reason": f"oracle grasp check: {result.reason}"})
            return None
    sid = f"s{scene:04d}_t{slot:02d}"
    scenario.name = f"{prefix}_{sid}"
    file = f"scenarios/{sid}.yaml"
    save_scenario(scenario, directory / file)
    return SuiteScenario(sid, scene, slot, scenario.target, file, shortest_path)


def resolve_task_file(config: SuiteConfig) -> Path:
    """The suite's task file: ``task_file``, else ``$VAMG_PAPER_TASKS``.

    Raises:
        SuiteError: neither is set, or the file does not exist.
    """
    path = config.task_file or os.environ.get(TASK_FILE_ENV, "")
    if not path:
        raise SuiteError(f"suite {config.name}: no task file: set {TASK_FILE_ENV}, pass --task-file, "
                         "or set task_file in the suite file (the paper authors' grasp_benchmark.json)")
    if not Path(path).is_file():
        raise SuiteError(f"suite {config.name}: task file {path}: no such file")
    return Path(path)


def _build_paper_tasks(config: SuiteConfig, directory: Path, progress: bool) -> Suite:
    """The authors' tasks: scene k of the file is suite scene k, task t its target slot t."""
    if find_replicacad_dir() is None:
        raise SuiteError(f"suite {config.name}: no ReplicaCAD dataset found (set MS_ASSET_DIR, VAMG_REPLICACAD_DIR, "
                         "or download it with `python -m mani_skill.utils.download_asset ReplicaCAD`)")
    path = resolve_task_file(config)
    try:
        scenes = read_task_file(path)[: config.scenes]
    except TaskFileError as e:
        raise SuiteError(str(e)) from None
    import_config = dc.replace(config.paper_task_config, time_limit=config.time_limit)
    (directory / "scenarios").mkdir(parents=True, exist_ok=True)
    scenarios: list[SuiteScenario] = []
    excluded: list[dict] = []
    imports: list[dict] = []
    bar = tqdm(total=sum(min(len(s.tasks), config.targets_per_scene) for s in scenes), desc=f"suite {config.name}",
               disable=not progress, leave=False)
    for scene in scenes:
        wanted = [t.index for t in scene.tasks[: config.targets_per_scene]]
        try:
            imported = import_scene(scene, config.dynamic, None, import_config, wanted)
        except (TaskFileError, ReplicaCadError) as e:
            excluded.append({"scene": scene.index, "object": None, "reason": str(e)})
            bar.update(len(wanted))
            continue
        imports.append(imported.report())
        for index, reason in imported.excluded:
            excluded.append({"scene": scene.index, "object": scene.tasks[index].model_id, "task": index, "reason": reason})
            bar.update(1)
        for index, scenario in imported.scenarios:
            bar.update(1)
            kept = _keep_graspable(config, directory, scenario, scene.index, index, config.name,
                                   shortest_base_path(scenario, config.shortest_path), excluded)
            if kept is not None:
                scenarios.append(kept)
    bar.close()
    tmp = directory / "import.json.tmp"
    tmp.write_text(json.dumps({"task_file": str(path), "scenes": imports}, indent=1))
    tmp.replace(directory / "import.json")
    return _write_manifest(config, directory, scenarios, excluded)


def _write_manifest(config: SuiteConfig, directory: Path, scenarios: list, excluded: list) -> Suite:
    manifest = {"config": _config_json(config), "scenarios": [dc.asdict(s) for s in scenarios], "excluded": excluded}
    tmp = _manifest_path(directory).with_suffix(".tmp")
    tmp.write_text(json.dumps(manifest, indent=1))
    tmp.replace(_manifest_path(directory))
    log.info("suite %s: %d scenarios, %d exclusions", config.name, len(scenarios), len(excluded))
    return Suite(config, directory, scenarios, excluded)
