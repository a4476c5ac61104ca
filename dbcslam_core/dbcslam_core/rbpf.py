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

import contextlib
import math
import time
from collections.abc import Callable
from dataclasses import dataclass, field, fields, replace
from typing import Any

import numpy as np
import numpy.typing as npt

from dbcslam_core import (
    contact_modes,
    force_kernels,
    kernels,
    kinematics_kernels,
    step_kernels,
)
from dbcslam_core.contact_modes import (
    N_MODES,
    ContactLayout,
    Hypotheses,
    LiveHypotheses,
    Mode,
    ReducedSolution,
    ViolationScales,
    enumerate_live,
    solve_reduced,
    sum_last,
)
from dbcslam_core.dynamics import PlanarModel
from dbcslam_core.errors import ModelError, SolverError
from dbcslam_core.extensions import ModelExtension
from dbcslam_core.force_likelihood import force_log_likelihood
from dbcslam_core.geometry import ContactKinematics, contact_coordinates, contact_kinematics
from dbcslam_core.observation import (
    ForceObservation,
    JointSmoother,
    LinearObservation,
    PoseObservation,
    PoseObservationModel,
    gaussian_log_density,
    gaussian_proposal,
    observation_terms,
    sample_gaussian_proposal,
    wrap_angle,
)
from dbcslam_core.parameters import (
    PARAMETER_MODELS,
    FrictionMap,
    FrictionMapView,
    predict_parameters,
)
from dbcslam_core.particles import MapHistory, ParticleSet
from dbcslam_core.resampling import (
    RESAMPLERS,
    effective_sample_size,
    make_resampler,
    normalise_log_weights,
)
from dbcslam_core.row_pool import RowPool, resolve_threads
from dbcslam_core.scenario import (
    Disk,
    Scenario,
    edge_scenario,
    gripper_scenario,
    push_scenario,
)
from dbcslam_core.surprise import SurpriseMonitor
from dbcslam_core.synthetic import PUSH_RECT, PUSH_RECT_MASS
from dbcslam_core.transition import (
    TransitionParams,
    contact_gap,
    edge_consistency,
    mode_transition,
    soft_modes,
)

__all__ = [
    "GRIPPER_BANK_PARTICLES",
    "DbcSlamFilter",
    "Estimate",
    "FilterConfig",
    "FilterInput",
    "warm_up_kernels",
]

GRIPPER_BANK_PARTICLES = 200
"""The gripper preset uses the friction bank below this many particles (`FilterConfig.preset`).
Final P(true mu) >= 0.9 on `bags/gripper`, filter seeds 0-4: with the bank 5/5 at 40 where
the single-copy filter has 1/5 (and 1/5 at 120); without it 5/5 at 150, 200, 300, 500 and
1000, where the bank has 3/5, 5/5, 5/5, 5/5 and 4/5, at 1.5x the CPU per step; on fresh
pybullet runs (seeds 0-9) 8 / 10 either way at 200 and 10 / 10 at 300 (README, "Friction at
small particle counts")."""

FloatArray = npt.NDArray[np.float64]
IntArray = npt.NDArray[np.int64]

_LOG_2PI = math.log(2.0 * math.pi)

