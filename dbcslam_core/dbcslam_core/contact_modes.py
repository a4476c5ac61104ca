"""Discrete contact modes of a potential contact (Sec. III-A of the paper).

Mode order is the order of dim 1 of `/dbcslam/contact_modes` in the contract:
`separated, sticking, sliding_pos, sliding_neg`. Sliding directions refer to the relative
tangential velocity of the body w.r.t. the obstacle along the contact tangent
`t = (n_y, -n_x)` (the normal rotated by -90 degrees).
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass
from enum import IntEnum
from typing import Any

import numpy as np
import numpy.typing as npt

from dbcslam_core import kernels
from dbcslam_core.errors import SolverError
from dbcslam_core.row_pool import RowPool

__all__ = [
    "DEFAULT_BACKEND",
    "MODE_NAMES",
    "N_MODES",
    "REDUCED_BACKENDS",
    "ContactLayout",
    "Hypotheses",
    "LiveHypotheses",
    "Mode",
    "ReducedSolution",
    "ViolationScales",
    "enumerate_hypotheses",
    "enumerate_live",
    "geometric_feasible",
    "solve_reduced",
    "sum_last",
    "violation_score",
]


class Mode(IntEnum):
    """Contact mode of one potential contact."""

    SEPARATED = 0
    STICKING = 1
    SLIDING_POS = 2
    SLIDING_NEG = 3


MODE_NAMES: tuple[str, ...] = ("separated", "sticking", "sliding_pos", "sliding_neg")
# plain ints for the hot paths (IntEnum member access and conversion cost ~1 us each)
_SEP, _STICK, _POS, _NEG = (int(m) for m in Mode)
N_MODES: int = len(MODE_NAMES)


# ---------------------------------------------------------------------------------------------
# Reduced dynamics given a mode assignment (Sec. III-A), batched.
# ---------------------------------------------------------------------------------------------

FloatArray = npt.NDArray[np.float64]
IntArray = npt.NDArray[np.int64]
BoolArray = npt.NDArray[np.bool_]


def sum_last(x: npt.NDArray[Any]) -> npt.NDArray[Any]:
    """x.sum(axis=-1) for a short last axis (< 8 entries) as a chain of slice additions.

    numpy adds the entries of a short axis in order, so the values are the same; but a
    reduction over a short inner axis costs ~10x more than a few elementwise additions
    (it dominated the per-step cost of small arrays). Booleans are counted (int64).
    """
    n = x.shape[-1]
    if n == 0 or n >= 8:
        return np.asarray(x.sum(axis=-1))
    out = x[..., 0].astype(np.int64) if x.dtype == np.bool_ else x[..., 0].copy()
    for i in range(1, n):
        out += x[..., i]
    return out


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
    backend: str | None = None,
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

    backend: key of REDUCED_BACKENDS: `compiled` (`kernels`, numba; the default when
    numba imports) or `numpy` (batched array operations; the reference and the fallback).
    None = `DEFAULT_BACKEND`. Both give the same results to round-off.
    """
    prob = _ReducedProblem.of(
        modes,
        v_free,
        inv_mass=inv_mass,
        jn=jn,
        jt=jt,
        phi=phi,
        vn_env=vn_env,
        vt_env=vt_env,
        mu=mu,
        mass=mass,
        dt=dt,
        scales=scales or ViolationScales(),
        eps_rel=eps_rel,
        groups=groups,
    )
    if _use_compiled(backend):
        return _solve_compiled(prob, sensitivity=impulse_sensitivity)
    return _solve_numpy(prob, sensitivity=impulse_sensitivity)


@dataclass(frozen=True)
class _ReducedProblem:
    """The inputs of `solve_reduced` as float arrays with their broadcast shapes: lead_g
    over everything but mu (the "geometry", solved once per element when no contact
    slides), lead over all (one solution per element)."""

    md: IntArray
    vf: FloatArray
    im: FloatArray
    jn: FloatArray
    jt: FloatArray
    phi: FloatArray
    vne: FloatArray
    vte: FloatArray
    mu: FloatArray
    ms: FloatArray | None
    dt: float
    sc: ViolationScales
    eps_rel: float
    groups: npt.ArrayLike | None
    lead_g: tuple[int, ...]
    lead: tuple[int, ...]

    @classmethod
    def of(
        cls,
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
        mass: npt.ArrayLike | None,
        dt: float,
        scales: ViolationScales,
        eps_rel: float,
        groups: npt.ArrayLike | None,
    ) -> _ReducedProblem:
        md = np.asarray(modes, dtype=np.int64)
        vf = np.asarray(v_free, dtype=np.float64)
        im = np.asarray(inv_mass, dtype=np.float64)
        jn_a = np.asarray(jn, dtype=np.float64)
        jt_a = np.asarray(jt, dtype=np.float64)
        phi_a = np.asarray(phi, dtype=np.float64)
        vne = np.asarray(vn_env, dtype=np.float64)
        vte = np.asarray(vt_env, dtype=np.float64)
        mu_a = np.asarray(mu, dtype=np.float64)
        ms = None if mass is None else np.asarray(mass, dtype=np.float64)
        lead_g = np.broadcast_shapes(
            md.shape[:-1],
            vf.shape[:-1],
            im.shape[:-1],
            jn_a.shape[:-2],
            jt_a.shape[:-2],
            phi_a.shape[:-1],
            vne.shape[:-1],
            vte.shape[:-1],
            () if ms is None else ms.shape[:-2],
        )
        lead = np.broadcast_shapes(lead_g, mu_a.shape[:-1])
        return cls(
            md, vf, im, jn_a, jt_a, phi_a, vne, vte, mu_a, ms, float(dt), scales, eps_rel,
            groups, lead_g, lead,
        )  # fmt: skip

    @property
    def n_c(self) -> int:
        return int(self.md.shape[-1])

    @property
    def nv(self) -> int:
        return int(self.vf.shape[-1])

    @property
    def n_g(self) -> int:
        return math.prod(self.lead_g)

    def gflat(self, x: npt.NDArray[Any], tail: tuple[int, ...]) -> npt.NDArray[Any]:
        """x broadcast to the geometry elements, (G, *tail)."""
        if x.shape[: x.ndim - len(tail)] != self.lead_g:
            x = np.broadcast_to(x, (*self.lead_g, *tail))
        return x.reshape(self.n_g, *tail)

    def geometry_index(self) -> IntArray:
        """The geometry element of each lead element (n_m,)."""
        gi = np.arange(self.n_g)
        if self.lead != self.lead_g:
            pad = (1,) * (len(self.lead) - len(self.lead_g))
            gi = np.broadcast_to(gi.reshape(pad + self.lead_g), self.lead).reshape(-1)
        return gi


