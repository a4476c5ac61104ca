"""Gaussian particles: each particle carries a Gaussian over its pose and twist (a research
probe on issue 10's friction at small particle counts).

DBC-SLAM's particles are points (q, v) (`dbcslam_core.particles`); at 40 particles the
fixed-friction filters' log-evidence falls tens to hundreds of nats short of a 4000-particle
filter's, and the friction posterior follows that noise (README, "Friction at small particle
counts"). Here a particle is a mixture-Kalman-filter component instead (Chen & Liu 2000): the
discrete part (the particle's contact-mode history) is sampled, the continuous state given
it is a Gaussian N(m, S) over x = (q, v) (m, m, rad, m/s, m/s, rad/s), world frame:

* every live mode hypothesis of every particle (the core's phases: free motion, mode
  prediction, enumeration, reduced dynamics at the particle's mean) is linearised by finite
  differences, v' = v_h + G (x - m) + w with w ~ N(0, cov_h) the hypothesis' process noise,
  and q' = q + dt v' + e_q (`kalman_entries`);
* the pose reading updates each (particle, hypothesis) child in closed form, which gives its
  predictive likelihood exactly (given the linearisation);
* the children are cut back to P particles by Fearnhead-Clifford resampling
  (`fearnhead_clifford`: the heavy children are kept, the others sampled without
  duplicates, so no two particles carry the same Gaussian);
* a particle's per-contact mode marginals (the next step's persistence prior) are those of
  its parent's hypotheses given a velocity drawn from its Gaussian, as the point filter
  conditions on its sampled velocity.

Fixed-friction filters only (`FilterConfig.frozen_friction`, no friction bank): the probe
compares friction evidence, the Bayes average over the candidates' fixed-friction filters.
Numpy path, finite-difference Jacobians (2 nq extra solves per step): a measurement of what
the representation buys, not a live filter (5.5-7.4 ms per step at 40 particles on the
gripper, 10-15x the compiled point filter's).

``python -m dbcslam_research.gaussian_particles --evidence DIR/gripper_evidence.json ...``
runs the Gaussian fixed-friction filters on the pybullet runs of `gripper_evidence` reports
(their simulator overrides, filter seed s as there) and compares, per run, the Bayes
average's P(true mu) with that of the report's point filters at the same seed and with the
report's verdict (its largest particle count); ``--synthetic N`` does the same on the core's
own synthetic grasps (seeds 0..N-1 at each ``--synthetic-mu``, the point filters and the
``--verdict-particles`` verdict run here). Writes ``gaussian_particles.md`` / ``.json``.
"""

from __future__ import annotations

import argparse
import json
import math
import statistics
import sys
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt

from dbcslam_core.angles import wrap_angle
from dbcslam_core.contact_modes import Mode
from dbcslam_core.errors import ModelError
from dbcslam_core.experiments import DBCSLAM, run_filter, run_fixed_friction
from dbcslam_core.observation import LinearObservation, gaussian_log_density
from dbcslam_core.particles import ParticleSet
from dbcslam_core.rbpf import (
    DbcSlamFilter,
    Estimate,
    FilterConfig,
    FilterInput,
    _Posterior,
    _Proposal,
)
from dbcslam_core.resampling import effective_sample_size, normalise_log_weights
from dbcslam_core.synthetic import Trajectory, gripper_trajectory
from dbcslam_research.cli import pool_map
from dbcslam_research.experiments import command_line, progress_printer, utc_now, write_json
from dbcslam_research.friction_calibration import load_verdicts
from dbcslam_research.gripper_evidence import SimSet, grasp_run

__all__ = [
    "CONFIDENT",
    "GaussianParticleFilter",
    "fearnhead_clifford",
    "kalman_entries",
    "main",
    "render_markdown",
    "summarise",
]

FloatArray = npt.NDArray[np.float64]
IntArray = npt.NDArray[np.int64]

CONFIDENT = 0.9
"""Issue 10's target: final P(true mu) >= 0.9."""

DEFAULT_OUT = Path("dbcslam_ros/research/results/gaussian_particles")

