"""`dbcslam demo` end to end (sim, filter, recorder as processes over DDS on loopback), and
replay of the recorded live run reproducing its estimates."""

from __future__ import annotations

import io
import json
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from dbcslam_ros.cli import main as cli_main
from dbcslam_ros.demo import DemoOptions, DemoResult, run_demo
from dbcslam_ros.errors import UsageError
from dbcslam_ros.evaluate import load_bag_arrays
from dbcslam_ros.replay import ReplayOptions, replay_bag

PARTICLES = 40
SEED = 2


@pytest.fixture(scope="module")
def demo_run(tmp_path_factory: pytest.TempPathFactory) -> tuple[DemoResult, str]:
    """One short live demo (core engine: fast and deterministic physics)."""
    out = tmp_path_factory.mktemp("demo") / "edge_run"
    stream = io.StringIO()
    result = run_demo(
        DemoOptions(
            scenario="edge",
            engine="core",
            duration=2.0,
            particles=PARTICLES,
            seed=SEED,
            out=out,
            progress=stream,
        )
    )
    return result, stream.getvalue()


def test_demo_records_a_bag_and_summarises(demo_run: tuple[DemoResult, str]) -> None:
    result, printed = demo_run
    assert result.exit_codes == {"sim": 0, "filter": 0, "record": 0}
    assert (result.bag / "metadata.yaml").is_file()
    metrics = json.loads((result.bag / "metrics.json").read_text())
    assert metrics["scenario"] == "edge"
    poses = metrics["demo"]["poses"]
    assert poses == 201  # 2 s at 100 Hz, t = 0 included: nothing lost by the recorder
    assert metrics["estimates"] >= 0.3 * poses
    # Smoke bound only: live accuracy depends on how many poses a loaded machine drops.
    assert metrics["position_rmse_over_noise"] < 5.0
    assert "sim time" in printed and "position RMSE" in printed and "mode accuracy" in printed
    names = {p.name for p in result.plots}
    assert {"trajectory.png", "contacts.png", "friction.png", "friction_map.png"} <= names
    for p in result.plots:
        assert p.parent == result.bag and p.read_bytes()[:4] == b"\x89PNG"


def test_replay_reproduces_the_live_estimates(
    demo_run: tuple[DemoResult, str], tmp_path: Path
) -> None:
    result, _ = demo_run
    live = load_bag_arrays(result.bag)
    res = replay_bag(
        result.bag,
        tmp_path / "replayed",
        ReplayOptions(params={"particles": PARTICLES, "seed": SEED}, plots=False),
    )
    replayed = load_bag_arrays(res.out)
    # Replay answers every pose; live may have dropped a few it could not keep up with.
    assert replayed.est_t.size == res.poses - 1
    assert live.est_t.size <= replayed.est_t.size
    assert live.est_t.size >= replayed.est_t.size - 0.5 * res.poses
    common, i_live, i_rep = np.intersect1d(live.est_t, replayed.est_t, return_indices=True)
    assert common.size == live.est_t.size  # every live estimate answers a replayed stamp
    diff = np.linalg.norm(live.est_pose[i_live, :2] - replayed.est_pose[i_rep, :2], axis=1)
    noise = 0.01  # edge scenario position noise std (m)
    assert float(np.mean(diff)) < noise
    # Until the first pose the live node dropped (backlog), both ran the same computation.
    dropped = ~np.isin(replayed.est_t, live.est_t)
    first_drop = int(np.argmax(dropped)) if np.any(dropped) else replayed.est_t.size
    same = i_rep < first_drop
    assert np.max(diff[same], initial=0.0) < 1e-9


def test_demo_usage_errors(tmp_path: Path, capsys: pytest.CaptureFixture[Any]) -> None:
    existing = tmp_path / "exists"
    existing.mkdir()
    with pytest.raises(UsageError, match="already exists"):
        run_demo(DemoOptions(out=existing))
    with pytest.raises(UsageError, match="push"):
        run_demo(DemoOptions(scenario="push", engine="core", out=tmp_path / "p"))
    assert cli_main(["demo", "--particles", "0", "--out", str(tmp_path / "q")]) == 2
    assert "--particles" in capsys.readouterr().err
