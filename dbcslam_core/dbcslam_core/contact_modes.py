"""Discrete contact modes of a potential contact (Sec. III-A of the paper).

Mode order is the order of dim 1 of `/dbcslam/contact_modes` in the contract:
`separated, sticking, sliding_pos, sliding_neg`. Sliding directions refer to the relative
tangential velocity of the body w.r.t. the obstacle along the contact tangent
`t = (n_y, -n_x)` (the normal rotated by -90 degrees).
"""

from __future__ import annotations

import functools
from dataclasses import dataclass
from enum import IntEnum

import numpy as np
import numpy.typing as npt

from dbcslam_core.errors import SolverError

__all__ = [
    "MODE_NAMES",
    "N_MODES",
    "ContactLayout",
    "Hypotheses",
    "Mode",
    "ReducedSolution",
    "ViolationScales",
    "enumerate_hypotheses",
    "geometric_feasible",
    "solve_reduced",
    "violation_score",
]


class Mode(IntEnum):
    """Contact mode of one potential contact."""

    SEPARATED = 0
    STICKING = 1
    SLIDING_POS = 2
    SLIDING_NEG = 3


MODE_NAMES: tuple[str, ...] = ("separated", "sticking", "sliding_pos", "sliding_neg")
N_MODES: int = len(MODE_NAMES)


# ---------------------------------------------------------------------------------------------
# Reduced dynamics given a mode assignment (Sec. III-A), batched.
# ---------------------------------------------------------------------------------------------

FloatArray = npt.NDArray[np.float64]
IntArray = npt.NDArray[np.int64]
BoolArray = npt.NDArray[np.bool_]


@dataclass(frozen=True)
class ViolationScales:
    """Scales of the inequality violations of the reduced dynamics.

    Impulse inequalities (ln >= 0, |lt| <= mu ln) are measured relative to the contact's own
    impulse magnitude: max(0, violation) / (|ln| + |lt| + impulse_floor), divided by
    `impulse` (dimensionless); impulse_floor in N s. Velocity inequalities (gap rate
    phi/dt + Jn v' - vn_env >= 0 of separated contacts, slip sign of sliding contacts) are
    divided by `velocity` (m/s). The log factor of a hypothesis is -0.5 * sum(scaled^2).
    """

    impulse: float = 0.02
    velocity: float = 1e-2
    impulse_floor: float = 1e-4


@dataclass(frozen=True)
class ReducedSolution:
    """Solution of the reduced dynamics for a batch of mode assignments.

    v_next (..., nv) post-step velocity; ln, lt (..., C) normal / tangential impulses (N s);
    gap_rate (..., C) = phi/dt + Jn v' - vn_env (m/s); vt (..., C) = Jt v' - vt_env (m/s);
    score (...) = sum of squared scaled inequality violations (0 = all inequalities hold).
    response (..., nv, nv): d v_next / d v_free, the linear map through which a perturbation
    of the free velocity (e.g. force noise) reaches v_next under this mode assignment
    (identity when every contact is separated; constrained directions are absorbed by the
    impulses, sliding friction follows the normal impulse).
    impulse_response (..., 2, C, nv) or None: d (ln, lt) / d v_free (N s per m/s), computed
    only when `solve_reduced(..., impulse_sensitivity=True)`; zero for separated contacts.
    """

    v_next: FloatArray
    ln: FloatArray
    lt: FloatArray
    gap_rate: FloatArray
    vt: FloatArray
    score: FloatArray
    response: FloatArray
    impulse_response: FloatArray | None = None


