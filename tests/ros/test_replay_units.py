"""`dbcslam replay` on bags written from the core's synthetic trajectories (no DDS)."""

from __future__ import annotations

import json
from collections import defaultdict
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import yaml

from dbcslam_core import metrics as core_metrics
from dbcslam_core.synthetic import edge_trajectory, gripper_trajectory
from dbcslam_ros.bag import BagWriter, open_bag
from dbcslam_ros.cli import main as cli_main
from dbcslam_ros.contract import DIAGNOSTICS, MARKERS, OUTPUT_TOPICS
from dbcslam_ros.errors import BagError, UsageError
from dbcslam_ros.offline.replay import (
    ReplayOptions,
    load_filter_params,
    replay_bag,
    replay_many,
    write_trajectory_bag,
)

OUTPUTS = tuple(t for t in OUTPUT_TOPICS if t != DIAGNOSTICS)


@pytest.fixture(scope="module")
def edge_traj() -> Any:
    return edge_trajectory(seed=3, duration=1.5)


@pytest.fixture(scope="module")
def edge_bag(tmp_path_factory: pytest.TempPathFactory, edge_traj: Any) -> Path:
    return write_trajectory_bag(edge_traj, tmp_path_factory.mktemp("syn") / "edge")


@pytest.fixture(scope="module")
def edge_replay(tmp_path_factory: pytest.TempPathFactory, edge_bag: Path) -> Any:
    out = tmp_path_factory.mktemp("rep") / "edge"
    return replay_bag(
        edge_bag, out, ReplayOptions(params={"particles": 100, "seed": 2}, plots=False)
    )


def _stamp(msg: Any) -> int:
    return int(msg.header.stamp.sec) * 1_000_000_000 + int(msg.header.stamp.nanosec)


def test_trajectory_bag_holds_inputs_and_truth(edge_bag: Path, edge_traj: Any) -> None:
    with open_bag(edge_bag) as bag:
        counts = bag.counts()
    n = edge_traj.n_steps
    assert counts["/scenario"] == 1
    for topic in ("/object/pose", "/object/wrench", "/truth/object/pose", "/truth/friction"):
        assert counts[topic] == n
    assert "/joint_states" not in counts  # the edge has no joints


def test_replay_answers_every_pose_pose_first_at_its_stamp(edge_replay: Any) -> None:
    res = edge_replay
    assert res.estimates == res.poses - 1  # the first pose initialises the filter
    groups: dict[int, list[str]] = defaultdict(list)
    pose_stamps: list[int] = []
    with open_bag(res.out) as bag:
        for raw, msg in bag.decoded([*OUTPUTS, "/object/pose"]):
            if raw.topic == "/object/pose":
                pose_stamps.append(_stamp(msg))
                continue
            groups[raw.log_time_ns].append(raw.topic)
            if raw.topic in ("/dbcslam/pose", "/dbcslam/odometry", "/dbcslam/friction_map"):
                assert raw.log_time_ns == _stamp(msg)
    assert sorted(groups) == pose_stamps[1:]
    with_markers = [stamp for stamp, topics in groups.items() if MARKERS in topics]
    for stamp, topics in groups.items():
        # one of each, pose first, in publication order; markers as live (every 0.1 s)
        expected = [t for t in OUTPUTS if t != MARKERS or stamp in with_markers]
        assert topics == expected
    assert 0.09 * len(groups) <= len(with_markers) <= 0.11 * len(groups) + 1


