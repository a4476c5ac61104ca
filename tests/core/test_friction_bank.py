"""The friction bank (`FilterConfig.friction_bank`): one copy of each particle's continuous
state per friction hypothesis, driven by shared random numbers; the particle's friction
belief is updated by its copies' predictive likelihoods."""

from __future__ import annotations

from dataclasses import replace
from typing import Any

import numpy as np
import pytest

from dbcslam_core.errors import ModelError
from dbcslam_core.observation import PoseObservation
from dbcslam_core.particles import MapHistory, ParticleSet
from dbcslam_core.rbpf import (
    GRIPPER_BANK_PARTICLES,
    DbcSlamFilter,
    Estimate,
    FilterConfig,
    FilterInput,
)
from dbcslam_core.synthetic import Trajectory, gripper_trajectory


@pytest.fixture(scope="module")
def gripper_traj() -> Trajectory:
    return gripper_trajectory(1, duration=2.0)


def _run(
    traj: Trajectory, cfg: FilterConfig, seed: int = 0
) -> tuple[list[Estimate], DbcSlamFilter]:
    sc = traj.scenario
    filt = DbcSlamFilter(sc, cfg, np.random.default_rng(seed))
    filt.initialize(traj.obs[0], [sc.noise.position] * 2 + [sc.noise.yaw], joints=traj.env_obs[0])
    out = []
    for k in range(traj.n_steps - 1):
        o = traj.obs[k + 1]
        obs = PoseObservation(float(o[0]), float(o[1]), float(o[2]))
        out.append(filt.step(obs, FilterInput(tuple(traj.u[k]), tuple(traj.env_obs[k + 1]))))
    return out, filt


def test_bank_is_the_default_of_the_gripper_preset_only_at_small_particle_counts() -> None:
    small, large = GRIPPER_BANK_PARTICLES - 1, GRIPPER_BANK_PARTICLES
    assert FilterConfig.preset("gripper", particles=small).friction_bank
    assert not FilterConfig.preset("gripper", particles=large).friction_bank
    assert not FilterConfig.preset("gripper").friction_bank  # 500 particles by default
    assert FilterConfig.preset("gripper", particles=large, friction_bank=True).friction_bank
    assert not FilterConfig.preset("gripper", particles=40, friction_bank=False).friction_bank
    assert not FilterConfig.preset("push", particles=small).friction_bank


def test_bank_options_without_the_bank_are_refused_not_ignored() -> None:
    """At 200 particles and more the gripper preset has no bank: a bank option there would
    silently do nothing, so it is an error that says how to turn the bank on."""
    with pytest.raises(ModelError, match="bank_switch acts only with friction_bank=True"):
        FilterConfig.preset("gripper", particles=GRIPPER_BANK_PARTICLES, bank_switch=1e-4)
    with pytest.raises(ModelError, match="bank_resampling, bank_surprise_window act only"):
        FilterConfig.preset(
            "edge", bank_resampling="hypothesis", bank_surprise_window=10, particles=40
        )
    on = FilterConfig.preset("gripper", particles=500, friction_bank=True, bank_switch=1e-4)
    assert on.friction_bank and on.bank_switch == 1e-4
    assert FilterConfig.preset("gripper", particles=40, bank_switch=1e-4).friction_bank
    assert not FilterConfig.preset("edge").friction_bank
    with pytest.raises(ModelError, match="friction_bank needs the time-invariant"):
        FilterConfig.preset("edge", friction_bank=True)


