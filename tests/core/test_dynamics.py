"""Tests of the planar contact model (Stewart-Trinkle time stepping)."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import example, given, settings
from hypothesis import strategies as st

from dbcslam_core.contact_modes import Mode
from dbcslam_core.dynamics import PlanarModel, State, modes_from_lcp
from dbcslam_core.errors import ModelError
from dbcslam_core.geometry import contact_kinematics
from dbcslam_core.lcp import PGSSolver
from dbcslam_core.scenario import Scenario, edge_scenario, gripper_scenario, push_scenario

G = 9.81


@pytest.fixture(scope="module")
def edge() -> Scenario:
    return edge_scenario()


@pytest.fixture(scope="module")
def gripper() -> Scenario:
    return gripper_scenario()


def test_mass_matrix_and_forces(edge: Scenario, gripper: Scenario) -> None:
    me = PlanarModel(edge)
    assert np.allclose(me.mass_matrix, np.diag([1.0, 1.0]))
    assert np.allclose(me.generalized_force([0, 0], [0, 0], [2.0, 1.0]), [2.0, 1.0 - G])
    mg = PlanarModel(gripper)
    i = gripper.body.inertia
    assert np.allclose(mg.mass_matrix, np.diag([0.2, 0.2, i]))
    # horizontal plane: no gravity in the model plane
    assert np.allclose(mg.generalized_force([0, 0, 0], [0, 0, 0], [1.0, 2.0, 0.1]), [1, 2, 0.1])
    with pytest.raises(ModelError, match="input wrench"):
        mg.generalized_force([0, 0, 0], [0, 0, 0], [1.0, 2.0])


def test_free_flight_is_explicit_euler(edge: Scenario) -> None:
    m = PlanarModel(edge)
    r = m.step(State(np.array([0.0, 1.0]), np.array([0.5, 0.2])), [1.0, 0.0], mu=0.3)
    v_exp = np.array([0.5 + 0.01 * 1.0, 0.2 - 0.01 * G])
    assert np.allclose(r.v, v_exp)
    assert np.allclose(r.q, [0.0, 1.0] + 0.01 * v_exp)
    assert r.modes.tolist() == [Mode.SEPARATED]
    assert r.ln[0] == 0.0


@pytest.mark.parametrize("mu", [0.3, 0.9])
@pytest.mark.parametrize("fx", [-12.0, -5.0, -1.0, 0.0, 2.0, 8.0, 12.0])
def test_point_on_edge_stick_slip_analytic(edge: Scenario, mu: float, fx: float) -> None:
    """A resting mass sticks when |fx| <= mu m g, else slides with Coulomb friction."""
    m = PlanarModel(edge)
    r = m.step(State(np.zeros(2), np.zeros(2)), [fx, 0.0], mu=mu)
    dt = edge.dt
    assert r.ln[0] == pytest.approx(G * dt)
    assert r.v[1] == pytest.approx(0.0, abs=1e-12)
    if abs(fx) <= mu * G:
        assert r.modes[0] == Mode.STICKING
        assert r.v[0] == pytest.approx(0.0, abs=1e-12)
        assert r.lt[0] == pytest.approx(-fx * dt)
    else:
        sign = math.copysign(1.0, fx)
        assert r.modes[0] == (Mode.SLIDING_POS if sign > 0 else Mode.SLIDING_NEG)
        assert r.v[0] == pytest.approx(dt * (fx - sign * mu * G))
        assert r.lt[0] == pytest.approx(-sign * mu * G * dt)
        assert r.slide[0] == pytest.approx(abs(r.v[0]))


def test_lift_off_and_landing(edge: Scenario) -> None:
    m = PlanarModel(edge)
    up = m.step(State(np.zeros(2), np.zeros(2)), [0.0, 2.0 * G], mu=0.3)
    assert up.modes[0] == Mode.SEPARATED and up.v[1] > 0
    # falling fast onto the edge: stops exactly at the surface (phi/dt stabilisation)
    land = m.step(State(np.array([0.0, 0.001]), np.array([1.0, -1.0])), [0.0, 0.0], mu=0.3)
    assert land.q[1] == pytest.approx(0.0, abs=1e-12)
    assert land.modes[0] == Mode.SLIDING_POS


def test_position_dependent_friction(edge: Scenario) -> None:
    m = PlanarModel(edge)

    def field(s: np.ndarray) -> np.ndarray:
        return np.where(s > 0.5, 0.9, 0.3)

    state = State(np.array([[0.0, 0.0], [1.0, 0.0]]), np.zeros((2, 2)))
    r = m.step(state, [5.0, 0.0], mu=field)
    assert r.mu[:, 0].tolist() == [0.3, 0.9]
    assert r.modes[:, 0].tolist() == [Mode.SLIDING_POS, Mode.STICKING]
    r2 = m.step(state, [5.0, 0.0], mu_pair=[0.9])
    assert r2.modes[:, 0].tolist() == [Mode.STICKING, Mode.STICKING]
    with pytest.raises(ModelError, match="exactly one"):
        m.step(state, [5.0, 0.0])


def test_batched_step_matches_single(gripper: Scenario) -> None:
    rng = np.random.default_rng(4)
    m = PlanarModel(gripper)
    q = np.column_stack([rng.normal(0, 0.003, 5), rng.normal(0, 0.003, 5), rng.uniform(-3, 3, 5)])
    v = rng.normal(0, 0.1, (5, 3))
    env = np.array([-0.045, 0.045])
    u = rng.normal(0, 0.5, (5, 3))
    batch = m.step(State(q, v), u, env, env + np.array([0.001, -0.001]), mu=0.4)
    for i in range(5):
        one = m.step(State(q[i], v[i]), u[i], env, env + np.array([0.001, -0.001]), mu=0.4)
        assert np.allclose(batch.v[i], one.v)
        assert np.array_equal(batch.modes[i], one.modes)


@settings(max_examples=40, deadline=None)
@given(
    seed=st.integers(0, 2**32 - 1),
    yaw=st.floats(-math.pi, math.pi),
    jaw_speed=st.floats(0.0, 0.05),
    mu=st.sampled_from([0.1, 0.4, 0.7]),
)
def test_gripper_step_never_penetrates_linearised(
    seed: int, yaw: float, jaw_speed: float, mu: float
) -> None:
    """After a step every linearised gap phi + dt (Jn v' - vn_env) is >= 0."""
    sc = gripper_scenario()
    rng = np.random.default_rng(seed)
    verts = np.asarray(sc.body.vertices)
    yv = verts[:, 0] * math.sin(yaw) + verts[:, 1] * math.cos(yaw)
    lower = yv.min() - 0.002
    upper = yv.max() + 0.02  # room: the jaws close only from the lower side
    env = np.array([lower, upper])
    env_next = env + np.array([jaw_speed, 0.0]) * sc.dt
    state = State(np.array([0.0, 0.0, yaw]), rng.normal(scale=[0.05, 0.05, 0.5]))
    m = PlanarModel(sc)
    r = m.step(state, rng.normal(scale=[0.3, 0.3, 0.005]), env, env_next, mu=mu)
    kin = contact_kinematics(sc, state.q, env, (env_next - env) / sc.dt)
    lin_gap = kin.phi + sc.dt * (kin.Jn @ r.v - kin.vn_env)
    assert np.all(lin_gap >= -1e-10)
    assert np.all(r.ln >= 0.0)
    assert np.all(np.abs(r.lt) <= mu * r.ln + 1e-12)
    # a contact carrying load closes its linearised gap exactly (complementarity): the lower
    # jaw pushes the body so that phi + dt (Jn v' - vn_env) = 0 (with an initial gap phi > 0
    # the normal velocity may still be below the jaw speed, by phi / dt)
    active = r.modes != Mode.SEPARATED
    assert np.all(np.abs(lin_gap[active]) <= 1e-9)


def test_edge_contact_on_jaw_with_pgs_matches_lemke(gripper: Scenario) -> None:
    verts = np.asarray(gripper.body.vertices)
    env = np.array([verts[:, 1].min(), 0.08])  # flat edge resting on the lower jaw
    state = State(np.zeros(3), np.array([0.02, 0.0, 0.0]))
    u = np.array([0.3, -0.5, 0.0])
    lem = PlanarModel(gripper).step(state, u, env, env, mu=0.4)
    pgs = PlanarModel(gripper, solver=PGSSolver(max_iter=2000)).step(state, u, env, env, mu=0.4)
    assert lem.modes[:2].tolist() == [Mode.SLIDING_POS, Mode.SLIDING_POS]
    assert np.allclose(pgs.v, lem.v, atol=1e-6)
    assert pgs.modes[:2].tolist() == lem.modes[:2].tolist()
    # both vertices carry the load: total normal impulse balances the push
    assert lem.ln[:2].sum() == pytest.approx(0.5 * gripper.dt)


def test_modes_from_lcp() -> None:
    ln = np.array([0.0, 1.0, 1.0, 1.0, 1e-12])
    slide = np.array([5.0, 0.0, 0.3, 0.3, 1.0])
    vt = np.array([1.0, 0.0, 0.3, -0.3, 1.0])
    assert modes_from_lcp(ln, slide, vt).tolist() == [
        Mode.SEPARATED,
        Mode.STICKING,
        Mode.SLIDING_POS,
        Mode.SLIDING_NEG,
        Mode.SEPARATED,
    ]


def test_bad_state_raises(edge: Scenario) -> None:
    m = PlanarModel(edge)
    with pytest.raises(ModelError, match="state"):
        m.step(State(np.zeros(3), np.zeros(3)), [0.0, 0.0], mu=0.3)
    with pytest.raises(ModelError, match="finite"):
        m.step(State(np.array([np.nan, 0.0]), np.zeros(2)), [0.0, 0.0], mu=0.3)
    with pytest.raises(ModelError, match="friction"):
        m.step(State(np.zeros(2), np.zeros(2)), [0.0, 0.0], mu=-0.1)


def test_disk_pusher_pushes_and_drags() -> None:
    square = [[-0.05, -0.05], [0.05, -0.05], [0.05, 0.05], [-0.05, 0.05]]
    sc = push_scenario(square, mass=1.0, pusher_radius=0.01)
    m = PlanarModel(sc)
    state = State(np.zeros(3), np.zeros(3))
    env = np.array([-0.06, 0.0])  # touching the left face
    # pushing straight along +x at 0.1 m/s: the body moves with the pusher, no rotation
    r = m.step(state, np.zeros(3), env, env + np.array([0.001, 0.0]), mu=0.5)
    assert r.v[0] == pytest.approx(0.1)
    assert r.v[1] == pytest.approx(0.0, abs=1e-12) and r.v[2] == pytest.approx(0.0, abs=1e-12)
    assert r.modes[0] == Mode.STICKING
    # pushing obliquely with little friction: the pusher slides along the face
    r2 = m.step(state, np.zeros(3), env, env + np.array([0.001, 0.002]), mu=0.05)
    # t = (n_y, -n_x) = (0, -1): the pusher moves along -t relative to the body, vt > 0
    assert r2.modes[0] == Mode.SLIDING_POS
    assert r2.v[0] == pytest.approx(0.1, rel=1e-6)  # normal motion still follows the pusher
    assert abs(r2.lt[0]) == pytest.approx(0.05 * r2.ln[0])


@settings(max_examples=60, deadline=None)
# frictionless: Lemke ray-terminated on the (degenerate) friction rows before they were decoupled
@example(seed=566896, yaw=-2.125, mu=0.0, touching="lower")
@given(
    seed=st.integers(0, 2**32 - 1),
    yaw=st.floats(-math.pi, math.pi),
    mu=st.sampled_from([0.0, 0.1, 0.4, 0.7]),
    touching=st.sampled_from(["lower", "upper", "both"]),
)
def test_active_set_solve_equals_full_lcp(seed: int, yaw: float, mu: float, touching: str) -> None:
    """The reduced (active-set) contact solve gives the full LCP's answer.

    (With mu >~ 1 the rigid-body LCP can have several solutions - Painleve-type - and the
    active-set solve prefers the one without spurious impulses; both verify.)
    """
    sc = gripper_scenario()
    rng = np.random.default_rng(seed)
    verts = np.asarray(sc.body.vertices)
    yv = verts[:, 0] * math.sin(yaw) + verts[:, 1] * math.cos(yaw)
    lower = yv.min() - (0.0 if touching in ("lower", "both") else 0.002)
    upper = yv.max() + (0.0 if touching in ("upper", "both") else 0.002)
    env = np.array([lower, upper])
    state = State(np.array([0.0, 0.0, yaw]), rng.normal(scale=[0.05, 0.05, 1.0]))
    u = rng.normal(scale=[0.5, 0.5, 0.01])
    fast = PlanarModel(sc, active_set=True).step(state, u, env, env, mu=mu)
    full = PlanarModel(sc).step(state, u, env, env, mu=mu)
    assert np.allclose(fast.v, full.v, atol=1e-9)
    assert np.array_equal(fast.modes, full.modes)
