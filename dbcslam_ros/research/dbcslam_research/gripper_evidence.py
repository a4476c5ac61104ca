"""How much the pybullet grasp says about the jaw friction, and how much of it 40 particles see.

``python -m dbcslam_research.gripper_evidence --out DIR`` measures, on fresh pybullet gripper
runs (`experiments_sim.sim_trajectory`; the simulator's seed changes the sensor noise, the
grasp is the same; ``--sim-set KEY=VALUE`` changes the simulation, e.g. ``jaw_mu=0.7`` the
true coefficient or ``"start=(0.0,0.0,0.2)"`` the grasp):

1. *Impacts within a step* (`impact_residuals`): from every true state (q_k, v_k) of one run
   the core model (`dynamics.PlanarModel`, the filter's contact model) predicts v_{k+1} for
   each friction candidate in one step of dt (the Stewart-Trinkle time-stepping the filter
   runs) and in ``--substeps`` steps of dt / n (pybullet integrates at 1 ms under 10 ms
   samples). The residuals against pybullet's v_{k+1}, in units of the filter's velocity
   process noise, give each candidate a log-likelihood per step: summed over the run, which
   coefficient does each discretisation favour, and at which steps (the impacts).
2. *Evidence and its Monte-Carlo noise* (`evidence_runs`): fixed-friction filters (DBC-SLAM
   frozen to each candidate, the gripper preset without the bank) at each ``--particles``
   count on pybullet runs 0..``--runs``-1 with filter seeds 0..``--filter-seeds``-1: the log
   marginal likelihood log p(o_1:T | mu) of each candidate. Their Bayes average
   (P(mu | o) from the scenario's prior and the estimates) is the friction posterior those
   particles can deliver; the margin log p(o | true) - max over the wrong ones is the data's
   evidence, its spread over filter seeds the estimator's noise.
3. *The data's verdict per run* (`run_verdicts`): at the largest ``--particles`` count, each
   candidate's log-evidence averaged over the filter seeds gives the (near-)exact posterior
   P(mu | o) of each run: the runs where it reaches 0.9 on the true coefficient are the runs
   on which a friction estimator can be both right and calibrated at 0.9; on the others a
   filter that ends at P(true) >= 0.9 is lucky or overconfident.

Writes ``gripper_evidence.md`` and ``gripper_evidence.json`` into ``--out`` and prints the
tables.
"""

from __future__ import annotations

import argparse
import dataclasses
import statistics
import sys
import time
from collections.abc import Callable, Sequence
from functools import lru_cache
from pathlib import Path
from typing import Any

import numpy as np

from dbcslam_core.dynamics import PlanarModel, State
from dbcslam_core.errors import DbcSlamError
from dbcslam_core.experiments import run_fixed_friction
from dbcslam_core.rbpf import FilterConfig
from dbcslam_core.resampling import normalise_log_weights
from dbcslam_core.synthetic import Trajectory
from dbcslam_research.cli import pool_map, settings_dirname
from dbcslam_research.experiments import command_line, progress_printer, utc_now, write_json
from dbcslam_research.experiments_sim import (
    check_sim_overrides,
    parse_sim_overrides,
    sim_trajectory,
)

__all__ = [
    "SimSet",
    "evidence_runs",
    "grasp_run",
    "impact_residuals",
    "main",
    "render_markdown",
    "run_verdicts",
]

DEFAULT_OUT = Path("dbcslam_ros/research/results/gripper_evidence")

SimSet = tuple[tuple[str, Any], ...]
"""Simulator overrides as sorted (key, value) pairs (hashable: runs are cached)."""


@lru_cache(maxsize=64)
def grasp_run(seed: int, duration: float | None = None, sim_set: SimSet = ()) -> Trajectory:
    """Pybullet gripper run `seed` (`duration` s, None = the simulator's default; simulator
    overrides `sim_set`) as a core trajectory; cached per process."""
    tr, _params, _force = sim_trajectory(
        "gripper", seed, duration=duration, overrides=dict(sim_set)
    )
    return tr


