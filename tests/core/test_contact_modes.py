"""Reduced dynamics given a mode assignment, geometric exclusions, hypothesis enumeration."""

from __future__ import annotations

import itertools

import numpy as np
import pytest
from hypothesis import assume, example, given, settings
from hypothesis import strategies as st

from dbcslam_core.contact_modes import (
    MODE_NAMES,
    N_MODES,
    ContactLayout,
    Mode,
    ViolationScales,
    enumerate_hypotheses,
    geometric_feasible,
    solve_reduced,
    violation_score,
)
from dbcslam_core.dynamics import PlanarModel, State
from dbcslam_core.geometry import contact_kinematics
from dbcslam_core.scenario import edge_scenario, gripper_scenario

EDGE = edge_scenario()
GRIPPER = gripper_scenario()


def _reduced(model: PlanarModel, q, v, u, env0, env1, mu, modes):  # type: ignore[no-untyped-def]
    groups = [c.obstacle for c in model.scenario.potential_contacts]
    sc = model.scenario
    dt = sc.dt
    kin = contact_kinematics(sc, q, env0, (np.asarray(env1) - np.asarray(env0)) / dt)
    v_free = v + dt * model.generalized_force(q, v, u) / model.mass_diag
    return solve_reduced(
        modes,
        v_free,
        inv_mass=1.0 / model.mass_diag,
        jn=kin.Jn,
        jt=kin.Jt,
        phi=kin.phi,
        vn_env=kin.vn_env,
        vt_env=kin.vt_env,
        mu=mu,
        dt=dt,
        groups=groups,
    )


def test_mode_names_match_enum() -> None:
    assert [m.name.lower() for m in Mode] == list(MODE_NAMES)
    assert N_MODES == 4


@settings(max_examples=150, deadline=None)
@given(
    x=st.floats(-1.0, 1.0),
    y=st.floats(-0.002, 0.01),
    vx=st.floats(-1.5, 1.5),
    vy=st.floats(-1.0, 1.0),
    fx=st.floats(-15.0, 15.0),
    fy=st.floats(-15.0, 5.0),
    mu=st.sampled_from([0.3, 0.9]),
)
def test_edge_reduced_solution_equals_lcp(
    x: float, y: float, vx: float, vy: float, fx: float, fy: float, mu: float
) -> None:
    model = PlanarModel(EDGE)
    q, v, u = np.array([x, y]), np.array([vx, vy]), np.array([fx, fy])
    r = model.step(State(q, v), u, mu=mu)
    sol = _reduced(model, q, v, u, np.zeros(0), np.zeros(0), np.full(1, mu), r.modes)
    np.testing.assert_allclose(sol.v_next, r.v, atol=1e-9)
    np.testing.assert_allclose(sol.ln, r.ln, atol=1e-9)
    np.testing.assert_allclose(sol.lt, r.lt, atol=1e-9)
    assert float(sol.score) < 1e-6


