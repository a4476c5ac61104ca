"""Clean shutdown on real rclpy: every node and tool exits 0 on SIGINT and on SIGTERM.

Jazzy rclpy shuts its context down from its own signal handler; a signal that lands while
the executor builds its wait set used to end the filter node with ``RCLError: ... context is
not valid`` (exit 1). Each process is started, given time to reach its spin loop (a log line,
it prints once its handlers are in place), signalled, and must exit 0
without a traceback. ``DBCSLAM_SHUTDOWN_REPEAT`` (default 2) repeats each case; the README
states the 20-of-20 run.
"""

from __future__ import annotations

import os
import signal
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import pytest

from dbcslam_core.scenario import edge_scenario

REPEAT = int(os.environ.get("DBCSLAM_SHUTDOWN_REPEAT", "2"))


def _cases(tmp: Path) -> dict[str, tuple[tuple[str, ...], str]]:
    scen = tmp / "edge.yaml"
    scen.write_text(edge_scenario().to_yaml())
    return {
        "filter": (
            ("dbcslam_ros.node.filter_node", "--ros-args", "-p", f"scenario_file:={scen}"),
            "configured for scenario",
        ),
        "sim": (
            (
                "sim_publisher.node",
                "--ros-args",
                "-p",
                "engine:=core",
                "-p",
                "duration:=60.0",
                "-p",
                "wait_for_subscribers:=0.0",
            ),
            "publishing scenario",
        ),
        "talker": (("dbcslam_ros.node.demo_nodes", "talker"), "sent 'hello 1'"),
        "listener": (("dbcslam_ros.node.demo_nodes", "listener"), "listening on chatter"),
        "record": (
            ("dbcslam_ros.cli", "record", "-o", str(tmp / "bag"), "--contract", "--overwrite"),
            "recording /scenario",
        ),
        "topic_echo": (("dbcslam_ros.cli", "topic", "echo", "/nobody"), "waiting for a publisher"),
        "topic_hz": (("dbcslam_ros.cli", "topic", "hz", "/nobody"), "waiting for a publisher"),
    }


@pytest.mark.parametrize("sig", [signal.SIGINT, signal.SIGTERM], ids=["SIGINT", "SIGTERM"])
@pytest.mark.parametrize(
    "case", ["filter", "sim", "talker", "listener", "record", "topic_echo", "topic_hz"]
)
def test_process_exits_0_on_signal(
    tmp_path: Path, node_process: Callable[..., Any], case: str, sig: signal.Signals
) -> None:
    argv, ready = _cases(tmp_path)[case]
    for i in range(REPEAT):
        proc = node_process(*argv)
        assert proc.wait_for_log(ready, 60.0), proc.log()
        time.sleep(0.1)  # the log line comes just before the spin loop
        assert proc.proc.poll() is None, proc.log()
        os.kill(proc.pid, sig)
        code = proc.proc.wait(15)
        assert code == 0, f"run {i + 1}/{REPEAT}: exit {code}\n{proc.log()}"
        assert "Traceback" not in proc.log(), proc.log()
