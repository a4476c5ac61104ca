"""Tests of the synthetic ground-truth trajectories (paper Figs. 3 and 4)."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from dbcslam_core.contact_modes import Mode
from dbcslam_core.extensions import ModelExtension
from dbcslam_core.geometry import contact_kinematics
from dbcslam_core.synthetic import (
    EDGE_ROUGH,
    Trajectory,
    delayed,
    edge_trajectory,
    gripper_trajectory,
)


@pytest.fixture(scope="module", params=[0, 1])
def edge(request: pytest.FixtureRequest) -> Trajectory:
    return edge_trajectory(request.param)


@pytest.fixture(scope="module", params=[0, 5])
def grip(request: pytest.FixtureRequest) -> Trajectory:
    return gripper_trajectory(request.param)


def _runs(modes: np.ndarray) -> list[int]:
    out: list[int] = []
    for m in modes:
        if not out or out[-1] != m:
            out.append(int(m))
    return out


def test_edge_shapes(edge: Trajectory) -> None:
    n = edge.n_steps
    assert n >= 300
    assert edge.q.shape == edge.v.shape == edge.u.shape == edge.obs.shape == (n, 2)
    assert edge.modes.shape == edge.mu.shape == edge.ln.shape == (n, 1)
    assert edge.env.shape == (n, 0)
    assert np.allclose(np.diff(edge.t), edge.scenario.dt)


def test_edge_mode_sequence(edge: Trajectory) -> None:
    m = edge.modes[:, 0]
    sep = np.mean(m == Mode.SEPARATED)
    stick = np.mean(m == Mode.STICKING)
    slide = np.mean((m == Mode.SLIDING_POS) | (m == Mode.SLIDING_NEG))
    assert min(sep, stick, slide) >= 0.10, (sep, stick, slide)
    # separated -> sliding (smooth) -> sticking (rough) -> sliding -> separated
    assert _runs(m) == [
        Mode.SEPARATED,
        Mode.SLIDING_POS,
        Mode.STICKING,
        Mode.SLIDING_POS,
        Mode.SEPARATED,
    ]
    x = edge.q[:, 0]
    first_contact = int(np.argmax(m != Mode.SEPARATED))
    assert x[first_contact] < EDGE_ROUGH[0]  # lands in the smooth region
    assert np.all(
        (x[m == Mode.STICKING] > EDGE_ROUGH[0]) & (x[m == Mode.STICKING] < EDGE_ROUGH[1])
    )
    lift = first_contact + int(np.argmax(m[first_contact:] == Mode.SEPARATED))
    assert x[lift] > EDGE_ROUGH[1]  # loses contact in the right smooth region
    # truth friction follows the map (row k + 1 is evaluated at the start of its step, q[k])
    rough = (x[:-1] > EDGE_ROUGH[0]) & (x[:-1] < EDGE_ROUGH[1])
    assert np.allclose(edge.mu[1:][rough, 0], 0.9)
    assert np.allclose(edge.mu[1:][~rough, 0], 0.3)
    # never below the edge
    assert edge.q[:, 1].min() >= -1e-9


def test_edge_observation_noise(edge: Trajectory) -> None:
    err = edge.obs - edge.q
    assert np.std(err) == pytest.approx(0.01, rel=0.15)
    assert abs(np.mean(err)) < 0.003


def test_determinism_and_seeds() -> None:
    a, b, c = edge_trajectory(3), edge_trajectory(3), edge_trajectory(4)
    assert np.array_equal(a.obs, b.obs) and np.array_equal(a.q, b.q)
    assert not np.allclose(a.obs, c.obs)
    assert not np.allclose(a.u, c.u)  # the force profile varies mildly with the seed
    assert np.median(np.abs(a.u - c.u)) < 0.05 * np.abs(a.u).max()


@settings(max_examples=100, deadline=None)
@given(st.floats(min_value=0.0, max_value=8.0), st.floats(min_value=-3.0, max_value=3.0))
def test_delay_is_continuous_not_whole_samples(lag: float, rate: float) -> None:
    """A 38.9 ms delay at 10 ms samples is 3.89 samples, not 4: on a ramp (yaw through
    +-pi included) the delayed samples are the ramp at t - lag, clamped at the start."""
    t = np.arange(12, dtype=np.float64)
    ramp = np.stack([0.01 * rate * t, -0.02 * t, 3.0 + 0.1 * rate * t], axis=1)
    wrapped = ramp.copy()
    wrapped[:, 2] = np.angle(np.exp(1j * ramp[:, 2]))
    got = delayed(wrapped, lag)
    want = ramp[0] + np.maximum(t - lag, 0.0)[:, None] * (ramp[1] - ramp[0])
    assert np.allclose(got, want, atol=1e-9)
    whole = delayed(wrapped[:, :2], float(round(lag)))
    assert np.array_equal(whole, wrapped[np.maximum(t.astype(int) - round(lag), 0), :2])


def test_sensor_delay_extension() -> None:
    delayed = edge_trajectory(0, extensions=(ModelExtension.make("sensor_delay", seconds=0.05),))
    nominal = edge_trajectory(0)
    assert np.array_equal(delayed.q, nominal.q)
    err = delayed.obs[5:] - nominal.q[:-5]
    assert np.std(err) == pytest.approx(0.01, rel=0.2)


def test_gripper_shapes(grip: Trajectory) -> None:
    n = grip.n_steps
    assert grip.q.shape == grip.obs.shape == grip.u.shape == (n, 3)
    assert grip.env.shape == grip.env_obs.shape == (n, 2)
    assert grip.modes.shape == (n, 6)
    assert grip.mu_pair.tolist() == [0.4]
    assert np.all(np.diff(grip.env[:, 1] - grip.env[:, 0]) <= 1e-12)  # jaws only close


def test_gripper_contact_events(grip: Trajectory) -> None:
    m = grip.modes
    touching = m != Mode.SEPARATED
    lower, upper = touching[:, :3].sum(1), touching[:, 3:].sum(1)
    first = int(np.argmax((lower + upper) > 0))
    assert lower[first] > 0 and upper[first] == 0  # approaches the lower jaw first
    vertex = np.sum((lower == 1) | (upper == 1))
    edge = np.sum((lower == 2) | (upper == 2))
    stick = np.sum(np.any(m == Mode.STICKING, axis=1))
    slide = np.sum(np.any((m == Mode.SLIDING_POS) | (m == Mode.SLIDING_NEG), axis=1))
    assert min(vertex, edge, stick, slide) >= 10, (vertex, edge, stick, slide)
    assert np.sum(lower == 2) >= 5 and np.sum(upper == 2) >= 1  # edge contacts on both jaws
    assert np.all(lower <= 2) and np.all(upper <= 2)
    # ends grasped: both jaws in contact over the last steps
    assert np.all(lower[-10:] > 0) and np.all(upper[-10:] > 0)
    # the rigid body never penetrates a jaw by more than round-off
    kin = contact_kinematics(grip.scenario, grip.q, grip.env)
    assert kin.phi.min() >= -1e-8


def test_gripper_observation_noise(grip: Trajectory) -> None:
    err = grip.obs - grip.q
    err[:, 2] = (err[:, 2] + np.pi) % (2 * np.pi) - np.pi
    assert np.std(err[:, :2]) == pytest.approx(0.002, rel=0.15)
    assert np.std(err[:, 2]) == pytest.approx(0.02, rel=0.15)
    assert np.std(grip.env_obs - grip.env) == pytest.approx(0.0005, rel=0.15)
