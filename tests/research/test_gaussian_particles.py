"""`dbcslam_research.gaussian_particles`: Fearnhead-Clifford cut-back, the closed-form
predict/update of a Gaussian particle, the filter on the core's synthetic gripper, and the
probe's summary and command line."""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from dbcslam_core.errors import ModelError
from dbcslam_core.experiments import DBCSLAM, run_filter
from dbcslam_core.observation import LinearObservation
from dbcslam_core.rbpf import FilterConfig
from dbcslam_core.synthetic import Trajectory, gripper_trajectory
from dbcslam_research.gaussian_particles import (
    GaussianParticleFilter,
    fearnhead_clifford,
    kalman_entries,
    main,
    render_markdown,
    summarise,
)

log_weights = st.lists(
    st.one_of(st.floats(-30.0, 5.0), st.just(-math.inf)), min_size=1, max_size=40
).filter(lambda xs: any(math.isfinite(x) for x in xs))


@given(log_w=log_weights, n=st.integers(1, 25), seed=st.integers(0, 2**31))
@settings(max_examples=200, deadline=None)
def test_cut_back_keeps_distinct_children_and_the_total_weight(
    log_w: list[float], n: int, seed: int
) -> None:
    idx, new = fearnhead_clifford(log_w, n, np.random.default_rng(seed))
    lw = np.asarray(log_w)
    w = np.exp(lw - lw.max())
    w /= w.sum()
    positive = int(np.sum(w > 0.0))
    assert idx.size == min(n, positive)
    assert np.unique(idx).size == idx.size  # no two particles share a child
    assert np.all(w[idx] > 0.0)
    assert math.isclose(float(np.exp(new).sum()), 1.0, rel_tol=1e-9)
    # every child at least 1 / n heavy is kept, with its own weight
    for i in np.flatnonzero(w >= 1.0 / n):
        assert i in idx
        assert math.isclose(float(np.exp(new[list(idx).index(i)])), w[i], rel_tol=1e-9)


def test_cut_back_is_unbiased() -> None:
    """E[new weight of child i] = W_i (the drawn children carry 1 / c)."""
    w = np.array([0.4, 0.2, 0.1, 0.1, 0.08, 0.06, 0.04, 0.02])
    rng = np.random.default_rng(3)
    acc = np.zeros(w.size)
    draws = 20000
    for _ in range(draws):
        idx, new = fearnhead_clifford(np.log(w), 4, rng)
        acc[idx] += np.exp(new)
    np.testing.assert_allclose(acc / draws, w, atol=0.005)


def test_cut_back_refuses_nonsense() -> None:
    with pytest.raises(ModelError, match="n must be >= 1"):
        fearnhead_clifford([0.0, 1.0], 0, np.random.default_rng(0))


def _spd(rng: np.random.Generator, shape: tuple[int, ...], n: int) -> np.ndarray:
    a = rng.normal(size=(*shape, n, n))
    return a @ np.swapaxes(a, -1, -2) + 0.5 * np.eye(n)


@given(seed=st.integers(0, 2**31))
@settings(max_examples=30, deadline=None)
def test_kalman_children_match_the_dense_joint_gaussian(seed: int) -> None:
    """Posterior and predictive likelihood equal conditioning the joint Gaussian of
    (x', o) written out densely."""
    rng = np.random.default_rng(seed)
    n, nb, nq, dt = 3, 2, 3, 0.01
    q = rng.normal(scale=0.1, size=(n, nq))
    cov_x = 1e-2 * _spd(rng, (n,), 2 * nq)
    v_h = rng.normal(size=(n, nb, nq))
    jac = rng.normal(size=(n, nb, nq, 2 * nq))
    cov_v = 1e-2 * _spd(rng, (n, nb), nq)
    sigma_q = np.array([1e-3, 2e-3, 3e-3])
    value = rng.normal(scale=0.1, size=nq)
    var = np.array([4e-4, 1e-4, 9e-4])
    obs = LinearObservation(
        index=np.arange(nq), value=value, var=var, angular=np.zeros(nq, dtype=bool)
    )
    kids = kalman_entries(q, cov_x, v_h=v_h, jac=jac, cov_v=cov_v, sigma_q=sigma_q, dt=dt, obs=obs)
    for i in range(n):
        for b in range(nb):
            a = np.block(
                [[np.eye(nq), np.zeros((nq, nq))], [np.zeros((nq, nq)), np.zeros((nq, nq))]]
            )
            a[:nq] += dt * jac[i, b]
            a[nq:] = jac[i, b]
            g = np.vstack([dt * np.eye(nq), np.eye(nq)])  # how w enters x'
            noise = g @ cov_v[i, b] @ g.T
            noise[:nq, :nq] += np.diag(sigma_q**2)
            prior = a @ cov_x[i] @ a.T + noise
            mean = np.concatenate([q[i] + dt * v_h[i, b], v_h[i, b]])
            s = prior[:nq, :nq] + np.diag(var)
            innov = value - mean[:nq]
            k = np.linalg.solve(s, prior[:nq, :]).T
            np.testing.assert_allclose(kids.mean[i, b], mean + k @ innov, rtol=1e-9, atol=1e-12)
            np.testing.assert_allclose(
                kids.cov[i, b], prior - k @ prior[:nq, :], rtol=1e-7, atol=1e-14
            )
            _sign, logdet = np.linalg.slogdet(s)
            lp = -0.5 * (innov @ np.linalg.solve(s, innov) + logdet + nq * math.log(2 * math.pi))
            assert math.isclose(float(kids.log_pred[i, b]), lp, rel_tol=1e-9)