@settings(max_examples=60, deadline=None)
@given(
    yaw=st.floats(-np.pi, np.pi),
    gap=st.floats(-0.001, 0.002),
    vx=st.floats(-0.3, 0.3),
    vy=st.floats(-0.3, 0.3),
    w=st.floats(-3.0, 3.0),
    fx=st.floats(-1.0, 1.0),
    fy=st.floats(-1.0, 1.0),
    tau=st.floats(-0.01, 0.01),
    closing=st.floats(0.0, 0.001),
    mu=st.sampled_from([0.1, 0.4, 0.7]),
)
# found by hypothesis: a vertex exactly on the jaw, round inputs; Lemke ended on a degenerate
# basis with a tangential impulse of 1.2e-6 N s at a contact 5 cm away (w = mu ln - lt < 0 by
# the whole row) that the overall residual check accepted (now `LemkeSolver.row_tol`)
@example(
    yaw=0.015625,
    gap=0.0,
    vx=0.0,
    vy=0.25,
    w=0.00475,
    fx=0.00390625,
    fy=0.0,
    tau=0.0,
    closing=0.0,
    mu=0.1,
)
def test_gripper_reduced_velocity_equals_lcp(
    yaw: float,
    gap: float,
    vx: float,
    vy: float,
    w: float,
    fx: float,
    fy: float,
    tau: float,
    closing: float,
    mu: float,
) -> None:
    model = PlanarModel(GRIPPER)
    env0 = np.array([-0.05, 0.05])
    env1 = env0 + np.array([closing, -closing])
    kin = contact_kinematics(GRIPPER, np.array([0.0, 0.0, yaw]), env0)
    y = gap - float(np.min(kin.phi[:3]))  # lowest vertex `gap` above the lower jaw
    q, v, u = np.array([0.0, y, yaw]), np.array([vx, vy, w]), np.array([fx, fy, tau])
    r = model.step(State(q, v), u, env0, env1, mu=mu)
    # The implied modes must be unambiguous: modes_from_lcp calls a slip below 1e-9 m/s
    # sticking (and an impulse below 1e-10 N s separated); within 100x of those thresholds
    # the mode is a rounding decision and the reduced solution may differ by ~ the threshold.
    assume(not np.any((r.slide > 0.0) & (r.slide < 1e-7)))
    assume(not np.any((r.ln > 0.0) & (r.ln < 1e-8)))
    sol = _reduced(model, q, v, u, env0, env1, np.full(6, mu), r.modes)
    # impulses may be non-unique (two sticking vertices on one jaw); velocities are unique
    np.testing.assert_allclose(sol.v_next, r.v, atol=1e-9)
    assert float(sol.score) < 1e-6


def test_wrong_modes_are_penalised_and_batching_broadcasts() -> None:
    model = PlanarModel(EDGE)
    q, v, u = np.array([0.0, 0.0]), np.array([1.0, 0.0]), np.array([0.0, 0.0])
    r = model.step(State(q, v), u, mu=0.3)
    assert r.modes.tolist() == [Mode.SLIDING_POS]
    all_modes = np.arange(4)[:, None]  # (4, 1): every mode of the single contact
    mu = np.array([[0.3], [0.9]])[:, None, :]  # (2, 1, 1): two friction values
    sol = _reduced(model, q, v, u, np.zeros(0), np.zeros(0), mu, all_modes[None])
    assert sol.score.shape == (2, 4)
    # with mu = 0.3 only sliding_pos is consistent; separated penetrates, sliding_neg has the
    # wrong slip sign; sticking needs more friction than 0.3 (and 0.9) can give
    best = np.argmin(sol.score, axis=1)
    assert best.tolist() == [Mode.SLIDING_POS, Mode.SLIDING_POS]
    assert np.all(sol.score[:, Mode.SEPARATED] > 10.0)
    assert np.all(sol.score[:, Mode.SLIDING_NEG] > 10.0)
    np.testing.assert_allclose(sol.v_next[0, Mode.SLIDING_POS], r.v, atol=1e-9)
    # the two friction values give different sliding velocities
    assert sol.v_next[1, Mode.SLIDING_POS, 0] < sol.v_next[0, Mode.SLIDING_POS, 0]


def test_violation_scales_sharpen_scores() -> None:
    model = PlanarModel(EDGE)
    q, v, u = np.array([0.0, 0.0]), np.array([0.0, 0.0]), np.array([5.0, 0.0])
    sc = EDGE
    kin = contact_kinematics(sc, q)
    vf = v + sc.dt * model.generalized_force(q, v, u) / model.mass_diag
    common = {
        "inv_mass": 1.0 / model.mass_diag,
        "jn": kin.Jn,
        "jt": kin.Jt,
        "phi": kin.phi,
        "vn_env": kin.vn_env,
        "vt_env": kin.vt_env,
        "mu": np.array([0.3]),
        "dt": sc.dt,
    }
    loose = solve_reduced(np.array([Mode.STICKING]), vf, scales=ViolationScales(0.5), **common)
    tight = solve_reduced(np.array([Mode.STICKING]), vf, scales=ViolationScales(0.01), **common)
    assert float(tight.score) > float(loose.score) > 0.0  # 5 N > 0.3 m g: cannot stick


