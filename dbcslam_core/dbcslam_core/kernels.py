"""Compiled kernels of the filter's hot path (numba): the reduced contact dynamics and the
Gaussian (Kalman-form) proposal update.

`reduced_dynamics` is the kernel of `contact_modes.solve_reduced`:

One loop over the lead elements (particle x mode hypothesis x friction hypothesis, flattened)
that builds and solves each element's r x r system in registers: the same equations as the
numpy path of `contact_modes.solve_reduced` (equality rows: normal rows of the non-separated
contacts, tangent rows of the sticking ones; a sliding contact's friction impulse follows its
normal impulse, lt = -c ln; relative Tikhonov term eps_rel on the diagonal as in the padded
form), then the post-step velocity, gap rates, slips, the violation score and the response
maps. Elements without sliding contacts do not depend on friction: consecutive elements of
one geometry element share their solve (as the numpy path solves them once).

The numpy path does about a thousand small array operations per filter step (gathers,
batched LAPACK calls on 2 x 2 .. 6 x 6 systems); here each system costs a few hundred
floating-point operations. Compiled with numba (`cache=True`: the machine code is stored
next to this file, or in numba's user cache directory when that is read-only, so a node
starts without recompiling). `AVAILABLE` is False when numba cannot be imported; callers
then use the numpy path.

Units as in `contact_modes.solve_reduced`: velocities m/s (rad/s), impulses N s, gaps m.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
import numpy.typing as npt

from dbcslam_core.row_pool import RowPool

__all__ = [
    "AVAILABLE",
    "enumerate_compact",
    "enumerate_tuples",
    "gaussian_update",
    "prepare_tuples",
    "reduced_dynamics",
]

FloatArray = npt.NDArray[np.float64]
IntArray = npt.NDArray[np.int64]

try:  # pragma: no cover - exercised by whichever import succeeds
    import numba
except ImportError:  # pragma: no cover
    AVAILABLE = False
else:
    AVAILABLE = True

_SEP, _STICK, _POS, _NEG = 0, 1, 2, 3

_MEMO_CONTACTS = 12
"""Most contacts for the enumeration's feasibility memo (a 2^C table per call)."""


def _lu_solve_inplace(a: FloatArray, b: FloatArray, r: int, m: int) -> bool:
    """Solve a[:r, :r] x = b[:r, :m] in place (b <- x) by Gaussian elimination with partial
    pivoting; returns False for a singular system (a zero pivot)."""
    for k in range(r):
        p = k
        best = abs(a[k, k])
        for i in range(k + 1, r):
            if abs(a[i, k]) > best:
                best = abs(a[i, k])
                p = i
        if best == 0.0:
            return False
        if p != k:
            for j in range(r):
                a[k, j], a[p, j] = a[p, j], a[k, j]
            for j in range(m):
                b[k, j], b[p, j] = b[p, j], b[k, j]
        inv = 1.0 / a[k, k]
        for i in range(k + 1, r):
            f = a[i, k] * inv
            if f != 0.0:
                for j in range(k + 1, r):
                    a[i, j] -= f * a[k, j]
                for j in range(m):
                    b[i, j] -= f * b[k, j]
    for k in range(r - 1, -1, -1):
        inv = 1.0 / a[k, k]
        for j in range(m):
            s = b[k, j]
            for i in range(k + 1, r):
                s -= a[k, i] * b[i, j]
            b[k, j] = s * inv
    return True


def _solve_rows(  # noqa: PLR0917 - numba helper (inlined): positional arrays
    grow: FloatArray,
    frow: FloatArray,
    x: FloatArray,
    amat: FloatArray,
    r: int,
    nv: int,
    eps: float,
) -> bool:
    """The equality system of r rows in place: amat = G F^T + eps I (rows G = grow, F =
    frow, (r, nv) each), x[:, 1:] = -G next to the gap column x[:, 0], then the LU solve of
    amat x = x (`_lu_solve_inplace`); False when singular. Shared by the reduced-dynamics
    kernel here and the fused entry kernel of `step_kernels`."""
    for i in range(r):
        for j in range(nv):
            x[i, 1 + j] = -grow[i, j]
        for j in range(r):
            s = 0.0
            for k in range(nv):
                s += grow[i, k] * frow[j, k]
            amat[i, j] = s
        amat[i, i] += eps
    return _lu_solve_inplace(amat, x, r, 1 + nv)


def _contact_violation(  # noqa: PLR0917 - numba helper (inlined): positional scalars
    mc: int,
    gr: float,
    vtc: float,
    lnc: float,
    ltc: float,
    acc: tuple[float, float],
    scales: tuple[float, float, float],
) -> tuple[float, float, float]:
    """One contact's terms of the violation score, added to acc = (v_sq, imp) in the order
    of the original sums: the velocity a mode forbids (separating gap rate, slip against a
    sliding direction) over scales[0], a negative normal impulse over scales[1] (magnitude
    floor scales[2]). Returns (v_sq, imp, mag) with mag = |ln| + |lt| + floor; the caller
    adds a sticking contact's friction, cap and mag - floor to its obstacle group's sums.
    Shared by `_kernel` and the entry kernels of `step_kernels`.

    Scalars only: the same helper writing the group sums into arrays it was handed made the
    fused entry kernel 1.8-2.7x slower (the compiler then kept no entry value in registers).
    """
    v_sq, imp = acc
    sc_velocity, sc_impulse, sc_floor = scales
    v_neg = 0.0
    if mc == _SEP:
        v_neg = -gr
    elif mc == _POS:
        v_neg = -vtc
    elif mc == _NEG:
        v_neg = vtc
    if v_neg > 0.0:
        v_sq += (v_neg / sc_velocity) ** 2
    mag = abs(lnc) + abs(ltc) + sc_floor
    if mc != _SEP and lnc < 0.0:
        imp += (-lnc / mag / sc_impulse) ** 2
    return v_sq, imp, mag