def test_copies_stay_identical_and_keep_the_prior_until_friction_matters(
    gripper_traj: Trajectory,
) -> None:
    """Before the first contact the friction cannot matter: a particle's copies see the same
    random numbers and the same dynamics, so they stay bit-identical and the bank belief
    stays at the prior (any asymmetry in the bank's bookkeeping would show here)."""
    first_contact = int(np.argmax((gripper_traj.modes != 0).any(axis=1)))
    assert first_contact > 10
    tr = replace(
        gripper_traj,
        **{
            f: getattr(gripper_traj, f)[: first_contact - 5]
            for f in (
                "t",
                "q",
                "v",
                "u",
                "env",
                "modes",
                "ln",
                "lt",
                "mu",
                "mu_pair",
                "obs",
                "env_obs",
            )
        },
    )
    cfg = FilterConfig.preset("gripper", particles=12, friction_hold_steps=0)
    est, filt = _run(tr, cfg)
    q = filt.q.reshape(12, 3, -1)
    np.testing.assert_array_equal(q[:, 0], q[:, 1])
    np.testing.assert_array_equal(q[:, 0], q[:, 2])
    assert filt.particles.bank is not None
    prior = np.asarray(tr.scenario.friction.prior[0])
    np.testing.assert_allclose(filt.particles.bank, np.tile(prior / prior.sum(), (12, 1)))
    np.testing.assert_allclose(est[-1].friction[0, :3], prior / prior.sum())


def test_bank_tracks_and_finds_the_friction(gripper_traj: Trajectory) -> None:
    true_mu = float(gripper_traj.mu[-1].max())
    cands = gripper_traj.scenario.friction.candidates[0]
    est, _ = _run(gripper_traj, FilterConfig.preset("gripper", particles=40), seed=3)
    pose = np.array([e.pose for e in est])
    err = np.sqrt(np.mean((pose[:, :2] - gripper_traj.q[1:, :2]) ** 2))
    assert err < 0.6 * gripper_traj.scenario.noise.position
    assert est[-1].friction[0, cands.index(true_mu)] > 0.9


def _bank_particles(n_p: int, copies: int, bank: np.ndarray, **extra: Any) -> ParticleSet:
    """A ParticleSet of n_p particles x copies rows whose row r sits at q = (r, r, r)."""
    rows = n_p * copies
    return ParticleSet(
        q=np.arange(rows, dtype=float)[:, None] * np.ones((1, 3)),
        v=np.zeros((rows, 3)),
        log_w=np.zeros(n_p),
        fric=np.ones((rows, 1)),
        modes=np.zeros((rows, 1, 2, 4)),
        history=MapHistory(2, n_p, 5),
        bank=bank,
        copies=copies,
        **extra,
    )


def test_resampling_moves_a_particles_copies_together() -> None:
    n_p, copies = 4, 3
    ps = _bank_particles(n_p, copies, np.arange(n_p * copies, dtype=float).reshape(n_p, copies))
    ps.resample(np.array([2, 2, 0, 3]))
    assert ps.q[:, 0].tolist() == [6, 7, 8, 6, 7, 8, 0, 1, 2, 9, 10, 11]
    assert ps.bank is not None
    assert ps.bank[:, 0].tolist() == [6, 6, 0, 9]
    assert ps.count == 4 and ps.size == 12


def test_bank_fixes_the_collapse_of_the_single_copy_filter() -> None:
    """At 40 particles, initial spread 2 mm / 2 mrad (pose and yaw), the single-copy filter
    ends confidently on a wrong jaw friction in seeds 0 and 1 (each particle's belief turns
    one-hot at an impact, resampling on pose spreads one label); the bank ends on the true
    mu = 0.4 in every seed. Not asserted, measured: with the yaw spread at the yaw noise
    (`_run`) the bank ends right in 3 of seeds 0-4 and the single-copy filter in 4."""
    traj = gripper_trajectory(1, duration=3.0)
    sc = traj.scenario
    true_k = sc.friction.candidates[0].index(float(traj.mu[-1].max()))

    def final_p(cfg: FilterConfig, seed: int) -> float:
        filt = DbcSlamFilter(sc, cfg, np.random.default_rng(seed))
        filt.initialize(traj.obs[0], [sc.noise.position] * 3, joints=traj.env_obs[0])
        for k in range(traj.n_steps - 1):
            o = traj.obs[k + 1]
            est = filt.step(
                PoseObservation(float(o[0]), float(o[1]), float(o[2])),
                FilterInput(tuple(traj.u[k]), tuple(traj.env_obs[k + 1])),
            )
        return float(est.friction[0, true_k])

    collapsed = 0
    for seed in range(3):
        cfg = FilterConfig.preset("gripper", particles=40)
        collapsed += int(final_p(replace(cfg, friction_bank=False), seed) < 0.01)
        assert final_p(cfg, seed) > 0.9, seed
    assert collapsed >= 1


