"""Planar rigid-body model with contacts: the Stewart-Trinkle time-stepping LCP (eqs. 3-4).

Impulse form (DESIGN.md): v' = v + M^-1 (dt F(q, v, u) + Jn^T ln + Jt^T lt), q' = q + dt v',
with per contact c the complementarity block, unknowns z_c = (ln, lt+, lt-, s):

    0 <= ln  _|_  phi/dt + Jn v' - vn_env      >= 0
    0 <= lt+ _|_  s + (Jt v' - vt_env)         >= 0
    0 <= lt- _|_  s - (Jt v' - vt_env)         >= 0
    0 <= s   _|_  mu ln - lt+ - lt-            >= 0        lt = lt+ - lt-

Kinematics are evaluated at (q, env); obstacle velocities are (env_next - env) / dt.
Generalised force F = gravity (edge scenario only: -m g along y; the other scenarios are a
horizontal plane) + input gain * u + extension forces. The input wrench u = (fx, fy[, tau])
acts at the centre of mass, world frame (N, N m). Units SI.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Union

import numpy as np
from numpy.typing import ArrayLike, NDArray

from .contact_modes import Mode
from .errors import ModelError, SolverError
from .extensions import (
    ModelExtension,
    compose_input_gain,
    compose_mass_factor,
    compose_mu_field,
    extra_force,
    support_friction_mu,
)
from .geometry import ContactKinematics, contact_kinematics
from .lcp import LCPSolver, LemkeSolver, PGSSolver, lcp_residuals
from .scenario import Scenario

__all__ = [
    "MuSpec",
    "PlanarModel",
    "State",
    "StepResult",
    "modes_from_lcp",
]

F64 = NDArray[np.float64]
MuSpec = Union[float, ArrayLike, Callable[[F64], ArrayLike]]  # noqa: UP007
"""Friction per contact: scalar, array (..., C), or callable s[..., C] -> mu[..., C]."""


@dataclass(frozen=True)
class State:
    """Generalised position q[..., nq] (m, rad) and velocity v[..., nv] (m/s, rad/s)."""

    q: F64
    v: F64


@dataclass(frozen=True)
class StepResult:
    """One time step: next state, contact impulses (N s) and modes.

    ln, lt[..., C]: normal / tangential impulse (lt along t = (n_y, -n_x)); slide[..., C]:
    slide speed s of the LCP (m/s, ~|vt| when sliding, 0 when sticking); vt[..., C]: relative
    tangential velocity Jt v' - vt_env; phi[..., C]: gap at the start of the step; mu[..., C]:
    friction used; modes[..., C]: `Mode` values (int64).
    """

    q: F64
    v: F64
    ln: F64
    lt: F64
    slide: F64
    vt: F64
    phi: F64
    mu: F64
    modes: NDArray[np.int64]


def modes_from_lcp(
    ln: ArrayLike,
    slide: ArrayLike,
    vt: ArrayLike,
    *,
    ln_tol: float = 1e-10,
    slide_tol: float = 1e-9,
) -> NDArray[np.int64]:
    """Contact modes implied by an LCP solution (arrays of equal shape, one entry per contact).

    ln <= ln_tol -> SEPARATED; else slide > slide_tol -> SLIDING_POS if vt > 0 else
    SLIDING_NEG; else STICKING. Tolerances in N s and m/s.
    """
    lna = np.asarray(ln, dtype=np.float64)
    sa = np.asarray(slide, dtype=np.float64)
    va = np.asarray(vt, dtype=np.float64)
    sliding = np.where(va > 0.0, int(Mode.SLIDING_POS), int(Mode.SLIDING_NEG))
    in_contact = np.where(sa > slide_tol, sliding, int(Mode.STICKING))
    return np.where(lna > ln_tol, in_contact, int(Mode.SEPARATED)).astype(np.int64)


class PlanarModel:
    """Deterministic planar contact model of a scenario (plus optional extensions).

    scenario: the a-priori model; extensions: tuple of `ModelExtension` (empty = nominal);
    solver: an `LCPSolver` (default `LemkeSolver()`; a `PGSSolver` uses its dedicated
    friction-cone solve). active_set: solve each step's LCP only over the contacts that can
    carry an impulse (exact: verified on the full LCP, full solve as fallback; 10-20x faster
    when most contacts are open); default False = always `solver.solve_batch` on the full
    LCP. With mu >~ 1 (Painleve-type non-uniqueness) the two may pick different valid
    solutions; the active-set one has no spurious impulses.
    """

    def __init__(
        self,
        scenario: Scenario,
        extensions: Sequence[ModelExtension] = (),
        solver: LCPSolver | None = None,
        *,
        active_set: bool = False,
    ) -> None:
        self.scenario = scenario
        self.active_set = active_set
        self.extensions: tuple[ModelExtension, ...] = tuple(extensions)
        self.solver: LCPSolver = solver if solver is not None else LemkeSolver()
        body = scenario.body
        k = compose_mass_factor(self.extensions)
        diag = [body.mass, body.mass] + ([body.inertia] if body.shape == "polygon" else [])
        self.mass_diag: F64 = k * np.asarray(diag, dtype=np.float64)
        self.input_gain: float = compose_input_gain(self.extensions)
        self.support_mu: float = support_friction_mu(self.extensions)
        self.nq: int = scenario.nq
        self.nc: int = scenario.n_contacts
        self.pairs: NDArray[np.int64] = np.asarray(scenario.contact_pairs, dtype=np.int64)

    # ------------------------------------------------------------------------ ingredients
    @property
    def mass_matrix(self) -> F64:
        """M = diag(m, m[, I]) (kg, kg m^2), including a mass_scale extension."""
        return np.diag(self.mass_diag)

    def generalized_force(self, q: ArrayLike, v: ArrayLike, u: ArrayLike) -> F64:
        """F(q, v, u)[..., nv]: gravity (edge only, -y) + gain * u + extension forces (N)."""
        va = np.asarray(v, dtype=np.float64)
        ua = np.asarray(u, dtype=np.float64)
        if ua.shape[-1:] != (self.nq,):
            msg = (
                f"input wrench u must have shape (..., {self.nq}) (fx, fy"
                f"{', tau' if self.nq == 3 else ''}), got {ua.shape}"
            )
            raise ModelError(msg)
        f = self.input_gain * ua + extra_force(self.extensions, q, va)
        if self.scenario.kind == "edge":
            g = np.zeros(self.nq)
            g[1] = -self.mass_diag[0] * self.scenario.gravity
            f = f + g
        return np.asarray(f, dtype=np.float64)

    def friction(
        self, kin: ContactKinematics, mu: MuSpec | None = None, mu_pair: ArrayLike | None = None
    ) -> F64:
        """Friction coefficient per contact [..., C].

        Exactly one of `mu` (scalar, per contact [..., C], or callable s -> mu) and `mu_pair`
        (per friction pair [..., P]) is given; extension fields are applied on top.
        """
        if (mu is None) == (mu_pair is None):
            msg = "give exactly one of mu (per contact / callable) and mu_pair (per pair)"
            raise ModelError(msg)
        if mu_pair is not None:
            mp = np.asarray(mu_pair, dtype=np.float64)
            n_pairs = len(self.scenario.friction.pairs)
            if mp.shape[-1:] != (n_pairs,):
                msg = f"mu_pair must have shape (..., {n_pairs}), got {mp.shape}"
                raise ModelError(msg)
            m = mp[..., self.pairs]
        elif callable(mu):
            m = np.asarray(mu(kin.s), dtype=np.float64)
        else:
            m = np.asarray(mu, dtype=np.float64)
        m = compose_mu_field(self.extensions, kin.s, m)
        if np.any(~np.isfinite(m)) or np.any(m < 0.0):
            msg = f"friction coefficients must be finite and >= 0, got {m}"
            raise ModelError(msg)
        return np.asarray(np.broadcast_to(m, kin.phi.shape), dtype=np.float64)

    def _prepare(
        self,
        state: State,
        u: ArrayLike,
        env: ArrayLike | None,
        env_next: ArrayLike | None,
    ) -> tuple[F64, F64, ContactKinematics, F64]:
        dt = self.scenario.dt
        q = np.asarray(state.q, dtype=np.float64)
        v = np.asarray(state.v, dtype=np.float64)
        if q.shape[-1:] != (self.nq,) or v.shape[-1:] != (self.nq,):
            msg = f"state q, v must have shape (..., {self.nq}), got {q.shape}, {v.shape}"
            raise ModelError(msg)
        if not (np.all(np.isfinite(q)) and np.all(np.isfinite(v))):
            msg = "state q, v must be finite"
            raise ModelError(msg)
        n_env = len(self.scenario.joints)
        e0 = np.zeros(n_env) if env is None else np.asarray(env, dtype=np.float64)
        e1 = e0 if env_next is None else np.asarray(env_next, dtype=np.float64)
        kin = contact_kinematics(self.scenario, q, e0, (e1 - e0) / dt)
        v_free = v + dt * self.generalized_force(q, v, u) / self.mass_diag
        if self.support_mu > 0.0:
            v_free = self._support_friction(v_free)
        return q, v, kin, v_free

    def _support_friction(self, v: F64) -> F64:
        speed = np.linalg.norm(v[..., 0:2], axis=-1, keepdims=True)
        dv = self.support_mu * self.scenario.gravity * self.scenario.dt
        factor = np.where(speed > dv, 1.0 - dv / np.maximum(speed, 1e-300), 0.0)
        out = v.copy()
        out[..., 0:2] = v[..., 0:2] * factor
        return out

    def lcp(
        self,
        state: State,
        u: ArrayLike,
        env: ArrayLike | None = None,
        env_next: ArrayLike | None = None,
        *,
        mu: MuSpec | None = None,
        mu_pair: ArrayLike | None = None,
    ) -> tuple[F64, F64]:
        """The Stewart-Trinkle LCP (A[..., 4C, 4C], b[..., 4C]) of one step, w = A z + b.

        Unknown order per contact block: (ln, lt+, lt-, s).
        """
        a, b, *_ = self._lcp(state, u, env, env_next, mu=mu, mu_pair=mu_pair)
        return a, b

    def _lcp(
        self,
        state: State,
        u: ArrayLike,
        env: ArrayLike | None,
        env_next: ArrayLike | None,
        *,
        mu: MuSpec | None,
        mu_pair: ArrayLike | None,
    ) -> tuple[F64, F64, ContactKinematics, F64, F64]:
        _, _, kin, v_free = self._prepare(state, u, env, env_next)
        muc = self.friction(kin, mu, mu_pair)
        minv = 1.0 / self.mass_diag
        jn, jt = kin.Jn, kin.Jt
        wnn = np.einsum("...ik,k,...jk->...ij", jn, minv, jn)
        wnt = np.einsum("...ik,k,...jk->...ij", jn, minv, jt)
        wtt = np.einsum("...ik,k,...jk->...ij", jt, minv, jt)
        wtn = np.swapaxes(wnt, -1, -2)
        lead = kin.phi.shape[:-1]
        c = self.nc
        a = np.zeros((*lead, c, 4, c, 4))
        a[..., :, 0, :, 0] = wnn
        a[..., :, 0, :, 1] = wnt
        a[..., :, 0, :, 2] = -wnt
        a[..., :, 1, :, 0] = wtn
        a[..., :, 1, :, 1] = wtt
        a[..., :, 1, :, 2] = -wtt
        a[..., :, 2, :, 0] = -wtn
        a[..., :, 2, :, 1] = -wtt
        a[..., :, 2, :, 2] = wtt
        eye = np.eye(c)
        a[..., :, 1, :, 3] = eye
        a[..., :, 2, :, 3] = eye
        a[..., :, 3, :, 0] = muc[..., :, None] * eye
        a[..., :, 3, :, 1] = -eye
        a[..., :, 3, :, 2] = -eye
        vn_free = np.einsum("...ck,...k->...c", jn, v_free)
        vt_free = np.einsum("...ck,...k->...c", jt, v_free) - kin.vt_env
        b = np.zeros((*lead, c, 4))
        b[..., 0] = kin.phi / self.scenario.dt + vn_free - kin.vn_env
        b[..., 1] = vt_free
        b[..., 2] = -vt_free
        return a.reshape(*lead, 4 * c, 4 * c), b.reshape(*lead, 4 * c), kin, v_free, muc

    def _solve_active(self, a: F64, b: F64) -> F64:
        """Exact contact-LCP solve on the contacts that can carry an impulse.

        Starts with the contacts whose free-motion gap rate is negative, solves that sub-LCP,
        gives every other contact ln = lt = 0 and slide s = |vt| (which satisfies its block
        exactly) and adds contacts whose gap condition is then violated; falls back to the
        full LCP if the assembled solution does not verify.
        """
        n = b.shape[0]
        nc = n // 4
        active = b[0::4] < 0.0
        tol = 1e-9 * max(1.0, float(np.max(np.abs(b))))
        for _ in range(nc + 1):
            idx = np.nonzero(active)[0]
            z = np.zeros(n)
            if len(idx):
                sub = (4 * idx[:, None] + np.arange(4)).ravel()
                z[sub] = self.solver.solve(a[np.ix_(sub, sub)], b[sub])
            rest = np.nonzero(~active)[0]
            w = a @ z + b
            z[4 * rest + 3] = np.abs(w[4 * rest + 1])
            w = a @ z + b
            viol = ~active & (w[0::4] < -tol)
            if not np.any(viol):
                if lcp_residuals(a, b, z).worst <= tol:
                    return z
                break
            active |= viol
        return self.solver.solve(a, b)

    # ------------------------------------------------------------------------------- step
    def step(
        self,
        state: State,
        u: ArrayLike,
        env: ArrayLike | None = None,
        env_next: ArrayLike | None = None,
        *,
        mu: MuSpec | None = None,
        mu_pair: ArrayLike | None = None,
    ) -> StepResult:
        """Advance one time step dt (broadcasts over leading axes of q, v, u, env).

        env, env_next: joint positions at the start / end of the step ([..., E], m);
        friction by `mu` (scalar, per contact, or callable of the tangent coordinate s) or
        `mu_pair` (per friction pair). Raises SolverError if the LCP solver fails.
        """
        a, b, kin, v_free, muc = self._lcp(state, u, env, env_next, mu=mu, mu_pair=mu_pair)
        lead = kin.phi.shape[:-1]
        c = self.nc
        minv = 1.0 / self.mass_diag
        if isinstance(self.solver, PGSSolver):
            jac = np.stack([kin.Jn, kin.Jt], axis=-2).reshape(*lead, 2 * c, self.nq)
            w = np.einsum("...ik,k,...jk->...ij", jac, minv, jac)
            cvec = np.stack(
                [b.reshape(*lead, c, 4)[..., 0], b.reshape(*lead, c, 4)[..., 1]], -1
            ).reshape(*lead, 2 * c)
            p = self.solver.solve_friction(w, cvec, muc).reshape(*lead, c, 2)
            ln, lt = p[..., 0], p[..., 1]
            slide = None
        else:
            flat_a = a.reshape(-1, 4 * c, 4 * c)
            flat_b = b.reshape(-1, 4 * c)
            try:
                if self.active_set:
                    z = np.stack(
                        [self._solve_active(flat_a[i], flat_b[i]) for i in range(len(flat_b))]
                    )
                else:
                    z = self.solver.solve_batch(flat_a, flat_b)
            except SolverError as err:
                msg = f"contact LCP of scenario '{self.scenario.kind}' failed: {err}"
                raise SolverError(msg) from err
            z = z.reshape(*lead, c, 4)
            ln = z[..., 0]
            lt = z[..., 1] - z[..., 2]
            slide = z[..., 3]
        dv = (
            np.einsum("...ck,...c->...k", kin.Jn, ln) + np.einsum("...ck,...c->...k", kin.Jt, lt)
        ) * minv
        v_next = v_free + dv
        q_next = np.asarray(state.q, dtype=np.float64) + self.scenario.dt * v_next
        vt = np.einsum("...ck,...k->...c", kin.Jt, v_next) - kin.vt_env
        if slide is None:
            slide = np.where(np.abs(lt) >= muc * ln * (1.0 - 1e-9), np.abs(vt), 0.0)
        modes = modes_from_lcp(ln, slide, vt)
        return StepResult(
            q=q_next,
            v=v_next,
            ln=np.asarray(ln, dtype=np.float64),
            lt=np.asarray(lt, dtype=np.float64),
            slide=np.asarray(slide, dtype=np.float64),
            vt=vt,
            phi=kin.phi,
            mu=muc,
            modes=modes,
        )
