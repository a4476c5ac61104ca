"""Tracking health on pybullet runs: how surprised the filter is by its observations.

``python -m dbcslam_research.tracking_health [SCENARIO:PARTICLES ...] --seeds N --out DIR``
runs DBC-SLAM (each scenario's preset, filter seed = simulator seed, as `experiments_sim`)
on pybullet runs 0..N-1 and reports per run the largest surprise of a step
(`dbcslam_core.surprise`: how far the step's log predictive likelihood falls below the
median of the recent steps, nats), the steps above `SURPRISE_WARNING`, the position RMSE over
the sensor noise and, on the gripper, the final posterior of the true jaw coefficient:
whether the surprise the filter node reports in ``/diagnostics`` separates runs that track
from runs that do not. ``--sim-set KEY=VALUE`` changes the simulation of every selected
scenario (e.g. ``jaw_mu=0.1``). Writes ``tracking_health.md`` and ``tracking_health.json``.
"""

from __future__ import annotations

import argparse
import statistics
import sys
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from dbcslam_core.experiments import run_dbcslam, score
from dbcslam_core.surprise import SURPRISE_WARNING, SurpriseMonitor
from dbcslam_research.cli import pool_map, settings_dirname
from dbcslam_research.experiments import command_line, progress_printer, utc_now, write_json
from dbcslam_research.experiments_sim import (
    check_sim_overrides,
    parse_sim_overrides,
    sim_trajectory,
)

__all__ = ["main", "parse_items", "render_markdown", "run_health", "surprises"]

DEFAULT_OUT = Path("dbcslam_ros/research/results/tracking_health")
DEFAULT_ITEMS = ("edge:1000", "gripper:500", "push:500", "edge:100", "gripper:40", "push:40")
SCENARIOS = ("edge", "gripper", "push")


def parse_items(items: Sequence[str]) -> list[tuple[str, int]]:
    """``SCENARIO:PARTICLES`` items -> [(scenario, particles)]; raises ValueError naming a bad
    item and what would be valid."""
    out: list[tuple[str, int]] = []
    for item in items:
        name, sep, count = item.partition(":")
        try:
            particles = int(count) if sep else 0
        except ValueError as err:
            msg = f"{item!r}: PARTICLES must be an integer"
            raise ValueError(msg) from err
        if name not in SCENARIOS or particles < 1:
            msg = f"{item!r}: expected SCENARIO:PARTICLES, SCENARIO one of {SCENARIOS}, >= 1"
            raise ValueError(msg)
        out.append((name, particles))
    return out


def surprises(log_likelihood: Sequence[float]) -> np.ndarray:
    """The surprise of every step (nats) from the steps' log predictive likelihoods, as the
    filter node computes it (`SurpriseMonitor`, one per run)."""
    monitor = SurpriseMonitor()
    return np.asarray([monitor.update(float(x)) for x in log_likelihood])


def run_health(task: tuple[str, int, int, tuple[tuple[str, Any], ...]]) -> dict[str, Any]:
    """One run: (scenario, particles, seed, simulator overrides) -> its health row."""
    kind, particles, seed, sim_set = task
    tr, _params, _force = sim_trajectory(kind, seed, overrides=dict(sim_set))
    trace = run_dbcslam(tr, seed=seed, particles=particles)
    if trace.log_likelihood is None:  # (run_filter always records it)
        msg = f"{kind} run {seed}: the trace has no log likelihoods"
        raise RuntimeError(msg)
    s = surprises(trace.log_likelihood.tolist())
    metrics = score(trace)  # the targets' metrics (per-axis RMSE over the noise std)
    return {
        "scenario": kind,
        "particles": particles,
        "seed": seed,
        "surprise_max": float(s.max()),
        "surprised_steps": int(np.count_nonzero(s > SURPRISE_WARNING)),
        "position_rmse_over_noise": metrics["position_rmse_ratio"],
        "p_true_final": metrics.get("final_true_friction_posterior")
        if kind == "gripper"
        else None,
    }