def _group_violation(
    imp: float,
    n_groups: int,
    groups: tuple[FloatArray, FloatArray, FloatArray],
    sc_impulse: float,
    sc_floor: float,
) -> float:
    """imp plus the friction-cone violation of each obstacle group's sticking contacts
    (|sum lt| above sum mu ln), in group order."""
    lt_g, cap_g, mag_g = groups
    for k in range(n_groups):
        viol = abs(lt_g[k]) - cap_g[k]
        if viol > 0.0:
            imp += (viol / (mag_g[k] + sc_floor) / sc_impulse) ** 2
    return imp


def _kernel(  # noqa: PLR0917 - numba entry point: positional arrays, no keyword-only args
    md: IntArray,
    vf: FloatArray,
    jn: FloatArray,
    jt: FloatArray,
    phi: FloatArray,
    vne: FloatArray,
    vte: FloatArray,
    minv: FloatArray,
    mass: FloatArray,
    has_mass: bool,
    mu_rows: FloatArray,
    gi: IntArray,
    ui: IntArray,
    group: IntArray,
    n_groups: int,
    dt: float,
    eps_rel: float,
    sc_impulse: float,
    sc_velocity: float,
    sc_floor: float,
    sensitivity: bool,
    v_next: FloatArray,
    ln: FloatArray,
    lt: FloatArray,
    gap_rate: FloatArray,
    vt: FloatArray,
    score: FloatArray,
    resp: FloatArray,
    irs: FloatArray,
) -> int:
    """Fill the outputs of every lead element; returns the number of singular systems.
    The steps are marked and mirror the numpy path of `solve_reduced`."""
    # Long because: one fused loop with the scratch arrays allocated once keeps each
    # element's temporaries in registers; its sibling, the entry kernel of `step_kernels` (the same
    # steps per live entry) split into inlined helpers measured 1.5x slower.
    n_g, n_c = md.shape
    nv = vf.shape[1]
    n_m = gi.shape[0]
    two_c = 2 * n_c
    # -- M^-1 [Jn; Jt]^T rows per geometry element and the Tikhonov scale ------------------
    mw = np.empty((n_g, two_c, nv))
    lu = np.empty((nv, nv))
    rhs_m = np.empty((nv, two_c))
    n_max = 0
    for g in range(n_g):
        cnt = 0
        for c in range(n_c):
            if md[g, c] != _SEP:
                cnt += 1
        n_max = max(n_max, cnt)
    n_bad = 0
    for g in range(n_g):
        if has_mass:
            for i in range(nv):
                for j in range(nv):
                    lu[i, j] = mass[g, i, j]
                for c in range(n_c):
                    rhs_m[i, c] = jn[g, c, i]
                    rhs_m[i, n_c + c] = jt[g, c, i]
            if not _lu_solve_inplace(lu, rhs_m, nv, two_c):
                n_bad += 1
            for c in range(two_c):
                for i in range(nv):
                    mw[g, c, i] = rhs_m[i, c]
        else:
            for c in range(n_c):
                for i in range(nv):
                    mw[g, c, i] = jn[g, c, i] * minv[g, i]
                    mw[g, n_c + c, i] = jt[g, c, i] * minv[g, i]
    # -- per lead element -----------------------------------------------------------------
    rows = np.empty(two_c, dtype=np.int64)  # slot of each equality row (c or C + c)
    grow = np.empty((two_c, nv))  # constraint rows G
    frow = np.empty((two_c, nv))  # M^-1 F^T rows
    amat = np.empty((two_c, two_c))
    x = np.empty((two_c, 1 + nv))
    cpl = np.zeros(n_c)
    lt_g = np.zeros(max(n_groups, 1))
    cap_g = np.zeros(max(n_groups, 1))
    mag_g = np.zeros(max(n_groups, 1))
    an = np.empty(n_c)
    at = np.empty(n_c)
    last_fix = -1  # lead element whose friction-free solution can be reused
    for m in range(n_m):
        g = gi[m]
        u = ui[m]
        n_act = 0
        n_stick = 0
        slides = False
        for c in range(n_c):
            mc = md[g, c]
            if mc != _SEP:
                n_act += 1
            if mc == _STICK:
                n_stick += 1
            if mc >= _POS:
                slides = True
        reuse = (not slides) and last_fix >= 0 and gi[last_fix] == g
        if reuse:
            for c in range(n_c):
                ln[m, c] = ln[last_fix, c]
                lt[m, c] = lt[last_fix, c]
            for i in range(nv):
                v_next[m, i] = v_next[last_fix, i]
                for j in range(nv):
                    resp[m, i, j] = resp[last_fix, i, j]
            if sensitivity:
                for k in range(2):
                    for c in range(n_c):
                        for i in range(nv):
                            irs[m, k, c, i] = irs[last_fix, k, c, i]
        else:
            # free-motion gap rates and slips of this geometry element
            for c in range(n_c):
                sn = 0.0
                st = 0.0
                for i in range(nv):
                    sn += jn[g, c, i] * vf[g, i]
                    st += jt[g, c, i] * vf[g, i]
                an[c] = sn - vne[g, c] + phi[g, c] / dt
                at[c] = st - vte[g, c]
            for i in range(nv):
                v_next[m, i] = vf[g, i]
                for j in range(nv):
                    resp[m, i, j] = 1.0 if i == j else 0.0
            for c in range(n_c):
                ln[m, c] = 0.0
                lt[m, c] = 0.0
                cpl[c] = 0.0
                if md[g, c] == _POS:
                    cpl[c] = mu_rows[u, c]
                elif md[g, c] == _NEG:
                    cpl[c] = -mu_rows[u, c]
            if sensitivity:
                for k in range(2):
                    for c in range(n_c):
                        for i in range(nv):
                            irs[m, k, c, i] = 0.0
            if n_act > 0:
                # Tikhonov scale: mean Delassus diagonal over the active contacts and the
                # first (n_max - n_act) separated ones (normal and tangent rows)
                extra = n_max - n_act
                dsum = 0.0
                for c in range(n_c):
                    take = md[g, c] != _SEP
                    if not take and extra > 0:
                        take = True
                        extra -= 1
                    if take:
                        for i in range(nv):
                            dsum += jn[g, c, i] * mw[g, c, i] + jt[g, c, i] * mw[g, n_c + c, i]
                eps = eps_rel * max(dsum / (2 * n_max), 1e-300)
                r = 0
                for c in range(n_c):  # normal rows of the active contacts, in contact order
                    if md[g, c] != _SEP:
                        rows[r] = c
                        for i in range(nv):
                            grow[r, i] = jn[g, c, i]
                            frow[r, i] = mw[g, c, i] - cpl[c] * mw[g, n_c + c, i]
                        x[r, 0] = -an[c]
                        r += 1
                for c in range(n_c):  # tangent rows of the sticking contacts
                    if md[g, c] == _STICK:
                        rows[r] = n_c + c
                        for i in range(nv):
                            grow[r, i] = jt[g, c, i]
                            frow[r, i] = mw[g, n_c + c, i]
                        x[r, 0] = -at[c]
                        r += 1
                if not _solve_rows(grow, frow, x, amat, r, nv, eps):
                    n_bad += 1
                for j in range(r):
                    for i in range(nv):
                        v_next[m, i] += frow[j, i] * x[j, 0]
                        for k in range(nv):
                            resp[m, i, k] += frow[j, i] * x[j, 1 + k]
                for j in range(r):
                    slot = rows[j]
                    if slot < n_c:
                        ln[m, slot] = x[j, 0]
                    else:
                        lt[m, slot - n_c] = x[j, 0]
                for c in range(n_c):
                    lt[m, c] -= cpl[c] * ln[m, c]
                if sensitivity:
                    for j in range(r):
                        slot = rows[j]
                        k = 0 if slot < n_c else 1
                        for i in range(nv):
                            irs[m, k, slot % n_c, i] = x[j, 1 + i]
                    for c in range(n_c):
                        for i in range(nv):
                            irs[m, 1, c, i] -= cpl[c] * irs[m, 0, c, i]
            if not slides:
                last_fix = m
        # -- gap rates, slips and the violation score of element m ------------------------
        v_sq = 0.0
        imp = 0.0
        for k in range(n_groups):
            lt_g[k] = 0.0
            cap_g[k] = 0.0
            mag_g[k] = 0.0
        for c in range(n_c):
            sn = 0.0
            st = 0.0
            for i in range(nv):
                sn += jn[g, c, i] * v_next[m, i]
                st += jt[g, c, i] * v_next[m, i]
            gr = sn - vne[g, c] + phi[g, c] / dt
            vtc = st - vte[g, c]
            gap_rate[m, c] = gr
            vt[m, c] = vtc
            mc = md[g, c]
            lnc = ln[m, c]
            ltc = lt[m, c]
            v_sq, imp, mag = _contact_violation(
                mc, gr, vtc, lnc, ltc, (v_sq, imp), (sc_velocity, sc_impulse, sc_floor)
            )
            if mc == _STICK:  # friction, cap and magnitude of the contact's obstacle group
                kg = group[c]
                lt_g[kg] += ltc
                cap_g[kg] += mu_rows[u, c] * lnc
                mag_g[kg] += mag - sc_floor
        imp = _group_violation(imp, n_groups, (lt_g, cap_g, mag_g), sc_impulse, sc_floor)
        score[m] = v_sq + (imp if n_act + n_stick <= nv else 0.0)
    return n_bad