def _true_index(tr: Trajectory) -> int:
    cands = np.asarray(tr.scenario.friction.candidates[0])
    return int(np.argmin(np.abs(cands - tr.mu_pair[0])))


def _advance(
    model: PlanarModel, tr: Trajectory, k: int, mu: float, substeps: int
) -> np.ndarray | None:
    """v_{k+1} of `model` (its dt = the sample period / substeps) from the true state k, the
    jaws moving linearly between their samples; None if the LCP solver fails."""
    state = State(tr.q[k], tr.v[k])
    e0, e1 = tr.env[k], tr.env[k + 1]
    try:
        for i in range(substeps):
            a, b = e0 + (e1 - e0) * i / substeps, e0 + (e1 - e0) * (i + 1) / substeps
            r = model.step(state, tr.u[k], a, b, mu_pair=[mu])
            state = State(r.q, r.v)
    except DbcSlamError:
        return None
    return np.asarray(state.v, dtype=np.float64)


def impact_residuals(
    seed: int,
    substeps: int,
    top: int = 4,
    duration: float | None = None,
    sim_set: SimSet = (),
) -> dict[str, Any]:
    """Section 1: per-candidate velocity log-likelihood of pybullet's steps (run `seed`,
    `duration` s, None = the simulator's default; simulator overrides `sim_set`) under the
    one-step and the sub-stepped model (the gripper preset's velocity process noise), summed
    relative to the best candidate over the steps where both models solve for every
    candidate, and the `top` steps where the candidates differ most (nats). Steps where the
    contact LCP has no solution from pybullet's state (the squeezed, jammed grasp) are
    counted, not scored."""
    tr = grasp_run(seed, duration, sim_set)
    sc = tr.scenario
    cands = [float(c) for c in sc.friction.candidates[0]]
    sig = np.asarray(FilterConfig.preset("gripper").process_noise[: sc.nq])
    per_model: dict[int, dict[int, np.ndarray]] = {}
    for n in (1, substeps):
        model = PlanarModel(dataclasses.replace(sc, dt=sc.dt / n))
        lls: dict[int, np.ndarray] = {}
        for k in range(tr.n_steps - 1):
            vs = [_advance(model, tr, k, mu, n) for mu in cands]
            if all(v is not None for v in vs):
                res = [((v - tr.v[k + 1]) / sig) for v in vs if v is not None]
                lls[k] = np.array([-0.5 * float(np.sum(r**2)) for r in res])
        per_model[n] = lls
    common = sorted(set(per_model[1]) & set(per_model[substeps]))
    out: dict[str, Any] = {
        "seed": seed,
        "candidates": cands,
        "true_mu": float(tr.mu_pair[0]),
        "steps": tr.n_steps - 1,
        "scored_steps": len(common),
        "unsolved_steps": {
            str(n): [k for k in range(tr.n_steps - 1) if k not in lls]
            for n, lls in per_model.items()
        },
    }
    for n, lls in per_model.items():
        rel = {k: lls[k] - lls[k].max() for k in common}
        totals = np.sum([rel[k] for k in common], axis=0) if common else np.zeros(len(cands))
        ranked = sorted(common, key=lambda k: -float(np.ptp(rel[k])))
        out[f"substeps_{n}"] = {
            "total": (totals - totals.max()).tolist(),
            "top": [{"step": k, "ll": rel[k].tolist()} for k in ranked[:top]],
        }
    return out


def _evidence_task(args: tuple[int, int, int, SimSet]) -> dict[str, Any]:
    """Log marginal likelihood of every candidate's fixed-friction filter on pybullet run
    `run` (simulator overrides `sim_set`) with filter seed `fseed` and `particles`
    particles."""
    run, fseed, particles, sim_set = args
    tr = grasp_run(run, None, sim_set)
    sc = tr.scenario
    log_ml = []
    for c in range(len(sc.friction.candidates[0])):
        trace = run_fixed_friction(
            tr, c, seed=fseed, particles=particles, overrides={"friction_bank": False}
        )
        assert trace.log_likelihood is not None  # (run_filter records it)
        log_ml.append(float(np.sum(trace.log_likelihood)))
    true = _true_index(tr)
    post, margin = _bayes(sc.friction.prior[0], log_ml, true)
    return {
        "run": run,
        "true": true,
        "filter_seed": fseed,
        "particles": particles,
        "log_ml": log_ml,
        "margin": margin,
        "p_true": float(post[true]),
    }


