"""The support-pressure study of the MIT pushes: model variants on the filter's evidence."""

from __future__ import annotations

import math

import numpy as np
import pytest

from dbcslam_core.discrepancy import Run
from dbcslam_core.discrepancy.scoring import ScoreConfig, Scorer
from dbcslam_core.errors import ScenarioError
from dbcslam_core.extensions import ModelExtension
from dbcslam_core.synthetic import push_trajectory
from dbcslam_research.mitpush_pressure import (
    Variant,
    score_variants,
    summarise,
    with_candidates,
)

NAME = "motion_surface=abs_shape=disc_a=0_v=80_i=0.000_s=0.500_t=1.000"
DISC = [
    (0.0525 * math.cos(a), 0.0525 * math.sin(a))
    for a in np.linspace(0.0, -2.0 * math.pi, 24, endpoint=False)  # clockwise
]


def _run(centre_fraction: float, seed: int = 0) -> Run:
    """A steep push on a disc (the pusher slides along the rim), mu_s 0.4, hidden pressure."""
    tr = push_trajectory(
        seed,
        vertices=DISC,
        mass=0.89,
        angle=1.0,
        speed=0.08,
        mu_pusher=0.2,
        mu_surface=0.4,
        extensions=(
            ModelExtension.make("support_concentration", centre_fraction=centre_fraction),
        ),
    )
    return Run(NAME, tr.scenario, tr.t, tr.obs, tr.u, tr.env_obs)


def test_with_candidates_replaces_only_the_named_pair() -> None:
    run = _run(0.0)
    fr = run.scenario.friction
    out = with_candidates(run, surface=(0.45,), pusher=None)
    i, j = fr.pair_index("surface"), fr.pair_index("pusher")
    assert out.scenario.friction.candidates[i] == (0.45,)
    assert out.scenario.friction.prior[i] == (1.0,)
    assert out.scenario.friction.candidates[j] == fr.candidates[j]
    assert run.scenario.friction.candidates[i] == fr.candidates[i]  # the input is untouched
    with pytest.raises(ScenarioError):
        with_candidates(run, bogus=(0.1,))


def test_a_hidden_centre_heavy_pressure_is_what_the_evidence_picks() -> None:
    """Data made with 60 % of the weight at the centre: at the true support coefficient the
    concentrated variant explains the disc's spin better than uniform pressure, and the
    summary reports it relative to the first variant, per shape."""
    run, plain = _run(0.6), _run(0.0)
    variants = (
        Variant("uniform", surface=(0.4,)),
        Variant("centre 0.6", surface=(0.4,), centre_fraction=0.6),
    )
    scores = score_variants([run, plain], Scorer(ScoreConfig(particles=60)), variants)
    gain = [c - u for c, u in zip(scores["centre 0.6"], scores["uniform"], strict=True)]
    assert gain[0] > 20.0  # hidden concentration: found
    assert gain[0] > gain[1] + 50.0  # uniform data: no such gain
    scores = {k: v[:1] for k, v in scores.items()}
    summary = summarise([run.name], scores)
    assert summary["shapes"] == ["disc"]
    assert summary["variants"]["uniform"]["total"] == 0.0
    assert summary["variants"]["centre 0.6"]["per_shape"]["disc"] > 20.0
