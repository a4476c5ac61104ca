"""Observation models p(o | x) (Sec. III-B) and the closed-form optimal proposal.

The filter observes a subset of the generalised coordinates with independent Gaussian noise:
a planar pose (x, y[, yaw]) in frame `world` (m, m, rad). For a point mass only (x, y) exist;
a yaw reading is then rejected. Angular residuals are wrapped to [-pi, pi).

Proposal (DESIGN.md, Estimator step 4): with velocity process noise e_v ~ N(0, sig_v^2) and
position process noise e_q ~ N(0, sig_q^2) (diagonal), v' = v'_h + e_v and
q' = q + dt v' + e_q, an observation o_d = q'_d + r_d, r_d ~ N(0, R_d), gives per observed
dimension (independent because everything is diagonal)

    predictive   o_d | h ~ N(q_d + dt v'_hd, S_d),  S_d = dt^2 sig_vd^2 + sig_qd^2 + R_d
    posterior    e_vd | o, h ~ N(dt sig_vd^2 y_d / S_d, sig_vd^2 (1 - dt^2 sig_vd^2 / S_d))
                 e_qd | e_vd, o ~ N(g_d (y_d - dt e_vd), sig_qd^2 R_d / (sig_qd^2 + R_d)),
                 g_d = sig_qd^2 / (sig_qd^2 + R_d),

y_d the (wrapped) innovation. Unobserved dimensions keep the prior.
"""

from __future__ import annotations

import functools
import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from dbcslam_core import kernels
from dbcslam_core.angles import wrap_angle
from dbcslam_core.errors import ModelError

__all__ = [
    "ForceObservation",
    "GaussianProposal",
    "JointSmoother",
    "LinearObservation",
    "PoseObservation",
    "PoseObservationModel",
    "ProposalTerms",
    "gaussian_log_density",
    "gaussian_proposal",
    "observation_terms",
    "proposal_terms",
    "sample_gaussian_proposal",
    "sample_noise",
    "smooth_joint_readings",
    "wrap_angle",
]

FloatArray = npt.NDArray[np.float64]
IntArray = npt.NDArray[np.int64]
BoolArray = npt.NDArray[np.bool_]

_LOG_2PI = math.log(2.0 * math.pi)


@dataclass(frozen=True)
class PoseObservation:
    """Observed planar pose in `world`: x, y (m), optional yaw (rad, counter-clockwise)."""

    x: float
    y: float
    yaw: float | None = None


@dataclass(frozen=True)
class ForceObservation:
    """Measured contact force (N, world frame) that the body exerts on an obstacle, e.g. the
    pusher's F/T reading ``/pusher/wrench`` (force on the pusher, world axes).

    fx, fy: force components (N) averaged over / at the end of the filter step it is passed
    with. obstacle: name of the instrumented obstacle (`Scenario.obstacles`); None = the
    scenario's only disk obstacle (the pusher). std: measurement noise std (N) per axis;
    None = `FilterConfig.force_noise`.

    Model (see `rbpf.DbcSlamFilter.step`): for a joint mode hypothesis h and friction
    hypothesis b, the reduced dynamics give the contact impulses (ln, lt) of the step; the
    predicted force is f_hb = -sum_c (n_c ln_c + t_c lt_c) / dt over the obstacle's
    contacts (n into the body, t = (n_y, -n_x)), and f ~ N(f_hb, std^2 I).
    """

    fx: float
    fy: float
    obstacle: str | None = None
    std: float | None = None

    def __post_init__(self) -> None:
        if not (math.isfinite(self.fx) and math.isfinite(self.fy)):
            msg = f"force observation must be finite, got ({self.fx}, {self.fy}) N"
            raise ModelError(msg)
        if self.std is not None and not (math.isfinite(self.std) and self.std > 0.0):
            msg = f"force observation std must be > 0 N, got {self.std}"
            raise ModelError(msg)


@dataclass(frozen=True)
class LinearObservation:
    """o = q[index] + r with r ~ N(0, diag(var)); `angular` marks dims wrapped to [-pi, pi)."""

    index: IntArray
    value: FloatArray
    var: FloatArray
    angular: BoolArray

    def residual(self, q_obs: npt.ArrayLike) -> FloatArray:
        """Innovation o - q[..., index] (angular dims wrapped), shape (..., D)."""
        r = np.asarray(self.value - np.asarray(q_obs, dtype=np.float64), dtype=np.float64)
        for k in np.flatnonzero(self.angular).tolist():  # wrap the angular columns only
            r[..., k] = wrap_angle(r[..., k])
        return r

    def log_likelihood(self, q: npt.ArrayLike) -> FloatArray:
        """log p(o | q) for q (..., nq)."""
        qa = np.asarray(q, dtype=np.float64)
        r = self.residual(qa[..., self.index])
        ll = -0.5 * (r * r / self.var + np.log(self.var) + _LOG_2PI)
        return np.asarray(ll.sum(axis=-1), dtype=np.float64)


