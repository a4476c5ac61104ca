"""Reference (pre-optimisation) implementation of `contact_modes.solve_reduced`.

The padded 2n x 2n formulation with one generic batched `np.linalg.solve` per (assignment,
friction) element, kept verbatim for equivalence tests of the optimised solver.
"""

from __future__ import annotations

import numpy as np
import numpy.typing as npt

from dbcslam_core.contact_modes import Mode, ReducedSolution, ViolationScales, violation_score
from dbcslam_core.errors import SolverError

FloatArray = npt.NDArray[np.float64]
IntArray = npt.NDArray[np.int64]


def solve_reduced_reference(
    modes: npt.ArrayLike,
    v_free: npt.ArrayLike,
    *,
    inv_mass: npt.ArrayLike,
    jn: npt.ArrayLike,
    jt: npt.ArrayLike,
    phi: npt.ArrayLike,
    vn_env: npt.ArrayLike,
    vt_env: npt.ArrayLike,
    mu: npt.ArrayLike,
    dt: float,
    scales: ViolationScales | None = None,
    eps_rel: float = 1e-10,
    groups: npt.ArrayLike | None = None,
    mass: npt.ArrayLike | None = None,
    impulse_sensitivity: bool = False,
) -> ReducedSolution:
    """The pre-optimisation `solve_reduced` (same arguments and result; see its docstring).

    Padded 2Ca x 2Ca systems over the contacts non-separated in some assignment, one generic
    batched solve per (assignment, friction) element: slow but simple, the test oracle.
    """
    sc = scales or ViolationScales()
    md = np.asarray(modes, dtype=np.int64)
    vf = np.asarray(v_free, dtype=np.float64)
    im = np.asarray(inv_mass, dtype=np.float64)
    jn_a = np.asarray(jn, dtype=np.float64)
    jt_a = np.asarray(jt, dtype=np.float64)
    phi_a = np.asarray(phi, dtype=np.float64)
    vne = np.asarray(vn_env, dtype=np.float64)
    vte = np.asarray(vt_env, dtype=np.float64)
    mu_a = np.asarray(mu, dtype=np.float64)
    n_c = md.shape[-1]
    nv = vf.shape[-1]
    lead = np.broadcast_shapes(
        md.shape[:-1],
        vf.shape[:-1],
        im.shape[:-1],
        jn_a.shape[:-2],
        jt_a.shape[:-2],
        phi_a.shape[:-1],
        vne.shape[:-1],
        vte.shape[:-1],
        mu_a.shape[:-1],
    )
    # Free-motion contact velocities (independent of the assignment).
    an = (jn_a @ vf[..., None])[..., 0] - vne + phi_a / dt
    at = (jt_a @ vf[..., None])[..., 0] - vte

    mdb = np.broadcast_to(md, (*lead, n_c))
    act = np.flatnonzero(np.any(mdb != Mode.SEPARATED, axis=tuple(range(len(lead)))))
    n_a = act.size
    n_m = int(np.prod(lead, dtype=np.int64))
    ln = np.zeros((n_m, n_c))
    lt = np.zeros((n_m, n_c))
    dv = np.zeros((n_m, nv))
    response = np.tile(np.eye(nv), (n_m, 1, 1))
    imp_resp = np.zeros((n_m, 2, n_c, nv)) if impulse_sensitivity else None
    if n_a:
        # All-separated entries keep v' = v_free (identity response). The others are solved
        # over their own non-separated contacts only: each row's active contacts are moved to
        # the front, so the systems are 2n x 2n with n the largest active count of a row.
        rows = np.flatnonzero(np.any(mdb != Mode.SEPARATED, axis=-1).reshape(n_m))

        def flat(x: FloatArray, tail: tuple[int, ...]) -> FloatArray:
            return np.broadcast_to(x, (*lead, *tail)).reshape(n_m, *tail)[rows]

        m_rows = mdb.reshape(n_m, n_c)[rows]
        is_sep = m_rows == Mode.SEPARATED
        n_max = int((~is_sep).sum(axis=1).max())
        idx = np.argsort(is_sep, axis=1, kind="stable")[:, :n_max]  # (M, n_max)
        idx3 = idx[..., None]
        ln_s, lt_s, dv_s, resp_s, dlam_s = _solve_active(
            np.take_along_axis(m_rows, idx, axis=1),
            vf=flat(vf, (nv,)),
            im=flat(im, (nv,)),
            jn_act=np.take_along_axis(flat(jn_a, (n_c, nv)), idx3, axis=1),
            jt_act=np.take_along_axis(flat(jt_a, (n_c, nv)), idx3, axis=1),
            an_b=np.take_along_axis(flat(an, (n_c,)), idx, axis=1),
            at_b=np.take_along_axis(flat(at, (n_c,)), idx, axis=1),
            mu_act=np.take_along_axis(flat(mu_a, (n_c,)), idx, axis=1),
            eps_rel=eps_rel,
            mass=None if mass is None else flat(np.asarray(mass, dtype=np.float64), (nv, nv)),
        )
        ln[rows[:, None], idx] = ln_s
        lt[rows[:, None], idx] = lt_s
        dv[rows] = dv_s
        response[rows] = resp_s
        if imp_resp is not None:
            sub = imp_resp[rows]  # (M, 2, C, nv)
            r_ix = np.arange(rows.size)[:, None]
            sub[r_ix, 0, idx] = dlam_s[:, :n_max]
            sub[r_ix, 1, idx] = dlam_s[:, n_max:]
            imp_resp[rows] = sub
    ln = ln.reshape(*lead, n_c)
    lt = lt.reshape(*lead, n_c)
    dv = dv.reshape(*lead, nv)
    response = response.reshape(*lead, nv, nv)
    v_next = np.broadcast_to(vf, (*lead, nv)) + dv
    gap_rate = (jn_a @ v_next[..., None])[..., 0] - vne + phi_a / dt
    vt = (jt_a @ v_next[..., None])[..., 0] - vte
    gap_rate = np.broadcast_to(gap_rate, (*lead, n_c))
    vt = np.broadcast_to(vt, (*lead, n_c))
    score = violation_score(mdb, ln, lt, gap_rate, vt, mu=mu_a, nv=nv, scales=sc, groups=groups)
    return ReducedSolution(
        v_next=np.asarray(v_next, dtype=np.float64),
        ln=ln,
        lt=lt,
        gap_rate=np.asarray(gap_rate, dtype=np.float64),
        vt=np.asarray(vt, dtype=np.float64),
        score=np.asarray(score, dtype=np.float64),
        response=np.asarray(response, dtype=np.float64),
        impulse_response=None
        if imp_resp is None
        else np.asarray(imp_resp.reshape(*lead, 2, n_c, nv), dtype=np.float64),
    )


