"""DBC-SLAM: the Rao-Blackwellized particle filter (Sec. III-B to III-D of the paper).

Per particle i the continuous state (q_i, v_i) is sampled; the discrete state is kept in closed
form: the friction belief ``fric[i, b]`` over the B joint friction hypotheses (one candidate per
pair, C-order of ``np.indices``) and per-contact mode marginals ``modes[i, b, c, m]`` conditioned
on b. Within a step, joint mode hypotheses are enumerated exactly (pruned); between steps the
joint mode posterior is projected onto per-contact marginals (Boyen-Koller). See DESIGN.md,
section "Estimator", for the step-by-step algorithm. Everything is vectorised over (particles,
hypotheses, friction); there is no Python loop over particles.

Frames and units: world frame `world` (REP-103), SI units; poses (x, y[, yaw]) of the body's
centre of mass; twists (vx, vy[, omega]) in the world frame.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np
import numpy.typing as npt

from dbcslam_core.contact_modes import (
    N_MODES,
    ContactLayout,
    Mode,
    ReducedSolution,
    ViolationScales,
    enumerate_hypotheses,
    solve_reduced,
    sum_last,
)
from dbcslam_core.dynamics import PlanarModel
from dbcslam_core.errors import ModelError
from dbcslam_core.extensions import ModelExtension
from dbcslam_core.force_likelihood import force_log_likelihood
from dbcslam_core.geometry import contact_coordinates, contact_kinematics
from dbcslam_core.observation import (
    ForceObservation,
    JointSmoother,
    LinearObservation,
    PoseObservation,
    PoseObservationModel,
    gaussian_log_density,
    gaussian_proposal,
    sample_gaussian_proposal,
    wrap_angle,
)
from dbcslam_core.parameters import (
    PARAMETER_MODELS,
    FrictionMap,
    FrictionMapView,
    predict_parameters,
)
from dbcslam_core.resampling import (
    RESAMPLERS,
    effective_sample_size,
    make_resampler,
    normalise_log_weights,
)
from dbcslam_core.scenario import Disk, Scenario
from dbcslam_core.transition import (
    TransitionParams,
    contact_gap,
    edge_consistency,
    mode_transition,
    soft_modes,
)

__all__ = ["DbcSlamFilter", "Estimate", "FilterConfig", "FilterInput"]

FloatArray = npt.NDArray[np.float64]
IntArray = npt.NDArray[np.int64]

_LOG_2PI = math.log(2.0 * math.pi)


@dataclass(frozen=True)
class FilterConfig:
    """Configuration of `DbcSlamFilter` (SI units).

    * particles: number of particles P; ess_threshold: resample when ESS < ess_threshold * P;
      resampler: key of RESAMPLERS.
    * prune_threshold: per-contact modes and normalised joint hypotheses below this
      probability are pruned; max_hypotheses: cap of joint mode hypotheses per particle.
    * parameter_model / contact_weight / free_weight: eq. (7) form and its weight w on the
      posterior, w = free_weight + (contact_weight - free_weight) * P(pair in contact).
    * process_noise: std of the velocity noise per step for (vx, vy, omega) (m/s, m/s, rad/s;
      a point mass uses the first two); position_noise: std of an additional position noise
      per step (m, m, rad). The velocity noise is force noise passed through the response map
      of each mode hypothesis (contact impulses absorb it in constrained directions) plus
      constrained_noise (variance fraction) of isotropic noise.
    * warmup_steps / warmup_boost: during the first warmup_steps steps the process noise is
      inflated by a factor decaying linearly from 1 + warmup_boost to 1 (the initial velocity
      is unobserved; this lets the cloud lock onto it).
    * support_velocity_eps (m/s): regularisation of the linearised support friction (push
      scenario: implicit Coulomb friction with the table, `PlanarModel.support_matrix`).
    * friction_hold_steps: the friction belief is held at the prior for this many initial
      steps (particles with wrong initial velocities that collide would bias it).
    * transition: softened NCP transition parameters; violation_impulse (dimensionless,
      relative to the contact's impulse magnitude) and violation_velocity (m/s): scales of
      the inequality violations of the reduced dynamics (contact_modes.ViolationScales).
    * frozen_friction: candidate index used for every pair (fixed-friction filter), or None
      to estimate friction.
    * init_position_std (m), init_yaw_std (rad): initial spread around the first observation
      (None = the observation noise); init_velocity_std: (m/s, m/s, rad/s).
    * map_range (m), map_cell (m): grid of the friction map over the contact coordinate s;
      map_lag: fixed lag (steps) of the smoothed friction committed to the map.
    * joint_accel_std: m/s^2, white-acceleration std of the Kalman smoother of joint
      readings.
    * gap_closure: fraction of a positive gap that an in-contact hypothesis closes within
      one step (1 = the time-stepping model: the whole gap, as a velocity jump phi / dt).
      Below 1 a particle whose estimate hovers a little off an obstacle (tilt / position
      error of the estimate) can take the contact hypothesis without a velocity spike that
      its proposal would reject; the gap then closes over a few steps.
    * gap_tolerance (m) or None: with a value, gap_closure applies to gap residuals of
      persisting contacts within this band, of both signs (`transition.contact_gap`): a
      penetration up to gap_tolerance and a positive gap up to gap_tolerance x the contact's
      previous P(in contact) are attributed to estimate errors (jaw positions from noisy joint
      readings jump ~0.14 mm rms between steps; tilt errors lift one vertex of an edge
      contact) and only gap_closure of them is closed per step, instead of a phi / dt
      velocity jump that pops a penetrating particle off the jaw or makes a light contact
      infeasible (ln < 0); the excess and the gap of a new contact (an impact) are closed
      within the step. None: gap_closure scales positive gaps only (any size).
    * joint_maneuver_accel_std: m/s^2, optional agile companion of the joint smoother that
      takes over at starts / stops (`JointSmoother`); allows a small joint_accel_std.
    * smoothed_joint_velocity: obstacle velocities from the joint smoother's velocity
      estimate (True) or from differences of smoothed positions (False).
    * force_noise (N): std per axis of a `ForceObservation` (measurement noise plus the force
      equivalent of the process noise and model error), used when the observation carries
      no std of its own. force_axes: which components of the reading enter the likelihood:
      `normal` (the component along the contact normal: measured better on synthetic and
      pybullet pushes, the tangential part is the most model-sensitive and biased stick/slide
      towards sliding with the lowest pusher friction) or `both`.
    """

    particles: int = 500
    ess_threshold: float = 0.5
    prune_threshold: float = 1e-3
    max_hypotheses: int = 32
    parameter_model: str = "mixture"
    contact_weight: float = 0.98
    free_weight: float = 0.0
    process_noise: tuple[float, float, float] = (0.01, 0.01, 0.5)
    position_noise: tuple[float, float, float] = (1e-5, 1e-5, 1e-4)
    support_velocity_eps: float = 5e-3
    constrained_noise: float = 0.01
    friction_hold_steps: int = 0
    warmup_steps: int = 30
    warmup_boost: float = 10.0
    transition: TransitionParams = field(default_factory=TransitionParams)
    violation_impulse: float = 0.02
    violation_velocity: float = 0.01
    resampler: str = "systematic"
    frozen_friction: int | None = None
    init_position_std: float | None = None
    init_yaw_std: float | None = None
    init_velocity_std: tuple[float, float, float] = (1.0, 1.0, 3.0)
    map_range: tuple[float, float] = (-2.0, 2.0)
    map_cell: float = 0.02
    map_lag: int = 20
    joint_accel_std: float = 0.3
    force_noise: float = 0.2
    force_axes: str = "normal"
    smoothed_joint_velocity: bool = True
    joint_maneuver_accel_std: float | None = None
    gap_closure: float = 1.0
    gap_tolerance: float | None = None

    def __post_init__(self) -> None:
        if self.particles < 1:
            msg = f"particles must be >= 1, got {self.particles}"
            raise ModelError(msg)
        if not 0.0 <= self.ess_threshold <= 1.0:
            msg = f"ess_threshold must be in [0, 1] (fraction of P), got {self.ess_threshold}"
            raise ModelError(msg)
        if not 0.0 <= self.prune_threshold < 1.0:
            msg = f"prune_threshold must be in [0, 1), got {self.prune_threshold}"
            raise ModelError(msg)
        if self.max_hypotheses < 1:
            msg = f"max_hypotheses must be >= 1, got {self.max_hypotheses}"
            raise ModelError(msg)
        if self.parameter_model not in PARAMETER_MODELS:
            msg = (
                f"parameter_model must be one of {list(PARAMETER_MODELS)}, got "
                f"{self.parameter_model!r}"
            )
            raise ModelError(msg)
        for name in ("contact_weight", "free_weight"):
            if not 0.0 <= getattr(self, name) <= 1.0:
                msg = f"{name} must be in [0, 1], got {getattr(self, name)}"
                raise ModelError(msg)
        if len(self.process_noise) != 3 or any(s <= 0.0 for s in self.process_noise):
            msg = f"process_noise needs 3 stds > 0 (vx, vy, omega), got {self.process_noise}"
            raise ModelError(msg)
        if self.resampler not in RESAMPLERS:
            msg = f"resampler must be one of {sorted(RESAMPLERS)}, got {self.resampler!r}"
            raise ModelError(msg)
        if self.force_axes not in ("normal", "both"):
            msg = f"force_axes must be 'normal' or 'both', got {self.force_axes!r}"
            raise ModelError(msg)
        if not (math.isfinite(self.force_noise) and self.force_noise > 0.0):
            msg = f"force_noise must be > 0 N, got {self.force_noise}"
            raise ModelError(msg)
        if not 0.0 < self.gap_closure <= 1.0:
            msg = f"gap_closure must be in (0, 1], got {self.gap_closure}"
            raise ModelError(msg)
        if self.gap_tolerance is not None and not (
            math.isfinite(self.gap_tolerance) and self.gap_tolerance >= 0.0
        ):
            msg = f"gap_tolerance must be None or a finite gap >= 0 m, got {self.gap_tolerance}"
            raise ModelError(msg)
        if self.map_lag < 0:
            msg = f"map_lag must be >= 0, got {self.map_lag}"
            raise ModelError(msg)

    @classmethod
    def preset(cls, kind: str, **overrides: Any) -> FilterConfig:
        """Tuned configuration for a scenario kind (`edge`, `gripper`, `push`).

        edge: friction varies along the edge -> eq. (7) mixture, prior mixed back in while in
        contact and fully out of contact. gripper / push: one time-invariant coefficient ->
        `reuse` (the belief accumulates over the whole grasp). gripper: contact gap residuals
        within gap_tolerance close at gap_closure per step (jaw-estimate jumps vs light
        contacts; `transition.contact_gap`).
        """
        base: dict[str, Any]
        if kind == "edge":
            base = {
                "parameter_model": "mixture",
                "contact_weight": 0.98,
                "free_weight": 0.0,
                "map_range": (-1.0, 3.0),
            }
        elif kind in ("gripper", "push"):
            base = {
                "parameter_model": "reuse",
                "contact_weight": 1.0,
                "free_weight": 1.0,
                "map_range": (-0.2, 0.2),
                "friction_hold_steps": 20,
                "process_noise": (0.003, 0.003, 0.1),
                "init_velocity_std": (0.2, 0.2, 2.0),
                "map_cell": 0.005,
            }
            if kind == "gripper":
                # light sliding contacts (0.03-0.1 N) close only ~60 um per step, less than the
                # jumps of the jaw estimate (0.14 mm rms): contact gap residuals of persisting
                # contacts are estimate errors and close slowly (`transition.contact_gap`)
                base["gap_closure"] = 0.05
                base["gap_tolerance"] = 1e-3
            if kind == "push":
                # constant-speed pusher: a stiff joint smoother (the pusher's position and
                # velocity enter sticking impulses and the predicted pusher force at 1/dt)
                # with an agile companion for starts and stops
                base["joint_accel_std"] = 0.01
                base["joint_maneuver_accel_std"] = 3.0
        else:
            msg = f"no preset for scenario kind {kind!r}; valid kinds are edge, gripper, push"
            raise ModelError(msg)
        base.update(overrides)
        return cls(**base)


@dataclass(frozen=True)
class FilterInput:
    """Known inputs of one filter step.

    wrench: applied force/moment at the centre of mass, world frame: (fx, fy[, tau]) (N, N m),
    acting during the step. joints: joint positions (m) in `scenario.joints` order at the END
    of the step (the time of the step's observation); the filter remembers the previous ones
    (joints at the start of the step). joints_start overrides those remembered start positions.
    """

    wrench: tuple[float, ...] = (0.0, 0.0, 0.0)
    joints: tuple[float, ...] = ()
    joints_start: tuple[float, ...] | None = None


@dataclass(frozen=True)
class Estimate:
    """Filter output of one step.

    pose (3,): weighted mean (x, y, yaw) (m, m, rad; yaw circular mean). A point mass has no
    orientation: yaw = 0 with zero variance (row/column 2 of pose_cov are 0).
    pose_cov (3, 3); twist (3,) = (vx, vy, omega) and twist_cov (3, 3), same convention.
    modes (C, 4): P(mode) per potential contact, order separated, sticking, sliding_pos,
    sliding_neg. friction (pairs, Kmax): posterior over each pair's candidates (zero-padded).
    friction_map: the spatial friction map. ess: effective sample size before resampling.
    live_hypotheses: mean number of live joint mode hypotheses per particle.
    log_likelihood: log p(o_l | o_{0:l-1}) (0 without observation). resampled: whether the
    particles were resampled in this step. step: step counter (1 for the first step).
    """

    step: int
    pose: FloatArray
    pose_cov: FloatArray
    twist: FloatArray
    twist_cov: FloatArray
    modes: FloatArray
    friction: FloatArray
    friction_map: FrictionMapView
    ess: float
    live_hypotheses: float
    log_likelihood: float
    resampled: bool


def _logsumexp(a: FloatArray, axis: int | tuple[int, ...]) -> FloatArray:
    if a.ndim == 1 and axis in (0, -1):  # scalar result: the same ops on Python floats
        m1 = float(a.max())
        m1 = m1 if math.isfinite(m1) else 0.0
        with np.errstate(divide="ignore"):
            return np.asarray(np.log(np.exp(a - m1).sum()) + m1, dtype=np.float64)
    m = np.max(a, axis=axis, keepdims=True)
    m = np.where(np.isfinite(m), m, 0.0)
    with np.errstate(divide="ignore"):
        out = np.log(np.sum(np.exp(a - m), axis=axis, keepdims=True)) + m
    return np.asarray(np.squeeze(out, axis=axis), dtype=np.float64)


class DbcSlamFilter:
    """Online DBC-SLAM filter: `step(observation, inputs) -> Estimate`.

    scenario: the a-priori model (`/scenario`); config: `FilterConfig`; rng: the only source of
    randomness; extensions: optional model extensions (force / mass / gain hooks) of the
    dynamics. The filter initialises itself from the first observation unless `initialize`
    was called.
    """

    def __init__(
        self,
        scenario: Scenario,
        config: FilterConfig | None = None,
        rng: np.random.Generator | None = None,
        extensions: tuple[ModelExtension, ...] = (),
    ) -> None:
        self.scenario = scenario
        self.config = config or FilterConfig()
        self.rng = rng if rng is not None else np.random.default_rng(0)
        self.extensions = tuple(extensions)
        self.model = PlanarModel(scenario, self.extensions)
        cfg = self.config
        self.nq = scenario.nq
        self.n_c = scenario.n_contacts
        self.dt = scenario.dt
        self._inv_mass = 1.0 / self.model.mass_diag
        self._sigma_v = np.asarray(cfg.process_noise[: self.nq], dtype=np.float64)
        self._sigma_q = np.asarray(cfg.position_noise[: self.nq], dtype=np.float64)
        self._obs_model = PoseObservationModel(
            self.nq, scenario.noise.position, scenario.noise.yaw if self.nq == 3 else 0.0
        )
        pcs = scenario.potential_contacts
        self._layout = ContactLayout(
            feature_vertex=tuple(c.vertex for c in pcs),
            obstacle=tuple(c.obstacle for c in pcs),
            n_vertices=len(scenario.body.vertices),
        )
        self._contact_pair = np.asarray(scenario.contact_pairs, dtype=np.int64)
        # (c, d): contacts of adjacent polygon vertices on the same obstacle (edge partners)
        n_vert = len(scenario.body.vertices)
        partners = [
            (a, b)
            for a in range(len(pcs))
            for b in range(len(pcs))
            if a != b
            and pcs[a].obstacle == pcs[b].obstacle
            and pcs[a].vertex >= 0
            and pcs[b].vertex >= 0
            and (abs(pcs[a].vertex - pcs[b].vertex) in (1, n_vert - 1))
        ]
        self._edge_partners = np.asarray(partners, dtype=np.int64).reshape(-1, 2)
        obstacles = scenario.obstacles
        self._obstacle_names = tuple(o.name for o in obstacles)
        self._contact_obstacle = np.asarray([c.obstacle for c in pcs], dtype=np.int64)
        disks = [i for i, o in enumerate(obstacles) if isinstance(o, Disk)]
        self._default_force_obstacle: int | None = disks[0] if len(disks) == 1 else None
        fr = scenario.friction
        self.n_pairs = len(fr.pairs)
        self._n_cand = [len(c) for c in fr.candidates]
        self._k_max = max(self._n_cand)
        if cfg.frozen_friction is not None:
            for p, n in enumerate(self._n_cand):
                if not 0 <= cfg.frozen_friction < n:
                    msg = (
                        f"frozen_friction index {cfg.frozen_friction} out of range for pair "
                        f"{fr.pairs[p]!r} with candidates {list(fr.candidates[p])}"
                    )
                    raise ModelError(msg)
            beta = np.full((1, self.n_pairs), cfg.frozen_friction, dtype=np.int64)
        else:
            beta = np.indices(self._n_cand).reshape(self.n_pairs, -1).T.astype(np.int64)
        self._beta = beta  # (B, pairs) candidate index per pair
        self._beta_onehot = [
            (beta[:, p, None] == np.arange(self._k_max)[None, :]).astype(np.float64)
            for p in range(self.n_pairs)
        ]  # per pair (B, Kmax): joint hypothesis -> the pair's candidate
        self.n_b = beta.shape[0]
        cand = [np.asarray(c, dtype=np.float64) for c in fr.candidates]
        self._mu = np.stack(
            [cand[int(p)][beta[:, int(p)]] for p in self._contact_pair], axis=-1
        )  # (B, C)
        # flat index of pred[p, b, c, m] (P, B, C, 4): p * stride + offset[b, c] + m
        self._pred_stride = self.n_b * self.n_c * N_MODES
        self._pred_offset = (
            np.arange(self.n_b)[:, None] * self.n_c + np.arange(self.n_c)[None, :]
        ) * N_MODES
        # support friction (push): coefficient per friction hypothesis b, or None
        sp = self.model.surface_pair
        self._surface_pair = sp
        self._mu_surface: FloatArray | None
        if sp is not None:
            self._mu_surface = cand[sp][beta[:, sp]]  # (B,)
        else:
            known = self.model.surface_mu()
            self._mu_surface = None if known is None else np.full(self.n_b, float(known))
        self._prior_pair = [np.asarray(p, dtype=np.float64) for p in fr.prior]
        if cfg.frozen_friction is not None:
            self._prior_b = np.ones(1)
        else:
            pri = np.ones(self.n_b)
            for p in range(self.n_pairs):
                pri = pri * self._prior_pair[p][beta[:, p]]
            self._prior_b = pri / pri.sum()
        self._scales = ViolationScales(
            impulse=cfg.violation_impulse,
            velocity=cfg.violation_velocity,
            impulse_floor=1e-3 * float(self.model.mass_diag[0]),
        )
        self._resampler = make_resampler(cfg.resampler)
        self.map = FrictionMap(fr.prior, cfg.map_range[0], cfg.map_range[1], cfg.map_cell)
        self._initialised = False
        self._step = 0
        self._joints_prev: FloatArray | None = None
        self._joint_filter = JointSmoother(
            len(scenario.joints),
            self.dt,
            scenario.noise.joint,
            cfg.joint_accel_std,
            maneuver_accel_std=cfg.joint_maneuver_accel_std,
        )
        self.q = np.zeros((cfg.particles, self.nq))
        self.v = np.zeros((cfg.particles, self.nq))
        self.log_w = np.zeros(cfg.particles)
        self.fric = np.tile(self._prior_b, (cfg.particles, 1))
        self.modes = np.zeros((cfg.particles, self.n_b, self.n_c, N_MODES))
        self.modes[..., Mode.SEPARATED] = 1.0
        # fixed-lag history for the friction map: ring buffer (map_lag + 1, P, W) of packed
        # per-particle rows [fric_pair (pairs * Kmax) | s (C) | P(in contact) (C)], the oldest
        # of the _hist_len entries at slot _hist_head
        self._hist_width = self.n_pairs * self._k_max + 2 * self.n_c
        self._hist_buf = np.zeros((cfg.map_lag + 1, cfg.particles, self._hist_width))
        self._hist_head = 0
        self._hist_len = 0
        # contacts of each friction pair (None: all contacts belong to the pair)
        self._pair_contacts: list[npt.NDArray[np.bool_] | None] = [
            None if bool(np.all(self._contact_pair == pr)) else self._contact_pair == pr
            for pr in range(self.n_pairs)
        ]

    # ------------------------------------------------------------------ initialisation
    def initialize(
        self,
        q_mean: npt.ArrayLike,
        q_std: npt.ArrayLike,
        v_mean: npt.ArrayLike | None = None,
        v_std: npt.ArrayLike | None = None,
        joints: npt.ArrayLike | None = None,
    ) -> None:
        """Draw the initial particles: q ~ N(q_mean, diag(q_std^2)), v ~ N(v_mean, v_std^2).

        joints: joint positions (m) at the initial time. Mode marginals start from the softened
        NCP checks of the initial state; friction from the prior.
        """
        p = self.config.particles
        qm = np.asarray(q_mean, dtype=np.float64).reshape(self.nq)
        qs = np.broadcast_to(np.asarray(q_std, dtype=np.float64), (self.nq,))
        vm = np.zeros(self.nq) if v_mean is None else np.asarray(v_mean, dtype=np.float64)
        vs = (
            np.asarray(self.config.init_velocity_std[: self.nq])
            if v_std is None
            else np.broadcast_to(np.asarray(v_std, dtype=np.float64), (self.nq,))
        )
        self.q = qm + qs * self.rng.standard_normal((p, self.nq))
        self.v = vm + vs * self.rng.standard_normal((p, self.nq))
        if self.nq == 3:
            self.q[:, 2] = wrap_angle(self.q[:, 2])
        self.log_w = np.zeros(p)
        self.fric = np.tile(self._prior_b, (p, 1))
        if joints is not None:
            self._joints_prev = self._joint_filter.reset(joints)
        env = self._joints_prev if self._joints_prev is not None else None
        kin = contact_kinematics(self.scenario, self.q, env, None)
        an = np.einsum("pcv,pv->pc", kin.Jn, self.v) - kin.vn_env
        at = np.einsum("pcv,pv->pc", kin.Jt, self.v) - kin.vt_env
        soft = soft_modes(kin.phi, an, at, self.dt, self.config.transition)
        self.modes = np.broadcast_to(soft[:, None], (p, self.n_b, self.n_c, N_MODES)).copy()
        self._hist_head = 0
        self._hist_len = 0
        self._initialised = True

    def _auto_initialize(self, lin: LinearObservation | None, joints: FloatArray) -> None:
        if lin is None:
            msg = "the filter needs an observation (or initialize()) before its first step"
            raise ModelError(msg)
        cfg = self.config
        qm = np.zeros(self.nq)
        qs = np.full(self.nq, math.pi)
        qm[lin.index] = lin.value
        qs[lin.index] = np.sqrt(lin.var)
        if cfg.init_position_std is not None:
            qs[:2] = cfg.init_position_std
        if self.nq == 3 and cfg.init_yaw_std is not None:
            qs[2] = cfg.init_yaw_std
        self.initialize(qm, qs, joints=joints)

    # ------------------------------------------------------------------------ the step
    def step(
        self,
        observation: PoseObservation | None,
        inputs: FilterInput,
        force: ForceObservation | None = None,
    ) -> Estimate:
        """One filter step of dt: predict with `inputs`, update with `observation` (None =
        predict only) and the optional contact force reading `force` (e.g. `/pusher/wrench`
        at the end of the step) and return the estimate at the end of the step.

        The force enters the likelihood per (particle, joint mode hypothesis, friction
        hypothesis): f ~ N(f_hb, std^2 I) with f_hb the force the reduced solution of the
        hypothesis exerts on the obstacle (`ForceObservation`). It is treated as
        conditionally independent of the sampled process noise given the hypothesis (the
        force equivalent of the process noise is folded into `FilterConfig.force_noise`), so
        it is a factor of the discrete hypothesis weights: it multiplies into the proposal
        weights of (h, b), the particle weight, and the closed-form mode/friction posterior.
        """
        cfg = self.config
        lin = None if observation is None else self._obs_model.linearize(observation)
        force_obst = None if force is None else self._force_obstacle(force)
        u = np.zeros(self.nq)
        wr = np.asarray(inputs.wrench, dtype=np.float64)
        if wr.size < self.nq - (1 if self.nq == 3 and wr.size == 2 else 0) or wr.size > 3:
            msg = f"wrench must be (fx, fy[, tau]), got {inputs.wrench}"
            raise ModelError(msg)
        u[: min(wr.size, self.nq)] = wr[: self.nq]
        n_env = len(self.scenario.joints)
        joints = np.asarray(inputs.joints, dtype=np.float64).reshape(-1)
        if joints.size != n_env:
            msg = (
                f"inputs.joints must hold {n_env} positions {list(self.scenario.joints)}, got "
                f"{inputs.joints}"
            )
            raise ModelError(msg)
        if inputs.joints_start is not None:
            self._joints_prev = self._joint_filter.reset(inputs.joints_start)
        if not self._initialised:
            if self._joints_prev is None:
                self._joints_prev = self._joint_filter.reset(joints)
            self._auto_initialize(lin, self._joints_prev)
        was_tracking = self._joint_filter.initialised and self._joint_filter.r > 0.0
        joints = self._joint_filter.update(joints)
        if cfg.smoothed_joint_velocity and was_tracking:
            # the smoother's velocity, not the difference of two smoothed positions: the
            # difference carries ~2x the position noise / dt, which sticking contacts turn
            # into spurious impulses (and contact forces)
            env_vel = self._joint_filter.velocity
            env0 = joints - self.dt * env_vel
        else:
            env0 = joints if self._joints_prev is None else self._joints_prev
            env_vel = (joints - env0) / self.dt
        self._joints_prev = joints
        self._step += 1
        dt = self.dt
        n_p = cfg.particles

        # 1. kinematics and free motion
        kin = contact_kinematics(self.scenario, self.q, env0, env_vel)
        m_eff: FloatArray | None = None
        v_free_b: FloatArray | None = None
        if self._mu_surface is None:
            f = self.model.generalized_force(self.q, self.v, u)
            v_free = self.v + dt * f * self._inv_mass
        else:  # support friction linearised at the particle velocity (dynamic or quasi-static)
            m_eff, v_free_b = self.model.support_terms(
                self.q, self.v, u, self._mu_surface, velocity_eps=cfg.support_velocity_eps
            )
            v_free = np.einsum("pb,pbv->pv", self.fric, v_free_b)  # transition only
        an = np.einsum("pcv,pv->pc", kin.Jn, v_free) - kin.vn_env
        at = np.einsum("pcv,pv->pc", kin.Jt, v_free) - kin.vt_env
        # 2. transition (softened NCP + persistence)
        soft = soft_modes(kin.phi, an, at, dt, cfg.transition)
        if cfg.transition.edge_tolerance > 0.0 and self._edge_partners.size:
            prev_in = 1.0 - np.einsum("pb,pbc->pc", self.fric, self.modes[..., Mode.SEPARATED])
            partner = np.zeros_like(prev_in)
            for c, d in self._edge_partners:
                partner[:, c] = np.maximum(partner[:, c], prev_in[:, d])
            soft = edge_consistency(
                soft, kin.phi, an, dt, partner_contact=partner, params=cfg.transition
            )
        pred = mode_transition(
            self.modes,
            soft[:, None],
            cfg.transition,
            phi=kin.phi[:, None],
            gap_rate_free=an[:, None],
            dt=dt,
        )  # (P, B, C, 4)
        marg = np.einsum("pb,pbcm->pcm", self.fric, pred)
        # 3. joint hypotheses
        hyp = enumerate_hypotheses(
            marg,
            cfg.prune_threshold,
            cfg.max_hypotheses,
            layout=self._layout,
            phi=kin.phi,
        )
        modes_k = hyp.modes  # (P, K, C)
        n_k = modes_k.shape[1]
        # 4. reduced dynamics for all live (particle, hypothesis) pairs x friction: the padded
        # (P, K) layout is compacted to the N live entries first.
        pi, ki = np.nonzero(hyp.valid)
        n_live = pi.size
        slot = np.full((n_p, n_k), -1, dtype=np.int64)
        slot[pi, ki] = np.arange(n_live)
        modes_n = modes_k[pi, ki]  # (N, C)
        # log prior per entry and friction hypothesis: sum_c log pred[p, b, c, mode_c]
        pbcm = (pi * self._pred_stride)[:, None, None] + self._pred_offset + modes_n[:, None, :]
        pred_full = pred
        if pred.shape != (n_p, self.n_b, self.n_c, N_MODES):
            pred_full = np.broadcast_to(pred, (n_p, self.n_b, self.n_c, N_MODES))
        with np.errstate(divide="ignore"):
            lp = sum_last(np.log(pred_full.take(pbcm)))  # (N, B)
        sol = self._solve_entries(
            modes_n,
            v_free.take(pi, axis=0) if v_free_b is None else v_free_b.take(pi, axis=0),
            kin,
            pi,
            None if m_eff is None else m_eff.take(pi, axis=0),
            sensitivity=force is not None,
        )
        v_h = sol.v_next  # (N, B, nv)
        l_cond_full = np.full((n_p, n_k, self.n_b), -np.inf)
        l_cond_full[pi, ki] = lp - 0.5 * sol.score
        l_cond_full = l_cond_full - self._lse(l_cond_full, 1)[:, None, :]
        with np.errstate(divide="ignore"):
            log_alpha_full = np.log(self.fric)[:, None, :] + l_cond_full  # (P, K, B)
        log_alpha = log_alpha_full[pi, ki]  # (N, B)
        # 5. optimal proposal. Process noise is force noise: a perturbation e of the free
        # velocity reaches v' through the response map of the hypothesis (constrained
        # directions are absorbed by the contact impulses), plus a small isotropic part.
        boost = 1.0
        if cfg.warmup_steps > 0:
            boost += cfg.warmup_boost * max(0.0, 1.0 - (self._step - 1) / cfg.warmup_steps)
        sig2 = (self._sigma_v * boost) ** 2
        if force is not None and force_obst is not None:
            log_alpha = log_alpha + self._force_log_likelihood(
                force, force_obst, sol, kin.normal[pi], sig2
            )
        resp = sol.response  # (N, B, nv, nv)
        cov_h = (resp * sig2) @ np.swapaxes(resp, -1, -2) + cfg.constrained_noise * np.diag(sig2)
        prop = gaussian_proposal(
            self.q.take(pi, axis=0)[:, None, :], v_h, cov_h, dt, lin, sigma_q=self._sigma_q
        )
        log_joint = np.full((n_p, n_k, self.n_b), -np.inf)
        log_joint[pi, ki] = log_alpha + prop.log_pred
        incr = self._lse(log_joint.reshape(n_p, -1), 1)  # (P,)
        flat = log_joint.reshape(n_p, -1)
        gumbel = -np.log(-np.log(self.rng.random(flat.shape)))
        pick = np.argmax(np.where(np.isfinite(flat), flat + gumbel, -np.inf), axis=1)
        k_star, b_star = np.unravel_index(pick, (n_k, self.n_b))
        rows = np.arange(n_p)
        n_star = slot[rows, k_star]
        v_new, e_q = sample_gaussian_proposal(
            prop,
            v_h=v_h[n_star, b_star],
            innovation=prop.innovation[n_star, b_star],
            v_mean=prop.v_mean[n_star, b_star],
            v_cov=prop.v_cov[n_star, b_star],
            dt=dt,
            rng=self.rng,
        )
        q_new = self.q + dt * v_new + e_q
        if self.nq == 3:
            q_new[:, 2] = wrap_angle(q_new[:, 2])
        # 6. closed-form discrete posterior given the sampled continuous state
        log_post = np.full((n_p, n_k, self.n_b), -np.inf)
        dens = gaussian_log_density(v_new.take(pi, axis=0)[:, None, :] - v_h, cov_h)
        log_post[pi, ki] = np.where(np.isfinite(log_alpha), log_alpha + dens, -np.inf)
        log_post = log_post - self._lse(log_post.reshape(n_p, -1), 1)[:, None, None]
        post = np.exp(log_post)  # (P, K, B)
        fric_post = post.sum(axis=1)  # (P, B)
        # num[p, b, c, m] = sum_k post[p, k, b] [mode_c of (p, k) == m], over the live entries
        # (flat index of (p, b, c, mode) as for lp above)
        post_n = post[pi, ki]  # (N, B)
        num = np.bincount(
            pbcm.reshape(-1),
            weights=np.repeat(post_n.reshape(-1), self.n_c),  # post_n[n, b] for every c
            minlength=n_p * self._pred_stride,
        ).reshape(n_p, self.n_b, self.n_c, N_MODES)
        marg_post = num.sum(axis=1)  # (P, C, 4)
        tiny = 1e-12
        modes_post = (num + tiny * marg_post[:, None]) / (fric_post[:, :, None, None] + tiny)
        in_c = modes_n != Mode.SEPARATED  # (N, C)
        p_n = post_n.sum(axis=1)  # (N,) posterior of each live entry
        pair_in = np.zeros((n_p, self.n_pairs))  # (P, pairs): P(pair in contact)
        for pr, mask in enumerate(self._pair_contacts):
            if mask is None:  # all contacts belong to the pair
                w_in = p_n * (sum_last(in_c) > 0)
            elif mask.any():
                w_in = p_n * in_c[:, mask].any(axis=1)
            else:
                continue
            pair_in[:, pr] = np.bincount(pi, weights=w_in, minlength=n_p)
        if self._surface_pair is not None:
            pair_in[:, self._surface_pair] = 1.0  # always on the support
        p_contact = 1.0 - marg_post[:, :, Mode.SEPARATED]  # (P, C)
        fric_pair = self._pair_marginals(fric_post)  # (P, pairs, Kmax)
        # 7. eq. (7): predictive friction belief for the next step
        if self._step <= cfg.friction_hold_steps:
            # warm-up: wrong initial velocities are still being weeded out, and collisions
            # of those particles would bias the friction belief -> hold it at the prior.
            self.fric = np.tile(self._prior_b, (n_p, 1))
            fric_pair = self._pair_marginals(self.fric)
        else:
            self.fric = self._predict_friction(fric_post, fric_pair, pair_in)
        self.modes = modes_post
        # 8. weights, marginal likelihood, map history, resampling
        w_prev, _ = normalise_log_weights(self.log_w)
        with np.errstate(divide="ignore"):
            log_ml = (
                float(_logsumexp(np.log(w_prev) + incr, axis=0))
                if lin is not None or force is not None
                else 0.0
            )
        self.log_w = self.log_w + incr
        if not np.any(np.isfinite(self.log_w)):
            msg = (
                f"all {n_p} particles have zero likelihood at step {self._step}: the observation "
                f"{observation} is incompatible with the model"
            )
            raise ModelError(msg)
        self.q, self.v = q_new, v_new
        w, _ = normalise_log_weights(self.log_w)
        # contact coordinate s at the end of the step for the map
        s_new = contact_coordinates(self.scenario, self.q, joints)
        old = self._hist_push(fric_pair, s_new, p_contact)
        if old is not None:
            self._commit(self.map, old[None], w)
        ess = effective_sample_size(w)
        estimate_w = w
        resampled = False
        if ess < cfg.ess_threshold * n_p:
            idx = self._resampler(w, self.rng)
            self.q = self.q[idx]
            self.v = self.v[idx]
            self.fric = self.fric[idx]
            self.modes = self.modes[idx]
            self._hist_buf = self._hist_buf.take(idx, axis=1)
            self.log_w = np.zeros(n_p)
            resampled = True
            # estimate with the pre-resampling weights (lower variance)
        # the map snapshot uses the weights of the (resampled) particles, as friction_map()
        map_w = normalise_log_weights(self.log_w)[0] if resampled else w
        return self._estimate(
            w=estimate_w,
            map_w=map_w,
            q=q_new,
            v=v_new,
            marg_post=marg_post,
            fric_pair=fric_pair,
            ess=ess,
            live=float(hyp.n_live.mean()),
            log_ml=log_ml,
            resampled=resampled,
        )

    # ------------------------------------------------------------------------ helpers
    @staticmethod
    def _lse(a: FloatArray, axis: int) -> FloatArray:
        """log sum exp over one axis, max-shifted (all -inf -> -inf); few numpy calls."""
        if axis == a.ndim - 1 and a.shape[-1] < 8:  # short last axis: slice chains
            m = a[..., 0].copy()
            for i in range(1, a.shape[-1]):
                np.maximum(m, a[..., i], out=m)
            m[~np.isfinite(m)] = 0.0
            with np.errstate(divide="ignore"):
                return np.asarray(np.log(sum_last(np.exp(a - m[..., None]))) + m)
        m = a.max(axis=axis, keepdims=True)
        m[~np.isfinite(m)] = 0.0
        with np.errstate(divide="ignore"):
            out = np.log(np.exp(a - m).sum(axis=axis, keepdims=True)) + m
        return np.asarray(out.squeeze(axis), dtype=np.float64)

    def _solve_entries(
        self,
        modes: IntArray,
        v_free: FloatArray,
        kin: Any,
        pi: IntArray,
        mass: FloatArray | None,
        *,
        sensitivity: bool,
    ) -> ReducedSolution:
        """Reduced dynamics of the N live entries x B friction hypotheses -> lead (N, B).

        modes (N, C); v_free (N, nv) or (N, B, nv) (support friction); kin at the particles,
        pi (N,) the entries' particles; mass (N, B, nv, nv) or None. `solve_reduced` solves
        the entries without sliding contacts once for all B (their system does not depend on
        friction) and the others per friction hypothesis.
        """
        vf = v_free if v_free.ndim == 3 else v_free[:, None, :]
        cfg = self.config
        prev_in = None
        if cfg.gap_tolerance is not None:  # P(in contact) at the previous step, per particle
            prev_in = 1.0 - np.einsum("pb,pbc->pc", self.fric, self.modes[..., Mode.SEPARATED])
            prev_in = prev_in.take(pi, axis=0)
        phi = contact_gap(
            kin.phi.take(pi, axis=0),
            modes != Mode.SEPARATED,
            closure=cfg.gap_closure,
            tolerance=cfg.gap_tolerance,
            previous_contact=prev_in,
        )
        return solve_reduced(
            modes[:, None, :],
            vf,
            inv_mass=self._inv_mass,
            jn=kin.Jn.take(pi, axis=0)[:, None],
            jt=kin.Jt.take(pi, axis=0)[:, None],
            phi=phi[:, None],
            vn_env=kin.vn_env.take(pi, axis=0)[:, None],
            vt_env=kin.vt_env.take(pi, axis=0)[:, None],
            mu=self._mu[None],
            dt=self.dt,
            scales=self._scales,
            groups=self._layout.obstacle,
            mass=mass,
            impulse_sensitivity=sensitivity,
        )

    def _force_obstacle(self, force: ForceObservation) -> int:
        """Index of the obstacle a force reading refers to (validated)."""
        if force.obstacle is None:
            if self._default_force_obstacle is None:
                msg = (
                    f"force observation without obstacle name, but scenario kind "
                    f"{self.scenario.kind!r} has no single disk obstacle (pusher); name one of "
                    f"{list(self._obstacle_names)}"
                )
                raise ModelError(msg)
            return self._default_force_obstacle
        if force.obstacle not in self._obstacle_names:
            msg = (
                f"force observation names obstacle {force.obstacle!r}; valid obstacles are "
                f"{list(self._obstacle_names)}"
            )
            raise ModelError(msg)
        return self._obstacle_names.index(force.obstacle)

    def _force_log_likelihood(
        self,
        force: ForceObservation,
        obstacle: int,
        sol: ReducedSolution,
        normal: FloatArray,
        sig2: FloatArray,
    ) -> FloatArray:
        """log-likelihood (N, B) of a force reading; see :mod:`dbcslam_core.force_likelihood`.

        sol: the reduced solution (impulses (N, B, C) and their sensitivity to the free
        velocity); normal (N, C, 2) contact normals (into the body, world frame); sig2 (nv,)
        the velocity process-noise variances of the step.
        """
        sel = self._contact_obstacle == obstacle
        std = self.config.force_noise if force.std is None else force.std
        ir = None if sol.impulse_response is None else sol.impulse_response[..., sel, :]
        return force_log_likelihood(
            (force.fx, force.fy),
            std,
            normal[:, None, sel, :],
            sol.ln[..., sel],
            sol.lt[..., sel],
            dt=self.dt,
            impulse_response=ir,
            sig2=sig2,
            axes=self.config.force_axes,
        )

    def _pair_marginals(self, fric_joint: FloatArray) -> FloatArray:
        """(P, B) joint friction belief -> (P, pairs, Kmax) per-pair marginals (zero-padded)."""
        n_p = fric_joint.shape[0]
        out = np.zeros((n_p, self.n_pairs, self._k_max))
        for p in range(self.n_pairs):
            if self.config.frozen_friction is not None:
                out[:, p, self.config.frozen_friction] = 1.0
            else:
                out[:, p, :] = fric_joint @ self._beta_onehot[p]
        return out

    def _predict_friction(
        self, fric_post: FloatArray, fric_pair: FloatArray, pair_in: FloatArray
    ) -> FloatArray:
        cfg = self.config
        if cfg.frozen_friction is not None:
            return np.ones_like(fric_post)
        if cfg.parameter_model == "reuse":
            return fric_post
        w = cfg.free_weight + (cfg.contact_weight - cfg.free_weight) * pair_in  # (P, pairs)
        # product over pairs of the pairs' predictive beliefs, per joint hypothesis (P, B)
        factors = [
            predict_parameters(
                fric_pair[:, p, : self._n_cand[p]],
                self._prior_pair[p],
                w[:, p],
                cfg.parameter_model,
            )[:, self._beta[:, p]]
            for p in range(self.n_pairs)
        ]
        joint = factors[0] if factors else np.ones_like(fric_post)
        for f in factors[1:]:
            joint = joint * f
        joint = joint / sum_last(joint)[:, None]
        return np.asarray(joint, dtype=np.float64)

    def _hist_push(
        self, fric_pair: FloatArray, s: FloatArray, p_contact: FloatArray
    ) -> FloatArray | None:
        """Append one step to the map history; returns the entry (P, W) that leaves the lag
        window (a view, valid until the next push) or None."""
        cap = self._hist_buf.shape[0]
        row = self._hist_buf[(self._hist_head + self._hist_len) % cap]
        pk = self.n_pairs * self._k_max
        row[:, :pk] = fric_pair.reshape(fric_pair.shape[0], pk)
        row[:, pk : pk + self.n_c] = s
        row[:, pk + self.n_c :] = p_contact
        self._hist_len += 1
        if self._hist_len <= self.config.map_lag:
            return None
        old: FloatArray = self._hist_buf[self._hist_head]
        self._hist_head = (self._hist_head + 1) % cap
        self._hist_len -= 1
        return old

    def _hist_entries(self) -> FloatArray:
        """The uncommitted history (L, P, W), oldest first."""
        cap = self._hist_buf.shape[0]
        if self._hist_head + self._hist_len <= cap:
            return self._hist_buf[self._hist_head : self._hist_head + self._hist_len]
        order = (self._hist_head + np.arange(self._hist_len)) % cap
        return self._hist_buf.take(order, axis=0)

    def _map_observations(
        self, entries: FloatArray, w: FloatArray
    ) -> list[tuple[FloatArray, FloatArray, FloatArray] | None]:
        """Friction-map observations of history entries (L, P, W) under particle weights w
        (P,): per pair None or (s, probs (N, K_pair), weight) of the (entry, particle, contact
        of the pair) triples with weight w x P(in contact) > 1e-9 and finite s."""
        pk = self.n_pairs * self._k_max
        n_c = self.n_c
        fp = entries[..., :pk].reshape(-1, self.n_pairs, self._k_max)  # (L P, pairs, Kmax)
        s = entries[..., pk : pk + n_c].reshape(-1, n_c)  # (L P, C)
        weight = (w[:, None] * entries[..., pk + n_c :]).reshape(-1, n_c)  # (L P, C)
        keep = weight > 1e-9
        out: list[tuple[FloatArray, FloatArray, FloatArray] | None] = []
        for pr in range(self.n_pairs):
            mask = self._pair_contacts[pr]
            sel = keep if mask is None else keep & mask[None, :]
            rows, cols = np.nonzero(sel)
            s_sel = s[rows, cols]
            fin = np.isfinite(s_sel)
            if not fin.all():
                rows, cols, s_sel = rows[fin], cols[fin], s_sel[fin]
            if rows.size == 0:
                out.append(None)
                continue
            out.append((s_sel, fp[rows, pr, : self._n_cand[pr]], weight[rows, cols]))
        return out

    def _commit(self, fmap: FrictionMap, entries: FloatArray, w: FloatArray) -> None:
        """Add history entries (L, P, W) to the map under particle weights w (P,)."""
        for pr, obs in enumerate(self._map_observations(entries, w)):
            if obs is not None:
                fmap.add(pr, *obs)

    def friction_map(self) -> FrictionMapView:
        """The friction map including the not yet committed (within the lag) history."""
        w, _ = normalise_log_weights(self.log_w)
        return self._friction_map_view(w)

    def _friction_map_view(self, w: FloatArray) -> FrictionMapView:
        """`friction_map` with the normalised weights w of self.log_w given."""
        if self._hist_len == 0:
            return self.map.view()
        obs = self._map_observations(self._hist_entries(), w)
        pending = [None if o is None else self.map.accumulate(*o) for o in obs]
        return self.map.view(pending)

    def _estimate(
        self,
        *,
        w: FloatArray,
        map_w: FloatArray,
        q: FloatArray,
        v: FloatArray,
        marg_post: FloatArray,
        fric_pair: FloatArray,
        ess: float,
        live: float,
        log_ml: float,
        resampled: bool,
    ) -> Estimate:
        pose = np.zeros(3)
        pose_cov = np.zeros((3, 3))
        twist = np.zeros(3)
        twist_cov = np.zeros((3, 3))
        nq = self.nq
        mean_q = w @ q
        dq = q - mean_q
        if nq == 3:
            yaw = math.atan2(float(w @ np.sin(q[:, 2])), float(w @ np.cos(q[:, 2])))
            mean_q[2] = yaw
            dq[:, 2] = wrap_angle(q[:, 2] - yaw)
        pose[:nq] = mean_q
        pose_cov[:nq, :nq] = (dq * w[:, None]).T @ dq
        mean_v = w @ v
        dv = v - mean_v
        twist[:nq] = mean_v
        twist_cov[:nq, :nq] = (dv * w[:, None]).T @ dv
        modes = np.einsum("p,pcm->cm", w, marg_post)
        friction = np.einsum("p,pqk->qk", w, fric_pair)
        return Estimate(
            step=self._step,
            pose=pose,
            pose_cov=pose_cov,
            twist=twist,
            twist_cov=twist_cov,
            modes=modes,
            friction=friction,
            friction_map=self._friction_map_view(map_w),
            ess=ess,
            live_hypotheses=live,
            log_likelihood=log_ml,
            resampled=resampled,
        )

    def with_config(self, **changes: Any) -> DbcSlamFilter:
        """A fresh filter with the same scenario and rng and a modified config."""
        return DbcSlamFilter(
            self.scenario, replace(self.config, **changes), self.rng, self.extensions
        )
