"""Quasi-static planar pushing: ellipsoidal limit surface and motion cone (pusher-slider).

A slider resting on a table and pushed slowly moves quasi-statically: inertia is negligible,
the support friction balances the pusher's contact force at every instant, and the slider
stops as soon as the pusher stops or leaves. References: K. M. Lynch and M. T. Mason,
"Stable pushing: mechanics, controllability, and planning", IJRR 1996; F. R. Hogan and
A. Rodriguez, "Feedback control of the pusher-slider system", WAFR 2016.

Model (body frame of the slider: origin at its centre of mass = centre of pressure, SI units):

* Limit surface: the support friction wrench w = (f_x, f_y, m) at sliding lies on the
  ellipsoid (f_x^2 + f_y^2) / f_max^2 + m^2 / m_max^2 = 1 with f_max = mu_s m g and
  m_max = c f_max. The body twist V = (v_x, v_y, omega) is normal to it:
  V ∝ A w with A = diag(1, 1, 1 / c^2). c (m) follows from the pressure distribution;
  for uniform pressure c = (1/Area) integral |r| dA (`limit_surface_c`).
* Pusher contact: a point contact at p with unit normal n pointing into the slider and
  tangent t = (n_y, -n_x) (the contact frame of `dbcslam_core.geometry`), Coulomb friction
  mu_c. The contact point moves with u = J V, J = [[1, 0, -p_y], [0, 1, p_x]], and a contact
  force f gives u = K f with K = J A J^T (2 x 2, symmetric positive definite).
* Modes, given the pusher velocity v at the contact (body frame): separated when
  n . v <= 0 (the slider stays put); sticking when f = K^-1 v lies in the friction cone
  (n . f >= 0, |t . f| <= mu_c n . f): the slider moves with the pusher; otherwise sliding
  along the cone edge f = lambda (n + s mu_c t), s = sign(t . f_stick), with lambda fixed by
  the normal constraint n . (K f) = n . v. The mode label follows the project's convention
  (`contact_modes.Mode`): SLIDING_POS when the slider point's tangential velocity relative to
  the pusher, t . (u - v), is positive.

Everything is vectorised over any leading (particles, hypotheses, ...) axes.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from .contact_modes import Mode
from .errors import ModelError

__all__ = [
    "QuasiStaticMotion",
    "limit_surface_c",
    "pusher_contact",
    "quasi_static_motion",
    "rollout_push",
]

FloatArray = npt.NDArray[np.float64]
IntArray = npt.NDArray[np.int64]


def _polygon(vertices: npt.ArrayLike) -> FloatArray:
    v = np.asarray(vertices, dtype=np.float64)
    if v.ndim != 2 or v.shape[1] != 2 or v.shape[0] < 3 or not np.all(np.isfinite(v)):
        msg = f"a polygon needs >= 3 finite (x, y) vertices, got array of shape {v.shape}"
        raise ModelError(msg)
    area2 = float(np.sum(v[:, 0] * np.roll(v[:, 1], -1) - np.roll(v[:, 0], -1) * v[:, 1]))
    if abs(area2) < 1e-14:
        msg = "the polygon has zero area"
        raise ModelError(msg)
    return v if area2 > 0 else v[::-1].copy()  # counter-clockwise


def limit_surface_c(vertices: npt.ArrayLike, subdivisions: int = 32) -> float:
    """c = m_max / f_max (m) of a uniform pressure distribution over a polygon.

    c = (1/Area) integral over the polygon of |r| dA, r measured from the area centroid.
    The polygon is cut into triangles from its centroid, each into subdivisions^2 similar
    sub-triangles integrated at their centroids (relative error ~1e-4 at 32). Disc of
    radius R: 2R/3; square of side a: 0.3826 a.
    """
    v = _polygon(vertices)
    if subdivisions < 1:
        msg = f"subdivisions must be >= 1, got {subdivisions}"
        raise ModelError(msg)
    x, y = v[:, 0], v[:, 1]
    xn, yn = np.roll(x, -1), np.roll(y, -1)
    cross = x * yn - xn * y
    area = 0.5 * float(np.sum(cross))
    cx = float(np.sum((x + xn) * cross)) / (6.0 * area)
    cy = float(np.sum((y + yn) * cross)) / (6.0 * area)
    k = subdivisions
    # barycentric centroids of the k^2 sub-triangles of a reference triangle (upright and
    # inverted), each of area 1/k^2 of the triangle
    ii, jj = np.meshgrid(np.arange(k), np.arange(k), indexing="ij")
    up = (ii + jj) <= k - 1
    bu = np.stack([(ii + 1 / 3), (jj + 1 / 3)], axis=-1)[up] / k
    dn = (ii + jj) <= k - 2
    bd = np.stack([(ii + 2 / 3), (jj + 2 / 3)], axis=-1)[dn] / k
    bary = np.concatenate([bu, bd])  # (k^2, 2) weights of the two edge vectors
    total = 0.0
    for a, b in zip(v - (cx, cy), np.roll(v, -1, axis=0) - (cx, cy), strict=True):
        tri_area = 0.5 * abs(a[0] * b[1] - a[1] * b[0])
        pts = bary[:, :1] * a + bary[:, 1:] * b
        total += tri_area * float(np.mean(np.hypot(pts[:, 0], pts[:, 1])))
    return total / area


def pusher_contact(
    vertices: npt.ArrayLike, centre: npt.ArrayLike, radius: float
) -> tuple[FloatArray, FloatArray, FloatArray]:
    """Contact of a disk pusher with a convex polygon, both in the slider's body frame.

    centre (..., 2): pusher centre (m). Returns gap (...,) (m; negative when penetrating),
    point (..., 2) the closest point of the outline (m) and normal (..., 2) the unit normal
    pointing into the slider (from the pusher towards the outline; for a centre inside the
    outline, the inward normal of the nearest edge).
    """
    v = _polygon(vertices)
    c = np.asarray(centre, dtype=np.float64)
    a = v  # (E, 2) edge starts
    e = np.roll(v, -1, axis=0) - v  # (E, 2) edge vectors
    rel = c[..., None, :] - a  # (..., E, 2)
    s = np.clip(np.sum(rel * e, axis=-1) / np.sum(e * e, axis=-1), 0.0, 1.0)
    closest = a + s[..., None] * e  # (..., E, 2)
    d_vec = closest - c[..., None, :]
    dist = np.hypot(d_vec[..., 0], d_vec[..., 1])
    k = np.argmin(dist, axis=-1)[..., None]
    point = np.take_along_axis(closest, k[..., None], axis=-2)[..., 0, :]
    d = np.take_along_axis(dist, k, axis=-1)[..., 0]
    # inside a counter-clockwise polygon: left of every edge
    inside = np.all(e[..., 0] * rel[..., 1] - e[..., 1] * rel[..., 0] >= 0.0, axis=-1)
    edge_k = np.take_along_axis(np.broadcast_to(e, (*dist.shape, 2)), k[..., None], axis=-2)
    edge_k = edge_k[..., 0, :]
    inward = np.stack([-edge_k[..., 1], edge_k[..., 0]], axis=-1)
    inward = inward / np.hypot(inward[..., 0], inward[..., 1])[..., None]
    safe = np.maximum(d, 1e-12)[..., None]
    normal = np.where((inside | (d < 1e-12))[..., None], inward, (point - c) / safe)
    gap = np.where(inside, -d, d) - radius
    return gap, point, normal


@dataclass(frozen=True)
class QuasiStaticMotion:
    """Result of `quasi_static_motion` (leading axes of the inputs).

    twist (..., 3): body twist (v_x, v_y, omega) of the slider (m/s, rad/s, body frame).
    mode (...,): `Mode` of the pusher contact. force (..., 2): contact force on the slider in
    the body frame along the cone (N when f_max is given, else the unit-scale direction).
    """

    twist: FloatArray
    mode: IntArray
    force: FloatArray


def quasi_static_motion(
    point: npt.ArrayLike,
    normal: npt.ArrayLike,
    pusher_velocity: npt.ArrayLike,
    *,
    mu_c: npt.ArrayLike,
    c: npt.ArrayLike,
    f_max: npt.ArrayLike | None = None,
) -> QuasiStaticMotion:
    """Slider twist and contact mode for a pusher velocity (all body frame, SI units).

    point, normal, pusher_velocity (..., 2): contact point (m), unit normal into the slider,
    velocity of the pusher at the contact (m/s). mu_c, c, f_max broadcast over the leading
    axes: pusher-slider friction, limit-surface ratio m_max / f_max (m), and optionally
    f_max = mu_s m g (N) to scale the force onto the limit surface.
    """
    p = np.asarray(point, dtype=np.float64)
    n = np.asarray(normal, dtype=np.float64)
    vp = np.asarray(pusher_velocity, dtype=np.float64)
    mu = np.asarray(mu_c, dtype=np.float64)
    cc = np.asarray(c, dtype=np.float64)
    if np.any(cc <= 0.0) or np.any(mu < 0.0):
        msg = f"need c > 0 and mu_c >= 0, got c in [{cc.min()}, {cc.max()}], mu_c min {mu.min()}"
        raise ModelError(msg)
    t = np.stack([n[..., 1], -n[..., 0]], axis=-1)
    inv_c2 = 1.0 / (cc * cc)
    px, py = p[..., 0], p[..., 1]
    # K = J A J^T = I + (1/c^2) [[py^2, -px py], [-px py, px^2]]
    k11 = 1.0 + inv_c2 * py * py
    k12 = -inv_c2 * px * py
    k22 = 1.0 + inv_c2 * px * px
    det = k11 * k22 - k12 * k12  # >= 1: K is SPD
    fx = (k22 * vp[..., 0] - k12 * vp[..., 1]) / det
    fy = (k11 * vp[..., 1] - k12 * vp[..., 0]) / det
    f_stick = np.stack([fx, fy], axis=-1)
    fn = np.sum(f_stick * n, axis=-1)
    ft = np.sum(f_stick * t, axis=-1)
    vn = np.sum(vp * n, axis=-1)
    sticking = (vn > 0.0) & (np.abs(ft) <= mu * fn)
    side = np.where(ft >= 0.0, 1.0, -1.0)
    edge = n + (side * mu)[..., None] * t
    k_edge = np.stack(
        [k11 * edge[..., 0] + k12 * edge[..., 1], k12 * edge[..., 0] + k22 * edge[..., 1]],
        axis=-1,
    )
    lam = vn / np.maximum(np.sum(n * k_edge, axis=-1), 1e-300)
    f_slide = lam[..., None] * edge
    moving = vn > 0.0
    f = np.where(sticking[..., None], f_stick, f_slide)
    f = np.where(moving[..., None], f, 0.0)
    torque = px * f[..., 1] - py * f[..., 0]
    twist = np.stack([f[..., 0], f[..., 1], torque * inv_c2], axis=-1)
    u = np.stack([twist[..., 0] - py * twist[..., 2], twist[..., 1] + px * twist[..., 2]], axis=-1)
    vt_rel = np.sum((u - vp) * t, axis=-1)
    mode = np.where(
        ~moving,
        int(Mode.SEPARATED),
        np.where(
            sticking,
            int(Mode.STICKING),
            np.where(vt_rel > 0.0, int(Mode.SLIDING_POS), int(Mode.SLIDING_NEG)),
        ),
    ).astype(np.int64)
    force = f
    if f_max is not None:
        fm = np.asarray(f_max, dtype=np.float64)
        size = np.sqrt(f[..., 0] ** 2 + f[..., 1] ** 2 + (torque / cc) ** 2)
        force = f * np.where(size > 0.0, fm / np.maximum(size, 1e-300), 0.0)[..., None]
    return QuasiStaticMotion(twist=twist, mode=mode, force=force)


def rollout_push(
    vertices: npt.ArrayLike,
    pose0: npt.ArrayLike,
    tip: npt.ArrayLike,
    *,
    radius: float,
    dt: float,
    mu_c: npt.ArrayLike,
    c: npt.ArrayLike,
) -> tuple[FloatArray, IntArray]:
    """Open-loop quasi-static prediction of a push from the slider's start pose.

    vertices (V, 2) outline about the centre of mass (body frame, m); pose0 (3,) world
    [x, y, yaw]; tip (T, 2) measured pusher centre path (world, m), one sample every dt s.
    mu_c and c broadcast to a batch shape B (e.g. a grid of candidates). Returns poses
    (*B, T, 3) and modes (*B, T - 1) of the pusher contact per step.

    Each step the pusher moves from tip[k] to tip[k + 1]; the part of its normal motion
    beyond the current gap (n . v - gap / dt, if positive) is the velocity the slider's
    contact point must follow; the slider's twist from `quasi_static_motion` is integrated
    with the midpoint rule in yaw.
    """
    v = _polygon(vertices)
    path = np.asarray(tip, dtype=np.float64)
    if path.ndim != 2 or path.shape[1] != 2 or path.shape[0] < 2:
        msg = f"tip path must be (T >= 2, 2), got shape {path.shape}"
        raise ModelError(msg)
    if not dt > 0.0 or not math.isfinite(dt):
        msg = f"dt must be a positive number of seconds, got {dt}"
        raise ModelError(msg)
    mu = np.asarray(mu_c, dtype=np.float64)
    cc = np.asarray(c, dtype=np.float64)
    batch = np.broadcast_shapes(mu.shape, cc.shape)
    pose = np.broadcast_to(np.asarray(pose0, dtype=np.float64), (*batch, 3)).copy()
    n_t = path.shape[0]
    poses = np.empty((*batch, n_t, 3))
    modes = np.empty((*batch, n_t - 1), dtype=np.int64)
    poses[..., 0, :] = pose
    for k in range(n_t - 1):
        cy, sy = np.cos(pose[..., 2]), np.sin(pose[..., 2])
        rel = path[k] - pose[..., :2]
        centre = np.stack(
            [cy * rel[..., 0] + sy * rel[..., 1], -sy * rel[..., 0] + cy * rel[..., 1]], -1
        )
        vw = (path[k + 1] - path[k]) / dt
        vb = np.stack([cy * vw[0] + sy * vw[1], -sy * vw[0] + cy * vw[1]], axis=-1)
        gap, point, normal = pusher_contact(v, centre, radius)
        vn = np.sum(vb * normal, axis=-1)
        t = np.stack([normal[..., 1], -normal[..., 0]], axis=-1)
        vn_eff = vn - np.maximum(gap, 0.0) / dt  # first close the gap, then push
        v_eff = vn_eff[..., None] * normal + np.sum(vb * t, axis=-1)[..., None] * t
        motion = quasi_static_motion(point, normal, v_eff, mu_c=mu, c=cc)
        tw = np.where((vn_eff > 0.0)[..., None], motion.twist, 0.0)
        modes[..., k] = np.where(vn_eff > 0.0, motion.mode, int(Mode.SEPARATED))
        mid = pose[..., 2] + 0.5 * dt * tw[..., 2]
        cm, sm = np.cos(mid), np.sin(mid)
        pose[..., 0] += dt * (cm * tw[..., 0] - sm * tw[..., 1])
        pose[..., 1] += dt * (sm * tw[..., 0] + cm * tw[..., 1])
        pose[..., 2] += dt * tw[..., 2]
        poses[..., k + 1, :] = pose
    return poses, modes