_FD_STEP_Q = (1e-6, 1e-6, 1e-5)  # m, m, rad
_FD_STEP_V = (1e-5, 1e-5, 1e-4)  # m/s, m/s, rad/s


def fearnhead_clifford(
    log_w: npt.ArrayLike, n: int, rng: np.random.Generator
) -> tuple[IntArray, FloatArray]:
    """Fearnhead-Clifford resampling of M weighted children to at most `n` (Fearnhead &
    Clifford 2003): with c solving sum_i min(c W_i, 1) = n, the children with c W_i >= 1 are
    kept with their weight W_i, n - k others are drawn by systematic sampling in proportion
    to W_i (each at most once) and weighted 1 / c. The new weights sum to 1 and are unbiased
    for the old. When at most n children have positive weight all of those are kept.

    Returns (indices into log_w, log of the new normalised weights); raises ModelError when
    no child has a positive weight or n < 1."""
    lw = np.asarray(log_w, dtype=np.float64).reshape(-1)
    if n < 1:
        msg = f"n must be >= 1 particles, got {n}"
        raise ModelError(msg)
    w, _ = normalise_log_weights(lw)  # raises on all -inf
    positive = np.flatnonzero(w > 0.0)
    if positive.size <= n:
        return positive.astype(np.int64), np.log(w[positive])
    order = positive[np.argsort(-w[positive], kind="stable")]
    ws = w[order]
    tail = np.cumsum(ws[::-1])[::-1]  # tail[k] = sum of ws[k:]
    k = 0
    while k < n and (n - k) * ws[k] >= tail[k]:  # c W_(k) >= 1: keep child k as it is
        k += 1
    if k == n:  # the rest weighs less than round-off of the kept ones
        return order[:n].astype(np.int64), np.log(ws[:n])
    draws = n - k  # c = draws / tail[k]; a drawn child weighs 1 / c
    rest = order[k:]
    cdf = np.cumsum(w[rest]) / tail[k]
    u = (rng.random() + np.arange(draws)) / draws
    picked = rest[np.minimum(np.searchsorted(cdf, u, side="right"), rest.size - 1)]
    idx = np.concatenate([order[:k], picked]).astype(np.int64)
    new = np.concatenate([ws[:k], np.full(draws, tail[k] / draws)])
    return idx, np.log(new)


@dataclass(frozen=True)
class KalmanChildren:
    """Per (entry, friction hypothesis): posterior mean (N, B, 2 nq) and covariance
    (N, B, 2 nq, 2 nq) of x' = (q', v') and the log predictive likelihood (N, B) of the
    reading (0 without one)."""

    mean: FloatArray
    cov: FloatArray
    log_pred: FloatArray


def kalman_entries(
    q: FloatArray,
    cov_x: FloatArray,
    *,
    v_h: FloatArray,
    jac: FloatArray,
    cov_v: FloatArray,
    sigma_q: FloatArray,
    dt: float,
    obs: LinearObservation | None,
) -> KalmanChildren:
    """One linear-Gaussian predict and update per entry x friction hypothesis.

    q (N, nq) the parents' mean poses, cov_x (N, 2nq, 2nq) their covariances of (q, v);
    v_h (N, B, nv) the post-step velocity of each hypothesis at the mean, jac (N, B, nv, 2nq)
    its Jacobian d v' / d(q, v), cov_v (N, B, nv, nv) its process noise, sigma_q (nq,) the
    per-step position noise std (m, m, rad), dt (s); obs the linearised pose reading.
    x' = (q + dt v' + e_q, v') with v' = v_h + jac (x - m) + w."""
    n, nb, nq = v_h.shape
    eye = np.eye(nq)
    top = np.concatenate([eye, np.zeros((nq, nq))], axis=1)[None, None] + dt * jac
    a = np.concatenate([top, jac], axis=2)  # (N, B, 2nq, 2nq): d x' / d x
    noise = np.empty((n, nb, 2 * nq, 2 * nq))
    noise[..., :nq, :nq] = dt * dt * cov_v + np.diag(np.asarray(sigma_q) ** 2)
    noise[..., :nq, nq:] = dt * cov_v
    noise[..., nq:, :nq] = dt * cov_v
    noise[..., nq:, nq:] = cov_v
    prior = a @ cov_x[:, None] @ np.swapaxes(a, -1, -2) + noise
    mean = np.concatenate([q[:, None, :] + dt * v_h, v_h], axis=-1)
    if obs is None:
        return KalmanChildren(mean, prior, np.zeros((n, nb)))
    idx = np.asarray(obs.index)
    h = np.zeros((idx.size, 2 * nq))
    h[np.arange(idx.size), idx] = 1.0
    innov = obs.residual(mean[..., idx])  # (N, B, D), angular dims wrapped
    ph = prior @ h.T  # (N, B, 2nq, D)
    s = h @ ph + np.diag(obs.var)
    s = 0.5 * (s + np.swapaxes(s, -1, -2))
    log_pred = gaussian_log_density(innov, s)
    # gain^T = S^-1 (P H^T)^T (solve, no inverse)
    gain = np.swapaxes(np.linalg.solve(s, np.swapaxes(ph, -1, -2)), -1, -2)
    post_mean = mean + (gain @ innov[..., None])[..., 0]
    post_cov = prior - gain @ np.swapaxes(ph, -1, -2)
    post_cov = 0.5 * (post_cov + np.swapaxes(post_cov, -1, -2))
    return KalmanChildren(post_mean, post_cov, log_pred)