def solve_reduced(
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
    """Solve the reduced (mode-fixed) time-stepping dynamics for all assignments at once.

    Shapes broadcast over any leading axes (...): modes (..., C) ints (Mode values);
    v_free (..., nv) = v + dt M^-1 F (velocity without contact impulses, m/s);
    inv_mass (..., nv) the diagonal of M^-1; jn, jt (..., C, nv) contact Jacobians;
    phi (..., C) gaps (m); vn_env, vt_env (..., C) obstacle velocities (m/s);
    mu (..., C) friction coefficient of each contact; dt step (s).

    Equalities (Sec. III-A): separated ln = lt = 0; sticking gap_rate = 0 and vt = 0; sliding
    gap_rate = 0 and lt = -/+ mu ln. The impulses solve a 2Ca x 2Ca system built from the
    Delassus matrix W M^-1 W^T over the Ca contacts that are non-separated in some assignment
    (np.linalg.solve, batched; no inverse). A relative Tikhonov term eps_rel on the velocity rows
    keeps statically indeterminate assignments (more constraints than dofs) solvable: it only
    changes impulses in the null space of W^T, which does not move v'.

    mass (..., nv, nv) optional full (effective) mass matrix, e.g. M + dt K with the support
    friction K of `PlanarModel.support_matrix` (push scenario): replaces the diagonal
    `inv_mass` (solved, never inverted).

    groups (C,) optional obstacle index per contact: the friction cone of sticking contacts on
    the same flat obstacle is checked in aggregate, |sum lt| <= sum mu ln. Their tangential
    rows coincide, so only the sum of their friction impulses is determined, and a split
    inside every individual cone exists iff the aggregate holds (lt_i proportional to ln_i).
    Assignments with more equality rows than velocity dofs are statically indeterminate: only
    their velocity inequalities are scored (checking their impulse inequalities exactly would
    need a feasibility LP over the null space of the impulses; not done).

    impulse_sensitivity: also return d (ln, lt) / d v_free (`ReducedSolution.impulse_response`),
    e.g. to propagate force process noise into a predicted contact force.
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


@functools.lru_cache(maxsize=64)
def _group_onehot(groups: tuple[int, ...]) -> FloatArray:
    """(C, G) membership of each contact in its obstacle group (cached: called per step)."""
    g = np.asarray(groups, dtype=np.int64)
    out = np.asarray((g[:, None] == np.unique(g)[None, :]), dtype=np.float64)
    out.setflags(write=False)
    return out


def violation_score(
    modes: npt.ArrayLike,
    ln: npt.ArrayLike,
    lt: npt.ArrayLike,
    gap_rate: npt.ArrayLike,
    vt: npt.ArrayLike,
    *,
    mu: npt.ArrayLike,
    nv: int,
    scales: ViolationScales | None = None,
    groups: npt.ArrayLike | None = None,
) -> FloatArray:
    """Sum of squared scaled inequality violations (...) of reduced solutions (see
    `solve_reduced`); all arguments (..., C) broadcast together (mu e.g. per friction
    hypothesis), nv the velocity dofs (for the determinacy test)."""
    sc = scales or ViolationScales()
    md = np.asarray(modes, dtype=np.int64)
    ln_a = np.asarray(ln, dtype=np.float64)
    lt_a = np.asarray(lt, dtype=np.float64)
    gr = np.asarray(gap_rate, dtype=np.float64)
    vt_a = np.asarray(vt, dtype=np.float64)
    mu_a = np.asarray(mu, dtype=np.float64)
    shape = np.broadcast_shapes(md.shape, ln_a.shape, lt_a.shape, gr.shape, vt_a.shape, mu_a.shape)
    mdb = np.broadcast_to(md, shape)
    ln_b = np.broadcast_to(ln_a, shape)
    lt_b = np.broadcast_to(lt_a, shape)
    mu_b = np.broadcast_to(mu_a, shape)
    sep_all = mdb == Mode.SEPARATED
    v_sep = np.where(sep_all, np.maximum(0.0, -gr), 0.0)
    v_slip = np.where(
        mdb == Mode.SLIDING_POS,
        np.maximum(0.0, -vt_a),
        np.where(mdb == Mode.SLIDING_NEG, np.maximum(0.0, vt_a), 0.0),
    )
    mag = np.abs(ln_b) + np.abs(lt_b) + sc.impulse_floor
    i_neg = np.where(sep_all, 0.0, np.maximum(0.0, -ln_b)) / mag
    stick_all = mdb == Mode.STICKING
    if groups is None:
        i_cone = np.where(stick_all, np.maximum(0.0, np.abs(lt_b) - mu_b * ln_b), 0.0) / mag
        cone_sq = np.sum((i_cone / sc.impulse) ** 2, axis=-1)
    else:
        onehot = _group_onehot(tuple(int(x) for x in np.asarray(groups).reshape(-1)))
        lt_g = np.einsum("...c,cg->...g", np.where(stick_all, lt_b, 0.0), onehot)
        cap_g = np.einsum("...c,cg->...g", np.where(stick_all, mu_b * ln_b, 0.0), onehot)
        mag_g = np.einsum(
            "...c,cg->...g", np.where(stick_all, mag - sc.impulse_floor, 0.0), onehot
        )
        i_cone_g = np.maximum(0.0, np.abs(lt_g) - cap_g) / (mag_g + sc.impulse_floor)
        cone_sq = np.sum((i_cone_g / sc.impulse) ** 2, axis=-1)
    # Statically indeterminate assignments (more equality rows than dofs, e.g. a triangle
    # wedged between both jaws) have a family of impulse solutions; the min-norm one computed
    # here need not be the feasible one, so their impulse inequalities are not scored.
    n_rows = np.sum(~sep_all, axis=-1) + np.sum(stick_all, axis=-1)
    determinate = n_rows <= nv
    imp_sq = np.where(determinate, np.sum((i_neg / sc.impulse) ** 2, axis=-1) + cone_sq, 0.0)
    score = np.sum(((v_sep + v_slip) / sc.velocity) ** 2, axis=-1) + imp_sq
    return np.asarray(score, dtype=np.float64)


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


# ---------------------------------------------------------------------------------------------
# Geometric feasibility and joint-hypothesis enumeration.
# ---------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class ContactLayout:
    """Static description of the potential contacts needed for geometric exclusions.

    feature_vertex[c]: body vertex of contact c (-1 for a point mass origin / outline);
    obstacle[c]: obstacle index; n_vertices: polygon vertex count (0 for a point mass).
    """

    feature_vertex: tuple[int, ...]
    obstacle: tuple[int, ...]
    n_vertices: int

    @property
    def n_contacts(self) -> int:
        """Number of potential contacts."""
        return len(self.obstacle)

    def forbidden_pairs(self) -> tuple[tuple[int, int], ...]:
        """Contact pairs that can never be in contact together: two non-adjacent vertices of
        a convex polygon on the same (flat) obstacle."""
        out: list[tuple[int, int]] = []
        nv = self.n_vertices
        for a in range(self.n_contacts):
            for b in range(a + 1, self.n_contacts):
                va, vb = self.feature_vertex[a], self.feature_vertex[b]
                if va < 0 or vb < 0 or self.obstacle[a] != self.obstacle[b]:
                    continue
                adjacent = abs(va - vb) == 1 or abs(va - vb) == nv - 1
                if not adjacent:
                    out.append((a, b))
        return tuple(out)

    def same_feature_pairs(self) -> tuple[tuple[int, int], ...]:
        """Pairs of contacts of the same body feature with two different obstacles."""
        out: list[tuple[int, int]] = []
        for a in range(self.n_contacts):
            for b in range(a + 1, self.n_contacts):
                if (
                    self.feature_vertex[a] == self.feature_vertex[b]
                    and self.obstacle[a] != self.obstacle[b]
                ):
                    out.append((a, b))
        return tuple(out)


def geometric_feasible(
    layout: ContactLayout,
    modes: npt.ArrayLike,
    phi: npt.ArrayLike | None = None,
    both_tolerance: float = 2e-3,
) -> BoolArray:
    """Which joint mode assignments (..., C) are geometrically possible.

    Excluded: more than two vertices of a convex polygon on one flat obstacle, two
    non-adjacent vertices on one obstacle (e.g. all three triangle vertices on one jaw), and
    one feature touching two obstacles unless its two gaps sum to less than `both_tolerance`
    (m; phi (..., C) broadcastable, e.g. jaws closed on the vertex). Without phi the latter
    combination is always excluded.
    """
    md = np.asarray(modes)
    inc = md != Mode.SEPARATED
    ok = np.ones(md.shape[:-1], dtype=bool)
    for obst in sorted(set(layout.obstacle)):
        idx = [c for c in range(layout.n_contacts) if layout.obstacle[c] == obst]
        if layout.n_vertices > 0 and len(idx) > 2:
            ok &= inc[..., idx].sum(axis=-1) <= 2
    for a, b in layout.forbidden_pairs():
        ok &= ~(inc[..., a] & inc[..., b])
    pairs = layout.same_feature_pairs()
    if pairs:
        ph = None if phi is None else np.asarray(phi, dtype=np.float64)
        for a, b in pairs:
            both = inc[..., a] & inc[..., b]
            if ph is None:
                ok &= ~both
            else:
                ok &= ~(both & (ph[..., a] + ph[..., b] > both_tolerance))
    return np.asarray(ok, dtype=np.bool_)


@dataclass(frozen=True)
class Hypotheses:
    """Joint mode hypotheses per particle.

    modes (P, K, C) Mode values; log_prior (P, K) log of the product of the per-contact
    marginals, -inf where invalid; valid (P, K).
    """

    modes: IntArray
    log_prior: FloatArray
    valid: BoolArray

    @property
    def n_live(self) -> IntArray:
        """Live hypotheses per particle (P,)."""
        return np.asarray(self.valid.sum(axis=1), dtype=np.int64)


def enumerate_hypotheses(
    marginals: npt.ArrayLike,
    threshold: float,
    max_hypotheses: int,
    *,
    layout: ContactLayout | None = None,
    phi: npt.ArrayLike | None = None,
    max_tuples: int = 4096,
) -> Hypotheses:
    """Enumerate the live joint mode hypotheses of every particle at once (no Python loop
    over particles).

    marginals (P, C, 4): per-contact mode probabilities. Per contact the live modes are those
    with probability >= threshold (the most probable is always live). Joint hypotheses are the
    product of live modes, ranked by log prior (sum of log marginals); geometrically impossible
    ones (`geometric_feasible`) are removed, joint hypotheses whose normalised probability is
    below threshold are pruned (the best is always kept), and at most max_hypotheses are kept.
    """
    mg = np.asarray(marginals, dtype=np.float64)
    n_p, n_c, _ = mg.shape
    order = np.argsort(-mg, axis=-1, kind="stable")  # (P, C, 4)
    sp = np.take_along_axis(mg, order, axis=-1)
    live = sp >= threshold
    live[..., 0] = True
    n_live = live.sum(axis=-1)  # (P, C)
    radix = n_live.max(axis=0)  # (C,)
    while int(np.prod(radix)) > max_tuples:
        radix[int(np.argmax(radix))] -= 1
    n_t = int(np.prod(radix))
    ranks = np.stack(np.unravel_index(np.arange(n_t), tuple(int(r) for r in radix)), -1)
    with np.errstate(divide="ignore"):
        lsp = np.log(sp)  # (P, C, 4)
    lsp = np.where(live, lsp, -np.inf)
    cidx = np.arange(n_c)
    logp = lsp[:, cidx[None, :], ranks].sum(axis=-1)  # (P, T)
    pre_k = n_t if n_t * n_c * n_p <= 3_000_000 else min(n_t, 4 * max_hypotheses)
    if pre_k < n_t:
        sel = np.argpartition(-logp, pre_k - 1, axis=1)[:, :pre_k]
    else:
        sel = np.broadcast_to(np.arange(n_t), (n_p, n_t))
    logp_s = np.take_along_axis(logp, sel, axis=1)
    rk = ranks[sel]  # (P, T', C)
    modes_s = np.take_along_axis(order[:, None, :, :], rk[..., None], axis=-1)[..., 0]
    if layout is not None:
        ph = None if phi is None else np.asarray(phi, dtype=np.float64)[:, None, :]
        feas = geometric_feasible(layout, modes_s, ph)
        logp_s = np.where(feas, logp_s, -np.inf)
    k = min(max_hypotheses, logp_s.shape[1])
    top = np.argsort(-logp_s, axis=1, kind="stable")[:, :k]
    logp_k = np.take_along_axis(logp_s, top, axis=1)
    modes_k = np.take_along_axis(modes_s, top[..., None], axis=1)
    # Prune by normalised joint probability (keep the best hypothesis of each particle).
    m = logp_k[:, :1]
    m_safe = np.where(np.isfinite(m), m, 0.0)
    e = np.exp(logp_k - m_safe)
    norm = e / np.maximum(e.sum(axis=1, keepdims=True), 1e-300)
    valid = np.isfinite(logp_k) & (norm >= threshold)
    valid[:, 0] = True
    # Trim trailing columns nobody uses.
    k_used = max(1, int(valid.sum(axis=1).max()))
    modes_k = modes_k[:, :k_used]
    valid = valid[:, :k_used]
    logp_k = np.where(valid, logp_k[:, :k_used], -np.inf)
    return Hypotheses(
        modes=np.asarray(modes_k, dtype=np.int64),
        log_prior=np.asarray(logp_k, dtype=np.float64),
        valid=np.asarray(valid, dtype=np.bool_),
    )