def _gripper_layout() -> ContactLayout:
    pcs = GRIPPER.potential_contacts
    return ContactLayout(
        tuple(c.vertex for c in pcs), tuple(c.obstacle for c in pcs), len(GRIPPER.body.vertices)
    )


def test_geometric_exclusions_gripper() -> None:
    layout = _gripper_layout()
    s, t = Mode.SEPARATED, Mode.STICKING
    three_lower = np.array([t, t, t, s, s, s])
    two_lower = np.array([t, Mode.SLIDING_POS, s, s, s, s])
    v0_both = np.array([t, s, s, t, s, s])
    assert not geometric_feasible(layout, three_lower)
    assert geometric_feasible(layout, two_lower)
    apart = np.full(6, 0.01)
    closed = np.zeros(6)
    assert not geometric_feasible(layout, v0_both, apart)
    assert geometric_feasible(layout, v0_both, closed)
    assert not geometric_feasible(layout, v0_both)
    # exhaustive count over all 4^6 assignments with the jaws apart: no vertex on both jaws,
    # at most two vertices per jaw
    allm = np.array(list(itertools.product(range(4), repeat=6)))
    feas = geometric_feasible(layout, allm, apart)
    inc = allm != 0
    ok = (inc[:, :3].sum(1) <= 2) & (inc[:, 3:].sum(1) <= 2) & ~np.any(inc[:, :3] & inc[:, 3:], 1)
    np.testing.assert_array_equal(feas, ok)


def test_enumerate_hypotheses_prunes_and_orders() -> None:
    layout = _gripper_layout()
    marg = np.zeros((2, 6, 4))
    marg[..., 0] = 1.0
    # particle 0: v0_lower and v1_lower likely in contact; particle 1: everything separated
    marg[0, 0] = [0.1, 0.6, 0.3, 0.0]
    marg[0, 1] = [0.2, 0.5, 0.2, 0.1]
    hyp = enumerate_hypotheses(marg, 1e-3, 64, layout=layout, phi=np.full((2, 6), 0.01))
    assert hyp.n_live.tolist()[1] == 1
    assert hyp.modes[1, 0].tolist() == [0] * 6
    n0 = int(hyp.n_live[0])
    assert n0 == 3 * 4  # live modes of contact 0 (3) x contact 1 (4), others separated
    lp = hyp.log_prior[0, :n0]
    assert np.all(np.diff(lp) <= 1e-12)
    expected = np.log(0.6 * 0.5)
    assert lp[0] == pytest.approx(expected)
    assert hyp.modes[0, 0, :2].tolist() == [Mode.STICKING, Mode.STICKING]
    capped = enumerate_hypotheses(marg, 1e-3, 5, layout=layout)
    assert capped.modes.shape[1] == 5 and int(capped.n_live[0]) == 5
    strict = enumerate_hypotheses(marg, 0.1, 64, layout=layout)
    assert int(strict.n_live[0]) < n0
    # three vertices likely on the lower jaw: the all-three combination is excluded
    marg3 = np.zeros((1, 6, 4))
    marg3[..., 0] = 1.0
    marg3[0, :3] = [0.01, 0.99, 0.0, 0.0]
    hyp3 = enumerate_hypotheses(marg3, 1e-3, 64, layout=layout)
    live = hyp3.modes[0][hyp3.valid[0]]
    assert not np.any(np.all(live[:, :3] != 0, axis=1))


@pytest.mark.parametrize("mode", list(Mode))
def test_response_is_derivative_of_reduced_solution(mode: Mode) -> None:
    model = PlanarModel(GRIPPER)
    rng = np.random.default_rng(int(mode))
    q = np.array([0.0, 0.02, 0.3])
    kin = contact_kinematics(GRIPPER, q, np.array([-0.05, 0.05]))
    q[1] -= float(np.min(kin.phi[:3]))
    modes = np.zeros(6, dtype=np.int64)
    modes[int(np.argmin(kin.phi[:3]))] = mode
    env = np.array([-0.05, 0.05])

    def reduced(v: np.ndarray):  # type: ignore[no-untyped-def]
        return _reduced(model, q, v, np.zeros(3), env, env, np.full(6, 0.4), modes)

    v0 = rng.normal(size=3) * 0.1
    base = reduced(v0)
    dvf = rng.normal(size=3) * 1e-3
    # v_free = v + dt F / m: perturbing v perturbs v_free by the same amount
    moved = reduced(v0 + dvf)
    np.testing.assert_allclose(moved.v_next - base.v_next, base.response @ dvf, atol=1e-10)
    if mode == Mode.SEPARATED:
        np.testing.assert_allclose(base.response, np.eye(3), atol=1e-12)


