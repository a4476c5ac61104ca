"""The score of a model on a set of runs: the DBC-SLAM filter's own evidence.

score(model, runs) = sum over runs and steps of log p(o_k | o_{0:k-1}, inputs, model), the
filter's log predictive likelihood (`Estimate.log_likelihood`). Friction (per region,
friction map), contact modes and the start state are integrated by the filter, never fixed.
Every evaluation uses the same filter seed (common random numbers across candidate models
and parameters); `ScoreConfig.particles` sets the Monte-Carlo noise (measured by
`Scorer.noise`, which re-runs a model with other seeds).

Besides the evidence, each run yields the one-step prediction of the position (the
contract's prediction RMSE): the model's deterministic step (`PlanarModel.step`, batched
PGS) from the filter's posterior mean state at k - 1 with the posterior mean friction
coefficient per pair, compared with the observed position at k (after `skip` initial steps
in which the filter locks on); and the tracking residual (posterior mean as the sensor would
see it vs the observation).
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

from ..dynamics import PlanarModel, State
from ..errors import DbcSlamError
from ..extensions import ModelExtension
from ..lcp import PGSSolver
from ..observation import PoseObservation
from ..rbpf import DbcSlamFilter, FilterConfig, FilterInput
from ..scenario import Scenario
from .effects import Hypothesis
from .runs import Run

__all__ = ["SCORE_OVERRIDES", "ModelScore", "RunTrace", "ScoreConfig", "Scorer"]

F64 = NDArray[np.float64]


@dataclass(frozen=True)
class ScoreConfig:
    """particles / seed of the scoring filter (fixed seed: common random numbers); skip:
    initial steps of each run left out of the score and the RMSEs (the filter runs over
    them: it locks on to the unknown initial velocity there, and a sensor-delay hypothesis
    has no inputs from before the recording; must exceed the largest delay searched,
    0.15 s at dt 0.01); filter_overrides: extra `FilterConfig`
    fields on top of the scenario preset (`SCORE_OVERRIDES` per scenario kind first)."""

    particles: int = 300
    seed: int = 0
    skip: int = 20
    filter_overrides: tuple[tuple[str, object], ...] = ()


@dataclass(frozen=True)
class RunTrace:
    """One filter pass over one run: per-step log predictive likelihood ll[T] (nan before
    the first step), posterior means q, v [T, nq] (true-state frame), one-step predicted
    observed position pred[T, 2] (nan where not predicted), failed: the filter lost all
    particles (the model cannot explain the data; loglik = -inf)."""

    ll: F64
    q: F64
    v: F64
    pred: F64
    failed: bool

    @property
    def loglik(self) -> float:
        """Summed log predictive likelihood (all steps)."""
        return -math.inf if self.failed else float(np.nansum(self.ll))

    def loglik_from(self, skip: int) -> float:
        """Summed log predictive likelihood from the `skip`-th sample on."""
        return -math.inf if self.failed else float(np.nansum(self.ll[skip:]))


@dataclass(frozen=True)
class ModelScore:
    """Score of one hypothesis on a set of runs."""

    hypothesis: Hypothesis
    loglik: float  # summed log predictive likelihood (nats)
    n_obs: int
    pred_rmse: float  # one-step predicted vs observed position (m)
    track_rmse: float  # posterior mean (sensor frame) vs observed position (m)
    traces: tuple[RunTrace, ...] = field(repr=False, default=())


SCORE_OVERRIDES: dict[str, dict[str, object]] = {
    "edge": {"process_noise": (0.005, 0.005, 0.5)},
}
"""Filter settings of the score per scenario kind, on top of `FilterConfig.preset`. Edge:
half the preset's velocity process noise (0.005 m/s per step, a 0.5 N force noise on 1 kg):
with the preset's 0.01 a hidden damping of 2 N s/m gained only ~90 nats over 10 s (the
noise absorbs it), with 0.005 ~1400-1900 nats; at 0.003 mis-specified models lose track
(scores of -1e4 to -1e5 nats) and the score surface becomes a cliff (measured on
`synthetic.edge_sweep_trajectory`, 200 particles, 3 seeds)."""


def _delayed(a: F64, shift: float) -> F64:
    """a[T, d] sampled at k - shift (linear interpolation, clamped at the ends)."""
    if shift == 0.0 or a.shape[1] == 0:
        return a
    n = a.shape[0]
    pos = np.clip(np.arange(n, dtype=np.float64) - shift, 0.0, n - 1.0)
    lo = np.floor(pos).astype(np.int64)
    hi = np.minimum(lo + 1, n - 1)
    fr = (pos - lo)[:, None]
    return np.asarray(a[lo] * (1.0 - fr) + a[hi] * fr, dtype=np.float64)


class Scorer:
    """Runs the filter over runs under hypotheses; caches every (hypothesis, run, seed)."""

    def __init__(
        self, cfg: ScoreConfig | None = None, progress: Callable[[str], None] | None = None
    ) -> None:
        self.cfg = cfg or ScoreConfig()
        self.say = progress or (lambda s: None)
        self._cache: dict[tuple[Hypothesis, int, int], RunTrace] = {}
        self.evaluations = 0

    def trace(self, hyp: Hypothesis, run: Run, seed: int | None = None) -> RunTrace:
        """The filter pass of `hyp` over `run` (cached)."""
        s = self.cfg.seed if seed is None else seed
        key = (hyp, id(run), s)
        if key not in self._cache:
            t0 = time.process_time()
            tr = self._run(hyp, run, s)
            self._cache[key] = tr
            self.evaluations += 1
            self.say(
                f"    filter run {self.evaluations}: {hyp.label()} on {run.name} (seed {s}): "
                f"{tr.loglik_from(self.cfg.skip):.1f} nats "
                f"({time.process_time() - t0:.1f} s CPU)"
            )
        return self._cache[key]

    def score(self, hyp: Hypothesis, runs: Sequence[Run], seed: int | None = None) -> ModelScore:
        """Summed evidence, prediction and tracking RMSE of `hyp` over `runs`."""
        traces = tuple(self.trace(hyp, r, seed) for r in runs)
        _, _, bias, _ = hyp.filter_setup(runs[0].scenario)
        pe, te = [], []
        for r, tr in zip(runs, traces, strict=True):
            ok = np.all(np.isfinite(r.obs[:, :2]), axis=-1) & np.all(np.isfinite(tr.pred), -1)
            ok[: self.cfg.skip] = False
            pe.append(tr.pred[ok] - r.obs[ok, :2])
            okq = np.all(np.isfinite(r.obs[:, :2]), axis=-1) & np.all(np.isfinite(tr.q), -1)
            okq[: self.cfg.skip] = False
            te.append(tr.q[okq, :2] + bias[:2] - r.obs[okq, :2])
        p = np.concatenate(pe) if pe else np.zeros((0, 2))
        t = np.concatenate(te) if te else np.zeros((0, 2))
        failed = any(tr.failed for tr in traces)
        return ModelScore(
            hypothesis=hyp,
            loglik=-math.inf
            if failed
            else float(sum(tr.loglik_from(self.cfg.skip) for tr in traces)),
            n_obs=int(sum(np.sum(np.isfinite(tr.ll[self.cfg.skip :])) for tr in traces)),
            pred_rmse=float(np.sqrt(np.mean(np.sum(p**2, -1)))) if p.size else math.nan,
            track_rmse=float(np.sqrt(np.mean(np.sum(t**2, -1)))) if t.size else math.nan,
            traces=traces,
        )

    def noise(self, hyp: Hypothesis, runs: Sequence[Run], seeds: Sequence[int]) -> float:
        """Std (nats) of the score of `hyp` on `runs` across filter seeds (Monte-Carlo
        noise of the score; includes the configured seed)."""
        vals = [self.score(hyp, runs, s).loglik for s in (self.cfg.seed, *seeds)]
        fin = [v for v in vals if math.isfinite(v)]
        return float(np.std(fin, ddof=1)) if len(fin) >= 2 else math.inf

    # ------------------------------------------------------------------------- one pass
    def _run(self, hyp: Hypothesis, run: Run, seed: int) -> RunTrace:
        sc, exts, bias, delay = hyp.filter_setup(run.scenario)
        nq = sc.nq
        n = run.t.shape[0]
        over = {**SCORE_OVERRIDES.get(sc.kind, {}), **dict(self.cfg.filter_overrides)}
        cfg = FilterConfig.preset(sc.kind, particles=self.cfg.particles, **over)
        filt = DbcSlamFilter(sc, cfg, np.random.default_rng(seed), exts)
        shift = delay / float(sc.dt)
        u = _delayed(run.u, shift)
        env = _delayed(run.env, shift)
        obs = np.array(run.obs, dtype=np.float64) - bias[None, :nq]
        ll = np.full(n, np.nan)
        q = np.full((n, nq), np.nan)
        v = np.full((n, nq), np.nan)
        mu_mean = np.full((n, len(sc.friction.pairs)), np.nan)
        fin = np.nonzero(np.all(np.isfinite(obs), axis=-1))[0]
        failed = fin.size == 0
        if not failed:
            k0 = int(fin[0])
            std0 = np.full(nq, sc.noise.position)
            if nq == 3:
                std0[2] = sc.noise.yaw
            filt.initialize(obs[k0], std0, joints=env[k0])
            q[k0] = obs[k0]
            v[k0] = 0.0
            cands = [np.asarray(c, dtype=np.float64) for c in sc.friction.candidates]
            mu_mean[k0] = [float(np.mean(c)) for c in cands]
            for k in range(k0 + 1, n):
                o = obs[k]
                ob = PoseObservation(*(float(x) for x in o)) if np.all(np.isfinite(o)) else None
                inp = FilterInput(
                    wrench=tuple(float(x) for x in u[k - 1]),
                    joints=tuple(float(x) for x in env[k]),
                )
                try:
                    est = filt.step(ob, inp)
                except DbcSlamError:
                    failed = True
                    break
                ll[k] = est.log_likelihood
                q[k] = est.pose[:nq]
                v[k] = est.twist[:nq]
                mu_mean[k] = [float(est.friction[p, : c.size] @ c) for p, c in enumerate(cands)]
        pred = self._predict(sc, exts, run, u, env, q, v, mu_mean) + bias[None, :2]
        return RunTrace(ll=ll, q=q, v=v, pred=pred, failed=failed)

    @staticmethod
    def _predict(  # noqa: PLR0917
        sc: Scenario,
        exts: tuple[ModelExtension, ...],
        run: Run,
        u: F64,
        env: F64,
        q: F64,
        v: F64,
        mu_mean: F64,
    ) -> F64:
        """One-step predicted position pred[k] from the posterior mean at k - 1 (nan where
        that is missing)."""
        n = q.shape[0]
        out = np.full((n, 2), np.nan)
        ok = np.all(np.isfinite(q[:-1]), -1) & np.all(np.isfinite(mu_mean[:-1]), -1)
        idx = np.nonzero(ok)[0]
        if idx.size == 0:
            return out
        model = PlanarModel(
            sc,
            exts,
            PGSSolver(max_iter=200),
            support_iterations=2,
            support_tol=1e-7,
        )
        try:
            r = model.step(
                State(q[idx], v[idx]),
                u[idx],
                env[idx],
                env[idx + 1],
                mu_pair=mu_mean[idx],
            )
        except DbcSlamError:
            return out
        out[idx + 1] = r.q[:, :2]
        return out
