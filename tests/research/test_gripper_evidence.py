"""`dbcslam_research.gripper_evidence`: on a pybullet grasp the filter's one-step
time-stepping model explains the first impact with a too-high jaw friction, the same model
sub-stepped as pybullet integrates explains it with the true one; the report renders what
was measured."""

from __future__ import annotations

from typing import Any

import numpy as np
import pytest

pytest.importorskip("pybullet")

from dbcslam_research.gripper_evidence import (
    impact_residuals,
    main,
    render_markdown,
    run_verdicts,
)


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
        "true": 1,
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


def test_verdicts_average_the_evidence_over_filter_seeds() -> None:
    rows = [
        {"run": 0, "true": 1, "filter_seed": 0, "particles": 1000, "log_ml": [0.0, 4.0, 1.0]},
        {"run": 0, "true": 1, "filter_seed": 1, "particles": 1000, "log_ml": [0.0, 2.0, 3.0]},
        {"run": 1, "true": 1, "filter_seed": 0, "particles": 1000, "log_ml": [0.0, 0.0, 5.0]},
        {"run": 1, "true": 1, "filter_seed": 0, "particles": 40, "log_ml": [0.0, 9.0, 0.0]},
    ]
    v = run_verdicts(rows, 1000, prior=[0.25, 0.5, 0.25])
    assert [x["run"] for x in v] == [0, 1]
    assert v[0]["filter_seeds"] == 2
    # run 0: mean log-evidence (0, 3, 2), log prior (log .25, log .5, log .25)
    w = np.array([0.25, 0.5 * np.exp(3.0), 0.25 * np.exp(2.0)])
    assert v[0]["p_true"] == pytest.approx(w[1] / w.sum())
    assert v[0]["most_probable"] == 1
    assert v[0]["margin"] == pytest.approx(1.0)
    assert v[1]["most_probable"] == 2  # the 40-particle row is not counted
    assert v[1]["margin"] == pytest.approx(-5.0)
    assert sum(v[1]["posterior"]) == pytest.approx(1.0)


def test_report_names_the_runs_the_data_do_not_decide(cause: dict[str, Any]) -> None:
    verdicts = [
        {"run": 0, "true": 1, "p_true": 0.97, "most_probable": 1, "margin": 4.0},
        {"run": 1, "true": 1, "p_true": 0.30, "most_probable": 2, "margin": -1.0},
    ]
    result = {
        "date": "x",
        "wall_s": 1.0,
        "substeps": 10,
        "runs": 2,
        "filter_seeds": 1,
        "particles": [1000],
        "sim_set": {"jaw_mu": 0.4},
        "cause": cause,
        "evidence": [_row(0, 0, 1000, 4.0, 0.97), _row(1, 0, 1000, -1.0, 0.30)],
        "verdict_particles": 1000,
        "verdicts": verdicts,
    }
    md = render_markdown(result, "cmd")
    assert "simulator overrides: jaw_mu=0.4 (true jaw mu 0.4)" in md
    assert "| 2 | 1 | 1 | 1.5 / -1.0 | 1: 0.30, 0.7 |" in md


def test_sim_set_reaches_the_simulator() -> None:
    out = impact_residuals(0, substeps=2, duration=0.2, sim_set=(("jaw_mu", 0.7),))
    assert out["true_mu"] == 0.7


@pytest.mark.parametrize(
    ("item", "says"),
    [
        ("no_such_parameter=1", "valid:"),
        ("jaw_mu", "KEY=VALUE"),
        ("jaw_mu=-0.5", "jaw_mu"),
    ],
)
def test_bad_sim_set_exits_2_naming_the_problem(
    item: str, says: str, capsys: pytest.CaptureFixture[str]
) -> None:
    with pytest.raises(SystemExit) as exc:
        main(["--sim-set", item, "--quiet"])
    assert exc.value.code == 2
    assert says in capsys.readouterr().err