class PoseObservationModel:
    """Pose sensor with independent Gaussian noise: std_position (m) on x and y, std_yaw
    (rad) on yaw (polygon bodies only, nq = 3)."""

    def __init__(self, nq: int, std_position: float, std_yaw: float = 0.0) -> None:
        if nq not in (2, 3):
            msg = f"nq must be 2 (point mass) or 3 (polygon), got {nq}"
            raise ModelError(msg)
        if not (math.isfinite(std_position) and std_position > 0.0):
            msg = f"position noise std must be > 0 m, got {std_position}"
            raise ModelError(msg)
        if nq == 3 and not (math.isfinite(std_yaw) and std_yaw > 0.0):
            msg = f"yaw noise std must be > 0 rad for a polygon body, got {std_yaw}"
            raise ModelError(msg)
        self.nq = nq
        self.std_position = float(std_position)
        self.std_yaw = float(std_yaw)
        # constant parts of `linearize` for (x, y) and (x, y, yaw) readings (read-only)
        self._const: dict[int, tuple[IntArray, FloatArray, BoolArray]] = {}
        for n in (2, 3):
            index = np.arange(n, dtype=np.int64)
            var = np.asarray([self.std_position**2] * 2 + [self.std_yaw**2] * (n - 2))
            angular = np.asarray([False, False, True][:n], dtype=np.bool_)
            for a in (index, var, angular):
                a.setflags(write=False)
            self._const[n] = (index, var, angular)

    def linearize(self, obs: PoseObservation) -> LinearObservation:
        """The observation as o = q[index] + r (validates finiteness)."""
        vals = [obs.x, obs.y]
        if obs.yaw is not None:
            if self.nq == 2:
                msg = f"a point mass has no yaw, but the observation carries yaw={obs.yaw}"
                raise ModelError(msg)
            vals.append(obs.yaw)
        if not all(math.isfinite(v) for v in vals):
            msg = f"observation must be finite, got {obs}"
            raise ModelError(msg)
        index, var, angular = self._const[len(vals)]
        return LinearObservation(
            index=index, value=np.asarray(vals, dtype=np.float64), var=var, angular=angular
        )


@dataclass(frozen=True)
class ProposalTerms:
    """Closed-form optimal-proposal terms for a batch of hypotheses.

    log_pred (...): log p(o | h) of each hypothesis. The posterior of the velocity noise e_v
    given o and h is N(v_mean, v_std^2) (per dimension); given a sampled e_v, the position
    noise e_q is N(q_gain * (innovation - dt e_v), q_std^2) on observed dimensions
    (see `sample_noise`). innovation (..., nq) is zero on unobserved dimensions.
    """

    log_pred: FloatArray
    innovation: FloatArray
    v_mean: FloatArray
    v_std: FloatArray
    q_gain: FloatArray
    q_std: FloatArray
    observed: BoolArray


def proposal_terms(
    q: npt.ArrayLike,
    v_next: npt.ArrayLike,
    dt: float,
    sigma_v: npt.ArrayLike,
    obs: LinearObservation | None,
    *,
    sigma_q: npt.ArrayLike | None = None,
) -> ProposalTerms:
    """Optimal proposal for v' = v_next + e_v, q' = q + dt v' + e_q (module docstring).

    q (..., nq) broadcastable against v_next (..., nv) (nv == nq); sigma_v (nv,) velocity
    noise std (m/s, rad/s); sigma_q (nq,) position noise std per step (m, rad; default 0).
    With obs None: log_pred = 0 and the prior noise.
    """
    qa = np.asarray(q, dtype=np.float64)
    vn = np.asarray(v_next, dtype=np.float64)
    sv = np.asarray(sigma_v, dtype=np.float64)
    sq = np.zeros_like(sv) if sigma_q is None else np.asarray(sigma_q, dtype=np.float64)
    lead = np.broadcast_shapes(qa.shape[:-1], vn.shape[:-1])
    nq = sv.size
    innov = np.zeros((*lead, nq))
    v_mean = np.zeros((*lead, nq))
    v_std = sv.copy()
    q_gain = np.zeros(nq)
    q_std = sq.copy()
    observed = np.zeros(nq, dtype=np.bool_)
    if obs is None:
        return ProposalTerms(np.zeros(lead), innov, v_mean, v_std, q_gain, q_std, observed)
    idx = obs.index
    observed[idx] = True
    s = dt * dt * sv[idx] ** 2 + sq[idx] ** 2 + obs.var
    pred = qa[..., idx] + dt * vn[..., idx]
    y = obs.residual(pred)
    innov[..., idx] = y
    log_pred = -0.5 * np.sum(y * y / s + np.log(s) + _LOG_2PI, axis=-1)
    v_mean[..., idx] = (dt * sv[idx] ** 2 / s) * y
    v_std[idx] = np.sqrt(sv[idx] ** 2 * (1.0 - dt * dt * sv[idx] ** 2 / s))
    r_q = sq[idx] ** 2 + obs.var
    q_gain[idx] = sq[idx] ** 2 / r_q
    q_std[idx] = np.sqrt(sq[idx] ** 2 * obs.var / r_q)
    return ProposalTerms(
        np.asarray(log_pred, dtype=np.float64), innov, v_mean, v_std, q_gain, q_std, observed
    )


