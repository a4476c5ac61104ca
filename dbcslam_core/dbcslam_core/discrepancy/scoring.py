"""The score of a model on a set of runs: the DBC-SLAM filter's own evidence.

score(model, runs) = sum over runs and steps of log p(o_k | o_{0:k-1}, inputs, model), the
filter's log predictive likelihood (`Estimate.log_likelihood`). Friction (per region,
friction map), contact modes and the start state are integrated by the filter, never fixed.
Every evaluation uses the same filter seed (common random numbers across candidate models
and parameters); `ScoreConfig.particles` sets the Monte-Carlo noise (measured by
`Scorer.noise`, which re-runs a model with other seeds).

Filter runs are independent and deterministic given (hypothesis, run, seed): `Scorer.prefetch`
computes a batch of them in a pool of `ScoreConfig.workers` processes (one filter run per
task; the results are cached, identical to a serial evaluation).

Besides the evidence, each run yields the one-step prediction of the position (the
contract's prediction RMSE): the model's deterministic step (`PlanarModel.step`, batched
PGS) from the filter's posterior mean state at k - 1 with the posterior mean friction
coefficient per pair, compared with the observed position at k (after `skip` initial steps
in which the filter locks on); and the tracking residual (posterior mean as the sensor would
see it vs the observation).
"""

from __future__ import annotations

import dataclasses
import math
import multiprocessing
import time
from collections.abc import Callable, Iterable, Sequence
from concurrent.futures import Executor, ProcessPoolExecutor, as_completed
from dataclasses import dataclass, field
from types import TracebackType

import numpy as np
from numpy.typing import NDArray

from ..angles import wrap_angle
from ..dynamics import PlanarModel, State
from ..errors import DbcSlamError, ModelError
from ..extensions import ModelExtension
from ..lcp import PGSSolver
from ..observation import PoseObservation, smooth_joint_readings
from ..rbpf import DbcSlamFilter, FilterConfig, FilterInput
from ..scenario import Scenario
from .effects import Hypothesis
from .runs import Run

__all__ = [
    "JOINT_SMOOTHING",
    "SCORE_OVERRIDES",
    "ModelScore",
    "RunTrace",
    "ScoreConfig",
    "Scorer",
    "filter_pass",
    "scoring_joints",
]

F64 = NDArray[np.float64]


@dataclass(frozen=True)
class ScoreConfig:
    """particles / seed of the scoring filter (fixed seed: common random numbers); skip:
    initial steps of each run left out of the score and the RMSEs (the filter runs over
    them: it locks on to the unknown initial velocity there, and a sensor-delay hypothesis
    has no inputs from before the recording; must exceed the largest delay searched,
    0.15 s at dt 0.01); filter_overrides: extra `FilterConfig`
    fields on top of the scenario preset (`SCORE_OVERRIDES` per scenario kind first);
    workers: processes that run batches of filter runs (`Scorer.prefetch`; 1 = in this
    process); two_sided_joints: smooth the recorded joint readings over the whole run
    first (`JOINT_SMOOTHING` per scenario kind) instead of the filter's causal smoother."""

    particles: int = 300
    seed: int = 0
    skip: int = 20
    filter_overrides: tuple[tuple[str, object], ...] = ()
    workers: int = 1
    two_sided_joints: bool = True

    def __post_init__(self) -> None:
        if self.particles < 1 or self.workers < 1 or self.skip < 0:
            msg = (
                f"ScoreConfig needs particles >= 1, workers >= 1, skip >= 0; got "
                f"{self.particles}, {self.workers}, {self.skip}"
            )
            raise ModelError(msg)


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
    "push": {"friction_bank": True, "bank_resampling": "hypothesis"},
}
"""Filter settings of the score per scenario kind, on top of `FilterConfig.preset`. Edge:
half the preset's velocity process noise (0.005 m/s per step, a 0.5 N force noise on 1 kg):
with the preset's 0.01 a hidden damping of 2 N s/m gained only ~90 nats over 10 s (the
noise absorbs it), with 0.005 ~1400-1900 nats; at 0.003 mis-specified models lose track
(scores of -1e4 to -1e5 nats) and the score surface becomes a cliff (measured on
`synthetic.edge_sweep_trajectory`, 200 particles, 3 seeds).

Push: the friction bank with `hypothesis` resampling, one fixed-friction sub-filter per
joint (pusher, support) coefficient hypothesis, so the evidence is the exact mixture
sum_b prior(b) Z(b) over the candidates (`FilterConfig.friction_bank`). The single-copy
filter's per-particle friction beliefs turn one-hot and resampling spreads a label: on the
benchmark's clean push draw 18 (support mu 0.1, a candidate) it lost ~68 nats against
knowing the coefficient (held-out run, 150 particles, seeds 0-2: 8097 / 8034 / 8100 against
8151 / 8168 / 8164), where an exact mixture over three equally likely candidates loses at
most ln 3, and the analysis named support_friction 0.12 (+73.8 nats held out). With the
bank: 8161 / 8160 / 8168, support_friction 0.12 gains +6 / +11 nats (training / held out,
was +207 / +106 at seeds 0-1). Cost: ~2x the CPU of a filter run (nine copies per particle
with three candidates per pair)."""


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