# ------------------------------------------------------------ bank options (issue 10)
def _bank_filter(particles: int = 4, **changes: object) -> DbcSlamFilter:
    """A gripper filter with the bank, initialised, past its friction hold, whose copies
    carry distinct poses (row r has x = r)."""
    traj = gripper_trajectory(1, duration=0.3)
    sc = traj.scenario
    cfg = FilterConfig.preset(
        "gripper", particles=particles, friction_hold_steps=0, friction_bank=True, **changes
    )
    filt = DbcSlamFilter(sc, cfg, np.random.default_rng(0))
    filt.initialize(traj.obs[0], [sc.noise.position] * 2 + [sc.noise.yaw], joints=traj.env_obs[0])
    filt._step = 1  # past friction_hold_steps = 0
    q = filt.q.copy()
    q[:, 0] = np.arange(q.shape[0], dtype=float)
    filt.q = q
    return filt


def _posterior_stub(filt: DbcSlamFilter) -> object:
    """A `_Posterior` with the shapes `_bank_evidence` reads (one pair, C contacts)."""
    from dbcslam_core.rbpf import _Posterior

    rows, n_c = filt.particles.size, filt.n_c
    return _Posterior(
        fric_post=np.ones((rows, 1)),
        fric_pair=np.empty((0, 1, 3)),
        modes_post=np.zeros((rows, 1, n_c, 4)),
        marg_post=np.zeros((rows, n_c, 4)),
        pair_in=np.zeros((rows, 1)),
        p_contact=np.zeros((rows, n_c)),
    )


@pytest.mark.parametrize(
    ("name", "value"),
    [
        ("bank_switch", -0.1),
        ("bank_switch", 1.0),
        ("bank_tempering", 0.0),
        ("bank_tempering", 1.5),
        ("bank_step_cap", 0.0),
        ("bank_step_cap", float("nan")),
        ("bank_surprise_gate", -1.0),
        ("bank_surprise_window", 4),
    ],
)
def test_bank_option_validation(name: str, value: float) -> None:
    with pytest.raises(ModelError, match=name):
        FilterConfig.preset("gripper", **{name: value})


def test_bank_options_default_to_the_exact_bank() -> None:
    cfg = FilterConfig.preset("gripper")
    assert cfg.bank_switch == 0.0 and cfg.bank_tempering == 1.0
    assert cfg.bank_step_cap is None and cfg.bank_surprise_gate is None


def test_switch_mixing_reseeds_a_negligible_copy_from_the_leader() -> None:
    """IMM mixing: a copy whose belief is far below the switch probability restarts from the
    leading copy's state; the leading copy keeps its own; the belief is the prediction
    through the switching transition."""
    eps = 1e-3
    filt = _bank_filter(bank_switch=eps)
    ps = filt.particles
    assert ps.bank is not None
    ps.bank = np.array([[1e-12, 1.0 - 2e-12, 1e-12]] * ps.count)
    q_before = ps.q.copy()
    filt._mix_bank()
    x = ps.q[:, 0].reshape(ps.count, 3)
    leader = q_before[:, 0].reshape(ps.count, 3)[:, 1]
    np.testing.assert_array_equal(x, np.repeat(leader[:, None], 3, axis=1))
    np.testing.assert_allclose(ps.bank[:, [0, 2]], eps / 2, rtol=1e-6)
    np.testing.assert_allclose(ps.bank.sum(axis=1), 1.0)


