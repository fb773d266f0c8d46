"""The package's layering, by static analysis: every module under ``seqdex_drake/`` is parsed with ``ast`` (nothing
is imported, so no Drake or torch) and its ``seqdex_drake`` imports are collected, top-level and inside functions
alike (a lazy import is still a dependency); imports under ``if TYPE_CHECKING:`` are skipped.

Rules: the layers of :data:`LAYERS` follow the data (a scenario becomes a station, sensed and driven by low-level
controllers; tasks define the MDPs, envs wrap them, rl trains, chaining composes, the controller deploys, evaluation
measures, the CLI calls): a module imports only from its own layer or the ones before it. No modules import each
other in a circle. Library code never imports the CLI. An import inside a function is there for an optional
dependency or start-up time and says so in a comment (on its line or the line before). A module's implicit import
of its parent packages is not counted (the root ``__init__`` imports the gym registration).
"""

import ast
import functools
from pathlib import Path

import pytest

PACKAGE_DIR = Path(__file__).resolve().parent.parent / "seqdex_drake"

#: The layers, lowest first: a module may import from its own layer and the ones before it. Each entry is a
#: package or module prefix; the root package (``seqdex_drake/__init__.py``, the public facade) stands above all.
LAYERS = [
    ("plain data", ("seqdex_drake.scenario", "seqdex_drake.atomic", "seqdex_drake.observation_layout",
                    "seqdex_drake.observation_spec", "seqdex_drake.env_state", "seqdex_drake.user_input",
                    "seqdex_drake.numerics")),
    ("models", ("seqdex_drake.robots", "seqdex_drake.modeling")),
    ("scene", ("seqdex_drake.scene",)),
    ("station", ("seqdex_drake.station", "seqdex_drake.manual", "seqdex_drake.harness")),
    ("sensors and low-level control", ("seqdex_drake.sensors", "seqdex_drake.control")),
    ("tasks", ("seqdex_drake.tasks",)),
    ("envs", ("seqdex_drake.envs",)),
    ("rl", ("seqdex_drake.rl",)),
    ("chaining", ("seqdex_drake.chaining",)),
    ("controller", ("seqdex_drake.controller",)),
    ("evaluation", ("seqdex_drake.evaluation",)),
    ("cli", ("seqdex_drake.cli",)),
]

#: The circles the layering broke: neither module of a pair may reach the other back.
BROKEN_PAIRS = [
    ("seqdex_drake.chaining.bidirectional", "seqdex_drake.chaining.single_policy"),
    ("seqdex_drake.chaining.feasibility", "seqdex_drake.chaining.feasibility_io"),
    ("seqdex_drake.controller.inference", "seqdex_drake.controller.inference_feasibility"),
    ("seqdex_drake.envs.subtask_env", "seqdex_drake.tasks.scripted.tool_grasp_script"),
]


def _module_name(path: Path) -> str:
    parts = list(path.relative_to(PACKAGE_DIR.parent).with_suffix("").parts)
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def _is_type_checking(test: ast.expr) -> bool:
    return (isinstance(test, ast.Name) and test.id == "TYPE_CHECKING") or \
        (isinstance(test, ast.Attribute) and test.attr == "TYPE_CHECKING")


class _ImportCollector(ast.NodeVisitor):
    """Collects ``(dotted name, line)`` of every import in a module, lazy ones included, ``TYPE_CHECKING`` ones
    not. ``from a.b import c`` gives ``a.b.c`` (a submodule or a name of ``a.b``; :func:`_resolve` decides)."""

    def __init__(self, module: str, is_package: bool):
        self.module, self.is_package = module, is_package
        self.names: list[tuple[str, int]] = []

    def visit_If(self, node: ast.If) -> None:
        if _is_type_checking(node.test):
            for child in node.orelse:
                self.visit(child)
        else:
            self.generic_visit(node)

    def visit_Import(self, node: ast.Import) -> None:
        self.names += [(alias.name, node.lineno) for alias in node.names]

    def visit_ImportFrom(self, node: ast.ImportFrom) -> None:
        base = node.module or ""
        if node.level:  # Relative: from the module's package, one level up per extra dot.
            package = self.module.split(".") if self.is_package else self.module.split(".")[:-1]
            package = package[:len(package) - (node.level - 1)]
            base = ".".join(package + ([node.module] if node.module else []))
        self.names += [(f"{base}.{alias.name}", node.lineno) for alias in node.names]