Job = tuple[Hypothesis, Run, int]
"""One filter run: hypothesis, run, seed."""


class Scorer:
    """Runs the filter over runs under hypotheses; caches every (hypothesis, run, seed).

    Use as a context manager when `ScoreConfig.workers` > 1 (the process pool is closed on
    exit; `close` does the same). The pool uses the `forkserver` start method (workers do
    not inherit the caller's threads), so a script that runs it needs the usual
    ``if __name__ == "__main__":`` guard. `evaluations`: filter runs made; `cpu_seconds`: their
    summed CPU time (in whichever process ran them).
    """

    def __init__(
        self, cfg: ScoreConfig | None = None, progress: Callable[[str], None] | None = None
    ) -> None:
        self.cfg = cfg or ScoreConfig()
        self.say = progress or (lambda s: None)
        self._cache: dict[tuple[Hypothesis, int, int], RunTrace] = {}
        # the runs the cache is keyed on (by id): held so that no id is recycled for another
        # run while its traces are cached (a freed run's id can go to the next new one)
        self._runs: dict[int, Run] = {}
        self._pool: Executor | None = None
        self.evaluations = 0
        self.cpu_seconds = 0.0

    def __enter__(self) -> Scorer:
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        self.close()

    def close(self) -> None:
        """Shut the worker pool down (if one was started)."""
        if self._pool is not None:
            self._pool.shutdown(wait=True, cancel_futures=True)
            self._pool = None

    def _key(self, hyp: Hypothesis, run: Run, seed: int | None) -> tuple[Hypothesis, int, int]:
        return (hyp, id(run), self.cfg.seed if seed is None else seed)

    def _store(self, job: Job, tr: RunTrace, cpu: float) -> None:
        hyp, run, s = job
        self._runs[id(run)] = run
        self._cache[self._key(hyp, run, s)] = tr
        self.evaluations += 1
        self.cpu_seconds += cpu
        self.say(
            f"    filter run {self.evaluations}: {hyp.label()} on {run.name} (seed {s}): "
            f"{tr.loglik_from(self.cfg.skip):.1f} nats ({cpu:.1f} s CPU)"
        )

    def trace(self, hyp: Hypothesis, run: Run, seed: int | None = None) -> RunTrace:
        """The filter pass of `hyp` over `run` (cached)."""
        key = self._key(hyp, run, seed)
        if key not in self._cache:
            job = (hyp, run, key[2])
            tr, cpu = _timed_run(self.cfg, *job)
            self._store(job, tr, cpu)
        return self._cache[key]

    def prefetch(self, jobs: Iterable[tuple[Hypothesis, Sequence[Run], int | None]]) -> None:
        """Compute the filter runs of all (hypothesis, runs, seed) not cached yet, in the
        worker pool when `workers` > 1 (then `score` / `trace` find them cached)."""
        todo: dict[tuple[Hypothesis, int, int], Job] = {}
        for hyp, runs, seed in jobs:
            for r in runs:
                key = self._key(hyp, r, seed)
                if key not in self._cache:
                    todo.setdefault(key, (hyp, r, key[2]))
        if self.cfg.workers <= 1 or len(todo) <= 1:
            for hyp, r, s in todo.values():
                self.trace(hyp, r, s)
            return
        if self._pool is None:
            # forkserver: workers do not inherit the parent's threads (ROS, BLAS)
            ctx = multiprocessing.get_context("forkserver")
            self._pool = ProcessPoolExecutor(self.cfg.workers, mp_context=ctx)
        futs = {self._pool.submit(_timed_run, self.cfg, *job): job for job in todo.values()}
        for fut in as_completed(futs):
            tr, cpu = fut.result()
            self._store(futs[fut], tr, cpu)

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
        all_seeds = (self.cfg.seed, *seeds)
        self.prefetch((hyp, runs, s) for s in all_seeds)
        vals = [self.score(hyp, runs, s).loglik for s in all_seeds]
        fin = [v for v in vals if math.isfinite(v)]
        return float(np.std(fin, ddof=1)) if len(fin) >= 2 else math.inf


