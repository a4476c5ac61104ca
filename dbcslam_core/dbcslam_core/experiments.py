"""The paper's experiments (Sec. IV): edge (table polishing) and parallel-jaw gripper.

For each scenario and seed: synthesize a ground-truth trajectory with noisy observations
(:mod:`dbcslam_core.synthetic`), run DBC-SLAM over it (and, on the edge, the fixed-friction
baseline frozen to each candidate), collect the per-step estimates into a :class:`RunTrace`
and score it with :mod:`dbcslam_core.metrics`. Results are plain records; plotting and file
output live in ``dbcslam_research.experiments`` / ``dbcslam_ros.offline.plotting``.

Timing convention of a run: the filter is initialised around the first observation (step 0,
position std = observation noise) with the joint positions of step 0; filter step k = 1..T-1
gets observation k, the wrench u[k-1] (acting over [t_{k-1}, t_k)) and the joints at t_k, and
its estimate is compared with the truth at t_k. Step 0 is not scored.

Targets (issue 3) are in :data:`TARGETS` (built with :func:`edge_targets` and
:func:`rmse_target`, which other target sets reuse); :func:`evaluate_targets` checks the
medians over seeds produced by :func:`summarize`. :func:`run_experiments` runs the
(scenario, seed, method) tasks of :func:`experiment_tasks` through :func:`run_task` on
``ExperimentConfig.workers`` processes with :func:`run_parallel` (generic: any picklable
zero-argument jobs); every run draws from its own seeded generators, so the results do not
depend on the number of workers (the step times do).
"""

from __future__ import annotations

import concurrent.futures as cf
import math
import multiprocessing
import os
import time
from collections.abc import Callable, Hashable, Mapping, Sequence
from dataclasses import dataclass, field
from functools import partial
from typing import Any, Generic, Protocol, TypeVar

import numpy as np
from numpy.typing import NDArray

from .baselines import BlackBoxNCPFilter, NCPFilterConfig, fixed_friction_filter
from .contact_modes import Mode
from .errors import ModelError
from .geometry import contact_kinematics
from .metrics import (
    contact_accuracy,
    contact_mode_accuracy,
    final_true_friction_posterior,
    friction_map_accuracy,
    position_rmse,
    slid_cells,
    stick_slide_accuracy,
    yaw_rmse,
)
from .observation import PoseObservation
from .parameters import FrictionMapView
from .rbpf import DbcSlamFilter, FilterConfig, FilterInput
from .scenario import Scenario
from .synthetic import EDGE_ROUGH, Trajectory, edge_mu_field, edge_trajectory, gripper_trajectory

__all__ = [
    "DBCSLAM",
    "SCENARIOS",
    "TARGETS",
    "ExperimentConfig",
    "ExperimentResults",
    "FilterLike",
    "RunRecord",
    "RunTrace",
    "Target",
    "TargetCheck",
    "black_box_config",
    "edge_targets",
    "evaluate_targets",
    "experiment_tasks",
    "fixed_method_name",
    "make_trajectory",
    "representative_seed",
    "rmse_target",
    "run_black_box",
    "run_dbcslam",
    "run_experiments",
    "run_filter",
    "run_fixed_friction",
    "run_parallel",
    "run_task",
    "score",
    "summarize",
]

F64 = NDArray[np.float64]
I64 = NDArray[np.int64]

SCENARIOS: tuple[str, ...] = ("edge", "gripper")
DBCSLAM = "dbcslam"
"""Method label of DBC-SLAM runs (the fixed-friction baseline: :func:`fixed_method_name`)."""

K = TypeVar("K", bound=Hashable)
R = TypeVar("R")


class _EstimateLike(Protocol):
    @property
    def pose(self) -> F64: ...

    @property
    def modes(self) -> F64: ...

    @property
    def friction(self) -> F64: ...

    @property
    def live_hypotheses(self) -> float: ...


class FilterLike(Protocol):
    """What :func:`run_filter` drives: DbcSlamFilter, BlackBoxNCPFilter."""

    def initialize(
        self,
        q_mean: Any,
        q_std: Any,
        v_mean: Any = None,
        v_std: Any = None,
        joints: Any = None,
    ) -> None:
        """Draw the initial particles."""
        ...

    def step(self, observation: PoseObservation | None, inputs: FilterInput) -> Any:
        """One filter step; returns an Estimate-like object."""
        ...


