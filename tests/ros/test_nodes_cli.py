"""``dbcslam sim`` and ``dbcslam filter``: help, usage errors (exit 2), a short run (exit 0)."""

from __future__ import annotations

import os
import subprocess
import sys

import pytest

from dbcslam_ros.cli import main


@pytest.mark.parametrize(
    ("argv", "words"),
    [
        (["sim"], ["--scenario", "--engine", "--fast", "/scenario", "dbcslam sim --scenario"]),
        (["filter"], ["--params", "/diagnostics", "catch_up_steps", "dbcslam filter"]),
    ],
)
def test_help_explains_with_examples(
    argv: list[str], words: list[str], capsys: pytest.CaptureFixture[str]
) -> None:
    with pytest.raises(SystemExit) as exc:
        main([*argv, "--help"])
    assert exc.value.code == 0
    out = capsys.readouterr().out
    assert "examples:" in out
    for word in words:
        assert word in out


@pytest.mark.parametrize(
    ("argv", "needle"),
    [
        (["sim", "--scenario", "push", "--engine", "core"], "push"),
        (["sim", "--scenario", "edge", "--params", "/no/such.yaml"], "/no/such.yaml"),
        (["sim", "--scenario", "edge", "--seed", "-3"], "--seed"),
        (["sim", "--scenario", "edge", "--duration", "0"], "--duration"),
        (["filter", "--params", "/no/such.yaml"], "/no/such.yaml"),
    ],
)
def test_bad_usage_exits_2_naming_the_problem(
    argv: list[str], needle: str, capsys: pytest.CaptureFixture[str]
) -> None:
    assert main(argv) == 2
    assert needle in capsys.readouterr().err


def test_unknown_scenario_is_an_argparse_error() -> None:
    with pytest.raises(SystemExit) as exc:
        main(["sim", "--scenario", "table"])
    assert exc.value.code == 2


def test_short_core_run_exits_0() -> None:
    env = dict(os.environ, ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST")
    proc = subprocess.run(
        [
            sys.executable, "-m", "dbcslam_ros.cli", "sim", "--scenario", "edge", "--engine",
            "core", "--duration", "0.2", "--fast", "--ros-args", "-p",
            "wait_for_subscribers:=0.0",
        ],
        env=env, capture_output=True, text=True, timeout=60, check=False,
    )  # fmt: skip
    assert proc.returncode == 0, proc.stderr
    assert "21 samples published" in proc.stdout + proc.stderr