def _timed_run(cfg: ScoreConfig, hyp: Hypothesis, run: Run, seed: int) -> tuple[RunTrace, float]:
    """One filter pass and its CPU time (s) in the process that ran it (pool task)."""
    t0 = time.process_time()
    tr = filter_pass(cfg, hyp, run, seed)
    return tr, time.process_time() - t0


JOINT_SMOOTHING: dict[str, float] = {"push": 1.0}
"""Scenario kind -> white acceleration std (m/s^2) of the two-sided smoother the score
applies to a run's joint readings (`observation.smooth_joint_readings`); the filter then
takes the smoothed positions as exact (joint noise 0). The analysis scores recorded runs,
so it may use the readings after each step. The filter's causal `JointSmoother` lags behind
the pusher's starts and stops, and on clean push data a model whose support friction stops
the block sooner made up for that lag: the benchmark's clean push draws 16 and 21 named
friction_scale 2.0 / 2.25. Measured on clean `science.push_draw`s, filter with the true
pusher and support coefficients against twice the support coefficient (training /
held-out run, 150 particles, mean of filter seeds 0 and 1): draw 16 (mu 0.4 / 0.25) causal
8032 / 8004 vs 8041 / 8057 nats (twice leads by +10 / +53), two-sided 8125 / 8170 vs
8125 / 8180 (+0 / +11); draw 24 (mu 0.25 / 0.1) causal 7887 / 7937 vs 8054 / 8086 (+168 /
+149), two-sided 8156 / 8160 vs 8080 / 8026 (-76 / -134). With noise-free pusher positions
draw 16's lead was +17 held-out: the lag, not the model, made most of it. Acceleration std
1.0 scored above 2.0 and 3.0 on draws 16, 21, 24 (0.17-0.19 mm rms pusher error against
0.5 mm raw). Gripper and edge keep the causal smoother (not measured there)."""


def scoring_joints(sc: Scenario, env: F64, cfg: ScoreConfig) -> tuple[Scenario, F64]:
    """(scenario, joint readings) the scoring filter runs on: `JOINT_SMOOTHING`'s two-sided
    smoothing of `env` (T, E) (m) with the scenario's joint noise set to 0, or both as
    given (kind not in the table, no joint noise, or `two_sided_joints` off)."""
    accel = JOINT_SMOOTHING.get(sc.kind)
    if not cfg.two_sided_joints or accel is None or sc.noise.joint <= 0.0 or env.shape[1] == 0:
        return sc, env
    smooth = smooth_joint_readings(env, float(sc.dt), float(sc.noise.joint), accel)
    exact = dataclasses.replace(sc, noise=dataclasses.replace(sc.noise, joint=0.0))
    return exact, smooth


# ----------------------------------------------------------------------------- one pass
def filter_pass(cfg: ScoreConfig, hyp: Hypothesis, run: Run, seed: int) -> RunTrace:
    """The scoring filter over `run` under `hyp` with filter seed `seed` (module docstring)."""
    sc, exts, bias, delay = hyp.filter_setup(run.scenario)
    sc, env_read = scoring_joints(sc, np.asarray(run.env, dtype=np.float64), cfg)
    nq = sc.nq
    n = run.t.shape[0]
    over = {**SCORE_OVERRIDES.get(sc.kind, {}), **dict(cfg.filter_overrides)}
    fcfg = FilterConfig.preset(sc.kind, particles=cfg.particles, **over)
    filt = DbcSlamFilter(sc, fcfg, np.random.default_rng(seed), exts)
    shift = delay / float(sc.dt)
    u = _delayed(run.u, shift)
    env = _delayed(env_read, shift)
    obs = np.array(run.obs, dtype=np.float64) - bias[None, :nq]
    if nq == 3:
        # a yaw bias moves readings near +-pi across the wrap: back into [-pi, pi)
        obs[:, 2] = wrap_angle(obs[:, 2])
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
    pred = _predict(sc, exts, run, u, env, q, v, mu_mean) + bias[None, :2]
    return RunTrace(ll=ll, q=q, v=v, pred=pred, failed=failed)


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