class GaussianParticleFilter(DbcSlamFilter):
    """DBC-SLAM with Gaussian particles (module docstring): fixed friction only."""

    def __init__(
        self, scenario: Any, config: FilterConfig, rng: np.random.Generator | None = None
    ) -> None:
        if config.frozen_friction is None or config.friction_bank:
            msg = (
                "GaussianParticleFilter needs a fixed-friction configuration "
                f"(frozen_friction set, friction_bank False), got frozen_friction="
                f"{config.frozen_friction}, friction_bank={config.friction_bank}"
            )
            raise ModelError(msg)
        super().__init__(scenario, config, rng)
        if self.n_fb != 1:  # pragma: no cover - frozen friction has one joint hypothesis
            msg = f"expected one friction hypothesis with frozen friction, got {self.n_fb}"
            raise ModelError(msg)
        self.cov_x: FloatArray = np.zeros((0, 2 * self.nq, 2 * self.nq))

    def initialize(
        self,
        q_mean: npt.ArrayLike,
        q_std: npt.ArrayLike,
        v_mean: npt.ArrayLike | None = None,
        v_std: npt.ArrayLike | None = None,
        joints: npt.ArrayLike | None = None,
    ) -> None:
        """Every particle starts as the prior Gaussian N((q_mean, v_mean), diag(q_std^2,
        v_std^2)) (the same for all: they part by their mode histories)."""
        super().initialize(q_mean, q_std, v_mean, v_std, joints)
        nq, ps = self.nq, self.particles
        qs = np.broadcast_to(np.asarray(q_std, dtype=np.float64), (nq,))
        vs = np.asarray(
            self.config.init_velocity_std[:nq] if v_std is None else v_std, dtype=np.float64
        )
        vm = np.zeros(nq) if v_mean is None else np.asarray(v_mean, dtype=np.float64)
        ps.q = np.tile(np.asarray(q_mean, dtype=np.float64).reshape(nq), (ps.size, 1))
        ps.v = np.tile(np.broadcast_to(vm, (nq,)), (ps.size, 1))
        var = np.concatenate([qs**2, np.broadcast_to(vs, (nq,)) ** 2])
        self.cov_x = np.tile(np.diag(var), (ps.size, 1, 1))

    def step(
        self,
        observation: Any,
        inputs: FilterInput,
        force: Any = None,
    ) -> Estimate:
        """Predict, update and cut back (module docstring); force readings are refused."""
        if force is not None:
            msg = "GaussianParticleFilter does not take force readings"
            raise ModelError(msg)
        inp = self._read_inputs(observation, inputs, None)
        free = self._free_motion(inp)
        pred = self._predict_modes(free)
        hyp = self._enumerate(pred, free)
        ent = self._live_entries(hyp.padded(), pred)
        dyn = self._hypothesis_dynamics(ent, free, inp)
        jac = self._linearise(ent, dyn.v_h, inp)
        kids = kalman_entries(
            self.particles.q.take(ent.pi, axis=0),
            self.cov_x.take(ent.pi, axis=0),
            v_h=dyn.v_h,
            jac=jac,
            cov_v=dyn.cov_h,
            sigma_q=self._sigma_q,
            dt=self.dt,
            obs=inp.lin,
        )
        log_child, log_ml = self._child_weights(ent.pi, dyn.log_alpha, kids.log_pred, inp)
        keep, log_w = fearnhead_clifford(log_child.reshape(-1), self.config.particles, self.rng)
        e_idx, b_idx = np.unravel_index(keep, log_child.shape)
        parents = ent.pi[e_idx]
        self._adopt(parents, kids.mean[e_idx, b_idx], kids.cov[e_idx, b_idx], log_w)
        self.particles.modes = self._mode_marginals(ent, dyn, parents)
        self._record_map(inp.joints)
        return self._summary(kids, log_child, ent.modes_n, float(hyp.counts.mean()), log_ml)

    # ----------------------------------------------------------------------- phases
    def _linearise(self, ent: Any, v_h: FloatArray, inp: Any) -> FloatArray:
        """d v' / d(q, v) (N, B, nv, 2nq) of every live entry at its particle's mean, by
        forward differences through the core's free motion and reduced dynamics (the
        entry's modes held)."""
        ps = self.particles
        nq = self.nq
        q0, v0 = ps.q, ps.v
        jac = np.zeros((*v_h.shape, 2 * nq))
        steps = (*_FD_STEP_Q[:nq], *_FD_STEP_V[:nq])
        try:
            for j, h in enumerate(steps):
                q, v = q0.copy(), v0.copy()
                (q if j < nq else v)[:, j % nq] += h
                ps.q, ps.v = q, v
                free = self._free_motion(inp)
                sol = self._solve_entries(
                    ent.modes_n,
                    free.v_free.take(ent.pi, axis=0)
                    if free.v_free_b is None
                    else free.v_free_b.take(ent.pi, axis=0),
                    free.kin,
                    ent.pi,
                    None if free.m_eff is None else free.m_eff.take(ent.pi, axis=0),
                    sensitivity=False,
                )
                jac[..., j] = (sol.v_next - v_h) / h
        finally:
            ps.q, ps.v = q0, v0
        return np.where(np.isfinite(jac), jac, 0.0)

    def _summary(
        self,
        kids: KalmanChildren,
        log_child: FloatArray,
        modes_n: IntArray,
        live: float,
        log_ml: float,
    ) -> Estimate:
        """The step's estimate over all children (before the cut-back: lower variance)."""
        nq = self.nq
        w_child = normalise_log_weights(log_child.reshape(-1))[0]
        w_kept = normalise_log_weights(self.particles.log_w)[0]
        fric = self._pair_marginals(self.particles.fric[:1])
        return self._estimate(
            w=w_child,
            row_w=w_child,
            map_w=w_kept,
            q=kids.mean[..., :nq].reshape(-1, nq),
            v=kids.mean[..., nq:].reshape(-1, nq),
            marg_post=np.repeat(_one_hot(modes_n), log_child.shape[1], axis=0),
            fric_pair=np.repeat(fric, w_child.size, axis=0),
            ess=effective_sample_size(w_kept),
            live=live,
            log_ml=log_ml,
            resampled=True,
        )

    def _child_weights(
        self, pi: IntArray, log_alpha: FloatArray, log_pred: FloatArray, inp: Any
    ) -> tuple[FloatArray, float]:
        """Log weights (N, B) of the children: parent weight x discrete proposal weight x
        predictive likelihood; and the step's log p(o_l | o_<l) (0 without a reading)."""
        w_prev = normalise_log_weights(self.particles.log_w)[0]
        with np.errstate(divide="ignore"):
            log_parent = np.log(w_prev)[pi][:, None]
        ok = np.isfinite(log_alpha)
        log_child = np.where(ok, log_parent + np.where(ok, log_alpha, 0.0) + log_pred, -np.inf)
        if not np.any(np.isfinite(log_child)):
            msg = f"no feasible hypothesis for any particle at step {self._step}"
            raise ModelError(msg)
        log_ml = float(self._lse(log_child.reshape(1, -1), 1)[0]) if inp.lin is not None else 0.0
        return log_child, log_ml

    def _adopt(
        self, parents: IntArray, mean: FloatArray, cov: FloatArray, log_w: FloatArray
    ) -> None:
        """The kept children become the particles (their parents' beliefs and map rows)."""
        ps: ParticleSet = self.particles
        nq = self.nq
        ps.resample(parents)
        ps.q = mean[:, :nq].copy()
        if nq == 3:
            ps.q[:, 2] = wrap_angle(ps.q[:, 2])
        ps.v = mean[:, nq:].copy()
        ps.log_w = log_w - np.max(log_w)
        self.cov_x = cov

    def _mode_marginals(self, ent: Any, dyn: Any, parents: IntArray) -> FloatArray:
        """Per new particle: its parent's hypothesis posterior given a velocity drawn from
        the particle's Gaussian, as per-contact mode marginals (P, B, C, 4)."""
        nq = self.nq
        v_mean, cov_x = self.particles.v, self.cov_x
        slots = ent.slot[parents]  # (P, K) entry index or -1
        ok = slots >= 0
        sl = np.where(ok, slots, 0)
        cov_v = cov_x[:, nq:, nq:] + 1e-14 * np.eye(nq)
        low = np.linalg.cholesky(0.5 * (cov_v + np.swapaxes(cov_v, -1, -2)))
        v = v_mean + (low @ self.rng.standard_normal((*v_mean.shape, 1)))[..., 0]
        dens = gaussian_log_density(v[:, None, None, :] - dyn.v_h[sl], dyn.cov_h[sl])
        la = dyn.log_alpha[sl]
        log_post = np.where(ok[..., None] & np.isfinite(la), la + dens, -np.inf)[..., 0]
        post = _rows(log_post)
        marg = np.einsum("pk,pkcm->pcm", post, _one_hot(ent.modes_n)[sl])
        return np.broadcast_to(marg[:, None], self.particles.modes.shape).copy()

    def _record_map(self, joints: FloatArray) -> None:
        """Append the step to the friction map's history: `DbcSlamFilter._move` with the
        particles' own state and beliefs."""
        ps = self.particles
        fric_pair = self._pair_marginals(ps.fric)
        p_contact = 1.0 - ps.modes[:, 0, :, Mode.SEPARATED]
        marg = ps.modes[:, 0]
        post = _Posterior(ps.fric, fric_pair, ps.modes, marg, np.zeros((0,)), p_contact)
        self._move(_Proposal(np.zeros(ps.count), ps.v, ps.q), post, joints)


