"""Fast paths of the filter's per-step helpers: same values as the straightforward forms."""

from __future__ import annotations

import numpy as np
import pytest

from dbcslam_core.contact_modes import N_MODES, sum_last
from dbcslam_core.experiments import make_trajectory
from dbcslam_core.observation import JointSmoother, PoseObservation, PoseObservationModel
from dbcslam_core.parameters import FrictionMap
from dbcslam_core.rbpf import DbcSlamFilter, FilterConfig, FilterInput
from dbcslam_core.synthetic import Trajectory
from dbcslam_core.transition import TransitionParams, mode_transition, soft_modes


@pytest.mark.parametrize("n", [1, 2, 3, 4, 6, 7, 8, 12])
@pytest.mark.parametrize("lead", [(5,), (40, 3), (7, 2, 3)])
def test_sum_last_matches_numpy_sum_bitwise(n: int, lead: tuple[int, ...]) -> None:
    rng = np.random.default_rng(n)
    x = rng.standard_normal((*lead, n)) * np.exp(5.0 * rng.standard_normal((*lead, n)))
    assert np.array_equal(sum_last(x), x.sum(axis=-1))
    view = np.swapaxes(np.ascontiguousarray(np.swapaxes(x, 0, -1)), 0, -1)  # strided last axis
    assert np.array_equal(sum_last(view), view.sum(axis=-1))
    b = x > 0.0
    assert np.array_equal(sum_last(b), b.sum(axis=-1))
    assert sum_last(b).dtype.kind == "i"


def test_sum_last_returns_a_new_array() -> None:
    x = np.ones((3, 1))
    s = sum_last(x)
    s += 1.0
    assert np.all(x == 1.0)


def _old_soft_modes(
    phi: np.ndarray, rate: np.ndarray, vt: np.ndarray, dt: float, p: TransitionParams
) -> np.ndarray:
    def sig(z: np.ndarray) -> np.ndarray:
        return 0.5 * (1.0 + np.tanh(0.5 * z))

    g = phi + dt * rate
    pc = sig(-g / p.gap_scale) * sig(-(g - p.far_gap) / p.gap_scale)
    a = vt / p.slip_scale
    p_stick = 1.0 / (1.0 + a * a)
    p_slide = 1.0 - p_stick
    d = sig(10.0 * a)
    inc = np.stack([p_stick, p_slide * d, p_slide * (1.0 - d)], axis=-1)
    inc = np.maximum(inc, p.slide_floor)
    inc = inc / inc.sum(axis=-1, keepdims=True)
    return np.concatenate([(1.0 - pc)[..., None], pc[..., None] * inc], axis=-1)


def test_soft_modes_and_transition_match_reference_form() -> None:
    rng = np.random.default_rng(3)
    p = TransitionParams()
    phi = rng.normal(0.0, 0.01, (50, 6))
    rate = rng.normal(0.0, 0.5, (50, 6))
    vt = rng.normal(0.0, 0.05, (50, 6))
    soft = soft_modes(phi, rate, vt, 0.01, p)
    assert np.array_equal(soft, _old_soft_modes(phi, rate, vt, 0.01, p))
    prev = rng.dirichlet(np.ones(N_MODES), (50, 3, 6))
    pred = mode_transition(
        prev, soft[:, None], p, phi=phi[:, None], gap_rate_free=rate[:, None], dt=0.01
    )
    # reference: persistence, far-gap reach, renormalisation
    ref = p.persistence * prev + (1.0 - p.persistence) * soft[:, None]
    g = phi[:, None] + 0.01 * rate[:, None]
    reach = (0.5 * (1.0 + np.tanh(0.5 * (-(g - p.far_gap) / p.gap_scale))))[..., None]
    moved = np.sum(ref[..., 1:] * (1.0 - reach), axis=-1, keepdims=True)
    ref = np.concatenate([ref[..., :1] + moved, ref[..., 1:] * reach], axis=-1)
    ref = ref / ref.sum(axis=-1, keepdims=True)
    assert np.array_equal(pred, ref)
    assert np.allclose(pred.sum(axis=-1), 1.0)


def test_friction_map_view_with_pending_equals_copy_and_add() -> None:
    rng = np.random.default_rng(1)
    fmap = FrictionMap(((0.2, 0.3, 0.5), (0.5, 0.5)), -1.0, 1.0, 0.1)
    fmap.add(0, rng.uniform(-1, 1, 30), rng.dirichlet(np.ones(3), 30), rng.random(30))
    before = fmap.view()
    s = rng.uniform(-1.2, 1.2, 40)
    probs = rng.dirichlet(np.ones(3), 40)
    w = rng.random(40) + 0.01
    ref = fmap.copy()
    ref.add(0, s, probs, w)
    view = fmap.view([fmap.accumulate(s, probs, w), None])
    expect = ref.view()
    for a, b in zip(view.probs + view.weight, expect.probs + expect.weight, strict=True):
        assert np.array_equal(a, b)
    after = fmap.view()  # the map itself is unchanged
    for a, b in zip(after.probs + after.weight, before.probs + before.weight, strict=True):
        assert np.array_equal(a, b)
    assert after.weight[0].sum() < view.weight[0].sum()


