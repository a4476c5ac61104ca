"""Mode transition model p(sigma_l | x_{l-1}, sigma_{l-1}, beta, i) (Sec. III-A).

Per potential contact, the hard NCP checks of the time-stepping model are softened into
probabilities computed from the free motion of the step (the velocity without contact
impulses, v_free = v + dt M^-1 F):

* contact: sigmoid(-g / gap_scale) with g = phi + dt (Jn v_free - vn_env) the gap the free
  motion would reach after one step (negative = it would penetrate). Contacts whose free gap
  exceeds far_gap cannot close within the step: their in-contact modes get the factor
  sigmoid(-(g - far_gap) / gap_scale).
* sticking vs sliding given contact: from the free relative slip velocity vt_free = Jt v_free -
  vt_env: p_stick proportional to 1 / (1 + (vt_free / slip_scale)^2), sliding in the direction
  of vt_free, each of the three in-contact modes floored at slide_floor (so the
  friction-dependent checks of the reduced dynamics, which depend on beta, can decide).
* persistence: pred = rho * previous marginal + (1 - rho) * soft (modes tend to stay).

The friction-dependent part of the NCP checks (cone |lt| <= mu ln, slip direction, ln >= 0,
non-penetration) is scored on the reduced solution of each joint hypothesis
(`contact_modes.solve_reduced`), which the filter multiplies into this prior per beta.
Geometric exclusions of joint hypotheses live in `contact_modes.geometric_feasible`.
`contact_gap` gives the gap the contact equalities of a hypothesis close within the step: the
time-stepping phi, or, with a gap tolerance, gap residuals of persisting contacts (jaw-estimate
jumps, tilt errors) closed only partly per step.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from dbcslam_core.contact_modes import N_MODES, Mode, sum_last
from dbcslam_core.errors import ModelError

__all__ = [
    "TransitionParams",
    "contact_gap",
    "edge_consistency",
    "mode_transition",
    "soft_modes",
]

FloatArray = npt.NDArray[np.float64]


@dataclass(frozen=True)
class TransitionParams:
    """Parameters of the softened NCP transition (SI units)."""

    persistence: float = 0.9
    """rho in [0, 1): weight of the previous mode marginal."""
    gap_scale: float = 2.5e-4
    """m: sigmoid scale of the predicted free gap."""
    far_gap: float = 1e-2
    """m: free gaps beyond this make contact within one step implausible."""
    slip_scale: float = 2e-2
    """m/s: slip speed at which sticking and sliding are equally likely."""
    slide_floor: float = 0.05
    """minimum share of each in-contact mode (sticking / sliding_pos / sliding_neg)."""
    edge_tolerance: float = 0.0
    """m: edge-contact consistency (`edge_consistency`); 0 disables it."""

    def __post_init__(self) -> None:
        if not 0.0 <= self.persistence < 1.0:
            msg = f"persistence must be in [0, 1), got {self.persistence}"
            raise ModelError(msg)
        for name in ("gap_scale", "slip_scale"):
            if not getattr(self, name) > 0.0:
                msg = f"{name} must be > 0, got {getattr(self, name)}"
                raise ModelError(msg)
        if not self.edge_tolerance >= 0.0:
            msg = f"edge_tolerance must be >= 0 m, got {self.edge_tolerance}"
            raise ModelError(msg)
        if not 0.0 <= self.slide_floor < 1.0 / 3.0:
            msg = f"slide_floor must be in [0, 1/3), got {self.slide_floor}"
            raise ModelError(msg)


def _sigmoid(x: FloatArray) -> FloatArray:
    return np.asarray(0.5 * (1.0 + np.tanh(0.5 * x)), dtype=np.float64)


def soft_modes(
    phi: npt.ArrayLike,
    gap_rate_free: npt.ArrayLike,
    vt_free: npt.ArrayLike,
    dt: float,
    params: TransitionParams,
) -> FloatArray:
    """Softened NCP mode probabilities (..., C, 4) from the free motion of the step.

    phi (..., C) current gaps (m); gap_rate_free (..., C) = Jn v_free - vn_env (m/s);
    vt_free (..., C) = Jt v_free - vt_env (m/s).
    """
    ph = np.asarray(phi, dtype=np.float64)
    g = ph + dt * np.asarray(gap_rate_free, dtype=np.float64)
    vt = np.asarray(vt_free, dtype=np.float64)
    pc = _sigmoid(-g / params.gap_scale) * _sigmoid(-(g - params.far_gap) / params.gap_scale)
    a = vt / params.slip_scale
    p_stick = 1.0 / (1.0 + a * a)
    p_slide = 1.0 - p_stick
    direction = _sigmoid(10.0 * a)
    shape = g.shape if g.shape == a.shape else np.broadcast_shapes(g.shape, a.shape)
    out = np.empty((*shape, N_MODES))
    inc = out[..., Mode.STICKING :]  # filled in place (no stack / concatenate)
    inc[..., 0] = p_stick
    np.multiply(p_slide, direction, out=inc[..., 1])
    np.multiply(p_slide, 1.0 - direction, out=inc[..., 2])
    np.maximum(inc, params.slide_floor, out=inc)
    inc /= sum_last(inc)[..., None]
    inc *= pc[..., None]
    out[..., Mode.SEPARATED] = 1.0 - pc
    return out


def edge_consistency(
    soft: npt.ArrayLike,
    phi: npt.ArrayLike,
    gap_rate_free: npt.ArrayLike,
    dt: float,
    *,
    partner_contact: npt.ArrayLike,
    params: TransitionParams,
) -> FloatArray:
    """Contact-consistency prior for polygon edges lying on a flat obstacle.

    soft (..., C, 4) softened modes (`soft_modes`); phi, gap_rate_free (..., C) as there;
    partner_contact (..., C): probability that an adjacent vertex of the same polygon edge
    is in contact with the same obstacle (0 where there is none). A vertex whose edge partner
    touches and whose free gap is within `edge_tolerance` (the gap a small tilt error of the
    estimate produces over the edge) gets the contact probability
    max(p, partner * sigmoid(-(g - edge_tolerance) / gap_scale)); the in-contact split
    (stick / slide) is kept. Without this, a few mrad of tilt make one vertex of an edge
    contact hover and light edge contacts are estimated as vertex contacts.
    """
    sf = np.asarray(soft, dtype=np.float64)
    if params.edge_tolerance <= 0.0:
        return sf
    g = np.asarray(phi, dtype=np.float64) + dt * np.asarray(gap_rate_free, dtype=np.float64)
    p_tol = _sigmoid(-(g - params.edge_tolerance) / params.gap_scale)
    pc = 1.0 - sf[..., Mode.SEPARATED]
    pc_new = np.maximum(pc, np.asarray(partner_contact, dtype=np.float64) * p_tol)
    inc = sf[..., Mode.STICKING :]
    inc = np.where(
        pc[..., None] > 1e-12, inc / np.maximum(pc, 1e-300)[..., None], 1.0 / (N_MODES - 1)
    )
    out = np.concatenate([(1.0 - pc_new)[..., None], pc_new[..., None] * inc], axis=-1)
    return np.asarray(out, dtype=np.float64)


def mode_transition(
    previous: npt.ArrayLike,
    soft: npt.ArrayLike,
    params: TransitionParams,
    *,
    phi: npt.ArrayLike | None = None,
    gap_rate_free: npt.ArrayLike | None = None,
    dt: float = 0.0,
) -> FloatArray:
    """Predicted per-contact mode marginals: rho * previous + (1 - rho) * soft.

    previous (..., C, 4) (e.g. (P, B, C, 4)); soft broadcastable (e.g. (P, 1, C, 4)).
    If phi / gap_rate_free are given, in-contact modes of contacts whose free gap exceeds
    far_gap are moved to `separated` also in the persistent part (a contact that is far away
    cannot persist). Rows are renormalised.
    """
    prev = np.asarray(previous, dtype=np.float64)
    sf = np.asarray(soft, dtype=np.float64)
    if prev.shape[-1] != N_MODES or sf.shape[-1] != N_MODES:
        msg = f"mode arrays need {N_MODES} modes in the last axis, got {prev.shape}, {sf.shape}"
        raise ModelError(msg)
    rho = params.persistence
    pred = rho * prev + (1.0 - rho) * sf
    # Below, per-mode slices (...) instead of (..., 4) blocks: numpy iterates the latter in
    # runs of 3-4 elements (same operations, same values).
    if phi is not None and gap_rate_free is not None:
        g = np.asarray(phi, dtype=np.float64) + dt * np.asarray(gap_rate_free, dtype=np.float64)
        reach = _sigmoid(-(g - params.far_gap) / params.gap_scale)
        lead = np.broadcast_shapes(pred.shape[:-1], reach.shape)
        if pred.shape[:-1] != lead:
            pred = np.array(np.broadcast_to(pred, (*lead, N_MODES)))
        reach = np.ascontiguousarray(np.broadcast_to(reach, lead))
        stay = 1.0 - reach
        moved = pred[..., 1] * stay  # in-contact mass that cannot reach the obstacle
        for m in range(2, N_MODES):
            moved += pred[..., m] * stay
        pred[..., Mode.SEPARATED] += moved
        for m in range(1, N_MODES):
            pred[..., m] *= reach
    total = np.maximum(sum_last(pred), 1e-300)
    out = np.empty(pred.shape)
    for m in range(N_MODES):
        np.divide(pred[..., m], total, out=out[..., m])
    return out


def contact_gap(
    phi: npt.ArrayLike,
    in_contact: npt.ArrayLike,
    *,
    closure: float = 1.0,
    tolerance: float | None = None,
    previous_contact: npt.ArrayLike | None = None,
) -> FloatArray:
    """Gap (m) that the contact equalities of a mode hypothesis close within one step.

    phi (..., C): gaps at the start of the step (m; negative = penetration); in_contact
    (..., C) bool: contacts the hypothesis puts in contact (only those change);
    previous_contact (..., C): P(in contact) of the contact at the previous step (None = 1).
    The result replaces phi in the equality phi / dt + Jn v' - vn_env = 0 of the reduced
    dynamics (`contact_modes.solve_reduced`).

    * closure 1 (default): the time-stepping model: an in-contact hypothesis closes the whole
      gap, or recovers the whole penetration, within the step (velocity jump phi / dt).
    * tolerance None, closure < 1: only positive gaps are scaled by closure.
    * tolerance t (m): a gap residual r = clip(phi, -t w, t w), w = previous_contact, of a
      contact that persists is attributed to estimate errors, not to the body: the obstacle
      pose comes from noisy joint readings and is re-estimated every step (gripper jaws:
      0.14 mm rms jumps between steps, i.e. 14 mm/s if closed within one step), and a small
      tilt error of the body puts one vertex of an edge contact off the obstacle. Only
      closure * r is closed per step (Baumgarte-type stabilisation: the residual decays
      geometrically, no phi / dt velocity spike that the proposal would reject or that would
      make a penetrating particle pop off the obstacle); the rest phi - r, and the whole gap
      of a new contact (w = 0: an impact), is closed within the step as in the
      time-stepping model.
    """
    ph = np.asarray(phi, dtype=np.float64)
    inc = np.asarray(in_contact, dtype=bool)
    if not 0.0 < closure <= 1.0:
        msg = f"closure must be in (0, 1], got {closure}"
        raise ModelError(msg)
    if tolerance is None:
        if closure >= 1.0:
            return ph
        return np.asarray(np.where(inc & (ph > 0.0), closure * ph, ph), dtype=np.float64)
    if not tolerance >= 0.0:
        msg = f"tolerance must be >= 0 m or None, got {tolerance}"
        raise ModelError(msg)
    band = np.full_like(ph, tolerance)
    if previous_contact is not None:
        band = band * np.clip(np.asarray(previous_contact, dtype=np.float64), 0.0, 1.0)
    residual = np.clip(ph, -tolerance, band)
    return np.asarray(np.where(inc, ph - (1.0 - closure) * residual, ph), dtype=np.float64)
