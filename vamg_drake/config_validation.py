"""Checking typed YAML files and dataclass configs, one line per problem.

Drake's ``yaml_load_typed`` rejects most malformed input, but not always
naming the field (``could not convert string to float: 'abc'``), and not at
all for values of the right type but out of range (a ``time_step`` of 0
hangs the simulator, a ``period`` of 0 never fires). This module adds:

* ``load_typed_file``: reads a YAML file for a dataclass schema; a missing,
  unreadable, binary, empty or non-mapping file, a YAML syntax error and a
  value of the wrong type (checked against the schema's type hints before
  Drake parses it) each become one ``<file>: <field>: <message>`` line;
* ``value_problems``: every number in a dataclass tree is finite and of its
  declared type (after construction in Python as well as from YAML);
* ``diagram_config_problems``: the range rules of ``DiagramConfig`` (periods
  and steps positive, counts non-negative, min below max, ...), applied
  recursively by field name so that new sub-configs are covered too.

Problems are raised as ``InputError`` (a ValueError); its ``problems`` are
the lines.
"""

import dataclasses as dc
import math
import re
import types
import typing
from pathlib import Path

import yaml
from pydrake.common.yaml import yaml_load_typed


class InputError(ValueError):
    """Bad user input (a file or an argument).

    Attributes:
        problems: one "<source>: <field>: <message>" line per problem.
    """

    def __init__(self, problems: list[str]):
        self.problems = list(problems)
        super().__init__("\n".join(self.problems))


# ------------------------------------------------------------- reading


class _TaggedLoader(yaml.SafeLoader):
    """SafeLoader that keeps Drake's union tags (``!Box``) as a ``__tag__`` key."""


def _construct_tagged(loader: _TaggedLoader, tag_suffix: str, node):
    if isinstance(node, yaml.MappingNode):
        value = loader.construct_mapping(node, deep=True)
    elif isinstance(node, yaml.SequenceNode):
        value = {"__value__": loader.construct_sequence(node, deep=True)}
    else:
        value = {"__value__": loader.construct_scalar(node)}
    value["__tag__"] = tag_suffix
    return value


_TaggedLoader.add_multi_constructor("!", _construct_tagged)


def read_yaml_text(path: Path, source: str) -> str:
    """The text of a YAML file; InputError for a missing, unreadable, binary or empty one."""
    if path.is_dir():
        raise InputError([f"{source}: is a directory, not a YAML file"])
    if not path.is_file():
        raise InputError([f"{source}: no such file"])
    try:
        data = path.read_bytes()
    except OSError as e:
        raise InputError([f"{source}: cannot be read ({e.strerror or e})"]) from None
    if b"\x00" in data:
        raise InputError([f"{source}: is a binary file, not YAML"])
    try:
        text = data.decode("utf-8")
    except UnicodeDecodeError as e:
        raise InputError([f"{source}: is not UTF-8 text (byte {e.start}); not a YAML file"]) from None
    if not text.strip() or all(not line.strip() or line.lstrip().startswith("#") for line in text.splitlines()):
        raise InputError([f"{source}: is empty"])
    return text


def parse_yaml_mapping(text: str, source: str) -> dict:
    """Parses YAML text whose root must be a mapping (tags kept as ``__tag__``)."""
    try:
        data = yaml.load(text, Loader=_TaggedLoader)  # noqa: S506 - a SafeLoader subclass
    except yaml.YAMLError as e:
        mark = getattr(e, "problem_mark", None)
        where = f" (line {mark.line + 1}, column {mark.column + 1})" if mark is not None else ""
        problem = getattr(e, "problem", None) or str(e)
        raise InputError([f"{source}: not valid YAML{where}: {' '.join(str(problem).split())}"]) from None
    if not isinstance(data, dict):
        raise InputError([f"{source}: the top level must be a mapping of fields, got {_kind(data)}"])
    return data


def _kind(value) -> str:
    if value is None:
        return "nothing (null)"
    if isinstance(value, bool):
        return f"a boolean ({value})"
    if isinstance(value, dict):
        return f"a mapping (!{value['__tag__']})" if "__tag__" in value else "a mapping"
    if isinstance(value, list):
        return "a list"
    return f"{type(value).__name__} {value!r}"[:80]


def _is_number(value) -> bool:
    return isinstance(value, (int, float)) and not isinstance(value, bool)


def _join(path: str, name: str) -> str:
    return f"{path}.{name}" if path else name