def _bayes(prior: Sequence[float], log_ml: Sequence[float], true: int) -> tuple[np.ndarray, float]:
    """The candidates' posterior from their `prior` and log-evidence `log_ml` (nats), and
    the margin log p(o | true) - max over the wrong candidates."""
    post, _ = normalise_log_weights(np.log(np.asarray(prior, dtype=np.float64)) + log_ml)
    margin = float(log_ml[true] - max(m for i, m in enumerate(log_ml) if i != true))
    return post, margin


def evidence_runs(
    runs: int,
    filter_seeds: int,
    particles: Sequence[int],
    workers: int,
    say: Callable[[str], None],
    *,
    sim_set: SimSet = (),
) -> list[dict[str, Any]]:
    """Section 2: one row per (particle count, pybullet run, filter seed)."""
    tasks = [
        (r, f, p, sim_set) for p in particles for r in range(runs) for f in range(filter_seeds)
    ]
    return pool_map(_evidence_task, tasks, workers, say, "evidence (filter sets)")


def run_verdicts(
    rows: Sequence[dict[str, Any]], particles: int, prior: Sequence[float]
) -> list[dict[str, Any]]:
    """Section 3: per pybullet run, from the rows of `particles` particles: each candidate's
    log-evidence averaged over the filter seeds (nats), the posterior P(mu | o) it gives
    under `prior` (the scenario's), P(true), the most probable candidate and the margin
    log p(o | true) - max over the wrong ones."""
    by_run: dict[int, list[dict[str, Any]]] = {}
    for r in rows:
        if r["particles"] == particles:
            by_run.setdefault(r["run"], []).append(r)
    out: list[dict[str, Any]] = []
    for run, rs in sorted(by_run.items()):
        ml = np.mean([r["log_ml"] for r in rs], axis=0)
        true = int(rs[0]["true"])
        post, margin = _bayes(prior, ml.tolist(), true)
        out.append(
            {
                "run": run,
                "filter_seeds": len(rs),
                "true": true,
                "posterior": post.tolist(),
                "p_true": float(post[true]),
                "most_probable": int(np.argmax(post)),
                "margin": margin,
            }
        )
    return out


def _within_run_std(rows: Sequence[dict[str, Any]]) -> float:
    """Pooled standard deviation of the margin over filter seeds within each run (nats)."""
    by_run: dict[int, list[float]] = {}
    for r in rows:
        by_run.setdefault(r["run"], []).append(r["margin"])
    dev = [m - statistics.mean(ms) for ms in by_run.values() if len(ms) > 1 for m in ms]
    dof = sum(len(ms) - 1 for ms in by_run.values() if len(ms) > 1)
    return float(np.sqrt(sum(d * d for d in dev) / dof)) if dof else float("nan")


def _spans(steps: Sequence[int]) -> str:
    """'3-5, 9' for [3, 4, 5, 9] ('none' if empty)."""
    spans: list[list[int]] = []
    for k in steps:
        if spans and k == spans[-1][1] + 1:
            spans[-1][1] = k
        else:
            spans.append([k, k])
    return ", ".join(f"{a}-{b}" if b > a else f"{a}" for a, b in spans) or "none"