def sample_noise(
    terms: ProposalTerms,
    innovation: npt.ArrayLike,
    v_mean: npt.ArrayLike,
    dt: float,
    rng: np.random.Generator,
) -> tuple[FloatArray, FloatArray]:
    """Draw (e_v, e_q) (N, nq) from the optimal proposal of the chosen hypotheses.

    innovation, v_mean (N, nq): rows of terms.innovation / terms.v_mean at the chosen
    hypotheses. e_v ~ N(v_mean, v_std^2); then e_q | e_v ~ N(q_gain (y - dt e_v), q_std^2)
    on observed dimensions and N(0, q_std^2) elsewhere (exact chain rule of the joint
    Gaussian posterior).
    """
    y = np.asarray(innovation, dtype=np.float64)
    vm = np.asarray(v_mean, dtype=np.float64)
    e_v = vm + terms.v_std * rng.standard_normal(vm.shape)
    q_mean = np.where(terms.observed, terms.q_gain * (y - dt * e_v), 0.0)
    e_q = q_mean + terms.q_std * rng.standard_normal(vm.shape)
    return np.asarray(e_v, dtype=np.float64), np.asarray(e_q, dtype=np.float64)


def _constant_velocity(dt: float) -> tuple[FloatArray, FloatArray]:
    """Constant-velocity model of a joint (position m, velocity m/s) over dt (s): the
    transition F and the process noise covariance per unit white acceleration variance."""
    f = np.array([[1.0, dt], [0.0, 1.0]])
    q_unit = np.array([[dt**4 / 4.0, dt**3 / 2.0], [dt**3 / 2.0, dt**2]])
    return f, q_unit