def test_replay_metrics_match_core_metrics(edge_replay: Any, edge_traj: Any) -> None:
    metrics = json.loads((edge_replay.out / "metrics.json").read_text())
    assert metrics == json.loads(json.dumps(edge_replay.metrics))
    est = []
    with open_bag(edge_replay.out) as bag:
        for _raw, msg in bag.decoded(["/dbcslam/pose"]):
            est.append((msg.pose.pose.position.x, msg.pose.pose.position.y))
    direct = core_metrics.position_rmse(np.asarray(est), edge_traj.q[1:, :2])
    assert metrics["position_rmse_m"] == pytest.approx(direct, rel=1e-5)
    assert metrics["position_rmse_over_noise"] < 1.0
    assert metrics["contact_accuracy"] > 0.9
    assert metrics["replay"]["estimates"] == edge_traj.n_steps - 1
    assert metrics["replay"]["params"]["particles"] == 100


def test_replay_is_deterministic_for_a_seed(tmp_path: Path, edge_bag: Path) -> None:
    opts = ReplayOptions(params={"particles": 30, "seed": 5}, plots=False)
    a = replay_bag(edge_bag, tmp_path / "a", opts)
    b = replay_bag(edge_bag, tmp_path / "b", opts)
    assert a.metrics["position_rmse_m"] == b.metrics["position_rmse_m"]


def test_replay_gripper_with_joints_writes_plots(tmp_path: Path) -> None:
    traj = gripper_trajectory(seed=1, duration=0.6)
    bag = write_trajectory_bag(traj, tmp_path / "gripper")
    res = replay_bag(bag, tmp_path / "out", ReplayOptions(params={"particles": 40}))
    assert res.estimates == traj.n_steps - 1
    names = sorted(p.name for p in res.plots)
    assert {"trajectory.png", "contacts.png", "modes.png", "friction.png"} <= set(names)
    for p in res.plots:
        assert p.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert res.metrics["yaw_rmse_rad"] is not None
    assert len(res.metrics["friction"]) == 1


def test_directory_of_bags_goes_to_one_folder_each(tmp_path: Path, edge_traj: Any) -> None:
    for name in ("a", "b"):
        write_trajectory_bag(edge_traj, tmp_path / "in" / name)
    results = replay_many(
        tmp_path / "in", tmp_path / "out", ReplayOptions(params={"particles": 20}, plots=False)
    )
    assert [r.out for r in results] == [tmp_path / "out" / "a", tmp_path / "out" / "b"]
    assert all((r.out / "metrics.json").is_file() for r in results)


def test_existing_output_needs_overwrite(tmp_path: Path, edge_bag: Path) -> None:
    opts = ReplayOptions(params={"particles": 10}, plots=False)
    replay_bag(edge_bag, tmp_path / "o", opts)
    with pytest.raises(UsageError, match="already exists"):
        replay_bag(edge_bag, tmp_path / "o", opts)
    over = ReplayOptions(params={"particles": 10}, plots=False, overwrite=True)
    replay_bag(edge_bag, tmp_path / "o", over)
    (tmp_path / "o" / "notes.txt").write_text("mine")
    with pytest.raises(UsageError, match="did not write"):
        replay_bag(edge_bag, tmp_path / "o", over)


def test_bag_without_scenario_needs_a_scenario_file(
    tmp_path: Path, edge_bag: Path, edge_traj: Any
) -> None:
    stripped = tmp_path / "noscenario"
    with open_bag(edge_bag) as src, BagWriter(stripped) as dst:
        for raw in src.messages():
            if raw.topic != "/scenario":
                dst.add_topic(raw.topic, raw.msgtype, raw.qos)
                dst.write(raw.topic, raw.data, raw.log_time_ns)
    opts = ReplayOptions(params={"particles": 10}, plots=False)
    with pytest.raises(BagError, match="no /scenario"):
        replay_bag(stripped, tmp_path / "o1", opts)
    scenario = tmp_path / "edge.yaml"
    scenario.write_text(str(edge_traj.scenario.to_yaml()))
    res = replay_bag(
        stripped,
        tmp_path / "o2",
        ReplayOptions(params={"particles": 10, "scenario_file": str(scenario)}, plots=False),
    )
    assert res.estimates == edge_traj.n_steps - 1


