"""`dbcslam discrepancy` on pybullet runs with ONE hidden effect (sim_publisher injection).

The robot's /scenario knows a single friction candidate 0.3 (= the nominal friction); the
simulator hides one effect (viscous damping, an observation bias), drawn from a seeded
generator, or none. The core analysis (the filter's evidence) must name it. A friction
patch is not a candidate of the filter-based analysis (the filter's own friction map
estimates where friction changes); pushes are not scored here (filter runs too slow for a
test at this time).
"""

from __future__ import annotations

from typing import Any

import numpy as np
import pytest

from dbcslam_core.discrepancy import DiscrepancyConfig, Run, analyse
from sim_publisher.params import NoiseParams
from sim_publisher.simulate import simulate
from sim_publisher.trajectory import to_trajectory

UNIFORM = ((-5.0, 5.0, 0.3),)
FORCE = (
    (0.0, 3.5, 0.0),
    (1.5, 3.5, 0.0),
    (2.0, 2.0, 0.0),
    (3.0, 4.5, 0.0),
    (3.5, 1.0, 0.0),
    (4.0, 1.0, 12.0),
    (4.3, 0.0, 10.0),
)


def _run(**overrides: Any) -> Run:
    sim = simulate(
        "edge",
        noise=NoiseParams(0.0005, 0.02, 0.0005, 0.0),
        friction_candidates=(0.3,),
        friction_prior=(1.0,),
        **overrides,
    )
    tr = to_trajectory(sim)
    return Run("pybullet-edge", tr.scenario, tr.t, tr.obs, tr.u, tr.env_obs)


def _rng(name: str) -> np.random.Generator:
    return np.random.default_rng([20261121, *map(ord, name)])


CFG = DiscrepancyConfig(particles=200, pictures=False, workers=2)
pytestmark = pytest.mark.timeout(1500)  # one analysis: ~40 filter runs


def test_pybullet_hidden_viscous_damping() -> None:
    b = float(_rng("damping").uniform(2.0, 3.5))
    res = analyse([_run(segments=UNIFORM, force=FORCE, damping=b)], (), CFG)
    assert res.winner is not None, res.evidence
    assert res.winner.effect == "viscous_damping", res.evidence
    assert res.winner.params["b"] == pytest.approx(b, rel=0.25)
    assert res.loglik_gain > 0.0


def test_pybullet_hidden_observation_bias() -> None:
    y = float(_rng("bias").uniform(0.006, 0.015))
    res = analyse([_run(segments=UNIFORM, force=FORCE, observation_bias=(0.0, y, 0.0))], (), CFG)
    assert res.verdict == "sensor_bias", res.evidence
    assert res.winner is not None
    assert abs(res.winner.params["y"] - y) <= 0.02 * 0.25 + 0.002
    assert abs(res.winner.params["x"]) <= 0.02


def test_pybullet_without_hidden_effect_is_none() -> None:
    res = analyse([_run(segments=UNIFORM, force=FORCE)], (), CFG)
    assert res.verdict == "none", res.evidence
