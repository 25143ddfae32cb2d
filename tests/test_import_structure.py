"""The package's import graph: no cycles, no upward imports, no hidden imports.

Every module of ``vamg_drake`` is parsed with ``ast`` (nothing is imported),
and every ``import`` / ``from ... import`` statement is resolved to the
package modules it loads, wherever it stands: at module level, under
``if TYPE_CHECKING:`` (an annotation is a dependency too) or inside a
function or class body. ``from vamg_drake.x import y`` is an edge to ``vamg_drake.x.y`` when
``y`` is a submodule, else to ``vamg_drake.x``.

Layers, lowest first; a module may import modules of its own layer and of
lower layers only:

====  ==================  =====================================================
rank  layer               modules
====  ==================  =====================================================
0     base                ``vamg_drake`` (the package), ``config_validation``
                          (typed YAML loading and range checks of any
                          dataclass), ``provenance`` (git and package versions,
                          atomic writes), ``rendering_check`` (the EGL
                          libraries headless rendering needs), ``scenarios``
                          (shipped scenario files); none imports another
                          package module
1     robot               ``robot.*``: layout, kinematics, spheres, camera
2     perception          ``perception.*``
3     world               ``world.*``
4     planning            ``planning.*``
5     policy, control     ``policy.*``, ``control.*`` (one layer: the tracker
                          and the subgoal policy sit side by side above the
                          planner)
6     systems             ``systems.*``: the LeafSystems
7     diagram             ``diagram``
8     episode             ``episode``
9     bench               ``bench.*``
10    cli                 ``cli``
11    testing             ``testing.*``: seeded workloads and references for
                          the tests and benchmarks, which nothing in the
                          product imports
====  ==================  =====================================================

An import inside a function or class body is forbidden, of a package module
(it would hide a cycle or an upward import) and of a required third-party
package alike (pydrake, scipy, tqdm, ... load at module level). It remains
allowed only for the optional dependencies in `LAZY_OPTIONAL_DEPENDENCIES`,
which a base install does not have, and for the slow-to-import modules in
`LAZY_HEAVY_MODULES` that only one command needs.
"""

import ast
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import vamg_drake

PACKAGE = "vamg_drake"
PACKAGE_DIR = Path(vamg_drake.__file__).parent

#: The rank of each layer (see the module docstring).
LAYERS: dict[str, int] = {
    "base": 0,
    "robot": 1,
    "perception": 2,
    "world": 3,
    "planning": 4,
    "policy": 5,
    "control": 5,
    "systems": 6,
    "diagram": 7,
    "episode": 8,
    "bench": 9,
    "cli": 10,
    "testing": 11,
}

#: The layer of each module or subpackage directly under the package.
TOP_LEVEL: dict[str, str] = {
    "config_validation": "base",
    "provenance": "base",
    "rendering_check": "base",
    "scenarios": "base",
    "robot": "robot",
    "perception": "perception",
    "world": "world",
    "planning": "planning",
    "policy": "policy",
    "control": "control",
    "systems": "systems",
    "diagram": "diagram",
    "episode": "episode",
    "bench": "bench",
    "cli": "cli",
    "testing": "testing",
}

#: Third-party packages that may be imported inside a function, and why: they
#: are optional extras (pyproject.toml), absent from a base install, so a
#: module-level import would break every user of the importing module.
LAZY_OPTIONAL_DEPENDENCIES: dict[str, str] = {
    "ray": "extra 'ray': only the Ray backend of `vamg bench` uses it",
    "ompl": "extras 'reference' and 'test': only reference planners compared against in tests use it",
}

#: Package modules that may be imported inside a function, and why: importing
#: them is slow and only one command needs them, while every command pays for
#: a module-level import.
LAZY_HEAVY_MODULES: dict[str, str] = {
    "vamg_drake.bench.grasp_training": "imports torch (~1.5 s); only `vamg grasps train` trains, `vamg run` never does",
}


@dataclass(frozen=True)
class Import:
    """One import statement's edge from ``module`` to ``target``."""

    module: str
    target: str  # a package module, or a third-party top-level name
    line: int
    local: bool  # inside a function or class body


def _modules() -> dict[str, tuple[Path, bool]]:
    """Every module of the package: dotted name -> (file, is a package)."""
    modules = {}
    for path in sorted(PACKAGE_DIR.rglob("*.py")):
        parts = list(path.relative_to(PACKAGE_DIR.parent).with_suffix("").parts)
        is_package = parts[-1] == "__init__"
        if is_package:
            parts.pop()
        modules[".".join(parts)] = (path, is_package)
    return modules


MODULES = _modules()