@dataclass(frozen=True)
class RunTrace:
    """Per-step record of one filter run over one trajectory (steps 1..T-1, see module doc).

    t (T',) s; true_q, obs_q, est_q (T', nq) (m, m[, rad]); est_modes (T', C, 4);
    true_modes (T', C) `Mode` codes; true_s (T', C) true contact coordinate along the
    obstacle tangent (m); friction_post (T', K) posterior of friction pair 0; true_mu (T', C)
    true friction per contact; candidates (K,) of pair 0; true_friction_index: index of the
    true (time-invariant) coefficient of pair 0, -1 if it varies (edge); live_hypotheses (T',)
    mean live joint hypotheses per particle; step_time (T',) wall time per step (s);
    map_edges (N + 1,) / map_post (N, K) / map_weight (N,): final friction map of pair 0
    (posterior NaN in never-touched cells; weight = accumulated contact evidence; None if the
    method has no map); rough_intervals: high-friction spans along the edge (m); edge_y:
    the edge line (m); baseline_q / baseline_label: optional estimate of a baseline drawn
    next to this run in the figures; log_likelihood (T',) the filter's log p(o_k | o_<k)
    per step (nats; its sum is the run's log marginal likelihood, the evidence for the
    filter's model).
    """

    scenario: str
    seed: int
    method: str
    particles: int
    t: F64
    true_q: F64
    obs_q: F64
    est_q: F64
    est_modes: F64
    true_modes: I64
    true_s: F64
    friction_post: F64
    true_mu: F64
    candidates: tuple[float, ...]
    true_friction_index: int
    live_hypotheses: F64 | None
    step_time: F64
    noise_position: float
    noise_yaw: float
    map_edges: F64 | None = None
    map_post: F64 | None = None
    map_weight: F64 | None = None
    rough_intervals: tuple[tuple[float, float], ...] = ()
    edge_y: float | None = None
    n_joint_modes: int | None = None
    baseline_q: F64 | None = None
    baseline_label: str = "fixed-friction baseline"
    log_likelihood: F64 | None = None