def render_markdown(result: dict[str, Any], command: str) -> str:
    """The report (sections 1 and 2) as Markdown."""
    cause = result["cause"]
    cands = cause["candidates"]
    n_sub = result["substeps"]
    lines = [
        "# Jaw-friction evidence on pybullet grasps",
        "",
        f"Command: `{command}`  ",
        f"Date: {result['date']}; {result['wall_s']:.0f} s wall; simulator overrides: "
        + (", ".join(f"{k}={v!r}" for k, v in result.get("sim_set", {}).items()) or "none")
        + f" (true jaw mu {cause['true_mu']:g}).",
        "",
        f"## 1. Impacts: one step vs {n_sub} sub-steps from pybullet's true states "
        f"(run {cause['seed']}, true mu {cause['true_mu']:g})",
        "",
        "Log-likelihood of pybullet's next velocity under the filter's velocity process noise, "
        f"summed over the {cause['scored_steps']} of {cause['steps']} steps that both models "
        "solve for every candidate, relative to the best candidate (nats), and the steps where "
        "the candidates differ most (relative log-likelihood per candidate). Not scored (the "
        "contact LCP has no solution from pybullet's state; the jammed, squeezed grasp): "
        + "; ".join(
            f"{'one step' if n == '1' else n + ' sub-steps'} {_spans(ks)}"
            for n, ks in cause["unsolved_steps"].items()
        )
        + ".",
        "",
        "| model | " + " | ".join(f"mu {c:g}" for c in cands) + " | steps |",
        "|---|" + "---|" * (len(cands) + 1),
    ]
    for n in (1, n_sub):
        sec = cause[f"substeps_{n}"]
        top = ", ".join(
            f"{s['step']} ({' / '.join(f'{x:.1f}' for x in s['ll'])})" for s in sec["top"]
        )
        name = "one step of dt (the filter)" if n == 1 else f"{n} steps of dt / {n}"
        lines.append(f"| {name} | " + " | ".join(f"{x:.1f}" for x in sec["total"]) + f" | {top} |")
    lines += [
        "",
        f"## 2. Fixed-friction filters: runs 0-{result['runs'] - 1} x filter seeds "
        f"0-{result['filter_seeds'] - 1}",
        "",
        "Margin = log p(o | true mu) - max over the wrong candidates (nats); P(true) = their "
        "Bayes average; 'below 0.9' counts the (run, seed) pairs with P(true) < 0.9.",
        "",
        "| particles | margin mean | median | min | std over filter seeds (within a run) | "
        "P(true) >= 0.9 | below 0.9 (run/seed: P) |",
        "|---|---|---|---|---|---|---|",
    ]
    for p in result["particles"]:
        rows = sorted(
            (r for r in result["evidence"] if r["particles"] == p),
            key=lambda r: (r["run"], r["filter_seed"]),
        )
        m = [r["margin"] for r in rows]
        low = [r for r in rows if r["p_true"] < 0.9]
        lines.append(
            f"| {p} | {statistics.mean(m):.1f} | {statistics.median(m):.1f} | {min(m):.1f} | "
            f"{_within_run_std(rows):.1f} | {len(rows) - len(low)} / {len(rows)} | "
            + (", ".join(f"{r['run']}/{r['filter_seed']}: {r['p_true']:.2f}" for r in low) or "-")
            + " |"
        )
    lines += _verdict_lines(result, cands)
    return "\n".join(lines) + "\n"


def _verdict_lines(result: dict[str, Any], cands: Sequence[float]) -> list[str]:
    """Section 3 of the report (empty when the result has no verdicts)."""
    verdicts = result.get("verdicts")
    if not verdicts:
        return []
    p = result["verdict_particles"]
    low = [v for v in verdicts if v["p_true"] < 0.9]
    right = sum(v["most_probable"] == v["true"] for v in verdicts)
    margins = [v["margin"] for v in verdicts]
    return [
        "",
        f"## 3. The data's verdict per run ({p} particles, log-evidence averaged over the "
        "filter seeds)",
        "",
        "P(true) from each candidate's mean log-evidence and the prior: the posterior a "
        "(near-)exact filter ends with. A run below 0.9 is one where no calibrated estimator "
        "can end at P(true) >= 0.9.",
        "",
        "| runs | P(true) >= 0.9 | true most probable | margin median / min [nats] | "
        "below 0.9 (run: P(true), most probable mu) |",
        "|---|---|---|---|---|",
        f"| {len(verdicts)} | {len(verdicts) - len(low)} | {right} | "
        f"{statistics.median(margins):.1f} / {min(margins):.1f} | "
        + (
            ", ".join(f"{v['run']}: {v['p_true']:.2f}, {cands[v['most_probable']]:g}" for v in low)
            or "-"
        )
        + " |",
    ]