def _gaussian_kernel(  # noqa: PLR0917 - numba entry point: positional arrays
    y: FloatArray,
    vh: FloatArray,
    sv: FloatArray,
    s_diag: FloatArray,
    dt: float,
    log_pred: FloatArray,
    v_mean: FloatArray,
    v_cov: FloatArray,
) -> None:
    """Per element m: S = dt^2 sv + s_diag = L L^T (pivots clipped at 1e-300 as in
    `observation._chol_of`), Z = L^-1 [y, dt sv^T], log_pred = log N(y; 0, S),
    v_mean = vh + Z_c^T Z_y, v_cov = sv - Z_c^T Z_c."""
    n_m, n = y.shape
    low = np.zeros((n, n))
    z = np.empty((n, n + 1))
    log_2pi = np.log(2.0 * np.pi)
    dt2 = dt * dt
    for m in range(n_m):
        for j in range(n):
            d = dt2 * sv[m, j, j] + s_diag[j, j]
            for k in range(j):
                d -= low[j, k] * low[j, k]
            ljj = np.sqrt(max(d, 1e-300))
            low[j, j] = ljj
            for i in range(j + 1, n):
                num = dt2 * sv[m, i, j] + s_diag[i, j]
                for k in range(j):
                    num -= low[i, k] * low[j, k]
                low[i, j] = num / ljj
        logdet = 0.0
        maha = 0.0
        for i in range(n):
            z[i, 0] = y[m, i]
            for v in range(n):
                z[i, 1 + v] = sv[m, v, i] * dt
            for col in range(n + 1):
                s = 0.0
                for k in range(i):
                    s += low[i, k] * z[k, col]
                z[i, col] = (z[i, col] - s) / low[i, i]
            maha += z[i, 0] * z[i, 0]
            logdet += np.log(low[i, i])
        log_pred[m] = -0.5 * (maha + 2.0 * logdet + n * log_2pi)
        for a in range(n):
            cx = 0.0
            for i in range(n):
                cx += z[i, 1 + a] * z[i, 0]
            v_mean[m, a] = vh[m, a] + cx
            for b in range(n):
                cx = 0.0
                for i in range(n):
                    cx += z[i, 1 + a] * z[i, 1 + b]
                v_cov[m, a, b] = sv[m, a, b] - cx