def schema_problems(schema, data, path: str = "") -> list[str]:
    """Type problems of parsed YAML ``data`` against the type hint ``schema``.

    Returns "<field>: <message>" lines (unknown fields, wrong types, wrong
    tuple lengths, unknown union tags); range checks come later, on the
    loaded dataclass.
    """
    where = path or "(top level)"
    origin = typing.get_origin(schema)
    if origin in (types.UnionType, typing.Union):
        options = typing.get_args(schema)
        if data is None:
            return [] if type(None) in options else [f"{where}: must not be empty"]
        classes = [o for o in options if dc.is_dataclass(o)]
        if isinstance(data, dict) and classes:
            tag = data.get("__tag__")
            if tag is None:
                return schema_problems(classes[0], data, path)
            for cls in classes:
                if cls.__name__ == tag:
                    return schema_problems(cls, data, path)
            return [f"{where}: unknown tag !{tag} (known: {', '.join('!' + c.__name__ for c in classes)})"]
        others = [o for o in options if o is not type(None)]
        if len(others) == 1:
            return schema_problems(others[0], data, path)
        return [f"{where}: expected one of {', '.join(getattr(o, '__name__', str(o)) for o in others)}, got {_kind(data)}"]
    if dc.is_dataclass(schema):
        if not isinstance(data, dict):
            return [f"{where}: expected a mapping of {schema.__name__} fields, got {_kind(data)}"]
        hints = typing.get_type_hints(schema)
        names = [f.name for f in dc.fields(schema)]
        problems = []
        for key, value in data.items():
            if key == "__tag__":
                continue
            if key not in names:
                problems.append(f"{_join(path, str(key))}: unknown field of {schema.__name__} (known: {', '.join(names)})")
                continue
            problems += schema_problems(hints[key], value, _join(path, key))
        return problems
    if origin in (list, tuple):
        if not isinstance(data, list):
            return [f"{where}: expected a list, got {_kind(data)}"]
        args = typing.get_args(schema)
        if origin is tuple and args and args[-1] is not Ellipsis:
            if len(data) != len(args):
                return [f"{where}: expected {len(args)} items, got {len(data)}"]
            element_types = list(args)
        else:
            element_types = [args[0] if args else typing.Any] * len(data)
        problems = []
        for i, (t, value) in enumerate(zip(element_types, data)):
            problems += schema_problems(t, value, f"{where}[{i}]")
        return problems
    if origin is dict:
        return [] if isinstance(data, dict) else [f"{where}: expected a mapping, got {_kind(data)}"]
    if schema is bool:
        return [] if isinstance(data, bool) else [f"{where}: expected true or false, got {_kind(data)}"]
    if schema is int:
        return [] if isinstance(data, int) and not isinstance(data, bool) else [f"{where}: expected an integer, got {_kind(data)}"]
    if schema is float:
        return [] if _is_number(data) else [f"{where}: expected a number, got {_kind(data)}"]
    if schema is str:
        return [] if isinstance(data, str) else [f"{where}: expected a string, got {_kind(data)}"]
    return []


def load_typed_file(path: str | Path, schema, defaults=None, source: str | None = None):
    """Reads a YAML file into dataclass ``schema`` (``defaults`` fill the rest).

    Raises:
        InputError: one "<source>: <field>: <message>" line per problem
            (``source`` defaults to the path as given).
    """
    path = Path(path)
    source = source or str(path)
    text = read_yaml_text(path, source)
    return load_typed_text(text, schema, defaults, source)


def load_typed_text(text: str, schema, defaults=None, source: str = "<string>"):
    """`load_typed_file` for YAML text."""
    data = parse_yaml_mapping(text, source)
    problems = schema_problems(schema, data)
    if problems:
        raise InputError([f"{source}: {p}" for p in problems])
    try:
        if defaults is None:
            return yaml_load_typed(schema=schema, data=text)
        return yaml_load_typed(schema=schema, data=text, defaults=defaults)
    except Exception as e:  # noqa: BLE001 - whatever the schema walk did not foresee, as one line
        raise InputError([f"{source}: does not fit {schema.__name__}: {type(e).__name__}: {' '.join(str(e).split())}"]) from None


# ------------------------------------------------------- checking values


def value_problems(obj, path: str = "") -> list[str]:
    """Type and finiteness problems of a dataclass tree (built in Python or loaded).

    Every float must be a finite number, every int an int, every bool a
    bool, every str a str, lists and tuples of those likewise.
    """
    return _value_problems(obj, type(obj), path)


def _value_problems(value, schema, path: str) -> list[str]:
    where = path or "(top level)"
    origin = typing.get_origin(schema)
    if origin in (types.UnionType, typing.Union):
        options = typing.get_args(schema)
        if value is None:
            return [] if type(None) in options else [f"{where}: must not be empty"]
        for option in options:
            if dc.is_dataclass(option) and isinstance(value, option):
                return _value_problems(value, option, path)
        others = [o for o in options if o is not type(None)]
        return _value_problems(value, others[0], path) if len(others) == 1 else []
    if dc.is_dataclass(schema):
        if not isinstance(value, schema):
            return [f"{where}: expected {schema.__name__}, got {_kind(value)}"]
        hints = typing.get_type_hints(schema)
        problems = []
        for f in dc.fields(schema):
            problems += _value_problems(getattr(value, f.name), hints.get(f.name, typing.Any), _join(path, f.name))
        return problems
    if origin in (list, tuple):
        if not isinstance(value, (list, tuple)):
            return [f"{where}: expected a list, got {_kind(value)}"]
        args = typing.get_args(schema)
        if origin is tuple and args and args[-1] is not Ellipsis:
            if len(value) != len(args):
                return [f"{where}: expected {len(args)} items, got {len(value)}"]
            element_types = list(args)
        else:
            element_types = [args[0] if args else typing.Any] * len(value)
        problems = []
        for i, (t, v) in enumerate(zip(element_types, value)):
            problems += _value_problems(v, t, f"{where}[{i}]")
        return problems
    if schema is bool:
        return [] if isinstance(value, bool) else [f"{where}: expected true or false, got {_kind(value)}"]
    if schema is int:
        return [] if isinstance(value, int) and not isinstance(value, bool) else [f"{where}: expected an integer, got {_kind(value)}"]
    if schema is float:
        if not _is_number(value):
            return [f"{where}: expected a number, got {_kind(value)}"]
        return [] if math.isfinite(value) else [f"{where}: must be a finite number, got {value}"]
    if schema is str:
        return [] if isinstance(value, str) else [f"{where}: expected a string, got {_kind(value)}"]
    return []


