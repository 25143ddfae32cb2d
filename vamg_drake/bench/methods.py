"""Methods: the full system and the paper's baselines as config files.

A method is a partial ``DiagramConfig`` in YAML under ``vamg_drake/bench/methods/``
(one system underneath, switched by ``policy``, ``strategy`` and ``gaze``):

=======================  ===================================================
full                     the paper's system (subgoal tree, velocity-aware gaze)
velocity_agnostic        gaze without the velocity weights (paper "Baselines")
direct_grasping          fixed observe/navigate/grasp sequence (paper "Baselines")
closed_loop_replanning   continuous replanning to the pre-grasp (appendix)
nav_and_manip            navigate to a fixed distance, then arm only (paper "Baselines")
capmap_placement         capability-map base placement, then arm only (appendix)
scripted, scripted_slow  harness checks with the scripted driver (not paper methods)
=======================  ===================================================

A method may also be given as a path to a YAML file; its name is the file stem.
"""

import hashlib
from dataclasses import dataclass
from pathlib import Path

from vamg_drake.config_validation import InputError, parse_yaml_mapping
from vamg_drake.diagram import DiagramConfig, load_diagram_config

METHODS_DIR = Path(__file__).parent / "methods"
#: The six methods of the paper's results table, in its row order.
PAPER_METHODS = ("nav_and_manip", "capmap_placement", "direct_grasping", "closed_loop_replanning", "velocity_agnostic", "full")


class MethodError(ValueError):
    """An unknown method or a method file that does not load."""


@dataclass(frozen=True)
class Method:
    """A named episode configuration.

    Attributes:
        name: recorded in the results.
        config: the diagram configuration.
        source: the YAML file it came from.
        digest: a short hash of the file's content (part of each episode's
            key, so that a method edited under the same name runs again).
    """

    name: str
    config: DiagramConfig
    source: Path
    digest: str = ""


def known_methods() -> list[str]:
    """Names of the method files shipped with the package."""
    return sorted(p.stem for p in METHODS_DIR.glob("*.yaml"))


def load_method(name: str) -> Method:
    """Loads a method by name (a shipped file) or by path to a YAML file.

    Raises:
        MethodError: unknown name (lists the known ones), a missing file, or
            YAML that does not fit ``DiagramConfig`` (names the file and field).
    """
    path = Path(name)
    if path.suffix in (".yaml", ".yml"):
        if not path.exists():
            raise MethodError(f"method file {path}: no such file")
    else:
        path = METHODS_DIR / f"{name}.yaml"
        if not path.is_file():
            raise MethodError(f"unknown method '{name}' (known: {', '.join(known_methods())}; or give a path to a .yaml file)")
    source = f"method '{path.stem}' ({path})"
    if path.is_dir():
        raise MethodError(f"{source}: is a directory, not a YAML file")
    try:
        data = path.read_bytes()
        text = data.decode("utf-8")
    except OSError as e:
        raise MethodError(f"{source}: cannot be read ({e.strerror or e})") from None
    except UnicodeDecodeError:
        raise MethodError(f"{source}: is a binary file, not YAML") from None
    try:
        if b"\x00" in data:
            raise InputError([f"{source}: is a binary file, not YAML"])
        if not text.strip():
            raise InputError([f"{source}: is empty"])
        declared = parse_yaml_mapping(text, source).get("method")
        config = load_diagram_config(path, source, text)
    except InputError as e:
        raise MethodError(str(e)) from None
    if declared is not None and declared != path.stem:
        raise MethodError(f"{source}: method: says '{declared}'; it must match the file name")
    config.method = path.stem
    return Method(path.stem, config, path, hashlib.sha256(data).hexdigest()[:10])


def load_methods(names: list[str]) -> list[Method]:
    """Loads several methods; every problem is reported at once.

    Raises:
        MethodError: one line per bad method; also for an empty or repeated list.
    """
    if not names:
        raise MethodError(f"no methods given (known: {', '.join(known_methods())})")
    problems, methods = [], []
    for name in names:
        try:
            methods.append(load_method(name))
        except MethodError as e:
            problems.append(str(e))
    seen = [m.name for m in methods]
    repeated = sorted({n for n in seen if seen.count(n) > 1})
    if repeated:
        problems.append(f"methods repeated: {', '.join(repeated)}")
    if problems:
        raise MethodError("\n".join(problems))
    return methods
