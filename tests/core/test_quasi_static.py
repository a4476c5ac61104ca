"""Quasi-static pusher-slider model: analytic cases and properties."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from dbcslam_core.contact_modes import Mode
from dbcslam_core.errors import ModelError
from dbcslam_core.quasi_static import (
    limit_surface_c,
    pusher_contact,
    quasi_static_motion,
    rollout_push,
)

SQUARE = 0.09 * np.array([[-0.5, -0.5], [0.5, -0.5], [0.5, 0.5], [-0.5, 0.5]])
C_SQ = limit_surface_c(SQUARE)


def disc(radius: float, n: int = 720) -> np.ndarray:
    a = np.linspace(0.0, 2.0 * math.pi, n, endpoint=False)
    return radius * np.column_stack([np.cos(a), np.sin(a)])


def test_c_of_uniform_disc_and_square() -> None:
    assert limit_surface_c(disc(0.05)) == pytest.approx(2 * 0.05 / 3, rel=1e-3)
    # square of side a: (a / 6) (sqrt(2) + asinh(1)) = 0.38260 a
    assert pytest.approx(0.09 * (math.sqrt(2) + math.asinh(1.0)) / 6, rel=1e-3) == C_SQ


def test_c_is_invariant_to_vertex_order_and_rotation() -> None:
    rot = np.array([[math.cos(0.3), -math.sin(0.3)], [math.sin(0.3), math.cos(0.3)]])
    assert limit_surface_c(SQUARE[::-1]) == pytest.approx(C_SQ, rel=1e-12)
    assert limit_surface_c(SQUARE @ rot.T) == pytest.approx(C_SQ, rel=1e-9)


def test_centred_push_moves_straight_and_sticks() -> None:
    m = quasi_static_motion([-0.045, 0.0], [1.0, 0.0], [0.05, 0.0], mu_c=0.2, c=C_SQ)
    np.testing.assert_allclose(m.twist, [0.05, 0.0, 0.0], atol=1e-15)
    assert m.mode == Mode.STICKING


def test_pusher_moving_away_separates() -> None:
    m = quasi_static_motion([-0.045, 0.0], [1.0, 0.0], [-0.05, 0.01], mu_c=0.2, c=C_SQ)
    np.testing.assert_array_equal(m.twist, 0.0)
    assert m.mode == Mode.SEPARATED


def test_off_centre_push_turns_away_from_the_contact() -> None:
    m = quasi_static_motion([-0.045, 0.03], [1.0, 0.0], [0.05, 0.0], mu_c=0.5, c=C_SQ)
    assert m.twist[0] > 0.0 and m.twist[2] < 0.0  # pushed above the centre: clockwise


@pytest.mark.parametrize("mu", [0.1, 0.3, 0.6])
def test_stick_slide_boundary_is_the_friction_cone(mu: float) -> None:
    """Sticking exactly while the sticking force stays in the cone |f_t| <= mu f_n: the
    motion cone. At the contact (-0.045, 0): K = diag(1, 1 + 0.045^2 / c^2), f = K^-1 v."""
    point, normal = np.array([-0.045, 0.0]), np.array([1.0, 0.0])
    angles = np.linspace(-1.2, 1.2, 241)
    v = 0.05 * np.column_stack([np.cos(angles), np.sin(angles)])
    m = quasi_static_motion(point, normal, v, mu_c=mu, c=C_SQ)
    k22 = 1.0 + 0.045**2 / C_SQ**2
    inside = np.abs(v[:, 1]) / k22 <= mu * v[:, 0]
    np.testing.assert_array_equal(m.mode == Mode.STICKING, inside)
    sliding = ~inside
    f = m.force[sliding]
    np.testing.assert_allclose(np.abs(f[:, 1]), mu * f[:, 0], rtol=1e-12)  # on the cone edge


@settings(deadline=None, max_examples=200)
@given(
    st.floats(-0.04, 0.04),
    st.floats(-1.0, 1.0),
    st.floats(0.0, 0.8),
)
def test_mirror_symmetry_and_normal_constraint(y: float, angle: float, mu: float) -> None:
    """Mirroring the push about the x axis mirrors the motion; the slider's contact point
    always keeps up with the pusher along the normal."""
    point, normal = np.array([-0.045, y]), np.array([1.0, 0.0])
    v = 0.05 * np.array([math.cos(angle), math.sin(angle)])
    m = quasi_static_motion(point, normal, v, mu_c=mu, c=C_SQ)
    mm = quasi_static_motion(point * [1, -1], normal, v * [1, -1], mu_c=mu, c=C_SQ)
    np.testing.assert_allclose(mm.twist, m.twist * [1, -1, -1], atol=1e-12)
    u_x = m.twist[0] - point[1] * m.twist[2]
    assert u_x == pytest.approx(v[0], abs=1e-12)
    if m.mode == Mode.STICKING:
        u_y = m.twist[1] + point[0] * m.twist[2]
        assert u_y == pytest.approx(v[1], abs=1e-12)


def test_pusher_contact_gap_point_and_normal() -> None:
    gap, point, normal = pusher_contact(SQUARE, [[-0.06, 0.01], [0.0, 0.0]], 0.005)
    np.testing.assert_allclose(gap[0], 0.015 - 0.005)
    np.testing.assert_allclose(point[0], [-0.045, 0.01])
    np.testing.assert_allclose(normal[0], [1.0, 0.0], atol=1e-12)
    assert gap[1] == pytest.approx(-0.045 - 0.005)  # centre inside: penetration


def test_rollout_centred_push_follows_the_pusher() -> None:
    dt = 0.01
    tip = np.column_stack([np.linspace(-0.07, 0.03, 101), np.zeros(101)])  # 0.1 m at 0.1 m/s
    poses, modes = rollout_push(
        SQUARE, [0.0, 0.0, 0.0], tip, radius=0.00475, dt=dt, mu_c=0.2, c=C_SQ
    )
    # contact after 0.07 - 0.045 - 0.00475 = 0.02025 m; the object then moves with the tip
    assert poses[-1, 0] == pytest.approx(0.1 - 0.02025, abs=1.5e-3)
    assert abs(poses[-1, 1]) < 1e-12 and abs(poses[-1, 2]) < 1e-12
    assert modes[0] == Mode.SEPARATED and modes[-1] == Mode.STICKING


def test_rollout_batches_candidates() -> None:
    tip = np.column_stack([np.linspace(-0.07, 0.03, 51), np.full(51, 0.02)])
    mu = np.array([[0.1], [0.4]])
    c = np.array([[0.5 * C_SQ, C_SQ, 2 * C_SQ]])
    poses, modes = rollout_push(SQUARE, [0, 0, 0], tip, radius=0.00475, dt=0.02, mu_c=mu, c=c)
    assert poses.shape == (2, 3, 51, 3) and modes.shape == (2, 3, 50)
    single, _ = rollout_push(SQUARE, [0, 0, 0], tip, radius=0.00475, dt=0.02, mu_c=0.4, c=C_SQ)
    np.testing.assert_allclose(poses[1, 1], single, atol=1e-14)


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        ({"vertices": [[0, 0], [1, 0]]}, "3 finite"),
        ({"dt": 0.0}, "positive"),
        ({"tip": [[0.0, 0.0]]}, "T >= 2"),
    ],
)
def test_bad_input_is_refused(kwargs: dict[str, object], match: str) -> None:
    args: dict[str, object] = {
        "vertices": SQUARE,
        "pose0": [0, 0, 0],
        "tip": [[0, 0], [0.01, 0]],
        "radius": 0.005,
        "dt": 0.01,
        "mu_c": 0.2,
        "c": C_SQ,
    }
    args.update(kwargs)
    with pytest.raises(ModelError, match=match):
        rollout_push(**args)  # type: ignore[arg-type]