def test_load_filter_params_forms(tmp_path: Path) -> None:
    nested = tmp_path / "n.yaml"
    nested.write_text(yaml.safe_dump({"dbcslam_filter": {"ros__parameters": {"particles": 7}}}))
    assert load_filter_params(nested) == {"particles": 7}
    flat = tmp_path / "f.yaml"
    flat.write_text("seed: 3\nparameter_model: geometric\n")
    assert load_filter_params(flat) == {"seed": 3, "parameter_model": "geometric"}
    bad = tmp_path / "b.yaml"
    bad.write_text("particls: 3\n")
    with pytest.raises(UsageError, match="particls"):
        load_filter_params(bad)


def test_cli_replay_exit_codes(
    tmp_path: Path, edge_bag: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    out = tmp_path / "cli"
    code = cli_main(
        ["replay", str(edge_bag), "-o", str(out), "--particles", "10", "--quiet", "--no-plots"]
    )
    assert code == 0
    assert "estimates from" in capsys.readouterr().out
    assert cli_main(["replay", str(tmp_path / "missing"), "-o", str(tmp_path / "x")]) == 2
    assert "missing" in capsys.readouterr().err
    not_a_bag = tmp_path / "junk.mcap"
    not_a_bag.write_bytes(b"not an mcap file at all")
    assert cli_main(["replay", str(not_a_bag), "-o", str(tmp_path / "y")]) == 2
    assert "junk.mcap" in capsys.readouterr().err
    assert cli_main(["replay", str(edge_bag), "-o", str(tmp_path / "z"), "--particles", "0"]) == 2


def test_unusable_scenario_gives_no_estimates_error(tmp_path: Path, edge_bag: Path) -> None:
    from dbcslam_ros.bag import jazzy_typestore, serialize

    broken = tmp_path / "badscenario"
    string = jazzy_typestore().types["std_msgs/msg/String"]
    with open_bag(edge_bag) as src, BagWriter(broken) as dst:
        for raw in src.messages():
            dst.add_topic(raw.topic, raw.msgtype, raw.qos)
            data = raw.data
            if raw.topic == "/scenario":
                data = serialize(string(data="scenario: [not, a, mapping"))[1]
            dst.write(raw.topic, data, raw.log_time_ns)
    with pytest.raises(BagError, match="no estimates"):
        replay_bag(broken, tmp_path / "o", ReplayOptions(params={"particles": 10}, plots=False))


def test_console_replay_exits_fast_with_everything_written(edge_bag: Path, tmp_path: Path) -> None:
    """The console script ends a replay without the interpreter's teardown (`fast_exit`):
    the exit code, the printed summary, the closed bag and metrics.json are all there; a
    failing replay still exits 2 with its message."""
    import os
    import subprocess
    import sys

    out = tmp_path / "out"
    cmd = [sys.executable, "-m", "dbcslam_ros.cli", "replay", str(edge_bag), "-o", str(out)]
    env = {k: v for k, v in os.environ.items() if k != "PYTHONUNBUFFERED"}  # buffered stdout
    done = subprocess.run(
        [*cmd, "--particles", "20", "--no-plots", "--quiet"],
        capture_output=True,
        text=True,
        timeout=300,
        check=False,
        env=env,
    )
    assert done.returncode == 0, done.stderr
    assert "estimates" in done.stdout and "position RMSE" in done.stdout  # flushed
    metrics = json.loads((out / "metrics.json").read_text())
    with open_bag(out) as bag:
        assert bag.counts()["/dbcslam/pose"] == metrics["estimates"] > 0
    again = subprocess.run(cmd, capture_output=True, text=True, timeout=300, check=False)
    assert again.returncode == 2
    assert "already exists" in again.stderr


def test_only_batch_commands_exit_fast() -> None:
    from dbcslam_ros.cli.registry import discover_commands

    fast = {name for name, command in discover_commands().items() if command.fast_exit}
    assert fast == {"replay"}