def _solve_numpy(prob: _ReducedProblem, *, sensitivity: bool) -> ReducedSolution:
    """`solve_reduced` with batched numpy operations (the reference path)."""
    n_c, nv, lead = prob.n_c, prob.nv, prob.lead
    rows = _constraint_rows(prob)
    sol = _solve_assignments(
        rows.modes,
        rows.g_ext,
        rows.mw_ext,
        rows.a_ext,
        prob.geometry_index(),
        mu_rows=_mu_rows(prob.mu, lead, n_c),
        eps_rel=prob.eps_rel,
        sensitivity=sensitivity,
    )
    ln = sol[0].reshape(*lead, n_c)
    lt = sol[1].reshape(*lead, n_c)
    v_next = prob.vf + sol[2].reshape(*lead, nv)
    gap_rate, vt = _contact_rates(prob, rows.w_all, v_next)
    onehot = None if prob.groups is None else _onehot_of(prob.groups)
    score = _violation_score(
        prob.md, ln, lt, gap_rate, vt, mu_a=prob.mu, nv=nv, sc=prob.sc, onehot=onehot
    )
    if score.shape != lead:
        score = np.broadcast_to(score, lead)
    imp_resp = sol[4]
    return ReducedSolution(
        v_next=np.asarray(v_next, dtype=np.float64),
        ln=ln,
        lt=lt,
        gap_rate=np.asarray(gap_rate, dtype=np.float64),
        vt=np.asarray(vt, dtype=np.float64),
        score=np.asarray(score, dtype=np.float64),
        response=np.asarray(sol[3].reshape(*lead, nv, nv), dtype=np.float64),
        impulse_response=None
        if imp_resp is None
        else np.asarray(imp_resp.reshape(*lead, 2, n_c, nv), dtype=np.float64),
    )


@dataclass(frozen=True)
class _Rows:
    """Per geometry element: modes (G, C); the constraint rows [Jn; Jt] flattened with a
    final zero row g_ext (G 2C + 1, nv) and as w_all (G, 2C, nv); the rows of M^-1 W^T
    mw_ext (same layout); the free gap rates / slips a_ext (G 2C + 1,)."""

    modes: IntArray
    g_ext: FloatArray
    w_all: FloatArray
    mw_ext: FloatArray
    a_ext: FloatArray


def _constraint_rows(prob: _ReducedProblem) -> _Rows:
    """The constraint rows, their M^-1 images and the free-motion rates of every geometry
    element (independent of the assignment)."""
    n_c, nv, n_g, gflat = prob.n_c, prob.nv, prob.n_g, prob.gflat
    an = (prob.jn @ prob.vf[..., None])[..., 0] - prob.vne + prob.phi / prob.dt
    at = (prob.jt @ prob.vf[..., None])[..., 0] - prob.vte
    md = prob.md
    mdg = md if md.shape[:-1] == prob.lead_g else np.broadcast_to(md, (*prob.lead_g, n_c))
    n_rows = n_g * 2 * n_c
    g_ext = np.empty((n_rows + 1, nv))
    w_all = g_ext[:n_rows].reshape(n_g, 2 * n_c, nv)
    w_all[:, :n_c] = gflat(prob.jn, (n_c, nv))
    w_all[:, n_c:] = gflat(prob.jt, (n_c, nv))
    g_ext[n_rows] = 0.0
    a_ext = np.empty(n_rows + 1)
    a_all = a_ext[:n_rows].reshape(n_g, 2 * n_c)
    a_all[:, :n_c] = gflat(an, (n_c,))
    a_all[:, n_c:] = gflat(at, (n_c,))
    a_ext[n_rows] = 0.0
    if prob.ms is not None:  # rows of M^-1 W^T (same layout, zero last row)
        mw_ext = np.zeros_like(g_ext)
        mw_ext[:n_rows] = np.swapaxes(
            np.linalg.solve(gflat(prob.ms, (nv, nv)), np.swapaxes(w_all, 1, 2)), 1, 2
        ).reshape(n_rows, nv)
    elif prob.im.ndim == 1:
        mw_ext = g_ext * prob.im
    else:
        mw_ext = np.zeros_like(g_ext)
        mw_ext[:n_rows] = (w_all * gflat(prob.im, (nv,))[:, None, :]).reshape(n_rows, nv)
    return _Rows(mdg.reshape(n_g, n_c), g_ext, w_all, mw_ext, a_ext)