if AVAILABLE:
    _lu_solve_inplace = numba.njit(cache=True, nogil=True)(_lu_solve_inplace)
    _solve_rows = numba.njit(cache=True, nogil=True, inline="always")(_solve_rows)
    _contact_violation = numba.njit(cache=True, nogil=True, inline="always")(_contact_violation)
    _group_violation = numba.njit(cache=True, nogil=True, inline="always")(_group_violation)
    _kernel = numba.njit(cache=True, nogil=True)(_kernel)
    _gaussian_kernel = numba.njit(cache=True, nogil=True)(_gaussian_kernel)


def gaussian_update(
    y: FloatArray, vh: FloatArray, sv: FloatArray, *, s_diag: FloatArray, dt: float
) -> tuple[FloatArray, FloatArray, FloatArray]:
    """Kalman-form update of the velocity v' ~ N(vh, sv) by an observation of every position
    dim o = q + dt v' + noise (noise covariance s_diag (n, n)): innovation y (M, n),
    vh (M, n), sv (M, n, n), all contiguous. Returns log p(y) (M,), the posterior mean (M, n)
    and covariance (M, n, n) of v' (see `observation.gaussian_proposal`)."""
    n_m, n = y.shape
    log_pred = np.empty(n_m)
    v_mean = np.empty((n_m, n))
    v_cov = np.empty((n_m, n, n))
    _gaussian_kernel(y, vh, sv, np.ascontiguousarray(s_diag), float(dt), log_pred, v_mean, v_cov)
    return log_pred, v_mean, v_cov


def reduced_dynamics(
    md: IntArray,
    vf: FloatArray,
    *,
    jn: FloatArray,
    jt: FloatArray,
    phi: FloatArray,
    vne: FloatArray,
    vte: FloatArray,
    minv: FloatArray,
    mass: FloatArray | None,
    mu_rows: FloatArray,
    gi: IntArray,
    ui: IntArray,
    group: IntArray,
    dt: float,
    eps_rel: float,
    scales: tuple[float, float, float],
    sensitivity: bool,
) -> tuple[dict[str, FloatArray], int]:
    """Run the kernel on geometry elements (G, ...) and lead elements (M,) = (gi, ui).

    md (G, C) modes; vf (G, nv); jn, jt (G, C, nv); phi, vne, vte (G, C); minv (G, nv) the
    diagonal of M^-1 (ignored when mass (G, nv, nv) is given); mu_rows (U, C); gi, ui (M,)
    the geometry element and mu row of each lead element; group (C,) obstacle group index of
    each contact (0..n-1); scales = (impulse, velocity, impulse_floor). Returns the outputs
    (v_next, ln, lt, gap_rate, vt, score, response, impulse_response) flattened over M and
    the number of singular systems met.
    """
    n_m = gi.shape[0]
    n_c = md.shape[1]
    nv = vf.shape[1]
    out: dict[str, Any] = {
        "v_next": np.empty((n_m, nv)),
        "ln": np.empty((n_m, n_c)),
        "lt": np.empty((n_m, n_c)),
        "gap_rate": np.empty((n_m, n_c)),
        "vt": np.empty((n_m, n_c)),
        "score": np.empty(n_m),
        "response": np.empty((n_m, nv, nv)),
        "impulse_response": np.empty((n_m if sensitivity else 0, 2, n_c, nv)),
    }
    n_groups = int(group.max()) + 1 if group.size else 0
    n_bad = _kernel(
        md,
        vf,
        jn,
        jt,
        phi,
        vne,
        vte,
        minv,
        np.zeros((0, nv, nv)) if mass is None else mass,
        mass is not None,
        mu_rows,
        gi,
        ui,
        group,
        n_groups,
        float(dt),
        float(eps_rel),
        float(scales[0]),
        float(scales[1]),
        float(scales[2]),
        bool(sensitivity),
        out["v_next"],
        out["ln"],
        out["lt"],
        out["gap_rate"],
        out["vt"],
        out["score"],
        out["response"],
        out["impulse_response"],
    )
    return out, int(n_bad)