@dataclass(frozen=True)
class RunRecord:
    """Scores of one run: scenario, seed, method, particles and metric name -> value."""

    scenario: str
    seed: int
    method: str
    particles: int
    metrics: dict[str, float]

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready dict."""
        return {
            "scenario": self.scenario,
            "seed": self.seed,
            "method": self.method,
            "particles": self.particles,
            "metrics": dict(self.metrics),
        }


@dataclass(frozen=True)
class ExperimentConfig:
    """What :func:`run_experiments` runs.

    seeds: trajectory / filter seeds; particles: DBC-SLAM (and baseline) particle count;
    scenarios: subset of ``SCENARIOS``; n_steps: truncate trajectories to this many samples
    (None = the full paper trajectories; for smoke tests); fixed_friction: also run the
    fixed-friction baseline on the edge, frozen to each candidate; filter_overrides: extra
    ``FilterConfig`` fields per scenario kind (on top of ``FilterConfig.preset``); workers:
    parallel processes (:func:`run_parallel`; the results do not depend on it, the step
    times do).
    """

    seeds: tuple[int, ...] = (0, 1, 2, 3, 4)
    particles: int = 500
    scenarios: tuple[str, ...] = SCENARIOS
    n_steps: int | None = None
    fixed_friction: bool = True
    filter_overrides: Mapping[str, Mapping[str, Any]] = field(default_factory=dict)
    workers: int = 1

    def __post_init__(self) -> None:
        bad = [s for s in self.scenarios if s not in SCENARIOS]
        if bad:
            msg = f"unknown scenarios {bad}; valid scenarios are {list(SCENARIOS)}"
            raise ModelError(msg)
        if self.particles < 1:
            msg = f"particles must be >= 1, got {self.particles}"
            raise ModelError(msg)
        if self.n_steps is not None and self.n_steps < 3:
            msg = f"n_steps must be >= 3 (or None for full trajectories), got {self.n_steps}"
            raise ModelError(msg)
        if not self.seeds:
            msg = "seeds must not be empty"
            raise ModelError(msg)
        if self.workers < 1:
            msg = f"workers must be >= 1, got {self.workers}"
            raise ModelError(msg)


ConfigT = TypeVar("ConfigT")


@dataclass
class ExperimentResults(Generic[ConfigT]):
    """All records plus the traces (key: (scenario, seed, method)) of a run configured by
    `config` (an `ExperimentConfig` here; the pybullet experiments use their own)."""

    config: ConfigT
    records: list[RunRecord] = field(default_factory=list)
    traces: dict[tuple[str, int, str], RunTrace] = field(default_factory=dict)

    def representative_seed(self, scenario: str, metric: str = "position_rmse") -> int:
        """The seed whose DBC-SLAM `metric` is the median over seeds (lower median)."""
        return representative_seed(self.records, scenario, metric)


def representative_seed(
    records: Sequence[RunRecord],
    scenario: str,
    metric: str = "position_rmse",
    method: str = DBCSLAM,
) -> int:
    """The seed whose `method` `metric` is the (lower) median over the seeds of `scenario`."""
    recs = [r for r in records if r.scenario == scenario and r.method == method]
    if not recs:
        msg = f"no {method!r} records for scenario {scenario!r}"
        raise ModelError(msg)
    recs.sort(key=lambda r: r.metrics[metric])
    return recs[(len(recs) - 1) // 2].seed


# --------------------------------------------------------------------------- running
def _truncate(tr: Trajectory, n: int | None) -> Trajectory:
    if n is None or n >= tr.n_steps:
        return tr
    return Trajectory(
        tr.scenario,
        tr.t[:n],
        tr.q[:n],
        tr.v[:n],
        tr.u[:n],
        tr.env[:n],
        tr.modes[:n],
        tr.ln[:n],
        tr.lt[:n],
        tr.mu[:n],
        tr.mu_pair,
        tr.obs[:n],
        tr.env_obs[:n],
    )


def make_trajectory(scenario: str, seed: int, n_steps: int | None = None) -> Trajectory:
    """The paper trajectory of `scenario` (``edge`` | ``gripper``) for `seed`."""
    if scenario == "edge":
        tr = edge_trajectory(seed)
    elif scenario == "gripper":
        tr = gripper_trajectory(seed)
    else:
        msg = f"unknown scenario {scenario!r}; valid scenarios are {list(SCENARIOS)}"
        raise ModelError(msg)
    return _truncate(tr, n_steps)


def _observation(tr: Trajectory, k: int) -> PoseObservation:
    o = tr.obs[k]
    if tr.scenario.nq == 3:
        return PoseObservation(float(o[0]), float(o[1]), float(o[2]))
    return PoseObservation(float(o[0]), float(o[1]))


def _nearest_index(values: F64, candidates: Sequence[float]) -> I64:
    c = np.asarray(candidates, dtype=np.float64)
    return np.asarray(np.argmin(np.abs(values[..., None] - c), axis=-1), dtype=np.int64)


def run_filter(
    filt: FilterLike,
    tr: Trajectory,
    *,
    method: str,
    seed: int,
    particles: int,
    progress: Callable[[int, int], None] | None = None,
) -> RunTrace:
    """Drive `filt` over trajectory `tr` (module-doc timing) and record a :class:`RunTrace`."""
    sc = tr.scenario
    _initialize(filt, tr)
    run = _drive(filt, tr, progress)
    kin = contact_kinematics(sc, tr.q[1:], tr.env[1:])
    cands = tuple(float(c) for c in sc.friction.candidates[0])
    map_edges, map_post, map_weight = _final_friction_map(run.last)
    return RunTrace(
        scenario=sc.kind,
        seed=seed,
        method=method,
        particles=particles,
        t=tr.t[1:],
        true_q=tr.q[1:],
        obs_q=tr.obs[1:],
        est_q=run.est_q,
        est_modes=run.est_modes,
        true_modes=tr.modes[1:],
        true_s=np.asarray(kin.s, dtype=np.float64),
        friction_post=run.friction,
        true_mu=tr.mu[1:],
        candidates=cands,
        true_friction_index=_true_friction_index(tr, cands),
        live_hypotheses=run.live,
        step_time=run.step_time,
        log_likelihood=run.log_likelihood,
        noise_position=sc.noise.position,
        noise_yaw=sc.noise.yaw,
        map_edges=map_edges,
        map_post=map_post,
        map_weight=map_weight,
        rough_intervals=(EDGE_ROUGH,) if sc.kind == "edge" else (),
        edge_y=sc.edge_y if sc.kind == "edge" else None,
        n_joint_modes=int(len(Mode) ** sc.n_contacts) if sc.kind == "gripper" else None,
    )


@dataclass(frozen=True)
class _Driven:
    """Per step k = 1..n-1 of a run: the estimate's pose, mode probabilities, friction
    posterior of the first pair, live hypotheses, step wall time (s) and log predictive
    likelihood (nats); the last estimate."""

    est_q: F64
    est_modes: F64
    friction: F64
    live: F64
    step_time: F64
    log_likelihood: F64
    last: Any


def _initialize(filt: FilterLike, tr: Trajectory) -> None:
    """Initialise `filt` at the first observation with the scenario's noise as spread."""
    sc = tr.scenario
    std0 = np.full(sc.nq, sc.noise.position)
    if sc.nq == 3:
        std0[2] = sc.noise.yaw
    filt.initialize(tr.obs[0], std0, joints=tr.env_obs[0])