class JointSmoother:
    """Constant-velocity Kalman filter per joint for noisy joint readings (m).

    Position-controlled joints (gripper jaws, pusher) enter the contact model as known inputs:
    their positions at the start and end of each step define the obstacle position and velocity.
    Raw readings with std `noise` would turn into velocity noise of ~noise * sqrt(2) / dt, which
    the contact equalities would transmit as spurious impulses; this filter (white acceleration
    noise `accel_std`, m/s^2) returns smoothed positions and velocities (`velocity`).
    noise == 0 passes readings through.

    maneuver_accel_std (m/s^2, optional): a second filter with this (large) acceleration noise
    runs alongside; when the smooth filter's normalised innovation squared, averaged
    exponentially with factor `maneuver_memory`, exceeds `maneuver_threshold` (a start, stop
    or turn of the joint), the smooth filter is re-started from the agile one. This keeps the
    velocity of constant-speed motions precise without lagging behind starts and stops.
    """

    def __init__(
        self,
        n_joints: int,
        dt: float,
        noise: float,
        accel_std: float = 1.0,
        *,
        maneuver_accel_std: float | None = None,
        maneuver_threshold: float = 4.0,
        maneuver_memory: float = 0.7,
    ) -> None:
        self.n = n_joints
        self.dt = float(dt)
        self.r = float(noise) ** 2
        self.q_a = float(accel_std) ** 2
        self.q_m = None if maneuver_accel_std is None else float(maneuver_accel_std) ** 2
        self.threshold = float(maneuver_threshold)
        self.memory = float(maneuver_memory)
        self.x = np.zeros((n_joints, 2))
        self.p = np.zeros((n_joints, 2, 2))
        self.xm = np.zeros((n_joints, 2))
        self.pm = np.zeros((n_joints, 2, 2))
        self.nis = np.zeros(n_joints)
        self.initialised = False
        self._f, self._q_unit = _constant_velocity(self.dt)

    @property
    def velocity(self) -> FloatArray:
        """Smoothed joint velocities (m/s) after the last update."""
        return np.asarray(self.x[:, 1].copy(), dtype=np.float64)

    def reset(self, position: npt.ArrayLike) -> FloatArray:
        """Start from a reading (velocity unknown: std 1 m/s). Returns the position."""
        pos = np.asarray(position, dtype=np.float64).reshape(self.n)
        self.x = np.stack([pos, np.zeros(self.n)], -1)
        self.p = np.zeros((self.n, 2, 2))
        self.p[:, 0, 0] = self.r
        self.p[:, 1, 1] = 1.0
        self.xm, self.pm = self.x.copy(), self.p.copy()
        self.nis = np.zeros(self.n)
        self.initialised = True
        return np.asarray(self.x[:, 0].copy(), dtype=np.float64)

    def _kf(
        self, x: FloatArray, p: FloatArray, q_a: float, pos: FloatArray
    ) -> tuple[FloatArray, FloatArray, FloatArray]:
        f = self._f
        qm = q_a * self._q_unit
        x = x @ f.T
        p = f @ p @ f.T + qm
        s = p[:, 0, 0] + self.r
        innov = pos - x[:, 0]
        k = p[:, :, 0] / s[:, None]
        x = x + k * innov[:, None]
        p = p - k[:, :, None] * p[:, None, 0, :]
        return x, p, innov * innov / s

    def update(self, position: npt.ArrayLike) -> FloatArray:
        """Predict one step dt and update with a reading; returns the smoothed positions."""
        pos = np.asarray(position, dtype=np.float64).reshape(self.n)
        if self.n == 0 and self.initialised:  # no joints (static obstacles): nothing to do
            return np.zeros(0)
        if self.r <= 0.0 or not self.initialised:
            return self.reset(pos)
        self.x, self.p, nis = self._kf(self.x, self.p, self.q_a, pos)
        if self.q_m is not None:
            self.xm, self.pm, _ = self._kf(self.xm, self.pm, self.q_m, pos)
            self.nis = self.memory * self.nis + (1.0 - self.memory) * nis
            jump = self.nis > self.threshold
            if np.any(jump):
                self.x[jump] = self.xm[jump]
                self.p[jump] = self.pm[jump]
                self.nis[jump] = 0.0
        return np.asarray(self.x[:, 0].copy(), dtype=np.float64)


def smooth_joint_readings(
    readings: npt.ArrayLike, dt: float, noise: float, accel_std: float
) -> FloatArray:
    """Two-sided (Rauch-Tung-Striebel) smoothing of a whole recording of joint readings.

    readings (T, J) (m, one column per joint, nan = no reading at that step), sampled every
    dt (s) with noise std `noise` (m); the same constant-velocity model as `JointSmoother`
    with white acceleration std `accel_std` (m/s^2). Returns the smoothed positions (T, J)
    (m). Offline only (it uses the readings after each step): `JointSmoother` filters
    causally and lags behind starts and stops, which a recorded run need not. noise == 0
    returns the readings unchanged. Raises ModelError for bad arguments or a joint without
    any reading.
    """
    z = np.array(readings, dtype=np.float64)
    if z.ndim != 2 or not dt > 0.0 or not noise >= 0.0 or not accel_std > 0.0:
        msg = (
            f"smooth_joint_readings needs readings (T, J), dt > 0 s, noise >= 0 m and "
            f"accel_std > 0 m/s^2; got shape {z.shape}, dt {dt}, noise {noise}, "
            f"accel_std {accel_std}"
        )
        raise ModelError(msg)
    n, n_j = z.shape
    if noise == 0.0 or n == 0 or n_j == 0:
        return z
    seen = np.isfinite(z)
    if not np.all(np.any(seen, axis=0)):
        msg = f"joint columns {np.nonzero(~np.any(seen, axis=0))[0].tolist()} have no reading"
        raise ModelError(msg)
    f, q_unit = _constant_velocity(dt)
    qn = accel_std**2 * q_unit
    r = noise**2
    x_f = np.zeros((n, n_j, 2))  # filtered
    p_f = np.zeros((n, n_j, 2, 2))
    x_p = np.zeros((n, n_j, 2))  # predicted
    p_p = np.zeros((n, n_j, 2, 2))
    first = np.argmax(seen, axis=0)
    x = np.stack([z[first, np.arange(n_j)], np.zeros(n_j)], -1)
    p = np.zeros((n_j, 2, 2))
    p[:, 0, 0], p[:, 1, 1] = r, 1.0  # velocity unknown: std 1 m/s (as `JointSmoother.reset`)
    for k in range(n):
        if k:
            x = x @ f.T
            p = f @ p @ f.T + qn
        x_p[k], p_p[k] = x, p
        ok = seen[k]
        gain = p[:, :, 0] / (p[:, 0, 0] + r)[:, None]
        innov = np.where(ok, z[k] - x[:, 0], 0.0)
        x = x + np.where(ok[:, None], gain * innov[:, None], 0.0)
        p = p - np.where(ok[:, None, None], gain[:, :, None] * p[:, None, 0, :], 0.0)
        x_f[k], p_f[k] = x, p
    # backward pass: the means only (the smoothed covariances are not needed)
    x_s = x_f[-1]
    out = np.empty((n, n_j))
    out[-1] = x_s[:, 0]
    for k in range(n - 2, -1, -1):
        # smoother gain C = P_f F^T P_p(k+1)^-1, by a solve (P_p symmetric)
        c = np.swapaxes(np.linalg.solve(p_p[k + 1], f @ p_f[k]), -1, -2)
        x_s = x_f[k] + (c @ (x_s - x_p[k + 1])[..., None])[..., 0]
        out[k] = x_s[:, 0]
    return out


