"""Force likelihood of a contact-force reading (dbcslam_core.force_likelihood)."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from dbcslam_core.contact_modes import Mode, solve_reduced
from dbcslam_core.force_likelihood import (
    OUTLIER_FRACTION,
    OUTLIER_STD,
    active_contacts,
    force_log_likelihood,
    predicted_force,
    static_preload_bound,
)

DT = 0.01
NORMAL = np.array([[[[1.0, 0.0]]]])  # (N=1, 1, Cs=1, 2): pusher on the -x side, into +x


def _ll(reading: tuple[float, float], ln: float, **kw: object) -> float:
    kw.setdefault("outlier_fraction", 0.0)
    out = force_log_likelihood(
        reading,
        0.2,
        NORMAL,
        np.array([[[ln]]]),
        np.zeros((1, 1, 1)),
        dt=DT,
        **kw,  # type: ignore[arg-type]
    )
    assert out.shape == (1, 1)
    return float(out[0, 0])


def test_predicted_force_is_the_reaction_on_the_pusher() -> None:
    f, t = predicted_force(NORMAL, np.array([[[0.02]]]), np.array([[[0.01]]]), DT)
    # impulse 0.02 N s into the body over 10 ms: 2 N on the body (+x), -2 N on the pusher
    np.testing.assert_allclose(f[0, 0], [-2.0, 1.0])
    np.testing.assert_allclose(t[0, 0, 0], [0.0, -1.0])


@pytest.mark.parametrize("axes", ["normal", "both"])
def test_without_preload_matches_gaussian(axes: str) -> None:
    got = _ll((-1.0, 0.1), 0.01, axes=axes)
    var = 0.04
    rn = -1.0 + 1.0
    if axes == "normal":
        want = -0.5 * (rn * rn / var + math.log(2 * math.pi * var))
    else:
        want = -0.5 * ((rn * rn + 0.01) / var) - math.log(2 * math.pi * var)
    assert got == pytest.approx(want)


@pytest.mark.parametrize("axes", ["normal", "both"])
def test_preload_explains_pressing_on_a_resting_body(axes: str) -> None:
    """Zero predicted impulse (body at rest), reading 3 N pressing: in-contact with the
    allowance scores as a perfect fit, separated (no allowance) is far off."""
    pressing = (-3.0, 0.0)  # force on the pusher, pushed back along -n
    sep = _ll(pressing, 0.0, axes=axes)
    contact = _ll(pressing, 0.0, axes=axes, preload_max=np.array([[4.0]]))
    peak = _ll((0.0, 0.0), 0.0, axes=axes)
    assert contact == pytest.approx(peak)
    assert contact - sep > 100.0


@pytest.mark.parametrize("axes", ["normal", "both"])
def test_preload_is_one_sided_and_bounded(axes: str) -> None:
    pmax = np.array([[2.0]])
    # pulling (force on the pusher along +n) cannot be preload
    assert _ll((1.0, 0.0), 0.0, axes=axes, preload_max=pmax) == pytest.approx(
        _ll((1.0, 0.0), 0.0, axes=axes)
    )
    # beyond the bound only the excess counts: 3 N with 2 N allowed = a 1 N residual
    assert _ll((-3.0, 0.0), 0.0, axes=axes, preload_max=pmax) == pytest.approx(
        _ll((-1.0, 0.0), 0.0, axes=axes)
    )
    # a reading at the model's prediction is unchanged by the allowance
    assert _ll((-2.0, 0.0), 0.02, axes=axes, preload_max=pmax) == pytest.approx(
        _ll((-2.0, 0.0), 0.02, axes=axes)
    )


@settings(max_examples=60, deadline=None)
@given(
    fx=st.floats(-8.0, 8.0),
    fy=st.floats(-8.0, 8.0),
    ln=st.floats(0.0, 0.05),
    pmax=st.floats(0.0, 6.0),
    axes=st.sampled_from(["normal", "both"]),
)
def test_preload_never_lowers_the_likelihood_and_is_monotone(
    fx: float, fy: float, ln: float, pmax: float, axes: str
) -> None:
    base = _ll((fx, fy), ln, axes=axes)
    lo = _ll((fx, fy), ln, axes=axes, preload_max=np.array([[pmax]]))
    hi = _ll((fx, fy), ln, axes=axes, preload_max=np.array([[pmax + 1.0]]))
    assert lo >= base - 1e-9
    assert hi >= lo - 1e-9
    assert math.isfinite(lo)


@pytest.mark.parametrize("axes", ["normal", "both"])
def test_contaminated_gaussian_caps_a_gross_error(axes: str) -> None:
    """Default reading model: (1 - e) N(S) + e N(S + s_out^2 I). A reading 8 N off the
    prediction (rigid impact vs compliant ramp) costs a bounded amount, a reading at the
    prediction almost exactly the plain Gaussian."""
    e, s_out = OUTLIER_FRACTION, OUTLIER_STD
    assert 0.0 < e < 0.1
    var, wide = 0.04, 0.04 + s_out * s_out
    k = 1 if axes == "normal" else 2  # dimension of the scored residual
    for res in (0.0, 0.3, 8.0):
        got = _ll((-res, 0.0), 0.0, axes=axes, outlier_fraction=e)
        plain = -0.5 * res * res / var - 0.5 * k * math.log(2 * math.pi * var)
        broad = -0.5 * res * res / wide - 0.5 * k * math.log(2 * math.pi * wide)
        want = float(np.logaddexp(math.log1p(-e) + plain, math.log(e) + broad))
        assert got == pytest.approx(want)
        assert _ll((-res, 0.0), 0.0, axes=axes) == pytest.approx(plain)
    peak = _ll((0.0, 0.0), 0.0, axes=axes, outlier_fraction=e)
    gross = _ll((-8.0, 0.0), 0.0, axes=axes, outlier_fraction=e)
    assert peak - gross < 15.0 * k  # the plain Gaussian: 800 nats
    with pytest.raises(ValueError, match="outlier_fraction"):
        _ll((0.0, 0.0), 0.0, outlier_fraction=1.0)


def test_both_axes_profile_with_anisotropic_covariance() -> None:
    """With a full covariance the profiled p minimises the Mahalanobis residual."""
    rng = np.random.default_rng(3)
    n_ent = 5
    normal = np.tile(NORMAL, (n_ent, 1, 1, 1))
    ir = rng.normal(0.0, 0.05, (n_ent, 1, 2, 1, 3))
    sig2 = np.array([1e-4, 4e-4, 1e-2])
    reading = (-2.5, 0.7)
    pmax = np.full((n_ent, 1), 5.0)
    got = force_log_likelihood(
        reading,
        0.2,
        normal,
        np.zeros((n_ent, 1, 1)),
        np.zeros((n_ent, 1, 1)),
        dt=DT,
        impulse_response=ir,
        sig2=sig2,
        axes="both",
        preload_max=pmax,
        outlier_fraction=0.0,
    )
    grid = np.linspace(0.0, 5.0, 5001)
    g = grid.size
    for e in range(n_ent):
        # brute force: the reading shifted by +p along n is the same residual as preload p
        vals = force_log_likelihood(
            np.stack([reading[0] + grid, np.full(g, reading[1])], axis=-1)[:, None, :],
            0.2,
            np.tile(normal[e : e + 1], (g, 1, 1, 1)),
            np.zeros((g, 1, 1)),
            np.zeros((g, 1, 1)),
            dt=DT,
            impulse_response=np.tile(ir[e : e + 1], (g, 1, 1, 1, 1)),
            sig2=sig2,
            axes="both",
            outlier_fraction=0.0,
        )[:, 0]
        best = float(np.max(vals))
        assert got[e, 0] >= best - 1e-9
        assert got[e, 0] <= best + 1e-5


def test_static_preload_bound_reserve() -> None:
    v = np.array([[[0.0, 0.0, 0.0], [0.0025, 0.0, 0.0], [0.01, 0.0, 0.0], [0.0, 0.0, 0.05]]])
    active = np.array([[True]])
    mu = np.array([0.4, 0.4, 0.4, 0.4])
    got = static_preload_bound(v, active, mu, weight=10.0, velocity_eps=0.005, radius=0.05)
    # at rest the whole static friction, half at eps/2, none when sliding; yaw rate 0.05
    # rad/s at radius 5 cm = 2.5 mm/s -> half
    np.testing.assert_allclose(got, [[4.0, 2.0, 0.0, 2.0]])
    assert np.all(
        static_preload_bound(v, np.array([[False]]), mu, weight=10.0, velocity_eps=0.005) == 0.0
    )
    with pytest.raises(ValueError, match="velocity_eps"):
        static_preload_bound(v, active, mu, weight=10.0, velocity_eps=0.0)


def test_active_contacts_from_the_reduced_solution() -> None:
    """Sticking / sliding contacts have a non-zero impulse response, separated ones zero."""
    modes = np.array([[Mode.SEPARATED], [Mode.STICKING], [Mode.SLIDING_POS]])
    jn = np.array([[[1.0, 0.0, 0.0]]])
    jt = np.array([[[0.0, 1.0, 0.02]]])
    sol = solve_reduced(
        modes,
        np.zeros((3, 3)),
        inv_mass=np.array([1.0, 1.0, 100.0]),
        jn=jn,
        jt=jt,
        phi=np.zeros((1, 1)),
        vn_env=np.zeros((1, 1)),
        vt_env=np.zeros((1, 1)),
        mu=np.full((1, 1), 0.3),
        dt=DT,
        impulse_sensitivity=True,
    )
    assert sol.impulse_response is not None
    np.testing.assert_array_equal(active_contacts(sol.impulse_response), [False, True, True])