def _drive(
    filt: FilterLike, tr: Trajectory, progress: Callable[[int, int], None] | None
) -> _Driven:
    """Step `filt` through samples 1..n-1 of `tr`, timing each ``step`` call alone."""
    sc = tr.scenario
    nq = sc.nq
    n = tr.n_steps
    est_q = np.zeros((n - 1, nq))
    est_modes = np.zeros((n - 1, sc.n_contacts, len(Mode)))
    fric = np.zeros((n - 1, len(sc.friction.candidates[0])))
    live = np.zeros(n - 1)
    times = np.zeros(n - 1)
    log_lik = np.zeros(n - 1)
    last: Any = None
    for k in range(1, n):
        inp = FilterInput(
            wrench=tuple(float(x) for x in tr.u[k - 1]),
            joints=tuple(float(x) for x in tr.env_obs[k]),
        )
        obs = _observation(tr, k)
        t0 = time.perf_counter()
        est = filt.step(obs, inp)
        times[k - 1] = time.perf_counter() - t0
        est_q[k - 1] = est.pose[:nq]
        est_modes[k - 1] = est.modes
        fric[k - 1] = est.friction[0, : fric.shape[1]]
        live[k - 1] = est.live_hypotheses
        log_lik[k - 1] = est.log_likelihood
        last = est
        if progress is not None:
            progress(k, n - 1)
    return _Driven(est_q, est_modes, fric, live, times, log_lik, last)


def _true_friction_index(tr: Trajectory, cands: Sequence[float]) -> int:
    """Index of the candidate nearest the true coefficient of the first pair (-1: unknown)."""
    mu_pair = np.asarray(tr.mu_pair, dtype=np.float64)
    if mu_pair.size and np.all(np.isfinite(mu_pair)):
        return int(_nearest_index(mu_pair[:1], cands)[0])
    return -1


def _final_friction_map(last: Any) -> tuple[F64 | None, F64 | None, F64 | None]:
    """Cell edges (m), P(candidate 0) per cell (NaN where never touched) and cell weights
    of the first pair's friction map in the last estimate; all None without a map."""
    fmap = getattr(last, "friction_map", None)
    if not isinstance(fmap, FrictionMapView):
        return None, None, None
    edges = np.asarray(fmap.s_min + np.arange(fmap.n_cells + 1) * fmap.cell_size, dtype=np.float64)
    post = np.asarray(fmap.probs[0], dtype=np.float64).copy()
    post[~fmap.touched(0)] = np.nan
    return edges, post, np.asarray(fmap.weight[0], dtype=np.float64)


def _filter_config(kind: str, particles: int, overrides: Mapping[str, Any]) -> FilterConfig:
    return FilterConfig.preset(kind, particles=particles, **dict(overrides))


def run_dbcslam(
    tr: Trajectory,
    *,
    seed: int,
    particles: int = 500,
    overrides: Mapping[str, Any] | None = None,
    progress: Callable[[int, int], None] | None = None,
) -> RunTrace:
    """DBC-SLAM (``FilterConfig.preset`` of the scenario kind) over `tr`."""
    cfg = _filter_config(tr.scenario.kind, particles, overrides or {})
    filt = DbcSlamFilter(tr.scenario, cfg, np.random.default_rng([seed, 1]))
    return run_filter(filt, tr, method=DBCSLAM, seed=seed, particles=particles, progress=progress)


def fixed_method_name(mu: float) -> str:
    """Method label of the fixed-friction baseline frozen to `mu`."""
    return f"fixed_mu_{mu:g}"


def run_fixed_friction(
    tr: Trajectory,
    candidate: int,
    *,
    seed: int,
    particles: int = 500,
    overrides: Mapping[str, Any] | None = None,
    progress: Callable[[int, int], None] | None = None,
) -> RunTrace:
    """The fixed-friction baseline (DBC-SLAM frozen to candidate index `candidate`)."""
    cfg = _filter_config(tr.scenario.kind, particles, overrides or {})
    filt = fixed_friction_filter(tr.scenario, candidate, cfg, np.random.default_rng([seed, 2]))
    mu = float(tr.scenario.friction.candidates[0][candidate])
    return run_filter(
        filt,
        tr,
        method=fixed_method_name(mu),
        seed=seed,
        particles=particles,
        progress=progress,
    )


