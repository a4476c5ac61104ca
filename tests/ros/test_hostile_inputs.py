"""Bad input on the real middleware: >= 10,000 hostile messages into a running filter node.

`tests/ros/hostile_feed.py` (its own process, plain rclpy) plays a curated bag into a live
``dbcslam filter`` and interleaves, after every valid sample, a burst of malformed or hostile
messages. The node must not crash, must never publish a non-finite number, must count every
rejected input by reason in ``/diagnostics``, and must still track the valid run.
"""

from __future__ import annotations

import json
import subprocess
import sys
from collections.abc import Callable
from pathlib import Path

import pytest

from dbcslam_ros.network import DISCOVERY_RANGE_VAR

REPO = Path(__file__).resolve().parents[2]
FEED = Path(__file__).with_name("hostile_feed.py")
#: reasons fixed by the kind of message sent
EXACT = ("nan", "zero_quaternion", "malformed", "unknown_joint", "no_pusher", "bad_scenario")
#: a far jump is `stamp_jump`, or `backlog` if a newer pose replaced it in the node's queue
TIME_REASONS = ("stamp_jump", "backlog")


@pytest.fixture
def ros_env(isolated_env: Callable[..., dict[str, str]]) -> dict[str, str]:
    return isolated_env(DISCOVERY_RANGE_VAR)


@pytest.fixture
def filter_node(
    ros_env: dict[str, str], tmp_path: Path, processes: list[subprocess.Popen[bytes]]
) -> subprocess.Popen[bytes]:
    """A live filter node, stopped by PID (SIGTERM, then SIGKILL) even on failure."""
    log = (tmp_path / "filter.log").open("wb")
    # 200 particles (not the edge live default of 1000): the flood is the test, and a node
    # that keeps up on a loaded machine sees it all (at 1000 particles and load 7 the best-effort
    # pose reader dropped up to half of the poses before the node saw them)
    args = ["-p", "diagnostics_period:=0.5", "-p", "marker_period:=0.0", "-p", "particles:=200"]
    proc = subprocess.Popen(
        [sys.executable, "-m", "dbcslam_ros.cli", "filter", "--ros-args", *args],
        stdout=log,
        stderr=subprocess.STDOUT,
        env=ros_env,
    )
    processes.append(proc)
    return proc


@pytest.mark.slow
def test_ten_thousand_hostile_messages(
    filter_node: subprocess.Popen[bytes], ros_env: dict[str, str], tmp_path: Path
) -> None:
    out = tmp_path / "feed.json"
    feed = subprocess.run(
        [
            sys.executable,
            str(FEED),
            str(REPO / "bags" / "edge"),
            str(out),
            "--bad",
            "10000",
            "--period",
            "0.08",
        ],
        env=ros_env,
        capture_output=True,
        timeout=240,
    )
    node_log = (tmp_path / "filter.log").read_text(errors="replace")
    assert feed.returncode == 0, feed.stderr.decode(errors="replace")[-3000:]
    res = json.loads(out.read_text())
    context = json.dumps(res, indent=1)[:4000] + "\n--- node log tail:\n" + node_log[-3000:]

    assert filter_node.poll() is None, "the filter node died\n" + context
    assert res["sent_total"] >= 10_000
    assert res["non_finite"] == [], context
    diag = res["diagnostics"]
    assert diag, "no /diagnostics received\n" + context
    sent = res["sent"]
    # Sensor topics are best effort (contract QoS): under a flood the middleware may drop
    # some messages before the node sees them, and the latched /scenario reader keeps only
    # the newest. What reaches the node is counted: never more than was sent (no valid input
    # is counted as rejected), and most of it (measured: 84-99 % per reason on a loaded
    # 2-core machine, 82 % of the latched /scenario messages).
    counted = {r: int(diag.get(f"rejected_{r}", "0")) for r in (*EXACT, "stamp_order")}
    counted["stamp_time"] = sum(int(diag.get(f"rejected_{r}", "0")) for r in TIME_REASONS)
    for reason, n in counted.items():
        assert 0.5 * sent[reason] <= n <= sent[reason], (reason, context)
    assert int(diag.get("resets", "0")) == 0, context
    # ... and the valid run is still tracked.
    assert res["matched_estimates"] >= 0.9 * res["valid_poses"], context
    assert res["position_rmse_per_axis"] <= 0.6 * res["noise_position"], context