def _rows(log_p: FloatArray) -> FloatArray:
    """Row-wise normalised probabilities of log_p (P, K)."""
    m = np.max(log_p, axis=1, keepdims=True)
    p = np.exp(log_p - np.where(np.isfinite(m), m, 0.0))
    return np.asarray(p / p.sum(axis=1, keepdims=True), dtype=np.float64)


def _one_hot(modes: IntArray) -> FloatArray:
    """(N, C) mode indices -> (N, C, 4) indicators."""
    out = np.zeros((*modes.shape, 4))
    np.put_along_axis(out, modes[..., None], 1.0, axis=-1)
    return out


# --------------------------------------------------------------------------- the probe
def load_report(path: Path) -> dict[str, Any]:
    """A `gripper_evidence` JSON report's simulator overrides, runs, per-run rows and the
    particle count of its verdicts; raises ValueError naming the file when it cannot be read
    or lacks them."""
    head = load_verdicts(path)
    rows = json.loads(path.read_text(encoding="utf-8")).get("evidence")
    if not rows:
        msg = f"--evidence {path}: no fixed-friction rows (section 2)"
        raise ValueError(msg)
    return {**head, "rows": rows, "path": str(path)}


Source = tuple[str, int, Any]
"""Where a run's trajectory comes from: ("pybullet", run, SimSet) or ("synthetic", seed, mu)."""


