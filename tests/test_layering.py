"""The package's layering, by static analysis: every module under ``seqdex_drake/`` is parsed with ``ast`` (nothing
is imported, so no Drake or torch) and its ``seqdex_drake`` imports are collected, top-level and inside functions
alike (a lazy import is still a dependency); imports under ``if TYPE_CHECKING:`` are skipped.

Rules: ``tasks/`` does not import ``systems/`` (the observation layout they read is
``seqdex_drake/observation_layout.py``); ``chaining/`` imports neither the switcher system nor ``envs/``; the
observation layout and the env state sit below ``systems/``, ``tasks/``, ``envs/`` and ``chaining/``; and no
modules import each other in a circle, except the known one between the sub-tasks and their env (see
:data:`KNOWN_CYCLE_PREFIXES`). A module's implicit import of its parent packages is not counted (the root
``__init__`` imports the gym registration, which would put every module in one circle).
"""

import ast
import functools
from pathlib import Path

import pytest

PACKAGE_DIR = Path(__file__).resolve().parent.parent / "seqdex_drake"

#: The one circle left, out of this layering's scope: ``tasks.registry.make_env`` builds a ``SubtaskEnv`` (which
#: imports ``tasks.base``), and ``TaskConfig``'s validation reaches ``scene.tool_grasp_script`` (through
#: ``tasks.residual``), whose ``measure`` builds a ``SubtaskEnv`` from the registry. Modules of a circle must all
#: start with one of these prefixes; any other circle fails.
KNOWN_CYCLE_PREFIXES = ("seqdex_drake.tasks.", "seqdex_drake.envs.subtask_env", "seqdex_drake.scene.tool_grasp_script")

#: The circles this layering broke: neither module of a pair may reach the other back.
BROKEN_PAIRS = [
    ("seqdex_drake.chaining.bidirectional", "seqdex_drake.chaining.single_policy"),
    ("seqdex_drake.chaining.feasibility", "seqdex_drake.chaining.feasibility_io"),
    ("seqdex_drake.systems.inference", "seqdex_drake.systems.inference_feasibility"),
]

LOW_MODULES = ("seqdex_drake.observation_layout", "seqdex_drake.env_state")
UPPER_PACKAGES = ("seqdex_drake.systems", "seqdex_drake.tasks", "seqdex_drake.envs", "seqdex_drake.chaining")


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


def test_the_graph_covers_the_package():
    graph = import_graph()
    assert {"seqdex_drake.tasks.rewards", "seqdex_drake.systems.switcher", "seqdex_drake.chaining.rollouts",
            "seqdex_drake.observation_layout"} <= graph.keys()
    assert "seqdex_drake.observation_layout" in graph["seqdex_drake.tasks.rewards"]


def test_tasks_do_not_import_systems():
    assert _violations("seqdex_drake.tasks", ("seqdex_drake.systems",)) == []


def test_chaining_imports_neither_the_switcher_nor_envs():
    assert _violations("seqdex_drake.chaining", ("seqdex_drake.systems.switcher", "seqdex_drake.envs")) == []


@pytest.mark.parametrize("module", LOW_MODULES)
def test_the_layout_modules_sit_below_systems_tasks_envs_and_chaining(module):
    assert module in import_graph()
    assert _violations(module, UPPER_PACKAGES) == []


@pytest.mark.parametrize(("first", "second"), BROKEN_PAIRS)
def test_the_broken_circles_stay_broken(first, second):
    graph = import_graph()
    assert first in graph and second in graph
    assert not (_reaches(graph, first, second) and _reaches(graph, second, first)), f"{first} <-> {second}"


def test_no_import_cycles_but_the_known_one():
    unexpected = [cycle for cycle in _cycles(import_graph())
                  if not all(module.startswith(KNOWN_CYCLE_PREFIXES) for module in cycle)]
    assert unexpected == []
