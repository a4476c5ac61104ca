"""Likelihood of a measured contact force (e.g. the pusher's F/T reading, `/pusher/wrench`).

The filter predicts, per (particle, joint mode hypothesis, friction hypothesis), the contact
impulses of the reduced dynamics; the force one obstacle exerts on the body over the step is
minus the sum of those impulses along the contact frames, divided by the step length. This
module turns that prediction and a reading into a log-likelihood.

Frames and units: world frame (REP-103), forces in N, impulses in N s, time in s.
"""

from __future__ import annotations

import math

import numpy as np
import numpy.typing as npt

from dbcslam_core.observation import gaussian_log_density

__all__ = ["FORCE_AXES", "force_log_likelihood", "predicted_force"]

FloatArray = npt.NDArray[np.float64]

#: Which components of a reading enter the likelihood: the component along the (mean)
#: contact normal only, or both planar components.
FORCE_AXES = ("normal", "both")


def predicted_force(
    normal: FloatArray, ln: FloatArray, lt: FloatArray, dt: float
) -> tuple[FloatArray, FloatArray]:
    """Force (N) the obstacle exerts on the body, and the tangent directions.

    normal: (N, 1, Cs, 2) contact normals of the obstacle's contacts (into the body, world
    frame); ln, lt: (N, B, Cs) normal / tangential impulses (N s); dt: step (s).
    Returns (f_pred (N, B, 2), tangent (N, 1, Cs, 2)).
    """
    t = np.stack([normal[..., 1], -normal[..., 0]], axis=-1)
    f_pred = -np.sum(normal * ln[..., None] + t * lt[..., None], axis=-2) / dt
    return np.asarray(f_pred), np.asarray(t)


def force_log_likelihood(
    reading: npt.ArrayLike,
    std: float,
    normal: FloatArray,
    ln: FloatArray,
    lt: FloatArray,
    *,
    dt: float,
    impulse_response: FloatArray | None = None,
    sig2: FloatArray | None = None,
    axes: str = "normal",
) -> FloatArray:
    """log N(f; f_hb, std^2 I + G diag(sig2) G^T), shape (N, B), of a force reading.

    reading: measured force (fx, fy) (N, world frame) the obstacle exerts on the body;
    std: reading noise std (N); normal (N, 1, Cs, 2): the obstacle's contact normals (into
    the body); ln, lt (N, B, Cs): the hypotheses' impulses (N s); dt: step (s).
    impulse_response (N, B, 2, Cs, nv) = d (ln, lt) / d v_free and sig2 (nv,) the velocity
    process-noise variances: G = d f_hb / d v_free. The process noise is force noise on the
    body, which the obstacle's impulses absorb in constrained directions, so it widens the
    predicted force (std^2 alone would make the reading over-confident about hypotheses whose
    velocity is off by the process noise). axes: "normal" (component along the mean contact
    normal only) or "both".
    """
    if axes not in FORCE_AXES:
        msg = f"force axes must be one of {FORCE_AXES}, got {axes!r}"
        raise ValueError(msg)
    f_pred, t = predicted_force(normal, ln, lt, dt)
    r = np.asarray(reading, dtype=float) - f_pred
    cov = np.broadcast_to(std * std * np.eye(2), (*r.shape[:-1], 2, 2))
    if impulse_response is not None and sig2 is not None:
        dln = impulse_response[..., 0, :, :]  # (N, B, Cs, nv)
        dlt = impulse_response[..., 1, :, :]
        g = -np.einsum("nacx,nbcv->nbxv", normal, dln) - np.einsum("nacx,nbcv->nbxv", t, dlt)
        g = g / dt  # (N, B, 2, nv)
        cov = cov + (g * sig2) @ np.swapaxes(g, -1, -2)
    if axes == "normal":
        nb = np.sum(normal, axis=-2)  # (N, 1, 2)
        nb = nb / np.maximum(np.linalg.norm(nb, axis=-1, keepdims=True), 1e-12)
        rn = np.sum(r * nb, axis=-1)
        nbb = np.broadcast_to(nb, r.shape)
        vn = np.einsum("nbx,nbxy,nby->nb", nbb, cov, nbb)
        return np.asarray(-0.5 * (rn * rn / vn + np.log(2.0 * math.pi * vn)))
    return gaussian_log_density(r, cov)