def _trajectory(source: Source) -> Trajectory:
    kind, number, setting = source
    if kind == "pybullet":
        return grasp_run(number, None, setting)
    return gripper_trajectory(number, mu_jaw=float(setting))


def fixed_evidence(
    tr: Trajectory, particles: int, fseed: int, *, gaussian: bool
) -> tuple[list[float], float]:
    """Every candidate's fixed-friction log-evidence (nats) on `tr` with Gaussian or point
    particles (rng as `run_fixed_friction`) and the mean step time (ms)."""
    sc = tr.scenario
    log_ml, ms = [], []
    for c in range(len(sc.friction.candidates[0])):
        if gaussian:
            cfg = FilterConfig.preset(
                sc.kind, particles=particles, friction_bank=False, frozen_friction=c
            )
            filt = GaussianParticleFilter(sc, cfg, np.random.default_rng([fseed, 2]))
            trace = run_filter(filt, tr, method=DBCSLAM, seed=fseed, particles=particles)
        else:
            trace = run_fixed_friction(
                tr, c, seed=fseed, particles=particles, overrides={"friction_bank": False}
            )
        assert trace.log_likelihood is not None
        log_ml.append(float(np.sum(trace.log_likelihood)))
        ms.append(1e3 * float(np.mean(trace.step_time)))
    return log_ml, float(np.mean(ms))


