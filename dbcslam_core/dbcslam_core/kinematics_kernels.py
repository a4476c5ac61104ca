"""Compiled contact kinematics of the filter's rows (numba): `geometry.contact_kinematics`
and `geometry.contact_coordinates` in one loop over the particles instead of ~40 small numpy
operations (rotations, gathers, the disk pusher's closest point on the body outline).

The numpy functions of `geometry` are the reference: the kernels here compute the same
expressions in the same order per element (no fused multiply-add, the sums of two products
started from +0.0 like numpy's reductions), and the cosines and sines of the yaw come from the
same numpy calls, so the outputs are equal bit for bit (`tests/core/test_kinematics_kernels.py`).
The compiled path covers the filter's case: q of shape (P, nq), env and env_vel of shape (E,),
(1, E) or (P, E); any other shape (and numba missing) takes the numpy function.

Frames and units as in `geometry` (world frame, SI: m, rad, m/s). No thread pool: the whole
kernel costs a few microseconds per hundred particles, less than handing ranges to threads.
"""

from __future__ import annotations

import numpy as np
import numpy.typing as npt
from numpy.typing import ArrayLike

from dbcslam_core import geometry, kernels
from dbcslam_core.geometry import ContactKinematics
from dbcslam_core.scenario import Scenario

__all__ = ["AVAILABLE", "contact_coordinates", "contact_kinematics", "warm_up"]

FloatArray = npt.NDArray[np.float64]
IntArray = npt.NDArray[np.int64]

AVAILABLE = kernels.AVAILABLE


def _halfspace_rows(  # noqa: PLR0917 - numba helper (inlined): positional arrays
    q: FloatArray,
    cos_yaw: FloatArray,
    sin_yaw: FloatArray,
    env: FloatArray,
    env_vel: FloatArray,
    hs_idx: IntArray,
    hs_geom: FloatArray,
    hs_joint: IntArray,
    polygon: bool,
    out: tuple[FloatArray, ...],
) -> None:
    """Half-space (edge, jaw) contacts of every row p of q (`geometry._halfspace_contacts`):
    hs_geom (H, 8) = body point r (2), normal n (2), tangent t (2), offset, sign; out as in
    `_kinematics_kernel` (unpacked once per call: per row it would cost reference counts)."""
    phi, jn, jt, vn_env, vt_env, point, s_out, normal = out
    for p in range(q.shape[0]):
        n_env = env.shape[1]
        pe = p if env.shape[0] > 1 else 0
        pv = p if env_vel.shape[0] > 1 else 0
        x = q[p, 0]
        y = q[p, 1]
        c = cos_yaw[p]
        s = sin_yaw[p]
        for h in range(hs_idx.shape[0]):
            ci = hs_idx[h]
            r0 = hs_geom[h, 0]
            r1 = hs_geom[h, 1]
            n0 = hs_geom[h, 2]
            n1 = hs_geom[h, 3]
            t0 = hs_geom[h, 4]
            t1 = hs_geom[h, 5]
            sign = hs_geom[h, 7]
            if polygon:
                rx = c * r0 - s * r1
                ry = s * r0 + c * r1
            else:
                rx = r0
                ry = r1
            px = x + rx
            py = y + ry
            j = hs_joint[h]
            jv = 0.0
            jvv = 0.0
            if j >= 0 and n_env > 0:
                jv = env[pe, j]
                jvv = env_vel[pv, j]
            d = hs_geom[h, 6] + sign * jv
            phi[p, ci] = px * n0 + py * n1 - d
            jn[p, ci, 0] = n0
            jn[p, ci, 1] = n1
            jt[p, ci, 0] = t0
            jt[p, ci, 1] = t1
            if polygon:
                jn[p, ci, 2] = rx * n1 - ry * n0
                jt[p, ci, 2] = rx * t1 - ry * t0
            vn_env[p, ci] = sign * jvv
            vt_env[p, ci] = 0.0
            point[p, ci, 0] = px
            point[p, ci, 1] = py
            s_out[p, ci] = px * t0 + py * t1
            normal[p, ci, 0] = n0
            normal[p, ci, 1] = n1