def test_batched_solve_equals_individual_solves() -> None:
    """Mixed batches (all-separated rows, different active sets and frictions) are solved
    exactly as each assignment on its own."""
    model = PlanarModel(GRIPPER)
    rng = np.random.default_rng(7)
    env = np.array([-0.03, 0.03])
    q = np.array([[0.001, 0.0, 0.2], [0.0, 0.004, -0.1], [-0.002, -0.003, 0.5]])
    v = rng.normal(size=(3, 3)) * 0.05
    u = rng.normal(size=(3, 3)) * 0.1
    modes = rng.integers(0, 4, size=(3, 5, 6)) * (rng.random((3, 5, 6)) < 0.3)
    modes[:, 0] = 0  # an all-separated row per particle
    mu = np.array([0.1, 0.4, 0.7])
    sc = GRIPPER
    kin = contact_kinematics(sc, q, env)
    vf = v + sc.dt * model.generalized_force(q, v, u) / model.mass_diag
    groups = [c.obstacle for c in sc.potential_contacts]

    def solve(m, sl):  # type: ignore[no-untyped-def]
        return solve_reduced(
            m,
            vf[sl],
            inv_mass=1.0 / model.mass_diag,
            jn=kin.Jn[sl],
            jt=kin.Jt[sl],
            phi=kin.phi[sl],
            vn_env=kin.vn_env[sl],
            vt_env=kin.vt_env[sl],
            mu=np.full(6, 1.0) * mu[:, None],
            dt=sc.dt,
            groups=groups,
        )

    full = solve(modes[:, :, None, :], (slice(None), None, None))
    for p in range(3):
        for k in range(5):
            one = solve(modes[p, k][None, :], (p,))
            np.testing.assert_allclose(full.v_next[p, k], one.v_next, atol=1e-12)
            np.testing.assert_allclose(full.ln[p, k], one.ln, atol=1e-12)
            np.testing.assert_allclose(full.response[p, k], one.response, atol=1e-12)
            np.testing.assert_allclose(full.score[p, k], one.score, rtol=1e-9, atol=1e-12)
    np.testing.assert_array_equal(full.response[:, 0], np.broadcast_to(np.eye(3), (3, 3, 3, 3)))


def test_full_mass_matches_diagonal_mass() -> None:
    model = PlanarModel(GRIPPER)
    q = np.array([0.0, 0.0, 0.3])
    kin = contact_kinematics(GRIPPER, q, np.array([-0.05, 0.05]))
    q[1] -= float(np.min(kin.phi[:3]))
    kin = contact_kinematics(GRIPPER, q, np.array([-0.05, 0.05]))
    vf = np.array([0.05, -0.1, 0.5])
    modes = np.zeros((4, 6), dtype=np.int64)
    modes[:, int(np.argmin(kin.phi[:3]))] = np.arange(4)
    common = {
        "inv_mass": 1.0 / model.mass_diag,
        "jn": kin.Jn,
        "jt": kin.Jt,
        "phi": kin.phi,
        "vn_env": kin.vn_env,
        "vt_env": kin.vt_env,
        "mu": np.full(6, 0.4),
        "dt": GRIPPER.dt,
    }
    diag = solve_reduced(modes, vf, **common)
    full = solve_reduced(modes, vf, mass=np.diag(model.mass_diag), **common)
    np.testing.assert_allclose(full.v_next, diag.v_next, atol=1e-13)
    np.testing.assert_allclose(full.response, diag.response, atol=1e-12)
    np.testing.assert_allclose(full.score, diag.score, atol=1e-9)