def _row(source: Source, fseed: int, particles: int, gaussian: bool) -> dict[str, Any]:
    """One (run, filter seed, particle count, representation) row with P(true)."""
    tr = _trajectory(source)
    cands = np.asarray(tr.scenario.friction.candidates[0])
    true = int(np.argmin(np.abs(cands - tr.mu_pair[0])))
    log_ml, ms = fixed_evidence(tr, particles, fseed, gaussian=gaussian)
    prior = tr.scenario.friction.prior[0]
    return {
        "run": source[1],
        "filter_seed": fseed,
        "particles": particles,
        "true": true,
        "log_ml": log_ml,
        "p_true": _p_true(log_ml, prior, true),
        "step_ms": ms,
    }


def _gauss_task(args: tuple[Source, int, int]) -> dict[str, Any]:
    source, fseed, particles = args
    return _row(source, fseed, particles, gaussian=True)


def _point_task(args: tuple[Source, int, int]) -> dict[str, Any]:
    source, fseed, particles = args
    return _row(source, fseed, particles, gaussian=False)


def _p_true(log_ml: Sequence[float], prior: Sequence[float], true: int) -> float:
    post, _ = normalise_log_weights(np.log(np.asarray(prior, dtype=np.float64)) + log_ml)
    return float(post[true])


def summarise(report: dict[str, Any], gauss: Sequence[dict[str, Any]]) -> list[dict[str, Any]]:
    """Per Gaussian particle count: runs, runs with the Bayes average's P(true) >= CONFIDENT
    (Gaussian, and the report's point filters at the same filter seed at each of its particle
    counts), the Gaussian log-evidence minus the verdict's (mean of the report's filters at
    its `verdict_particles`), for the true and the wrong candidates (nats), and the Gaussian
    filters' mean step time (ms)."""
    vp = report["verdict_particles"]
    ref: dict[int, list[list[float]]] = {}
    for r in report["rows"]:
        if r["particles"] == vp:
            ref.setdefault(r["run"], []).append(r["log_ml"])
    ref_ml = {run: np.mean(v, axis=0) for run, v in ref.items()}
    out = []
    for p in sorted({g["particles"] for g in gauss}):
        rows = [g for g in gauss if g["particles"] == p]
        point = {}
        for q in sorted({r["particles"] for r in report["rows"]}):
            hits = [
                r["p_true"] >= CONFIDENT
                for r in report["rows"]
                if r["particles"] == q
                and any(
                    g["run"] == r["run"] and g["filter_seed"] == r["filter_seed"] for g in rows
                )
            ]
            point[str(q)] = [sum(hits), len(hits)]
        gap_true, gap_wrong, misses = [], [], []
        right = 0
        for g in rows:
            pt = g["p_true"]
            right += pt >= CONFIDENT
            if pt < CONFIDENT:
                misses.append([g["run"], g["filter_seed"], pt])
            if g["run"] in ref_ml:
                d = np.asarray(g["log_ml"]) - ref_ml[g["run"]]
                gap_true.append(float(d[g["true"]]))
                gap_wrong += [float(x) for i, x in enumerate(d) if i != g["true"]]
        out.append(
            {
                "particles": p,
                "runs": len(rows),
                "gaussian_right": right,
                "point_right": point,
                "gap_true": gap_true,
                "gap_wrong": gap_wrong,
                "misses": misses,
                "step_ms": statistics.fmean(g.get("step_ms", math.nan) for g in rows),
            }
        )
    return out


