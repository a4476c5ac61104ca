"""dbcslam_core.discrepancy: hidden effects in synthetic edge runs are named and recovered.

Data: the edge scenario (point mass on an edge under gravity, 0.5 mm observation noise,
one friction candidate 0.5 = the nominal friction) driven by the `edge_trajectory` force
profile (plus force pulses for the delay case), true model = nominal + ONE hidden effect
whose size is drawn from a seeded generator. The analysis must name the effect, recover
its parameters (within 25 %, positions within 2 cm) with gain >= 1.5, and say `none` on
data without a hidden effect.
"""

from __future__ import annotations

from functools import cache

import numpy as np
import pytest
from edge_data import MU, single_mu_edge_scenario

from dbcslam_core.discrepancy import DiscrepancyConfig, Run, analyse, smooth_states
from dbcslam_core.dynamics import PlanarModel
from dbcslam_core.extensions import ModelExtension
from dbcslam_core.scenario import Scenario
from dbcslam_core.synthetic import edge_trajectory, observe, simulate


def _scenario() -> Scenario:
    return single_mu_edge_scenario(0.0005)


@cache
def _inputs(pulses: bool) -> tuple[np.ndarray, np.ndarray]:
    base = edge_trajectory(0, duration=4.0)
    u = base.u.copy()
    if pulses:
        sc = _scenario()
        sq = np.sign(np.sin(2.0 * np.pi * base.t / 0.4))
        u[:, 0] += 0.4 * sc.body.mass * sc.gravity * sq * (base.t < 2.5)
    return base.t, u


def edge_run(
    extensions: tuple[ModelExtension, ...], seed: int = 0, *, pulses: bool = False
) -> Run:
    """A synthetic edge run with the given (hidden) extensions."""
    sc = _scenario()
    t, u = _inputs(pulses)
    env = np.zeros((t.size, 0))
    model = PlanarModel(sc, extensions, active_set=True)
    q, _v, env, *_ = simulate(model, (0.0, sc.edge_y + 0.1), (1.2, 0.0), u, env, mu=MU)
    obs, env_obs = observe(sc, q, env, np.random.default_rng(seed), extensions)
    return Run("edge", sc, t, obs, u, env_obs)


def draw_effect(effect: str, rng: np.random.Generator) -> ModelExtension:
    """A hidden effect of a random but observable size."""
    if effect == "friction_scale":
        f = float(rng.uniform(1.4, 1.8)) if rng.random() < 0.5 else float(rng.uniform(0.5, 0.7))
        return ModelExtension.make(effect, factor=f)
    if effect == "viscous_damping":
        return ModelExtension.make(effect, b=float(rng.uniform(0.6, 1.5)))
    if effect == "sensor_bias":
        return ModelExtension.make(effect, x=0.0, y=float(rng.uniform(0.006, 0.015)), yaw=0.0)
    if effect == "sensor_delay":
        return ModelExtension.make(effect, seconds=0.01 * int(rng.integers(3, 7)))
    if effect == "support_friction":
        return ModelExtension.make(effect, mu=float(rng.uniform(0.15, 0.3)))
    if effect == "friction_patch":
        x0 = float(rng.uniform(0.35, 0.45))
        return ModelExtension.make(
            effect, x_min=x0, x_max=x0 + float(rng.uniform(0.25, 0.35)), mu=1.0
        )
    raise AssertionError(effect)


CFG = DiscrepancyConfig()


@pytest.mark.parametrize(
    "effect",
    [
        "friction_scale",
        "viscous_damping",
        "sensor_bias",
        "sensor_delay",
        "support_friction",
        "friction_patch",
    ],
)
def test_hidden_effect_is_named_and_recovered(effect: str) -> None:
    rng = np.random.default_rng([2026, len(effect), ord(effect[-1])])
    ext = draw_effect(effect, rng)
    run = edge_run((ext,), seed=int(rng.integers(1000)), pulses=effect == "sensor_delay")
    res = analyse([run], (), CFG)
    assert res.verdict == effect, (res.verdict, res.evidence, ext)
    assert res.winner is not None
    for name, true in ext.params:
        got = res.winner.params[name]
        if name in ("x", "y", "x_min", "x_max"):
            assert abs(got - true) <= 0.02, (name, got, true)
        elif name == "yaw":
            assert abs(got - true) <= 0.01
        else:
            assert abs(got - true) <= 0.25 * abs(true), (name, got, true)
    assert res.gain >= 1.5, res.gain
    doc = res.to_dict()
    assert doc["verdict"] == effect
    assert doc["extended"]["effect"] == effect
    assert doc["gain"] == pytest.approx(
        doc["nominal"]["heldout_rmse"] / doc["extended"]["heldout_rmse"], rel=1e-3
    )
    loaded = ModelExtension.from_dict(doc["extended"])
    assert loaded.effect == effect


def test_no_hidden_effect_gives_none() -> None:
    res = analyse([edge_run((), seed=3)], (), CFG)
    assert res.verdict == "none", res.evidence
    assert res.winner is None
    assert res.to_dict()["extended"]["effect"] == "none"
    assert res.gain == 1.0


def test_mass_scale_and_input_gain_are_not_guessed() -> None:
    ext = ModelExtension.make("mass_scale", factor=1.5)
    res = analyse([edge_run((ext,), seed=5)], (), CFG)
    assert res.winner is not None
    assert res.winner.effect in ("mass_scale", "input_gain")
    if res.winner.effect == "input_gain":  # only acceptable when both are named
        assert set(res.ambiguous) == {"mass_scale", "input_gain"}
        assert "mass_scale" in res.verdict and "input_gain" in res.verdict


def test_heldout_runs_are_not_fitted() -> None:
    ext = ModelExtension.make("viscous_damping", b=1.0)
    res = analyse([edge_run((ext,), seed=1)], [edge_run((ext,), seed=2)], CFG)
    assert res.verdict == "viscous_damping"
    assert "held-out runs" in res.heldout_description
    assert res.nominal.n_heldout > 0


def test_smooth_states_recovers_a_quadratic() -> None:
    t = np.arange(50) * 0.01
    y = (0.3 + 1.2 * t - 2.0 * t**2)[:, None]
    q, v = smooth_states(y, 0.01, 9, 2)
    np.testing.assert_allclose(q, y, atol=1e-12)
    np.testing.assert_allclose(v[:, 0], 1.2 - 4.0 * t, atol=1e-9)
