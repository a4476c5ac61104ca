"""Baselines DBC-SLAM is compared against (Sec. IV of the paper).

* Fixed-friction filter: the DBC-SLAM RBPF with the friction belief frozen to one candidate
  (:func:`fixed_friction_filter`). The paper reports that it diverges as soon as the contact
  enters a region whose friction differs from the frozen value.
* Black-box NCP particle filter (:class:`BlackBoxNCPFilter`, Zhang & Trinkle 2012 style): a
  bootstrap particle filter that advances every particle with the FULL time-stepping LCP of
  :class:`~dbcslam_core.dynamics.PlanarModel` (a black box: no contact-mode enumeration, no
  Rao-Blackwellisation). Friction is a discrete particle state (one candidate index per
  friction pair) with regime switching (each step, with probability ``switch_prob``, a pair's
  index is redrawn from the prior) so the filter can follow friction that changes along the
  contact. Gaussian process noise acts on the velocity, the observation model is the pose
  model of :mod:`dbcslam_core.observation`. Contact modes are those implied by each particle's
  LCP solution; the friction posterior is the weighted particle count per candidate.

  The LCP solver is chosen by name from :data:`dbcslam_core.lcp.SOLVERS`: ``"lemke"`` pivots
  one LCP per particle (the straightforward implementation of the paper's comparison; the
  loop is in :meth:`LemkeSolver.solve_batch`), ``"pgs"`` runs the batched projected
  Gauss-Seidel friction solve over all particles at once (the fair, vectorised comparison).

Timing convention (same as :class:`dbcslam_core.rbpf.DbcSlamFilter`): every call of ``step``
propagates over one model step dt with the given input wrench (N, N m, acting over the step)
from the joint positions of the previous call (or of ``initialize``) to those given now, then
weighs by the observation. Without a prior ``initialize`` the first call initialises the
particles around its observation first.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field, replace
from typing import Protocol

import numpy as np
from numpy.typing import ArrayLike, NDArray

from .contact_modes import N_MODES
from .dynamics import PlanarModel, State, StepResult
from .errors import ModelError, SolverError
from .extensions import ModelExtension
from .lcp import SOLVERS, LCPSolver, PGSSolver
from .observation import (
    LinearObservation,
    PoseObservation,
    PoseObservationModel,
    proposal_terms,
    sample_noise,
    wrap_angle,
)
from .rbpf import DbcSlamFilter, FilterConfig
from .resampling import effective_sample_size, make_resampler, normalise_log_weights
from .scenario import Scenario

__all__ = [
    "BlackBoxNCPFilter",
    "NCPEstimate",
    "NCPFilterConfig",
    "fixed_friction_filter",
]

F64 = NDArray[np.float64]
I64 = NDArray[np.int64]


def fixed_friction_filter(
    scenario: Scenario,
    candidate: int,
    config: FilterConfig | None = None,
    rng: np.random.Generator | None = None,
    extensions: Sequence[ModelExtension] = (),
) -> DbcSlamFilter:
    """The fixed-friction baseline: DBC-SLAM with every pair's friction frozen to one value.

    candidate: index into each pair's ``friction.candidates`` (e.g. 0 -> mu = 0.3 on the edge).
    config: base configuration (default ``FilterConfig.preset(scenario.kind)``); its
    ``frozen_friction`` is overridden. Raises ModelError if the index is out of range.
    """
    base = config if config is not None else FilterConfig.preset(scenario.kind)
    n_min = min(len(c) for c in scenario.friction.candidates)
    if not 0 <= candidate < n_min:
        msg = (
            f"fixed-friction candidate index {candidate} out of range; valid indices are "
            f"0..{n_min - 1} (candidates {[list(c) for c in scenario.friction.candidates]})"
        )
        raise ModelError(msg)
    return DbcSlamFilter(
        scenario, replace(base, frozen_friction=candidate), rng, tuple(extensions)
    )


class InputLike(Protocol):
    """What a filter step needs besides the observation (matches ``rbpf.FilterInput``)."""

    @property
    def wrench(self) -> ArrayLike:
        """Applied wrench (fx, fy[, tau]) at the centre of mass, world frame (N, N m)."""
        ...

    @property
    def joints(self) -> ArrayLike:
        """Joint (obstacle) positions in ``scenario.joints`` order (m)."""
        ...


@dataclass(frozen=True)
class NCPFilterConfig:
    """Settings of the black-box NCP particle filter.

    particles: number of particles P. solver: key of ``lcp.SOLVERS`` (``lemke`` | ``pgs``).
    process_noise: velocity noise std per dof (m/s, m/s[, rad/s]); position_noise: position
    noise std per step and dof (m, m[, rad]); None = ``default_noise`` of the scenario kind
    (position noise default 0). switch_prob: per-step probability that a particle redraws a
    friction pair's candidate index from the prior (regime switching). init_velocity_std: std (m/s,
    rad/s) of the initial velocity spread around zero (vx, vy, omega). warmup_steps /
    warmup_boost: as in DBC-SLAM's FilterConfig, the process noise is inflated by a factor
    decaying linearly from 1 + warmup_boost to 1 over the first steps (unknown initial
    velocity). ess_threshold: resample when
    ESS < ess_threshold * P. pgs_max_iter / pgs_tol: PGS settings for ``solver="pgs"``.
    proposal: ``bootstrap`` (sample the noise from the prior, weigh by the likelihood) or
    ``optimal`` (the same closed-form Gaussian proposal as DBC-SLAM around the LCP solution).
    active_set: pass ``active_set=True`` to :class:`PlanarModel` (Lemke only: each particle's
    LCP is solved over the contacts that can close, exact, much faster when most contacts are
    open); False = the straightforward full LCP per particle.
    """

    particles: int = 500
    solver: str = "lemke"
    process_noise: tuple[float, ...] | None = None
    position_noise: tuple[float, ...] | None = None
    switch_prob: float = 0.02
    init_velocity_std: tuple[float, float, float] = (1.0, 1.0, 3.0)
    ess_threshold: float = 0.5
    resampler: str = "systematic"
    warmup_steps: int = 30
    warmup_boost: float = 10.0
    pgs_max_iter: int = 100
    pgs_tol: float = 1e-8
    proposal: str = "bootstrap"
    active_set: bool = False

    default_noise: dict[str, tuple[float, ...]] = field(
        default_factory=lambda: {
            # tuned for this filter (best position RMSE of a small grid on seeds 0-1, 500
            # particles): a bootstrap filter without Rao-Blackwellisation degenerates with
            # the much tighter noise DBC-SLAM uses (gripper: 3.5 mm vs 1.0 mm RMSE).
            "edge": (0.01, 0.01),
            "gripper": (0.03, 0.03, 1.0),
            "push": (0.01, 0.01, 0.3),
        }
    )

    def __post_init__(self) -> None:
        if self.particles < 1:
            msg = f"particles must be >= 1, got {self.particles}"
            raise ModelError(msg)
        if self.solver not in SOLVERS:
            msg = f"unknown LCP solver {self.solver!r}; valid solvers are {sorted(SOLVERS)}"
            raise ModelError(msg)
        if not 0.0 <= self.switch_prob <= 1.0:
            msg = f"switch_prob must be in [0, 1], got {self.switch_prob}"
            raise ModelError(msg)
        if self.proposal not in ("bootstrap", "optimal"):
            msg = f"proposal must be 'bootstrap' or 'optimal', got {self.proposal!r}"
            raise ModelError(msg)
        if not 0.0 <= self.ess_threshold <= 1.0:
            msg = f"ess_threshold must be in [0, 1], got {self.ess_threshold}"
            raise ModelError(msg)

    def noise_for(self, scenario: Scenario) -> tuple[F64, F64]:
        """Velocity and position process-noise stds (nv,), (nq,) for `scenario`."""
        if self.process_noise is not None:
            sig = np.asarray(self.process_noise, dtype=np.float64)
        elif scenario.kind in self.default_noise:
            sig = np.asarray(self.default_noise[scenario.kind], dtype=np.float64)
        else:
            msg = f"no default process noise for scenario kind {scenario.kind!r}; give one"
            raise ModelError(msg)
        if sig.shape != (scenario.nq,) or np.any(sig <= 0.0):
            msg = f"process_noise must be {scenario.nq} positive stds, got {sig.tolist()}"
            raise ModelError(msg)
        sq = (
            np.zeros(scenario.nq)
            if self.position_noise is None
            else np.asarray(self.position_noise, dtype=np.float64)
        )
        if sq.shape != (scenario.nq,) or np.any(sq < 0.0):
            msg = f"position_noise must be {scenario.nq} stds >= 0, got {sq.tolist()}"
            raise ModelError(msg)
        return sig, sq


@dataclass(frozen=True)
class NCPEstimate:
    """Output of one black-box filter step (field names as in ``rbpf.Estimate``).

    pose (3,) x, y (m), yaw (rad; 0 for a point mass); pose_cov (3, 3); twist (3,) (m/s,
    rad/s); modes (C, 4) P(mode) per contact (from the particles' LCP solutions); friction
    (pairs, Kmax) posterior (weighted particle counts, zero-padded); ess; live_hypotheses
    (always 1: one LCP solution per particle); log_likelihood (increment of this step);
    resampled.
    """

    step: int
    pose: F64
    pose_cov: F64
    twist: F64
    twist_cov: F64
    modes: F64
    friction: F64
    ess: float
    live_hypotheses: float
    log_likelihood: float
    resampled: bool


def _make_solver(cfg: NCPFilterConfig) -> LCPSolver:
    if cfg.solver == "pgs":
        return PGSSolver(max_iter=cfg.pgs_max_iter, tol=cfg.pgs_tol)
    solver: LCPSolver = SOLVERS[cfg.solver]()
    return solver


class BlackBoxNCPFilter:
    """Bootstrap particle filter with the full LCP simulation as its motion model.

    Args:
        scenario: the a-priori model (body, contacts, friction candidates, noise).
        config: :class:`NCPFilterConfig`.
        rng: the only source of randomness.
        extensions: model extensions passed to :class:`PlanarModel` (default nominal).
    """

    def __init__(
        self,
        scenario: Scenario,
        config: NCPFilterConfig | None = None,
        rng: np.random.Generator | None = None,
        extensions: Sequence[ModelExtension] = (),
    ) -> None:
        self.scenario = scenario
        self.config = config if config is not None else NCPFilterConfig()
        self.rng = rng if rng is not None else np.random.default_rng(0)
        self.model = PlanarModel(
            scenario,
            extensions,
            solver=_make_solver(self.config),
            active_set=self.config.active_set,
        )
        self.nq = scenario.nq
        self.nc = scenario.n_contacts
        self.sigma_v, self.sigma_q = self.config.noise_for(scenario)
        self.obs_model = PoseObservationModel(
            self.nq, scenario.noise.position, scenario.noise.yaw if self.nq == 3 else 0.0
        )
        fr = scenario.friction
        self.n_pairs = len(fr.pairs)
        self.k_max = max(len(c) for c in fr.candidates)
        self.cand = np.zeros((self.n_pairs, self.k_max))
        self.n_cand = np.array([len(c) for c in fr.candidates], dtype=np.int64)
        self.prior_cdf = np.ones((self.n_pairs, self.k_max))
        for p, (cands, pri) in enumerate(zip(fr.candidates, fr.prior, strict=True)):
            self.cand[p, : len(cands)] = cands
            self.prior_cdf[p, : len(pri)] = np.cumsum(pri) / np.sum(pri)
        self.resampler = make_resampler(self.config.resampler)
        self.q: F64 = np.zeros((0, self.nq))
        self.v: F64 = np.zeros((0, self.nq))
        self.fric: I64 = np.zeros((0, self.n_pairs), dtype=np.int64)
        self.log_w: F64 = np.zeros(0)
        self.env_prev: F64 = np.zeros(len(scenario.joints))
        self.n_steps = 0
        self.n_prop = 0
        self.initialized = False
        self.failed_solves = 0

    # ------------------------------------------------------------------ initialisation
    def _draw_friction(self, n: int) -> I64:
        u = self.rng.random((n, self.n_pairs))
        idx = np.empty((n, self.n_pairs), dtype=np.int64)
        for p in range(self.n_pairs):
            idx[:, p] = np.searchsorted(self.prior_cdf[p, : self.n_cand[p]], u[:, p], "right")
        return np.minimum(idx, self.n_cand - 1)

    def initialize(
        self,
        q_mean: ArrayLike,
        q_std: ArrayLike,
        v_mean: ArrayLike | None = None,
        v_std: ArrayLike | None = None,
        joints: ArrayLike | None = None,
    ) -> None:
        """Draw the particles: q ~ N(q_mean, q_std^2), v ~ N(v_mean, v_std^2) (per dof)."""
        n = self.config.particles
        qm = np.broadcast_to(np.asarray(q_mean, dtype=np.float64), (self.nq,))
        qs = np.broadcast_to(np.asarray(q_std, dtype=np.float64), (self.nq,))
        vm = np.zeros(self.nq) if v_mean is None else np.asarray(v_mean, dtype=np.float64)
        vs = (
            np.asarray(self.config.init_velocity_std[: self.nq], dtype=np.float64)
            if v_std is None
            else np.broadcast_to(np.asarray(v_std, dtype=np.float64), (self.nq,))
        )
        self.q = qm + qs * self.rng.standard_normal((n, self.nq))
        self.v = vm + vs * self.rng.standard_normal((n, self.nq))
        self.fric = self._draw_friction(n)
        self.log_w = np.full(n, -math.log(n))
        self.n_prop = 0
        if joints is not None:
            self.env_prev = np.asarray(joints, dtype=np.float64).reshape(-1)
        self.initialized = True

    def _obs_std(self) -> F64:
        std = np.full(self.nq, self.scenario.noise.position)
        if self.nq == 3:
            std[2] = self.scenario.noise.yaw
        return std

    # ---------------------------------------------------------------------------- step
    def _simulate(self, u: F64, env_next: F64) -> tuple[StepResult, NDArray[np.bool_]]:
        """Advance every particle with the full LCP; returns the result and a failure mask."""
        state = State(self.q, self.v)
        mu_pair = self.cand[np.arange(self.n_pairs)[None, :], self.fric]
        ok = np.ones(self.q.shape[0], dtype=bool)
        try:
            res = self.model.step(state, u, self.env_prev, env_next, mu_pair=mu_pair)
        except SolverError:
            # Some particle's LCP failed (e.g. Lemke ray termination): redo one by one and
            # drop the failing particles (zero weight) instead of failing the whole filter.
            parts: list[StepResult | None] = []
            for i in range(self.q.shape[0]):
                try:
                    parts.append(
                        self.model.step(
                            State(self.q[i], self.v[i]),
                            u,
                            self.env_prev,
                            env_next,
                            mu_pair=mu_pair[i],
                        )
                    )
                except SolverError:
                    parts.append(None)
                    ok[i] = False
            self.failed_solves += int(np.sum(~ok))
            if not np.any(ok):
                msg = (
                    f"black-box NCP filter: the LCP of every particle failed at step "
                    f"{self.n_steps} (solver {self.config.solver!r})"
                )
                raise SolverError(msg) from None
            good = next(p for p in parts if p is not None)
            fields = {}
            for name in ("q", "v", "ln", "lt", "slide", "vt", "phi", "mu", "modes"):
                ref = getattr(good, name)
                fields[name] = np.stack(
                    [getattr(p, name) if p is not None else ref for p in parts]
                )
            res = StepResult(**fields)
        return res, ok

    def step(self, observation: PoseObservation | None, inputs: InputLike) -> NCPEstimate:
        """One filter step (see the module docstring for the timing convention)."""
        obs, inp = observation, inputs
        joints = np.asarray(inp.joints, dtype=np.float64).reshape(-1)
        if joints.size != len(self.scenario.joints):
            msg = (
                f"inputs carry {joints.size} joint positions, scenario '{self.scenario.kind}' "
                f"needs {len(self.scenario.joints)} ({list(self.scenario.joints)})"
            )
            raise ModelError(msg)
        lin = None if obs is None else self.obs_model.linearize(obs)
        if not self.initialized:
            if lin is None:
                msg = "the first step needs an observation to initialise the particles"
                raise ModelError(msg)
            q0 = np.zeros(self.nq)
            q0[lin.index] = lin.value
            self.initialize(q0, self._obs_std(), joints=joints)
        u = np.asarray(inp.wrench, dtype=np.float64).reshape(-1)[: self.nq]
        if u.size != self.nq:
            msg = f"input wrench needs {self.nq} components, got {u.size}"
            raise ModelError(msg)
        # regime switching of the friction indices
        switch = self.rng.random(self.fric.shape) < self.config.switch_prob
        if np.any(switch):
            self.fric = np.where(switch, self._draw_friction(self.fric.shape[0]), self.fric)
        res, ok = self._simulate(u, joints)
        self.env_prev = joints
        self.n_prop += 1
        boost = 1.0
        if self.config.warmup_steps > 0:
            frac = 1.0 - (self.n_prop - 1) / self.config.warmup_steps
            boost += self.config.warmup_boost * max(0.0, frac)
        dt = self.scenario.dt
        n = self.q.shape[0]
        log_inc = np.zeros(n)
        if self.config.proposal == "optimal" and lin is not None:
            e_v, e_q, log_inc = self._optimal_noise(res, lin, boost)
        else:
            e_v = boost * self.sigma_v * self.rng.standard_normal((n, self.nq))
            e_q = self.sigma_q * self.rng.standard_normal((n, self.nq))
        v_new = res.v + e_v
        q_new = res.q + dt * e_v + e_q
        if self.config.proposal == "bootstrap" and lin is not None:
            log_inc = lin.log_likelihood(q_new)
        log_inc = np.where(ok, log_inc, -np.inf)
        self.q, self.v = q_new, v_new
        if self.nq == 3:
            self.q[:, 2] = wrap_angle(self.q[:, 2])
        # self.log_w is normalised, so log_sum is the log marginal-likelihood increment
        # log sum_i w_i p(o | x_i)
        w, log_lik = normalise_log_weights(self.log_w + log_inc)
        self.log_w = np.log(np.maximum(w, 1e-300))
        est = self._estimate(res, log_lik if lin is not None else 0.0, resampled=False)
        ess = effective_sample_size(w)
        if ess < self.config.ess_threshold * n:
            idx = self.resampler(w, self.rng)
            self.q, self.v, self.fric = self.q[idx], self.v[idx], self.fric[idx]
            self.log_w = np.full(n, -math.log(n))
            est = replace(est, resampled=True)
        self.n_steps += 1
        return est

    def _optimal_noise(
        self, res: StepResult, lin: LinearObservation, boost: float
    ) -> tuple[F64, F64, F64]:
        sig_v = boost * self.sigma_v
        pt = proposal_terms(self.q, res.v, self.scenario.dt, sig_v, lin, sigma_q=self.sigma_q)
        e_v, e_q = sample_noise(pt, pt.innovation, pt.v_mean, self.scenario.dt, self.rng)
        return e_v, e_q, pt.log_pred

    # ------------------------------------------------------------------------ estimate
    def _estimate(self, res: StepResult, log_lik: float, resampled: bool) -> NCPEstimate:
        w, _ = normalise_log_weights(self.log_w)
        pose = np.zeros(3)
        pose_cov = np.zeros((3, 3))
        twist = np.zeros(3)
        twist_cov = np.zeros((3, 3))
        nq = self.nq
        mean = w @ self.q
        if nq == 3:
            mean[2] = math.atan2(float(w @ np.sin(self.q[:, 2])), float(w @ np.cos(self.q[:, 2])))
        d = self.q - mean
        if nq == 3:
            d[:, 2] = wrap_angle(d[:, 2])
        pose[:nq] = mean
        pose_cov[:nq, :nq] = (w[:, None] * d).T @ d
        vm = w @ self.v
        dv = self.v - vm
        twist[:nq] = vm
        twist_cov[:nq, :nq] = (w[:, None] * dv).T @ dv
        modes = np.zeros((self.nc, N_MODES))
        m = res.modes.reshape(-1, self.nc)
        for c in range(self.nc):
            modes[c] = np.bincount(m[:, c], weights=w, minlength=N_MODES)[:N_MODES]
        fric = np.zeros((self.n_pairs, self.k_max))
        for p in range(self.n_pairs):
            fric[p] = np.bincount(self.fric[:, p], weights=w, minlength=self.k_max)
        return NCPEstimate(
            step=self.n_steps,
            pose=pose,
            pose_cov=pose_cov,
            twist=twist,
            twist_cov=twist_cov,
            modes=modes,
            friction=fric,
            ess=effective_sample_size(w),
            live_hypotheses=1.0,
            log_likelihood=float(log_lik),
            resampled=resampled,
        )
