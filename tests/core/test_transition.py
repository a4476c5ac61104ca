"""Softened NCP mode transition model."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from dbcslam_core.contact_modes import Mode
from dbcslam_core.errors import ModelError
from dbcslam_core.transition import TransitionParams, mode_transition, soft_modes

P = TransitionParams()
DT = 0.01


@settings(max_examples=100, deadline=None)
@given(
    phi=st.floats(-0.01, 0.1),
    vn=st.floats(-5.0, 5.0),
    vt=st.floats(-5.0, 5.0),
)
def test_soft_modes_are_distributions(phi: float, vn: float, vt: float) -> None:
    out = soft_modes(np.array([phi]), np.array([vn]), np.array([vt]), DT, P)
    assert out.shape == (1, 4)
    assert np.all(out >= 0.0)
    assert out.sum() == pytest.approx(1.0)


def test_soft_modes_follow_gap_and_slip() -> None:
    far = soft_modes(np.array([0.05]), np.array([0.0]), np.array([0.0]), DT, P)[0]
    assert far[Mode.SEPARATED] > 0.999
    pressing = soft_modes(np.array([0.0]), np.array([-0.1]), np.array([0.0]), DT, P)[0]
    assert pressing[Mode.SEPARATED] < 0.02
    assert pressing[Mode.STICKING] == max(pressing)
    lifting = soft_modes(np.array([0.0]), np.array([0.5]), np.array([0.0]), DT, P)[0]
    assert lifting[Mode.SEPARATED] > 0.99
    sliding = soft_modes(np.array([0.0]), np.array([-0.1]), np.array([0.5]), DT, P)[0]
    assert sliding[Mode.SLIDING_POS] > 0.8
    assert sliding[Mode.SLIDING_NEG] > 0.5 * P.slide_floor
    back = soft_modes(np.array([0.0]), np.array([-0.1]), np.array([-0.5]), DT, P)[0]
    assert back[Mode.SLIDING_NEG] > 0.8


def test_persistence_and_far_contacts() -> None:
    prev = np.array([[0.0, 1.0, 0.0, 0.0]])
    soft = np.array([[0.0, 0.0, 1.0, 0.0]])
    pred = mode_transition(prev, soft, P)
    np.testing.assert_allclose(pred, [[0.0, 0.9, 0.1, 0.0]])
    # a contact whose free gap is far cannot persist in contact
    far = mode_transition(prev, soft, P, phi=np.array([0.05]), gap_rate_free=np.zeros(1), dt=DT)
    assert far[0, Mode.SEPARATED] == pytest.approx(1.0)
    near = mode_transition(prev, soft, P, phi=np.array([0.0]), gap_rate_free=np.zeros(1), dt=DT)
    np.testing.assert_allclose(near, pred, atol=1e-4)
    # broadcasting (P, B, C, 4) against (P, 1, C, 4)
    prevb = np.tile(prev, (2, 3, 1, 1))
    assert mode_transition(prevb, soft[None, None], P).shape == (2, 3, 1, 4)


def test_params_validate() -> None:
    with pytest.raises(ModelError):
        TransitionParams(persistence=1.0)
    with pytest.raises(ModelError):
        TransitionParams(gap_scale=0.0)
    with pytest.raises(ModelError):
        mode_transition(np.zeros((1, 3)), np.zeros((1, 3)), P)


def test_edge_consistency_raises_contact_of_hovering_edge_partner() -> None:
    from dbcslam_core.transition import edge_consistency

    base = TransitionParams(gap_scale=1e-4)
    phi = np.array([3e-4, 3e-4, 3e-3])
    rate = np.zeros(3)
    soft = soft_modes(phi, rate, np.array([0.0, 0.05, 0.0]), 0.01, base)
    partner = np.array([1.0, 0.0, 1.0])
    off = edge_consistency(soft, phi, rate, 0.01, partner_contact=partner, params=base)
    np.testing.assert_array_equal(off, soft)  # tolerance 0: disabled
    on_p = TransitionParams(gap_scale=1e-4, edge_tolerance=5e-4)
    on = edge_consistency(soft, phi, rate, 0.01, partner_contact=partner, params=on_p)
    np.testing.assert_allclose(on.sum(axis=-1), 1.0)
    assert on[0, Mode.SEPARATED] < 0.2 < soft[0, Mode.SEPARATED]  # partner touches, gap small
    np.testing.assert_allclose(on[1], soft[1])  # no partner in contact
    assert on[2, Mode.SEPARATED] > 0.99  # gap far beyond the tolerance
    # the stick / slide split given contact is kept
    np.testing.assert_allclose(
        on[0, 1:] / on[0, 1:].sum(), soft[0, 1:] / soft[0, 1:].sum(), rtol=1e-9
    )


def test_contact_gap_legacy_and_time_stepping() -> None:
    from dbcslam_core.transition import contact_gap

    phi = np.array([3e-4, -2e-4, 5e-3])
    inc = np.array([True, True, False])
    # closure 1 without tolerance: the time-stepping model (whole gap within the step)
    np.testing.assert_array_equal(contact_gap(phi, inc), phi)
    # legacy partial closure: positive gaps of in-contact contacts only
    np.testing.assert_allclose(contact_gap(phi, inc, closure=0.1), [3e-5, -2e-4, 5e-3])
    with pytest.raises(ModelError, match="closure"):
        contact_gap(phi, inc, closure=0.0)
    with pytest.raises(ModelError, match="tolerance"):
        contact_gap(phi, inc, closure=0.5, tolerance=-1.0)


@settings(max_examples=100, deadline=None)
@given(
    phi=st.floats(-5e-3, 5e-3),
    closure=st.floats(0.01, 1.0),
    tol=st.floats(0.0, 2e-3),
    prev=st.floats(0.0, 1.0),
)
def test_contact_gap_band(phi: float, closure: float, tol: float, prev: float) -> None:
    """Within the band (penetration: tolerance; gap: tolerance x previous P(contact)) a
    residual is closed at `closure` per step, beyond it fully; same sign, never more than the
    gap, separated contacts unchanged."""
    from dbcslam_core.transition import contact_gap

    out = contact_gap(
        np.array([phi, phi]),
        np.array([True, False]),
        closure=closure,
        tolerance=tol,
        previous_contact=np.array([prev, prev]),
    )
    r = min(max(phi, -tol), tol * prev)
    assert out[0] == pytest.approx(phi - (1.0 - closure) * r, abs=1e-15)
    assert out[1] == phi
    assert abs(out[0]) <= abs(phi) + 1e-15
    assert out[0] * phi >= 0.0


def test_contact_gap_spares_impacts() -> None:
    """A persisting contact hovering / penetrating by a jaw-estimate jump closes it slowly; a new
    contact (previous P(contact) 0: an impact) closes the whole gap within the step."""
    from dbcslam_core.transition import contact_gap

    phi = np.array([2e-4, -2e-4, 2e-4, 3e-3])
    prev = np.array([1.0, 1.0, 0.0, 1.0])
    out = contact_gap(phi, np.ones(4, bool), closure=0.1, tolerance=1e-3, previous_contact=prev)
    np.testing.assert_allclose(out, [2e-5, -2e-5, 2e-4, 3e-3 - 0.9e-3])