_WARM: set[str] = set()  # scenario kinds whose compiled kernels ran in this process (warm_up)


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
    * friction_bank: every particle carries one copy of the continuous state (and of the mode
      marginals) per joint friction hypothesis b, driven by the same random numbers (a bank
      of B fixed-friction sub-filters per particle). The friction belief of a particle is
      then updated by the predictive likelihood of its b-copies, p(b | o) proportional to
      p(b) prod_l p(o_l | o_{<l}, b, copy b), instead of being conditioned on one sampled
      velocity: without the bank, an impact's sampled velocity fits one b only, each
      particle's closed-form belief turns one-hot there and resampling on pose spreads a
      label (at 40 particles the gripper ended on a wrong coefficient in 4 of 5 seeds).
      Resampling moves whole banks. Requires the time-invariant `reuse` parameter model
      (the copies would need IMM-style mixing for a coefficient that changes between
      steps). Cost: every step runs on P x B copies (1.5x the CPU per step on the gripper at
      equal P). The gripper preset sets it below `GRIPPER_BANK_PARTICLES`: from there the
      single-copy filter's belief no longer collapses and ends right as often.
    * bank_switch (probability per step, in [0, 1)): with the bank, IMM mixing of a
      particle's copies at the start of every step after friction_hold_steps: the
      coefficient is modelled as switching to each other hypothesis with probability
      bank_switch / (B - 1) per step, the bank belief is predicted through that transition
      and copy b restarts from copy a's state (q, v, mode marginals) with the mixing
      probability T[a, b] bank[a] / sum_a' T[a', b] bank[a'] (one draw per copy). A copy whose
      belief fell below ~bank_switch is thereby re-seeded from the leading copy instead of
      drifting away unobserved, so the belief can come back when later evidence favours it.
      0 = no mixing (the time-invariant coefficient).
    * bank_resampling: how the bank resamples. `particle`: a particle's copies move together
      (resampled on the particle's evidence log sum_b bank[i, b] p(o | copy b)). `hypothesis`:
      B fixed-friction sub-filters of P copies each, with common random numbers (shared
      draws and one resampling stream for all sub-filters): copy b of every particle carries
      its own weight within hypothesis b and the copies of each hypothesis are resampled on
      those (all hypotheses at once, when the smallest ESS < ess_threshold * P); the friction
      belief is shared by all particles, pi(b) proportional to prior(b) prod_l Z_l(b) with
      Z_l(b) = sum_i W_ib p(o_l | copy i, b) the sub-filter's marginal likelihood (held at the
      prior during friction_hold_steps). No copy drifts unselected behind a leading one, and
      a particle's belief cannot turn one-hot on its own trajectory; the particle weights stay
      uniform and bank[i, b] = P W_ib pi(b) (so w_i bank[i, b] is the row's weight). The
      options below (switch, tempering, cap, gate) act on per-particle beliefs: `particle`
      only.
    * bank_tempering (dimensionless, (0, 1]) and bank_step_cap (nats, > 0, or None): the
      bank belief update uses the copies' log evidence tempered, bank[i, b] proportional to
      bank[i, b] p(o | copy b)^bank_tempering, and, with a cap, each copy's log evidence
      floored at the particle's best copy's minus bank_step_cap (one step's friction log
      likelihood ratio at most the cap). A particle's evidence (its weight increment) stays
      log sum_b bank[i, b] p(o | copy b). 1.0 / None = the exact update. Rationale: one
      particle's copies are single sampled trajectories whose likelihood ratios are sharper
      than the marginal p(o_l | o_<l, b) (on pybullet gripper runs the copies' per-step
      ratios were several times the 500-particle fixed-friction filters' marginal ones).
    * bank_surprise_gate (nats, > 0, or None) and bank_surprise_window (steps): with the bank,
      the belief is not updated in a step whose log predictive likelihood
      log p(o_l | o_<l) falls more than bank_surprise_gate below the median of the last
      bank_surprise_window observed steps (at least 5 of them): the particle cloud lost
      track of the observation (e.g. at an impact with few particles), and the copies'
      likelihood ratios then reflect which copy happens to lie nearest, not the friction.
      None = no gate.
    * threads: threads of the compiled kernels over ranges of rows (`row_pool`): None = the
      CPUs this process may use, at most 4; 1 = the calling thread only. Small problems
      (below ~256 live entries per thread) run in the calling thread anyway. The estimates
      do not depend on it (bit for bit).
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
    friction_bank: bool = False
    bank_switch: float = 0.0
    bank_resampling: str = "particle"
    bank_tempering: float = 1.0
    bank_step_cap: float | None = None
    bank_surprise_gate: float | None = None
    bank_surprise_window: int = 20
    threads: int | None = None

    def __post_init__(self) -> None:
        resolve_threads(self.threads)  # raises ModelError naming the valid values
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
        if self.friction_bank and self.parameter_model != "reuse":
            msg = (
                "friction_bank needs the time-invariant parameter_model 'reuse' (a coefficient "
                f"that changes between steps would need IMM mixing), got {self.parameter_model!r}"
            )
            raise ModelError(msg)
        if not 0.0 < self.bank_tempering <= 1.0:
            msg = f"bank_tempering must be in (0, 1], got {self.bank_tempering}"
            raise ModelError(msg)
        if self.bank_step_cap is not None and not (
            math.isfinite(self.bank_step_cap) and self.bank_step_cap > 0.0
        ):
            msg = f"bank_step_cap must be None or > 0 nats, got {self.bank_step_cap}"
            raise ModelError(msg)
        if self.bank_surprise_gate is not None and not (
            math.isfinite(self.bank_surprise_gate) and self.bank_surprise_gate > 0.0
        ):
            msg = f"bank_surprise_gate must be None or > 0 nats, got {self.bank_surprise_gate}"
            raise ModelError(msg)
        if self.bank_surprise_window < 5:
            msg = f"bank_surprise_window must be >= 5 steps, got {self.bank_surprise_window}"
            raise ModelError(msg)
        if self.bank_resampling not in ("particle", "hypothesis"):
            msg = (
                f"bank_resampling must be 'particle' or 'hypothesis', got {self.bank_resampling!r}"
            )
            raise ModelError(msg)
        if self.bank_resampling == "hypothesis" and (
            self.bank_switch > 0.0
            or self.bank_tempering != 1.0
            or self.bank_step_cap is not None
            or self.bank_surprise_gate is not None
        ):
            msg = (
                "bank_resampling 'hypothesis' shares one friction belief: bank_switch, "
                "bank_tempering, bank_step_cap and bank_surprise_gate act on per-particle "
                "beliefs ('particle' resampling) and must keep their defaults"
            )
            raise ModelError(msg)
        if not 0.0 <= self.bank_switch < 1.0:
            msg = f"bank_switch must be a probability in [0, 1), got {self.bank_switch}"
            raise ModelError(msg)
        changed = [  # the bank options set away from their defaults
            f.name
            for f in fields(self)
            if f.name.startswith("bank_") and getattr(self, f.name) != f.default
        ]
        if changed and not self.friction_bank:
            one = len(changed) == 1
            msg = (
                f"{', '.join(changed)} {'acts' if one else 'act'} only with friction_bank=True, "
                f"which is off here (the gripper preset turns it on below "
                f"{GRIPPER_BANK_PARTICLES} particles, this config has {self.particles}); pass "
                f"friction_bank=True to use {'it' if one else 'them'}"
            )
            raise ModelError(msg)

    @classmethod
    def preset(cls, kind: str, **overrides: Any) -> FilterConfig:
        """Tuned configuration for a scenario kind (`edge`, `gripper`, `push`).

        edge: friction varies along the edge -> eq. (7) mixture, prior mixed back in while in
        contact and fully out of contact. gripper / push: one time-invariant coefficient ->
        `reuse` (the belief accumulates over the whole grasp). gripper: contact gap residuals
        within gap_tolerance close at gap_closure per step (jaw-estimate jumps vs light
        contacts; `transition.contact_gap`), and the friction bank below
        `GRIPPER_BANK_PARTICLES` particles (an explicit ``friction_bank`` override wins).
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
                # one state copy per friction candidate below GRIPPER_BANK_PARTICLES (the
                # gripper's belief collapsed at small particle counts); from there on the
                # single-copy filter ends right as often and costs 1 / 1.5 (README, "Friction
                # at small particle counts"); not for push: on bags/push the bank ended
                # confidently on a wrong pusher coefficient (0.1 / 0.3 at 500 particles)
                particles = int(overrides.get("particles", cls.particles))
                base["friction_bank"] = particles < GRIPPER_BANK_PARTICLES
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
    particle_poses (R, nq) and particle_weights (R,): the particle cloud the estimate was
    computed from (rows of the state arrays before resampling; weights sum to 1), e.g. for
    visualisation.
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
    particle_poses: FloatArray = field(default_factory=lambda: np.zeros((0, 3)))
    particle_weights: FloatArray = field(default_factory=lambda: np.zeros(0))

    def non_finite_field(self) -> str | None:
        """Name of the first output field holding a NaN or infinity (None: all finite)."""
        for name in ("pose", "pose_cov", "twist", "twist_cov", "modes", "friction"):
            if not np.all(np.isfinite(getattr(self, name))):
                return name
        for pair, probs in enumerate(self.friction_map.probs):
            if not np.all(np.isfinite(probs)):
                return f"friction map (pair {pair})"
        return None


def _compiled_backend() -> bool:
    """Whether the step runs its compiled kernels: numba available and the compiled backend
    selected (`contact_modes.DEFAULT_BACKEND`, read at every call: tests switch it)."""
    return step_kernels.AVAILABLE and contact_modes.DEFAULT_BACKEND == "compiled"


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


@dataclass(frozen=True)
class _StepInputs:
    """Inputs of one step: the observation and its linearisation, the force reading and its
    obstacle, the wrench u (nq,), smoothed joints at the end of the step and the obstacle
    positions / velocities during the step (env0, env_vel)."""

    observation: PoseObservation | None
    lin: LinearObservation | None
    force: ForceObservation | None
    force_obstacle: int | None
    u: FloatArray
    joints: FloatArray
    env0: FloatArray
    env_vel: FloatArray


@dataclass(frozen=True)
class _FreeMotion:
    """Kinematics at the particles and the motion without contact impulses: v_free (P, nv);
    with support friction v_free_b (P, B, nv) and the effective mass m_eff (P, B, nv, nv);
    free gap rates an and slips at (P, C)."""

    kin: ContactKinematics
    v_free: FloatArray
    v_free_b: FloatArray | None
    m_eff: FloatArray | None
    an: FloatArray
    at: FloatArray


@dataclass(frozen=True)
class _Entries:
    """The N live (particle, joint hypothesis) entries: hyp (padded (P, K) layout), n_k = K,
    pi / ki (N,) their particle and hypothesis, slot (P, K) entry index or -1, modes_n (N, C),
    pbcm (N, B, C) flat index of pred[p, b, c, mode], lp (N, B) log prior."""

    hyp: Hypotheses
    n_k: int
    pi: IntArray
    ki: IntArray
    slot: IntArray
    modes_n: IntArray
    pbcm: IntArray
    lp: FloatArray


@dataclass(frozen=True)
class _Dynamics:
    """Per entry x friction hypothesis: post-step velocity v_h (N, B, nv), discrete proposal
    weight log_alpha (N, B) and velocity noise covariance cov_h (N, B, nv, nv)."""

    v_h: FloatArray
    log_alpha: FloatArray
    cov_h: FloatArray


@dataclass(frozen=True)
class _Proposal:
    """Per particle: evidence incr (P,) = log sum over (h, b) of proposal weight x predictive
    likelihood, and the sampled state v_new, q_new (P, nq)."""

    incr: FloatArray
    v_new: FloatArray
    q_new: FloatArray


@dataclass
class _Posterior:
    """Closed-form discrete posterior per particle: fric_post (P, B), fric_pair (P, pairs,
    Kmax) per-pair marginals, modes_post (P, B, C, 4) given b, marg_post (P, C, 4), pair_in
    (P, pairs) P(pair in contact), p_contact (P, C)."""

    fric_post: FloatArray
    fric_pair: FloatArray
    modes_post: FloatArray
    marg_post: FloatArray
    pair_in: FloatArray
    p_contact: FloatArray


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
        self._init_contacts()
        self._init_friction()
        self._scales = ViolationScales(
            impulse=cfg.violation_impulse,
            velocity=cfg.violation_velocity,
            impulse_floor=1e-3 * float(self.model.mass_diag[0]),
        )
        self._resampler = make_resampler(cfg.resampler)
        self._work: dict[str, npt.NDArray[Any]] = {}  # reusable per-step buffers (step_kernels)
        self._pool = RowPool(cfg.threads)  # threads of the compiled kernels over rows
        prior = scenario.friction.prior
        self.map = FrictionMap(prior, cfg.map_range[0], cfg.map_range[1], cfg.map_cell)
        self._initialised = False
        self._step = 0
        self._surprise = SurpriseMonitor(cfg.bank_surprise_window)  # `_surprised`
        self._joints_prev: FloatArray | None = None
        self._joint_filter = JointSmoother(
            len(scenario.joints),
            self.dt,
            scenario.noise.joint,
            cfg.joint_accel_std,
            maneuver_accel_std=cfg.joint_maneuver_accel_std,
        )
        self.particles = self._empty_particles()

    def _init_contacts(self) -> None:
        """Static contact structure: layout for the geometric exclusions, friction pair and
        obstacle of each contact, edge partners, the default force obstacle (a single
        disk: the pusher)."""
        scenario = self.scenario
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

    def _init_friction(self) -> None:
        """Joint friction hypotheses beta (B, pairs), their coefficients per contact, the
        friction bank's copies, the support coefficient per hypothesis and the priors."""
        cfg = self.config
        fr = self.scenario.friction
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
        # friction bank: n_sub copies of each particle, one per friction hypothesis, whose
        # arrays carry a friction axis of length n_fb = 1 (sub-particle j = i * n_sub + b has
        # hypothesis _sub_b[j]); without the bank n_sub = 1 and the arrays carry all B
        self._bank = cfg.friction_bank and cfg.frozen_friction is None and self.n_b > 1
        self._n_sub = self.n_b if self._bank else 1
        self._by_hypothesis = self._bank and cfg.bank_resampling == "hypothesis"
        self._log_pi = np.zeros(self._n_sub)  # hypothesis resampling: log pi(b)
        self.n_fb = 1 if self._bank else self.n_b
        self._sub_b: IntArray | None = (
            np.tile(np.arange(self.n_b), cfg.particles) if self._bank else None
        )
        # flat index of pred[p, b, c, m] (P, B, C, 4): p * stride + offset[b, c] + m
        self._pred_stride = self.n_fb * self.n_c * N_MODES
        self._pred_offset = (
            np.arange(self.n_fb)[:, None] * self.n_c + np.arange(self.n_c)[None, :]
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
        self._prior_fb = np.ones(1) if self._bank else self._prior_b  # arrays' friction axis
        # contacts of each friction pair (None: all contacts belong to the pair)
        self._pair_contacts: list[npt.NDArray[np.bool_] | None] = [
            None if bool(np.all(self._contact_pair == pr)) else self._contact_pair == pr
            for pr in range(self.n_pairs)
        ]
        # the same as a (pairs, C) mask, and each contact's obstacle group (0..n-1), for
        # the compiled phases
        self._pair_mask = self._contact_pair[None, :] == np.arange(self.n_pairs)[:, None]
        self._group_index = np.unique(self._contact_obstacle, return_inverse=True)[1].astype(
            np.int64
        )

    def _empty_particles(self) -> ParticleSet:
        """The particle set before initialisation (all contacts separated, prior friction)."""
        cfg = self.config
        n_sub_particles = cfg.particles * self._n_sub
        modes0 = np.zeros((n_sub_particles, self.n_fb, self.n_c, N_MODES))
        modes0[..., Mode.SEPARATED] = 1.0
        return ParticleSet(
            q=np.zeros((n_sub_particles, self.nq)),
            v=np.zeros((n_sub_particles, self.nq)),
            log_w=np.zeros(cfg.particles),
            fric=np.tile(self._prior_fb, (n_sub_particles, 1)),
            modes=modes0,
            history=MapHistory(
                cfg.map_lag, cfg.particles, self.n_pairs * self._k_max + 2 * self.n_c
            ),
            bank=np.tile(self._prior_b, (cfg.particles, 1)) if self._bank else None,
            copies=self._n_sub,
        )

    # ------------------------------------------------------------- particle arrays
    @property
    def q(self) -> FloatArray:
        """Particle poses (P, nq) (m, m[, rad]), world frame."""
        return self.particles.q

    @q.setter
    def q(self, value: FloatArray) -> None:
        self.particles.q = value

    @property
    def v(self) -> FloatArray:
        """Particle twists (P, nq) (m/s, m/s[, rad/s]), world frame."""
        return self.particles.v

    @v.setter
    def v(self, value: FloatArray) -> None:
        self.particles.v = value

    @property
    def log_w(self) -> FloatArray:
        """Unnormalised log weights (P,)."""
        return self.particles.log_w

    @property
    def fric(self) -> FloatArray:
        """Friction belief over the joint friction hypotheses (P, B)."""
        return self.particles.fric

    @property
    def modes(self) -> FloatArray:
        """Per-contact mode marginals given the friction hypothesis (P, B, C, 4)."""
        return self.particles.modes

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
        q = qm + qs * self.rng.standard_normal((p, self.nq))
        v = vm + vs * self.rng.standard_normal((p, self.nq))
        if self.nq == 3:
            q[:, 2] = wrap_angle(q[:, 2])
        if self._n_sub > 1:  # the bank's copies start from their particle's state
            q = np.repeat(q, self._n_sub, axis=0)
            v = np.repeat(v, self._n_sub, axis=0)
        if joints is not None:
            self._joints_prev = self._joint_filter.reset(joints)
        env = self._joints_prev if self._joints_prev is not None else None
        kin = self._kinematics(q, env, None)
        an = np.einsum("pcv,pv->pc", kin.Jn, v) - kin.vn_env
        at = np.einsum("pcv,pv->pc", kin.Jt, v) - kin.vt_env
        soft = soft_modes(kin.phi, an, at, self.dt, self.config.transition)
        ps = self.particles
        n_sub_particles = q.shape[0]
        ps.q, ps.v, ps.log_w = q, v, np.zeros(p)
        ps.fric = np.tile(self._prior_fb, (n_sub_particles, 1))
        ps.modes = np.broadcast_to(
            soft[:, None], (n_sub_particles, self.n_fb, self.n_c, N_MODES)
        ).copy()
        if ps.bank is not None:
            ps.bank = np.tile(self._prior_b, (p, 1))
            if self._by_hypothesis:
                ps.copy_log_w = np.zeros((p, self._n_sub))
                self._log_pi = np.log(self._prior_b)
        ps.history.clear()
        self._surprise.clear()
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

        The phases (DESIGN.md, "Estimator"): read the inputs, free motion, mode prediction
        (softened NCP transition), live joint hypotheses, their reduced dynamics, the optimal
        proposal and the sampled state, the closed-form discrete posterior, eq. (7), weights
        and resampling, and the estimate.
        """
        self._mix_bank()
        inp = self._read_inputs(observation, inputs, force)
        free = self._free_motion(inp)
        pred = self._predict_modes(free)
        hyp = self._enumerate(pred, free)
        if self._compiled_ok(inp):  # phases 4-6 in one compiled pass per row
            prop, post = self._compiled_phases(hyp, pred, free, inp)
        else:  # the numpy reference
            ent = self._live_entries(hyp.padded(), pred)
            dyn = self._hypothesis_dynamics(ent, free, inp)
            prop = self._propose(ent, dyn, inp)
            post = self._discrete_posterior(ent, dyn, prop)
        incr = (
            prop.incr
            if self._n_sub == 1
            else self._bank_evidence(prop.incr, post, inp.lin is not None or inp.force is not None)
        )
        self._update_beliefs(post)
        log_ml = self._reweight(incr, inp)
        w = self._move(prop, post, inp.joints)
        row_w = self._row_weights(w)
        ess, resampled = self._maybe_resample(w)
        map_w = normalise_log_weights(self.particles.log_w)[0] if resampled else w
        return self._estimate(
            w=w,  # the pre-resampling weights (lower variance)
            row_w=row_w,  # the same per row of the state arrays (bank copies)
            map_w=map_w,  # the map snapshot: the (resampled) particles' weights
            q=prop.q_new,
            v=prop.v_new,
            marg_post=post.marg_post,
            fric_pair=post.fric_pair,
            ess=ess,
            live=float(hyp.counts.mean()),
            log_ml=log_ml,
            resampled=resampled,
        )

    # -------------------------------------------------------------------- step phases
    def _read_inputs(
        self,
        observation: PoseObservation | None,
        inputs: FilterInput,
        force: ForceObservation | None,
    ) -> _StepInputs:
        """Validate the inputs, linearise the observation, advance the joint smoother and
        initialise the particles from the first observation if needed."""
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
        return _StepInputs(observation, lin, force, force_obst, u, joints, env0, env_vel)

    def _kinematics(
        self, q: FloatArray, env: FloatArray | None, env_vel: FloatArray | None
    ) -> ContactKinematics:
        """`geometry.contact_kinematics` of the particles q (P, nq) at the joints env (E,)
        (m) moving at env_vel (E,) (m/s): compiled (`kinematics_kernels`, the same values)
        with the compiled backend, else the numpy reference."""
        if _compiled_backend():
            return kinematics_kernels.contact_kinematics(self.scenario, q, env, env_vel)
        return contact_kinematics(self.scenario, q, env, env_vel)

    def _free_motion(self, inp: _StepInputs) -> _FreeMotion:
        """Contact kinematics at the particles and the velocity without contact impulses
        (with the implicit support friction per friction hypothesis when the body rests on
        a surface: v_free (P, B, nv) and the effective mass (P, B, nv, nv))."""
        cfg = self.config
        dt = self.dt
        ps = self.particles
        kin = self._kinematics(ps.q, inp.env0, inp.env_vel)
        m_eff: FloatArray | None = None
        v_free_b: FloatArray | None = None
        if self._mu_surface is None:
            f = self.model.generalized_force(ps.q, ps.v, inp.u)
            v_free = ps.v + dt * f * self._inv_mass
        else:  # support friction linearised at the particle velocity (dynamic or quasi-static)
            mu_s = (  # (B,) or per bank copy (P B, 1)
                self._mu_surface if self._sub_b is None else self._mu_surface[self._sub_b][:, None]
            )
            if _compiled_backend():
                m_eff, v_free_b = step_kernels.support_terms(
                    self.model,
                    ps.q,
                    ps.v,
                    inp.u,
                    mu_s,
                    velocity_eps=cfg.support_velocity_eps,
                    pool=self._pool,
                )
            else:
                m_eff, v_free_b = self.model.support_terms(
                    ps.q, ps.v, inp.u, mu_s, velocity_eps=cfg.support_velocity_eps
                )
            v_free = np.einsum("pb,pbv->pv", ps.fric, v_free_b)  # transition only
        an = np.einsum("pcv,pv->pc", kin.Jn, v_free) - kin.vn_env
        at = np.einsum("pcv,pv->pc", kin.Jt, v_free) - kin.vt_env
        return _FreeMotion(kin, v_free, v_free_b, m_eff, an, at)

    def _predict_modes(self, free: _FreeMotion) -> FloatArray:
        """Predicted per-contact mode marginals (P, B, C, 4): softened NCP checks of the free
        motion, edge consistency of adjacent vertices, persistence (`transition`)."""
        cfg = self.config
        ps = self.particles
        kin = free.kin
        tp = cfg.transition
        if _compiled_backend() and not (
            tp.edge_tolerance > 0.0 and self._edge_partners.size
        ):  # one compiled pass (same operations)
            return step_kernels.predict_modes(
                ps.modes,
                kin.phi,
                free.an,
                free.at,
                dt=self.dt,
                params=(tp.gap_scale, tp.far_gap, tp.slip_scale, tp.slide_floor, tp.persistence),
                pool=self._pool,
            )
        soft = soft_modes(kin.phi, free.an, free.at, self.dt, cfg.transition)
        if cfg.transition.edge_tolerance > 0.0 and self._edge_partners.size:
            prev_in = 1.0 - np.einsum("pb,pbc->pc", ps.fric, ps.modes[..., Mode.SEPARATED])
            partner = np.zeros_like(prev_in)
            for c, d in self._edge_partners:
                partner[:, c] = np.maximum(partner[:, c], prev_in[:, d])
            soft = edge_consistency(
                soft, kin.phi, free.an, self.dt, partner_contact=partner, params=cfg.transition
            )
        return mode_transition(
            ps.modes,
            soft[:, None],
            cfg.transition,
            phi=kin.phi[:, None],
            gap_rate_free=free.an[:, None],
            dt=self.dt,
        )

    def _enumerate(self, pred: FloatArray, free: _FreeMotion) -> LiveHypotheses:
        """Joint mode hypotheses per row (the valid ones, row after row) from the predicted
        marginals averaged over the friction belief."""
        cfg = self.config
        marg = np.einsum("pb,pbcm->pcm", self.particles.fric, pred)
        return enumerate_live(
            marg,
            cfg.prune_threshold,
            cfg.max_hypotheses,
            layout=self._layout,
            phi=free.kin.phi,
            pool=self._pool,
            work=self._work,
        )

    def _live_entries(self, hyp: Hypotheses, pred: FloatArray) -> _Entries:
        """The joint mode hypotheses compacted from the padded (P, K) layout to the N live
        entries, with their log prior per friction hypothesis (N, B)."""
        n_p = self.particles.size
        n_k = hyp.modes.shape[1]
        pi, ki = np.nonzero(hyp.valid)
        slot = np.full((n_p, n_k), -1, dtype=np.int64)
        slot[pi, ki] = np.arange(pi.size)
        modes_n = hyp.modes[pi, ki]  # (N, C)
        # log prior per entry and friction hypothesis: sum_c log pred[p, b, c, mode_c]
        pbcm = (pi * self._pred_stride)[:, None, None] + self._pred_offset + modes_n[:, None, :]
        pred_full = pred
        if pred.shape != (n_p, self.n_fb, self.n_c, N_MODES):
            pred_full = np.broadcast_to(pred, (n_p, self.n_fb, self.n_c, N_MODES))
        with np.errstate(divide="ignore"):
            lp = sum_last(np.log(pred_full.take(pbcm)))  # (N, B)
        return _Entries(hyp, n_k, pi, ki, slot, modes_n, pbcm, lp)

    def _hypothesis_dynamics(
        self, ent: _Entries, free: _FreeMotion, inp: _StepInputs
    ) -> _Dynamics:
        """Reduced dynamics of every live entry x friction hypothesis, the discrete proposal
        weights log alpha (N, B) (friction belief x mode prior x NCP consistency, times the
        force likelihood) and the velocity noise covariance of each (N, B, nv, nv)."""
        cfg = self.config
        n_p = self.particles.size
        sol = self._solve_entries(
            ent.modes_n,
            free.v_free.take(ent.pi, axis=0)
            if free.v_free_b is None
            else free.v_free_b.take(ent.pi, axis=0),
            free.kin,
            ent.pi,
            None if free.m_eff is None else free.m_eff.take(ent.pi, axis=0),
            sensitivity=inp.force is not None,
        )
        l_cond = np.full((n_p, ent.n_k, self.n_fb), -np.inf)
        l_cond[ent.pi, ent.ki] = ent.lp - 0.5 * sol.score
        l_cond = l_cond - self._lse(l_cond, 1)[:, None, :]
        with np.errstate(divide="ignore"):
            log_alpha_full = np.log(self.particles.fric)[:, None, :] + l_cond  # (P, K, B)
        log_alpha = log_alpha_full[ent.pi, ent.ki]  # (N, B)
        # Process noise is force noise: a perturbation e of the free velocity reaches v'
        # through the response map of the hypothesis (constrained directions are absorbed by
        # the contact impulses), plus a small isotropic part.
        sig2 = self._velocity_noise()
        if inp.force is not None and inp.force_obstacle is not None:
            log_alpha = log_alpha + self._force_log_likelihood(
                inp.force,
                inp.force_obstacle,
                (sol.ln, sol.lt, sol.impulse_response),
                free.kin.normal[ent.pi],
                sig2,
            )
        resp = sol.response  # (N, B, nv, nv)
        cov_h = (resp * sig2) @ np.swapaxes(resp, -1, -2) + cfg.constrained_noise * np.diag(sig2)
        return _Dynamics(sol.v_next, log_alpha, cov_h)

    def _velocity_noise(self) -> FloatArray:
        """Velocity process-noise variances (nv,) of this step (inflated during warm-up)."""
        cfg = self.config
        boost = 1.0
        if cfg.warmup_steps > 0:
            boost += cfg.warmup_boost * max(0.0, 1.0 - (self._step - 1) / cfg.warmup_steps)
        return np.asarray((self._sigma_v * boost) ** 2, dtype=np.float64)

    def _compiled_ok(self, inp: _StepInputs) -> bool:
        """Whether phases 4-6 can run compiled (`step_kernels`): numba present, the compiled
        backend selected (`contact_modes.DEFAULT_BACKEND`), and a reading of every pose dim
        (or none)."""
        if not (_compiled_backend()):
            return False
        lin = inp.lin
        return lin is None or (
            lin.index.size == self.nq and bool(np.array_equal(lin.index, np.arange(self.nq)))
        )

    def _compiled_phases(
        self, hyp: LiveHypotheses, pred: FloatArray, free: _FreeMotion, inp: _StepInputs
    ) -> tuple[_Proposal, _Posterior]:
        """Phases 4-6 (`_hypothesis_dynamics`, `_propose`, `_discrete_posterior`) through the
        compiled kernels of `step_kernels`: the same equations per element, the same random
        numbers in the same order, values equal to round-off."""
        n_live = hyp.counts
        starts = np.zeros(self.particles.size + 1, dtype=np.int64)
        np.cumsum(n_live, out=starts[1:])
        sig2 = self._velocity_noise()
        out = self._compiled_dynamics(starts, hyp.modes, pred, free, inp=inp, sig2=sig2)
        log_alpha = out["log_alpha"]
        if inp.force is not None and inp.force_obstacle is not None:
            log_alpha = log_alpha + self._compiled_force_log_likelihood(
                starts,
                inp.force,
                obstacle=inp.force_obstacle,
                out=out,
                normal=free.kin.normal,
                sig2=sig2,
            )
        res = self._compiled_proposal(
            starts, hyp, out, log_alpha, free=free, inp=inp, cov_floor=self._cov_floor(sig2)
        )
        pair_in = res["pair_in"]
        if self._surface_pair is not None:
            pair_in[:, self._surface_pair] = 1.0  # always on the support
        marg_post = res["marg_post"]
        fric_post = res["fric_post"]
        fric_pair = (
            self._pair_marginals(fric_post)
            if self._n_sub == 1
            else np.empty((0, self.n_pairs, self._k_max))
        )
        post = _Posterior(
            fric_post,
            fric_pair,
            res["modes_post"],
            marg_post,
            pair_in,
            1.0 - marg_post[:, :, Mode.SEPARATED],
        )
        return _Proposal(res["incr"], res["v_new"], res["q_new"]), post

    def _compiled_dynamics(
        self,
        starts: IntArray,
        modes_n: IntArray,
        pred: FloatArray,
        free: _FreeMotion,
        *,
        inp: _StepInputs,
        sig2: FloatArray,
    ) -> dict[str, Any]:
        """Phase 4 compiled (`step_kernels.entry_dynamics`): per live entry (rows starts,
        modes modes_n (N, C)) x friction the post-step velocity, impulses, noise covariance
        and proposal weight log alpha (without a force reading)."""
        cfg = self.config
        ps = self.particles
        kin = free.kin
        prev_in = None
        if cfg.gap_tolerance is not None:  # P(in contact) at the previous step, per row
            prev_in = 1.0 - np.einsum("pb,pbc->pc", ps.fric, ps.modes[..., Mode.SEPARATED])
        with np.errstate(divide="ignore"):
            log_pred = np.log(pred)
        out, n_bad = step_kernels.entry_dynamics(
            starts,
            modes_n,
            jn=kin.Jn,
            jt=kin.Jt,
            phi=kin.phi,
            vn_env=kin.vn_env,
            vt_env=kin.vt_env,
            v_free=free.v_free[:, None, :] if free.v_free_b is None else free.v_free_b,
            inv_mass=self._inv_mass,
            mass=free.m_eff,
            mu=self._mu,
            row_b=self._sub_b,
            group=self._group_index,
            prev_in=prev_in,
            log_pred=log_pred,
            fric=ps.fric,
            sig2=sig2,
            params=(
                self.dt,
                1e-10,  # eps_rel of `solve_reduced`
                self._scales.impulse,
                self._scales.velocity,
                self._scales.impulse_floor,
                cfg.gap_closure,
                -1.0 if cfg.gap_tolerance is None else cfg.gap_tolerance,
                cfg.constrained_noise,
            ),
            sensitivity=inp.force is not None,
            work=self._work,
            pool=self._pool,
        )
        if n_bad or not np.isfinite(out["v_next"]).all():
            msg = (
                f"reduced dynamics system is singular for {max(n_bad, 1)} of "
                f"{out['score'].size} assignments"
            )
            raise SolverError(msg)
        return out

    def _compiled_proposal(
        self,
        starts: IntArray,
        hyp: LiveHypotheses,
        out: dict[str, Any],
        log_alpha: FloatArray,
        *,
        free: _FreeMotion,
        inp: _StepInputs,
        cov_floor: FloatArray | None,
    ) -> dict[str, FloatArray]:
        """Phases 5-6 compiled (`step_kernels.propose_rows`), with the random numbers of the
        numpy path in its order: Gumbel uniforms over the padded (K, F) layout (a bank's
        copies share their particle's: `_shared_draws` without the repeat), then the normals
        of v' and of the position noise. cov_floor: see `_cov_floor`."""
        ps = self.particles
        n_r = ps.size
        uniforms = self.rng.random((n_r // self._n_sub, hyp.width * self.n_fb))
        normals = self.rng.standard_normal if self._n_sub == 1 else self._shared_normals
        z_v = normals((n_r, self.nq))
        z_q = normals((n_r, self.nq))
        lin = inp.lin
        _, s_diag, q_gain, q_std = observation_terms(lin, self._sigma_q, self.nq)
        return step_kernels.propose_rows(
            starts,
            hyp.modes,
            q=ps.q,
            v_h=out["v_next"],
            cov=out["cov"],
            log_alpha=log_alpha,
            observation=None if lin is None else (lin.value, lin.angular, s_diag),
            q_gain=q_gain,
            q_std=q_std,
            dt=self.dt,
            shared=free.v_free_b is None and free.m_eff is None,
            uniforms=uniforms,
            copies=self._n_sub,
            z_v=z_v,
            z_q=z_q,
            pair_mask=self._pair_mask,
            cov_floor=cov_floor,
            pool=self._pool,
        )

    def _cov_floor(self, sig2: FloatArray) -> FloatArray | None:
        """The diagonal every velocity covariance of `_compiled_dynamics` lies above (its
        constrained-noise term c sig2, (nv,)), None when it is not positive definite."""
        floor = self.config.constrained_noise * np.asarray(sig2, dtype=np.float64)
        return floor if bool(np.all(floor > 0.0)) else None

    def _propose(self, ent: _Entries, dyn: _Dynamics, inp: _StepInputs) -> _Proposal:
        """Optimal proposal: per entry x friction the Gaussian posterior of v' given the
        observation; one (hypothesis, friction) drawn per particle in proportion to its
        weight (Gumbel-max), then v' and the position noise from its Gaussian."""
        dt = self.dt
        n_p = self.particles.size
        prop = gaussian_proposal(
            self.particles.q.take(ent.pi, axis=0)[:, None, :],
            dyn.v_h,
            dyn.cov_h,
            dt,
            inp.lin,
            sigma_q=self._sigma_q,
        )
        log_joint = np.full((n_p, ent.n_k, self.n_fb), -np.inf)
        log_joint[ent.pi, ent.ki] = dyn.log_alpha + prop.log_pred
        flat = log_joint.reshape(n_p, -1)
        incr = self._lse(flat, 1)  # (P,)
        gumbel = -np.log(-np.log(self._shared_draws(self.rng.random, flat.shape)))
        pick = np.argmax(np.where(np.isfinite(flat), flat + gumbel, -np.inf), axis=1)
        k_star, b_star = np.unravel_index(pick, (ent.n_k, self.n_fb))
        n_star = ent.slot[np.arange(n_p), k_star]
        v_new, e_q = sample_gaussian_proposal(
            prop,
            v_h=dyn.v_h[n_star, b_star],
            innovation=prop.innovation[n_star, b_star],
            v_mean=prop.v_mean[n_star, b_star],
            v_cov=prop.v_cov[n_star, b_star],
            dt=dt,
            rng=self.rng,
            draw=None if self._n_sub == 1 else self._shared_normals,
        )
        q_new = self.particles.q + dt * v_new + e_q
        if self.nq == 3:
            q_new[:, 2] = wrap_angle(q_new[:, 2])
        return _Proposal(incr, v_new, q_new)

    def _discrete_posterior(self, ent: _Entries, dyn: _Dynamics, prop: _Proposal) -> _Posterior:
        """Closed-form posterior of the discrete state given the sampled continuous state:
        joint over (hypothesis, friction), then the friction belief (P, B), the per-contact
        mode marginals given b (P, B, C, 4) and overall (P, C, 4), and P(pair in contact)."""
        n_p = self.particles.size
        log_post = np.full((n_p, ent.n_k, self.n_fb), -np.inf)
        v_rel = prop.v_new.take(ent.pi, axis=0)[:, None, :] - dyn.v_h
        dens = gaussian_log_density(v_rel, dyn.cov_h)
        log_post[ent.pi, ent.ki] = np.where(
            np.isfinite(dyn.log_alpha), dyn.log_alpha + dens, -np.inf
        )
        log_post = log_post - self._lse(log_post.reshape(n_p, -1), 1)[:, None, None]
        post = np.exp(log_post)  # (P, K, B)
        fric_post = post.sum(axis=1)  # (P, B)
        # num[p, b, c, m] = sum_k post[p, k, b] [mode_c of (p, k) == m], over the live entries
        # (flat index of (p, b, c, mode) as for the log prior)
        post_n = post[ent.pi, ent.ki]  # (N, B)
        num = np.bincount(
            ent.pbcm.reshape(-1),
            weights=np.repeat(post_n.reshape(-1), self.n_c),  # post_n[n, b] for every c
            minlength=n_p * self._pred_stride,
        ).reshape(n_p, self.n_fb, self.n_c, N_MODES)
        marg_post = num.sum(axis=1)  # (P, C, 4)
        tiny = 1e-12
        modes_post = (num + tiny * marg_post[:, None]) / (fric_post[:, :, None, None] + tiny)
        in_c = ent.modes_n != Mode.SEPARATED  # (N, C)
        p_n = post_n.sum(axis=1)  # (N,) posterior of each live entry
        pair_in = np.zeros((n_p, self.n_pairs))  # (P, pairs): P(pair in contact)
        for pr, mask in enumerate(self._pair_contacts):
            if mask is None:  # all contacts belong to the pair
                w_in = p_n * (sum_last(in_c) > 0)
            elif mask.any():
                w_in = p_n * in_c[:, mask].any(axis=1)
            else:
                continue
            pair_in[:, pr] = np.bincount(ent.pi, weights=w_in, minlength=n_p)
        if self._surface_pair is not None:
            pair_in[:, self._surface_pair] = 1.0  # always on the support
        p_contact = 1.0 - marg_post[:, :, Mode.SEPARATED]  # (P, C)
        # (P, pairs, Kmax); a bank's copies have one friction each: `_bank_evidence` sets it
        fric_pair = (
            self._pair_marginals(fric_post)
            if self._n_sub == 1
            else np.empty((0, self.n_pairs, self._k_max))
        )
        return _Posterior(fric_post, fric_pair, modes_post, marg_post, pair_in, p_contact)

    def _surprised(self, incr: FloatArray, observed: bool) -> bool:
        """`FilterConfig.bank_surprise_gate`: whether this step's log predictive likelihood
        (from the particles' evidence incr (P,)) lies more than the gate below the median of
        the recent observed steps; records the step."""
        gate = self.config.bank_surprise_gate
        if gate is None or not observed:
            return False
        w_prev, _ = normalise_log_weights(self.particles.log_w)
        with np.errstate(divide="ignore"):
            log_ml = float(_logsumexp(np.log(w_prev) + incr, axis=0))
        return self._surprise.update(log_ml) > gate

    def _bank_evidence(
        self, incr_rows: FloatArray, post: _Posterior, observed: bool = True
    ) -> FloatArray:
        """Friction bank: each particle's evidence (P,) = log sum_b bank[i, b] p(o | copy b)
        from its copies' evidence (P B,); the bank belief becomes the posterior (held at the
        prior during `friction_hold_steps`); the per-pair friction marginals and P(in
        contact) of the particle (for the map and the estimate) from the bank."""
        ps = self.particles
        assert ps.bank is not None
        n_p = ps.count
        cfg = self.config
        ev = incr_rows.reshape(n_p, self._n_sub)
        if self._by_hypothesis:
            return self._hypothesis_evidence(ev, post)
        with np.errstate(divide="ignore"):
            log_bank = np.log(ps.bank)
        joint = log_bank + ev
        incr = self._lse(joint, 1)
        surprised = self._surprised(incr, observed)
        if self._step > cfg.friction_hold_steps and not surprised:
            if cfg.bank_tempering != 1.0 or cfg.bank_step_cap is not None:
                ev_b = ev
                if cfg.bank_step_cap is not None:
                    best = np.max(ev, axis=1, keepdims=True)
                    with np.errstate(invalid="ignore"):
                        ev_b = np.where(
                            np.isfinite(best), np.maximum(ev, best - cfg.bank_step_cap), ev
                        )
                joint = log_bank + cfg.bank_tempering * ev_b
            norm = self._lse(joint, 1)
            ok = np.isfinite(norm)
            ps.bank = np.where(
                ok[:, None], np.exp(joint - np.where(ok, norm, 0.0)[:, None]), ps.bank
            )
        post.fric_pair = self._pair_marginals(ps.bank)
        post.p_contact = np.einsum(
            "pb,pbc->pc", ps.bank, post.p_contact.reshape(n_p, self._n_sub, self.n_c)
        )
        return incr

    def _hypothesis_evidence(self, ev: FloatArray, post: _Posterior) -> FloatArray:
        """Hypothesis resampling (`FilterConfig.bank_resampling`): the copies' evidence ev
        (P, B) updates their weights within each hypothesis and the shared belief pi(b) by the
        sub-filters' marginal likelihoods Z(b); returns each particle's evidence (P,), the
        same log sum_b pi(b) Z(b) for all (the step's log predictive likelihood; the particle
        weights stay uniform)."""
        ps = self.particles
        assert ps.copy_log_w is not None
        n_p = ps.count
        lw = ps.copy_log_w - self._lse(ps.copy_log_w.T, 1)[None, :]  # normalised per column
        new = lw + ev
        log_z = self._lse(new.T, 1)  # (B,) log Z(b)
        ok = np.isfinite(log_z)
        with np.errstate(invalid="ignore"):
            step_ml = self._lse((self._log_pi + log_z)[None, :], 1)  # (1,)
        if self._step > self.config.friction_hold_steps and np.isfinite(step_ml[0]):
            log_pi = self._log_pi + np.where(ok, log_z, -np.inf)
            self._log_pi = log_pi - self._lse(log_pi[None, :], 1)
        ps.copy_log_w = np.where(ok[None, :], new, lw)  # a column without support keeps lw
        ps.bank = self._hypothesis_bank()
        # every particle's friction is the shared pi; its P(in contact) is over its copies
        # weighted by their row weights (normalised per particle)
        pi = np.exp(self._log_pi)
        post.fric_pair = np.repeat(self._pair_marginals(pi[None, :]), n_p, axis=0)
        tot = ps.bank.sum(axis=1, keepdims=True)
        own = np.divide(ps.bank, tot, out=np.tile(pi, (n_p, 1)), where=tot > 0.0)
        post.p_contact = np.einsum(
            "pb,pbc->pc", own, post.p_contact.reshape(n_p, self._n_sub, self.n_c)
        )
        return np.full(n_p, step_ml[0])

    def _hypothesis_bank(self) -> FloatArray:
        """bank[i, b] = P W_ib pi(b) (hypothesis resampling): with the uniform particle
        weights 1 / P, w_i bank[i, b] = W_ib pi(b) is the row's weight and sum_i w_i bank[i]
        = pi."""
        ps = self.particles
        assert ps.copy_log_w is not None
        lw = ps.copy_log_w
        w_copy = np.exp(lw - self._lse(lw.T, 1)[None, :])
        return np.asarray(ps.count * w_copy * np.exp(self._log_pi)[None, :])

    def _resample_hypotheses(self) -> tuple[float, bool]:
        """Hypothesis resampling: when the smallest ESS of the hypotheses' copy weights
        falls below the threshold, resample every hypothesis' copies with one random stream
        (common random numbers); returns (smallest ESS, resampled)."""
        ps = self.particles
        assert ps.copy_log_w is not None
        n_p = ps.count
        w_copy = np.exp(ps.copy_log_w - self._lse(ps.copy_log_w.T, 1)[None, :])
        ess = float(np.min(1.0 / np.sum(w_copy**2, axis=0)))
        if ess >= self.config.ess_threshold * n_p:
            return ess, False
        seed = int(self.rng.integers(2**63))
        anc = np.stack(
            [
                self._resampler(w_copy[:, b], np.random.default_rng(seed))
                for b in range(self._n_sub)
            ],
            axis=1,
        )
        ps.resample_copies(anc, int(np.argmax(self._log_pi)))
        ps.bank = self._hypothesis_bank()
        return ess, True

    def _mix_bank(self) -> None:
        """IMM mixing of the bank's copies (`FilterConfig.bank_switch`): predict each
        particle's bank belief through the switching transition T and restart copy b from
        copy a ~ T[a, b] bank[a] (its q, v and mode marginals); no-op without the bank, with
        bank_switch = 0, or while the belief is held at the prior."""
        eps = self.config.bank_switch
        ps = self.particles
        if (
            ps.bank is None
            or eps <= 0.0
            or not self._initialised
            or self._step <= self.config.friction_hold_steps
        ):
            return
        n_p, n_b = ps.bank.shape
        trans = np.full((n_b, n_b), eps / (n_b - 1))
        np.fill_diagonal(trans, 1.0 - eps)
        joint = ps.bank[:, :, None] * trans[None]  # (P, a, b): bank[a] T[a, b]
        pred = joint.sum(axis=1)  # (P, b)
        mix = joint / pred[:, None, :]  # P(source a | target b)
        cdf = np.cumsum(mix, axis=1)  # over a
        u = self.rng.random((n_p, 1, n_b))
        src = np.minimum((u > cdf).sum(axis=1), n_b - 1)  # (P, b) source copy
        rows = (np.arange(n_p)[:, None] * n_b + src).reshape(-1)
        ps.q, ps.v, ps.modes = ps.q[rows], ps.v[rows], ps.modes[rows]
        ps.bank = pred

    def _shared_draws(
        self, draw: Callable[[tuple[int, ...]], FloatArray], shape: tuple[int, ...]
    ) -> FloatArray:
        """Random numbers of `shape` (rows first); a bank's copies share their particle's
        (common random numbers: the copies differ by their friction only)."""
        if self._n_sub == 1:
            return draw(shape)
        per_particle = draw((shape[0] // self._n_sub, *shape[1:]))
        return np.repeat(per_particle, self._n_sub, axis=0)

    def _shared_normals(self, shape: tuple[int, ...]) -> FloatArray:
        """Standard normals of `shape`, shared by a bank's copies (`_shared_draws`)."""
        return self._shared_draws(self.rng.standard_normal, shape)

    def _row_weights(self, w: FloatArray) -> FloatArray:
        """Weights (P B,) of the rows of the state arrays: w (P,) x the bank belief."""
        bank = self.particles.bank
        return w if bank is None else np.asarray((w[:, None] * bank).reshape(-1))

    def weighted_particles(self) -> tuple[FloatArray, FloatArray]:
        """Particle poses (rows of the state arrays, (R, nq)) and their normalised weights
        (R,) (bank copies weighted by their particle's friction belief): e.g. for markers."""
        w, _ = normalise_log_weights(self.particles.log_w)
        return self.particles.q, self._row_weights(w)

    def _update_beliefs(self, post: _Posterior) -> None:
        """Eq. (7): the predictive friction belief of the next step (held at the prior
        during `friction_hold_steps`) and the mode marginals given b."""
        ps = self.particles
        if self._n_sub > 1:  # bank: per-copy friction is its own hypothesis
            # a copy without any feasible hypothesis (zero evidence: its belief weight
            # is 0 now) keeps its previous marginals instead of 0/0
            bad = ~np.asarray(np.isfinite(post.modes_post).all(axis=(1, 2, 3)))
            ps.modes = np.where(bad[:, None, None, None], ps.modes, post.modes_post)
            return
        if self._step <= self.config.friction_hold_steps:
            # warm-up: wrong initial velocities are still being weeded out, and collisions
            # of those particles would bias the friction belief -> hold it at the prior.
            ps.fric = np.tile(self._prior_b, (ps.size, 1))
            post.fric_pair = self._pair_marginals(ps.fric)
        else:
            ps.fric = self._predict_friction(post.fric_post, post.fric_pair, post.pair_in)
        ps.modes = post.modes_post

    def _reweight(self, incr: FloatArray, inp: _StepInputs) -> float:
        """Multiply the weights by each particle's evidence; returns the step's log marginal
        likelihood log p(o_l | o_{0:l-1}) (0 without observation)."""
        ps = self.particles
        w_prev, _ = normalise_log_weights(ps.log_w)
        with np.errstate(divide="ignore"):
            log_ml = (
                float(_logsumexp(np.log(w_prev) + incr, axis=0))
                if inp.lin is not None or inp.force is not None
                else 0.0
            )
        ps.log_w = ps.log_w + incr
        if not np.any(np.isfinite(ps.log_w)):
            msg = (
                f"all {ps.count} particles have zero likelihood at step {self._step}: the "
                f"observation {inp.observation} is incompatible with the model"
            )
            raise ModelError(msg)
        return log_ml

    def _move(self, prop: _Proposal, post: _Posterior, joints: FloatArray) -> FloatArray:
        """Take the sampled state and append the step to the friction-map history (the entry
        leaving the lag window is committed); returns the normalised weights (P,)."""
        ps = self.particles
        ps.q, ps.v = prop.q_new, prop.v_new
        w, _ = normalise_log_weights(ps.log_w)
        if _compiled_backend():
            s_new = kinematics_kernels.contact_coordinates(self.scenario, ps.q, joints)
        else:  # the numpy reference (the same values)
            s_new = contact_coordinates(self.scenario, ps.q, joints)  # contact coordinate s
        if ps.bank is not None:  # a particle's s: its most probable copy's
            s_new = s_new.reshape(ps.count, self._n_sub, self.n_c)
            s_new = s_new[np.arange(ps.count), np.argmax(ps.bank, axis=1)]
        pk = self.n_pairs * self._k_max
        row = np.empty((ps.count, ps.history.buf.shape[2]))
        row[:, :pk] = post.fric_pair.reshape(ps.count, pk)
        row[:, pk : pk + self.n_c] = s_new
        row[:, pk + self.n_c :] = post.p_contact
        old = ps.history.push(row)
        if old is not None:
            self._commit(self.map, old[None], w)
        return w

    def _maybe_resample(self, w: FloatArray) -> tuple[float, bool]:
        """Resample when the effective sample size falls below the threshold; returns
        (ESS before resampling, whether the set was resampled)."""
        if self._by_hypothesis:
            return self._resample_hypotheses()
        ess = effective_sample_size(w)
        if ess >= self.config.ess_threshold * self.particles.count:
            return ess, False
        self.particles.resample(self._resampler(w, self.rng))
        return ess, True

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
            mu=self._mu[None] if self._sub_b is None else self._mu[self._sub_b[pi]][:, None],
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
        impulses: tuple[FloatArray, FloatArray, FloatArray | None],
        normal: FloatArray,
        sig2: FloatArray,
    ) -> FloatArray:
        """log-likelihood (N, B) of a force reading; see :mod:`dbcslam_core.force_likelihood`.

        impulses: (ln, lt) (N, B, C) of the reduced solutions and their sensitivity to the
        free velocity (N, B, 2, C, nv) or None; normal (N, C, 2) contact normals (into the
        body, world frame); sig2 (nv,) the velocity process-noise variances of the step.
        """
        ln, lt, ir_all = impulses
        sel = self._contact_obstacle == obstacle
        std = self.config.force_noise if force.std is None else force.std
        ir = None if ir_all is None else ir_all[..., sel, :]
        return force_log_likelihood(
            (force.fx, force.fy),
            std,
            normal[:, None, sel, :],
            ln[..., sel],
            lt[..., sel],
            dt=self.dt,
            impulse_response=ir,
            sig2=sig2,
            axes=self.config.force_axes,
        )

    def _compiled_force_log_likelihood(
        self,
        starts: IntArray,
        force: ForceObservation,
        *,
        obstacle: int,
        out: dict[str, Any],
        normal: FloatArray,
        sig2: FloatArray,
    ) -> FloatArray:
        """`_force_log_likelihood` of the live entries (rows starts, outputs `out` of
        `_compiled_dynamics`, normals (P, C, 2) per row): compiled (`force_kernels`) for the
        normal component, the numpy function for `force_axes` "both"."""
        if self.config.force_axes != "normal" or not force_kernels.AVAILABLE:
            pi = np.repeat(np.arange(self.particles.size), np.diff(starts))
            return self._force_log_likelihood(
                force, obstacle, (out["ln"], out["lt"], out["impulse_response"]), normal[pi], sig2
            )
        return force_kernels.normal_force_log_likelihood(
            starts,
            (force.fx, force.fy),
            std=self.config.force_noise if force.std is None else force.std,
            normal=normal,
            sel=np.flatnonzero(self._contact_obstacle == obstacle),
            ln=out["ln"],
            lt=out["lt"],
            dt=self.dt,
            impulse_response=out["impulse_response"],
            sig2=None if out["impulse_response"] is None else sig2,
            pool=self._pool,
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
        w, _ = normalise_log_weights(self.particles.log_w)
        return self._friction_map_view(w)

    def _friction_map_view(self, w: FloatArray) -> FrictionMapView:
        """`friction_map` with the normalised weights w of self.log_w given."""
        history = self.particles.history
        if history.length == 0:
            return self.map.view()
        pending: list[tuple[FloatArray, FloatArray] | None]
        if _compiled_backend():
            fmap = self.map
            pending = step_kernels.map_pending(
                history.buf,
                history.head,
                history.length,
                w,
                pair_mask=self._pair_mask,
                n_cand=np.asarray(self._n_cand, dtype=np.int64),
                grid=(fmap.s_min, fmap.cell_size, fmap.n_cells),
            )
        else:
            obs = self._map_observations(history.entries(), w)
            pending = [None if o is None else self.map.accumulate(*o) for o in obs]
        return self.map.view(pending)

    def _estimate(
        self,
        *,
        w: FloatArray,
        row_w: FloatArray,
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
        """The per-step summary: weighted moments of the rows q, v (R, nq) and mode marginals
        marg_post (R, C, 4) under row_w (R,); friction (pairs, Kmax) from the particles'
        fric_pair under w (P,); the friction map under map_w (P,)."""
        pose = np.zeros(3)
        pose_cov = np.zeros((3, 3))
        twist = np.zeros(3)
        twist_cov = np.zeros((3, 3))
        nq = self.nq
        friction = np.einsum("p,pqk->qk", w, fric_pair)
        w = row_w
        if self._n_sub > 1:  # copies without weight may hold 0/0 marginals: keep them out
            marg_post = np.where((w > 0.0)[:, None, None], marg_post, 0.0)
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
            particle_poses=q,
            particle_weights=w,
        )

    def warm_up(self) -> float:
        """Run the compiled kernels once, on a throwaway two-particle copy of this filter
        (same scenario and configuration, its own random numbers), so that the first real
        step does not pay numba's loading of the cached machine code (~0.3 s) or, on a
        fresh install, its compilation (~29 s for the kernels of all three kinds, measured
        by `make venv` on a fresh clone: the entry and proposal kernels compile once per
        velocity dimension). Once per process and scenario kind; returns the seconds
        spent (0 when already warm or without numba). A node calls :func:`warm_up_kernels`
        when it starts and this when it is configured, before the first pose arrives."""
        kind = self.scenario.kind
        if kind in _WARM or not kernels.AVAILABLE:
            return 0.0
        started = time.perf_counter()
        probe = DbcSlamFilter(
            self.scenario,
            replace(self.config, particles=2),
            np.random.default_rng(0),
            self.extensions,
        )
        pose = PoseObservation(0.0, 0.0, 0.0 if self.nq == 3 else None)
        inputs = FilterInput(joints=tuple(0.0 for _ in self.scenario.joints))
        # best effort: the probe's state is arbitrary (e.g. a body inside both jaws) and any
        # error it meets is one the real first step reports itself
        with contextlib.suppress(Exception):
            probe.step(pose, inputs)
            probe.step(pose, inputs)
        # the kinematics kernels also when the probe's steps stopped early
        kinematics_kernels.warm_up(self.scenario)
        if self.scenario.kind == "push":  # the force likelihood of `/pusher/wrench`
            force_kernels.warm_up(self.nq)
        _WARM.add(kind)
        return time.perf_counter() - started

    def with_config(self, **changes: Any) -> DbcSlamFilter:
        """A fresh filter with the same scenario and rng and a modified config."""
        return DbcSlamFilter(
            self.scenario, replace(self.config, **changes), self.rng, self.extensions
        )


def warm_up_kernels(kinds: tuple[str, ...] = ("gripper", "push", "edge")) -> float:
    """:meth:`DbcSlamFilter.warm_up` for the built-in scenario of each kind in ``kinds``
    (their preset configurations): loads, or on a fresh install compiles (~30 s in all on a
    2-core machine), the machine code every scenario kind needs. A node calls it at start-up,
    before it subscribes, so a first /scenario never waits for a compilation while poses
    arrive; ``make venv`` calls it once so the cache is filled at install. Returns the
    seconds spent (0 without numba or when all are warm)."""
    builders: dict[str, Callable[[], Scenario]] = {
        "edge": edge_scenario,
        "gripper": gripper_scenario,
        "push": lambda: push_scenario(PUSH_RECT, mass=PUSH_RECT_MASS, support_pair="surface"),
    }
    spent = 0.0
    for kind in kinds:
        try:
            scenario = builders[kind]()
        except KeyError as err:
            msg = f"no built-in scenario of kind {kind!r}; valid: {sorted(builders)}"
            raise ModelError(msg) from err
        probe = DbcSlamFilter(
            scenario, FilterConfig.preset(kind, particles=2), np.random.default_rng(0)
        )
        spent += probe.warm_up()
    return spent