def imports_of(source: str, module: str, is_package: bool = False) -> list[tuple[str, int]]:
    """The ``(dotted name, line)`` of every import in ``source`` (see :class:`_ImportCollector`)."""
    collector = _ImportCollector(module, is_package)
    collector.visit(ast.parse(source))
    return collector.names


def _resolve(name: str, modules) -> str | None:
    """The longest known module that ``name`` is or lies in (None outside the package)."""
    parts = name.split(".")
    while parts and ".".join(parts) not in modules:
        parts.pop()
    return ".".join(parts) if parts else None


@functools.cache
def import_graph() -> dict[str, dict[str, int]]:
    """Module -> {imported package module: first line importing it}, over every module of the package."""
    paths = {_module_name(path): path for path in sorted(PACKAGE_DIR.rglob("*.py"))}
    graph = {}
    for module, path in paths.items():
        edges: dict[str, int] = {}
        for name, line in imports_of(path.read_text(), module, path.name == "__init__.py"):
            target = _resolve(name, paths) if name.startswith("seqdex_drake") else None
            if target is not None and target != module:
                edges.setdefault(target, line)
        graph[module] = edges
    return graph


def _in(module: str, package: str) -> bool:
    return module == package or module.startswith(package + ".")


def _violations(importers: str, forbidden: tuple[str, ...]) -> list[str]:
    return [f"{module} (line {line}) imports {target}"
            for module, edges in import_graph().items() if _in(module, importers)
            for target, line in edges.items() if any(_in(target, package) for package in forbidden)]


def _cycles(graph: dict[str, dict[str, int]]) -> list[list[str]]:
    """The strongly connected components of more than one module (Tarjan's algorithm)."""
    index, low, stack, on_stack, components = {}, {}, [], set(), []

    def visit(node: str) -> None:
        index[node] = low[node] = len(index)
        stack.append(node)
        on_stack.add(node)
        for target in graph[node]:
            if target not in index:
                visit(target)
                low[node] = min(low[node], low[target])
            elif target in on_stack:
                low[node] = min(low[node], index[target])
        if low[node] == index[node]:
            component = []
            while True:
                member = stack.pop()
                on_stack.discard(member)
                component.append(member)
                if member == node:
                    break
            if len(component) > 1:
                components.append(sorted(component))

    for node in graph:
        if node not in index:
            visit(node)
    return components


def _reaches(graph: dict[str, dict[str, int]], source: str, target: str) -> bool:
    seen, frontier = {source}, [source]
    while frontier:
        for successor in graph[frontier.pop()]:
            if successor == target:
                return True
            if successor not in seen:
                seen.add(successor)
                frontier.append(successor)
    return False


def test_the_collector_counts_lazy_imports_and_skips_type_checking_ones():
    source = ("from typing import TYPE_CHECKING\nimport seqdex_drake.a\nfrom seqdex_drake.b import c\n"
              "if TYPE_CHECKING:\n    from seqdex_drake.hidden import x\nelse:\n    import seqdex_drake.shown\n"
              "def f():\n    from seqdex_drake.lazy import y\n    from . import sibling\n")
    names = [name for name, _ in imports_of(source, "seqdex_drake.pkg.mod")]
    assert names == ["typing.TYPE_CHECKING", "seqdex_drake.a", "seqdex_drake.b.c", "seqdex_drake.shown",
                     "seqdex_drake.lazy.y", "seqdex_drake.pkg.sibling"]
    modules = {"seqdex_drake", "seqdex_drake.b", "seqdex_drake.b.c", "seqdex_drake.lazy"}
    assert _resolve("seqdex_drake.b.c", modules) == "seqdex_drake.b.c"  # A submodule.
    assert _resolve("seqdex_drake.lazy.y", modules) == "seqdex_drake.lazy"  # A name in a module.


