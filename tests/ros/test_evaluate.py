"""`dbcslam evaluate`: metrics of a bag's estimates against its truth, and its errors."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from dbcslam_core.synthetic import edge_trajectory
from dbcslam_ros.bag import BagWriter, open_bag
from dbcslam_ros.cli import main as cli_main
from dbcslam_ros.offline.evaluate import (
    MissingTopicsError,
    evaluate_bag,
    load_bag_arrays,
    match_stamps,
    metrics_table,
)
from dbcslam_ros.offline.replay import ReplayOptions, replay_bag, write_trajectory_bag


@pytest.fixture(scope="module")
def replayed(tmp_path_factory: pytest.TempPathFactory) -> Path:
    base = tmp_path_factory.mktemp("eval")
    bag = write_trajectory_bag(edge_trajectory(seed=4, duration=1.2), base / "edge")
    replay_bag(bag, base / "out", ReplayOptions(params={"particles": 60}, plots=False))
    return base / "out"


def _copy(src: Path, dst: Path, keep: Any, log_time: Any = None) -> Path:
    """Copy the messages of src for which keep(topic) holds; log_time(raw) may retime."""
    with open_bag(src) as reader, BagWriter(dst) as writer:
        for raw in reader.messages():
            if keep(raw.topic):
                writer.add_topic(raw.topic, raw.msgtype, raw.qos)
                lt = raw.log_time_ns if log_time is None else log_time(raw)
                writer.write(raw.topic, raw.data, lt)
    return dst


def test_cli_evaluate_writes_json(
    replayed: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    out = tmp_path / "m.json"
    assert cli_main(["evaluate", str(replayed), "--json", str(out)]) == 0
    metrics = json.loads(out.read_text())
    printed = capsys.readouterr().out
    assert "position RMSE" in printed
    assert metrics["estimates"] == metrics["matched"] > 100
    assert 0.0 < metrics["position_rmse_m"] < metrics["observation_rmse_m"]
    assert metrics["position_rmse_over_noise"] == pytest.approx(
        metrics["position_rmse_m"] / metrics["position_noise_std_m"], rel=1e-3
    )
    for key in ("contact_accuracy", "stick_slide_accuracy", "contact_mode_accuracy"):
        assert 0.5 < metrics[key] <= 1.0
    (pair,) = metrics["friction"]
    assert pair["pair"] == "edge"
    assert sum(pair["final_posterior"]) == pytest.approx(1.0, abs=1e-3)
    assert pair["p_true"] == pair["final_posterior"][pair["true_index"]]
    assert metrics["step_time_ms_mean"] > 0.0
    assert metrics["yaw_rmse_rad"] is None  # point mass


def test_live_timing_gives_the_same_metrics(replayed: Path, tmp_path: Path) -> None:
    """Outputs logged at receive times after their stamps (as a live recorder does)."""
    rng = np.random.default_rng(0)
    offsets: dict[int, int] = {}

    def jitter(raw: Any) -> int:
        if raw.topic.startswith("/dbcslam/") or raw.topic.startswith("/truth/"):
            base = offsets.setdefault(raw.log_time_ns, int(rng.integers(1, 4_000_000)))
            return raw.log_time_ns + base + int(rng.integers(0, 200_000))
        return raw.log_time_ns

    live = _copy(replayed, tmp_path / "live", lambda _t: True, jitter)
    a = evaluate_bag(replayed)
    b = evaluate_bag(live)
    for key in ("position_rmse_m", "contact_mode_accuracy", "matched", "friction"):
        assert a[key] == b[key]


def test_no_truth_is_an_error_naming_the_topics(
    replayed: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    bag = _copy(replayed, tmp_path / "notruth", lambda t: not t.startswith("/truth/"))
    with pytest.raises(MissingTopicsError) as info:
        evaluate_bag(bag)
    assert info.value.missing == (
        "/truth/object/pose",
        "/truth/contact_modes",
        "/truth/friction",
    )
    assert cli_main(["evaluate", str(bag)]) == 2
    err = capsys.readouterr().err
    assert "/truth/object/pose" in err and "notruth" in err
    partial = evaluate_bag(bag, require_truth=False)
    assert partial["truth"] is False and partial["estimates"] > 0


def test_no_estimates_is_an_error(
    replayed: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    bag = _copy(replayed, tmp_path / "noest", lambda t: not t.startswith("/dbcslam/"))
    assert cli_main(["evaluate", str(bag)]) == 2
    assert "/dbcslam/pose" in capsys.readouterr().err
    assert cli_main(["evaluate", str(tmp_path / "nothing")]) == 2


def test_arrays_align_modes_with_poses(replayed: Path) -> None:
    arr = load_bag_arrays(replayed)
    assert arr.modes is not None and arr.friction is not None
    assert arr.modes.shape == (arr.est_t.size, 1, 4)
    np.testing.assert_allclose(arr.modes.sum(axis=-1), 1.0, atol=1e-9)
    assert arr.truth_modes is not None and arr.truth_modes.shape == (arr.truth_t.size, 1)
    assert arr.friction_map is not None
    assert "position RMSE" in metrics_table(evaluate_bag(replayed, arrays=arr))


def test_match_stamps_nearest_within_tolerance() -> None:
    a = np.array([10, 20, 31, 50], dtype=np.int64)
    b = np.array([0, 10, 20, 30, 40], dtype=np.int64)
    i, j = match_stamps(a, b, tol_ns=2)
    assert i.tolist() == [0, 1, 2]
    assert j.tolist() == [1, 2, 3]
    i, j = match_stamps(a, np.zeros(0, dtype=np.int64), tol_ns=2)
    assert i.size == j.size == 0


def test_contact_flag_metrics_count_agreement_per_matched_step() -> None:
    from dbcslam_ros.offline.evaluate import BagArrays, contact_flag_metrics

    # P(separated) per step: 0.9 (sep), 0.2 (contact), 0.4 (contact), 0.7 (sep), 0.1 (contact)
    p_sep = np.array([0.9, 0.2, 0.4, 0.7, 0.1])
    modes = np.zeros((5, 1, 4))
    modes[:, 0, 0] = p_sep
    modes[:, 0, 1] = 1.0 - p_sep
    arr = BagArrays(path=Path("x"))
    arr.est_t = np.arange(5, dtype=np.int64) * 10
    arr.modes = modes
    # flags at the same stamps except the last estimate (no flag within tolerance)
    arr.flag_t = np.array([0, 10, 20, 30, 100], dtype=np.int64)
    arr.flag = np.array([[False], [True], [False], [True], [True]])
    out = contact_flag_metrics(arr, tol_ns=2)
    # matched steps 0-3: est [sep, c, c, sep] vs flag [sep, c, sep, c] -> 2 of 4 agree
    assert out["contact_flag_entries"] == 4
    assert out["contact_flag_agreement"] == pytest.approx(0.5)
    assert out["contact_flag_recall"] == pytest.approx(0.5)  # flagged contact: steps 1, 3
    assert out["contact_flag_specificity"] == pytest.approx(0.5)  # flagged sep: steps 0, 2
    assert out["contact_flag_in_contact_fraction"] == pytest.approx(0.5)
    arr.flag = np.zeros((5, 2), dtype=bool)
    assert "contact_flag_error" in contact_flag_metrics(arr, tol_ns=2)