# ------------------------------------------------ DiagramConfig ranges

#: Fields (by name, anywhere in the tree) that must be > 0: a zero period
#: never fires or hangs the simulator, a zero resolution divides by zero.
_POSITIVE = re.compile(
    r"^(time_step|period|command_period|head_pan_period|voxel_size|resolution|\w+_resolution|\w+_dt|depth_max"
    r"|speed|turn_rate|attempt_wall_limit_s|turning_radius|rrt_step|lift_height|radius|grasp_radius|crop_radius"
    r"|gain|max_opening|finger_length|finger_width|finger_thickness|max_rate_ratio)$")
#: Integer fields that must be >= 1 (a count of zero makes the component do nothing or fail).
_POSITIVE_INT = re.compile(
    r"^(width|height|max_attempts|num_\w+|max_points|samples_per_base|max_candidates|rrt_max_iterations"
    r"|hybrid_astar_max_expansions|lookahead_waypoints|max_resampled_waypoints|n_diverse|normal_neighbours"
    r"|max_total_failures|max_motion_failures|bspline_samples|attempt_budget_iterations)$")
#: (min field, max field) pairs that must be ordered, in the same sub-config.
_ORDERED = (("depth_min", "depth_max"), ("pan_min", "pan_max"), ("tilt_min", "tilt_max"), ("z_min", "z_max"))
#: Float fields that may be negative (offsets, angles, heights relative to something).
_SIGNED = re.compile(r"^(pan_min|pan_max|tilt_min|tilt_max|head_tilt|floor_z|ground_height|z_min|z_max"
                     r"|fingertip_x|footprint_split_z|\w+_weight)$")


def diagram_config_problems(config) -> list[str]:
    """Type, finiteness and range problems of a ``DiagramConfig`` ("<field>: <message>" lines).

    Ranges by field name, recursively: steps, periods, resolutions and
    voxel sizes > 0; counts >= 0 and the counts in ``_POSITIVE_INT`` >= 1;
    every other float >= 0 except the signed ones (``_SIGNED``); seeds >= 0;
    each (min, max) pair of ``_ORDERED`` ordered.
    """
    return value_problems(config) + _range_problems(config, "")


def _range_problems(obj, path: str) -> list[str]:
    problems = []
    for f in dc.fields(obj):
        value, where = getattr(obj, f.name), _join(path, f.name)
        if dc.is_dataclass(value):
            problems += _range_problems(value, where)
        elif isinstance(value, bool) or value is None:
            continue
        elif isinstance(value, int):
            if _POSITIVE_INT.match(f.name) and value < 1:
                problems.append(f"{where}: must be at least 1, got {value}")
            elif value < 0:
                problems.append(f"{where}: must not be negative, got {value}")
        elif isinstance(value, float) and math.isfinite(value):  # (non-finite: value_problems)
            if _POSITIVE.match(f.name) and not value > 0:
                problems.append(f"{where}: must be positive, got {value}")
            elif not _SIGNED.match(f.name) and value < 0:
                problems.append(f"{where}: must not be negative, got {value}")
        elif isinstance(value, (list, tuple)) and f.name in ("gains", "base_xy", "base_theta", "torso", "arm", "head",
                                                            "fingers", "q_diag", "r_diag", "standoff", "base_radius",
                                                            "contact_offsets", "placement_fractions", "fold_fractions"):
            if any(_is_number(v) and v < 0 for v in value):
                problems.append(f"{where}: must not hold negative numbers, got {list(value)}")
    names = {f.name for f in dc.fields(obj)}
    for lo, hi in _ORDERED:
        if lo in names and hi in names:
            a, b = getattr(obj, lo), getattr(obj, hi)
            if _is_number(a) and _is_number(b) and math.isfinite(a) and math.isfinite(b) and not a < b:
                problems.append(f"{_join(path, lo)}: must be below {hi} ({b}), got {a}")
    return problems


def check_diagram_config(config, source: str = "DiagramConfig") -> None:
    """Raises InputError listing every ``diagram_config_problems`` line as "<source>: <line>"."""
    problems = diagram_config_problems(config)
    if problems:
        raise InputError([f"{source}: {p}" for p in problems])