def _spread(xs: Sequence[float]) -> str:
    if not xs:
        return "-"
    return f"{statistics.median(xs):+.1f} [{min(xs):+.1f}, {max(xs):+.1f}]"


def render_markdown(result: dict[str, Any], command: str) -> str:
    """The report: one table per section (an evidence report or a synthetic coefficient)."""
    lines = [
        "# Gaussian particles: friction evidence at small particle counts",
        "",
        f"Command: `{command}`  ",
        f"Date: {result['date']}; {result['wall_s']:.0f} s wall; filter seeds "
        f"{result['filter_seeds']}.",
        "",
        "'right': the Bayes average over the candidates' fixed-friction filters gives the "
        f"true mu P >= {CONFIDENT} (issue 10's target). 'point filters N': DBC-SLAM's point "
        "particles (N of them) on the same runs and filter seeds. 'vs verdict': Gaussian "
        "log-evidence minus the verdict filters' (the largest point count, mean over its "
        "seeds), median [min, max], nats. 'step': the Gaussian filters' mean step time "
        "(numpy path with finite-difference Jacobians, not the compiled point filter's).",
    ]
    for sec in result["reports"]:
        lines += ["", f"## {sec['title']}", ""]
        counts = sorted({k for s in sec["summary"] for k in s["point_right"]}, key=int)
        head = " | ".join(f"point filters {k}" for k in counts)
        lines += [
            f"| Gaussian particles | runs | Gaussian right | {head} | vs verdict, true mu "
            "| vs verdict, wrong mu | step [ms] | Gaussian misses: run/seed (P(true)) |",
            "|" + "---|" * (7 + len(counts)),
        ]
        for s in sec["summary"]:
            pts = " | ".join(
                f"{s['point_right'][k][0]} / {s['point_right'][k][1]}" for k in counts
            )
            miss = ", ".join(f"{r}/{sd} ({p:.2f})" for r, sd, p in s["misses"]) or "-"
            lines.append(
                f"| {s['particles']} | {s['runs']} | {s['gaussian_right']} | {pts} | "
                f"{_spread(s['gap_true'])} | {_spread(s['gap_wrong'])} | "
                f"{s['step_ms']:.1f} | {miss} |"
            )
    return "\n".join(lines) + "\n"


def _pybullet_section(
    rep: dict[str, Any], a: argparse.Namespace, say: Callable[[str], None]
) -> dict[str, Any]:
    """The Gaussian filters on an evidence report's pybullet runs, against its rows."""
    sim_set: SimSet = tuple(sorted(rep["sim_set"].items()))
    runs = sorted({r["run"] for r in rep["rows"]})[: a.runs]
    say(f"{rep['path']}: runs {runs[0]}..{runs[-1]}")
    tasks = [
        (("pybullet", r, sim_set), s, n) for n in a.particles for s in a.filter_seeds for r in runs
    ]
    gauss = pool_map(_gauss_task, tasks, a.workers, say, "Gaussian filters")
    title = f"{rep['path']} (simulator {rep['sim_set'] or 'defaults'})"
    return {"title": title, "rows": gauss, "summary": summarise(rep, gauss)}


