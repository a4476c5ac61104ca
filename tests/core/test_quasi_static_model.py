"""The quasi-static push model of `PlanarModel` (``surface.model: quasi_static``) against the
pusher-slider mechanics of `dbcslam_core.quasi_static` (motion cone, limit surface)."""

from __future__ import annotations

import itertools
import math
from typing import Any

import numpy as np
import pytest

from dbcslam_core.contact_modes import Mode, ViolationScales, solve_reduced
from dbcslam_core.dynamics import PlanarModel, State
from dbcslam_core.errors import ModelError, ScenarioError
from dbcslam_core.extensions import ModelExtension
from dbcslam_core.geometry import contact_kinematics
from dbcslam_core.quasi_static import limit_surface_c, quasi_static_motion
from dbcslam_core.scenario import Scenario, push_scenario

SQUARE = 0.09 * np.array([[-0.5, -0.5], [0.5, -0.5], [0.5, 0.5], [-0.5, 0.5]])
RADIUS = 0.00475
MASS = 0.84
MU_S = 0.3
G = 9.81

# (contact offset along the pushed side (m), pusher velocity in the body frame (m/s), mu_c)
PUSHES = [
    (0.0, (0.05, 0.0), 0.2),  # centred: sticking, straight
    (0.03, (0.05, 0.0), 0.5),  # off-centre, high friction: sticking, turning
    (0.03, (0.05, 0.0), 0.05),  # off-centre, low friction: sliding
    (0.01, (0.05, 0.03), 0.2),  # oblique: sticking
    (0.01, (0.05, -0.03), 0.2),  # oblique the other way: sliding
    (-0.025, (0.02, 0.04), 0.3),  # steep: sliding
]


def _scenario(model: str | None = "quasi_static", **kw: Any) -> Scenario:
    args: dict[str, Any] = {
        "mass": MASS,
        "support_mu": MU_S,
        "pusher_radius": RADIUS,
        "dt": 0.01,
        "model": model,
    }
    args.update(kw)
    return push_scenario(SQUARE.tolist(), **args)


def _rot(yaw: float) -> np.ndarray:
    return np.array([[math.cos(yaw), -math.sin(yaw)], [math.sin(yaw), math.cos(yaw)]])


def _touching(offset: float, v_body: tuple[float, float], yaw: float) -> tuple[np.ndarray, ...]:
    """Slider pose q, pusher centre at the start and end of a step (world), touching the
    slider's left side (x = -0.045) at y = offset."""
    q = np.array([0.1, -0.2, yaw])
    r = _rot(yaw)
    e0 = q[:2] + r @ np.array([-0.045 - RADIUS, offset])
    e1 = e0 + 0.01 * (r @ np.asarray(v_body))
    return q, e0, e1


def _body_twist(v_world: np.ndarray, yaw: float) -> np.ndarray:
    return np.array([*(_rot(yaw).T @ v_world[:2]), v_world[2]])


def test_limit_surface_c_of_the_model_is_the_pressure_lever_arm() -> None:
    model = PlanarModel(_scenario())
    # the model's uniform support points approximate the integral of quasi_static.py
    assert model.limit_surface_c == pytest.approx(limit_surface_c(SQUARE), rel=0.01)
    rim = PlanarModel(_scenario(pressure="rim"))
    assert rim.limit_surface_c > model.limit_surface_c


@pytest.mark.parametrize(("offset", "v_body", "mu_c"), PUSHES)
@pytest.mark.parametrize("yaw", [0.0, 0.7])
def test_lcp_step_is_the_motion_cone(
    offset: float, v_body: tuple[float, float], mu_c: float, yaw: float
) -> None:
    """One quasi-static step of the LCP: twist, contact mode and force on the limit surface
    equal the motion-cone answer of `quasi_static_motion`."""
    model = PlanarModel(_scenario())
    q, e0, e1 = _touching(offset, v_body, yaw)
    r = model.step(State(q, np.zeros(3)), np.zeros(3), e0, e1, mu=mu_c)
    ref = quasi_static_motion(
        [-0.045, offset],
        [1.0, 0.0],
        v_body,
        mu_c=mu_c,
        c=model.limit_surface_c,
        f_max=MU_S * MASS * G,
    )
    np.testing.assert_allclose(_body_twist(r.v, yaw), ref.twist, rtol=1e-6, atol=1e-9)
    assert int(r.modes[0]) == int(ref.mode)
    force = np.hypot(r.ln[0], r.lt[0]) / 0.01  # N
    assert force == pytest.approx(float(np.hypot(*ref.force)), rel=1e-5)


