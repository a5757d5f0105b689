"""The package's layers (docs/architecture.md): every import goes to a strictly lower rank,
no module imports itself back through others (imports for the type checker included), no
private module is imported from outside its package, imports of the package's own modules
sit at module level outside the entry layers (the facade, the command line, ros/; optional
dependencies such as matplotlib may load late anywhere), only ``strain_comp/ros/`` imports ROS,
docs/architecture.md names every module, and the public API's functions give Args and Returns.

The truth is the source itself: each module's imports read with ``ast``, a circle found by
a depth-first search of the module graph.
"""

from __future__ import annotations

import ast
import re
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PACKAGE = ROOT / "strain_comp"
RANK = {"errors": 0, "_numba": 0, "progress": 0, "version": 0, "io": 1, "base": 2,
        "models": 3, "core": 4, "offline": 5, "diagnosis": 6, "ros": 7, "api": 8, "cli": 9,
        "__init__": 10}
"""Rank of each unit (a top-level module or subpackage; ``__init__`` is the package's facade,
``import strain_comp as sc``); an import from one unit to another must go to a strictly
lower rank."""
LATE_IMPORTS = {"cli", "ros", "__init__"}
"""The entry layers, which may import the package's own modules inside functions: the
command line imports each command's modules when it runs, the node its ROS machinery after
its signal handlers, the facade ``strain_comp.api`` on first use (``strain-comp --version``
loads no numpy; docs/architecture.md gives the measurement)."""
ROS_PACKAGES = {"rclpy", "rcl_interfaces", "std_msgs", "sensor_msgs", "diagnostic_msgs",
                "std_srvs", "rosgraph_msgs", "builtin_interfaces", "ament_index_python"}

SOURCES = sorted(PACKAGE.rglob("*.py"))


def _module(path: Path) -> str:
    """``strain_comp.core.engine`` of ``strain_comp/core/engine.py`` (a package: its name)."""
    parts = list(path.relative_to(ROOT).with_suffix("").parts)
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


MODULES = {_module(p) for p in SOURCES}


def _unit(module: str) -> str:
    """The ranked unit of a module of the package."""
    rest = module.split(".")[1:]
    if not rest:
        return "__init__"
    return rest[0]


def _imports(path: Path) -> list[tuple[str, bool]]:
    """(imported module, inside a function) of every import of ``path``, those under ``if
    TYPE_CHECKING`` included (a circle through the type checker is a circle);
    ``from strain_comp import api`` imports ``strain_comp.api``, not the facade."""
    found: list[tuple[str, bool]] = []

    def visit(node: ast.AST, nested: bool) -> None:
        for child in ast.iter_child_nodes(node):
            if isinstance(child, ast.ImportFrom) and child.module and child.level == 0:
                modules = [f"{child.module}.{a.name}" for a in child.names
                           if f"{child.module}.{a.name}" in MODULES]
                if len(modules) < len(child.names):
                    found.append((child.module, nested))
                found.extend((m, nested) for m in modules)
            elif isinstance(child, ast.Import):
                found.extend((alias.name, nested) for alias in child.names)
            inner = nested or isinstance(child, (ast.FunctionDef, ast.AsyncFunctionDef))
            visit(child, inner)

    visit(ast.parse(path.read_text(encoding="utf-8")), False)
    return found


def _own(name: str) -> str | None:
    """The package's module ``name`` refers to (a name inside a module: that module)."""
    while name and name not in MODULES:
        name = name.rpartition(".")[0]
    return name or None


GRAPH = {_module(p): {m for name, _ in _imports(p) if (m := _own(name)) and m != _module(p)}
         for p in SOURCES}


def test_every_unit_has_a_rank() -> None:
    assert {_unit(m) for m in MODULES} <= set(RANK)


@pytest.mark.parametrize("path", SOURCES, ids=lambda p: str(p.relative_to(PACKAGE)))
def test_imports_go_to_strictly_lower_ranks(path: Path) -> None:
    module = _module(path)
    unit = _unit(module)
    for name, _ in _imports(path):
        top = name.split(".")[0]
        if top in ROS_PACKAGES:
            assert unit == "ros", f"{module} imports {name} outside strain_comp/ros"
        target = _own(name)
        if target is None or target == module:
            continue
        other = _unit(target)
        assert other == unit or RANK[other] < RANK[unit], \
            f"{module} ({unit}, rank {RANK[unit]}) imports {target} ({other}, rank {RANK[other]})"


@pytest.mark.parametrize("path", SOURCES, ids=lambda p: str(p.relative_to(PACKAGE)))
def test_no_late_imports_of_the_package(path: Path) -> None:
    module = _module(path)
    if _unit(module) in LATE_IMPORTS:
        return
    late = [name for name, nested in _imports(path) if nested and _own(name) is not None
            and _own(name) != module]
    assert not late, f"{module} imports {late} inside a function"