def _synthetic_section(
    mu: float, a: argparse.Namespace, say: Callable[[str], None]
) -> dict[str, Any]:
    """Gaussian and point filters on the core's synthetic grasps (seeds 0..N-1) at mu."""
    say(f"synthetic gripper, mu_jaw {mu:g}: seeds 0..{a.synthetic - 1}")
    sources = [("synthetic", seed, mu) for seed in range(a.synthetic)]
    point_counts = sorted({*a.particles, a.verdict_particles})
    tasks = [(src, s, n) for n in a.particles for s in a.filter_seeds for src in sources]
    gauss = pool_map(_gauss_task, tasks, a.workers, say, "Gaussian filters")
    point_tasks = [(src, s, n) for n in point_counts for s in a.filter_seeds for src in sources]
    point = pool_map(_point_task, point_tasks, a.workers, say, "point filters")
    rep = {"rows": point, "verdict_particles": a.verdict_particles}
    title = f"synthetic gripper (`synthetic.gripper_trajectory(seed, mu_jaw={mu:g})`)"
    return {"title": title, "rows": gauss, "point_rows": point, "summary": summarise(rep, gauss)}


def main(argv: Sequence[str] | None = None) -> int:
    """Command line (see the module docstring)."""
    p = argparse.ArgumentParser(
        prog="python -m dbcslam_research.gaussian_particles",
        description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
        epilog="examples: python -m dbcslam_research.gaussian_particles --evidence "
        "dbcslam_ros/research/results/gripper_evidence/jaw_mu_0.4/gripper_evidence.json "
        "--particles 40 --runs 5; ... --synthetic 10 (the core's own model, no pybullet)",
    )
    p.add_argument(
        "--evidence",
        type=Path,
        nargs="+",
        default=[],
        help="gripper_evidence JSON reports (their pybullet runs and simulator overrides)",
    )
    p.add_argument(
        "--synthetic",
        type=int,
        default=0,
        metavar="N",
        help="also the core's synthetic grasps, seeds 0..N-1, at each --synthetic-mu (0: none)",
    )
    p.add_argument(
        "--synthetic-mu", type=float, nargs="+", default=[0.1, 0.4, 0.7], help="(0.1 0.4 0.7)"
    )
    p.add_argument(
        "--verdict-particles",
        type=int,
        default=1000,
        help="point particles of the synthetic verdict filters (1000)",
    )
    p.add_argument("--particles", type=int, nargs="+", default=[40], help="(40)")
    p.add_argument("--filter-seeds", type=int, nargs="+", default=[0], help="(0)")
    p.add_argument(
        "--runs", type=int, default=None, help="the first N runs of each report (default: all)"
    )
    p.add_argument("--workers", type=int, default=2, help="processes (2)")
    p.add_argument("--out", type=Path, default=DEFAULT_OUT, help=f"({DEFAULT_OUT})")
    p.add_argument("--quiet", action="store_true", help="no progress lines or table")
    a = p.parse_args(argv)
    if not a.evidence and a.synthetic < 1:
        p.error("give --evidence REPORT ... and / or --synthetic N (N >= 1)")
    counts = [*a.particles, a.workers, a.verdict_particles, a.runs or 1]
    if min(counts) < 1 or a.synthetic < 0:
        p.error("--particles, --workers, --verdict-particles, --runs must be >= 1")
    if min(a.filter_seeds) < 0:
        p.error(f"--filter-seeds must be >= 0, got {a.filter_seeds}")
    try:
        reports = [load_report(path) for path in a.evidence]
    except ValueError as err:
        p.error(str(err))
    say: Callable[[str], None] = progress_printer(a.quiet)
    t0 = time.perf_counter()
    sections = [_pybullet_section(rep, a, say) for rep in reports]
    if a.synthetic:
        sections += [_synthetic_section(mu, a, say) for mu in a.synthetic_mu]
    result = {
        "date": utc_now(),
        "wall_s": time.perf_counter() - t0,
        "filter_seeds": a.filter_seeds,
        "reports": sections,
    }
    a.out.mkdir(parents=True, exist_ok=True)
    md = render_markdown(
        result, command_line("python -m dbcslam_research.gaussian_particles", argv)
    )
    (a.out / "gaussian_particles.md").write_text(md, encoding="utf-8")
    write_json(a.out / "gaussian_particles.json", result)
    if not a.quiet:
        print(md)
    return 0


if __name__ == "__main__":
    sys.exit(main())