def _insert_desc(  # noqa: PLR0917 - numba helper
    vals: FloatArray, idx: IntArray, n: int, cap: int, v: float, i: int
) -> int:
    """Insert (v, i) into the first n entries of vals/idx kept sorted by descending v, ties
    in insertion order (a stable sort of -v); at most cap entries. Returns the new n."""
    if n == cap and not v > vals[n - 1]:
        return n  # not better than the last kept (ties keep the earlier)
    pos = n if n < cap else cap - 1
    while pos > 0 and v > vals[pos - 1]:
        pos -= 1
    last = min(n, cap - 1)
    for j in range(last, pos, -1):
        vals[j] = vals[j - 1]
        idx[j] = idx[j - 1]
    vals[pos] = v
    idx[pos] = i
    return min(n + 1, cap)


def _feasible(  # noqa: PLR0917 - numba helper: positional arrays
    modes: IntArray,
    crowded: IntArray,
    forbidden: IntArray,
    same: IntArray,
    phi: FloatArray,
    has_phi: bool,
    both_tolerance: float,
) -> bool:
    """`contact_modes.geometric_feasible` of one joint assignment modes (C,)."""
    for g in range(crowded.shape[0]):
        n_in = 0
        for j in range(crowded.shape[1]):
            c = crowded[g, j]
            if c >= 0 and modes[c] != _SEP:
                n_in += 1
        if n_in > 2:
            return False
    for f in range(forbidden.shape[0]):
        if modes[forbidden[f, 0]] != _SEP and modes[forbidden[f, 1]] != _SEP:
            return False
    for s in range(same.shape[0]):
        a = same[s, 0]
        b = same[s, 1]
        both = modes[a] != _SEP and modes[b] != _SEP
        if both and (not has_phi or phi[a] + phi[b] > both_tolerance):
            return False
    return True