def black_box_config(
    scenario: Scenario, *, particles: int, solver: str = "pgs", active_set: bool = False
) -> NCPFilterConfig:
    """The black-box filter's configuration of `run_black_box`: its own tuned velocity
    process noise (``NCPFilterConfig.default_noise``) and the position noise (m, m[, rad]),
    initial velocity spread and warm-up of the DBC-SLAM preset of the scenario's kind."""
    base = FilterConfig.preset(scenario.kind)
    return NCPFilterConfig(
        particles=particles,
        solver=solver,
        position_noise=tuple(base.position_noise[: scenario.nq]),
        init_velocity_std=base.init_velocity_std,
        warmup_steps=base.warmup_steps,
        warmup_boost=base.warmup_boost,
        active_set=active_set,
    )


def run_black_box(
    tr: Trajectory,
    *,
    seed: int,
    particles: int = 500,
    solver: str = "pgs",
    active_set: bool = False,
    config: NCPFilterConfig | None = None,
    progress: Callable[[int, int], None] | None = None,
) -> RunTrace:
    """The black-box NCP particle filter over `tr` (solver ``lemke`` or ``pgs``).

    Unless `config` is given it uses its own tuned velocity process noise
    (``NCPFilterConfig.default_noise``) and the position noise, initial velocity spread and
    warm-up of the DBC-SLAM preset; active_set: Lemke over the contacts that can close only
    (method ``blackbox_lemke_as``).
    """
    if config is None:
        config = black_box_config(
            tr.scenario, particles=particles, solver=solver, active_set=active_set
        )
    filt = BlackBoxNCPFilter(tr.scenario, config, np.random.default_rng([seed, 3]))
    return run_filter(
        filt,
        tr,
        method=f"blackbox_{config.solver}" + ("_as" if config.active_set else ""),
        seed=seed,
        particles=config.particles,
        progress=progress,
    )


# --------------------------------------------------------------------------- scoring
def _map_truth(trace: RunTrace) -> tuple[I64, NDArray[np.bool_]]:
    """True candidate index per map cell and which cells have constant true friction."""
    assert trace.map_edges is not None
    edges = trace.map_edges
    field_fn = edge_mu_field()
    fr = np.linspace(0.0, 1.0, 9)
    pts = edges[:-1, None] + fr[None, :] * np.diff(edges)[:, None]
    mus = field_fn(pts)
    pure = np.all(mus == mus[:, :1], axis=1)
    return _nearest_index(mus[:, 4], trace.candidates), pure


