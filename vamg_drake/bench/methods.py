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

import dataclasses as dc
from dataclasses import dataclass
from pathlib import Path

import yaml
from pydrake.common.yaml import yaml_load_typed

from vamg_drake.diagram import DiagramConfig

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
    """

    name: str
    config: DiagramConfig
    source: Path


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
        if not path.is_file():
            raise MethodError(f"method file {path}: no such file")
    else:
        path = METHODS_DIR / f"{name}.yaml"
        if not path.is_file():
            raise MethodError(f"unknown method '{name}' (known: {', '.join(known_methods())}; or give a path to a .yaml file)")
    text = path.read_text()
    try:
        config = yaml_load_typed(schema=DiagramConfig, data=text, defaults=DiagramConfig())
    except Exception as e:  # Drake raises RuntimeError / ValueError naming the field
        message = " ".join(str(e).split())
        fields = ", ".join(f.name for f in dc.fields(DiagramConfig))
        raise MethodError(f"method '{path.stem}' ({path}): does not fit DiagramConfig: {message} (DiagramConfig fields: {fields})") from None
    declared = (yaml.safe_load(text) or {}).get("method")
    if declared is not None and declared != path.stem:
        raise MethodError(f"method '{path.stem}' ({path}): field 'method' says '{declared}'; it must match the file name")
    if hasattr(config, "method"):
        config.method = path.stem
    return Method(path.stem, config, path)


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