def _solve_active(
    m_a: IntArray,
    *,
    vf: FloatArray,
    im: FloatArray,
    jn_act: FloatArray,
    jt_act: FloatArray,
    an_b: FloatArray,
    at_b: FloatArray,
    mu_act: FloatArray,
    eps_rel: float,
    mass: FloatArray | None = None,
) -> tuple[FloatArray, FloatArray, FloatArray, FloatArray, FloatArray]:
    """Impulses, dv, response and d lambda / d v_free (M, 2Ca, nv) of the reduced system on
    the active contacts (rows (M,))."""
    n_a = m_a.shape[-1]
    nv = vf.shape[-1]
    w = np.concatenate([jn_act, jt_act], axis=-2)  # (M, 2Ca, nv)
    if mass is None:
        wm = w * im[..., None, :]  # (M^-1 W^T)^T for a diagonal mass
    else:  # full effective mass: solved, not inverted
        wm = np.swapaxes(np.linalg.solve(mass, np.swapaxes(w, -1, -2)), -1, -2)
    d = wm @ np.swapaxes(w, -1, -2)
    diag_mean = np.mean(np.diagonal(d, axis1=-2, axis2=-1), axis=-1)
    eps = eps_rel * np.maximum(diag_mean, 1e-300)
    eye = np.eye(2 * n_a)
    sep = m_a == Mode.SEPARATED
    stick = m_a == Mode.STICKING
    pos = m_a == Mode.SLIDING_POS
    neg = m_a == Mode.SLIDING_NEG
    vel_row = np.concatenate([~sep, stick], axis=-1)
    amat = np.where(vel_row[..., None], d + eps[..., None, None] * eye, eye)
    coup = np.where(pos, mu_act, np.where(neg, -mu_act, 0.0))
    ar = np.arange(n_a)
    amat[..., n_a + ar, ar] += coup
    rhs = np.concatenate([np.where(~sep, -an_b, 0.0), np.where(stick, -at_b, 0.0)], -1)
    sens = np.concatenate(
        [np.where(~sep[..., None], -jn_act, 0.0), np.where(stick[..., None], -jt_act, 0.0)],
        axis=-2,
    )
    rhs_all = np.concatenate([rhs[..., None], sens], axis=-1)
    try:
        sol_all = np.linalg.solve(amat, rhs_all)
    except np.linalg.LinAlgError as err:
        msg = f"reduced dynamics system is singular for {m_a.shape[0]} assignments"
        raise SolverError(msg) from err
    lam = sol_all[..., 0]
    wt_sol = np.swapaxes(wm, -1, -2) @ sol_all  # M^-1 W^T sol
    dv = wt_sol[..., 0]
    response = np.eye(nv) + wt_sol[..., 1:]
    return lam[..., :n_a], lam[..., n_a:], dv, response, sol_all[..., 1:]