def test_switch_mixing_keeps_copies_of_a_spread_belief_and_is_off_by_default() -> None:
    """With a uniform belief a copy restarts from another one with probability eps only;
    eps = 0 (the default) leaves the set untouched."""
    filt = _bank_filter(particles=2000, bank_switch=0.01)
    ps = filt.particles
    q_before = ps.q.copy()
    filt._mix_bank()
    moved = np.mean(ps.q[:, 0] != q_before[:, 0])
    assert 0.005 < moved < 0.015  # expected fraction eps = 0.01 of the 6000 copies
    np.testing.assert_allclose(ps.bank, 1.0 / 3.0)
    off = _bank_filter()
    q_off, bank_off = off.particles.q.copy(), off.particles.bank
    off._mix_bank()
    np.testing.assert_array_equal(off.particles.q, q_off)
    assert off.particles.bank is bank_off


def test_tempering_and_cap_change_the_belief_not_the_particle_evidence() -> None:
    ev = np.array([[0.0, -2.0, -10.0], [1.0, 1.0, 1.0]])

    def run(**changes: object) -> tuple[np.ndarray, np.ndarray]:
        filt = _bank_filter(particles=2, **changes)
        assert filt.particles.bank is not None
        incr = filt._bank_evidence(ev.reshape(-1).copy(), _posterior_stub(filt))  # type: ignore[arg-type]
        return incr, filt.particles.bank

    exact_incr, exact = run()
    expected = np.log(np.exp(ev).mean(axis=1))  # uniform prior belief
    np.testing.assert_allclose(exact_incr, expected)
    np.testing.assert_allclose(exact[0], np.exp(ev[0]) / np.exp(ev[0]).sum())
    t_incr, tempered = run(bank_tempering=0.5)
    np.testing.assert_allclose(t_incr, expected)
    np.testing.assert_allclose(tempered[0], np.exp(0.5 * ev[0]) / np.exp(0.5 * ev[0]).sum())
    c_incr, capped = run(bank_step_cap=3.0)
    np.testing.assert_allclose(c_incr, expected)
    floor = np.array([0.0, -2.0, -3.0])  # -10 floored at the best copy's 0 - 3
    np.testing.assert_allclose(capped[0], np.exp(floor) / np.exp(floor).sum())
    for bank in (exact, tempered, capped):  # equal evidence: the belief stays uniform
        np.testing.assert_allclose(bank[1], 1.0 / 3.0)


def test_surprise_gate_skips_the_belief_update_of_a_step_that_lost_track() -> None:
    filt = _bank_filter(particles=2, bank_surprise_gate=3.0, bank_surprise_window=5)
    ps = filt.particles
    assert ps.bank is not None
    normal = np.array([[10.0, 10.0, 10.0], [10.0, 10.0, 10.0]]).reshape(-1)
    for _ in range(5):  # log p(o_l | o_<l) = 10 nats: the reference
        filt._bank_evidence(normal.copy(), _posterior_stub(filt))  # type: ignore[arg-type]
    np.testing.assert_allclose(ps.bank, 1.0 / 3.0)
    lost = np.array([[0.0, 4.0, 2.0], [0.0, 4.0, 2.0]]).reshape(-1)  # ~3.1 nats: 7 below
    before = ps.bank.copy()
    incr = filt._bank_evidence(lost.copy(), _posterior_stub(filt))  # type: ignore[arg-type]
    np.testing.assert_array_equal(ps.bank, before)  # gated: belief unchanged
    np.testing.assert_allclose(incr, np.log(np.exp([0.0, 4.0, 2.0]).mean()))  # weight still
    mild = np.array([[9.0, 10.0, 8.0], [9.0, 10.0, 8.0]]).reshape(-1)  # within the gate
    filt._bank_evidence(mild.copy(), _posterior_stub(filt))  # type: ignore[arg-type]
    assert ps.bank[0, 1] > ps.bank[0, 0] > ps.bank[0, 2]
    # unobserved steps never gate and are not recorded
    n_recent = len(filt._surprise)
    filt._bank_evidence(lost.copy(), _posterior_stub(filt), observed=False)  # type: ignore[arg-type]
    assert len(filt._surprise) == n_recent


