"""Observation model and the closed-form optimal proposal."""

from __future__ import annotations

import numpy as np
import pytest

from dbcslam_core.errors import ModelError
from dbcslam_core.observation import (
    ForceObservation,
    JointSmoother,
    PoseObservation,
    PoseObservationModel,
    proposal_terms,
    sample_noise,
    wrap_angle,
)


def test_linearize_and_likelihood() -> None:
    m = PoseObservationModel(3, 0.01, 0.1)
    lin = m.linearize(PoseObservation(1.0, 2.0, np.pi - 0.05))
    q = np.array([1.0, 2.0, -np.pi + 0.05])  # 0.1 rad away across the wrap
    ll = lin.log_likelihood(q)
    expected = -0.5 * (
        (0.1 / 0.1) ** 2 + 2 * np.log(2 * np.pi) + np.log(2 * np.pi) + np.log(1e-4 * 1e-4 * 1e-2)
    )
    assert ll == pytest.approx(expected)
    assert PoseObservationModel(2, 0.01).linearize(PoseObservation(0.0, 0.0)).index.size == 2
    with pytest.raises(ModelError, match="no yaw"):
        PoseObservationModel(2, 0.01).linearize(PoseObservation(0.0, 0.0, 0.1))
    with pytest.raises(ModelError, match="finite"):
        m.linearize(PoseObservation(np.nan, 0.0, 0.0))
    assert wrap_angle(3 * np.pi) == pytest.approx(-np.pi)


def test_proposal_matches_joint_gaussian_conditioning() -> None:
    """(e_v, e_q, o) are jointly Gaussian per dimension: compare with direct conditioning."""
    dt, sv, sq, r = 0.01, 0.3, 0.002, 0.01
    m = PoseObservationModel(2, r)
    lin = m.linearize(PoseObservation(0.013, -0.004))
    q = np.array([0.0, 0.0])
    vh = np.array([1.0, -0.5])
    t = proposal_terms(q, vh, dt, np.full(2, sv), lin, sigma_q=np.full(2, sq))
    # joint covariance of (e_v, e_q, o) for one dimension
    cov = np.array(
        [
            [sv**2, 0.0, dt * sv**2],
            [0.0, sq**2, sq**2],
            [dt * sv**2, sq**2, dt**2 * sv**2 + sq**2 + r**2],
        ]
    )
    for d in range(2):
        y = lin.value[d] - (q[d] + dt * vh[d])
        mean_post = cov[:2, 2] / cov[2, 2] * y
        cov_post = cov[:2, :2] - np.outer(cov[:2, 2], cov[2, :2]) / cov[2, 2]
        assert t.v_mean[d] == pytest.approx(mean_post[0])
        assert t.v_std[d] ** 2 == pytest.approx(cov_post[0, 0])
        # e_q | e_v: conditional of the joint posterior
        gain = cov_post[1, 0] / cov_post[0, 0]
        var_q = cov_post[1, 1] - cov_post[1, 0] ** 2 / cov_post[0, 0]
        assert t.q_std[d] ** 2 == pytest.approx(var_q)
        e_v = 0.05
        mean_q = t.q_gain[d] * (y - dt * e_v)
        assert mean_q == pytest.approx(mean_post[1] + gain * (e_v - mean_post[0]))
    s = dt**2 * sv**2 + sq**2 + r**2
    y = lin.value - dt * vh
    assert float(t.log_pred) == pytest.approx(
        float(np.sum(-0.5 * (y**2 / s + np.log(2 * np.pi * s))))
    )


def test_sample_noise_moments_and_prediction_only() -> None:
    dt = 0.01
    lin = PoseObservationModel(2, 0.01).linearize(PoseObservation(0.02, 0.0))
    sv = np.array([0.5, 0.5])
    sq = np.array([0.001, 0.001])
    t = proposal_terms(np.zeros(2), np.zeros(2), dt, sv, lin, sigma_q=sq)
    rng = np.random.default_rng(1)
    n = 200_000
    e_v, e_q = sample_noise(
        t, np.broadcast_to(t.innovation, (n, 2)), np.broadcast_to(t.v_mean, (n, 2)), dt, rng
    )
    q_next = dt * e_v + e_q
    # posterior mean of q' given o: prior var p = dt^2 sv^2 + sq^2, obs var R
    p = dt**2 * sv[0] ** 2 + sq[0] ** 2
    assert q_next[:, 0].mean() == pytest.approx(p / (p + 1e-4) * 0.02, rel=0.02)
    assert q_next[:, 0].var() == pytest.approx(p * 1e-4 / (p + 1e-4), rel=0.02)
    t0 = proposal_terms(np.zeros(2), np.zeros(2), dt, sv, None, sigma_q=sq)
    assert float(t0.log_pred) == 0.0
    np.testing.assert_allclose(t0.v_std, sv)
    np.testing.assert_allclose(t0.q_std, sq)