def _chol_entries(a: FloatArray) -> list[list[FloatArray]]:
    """Lower Cholesky factor of SPD matrices a (..., n, n), small n: low[i][j] (j <= i) are
    (...) arrays (structure of arrays: every operation is one vectorised op over the batch,
    no small-axis reductions; pivots clipped at 1e-300)."""
    n = a.shape[-1]
    return _chol_of([[a[..., i, j] for j in range(i + 1)] for i in range(n)])


def _chol_of(a: list[list[FloatArray]]) -> list[list[FloatArray]]:
    """`_chol_entries` of a matrix given by its lower entries a[i][j] (j <= i), (...) each."""
    n = len(a)
    low: list[list[FloatArray]] = [[] for _ in range(n)]
    for j in range(n):
        d = a[j][j]
        if j:
            s = low[j][0] * low[j][0]
            for k in range(1, j):
                s = s + low[j][k] * low[j][k]
            d = d - s
        ljj = np.sqrt(np.maximum(d, 1e-300))
        low[j].append(ljj)
        for i in range(j + 1, n):
            num = a[i][j]
            if j:
                s = low[i][0] * low[j][0]
                for k in range(1, j):
                    s = s + low[i][k] * low[j][k]
                num = num - s
            low[i].append(num / ljj)
    return low


def _forward_entries(low: list[list[FloatArray]], b: FloatArray) -> list[FloatArray]:
    """Rows y_i (..., m) of L^-1 b for b (..., n, m) (forward substitution)."""
    y: list[FloatArray] = []
    for i in range(len(low)):
        acc = b[..., i, :]
        if i:
            s = low[i][0][..., None] * y[0]
            for k in range(1, i):
                s = s + low[i][k][..., None] * y[k]
            acc = acc - s
        y.append(acc / low[i][i][..., None])
    return y


def _backward_entries(low: list[list[FloatArray]], y: list[FloatArray]) -> list[FloatArray]:
    """Rows x_i (..., m) of L^-T y (back substitution)."""
    n = len(low)
    x: list[FloatArray] = [y[0]] * n
    for i in reversed(range(n)):
        acc = y[i]
        if i + 1 < n:
            s = low[i + 1][i][..., None] * x[i + 1]
            for k in range(i + 2, n):
                s = s + low[k][i][..., None] * x[k]
            acc = acc - s
        x[i] = acc / low[i][i][..., None]
    return x


def _logdet_entries(low: list[list[FloatArray]]) -> FloatArray:
    """log det(L L^T) = 2 sum log L_ii."""
    s = np.log(low[0][0])
    for i in range(1, len(low)):
        s = s + np.log(low[i][i])
    return np.asarray(2.0 * s, dtype=np.float64)


def _cholesky_small(a: FloatArray) -> FloatArray:
    """Batched Cholesky factor L (lower) of SPD matrices (..., n, n) for small n.

    Column-by-column (loop over the n <= 3 matrix dimensions, vectorised over the batch);
    faster than LAPACK's per-matrix call overhead for millions of 2x2 / 3x3 blocks.
    """
    n = a.shape[-1]
    ent = _chol_entries(a)
    low = np.zeros_like(a)
    for i in range(n):
        for j in range(i + 1):
            low[..., i, j] = ent[i][j]
    return low


def _entries_of(low: FloatArray) -> list[list[FloatArray]]:
    n = low.shape[-1]
    return [[low[..., i, j] for j in range(i + 1)] for i in range(n)]


def _cho_solve_small(low: FloatArray, b: FloatArray) -> FloatArray:
    """Solve (L L^T) x = b for b (..., n, m) by forward and back substitution."""
    ent = _entries_of(low)
    x = _backward_entries(ent, _forward_entries(ent, b))
    return np.asarray(np.stack(x, axis=-2), dtype=np.float64)


