"""Observation-side model extensions (sensor_bias, sensor_delay) act in the filter path.

`FilterSession` (shared by the filter node and `dbcslam replay`) corrects every pose by the
model file's sensor effects; a bag with a hidden sensor bias is tracked better (against the
truth) with the model file of the discrepancy analysis than with the nominal model.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from edge_data import hidden_effect_trajectory, single_mu_edge_scenario

from dbcslam_core.extensions import ModelExtension
from dbcslam_core.rbpf import FilterConfig
from dbcslam_core.scenario import Scenario
from dbcslam_core.synthetic import Trajectory
from dbcslam_ros.convert import PoseReading
from dbcslam_ros.node.session import FilterSession, observation_correction
from dbcslam_ros.offline.discrepancy_report import filter_tracking
from dbcslam_ros.offline.evaluate import load_bag_arrays, match_stamps
from dbcslam_ros.offline.replay import ReplayOptions, replay_bag, write_trajectory_bag


def _scenario() -> Scenario:
    return single_mu_edge_scenario(0.002)


def _trajectory(extensions: tuple[ModelExtension, ...], seed: int) -> Trajectory:
    return hidden_effect_trajectory(extensions, seed, duration=2.0, position_noise=0.002)


def _model_file(path: Path, ext: ModelExtension) -> Path:
    import yaml

    path.write_text(yaml.safe_dump({"extensions": [ext.to_dict()]}))
    return path


def test_correction_sums_bias_and_delay() -> None:
    exts = (
        ModelExtension.make("sensor_bias", x=0.01, y=-0.02, yaw=0.1),
        ModelExtension.make("viscous_damping", b=1.0),
        ModelExtension.make("sensor_delay", seconds=0.03),
        ModelExtension.make("sensor_bias", x=0.001, y=0.0, yaw=0.0),
    )
    bias, delay = observation_correction(exts)
    assert bias == pytest.approx((0.011, -0.02, 0.1))
    assert delay == pytest.approx(0.03)
    sc = _scenario()
    session = FilterSession(sc, FilterConfig(particles=10), extensions=exts)
    r = session.correct(PoseReading(1_000_000_000, 0.5, 0.3, 3.1))
    assert r.stamp_ns == 970_000_000
    assert (r.x, r.y) == pytest.approx((0.489, 0.32))
    assert r.yaw == pytest.approx(3.0)
    plain = FilterSession(sc, FilterConfig(particles=10))
    reading = PoseReading(5, 0.1, 0.2, 0.3)
    assert plain.correct(reading) is reading


def test_delay_moves_the_estimate_stamp_back() -> None:
    sc = _scenario()
    exts = (ModelExtension.make("sensor_delay", seconds=0.02),)
    session = FilterSession(sc, FilterConfig(particles=20), extensions=exts)
    dt_ns = round(sc.dt * 1e9)
    out = []
    for k in range(3):
        out += session.add_pose(PoseReading(10 * dt_ns + k * dt_ns, 0.0, 0.1, 0.0))
    assert [e.stamp_ns for e in out] == [9 * dt_ns, 10 * dt_ns]


def _rmse_vs_truth(bag: Path) -> float:
    arr = load_bag_arrays(bag)
    i, j = match_stamps(arr.est_t, arr.truth_t, 1_000_000)
    e = arr.est_pose[i, :2] - arr.truth_pose[j, :2]
    return float(np.sqrt(np.mean(np.sum(e**2, axis=-1))))


def test_hidden_bias_is_tracked_better_with_the_model_file(tmp_path: Path) -> None:
    rng = np.random.default_rng(20261121)
    ext = ModelExtension.make(
        "sensor_bias",
        x=float(rng.uniform(0.006, 0.012)),
        y=float(rng.uniform(0.006, 0.012)),
        yaw=0.0,
    )
    bag = write_trajectory_bag(_trajectory((ext,), seed=int(rng.integers(100))), tmp_path / "b")
    model = _model_file(tmp_path / "model.yaml", ext)
    rmse = {}
    for label, mf in (("nominal", ""), ("extended", str(model))):
        # gate off: the node gates the RAW pose against the (de-biased) estimate
        params = {"particles": 60, "model_file": mf, "gating_threshold": 0.0}
        opts = ReplayOptions(params=params, plots=False)
        rmse[label] = _rmse_vs_truth(replay_bag(bag, tmp_path / label, opts).out)
    # the nominal filter follows the biased sensor along the edge (across it, the contact
    # holds the body on the edge); the extended one removes the bias
    assert rmse["nominal"] > 0.7 * ext.param("x")
    assert rmse["extended"] < 0.5 * rmse["nominal"]
    # the report's tracking block says the same (sensor-frame RMSE vs the observations too)
    block = filter_tracking([bag], model, tmp_path / "track", particles=60)
    assert block["extended"]["rmse_vs_truth_state"] < block["nominal"]["rmse_vs_truth_state"]
    assert block["gain"] > 2.0
