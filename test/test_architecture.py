"""The package's layers: each subpackage imports only from the layers below it, and only
``strain_comp/ros/`` imports ROS (docs/architecture.md; docs/design.md, "Layout")."""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

PACKAGE = Path(__file__).resolve().parents[1] / "strain_comp"
LAYER = {"errors": 0, "_numba": 0, "io": 1, "models": 2, "core": 2, "offline": 3,
         "diagnosis": 3, "ros": 4, "cli": 4, "api": 4, "__init__": 4, "progress": 0}
"""Rank of each top-level module or subpackage; an import may only go to an equal or lower
rank (equal: the core's models and engine use each other, as do fit and the loop)."""
ROS_PACKAGES = {"rclpy", "rcl_interfaces", "std_msgs", "sensor_msgs", "diagnostic_msgs",
                "std_srvs", "rosgraph_msgs", "builtin_interfaces", "ament_index_python"}


def _unit(path: Path) -> str:
    parts = path.relative_to(PACKAGE).parts
    return parts[0] if len(parts) > 1 else path.stem


def _imports(path: Path) -> list[str]:
    names: list[str] = []
    for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
        if isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            names.append(node.module)
        elif isinstance(node, ast.Import):
            names.extend(alias.name for alias in node.names)
    return names


SOURCES = sorted(PACKAGE.rglob("*.py"))


def test_every_unit_has_a_layer() -> None:
    assert {_unit(p) for p in SOURCES} <= set(LAYER)


@pytest.mark.parametrize("path", SOURCES, ids=lambda p: str(p.relative_to(PACKAGE)))
def test_imports_follow_the_layers(path: Path) -> None:
    unit = _unit(path)
    for name in _imports(path):
        top = name.split(".")[0]
        if top in ROS_PACKAGES:
            assert unit == "ros", f"{path}: imports {name} outside strain_comp/ros"
        if top == "strain_comp" and "." in name:
            target = name.split(".")[1]
            assert LAYER[target] <= LAYER[unit], f"{path}: {unit} imports {name} (a higher layer)"