def _enumerate_kernel(  # noqa: PLR0917 - numba entry point: positional arrays
    order: IntArray,
    lsp: FloatArray,
    threshold: float,
    ranks: IntArray,
    n_keep: int,
    pre_k: int,
    phi: FloatArray,
    has_phi: bool,
    crowded: IntArray,
    forbidden: IntArray,
    same: IntArray,
    both_tolerance: float,
    n_live: IntArray,
    out_modes: IntArray,
    out_logp: FloatArray,
    out_valid: npt.NDArray[np.bool_],
    compact: bool,
    flat_modes: IntArray,
    flat_logp: FloatArray,
    counts: IntArray,
    lo: int,
    hi: int,
) -> int:
    """Per particle p of lo .. hi - 1: the joint hypotheses of
    `contact_modes.enumerate_hypotheses` (top n_keep by log prior among the feasible ones; with
    pre_k < T the pre_k most probable tuples are screened first, as there); returns the largest
    valid count. Only the tuples whose digits are live (digit c < n_live[p, c], (P, C), at most
    the radix) are visited, in tuple order: the others have log prior -inf and cannot be valid
    (the slots after the visited tuples stay empty: modes 0, log prior -inf, not valid).
    compact: write only the valid hypotheses, row after row from row lo n_keep, into flat_modes
    (>= P n_keep, C) and flat_logp, and their count per particle into counts (P,), instead of
    the padded out_* arrays."""
    # Long because: a numba entry point with 19 positional arrays (signature and docstring
    # are half of it); the per-particle odometer loop stays in one function so that the
    # scratch arrays are allocated once per call (the row output is already `_emit_row`).
    n_c = lsp.shape[1]
    n_t = ranks.shape[0]
    truncated = pre_k < n_t
    pre_v = np.empty(max(pre_k, 1))
    pre_i = np.empty(max(pre_k, 1), dtype=np.int64)
    top_v = np.empty(n_keep)
    top_i = np.empty(n_keep, dtype=np.int64)
    cand = np.empty(n_c, dtype=np.int64)
    # feasibility depends only on which contacts are in (and the particle's gaps): memoised
    # per particle by that bit mask (tuples that differ in stick / slide share it; 2x faster)
    use_memo = n_c <= _MEMO_CONTACTS
    memo_ok = np.zeros(1 << n_c if use_memo else 1, dtype=np.bool_)
    memo_p = np.full(1 << n_c if use_memo else 1, -1, dtype=np.int64)
    e = np.empty(n_keep)
    k_used = 1
    stride = np.ones(n_c, dtype=np.int64)  # C-order strides of the digit tuples
    for c in range(n_c - 2, -1, -1):
        stride[c] = stride[c + 1] * (ranks[n_t - 1, c + 1] + 1)
    digit = np.zeros(n_c, dtype=np.int64)
    part = np.zeros(n_c + 1)  # part[c + 1]: log prior of the digits of contacts 0 .. c
    offset = lo * n_keep
    for p in range(lo, hi):
        n_pre = 0
        n_top = 0
        # only the tuples of live digits (the others have log prior -inf), in tuple order
        for c in range(n_c):
            digit[c] = 0
        t_next = 0
        c_changed = 0  # the partial sums of contacts before it are still valid
        more = True
        while more:
            t = t_next
            part[1] = lsp[p, 0, digit[0]]  # (summed left to right, as one sum would be)
            for c in range(max(c_changed, 1), n_c):
                part[c + 1] = part[c] + lsp[p, c, digit[c]]
            lp = float(part[n_c])
            c = n_c - 1  # next tuple: odometer over digit[c] < n_live[p, c]
            while c >= 0:
                digit[c] += 1
                t_next += stride[c]
                if digit[c] < n_live[p, c]:
                    break
                t_next -= digit[c] * stride[c]
                digit[c] = 0
                c -= 1
            more = c >= 0
            c_changed = max(c, 0)
            if truncated:
                n_pre = _insert_desc(pre_v, pre_i, n_pre, pre_k, lp, t)
                continue
            if n_top == n_keep and not lp > top_v[n_keep - 1]:
                continue  # not kept, feasible or not (`_insert_desc`: ties keep the earlier)
            if lp > -np.inf:  # (a tuple with a dead mode stays -inf: no check needed)
                mask = 0
                for c in range(n_c):
                    cand[c] = order[p, c, ranks[t, c]]
                    if cand[c] != _SEP:
                        mask |= 1 << c
                if not use_memo:
                    ok = _feasible(cand, crowded, forbidden, same, phi[p], has_phi, both_tolerance)
                elif memo_p[mask] == p:
                    ok = memo_ok[mask]
                else:
                    ok = _feasible(cand, crowded, forbidden, same, phi[p], has_phi, both_tolerance)
                    memo_ok[mask] = ok
                    memo_p[mask] = p
                if not ok:
                    lp = -np.inf
            n_top = _insert_desc(top_v, top_i, n_top, n_keep, lp, t)
        if truncated:
            for r in range(n_pre):
                t = pre_i[r]
                lp = pre_v[r]
                if lp > -np.inf:
                    for c in range(n_c):
                        cand[c] = order[p, c, ranks[t, c]]
                    if not _feasible(
                        cand, crowded, forbidden, same, phi[p], has_phi, both_tolerance
                    ):
                        lp = -np.inf
                n_top = _insert_desc(top_v, top_i, n_top, n_keep, lp, t)
        n_valid, offset = _emit_row(
            p,
            (top_v, top_i, e, n_top),
            order,
            ranks,
            threshold,
            compact,
            (out_modes, out_logp, out_valid),
            (flat_modes, flat_logp, counts),
            offset,
        )
        k_used = max(k_used, n_valid)
    return k_used


def _emit_row(  # noqa: PLR0917 - numba helper (inlined): positional arrays
    p: int,
    top: tuple[FloatArray, IntArray, FloatArray, int],
    order: IntArray,
    ranks: IntArray,
    threshold: float,
    compact: bool,
    padded: tuple[IntArray, FloatArray, npt.NDArray[np.bool_]],
    flat: tuple[IntArray, FloatArray, IntArray],
    offset: int,
) -> tuple[int, int]:
    """Particle p's kept tuples top = (log priors, tuple indices, scratch, count), sorted:
    valid = the first, and those whose normalised probability is >= threshold; written to
    the padded arrays (modes, log prior, valid) or, compact, the valid ones to flat = (modes,
    log prior, counts) from row offset. Returns (valid count, next offset)."""
    top_v, top_i, e, n_top = top
    out_modes, out_logp, out_valid = padded
    flat_modes, flat_logp, counts = flat
    n_c = order.shape[1]
    m = top_v[0] if np.isfinite(top_v[0]) else 0.0
    tot = 0.0
    for k in range(n_top):
        e[k] = np.exp(top_v[k] - m) if top_v[k] > -np.inf else 0.0
        tot += e[k]
    tot = max(tot, 1e-300)
    n_valid = 0
    for k in range(n_top):
        t = top_i[k]
        ok = k == 0 or (np.isfinite(top_v[k]) and e[k] / tot >= threshold)
        if compact:  # the valid ones (a prefix: sorted by log prior), rows in order
            if ok:
                for c in range(n_c):
                    flat_modes[offset, c] = order[p, c, ranks[t, c]]
                flat_logp[offset] = top_v[k]
                offset += 1
        else:
            for c in range(n_c):
                out_modes[p, k, c] = order[p, c, ranks[t, c]]
            out_valid[p, k] = ok
            out_logp[p, k] = top_v[k] if ok else -np.inf
        if ok:
            n_valid += 1
    if compact:
        counts[p] = n_valid
    return n_valid, offset


