"""The colcon workspace builds with PyPI colcon; scripts land where `ros2 run` looks."""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
import xml.etree.ElementTree as ET
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[2]
PACKAGES = ("dbcslam_core", "dbcslam_ros", "sim_publisher")
COLCON = Path(sys.executable).with_name("colcon")


@pytest.fixture(scope="module")
def colcon_install(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """Build ros_ws/ into a temporary directory; return its install base."""
    if not COLCON.exists():
        pytest.fail(f"colcon is not installed next to {sys.executable}; run `make venv`")
    base = tmp_path_factory.mktemp("colcon")
    cmd = [
        str(COLCON),
        "--log-base",
        str(base / "log"),
        "build",
        "--base-paths",
        str(REPO / "ros_ws" / "src"),
        "--build-base",
        str(base / "build"),
        "--install-base",
        str(base / "install"),
    ]
    result = subprocess.run(cmd, capture_output=True, text=True, cwd=base, timeout=600)
    assert result.returncode == 0, result.stdout[-3000:] + result.stderr[-3000:]
    return base / "install"


def test_workspace_links_point_at_the_packages() -> None:
    for pkg in PACKAGES:
        link = REPO / "ros_ws" / "src" / pkg
        assert link.is_symlink(), f"{link} should be a relative symlink"
        assert not os.path.isabs(os.readlink(link))
        assert link.resolve() == (REPO / pkg).resolve()


@pytest.mark.parametrize("pkg", PACKAGES)
def test_package_xml_is_format_3_ament_python(pkg: str) -> None:
    root = ET.parse(REPO / pkg / "package.xml").getroot()
    assert root.get("format") == "3"
    assert root.findtext("name") == pkg
    assert root.findtext("export/build_type") == "ament_python"
    assert (REPO / pkg / "resource" / pkg).exists()


def test_core_depends_on_no_ros_package() -> None:
    root = ET.parse(REPO / "dbcslam_core" / "package.xml").getroot()
    deps = {e.text for e in root.iter("exec_depend")}
    assert deps <= {"python3-numpy", "python3-scipy", "python3-yaml", "python3-numba"}


@pytest.mark.parametrize("pkg", PACKAGES)
def test_colcon_installs_package_index_and_manifest(colcon_install: Path, pkg: str) -> None:
    share = colcon_install / pkg / "share"
    assert (share / "ament_index" / "resource_index" / "packages" / pkg).exists()
    assert (share / pkg / "package.xml").exists()


def test_console_scripts_land_in_lib_pkg(colcon_install: Path) -> None:
    lib = colcon_install / "dbcslam_ros" / "lib" / "dbcslam_ros"
    for script in ("dbcslam", "talker", "listener"):
        path = lib / script
        assert path.exists(), f"{path} missing: `ros2 run dbcslam_ros {script}` would fail"
        assert os.access(path, os.X_OK)


def test_installed_cli_runs_from_the_install_space(colcon_install: Path) -> None:
    site = sorted(colcon_install.glob("*/lib/python3*/site-packages"))
    assert len(site) == len(PACKAGES)
    env = {**os.environ, "PYTHONPATH": os.pathsep.join(str(s) for s in site)}
    script = colcon_install / "dbcslam_ros" / "lib" / "dbcslam_ros" / "dbcslam"
    result = subprocess.run(
        [sys.executable, str(script), "--help"],
        capture_output=True,
        text=True,
        env=env,
        timeout=120,
    )
    assert result.returncode == 0, result.stderr
    assert "usage" in result.stdout.lower()
    assert shutil.which("python3") is not None