@pytest.mark.parametrize("mode", [Mode.STICKING, Mode.SLIDING_POS])
def test_impulse_response_is_derivative_of_impulses(mode: Mode) -> None:
    """`impulse_response` = d(ln, lt)/d v_free (used to widen predicted contact forces)."""
    model = PlanarModel(GRIPPER)
    rng = np.random.default_rng(3 + int(mode))
    q = np.array([0.0, 0.02, 0.3])
    env = np.array([-0.05, 0.05])
    kin = contact_kinematics(GRIPPER, q, env)
    q[1] -= float(np.min(kin.phi[:3]))
    modes = np.zeros(6, dtype=np.int64)
    modes[int(np.argmin(kin.phi[:3]))] = mode
    kin = contact_kinematics(GRIPPER, q, env, np.zeros(2))

    def solve(v: np.ndarray, sens: bool = False):  # type: ignore[no-untyped-def]
        return solve_reduced(
            modes,
            v,
            inv_mass=1.0 / model.mass_diag,
            jn=kin.Jn,
            jt=kin.Jt,
            phi=kin.phi,
            vn_env=kin.vn_env,
            vt_env=kin.vt_env,
            mu=np.full(6, 0.4),
            dt=GRIPPER.dt,
            impulse_sensitivity=sens,
        )

    v0 = rng.normal(size=3) * 0.05
    base = solve(v0, sens=True)
    assert solve(v0).impulse_response is None
    assert base.impulse_response is not None and base.impulse_response.shape == (2, 6, 3)
    dv = rng.normal(size=3) * 1e-4
    moved = solve(v0 + dv)
    np.testing.assert_allclose(moved.ln - base.ln, base.impulse_response[0] @ dv, atol=1e-12)
    np.testing.assert_allclose(moved.lt - base.lt, base.impulse_response[1] @ dv, atol=1e-12)
    sep = modes == Mode.SEPARATED
    assert np.all(base.impulse_response[:, sep] == 0.0)
    assert np.any(base.impulse_response[0, ~sep] != 0.0)


def test_violation_score_rescores_non_sliding_solutions_per_friction() -> None:
    """Without sliding contacts the reduced system does not depend on mu: one solve plus
    `violation_score` per mu equals solving each mu (what the filter does per beta)."""
    model = PlanarModel(GRIPPER)
    rng = np.random.default_rng(11)
    env = np.array([-0.03, 0.03])
    q = np.array([[0.001, 0.0, 0.2], [0.0, 0.004, -0.1]])
    v = rng.normal(size=(2, 3)) * 0.05
    sc = GRIPPER
    kin = contact_kinematics(sc, q, env)
    vf = v + sc.dt * model.generalized_force(q, v, np.zeros(3)) / model.mass_diag
    groups = [c.obstacle for c in sc.potential_contacts]
    modes = np.zeros((2, 6, 6), dtype=np.int64)  # one sticking contact per assignment
    modes[:, np.arange(6), np.arange(6)] = Mode.STICKING
    mu = np.array([0.05, 0.4, 0.9])[:, None] * np.ones(6)  # (B, C)

    def solve(m):  # type: ignore[no-untyped-def]
        return solve_reduced(
            modes[:, :, None, :],
            vf[:, None, None],
            inv_mass=1.0 / model.mass_diag,
            jn=kin.Jn[:, None, None],
            jt=kin.Jt[:, None, None],
            phi=kin.phi[:, None, None],
            vn_env=kin.vn_env[:, None, None],
            vt_env=kin.vt_env[:, None, None],
            mu=m,
            dt=sc.dt,
            groups=groups,
        )

    full = solve(mu)  # (2, 6, 3)
    one = solve(mu[:1])  # (2, 6, 1)
    np.testing.assert_allclose(full.v_next, np.broadcast_to(one.v_next, full.v_next.shape))
    score = violation_score(
        modes[:, :, None, :], one.ln, one.lt, one.gap_rate, one.vt, mu=mu, nv=3, groups=groups
    )
    np.testing.assert_allclose(score, full.score, rtol=1e-9, atol=1e-12)
    assert np.ptp(full.score, axis=-1).max() > 0.0  # the cone check does depend on mu
