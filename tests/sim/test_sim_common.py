"""Behaviour shared by all scenarios: records layout, noise, seeds, the a-priori scenario."""

from __future__ import annotations

import dataclasses
from typing import Any

import numpy as np
import pytest
import yaml

from dbcslam_core.scenario import Scenario
from sim_publisher.base import Simulation
from sim_publisher.params import EdgeParams, GripperParams, NoiseParams, PushParams
from sim_publisher.records import MODE_NAMES, SimRun
from sim_publisher.simulate import SIMULATIONS, make_simulation, simulate

RUNS = ["edge_run", "gripper_run", "push_run"]


@pytest.mark.parametrize("name", RUNS)
def test_records_layout(name: str, request: pytest.FixtureRequest) -> None:
    run: SimRun = request.getfixturevalue(name)
    p = run.params
    arr = run.stack()
    n = round(p.duration * p.rate) + 1
    assert len(run.records) == n
    assert np.allclose(np.diff(arr["t"]), 1.0 / p.rate)
    c, j = len(run.contacts), len(run.joint_names)
    assert arr["modes"].shape == (n, c, len(MODE_NAMES))
    assert np.all(arr["modes"].sum(axis=2) == 1.0)
    assert set(np.unique(arr["modes"])) <= {0.0, 1.0}
    assert arr["joints"].shape == (n, j) and arr["observed_joints"].shape == (n, j)
    assert arr["friction"].shape == (n, len(run.pairs))
    assert arr["normal_forces"].shape == (n, c)
    for key in ("pose", "twist", "observed_pose", "wrench", "pusher_wrench"):
        assert arr[key].shape == (n, 3)
        assert np.all(np.isfinite(arr[key]))
    # twist is the derivative of the pose (central differences, away from impacts)
    dpose = np.gradient(arr["pose"][:, :2], arr["t"], axis=0)
    assert np.median(np.abs(dpose - arr["twist"][:, :2])) < 1e-3


def _chi2_ok(residuals: np.ndarray, sigma: float) -> bool:
    """sum(r^2)/sigma^2 ~ chi2(N): accept within 5 standard deviations of N."""
    n = residuals.size
    stat = float(np.sum(residuals**2)) / sigma**2
    return bool(abs(stat - n) < 5.0 * np.sqrt(2.0 * n))


@pytest.mark.parametrize("name", RUNS)
def test_observation_noise_matches_its_std(name: str, request: pytest.FixtureRequest) -> None:
    run: SimRun = request.getfixturevalue(name)
    noise = run.params.noise
    arr = run.stack()
    err = arr["observed_pose"] - arr["pose"]
    assert _chi2_ok(err[:, :2], noise.position)
    assert abs(float(np.mean(err[:, :2]))) < 5.0 * noise.position / np.sqrt(err[:, :2].size)
    if run.scenario_name == "edge":
        assert np.all(arr["observed_pose"][:, 2] == 0.0)  # a point has no yaw
    else:
        assert _chi2_ok(err[:, 2], noise.yaw)
    if run.joint_names:
        assert _chi2_ok(arr["observed_joints"] - arr["joints"], noise.joint)
    if run.scenario_name == "push":
        ferr = arr["observed_pusher_wrench"] - arr["pusher_wrench"]
        assert _chi2_ok(ferr[:, :2], noise.force)
        assert np.all(ferr[:, 2] == 0.0)


def test_chi2_check_rejects_a_wrong_std() -> None:
    rng = np.random.default_rng(0)
    r = rng.normal(0.0, 0.01, size=2000)
    assert _chi2_ok(r, 0.01)
    assert not _chi2_ok(r, 0.012)
    assert not _chi2_ok(r, 0.008)