@dataclass(frozen=True)
class GaussianProposal:
    """Optimal proposal with a full velocity-noise covariance per hypothesis.

    Model: v' = v_h + e_v, e_v ~ N(0, cov_v) (cov_v (..., nv, nv), e.g. force noise pushed
    through the reduced dynamics of hypothesis h); q' = q + dt v' + e_q, e_q ~ N(0,
    diag(sigma_q^2)); o = q'[index] + r. Fields: log_pred (...) = log p(o | h);
    innovation (..., nq) (zero on unobserved dims); v_mean (..., nv) and v_cov (..., nv, nv):
    the Gaussian posterior of v' given o and h; q_gain, q_std, observed (nq,): the position
    noise posterior e_q | v', o ~ N(q_gain (y - dt (v' - v_h)), q_std^2) on observed dims.
    """

    log_pred: FloatArray
    innovation: FloatArray
    v_mean: FloatArray
    v_cov: FloatArray
    q_gain: FloatArray
    q_std: FloatArray
    observed: BoolArray


def gaussian_proposal(
    q: npt.ArrayLike,
    v_h: npt.ArrayLike,
    cov_v: npt.ArrayLike,
    dt: float,
    obs: LinearObservation | None,
    *,
    sigma_q: npt.ArrayLike | None = None,
) -> GaussianProposal:
    """Closed-form optimal proposal (Kalman form) for a batch of hypotheses.

    q (..., nq), v_h (..., nv), cov_v (..., nv, nv) broadcast together (nv == nq). Uses batched
    np.linalg.solve / cholesky on the (D x D) innovation covariances, no explicit inverse.
    """
    qa = np.asarray(q, dtype=np.float64)
    vh = np.asarray(v_h, dtype=np.float64)
    sv = np.asarray(cov_v, dtype=np.float64)
    nq = vh.shape[-1]
    sq = np.zeros(nq) if sigma_q is None else np.asarray(sigma_q, dtype=np.float64)
    lead = np.broadcast_shapes(qa.shape[:-1], vh.shape[:-1], sv.shape[:-2])
    if vh.shape[:-1] != lead:
        vh = np.broadcast_to(vh, (*lead, nq))
    if sv.shape[:-2] != lead:
        sv = np.broadcast_to(sv, (*lead, nq, nq))
    if obs is None:
        return GaussianProposal(
            np.zeros(lead),
            np.zeros((*lead, nq)),
            vh.copy(),
            sv.copy(),
            np.zeros(nq),
            sq.copy(),
            np.zeros(nq, dtype=np.bool_),
        )
    idx = obs.index
    n_d = idx.size
    every, observed, s_diag, q_gain, q_std = _observation_terms(
        np.asarray(idx, dtype=np.int64).tobytes(), obs.var.tobytes(), sq.tobytes(), nq
    )
    if every:  # (vh has the full batch shape here)
        log_pred, y, v_mean, v_cov = _proposal_all_observed(
            qa, vh, sv, dt=dt, obs=obs, s_diag=s_diag
        )
        return GaussianProposal(log_pred, y, v_mean, v_cov, q_gain, q_std, observed)
    sv_o = sv if every else sv[..., idx, :][..., :, idx]
    s_o = dt * dt * sv_o + s_diag
    pred = qa + dt * vh if every else qa[..., idx] + dt * vh[..., idx]
    y = obs.residual(pred)
    if every:
        innov = y if y.shape == (*lead, nq) else np.broadcast_to(y, (*lead, nq))
    else:
        innov = np.zeros((*lead, nq))
        innov[..., idx] = y
    # rhs = [y, c^T] (..., D, 1 + nv), c = cov(v', o) = dt sv[:, idx] (..., nv, D)
    rhs = np.empty((*lead, n_d, 1 + nq))
    rhs[..., 0] = y
    np.multiply(np.swapaxes(sv if every else sv[..., :, idx], -1, -2), dt, out=rhs[..., 1:])
    # S = L L^T: with Z = L^-1 [y, c^T], maha = |Z_y|^2 and c S^-1 [y, c^T] = Z_c^T Z
    low = _chol_entries(s_o)
    z = _forward_entries(low, rhs)  # D rows (..., 1 + nv)
    logdet = _logdet_entries(low)
    maha = z[0][..., 0] * z[0][..., 0]
    cx = z[0][..., 1:, None] * z[0][..., None, :]  # (..., nv, 1 + nv)
    for i in range(1, n_d):
        maha = maha + z[i][..., 0] * z[i][..., 0]
        cx += z[i][..., 1:, None] * z[i][..., None, :]
    log_pred = -0.5 * (maha + logdet + n_d * _LOG_2PI)
    v_mean = vh + cx[..., 0]
    v_cov = sv - cx[..., 1:]
    return GaussianProposal(
        np.asarray(log_pred, dtype=np.float64),
        innov,
        np.asarray(v_mean, dtype=np.float64),
        np.asarray(v_cov, dtype=np.float64),
        q_gain,
        q_std,
        observed,
    )


