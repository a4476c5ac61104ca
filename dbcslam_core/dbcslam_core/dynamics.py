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

Support friction (horizontal scenarios; DESIGN.md "Support friction"): Coulomb friction of
support points p_i (weights w_i, normal force w_i m g) against the plane, implicit and
linearised: K(q, v_lin) = mu_s m g sum_i w_i J_i^T J_i / max(|J_i v_lin|, v_eps) and

    (M + dt K) v' = M v + dt F + Jn^T ln + Jt^T lt,

i.e. M is replaced by the effective mass M + dt K everywhere above (the LCP stays linear).
`step` re-linearises at the new v' (iteratively reweighted: a majorise-minimise iteration
of the exact implicit Coulomb step) until v' stops changing; `support_iterations=1` keeps
the single linearisation at the start velocity (the filter's linear model).

Quasi-static push model (``surface.model: quasi_static``; Lynch & Mason 1996, Hogan &
Rodriguez 2016; `dbcslam_core.quasi_static`): inertia is neglected and the support friction
wrench lies on the ellipsoidal limit surface of the pressure distribution, f_max = mu_s m g,
m_max = c f_max with c = sum_i w_i |p_i| (the mean lever arm of the support pressure,
`limit_surface_c`). With D = diag(1, 1, c^2) (the same in body and world frame: rotations
leave the translational block unchanged) the friction wrench of a twist v' is
-f_max D v' / |v'|_D, |v|_D = sqrt(v_x^2 + v_y^2 + c^2 w^2), i.e. the same linear form as
above with K = mu_s m g D / max(|v_lin|_D, v_eps) and no mass and no coasting:

    dt K v' = dt F + Jn^T ln + Jt^T lt       (effective mass dt K, free velocity dt (dt K)^-1 F)

so the object moves only while pushed, with twist ∝ D^-1 J^T lambda = diag(1, 1, 1/c^2) x the
pusher wrench: the motion cone, sticking / sliding / separation of the pusher contact are the
LCP's (and the filter's mode enumeration's) contact modes. The velocity does not depend on
the linearisation (K's shape is fixed, only its scale changes); the impulse does, so `step`
re-linearises at v' until the wrench lies on the limit surface.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass, fields
from typing import Any, Union

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
    support_centre_fraction,
    support_friction_mu,
    support_rim_fraction,
)
from .geometry import ContactKinematics, contact_kinematics, rotate, support_points
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


@dataclass(frozen=True)
class _FlatStep:
    """A batched step's inputs flattened to `n` rows (see `PlanarModel.step`): q, v, u
    [n, nq]; env, env_next [n, E]; mu as given or [n, C]; mu_pair [n, P]; mus [n]."""

    n: int
    q: F64
    v: F64
    u: F64
    env: F64
    env_next: F64
    mu: MuSpec | None
    mu_pair: F64 | None
    mus: F64


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

    Support friction (see module docstring) is on when the support coefficient is given
    (`surface_mu`): a ``support_friction`` extension, the scenario's ``surface.pair`` (from
    ``mu_pair``), an explicit ``mu_surface``, or ``surface.mu`` > 0. support_iterations:
    maximum number of re-linearisations per step (1 = linearised at the start velocity);
    support_tol (m/s): stop when v' changes by less. `support_points` / `support_weights`
    hold the pressure distribution (``surface.pressure``, or the ``support_pressure``
    extension's rim_fraction blend of uniform and rim; a ``support_concentration`` extension
    puts its centre_fraction of the load on an extra point at the centre of mass).
    quasi_static (``surface.model: quasi_static``): the quasi-static push model of the module
    docstring, with the limit-surface ratio `limit_surface_c` (m) of that distribution.
    """

    def __init__(
        self,
        scenario: Scenario,
        extensions: Sequence[ModelExtension] = (),
        solver: LCPSolver | None = None,
        *,
        active_set: bool = False,
        support_iterations: int = 100,
        support_tol: float = 1e-9,
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
        self.support_mu: float | None = support_friction_mu(self.extensions)
        self.nq: int = scenario.nq
        self.nc: int = scenario.n_contacts
        self.pairs: NDArray[np.int64] = np.asarray(scenario.contact_pairs, dtype=np.int64)
        if support_iterations < 1 or not support_tol > 0.0:
            msg = (
                f"support_iterations must be >= 1 and support_tol > 0, got "
                f"{support_iterations}, {support_tol}"
            )
            raise ModelError(msg)
        self.support_iterations = int(support_iterations)
        self.support_tol = float(support_tol)
        surf = scenario.surface
        self.surface_pair: int | None = (
            None if surf.pair is None else scenario.friction.pair_index(surf.pair)
        )
        self.velocity_eps: float = surf.velocity_eps
        verts = body.vertices if body.shape == "polygon" else ()
        pts, wts = support_points(
            verts, surf.pressure_model, rim_fraction=support_rim_fraction(self.extensions)
        )
        centre = support_centre_fraction(self.extensions)
        if centre > 0.0:
            pts = np.vstack([pts, np.zeros((1, 2))])
            wts = np.concatenate([(1.0 - centre) * wts, [centre]])
        self.support_points: F64 = pts
        self.support_weights: F64 = wts
        self.limit_surface_c: float = float(
            np.sum(wts * np.hypot(pts[:, 0], pts[:, 1])) / np.sum(wts)
        )
        """c = m_max / f_max (m): mean lever arm of the support pressure about the CoM."""
        self.quasi_static: bool = scenario.kind == "push" and surf.quasi_static
        if self.quasi_static:
            self._check_quasi_static()

    def _check_quasi_static(self) -> None:
        if self.limit_surface_c < 1e-6:
            msg = (
                f"the quasi-static push model needs a pressure distribution with a lever arm: "
                f"limit-surface c = {self.limit_surface_c:.3g} m (pressure "
                f"{self.scenario.surface.pressure_model!r}); use uniform, rim, vertices or tripod"
            )
            raise ModelError(msg)
        surf = self.scenario.surface
        if self.support_mu is None and surf.pair is None and not surf.mu > 0.0:
            msg = (
                "the quasi-static push model needs support friction (it sets the force scale "
                "f_max = mu_s m g): give surface.pair (estimated) or surface.mu > 0"
            )
            raise ModelError(msg)

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

    # ------------------------------------------------------------------ support friction
    def surface_mu(
        self, mu_pair: ArrayLike | None = None, mu_surface: ArrayLike | None = None
    ) -> F64 | None:
        """Support friction coefficient [...] (None = no support friction).

        Precedence: a ``support_friction`` extension (the model's own value), then an
        explicit `mu_surface`, then ``mu_pair[..., surface pair]`` when the scenario names a
        support pair, then the known ``surface.mu`` (None when it is 0). A scenario with a
        support pair and neither mu_pair nor mu_surface given is an error.
        """
        if self.support_mu is not None:
            return np.asarray(self.support_mu, dtype=np.float64)
        if mu_surface is not None:
            m = np.asarray(mu_surface, dtype=np.float64)
        elif self.surface_pair is not None:
            if mu_pair is None:
                msg = (
                    f"scenario has the support friction pair {self.scenario.surface.pair!r}: "
                    "give mu_pair (per pair, including it) or mu_surface"
                )
                raise ModelError(msg)
            m = np.asarray(mu_pair, dtype=np.float64)[..., self.surface_pair]
        elif self.scenario.surface.mu > 0.0:
            m = np.asarray(self.scenario.surface.mu, dtype=np.float64)
        else:
            return None
        if np.any(~np.isfinite(m)) or np.any(m < 0.0):
            msg = f"support friction coefficient must be finite and >= 0, got {m}"
            raise ModelError(msg)
        if self.quasi_static and np.any(m <= 0.0):
            msg = f"the quasi-static push model needs a support coefficient > 0, got {m}"
            raise ModelError(msg)
        return m

    def support_matrix(
        self,
        q: ArrayLike,
        v: ArrayLike,
        mu_surface: ArrayLike = 1.0,
        *,
        velocity_eps: float | None = None,
    ) -> F64:
        """Linearised support friction K[..., nv, nv] (N s/m; generalised force -K v').

        K = mu_s m g sum_i w_i J_i^T J_i / max(|J_i v|, velocity_eps) with J_i the 2 x nv
        Jacobian of support point i (body frame `support_points`, weight `support_weights`),
        evaluated at q[..., nq], v[..., nv] (the linearisation velocity); mu_surface [...]
        broadcasts over the leading axes; K is linear in it (compute K at mu 1 and scale).
        Symmetric positive semi-definite. velocity_eps (m/s) defaults to the scenario's.
        Quasi-static model: K = mu_s m g D / max(|v|_D, velocity_eps), D = diag(1, 1, c^2)
        (ellipsoidal limit surface, module docstring).
        """
        qa = np.asarray(q, dtype=np.float64)
        va = np.asarray(v, dtype=np.float64)
        mu = np.asarray(mu_surface, dtype=np.float64)
        eps = self.velocity_eps if velocity_eps is None else float(velocity_eps)
        if not eps > 0.0:
            msg = f"velocity_eps must be > 0 m/s, got {eps}"
            raise ModelError(msg)
        load = self.mass_diag[0] * self.scenario.gravity
        if self.quasi_static:
            d = self.limit_surface_diag
            speed = np.sqrt(np.sum(d * va * va, axis=-1))
            scale = load / np.maximum(speed, eps)
            return np.asarray(mu[..., None, None] * (scale[..., None, None] * np.diag(d)))
        w = self.support_weights
        nv = self.nq
        if nv == 2:
            speed = np.linalg.norm(va, axis=-1)
            c = load * float(np.sum(w)) / np.maximum(speed, eps)
            k = c[..., None, None] * np.eye(2)
            return np.asarray(mu[..., None, None] * k, dtype=np.float64)
        r = rotate(qa[..., 2, None], self.support_points)  # (..., N, 2) world offsets
        vi = va[..., None, :2] + va[..., None, 2:3] * np.stack([-r[..., 1], r[..., 0]], -1)
        c = load * w / np.maximum(np.linalg.norm(vi, axis=-1), eps)  # (..., N)
        s0 = np.sum(c, axis=-1)
        sx = np.sum(c * r[..., 0], axis=-1)
        sy = np.sum(c * r[..., 1], axis=-1)
        srr = np.sum(c * np.sum(r * r, axis=-1), axis=-1)
        zero = np.zeros_like(s0)
        k = np.stack(
            [
                np.stack([s0, zero, -sy], -1),
                np.stack([zero, s0, sx], -1),
                np.stack([-sy, sx, srr], -1),
            ],
            -2,
        )
        return np.asarray(mu[..., None, None] * k, dtype=np.float64)

    def effective_mass(
        self,
        q: ArrayLike,
        v: ArrayLike,
        mu_surface: ArrayLike = 1.0,
        *,
        velocity_eps: float | None = None,
    ) -> F64:
        """M + dt K(q, v, mu_surface) [..., nv, nv] (kg, kg m^2): see `support_matrix`.

        The step's velocity update is (M + dt K) v' = M v + dt F + J^T impulses. Quasi-static
        model: dt K (no inertia).
        """
        k = self.support_matrix(q, v, mu_surface, velocity_eps=velocity_eps)
        if self.quasi_static:
            return np.asarray(self.scenario.dt * k, dtype=np.float64)
        return np.asarray(self.mass_matrix + self.scenario.dt * k, dtype=np.float64)

    @property
    def limit_surface_diag(self) -> F64:
        """D = (1, 1, c^2) (m^2 for the rotation): the ellipsoidal limit-surface metric."""
        return np.asarray([1.0, 1.0, self.limit_surface_c**2], dtype=np.float64)

    def support_terms(
        self,
        q: ArrayLike,
        v: ArrayLike,
        u: ArrayLike,
        mu_surface: ArrayLike,
        *,
        velocity_eps: float | None = None,
    ) -> tuple[F64, F64]:
        """Effective mass [P, B, nv, nv] and free velocity [P, B, nv] for P states x B
        support coefficients (the filter's friction hypotheses).

        q, v [P, nq]: states (v is the linearisation velocity); u [nq] or [P, nq]: input
        wrench; mu_surface [B], or [P, B] per state (> 0 for the quasi-static model). K is
        computed once at mu 1
        and scaled per coefficient. Dynamic: (M + dt mu K, (M + dt mu K)^-1 (M v + dt F));
        quasi-static: (dt mu K, (dt mu K)^-1 dt F) - the object does not coast.
        """
        qa = np.asarray(q, dtype=np.float64)
        va = np.asarray(v, dtype=np.float64)
        mus = np.asarray(mu_surface, dtype=np.float64)
        if self.quasi_static and np.any(mus <= 0.0):
            msg = (
                f"the quasi-static push model needs support coefficients > 0 (f_max = mu_s m "
                f"g), got {mus.tolist()}"
            )
            raise ModelError(msg)
        k1 = self.support_matrix(qa, va, 1.0, velocity_eps=velocity_eps)
        mus2 = mus[None, :] if mus.ndim == 1 else mus  # per state: [P, B]
        dtk = self.scenario.dt * mus2[:, :, None, None] * k1[:, None]
        m_eff = dtk if self.quasi_static else self.mass_matrix + dtk
        return m_eff, self.free_velocity(qa[:, None], va[:, None], u, m_eff)

    def free_velocity(
        self,
        q: ArrayLike,
        v: ArrayLike,
        u: ArrayLike,
        m_eff: ArrayLike | None = None,
    ) -> F64:
        """v_free[..., nv] = m_eff^-1 (M v + dt F(q, v, u)) (m/s): velocity without impulses.

        m_eff: effective mass [..., nv, nv] (`effective_mass`); None = M (no support friction).
        Quasi-static model: m_eff^-1 dt F (no coasting; m_eff is required).
        """
        va = np.asarray(v, dtype=np.float64)
        f = self.generalized_force(q, va, u)
        if m_eff is None:
            if self.quasi_static:
                msg = "the quasi-static push model needs the effective mass (support friction)"
                raise ModelError(msg)
            return np.asarray(va + self.scenario.dt * f / self.mass_diag, dtype=np.float64)
        rhs = self.scenario.dt * f
        if not self.quasi_static:
            rhs = rhs + self.mass_diag * va
        me = np.asarray(m_eff, dtype=np.float64)
        lead = np.broadcast_shapes(me.shape[:-2], rhs.shape[:-1])
        me = np.broadcast_to(me, (*lead, self.nq, self.nq))
        rhs = np.broadcast_to(rhs, (*lead, self.nq))
        return np.asarray(np.linalg.solve(me, rhs[..., None])[..., 0], dtype=np.float64)

    def _prepare(
        self,
        state: State,
        u: ArrayLike,
        env: ArrayLike | None,
        env_next: ArrayLike | None,
        *,
        mus: F64 | None,
        v_lin: F64 | None,
    ) -> tuple[F64, F64, ContactKinematics, F64, F64 | None]:
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
        m_eff = None
        if mus is not None:
            m_eff = self.effective_mass(q, v if v_lin is None else v_lin, mus)
            lead = np.broadcast_shapes(m_eff.shape[:-2], kin.phi.shape[:-1])
            m_eff = np.broadcast_to(m_eff, (*lead, self.nq, self.nq))
        v_free = self.free_velocity(q, v, u, m_eff)
        return q, v, kin, v_free, m_eff

    def lcp(
        self,
        state: State,
        u: ArrayLike,
        env: ArrayLike | None = None,
        env_next: ArrayLike | None = None,
        *,
        mu: MuSpec | None = None,
        mu_pair: ArrayLike | None = None,
        mu_surface: ArrayLike | None = None,
        v_lin: ArrayLike | None = None,
    ) -> tuple[F64, F64]:
        """The Stewart-Trinkle LCP (A[..., 4C, 4C], b[..., 4C]) of one step, w = A z + b.

        Unknown order per contact block: (ln, lt+, lt-, s). With support friction the mass
        is the effective mass linearised at v_lin (default: the state's velocity).
        """
        mus = self.surface_mu(mu_pair, mu_surface)
        vl = None if v_lin is None else np.asarray(v_lin, dtype=np.float64)
        a, b, *_ = self._lcp(state, u, env, env_next, mu=mu, mu_pair=mu_pair, mus=mus, v_lin=vl)
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
        mus: F64 | None,
        v_lin: F64 | None,
    ) -> tuple[F64, F64, ContactKinematics, F64, F64, F64 | None]:
        _, _, kin, v_free, m_eff = self._prepare(state, u, env, env_next, mus=mus, v_lin=v_lin)
        muc = self.friction(kin, mu, mu_pair)
        jn, jt = kin.Jn, kin.Jt
        c = self.nc
        if m_eff is None:
            minv = 1.0 / self.mass_diag
            wnn = np.einsum("...ik,k,...jk->...ij", jn, minv, jn)
            wnt = np.einsum("...ik,k,...jk->...ij", jn, minv, jt)
            wtt = np.einsum("...ik,k,...jk->...ij", jt, minv, jt)
        else:
            jac = np.concatenate([jn, jt], axis=-2)  # (..., 2C, nv)
            mj = np.linalg.solve(m_eff, np.swapaxes(jac, -1, -2))  # M_eff^-1 J^T
            d = jac @ mj
            wnn, wnt, wtt = d[..., :c, :c], d[..., :c, c:], d[..., c:, c:]
        wtn = np.swapaxes(wnt, -1, -2)
        lead = kin.phi.shape[:-1]
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
        free = muc == 0.0
        if np.any(free):
            # Frictionless contacts: lt = 0 exactly. Their (lt+, lt-, s) rows with mu = 0 are
            # degenerate (Lemke can ray-terminate on them), so they are decoupled to w = z,
            # b = 0 (solution z = 0); the slide speed is filled in after the solve.
            fb = np.broadcast_to(free, (*lead, c))
            rows = np.zeros((*lead, c, 4, 1, 1), dtype=bool)
            rows[..., :, 1:, 0, 0] = fb[..., :, None]
            cols = np.zeros((*lead, 1, 1, c, 4), dtype=bool)
            cols[..., 0, 0, :, 1:] = fb[..., :, None]
            a = np.where(rows | cols, 0.0, a)
            ar = np.arange(c)
            for k in (1, 2, 3):
                a[..., ar, k, ar, k] = np.where(fb, 1.0, a[..., ar, k, ar, k])
            b[..., :, 1:] = np.where(fb[..., None], 0.0, b[..., :, 1:])
        return (
            a.reshape(*lead, 4 * c, 4 * c),
            b.reshape(*lead, 4 * c),
            kin,
            v_free,
            muc,
            m_eff,
        )

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
        mu_surface: ArrayLike | None = None,
    ) -> StepResult:
        """Advance one time step dt (broadcasts over leading axes of q, v, u, env).

        env, env_next: joint positions at the start / end of the step ([..., E], m);
        friction by `mu` (scalar, per contact, or callable of the tangent coordinate s) or
        `mu_pair` (per friction pair, including the support pair if the scenario has one);
        mu_surface [...]: support friction coefficient (see `surface_mu`). With support
        friction the step is re-linearised at its own result up to `support_iterations`
        times (until v' changes by < `support_tol`, per batch element); an element that has
        not converged by then keeps its last iterate (the step linearised at the previous
        iterate). Raises SolverError if the LCP solver fails.
        """
        mus = self.surface_mu(mu_pair, mu_surface)
        r = self._step_once(state, u, env, env_next, mu=mu, mu_pair=mu_pair, mus=mus, v_lin=None)
        if mus is None:
            return r
        if self.support_iterations == 1:
            return r
        lead = r.v.shape[:-1]
        flat = self._flat_step(state, u, env, env_next, mu=mu, mu_pair=mu_pair, mus=mus, lead=lead)
        out = self._relinearise(r, flat)
        shaped = {k: val.reshape(*lead, -1) for k, val in out.items()}
        shaped["modes"] = shaped["modes"].astype(np.int64)
        return StepResult(**shaped)

    def _flat_step(
        self,
        state: State,
        u: ArrayLike,
        env: ArrayLike | None,
        env_next: ArrayLike | None,
        *,
        mu: MuSpec | None,
        mu_pair: ArrayLike | None,
        mus: F64,
        lead: tuple[int, ...],
    ) -> _FlatStep:
        """The step's inputs broadcast to the batch shape `lead` and flattened to rows."""
        n = int(np.prod(lead))

        def flat(x: ArrayLike, width: int) -> F64:
            a = np.asarray(x, dtype=np.float64)
            return np.broadcast_to(a, (*lead, width)).reshape(n, width)

        n_env = len(self.scenario.joints)
        e0 = flat(np.zeros(n_env) if env is None else env, n_env)
        mu_f: MuSpec | None = mu
        if mu is not None and not callable(mu):
            mu_f = flat(mu, self.nc)
        return _FlatStep(
            n=n,
            q=flat(state.q, self.nq),
            v=flat(state.v, self.nq),
            u=flat(u, self.nq),
            env=e0,
            env_next=e0 if env_next is None else flat(env_next, n_env),
            mu=mu_f,
            mu_pair=None if mu_pair is None else flat(mu_pair, len(self.scenario.friction.pairs)),
            mus=np.broadcast_to(mus, lead).reshape(n),
        )

    def _relinearise(self, first: StepResult, flat: _FlatStep) -> dict[str, NDArray[Any]]:
        """Fixed point v' = g(v_lin) of the support-friction re-linearisation.

        Anderson(1)-accelerated (secant on the residual g(x) - x), per batch row: converged
        rows drop out. `first`: the step linearised at the start velocity. Returns each
        row's last iterate, the `StepResult` fields as (rows, -1) arrays.
        """
        out = {
            f.name: np.array(getattr(first, f.name)).reshape(flat.n, -1)
            for f in fields(StepResult)
        }
        g0 = out["v"].copy()
        x1 = g0.copy()
        res0 = g0 - flat.v
        active = np.arange(flat.n)
        for _ in range(self.support_iterations - 1):
            rs = self._step_once(
                State(flat.q[active], flat.v[active]),
                flat.u[active],
                flat.env[active],
                flat.env_next[active],
                mu=flat.mu[active] if isinstance(flat.mu, np.ndarray) else flat.mu,
                mu_pair=None if flat.mu_pair is None else flat.mu_pair[active],
                mus=flat.mus[active],
                v_lin=x1[active],
            )
            for f in fields(StepResult):
                out[f.name][active] = getattr(rs, f.name).reshape(len(active), -1)
            g1 = rs.v
            res1 = g1 - x1[active]
            done = np.max(np.abs(res1), axis=-1) <= self.support_tol
            dr = res1 - res0[active]
            den = np.sum(dr * dr, axis=-1, keepdims=True)
            num = np.sum(res1 * dr, axis=-1, keepdims=True)
            gamma = np.clip(np.where(den > 0.0, num / np.maximum(den, 1e-300), 0.0), -10.0, 10.0)
            x1[active] = g1 - gamma * (g1 - g0[active])
            g0[active] = g1
            res0[active] = res1
            active = active[~done]
            if active.size == 0:
                break
        return out

    def _step_once(
        self,
        state: State,
        u: ArrayLike,
        env: ArrayLike | None,
        env_next: ArrayLike | None,
        *,
        mu: MuSpec | None,
        mu_pair: ArrayLike | None,
        mus: F64 | None,
        v_lin: F64 | None,
    ) -> StepResult:
        a, b, kin, v_free, muc, m_eff = self._lcp(
            state, u, env, env_next, mu=mu, mu_pair=mu_pair, mus=mus, v_lin=v_lin
        )
        lead = kin.phi.shape[:-1]
        c = self.nc
        minv = 1.0 / self.mass_diag
        if isinstance(self.solver, PGSSolver):
            jac = np.stack([kin.Jn, kin.Jt], axis=-2).reshape(*lead, 2 * c, self.nq)
            if m_eff is None:
                w = np.einsum("...ik,k,...jk->...ij", jac, minv, jac)
            else:
                w = jac @ np.linalg.solve(m_eff, np.swapaxes(jac, -1, -2))
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
        gen = np.einsum("...ck,...c->...k", kin.Jn, ln) + np.einsum("...ck,...c->...k", kin.Jt, lt)
        dv = gen * minv if m_eff is None else np.linalg.solve(m_eff, gen[..., None])[..., 0]
        v_next = v_free + dv
        q_next = np.asarray(state.q, dtype=np.float64) + self.scenario.dt * v_next
        vt = np.einsum("...ck,...k->...c", kin.Jt, v_next) - kin.vt_env
        if slide is None:
            slide = np.where(np.abs(lt) >= muc * ln * (1.0 - 1e-9), np.abs(vt), 0.0)
        else:  # frictionless contacts were decoupled in the LCP: they slide at |vt|
            slide = np.where(muc == 0.0, np.abs(vt), slide)
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