@pytest.mark.parametrize("path", SOURCES, ids=lambda p: str(p.relative_to(PACKAGE)))
def test_private_modules_stay_in_their_package(path: Path) -> None:
    """A module whose name starts with ``_`` is imported only from its own package (the
    package's ``_numba`` set-up is everyone's)."""
    module = _module(path)
    for name, _ in _imports(path):
        target = _own(name)
        if target is None or target == "strain_comp._numba":
            continue
        private = [i for i, part in enumerate(target.split(".")) if part.startswith("_")
                   and part != "__init__"]
        if private:
            package = ".".join(target.split(".")[:private[0]])
            assert module.startswith(package + "."), f"{module} imports private {target}"


def _circles(graph: dict[str, set[str]]) -> list[list[str]]:
    """Depth-first search of ``graph``: a module reached again while it is still on the
    path closes a circle (returned as that path)."""
    state: dict[str, int] = {}
    circles: list[list[str]] = []

    def walk(module: str, path: list[str]) -> None:
        state[module] = 1
        for nxt in sorted(graph.get(module, ())):
            if state.get(nxt) == 1:
                circles.append([*path[path.index(nxt):], nxt])
            elif nxt not in state:
                walk(nxt, [*path, nxt])
        state[module] = 2

    for module in sorted(graph):
        if module not in state:
            walk(module, [module])
    return circles


def test_no_import_circles() -> None:
    assert _circles(GRAPH) == []


def test_the_circle_search_finds_a_circle() -> None:
    graph = {"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"a"}, "e": {"d", "b"}}
    assert _circles(graph) == [["a", "b", "c", "a"]]


def test_architecture_md_names_every_module() -> None:
    """docs/architecture.md names each module by its path under strain_comp/ (a file
    ``core/engine.py``; a package's ``__init__.py`` by its directory ``diagnosis/``)."""
    text = (ROOT / "docs" / "architecture.md").read_text(encoding="utf-8")
    named = set(re.findall(r"[\w/]+\.py|[\w/]+/", text))
    missing = []
    for path in SOURCES:
        rel = path.relative_to(PACKAGE).as_posix()
        if rel == "__init__.py":
            continue
        wanted = rel[:-len("__init__.py")] if path.name == "__init__.py" else rel
        if wanted not in named:
            missing.append(wanted)
    assert not missing, f"docs/architecture.md does not name {missing}"


def _docstring_gaps(path: Path) -> list[str]:
    """Public module-level functions of ``path`` whose docstring lacks a section, as
    rosbags writes them: ``Args:`` when the function takes arguments, ``Returns:`` (or
    ``Yields:``) when it returns something other than None."""
    gaps = []
    for node in ast.parse(path.read_text(encoding="utf-8")).body:
        if not isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)) \
                or node.name.startswith("_") \
                or any(ast.unparse(d).endswith("overload") for d in node.decorator_list):
            continue  # a typing overload is a signature; its implementation is documented
        doc = ast.get_docstring(node) or ""
        args = node.args
        takes = args.posonlyargs + args.args + args.kwonlyargs + \
            [a for a in (args.vararg, args.kwarg) if a is not None]
        returns = node.returns is not None and ast.unparse(node.returns) != "None"
        if not doc:
            missing = ["docstring"]
        else:
            missing = [section for section, needed in (("Args:", bool(takes)),
                                                       ("Returns:", returns))
                       if needed and section not in doc
                       and not (section == "Returns:" and "Yields:" in doc)]
        if missing:
            gaps.append(f"{node.name}: no {', '.join(missing)}")
    return gaps


PUBLIC_API = sorted(p for p in (PACKAGE / "api").glob("*.py") if not p.name.startswith("_"))
"""The public API (``strain_comp.api``, which ``strain_comp.__all__`` re-exports; its private
modules aside): only its functions must give Args and Returns; elsewhere a one-line
docstring where the name does not say it, by judgement."""


@pytest.mark.parametrize("path", PUBLIC_API, ids=lambda p: str(p.relative_to(PACKAGE)))
def test_public_api_functions_give_args_and_returns(path: Path) -> None:
    assert _docstring_gaps(path) == []


def test_the_docstring_rule_catches_a_missing_section(tmp_path: Path) -> None:
    module = tmp_path / "m.py"
    module.write_text('def f(x: int) -> int:\n    """Twice x."""\n    return 2 * x\n\n\n'
                      'def g(x: int) -> None:\n    """Print x.\n\n    Args:\n        x: A '
                      'number.\n\n    """\n\n\ndef h() -> int:\n    return 1\n\n\n'
                      'def _p(x: int) -> int:\n    return x\n\n\n@overload\n'
                      'def q(x: int) -> int: ...\n', encoding="utf-8")
    assert _docstring_gaps(module) == ["f: no Args:, Returns:", "h: no docstring"]
