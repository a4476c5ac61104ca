"""Launch files parse and name executables that exist (ROS 2 launch is not installed here).

The launch modules are imported with stub ``launch`` / ``launch_ros`` packages in sys.modules
whose classes record their arguments; the test then walks the returned description.
"""

from __future__ import annotations

import ast
import importlib.util
import sys
import types
from pathlib import Path
from typing import Any

import pytest

ROOT = Path(__file__).resolve().parents[2]


class Recorded:
    """Instance of a stub launch class: remembers its class name, args and kwargs."""

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        self.args = args
        self.kwargs = kwargs

    def __repr__(self) -> str:
        return f"{type(self).__name__}({self.args}, {self.kwargs})"


class StubModule(types.ModuleType):
    """A module whose every attribute is a fresh Recorded subclass of that name."""

    def __getattr__(self, name: str) -> Any:
        if name.startswith("__"):
            raise AttributeError(name)
        cls = type(name, (Recorded,), {})
        setattr(self, name, cls)
        return cls


STUBS = (
    "launch",
    "launch.actions",
    "launch.conditions",
    "launch.event_handlers",
    "launch.events",
    "launch.substitutions",
    "launch_ros",
    "launch_ros.actions",
    "launch_ros.parameter_descriptions",
)


@pytest.fixture
def stub_launch(monkeypatch: pytest.MonkeyPatch) -> None:
    for name in STUBS:
        monkeypatch.setitem(sys.modules, name, StubModule(name))


def _load(path: Path) -> Any:
    spec = importlib.util.spec_from_file_location(f"launch_under_test_{path.stem}", path)
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def console_scripts(package: str) -> set[str]:
    """Console script names declared in <package>/setup.py (parsed, not executed)."""
    tree = ast.parse((ROOT / package / "setup.py").read_text())
    names: set[str] = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Dict):
            for key, value in zip(node.keys, node.values, strict=True):
                if isinstance(key, ast.Constant) and key.value == "console_scripts":
                    for elt in getattr(value, "elts", []):
                        names.add(str(ast.literal_eval(elt)).split("=")[0].strip())
    return names


def _nodes(description: Any) -> list[Recorded]:
    (entities,) = description.args
    return [e for e in entities if type(e).__name__ == "Node"]


def _arguments(description: Any) -> dict[str, str]:
    (entities,) = description.args
    return {
        e.args[0]: e.kwargs["default_value"]
        for e in entities
        if type(e).__name__ == "DeclareLaunchArgument"
    }


LAUNCH_FILES = [
    ROOT / "dbcslam_ros" / "launch" / "demo.launch.py",
    ROOT / "sim_publisher" / "launch" / "sim.launch.py",
]


@pytest.mark.parametrize("path", LAUNCH_FILES, ids=lambda p: p.name)
def test_launch_executables_are_console_scripts(stub_launch: None, path: Path) -> None:
    description = _load(path).generate_launch_description()
    nodes = _nodes(description)
    assert nodes
    for node in nodes:
        package = node.kwargs["package"]
        executable = node.kwargs["executable"]
        assert (ROOT / package / "package.xml").is_file(), package
        assert executable in console_scripts(package), (package, executable)


def test_demo_launch_runs_sim_filter_and_optional_recorder(stub_launch: None) -> None:
    description = _load(LAUNCH_FILES[0]).generate_launch_description()
    args = _arguments(description)
    assert args["scenario"] == "gripper"
    assert {"engine", "fast", "particles", "record", "bag"} <= set(args)
    by_exec: dict[str, list[Recorded]] = {}
    for node in _nodes(description):
        by_exec.setdefault(node.kwargs["executable"], []).append(node)
    assert [n.kwargs["name"] for n in by_exec["sim_node"]] == ["sim_publisher"]
    assert {n.kwargs["name"] for n in by_exec["filter_node"]} == {"dbcslam_filter"}
    (recorder,) = by_exec["dbcslam"]
    assert recorder.kwargs["arguments"][:2] == ["record", "-o"]
    assert type(recorder.kwargs["condition"]).__name__ == "IfCondition"
    # the sim node gets every parameter the node declares
    from sim_publisher.node import PARAMETERS

    (sim,) = by_exec["sim_node"]
    assert set(sim.kwargs["parameters"][0]) <= set(PARAMETERS)


def test_sim_launch_parameters_are_declared_by_the_node(stub_launch: None) -> None:
    from sim_publisher.node import PARAMETERS

    description = _load(LAUNCH_FILES[1]).generate_launch_description()
    (sim,) = _nodes(description)
    params = sim.kwargs["parameters"][0]
    assert set(params) <= set(PARAMETERS)
    assert set(_arguments(description)) >= {"scenario", "engine", "duration", "fast"}


def test_setup_declares_the_node_entry_points() -> None:
    assert "sim_node" in console_scripts("sim_publisher")
    assert {"filter_node", "dbcslam"} <= console_scripts("dbcslam_ros")
