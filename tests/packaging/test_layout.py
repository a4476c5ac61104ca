"""The README's layout table is the tree: every path it names exists, and every folder and
top-level module of the ROS package (and every top-level folder) has its row."""

from __future__ import annotations

import re
from pathlib import Path

REPO = Path(__file__).resolve().parents[2]
ROS = REPO / "dbcslam_ros" / "dbcslam_ros"
#: The required top level (DEVELOPERS.md) plus build and tool files.
TOP_LEVEL = {"ros_ws", "dbcslam_core", "dbcslam_ros", "sim_publisher", "bags", "tests"}


def _layout_paths() -> list[str]:
    text = (REPO / "README.md").read_text(encoding="utf-8")
    section = text.split("\n## Layout\n", 1)[1].split("\n## ", 1)[0]
    return re.findall(r"^\| `([^`]+)` \|", section, flags=re.M)


def test_every_path_of_the_layout_table_exists() -> None:
    paths = _layout_paths()
    assert len(paths) >= 10
    missing = [p for p in paths if not (REPO / p).exists()]
    assert not missing, f"README layout names paths that do not exist: {missing}"


def test_every_folder_and_module_of_the_ros_package_has_a_row() -> None:
    rows = {p.rstrip("/") for p in _layout_paths()}
    parts = [p for p in ROS.iterdir() if p.name != "__pycache__" and not p.name.startswith(".")]
    wanted = {
        str(p.relative_to(REPO))
        for p in parts
        if (p.is_dir() or (p.suffix == ".py" and p.name != "__init__.py"))
    }
    missing = sorted(wanted - rows)
    assert not missing, f"README layout has no row for {missing}"


def test_top_level_is_the_required_one() -> None:
    dirs = {
        p.name
        for p in REPO.iterdir()
        if p.is_dir() and not p.name.startswith(".") and p.name not in {"build", "out"}
    }
    assert dirs <= TOP_LEVEL, f"unexpected top-level folders: {sorted(dirs - TOP_LEVEL)}"
    rows = {p.rstrip("/") for p in _layout_paths()}
    assert {d for d in TOP_LEVEL if d != "dbcslam_ros"} <= rows


def test_the_tests_row_names_every_test_folder() -> None:
    text = (REPO / "README.md").read_text(encoding="utf-8")
    row = next(line for line in text.splitlines() if line.startswith("| `tests/` |"))
    named = set(re.findall(r"`(tests/[a-z_]+)`", row))
    folders = {
        f"tests/{p.name}"
        for p in (REPO / "tests").iterdir()
        if p.is_dir() and any(p.glob("test_*.py"))
    }
    assert named == folders, f"tests row names {sorted(named)}, the tree has {sorted(folders)}"


def test_design_names_every_core_module() -> None:
    """dbcslam_core/DESIGN.md's module map has a row for every module and subpackage."""
    core = REPO / "dbcslam_core" / "dbcslam_core"
    text = (REPO / "dbcslam_core" / "DESIGN.md").read_text(encoding="utf-8")
    rows = set(re.findall(r"^\| `([^`]+)` \|", text, flags=re.M))
    wanted = {p.name for p in core.glob("*.py") if p.name != "__init__.py"}
    wanted |= {f"{p.name}/" for p in core.iterdir() if (p / "__init__.py").exists()}
    missing = sorted(wanted - rows)
    assert not missing, f"DESIGN.md's module map has no row for {missing}"
    stale = sorted(r for r in rows if r.endswith((".py", "/")) and r not in wanted)
    assert not stale, f"DESIGN.md names modules that do not exist: {stale}"