def _resolve(module: str, is_package: bool, node: ast.Import | ast.ImportFrom) -> list[str]:
    """The modules (package ones dotted in full, third-party ones by their top
    name) that ``node`` imports."""
    if isinstance(node, ast.Import):
        return [alias.name if alias.name.split(".")[0] == PACKAGE else alias.name.split(".")[0] for alias in node.names]
    if node.level:
        base = module.split(".") if is_package else module.split(".")[:-1]
        base = base[: len(base) - (node.level - 1)]
        name = ".".join(base + ([node.module] if node.module else []))
    else:
        name = node.module or ""
    if name.split(".")[0] != PACKAGE:
        return [name.split(".")[0]]
    targets = []
    for alias in node.names:
        submodule = f"{name}.{alias.name}"
        targets.append(submodule if submodule in MODULES else name)
    return targets


class _ImportCollector(ast.NodeVisitor):
    def __init__(self, module: str, is_package: bool):
        self.module = module
        self.is_package = is_package
        self.depth = 0
        self.imports: list[Import] = []

    def _scope(self, node: ast.AST) -> None:
        self.depth += 1
        self.generic_visit(node)
        self.depth -= 1

    visit_FunctionDef = visit_AsyncFunctionDef = visit_Lambda = visit_ClassDef = _scope

    def visit_Import(self, node: ast.Import | ast.ImportFrom) -> None:
        for target in _resolve(self.module, self.is_package, node):
            self.imports.append(Import(self.module, target, node.lineno, self.depth > 0))

    visit_ImportFrom = visit_Import


def _imports() -> list[Import]:
    imports = []
    for module, (path, is_package) in MODULES.items():
        collector = _ImportCollector(module, is_package)
        collector.visit(ast.parse(path.read_text(), filename=str(path)))
        imports.extend(collector.imports)
    return imports


IMPORTS = _imports()


def _package_edges() -> Iterator[Import]:
    for imp in IMPORTS:
        if imp.target in MODULES and imp.target != imp.module:
            yield imp


def _layer(module: str) -> str:
    parts = module.split(".")
    if len(parts) == 1:
        return "base"
    assert parts[1] in TOP_LEVEL, f"{module}: place '{parts[1]}' in TOP_LEVEL and the docstring's layer table"
    return TOP_LEVEL[parts[1]]


def _cycles(graph: dict[str, set[str]]) -> list[list[str]]:
    """The strongly connected components with more than one module (Tarjan)."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    components: list[list[str]] = []

    def visit(v: str) -> None:
        index[v] = low[v] = len(index)
        stack.append(v)
        on_stack.add(v)
        for w in sorted(graph[v]):
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on_stack:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            component = []
            while True:
                w = stack.pop()
                on_stack.discard(w)
                component.append(w)
                if w == v:
                    break
            if len(component) > 1:
                components.append(sorted(component))

    for v in sorted(graph):
        if v not in index:
            visit(v)
    return components


def test_every_module_is_parsed_and_placed() -> None:
    assert len(MODULES) > 50
    for module in MODULES:
        assert _layer(module) in LAYERS


def test_no_import_cycle() -> None:
    graph: dict[str, set[str]] = {m: set() for m in MODULES}
    for imp in _package_edges():
        graph[imp.module].add(imp.target)
    cycles = _cycles(graph)
    lines = []
    for component in cycles:
        members = set(component)
        lines.append("cycle: " + ", ".join(component))
        lines += sorted({f"    {i.module}:{i.line} -> {i.target}" for i in _package_edges()
                         if i.module in members and i.target in members})
    assert not cycles, "\n".join(lines)


def test_no_upward_import() -> None:
    upward = sorted({
        f"{i.module}:{i.line} ({_layer(i.module)}) -> {i.target} ({_layer(i.target)})"
        for i in _package_edges()
        if LAYERS[_layer(i.target)] > LAYERS[_layer(i.module)]
    })
    assert not upward, "imports from a lower layer to a higher one:\n" + "\n".join(upward)


def test_function_local_imports_only_for_optional_dependencies() -> None:
    local = sorted({
        f"{i.module}:{i.line} imports {i.target} inside a function or class"
        for i in IMPORTS
        if i.local and i.target not in LAZY_OPTIONAL_DEPENDENCIES and i.target not in LAZY_HEAVY_MODULES
    })
    assert not local, "move these imports to the top of their module:\n" + "\n".join(local)


def test_the_checks_see_what_they_check() -> None:
    """The collector resolves submodules, relative and function-local imports."""
    source = (
        "from vamg_drake.robot import layout\n"
        "from . import episode\n"
        "def f():\n"
        "    import ray\n"
        "    from vamg_drake.world.scenario import Scenario\n"
    )
    collector = _ImportCollector("vamg_drake.cli", is_package=False)
    collector.visit(ast.parse(source))
    assert [(i.target, i.local) for i in collector.imports] == [
        ("vamg_drake.robot.layout", False),
        ("vamg_drake.episode", False),
        ("ray", True),
        ("vamg_drake.world.scenario", True),
    ]
    assert _cycles({"a": {"b"}, "b": {"a"}, "c": {"a"}}) == [["a", "b"]]