def _edge_filter(map_lag: int) -> tuple[DbcSlamFilter, Trajectory]:
    tr = make_trajectory("edge", 0)
    cfg = FilterConfig.preset("edge", particles=30, map_lag=map_lag)
    filt = DbcSlamFilter(tr.scenario, cfg, np.random.default_rng(0))
    filt.initialize(tr.obs[0], [0.002, 0.002], joints=tr.env_obs[0])
    return filt, tr


def test_map_history_ring_buffer_order_and_eviction() -> None:
    filt, _ = _edge_filter(map_lag=3)
    n_p = filt.config.particles
    fp = np.zeros((n_p, filt.n_pairs, filt._k_max))
    evicted = []
    for k in range(7):
        s = np.full((n_p, filt.n_c), float(k))
        pk = filt.n_pairs * filt._k_max
        row = np.concatenate([fp.reshape(n_p, pk), s, np.ones((n_p, filt.n_c))], axis=1)
        old = filt.particles.history.push(row)
        evicted.append(None if old is None else float(old[0, filt.n_pairs * filt._k_max]))
        entries = filt.particles.history.entries()
        steps = entries[:, 0, filt.n_pairs * filt._k_max]
        assert steps.tolist() == [float(j) for j in range(max(0, k - 2), k + 1)]
    assert evicted == [None, None, None, 0.0, 1.0, 2.0, 3.0]


def test_friction_map_of_estimate_equals_friction_map_method() -> None:
    filt, tr = _edge_filter(map_lag=4)
    for k in range(1, 12):
        est = filt.step(
            PoseObservation(*tr.obs[k]),
            FilterInput(tuple(tr.u[k - 1]), tuple(tr.env_obs[k])),
        )
        again = filt.friction_map()
        for a, b in zip(est.friction_map.probs, again.probs, strict=True):
            assert np.array_equal(a, b)
        for a, b in zip(est.friction_map.weight, again.weight, strict=True):
            assert np.array_equal(a, b)


def test_joint_smoother_without_joints() -> None:
    js = JointSmoother(0, 0.01, 1e-3)
    assert js.update(np.zeros(0)).shape == (0,)
    assert js.update(np.zeros(0)).shape == (0,)
    assert js.velocity.shape == (0,)


def test_linearize_shares_read_only_constants() -> None:
    model = PoseObservationModel(3, 0.001, 0.01)
    a = model.linearize(PoseObservation(1.0, 2.0, 0.5))
    b = model.linearize(PoseObservation(3.0, 4.0, -0.5))
    assert np.array_equal(a.var, [1e-6, 1e-6, 1e-4])
    assert a.value.tolist() == [1.0, 2.0, 0.5] and b.value.tolist() == [3.0, 4.0, -0.5]
    assert not a.var.flags.writeable
    xy = model.linearize(PoseObservation(1.0, 2.0))
    assert xy.index.tolist() == [0, 1] and not xy.angular.any()


@pytest.mark.parametrize("nq", [2, 3])
def test_all_observed_proposal_matches_dense_conditioning(nq: int) -> None:
    """Entrywise fast path (every dim observed) vs the dense Gaussian conditioning formulas,
    over a (N, B) batch; and vs the general path (dims observed in another order)."""
    from dbcslam_core.observation import LinearObservation, gaussian_log_density, gaussian_proposal

    rng = np.random.default_rng(nq)
    n, b, dt = 7, 3, 0.01
    q = rng.normal(size=(n, 1, nq))
    vh = rng.normal(size=(n, b, nq))
    a = rng.normal(size=(n, b, nq, nq))
    cov = a @ np.swapaxes(a, -1, -2) + 0.1 * np.eye(nq)
    sq = np.full(nq, 1e-3)
    var = np.linspace(1e-4, 3e-4, nq)
    value = rng.normal(size=nq) * 0.01
    lin = LinearObservation(np.arange(nq), value, var, np.zeros(nq, dtype=bool))
    prop = gaussian_proposal(q, vh, cov, dt, lin, sigma_q=sq)
    s = dt * dt * cov + np.diag(sq**2 + var)
    y = value - (q + dt * vh)
    c = dt * cov
    gain = np.swapaxes(np.linalg.solve(s, np.swapaxes(c, -1, -2)), -1, -2)  # c S^-1 (S sym.)
    np.testing.assert_allclose(prop.innovation, y, rtol=1e-12)
    np.testing.assert_allclose(prop.v_mean, vh + (gain @ y[..., None])[..., 0], rtol=1e-9)
    np.testing.assert_allclose(
        prop.v_cov, cov - gain @ np.swapaxes(c, -1, -2), rtol=1e-9, atol=1e-12
    )
    np.testing.assert_allclose(prop.log_pred, gaussian_log_density(y, s), rtol=1e-10)
    perm = np.arange(nq)[::-1].copy()
    lin_p = LinearObservation(perm, value[perm], var[perm], np.zeros(nq, dtype=bool))
    prop_p = gaussian_proposal(q, vh, cov, dt, lin_p, sigma_q=sq)
    np.testing.assert_allclose(prop_p.v_mean, prop.v_mean, rtol=1e-9)
    np.testing.assert_allclose(prop_p.log_pred, prop.log_pred, rtol=1e-9)
