"""`dbcslam demo` end to end (sim, filter, recorder as processes over DDS on loopback), and
replay of the recorded live run reproducing its estimates."""

from __future__ import annotations

import contextlib
import io
import json
import random
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from dbcslam_ros.bag import open_bag
from dbcslam_ros.cli import main as cli_main
from dbcslam_ros.errors import UsageError
from dbcslam_ros.offline.demo import DemoOptions, run_demo
from dbcslam_ros.offline.evaluate import load_bag_arrays
from dbcslam_ros.offline.replay import ReplayOptions, replay_bag

PARTICLES = 40
SEED = 2


@dataclass(frozen=True)
class DemoRun:
    bag: Path
    code: int
    printed: str


@pytest.fixture(scope="module")
def demo_run(tmp_path_factory: pytest.TempPathFactory) -> DemoRun:
    """One short live demo through the CLI (core engine: fast, deterministic physics)."""
    out = tmp_path_factory.mktemp("demo") / "edge_run"
    stream = io.StringIO()
    argv = ["demo", "--scenario", "edge", "--engine", "core", "--duration", "2"]
    argv += ["--particles", str(PARTICLES), "--seed", str(SEED), "--out", str(out)]
    # A domain of its own, outside the 1..100 of tests/conftest.py: other test runs on this
    # machine (other suites start simulators too) must not cross-talk with the recording.
    domain = str(random.SystemRandom().randint(120, 230))
    with pytest.MonkeyPatch.context() as mp, contextlib.redirect_stdout(stream):
        mp.setenv("ROS_DOMAIN_ID", domain)
        code = cli_main(argv)
    return DemoRun(out, code, stream.getvalue())


def test_demo_records_a_bag_and_summarises(demo_run: DemoRun) -> None:
    assert demo_run.code == 0, demo_run.printed
    bag = demo_run.bag
    assert (bag / "metadata.yaml").is_file()
    metrics = json.loads((bag / "metrics.json").read_text())
    assert metrics["demo"]["exit_codes"] == {"sim": 0, "filter": 0, "record": 0}
    assert metrics["scenario"] == "edge"
    with open_bag(bag) as reader:
        counts = reader.counts()
    # 2 s at 100 Hz, t = 0 included. The recorder subscribed before the simulator started,
    # so the reliable truth is complete; best-effort inputs may lose a message under load.
    assert counts["/truth/object/pose"] == 201
    assert counts["/object/pose"] >= 195
    assert counts["/scenario"] == 1
    assert counts["/dbcslam/pose"] == metrics["estimates"]
    # markers at the node's period (0.1 s of stamp time): about one per ten estimates
    assert 1 <= counts["/dbcslam/markers"] <= metrics["estimates"] // 10 + 2
    assert metrics["estimates"] >= 0.2 * counts["/object/pose"]
    # Smoke bound only: live accuracy depends on how many poses a loaded machine drops.
    assert metrics["position_rmse_over_noise"] < 5.0
    printed = demo_run.printed
    assert "sim time" in printed and "position RMSE" in printed and "mode accuracy" in printed
    names = {p.name for p in bag.glob("*.png")}
    assert {"trajectory.png", "contacts.png", "friction.png", "friction_map.png"} <= names
    for p in bag.glob("*.png"):
        assert p.read_bytes()[:4] == b"\x89PNG"


def test_replay_reproduces_the_live_estimates(demo_run: DemoRun, tmp_path: Path) -> None:
    live = load_bag_arrays(demo_run.bag)
    res = replay_bag(
        demo_run.bag,
        tmp_path / "replayed",
        ReplayOptions(params={"particles": PARTICLES, "seed": SEED}, plots=False),
    )
    replayed = load_bag_arrays(res.out)
    # Replay answers every recorded pose (after the first, which initialises the filter).
    assert replayed.est_t.size == res.poses - 1
    assert set(replayed.est_t.tolist()) == set(live.obs_t[1:].tolist())
    # Live answered at most as many; on a loaded machine it drops poses it cannot keep up
    # with, and a best-effort pose may reach the filter but not the recorder (or vice versa).
    recorded = np.isin(live.est_t, live.obs_t[1:])
    assert np.count_nonzero(recorded) <= replayed.est_t.size
    assert np.count_nonzero(recorded) >= 0.2 * replayed.est_t.size
    common, i_live, i_rep = np.intersect1d(live.est_t, replayed.est_t, return_indices=True)
    assert common.size == np.count_nonzero(recorded)
    diff = np.linalg.norm(live.est_pose[i_live, :2] - replayed.est_pose[i_rep, :2], axis=1)
    # Until both saw a different sequence of poses (the live node dropped one for backlog, or
    # answered one the recorder missed), they ran the very same computation.
    diverged = [replayed.est_t.size]
    only_replay = ~np.isin(replayed.est_t, live.est_t)
    if np.any(only_replay):
        diverged.append(int(np.argmax(only_replay)))
    if live.est_t.size and live.est_t[0] <= live.obs_t[0]:
        diverged.append(0)  # live initialised on a pose the recorder missed
    if not np.all(recorded):
        first_unrecorded = live.est_t[int(np.argmax(~recorded))]
        diverged.append(int(np.searchsorted(replayed.est_t, first_unrecorded)))
    same = i_rep < min(diverged)
    assert np.max(diff[same], initial=0.0) < 1e-9
    # Replay (no drops) tracks the truth within the observation noise (0.01 m std).
    assert res.metrics["position_rmse_over_noise"] < 1.0
    summary = res.metrics["replay"]["recorded_estimates"]
    assert summary["recorded"] == live.est_t.size
    assert summary["same_stamps"] == common.size
    assert summary["position_diff_max_m"] == pytest.approx(float(np.max(diff)), abs=1e-6)


def test_demo_usage_errors(tmp_path: Path, capsys: pytest.CaptureFixture[Any]) -> None:
    existing = tmp_path / "exists"
    existing.mkdir()
    with pytest.raises(UsageError, match="already exists"):
        run_demo(DemoOptions(out=existing))
    with pytest.raises(UsageError, match="push"):
        run_demo(DemoOptions(scenario="push", engine="core", out=tmp_path / "p"))
    assert cli_main(["demo", "--particles", "0", "--out", str(tmp_path / "q")]) == 2
    assert "--particles" in capsys.readouterr().err