def layer_of(module: str) -> int:
    """The index in :data:`LAYERS` of ``module``'s layer; the root package is above every layer."""
    if module == "seqdex_drake":
        return len(LAYERS)
    for index, (_, prefixes) in enumerate(LAYERS):
        if any(_in(module, prefix) for prefix in prefixes):
            return index
    raise AssertionError(f"{module} is in no layer of LAYERS: add its package to a layer")


def _upward_imports(graph: dict[str, dict[str, int]]) -> list[str]:
    return [f"{module} (line {line}, layer {LAYERS[layer_of(module)][0]!r}) imports {target} (layer "
            f"{LAYERS[layer_of(target)][0]!r})"
            for module, edges in graph.items() if module != "seqdex_drake"
            for target, line in edges.items() if layer_of(target) > layer_of(module)]


def _unexplained_function_imports(path: Path) -> list[str]:
    """Imports inside functions without a comment on their line or the line before."""
    source = path.read_text()
    lines = source.splitlines()
    found = []
    for function in ast.walk(ast.parse(source)):
        if not isinstance(function, ast.FunctionDef | ast.AsyncFunctionDef):
            continue
        for node in ast.walk(function):
            if isinstance(node, ast.Import | ast.ImportFrom):
                before = lines[node.lineno - 2].strip() if node.lineno > 1 else ""
                if "#" not in lines[node.lineno - 1] and "#" not in before:
                    found.append(f"{path.relative_to(PACKAGE_DIR.parent)}:{node.lineno}")
    return found


def test_the_graph_covers_the_package():
    graph = import_graph()
    assert {"seqdex_drake.tasks.rewards", "seqdex_drake.controller.switcher", "seqdex_drake.chaining.rollouts",
            "seqdex_drake.observation_layout", "seqdex_drake.tasks.scripted.tool_grasp_script"} <= graph.keys()
    assert "seqdex_drake.observation_layout" in graph["seqdex_drake.tasks.rewards"]


def test_every_module_is_in_a_layer():
    for module in import_graph():
        layer_of(module)


def test_no_module_imports_a_later_layer():
    assert _upward_imports(import_graph()) == []


def test_the_layer_check_catches_an_upward_import():
    graph = {"seqdex_drake.tasks.base": {"seqdex_drake.envs.subtask_env": 3}, "seqdex_drake.envs.subtask_env": {}}
    assert _upward_imports(graph) == ["seqdex_drake.tasks.base (line 3, layer 'tasks') imports "
                                      "seqdex_drake.envs.subtask_env (layer 'envs')"]


def test_library_code_does_not_import_the_cli():
    library = [line for line in _violations("seqdex_drake", ("seqdex_drake.cli",))
               if not line.startswith("seqdex_drake.cli ") and not line.startswith("seqdex_drake.cli.")]
    assert library == []


@pytest.mark.parametrize(("first", "second"), BROKEN_PAIRS)
def test_the_broken_circles_stay_broken(first, second):
    graph = import_graph()
    assert first in graph and second in graph
    assert not (_reaches(graph, first, second) and _reaches(graph, second, first)), f"{first} <-> {second}"


def test_no_import_cycles():
    assert _cycles(import_graph()) == []


def test_the_cycle_finder_finds_one():
    graph = {"a": {"b": 1}, "b": {"c": 1}, "c": {"a": 1}, "d": {"a": 1}}
    assert _cycles(graph) == [["a", "b", "c"]]


def test_imports_inside_functions_say_why():
    assert [place for path in sorted(PACKAGE_DIR.rglob("*.py")) for place in _unexplained_function_imports(path)] == []


def test_scripts_and_experiments_use_only_the_public_api():
    """Drivers outside the package import no CLI internals (``scripts/simulate_chain.py`` is the CLI's thin entry)."""
    repo = PACKAGE_DIR.parent
    found = []
    for path in sorted([*repo.glob("scripts/*.py"), *repo.glob("experiments/*.py"), *repo.glob("benchmarks/*.py")]):
        for name, line in imports_of(path.read_text(), path.stem):
            allowed = path.name == "simulate_chain.py" and name == "seqdex_drake.cli.main.main"
            if (name == "seqdex_drake.cli" or name.startswith("seqdex_drake.cli.")) and not allowed:
                found.append(f"{path.relative_to(repo)}:{line} imports {name}")
    assert found == []