def score(trace: RunTrace) -> dict[str, float]:
    """Metrics of one run (names are the keys of the experiment table).

    Common: position_rmse (per-axis RMS, m), position_rmse_ratio (/ position noise std),
    obs_position_rmse (of the raw observations, m), contact_accuracy, contact_mode_accuracy
    (argmax of 4 modes over all (step, contact) entries), contact_mode_accuracy_in_contact,
    live_hypotheses (mean per particle), step_time_ms (median).
    Edge: stick_slide_accuracy, friction_map_accuracy (slid cells whose true coefficient is
    constant over the cell), true_friction_posterior_mean (mean posterior of the true local
    coefficient over in-contact steps). Gripper: yaw_rmse (rad), yaw_rmse_ratio,
    final_true_friction_posterior and final_friction_argmax (the candidate of the first pair
    with the largest final posterior: the coefficient the run ends on).
    """
    m: dict[str, float] = {}
    pos = position_rmse(trace.est_q[:, :2], trace.true_q[:, :2])
    m["position_rmse"] = pos
    m["position_rmse_ratio"] = pos / trace.noise_position
    m["obs_position_rmse"] = position_rmse(trace.obs_q[:, :2], trace.true_q[:, :2])
    m["contact_accuracy"] = contact_accuracy(trace.est_modes, trace.true_modes)
    m["contact_mode_accuracy"] = contact_mode_accuracy(trace.est_modes, trace.true_modes)
    in_contact = trace.true_modes != Mode.SEPARATED
    m["contact_mode_accuracy_in_contact"] = contact_mode_accuracy(
        trace.est_modes, trace.true_modes, mask=in_contact, empty=math.nan
    )
    m["stick_slide_accuracy"] = stick_slide_accuracy(
        trace.est_modes, trace.true_modes, empty=math.nan
    )
    if trace.live_hypotheses is not None:
        m["live_hypotheses"] = float(np.mean(trace.live_hypotheses))
    m["step_time_ms"] = float(np.median(trace.step_time) * 1e3)
    if trace.true_q.shape[1] == 3:
        yaw = yaw_rmse(trace.est_q[:, 2], trace.true_q[:, 2])
        m["yaw_rmse"] = yaw
        m["yaw_rmse_ratio"] = yaw / trace.noise_yaw
    if trace.true_friction_index >= 0:
        m["final_true_friction_posterior"] = final_true_friction_posterior(
            trace.friction_post, trace.true_friction_index
        )
        m["final_friction_argmax"] = float(
            trace.candidates[int(np.argmax(trace.friction_post[-1]))]
        )
    if trace.scenario == "edge":
        ti = _nearest_index(trace.true_mu[:, 0], trace.candidates)
        touching = in_contact[:, 0]
        if np.any(touching):
            p_true = trace.friction_post[np.arange(ti.size), ti]
            m["true_friction_posterior_mean"] = float(np.mean(p_true[touching]))
        if trace.map_edges is not None and trace.map_post is not None:
            true_cell, pure = _map_truth(trace)
            slid = slid_cells(trace.true_s[:, 0], trace.true_modes[:, 0], trace.map_edges)
            m["friction_map_accuracy"] = friction_map_accuracy(
                trace.map_post, true_cell, slid & pure, empty=math.nan
            )
            m["friction_map_cells"] = float(np.sum(slid & pure))
    return m


# --------------------------------------------------------------------------- the driver
def _single_threaded_blas() -> None:
    for var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
        os.environ.setdefault(var, "1")


def run_parallel(
    jobs: Sequence[tuple[K, Callable[[], R]]],
    *,
    workers: int = 1,
    on_done: Callable[[K, R], None] | None = None,
) -> dict[K, R]:
    """Run `jobs` ((key, zero-argument callable) pairs) on `workers` processes.

    workers == 1 runs them in order in this process; otherwise a spawn-context process pool
    (BLAS limited to one thread per worker) runs them and the callables must be picklable
    (``functools.partial`` of a module-level function). `on_done(key, result)` is called in
    this process as each job finishes (completion order). Returns {key: result} in job order;
    the first exception of a job is re-raised.
    """
    if workers < 1:
        msg = f"workers must be >= 1, got {workers}"
        raise ModelError(msg)
    done: dict[K, R] = {}
    if workers == 1 or len(jobs) <= 1:
        for key, fn in jobs:
            done[key] = fn()
            if on_done is not None:
                on_done(key, done[key])
        return done
    ctx = multiprocessing.get_context("spawn")
    with cf.ProcessPoolExecutor(
        min(workers, len(jobs)), mp_context=ctx, initializer=_single_threaded_blas
    ) as ex:
        futs = {ex.submit(fn): key for key, fn in jobs}
        for fut in cf.as_completed(futs):
            key = futs[fut]
            done[key] = fut.result()
            if on_done is not None:
                on_done(key, done[key])
    return {key: done[key] for key, _ in jobs}


def experiment_tasks(config: ExperimentConfig) -> list[tuple[str, int, str]]:
    """The (scenario, seed, method) runs of `config`; method ``dbcslam`` or ``fixed:<k>``
    (edge fixed-friction baseline frozen to candidate index k)."""
    out: list[tuple[str, int, str]] = []
    for scen in config.scenarios:
        n_cand = len(_paper_candidates(scen))
        for seed in config.seeds:
            out.append((scen, seed, DBCSLAM))
            if scen == "edge" and config.fixed_friction:
                out += [(scen, seed, f"fixed:{k}") for k in range(n_cand)]
    return out


def _paper_candidates(scenario: str) -> tuple[float, ...]:
    """Friction candidates of pair 0 of the paper scenario `scenario` (as synthesized)."""
    from .scenario import edge_scenario, gripper_scenario

    if scenario not in SCENARIOS:
        msg = f"unknown scenario {scenario!r}; valid scenarios are {list(SCENARIOS)}"
        raise ModelError(msg)
    sc = edge_scenario() if scenario == "edge" else gripper_scenario()
    return tuple(float(c) for c in sc.friction.candidates[0])


