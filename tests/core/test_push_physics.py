"""Push scenario physics: support friction (implicit regularised Coulomb), pushing, stopping."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from dbcslam_core.contact_modes import Mode
from dbcslam_core.dynamics import PlanarModel, State
from dbcslam_core.errors import ModelError, ScenarioError
from dbcslam_core.extensions import ModelExtension
from dbcslam_core.geometry import polygon_inertia, rotate, support_points
from dbcslam_core.scenario import PRESSURE_MODELS, Scenario, SurfaceSpec, push_scenario
from dbcslam_core.synthetic import PUSH_RECT, PUSH_RECT_MASS, push_path, push_trajectory

G = 9.81
MU_S = 0.25
MU_P = 0.4
HEX = [[0.05 * np.cos(a), 0.05 * np.sin(a)] for a in np.arange(6) * np.pi / 3.0]


@pytest.fixture(scope="module")
def scenario() -> Scenario:
    return push_scenario(PUSH_RECT, mass=PUSH_RECT_MASS, support_pair="surface")


@pytest.fixture(scope="module")
def model(scenario: Scenario) -> PlanarModel:
    return PlanarModel(scenario)


FAR = np.array([1.0, 1.0])  # pusher far away


def _coast(model: PlanarModel, v0: np.ndarray, n: int) -> np.ndarray:
    q, v = np.zeros(3), np.asarray(v0, dtype=np.float64)
    out = [v]
    for _ in range(n):
        r = model.step(State(q, v), np.zeros(3), FAR, FAR, mu_pair=[MU_P, MU_S])
        q, v = r.q, r.v
        out.append(v)
    return np.asarray(out)


def _coulomb_force(model: PlanarModel, q: np.ndarray, v: np.ndarray, mu: float) -> np.ndarray:
    """Generalised support friction force of the exact Coulomb law at (q, v)."""
    r = rotate(q[2], model.support_points)
    vi = v[:2] + v[2] * np.stack([-r[:, 1], r[:, 0]], -1)
    f = -mu * model.mass_diag[0] * G * model.support_weights[:, None] * vi
    f = f / np.linalg.norm(vi, axis=1)[:, None]
    return np.array([f[:, 0].sum(), f[:, 1].sum(), np.sum(r[:, 0] * f[:, 1] - r[:, 1] * f[:, 0])])


# ----------------------------------------------------------------------------- support points
@pytest.mark.parametrize("pressure", PRESSURE_MODELS)
@pytest.mark.parametrize("outline", [PUSH_RECT, HEX, [[0.0, 0.0], [0.1, 0.0], [0.0, 0.05]]])
def test_support_points_balance_about_the_centre_of_mass(
    pressure: str, outline: list[list[float]]
) -> None:
    from dbcslam_core.geometry import polygon_centroid

    verts = np.asarray(outline) - polygon_centroid(outline)
    p, w = support_points(verts, pressure)
    assert np.all(w > 0.0)
    assert w.sum() == pytest.approx(1.0)
    assert np.allclose(w @ p, 0.0, atol=1e-15)


def test_uniform_pressure_has_the_polar_moment_of_the_area() -> None:
    p, w = support_points(PUSH_RECT, "uniform")
    gyration = polygon_inertia(PUSH_RECT, 1.0)
    assert w @ np.sum(p * p, axis=1) == pytest.approx(gyration, rel=0.02)
    pr, wr = support_points(PUSH_RECT, "rim")
    assert wr @ np.sum(pr * pr, axis=1) > 1.5 * gyration  # rim: more rotational friction


def test_rim_fraction_blends_uniform_and_rim() -> None:
    def second_moment(f: float) -> float:
        p, w = support_points(PUSH_RECT, rim_fraction=f)
        return float(w @ np.sum(p * p, axis=1))

    lo, mid, hi = second_moment(0.0), second_moment(0.5), second_moment(1.0)
    assert mid == pytest.approx(0.5 * (lo + hi))
    with pytest.raises(ModelError, match="rim_fraction"):
        support_points(PUSH_RECT, rim_fraction=1.5)
    with pytest.raises(ModelError, match="pressure"):
        support_points(PUSH_RECT, "bumpy")


# ----------------------------------------------------------------------------- support matrix
def test_support_matrix_reproduces_coulomb_force_and_is_vectorised(model: PlanarModel) -> None:
    rng = np.random.default_rng(0)
    q = rng.normal(size=(5, 3)) * [0.1, 0.1, 1.0]
    v = rng.normal(size=(5, 3)) * [0.05, 0.05, 1.0]
    mu = np.array([0.1, 0.2, 0.3, 0.4, 0.5])
    k = model.support_matrix(q, v, mu)
    assert k.shape == (5, 3, 3)
    assert np.allclose(k, np.swapaxes(k, -1, -2))
    assert np.all(np.linalg.eigvalsh(k) > -1e-9)
    for i in range(5):
        assert np.allclose(-k[i] @ v[i], _coulomb_force(model, q[i], v[i], mu[i]), rtol=1e-9)
    # linear in mu, broadcasting over a friction axis
    k1 = model.support_matrix(q[:, None], v[:, None], np.array([1.0, 2.0]))
    assert k1.shape == (5, 2, 3, 3)
    assert np.allclose(k1[:, 1], 2.0 * k1[:, 0])
    assert np.allclose(k1[:, 0] * mu[:, None, None], k)
    m_eff = model.effective_mass(q, v, mu)
    assert np.allclose(m_eff, model.mass_matrix + model.scenario.dt * k)


def test_one_linearised_step_solves_the_linear_system(scenario: Scenario) -> None:
    lin = PlanarModel(scenario, support_iterations=1)
    q = np.array([0.01, -0.02, 0.3])
    v = np.array([0.03, 0.01, 0.5])
    u = np.array([0.5, -0.2, 0.01])
    r = lin.step(State(q, v), u, FAR, FAR, mu_pair=[MU_P, MU_S])
    m_eff = lin.effective_mass(q, v, MU_S)
    lhs = m_eff @ r.v
    rhs = lin.mass_matrix @ v + scenario.dt * u
    assert np.allclose(lhs, rhs, rtol=1e-10)
    assert np.allclose(r.v, lin.free_velocity(q, v, u, m_eff))


# ---------------------------------------------------------------------------- free sliding
def test_free_slide_decelerates_at_mu_g_and_stops(model: PlanarModel) -> None:
    a = MU_S * G * model.scenario.dt
    v = _coast(model, np.array([0.1, 0.0, 0.0]), 8)
    speeds = v[:, 0]
    n_slide = int(0.1 // a)
    assert np.allclose(np.diff(speeds[: n_slide + 1]), -a, rtol=1e-6)
    assert np.all(np.abs(speeds[n_slide + 1 :]) <= model.velocity_eps)
    assert np.all(speeds >= 0.0)  # never reverses
    assert np.allclose(v[:, 1:], 0.0, atol=1e-12)


def test_linearised_model_decelerates_within_a_few_percent_when_fast(
    scenario: Scenario,
) -> None:
    lin = PlanarModel(scenario, support_iterations=1)
    v = _coast(lin, np.array([0.6, -0.8, 0.0]), 1)
    decel = (1.0 - np.linalg.norm(v[1, :2])) / scenario.dt
    assert decel == pytest.approx(MU_S * G, rel=0.03)


def test_spinning_body_feels_the_coulomb_torque(model: PlanarModel) -> None:
    omega0 = 5.0
    v = _coast(model, np.array([0.0, 0.0, omega0]), 1)
    torque = (
        MU_S
        * model.mass_diag[0]
        * G
        * float(model.support_weights @ np.linalg.norm(model.support_points, axis=1))
    )
    expected = omega0 - model.scenario.dt * torque / model.mass_diag[2]
    assert v[1, 2] == pytest.approx(expected, rel=1e-6)
    assert np.allclose(v[1, :2], 0.0, atol=1e-9)


# ------------------------------------------------------------------------------- pushing
def _push(
    model: PlanarModel,
    *,
    side_position: float,
    speed: float = 0.05,
    n_push: int = 40,
    n_hold: int = 6,
    angle: float = 0.0,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    sc = model.scenario
    start, d = push_path(
        sc.body.vertices,
        side=0,
        side_position=side_position,
        angle=angle,
        pusher_radius=sc.pusher_radius,
        approach=0.0,
    )
    n = n_push + n_hold
    env = start + speed * sc.dt * np.minimum(np.arange(n + 1), n_push)[:, None] * d
    q, v = np.zeros(3), np.zeros(3)
    vs, modes, fn = [], [], []
    for k in range(n):
        r = model.step(State(q, v), np.zeros(3), env[k], env[k + 1], mu_pair=[MU_P, MU_S])
        q, v = r.q, r.v
        vs.append(v)
        modes.append(int(r.modes[0]))
        fn.append(float(r.ln[0]) / sc.dt)
    return np.asarray(vs), np.asarray(modes), np.asarray(fn), q


def test_centred_push_moves_straight_at_pusher_speed(model: PlanarModel) -> None:
    v, modes, fn, q = _push(model, side_position=0.5)
    assert np.allclose(v[:40], [0.0, 0.05, 0.0], atol=1e-9)  # side 0 is pushed along +y
    assert np.all(modes[:40] == Mode.STICKING)
    # quasi-static: the pusher force balances the support friction
    assert np.allclose(fn[1:40], MU_S * PUSH_RECT_MASS * G, rtol=1e-6)
    assert q[2] == pytest.approx(0.0, abs=1e-12)


@pytest.mark.parametrize(("side_position", "sign"), [(0.8, 1.0), (0.2, -1.0)])
def test_off_centre_push_rotates_towards_the_free_side(
    model: PlanarModel, side_position: float, sign: float
) -> None:
    v, modes, _, q = _push(model, side_position=side_position)
    assert np.all(sign * v[1:40, 2] > 0.05)  # rad/s
    assert sign * q[2] > 0.05
    assert np.all(modes[1:40] != Mode.SEPARATED)
    assert v[5, 1] > 0.0


@pytest.mark.parametrize("speed", [0.01, 0.04, 0.15])
def test_object_stops_within_two_steps_of_the_pusher(model: PlanarModel, speed: float) -> None:
    v, modes, _, _ = _push(model, side_position=0.5, speed=speed)
    speeds = np.linalg.norm(v[:, :2], axis=1)
    a = MU_S * G * model.scenario.dt
    n_stop = int(np.ceil(speed / a))  # steps to shed the speed at mu_s g
    assert np.all(speeds[40 + n_stop :] <= model.velocity_eps)
    assert n_stop <= 7
    assert modes[-1] == Mode.SEPARATED  # the pusher holds still, the object has stopped


def test_rim_pressure_turns_slower_than_uniform(scenario: Scenario) -> None:
    rim = PlanarModel(scenario, (ModelExtension.make("support_pressure", rim_fraction=1.0),))
    uni = PlanarModel(scenario, (ModelExtension.make("support_pressure", rim_fraction=0.0),))
    _, _, _, q_rim = _push(rim, side_position=0.8, n_hold=1)
    _, _, _, q_uni = _push(uni, side_position=0.8, n_hold=1)
    assert 0.0 < q_rim[2] < 0.9 * q_uni[2]


# ------------------------------------------------------------------ friction sources, yaml
def test_support_coefficient_sources(scenario: Scenario) -> None:
    m = PlanarModel(scenario)
    assert m.surface_pair == 1
    with pytest.raises(ModelError, match="support friction pair"):
        m.surface_mu()
    assert float(m.surface_mu([0.3, 0.2])) == 0.2
    assert float(m.surface_mu([0.3, 0.2], mu_surface=0.5)) == 0.5
    ext = PlanarModel(scenario, (ModelExtension.make("support_friction", mu=0.7),))
    assert float(ext.surface_mu([0.3, 0.2])) == 0.7
    known = push_scenario(PUSH_RECT, mass=1.0, support_mu=0.3)
    assert float(PlanarModel(known).surface_mu()) == 0.3
    assert PlanarModel(push_scenario(PUSH_RECT, mass=1.0)).surface_mu() is None


def test_scenario_yaml_surface_keys_round_trip() -> None:
    sc = push_scenario(
        PUSH_RECT, mass=1.0, support_pair="table", pressure="rim", velocity_eps=1e-3
    )
    again = Scenario.from_yaml(sc.to_yaml())
    assert again == sc
    assert again.surface.pressure_model == "rim"
    assert again.surface.velocity_eps == 1e-3
    plain = push_scenario(PUSH_RECT, mass=1.0)
    assert "pressure" not in plain.to_dict()["surface"]  # old YAML stays as it was
    assert plain.surface.pressure_model == "uniform"
    d = plain.to_dict()
    d["surface"]["pressure"] = "soft"
    with pytest.raises(ScenarioError, match=r"surface\.pressure"):
        Scenario.from_dict(d)
    with pytest.raises(ScenarioError, match="velocity_eps"):
        SurfaceSpec(None, (("velocity_eps", 0.0),))


# ----------------------------------------------------------------------- synthetic pushes
def test_push_trajectory_centred() -> None:
    tr = push_trajectory(0)
    sc = tr.scenario
    assert tr.modes[0, 0] == Mode.SEPARATED
    moving = tr.modes[:, 0] == Mode.STICKING
    assert 90 <= int(moving.sum()) <= 101
    assert tr.q[-1, 1] == pytest.approx(0.05, abs=1e-3)  # travel
    assert abs(tr.q[-1, 0]) < 1e-9 and abs(tr.q[-1, 2]) < 1e-9
    assert np.allclose(tr.mu_pair, [MU_P, MU_S])
    resid = tr.obs[:, :2] - tr.q[:, :2]
    assert np.std(resid) == pytest.approx(sc.noise.position, rel=0.2)
    again = push_trajectory(0)
    assert np.array_equal(again.obs, tr.obs)
    assert not np.array_equal(push_trajectory(1).obs, tr.obs)


def test_push_trajectory_angled_push_slides_and_turns() -> None:
    tr = push_trajectory(0, side_position=0.3, angle=0.5, pressure="rim")
    counts = np.bincount(tr.modes[:, 0], minlength=4)
    assert counts[Mode.SLIDING_POS] + counts[Mode.SLIDING_NEG] >= 10
    assert counts[Mode.STICKING] >= 10
    assert tr.q[-1, 2] < -0.1  # contact left of the centre of mass: clockwise
    assert tr.scenario.surface.pressure == "rim"
    sliding = tr.modes[:, 0] >= Mode.SLIDING_POS
    assert np.allclose(np.abs(tr.lt[sliding, 0]), MU_P * tr.ln[sliding, 0], rtol=1e-6)


def test_push_trajectory_with_given_scenario_and_known_support() -> None:
    sc = push_scenario(HEX, mass=0.5, support_mu=0.2)
    tr = push_trajectory(
        2, scenario=dataclasses.replace(sc, dt=0.005), speed=0.1, side=1, mu_surface=0.3
    )
    assert tr.mu_pair.shape == (1,)
    assert tr.n_steps == round((0.06 / 0.1 + 0.3) / 0.005) + 1
    with pytest.raises(ModelError, match="side"):
        push_trajectory(0, side=9)


def test_batched_step_equals_single_steps(model: PlanarModel) -> None:
    """Each batch element re-linearises on its own (converged elements drop out)."""
    rng = np.random.default_rng(3)
    start, d = push_path(
        PUSH_RECT, side=0, side_position=0.7, angle=0.2, pusher_radius=0.00475, approach=0.0
    )
    q = np.zeros((6, 3))
    v = rng.normal(size=(6, 3)) * [0.03, 0.03, 0.3]
    v[0] = 0.0
    env0 = np.broadcast_to(start, (6, 2))
    env1 = env0 + 0.0005 * d
    mu_pair = np.array([[MU_P, s] for s in (0.1, 0.2, 0.25, 0.3, 0.4, 0.5)])
    batch = model.step(State(q, v), np.zeros(3), env0, env1, mu_pair=mu_pair)
    for i in range(6):
        one = model.step(State(q[i], v[i]), np.zeros(3), env0[i], env1[i], mu_pair=mu_pair[i])
        assert np.allclose(batch.v[i], one.v, rtol=0.0, atol=1e-9)
        assert np.allclose(batch.ln[i], one.ln, rtol=0.0, atol=1e-11)
        assert batch.modes[i, 0] == one.modes[0]
    assert batch.modes.dtype == np.int64
    assert batch.q.shape == (6, 3) and batch.ln.shape == (6, 1)
