"""Tests of rotations, polygon mass properties and contact kinematics."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import example, given, settings
from hypothesis import strategies as st

from dbcslam_core.errors import ModelError
from dbcslam_core.geometry import (
    contact_kinematics,
    cross2,
    polygon_area,
    polygon_centroid,
    polygon_inertia,
    rot,
    rotate,
    wrap_angle,
)
from dbcslam_core.scenario import Scenario, edge_scenario, gripper_scenario, push_scenario

SQUARE = [[-0.05, -0.05], [0.05, -0.05], [0.05, 0.05], [-0.05, 0.05]]
HEXAGON = [[0.04 * math.cos(a), 0.03 * math.sin(a)] for a in np.linspace(0, 2 * math.pi, 7)[:-1]]


@pytest.fixture(scope="module")
def gripper() -> Scenario:
    return gripper_scenario()


@pytest.fixture(scope="module")
def push() -> Scenario:
    return push_scenario(HEXAGON, mass=0.5, pusher_radius=0.01)


def test_rotation_helpers() -> None:
    th = np.array([0.0, 0.3, -2.0])
    r = rot(th)
    assert r.shape == (3, 2, 2)
    assert np.allclose(r @ np.swapaxes(r, -1, -2), np.eye(2))
    assert np.allclose(np.linalg.det(r), 1.0)
    p = np.array([1.0, 2.0])
    assert np.allclose(rotate(th, p), r @ p)
    assert np.allclose(rotate(math.pi / 2, [1.0, 0.0]), [0.0, 1.0])
    assert cross2([1.0, 0.0], [0.0, 1.0]) == 1.0
    assert np.allclose(
        wrap_angle([math.pi + 0.1, -math.pi - 0.1]), [-math.pi + 0.1, math.pi - 0.1]
    )


def test_polygon_properties() -> None:
    assert polygon_area(SQUARE) == pytest.approx(0.01)
    assert polygon_area(SQUARE[::-1]) == pytest.approx(-0.01)
    assert np.allclose(polygon_centroid(SQUARE), 0.0)
    assert polygon_inertia(SQUARE, 2.0) == pytest.approx(2.0 * 0.02 / 12.0)
    shifted = np.asarray(SQUARE) + np.array([0.3, -0.1])
    assert np.allclose(polygon_centroid(shifted), [0.3, -0.1])
    # parallel axis theorem
    i_origin = polygon_inertia(shifted, 2.0)
    i_centroid = polygon_inertia(shifted, 2.0, about_centroid=True)
    assert i_origin == pytest.approx(i_centroid + 2.0 * (0.09 + 0.01))
    with pytest.raises(ModelError):
        polygon_area([[0.0, 0.0], [1.0, 0.0]])


def test_edge_kinematics_values() -> None:
    sc = edge_scenario(edge_y=0.2)
    k = contact_kinematics(sc, [1.5, 0.5])
    assert k.phi.shape == (1,)
    assert k.phi[0] == pytest.approx(0.3)
    assert np.allclose(k.Jn, [[0.0, 1.0]])
    assert np.allclose(k.Jt, [[1.0, 0.0]])
    assert k.s[0] == pytest.approx(1.5)
    assert np.allclose(k.point, [[1.5, 0.5]])
    assert np.allclose(k.vn_env, 0.0) and np.allclose(k.vt_env, 0.0)


def test_gripper_kinematics_values(gripper: Scenario) -> None:
    verts = np.asarray(gripper.body.vertices)
    q = np.array([0.01, 0.002, 0.0])
    env = np.array([-0.04, 0.05])
    k = contact_kinematics(gripper, q, env, [0.1, -0.2])
    lower = verts[:, 1] + q[1] - env[0]
    upper = env[1] - (verts[:, 1] + q[1])
    assert np.allclose(k.phi, np.concatenate([lower, upper]))
    assert np.allclose(k.vn_env, [0.1] * 3 + [0.2] * 3)
    assert np.allclose(k.Jn[:3, :2], [0.0, 1.0])
    assert np.allclose(k.Jn[3:, :2], [0.0, -1.0])
    assert np.allclose(k.Jt[3:, :2], [-1.0, 0.0])  # t = (n_y, -n_x)
    assert np.allclose(k.s[3:], -(verts[:, 0] + q[0]))


def _fd_check(sc: Scenario, q: np.ndarray, env: np.ndarray, v: np.ndarray, ev: np.ndarray) -> None:
    # central differences: near a vertex the gap is curved with radius ~ the distance (down to
    # 0.1 mm here), where a one-sided difference would be off by h / (2 d) ~ 5e-4
    h = 1e-7
    k0 = contact_kinematics(sc, q, env, ev)
    kp = contact_kinematics(sc, q + h * v, env + h * ev, ev)
    km = contact_kinematics(sc, q - h * v, env - h * ev, ev)
    dphi = (kp.phi - km.phi) / (2.0 * h)
    pred = np.einsum("ck,k->c", k0.Jn, v) - k0.vn_env
    assert np.allclose(dphi, pred, atol=2e-5 * (1 + np.abs(v).sum() + np.abs(ev).sum()))


@settings(max_examples=60, deadline=None)
@given(
    q=st.tuples(st.floats(-0.02, 0.02), st.floats(-0.02, 0.02), st.floats(-math.pi, math.pi)),
    v=st.tuples(st.floats(-1, 1), st.floats(-1, 1), st.floats(-3, 3)),
    ev=st.tuples(st.floats(-1, 1), st.floats(-1, 1)),
)
def test_gripper_jacobian_matches_finite_differences(
    q: tuple[float, float, float], v: tuple[float, float, float], ev: tuple[float, float]
) -> None:
    sc = gripper_scenario()
    _fd_check(sc, np.array(q), np.array([-0.05, 0.05]), np.array(v), np.array(ev))


@settings(max_examples=80, deadline=None)
# disk just outside a vertex, moving tangentially (one-sided differences failed here)
@example(c=(0.041015625, 0.0), yaw=0.0, v=(0.0, 0.0, 0.0), ev=(0.0, 1.0))
@given(
    c=st.tuples(st.floats(-0.08, 0.08), st.floats(-0.08, 0.08)),
    yaw=st.floats(-math.pi, math.pi),
    v=st.tuples(st.floats(-1, 1), st.floats(-1, 1), st.floats(-3, 3)),
    ev=st.tuples(st.floats(-1, 1), st.floats(-1, 1)),
)
def test_disk_jacobian_and_signed_distance(
    c: tuple[float, float],
    yaw: float,
    v: tuple[float, float, float],
    ev: tuple[float, float],
) -> None:
    sc = push_scenario(HEXAGON, mass=0.5, pusher_radius=0.01)
    q = np.array([0.01, -0.02, yaw])
    env = np.array([0.01 + c[0], -0.02 + c[1]])
    k = contact_kinematics(sc, q, env)
    # the contact point is on the outline; gap = +-|centre - point| - r
    d = np.linalg.norm(env - k.point[0])
    c_body = rotate(-yaw, env - q[:2])
    verts = np.asarray(HEXAGON)
    edges = np.roll(verts, -1, 0) - verts
    inside = np.all(cross2(edges, c_body - verts) >= 0)
    expected = (-d if inside else d) - 0.01
    assert k.phi[0] == pytest.approx(expected, abs=1e-12)
    assert np.linalg.norm(k.normal[0]) == pytest.approx(1.0)
    # moving the body along the normal opens the gap at unit rate
    k2 = contact_kinematics(sc, q + np.r_[1e-6 * k.normal[0], 0.0], env)
    assert (k2.phi[0] - k.phi[0]) / 1e-6 == pytest.approx(1.0, abs=1e-3)
    if k.phi[0] + 0.01 > 1e-4:  # outside: the closest point is unique (no medial axis)
        _fd_check(sc, q, env, np.array(v), np.array(ev))


def test_disk_inside_case(push: Scenario) -> None:
    # centre inside the body, 5 mm from the right-most edge region
    q = np.array([0.0, 0.0, 0.0])
    k = contact_kinematics(push, q, [0.02, 0.0])
    assert k.phi[0] < -0.01
    assert k.normal[0, 0] < 0.0  # pushes the body towards -x (away from the pusher side)
    far = contact_kinematics(push, q, [0.1, 0.0])
    assert far.phi[0] > 0.0
    assert far.normal[0, 0] < 0.0  # same direction outside: continuous through the boundary


def test_broadcasting_over_particles_and_hypotheses(gripper: Scenario) -> None:
    rng = np.random.default_rng(1)
    q = rng.normal(scale=0.01, size=(7, 1, 3))
    env = np.array([-0.05, 0.05]) + rng.normal(scale=0.001, size=(1, 4, 2))
    k = contact_kinematics(gripper, q, env, np.zeros(2))
    assert k.phi.shape == (7, 4, 6)
    assert k.Jn.shape == (7, 4, 6, 3)
    assert k.point.shape == (7, 4, 6, 2)
    single = contact_kinematics(gripper, q[3, 0], env[0, 2], np.zeros(2))
    assert np.allclose(k.phi[3, 2], single.phi)
    assert np.allclose(k.Jt[3, 2], single.Jt)


def test_bad_shapes_raise(gripper: Scenario) -> None:
    with pytest.raises(ModelError, match="q must have shape"):
        contact_kinematics(gripper, np.zeros(2), np.zeros(2))
    with pytest.raises(ModelError, match="env must have shape"):
        contact_kinematics(gripper, np.zeros(3), np.zeros(3))