def _proposal_all_observed(
    qa: FloatArray,
    vh: FloatArray,
    sv: FloatArray,
    *,
    dt: float,
    obs: LinearObservation,
    s_diag: FloatArray,
    compiled: bool = kernels.AVAILABLE,
) -> tuple[FloatArray, FloatArray, FloatArray, FloatArray]:
    """`gaussian_proposal` (log_pred, innovation, v_mean, v_cov) when every dim is observed,
    in order (the filter's case), entry by entry: the same operations as the general form
    (same values to round-off) either compiled (`kernels.gaussian_update`, one loop over the
    batch) or on the (...) batch arrays of each matrix entry (no ops on (..., n, n) blocks,
    whose tiny inner axes make numpy iterate in runs of n elements)."""
    n = vh.shape[-1]
    dt2 = dt * dt
    y = obs.residual(qa + dt * vh)  # (..., n)
    if compiled:
        lead = y.shape[:-1]
        log_pred, v_mean, v_cov = kernels.gaussian_update(
            np.ascontiguousarray(y.reshape(-1, n)),
            np.ascontiguousarray(vh.reshape(-1, n)),
            np.ascontiguousarray(sv.reshape(-1, n, n)),
            s_diag=s_diag,
            dt=dt,
        )
        return (
            log_pred.reshape(lead),
            y,
            v_mean.reshape(*lead, n),
            v_cov.reshape(*lead, n, n),
        )
    # S = dt^2 cov_v + diag(sq^2 + R) = L L^T (lower entries)
    s_ent = [[dt2 * sv[..., i, j] + s_diag[i, j] for j in range(i + 1)] for i in range(n)]
    low = _chol_of(s_ent)
    # rows of Z = L^-1 [y, c^T], c = cov(v', o) = dt cov_v: row i = [y_i, dt cov_v[:, i]]
    z: list[list[FloatArray]] = []
    for i in range(n):
        row = [y[..., i]] + [sv[..., v, i] * dt for v in range(n)]
        if i:
            for col in range(n + 1):
                s = low[i][0] * z[0][col]
                for k in range(1, i):
                    s = s + low[i][k] * z[k][col]
                row[col] = row[col] - s
        z.append([r / low[i][i] for r in row])
    maha = z[0][0] * z[0][0]
    for i in range(1, n):
        maha = maha + z[i][0] * z[i][0]
    log_pred = -0.5 * (maha + _logdet_entries(low) + n * _LOG_2PI)
    # c S^-1 [y, c^T] = Z_c^T Z: entry (a, b) = sum_i z_i[1 + a] z_i[b]
    v_mean = np.empty(vh.shape)
    v_cov = np.empty(sv.shape)
    for a in range(n):
        for b in range(n + 1):
            cx = z[0][1 + a] * z[0][b]
            for i in range(1, n):
                cx += z[i][1 + a] * z[i][b]
            if b == 0:
                np.add(vh[..., a], cx, out=v_mean[..., a])
            else:
                np.subtract(sv[..., a, b - 1], cx, out=v_cov[..., a, b - 1])
    return np.asarray(log_pred, dtype=np.float64), y, v_mean, v_cov


@functools.lru_cache(maxsize=64)
def _observation_terms(
    idx_b: bytes, var_b: bytes, sq_b: bytes, nq: int
) -> tuple[bool, BoolArray, FloatArray, FloatArray, FloatArray]:
    """Terms of `gaussian_proposal` that depend only on the observation model (index, var)
    and the position noise sq (cached, read-only; keys are the arrays' bytes): whether all
    dims are observed in order, the observed mask, diag(sq^2 + var) over the observed dims,
    and the position-noise posterior gain and std (nq,)."""
    idx = np.frombuffer(idx_b, dtype=np.int64)
    var = np.frombuffer(var_b, dtype=np.float64)
    sq = np.frombuffer(sq_b, dtype=np.float64)
    every = idx.size == nq and bool(np.all(idx == np.arange(nq)))  # all dims, in order
    observed = np.zeros(nq, dtype=np.bool_)
    observed[idx] = True
    s_diag = np.diag(sq[idx] ** 2 + var)
    r_q = sq[idx] ** 2 + var
    q_gain = np.zeros(nq)
    q_gain[idx] = sq[idx] ** 2 / r_q
    q_std = sq.copy()
    q_std[idx] = np.sqrt(sq[idx] ** 2 * var / r_q)
    for a in (observed, s_diag, q_gain, q_std):
        a.setflags(write=False)
    return every, observed, s_diag, q_gain, q_std


