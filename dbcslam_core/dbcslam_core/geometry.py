"""Planar geometry: rotations, polygon mass properties and vectorised contact kinematics.

Frames: `world` (REP-103, x-y plane, yaw about +z counter-clockwise). Body coordinates are
about the centre of mass. Contact frame: normal n into the body's free side (from the
obstacle towards the body), tangent t = (n_y, -n_x).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from functools import lru_cache

import numpy as np
from numpy.typing import ArrayLike, NDArray

from .angles import wrap_angle
from .errors import ModelError
from .polygon import as_polygon, cross2, polygon_area, polygon_centroid, polygon_inertia
from .scenario import PRESSURE_MODELS, Disk, HalfSpace, Scenario

__all__ = [
    "ContactKinematics",
    "contact_coordinates",
    "contact_kinematics",
    "cross2",
    "polygon_area",
    "polygon_centroid",
    "polygon_inertia",
    "rot",
    "rotate",
    "support_points",
    "wrap_angle",
]

F64 = NDArray[np.float64]
I64 = NDArray[np.int64]


def rot(yaw: ArrayLike) -> F64:
    """Rotation matrices R(yaw) of shape (..., 2, 2) (rad, counter-clockwise)."""
    th = np.asarray(yaw, dtype=np.float64)
    c, s = np.cos(th), np.sin(th)
    return np.stack([np.stack([c, -s], -1), np.stack([s, c], -1)], -2)


def rotate(yaw: ArrayLike, p: ArrayLike) -> F64:
    """R(yaw) @ p for points p[..., 2], broadcasting yaw[...] against p[..., :]."""
    th = np.asarray(yaw, dtype=np.float64)
    pa = np.asarray(p, dtype=np.float64)
    c, s = np.cos(th), np.sin(th)
    x, y = pa[..., 0], pa[..., 1]
    return np.stack([c * x - s * y, s * x + c * y], -1)


def _subdivided_triangles(tris: F64, k: int) -> tuple[F64, F64]:
    """Centroids and areas of the k^2 congruent sub-triangles of each triangle (T, 3, 2)."""
    up = [(i + 1.0 / 3.0, j + 1.0 / 3.0) for i in range(k) for j in range(k - i)]
    down = [(i + 2.0 / 3.0, j + 2.0 / 3.0) for i in range(k - 1) for j in range(k - 1 - i)]
    bary = np.asarray(up + down, dtype=np.float64) / k  # (k^2, 2) coordinates along AB, AC
    a, b, c = tris[:, 0], tris[:, 1], tris[:, 2]
    pts = a[:, None] + bary[None, :, :1] * (b - a)[:, None] + bary[None, :, 1:] * (c - a)[:, None]
    area = 0.5 * cross2(b - a, c - a)
    w = np.repeat(area[:, None] / (k * k), k * k, axis=1)
    return pts.reshape(-1, 2), w.reshape(-1)


def _uniform_support(v: F64, target: int) -> tuple[F64, F64]:
    n = len(v)
    for apex in (np.zeros(2), v[0]):
        tris = np.stack([np.broadcast_to(apex, v.shape), v, np.roll(v, -1, axis=0)], axis=1)
        area = 0.5 * cross2(tris[:, 1] - tris[:, 0], tris[:, 2] - tris[:, 0])
        if np.all(area >= -1e-15 * np.max(np.abs(v)) ** 2):
            keep = area > 0.0
            k = max(1, round(math.sqrt(target / max(int(np.sum(keep)), 1))))
            return _subdivided_triangles(tris[keep], k)
    msg = (
        f"pressure 'uniform' needs an outline that is star-shaped about its centre of mass or "
        f"vertex 0 ({n} vertices given); use pressure 'rim', 'centre' or 'tripod'"
    )
    raise ModelError(msg)


def _rim_support(v: F64, target: int) -> tuple[F64, F64]:
    e = np.roll(v, -1, axis=0) - v
    length = np.linalg.norm(e, axis=1)
    per = float(np.sum(length))
    pts: list[F64] = []
    wts: list[F64] = []
    for a, d, ln_ in zip(v, e, length, strict=True):
        m = max(1, math.ceil(target * ln_ / per))
        f = (np.arange(m) + 0.5) / m
        pts.append(a + f[:, None] * d)
        wts.append(np.full(m, ln_ / m))
    return np.concatenate(pts), np.concatenate(wts)


def _tripod_support(v: F64) -> tuple[F64, F64]:
    e = np.roll(v, -1, axis=0) - v
    # distance from the origin to each edge line (inside: > 0 for a CCW outline)
    dist = cross2(e, -v) / np.linalg.norm(e, axis=1)
    r = 0.9 * float(np.min(dist))
    if r <= 0.0:
        msg = "pressure 'tripod' needs the centre of mass inside the outline"
        raise ModelError(msg)
    ang = np.pi / 2.0 + 2.0 * np.pi * np.arange(3) / 3.0
    return r * np.stack([np.cos(ang), np.sin(ang)], -1), np.full(3, 1.0)


@lru_cache(maxsize=64)
def _support_cached(
    verts: tuple[tuple[float, float], ...], pressure: str, target: int
) -> tuple[F64, F64]:
    v = np.asarray(verts, dtype=np.float64)
    if len(v) == 1 or pressure == "centre":
        p, w = np.zeros((1, 2)), np.ones(1)
    elif pressure == "uniform":
        p, w = _uniform_support(v, target)
    elif pressure == "rim":
        p, w = _rim_support(v, target)
    elif pressure == "vertices":
        p, w = v.copy(), np.ones(len(v))
    else:
        p, w = _tripod_support(v)
    w = w / np.sum(w)
    p = p - w @ p  # the pressure centre is the centre of mass (moment balance)
    p.setflags(write=False)
    w.setflags(write=False)
    return p, w


def support_points(
    vertices: Sequence[Sequence[float]] | ArrayLike,
    pressure: str = "uniform",
    *,
    rim_fraction: float | None = None,
    target: int = 96,
) -> tuple[F64, F64]:
    """Points (N, 2) (body frame, m) and weights (N,) (sum 1) carrying the support pressure.

    Point i carries the normal force w_i m g. pressure (one of `scenario.PRESSURE_MODELS`):
    ``uniform`` - the outline area, triangulated from the centre of mass (else from vertex 0)
    and each triangle cut into k^2 equal sub-triangles (their centroids, weights = areas;
    about `target` points); ``rim`` - the outline, each edge cut into pieces of about
    perimeter / target (midpoints, weights = lengths); ``vertices`` - the outline's vertices,
    equal weights (a block resting on its corners; pybullet's contact manifold of a box on a
    plane); ``centre`` - one point at the centre
    of mass (no rotational support friction); ``tripod`` - three equal points at 120 deg on
    a circle of 0.9 x the largest radius about the centre of mass that fits in the outline.
    rim_fraction in [0, 1] (the ``support_pressure`` effect): the weights are
    (1 - f) x ``uniform`` and f x ``rim`` instead. The points are shifted so that the
    pressure centre sum w_i p_i is the centre of mass (0, 0) exactly (static moment balance on
    a flat support). A point mass (no vertices) gets the single point (0, 0).
    """
    v = as_polygon(vertices) if np.size(vertices) else np.zeros((1, 2))
    if pressure not in PRESSURE_MODELS:
        msg = f"unknown pressure distribution {pressure!r}; valid are {list(PRESSURE_MODELS)}"
        raise ModelError(msg)
    key = tuple((float(x), float(y)) for x, y in v)
    if rim_fraction is None:
        return _support_cached(key, pressure, target)
    f = float(rim_fraction)
    if not 0.0 <= f <= 1.0:
        msg = f"rim_fraction must lie in [0, 1], got {rim_fraction}"
        raise ModelError(msg)
    pu, wu = _support_cached(key, "uniform", target)
    pr, wr = _support_cached(key, "rim", target)
    p = np.concatenate([pu, pr])
    w = np.concatenate([(1.0 - f) * wu, f * wr])
    keep = w > 0.0
    return p[keep], w[keep]


@dataclass(frozen=True)
class ContactKinematics:
    """Contact geometry of every potential contact (C) at leading shape `...`.

    phi[..., C]: signed gap (m, < 0 penetrating); Jn, Jt[..., C, nv]: normal / tangential
    Jacobian rows (gap rate = Jn v - vn_env, relative tangential velocity = Jt v - vt_env);
    vn_env, vt_env[..., C]: obstacle surface velocity along n / t (m/s); point[..., C, 2]:
    world contact point on the body (m); s[..., C]: contact coordinate along the obstacle
    tangent (half-space: t . point; disk: arc length along the body outline from vertex 0);
    normal[..., C, 2]: the unit contact normal (world).
    """

    phi: F64
    Jn: F64
    Jt: F64
    vn_env: F64
    vt_env: F64
    point: F64
    s: F64
    normal: F64


@dataclass(frozen=True)
class _Layout:
    # half-space contacts
    hs_idx: I64  # contact indices
    hs_r: F64  # (H, 2) body-frame point
    hs_n: F64  # (H, 2)
    hs_t: F64  # (H, 2) tangent (n_y, -n_x)
    hs_off: F64  # (H,)
    hs_sign: F64  # (H,)
    hs_joint: I64  # (H,) joint index, -1 static
    # disk contacts
    dk_idx: I64
    dk_radius: F64  # (D,)
    dk_jx: I64  # (D,)
    dk_jy: I64  # (D,)
    verts: F64  # (V, 2) body polygon (CCW) or empty
    perim0: F64  # (V,) arc length at each vertex
    hs_sel: slice | I64  # hs_idx / dk_idx as a slice when consecutive (basic indexing)
    dk_sel: slice | I64


@lru_cache(maxsize=64)
def _layout(scenario: Scenario) -> _Layout:
    joints = scenario.joints
    obst = scenario.obstacles
    verts = np.asarray(scenario.body.vertices, dtype=np.float64).reshape(-1, 2)
    hs: list[tuple[int, tuple[float, float], tuple[float, float], float, float, int]] = []
    dk: list[tuple[int, float, int, int]] = []
    for c, pc in enumerate(scenario.potential_contacts):
        o = obst[pc.obstacle]
        if isinstance(o, HalfSpace):
            r = (0.0, 0.0) if pc.feature == "origin" else tuple(verts[pc.vertex])
            j = -1 if o.joint is None else joints.index(o.joint)
            hs.append((c, (float(r[0]), float(r[1])), o.normal, o.offset, o.sign, j))
        elif isinstance(o, Disk):
            dk.append((c, o.radius, joints.index(o.joint_x), joints.index(o.joint_y)))
    perim0 = np.zeros(len(verts))
    if len(verts):
        seg = np.linalg.norm(np.roll(verts, -1, 0) - verts, axis=1)
        perim0 = np.concatenate([[0.0], np.cumsum(seg)[:-1]])
    hs_idx = np.array([h[0] for h in hs], dtype=np.int64)
    dk_idx = np.array([d[0] for d in dk], dtype=np.int64)
    return _Layout(
        hs_idx=hs_idx,
        hs_r=np.array([h[1] for h in hs], dtype=np.float64).reshape(-1, 2),
        hs_n=np.array([h[2] for h in hs], dtype=np.float64).reshape(-1, 2),
        hs_t=np.array([(h[2][1], -h[2][0]) for h in hs], dtype=np.float64).reshape(-1, 2),
        hs_off=np.array([h[3] for h in hs], dtype=np.float64),
        hs_sign=np.array([h[4] for h in hs], dtype=np.float64),
        hs_joint=np.array([h[5] for h in hs], dtype=np.int64),
        dk_idx=dk_idx,
        dk_radius=np.array([d[1] for d in dk], dtype=np.float64),
        dk_jx=np.array([d[2] for d in dk], dtype=np.int64),
        dk_jy=np.array([d[3] for d in dk], dtype=np.int64),
        verts=verts,
        perim0=perim0,
        hs_sel=_as_slice(hs_idx),
        dk_sel=_as_slice(dk_idx),
    )


def _as_slice(idx: I64) -> slice | I64:
    """A consecutive ascending index array as a slice (basic instead of fancy indexing)."""
    if idx.size and idx[-1] - idx[0] == idx.size - 1 and bool(np.all(np.diff(idx) == 1)):
        return slice(int(idx[0]), int(idx[-1]) + 1)
    return idx


def _joint_values(env: F64, jidx: NDArray[np.int64]) -> F64:
    """env[..., j] for each j (0 where j < 0)."""
    if env.shape[-1] == 0:
        return np.zeros((*env.shape[:-1], len(jidx)))
    vals = env[..., np.maximum(jidx, 0)]
    return np.where(jidx >= 0, vals, 0.0)


def contact_kinematics(
    scenario: Scenario,
    q: ArrayLike,
    env: ArrayLike | None = None,
    env_vel: ArrayLike | None = None,
) -> ContactKinematics:
    """Contact kinematics of all potential contacts, broadcasting over leading axes.

    q[..., nq] (x, y[, yaw]) in m, rad; env[..., E] joint positions (m) in the order of
    `scenario.joints`; env_vel[..., E] joint velocities (m/s). E may be 0 (edge scenario);
    env/env_vel default to zeros. Returns `ContactKinematics` with leading shape the
    broadcast of the three leading shapes.
    """
    qa, ea, ev = _kinematics_inputs(scenario, q, env, env_vel)
    lead = qa.shape[:-1]
    nq = scenario.nq
    n_c = scenario.n_contacts
    out = ContactKinematics(
        phi=np.empty((*lead, n_c)),
        Jn=np.zeros((*lead, n_c, nq)),
        Jt=np.zeros((*lead, n_c, nq)),
        vn_env=np.zeros((*lead, n_c)),
        vt_env=np.zeros((*lead, n_c)),
        point=np.empty((*lead, n_c, 2)),
        s=np.empty((*lead, n_c)),
        normal=np.empty((*lead, n_c, 2)),
    )
    lay = _layout(scenario)
    yaw = qa[..., 2] if nq == 3 else np.zeros(lead)
    if len(lay.hs_idx):
        _halfspace_contacts(out, lay, qa[..., None, 0:2], yaw, ea, ev, polygon=nq == 3)
    if len(lay.dk_idx):
        _disk_contacts(out, lay, qa[..., None, 0:2], yaw, ea, ev)
    return out


def _kinematics_inputs(
    scenario: Scenario, q: ArrayLike, env: ArrayLike | None, env_vel: ArrayLike | None
) -> tuple[F64, F64, F64]:
    """q broadcast to the common leading shape, env and env_vel (validated)."""
    nq = scenario.nq
    n_env = len(scenario.joints)
    qa = np.asarray(q, dtype=np.float64)
    if qa.ndim < 1 or qa.shape[-1] != nq:
        msg = f"q must have shape (..., {nq}) for scenario '{scenario.kind}', got {qa.shape}"
        raise ModelError(msg)
    ea = np.zeros(n_env) if env is None else np.asarray(env, dtype=np.float64)
    ev = np.zeros(n_env) if env_vel is None else np.asarray(env_vel, dtype=np.float64)
    for name, arr in (("env", ea), ("env_vel", ev)):
        if arr.ndim < 1 or arr.shape[-1] != n_env:
            msg = (
                f"{name} must have shape (..., {n_env}) (joints {list(scenario.joints)}), got "
                f"{arr.shape}"
            )
            raise ModelError(msg)
    lead = np.broadcast_shapes(qa.shape[:-1], ea.shape[:-1], ev.shape[:-1])
    if qa.shape[:-1] != lead:
        qa = np.broadcast_to(qa, (*lead, nq))
    # env / env_vel broadcast in the arithmetic and assignments of the callers
    return qa, ea, ev


def _halfspace_contacts(  # noqa: PLR0917 - the contact arrays and the state, unpacked
    out: ContactKinematics,
    lay: _Layout,
    pos: F64,
    yaw: F64,
    ea: F64,
    ev: F64,
    *,
    polygon: bool,
) -> None:
    """Fill the half-space (edge, jaw) contacts of `out`: pos (..., 1, 2) body position."""
    idx = lay.hs_sel
    jidx = lay.hs_joint
    # a point mass (nq = 2) has no orientation: its contact points are its origin
    r_w = rotate(yaw[..., None], lay.hs_r) if polygon else lay.hs_r  # (..., H, 2)
    p = pos + r_w
    n = lay.hs_n
    t = lay.hs_t
    d = lay.hs_off + lay.hs_sign * _joint_values(ea, jidx)
    out.phi[..., idx] = p[..., 0] * n[:, 0] + p[..., 1] * n[:, 1] - d  # = sum(p * n, -1) - d
    out.Jn[..., idx, :2] = n
    out.Jt[..., idx, :2] = t
    if polygon:
        out.Jn[..., idx, 2] = cross2(r_w, n)
        out.Jt[..., idx, 2] = cross2(r_w, t)
    out.vn_env[..., idx] = lay.hs_sign * _joint_values(ev, jidx)
    out.point[..., idx, :] = p
    out.s[..., idx] = p[..., 0] * t[:, 0] + p[..., 1] * t[:, 1]
    out.normal[..., idx, :] = n


def _disk_contacts(  # noqa: PLR0917 - the contact arrays and the state, unpacked
    out: ContactKinematics, lay: _Layout, pos: F64, yaw: F64, ea: F64, ev: F64
) -> None:
    """Fill the disk (pusher) contacts of `out`: the closest point of the body outline to
    the disk centre, normal from the pusher into the body (also with the centre inside)."""
    idx = lay.dk_sel
    jx = lay.dk_jx
    jy = lay.dk_jy
    centre = np.stack([ea[..., jx], ea[..., jy]], -1)  # (..., D, 2)
    cvel = np.stack([ev[..., jx], ev[..., jy]], -1)
    # centre in the body frame
    c_b = rotate(-yaw[..., None], centre - pos)  # (..., D, 2)
    v = lay.verts  # (V, 2)
    w = np.roll(v, -1, 0)
    e = w - v  # (V, 2)
    elen2 = np.sum(e * e, -1)
    rel = c_b[..., None, :] - v  # (..., D, V, 2)
    tt = np.clip(np.sum(rel * e, -1) / elen2, 0.0, 1.0)  # (..., D, V)
    cp = v + tt[..., None] * e  # closest point on each edge
    diff = c_b[..., None, :] - cp
    dist2 = np.sum(diff * diff, -1)
    k = np.argmin(dist2, -1)  # (..., D)
    cp_k = np.take_along_axis(cp, k[..., None, None], -2)[..., 0, :]
    dist = np.sqrt(np.take_along_axis(dist2, k[..., None], -1)[..., 0])
    inside = np.all(cross2(e, rel) >= 0.0, -1)  # CCW polygon
    out_n = np.stack([e[:, 1], -e[:, 0]], -1) / np.sqrt(elen2)[:, None]  # outward normals
    edge_out = out_n[k]  # (..., D, 2)
    tiny = dist < 1e-12
    safe = np.where(tiny, 1.0, dist)[..., None]
    # normal (body frame) from the pusher towards the body
    n_b = np.where(
        tiny[..., None],
        -edge_out,
        np.where(inside[..., None], 1.0, -1.0) * (c_b - cp_k) / safe,
    )
    sd = np.where(inside, -dist, dist)
    r_w = rotate(yaw[..., None], cp_k)
    n_w = rotate(yaw[..., None], n_b)
    t_w = np.stack([n_w[..., 1], -n_w[..., 0]], -1)
    out.phi[..., idx] = sd - lay.dk_radius
    out.Jn[..., idx, 0] = n_w[..., 0]
    out.Jn[..., idx, 1] = n_w[..., 1]
    out.Jt[..., idx, 0] = t_w[..., 0]
    out.Jt[..., idx, 1] = t_w[..., 1]
    out.Jn[..., idx, 2] = cross2(r_w, n_w)
    out.Jt[..., idx, 2] = cross2(r_w, t_w)
    out.vn_env[..., idx] = np.sum(cvel * n_w, -1)
    out.vt_env[..., idx] = np.sum(cvel * t_w, -1)
    out.point[..., idx, :] = pos + r_w
    ttk = np.take_along_axis(tt, k[..., None], -1)[..., 0]
    out.s[..., idx] = lay.perim0[k] + ttk * np.sqrt(elen2)[k]
    out.normal[..., idx, :] = n_w


def contact_coordinates(scenario: Scenario, q: ArrayLike, env: ArrayLike | None = None) -> F64:
    """The contact coordinates s (..., C) (m) of `contact_kinematics` alone.

    Same arguments, broadcasting and values as ``contact_kinematics(scenario, q, env).s``;
    for half-space contacts s = p . t depends on the pose only and is computed without the
    rest of the kinematics (disk contacts fall back to the full computation).
    """
    lay = _layout(scenario)
    if len(lay.dk_idx):
        return contact_kinematics(scenario, q, env).s
    nq = scenario.nq
    qa = np.asarray(q, dtype=np.float64)
    if qa.ndim < 1 or qa.shape[-1] != nq:
        msg = f"q must have shape (..., {nq}) for scenario '{scenario.kind}', got {qa.shape}"
        raise ModelError(msg)
    lead = qa.shape[:-1]
    if env is not None:
        ea = np.asarray(env, dtype=np.float64)
        if ea.ndim < 1 or ea.shape[-1] != len(scenario.joints):
            msg = (
                f"env must have shape (..., {len(scenario.joints)}) (joints "
                f"{list(scenario.joints)}), got {ea.shape}"
            )
            raise ModelError(msg)
        lead = np.broadcast_shapes(lead, ea.shape[:-1])
        if qa.shape[:-1] != lead:
            qa = np.broadcast_to(qa, (*lead, nq))
    s = np.empty((*lead, scenario.n_contacts))
    if len(lay.hs_idx):
        r_w = rotate(qa[..., 2, None], lay.hs_r) if nq == 3 else lay.hs_r
        p = qa[..., None, 0:2] + r_w
        t = lay.hs_t
        s[..., lay.hs_sel] = p[..., 0] * t[:, 0] + p[..., 1] * t[:, 1]
    return s
