"""Replay feeds /pusher/wrench to the filter node (through the same FilterNode code as live)."""

from __future__ import annotations

from pathlib import Path

import pytest

from dbcslam_ros.offline.replay import ReplayOptions, replay_bag

PUSH_BAG = Path(__file__).resolve().parents[2] / "bags" / "push"


@pytest.mark.skipif(not PUSH_BAG.is_dir(), reason="curated push bag not present")
@pytest.mark.parametrize("use", [True, False])
def test_replay_uses_the_pusher_force(tmp_path: Path, use: bool) -> None:
    params = {"particles": 10, "use_pusher_wrench": use, "marker_particles": 0}
    res = replay_bag(PUSH_BAG, tmp_path / "out", ReplayOptions(params=params, plots=False))
    diag = res.metrics["diagnostics_last"]
    assert res.estimates > 0.8 * res.poses
    # the simulator publishes one /pusher/wrench per pose, logged before it: every model step
    # has its force reading
    expected = int(diag["filter_steps"]) if use else 0
    assert int(diag["force_steps"]) == expected
    assert diag.get("rejected_no_pusher", "0") == "0"
