"""Compiled phases 4-6 of the filter step (numba): hypothesis dynamics, optimal proposal and
closed-form discrete posterior, one loop over the live (particle, joint mode hypothesis)
entries instead of ~100 numpy passes over padded (particles x hypotheses x friction) arrays.

The numpy path of `rbpf.DbcSlamFilter` (`_hypothesis_dynamics`, `_propose`,
`_discrete_posterior`) is the reference; these kernels compute the same equations in the
same order per element (values equal to round-off, `tests/core/test_step_kernels.py`):

* `entry_dynamics`: per live entry n (row pi[n] of the state arrays, modes md[n]) and
  friction hypothesis f: the contact gap the entry closes (`transition.contact_gap`), the
  reduced dynamics (`kernels._kernel`, the same loop, with the row's kinematics read in place
  instead of gathered per entry), the log prior sum_c log_pred[p, f, c, mode_c], the
  discrete proposal weight log alpha = log fric[p, f] + l - lse_k(l), l = log prior - score / 2,
  and the velocity noise covariance R diag(sig2) R^T + constrained_noise diag(sig2).
* `propose_rows`: per row p: the Kalman-form proposal of every entry x friction
  (`kernels._gaussian_kernel`), the evidence lse(log alpha + log p(o)), one (entry,
  friction) drawn by Gumbel-max (uniforms from the caller), v' and the position noise
  from its Gaussian (standard normals drawn by the caller), then the discrete posterior given
  v': friction (R, F), per-contact mode marginals given f (R, F, C, 4) and overall (R, C, 4),
  and P(pair in contact) (R, pairs).

Entries of a row are contiguous: starts[p] .. starts[p + 1] (R + 1,). Units as in
`contact_modes.solve_reduced` and `observation.gaussian_proposal` (SI, world frame).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import TYPE_CHECKING, Any, TypeVar

import numpy as np
import numpy.typing as npt

from dbcslam_core import kernels
from dbcslam_core.errors import ModelError, SolverError
from dbcslam_core.row_pool import RowPool

if TYPE_CHECKING:
    from dbcslam_core.dynamics import PlanarModel

__all__ = [
    "AVAILABLE",
    "entry_dynamics",
    "map_pending",
    "predict_modes",
    "propose_rows",
    "support_terms",
]

FloatArray = npt.NDArray[np.float64]
IntArray = npt.NDArray[np.int64]
BoolArray = npt.NDArray[np.bool_]
T = TypeVar("T")

AVAILABLE = kernels.AVAILABLE

_SEP, _STICK, _POS, _NEG = 0, 1, 2, 3
_LOG_2PI = math.log(2.0 * math.pi)


def _row_mw(  # noqa: PLR0917 - numba helper: positional arrays
    p: int,
    jn: FloatArray,
    jt: FloatArray,
    minv: FloatArray,
    mass: FloatArray,
    has_mass: bool,
    mw: FloatArray,
    lu: FloatArray,
    rhs_m: FloatArray,
) -> int:
    """M^-1 [Jn; Jt]^T rows of row p into mw (F, 2C, nv) (one per friction hypothesis with
    a mass per (row, f), else mw[0]); returns the number of singular mass matrices."""
    n_c = jn.shape[1]
    nv = jn.shape[2]
    n_bad = 0
    if has_mass:
        for f in range(mass.shape[1]):
            for i in range(nv):
                for j in range(nv):
                    lu[i, j] = mass[p, f, i, j]
                for c in range(n_c):
                    rhs_m[i, c] = jn[p, c, i]
                    rhs_m[i, n_c + c] = jt[p, c, i]
            if not kernels._lu_solve_inplace(lu, rhs_m, nv, 2 * n_c):
                n_bad += 1
            for c in range(2 * n_c):
                for i in range(nv):
                    mw[f, c, i] = rhs_m[i, c]
    else:
        for c in range(n_c):
            for i in range(nv):
                mw[0, c, i] = jn[p, c, i] * minv[i]
                mw[0, n_c + c, i] = jt[p, c, i] * minv[i]
    return n_bad


def _entry_gap(  # noqa: PLR0917 - numba helper
    phi: float, in_contact: bool, closure: float, tolerance: float, has_prev: bool, prev: float
) -> float:
    """`transition.contact_gap` of one contact (tolerance < 0: None; has_prev False: no
    previous contact probability)."""
    if tolerance < 0.0:
        if closure >= 1.0:
            return phi
        if in_contact and phi > 0.0:
            return closure * phi
        return phi
    band = tolerance
    if has_prev:
        band = tolerance * min(max(prev, 0.0), 1.0)
    residual = min(max(phi, -tolerance), band)
    if in_contact:
        return phi - (1.0 - closure) * residual
    return phi


def _entry_kernel_for(nv_const: int) -> Callable[..., int]:
    """The entry kernel for velocity dimension nv_const (0: any, read from the arrays). A
    constant nv lets the compiler unroll every loop over the velocity dims: the gripper's
    heaviest step (14,764 live entries) 10.3 -> 7.4 ms on one thread, the same values bit
    for bit. One cached machine code per constant (numba keys its cache on the closure)."""

    def _entry_kernel(  # noqa: PLR0917 - numba entry point, mirrors kernels._kernel
        starts: IntArray,
        md: IntArray,
        jn: FloatArray,
        jt: FloatArray,
        phi_row: FloatArray,
        vne: FloatArray,
        vte: FloatArray,
        vf: FloatArray,
        minv: FloatArray,
        mass: FloatArray,
        has_mass: bool,
        mu_tab: FloatArray,
        row_b: IntArray,
        group: IntArray,
        n_groups: int,
        params: FloatArray,
        prev_in: FloatArray,
        has_prev: bool,
        sensitivity: bool,
        log_pred: FloatArray,
        fric: FloatArray,
        sig2: FloatArray,
        v_next: FloatArray,
        ln: FloatArray,
        lt: FloatArray,
        score: FloatArray,
        resp: FloatArray,
        irs: FloatArray,
        cov: FloatArray,
        log_alpha: FloatArray,
        n_max: int,
        lo: int,
        hi: int,
    ) -> int:
        """Fill the per-(entry, friction) outputs of rows lo .. hi - 1; returns the number of
        singular systems.

        params = (dt, eps_rel, impulse scale, velocity scale, impulse floor, gap closure, gap
        tolerance (< 0: None), constrained noise). vf (R, Fv, nv) with Fv in (1, F): with Fv = F
        or a mass per (row, f) the geometry differs per f (no sharing of friction-free solves).
        n_max: the most active contacts of any entry (of all rows: the regularisation of
        `kernels._kernel` depends on it). The steps within an element are those of
        `kernels._kernel`.
        """
        # Long because: one fused loop over the entries keeps the per-entry temporaries in
        # registers; the same steps split into inlined helpers (row set-up, modes and gaps,
        # assembly, solve, score, noise and prior, normalisation) measured 1.5x slower (4.1 ->
        # 6.1 ms per gripper step at 1000 particles, CPU time, min of 40). The steps are marked.
        dt, eps_rel, sc_impulse, sc_velocity, sc_floor = (
            params[0],
            params[1],
            params[2],
            params[3],
            params[4],
        )
        closure, tolerance, c_noise = params[5], params[6], params[7]
        n_c = md.shape[1]
        nv = nv_const if nv_const > 0 else jn.shape[2]
        n_f = log_alpha.shape[1]
        two_c = 2 * n_c
        shared = (not has_mass) and vf.shape[1] == 1
        mw = np.empty((mass.shape[1] if has_mass else 1, two_c, nv))
        lu = np.empty((nv, nv))
        rhs_m = np.empty((nv, two_c))
        rows = np.empty(two_c, dtype=np.int64)
        grow = np.empty((two_c, nv))
        frow = np.empty((two_c, nv))
        amat = np.empty((two_c, two_c))
        x = np.empty((two_c, 1 + nv))
        cpl = np.zeros(n_c)
        lt_g = np.zeros(max(n_groups, 1))
        cap_g = np.zeros(max(n_groups, 1))
        mag_g = np.zeros(max(n_groups, 1))
        an = np.empty(n_c)
        at = np.empty(n_c)
        phd = np.empty(n_c)
        phd_row = np.empty(n_c)
        n_fv = vf.shape[1]
        n_fm = mw.shape[0]
        base_n = np.empty((n_fv, n_c))  # Jn v_free - vn_env per contact (the row's)
        base_t = np.empty((n_fv, n_c))
        dg = np.empty((n_fm, n_c))  # Delassus diagonal (normal + tangent) per contact
        n_bad = 0
        for p in range(lo, hi):
            if starts[p + 1] == starts[p]:
                continue
            n_bad += _row_mw(p, jn, jt, minv, mass, has_mass, mw, lu, rhs_m)
            for fv in range(n_fv):
                for c in range(n_c):
                    sn = 0.0
                    st = 0.0
                    for i in range(nv):
                        sn += jn[p, c, i] * vf[p, fv, i]
                        st += jt[p, c, i] * vf[p, fv, i]
                    base_n[fv, c] = sn - vne[p, c]
                    base_t[fv, c] = st - vte[p, c]
            for c in range(n_c):
                phd_row[c] = phi_row[p, c] / dt
            for fm in range(n_fm):
                for c in range(n_c):
                    d = 0.0
                    for i in range(nv):
                        d += jn[p, c, i] * mw[fm, c, i] + jt[p, c, i] * mw[fm, n_c + c, i]
                    dg[fm, c] = d
            for n in range(starts[p], starts[p + 1]):
                n_act = 0
                n_stick = 0
                slides = False
                for c in range(n_c):
                    mc = md[n, c]
                    if mc != _SEP:
                        n_act += 1
                    if mc == _STICK:
                        n_stick += 1
                    if mc >= _POS:
                        slides = True
                    if mc == _SEP:  # (the gap of a separated contact is not changed)
                        phd[c] = phd_row[c]
                    else:
                        prev = prev_in[p, c] if has_prev else 1.0
                        phd[c] = (
                            _entry_gap(phi_row[p, c], True, closure, tolerance, has_prev, prev)
                            / dt
                        )
                u_row = row_b[p]
                for f in range(n_f):
                    fv = f if vf.shape[1] > 1 else 0
                    fm = f if has_mass else 0
                    u = u_row if u_row >= 0 else f
                    if f > 0 and shared and not slides:
                        for c in range(n_c):
                            ln[n, f, c] = ln[n, 0, c]
                            lt[n, f, c] = lt[n, 0, c]
                        for i in range(nv):
                            v_next[n, f, i] = v_next[n, 0, i]
                            for j in range(nv):
                                resp[n, f, i, j] = resp[n, 0, i, j]
                        if sensitivity:
                            for k in range(2):
                                for c in range(n_c):
                                    for i in range(nv):
                                        irs[n, f, k, c, i] = irs[n, 0, k, c, i]
                    else:
                        for c in range(n_c):
                            an[c] = base_n[fv, c] + phd[c]
                            at[c] = base_t[fv, c]
                        for i in range(nv):
                            v_next[n, f, i] = vf[p, fv, i]
                            for j in range(nv):
                                resp[n, f, i, j] = 1.0 if i == j else 0.0
                        for c in range(n_c):
                            ln[n, f, c] = 0.0
                            lt[n, f, c] = 0.0
                            cpl[c] = 0.0
                            if md[n, c] == _POS:
                                cpl[c] = mu_tab[u, c]
                            elif md[n, c] == _NEG:
                                cpl[c] = -mu_tab[u, c]
                        if sensitivity:
                            for k in range(2):
                                for c in range(n_c):
                                    for i in range(nv):
                                        irs[n, f, k, c, i] = 0.0
                        if n_act > 0:
                            extra = n_max - n_act
                            dsum = 0.0
                            for c in range(n_c):
                                take = md[n, c] != _SEP
                                if not take and extra > 0:
                                    take = True
                                    extra -= 1
                                if take:
                                    dsum += dg[fm, c]
                            eps = eps_rel * max(dsum / (2 * n_max), 1e-300)
                            r = 0
                            for c in range(n_c):
                                if md[n, c] != _SEP:
                                    rows[r] = c
                                    for i in range(nv):
                                        grow[r, i] = jn[p, c, i]
                                        frow[r, i] = mw[fm, c, i] - cpl[c] * mw[fm, n_c + c, i]
                                    x[r, 0] = -an[c]
                                    r += 1
                            for c in range(n_c):
                                if md[n, c] == _STICK:
                                    rows[r] = n_c + c
                                    for i in range(nv):
                                        grow[r, i] = jt[p, c, i]
                                        frow[r, i] = mw[fm, n_c + c, i]
                                    x[r, 0] = -at[c]
                                    r += 1
                            if not kernels._solve_rows(grow, frow, x, amat, r, nv, eps):
                                n_bad += 1
                            for j in range(r):
                                for i in range(nv):
                                    v_next[n, f, i] += frow[j, i] * x[j, 0]
                                    for k in range(nv):
                                        resp[n, f, i, k] += frow[j, i] * x[j, 1 + k]
                            for j in range(r):
                                slot = rows[j]
                                if slot < n_c:
                                    ln[n, f, slot] = x[j, 0]
                                else:
                                    lt[n, f, slot - n_c] = x[j, 0]
                            for c in range(n_c):
                                lt[n, f, c] -= cpl[c] * ln[n, f, c]
                            if sensitivity:
                                for j in range(r):
                                    slot = rows[j]
                                    k = 0 if slot < n_c else 1
                                    for i in range(nv):
                                        irs[n, f, k, slot % n_c, i] = x[j, 1 + i]
                                for c in range(n_c):
                                    for i in range(nv):
                                        irs[n, f, 1, c, i] -= cpl[c] * irs[n, f, 0, c, i]
                    # -- violation score of (n, f) (as kernels._kernel) --------------------------
                    v_sq = 0.0
                    imp = 0.0
                    for k in range(n_groups):
                        lt_g[k] = 0.0
                        cap_g[k] = 0.0
                        mag_g[k] = 0.0
                    fv = f if vf.shape[1] > 1 else 0
                    for c in range(n_c):
                        mc = md[n, c]
                        # the gap rate of a separated contact and the slip of a sliding one
                        gr = 0.0
                        vtc = 0.0
                        if n_act == 0:  # v' = v_free: the row's free rates
                            gr = base_n[fv, c] + phd[c]
                        elif mc == _SEP:
                            sn = 0.0
                            for i in range(nv):
                                sn += jn[p, c, i] * v_next[n, f, i]
                            gr = (sn - vne[p, c]) + phd[c]
                        elif mc >= _POS:
                            st = 0.0
                            for i in range(nv):
                                st += jt[p, c, i] * v_next[n, f, i]
                            vtc = st - vte[p, c]
                        lnc = ln[n, f, c]
                        ltc = lt[n, f, c]
                        v_sq, imp, mag = kernels._contact_violation(
                            mc, gr, vtc, lnc, ltc, (v_sq, imp), (sc_velocity, sc_impulse, sc_floor)
                        )
                        if mc == _STICK:  # the group sums of a sticking contact
                            kg = group[c]
                            lt_g[kg] += ltc
                            cap_g[kg] += mu_tab[u, c] * lnc
                            mag_g[kg] += mag - sc_floor
                    imp = kernels._group_violation(
                        imp, n_groups, (lt_g, cap_g, mag_g), sc_impulse, sc_floor
                    )
                    score[n, f] = v_sq + (imp if n_act + n_stick <= nv else 0.0)
                    # -- velocity noise covariance R diag(sig2) R^T + c diag(sig2) ---------------
                    if f > 0 and shared and not slides:  # R is f = 0's: so is the covariance
                        for i in range(nv):
                            for j in range(nv):
                                cov[n, f, i, j] = cov[n, 0, i, j]
                    else:
                        for i in range(nv):
                            for j in range(nv):
                                s = 0.0
                                for k in range(nv):
                                    s += resp[n, f, i, k] * sig2[k] * resp[n, f, j, k]
                                cov[n, f, i, j] = s + (c_noise * sig2[i] if i == j else 0.0)
                    # -- log prior (sum over contacts) and l = log prior - score / 2 -------------
                    lp = 0.0
                    for c in range(n_c):
                        lp += log_pred[p, f, c, md[n, c]]
                    log_alpha[n, f] = lp - 0.5 * score[n, f]
            # -- normalise l over the row's entries per f, times the friction belief -------------
            for f in range(n_f):
                m = -np.inf
                for n in range(starts[p], starts[p + 1]):
                    m = max(m, log_alpha[n, f])
                if not np.isfinite(m):
                    m = 0.0
                tot = 0.0
                for n in range(starts[p], starts[p + 1]):
                    d = log_alpha[n, f] - m
                    if d > -746.0:  # (exp underflows to exactly 0 below: nothing to add)
                        tot += math.exp(d)
                lse = (math.log(tot) if tot > 0.0 else -np.inf) + m
                lf = math.log(fric[p, f]) if fric[p, f] > 0.0 else -np.inf
                for n in range(starts[p], starts[p + 1]):
                    log_alpha[n, f] = lf + (log_alpha[n, f] - lse)
        return n_bad

    return _entry_kernel


def _wrap(a: float) -> float:
    """`angles.wrap_angle` of one angle (rad, to [-pi, pi))."""
    return (a + np.pi) % (2.0 * np.pi) - np.pi


def _chol_lower(a: FloatArray, low: FloatArray, n: int) -> None:
    """Lower Cholesky factor of a[:n, :n] into low: the operations of `observation._chol_of`
    in its order (sums of products, then one subtraction; pivots clipped at 1e-300)."""
    for j in range(n):
        d = a[j, j]
        if j:
            s = low[j, 0] * low[j, 0]
            for k in range(1, j):
                s = s + low[j, k] * low[j, k]
            d = d - s
        ljj = math.sqrt(max(d, 1e-300))
        low[j, j] = ljj
        for i in range(j + 1, n):
            num = a[i, j]
            if j:
                s = low[i, 0] * low[j, 0]
                for k in range(1, j):
                    s = s + low[i, k] * low[j, k]
                num = num - s
            low[i, j] = num / ljj


def _log_diag(low: FloatArray, n: int) -> float:
    """sum_i log low[i, i] (log det of the factor): one log of the product when that is a
    normal number (the usual case), else the sum of logs."""
    prod = 1.0
    for i in range(n):
        prod *= low[i, i]
    if 1e-300 < prod < 1e300:
        return math.log(prod)
    s = 0.0
    for i in range(n):
        s += math.log(low[i, i])
    return s


def _gaussian_at(  # noqa: PLR0917 - numba helper: positional arrays
    p: int,
    n: int,
    f: int,
    q: FloatArray,
    v_h: FloatArray,
    cov: FloatArray,
    obs_value: FloatArray,
    angular: BoolArray,
    s_diag: FloatArray,
    dt: float,
    low: FloatArray,
    z: FloatArray,
    y: FloatArray,
    full: bool,
    v_mean: FloatArray,
    v_cov: FloatArray,
    dims: tuple[int, int],
) -> float:
    """The Kalman-form proposal of (entry n, friction f) of row p (`kernels._gaussian_kernel`
    with reciprocal pivots): innovation y, S = dt^2 cov + s_diag = L L^T, Z = L^-1 [y, dt
    cov^T]; returns log N(y; 0, S); with full also v_mean = v_h + Z_c^T Z_y and v_cov = cov
    - Z_c^T Z_c (the columns Z_c are solved only then; Z_y is the same either way). dims =
    (nv, nq), the velocity and pose dimensions (constants of the calling kernel)."""
    nv, nq = dims
    dt2 = dt * dt
    for i in range(nq):
        r = obs_value[i] - (q[p, i] + dt * v_h[n, f, i])
        y[i] = _wrap(r) if angular[i] else r
    for j in range(nv):
        d = dt2 * cov[n, f, j, j] + s_diag[j, j]
        for k in range(j):
            d -= low[j, k] * low[j, k]
        ljj = math.sqrt(max(d, 1e-300))
        low[j, j] = ljj
        for i in range(j + 1, nv):
            num = dt2 * cov[n, f, i, j] + s_diag[i, j]
            for k in range(j):
                num -= low[i, k] * low[j, k]
            low[i, j] = num / ljj
    n_col = nv + 1 if full else 1
    maha = 0.0
    for i in range(nv):
        z[i, 0] = y[i]
        if full:
            for v in range(nv):
                z[i, 1 + v] = cov[n, f, v, i] * dt
        inv = 1.0 / low[i, i]
        for col in range(n_col):
            s = 0.0
            for k in range(i):
                s += low[i, k] * z[k, col]
            z[i, col] = (z[i, col] - s) * inv
        maha += z[i, 0] * z[i, 0]
    if full:
        for aa in range(nv):
            cx = 0.0
            for i in range(nv):
                cx += z[i, 1 + aa] * z[i, 0]
            v_mean[aa] = v_h[n, f, aa] + cx
            for bb in range(nv):
                cx = 0.0
                for i in range(nv):
                    cx += z[i, 1 + aa] * z[i, 1 + bb]
                v_cov[aa, bb] = cov[n, f, aa, bb] - cx
    return float(-0.5 * (maha + 2.0 * _log_diag(low, nv) + nv * _LOG_2PI))


def _lse_row(vals: FloatArray, n: int) -> float:
    """log sum exp of vals[:n], max-shifted (all -inf -> -inf)."""
    m = -np.inf
    for i in range(n):
        m = max(m, vals[i])
    if not np.isfinite(m):
        m = 0.0
    tot = 0.0
    for i in range(n):
        tot += math.exp(vals[i] - m)
    return (math.log(tot) if tot > 0.0 else -np.inf) + m


def _slides(md: IntArray, n: int) -> bool:
    """Whether entry n has a sliding contact (its dynamics depend on friction)."""
    for c in range(md.shape[1]):  # noqa: SIM110 - a plain loop for numba
        if md[n, c] >= _POS:
            return True
    return False


def _row_evidence(  # noqa: PLR0917 - numba helper (inlined): positional arrays
    p: int,
    s0: int,
    n_e: int,
    md: IntArray,
    q: FloatArray,
    v_h: FloatArray,
    cov: FloatArray,
    log_alpha: FloatArray,
    obs: tuple[bool, FloatArray, BoolArray, FloatArray, float, bool, float],
    low: FloatArray,
    z: FloatArray,
    y: FloatArray,
    vm: FloatArray,
    vc: FloatArray,
    lj: FloatArray,
    dims: tuple[int, int],
) -> None:
    """lj[e n_f + f] = log alpha + log p(o) of every (entry, f) of row p (log p(o) once per
    entry when v_h, cov do not depend on f); obs = (has_obs, value, angular, s_diag, dt,
    shared, u_obs) with u_obs an upper bound of every log p(o) (inf: none); dims = (nv, nq).

    Pruning (exact to round-off): log p(o) of the element with the largest log alpha is
    computed first (lj_ref); an element with log alpha + u_obs < lj_ref - PRUNE_NATS has lj
    below the row's largest by more than PRUNE_NATS, so it adds less than e^-PRUNE_NATS of
    the largest term to the evidence and no Gumbel perturbation (< 37 nats from float64
    uniforms) can make it the draw: its lj is set to -inf without its Gaussian."""
    has_obs, obs_value, angular, s_diag, dt, shared, u_obs = obs
    n_f = log_alpha.shape[1]
    if not has_obs:
        for e in range(n_e):
            for f in range(n_f):
                lj[e * n_f + f] = log_alpha[s0 + e, f]
        return
    best = -np.inf  # the reference: the first element of the largest log alpha
    e_ref = 0
    f_ref = 0
    for e in range(n_e):
        for f in range(n_f):
            if log_alpha[s0 + e, f] > best:
                best = log_alpha[s0 + e, f]
                e_ref = e
                f_ref = f
    prune = u_obs < np.inf and n_e * n_f > 1
    cut = -np.inf
    # the reference first (its log p(o) sets the cut), then the rest in any order: the
    # values do not depend on it (an f-independent entry's log p(o) is the same for every f)
    for k in range(n_e):
        e = (e_ref + k) % n_e
        n = s0 + e
        same = shared and not _slides(md, n)  # v_h, cov do not depend on f
        have = False  # log p(o) of this entry computed (for every f when same)
        log_pred = 0.0
        for j in range(n_f):
            f = (f_ref + j) % n_f
            la = log_alpha[n, f]
            if la < cut:
                lj[e * n_f + f] = -np.inf
                continue
            if not (same and have):
                log_pred = _gaussian_at(
                    p, n, f, q, v_h, cov, obs_value, angular, s_diag, dt, low, z, y, False,
                    vm, vc, dims,
                )  # fmt: skip
                have = True
            lj[e * n_f + f] = la + log_pred
            if prune and k == 0 and j == 0:
                cut = best + log_pred - PRUNE_NATS - u_obs


def _gumbel_pick(lj: FloatArray, n_m: int, uniforms: FloatArray, row: int) -> int:
    """Gumbel-max draw over the padded flat layout: argmax of lj[m] - log(-log u[row, m])
    over the finite lj (the first of ties; 0 when none or a single candidate)."""
    best = -np.inf
    pick = 0
    for m in range(n_m if n_m > 1 else 0):  # (a single candidate is the draw)
        if np.isfinite(lj[m]):
            g = lj[m] - math.log(-math.log(uniforms[row, m]))
            if g > best:
                best = g
                pick = m
    return pick


def _sample_state(  # noqa: PLR0917 - numba helper (inlined): positional arrays
    p: int,
    vm: FloatArray,
    vc: FloatArray,
    y: FloatArray,
    v_h: FloatArray,
    star: tuple[int, int],
    noise: tuple[FloatArray, FloatArray, FloatArray, FloatArray, bool, float],
    q: FloatArray,
    a: FloatArray,
    low: FloatArray,
    corr: FloatArray,
    v_new: FloatArray,
    q_new: FloatArray,
    dims: tuple[int, int],
) -> None:
    """v' ~ N(vm, vc) (symmetrised, jittered Cholesky factor, normals z_v[p]) and q' = q +
    dt v' + e_q with e_q | v' on the observed dims (`observation.sample_gaussian_proposal`);
    noise = (z_v, z_q, q_gain, q_std, has_obs, dt); star = the drawn (entry, f) of v_h;
    dims = (nv, nq)."""
    z_v, z_q, q_gain, q_std, has_obs, dt = noise
    nv, nq = dims
    scale = 0.0
    for i in range(nv):
        for j in range(nv):
            a[i, j] = 0.5 * (vc[i, j] + vc[j, i])
        scale = abs(a[0, 0]) if i == 0 else max(scale, abs(a[i, i]))
    for i in range(nv):
        a[i, i] += 1e-12 * max(scale, 1e-300)
    _chol_lower(a, low, nv)
    for i in range(nv):
        s = low[i, 0] * z_v[p, 0]
        for k in range(1, i + 1):
            s = s + low[i, k] * z_v[p, k]
        corr[i] = s
    for i in range(nv):
        v_new[p, i] = vm[i] + corr[i]
    for i in range(nq):
        e_q = q_std[i] * z_q[p, i]
        if has_obs:
            r = y[i] - dt * (v_new[p, i] - v_h[star[0], star[1], i])
            e_q = q_gain[i] * r + e_q
        else:
            e_q = 0.0 + e_q
        q_new[p, i] = q[p, i] + dt * v_new[p, i] + e_q
    if nq == 3:
        q_new[p, 2] = _wrap(q_new[p, 2])


def _entry_density(  # noqa: PLR0917 - numba helper (inlined): positional arrays
    p: int,
    n: int,
    f: int,
    v_new: FloatArray,
    v_h: FloatArray,
    cov: FloatArray,
    a: FloatArray,
    low: FloatArray,
    z: FloatArray,
    nv: int,
) -> float:
    """log N(v_new[p] - v_h[n, f]; 0, cov[n, f]) (`observation.gaussian_log_density`, the
    same operations); a, low, z: scratch; nv the velocity dimension."""
    for i in range(nv):
        for j in range(nv):
            a[i, j] = cov[n, f, i, j]
    _chol_lower(a, low, nv)
    maha = 0.0
    for i in range(nv):
        acc = v_new[p, i] - v_h[n, f, i]
        if i:
            s = low[i, 0] * z[0]
            for k in range(1, i):
                s = s + low[i, k] * z[k]
            acc = acc - s
        z[i] = acc / low[i, i]
        maha += z[i] * z[i]
    return float(-0.5 * (maha + 2.0 * _log_diag(low, nv) + nv * _LOG_2PI))


def _row_log_posterior(  # noqa: PLR0917 - numba helper (inlined): positional arrays
    p: int,
    s0: int,
    n_e: int,
    md: IntArray,
    v_new: FloatArray,
    v_h: FloatArray,
    cov: FloatArray,
    log_alpha: FloatArray,
    shared: bool,
    star: tuple[int, int, float],
    work: tuple[FloatArray, FloatArray, FloatArray],
    lpost: FloatArray,
    nv: int,
) -> None:
    """lpost[e n_f + f] = log alpha + log N(v'; v_h, cov) of every (entry, f) of row p (-inf
    where alpha is 0; the density once per entry when it does not depend on f; none for a
    single candidate, whose posterior is 1). star = (n, f) of the drawn element and u_dens,
    an upper bound of every density (inf: none); work = scratch (a, low, z); nv the velocity
    dimension.

    Pruning (exact to round-off, as in `_row_evidence`): with the drawn element's lpost as
    reference, an element with log alpha + u_dens < lpost_ref - PRUNE_NATS weighs less than
    e^-PRUNE_NATS of it: its lpost is -inf without its density."""
    a, low, z = work
    n_star, f_star, u_dens = star
    n_f = log_alpha.shape[1]
    n_m = n_e * n_f
    prune = n_m > 1 and u_dens < np.inf
    cut = -np.inf
    e_star = n_star - s0
    # the drawn element first (its lpost sets the cut), then the rest (order-free values)
    for k in range(n_e):
        e = (e_star + k) % n_e
        n = s0 + e
        same = shared and not _slides(md, n)
        f_dens = -1  # the f whose density was computed
        dens = 0.0
        for j in range(n_f):
            f = (f_star + j) % n_f
            m = e * n_f + f
            la = log_alpha[n, f]
            if not np.isfinite(la) or la < cut:
                lpost[m] = -np.inf
            elif n_m == 1:  # a single finite candidate has posterior 1 (any density)
                lpost[m] = la
            elif same and f_dens >= 0:  # v_h, cov of f_dens: the same density
                lpost[m] = la + dens
            else:
                f_dens = f
                dens = _entry_density(p, n, f, v_new, v_h, cov, a, low, z, nv)
                lpost[m] = la + dens
            if prune and k == 0 and j == 0 and np.isfinite(la):
                cut = lpost[m] - PRUNE_NATS - u_dens


def _row_marginals(  # noqa: PLR0917 - numba helper (inlined): positional arrays
    p: int,
    s0: int,
    n_e: int,
    md: IntArray,
    lpost: FloatArray,
    pair_mask: BoolArray,
    fric_post: FloatArray,
    modes_post: FloatArray,
    marg_post: FloatArray,
    pair_in: FloatArray,
) -> None:
    """The normalised posterior of row p's (entry, f) from lpost: friction (F,), mode
    marginals given f (F, C, 4) (+ tiny, as `rbpf._discrete_posterior`) and overall (C, 4),
    P(pair in contact) (pairs,); sums in entry order (as np.bincount)."""
    n_f, n_c = modes_post.shape[1], modes_post.shape[2]
    tiny = 1e-12
    norm = _lse_row(lpost, n_e * n_f)
    for f in range(n_f):
        fric_post[p, f] = 0.0
        for c in range(n_c):
            for mo in range(4):
                modes_post[p, f, c, mo] = 0.0
    for pr in range(pair_mask.shape[0]):
        pair_in[p, pr] = 0.0
    for e in range(n_e):
        n = s0 + e
        p_n = 0.0
        for f in range(n_f):
            if lpost[e * n_f + f] == -np.inf:  # weight 0 (adds nothing below)
                continue
            w = math.exp(lpost[e * n_f + f] - norm)
            fric_post[p, f] += w
            p_n += w
            for c in range(n_c):
                modes_post[p, f, c, md[n, c]] += w
        for pr in range(pair_mask.shape[0]):
            touch = False
            for c in range(n_c):
                if pair_mask[pr, c] and md[n, c] != _SEP:
                    touch = True
            if touch:
                pair_in[p, pr] += p_n
    for c in range(n_c):
        for mo in range(4):
            s = modes_post[p, 0, c, mo]
            for f in range(1, n_f):
                s += modes_post[p, f, c, mo]
            marg_post[p, c, mo] = s
    for f in range(n_f):
        den = fric_post[p, f] + tiny
        for c in range(n_c):
            for mo in range(4):
                modes_post[p, f, c, mo] = (
                    modes_post[p, f, c, mo] + tiny * marg_post[p, c, mo]
                ) / den


def _propose_kernel_for(nv_const: int) -> Callable[..., None]:
    """The proposal kernel for velocity (and pose) dimension nv_const (0: any, read from the
    arrays): with a constant the compiler unrolls the small Cholesky factors and solves
    (gripper, 14,764 live entries: 4.7 -> 2.4 ms on one thread, the same values bit for
    bit); see `_entry_kernel_for`."""

    def _propose_kernel(  # noqa: PLR0917 - numba entry point: positional arrays
        starts: IntArray,
        md: IntArray,
        q: FloatArray,
        v_h: FloatArray,
        cov: FloatArray,
        log_alpha: FloatArray,
        has_obs: bool,
        obs_value: FloatArray,
        angular: BoolArray,
        s_diag: FloatArray,
        q_gain: FloatArray,
        q_std: FloatArray,
        dt: float,
        shared: bool,
        uniforms: FloatArray,
        copies: int,
        z_v: FloatArray,
        z_q: FloatArray,
        pair_mask: BoolArray,
        incr: FloatArray,
        v_new: FloatArray,
        q_new: FloatArray,
        fric_post: FloatArray,
        modes_post: FloatArray,
        marg_post: FloatArray,
        pair_in: FloatArray,
        bounds: FloatArray,
        lo: int,
        hi: int,
    ) -> None:
        """Per row p of lo .. hi - 1: the evidence of each (entry, f), the Gumbel-max draw over
        the padded (K, F) layout (uniforms (R / copies, K F), shared by the copies of a
        particle), the sampled v', q' and the discrete posterior given v' (see the module
        docstring). bounds = (u_obs, u_dens): upper bounds of log p(o | element) and of
        log N(v' | element) for the pruning of negligible elements (inf: none)."""
        n_f = log_alpha.shape[1]
        nv = nv_const if nv_const > 0 else v_h.shape[2]
        dims = (nv, nv_const if nv_const > 0 else q.shape[1])
        k_max = 1
        for p in range(lo, hi):
            k_max = max(k_max, starts[p + 1] - starts[p])
        lj = np.empty(k_max * n_f)
        lpost = np.empty(k_max * n_f)
        y = np.empty(q.shape[1])
        vm = np.empty(nv)
        vc = np.empty((nv, nv))
        low = np.zeros((nv, nv))
        z = np.empty((nv, nv + 1))
        a = np.empty((nv, nv))
        corr = np.empty(nv)
        obs = (has_obs, obs_value, angular, s_diag, dt, shared, bounds[0])
        noise = (z_v, z_q, q_gain, q_std, has_obs, dt)
        for p in range(lo, hi):
            s0 = starts[p]
            n_e = starts[p + 1] - s0
            _row_evidence(p, s0, n_e, md, q, v_h, cov, log_alpha, obs, low, z, y, vm, vc, lj, dims)
            incr[p] = _lse_row(lj, n_e * n_f)
            pick = _gumbel_pick(lj, n_e * n_f, uniforms, p // copies)
            # (m = e n_f + f is the flat index k n_f + f of the padded layout: e == k)
            n_star = s0 + pick // n_f
            f_star = pick % n_f
            if has_obs:  # the proposal's posterior of v' of the drawn (entry, f)
                _gaussian_at(
                    p,
                    n_star,
                    f_star,
                    q,
                    v_h,
                    cov,
                    obs_value,
                    angular,
                    s_diag,
                    dt,
                    low,
                    z,
                    y,
                    True,
                    vm,
                    vc,
                    dims,
                )
            else:
                for i in range(nv):
                    y[i] = 0.0
                    vm[i] = v_h[n_star, f_star, i]
                    for j in range(nv):
                        vc[i, j] = cov[n_star, f_star, i, j]
            _sample_state(
                p, vm, vc, y, v_h, (n_star, f_star), noise, q, a, low, corr, v_new, q_new, dims
            )
            star = (n_star, f_star, bounds[1])
            _row_log_posterior(
                p, s0, n_e, md, v_new, v_h, cov, log_alpha, shared, star, (a, low, corr), lpost, nv
            )
            _row_marginals(
                p, s0, n_e, md, lpost, pair_mask, fric_post, modes_post, marg_post, pair_in
            )

    return _propose_kernel


def _map_pending_kernel(  # noqa: PLR0917 - numba entry point: positional arrays
    buf: FloatArray,
    head: int,
    length: int,
    w: FloatArray,
    pair_mask: BoolArray,
    n_cand: IntArray,
    k_max: int,
    grid: FloatArray,
    sums: FloatArray,
    wsum: FloatArray,
    count: IntArray,
) -> None:
    """Per pair: sums (pairs, cells, Kmax) of weight x friction marginals and wsum (pairs,
    cells) of weight over the history entries l < length (ring slots (head + l) % cap of buf
    (cap, P, W), rows [fric_pair (pairs Kmax) | s (C) | P(in contact) (C)]) and their
    contacts c of the pair with weight = w[p] P(in contact) > 1e-9 and finite s; count
    (pairs,) the observations. The order of accumulation is that of
    `rbpf._map_observations` + `FrictionMap.accumulate` (entry, particle, contact)."""
    cap, n_p, _ = buf.shape
    n_pairs, n_c = pair_mask.shape
    pk = n_pairs * k_max
    s_min, cell_size, n_cells = grid[0], grid[1], int(grid[2])
    for pr in range(n_pairs):
        for e in range(length):
            slot = (head + e) % cap
            for p in range(n_p):
                for c in range(n_c):
                    if not pair_mask[pr, c]:
                        continue
                    weight = w[p] * buf[slot, p, pk + n_c + c]
                    s = buf[slot, p, pk + c]
                    if not (weight > 1e-9 and np.isfinite(s)):
                        continue
                    j = math.floor((s - s_min) / cell_size)
                    cell = int(min(max(j, 0.0), n_cells - 1.0))
                    for k in range(n_cand[pr]):
                        sums[pr, cell, k] += weight * buf[slot, p, pr * k_max + k]
                    wsum[pr, cell] += weight
                    count[pr] += 1


def _sig(x: float) -> float:
    """`transition._sigmoid` of one value."""
    return 0.5 * (1.0 + math.tanh(0.5 * x))


def _predict_kernel(  # noqa: PLR0917 - numba entry point: positional arrays
    prev: FloatArray,
    phi: FloatArray,
    an: FloatArray,
    at: FloatArray,
    params: FloatArray,
    out: FloatArray,
    lo: int,
    hi: int,
) -> None:
    """`transition.soft_modes` of the free motion and `transition.mode_transition` (with the
    far-gap reach) per (row, friction, contact) of rows lo .. hi - 1, the same operations in
    the same order. params = (dt, gap_scale, far_gap, slip_scale, slide_floor,
    persistence)."""
    dt, gs, far, slip, floor, rho = (
        params[0],
        params[1],
        params[2],
        params[3],
        params[4],
        params[5],
    )
    _, n_f, n_c, _ = prev.shape
    soft = np.empty(4)
    pred = np.empty(4)
    for p in range(lo, hi):
        for c in range(n_c):
            g = phi[p, c] + dt * an[p, c]
            reach = _sig(-(g - far) / gs)
            pc = _sig(-g / gs) * reach
            a = at[p, c] / slip
            p_stick = 1.0 / (1.0 + a * a)
            p_slide = 1.0 - p_stick
            d = _sig(10.0 * a)
            soft[1] = max(p_stick, floor)
            soft[2] = max(p_slide * d, floor)
            soft[3] = max(p_slide * (1.0 - d), floor)
            tot = soft[1] + soft[2] + soft[3]
            for m in range(1, 4):
                soft[m] = soft[m] / tot * pc
            soft[0] = 1.0 - pc
            stay = 1.0 - reach
            for f in range(n_f):
                for m in range(4):
                    pred[m] = rho * prev[p, f, c, m] + (1.0 - rho) * soft[m]
                moved = pred[1] * stay
                for m in range(2, 4):
                    moved += pred[m] * stay
                pred[0] += moved
                for m in range(1, 4):
                    pred[m] *= reach
                total = max(pred[0] + pred[1] + pred[2] + pred[3], 1e-300)
                for m in range(4):
                    out[p, f, c, m] = pred[m] / total


def _support_kernel(  # noqa: PLR0917 - numba entry point: positional arrays
    q: FloatArray,
    v: FloatArray,
    force: FloatArray,
    mus: FloatArray,
    points: FloatArray,
    weights: FloatArray,
    mass: FloatArray,
    limit_diag: FloatArray,
    params: FloatArray,
    m_eff: FloatArray,
    v_free: FloatArray,
    lo: int,
    hi: int,
) -> int:
    """`PlanarModel.support_terms` for rows lo .. hi - 1: the linearised support friction K
    at mu 1 of each row (points (N, 2) body frame, weights (N,)), then per coefficient
    mus[p, b] the effective mass M + dt mu K (quasi-static: dt mu K) into m_eff (R, B, nv,
    nv) and v_free = m_eff^-1 (M v + dt F) (quasi-static: m_eff^-1 dt F) into v_free (R, B,
    nv). params = (dt, load = m g (N), velocity eps (m/s), quasi-static 0 / 1). Returns the
    number of singular effective masses (their v_free is NaN)."""
    dt, load, eps, quasi = params[0], params[1], params[2], params[3] > 0.5
    nv = v.shape[1]
    n_b = mus.shape[1]
    k1 = np.zeros((nv, nv))
    lu = np.empty((nv, nv))
    rhs = np.empty((nv, 1))
    n_bad = 0
    for p in range(lo, hi):
        for i in range(nv):
            for j in range(nv):
                k1[i, j] = 0.0
        if quasi:
            sp = 0.0
            for i in range(nv):
                sp += limit_diag[i] * v[p, i] * v[p, i]
            scale = load / max(math.sqrt(sp), eps)
            for i in range(nv):
                k1[i, i] = scale * limit_diag[i]
        elif nv == 2:
            scale = load * np.sum(weights) / max(math.hypot(v[p, 0], v[p, 1]), eps)
            k1[0, 0] = scale
            k1[1, 1] = scale
        else:
            co, si = math.cos(q[p, 2]), math.sin(q[p, 2])
            s0 = sx = sy = srr = 0.0
            for n in range(points.shape[0]):
                rx = co * points[n, 0] - si * points[n, 1]
                ry = si * points[n, 0] + co * points[n, 1]
                vx = v[p, 0] - v[p, 2] * ry
                vy = v[p, 1] + v[p, 2] * rx
                c = load * weights[n] / max(math.sqrt(vx * vx + vy * vy), eps)
                s0 += c
                sx += c * rx
                sy += c * ry
                srr += c * (rx * rx + ry * ry)
            k1[0, 0] = s0
            k1[1, 1] = s0
            k1[0, 2] = -sy
            k1[2, 0] = -sy
            k1[1, 2] = sx
            k1[2, 1] = sx
            k1[2, 2] = srr
        for b in range(n_b):
            mu = mus[p, b]
            for i in range(nv):
                for j in range(nv):
                    m_ij = dt * mu * k1[i, j]
                    if not quasi:
                        m_ij += mass[i, j]
                    m_eff[p, b, i, j] = m_ij
                    lu[i, j] = m_ij
                r = dt * force[p, i]
                if not quasi:
                    for j in range(nv):
                        r += mass[i, j] * v[p, j]
                rhs[i, 0] = r
            if not kernels._lu_solve_inplace(lu, rhs, nv, 1):
                n_bad += 1
                for i in range(nv):
                    v_free[p, b, i] = np.nan
                continue
            for i in range(nv):
                v_free[p, b, i] = rhs[i, 0]
    return n_bad


_SPECIALISED_NV = (0, 2, 3)
"""Velocity dimensions with their own compiled entry kernel (0: the generic one): the point
mass (2) and the planar rigid body (3)."""
_ENTRY_KERNELS: dict[int, Callable[..., int]]
_PROPOSE_KERNELS: dict[int, Callable[..., None]]

if AVAILABLE:
    import numba

    _support_kernel = numba.njit(cache=True, nogil=True, error_model="numpy")(_support_kernel)
    _sig = numba.njit(cache=True, nogil=True, error_model="numpy")(_sig)
    _predict_kernel = numba.njit(cache=True, nogil=True, error_model="numpy")(_predict_kernel)

    _map_pending_kernel = numba.njit(cache=True, nogil=True, error_model="numpy")(
        _map_pending_kernel
    )

    _row_mw = numba.njit(cache=True, nogil=True, error_model="numpy")(_row_mw)
    _entry_gap = numba.njit(cache=True, nogil=True, error_model="numpy")(_entry_gap)
    _ENTRY_KERNELS = {
        nv: numba.njit(cache=True, nogil=True, error_model="numpy")(_entry_kernel_for(nv))
        for nv in _SPECIALISED_NV
    }
    _wrap = numba.njit(cache=True, nogil=True, error_model="numpy")(_wrap)
    _chol_lower = numba.njit(cache=True, nogil=True, error_model="numpy")(_chol_lower)
    _log_diag = numba.njit(cache=True, nogil=True, error_model="numpy")(_log_diag)
    _gaussian_at = numba.njit(cache=True, nogil=True, error_model="numpy", inline="always")(
        _gaussian_at
    )
    _lse_row = numba.njit(cache=True, nogil=True, error_model="numpy")(_lse_row)
    # helpers of the per-row loop: inlined (a call with many array arguments costs ~30 %)
    _inline = numba.njit(cache=True, nogil=True, error_model="numpy", inline="always")
    _slides = _inline(_slides)
    _row_evidence = _inline(_row_evidence)
    _gumbel_pick = _inline(_gumbel_pick)
    _sample_state = _inline(_sample_state)
    _entry_density = _inline(_entry_density)
    _row_log_posterior = _inline(_row_log_posterior)
    _row_marginals = _inline(_row_marginals)
    _PROPOSE_KERNELS = {
        nv: numba.njit(cache=True, nogil=True, error_model="numpy")(_propose_kernel_for(nv))
        for nv in _SPECIALISED_NV
    }
else:  # pragma: no cover - numba missing: the numpy phases run instead
    _ENTRY_KERNELS = {nv: _entry_kernel_for(nv) for nv in _SPECIALISED_NV}
    _PROPOSE_KERNELS = {nv: _propose_kernel_for(nv) for nv in _SPECIALISED_NV}


_MIN_ENTRIES = 256
"""Fewest live entries per thread of the entry and proposal kernels (~0.1 ms of work;
smaller problems run in the calling thread)."""
PRUNE_NATS = 100.0
"""Elements of a row whose log weight is below the row's largest by more than this are
pruned from the proposal (`_row_evidence`, `_row_log_posterior`): e^-100 ~ 4e-44 of the
largest term, far below float64 round-off of the sums, and more than any Gumbel perturbation
of a float64 uniform (< 37 nats) can overcome, so the draws and sums are those without
pruning (to round-off)."""
_MIN_ROWS = 256
"""Fewest rows per thread of the mode prediction and support-friction kernels (gripper, 1000
rows: 0.37 -> 0.29 ms on two threads)."""


def _chunks(
    pool: RowPool | None, n_rows: int, starts: IntArray | None, min_work: int
) -> list[tuple[int, int]]:
    """The row ranges of one kernel call: one range without a pool."""
    if pool is None:
        return [(0, n_rows)]
    return pool.chunks(n_rows, starts=starts, min_work=min_work)


def _run_rows(
    pool: RowPool | None,
    kernel: Callable[..., T],
    args: tuple[Any, ...],
    bounds: list[tuple[int, int]],
) -> list[T]:
    """kernel(*args, lo, hi) for every range of bounds (on the pool's threads)."""
    if pool is None or len(bounds) == 1:
        return [kernel(*args, lo, hi) for lo, hi in bounds]
    return pool.map(lambda lo, hi: kernel(*args, lo, hi), bounds)


def entry_dynamics(
    starts: IntArray,
    md: IntArray,
    *,
    jn: FloatArray,
    jt: FloatArray,
    phi: FloatArray,
    vn_env: FloatArray,
    vt_env: FloatArray,
    v_free: FloatArray,
    inv_mass: FloatArray,
    mass: FloatArray | None,
    mu: FloatArray,
    row_b: IntArray | None,
    group: IntArray,
    prev_in: FloatArray | None,
    log_pred: FloatArray,
    fric: FloatArray,
    sig2: FloatArray,
    params: tuple[float, ...],
    sensitivity: bool,
    work: dict[str, npt.NDArray[Any]] | None = None,
    pool: RowPool | None = None,
) -> tuple[dict[str, Any], int]:
    """Phase 4 of the step for the N live entries (rows starts[p] .. starts[p + 1] of row p,
    modes md (N, C)) x F friction hypotheses.

    Per row (R rows): jn, jt (R, C, nv) contact Jacobians; phi, vn_env, vt_env (R, C) gaps
    (m) and obstacle velocities (m/s); v_free (R, Fv, nv), Fv in (1, F), the velocity
    without contact impulses; inv_mass (nv,) the diagonal of M^-1 or mass (R, Fm, nv, nv) an
    effective mass; mu (B, C) the coefficient of each contact per joint friction hypothesis
    and row_b (R,) each row's hypothesis (friction bank; None: f is the hypothesis); group
    (C,) obstacle group index 0..n-1 of each contact; prev_in (R, C) P(in contact) at the
    previous step (None = 1); log_pred (R, F, C, 4) log predicted mode marginals; fric (R, F) the
    friction belief; sig2 (nv,) velocity process-noise variances. params = (dt, eps_rel,
    impulse scale, velocity scale, impulse floor, gap closure, gap tolerance or -1,
    constrained noise).

    Returns (v_next (N, F, nv), ln, lt (N, F, C), score (N, F), response (N, F, nv, nv),
    impulse_response (N, F, 2, C, nv) or None, cov (N, F, nv, nv), log_alpha (N, F)) and
    the number of singular systems met. work: reusable buffers (a dict kept by the
    caller): the outputs are then views of them, valid until the next call with the same
    work. pool: threads over ranges of rows (`row_pool`; same outputs for any split).
    """
    # Long because: the argument list, its documentation and the one call that hands ~30
    # contiguous arrays to the compiled kernel; there is no logic here to split.
    n_e, n_c = md.shape
    nv = jn.shape[2]
    n_r = starts.shape[0] - 1
    n_f = fric.shape[1]
    shapes = {
        "v_next": (n_e, n_f, nv),
        "ln": (n_e, n_f, n_c),
        "lt": (n_e, n_f, n_c),
        "score": (n_e, n_f),
        "response": (n_e, n_f, nv, nv),
        "impulse_response": (n_e if sensitivity else 0, n_f, 2, n_c, nv),
        "cov": (n_e, n_f, nv, nv),
        "log_alpha": (n_e, n_f),
    }
    out: dict[str, Any] = {
        name: kernels.work_buffer(work, name, shape) for name, shape in shapes.items()
    }
    n_groups = int(group.max()) + 1 if group.size else 0
    c = np.ascontiguousarray
    starts = c(starts, dtype=np.int64)
    md = c(md, dtype=np.int64)
    n_max = int((md != _SEP).sum(axis=1).max(initial=0))
    args = (
        starts,
        md,
        c(jn),
        c(jt),
        c(phi),
        c(vn_env),
        c(vt_env),
        c(v_free),
        c(inv_mass, dtype=np.float64),
        np.zeros((n_r, 1, nv, nv)) if mass is None else c(mass),
        mass is not None,
        c(mu),
        np.full(n_r, -1, dtype=np.int64) if row_b is None else c(row_b, dtype=np.int64),
        c(group, dtype=np.int64),
        n_groups,
        np.asarray(params, dtype=np.float64),
        np.zeros((0, n_c)) if prev_in is None else c(prev_in),
        prev_in is not None,
        bool(sensitivity),
        c(np.broadcast_to(log_pred, (n_r, n_f, n_c, 4))),
        c(fric),
        c(sig2, dtype=np.float64),
        out["v_next"],
        out["ln"],
        out["lt"],
        out["score"],
        out["response"],
        out["impulse_response"],
        out["cov"],
        out["log_alpha"],
        n_max,
    )
    bounds = _chunks(pool, n_r, starts, _MIN_ENTRIES)
    kernel = _ENTRY_KERNELS.get(nv, _ENTRY_KERNELS[0])
    n_bad = sum(_run_rows(pool, kernel, args, bounds))
    if not sensitivity:
        out["impulse_response"] = None
    return out, int(n_bad)


def propose_rows(
    starts: IntArray,
    md: IntArray,
    *,
    q: FloatArray,
    v_h: FloatArray,
    cov: FloatArray,
    log_alpha: FloatArray,
    observation: tuple[FloatArray, BoolArray, FloatArray] | None,
    q_gain: FloatArray,
    q_std: FloatArray,
    dt: float,
    shared: bool = False,
    uniforms: FloatArray,
    copies: int,
    z_v: FloatArray,
    z_q: FloatArray,
    pair_mask: BoolArray,
    cov_floor: FloatArray | None = None,
    prune: bool = True,
    pool: RowPool | None = None,
) -> dict[str, FloatArray]:
    """Phases 5-6 of the step per row (R rows, entries starts[p] .. starts[p + 1], modes md
    (N, C)): q (R, nq) poses; v_h (N, F, nv), cov (N, F, nv, nv), log_alpha (N, F) of
    `entry_dynamics`; observation = (value (nq,), angular (nq,), s_diag (nq, nq)) of a pose
    reading of every dim in order, or None; q_gain, q_std (nq,) the position-noise posterior
    gain and std; uniforms (R / copies, K F) the uniforms of the Gumbel draws of the padded
    (K, F) layout (K >= the largest entry count of a row), row p using row p // copies (the
    copies of a friction bank share them); z_v, z_q (R, nq) standard normals of v' and of the
    position noise; pair_mask (pairs, C) the contacts of each friction pair; shared: v_h and
    cov of an entry without sliding contacts are the same for every f (no per-friction
    support terms), so its proposal and density are computed once. cov_floor (nv,): a
    diagonal every cov is above in the PSD order (the constrained noise c sig2), which
    bounds the densities so that negligible elements can be pruned (`PRUNE_NATS`; None: the
    densities are not pruned); prune False: no pruning at all (the reference of the tests).
    pool: threads over ranges of rows (`row_pool`; same outputs for any split).

    Returns incr (R,) the evidence, v_new and q_new (R, nq) the sampled state, fric_post
    (R, F), modes_post (R, F, C, 4), marg_post (R, C, 4) and pair_in (R, pairs).
    """
    # Long because: the argument list, its documentation and the one call that hands the
    # arrays to the compiled kernel; there is no logic here to split.
    n_r = starts.shape[0] - 1
    n_c = md.shape[1]
    n_f = log_alpha.shape[1]
    nq = q.shape[1]
    out = {
        "incr": np.empty(n_r),
        "v_new": np.empty((n_r, nq)),
        "q_new": np.empty((n_r, nq)),
        "fric_post": np.empty((n_r, n_f)),
        "modes_post": np.empty((n_r, n_f, n_c, 4)),
        "marg_post": np.empty((n_r, n_c, 4)),
        "pair_in": np.empty((n_r, pair_mask.shape[0])),
    }
    value, angular, s_diag = (
        (np.zeros(nq), np.zeros(nq, dtype=np.bool_), np.zeros((nq, nq)))
        if observation is None
        else observation
    )
    c = np.ascontiguousarray
    starts = c(starts, dtype=np.int64)
    args = (
        starts,
        c(md, dtype=np.int64),
        c(q),
        c(v_h),
        c(cov),
        c(log_alpha),
        observation is not None,
        c(value, dtype=np.float64),
        c(angular, dtype=np.bool_),
        c(s_diag, dtype=np.float64),
        c(q_gain, dtype=np.float64),
        c(q_std, dtype=np.float64),
        float(dt),
        bool(shared),
        c(uniforms),
        int(copies),
        c(z_v),
        c(z_q),
        c(pair_mask, dtype=np.bool_),
        out["incr"],
        out["v_new"],
        out["q_new"],
        out["fric_post"],
        out["modes_post"],
        out["marg_post"],
        out["pair_in"],
        np.array(
            [_log_density_bound(s_diag), _log_density_bound(cov_floor)]
            if prune
            else [math.inf, math.inf]
        ),
    )
    kernel = _PROPOSE_KERNELS.get(v_h.shape[2] if v_h.shape[2] == nq else 0, _PROPOSE_KERNELS[0])
    _run_rows(pool, kernel, args, _chunks(pool, n_r, starts, _MIN_ENTRIES))
    return out


def _log_density_bound(floor: FloatArray | None) -> float:
    """An upper bound of log N(x; m, S) for every S >= floor (PSD order): -1/2 log det(2 pi
    floor); inf without a positive-definite floor (no pruning). floor: (n, n) or its
    diagonal (n,)."""
    if floor is None or floor.size == 0:
        return math.inf
    f = np.asarray(floor, dtype=np.float64)
    mat = np.diag(f) if f.ndim == 1 else f
    sign, logdet = np.linalg.slogdet(2.0 * math.pi * mat)
    if sign <= 0 or not np.isfinite(logdet) or not np.all(np.isfinite(mat)):
        return math.inf
    return float(-0.5 * logdet)


def map_pending(
    buf: FloatArray,
    head: int,
    length: int,
    w: FloatArray,
    *,
    pair_mask: BoolArray,
    n_cand: IntArray,
    grid: tuple[float, float, int],
) -> list[tuple[FloatArray, FloatArray] | None]:
    """The uncommitted friction-map history (a `particles.MapHistory` ring: buf (cap, P,
    W), head, length) under particle weights w (P,) as pending per-cell sums for
    `FrictionMap.view`: per pair None (no observation) or (sums (cells, K_pair), weights
    (cells,)), the values of `FrictionMap.accumulate` of `rbpf._map_observations`; grid =
    (s_min (m), cell size (m), number of cells); pair_mask (pairs, C) the contacts of each
    pair; n_cand (pairs,) candidates per pair."""
    n_pairs = pair_mask.shape[0]
    k_max = int(buf.shape[2] - 2 * pair_mask.shape[1]) // n_pairs
    n_cells = int(grid[2])
    sums = np.zeros((n_pairs, n_cells, k_max))
    wsum = np.zeros((n_pairs, n_cells))
    count = np.zeros(n_pairs, dtype=np.int64)
    _map_pending_kernel(
        buf,
        int(head),
        int(length),
        np.ascontiguousarray(w, dtype=np.float64),
        np.ascontiguousarray(pair_mask, dtype=np.bool_),
        np.ascontiguousarray(n_cand, dtype=np.int64),
        k_max,
        np.asarray(grid, dtype=np.float64),
        sums,
        wsum,
        count,
    )
    return [
        None if count[pr] == 0 else (sums[pr, :, : int(n_cand[pr])], wsum[pr])
        for pr in range(n_pairs)
    ]


def predict_modes(
    previous: FloatArray,
    phi: FloatArray,
    gap_rate_free: FloatArray,
    vt_free: FloatArray,
    *,
    dt: float,
    params: tuple[float, float, float, float, float],
    pool: RowPool | None = None,
) -> FloatArray:
    """Predicted per-contact mode marginals (R, F, C, 4) from the previous ones previous (R,
    F, C, 4) and the free motion (phi, gap_rate_free, vt_free (R, C): m, m/s, m/s): the
    softened NCP checks (`transition.soft_modes`) and the persistence transition with the
    far-gap reach (`transition.mode_transition`), without edge consistency. params =
    (gap_scale, far_gap, slip_scale, slide_floor, persistence) of `TransitionParams`; pool:
    threads over ranges of rows (`row_pool`)."""
    prev = np.ascontiguousarray(previous, dtype=np.float64)
    out = np.empty(prev.shape)
    args = (
        prev,
        np.ascontiguousarray(phi, dtype=np.float64),
        np.ascontiguousarray(gap_rate_free, dtype=np.float64),
        np.ascontiguousarray(vt_free, dtype=np.float64),
        np.asarray((dt, *params), dtype=np.float64),
        out,
    )
    _run_rows(pool, _predict_kernel, args, _chunks(pool, prev.shape[0], None, _MIN_ROWS))
    return out


def support_terms(
    model: PlanarModel,
    q: FloatArray,
    v: FloatArray,
    u: FloatArray,
    mu_surface: FloatArray,
    *,
    velocity_eps: float | None = None,
    pool: RowPool | None = None,
) -> tuple[FloatArray, FloatArray]:
    """`PlanarModel.support_terms` compiled (the same equations; values equal to round-off,
    the 3 x 3 solves by LU with partial pivoting as numpy's): effective mass (R, B, nv, nv)
    (kg, kg m^2) and free velocity (R, B, nv) (m/s) for R states q, v (R, nq) (v the
    linearisation velocity), input wrench u (nq,) or (R, nq) and support coefficients
    mu_surface (B,) or (R, B). The generalised force (inputs, extensions) comes from the
    model. pool: threads over ranges of rows."""
    qa = np.ascontiguousarray(q, dtype=np.float64)
    va = np.ascontiguousarray(v, dtype=np.float64)
    mus = np.asarray(mu_surface, dtype=np.float64)
    if model.quasi_static and np.any(mus <= 0.0):
        msg = (
            f"the quasi-static push model needs support coefficients > 0 (f_max = mu_s m "
            f"g), got {mus.tolist()}"
        )
        raise ModelError(msg)
    eps = model.velocity_eps if velocity_eps is None else float(velocity_eps)
    if not eps > 0.0:
        msg = f"velocity_eps must be > 0 m/s, got {eps}"
        raise ModelError(msg)
    n_r, nv = va.shape
    mus2 = np.ascontiguousarray(
        np.broadcast_to(mus[None, :] if mus.ndim == 1 else mus, (n_r, mus.shape[-1]))
    )
    force = np.ascontiguousarray(
        np.broadcast_to(model.generalized_force(qa, va, u), (n_r, nv)), dtype=np.float64
    )
    m_eff = np.empty((n_r, mus2.shape[1], nv, nv))
    v_free = np.empty((n_r, mus2.shape[1], nv))
    args = (
        qa,
        va,
        force,
        mus2,
        np.ascontiguousarray(model.support_points, dtype=np.float64),
        np.ascontiguousarray(model.support_weights, dtype=np.float64),
        np.ascontiguousarray(model.mass_matrix),
        np.ascontiguousarray(model.limit_surface_diag[:nv]),
        np.asarray(
            (
                model.scenario.dt,
                float(model.mass_diag[0] * model.scenario.gravity),
                eps,
                1.0 if model.quasi_static else 0.0,
            )
        ),
        m_eff,
        v_free,
    )
    n_bad = sum(_run_rows(pool, _support_kernel, args, _chunks(pool, n_r, None, _MIN_ROWS)))
    if n_bad:
        msg = (
            f"support friction: the effective mass is singular for {n_bad} (state, "
            "coefficient) pairs"
        )
        raise SolverError(msg)
    return m_eff, v_free