def observation_terms(
    obs: LinearObservation | None, sigma_q: npt.ArrayLike, nq: int
) -> tuple[bool, FloatArray, FloatArray, FloatArray]:
    """The constant terms of `gaussian_proposal` for a reading obs (None: no reading) and the
    position noise std sigma_q (nq,): whether every dim is observed in order, diag(sq^2 +
    var) over the observed dims, and the position-noise posterior gain and std (nq,)
    (read-only arrays)."""
    sq = np.asarray(sigma_q, dtype=np.float64).reshape(nq)
    if obs is None:
        return False, np.zeros((0, 0)), np.zeros(nq), sq.copy()
    every, _, s_diag, q_gain, q_std = _observation_terms(
        np.asarray(obs.index, dtype=np.int64).tobytes(), obs.var.tobytes(), sq.tobytes(), nq
    )
    return every, s_diag, q_gain, q_std


def sample_gaussian_proposal(
    prop: GaussianProposal,
    *,
    v_h: npt.ArrayLike,
    innovation: npt.ArrayLike,
    v_mean: npt.ArrayLike,
    v_cov: npt.ArrayLike,
    dt: float,
    rng: np.random.Generator,
    draw: Callable[[tuple[int, ...]], FloatArray] | None = None,
) -> tuple[FloatArray, FloatArray]:
    """Draw (v', e_q) (N, nq) for the chosen hypotheses (rows of prop's arrays).

    v' ~ N(v_mean, v_cov) via a jittered Cholesky factor; then e_q | v' on observed dims.
    draw(shape): the standard normals (default rng.standard_normal; e.g. shared by rows
    that must see the same noise).
    """
    normals = rng.standard_normal if draw is None else draw
    vm = np.asarray(v_mean, dtype=np.float64)
    cov = np.asarray(v_cov, dtype=np.float64)
    cov = 0.5 * (cov + np.swapaxes(cov, -1, -2))
    n = vm.shape[-1]
    diag = np.abs(np.diagonal(cov, axis1=-2, axis2=-1))
    scale = diag[..., 0]
    for i in range(1, n):  # max over the (short) diagonal
        scale = np.maximum(scale, diag[..., i])
    ar = np.arange(n)
    cov[..., ar, ar] += 1e-12 * np.maximum(scale, 1e-300)[..., None]  # jitter on the diagonal
    low = _chol_entries(cov)
    z = normals(vm.shape)
    corr = np.stack(
        [
            sum((low[i][k] * z[..., k] for k in range(1, i + 1)), low[i][0] * z[..., 0])
            for i in range(n)
        ],
        axis=-1,
    )
    v_new = vm + corr
    y = np.asarray(innovation, dtype=np.float64)
    r = y - dt * (v_new - np.asarray(v_h, dtype=np.float64))
    q_mean = np.where(prop.observed, prop.q_gain * r, 0.0)
    e_q = q_mean + prop.q_std * normals(vm.shape)
    return np.asarray(v_new, dtype=np.float64), np.asarray(e_q, dtype=np.float64)


def gaussian_log_density(x: npt.ArrayLike, cov: npt.ArrayLike) -> FloatArray:
    """log N(x; 0, cov) for x (..., n), cov (..., n, n) (batched solve + Cholesky)."""
    xa = np.asarray(x, dtype=np.float64)
    ca = np.asarray(cov, dtype=np.float64)
    lead = np.broadcast_shapes(xa.shape[:-1], ca.shape[:-2])
    n = xa.shape[-1]
    if xa.shape[:-1] != lead:
        xa = np.broadcast_to(xa, (*lead, n))
    if ca.shape[:-2] != lead:
        ca = np.broadcast_to(ca, (*lead, n, n))
    low = _chol_entries(ca)
    z: list[FloatArray] = []  # entries of L^-1 x (forward substitution): x^T cov^-1 x = |.|^2
    for i in range(n):
        acc = xa[..., i]
        if i:
            s = low[i][0] * z[0]
            for k in range(1, i):
                s = s + low[i][k] * z[k]
            acc = acc - s
        z.append(acc / low[i][i])
    maha = z[0] * z[0]
    for i in range(1, n):
        maha = maha + z[i] * z[i]
    out = -0.5 * (maha + _logdet_entries(low) + n * _LOG_2PI)
    return np.asarray(out, dtype=np.float64)