def main(argv: Sequence[str] | None = None) -> int:
    """Command line (see the module docstring)."""
    p = argparse.ArgumentParser(
        prog="python -m dbcslam_research.gripper_evidence",
        description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
        epilog="example: python -m dbcslam_research.gripper_evidence --runs 5 --filter-seeds 4",
    )
    p.add_argument(
        "--out",
        type=Path,
        default=None,
        help=f"output dir ({DEFAULT_OUT}; with --sim-set a sim_KEY=VALUE subfolder of it)",
    )
    p.add_argument("--runs", type=int, default=5, help="pybullet runs 0..N-1 (5)")
    p.add_argument("--filter-seeds", type=int, default=4, help="filter seeds 0..N-1 (4)")
    p.add_argument(
        "--particles", type=int, nargs="+", default=[40, 200, 1000], help="(40 200 1000)"
    )
    p.add_argument("--substeps", type=int, default=10, help="sub-steps of section 1 (10)")
    p.add_argument("--workers", type=int, default=2, help="processes (2)")
    p.add_argument(
        "--sim-set",
        action="append",
        default=[],
        metavar="KEY=VALUE",
        help="gripper simulator parameter for every run (repeatable; VALUE a Python literal, "
        'e.g. --sim-set jaw_mu=0.7, --sim-set "start=(0.0,0.0,0.2)"; validated by the '
        "simulator's parameter schema)",
    )
    p.add_argument("--quiet", action="store_true", help="no progress lines or tables")
    a = p.parse_args(argv)
    for name in ("runs", "filter_seeds", "substeps", "workers"):
        if getattr(a, name) < 1:
            p.error(f"--{name.replace('_', '-')} must be >= 1, got {getattr(a, name)}")
    if min(a.particles) < 1:
        p.error(f"--particles must be >= 1, got {a.particles}")
    try:
        overrides = parse_sim_overrides(a.sim_set)
        check_sim_overrides("gripper", overrides)
    except ValueError as err:
        p.error(str(err))
    sim_set: SimSet = tuple(sorted(overrides.items()))
    say = progress_printer(a.quiet)
    t0 = time.perf_counter()
    say(f"section 1: pybullet run 0, one step vs {a.substeps} sub-steps")
    result: dict[str, Any] = {
        "date": utc_now(),
        "substeps": a.substeps,
        "runs": a.runs,
        "filter_seeds": a.filter_seeds,
        "particles": a.particles,
        "sim_set": dict(sim_set),
        "cause": impact_residuals(0, a.substeps, sim_set=sim_set),
    }
    say("section 2: fixed-friction filters")
    result["evidence"] = evidence_runs(
        a.runs, a.filter_seeds, a.particles, a.workers, say, sim_set=sim_set
    )
    result["verdict_particles"] = max(a.particles)
    prior = grasp_run(0, None, sim_set).scenario.friction.prior[0]
    result["verdicts"] = run_verdicts(result["evidence"], max(a.particles), prior)
    result["wall_s"] = time.perf_counter() - t0
    if a.out is None:  # a simulator variant does not overwrite the default report
        a.out = DEFAULT_OUT / settings_dirname("sim_", overrides) if overrides else DEFAULT_OUT
    a.out.mkdir(parents=True, exist_ok=True)
    md = render_markdown(result, command_line("python -m dbcslam_research.gripper_evidence", argv))
    (a.out / "gripper_evidence.md").write_text(md, encoding="utf-8")
    write_json(a.out / "gripper_evidence.json", result)
    if not a.quiet:
        print(md)
    return 0


if __name__ == "__main__":
    sys.exit(main())