def _contact_rates(
    prob: _ReducedProblem, w_all: FloatArray, v_next: FloatArray
) -> tuple[FloatArray, FloatArray]:
    """Gap rates and slips (*lead, C) after the step: [Jn; Jt] v' of every lead element in
    one batched product (w_all in the geometry layout)."""
    n_c, nv, lead, lead_g = prob.n_c, prob.nv, prob.lead, prob.lead_g
    n_m = math.prod(lead)
    lead_gp = (1,) * (len(lead) - len(lead_g)) + lead_g
    j = len(lead_gp)
    while j and lead_gp[j - 1] == 1:
        j -= 1
    if lead_gp[:j] == lead[:j] and len(lead) == len(lead_gp):
        # geometry = leading axes: (G, rest, nv) @ (G, nv, 2C), no broadcasting
        vv = v_next if v_next.shape == (*lead, nv) else np.broadcast_to(v_next, (*lead, nv))
        vv = vv.reshape(prob.n_g, n_m // prob.n_g, nv)
        wv = (vv @ np.swapaxes(w_all, 1, 2)).reshape(*lead, 2 * n_c)
    else:
        w_lead = w_all.reshape((*lead_gp, 2 * n_c, nv))
        wv = (w_lead @ v_next[..., None])[..., 0]  # (*lead, 2C)
    return wv[..., :n_c] - prob.vne + prob.phi / prob.dt, wv[..., n_c:] - prob.vte


REDUCED_BACKENDS: dict[str, str] = {
    "compiled": "one compiled loop over the systems (dbcslam_core.kernels, numba)",
    "numpy": "batched numpy array operations (reference; no compiler needed)",
}
DEFAULT_BACKEND: str = "compiled" if kernels.AVAILABLE else "numpy"


def _use_compiled(backend: str | None) -> bool:
    name = DEFAULT_BACKEND if backend is None else backend
    if name not in REDUCED_BACKENDS:
        msg = f"reduced-dynamics backend must be one of {sorted(REDUCED_BACKENDS)}, got {name!r}"
        raise SolverError(msg)
    if name == "compiled" and not kernels.AVAILABLE:
        msg = "reduced-dynamics backend 'compiled' needs numba, which is not installed"
        raise SolverError(msg)
    return name == "compiled"


def _solve_compiled(prob: _ReducedProblem, *, sensitivity: bool) -> ReducedSolution:
    """`solve_reduced` through the compiled kernel: geometry elements flattened to (G, ...)
    contiguous arrays, lead elements to (geometry index, mu row) pairs."""
    n_c, nv, lead = prob.n_c, prob.nv, prob.lead

    def gflat(x: npt.NDArray[Any], tail: tuple[int, ...]) -> npt.NDArray[Any]:
        return np.ascontiguousarray(prob.gflat(x, tail))

    gi = np.ascontiguousarray(prob.geometry_index(), dtype=np.int64)
    groups = prob.groups
    mu_u, ui = _mu_rows(prob.mu, lead, n_c)
    if groups is None:
        group = np.arange(n_c, dtype=np.int64)
    else:
        group = np.unique(np.asarray(groups, dtype=np.int64).reshape(-1), return_inverse=True)[1]
    out, n_bad = kernels.reduced_dynamics(
        gflat(prob.md, (n_c,)),
        gflat(prob.vf, (nv,)),
        jn=gflat(prob.jn, (n_c, nv)),
        jt=gflat(prob.jt, (n_c, nv)),
        phi=gflat(prob.phi, (n_c,)),
        vne=gflat(prob.vne, (n_c,)),
        vte=gflat(prob.vte, (n_c,)),
        minv=gflat(prob.im, (nv,)),
        mass=None if prob.ms is None else gflat(prob.ms, (nv, nv)),
        mu_rows=np.ascontiguousarray(mu_u),
        gi=gi,
        ui=np.ascontiguousarray(ui, dtype=np.int64),
        group=np.ascontiguousarray(group, dtype=np.int64),
        dt=prob.dt,
        eps_rel=prob.eps_rel,
        scales=(prob.sc.impulse, prob.sc.velocity, prob.sc.impulse_floor),
        sensitivity=sensitivity,
    )
    if n_bad or not np.isfinite(out["v_next"]).all():
        msg = f"reduced dynamics system is singular for {max(n_bad, 1)} of {gi.size} assignments"
        raise SolverError(msg)
    ir = out["impulse_response"]
    return ReducedSolution(
        v_next=out["v_next"].reshape(*lead, nv),
        ln=out["ln"].reshape(*lead, n_c),
        lt=out["lt"].reshape(*lead, n_c),
        gap_rate=out["gap_rate"].reshape(*lead, n_c),
        vt=out["vt"].reshape(*lead, n_c),
        score=out["score"].reshape(lead),
        response=out["response"].reshape(*lead, nv, nv),
        impulse_response=ir.reshape(*lead, 2, n_c, nv) if sensitivity else None,
    )


def _mu_rows(mu_a: FloatArray, lead: tuple[int, ...], n_c: int) -> tuple[FloatArray, IntArray]:
    """Distinct friction rows (U, C) of mu and the row of each lead element (n_m,)."""
    mu_lead = mu_a.shape[:-1]
    mu_lead = (1,) * (len(lead) - len(mu_lead)) + mu_lead
    n_u = math.prod(mu_lead)
    rows = mu_a.reshape(n_u, mu_a.shape[-1])
    if rows.shape[1] != n_c:
        rows = np.broadcast_to(rows, (n_u, n_c))
    ui = np.arange(n_u).reshape(mu_lead)
    if mu_lead != lead:
        ui = np.broadcast_to(ui, lead)
    return rows, ui.reshape(-1)


def _solve_assignments(
    modes: IntArray,
    g_ext: FloatArray,
    mw_ext: FloatArray,
    a_ext: FloatArray,
    gi: IntArray,
    *,
    mu_rows: tuple[FloatArray, IntArray],
    eps_rel: float,
    sensitivity: bool,
) -> tuple[FloatArray, FloatArray, FloatArray, FloatArray, FloatArray | None]:
    """Impulses, dv, response (and d(ln, lt)/d v_free) of every lead element (n_m,).

    Per geometry element g (modes (G, C); g_ext (G 2C + 1, nv) the rows [Jn; Jt] of each
    element, flattened, and a final zero row; mw_ext the rows of M^-1 W^T, same layout;
    a_ext (G 2C + 1,) free gap rates / slips, same layout) the equality rows are the normal rows
    of the non-separated contacts and the tangent rows of the sticking ones (r rows). A
    sliding contact's friction impulse follows its normal impulse (lt = -c ln, c = +mu
    sliding_pos, -mu sliding_neg), so its normal column acts along f = Jn - c Jt. The
    r x r system (G M^-1 F^T + eps I) lambda = -a is the padded 2n x 2n system of the
    Stewart-Trinkle equalities with the identity rows (separated contacts, sliding tangent
    rows) eliminated exactly; eps = eps_rel * the mean Delassus diagonal over the n_max
    first-active-then-separated contacts (n_max: largest active count), as in the padded
    form. Elements without sliding contacts are solved once per geometry element; gi (n_m,)
    maps lead elements to geometry elements, mu_rows = (distinct mu rows (U, C), row of each
    lead element (n_m,)).
    """
    n_c = modes.shape[1]
    nv = g_ext.shape[-1]
    n_act = sum_last(modes != _SEP)
    if not (n_act > 0).any():
        resp = np.broadcast_to(np.eye(nv), (gi.size, nv, nv)).copy()
        ir0 = np.zeros((gi.size, 2, n_c, nv)) if sensitivity else None
        return (
            np.zeros((gi.size, n_c)),
            np.zeros((gi.size, n_c)),
            np.zeros((gi.size, nv)),
            resp,
            ir0,
        )
    eps_g = _tikhonov_eps(modes, g_ext, mw_ext, n_act, eps_rel)
    sys = _equality_systems(modes, g_ext, mw_ext, a_ext, gi, mu_rows=mu_rows, n_act=n_act)
    x, dv_t, resp_t = _solve_systems(sys, eps_g.take(sys.src), nv)
    return _per_element(sys, x, dv_t, resp_t, gi, n_g=modes.shape[0], sensitivity=sensitivity)


@dataclass
class _Systems:
    """The equality systems of `_solve_assignments`, sorted by size (S systems, R rows at
    most): src geometry element of each, perm the sort, size_s rows, val_s / ord_s valid
    rows and their contact slots, gr the constraint rows G, mf the rows of M^-1 F^T, cpl
    the friction coupling of sliding normal rows, rhs [-a, -G]; g_fix / e_sl the geometry
    elements solved once and the lead elements with sliding contacts."""

    src: IntArray
    perm: IntArray
    size_s: IntArray
    val_s: npt.NDArray[np.bool_]
    ord_s: IntArray
    gr: FloatArray
    mf: FloatArray
    cpl: FloatArray
    rhs: FloatArray
    g_fix: IntArray
    e_sl: IntArray
    n_c: int


def _tikhonov_eps(
    modes: IntArray, g_ext: FloatArray, mw_ext: FloatArray, n_act: IntArray, eps_rel: float
) -> FloatArray:
    """Tikhonov term per geometry element: eps_rel * the mean Delassus diagonal over the
    n_max first-active-then-separated contacts (as the padded formulation)."""
    n_g, n_c = modes.shape
    sep = modes == _SEP
    n_max = int(n_act.max())
    pad = ~sep | (sep & (np.cumsum(sep, axis=1) <= (n_max - n_act)[:, None]))
    n_rows = n_g * 2 * n_c
    diag = np.einsum("kv,kv->k", g_ext[:n_rows], mw_ext[:n_rows]).reshape(n_g, 2 * n_c)
    diag_mean = sum_last(np.where(np.concatenate([pad, pad], axis=1), diag, 0.0)) / (2 * n_max)
    return np.asarray(eps_rel * np.maximum(diag_mean, 1e-300))


def _equality_systems(
    modes: IntArray,
    g_ext: FloatArray,
    mw_ext: FloatArray,
    a_ext: FloatArray,
    gi: IntArray,
    *,
    mu_rows: tuple[FloatArray, IntArray],
    n_act: IntArray,
) -> _Systems:
    """Equality rows (normal slots of active contacts, tangent slots of sticking ones, valid
    rows first) of the systems to solve: once per geometry element without sliding contacts,
    per lead element with sliding contacts (their friction couples lt to ln)."""
    n_g, n_c = modes.shape
    two_c = 2 * n_c
    n_rows = n_g * two_c
    mu_u, ui = mu_rows
    stick = modes == _STICK
    sgn = (modes == _POS).astype(np.float64) - (modes == _NEG)
    slot_ok = np.concatenate([modes != _SEP, stick], axis=1)  # (G, 2C)
    r_cnt = n_act + sum_last(stick)  # = slot_ok.sum(axis=1)
    r_max = int(r_cnt.max())
    order = np.argsort(~slot_ok, axis=1, kind="stable")[:, :r_max]  # (G, R)
    slides = sum_last(modes >= _POS) > 0  # any sliding contact (sgn != 0)
    g_fix = np.flatnonzero((n_act > 0) & ~slides)
    e_sl = np.flatnonzero(slides[gi])
    sys_g = np.concatenate([g_fix, gi[e_sl]])  # geometry element of each system (S,)
    sys_u = np.concatenate([np.zeros(g_fix.size, dtype=np.int64), ui[e_sl]])  # its mu row
    # sort the systems by size: each size class is a contiguous slice solved unpadded
    perm = np.argsort(r_cnt.take(sys_g), kind="stable")
    src = sys_g.take(perm)
    ord_s = order.take(src, axis=0)  # (S, R)
    val_s = slot_ok.reshape(-1).take(src[:, None] * two_c + ord_s)
    cont_s = ord_s % n_c
    base = src[:, None] * two_c
    fidx = np.where(val_s, base + ord_s, n_rows)  # invalid rows -> the zero row
    gr = g_ext.take(fidx, axis=0)  # (S, R, nv) constraint rows G
    mf = mw_ext.take(fidx, axis=0)  # rows of M^-1 F^T; sliding normal rows: below
    cpl = np.zeros((src.size, r_max))
    if e_sl.size:
        is_n = val_s & (ord_s < n_c)
        row_sgn = np.where(is_n, sgn.take(src[:, None] * n_c + cont_s), 0.0)
        mu_sel = mu_u.take(sys_u.take(perm)[:, None] * n_c + cont_s)
        cpl = row_sgn * mu_sel
        mf -= cpl[..., None] * mw_ext.take(base + n_c + cont_s, axis=0)
    rhs = np.empty((src.size, r_max, 1 + g_ext.shape[-1]))  # [-a, -G] (S, R, 1 + nv)
    np.negative(a_ext.take(fidx), out=rhs[..., 0])
    np.negative(gr, out=rhs[..., 1:])
    size_s = r_cnt.take(src)
    return _Systems(src, perm, size_s, val_s, ord_s, gr, mf, cpl, rhs, g_fix, e_sl, n_c)


def _solve_systems(
    sys: _Systems, eps_s: FloatArray, nv: int
) -> tuple[FloatArray, FloatArray, FloatArray]:
    """(G M^-1 F^T + eps I) x = [-a, -G] per size class (1, 2, the rest padded): the
    solutions x (S, R, 1 + nv), dv (S + 1, nv) and the velocity response (S + 1, nv, nv); row
    S (zero dv, identity response) stands for the elements without contacts."""
    n_s, r_max = sys.val_s.shape
    x = np.zeros_like(sys.rhs)
    dv_t = np.zeros((n_s + 1, nv))
    resp_t = np.zeros((n_s + 1, nv, nv))
    bounds = np.searchsorted(sys.size_s, [1, 2, 3, r_max + 1])
    for k, a, b in ((1, bounds[0], bounds[1]), (2, bounds[1], bounds[2]), (r_max, bounds[2], n_s)):
        if b <= a or k < 1:
            continue
        mf_t = np.swapaxes(sys.mf[a:b, :k], 1, 2)  # M^-1 F^T (n, nv, k)
        amat = sys.gr[a:b, :k] @ mf_t
        ar = np.arange(k)
        amat[:, ar, ar] += np.where(sys.val_s[a:b, :k], eps_s[a:b, None], 1.0)
        xk = _solve_small(amat, sys.rhs[a:b, :k])
        x[a:b, :k] = xk
        dv_t[a:b] = (mf_t @ xk[..., :1])[..., 0]
        resp_t[a:b] = mf_t @ xk[..., 1:]
    resp_t[:, np.arange(nv), np.arange(nv)] += 1.0
    return x, dv_t, resp_t


def _per_element(
    sys: _Systems,
    x: FloatArray,
    dv_t: FloatArray,
    resp_t: FloatArray,
    gi: IntArray,
    *,
    n_g: int,
    sensitivity: bool,
) -> tuple[FloatArray, FloatArray, FloatArray, FloatArray, FloatArray | None]:
    """The systems' rows scattered back to contact slots (invalid rows -> a dummy slot 2C),
    then each lead element's (ln, lt, dv, response, sensitivity) from its system's row."""
    n_s = sys.src.size
    n_c = sys.n_c
    two_c = 2 * n_c
    nv = dv_t.shape[1]
    slot = np.arange(n_s)[:, None] * (two_c + 1) + np.where(sys.val_s, sys.ord_s, two_c)
    lam_slots = np.zeros((n_s + 1, two_c + 1))
    lam_slots.reshape(-1)[slot] = x[..., 0]
    cpl_slots = np.zeros((n_s + 1, two_c + 1))
    cpl_slots.reshape(-1)[slot] = sys.cpl
    cpl_c = cpl_slots[:, :n_c]  # coupling per contact: lt = -c ln (sliding)
    ln_t = lam_slots[:, :n_c]
    lt_t = lam_slots[:, n_c:two_c] - cpl_c * ln_t
    ir_t = None
    if sensitivity:
        sens_slots = np.zeros((n_s + 1, two_c + 1, nv))
        sens_slots.reshape(-1, nv)[slot] = x[..., 1:]
        ir_n = sens_slots[:, :n_c]
        ir_t = np.stack([ir_n, sens_slots[:, n_c:two_c] - cpl_c[..., None] * ir_n], axis=1)
    # system row of each lead element
    n_fix = sys.g_fix.size
    inv = np.empty(n_s, dtype=np.int64)
    inv[sys.perm] = np.arange(n_s)
    pos_g = np.full(n_g, n_s)
    pos_g[sys.g_fix] = inv[:n_fix]
    row_e = pos_g.take(gi)
    row_e[sys.e_sl] = inv[n_fix:]
    return (
        ln_t.take(row_e, axis=0),
        lt_t.take(row_e, axis=0),
        dv_t.take(row_e, axis=0),
        resp_t.take(row_e, axis=0),
        None if ir_t is None else ir_t.take(row_e, axis=0),
    )


def _solve_small(amat: FloatArray, rhs: FloatArray) -> FloatArray:
    """Solve the batch amat (S, k, k) x = rhs (S, k, m) for small k.

    k = 1 and 2 in closed form (division, Cramer's rule: forward stable for 2 x 2; LAPACK's
    per-matrix overhead dominates for tiny systems), larger k with a batched
    `np.linalg.solve`. Raises SolverError for singular systems.
    """
    k = amat.shape[-1]
    x: FloatArray
    if k == 1:
        x = rhs / amat
    elif k == 2:
        # scaled by the largest entry of each matrix: the determinant of tiny (or huge)
        # entries would underflow (overflow) although the system is well conditioned
        s = np.abs(amat).max(axis=(1, 2))[:, None]
        s = np.where(s > 0.0, s, 1.0)
        a = amat[:, 0, 0, None] / s
        b = amat[:, 0, 1, None] / s
        c = amat[:, 1, 0, None] / s
        d = amat[:, 1, 1, None] / s
        r0 = rhs[:, 0] / s
        r1 = rhs[:, 1] / s
        det = a * d - b * c  # zero only for singular systems: caught below (non-finite)
        x = np.empty_like(rhs)
        x[:, 0] = (d * r0 - b * r1) / det
        x[:, 1] = (a * r1 - c * r0) / det
    else:
        try:
            x = np.asarray(np.linalg.solve(amat, rhs), dtype=np.float64)
        except np.linalg.LinAlgError as err:
            msg = f"reduced dynamics system is singular for some of {amat.shape[0]} assignments"
            raise SolverError(msg) from err
    if not np.isfinite(x).all():
        n_bad = int((~np.isfinite(x)).any(axis=(1, 2)).sum())
        msg = (
            f"reduced dynamics system is singular or its solution overflows for {n_bad} of "
            f"{amat.shape[0]} assignments"
        )
        raise SolverError(msg)
    return np.asarray(x, dtype=np.float64)


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
    onehot = None if groups is None else _onehot_of(groups)
    score = _violation_score(md, ln_a, lt_a, gr, vt_a, mu_a=mu_a, nv=nv, sc=sc, onehot=onehot)
    return np.asarray(np.broadcast_to(score, shape[:-1]), dtype=np.float64)


def _onehot_of(groups: npt.ArrayLike) -> FloatArray:
    """`_group_onehot` of a group sequence (tuples of ints, the filter's case, directly)."""
    if isinstance(groups, tuple) and all(type(g) is int for g in groups):
        return _group_onehot(groups)
    return _group_onehot(tuple(int(x) for x in np.asarray(groups).reshape(-1)))


def _violation_score(
    md: IntArray,
    ln_a: FloatArray,
    lt_a: FloatArray,
    gr: FloatArray,
    vt_a: FloatArray,
    *,
    mu_a: FloatArray,
    nv: int,
    sc: ViolationScales,
    onehot: FloatArray | None,
) -> FloatArray:
    """`violation_score` on arrays (no validation; the result is not broadcast to the
    full shape: (...) of the terms that enter)."""
    # mode masks at the (often much smaller) shape of `modes`; broadcast in the arithmetic
    sep = md == _SEP
    stick = md == _STICK
    # velocity inequalities: separated gap rate >= 0, sliding slip sign (exclusive cases)
    v_neg = np.where(
        sep,
        -gr,
        np.where(md == _POS, -vt_a, np.where(md == _NEG, vt_a, 0.0)),
    )
    v_sq = sum_last((np.maximum(0.0, v_neg) / sc.velocity) ** 2)
    mag = np.abs(ln_a) + np.abs(lt_a) + sc.impulse_floor
    i_neg = np.where(sep, 0.0, np.maximum(0.0, -ln_a)) / mag
    imp = sum_last((i_neg / sc.impulse) ** 2)
    if np.any(stick):
        if onehot is None:
            i_cone = np.where(stick, np.maximum(0.0, np.abs(lt_a) - mu_a * ln_a), 0.0) / mag
            imp = imp + sum_last((i_cone / sc.impulse) ** 2)
        else:
            lt_g = np.where(stick, lt_a, 0.0)
            cap_g = np.where(stick, mu_a * ln_a, 0.0)
            mag_g = np.where(stick, mag - sc.impulse_floor, 0.0)
            if onehot.shape[1] < onehot.shape[0]:  # else one contact per group: no sums
                lt_g, cap_g, mag_g = lt_g @ onehot, cap_g @ onehot, mag_g @ onehot
            i_cone_g = np.maximum(0.0, np.abs(lt_g) - cap_g) / (mag_g + sc.impulse_floor)
            imp = imp + sum_last((i_cone_g / sc.impulse) ** 2)
    # Statically indeterminate assignments (more equality rows than dofs, e.g. a triangle
    # wedged between both jaws) have a family of impulse solutions; the min-norm one computed
    # here need not be the feasible one, so their impulse inequalities are not scored.
    n_rows = sum_last(~sep) + sum_last(stick)
    return np.asarray(v_sq + np.where(n_rows <= nv, imp, 0.0), dtype=np.float64)


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


@functools.lru_cache(maxsize=64)
def _layout_rules(
    layout: ContactLayout,
) -> tuple[tuple[tuple[int, ...], ...], tuple[tuple[int, int], ...], tuple[tuple[int, int], ...]]:
    """Static exclusion rules of a layout (cached: used every step): contact index groups of
    one flat obstacle with more than two vertex contacts, forbidden pairs, same-feature
    pairs."""
    crowded = []
    for obst in sorted(set(layout.obstacle)):
        idx = tuple(c for c in range(layout.n_contacts) if layout.obstacle[c] == obst)
        if layout.n_vertices > 0 and len(idx) > 2:
            crowded.append(idx)
    return tuple(crowded), layout.forbidden_pairs(), layout.same_feature_pairs()


@functools.lru_cache(maxsize=256)
def _mixed_radix(radix: tuple[int, ...]) -> IntArray:
    """(prod(radix), len(radix)) all digit tuples in C order (cached, read-only)."""
    n_t = math.prod(radix)
    out = np.stack(np.unravel_index(np.arange(n_t), radix), -1).astype(np.int64)
    out.setflags(write=False)
    return out


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
    inc = md != _SEP
    ok = np.ones(md.shape[:-1], dtype=bool)
    crowded, forbidden, pairs = _layout_rules(layout)
    for idx in crowded:
        n_in = inc[..., idx[0]].astype(np.int64)  # contacts in contact (slices: no gather)
        for c in idx[1:]:
            n_in += inc[..., c]
        ok &= n_in <= 2
    for a, b in forbidden:
        ok &= ~(inc[..., a] & inc[..., b])
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


@dataclass(frozen=True)
class LiveHypotheses:
    """The valid joint hypotheses of `enumerate_live`, row after row (no padding): modes
    (N, C), log_prior (N,), counts (P,) per particle (>= 1), width = the largest count (K of
    the padded `Hypotheses` layout)."""

    modes: IntArray
    log_prior: FloatArray
    counts: IntArray
    width: int

    @property
    def n_live(self) -> IntArray:
        """Live hypotheses per particle (P,)."""
        return self.counts

    def padded(self) -> Hypotheses:
        """The same hypotheses in the padded (P, K) layout (empty slots: modes 0, log prior
        -inf, not valid)."""
        n_p = self.counts.shape[0]
        valid = np.arange(self.width)[None, :] < self.counts[:, None]
        modes = np.zeros((n_p, self.width, self.modes.shape[1]), dtype=np.int64)
        modes[valid] = self.modes
        logp = np.full((n_p, self.width), -np.inf)
        logp[valid] = self.log_prior
        return Hypotheses(modes=modes, log_prior=logp, valid=valid)


def enumerate_live(
    marginals: npt.ArrayLike,
    threshold: float,
    max_hypotheses: int,
    *,
    layout: ContactLayout | None = None,
    phi: npt.ArrayLike | None = None,
    max_tuples: int = 4096,
    pool: RowPool | None = None,
    work: dict[str, npt.NDArray[Any]] | None = None,
) -> LiveHypotheses:
    """`enumerate_hypotheses` (same hypotheses, same order) as the list of the valid ones
    (compiled without the padded arrays when numba is available; on the threads of pool,
    with the reusable scratch buffers of work)."""
    mg = np.asarray(marginals, dtype=np.float64)
    if not kernels.AVAILABLE:
        hyp = enumerate_hypotheses(
            mg, threshold, max_hypotheses, layout=layout, phi=phi, max_tuples=max_tuples
        )
        counts = hyp.n_live
        return LiveHypotheses(
            hyp.modes[hyp.valid], hyp.log_prior[hyp.valid], counts, int(hyp.modes.shape[1])
        )
    if mg.ndim != 3 or mg.shape[-1] != N_MODES:
        msg = f"marginals must be (particles, contacts, {N_MODES}), got shape {mg.shape}"
        raise SolverError(msg)
    args, kwargs = _compiled_enumeration_args(
        mg, threshold, max_hypotheses, layout=layout, phi=phi, max_tuples=max_tuples, pool=pool
    )
    modes, logp, counts, width = kernels.enumerate_compact(*args, **kwargs, pool=pool, work=work)
    return LiveHypotheses(modes, logp, counts, width)


def _radix(n_live_max: list[int], max_tuples: int) -> tuple[int, ...]:
    """Live modes per contact over all particles, reduced (largest first) until the number
    of joint tuples is at most max_tuples."""
    radix_t = list(n_live_max)
    while math.prod(radix_t) > max_tuples:
        radix_t[radix_t.index(max(radix_t))] -= 1  # the first largest, as np.argmax
    return tuple(radix_t)


@functools.lru_cache(maxsize=64)
def _layout_arrays(layout: ContactLayout) -> tuple[IntArray, IntArray, IntArray]:
    """`_layout_rules` as int arrays for the compiled kernel (crowded groups padded -1)."""
    crowded, forbidden, same = _layout_rules(layout)
    width = max((len(g) for g in crowded), default=0)
    crowd = np.full((len(crowded), width), -1, dtype=np.int64)
    for i, g in enumerate(crowded):
        crowd[i, : len(g)] = g
    out = (
        crowd,
        np.asarray(forbidden, dtype=np.int64).reshape(-1, 2),
        np.asarray(same, dtype=np.int64).reshape(-1, 2),
    )
    for a in out:
        a.setflags(write=False)
    return out


def _compiled_enumeration_args(
    mg: FloatArray,
    threshold: float,
    max_hypotheses: int,
    *,
    layout: ContactLayout | None,
    phi: npt.ArrayLike | None,
    max_tuples: int,
    pool: RowPool | None = None,
) -> tuple[tuple[IntArray, FloatArray], dict[str, Any]]:
    """The inputs of `kernels.enumerate_tuples` / `enumerate_compact` for marginals mg (the
    mode ordering on the threads of pool)."""
    n_p, n_c, _ = mg.shape
    # (P, C, 4) modes by descending probability (stable, as the numpy path), their log
    # probabilities (-inf where not live) and the live count per (particle, contact)
    order, lsp, n_live = kernels.prepare_tuples(mg, threshold, pool=pool)
    radix_t = _radix(n_live.max(axis=0).tolist(), max_tuples)
    n_t = math.prod(radix_t)
    pre_k = n_t if n_t * n_c * n_p <= 3_000_000 else min(n_t, 4 * max_hypotheses)
    if layout is None:
        empty = np.zeros((0, 2), dtype=np.int64)
        rules = (np.zeros((0, 0), dtype=np.int64), empty, empty)
    else:
        rules = _layout_arrays(layout)
    kwargs: dict[str, Any] = {
        "n_live": n_live,
        "threshold": threshold,
        "ranks": _mixed_radix(radix_t),
        "n_keep": min(max_hypotheses, pre_k),
        "pre_k": pre_k,
        "phi": None if (phi is None or layout is None) else np.asarray(phi, dtype=np.float64),
        "rules": rules,
        "both_tolerance": 2e-3,
    }
    return (order, lsp), kwargs


def _enumerate_compiled(
    mg: FloatArray,
    threshold: float,
    max_hypotheses: int,
    *,
    layout: ContactLayout | None,
    phi: npt.ArrayLike | None,
    max_tuples: int,
) -> Hypotheses:
    """`enumerate_hypotheses` through `kernels.enumerate_tuples` (same rules)."""
    args, kwargs = _compiled_enumeration_args(
        mg, threshold, max_hypotheses, layout=layout, phi=phi, max_tuples=max_tuples
    )
    modes, logp, valid = kernels.enumerate_tuples(*args, **kwargs)
    return Hypotheses(modes=modes, log_prior=logp, valid=valid)


def enumerate_hypotheses(
    marginals: npt.ArrayLike,
    threshold: float,
    max_hypotheses: int,
    *,
    layout: ContactLayout | None = None,
    phi: npt.ArrayLike | None = None,
    max_tuples: int = 4096,
    compiled: bool | None = None,
) -> Hypotheses:
    """Enumerate the live joint mode hypotheses of every particle at once (no Python loop
    over particles).

    marginals (P, C, 4): per-contact mode probabilities. Per contact the live modes are those
    with probability >= threshold (the most probable is always live). Joint hypotheses are the
    product of live modes, ranked by log prior (sum of log marginals); geometrically impossible
    ones (`geometric_feasible`) are removed, joint hypotheses whose normalised probability is
    below threshold are pruned (the best is always kept), and at most max_hypotheses are kept.

    compiled: use `kernels.enumerate_tuples` (None: when numba is available); the same
    hypotheses as the numpy path, except the order among exactly tied log priors at the
    boundary of a truncated enumeration (numpy's argpartition leaves it unspecified).
    """
    mg = np.asarray(marginals, dtype=np.float64)
    if mg.ndim != 3 or mg.shape[-1] != N_MODES:
        msg = f"marginals must be (particles, contacts, {N_MODES}), got shape {mg.shape}"
        raise SolverError(msg)
    if compiled is None:
        compiled = kernels.AVAILABLE
    enumerate_ = _enumerate_compiled if compiled else _enumerate_numpy
    return enumerate_(mg, threshold, max_hypotheses, layout=layout, phi=phi, max_tuples=max_tuples)


def _enumerate_numpy(
    mg: FloatArray,
    threshold: float,
    max_hypotheses: int,
    *,
    layout: ContactLayout | None,
    phi: npt.ArrayLike | None,
    max_tuples: int,
) -> Hypotheses:
    """`enumerate_hypotheses` with batched numpy operations (the reference path)."""
    n_p, n_c, _ = mg.shape
    order = np.argsort(-mg, axis=-1, kind="stable")  # (P, C, 4)
    sp = -np.sort(-mg, axis=-1)  # = mg along `order` (same values, no gather)
    live = sp >= threshold
    live[..., 0] = True
    n_live = sum_last(live)  # (P, C)
    radix = n_live.max(axis=0)  # (C,)
    radix_t = _radix(radix.tolist(), max_tuples)
    n_t = math.prod(radix_t)
    ranks = _mixed_radix(radix_t)
    with np.errstate(divide="ignore"):
        lsp = np.log(sp)  # (P, C, 4)
    lsp = np.where(live, lsp, -np.inf)
    cidx = np.arange(n_c)
    logp = sum_last(lsp[:, cidx[None, :], ranks])  # (P, T)
    pre_k = n_t if n_t * n_c * n_p <= 3_000_000 else min(n_t, 4 * max_hypotheses)
    if pre_k < n_t:
        sel = np.argpartition(-logp, pre_k - 1, axis=1)[:, :pre_k]
        logp_s = np.take_along_axis(logp, sel, axis=1)
        rk = ranks[sel]  # (P, T', C)
    else:  # all tuples
        logp_s = logp
        rk = ranks  # broadcast against base_pc below
    # modes_s[p, t, c] = order[p, c, rk[p, t, c]] (flat gather)
    base_pc = (np.arange(n_p) * (n_c * N_MODES))[:, None, None] + np.arange(n_c) * N_MODES
    modes_s = order.take(base_pc + rk)  # (P, T', C)
    if layout is not None:
        ph = None if phi is None else np.asarray(phi, dtype=np.float64)[:, None, :]
        feas = geometric_feasible(layout, modes_s, ph)
        logp_s = np.where(feas, logp_s, -np.inf)
    k = min(max_hypotheses, logp_s.shape[1])
    top = np.argsort(-logp_s, axis=1, kind="stable")[:, :k]
    logp_k = np.take_along_axis(logp_s, top, axis=1)
    n_ts = modes_s.shape[1]
    modes_k = modes_s.take(
        ((np.arange(n_p) * n_ts)[:, None] + top)[..., None] * n_c + np.arange(n_c)
    )  # modes_s[p, top[p, k], c]
    # Prune by normalised joint probability (keep the best hypothesis of each particle).
    m = logp_k[:, :1]
    m_safe = np.where(np.isfinite(m), m, 0.0)
    e = np.exp(logp_k - m_safe)
    norm = e / np.maximum(sum_last(e)[:, None], 1e-300)
    valid = np.isfinite(logp_k) & (norm >= threshold)
    valid[:, 0] = True
    # Trim trailing columns nobody uses.
    k_used = max(1, int(sum_last(valid).max()))
    modes_k = modes_k[:, :k_used]
    valid = valid[:, :k_used]
    logp_k = np.where(valid, logp_k[:, :k_used], -np.inf)
    return Hypotheses(
        modes=np.asarray(modes_k, dtype=np.int64),
        log_prior=np.asarray(logp_k, dtype=np.float64),
        valid=np.asarray(valid, dtype=np.bool_),
    )