def _disk_rows(  # noqa: PLR0917 - numba helper (inlined): positional arrays
    q: FloatArray,
    trig: FloatArray,
    env: FloatArray,
    env_vel: FloatArray,
    dk_idx: IntArray,
    dk_radius: FloatArray,
    dk_joints: IntArray,
    verts: FloatArray,
    perim0: FloatArray,
    out: tuple[FloatArray, ...],
) -> None:
    """Disk (pusher) contacts of every row p of q (`geometry._disk_contacts`): the closest
    point of the body outline (verts (V, 2), CCW, body frame) to the disk centre, the normal
    from the pusher into the body (also with the centre inside). trig (4, P): cos yaw, sin yaw,
    cos(-yaw), sin(-yaw); dk_joints (D, 2): the joints of the centre's x and y; out as in
    `_kinematics_kernel`."""
    phi, jn, jt, vn_env, vt_env, point, s_out, normal = out
    for p in range(q.shape[0]):
        n_v = verts.shape[0]
        pe = p if env.shape[0] > 1 else 0
        pv = p if env_vel.shape[0] > 1 else 0
        x = q[p, 0]
        y = q[p, 1]
        c = trig[0, p]
        s = trig[1, p]
        cm = trig[2, p]
        sm = trig[3, p]
        for dd in range(dk_idx.shape[0]):
            ci = dk_idx[dd]
            jx = dk_joints[dd, 0]
            jy = dk_joints[dd, 1]
            dx = env[pe, jx] - x
            dy = env[pe, jy] - y
            cvx = env_vel[pv, jx]
            cvy = env_vel[pv, jy]
            # centre in the body frame
            cbx = cm * dx - sm * dy
            cby = sm * dx + cm * dy
            k = 0
            best = 0.0
            inside = True
            tt_k = 0.0
            cpx_k = 0.0
            cpy_k = 0.0
            for i in range(n_v):
                vx = verts[i, 0]
                vy = verts[i, 1]
                i1 = i + 1 if i + 1 < n_v else 0
                ex = verts[i1, 0] - vx
                ey = verts[i1, 1] - vy
                elen2 = 0.0 + ex * ex + ey * ey
                relx = cbx - vx
                rely = cby - vy
                tt = (0.0 + relx * ex + rely * ey) / elen2
                if tt < 0.0:  # np.clip(., 0, 1) (NaN kept)
                    tt = 0.0
                elif tt > 1.0:
                    tt = 1.0
                cpx = vx + tt * ex
                cpy = vy + tt * ey
                dfx = cbx - cpx
                dfy = cby - cpy
                d2 = 0.0 + dfx * dfx + dfy * dfy
                # np.argmin: the first minimum, a NaN counts as the minimum
                if i == 0 or (not np.isnan(best) and (d2 < best or np.isnan(d2))):
                    k = i
                    best = d2
                    tt_k = tt
                    cpx_k = cpx
                    cpy_k = cpy
                if not ex * rely - ey * relx >= 0.0:
                    inside = False
            k1 = k + 1 if k + 1 < n_v else 0
            ekx = verts[k1, 0] - verts[k, 0]
            eky = verts[k1, 1] - verts[k, 1]
            elen = np.sqrt(0.0 + ekx * ekx + eky * eky)
            dist = np.sqrt(best)
            # normal (body frame) from the pusher towards the body
            if dist < 1e-12:
                nbx = -(eky / elen)
                nby = -(-ekx / elen)
            else:
                sgn = 1.0 if inside else -1.0
                nbx = sgn * (cbx - cpx_k) / dist
                nby = sgn * (cby - cpy_k) / dist
            sd = -dist if inside else dist
            rwx = c * cpx_k - s * cpy_k
            rwy = s * cpx_k + c * cpy_k
            nwx = c * nbx - s * nby
            nwy = s * nbx + c * nby
            twx = nwy
            twy = -nwx
            phi[p, ci] = sd - dk_radius[dd]
            jn[p, ci, 0] = nwx
            jn[p, ci, 1] = nwy
            jn[p, ci, 2] = rwx * nwy - rwy * nwx
            jt[p, ci, 0] = twx
            jt[p, ci, 1] = twy
            jt[p, ci, 2] = rwx * twy - rwy * twx
            vn_env[p, ci] = 0.0 + cvx * nwx + cvy * nwy
            vt_env[p, ci] = 0.0 + cvx * twx + cvy * twy
            point[p, ci, 0] = x + rwx
            point[p, ci, 1] = y + rwy
            s_out[p, ci] = perim0[k] + tt_k * elen
            normal[p, ci, 0] = nwx
            normal[p, ci, 1] = nwy


