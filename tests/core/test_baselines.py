"""Tests of dbcslam_core.baselines: fixed-friction factory and the black-box NCP filter."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pytest

from dbcslam_core.baselines import BlackBoxNCPFilter, NCPFilterConfig, fixed_friction_filter
from dbcslam_core.errors import ModelError, SolverError
from dbcslam_core.lcp import LemkeSolver
from dbcslam_core.metrics import contact_accuracy, position_rmse
from dbcslam_core.observation import PoseObservation
from dbcslam_core.rbpf import FilterConfig, FilterInput
from dbcslam_core.synthetic import Trajectory, edge_trajectory


@pytest.fixture(scope="module")
def edge() -> Trajectory:
    return edge_trajectory(0)


@dataclass(frozen=True)
class Run:
    pose: np.ndarray
    modes: np.ndarray
    friction: np.ndarray


def run(filt: BlackBoxNCPFilter, tr: Trajectory, n: int) -> Run:
    filt.initialize(tr.obs[0], tr.scenario.noise.position, joints=tr.env[0])
    poses, modes, fric = [], [], []
    for k in range(1, n):
        est = filt.step(
            PoseObservation(*tr.obs[k]), FilterInput(wrench=tuple(tr.u[k - 1]), joints=())
        )
        poses.append(est.pose[:2])
        modes.append(est.modes)
        fric.append(est.friction[0])
    return Run(np.array(poses), np.array(modes), np.array(fric))


def test_fixed_friction_filter_freezes(edge: Trajectory) -> None:
    cfg = FilterConfig.preset("edge", particles=16)
    filt = fixed_friction_filter(edge.scenario, 1, cfg, np.random.default_rng(0))
    assert filt.config.frozen_friction == 1
    assert filt.config.particles == 16
    est = filt.step(PoseObservation(*edge.obs[1]), FilterInput(wrench=tuple(edge.u[0])))
    np.testing.assert_allclose(est.friction[0], [0.0, 1.0])


def test_fixed_friction_filter_rejects_bad_index(edge: Trajectory) -> None:
    with pytest.raises(ModelError, match="out of range"):
        fixed_friction_filter(edge.scenario, 2)


def test_config_validation() -> None:
    with pytest.raises(ModelError, match="unknown LCP solver"):
        NCPFilterConfig(solver="simplex")
    with pytest.raises(ModelError, match="proposal"):
        NCPFilterConfig(proposal="magic")
    with pytest.raises(ModelError, match="particles"):
        NCPFilterConfig(particles=0)


@pytest.mark.parametrize("proposal", ["bootstrap", "optimal"])
def test_black_box_tracks_edge(edge: Trajectory, proposal: str) -> None:
    n = 200
    cfg = NCPFilterConfig(particles=200, solver="pgs", proposal=proposal)
    out = run(BlackBoxNCPFilter(edge.scenario, cfg, np.random.default_rng(3)), edge, n)
    truth = edge.q[1:n]
    # clearly better than the raw observations (1 cm std per axis)
    assert position_rmse(out.pose, truth) < 0.6 * edge.scenario.noise.position
    assert contact_accuracy(out.modes, edge.modes[1:n]) > 0.9
    np.testing.assert_allclose(out.modes.sum(-1), 1.0, atol=1e-9)
    np.testing.assert_allclose(out.friction.sum(-1), 1.0, atol=1e-9)
    # while sticking in the rough region (mu = 0.9) the particles with mu = 0.3 slide away
    sticking_rough = (edge.modes[1:n, 0] == 1) & (edge.mu[1:n, 0] > 0.5)
    assert np.mean(out.friction[sticking_rough, 1]) > 0.7


def test_lemke_and_pgs_agree_on_one_contact(edge: Trajectory) -> None:
    n = 30
    runs = [
        run(
            BlackBoxNCPFilter(
                edge.scenario,
                NCPFilterConfig(particles=20, solver=s, pgs_tol=1e-12, pgs_max_iter=500),
                np.random.default_rng(5),
            ),
            edge,
            n,
        )
        for s in ("lemke", "pgs")
    ]
    np.testing.assert_allclose(runs[0].pose, runs[1].pose, atol=1e-6)


class _NoBatchLemke:
    """Lemke that refuses batches (forces the per-particle fallback) or always fails."""

    def __init__(self, always_fail: bool = False) -> None:
        self.inner = LemkeSolver()
        self.always_fail = always_fail

    def solve(self, A: np.ndarray, b: np.ndarray) -> np.ndarray:
        return self.inner.solve(A, b)

    def solve_batch(self, A: np.ndarray, b: np.ndarray) -> np.ndarray:
        if self.always_fail or np.asarray(b).shape[0] > 1:
            msg = "refused"
            raise SolverError(msg)
        return self.inner.solve_batch(A, b)


def test_per_particle_fallback_matches_batch(edge: Trajectory) -> None:
    cfg = NCPFilterConfig(particles=10, solver="lemke")
    ref = BlackBoxNCPFilter(edge.scenario, cfg, np.random.default_rng(9))
    alt = BlackBoxNCPFilter(edge.scenario, cfg, np.random.default_rng(9))
    alt.model.solver = _NoBatchLemke()
    a = run(ref, edge, 15)
    b = run(alt, edge, 15)
    np.testing.assert_allclose(a.pose, b.pose, atol=1e-12)
    assert alt.failed_solves == 0


def test_all_particles_failing_raises(edge: Trajectory) -> None:
    filt = BlackBoxNCPFilter(edge.scenario, NCPFilterConfig(particles=4), np.random.default_rng(0))
    filt.model.solver = _NoBatchLemke(always_fail=True)
    with pytest.raises(SolverError, match="every particle failed"):
        run(filt, edge, 3)


def test_active_set_lemke_matches_full_lemke(edge: Trajectory) -> None:
    outs = [
        run(
            BlackBoxNCPFilter(
                edge.scenario,
                NCPFilterConfig(particles=16, solver="lemke", active_set=act),
                np.random.default_rng(4),
            ),
            edge,
            40,
        )
        for act in (False, True)
    ]
    np.testing.assert_allclose(outs[0].pose, outs[1].pose, atol=1e-9)
    np.testing.assert_allclose(outs[0].modes, outs[1].modes, atol=1e-9)
