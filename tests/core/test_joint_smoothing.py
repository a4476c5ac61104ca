"""Two-sided joint smoothing (`observation.smooth_joint_readings`) and its use by the
discrepancy score (`discrepancy.scoring.scoring_joints`): the recorded pusher readings of a
push run are smoothed over the whole run, without the causal smoother's lag at stops."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from dbcslam_core.discrepancy.scoring import JOINT_SMOOTHING, ScoreConfig, scoring_joints
from dbcslam_core.errors import ModelError
from dbcslam_core.observation import JointSmoother, smooth_joint_readings
from dbcslam_core.scenario import gripper_scenario, push_scenario
from dbcslam_core.synthetic import PUSH_RECT, PUSH_RECT_MASS

DT, NOISE = 0.01, 5e-4


def _batch_map(z: np.ndarray, dt: float, noise: float, accel: float) -> np.ndarray:
    """Positions of the MAP trajectory of the constant-velocity model given readings z (T,)
    by one dense least-squares solve (the smoother's definition, not its recursion). The
    model's process noise is one white acceleration a_k per step, x_k+1 = F x_k + g a_k,
    g = (dt^2 / 2, dt), a_k ~ N(0, accel^2); prior x_0 ~ N((z_0, 0), diag(r, 1)). Unknowns
    theta = (x_0, a_0 .. a_T-2); positions = A theta."""
    n = z.shape[0]
    f = np.array([[1.0, dt], [0.0, 1.0]])
    g = np.array([dt**2 / 2.0, dt])
    m = 2 + (n - 1)
    lin = np.zeros((n, 2, m))  # state k as a linear map of theta
    lin[0, :, :2] = np.eye(2)
    for k in range(n - 1):
        lin[k + 1] = f @ lin[k]
        lin[k + 1, :, 2 + k] += g
    ok = np.isfinite(z)
    a = lin[ok, 0, :] / noise
    b = z[ok] / noise
    prior_sd = np.concatenate([[noise, 1.0], np.full(n - 1, accel)])
    prior_mean = np.concatenate([[z[0], 0.0], np.zeros(n - 1)])
    a = np.vstack([a, np.diag(1.0 / prior_sd)])
    b = np.concatenate([b, prior_mean / prior_sd])
    theta = np.linalg.lstsq(a, b, rcond=None)[0]
    return lin[:, 0, :] @ theta


def _stop_and_go(n: int = 300) -> np.ndarray:
    """A pusher track (T,) that moves at 0.1 m/s and stops within 0.1 s, twice (m)."""
    t = np.arange(n) * DT
    speed = 0.1 * ((t % 1.5) < 0.9)
    return np.cumsum(np.convolve(speed, np.ones(10) / 10.0, mode="same")) * DT


def test_smoother_is_the_map_trajectory_of_its_model() -> None:
    rng = np.random.default_rng(3)
    truth = _stop_and_go(80)
    z = truth + NOISE * rng.standard_normal(truth.shape)
    z[30:34] = np.nan  # missing readings: prediction only
    got = smooth_joint_readings(z[:, None], DT, NOISE, 1.0)[:, 0]
    np.testing.assert_allclose(got, _batch_map(z, DT, NOISE, 1.0), rtol=0, atol=1e-9)


def test_two_sided_smoothing_has_no_lag_at_stops() -> None:
    """The reason the score uses it: the causal smoother overshoots the pusher's stops."""
    rng = np.random.default_rng(4)
    truth = _stop_and_go()
    z = truth + NOISE * rng.standard_normal(truth.shape)
    two = smooth_joint_readings(z[:, None], DT, NOISE, 1.0)[:, 0]
    js = JointSmoother(1, DT, NOISE, 1.0, maneuver_accel_std=3.0)
    js.reset(z[:1])
    causal = np.concatenate([z[:1], [js.update(z[k : k + 1])[0] for k in range(1, z.size)]])

    def rms(x: np.ndarray) -> float:
        return float(np.sqrt(np.mean((x[20:] - truth[20:]) ** 2)))

    assert rms(two) < 0.5 * NOISE
    assert rms(two) < 0.8 * rms(causal)


@settings(max_examples=40, deadline=None)
@given(
    shift=st.floats(-2.0, 2.0),
    seed=st.integers(0, 2**16),
    accel=st.floats(0.1, 10.0),
)
def test_smoother_properties(shift: float, seed: int, accel: float) -> None:
    """Shift-equivariant, joints independent of each other, noise 0 passes readings."""
    rng = np.random.default_rng(seed)
    z = np.cumsum(rng.normal(0.0, 1e-3, size=(60, 2)), axis=0)
    both = smooth_joint_readings(z, DT, NOISE, accel)
    np.testing.assert_allclose(
        smooth_joint_readings(z + shift, DT, NOISE, accel), both + shift, atol=1e-9
    )
    one = smooth_joint_readings(z[:, 1:], DT, NOISE, accel)
    np.testing.assert_allclose(one[:, 0], both[:, 1], atol=1e-12)
    np.testing.assert_array_equal(smooth_joint_readings(z, DT, 0.0, accel), z)


@pytest.mark.parametrize(
    ("readings", "dt", "noise", "accel", "match"),
    [
        (np.zeros(5), DT, NOISE, 1.0, "readings"),
        (np.zeros((5, 1)), 0.0, NOISE, 1.0, "dt"),
        (np.zeros((5, 1)), DT, -1.0, 1.0, "noise"),
        (np.zeros((5, 1)), DT, NOISE, 0.0, "accel_std"),
        (np.full((5, 2), np.nan), DT, NOISE, 1.0, r"joint columns \[0, 1\]"),
    ],
)
def test_smoother_rejects_bad_input(
    readings: np.ndarray, dt: float, noise: float, accel: float, match: str
) -> None:
    with pytest.raises(ModelError, match=match):
        smooth_joint_readings(readings, dt, noise, accel)


def test_score_smooths_push_joints_only() -> None:
    rng = np.random.default_rng(5)
    push = push_scenario(PUSH_RECT, mass=PUSH_RECT_MASS, support_pair="surface")
    env = np.stack([np.zeros(200), _stop_and_go(200)], -1) + NOISE * rng.standard_normal((200, 2))
    sc, got = scoring_joints(push, env, ScoreConfig())
    assert sc.noise.joint == 0.0  # the filter takes the smoothed readings as exact
    assert dataclasses.replace(sc, noise=push.noise) == push
    np.testing.assert_allclose(
        got, smooth_joint_readings(env, push.dt, push.noise.joint, JOINT_SMOOTHING["push"])
    )
    off = scoring_joints(push, env, ScoreConfig(two_sided_joints=False))
    assert off[0] is push and off[1] is env
    grip = gripper_scenario()
    genv = env[:, :1] if len(grip.joints) == 1 else np.zeros((200, len(grip.joints)))
    assert grip.kind not in JOINT_SMOOTHING
    assert scoring_joints(grip, genv, ScoreConfig())[1] is genv