def test_without_a_reading_the_child_is_the_prediction() -> None:
    rng = np.random.default_rng(1)
    cov_x = 1e-2 * _spd(rng, (2,), 4)
    kids = kalman_entries(
        np.zeros((2, 2)),
        cov_x,
        v_h=np.ones((2, 1, 2)),
        jac=np.zeros((2, 1, 2, 4)),
        cov_v=np.tile(np.eye(2), (2, 1, 1, 1)),
        sigma_q=np.zeros(2),
        dt=0.1,
        obs=None,
    )
    assert np.all(kids.log_pred == 0.0)
    np.testing.assert_allclose(kids.mean[:, 0], [[0.1, 0.1, 1.0, 1.0]] * 2)


@pytest.fixture(scope="module")
def grasp() -> Trajectory:
    return gripper_trajectory(1, duration=1.0)


def test_filter_refuses_a_friction_estimating_configuration(grasp: Trajectory) -> None:
    with pytest.raises(ModelError, match="frozen_friction"):
        GaussianParticleFilter(grasp.scenario, FilterConfig.preset("gripper", particles=10))


def test_filter_tracks_the_synthetic_grasp(grasp: Trajectory) -> None:
    """On the core's own gripper model the Gaussian particles track the body better than
    the pose readings do and keep P particles with positive semi-definite covariances."""
    cfg = FilterConfig.preset("gripper", particles=20, friction_bank=False, frozen_friction=1)
    filt = GaussianParticleFilter(grasp.scenario, cfg, np.random.default_rng(0))
    trace = run_filter(filt, grasp, method=DBCSLAM, seed=0, particles=20)
    assert trace.log_likelihood is not None
    assert np.all(np.isfinite(trace.log_likelihood))
    rmse = float(np.sqrt(np.mean((trace.est_q[:, :2] - trace.true_q[:, :2]) ** 2)))
    raw = float(np.sqrt(np.mean((trace.obs_q[:, :2] - trace.true_q[:, :2]) ** 2)))
    assert rmse < 0.9 * raw  # better than the readings themselves (measured 0.82)
    ps = filt.particles
    assert ps.count == 20
    assert np.all(np.linalg.eigvalsh(filt.cov_x) > -1e-12)


def _report(tmp_path: Path) -> Path:
    rows = []
    for run in (0, 1):
        for p, ml in ((40, [0.0, 1.0, 0.0]), (4000, [0.0, 10.0 + run, 2.0])):
            rows.append(
                {
                    "run": run,
                    "filter_seed": 0,
                    "particles": p,
                    "true": 1,
                    "log_ml": ml,
                    "p_true": 0.5 if p == 40 else 0.99,
                }
            )
    data = {
        "sim_set": {"jaw_mu": 0.4},
        "verdicts": [{"run": 0, "true": 1, "p_true": 0.99}],
        "verdict_particles": 4000,
        "cause": {"candidates": [0.1, 0.4, 0.7]},
        "evidence": rows,
    }
    path = tmp_path / "gripper_evidence.json"
    path.write_text(json.dumps(data), encoding="utf-8")
    return path


def test_summary_counts_and_gaps(tmp_path: Path) -> None:
    from dbcslam_research.gaussian_particles import load_report

    rep = load_report(_report(tmp_path))
    gauss = [
        {"run": 0, "filter_seed": 0, "particles": 40, "true": 1, "log_ml": [0.0, 9.0, 1.0]},
        {"run": 1, "filter_seed": 0, "particles": 40, "true": 1, "log_ml": [0.0, 1.0, 1.0]},
    ]
    for g, ms in zip(gauss, (10.0, 20.0), strict=True):  # P(true) under a uniform prior
        ml = np.asarray(g["log_ml"])
        g["p_true"] = float(np.exp(ml[1]) / np.exp(ml).sum())
        g["step_ms"] = ms
    (s,) = summarise(rep, gauss)
    assert s["runs"] == 2
    assert s["gaussian_right"] == 1
    assert s["point_right"] == {"40": [0, 2], "4000": [2, 2]}
    assert s["gap_true"] == [-1.0, -10.0]  # 9 - 10, 1 - 11
    assert s["gap_wrong"] == [0.0, -1.0, 0.0, -1.0]
    assert [m[:2] for m in s["misses"]] == [[1, 0]]
    assert s["step_ms"] == 15.0
    result: dict[str, Any] = {
        "date": "d",
        "wall_s": 1.0,
        "filter_seeds": [0],
        "reports": [{"title": "e.json", "summary": [s]}],
    }
    md = render_markdown(result, "cmd")
    assert (
        "| 40 | 2 | 1 | 0 / 2 | 2 / 2 | -5.5 [-10.0, -1.0] | -0.5 [-1.0, +0.0] | 15.0 "
        "| 1/0 (0.42) |" in md
    )


def test_command_line_names_an_unreadable_report(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    missing = tmp_path / "nope.json"
    with pytest.raises(SystemExit) as exc:
        main(["--evidence", str(missing), "--out", str(tmp_path)])
    assert exc.value.code == 2
    assert str(missing) in capsys.readouterr().err


def test_command_line_needs_a_source(capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit) as exc:
        main([])
    assert exc.value.code == 2
    assert "--synthetic" in capsys.readouterr().err