def test_hypothesis_resampling_validation() -> None:
    with pytest.raises(ModelError, match="bank_resampling must be"):
        FilterConfig.preset("gripper", bank_resampling="column")
    for name, value in (
        ("bank_switch", 1e-4),
        ("bank_tempering", 0.5),
        ("bank_step_cap", 2.0),
        ("bank_surprise_gate", 4.0),
    ):
        with pytest.raises(ModelError, match="shares one friction belief"):
            FilterConfig.preset("gripper", bank_resampling="hypothesis", **{name: value})


def test_resample_copies_resamples_each_hypothesis_on_its_own() -> None:
    n_p, copies = 3, 2
    ps = _bank_particles(
        n_p,
        copies,
        np.full((n_p, copies), 0.5),
        copy_log_w=np.array([[0.0, -1.0], [-2.0, 0.0], [-3.0, -4.0]]),
    )
    ps.history.push(np.arange(n_p, dtype=float)[:, None] * np.ones((1, 5)))
    ps.resample_copies(np.array([[2, 0], [2, 1], [0, 1]]), lead=1)
    # copy b of particle i <- copy b of particle anc[i, b]: rows 2b' + b
    assert ps.q[:, 0].tolist() == [4, 1, 4, 3, 0, 3]
    assert ps.copy_log_w is not None
    np.testing.assert_array_equal(ps.copy_log_w, 0.0)
    assert ps.history.entries()[0, :, 0].tolist() == [0, 1, 1]  # hypothesis 1's ancestry
    assert ps.log_w.tolist() == [0.0, 0.0, 0.0]


def test_hypothesis_evidence_is_the_sub_filters_marginal_likelihood() -> None:
    """pi(b) moves by Z(b) = sum_i W_ib p(o | copy i, b), each copy's weight within its
    hypothesis by its own evidence, and every particle's evidence is log sum_b pi(b) Z(b)."""
    filt = _bank_filter(particles=3, bank_resampling="hypothesis")
    ps = filt.particles
    assert ps.copy_log_w is not None and ps.bank is not None
    lw0 = np.log(np.array([[0.5, 0.2, 0.1], [0.25, 0.3, 0.1], [0.25, 0.5, 0.8]]))
    ps.copy_log_w = lw0.copy()
    pi0 = np.exp(filt._log_pi)
    ev = np.array([[0.0, -1.0, -3.0], [-1.0, 0.5, -2.0], [-2.0, -0.5, -np.inf]])
    incr = filt._bank_evidence(ev.reshape(-1).copy(), _posterior_stub(filt))  # type: ignore[arg-type]
    w0 = np.exp(lw0)
    z = np.sum(w0 * np.exp(ev), axis=0)
    np.testing.assert_allclose(incr, np.log(pi0 @ z))
    pi = np.exp(filt._log_pi)
    np.testing.assert_allclose(pi, pi0 * z / (pi0 @ z))
    w_new = w0 * np.exp(ev) / z
    np.testing.assert_allclose(ps.bank, 3 * w_new * pi[None, :], atol=1e-15)
    est_friction = ps.bank.mean(axis=0)  # sum_i w_i bank[i] with w_i = 1 / P
    np.testing.assert_allclose(est_friction, pi)


def test_hypothesis_resampling_tracks_and_finds_the_friction(gripper_traj: Trajectory) -> None:
    true_mu = float(gripper_traj.mu[-1].max())
    cands = gripper_traj.scenario.friction.candidates[0]
    cfg = FilterConfig.preset("gripper", particles=40, bank_resampling="hypothesis")
    est, filt = _run(gripper_traj, cfg, seed=3)
    pose = np.array([e.pose for e in est])
    err = np.sqrt(np.mean((pose[:, :2] - gripper_traj.q[1:, :2]) ** 2))
    assert err < 0.6 * gripper_traj.scenario.noise.position
    assert est[-1].friction[0, cands.index(true_mu)] > 0.9
    assert any(e.resampled for e in est)
    # the particle weights stay uniform; the shared belief is every particle's friction
    np.testing.assert_allclose(filt.particles.log_w, filt.particles.log_w[0])
    assert filt.particles.bank is not None
    np.testing.assert_allclose(filt.particles.bank.mean(axis=0), np.exp(filt._log_pi))