def run_task(
    scenario: str,
    seed: int,
    method: str,
    *,
    particles: int = 500,
    n_steps: int | None = None,
    overrides: Mapping[str, Any] | None = None,
) -> tuple[RunRecord, RunTrace, float]:
    """Synthesize, filter and score one run; returns (record, trace, wall time s).

    method: ``dbcslam`` or ``fixed:<candidate index>`` (see :func:`experiment_tasks`).
    """
    t0 = time.perf_counter()
    tr = make_trajectory(scenario, seed, n_steps)
    if method == DBCSLAM:
        trace = run_dbcslam(tr, seed=seed, particles=particles, overrides=overrides)
    elif method.startswith("fixed:") and method[6:].isdigit():
        trace = run_fixed_friction(
            tr, int(method[6:]), seed=seed, particles=particles, overrides=overrides
        )
    else:
        msg = f"unknown method {method!r}; valid: {DBCSLAM!r} or 'fixed:<candidate index>'"
        raise ModelError(msg)
    rec = RunRecord(scenario, seed, trace.method, particles, score(trace))
    return rec, trace, time.perf_counter() - t0


def run_experiments(
    config: ExperimentConfig | None = None,
    progress: Callable[[str], None] | None = None,
) -> ExperimentResults[ExperimentConfig]:
    """Run every (scenario, seed, method) of `config` on ``config.workers`` processes;
    `progress` receives one-line messages. Records are in task order."""
    cfg = config if config is not None else ExperimentConfig()
    res: ExperimentResults[ExperimentConfig] = ExperimentResults(cfg)
    say = progress if progress is not None else (lambda _msg: None)
    tasks = experiment_tasks(cfg)
    n_done = 0

    def report(key: tuple[str, int, str], out: tuple[RunRecord, RunTrace, float]) -> None:
        nonlocal n_done
        n_done += 1
        rec, _, wall = out
        m = rec.metrics
        say(
            f"[{n_done:2d}/{len(tasks)}] {key[0]:8s} seed {key[1]} {rec.method:14s} "
            f"{wall:6.1f} s  pos RMSE {m['position_rmse'] * 1e3:7.2f} mm  "
            f"contact {m['contact_accuracy']:.3f}"
        )

    jobs = [
        (
            key,
            partial(
                run_task,
                *key,
                particles=cfg.particles,
                n_steps=cfg.n_steps,
                overrides=cfg.filter_overrides.get(key[0]),
            ),
        )
        for key in tasks
    ]
    done = run_parallel(jobs, workers=cfg.workers, on_done=report)
    for key in tasks:
        rec, trace, _ = done[key]
        res.records.append(rec)
        res.traces[(key[0], key[1], rec.method)] = trace
    return res


def summarize(records: Sequence[RunRecord]) -> dict[str, dict[str, dict[str, float]]]:
    """Median over seeds: {scenario: {method: {metric: median}}} (NaNs ignored)."""
    out: dict[str, dict[str, dict[str, float]]] = {}
    groups: dict[tuple[str, str], list[RunRecord]] = {}
    for r in records:
        groups.setdefault((r.scenario, r.method), []).append(r)
    for (scen, meth), recs in groups.items():
        names = sorted({k for r in recs for k in r.metrics})
        med: dict[str, float] = {}
        for name in names:
            vals = np.array([r.metrics.get(name, math.nan) for r in recs], dtype=np.float64)
            vals = vals[np.isfinite(vals)]
            med[name] = float(np.median(vals)) if vals.size else math.nan
        med["n_seeds"] = float(len(recs))
        out.setdefault(scen, {})[meth] = med
    return out


# --------------------------------------------------------------------------- targets
@dataclass(frozen=True)
class Target:
    """One target: `scenario`, label, how to get the value from the summary, comparison."""

    scenario: str
    label: str
    metric: str
    op: str  # "<=", ">=" or "report"
    threshold: float
    unit: str = ""