def _kinematics_kernel(  # noqa: PLR0917 - numba entry point: positional arrays
    q: FloatArray,
    trig: FloatArray,
    env: FloatArray,
    env_vel: FloatArray,
    hs_idx: IntArray,
    hs_geom: FloatArray,
    hs_joint: IntArray,
    polygon: bool,
    dk_idx: IntArray,
    dk_radius: FloatArray,
    dk_joints: IntArray,
    verts: FloatArray,
    perim0: FloatArray,
    phi: FloatArray,
    jn: FloatArray,
    jt: FloatArray,
    vn_env: FloatArray,
    vt_env: FloatArray,
    point: FloatArray,
    s_out: FloatArray,
    normal: FloatArray,
) -> None:
    """Every potential contact of every row p of q (P, nq) into the fields of
    `ContactKinematics`: phi, vn_env, vt_env, s_out (P, C); jn, jt (P, C, nq) (zeros on
    entry); point, normal (P, C, 2). env, env_vel (1 or P, E); trig (4, P) = cos, sin of yaw
    and of -yaw (numpy's values). Half-space contacts: hs_idx (H,) with hs_geom (H, 8) = r,
    n, t, offset, sign and hs_joint (H,) (-1 static); disk contacts: dk_idx (D,), dk_radius
    (D,), dk_joints (D, 2), outline verts (V, 2) and its arc length at each vertex perim0
    (V,)."""
    out = (phi, jn, jt, vn_env, vt_env, point, s_out, normal)
    n_h = hs_idx.shape[0]
    n_d = dk_idx.shape[0]
    if n_h:
        _halfspace_rows(q, trig[0], trig[1], env, env_vel, hs_idx, hs_geom, hs_joint, polygon, out)
    if n_d:
        _disk_rows(q, trig, env, env_vel, dk_idx, dk_radius, dk_joints, verts, perim0, out)


def _coordinates_kernel(  # noqa: PLR0917 - numba entry point: positional arrays
    q: FloatArray,
    trig: FloatArray,
    hs_idx: IntArray,
    hs_geom: FloatArray,
    polygon: bool,
    s_out: FloatArray,
) -> None:
    """s (P, C) of the half-space contacts alone (`geometry.contact_coordinates`): s = p . t
    with p the world contact point; trig (2, P) = cos, sin of yaw."""
    for p in range(q.shape[0]):
        x = q[p, 0]
        y = q[p, 1]
        c = trig[0, p]
        s = trig[1, p]
        for h in range(hs_idx.shape[0]):
            r0 = hs_geom[h, 0]
            r1 = hs_geom[h, 1]
            if polygon:
                px = x + (c * r0 - s * r1)
                py = y + (s * r0 + c * r1)
            else:
                px = x + r0
                py = y + r1
            s_out[p, hs_idx[h]] = px * hs_geom[h, 4] + py * hs_geom[h, 5]


if AVAILABLE:
    import numba

    _halfspace_rows = numba.njit(cache=True, nogil=True, inline="always")(_halfspace_rows)
    _disk_rows = numba.njit(cache=True, nogil=True, inline="always")(_disk_rows)
    _kinematics_kernel = numba.njit(cache=True, nogil=True)(_kinematics_kernel)
    _coordinates_kernel = numba.njit(cache=True, nogil=True)(_coordinates_kernel)


class _Packed:
    """The kernels' layout arrays of a scenario (contiguous, one dtype each, so that every
    scenario kind runs the same compiled specialisation)."""

    def __init__(self, scenario: Scenario) -> None:
        lay = geometry._layout(scenario)
        self.nq = scenario.nq
        self.n_c = scenario.n_contacts
        self.n_env = len(scenario.joints)
        self.polygon = scenario.nq == 3
        self.hs_idx = np.ascontiguousarray(lay.hs_idx, dtype=np.int64)
        self.hs_geom = np.ascontiguousarray(
            np.concatenate(
                [lay.hs_r, lay.hs_n, lay.hs_t, lay.hs_off[:, None], lay.hs_sign[:, None]], axis=1
            ),
            dtype=np.float64,
        ).reshape(-1, 8)
        self.hs_joint = np.ascontiguousarray(lay.hs_joint, dtype=np.int64)
        self.dk_idx = np.ascontiguousarray(lay.dk_idx, dtype=np.int64)
        self.dk_radius = np.ascontiguousarray(lay.dk_radius, dtype=np.float64)
        self.dk_joints = np.ascontiguousarray(
            np.stack([lay.dk_jx, lay.dk_jy], axis=1), dtype=np.int64
        ).reshape(-1, 2)
        self.verts = np.ascontiguousarray(lay.verts, dtype=np.float64).reshape(-1, 2)
        self.perim0 = np.ascontiguousarray(lay.perim0, dtype=np.float64)
        # the compiled disk code reads joints and writes the yaw column (numpy: the same)
        self.disk_ok = self.dk_idx.size == 0 or (self.nq == 3 and self.verts.shape[0] > 0)


_PACKED: dict[Scenario, _Packed] = {}


def _packed(scenario: Scenario) -> _Packed:
    pk = _PACKED.get(scenario)
    if pk is None:
        if len(_PACKED) >= 64:  # as geometry._layout's cache
            _PACKED.clear()
        pk = _PACKED[scenario] = _Packed(scenario)
    return pk


def _rows_2d(arr: FloatArray, n_rows: int) -> FloatArray | None:
    """arr (E,), (1, E) or (n_rows, E) as a contiguous (1 or n_rows, E) array; None for any
    other shape (the caller takes the numpy path)."""
    if arr.ndim == 1:
        return np.ascontiguousarray(arr.reshape(1, -1))
    if arr.ndim == 2 and arr.shape[0] in {1, n_rows}:
        return np.ascontiguousarray(arr)
    return None


