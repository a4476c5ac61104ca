"""`make bench`: per-step time of DBC-SLAM vs particle count, and vs a black-box NCP filter.

What is measured (all on the synthetic paper data of :mod:`dbcslam_core.synthetic`, seed 0):

1. Scaling: DBC-SLAM's per-step wall time for each particle count of ``--particles``
   (default 100, 300, 1000, 3000, 10000) on a slice of ``--steps`` samples of each scenario
   (the window of the trajectory with the most true contacts, so the contact-mode
   enumeration is exercised), next to the black-box NCP particle filter
   (:class:`dbcslam_core.baselines.BlackBoxNCPFilter`) at the same particle count on the
   same data, in two variants: ``pgs`` (batched projected Gauss-Seidel over all particles)
   ``lemke`` (one Lemke pivoting solve of the full LCP per particle, the straightforward
   implementation of the paper's comparison) and ``lemke`` with the model's active-set option
   (Lemke only over the contacts that can close; exact); the Lemke variants only up to
   ``--lemke-max`` particles because they are slow.
   Per-step position RMSE on the slice is reported side by side.
2. Accuracy on the full trajectories at ``--accuracy-particles`` (default 500): DBC-SLAM vs
   the black-box PGS filter (full metrics of :func:`dbcslam_core.experiments.score`).
3. Offline replay, start-up included: the wall time of ``dbcslam replay BAG --particles N
   --no-plots`` as a fresh process (``--replay``, default ``bags/gripper`` at
   ``--replay-particles`` 1000, ``--replay-runs`` 3 runs, the median and the smallest
   reported) next to the time the bag's data last.

Timing: ``time.perf_counter`` around each ``step`` call, the first ``--warmup`` steps
discarded, the median of the rest reported (ms/step). DBC-SLAM runs with its default threads
over rows (``FilterConfig.threads``: the usable CPUs, at most 4) and again on one thread (the
black boxes use one; the estimates are the same bit for bit). Both filters use the same observation
model, position noise and warm-up; the black-box filter's velocity process noise is its own
(tuned) one, ``NCPFilterConfig.default_noise``, because with DBC-SLAM's tighter noise the
bootstrap filter degenerates.

Writes ``bench.md`` and ``bench.json`` into ``--out`` (default ``dbcslam_ros/research/results``)
and prints the Markdown table.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import platform
import statistics
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable, Sequence
from functools import partial
from pathlib import Path
from typing import Any

import numpy as np

from dbcslam_core.experiments import (
    SCENARIOS,
    RunTrace,
    make_trajectory,
    run_black_box,
    run_dbcslam,
    score,
)
from dbcslam_core.row_pool import resolve_threads
from dbcslam_core.synthetic import Trajectory
from dbcslam_research.cli import ints_argument
from dbcslam_research.experiments import command_line, progress_printer, utc_now, write_json
from dbcslam_research.slices import contact_window, slice_trajectory
from dbcslam_research.step_profile import profile_steps, render_profile

__all__ = ["main", "reading_lines", "render_markdown", "time_replay"]

DEFAULT_OUT = Path("dbcslam_ros/research/results")


def _ms(trace: RunTrace, warmup: int) -> float:
    t = trace.step_time[warmup:] if trace.step_time.size > warmup else trace.step_time
    return float(np.median(t) * 1e3)


def _timed(fn: Callable[[], RunTrace], warmup: int, repeat: int) -> tuple[RunTrace, float]:
    """Run `fn` `repeat` times (same seed, same result); the smallest median step time (ms).

    The minimum over repetitions discards slow-downs caused by other jobs on the machine.
    """
    first = fn()
    best = _ms(first, warmup)
    for _ in range(repeat - 1):
        best = min(best, _ms(fn(), warmup))
    return first, best


def _rmse_mm(trace: RunTrace) -> float:
    d = trace.est_q[:, :2] - trace.true_q[:, :2]
    return float(np.sqrt(np.mean(d * d)) * 1e3)


def _fmt(x: float, nd: int = 2) -> str:
    return "-" if not math.isfinite(x) else f"{x:.{nd}f}"


def run_bench(
    scenarios: Sequence[str],
    *,
    particles: Sequence[int],
    steps: int,
    warmup: int,
    lemke_max: int,
    accuracy_particles: int,
    say: Callable[[str], None],
    repeat: int = 1,
) -> dict[str, Any]:
    """Run the benchmark; returns a JSON-ready dict (rows of the two tables)."""
    scaling: list[dict[str, Any]] = []
    accuracy: list[dict[str, Any]] = []
    for scen in scenarios:
        full = make_trajectory(scen, 0)
        start = contact_window(full, steps)
        part = slice_trajectory(full, start, start + steps)
        say(
            f"{scen}: slice of {part.n_steps} samples from step {start} "
            f"(t = {full.t[start]:.2f} s)"
        )
        for p in particles:
            row = _scaling_row(part, p, warmup=warmup, repeat=repeat, lemke_max=lemke_max)
            scaling.append({"scenario": scen, "particles": p, "slice_start": start, **row})
            say(
                f"  P={p:6d}: DBC-SLAM {row['dbcslam_ms']:8.2f} ms  black-box PGS "
                f"{row['blackbox_pgs_ms']:8.2f} ms  Lemke {_fmt(row['blackbox_lemke_ms'])} ms  "
                f"Lemke active-set {_fmt(row['blackbox_lemke_as_ms'])} ms"
            )
        if accuracy_particles > 0:
            accuracy += _accuracy_rows(scen, full, accuracy_particles, say)
    return {"scaling": scaling, "accuracy": accuracy}


def _scaling_row(
    part: Trajectory, p: int, *, warmup: int, repeat: int, lemke_max: int
) -> dict[str, Any]:
    """Step time (ms) and RMSE (mm) of DBC-SLAM and the black-box filters with ``p``
    particles on the slice, and their ratios (Lemke variants NaN above ``lemke_max``)."""
    row: dict[str, Any] = {}
    dbc, row["dbcslam_ms"] = _timed(
        partial(run_dbcslam, part, seed=0, particles=p), warmup, repeat
    )
    row["dbcslam_rmse_mm"] = _rmse_mm(dbc)
    # the same filter on one thread (the black boxes use one): same estimates, bit for bit
    _, row["dbcslam_1thread_ms"] = _timed(
        partial(run_dbcslam, part, seed=0, particles=p, overrides={"threads": 1}),
        warmup,
        repeat,
    )
    live = dbc.live_hypotheses
    row["dbcslam_live_hypotheses"] = math.nan if live is None else float(np.mean(live))
    pgs, row["blackbox_pgs_ms"] = _timed(
        partial(run_black_box, part, seed=0, particles=p, solver="pgs"), warmup, repeat
    )
    row["blackbox_pgs_rmse_mm"] = _rmse_mm(pgs)
    for key, act in (("blackbox_lemke", False), ("blackbox_lemke_as", True)):
        if p <= lemke_max:
            lemke = partial(
                run_black_box, part, seed=0, particles=p, solver="lemke", active_set=act
            )
            lem, row[f"{key}_ms"] = _timed(lemke, warmup, repeat)
            row[f"{key}_rmse_mm"] = _rmse_mm(lem)
        else:
            row[f"{key}_ms"] = math.nan
            row[f"{key}_rmse_mm"] = math.nan
    row["ratio_lemke_over_dbcslam"] = row["blackbox_lemke_ms"] / row["dbcslam_ms"]
    row["ratio_lemke_as_over_dbcslam"] = row["blackbox_lemke_as_ms"] / row["dbcslam_ms"]
    row["ratio_pgs_over_dbcslam"] = row["blackbox_pgs_ms"] / row["dbcslam_ms"]
    return row


def _accuracy_rows(
    scen: str, full: Trajectory, particles: int, say: Callable[[str], None]
) -> list[dict[str, Any]]:
    """Full metrics of DBC-SLAM and the black-box PGS filter on the whole trajectory."""
    runs: list[tuple[str, Callable[[], RunTrace]]] = [
        ("dbcslam", partial(run_dbcslam, full, seed=0, particles=particles)),
        ("blackbox_pgs", partial(run_black_box, full, seed=0, particles=particles, solver="pgs")),
    ]
    rows: list[dict[str, Any]] = []
    for name, fn in runs:
        m = score(fn())
        rows.append({"scenario": scen, "method": name, "particles": particles, **m})
        say(
            f"  full trajectory, {name}: pos RMSE {m['position_rmse'] * 1e3:.2f} mm, "
            f"{m['step_time_ms']:.2f} ms/step"
        )
    return rows


def time_replay(
    bag: Path, particles: int, runs: int, say: Callable[[str], None]
) -> dict[str, Any]:
    """Wall time of `dbcslam replay BAG --particles N --no-plots` as a fresh process (imports,
    kernel loading, bag reading and writing included), `runs` times; with the time the bag's
    poses span (s, their stamps) and the replay's final P(true mu) per friction pair.

    Raises:
        RuntimeError: a bag with fewer than two poses, or a replay that exited with an
            error (its stderr in the message).
    """
    from dbcslam_ros.bag.reader import open_bag

    with open_bag(bag) as reader:  # the time the poses span (their header stamps)
        stamps = [
            int(m.header.stamp.sec) * 1_000_000_000 + int(m.header.stamp.nanosec)
            for _, m in reader.decoded(["/object/pose"])
        ]
    if len(stamps) < 2:
        msg = f"{bag}: fewer than two /object/pose messages, nothing to time"
        raise RuntimeError(msg)
    data_s = (max(stamps) - min(stamps)) / 1e9
    walls: list[float] = []
    metrics: dict[str, Any] = {}
    with tempfile.TemporaryDirectory(prefix="dbcslam-bench-replay-") as tmp:
        out = Path(tmp) / "out"
        cmd = [
            sys.executable, "-m", "dbcslam_ros.cli", "replay", str(bag), "-o", str(out),
            "--particles", str(particles), "--no-plots", "--quiet", "--overwrite",
        ]  # fmt: skip
        for k in range(runs):
            t0 = time.perf_counter()
            done = subprocess.run(cmd, capture_output=True, text=True, check=False)
            walls.append(time.perf_counter() - t0)
            if done.returncode != 0:
                msg = f"{' '.join(cmd)} exited with {done.returncode}: {done.stderr[-2000:]}"
                raise RuntimeError(msg)
            say(f"replay {bag} at {particles} particles, run {k + 1}: {walls[-1]:.2f} s wall")
        metrics = json.loads((out / "metrics.json").read_text(encoding="utf-8"))
    p_true = {
        str(f["pair"]): f.get("p_true")
        for f in metrics.get("friction") or []
        if isinstance(f, dict) and "pair" in f
    }
    return {
        "bag": str(bag),
        "particles": particles,
        "data_s": data_s,
        "wall_s": walls,
        "wall_median_s": statistics.median(walls),
        "wall_min_s": min(walls),
        "estimates": metrics.get("estimates"),
        "final_p_true": p_true,
    }


def _replay_lines(rep: dict[str, Any]) -> list[str]:
    """The replay-timing table of `render_markdown`."""
    verdict = "yes" if rep["wall_median_s"] <= rep["data_s"] else "no"
    p_true = ", ".join(f"{k} {_fmt(v, 3)}" for k, v in rep["final_p_true"].items()) or "-"
    return [
        "",
        "## Offline replay, start-up included",
        "",
        "| bag | particles | data [s] | wall median / min [s] (runs) | within the data's time "
        "| estimates | final P(true mu) |",
        "|---|---|---|---|---|---|---|",
        f"| `{rep['bag']}` | {rep['particles']} | {_fmt(rep['data_s'])} | "
        f"{_fmt(rep['wall_median_s'])} / {_fmt(rep['wall_min_s'])} ({len(rep['wall_s'])}) | "
        f"{verdict} | {rep['estimates']} | {p_true} |",
    ]


def render_markdown(result: dict[str, Any], command: str) -> str:
    """The two benchmark tables as Markdown."""
    meta = result["meta"]
    lines = [
        "# DBC-SLAM benchmark",
        "",
        f"Command: `{command}`  ",
        f"Date: {meta.get('date_utc', 'n/a')}; machine: {meta['machine']}; "
        f"numpy {meta['numpy']}; {meta['cpus']} CPUs; 1-min load "
        f"average before/after {meta['loadavg_1min_before_after'][0]:.1f}/"
        f"{meta['loadavg_1min_before_after'][1]:.1f} (other jobs share the CPUs). Median "
        f"per-step wall time after {meta['warmup']} warm-up steps (smallest of "
        f"{meta['repeat']} repetition(s)), slice of "
        f"{meta['steps']} samples (window with the most true contacts), seed 0.",
        "",
        "## Per-step time vs particles (equal particles, equal data)",
        "",
        f"| scenario | particles | DBC-SLAM [ms] ({meta.get('threads', '?')} threads) "
        "| DBC-SLAM 1 thread [ms] | black-box PGS [ms] | black-box Lemke [ms] "
        "| black-box Lemke active-set [ms] | Lemke / DBC | Lemke-AS / DBC | PGS / DBC "
        "| live hyp / particle | RMSE DBC / PGS / Lemke / Lemke-AS [mm] |",
        "|---|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for r in result["scaling"]:
        lines.append(
            f"| {r['scenario']} | {r['particles']} | {_fmt(r['dbcslam_ms'])} | "
            f"{_fmt(r.get('dbcslam_1thread_ms', math.nan))} | "
            f"{_fmt(r['blackbox_pgs_ms'])} | {_fmt(r['blackbox_lemke_ms'])} | "
            f"{_fmt(r['blackbox_lemke_as_ms'])} | "
            f"{_fmt(r['ratio_lemke_over_dbcslam'])} | "
            f"{_fmt(r['ratio_lemke_as_over_dbcslam'])} | {_fmt(r['ratio_pgs_over_dbcslam'])} | "
            f"{_fmt(r['dbcslam_live_hypotheses'])} | {_fmt(r['dbcslam_rmse_mm'])} / "
            f"{_fmt(r['blackbox_pgs_rmse_mm'])} / {_fmt(r['blackbox_lemke_rmse_mm'])} / "
            f"{_fmt(r['blackbox_lemke_as_rmse_mm'])} |"
        )
    lines += ["", *reading_lines(result)]
    if result["accuracy"]:
        lines += [
            "",
            "## Accuracy on the full trajectories (seed 0)",
            "",
            "| scenario | method | particles | pos RMSE [mm] | yaw RMSE [mrad] | in-contact acc "
            "| stick/slide acc | mode acc | mean P(true mu) in contact | final P(true mu) "
            "| step time [ms] |",
            "|---|---|---|---|---|---|---|---|---|---|---|",
        ]
        for r in result["accuracy"]:
            lines.append(
                f"| {r['scenario']} | {r['method']} | {r['particles']} | "
                f"{_fmt(r['position_rmse'] * 1e3)} | "
                f"{_fmt(r.get('yaw_rmse', math.nan) * 1e3)} | "
                f"{_fmt(r['contact_accuracy'], 3)} | "
                f"{_fmt(r.get('stick_slide_accuracy', math.nan), 3)} | "
                f"{_fmt(r['contact_mode_accuracy'], 3)} | "
                f"{_fmt(r.get('true_friction_posterior_mean', math.nan), 3)} | "
                f"{_fmt(r.get('final_true_friction_posterior', math.nan), 3)} | "
                f"{_fmt(r['step_time_ms'])} |"
            )
    if result.get("profile"):
        lines += [
            "",
            "## Where the time goes (one thread, ms per step)",
            "",
            "Command: `python -m dbcslam_research.step_profile` (the same slices; wall time "
            "per phase of `DbcSlamFilter.step`, mean after the warm-up steps).",
            "",
            *render_profile(result["profile"]),
        ]
    if result.get("replay"):
        lines += _replay_lines(result["replay"])
    lines.append("")
    return "\n".join(lines)


def _span(values: Sequence[float]) -> str:
    lo, hi = min(values), max(values)
    return f"{lo:.1f}x" if abs(hi - lo) < 0.05 else f"{lo:.1f}-{hi:.1f}x"


def reading_lines(result: dict[str, Any], target: float = 10.0) -> list[str]:
    """Plain-language reading of the scaling table, computed from its numbers.

    Per scenario: where DBC-SLAM is >= `target` x faster than the per-particle Lemke black box
    (the paper's "straightforward NCP" filter), the range of that ratio, and the ratios to the
    active-set Lemke and batched-PGS black boxes (which are not the paper's comparison but
    are honest alternatives to it).
    """
    lines = ["**Reading the table.**"]
    by_scen: dict[str, list[dict[str, Any]]] = {}
    for r in result["scaling"]:
        by_scen.setdefault(r["scenario"], []).append(r)
    for scen, rows in by_scen.items():
        lemke = [r for r in rows if math.isfinite(r.get("ratio_lemke_over_dbcslam") or math.nan)]
        pgs = [r["ratio_pgs_over_dbcslam"] for r in rows]
        parts = [f"*{scen}*:"]
        if lemke:
            met = [r["particles"] for r in lemke if r["ratio_lemke_over_dbcslam"] >= target]
            ratios = [r["ratio_lemke_over_dbcslam"] for r in lemke]
            where = (
                "at no measured particle count"
                if not met
                else (
                    "at every measured particle count"
                    if len(met) == len(lemke)
                    else "at " + ", ".join(str(p) for p in met) + " particles"
                )
            )
            parts.append(
                f"DBC-SLAM is {_span(ratios)} faster than the per-particle Lemke black box "
                f"(target >= {target:g}x met {where});"
            )
            las = [r["ratio_lemke_as_over_dbcslam"] for r in lemke]
            parts.append(f"{_span(las)} faster than the active-set Lemke black box;")
        parts.append(
            f"the batched-PGS black box takes {_span(pgs)} of DBC-SLAM's time per step "
            "(it solves one cheap fixed-iteration problem per particle instead of "
            "enumerating contact-mode and friction hypotheses; compare its accuracy below)."
        )
        lines.append("- " + " ".join(parts))
    lines += _profile_reading(result.get("profile") or [])
    lines.append(
        "- The compiled per-row kernels run on the threads of the first DBC-SLAM column from "
        "~256 live entries per thread (the 1-thread column is the same filter on one thread); "
        "the black boxes' Lemke cost is per particle."
    )
    return lines


def _profile_reading(rows: Sequence[dict[str, Any]]) -> list[str]:
    """Where DBC-SLAM's step goes against the PGS box's, per scenario, from the profile."""
    lines = []
    by_scen: dict[str, list[dict[str, Any]]] = {}
    for r in rows:
        by_scen.setdefault(r["scenario"], []).append(r)
    for scen, rs in by_scen.items():
        lo, hi = rs[0], rs[-1]
        share = [r["dbcslam"]["_compiled_phases"] / r["dbcslam"]["step"] for r in rs]
        rest = lo["dbcslam"]["step"] - lo["dbcslam"]["_compiled_phases"]
        lines.append(
            f"- *{scen}*, where the time goes (one thread, table below): the compiled "
            f"hypothesis phases (dynamics, proposal, posterior of every live mode x friction "
            f"hypothesis) take {min(share):.0%}-{max(share):.0%} of DBC-SLAM's step "
            f"({hi['dbcslam']['_compiled_phases']:.2f} of {hi['dbcslam']['step']:.2f} ms at "
            f"{hi['particles']} particles, where the PGS box's whole step takes "
            f"{hi['blackbox_pgs']['step']:.2f} ms); the rest of the step (numpy and Python) "
            f"takes {rest:.2f} ms at {lo['particles']} particles (the PGS box's whole step "
            f"{lo['blackbox_pgs']['step']:.2f} ms)."
        )
    return lines


def _counts_or_none(text: str) -> list[int]:
    """argparse type: comma-separated positive integers, or 0 for none."""
    return [] if text.strip() == "0" else ints_argument(text)


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point; returns the exit code (0 ok, 2 bad arguments)."""
    p = argparse.ArgumentParser(
        prog="python -m dbcslam_research.bench",
        description="Per-step time of DBC-SLAM vs particle count and vs a black-box NCP "
        "particle filter (Lemke loop and batched PGS) on the paper's synthetic data.",
    )
    p.add_argument("--out", type=Path, default=DEFAULT_OUT, help=f"output dir ({DEFAULT_OUT})")
    p.add_argument(
        "--particles",
        type=ints_argument,
        default=[100, 300, 1000, 3000, 10000],
        help="particle counts",
    )
    p.add_argument("--steps", type=int, default=40, help="samples in the timed slice (40)")
    p.add_argument("--warmup", type=int, default=5, help="warm-up steps not timed (5)")
    p.add_argument(
        "--lemke-max", type=int, default=1000, help="largest particle count for Lemke (1000)"
    )
    p.add_argument(
        "--accuracy-particles",
        type=int,
        default=500,
        help="particles of the full-trajectory accuracy comparison (0 = skip; 500)",
    )
    p.add_argument("--scenarios", default="gripper,edge", help=f"subset of {','.join(SCENARIOS)}")
    p.add_argument(
        "--repeat",
        type=int,
        default=1,
        help="repetitions of each timed run; the smallest median is reported (1)",
    )
    p.add_argument(
        "--replay",
        type=Path,
        default=Path("bags/gripper"),
        help="bag of the replay timing (bags/gripper)",
    )
    p.add_argument(
        "--replay-particles", type=int, default=1000, help="particles of the replay (1000)"
    )
    p.add_argument(
        "--replay-runs", type=int, default=3, help="replay processes timed (0 = skip; 3)"
    )
    p.add_argument(
        "--profile-particles",
        type=_counts_or_none,
        default=[100, 1000, 10000],
        help="particle counts of the per-phase profile (python -m "
        "dbcslam_research.step_profile); 0 = skip (100,1000,10000)",
    )
    p.add_argument("--quiet", action="store_true")
    args = p.parse_args(argv)
    scenarios = [s for s in args.scenarios.split(",") if s]
    if not scenarios or any(s not in SCENARIOS for s in scenarios):
        p.print_usage(sys.stderr)
        print(f"error: --scenarios must be a subset of {list(SCENARIOS)}", file=sys.stderr)
        return 2
    if args.replay_runs > 0 and not args.replay.exists():
        p.print_usage(sys.stderr)
        print(f"error: --replay {args.replay}: no such bag (or --replay-runs 0)", file=sys.stderr)
        return 2
    if args.replay_runs < 0 or args.replay_particles < 1:
        p.print_usage(sys.stderr)
        print("error: need --replay-runs >= 0 and --replay-particles >= 1", file=sys.stderr)
        return 2
    if args.steps < args.warmup + 3 or args.warmup < 0 or args.repeat < 1:
        p.print_usage(sys.stderr)
        print(
            "error: need --steps >= --warmup + 3, --warmup >= 0 and --repeat >= 1",
            file=sys.stderr,
        )
        return 2

    say = progress_printer(args.quiet)
    command = command_line("python -m dbcslam_research.bench", argv)
    load_before = os.getloadavg()[0]
    t0 = time.perf_counter()
    result = run_bench(
        scenarios,
        particles=args.particles,
        steps=args.steps,
        warmup=args.warmup,
        lemke_max=args.lemke_max,
        accuracy_particles=args.accuracy_particles,
        say=say,
        repeat=args.repeat,
    )
    if args.profile_particles:
        say("where the time goes (one thread):")
        result["profile"] = profile_steps(
            scenarios, args.profile_particles, steps=args.steps, warmup=args.warmup, say=say
        )
    if args.replay_runs > 0:
        result["replay"] = time_replay(args.replay, args.replay_particles, args.replay_runs, say)
    result["meta"] = {
        "command": command,
        "date_utc": utc_now(),
        "machine": f"{platform.machine()} {platform.processor() or platform.system()}",
        "python": platform.python_version(),
        "numpy": np.__version__,
        "cpus": os.cpu_count(),
        "threads": resolve_threads(None),
        "steps": args.steps,
        "warmup": args.warmup,
        "repeat": args.repeat,
        "elapsed_s": time.perf_counter() - t0,
        "loadavg_1min_before_after": [load_before, os.getloadavg()[0]],
    }
    md = render_markdown(result, command)
    args.out.mkdir(parents=True, exist_ok=True)
    (args.out / "bench.md").write_text(md, encoding="utf-8")
    write_json(args.out / "bench.json", result)
    print(md)
    say(f"wrote {args.out / 'bench.md'} and bench.json in {result['meta']['elapsed_s']:.0f} s")
    return 0


if __name__ == "__main__":
    sys.exit(main())
