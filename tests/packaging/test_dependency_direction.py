"""One direction of dependency: dbcslam_core imports neither ROS, DDS, pybullet nor plotting."""

from __future__ import annotations

import ast
import subprocess
import sys
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[2]
CORE = REPO / "dbcslam_core" / "dbcslam_core"
FORBIDDEN = (
    "rclpy",
    "cyclonedds",
    "pybullet",
    "matplotlib",
    "rosbags",
    "mcap",
    "dbcslam_ros",
    "sim_publisher",
    "h5py",
)


def _imported_modules(path: Path) -> set[str]:
    tree = ast.parse(path.read_text(), filename=str(path))
    names: set[str] = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            names.update(alias.name.split(".")[0] for alias in node.names)
        elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            names.add(node.module.split(".")[0])
    return names


@pytest.mark.parametrize("path", sorted(CORE.rglob("*.py")), ids=lambda p: p.name)
def test_core_module_imports_no_adapter_library(path: Path) -> None:
    bad = _imported_modules(path).intersection(FORBIDDEN)
    assert not bad, f"{path.relative_to(REPO)} imports {sorted(bad)}"


def test_importing_the_core_loads_no_adapter_library() -> None:
    code = (
        "import sys, pkgutil, importlib, dbcslam_core\n"
        "for m in pkgutil.walk_packages(dbcslam_core.__path__, 'dbcslam_core.'):\n"
        "    importlib.import_module(m.name)\n"
        f"bad = sorted(n for n in sys.modules if n.split('.')[0] in {FORBIDDEN!r})\n"
        "print(','.join(bad))\n"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert out.returncode == 0, out.stderr[-2000:]
    assert out.stdout.strip() == "", f"dbcslam_core pulled in: {out.stdout.strip()}"


ROS = REPO / "dbcslam_ros" / "dbcslam_ros"
#: dbcslam_ros is what a ROS user installs: it imports neither the simulator nor the research
#: scripts (sim_publisher supplies `dbcslam sim` through the `dbcslam.commands` entry points).
ROS_FORBIDDEN = ("sim_publisher", "dbcslam_research", "pybullet")


@pytest.mark.parametrize("path", sorted(ROS.rglob("*.py")), ids=lambda p: str(p.relative_to(ROS)))
def test_ros_package_imports_neither_simulator_nor_research(path: Path) -> None:
    bad = _imported_modules(path).intersection(ROS_FORBIDDEN)
    assert not bad, f"{path.relative_to(REPO)} imports {sorted(bad)}"


def test_sim_command_comes_from_the_entry_point_group() -> None:
    from importlib.metadata import entry_points

    from dbcslam_ros.cli.registry import ENTRY_POINT_GROUP, discover_commands

    names = {ep.name: ep.value for ep in entry_points(group=ENTRY_POINT_GROUP)}
    assert names.get("sim") == "sim_publisher.command:COMMAND"
    assert "sim" in discover_commands()
    assert not (ROS / "cli" / "commands" / "sim.py").exists()


def test_setup_installs_only_the_ros_package() -> None:
    from setuptools import find_packages

    found = find_packages(str(REPO / "dbcslam_ros"), include=["dbcslam_ros", "dbcslam_ros.*"])
    assert found and all(p.split(".")[0] == "dbcslam_ros" for p in found)
    assert (REPO / "dbcslam_ros" / "research" / "dbcslam_research" / "__init__.py").exists()
    assert "find_packages(include=[PACKAGE" in (REPO / "dbcslam_ros" / "setup.py").read_text()