@pytest.mark.parametrize(("offset", "v_body", "mu_c"), PUSHES)
def test_filter_reduced_solution_is_the_motion_cone(
    offset: float, v_body: tuple[float, float], mu_c: float
) -> None:
    """The filter's path (`support_terms` + `solve_reduced` under the mode hypothesis):
    the hypothesis of the motion-cone mode reproduces its twist with zero violation, and
    the other in-contact hypotheses violate an inequality."""
    yaw = 0.4
    model = PlanarModel(_scenario())
    q, e0, e1 = _touching(offset, v_body, yaw)
    v_lin = np.zeros((1, 3))
    m_eff, v_free = model.support_terms(q[None], v_lin, np.zeros(3), np.array([MU_S]))
    np.testing.assert_array_equal(v_free, 0.0)  # no coasting
    kin = contact_kinematics(model.scenario, q[None], e0, (e1 - e0) / 0.01)
    ref = quasi_static_motion(
        [-0.045, offset], [1.0, 0.0], v_body, mu_c=mu_c, c=model.limit_surface_c
    )
    modes = np.array([[int(m)] for m in Mode])  # (4, C = 1)
    sol = solve_reduced(
        modes,
        v_free[0],
        inv_mass=1.0 / model.mass_diag,
        jn=kin.Jn,
        jt=kin.Jt,
        phi=kin.phi,
        vn_env=kin.vn_env,
        vt_env=kin.vt_env,
        mu=np.array([mu_c]),
        dt=0.01,
        scales=ViolationScales(impulse=1e-3, velocity=1e-3),
        mass=m_eff[0],
    )
    right = int(ref.mode)
    np.testing.assert_allclose(_body_twist(sol.v_next[right], yaw), ref.twist, atol=1e-9)
    assert sol.score[right] == pytest.approx(0.0, abs=1e-12)
    for m in (Mode.STICKING, Mode.SLIDING_POS, Mode.SLIDING_NEG):
        if int(m) != right:
            assert sol.score[int(m)] > 0.0
    np.testing.assert_array_equal(sol.v_next[int(Mode.SEPARATED)], 0.0)


def test_released_object_stops_at_once_but_the_dynamic_one_coasts() -> None:
    q = np.array([0.0, 0.0, 0.3])
    far = np.array([1.0, 1.0])  # pusher far away
    v = np.array([0.1, 0.0, 0.0])
    qs = PlanarModel(_scenario()).step(State(q, v), np.zeros(3), far, far, mu=0.2)
    dyn = PlanarModel(_scenario("dynamic")).step(State(q, v), np.zeros(3), far, far, mu=0.2)
    np.testing.assert_allclose(qs.v, 0.0, atol=1e-12)
    assert dyn.v[0] == pytest.approx(0.1 - MU_S * G * 0.01, rel=1e-6)  # Coulomb deceleration


def test_centre_concentration_shrinks_c_and_turns_faster() -> None:
    ext = ModelExtension.make("support_concentration", centre_fraction=0.4)
    base = PlanarModel(_scenario())
    conc = PlanarModel(_scenario(), (ext,))
    assert conc.limit_surface_c == pytest.approx(0.6 * base.limit_surface_c, rel=1e-12)
    q, e0, e1 = _touching(0.03, (0.05, 0.0), 0.0)
    w_base = base.step(State(q, np.zeros(3)), np.zeros(3), e0, e1, mu=0.5).v[2]
    w_conc = conc.step(State(q, np.zeros(3)), np.zeros(3), e0, e1, mu=0.5).v[2]
    assert w_conc < w_base < 0.0  # pushed above the centre: clockwise, faster with smaller c


