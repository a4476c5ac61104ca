"""The friction bank (`FilterConfig.friction_bank`): one continuous state per friction
hypothesis per particle (fixed seeds, synthetic runs)."""

from __future__ import annotations

from dataclasses import replace

import hypothesis.extra.numpy as hnp
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from dbcslam_core.friction_bank import (
    bank_mean,
    bank_rows,
    combine_evidence,
    sample_shared_proposal,
    shared_normal,
    weighted_rows,
)
from dbcslam_core.observation import (
    LinearObservation,
    PoseObservation,
    gaussian_proposal,
    sample_gaussian_proposal,
)
from dbcslam_core.rbpf import DbcSlamFilter, Estimate, FilterConfig, FilterInput
from dbcslam_core.synthetic import Trajectory, edge_trajectory, gripper_trajectory


def _obs(traj: Trajectory, k: int) -> PoseObservation:
    o = traj.obs[k]
    return PoseObservation(float(o[0]), float(o[1]), float(o[2]) if o.size == 3 else None)


def _run(
    traj: Trajectory, cfg: FilterConfig, seed: int = 0
) -> tuple[list[Estimate], DbcSlamFilter]:
    sc = traj.scenario
    f = DbcSlamFilter(sc, cfg, np.random.default_rng(seed))
    f.initialize(traj.obs[0], traj.obs[0] * 0 + sc.noise.position, joints=traj.env_obs[0])
    out = [
        f.step(_obs(traj, k + 1), FilterInput(tuple(traj.u[k]), tuple(traj.env_obs[k + 1])))
        for k in range(traj.n_steps - 1)
    ]
    return out, f


def _pos_rmse(est: list[Estimate], traj: Trajectory) -> float:
    pose = np.array([e.pose[:2] for e in est])
    return float(np.sqrt(np.mean((pose - traj.q[1:, :2]) ** 2)))


@pytest.fixture(scope="module")
def gripper_traj() -> Trajectory:
    return gripper_trajectory(1, duration=3.0)  # true jaw friction 0.4 (candidate 1)


def _assert_same(a: list[Estimate], b: list[Estimate]) -> None:
    for x, y in zip(a, b, strict=True):
        np.testing.assert_array_equal(x.pose, y.pose)
        np.testing.assert_array_equal(x.twist, y.twist)
        np.testing.assert_array_equal(x.modes, y.modes)
        np.testing.assert_array_equal(x.friction, y.friction)
        assert x.log_likelihood == y.log_likelihood
        assert x.resampled == y.resampled


@pytest.mark.parametrize("kind", ["gripper", "edge"])
@pytest.mark.parametrize("copies", ["bank", "filters"])
def test_copies_with_one_hypothesis_are_the_single_copy_filter(kind: str, copies: str) -> None:
    """B = 1 (frozen friction): the copies consume the same random numbers and do the same
    arithmetic as the single-copy filter, so the outputs are equal (bank: identical; filters:
    to round-off, its weights are renormalised every step)."""
    traj = gripper_trajectory(1, duration=1.0) if kind == "gripper" else edge_trajectory(0)
    cfg = FilterConfig.preset(kind, particles=30, frozen_friction=1, friction_copies="none")
    single, fs = _run(traj, cfg)
    copied, fc = _run(traj, replace(cfg, friction_copies=copies))
    assert fc.bank is not None and fs.bank is None
    if copies == "bank":
        _assert_same(single, copied)
        np.testing.assert_array_equal(fs.q, fc.q)
        np.testing.assert_array_equal(fs.modes, fc.modes)
        return
    for x, y in zip(single, copied, strict=True):
        np.testing.assert_allclose(x.pose, y.pose, rtol=0, atol=1e-12)
        np.testing.assert_allclose(x.modes, y.modes, rtol=0, atol=1e-9)
        assert x.log_likelihood == pytest.approx(y.log_likelihood, abs=1e-9)
        assert x.resampled == y.resampled


@pytest.mark.parametrize("copies", ["bank", "filters"])
def test_copies_do_not_collapse_onto_a_wrong_friction(
    gripper_traj: Trajectory, copies: str
) -> None:
    """At 40 particles the single-copy filter ends confidently on a wrong jaw friction in
    some seeds (each particle's belief turns one-hot at an impact, resampling on pose spreads
    one label); with a state copy per friction hypothesis mu = 0.4 is identified in every
    seed, tracking at least as well."""
    true_k = 1
    wrong_single = 0
    for seed in range(3):
        cfg = FilterConfig.preset("gripper", particles=40, friction_copies="none")
        single, _ = _run(gripper_traj, cfg, seed)
        copied, _ = _run(gripper_traj, replace(cfg, friction_copies=copies), seed)
        if single[-1].friction[0, true_k] < 0.01:
            wrong_single += 1
        assert copied[-1].friction[0, true_k] > 0.9, (seed, copied[-1].friction)
        assert _pos_rmse(copied, gripper_traj) < 0.5 * gripper_traj.scenario.noise.position
    assert wrong_single >= 1  # the collapse the copies fix (seeds 0 and 1 today)


def test_filters_rows_are_the_public_particles() -> None:
    traj = gripper_trajectory(1, duration=0.5)
    cfg = FilterConfig.preset("gripper", particles=20, friction_copies="filters")
    est, f = _run(traj, replace(cfg, friction_hold_steps=0))
    rows = 20 * f.n_b
    assert f.q.shape == (rows, 3) and f.v.shape == (rows, 3) and f.log_w.shape == (rows,)
    assert f.fric.shape == (rows, f.n_b)
    np.testing.assert_allclose(f.fric, np.tile(est[-1].friction[0], (rows, 1)), atol=1e-9)
    # the row weights are the column weights x the belief in the column's friction
    w = np.exp(f.log_w)
    np.testing.assert_allclose(w.reshape(20, f.n_b).sum(axis=0), f.fric[0], atol=1e-9)
    assert any(e.resampled for e in est)