@dataclass(frozen=True)
class TargetCheck:
    """A target evaluated on medians: value (NaN if missing), passed (None for report-only)."""

    target: Target
    value: float
    passed: bool | None

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready dict."""
        t = self.target
        return {
            "scenario": t.scenario,
            "target": t.label,
            "metric": t.metric,
            "op": t.op,
            "threshold": t.threshold,
            "value": self.value,
            "passed": self.passed,
        }


def rmse_target(scenario: str, metric: str, ratio: float, subject: str = "") -> Target:
    """``<subject>position|yaw RMSE <= ratio x noise std`` on ``position_rmse_ratio`` or
    ``yaw_rmse_ratio`` (`metric`: ``position`` or ``yaw``)."""
    if metric not in ("position", "yaw"):
        msg = f"metric must be 'position' or 'yaw', got {metric!r}"
        raise ModelError(msg)
    label = f"{subject}{metric} RMSE <= {ratio:g} x noise std"
    return Target(scenario, label, f"{metric}_rmse_ratio", "<=", ratio)


def edge_targets(position_ratio: float = 0.5) -> tuple[Target, ...]:
    """The edge targets shared by the synthetic and the pybullet experiments: position RMSE
    <= `position_ratio` x noise, in-contact >= 95 %, stick/slide >= 90 %, friction map >= 90 %
    of slid cells, fixed-friction RMSE >= 2 x DBC-SLAM (better candidate)."""
    return (
        rmse_target("edge", "position", position_ratio),
        Target(
            "edge", "in-contact classification >= 95% of steps", "contact_accuracy", ">=", 0.95
        ),
        Target(
            "edge", "stick/slide >= 90% of in-contact steps", "stick_slide_accuracy", ">=", 0.90
        ),
        Target(
            "edge",
            "friction map: true mu posterior > 0.5 in >= 90% of slid cells",
            "friction_map_accuracy",
            ">=",
            0.90,
        ),
        Target(
            "edge",
            "fixed-friction RMSE >= 2 x DBC-SLAM (better candidate)",
            "fixed_rmse_ratio_best",
            ">=",
            2.0,
        ),
    )


TARGETS: tuple[Target, ...] = (
    *edge_targets(0.5),
    Target(
        "edge",
        "fixed-friction RMSE / DBC-SLAM (worse candidate)",
        "fixed_rmse_ratio_worst",
        "report",
        math.nan,
    ),
    Target(
        "gripper",
        "P(mu = 0.4) >= 0.95 at the end",
        "final_true_friction_posterior",
        ">=",
        0.95,
    ),
    rmse_target("gripper", "position", 0.5),
    rmse_target("gripper", "yaw", 0.5),
    Target("gripper", "contact-mode accuracy >= 90%", "contact_mode_accuracy", ">=", 0.90),
    Target(
        "gripper",
        "mean live hypotheses per particle (of 4^6 = 4096 joint modes; paper: 512)",
        "live_hypotheses",
        "report",
        math.nan,
    ),
)
"""Issue 3's targets (medians over seeds)."""


def _fixed_ratios(
    records: Sequence[RunRecord],
) -> tuple[float, float]:
    """Medians over seeds of min/max over candidates of fixed RMSE / DBC-SLAM RMSE (edge)."""
    best: list[float] = []
    worst: list[float] = []
    seeds = sorted({r.seed for r in records if r.scenario == "edge"})
    for s in seeds:
        dbc = [r for r in records if (r.scenario, r.seed, r.method) == ("edge", s, DBCSLAM)]
        fixed = [
            r
            for r in records
            if r.scenario == "edge" and r.seed == s and r.method.startswith("fixed_mu_")
        ]
        if not dbc or not fixed:
            continue
        base = dbc[0].metrics["position_rmse"]
        ratios = [r.metrics["position_rmse"] / base for r in fixed]
        best.append(min(ratios))
        worst.append(max(ratios))
    med = (
        float(np.median(best)) if best else math.nan,
        float(np.median(worst)) if worst else math.nan,
    )
    return med


def evaluate_targets(
    records: Sequence[RunRecord], targets: Sequence[Target] = TARGETS
) -> list[TargetCheck]:
    """Check each target on the medians over seeds of the DBC-SLAM records.

    The fixed-friction ratios are per seed (fixed RMSE / DBC-SLAM RMSE, best and worst
    candidate), then the median over seeds. Targets of scenarios without records are skipped.
    """
    summary = summarize(records)
    best, worst = _fixed_ratios(records)
    out: list[TargetCheck] = []
    for t in targets:
        if t.scenario not in summary:
            continue
        if t.metric == "fixed_rmse_ratio_best":
            value = best
        elif t.metric == "fixed_rmse_ratio_worst":
            value = worst
        else:
            value = summary[t.scenario].get(DBCSLAM, {}).get(t.metric, math.nan)
        passed: bool | None
        if t.op == "report":
            passed = None
        elif not math.isfinite(value):
            passed = False
        elif t.op == "<=":
            passed = value <= t.threshold
        else:
            passed = value >= t.threshold
        out.append(TargetCheck(t, value, passed))
    return out
