"""The push score integrates the friction candidates exactly (`scoring.SCORE_OVERRIDES`).

A clean synthetic push (`synthetic.push_sweep_trajectory`, support mu 0.1 and pusher mu 0.25,
both among the scenario's candidates 0.1 / 0.25 / 0.4) scored with the candidates must come
within ln 9 (nine joint hypotheses, equally likely) of the score with the true coefficients
as the only candidates; the single-copy filter, whose per-particle friction beliefs turn
one-hot and resample on pose, lost up to ~120 nats there (measured, 60 particles, 3 s).
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from dbcslam_core.discrepancy import Hypothesis, Run, ScoreConfig, Scorer
from dbcslam_core.discrepancy.scoring import SCORE_OVERRIDES
from dbcslam_core.synthetic import push_sweep_trajectory

#: slack on top of ln 9 for the Monte-Carlo noise of a 60-particle score (measured spread of
#: the bank's score against the known coefficients: -1.0 to +14.8 nats)
SLACK = 5.0
SINGLE_COPY = (("friction_bank", False), ("bank_resampling", "particle"))


def _run(seed: int) -> Run:
    tr = push_sweep_trajectory(seed, duration=3.0, mu_pusher=0.25, mu_surface=0.1)
    return Run(f"push-{seed}", tr.scenario, tr.t, tr.obs, tr.u, tr.env_obs)


def _known(run: Run) -> Run:
    """The run with the true coefficients as the only candidates."""
    fr = run.scenario.friction
    scenario = dataclasses.replace(
        run.scenario,
        friction=dataclasses.replace(fr, candidates=((0.25,), (0.1,)), prior=((1.0,), (1.0,))),
    )
    return dataclasses.replace(run, scenario=scenario)


def _scores(run: Run, overrides: tuple[tuple[str, object], ...] = ()) -> list[float]:
    with Scorer(ScoreConfig(particles=60, filter_overrides=overrides)) as s:
        return [s.score(Hypothesis(), [run], seed).loglik for seed in (0, 1)]


def test_push_scores_use_the_hypothesis_bank() -> None:
    assert SCORE_OVERRIDES["push"] == {"friction_bank": True, "bank_resampling": "hypothesis"}


@pytest.mark.parametrize("seed", [0, 1])
def test_push_score_loses_at_most_ln9_against_knowing_the_friction(seed: int) -> None:
    run = _run(seed)
    assert run.scenario.friction.candidates == ((0.1, 0.25, 0.4), (0.1, 0.25, 0.4))
    known = _scores(_known(run), SINGLE_COPY)
    grid = _scores(run)
    for g, k in zip(grid, known, strict=True):
        assert g >= k - math.log(9.0) - SLACK, (grid, known)
    # the single-copy filter's integration falls short on at least one filter seed here
    single = _scores(run, SINGLE_COPY)
    assert min(np.subtract(single, known)) < -math.log(9.0) - SLACK, (single, known)