def _prepare_kernel(  # noqa: PLR0917 - numba entry point: positional arrays
    mg: FloatArray,
    lg: FloatArray,
    threshold: float,
    order: IntArray,
    lsp: FloatArray,
    n_live: IntArray,
    lo: int,
    hi: int,
) -> None:
    """Per (particle p of lo .. hi - 1, contact): the modes by descending probability (a
    stable sort, as np.argsort(-mg, kind="stable")) into order, their log probabilities lg
    (= log mg) in that order into lsp (-inf where not live: below threshold, except the
    most probable) and the number of live modes into n_live (P, C)."""
    _, n_c, n_m = mg.shape
    for p in range(lo, hi):
        for c in range(n_c):
            for i in range(n_m):  # rank of mode i: larger ones, then equal ones before it
                v = mg[p, c, i]
                rank = 0
                for j in range(n_m):
                    w = mg[p, c, j]
                    rank += (w > v) or (w == v and j < i)
                order[p, c, rank] = i
            cnt = 0
            for i in range(n_m):
                k = order[p, c, i]
                live = i == 0 or mg[p, c, k] >= threshold
                lsp[p, c, i] = lg[p, c, k] if live else -np.inf
                if live:
                    cnt += 1
            n_live[p, c] = cnt


if AVAILABLE:
    _prepare_kernel = numba.njit(cache=True, nogil=True)(_prepare_kernel)
    # inlined: the calls per visited tuple cost ~20 % of the enumeration
    _insert_desc = numba.njit(cache=True, nogil=True, inline="always")(_insert_desc)
    _feasible = numba.njit(cache=True, nogil=True, inline="always")(_feasible)
    _emit_row = numba.njit(cache=True, nogil=True, inline="always")(_emit_row)
    _enumerate_kernel = numba.njit(cache=True, nogil=True)(_enumerate_kernel)


def prepare_tuples(
    mg: FloatArray, threshold: float, *, pool: RowPool | None = None
) -> tuple[IntArray, FloatArray, IntArray]:
    """Modes per (particle, contact) of the marginals mg (P, C, 4) by descending probability
    (stable): order (P, C, 4), their log probabilities lsp (P, C, 4) (-inf where not live:
    below threshold, except the most probable) and the live count (P, C). pool: threads
    over ranges of particles."""
    mga = np.ascontiguousarray(mg, dtype=np.float64)
    with np.errstate(divide="ignore"):
        lg = np.log(mga)
    order = np.empty(mga.shape, dtype=np.int64)
    lsp = np.empty(mga.shape)
    n_live = np.empty(mga.shape[:2], dtype=np.int64)
    args = (mga, lg, float(threshold), order, lsp, n_live)
    n_p = mga.shape[0]
    if pool is None or n_p < 2 * _MIN_PREPARE_ROWS:
        _prepare_kernel(*args, 0, n_p)
    else:
        pool.map(
            lambda lo, hi: _prepare_kernel(*args, lo, hi),
            pool.chunks(n_p, min_work=_MIN_PREPARE_ROWS),
        )
    return order, lsp, n_live