def render_markdown(result: dict[str, Any], command: str) -> str:
    """The report: one row per (scenario, particles), the runs above the warning listed."""
    lines = [
        "# Tracking health on pybullet runs",
        "",
        f"Command: `{command}`  ",
        f"Date: {result['date']}; {result['wall_s']:.0f} s wall; simulator overrides: "
        f"{result['sim_set'] or 'none'}; warning above {SURPRISE_WARNING:g} nats.",
        "",
        "Surprise of a step: median of the recent steps' log predictive likelihood minus its "
        "own (nats; `dbcslam_core.surprise`, the filter node's `/diagnostics`). 'flagged': "
        "runs with a step above the warning; RMSE / noise: per-axis position RMSE over the "
        "sensor's position noise std (as the targets of `experiments_sim`).",
        "",
        "| scenario | particles | runs | largest surprise median / max [nats] | flagged | "
        "RMSE / noise, flagged runs | RMSE / noise, other runs (max) | final P(true mu) < 0.9 "
        "(flagged / other) |",
        "|---|---|---|---|---|---|---|---|",
    ]
    groups: dict[tuple[str, int], list[dict[str, Any]]] = {}
    for row in result["runs"]:
        groups.setdefault((row["scenario"], row["particles"]), []).append(row)
    for (kind, particles), rows in groups.items():
        flagged = [r for r in rows if r["surprised_steps"] > 0]
        other = [r for r in rows if r["surprised_steps"] == 0]
        peak = [r["surprise_max"] for r in rows]
        bad = ", ".join(f"{r['seed']}: {r['position_rmse_over_noise']:.2f}" for r in flagged)
        ok_max = max((r["position_rmse_over_noise"] for r in other), default=float("nan"))
        wrong = "-"
        if kind == "gripper":
            n_f = sum(r["p_true_final"] < 0.9 for r in flagged)
            n_o = sum(r["p_true_final"] < 0.9 for r in other)
            wrong = f"{n_f} / {n_o}"
        lines.append(
            f"| {kind} | {particles} | {len(rows)} | {statistics.median(peak):.1f} / "
            f"{max(peak):.1f} | {len(flagged)} | {bad or '-'} | {ok_max:.2f} | {wrong} |"
        )
    return "\n".join(lines) + "\n"


def main(argv: Sequence[str] | None = None) -> int:
    """Command line (see the module docstring)."""
    p = argparse.ArgumentParser(
        prog="python -m dbcslam_research.tracking_health",
        description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
        epilog="example: python -m dbcslam_research.tracking_health gripper:40 --seeds 20 "
        "--sim-set jaw_mu=0.1",
    )
    p.add_argument(
        "items",
        nargs="*",
        default=list(DEFAULT_ITEMS),
        metavar="SCENARIO:PARTICLES",
        help=f"filters to run ({' '.join(DEFAULT_ITEMS)})",
    )
    p.add_argument("--seeds", type=int, default=10, help="pybullet runs 0..N-1 (10)")
    p.add_argument(
        "--sim-set",
        action="append",
        default=[],
        metavar="KEY=VALUE",
        help="simulator parameter of every selected scenario (repeatable), e.g. jaw_mu=0.1",
    )
    p.add_argument("--workers", type=int, default=2, help="processes (2)")
    p.add_argument(
        "--out", type=Path, default=None, help=f"output dir ({DEFAULT_OUT}[/sim_KEY=VALUE])"
    )
    p.add_argument("--quiet", action="store_true", help="no progress lines or table")
    a = p.parse_args(argv)
    try:
        items = parse_items(a.items)
        if a.seeds < 1 or a.workers < 1:
            msg = f"--seeds and --workers must be >= 1, got {a.seeds}, {a.workers}"
            raise ValueError(msg)
        overrides = parse_sim_overrides(a.sim_set)
        for kind in dict.fromkeys(k for k, _ in items):
            check_sim_overrides(kind, overrides)
    except ValueError as err:
        p.error(str(err))
    sim_set = tuple(sorted(overrides.items()))
    say = progress_printer(a.quiet)
    t0 = time.perf_counter()
    tasks = [(k, n, s, sim_set) for k, n in items for s in range(a.seeds)]
    runs = pool_map(run_health, tasks, a.workers, say, "DBC-SLAM (runs)")
    result = {
        "date": utc_now(),
        "sim_set": dict(sim_set),
        "warning_nats": SURPRISE_WARNING,
        "runs": runs,
        "wall_s": time.perf_counter() - t0,
    }
    out = a.out
    if out is None:
        out = DEFAULT_OUT / settings_dirname("sim_", overrides) if overrides else DEFAULT_OUT
    out.mkdir(parents=True, exist_ok=True)
    md = render_markdown(result, command_line("python -m dbcslam_research.tracking_health", argv))
    (out / "tracking_health.md").write_text(md, encoding="utf-8")
    write_json(out / "tracking_health.json", result)
    if not a.quiet:
        print(md)
    return 0


if __name__ == "__main__":
    sys.exit(main())