@pytest.mark.parametrize("scenario", ["edge", "gripper", "push"])
def test_same_seed_same_records_other_seed_same_truth(scenario: str) -> None:
    a = simulate(scenario, duration=1.0, seed=7)
    b = simulate(scenario, duration=1.0, seed=7)
    c = simulate(scenario, duration=1.0, seed=8)
    assert all(ra.same_as(rb) for ra, rb in zip(a.records, b.records, strict=True))
    sa, sc = a.stack(), c.stack()
    assert np.array_equal(sa["pose"], sc["pose"])  # physics does not depend on the seed
    assert np.array_equal(sa["modes"], sc["modes"])
    assert not np.array_equal(sa["observed_pose"], sc["observed_pose"])


TRUTH_CHANGES: dict[str, tuple[Any, dict[str, Any]]] = {
    "edge": (EdgeParams, {"segments": ((-5.0, 0.1, 0.9), (0.1, 5.0, 0.3))}),
    "gripper": (GripperParams, {"jaw_mu": 0.7}),
    "push": (PushParams, {"mu_surface": 0.31, "mu_pusher": 0.27}),
}


@pytest.mark.parametrize("scenario", ["edge", "gripper", "push"])
def test_scenario_yaml_is_a_priori_only(scenario: str) -> None:
    cls, change = TRUTH_CHANGES[scenario]
    sim = SIMULATIONS[scenario](cls())
    other = SIMULATIONS[scenario](cls(**change))
    text = sim.scenario_yaml()
    # the hidden friction layout does not reach the robot's a-priori model
    assert text == other.scenario_yaml()
    keys = set(_keys(yaml.safe_load(text)))
    for leak in ("segments", "mu_surface", "mu_pusher", "jaw_mu", "mu"):
        assert leak not in keys
    parsed = Scenario.from_yaml(text)
    assert parsed.kind == scenario
    assert parsed.contacts == sim.contacts
    assert parsed.friction.pairs == sim.pairs
    assert parsed.dt == pytest.approx(1.0 / sim.params.rate)
    assert parsed.noise.position == sim.params.noise.position
    assert parsed.joints == sim.joint_names


def _keys(data: object) -> list[str]:
    out: list[str] = []
    if isinstance(data, dict):
        for k, v in data.items():
            out.append(str(k))
            out.extend(_keys(v))
    elif isinstance(data, list):
        for v in data:
            out.extend(_keys(v))
    return out


@pytest.mark.parametrize("name", RUNS)
def test_true_friction_is_among_the_candidates(name: str, request: pytest.FixtureRequest) -> None:
    run: SimRun = request.getfixturevalue(name)
    cands = run.scenario.friction.candidates
    values = run.stack()["friction"]
    for k in range(len(run.pairs)):
        assert set(np.unique(values[:, k])) <= set(cands[k])


def test_make_simulation_checks_arguments() -> None:
    sim = make_simulation("edge", duration=0.1)
    assert isinstance(sim, Simulation) and sim.params.duration == 0.1
    with pytest.raises(ValueError, match="scenario"):
        make_simulation("table")
    with pytest.raises(ValueError, match="not both"):
        make_simulation("edge", EdgeParams(), duration=1.0)


def test_noise_params_replace_keeps_validation() -> None:
    with pytest.raises(ValueError, match=r"noise\.position"):
        dataclasses.replace(NoiseParams(), position=-1.0)


@pytest.mark.parametrize("scenario", ["edge", "push"])
def test_sample_rate_does_not_change_the_physics(scenario: str) -> None:
    fast = simulate(scenario, duration=1.5, rate=100.0).stack()
    slow = simulate(scenario, duration=1.5, rate=50.0).stack()
    assert np.array_equal(fast["pose"][::2], slow["pose"])
    assert np.array_equal(fast["modes"][::2], slow["modes"])
    assert Scenario.from_yaml(simulate(scenario, duration=0.02, rate=50.0).scenario_yaml).dt == (
        pytest.approx(0.02)
    )


def test_streamed_records_equal_the_run(edge_sim: Simulation, edge_run: SimRun) -> None:
    streamed = list(edge_sim.records())
    assert len(streamed) == len(edge_run.records)
    assert all(a.same_as(b) for a, b in zip(streamed, edge_run.records, strict=True))
