"""DBC-SLAM finds the jaw friction of pybullet grasps whatever the true coefficient is (the
simulator's contact model is not the filter's, and the candidates stay 0.1 / 0.4 / 0.7)."""

from __future__ import annotations

import pytest

pytest.importorskip("pybullet")

from dbcslam_research.experiments_sim import run_task


@pytest.mark.parametrize("jaw_mu", [0.1, 0.4, 0.7])
def test_identifies_the_true_jaw_coefficient(jaw_mu: float) -> None:
    rec, _, _ = run_task("gripper", 0, "dbcslam", particles=500, overrides={"jaw_mu": jaw_mu})
    m = rec.metrics
    assert m["final_friction_argmax"] == jaw_mu
    assert m["final_true_friction_posterior"] >= 0.9
    assert m["position_rmse_ratio"] < 0.5  # the pose tracked below the sensor noise
    assert m["contact_mode_accuracy"] > 0.9
