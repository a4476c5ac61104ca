"""`dbcslam_research.gripper_evidence`: on a pybullet grasp the filter's one-step
time-stepping model explains the first impact with a too-high jaw friction, the same model
sub-stepped as pybullet integrates explains it with the true one; the report renders what
was measured."""

from __future__ import annotations

from typing import Any

import pytest

pytest.importorskip("pybullet")

from dbcslam_research.gripper_evidence import impact_residuals, render_markdown


@pytest.fixture(scope="module")
def cause() -> dict[str, Any]:
    return impact_residuals(0, substeps=10, duration=0.7)  # through the first impact


def test_one_step_model_prefers_a_too_high_coefficient(cause: dict[str, Any]) -> None:
    cands = cause["candidates"]
    true = cands.index(cause["true_mu"])
    one = cause["substeps_1"]["total"]
    fine = cause["substeps_10"]["total"]
    assert max(range(len(cands)), key=fine.__getitem__) == true
    assert fine[true] - max(x for i, x in enumerate(fine) if i != true) > 10.0  # nats
    assert max(range(len(cands)), key=one.__getitem__) > true  # a stickier coefficient
    assert one[true] < -3.0


def test_the_difference_is_made_at_an_impact(cause: dict[str, Any]) -> None:
    """The step that separates the candidates most is the same under both models (the
    triangle's first impact on a jaw), and there they disagree on the coefficient."""
    top_one = cause["substeps_1"]["top"][0]
    top_fine = cause["substeps_10"]["top"][0]
    assert top_one["step"] == top_fine["step"]
    true = cause["candidates"].index(cause["true_mu"])
    assert top_fine["ll"][true] == 0.0
    assert top_one["ll"][true] < 0.0


def _row(run: int, seed: int, p: int, margin: float, p_true: float) -> dict[str, Any]:
    return {
        "run": run,
        "filter_seed": seed,
        "particles": p,
        "log_ml": [0.0, margin, 0.0],
        "margin": margin,
        "p_true": p_true,
    }


def test_report_states_the_measured_spread(cause: dict[str, Any]) -> None:
    result = {
        "date": "x",
        "wall_s": 1.0,
        "substeps": 10,
        "runs": 2,
        "filter_seeds": 2,
        "particles": [40],
        "cause": cause,
        "evidence": [
            _row(0, 0, 40, 10.0, 1.0),
            _row(0, 1, 40, 6.0, 0.99),
            _row(1, 0, 40, -4.0, 0.02),
            _row(1, 1, 40, 0.0, 0.5),
        ],
    }
    md = render_markdown(result, "cmd")
    # mean 3.0, median 3.0, min -4.0, pooled within-run std sqrt((4+4+4+4)/2) = 2.83
    assert "| 40 | 3.0 | 3.0 | -4.0 | 2.8 | 2 / 4 | 1/0: 0.02, 1/1: 0.50 |" in md
    assert "| one step of dt (the filter) |" in md
    assert f"the {cause['scored_steps']} of {cause['steps']} steps" in md
    assert cause["scored_steps"] == cause["steps"]  # before the squeezed grasp: all solve
    assert "one step none; 10 sub-steps none." in md