def test_joint_smoother_reduces_noise_and_tracks_ramp() -> None:
    rng = np.random.default_rng(0)
    dt, noise = 0.01, 5e-4
    t = np.arange(300) * dt
    truth = 0.05 * t
    sm = JointSmoother(1, dt, noise, accel_std=0.3)
    sm.reset(truth[0] + noise * rng.standard_normal())
    est = np.array([sm.update([x + noise * rng.standard_normal()])[0] for x in truth[1:]])
    err = est[50:] - truth[51:]
    assert np.sqrt(np.mean(err**2)) < 0.5 * noise
    passthrough = JointSmoother(2, dt, 0.0)
    np.testing.assert_allclose(passthrough.update([1.0, 2.0]), [1.0, 2.0])


def test_full_covariance_proposal_matches_diagonal_case_and_conditioning() -> None:
    from scipy.stats import multivariate_normal

    from dbcslam_core.observation import gaussian_log_density, gaussian_proposal

    dt = 0.01
    lin = PoseObservationModel(3, 0.002, 0.02).linearize(PoseObservation(0.001, -0.002, 0.03))
    q = np.array([0.0, 0.0, 0.01])
    vh = np.array([0.1, -0.2, 1.0])
    sv = np.array([0.3, 0.2, 2.0])
    sq = np.array([1e-4, 1e-4, 1e-3])
    diag = proposal_terms(q, vh, dt, sv, lin, sigma_q=sq)
    full = gaussian_proposal(q, vh, np.diag(sv**2), dt, lin, sigma_q=sq)
    assert float(full.log_pred) == pytest.approx(float(diag.log_pred))
    np.testing.assert_allclose(full.v_mean - vh, diag.v_mean)
    np.testing.assert_allclose(np.sqrt(np.diag(full.v_cov)), diag.v_std)
    # a correlated covariance: compare with joint-Gaussian conditioning of (v', o)
    a = np.array([[1.0, 0.3, 0.0], [0.3, 0.5, 0.2], [0.0, 0.2, 2.0]])
    cov = a @ a.T * 0.01
    full = gaussian_proposal(q, vh, cov, dt, lin, sigma_q=sq)
    s_o = dt**2 * cov + np.diag(sq**2 + lin.var)
    y = lin.residual(q + dt * vh)
    c = dt * cov
    np.testing.assert_allclose(full.v_mean, vh + c @ np.linalg.solve(s_o, y))
    np.testing.assert_allclose(full.v_cov, cov - c @ np.linalg.solve(s_o, c.T), atol=1e-15)
    expected = multivariate_normal(np.zeros(3), s_o).logpdf(y)
    assert float(full.log_pred) == pytest.approx(float(expected))
    x = np.array([0.01, -0.02, 0.05])
    assert float(gaussian_log_density(x, cov)) == pytest.approx(
        float(multivariate_normal(np.zeros(3), cov).logpdf(x))
    )


def test_force_observation_validates() -> None:
    f = ForceObservation(1.0, -2.0)
    assert f.obstacle is None and f.std is None
    with pytest.raises(ModelError, match="finite"):
        ForceObservation(float("nan"), 0.0)
    with pytest.raises(ModelError, match="std"):
        ForceObservation(0.0, 0.0, std=0.0)


def test_joint_smoother_maneuver_companion_is_smooth_and_follows_stops() -> None:
    """A stiff smoother alone lags at a stop; the agile companion takes over there, while the
    constant-speed velocity stays far more precise than with a soft smoother."""
    dt, noise = 0.01, 5e-4

    def run(accel: float, maneuver: float | None) -> tuple[float, float]:
        js = JointSmoother(1, dt, noise, accel, maneuver_accel_std=maneuver)
        js.reset([0.0])
        rng = np.random.default_rng(0)
        v_err, p_err = [], []
        for k in range(300):
            t = k * dt
            x = 0.05 * min(max(t - 0.5, 0.0), 1.5)
            v = 0.05 if 0.5 <= t < 2.0 else 0.0
            pos = js.update([x + noise * rng.standard_normal()])[0]
            if 100 <= k < 190:
                v_err.append(js.velocity[0] - v)
            if 200 <= k < 240:
                p_err.append(abs(pos - x))
        return float(np.std(v_err)), float(np.max(p_err))

    v_soft, _ = run(0.3, None)
    _, p_stiff = run(0.01, None)
    v_man, p_man = run(0.01, 3.0)
    assert v_man < 0.2 * v_soft
    assert p_man < 0.5 * p_stiff