def work_buffer(
    work: dict[str, npt.NDArray[Any]] | None,
    name: str,
    shape: tuple[int, ...],
    dtype: type[np.generic] = np.float64,
) -> npt.NDArray[Any]:
    """An uninitialised array of `shape` and `dtype`: a view of the reusable buffer `name` of
    work (grown when too small), or a new array without work. Reusing the large per-step
    temporaries avoids the page faults of fresh allocations (glibc maps arrays above 128 kB
    anew each time; faults of threads writing one fresh array also contend)."""
    if work is None:
        return np.empty(shape, dtype=dtype)
    size = math.prod(shape)
    buf = work.get(name)
    if buf is None or buf.size < size or buf.dtype != np.dtype(dtype):
        buf = np.empty(max(size, 1024) + size // 4, dtype=dtype)
        work[name] = buf
    return buf[:size].reshape(shape)


_MIN_PREPARE_ROWS = 512
"""Fewest particles per thread of the mode ordering (`prepare_tuples`)."""
_MIN_ENUMERATION_VISITS = 4096
"""Fewest visited tuples per thread of the enumeration (~0.2 ms of work; smaller problems:
the calling thread). Split by tuples, not particles: 500 gripper particles at a contact visit
64 tuples each (1.7 ms on one thread)."""


def _run_enumeration(
    arrays: tuple[
        IntArray, FloatArray, IntArray, IntArray, FloatArray | None, tuple[IntArray, ...]
    ],
    numbers: tuple[float, int, int, float],
    padded: tuple[IntArray, FloatArray, npt.NDArray[np.bool_]],
    flat: tuple[IntArray, FloatArray, IntArray],
    *,
    compact: bool,
    bounds: list[tuple[int, int]] | None = None,
    pool: RowPool | None = None,
) -> int:
    """One call of `_enumerate_kernel` for `enumerate_tuples` / `enumerate_compact`:
    arrays = (order, lsp, n_live, ranks, phi or None, rules), numbers = (threshold, n_keep,
    pre_k, both_tolerance); the outputs go to `padded` (modes, log prior, valid) or, with
    `compact`, to `flat` (modes, log prior, counts; rows of range (lo, hi) from row
    lo n_keep). bounds: row ranges run on the threads of pool (default: all rows at once).
    Returns K, the largest valid count."""
    order, lsp, n_live, ranks, phi, rules = arrays
    threshold, n_keep, pre_k, both_tolerance = numbers
    n_p, n_c, _ = lsp.shape
    has_phi = phi is not None
    ph = np.zeros((n_p, n_c)) if phi is None else np.ascontiguousarray(phi, dtype=np.float64)
    args = (
        np.ascontiguousarray(order, dtype=np.int64),
        np.ascontiguousarray(lsp, dtype=np.float64),
        float(threshold),
        np.ascontiguousarray(ranks, dtype=np.int64),
        int(n_keep),
        int(pre_k),
        ph,
        has_phi,
        rules[0],
        rules[1],
        rules[2],
        float(both_tolerance),
        np.minimum(n_live, ranks[-1] + 1),  # (digits beyond the radix are not visited)
        *padded,
        compact,
        *flat,
    )
    bounds = [(0, n_p)] if bounds is None else bounds
    if pool is None or len(bounds) == 1:
        return max(int(_enumerate_kernel(*args, lo, hi)) for lo, hi in bounds)
    return max(pool.map(lambda lo, hi: int(_enumerate_kernel(*args, lo, hi)), bounds))


def enumerate_tuples(
    order: IntArray,
    lsp: FloatArray,
    *,
    n_live: IntArray,
    threshold: float,
    ranks: IntArray,
    n_keep: int,
    pre_k: int,
    phi: FloatArray | None,
    rules: tuple[IntArray, IntArray, IntArray],
    both_tolerance: float,
) -> tuple[IntArray, FloatArray, npt.NDArray[np.bool_]]:
    """Compiled `contact_modes.enumerate_hypotheses` core: order (P, C, 4) the modes of each
    contact by descending probability and lsp (P, C, 4) their log probabilities (-inf where
    not live), in that order; n_live (P, C) the live modes of each contact; ranks
    (T, C) the mixed-radix digit tuples, n_keep = min(max_hypotheses, pre_k) columns, phi
    (P, C) gaps or None, rules = (crowded (G, L) padded with -1, forbidden (F, 2), same
    feature (S, 2)). Returns modes (P, K, C), log prior (P, K), valid (P, K), K the largest
    valid count (>= 1)."""
    n_p, n_c, _ = lsp.shape
    out_modes = np.zeros((n_p, n_keep, n_c), dtype=np.int64)
    out_logp = np.full((n_p, n_keep), -np.inf)
    out_valid = np.zeros((n_p, n_keep), dtype=np.bool_)
    flat = (np.zeros((0, n_c), dtype=np.int64), np.zeros(0), np.zeros(0, dtype=np.int64))
    k_used = _run_enumeration(
        (order, lsp, n_live, ranks, phi, rules),
        (threshold, n_keep, pre_k, both_tolerance),
        (out_modes, out_logp, out_valid),
        flat,
        compact=False,
    )
    return out_modes[:, :k_used], out_logp[:, :k_used], out_valid[:, :k_used]


def enumerate_compact(
    order: IntArray,
    lsp: FloatArray,
    *,
    n_live: IntArray,
    threshold: float,
    ranks: IntArray,
    n_keep: int,
    pre_k: int,
    phi: FloatArray | None,
    rules: tuple[IntArray, IntArray, IntArray],
    both_tolerance: float,
    pool: RowPool | None = None,
    work: dict[str, npt.NDArray[Any]] | None = None,
) -> tuple[IntArray, FloatArray, IntArray, int]:
    """`enumerate_tuples` with the valid hypotheses only, row after row: modes (N, C), log
    prior (N,), the count of each particle (P,) and K, the largest count (the width of the
    padded layout). No padded (P, K, C) array is built. pool: threads over ranges of
    particles (the same result for any split); work: reusable scratch buffers (the results
    are new arrays all the same)."""
    n_p, n_c, _ = lsp.shape
    flat_modes = work_buffer(work, "enumeration_modes", (n_p * n_keep, n_c), np.int64)
    flat_logp = work_buffer(work, "enumeration_logp", (n_p * n_keep,))
    counts = np.empty(n_p, dtype=np.int64)
    bounds = [(0, n_p)]
    if pool is not None and pool.threads > 1 and n_p >= 2:
        # work of a particle ~ the tuples of live modes it visits
        visits = np.minimum(n_live, ranks[-1] + 1).prod(axis=1)
        starts = np.concatenate([[0], np.cumsum(visits)])
        bounds = pool.chunks(n_p, starts=starts, min_work=_MIN_ENUMERATION_VISITS)
    padded = (
        np.zeros((0, n_keep, n_c), dtype=np.int64),
        np.zeros((0, n_keep)),
        np.zeros((0, n_keep), dtype=np.bool_),
    )
    k_used = _run_enumeration(
        (order, lsp, n_live, ranks, phi, rules),
        (threshold, n_keep, pre_k, both_tolerance),
        padded,
        (flat_modes, flat_logp, counts),
        compact=True,
        bounds=bounds,
        pool=pool,
    )
    if len(bounds) > 1:  # each range wrote from row lo n_keep: close the gaps
        keep = np.concatenate(
            [np.arange(lo * n_keep, lo * n_keep + counts[lo:hi].sum()) for lo, hi in bounds]
        )
        return flat_modes[keep], flat_logp[keep], counts, int(k_used)
    n = int(counts.sum())
    return flat_modes[:n].copy(), flat_logp[:n].copy(), counts, int(k_used)
