"""Tests of the model-extension seam."""

from __future__ import annotations

import numpy as np
import pytest

from dbcslam_core.contact_modes import Mode
from dbcslam_core.dynamics import PlanarModel, State
from dbcslam_core.errors import ModelError
from dbcslam_core.extensions import EFFECTS, ModelExtension, compose_observation
from dbcslam_core.scenario import edge_scenario, push_scenario

G = 9.81
SQUARE = [[-0.05, -0.05], [0.05, -0.05], [0.05, 0.05], [-0.05, 0.05]]


def _ext(effect: str, **params: float) -> ModelExtension:
    return ModelExtension.make(effect, **params)


def test_vocabulary_matches_contract() -> None:
    assert set(EFFECTS) == {
        "friction_scale",
        "friction_patch",
        "viscous_damping",
        "mass_scale",
        "input_gain",
        "sensor_delay",
        "sensor_bias",
        "support_friction",
        "support_pressure",
        "support_concentration",  # push: limit-surface c (scenario-specific, documented)
        "none",
    }


@pytest.mark.parametrize(
    ("effect", "params", "needle"),
    [
        ("wind", {}, "unknown model effect"),
        ("viscous_damping", {}, "takes parameters"),
        ("viscous_damping", {"b": 1.0, "c": 2.0}, "takes parameters"),
        ("mass_scale", {"factor": 0.0}, "factor"),
        ("friction_patch", {"x_min": 1.0, "x_max": 0.0, "mu": 0.5}, "x_min < x_max"),
        ("viscous_damping", {"b": -1.0}, "b must be"),
        ("sensor_delay", {"seconds": float("nan")}, "finite"),
    ],
)
def test_invalid_extensions(effect: str, params: dict[str, float], needle: str) -> None:
    with pytest.raises(ModelError, match=needle):
        ModelExtension.make(effect, **params)


def test_dict_round_trip() -> None:
    e = _ext("friction_patch", x_min=0.2, x_max=0.5, mu=0.9)
    assert ModelExtension.from_dict(e.to_dict()) == e
    assert ModelExtension.from_dict({"effect": "none"}) == ModelExtension("none")
    with pytest.raises(ModelError):
        ModelExtension.from_dict({"params": {}})
    with pytest.raises(ModelError, match="numbers"):
        ModelExtension.from_dict({"effect": "mass_scale", "params": {"factor": "big"}})


def test_nominal_model_is_empty_tuple() -> None:
    sc = edge_scenario()
    state = State(np.array([0.0, 0.0]), np.array([0.4, 0.0]))
    nominal = PlanarModel(sc).step(state, [1.0, 0.0], mu=0.3)
    noop = PlanarModel(sc, (ModelExtension("none"),)).step(state, [1.0, 0.0], mu=0.3)
    assert np.array_equal(nominal.v, noop.v)


def test_friction_hooks_change_the_step() -> None:
    sc = edge_scenario()
    state = State(np.array([0.3, 0.0]), np.zeros(2))
    u = [5.0, 0.0]  # between 0.3 m g and 0.9 m g
    assert PlanarModel(sc).step(state, u, mu=0.3).modes[0] == Mode.SLIDING_POS
    scaled = PlanarModel(sc, (_ext("friction_scale", factor=3.0),)).step(state, u, mu=0.3)
    assert scaled.mu[0] == pytest.approx(0.9) and scaled.modes[0] == Mode.STICKING
    patch = _ext("friction_patch", x_min=0.2, x_max=0.4, mu=0.9)
    inside = PlanarModel(sc, (patch,)).step(state, u, mu=0.3)
    outside = PlanarModel(sc, (patch,)).step(State(np.array([0.5, 0.0]), np.zeros(2)), u, mu=0.3)
    assert inside.modes[0] == Mode.STICKING and outside.modes[0] == Mode.SLIDING_POS


def test_force_mass_and_gain_hooks() -> None:
    sc = edge_scenario()
    state = State(np.array([0.0, 1.0]), np.array([2.0, 0.0]))  # in flight
    dt = sc.dt
    damped = PlanarModel(sc, (_ext("viscous_damping", b=0.5),)).step(state, [0.0, 0.0], mu=0.3)
    assert damped.v[0] == pytest.approx(2.0 - dt * 0.5 * 2.0)
    heavy = PlanarModel(sc, (_ext("mass_scale", factor=2.0),))
    assert heavy.mass_diag[0] == pytest.approx(2.0)
    r = heavy.step(state, [4.0, 0.0], mu=0.3)
    assert r.v[0] == pytest.approx(2.0 + dt * 4.0 / 2.0)
    assert r.v[1] == pytest.approx(-dt * G)  # gravity scales with the mass
    gain = PlanarModel(sc, (_ext("input_gain", factor=0.5),)).step(state, [4.0, 0.0], mu=0.3)
    assert np.allclose(gain.v, r.v)  # mass k and gain 1/k are indistinguishable


def test_support_friction_decelerates_without_reversing() -> None:
    sc = push_scenario(SQUARE, mass=1.0)
    far = np.array([1.0, 1.0])  # pusher far away
    model = PlanarModel(sc, (_ext("support_friction", mu=0.5),))
    r = model.step(State(np.zeros(3), np.array([0.2, 0.0, 0.0])), np.zeros(3), far, far, mu=0.2)
    assert r.v[0] == pytest.approx(0.2 - 0.5 * G * sc.dt)
    slow = model.step(
        State(np.zeros(3), np.array([0.01, 0.0, 0.0])), np.zeros(3), far, far, mu=0.2
    )
    # stops (up to the regularisation speed) without reversing
    assert 0.0 <= slow.v[0] <= model.velocity_eps


def test_observation_hooks() -> None:
    bias = _ext("sensor_bias", x=0.01, y=-0.02, yaw=0.1)
    obs = compose_observation((bias,), np.array([[1.0, 2.0, 0.5]]))
    assert np.allclose(obs, [[1.01, 1.98, 0.6]])
    assert np.allclose(compose_observation((bias,), np.array([1.0, 2.0])), [1.01, 1.98])
    assert _ext("sensor_delay", seconds=0.05).delay == 0.05
    assert bias.delay == 0.0