def contact_kinematics(
    scenario: Scenario,
    q: ArrayLike,
    env: ArrayLike | None = None,
    env_vel: ArrayLike | None = None,
) -> ContactKinematics:
    """`geometry.contact_kinematics`, compiled for q (P, nq) and env, env_vel (E,), (1, E) or
    (P, E) (the same arguments, validation and values, bit for bit); the numpy function for
    any other shape or without numba."""
    if not AVAILABLE:
        return geometry.contact_kinematics(scenario, q, env, env_vel)
    qa, ea, ev = geometry._kinematics_inputs(scenario, q, env, env_vel)
    pk = _packed(scenario)
    if qa.ndim != 2 or not pk.disk_ok:
        return geometry.contact_kinematics(scenario, qa, ea, ev)
    n_p = qa.shape[0]
    e2 = _rows_2d(ea, n_p)
    v2 = _rows_2d(ev, n_p)
    if e2 is None or v2 is None:
        return geometry.contact_kinematics(scenario, qa, ea, ev)
    n_c = pk.n_c
    nq = pk.nq
    out = ContactKinematics(
        phi=np.empty((n_p, n_c)),
        Jn=np.zeros((n_p, n_c, nq)),
        Jt=np.zeros((n_p, n_c, nq)),
        vn_env=np.empty((n_p, n_c)),
        vt_env=np.empty((n_p, n_c)),
        point=np.empty((n_p, n_c, 2)),
        s=np.empty((n_p, n_c)),
        normal=np.empty((n_p, n_c, 2)),
    )
    trig = np.empty((4, n_p))
    if pk.polygon:
        yaw = qa[..., 2]  # the reference's cos / sin calls on the same (strided) view
        trig[0] = np.cos(yaw)
        trig[1] = np.sin(yaw)
        if pk.dk_idx.size:
            neg = -yaw
            trig[2] = np.cos(neg)
            trig[3] = np.sin(neg)
        else:
            trig[2:] = 0.0
    else:  # a point mass: no rotation (the disk path needs nq = 3: `disk_ok`)
        trig[0] = 1.0
        trig[1:] = 0.0
    _kinematics_kernel(
        np.ascontiguousarray(qa),
        trig,
        e2,
        v2,
        pk.hs_idx,
        pk.hs_geom,
        pk.hs_joint,
        pk.polygon,
        pk.dk_idx,
        pk.dk_radius,
        pk.dk_joints,
        pk.verts,
        pk.perim0,
        out.phi,
        out.Jn,
        out.Jt,
        out.vn_env,
        out.vt_env,
        out.point,
        out.s,
        out.normal,
    )
    return out


def contact_coordinates(
    scenario: Scenario, q: ArrayLike, env: ArrayLike | None = None
) -> FloatArray:
    """`geometry.contact_coordinates`, compiled for q (P, nq) and env None, (E,), (1, E) or
    (P, E) (the same values, bit for bit); the numpy function otherwise."""
    pk = _packed(scenario) if AVAILABLE else None
    if pk is None:
        return geometry.contact_coordinates(scenario, q, env)
    if pk.dk_idx.size:  # as the reference: the full kinematics
        return contact_kinematics(scenario, q, env).s
    qa = np.asarray(q, dtype=np.float64)
    if qa.ndim != 2 or qa.shape[1] != pk.nq:
        return geometry.contact_coordinates(scenario, q, env)
    if env is not None:
        ea = np.asarray(env, dtype=np.float64)
        if not (
            ea.shape[-1:] == (pk.n_env,)
            and (ea.ndim == 1 or (ea.ndim == 2 and ea.shape[0] == qa.shape[0]))
        ):
            return geometry.contact_coordinates(scenario, q, env)
    n_p = qa.shape[0]
    trig = np.empty((2, n_p))
    if pk.polygon:
        yaw = qa[..., 2]
        trig[0] = np.cos(yaw)
        trig[1] = np.sin(yaw)
    else:
        trig[0] = 1.0
        trig[1] = 0.0
    s = np.empty((n_p, pk.n_c))
    _coordinates_kernel(np.ascontiguousarray(qa), trig, pk.hs_idx, pk.hs_geom, pk.polygon, s)
    return s


def warm_up(scenario: Scenario) -> None:
    """Load (or compile) the kernels `contact_kinematics` and `contact_coordinates` run for
    `scenario`, on one particle at the origin with the joints at zero."""
    if not AVAILABLE:
        return
    q = np.zeros((1, scenario.nq))
    env = np.zeros(len(scenario.joints))
    contact_kinematics(scenario, q, env, env)
    contact_coordinates(scenario, q, env)