def test_bank_public_arrays_and_resampling_keep_copies_together() -> None:
    traj = gripper_trajectory(1, duration=0.5)
    n_p = 20
    f = DbcSlamFilter(
        traj.scenario,
        FilterConfig.preset(
            "gripper", particles=n_p, friction_hold_steps=0, friction_copies="bank"
        ),
        np.random.default_rng(3),
    )
    assert f.bank is not None
    n_b = f.n_b
    f.initialize(traj.obs[0], traj.obs[0] * 0 + 1e-3, joints=traj.env_obs[0])
    # every copy of a bank starts from the particle's draw
    np.testing.assert_allclose(f.particles.q, np.repeat(f.q, n_b, axis=0), rtol=1e-12, atol=1e-15)
    resampled = False
    for k in range(traj.n_steps - 1):
        est = f.step(_obs(traj, k + 1), FilterInput(tuple(traj.u[k]), tuple(traj.env_obs[k + 1])))
        resampled |= est.resampled
        assert f.q.shape == (n_p, 3) and f.v.shape == (n_p, 3) and f.log_w.shape == (n_p,)
        assert f.fric.shape == (n_p, n_b) and f.modes.shape == (n_p, n_b, f.n_c, 4)
        np.testing.assert_allclose(f.fric.sum(axis=1), 1.0)
        np.testing.assert_allclose(est.friction.sum(axis=1), 1.0)
    assert resampled
    # setting q moves every copy by the change of the bank mean (session catch-up)
    before = f.particles.q.copy()
    f.q = f.q + np.array([0.01, -0.02, 0.0])
    np.testing.assert_allclose(f.particles.q - before, np.tile([0.01, -0.02, 0.0], (n_p * n_b, 1)))


def test_bank_rows_and_weighted_rows() -> None:
    np.testing.assert_array_equal(bank_rows(np.array([2, 0]), 3), [6, 7, 8, 0, 1, 2])
    x = np.arange(12.0).reshape(6, 2)  # 2 banks x 3 copies
    w = np.array([[1.0, 0.0, 0.0], [0.25, 0.25, 0.5]])
    np.testing.assert_allclose(weighted_rows(x, w), [[0.0, 1.0], [8.5, 9.5]])


def test_bank_mean_wraps_angles() -> None:
    q = np.array([[0.0, 0.0, np.pi - 0.1], [1.0, 0.0, -np.pi + 0.1]])
    m = bank_mean(q, np.array([[0.5, 0.5]]), angular=True)
    np.testing.assert_allclose(m[0, :2], [0.5, 0.0])
    assert abs(abs(m[0, 2]) - np.pi) < 1e-12


@settings(max_examples=60, deadline=None)
@given(
    fric=hnp.arrays(np.float64, (4, 3), elements=st.floats(0.01, 1.0)),
    log_lik=hnp.arrays(np.float64, (12,), elements=st.floats(-50.0, 50.0)),
)
def test_combine_evidence_is_bayes(fric: np.ndarray, log_lik: np.ndarray) -> None:
    fric = fric / fric.sum(axis=1, keepdims=True)
    incr, post = combine_evidence(fric, log_lik)
    lik = np.exp(log_lik.reshape(4, 3))
    np.testing.assert_allclose(incr, np.log((fric * lik).sum(axis=1)), rtol=1e-9, atol=1e-9)
    np.testing.assert_allclose(post, fric * lik / (fric * lik).sum(axis=1, keepdims=True))


def test_combine_evidence_zero_likelihood_bank_keeps_its_belief() -> None:
    fric = np.array([[0.2, 0.8], [0.5, 0.5]])
    incr, post = combine_evidence(fric, np.array([-np.inf, -np.inf, 0.0, -np.inf]))
    assert incr[0] == -np.inf and incr[1] == pytest.approx(np.log(0.5))
    np.testing.assert_array_equal(post, [[0.2, 0.8], [1.0, 0.0]])


def test_shared_proposal_sample_equals_the_rng_driven_one() -> None:
    rng = np.random.default_rng(7)
    n, nq = 6, 3
    q = rng.normal(size=(n, nq))
    v_h = rng.normal(size=(n, nq))
    a = rng.normal(size=(n, nq, nq))
    cov = a @ np.swapaxes(a, -1, -2) * 1e-2 + 1e-4 * np.eye(nq)
    lin = LinearObservation(
        index=np.array([0, 1, 2]),
        value=np.array([0.1, -0.2, 0.3]),
        var=np.full(3, 1e-4),
        angular=np.array([False, False, True]),
    )
    prop = gaussian_proposal(q, v_h, cov, 0.01, lin, sigma_q=np.full(nq, 1e-4))
    kw = {"v_h": v_h, "innovation": prop.innovation, "v_mean": prop.v_mean, "v_cov": prop.v_cov}
    v1, e1 = sample_gaussian_proposal(prop, **kw, dt=0.01, rng=np.random.default_rng(1))
    r = np.random.default_rng(1)
    z_v, z_q = shared_normal(r, n, 1, (nq,)), shared_normal(r, n, 1, (nq,))
    v2, e2 = sample_shared_proposal(prop, **kw, dt=0.01, z_v=z_v, z_q=z_q)
    np.testing.assert_array_equal(v1, v2)
    np.testing.assert_array_equal(e1, e2)
    z = shared_normal(np.random.default_rng(0), 2, 3, (nq,))
    np.testing.assert_array_equal(z[0], z[2])
    assert not np.array_equal(z[0], z[3])