def test_scenario_key_round_trips_and_is_validated() -> None:
    sc = _scenario()
    assert sc.surface.quasi_static
    back = Scenario.from_yaml(sc.to_yaml())
    assert back.surface.model == "quasi_static"
    assert _scenario(None).surface.push_model == "dynamic"
    assert "model" not in _scenario(None).to_yaml().split("surface:")[1]
    bad = sc.to_yaml().replace("quasi_static", "quasistatic")
    with pytest.raises(ScenarioError, match=r"surface\.model"):
        Scenario.from_yaml(bad)


def test_quasi_static_needs_support_friction_and_a_lever_arm() -> None:
    with pytest.raises(ModelError, match="support friction"):
        PlanarModel(_scenario(support_mu=None))
    with pytest.raises(ModelError, match="lever arm"):
        PlanarModel(_scenario(pressure="centre"))
    model = PlanarModel(_scenario())
    with pytest.raises(ModelError, match="> 0"):
        model.support_terms(np.zeros((1, 3)), np.zeros((1, 3)), np.zeros(3), np.array([0.0]))


def test_support_concentration_is_a_scorable_push_effect() -> None:
    from dbcslam_core.discrepancy.effects import (
        FILTER_EFFECTS,
        Hypothesis,
        effect_size,
        effect_spaces,
    )
    from dbcslam_core.discrepancy.runs import default_effects

    sc = _scenario()
    assert "support_concentration" in FILTER_EFFECTS
    assert "support_concentration" in default_effects(sc)
    (space,) = effect_spaces(sc, "support_concentration")
    assert (space.lo, space.hi, space.default) == (0.0, 0.99, 0.0)
    # the grid steps c = (1 - centre_fraction) c0 by at most 2x up to 0.9; beyond it the
    # evidence is flat (effects.py) and the fit evaluates the bound and refines towards it
    c = [1.0 - f for f in (space.default, *space.grid)]
    assert all(1.0 < a / b <= 2.0 + 1e-9 for a, b in itertools.pairwise(c))
    assert space.grid[-1] == 0.9 < space.hi
    assert space.at_bound(0.99) and not space.at_bound(0.3) and not space.at_bound(0.9)
    ModelExtension.make("support_concentration", centre_fraction=0.99)  # valid to the bound
    assert effect_size("support_concentration", {"centre_fraction": 0.05}, sc) < 1.0
    _, exts, _, _ = Hypothesis.make(
        "support_concentration", {"centre_fraction": 0.3}
    ).filter_setup(sc)
    assert PlanarModel(sc, exts).limit_surface_c == pytest.approx(
        0.7 * PlanarModel(sc).limit_surface_c
    )
    with pytest.raises(ModelError, match="centre_fraction"):
        ModelExtension.make("support_concentration", centre_fraction=1.0)


@pytest.mark.parametrize("model", ["dynamic", "quasi_static"])
def test_support_friction_effect_reaches_the_filter_with_a_support_pair(model: str) -> None:
    """With an estimated support pair the filter's support coefficient is that pair's
    candidates: the effect must replace them (it used to be ignored: nominal scores)."""
    from dbcslam_core.discrepancy.effects import Hypothesis
    from dbcslam_core.rbpf import DbcSlamFilter, FilterConfig

    sc = _scenario(model, support_mu=None, support_pair="surface")
    assert sc.friction.pairs == ("pusher", "surface")
    sc2, exts, _, _ = Hypothesis.make("support_friction", {"mu": 0.7}).filter_setup(sc)
    i = sc2.friction.pair_index("surface")
    assert sc2.friction.candidates[i] == (0.7,) and sc2.friction.prior[i] == (1.0,)
    assert sc2.friction.candidates[0] == sc.friction.candidates[0]
    filt = DbcSlamFilter(sc2, FilterConfig.preset("push", particles=4), extensions=exts)
    np.testing.assert_array_equal(filt._mu_surface, 0.7)
