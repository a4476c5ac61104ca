"""Replay of the curated bags under bags/ (recorded live from the pybullet simulator)."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import pytest

from dbcslam_ros.bag import find_bags, open_bag
from dbcslam_ros.offline.evaluate import evaluate_bag
from dbcslam_ros.offline.replay import ReplayOptions, replay_bag

BAGS = Path(__file__).resolve().parents[2] / "bags"
#: Few particles keep the tests fast; the thresholds below are loose accordingly.
PARTICLES = {"edge": 100, "gripper": 50, "push": 50}
OUTPUTS = (
    "/dbcslam/pose",
    "/dbcslam/odometry",
    "/dbcslam/contact_modes",
    "/dbcslam/friction",
    "/dbcslam/friction_map",
)


def _stamp(msg: Any) -> int:
    return int(msg.header.stamp.sec) * 1_000_000_000 + int(msg.header.stamp.nanosec)


def _marker_stamps(stamps: list[int], period_ns: int) -> list[int]:
    """The estimate stamps that carry markers: the first, then the first at least
    period_ns after the last marker (a jump back in time restarts the clock)."""
    out: list[int] = []
    for s in stamps:
        if not out or not 0 <= s - out[-1] < period_ns:
            out.append(s)
    return out


def test_every_scenario_has_a_curated_bag() -> None:
    assert {"edge", "gripper", "push"} <= {p.name for p in find_bags(BAGS)}
    assert (BAGS / "README.md").is_file()


@pytest.mark.parametrize("name", sorted(PARTICLES))
def test_replay_of_curated_bag(name: str, tmp_path: Path) -> None:
    plots = name == "push"  # one bag with plots is enough (matplotlib is slow)
    res = replay_bag(
        BAGS / name,
        tmp_path / name,
        ReplayOptions(params={"particles": PARTICLES[name], "seed": 0}, plots=plots),
    )
    # Every pose after the first (which initialises the filter) is answered, unless rejected.
    assert res.estimates == res.poses - 1 - sum(res.rejected.values())
    assert res.estimates >= 0.95 * (res.poses - 1)
    with open_bag(res.out) as bag:
        counts = bag.counts()
        assert counts["/object/pose"] == res.poses
        for topic in OUTPUTS:
            assert counts[topic] == res.estimates
        for topic in ("/truth/object/pose", "/truth/contact_modes", "/truth/friction"):
            assert counts[topic] == res.poses  # copied from the source
        pose_stamps = set()
        previous_log = -1
        first_at_log: dict[int, str] = {}
        for raw, msg in bag.decoded([*OUTPUTS, "/object/pose"]):
            if raw.topic == "/object/pose":
                pose_stamps.add(_stamp(msg))
                continue
            first_at_log.setdefault(raw.log_time_ns, raw.topic)
            if raw.topic == "/dbcslam/pose":
                assert raw.log_time_ns == _stamp(msg)
                assert raw.log_time_ns > previous_log
                previous_log = raw.log_time_ns
        assert set(first_at_log.values()) == {"/dbcslam/pose"}
        assert set(first_at_log) <= pose_stamps
        # markers as live: at the first estimate, then once per marker_period (0.1 s) of
        # stamp time, logged with the estimate they show
        marker_logs = [raw.log_time_ns for raw, _ in bag.decoded(["/dbcslam/markers"])]
        assert marker_logs == _marker_stamps(sorted(first_at_log), 100_000_000)
    metrics = json.loads((res.out / "metrics.json").read_text())
    # computed from the messages as they were written: the same as from the bag read back
    read_back = json.loads(json.dumps(evaluate_bag(res.out, require_truth=False)))
    assert {k: v for k, v in metrics.items() if k != "replay"} == read_back
    with open_bag(BAGS / name) as src:
        recorded = src.counts().get("/dbcslam/pose", 0)
    if recorded:  # the source's own estimates, read in the same pass as its inputs
        assert metrics["replay"]["recorded_estimates"]["recorded"] == recorded
    assert metrics["scenario"] == name
    assert metrics["matched"] == res.estimates
    assert metrics["position_rmse_over_noise"] < 3.0
    assert metrics["contact_accuracy"] > 0.5
    for pair in metrics["friction"]:
        assert sum(pair["final_posterior"]) == pytest.approx(1.0, abs=1e-3)
    if name == "edge":
        assert metrics["friction_map_accuracy"] is not None
    else:
        assert metrics["yaw_rmse_rad"] is not None
    if plots:
        assert {p.name for p in res.plots} >= {"trajectory.png", "modes.png", "friction.png"}
