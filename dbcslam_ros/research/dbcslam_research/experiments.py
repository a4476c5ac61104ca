"""`make experiments`: the paper's experiments over seeds, a target table and figures.

Runs :func:`dbcslam_core.experiments.run_experiments` (edge and gripper, DBC-SLAM and the
fixed-friction baseline), then writes into ``--out`` (default ``dbcslam_ros/research/results``):

* ``experiments.md``: targets (median over seeds vs threshold, PASS/FAIL), medians per method
  and per-seed values;
* ``experiments.json``: the same numbers, machine readable (config, targets, summary, runs);
* ``edge_*.png`` and ``gripper_*.png``: the paper-style figures of the representative seed
  (the seed with the median DBC-SLAM position RMSE).

Usage: ``python -m dbcslam_research.experiments [--out DIR] [--seeds N] [--particles N]
[--scenarios edge,gripper] [--workers W] [--steps N] [--set KEY=VALUE ...] [--no-fixed]
[--no-figures] [--quiet]``.

The formatting, file and CLI helpers here (``targets_table``, ``medians_tables``,
``report_sections``, ``report_payload``, ``write_json``, ``save_figures``,
``add_common_arguments``, ...) are shared with ``dbcslam_research.experiments_sim`` and
``dbcslam_research.bench``.
Exit code 0 when it ran (whether or not targets pass), 2 on bad arguments.
"""

from __future__ import annotations

import argparse
import dataclasses
import datetime as dt
import json
import math
import os
import sys
import time
from collections.abc import Callable, Collection, Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from dbcslam_core.errors import ModelError
from dbcslam_core.experiments import (
    DBCSLAM,
    SCENARIOS,
    ExperimentConfig,
    ExperimentResults,
    RunRecord,
    RunTrace,
    TargetCheck,
    evaluate_targets,
    representative_seed,
    run_experiments,
    summarize,
)
from dbcslam_core.metrics import position_rmse
from dbcslam_core.rbpf import FilterConfig
from dbcslam_research.cli import key_values

__all__ = [
    "DEFAULT_OUT",
    "PER_SEED_KEYS",
    "TABLE_METRICS",
    "add_common_arguments",
    "add_set_argument",
    "command_line",
    "figure_trace",
    "fmt_value",
    "json_safe",
    "main",
    "medians_tables",
    "parse_overrides",
    "parse_scenarios",
    "per_seed_table",
    "print_checks",
    "progress_printer",
    "render_markdown",
    "report_payload",
    "report_sections",
    "save_figures",
    "targets_table",
    "utc_now",
    "verdict",
    "write_json",
    "write_outputs",
]

DEFAULT_OUT = Path("dbcslam_ros/research/results")

TABLE_METRICS: tuple[tuple[str, str, float], ...] = (
    # (metric, column header, scale)
    ("position_rmse", "pos RMSE [mm]", 1e3),
    ("position_rmse_ratio", "pos RMSE / noise", 1.0),
    ("obs_position_rmse", "obs RMSE [mm]", 1e3),
    ("yaw_rmse", "yaw RMSE [mrad]", 1e3),
    ("yaw_rmse_ratio", "yaw RMSE / noise", 1.0),
    ("contact_accuracy", "in-contact acc", 1.0),
    ("stick_slide_accuracy", "stick/slide acc", 1.0),
    ("contact_mode_accuracy", "mode acc (all)", 1.0),
    ("contact_mode_accuracy_in_contact", "mode acc (in contact)", 1.0),
    ("friction_map_accuracy", "friction-map acc", 1.0),
    ("friction_map_cells", "slid cells", 1.0),
    ("true_friction_posterior_mean", "mean P(true mu) in contact", 1.0),
    ("final_true_friction_posterior", "final P(true mu)", 1.0),
    ("live_hypotheses", "live hyp / particle", 1.0),
    ("step_time_ms", "step time [ms]", 1.0),
)
"""Columns of the per-method median tables: (metric key, header, scale); a column appears
only if some method of the scenario has the metric."""

PER_SEED_KEYS: tuple[str, ...] = (
    "position_rmse_ratio",
    "yaw_rmse_ratio",
    "contact_accuracy",
    "stick_slide_accuracy",
    "contact_mode_accuracy",
    "friction_map_accuracy",
    "final_true_friction_posterior",
    "final_friction_argmax",
)
"""Metrics listed per seed (after the position RMSE) in :func:`per_seed_table`."""


# ------------------------------------------------------------------------------ formatting
def fmt_value(x: float, digits: int = 3) -> str:
    """A table cell: ``n/a`` for NaN/inf, integers from 1000 up, `digits` decimals (tiny
    values in `digits` significant digits)."""
    if not math.isfinite(x):
        return "n/a"
    if abs(x) >= 1000:
        return f"{x:.0f}"
    return f"{x:.{digits}g}" if abs(x) < 1e-3 and x != 0 else f"{x:.{digits}f}"


def verdict(check: TargetCheck) -> str:
    """``PASS``, ``FAIL`` or ``report`` (report-only target)."""
    if check.passed is None:
        return "report"
    return "PASS" if check.passed else "FAIL"


def targets_table(checks: Sequence[TargetCheck]) -> list[str]:
    """Markdown lines of the target table (scenario, target, median, threshold, verdict)."""
    lines = [
        "| scenario | target | median | threshold | verdict |",
        "|---|---|---|---|---|",
    ]
    for c in checks:
        t = c.target
        thr = "-" if t.op == "report" else f"{t.op} {fmt_value(t.threshold)}"
        lines.append(f"| {t.scenario} | {t.label} | {fmt_value(c.value)} | {thr} | {verdict(c)} |")
    return lines


def medians_tables(
    summary: Mapping[str, Mapping[str, Mapping[str, float]]],
    metrics: Sequence[tuple[str, str, float]] = TABLE_METRICS,
) -> list[str]:
    """Markdown lines: one ``### scenario`` table of medians per method (``summarize``)."""
    lines: list[str] = []
    for scen, methods in summary.items():
        cols = [(m, h, s) for m, h, s in metrics if any(m in v for v in methods.values())]
        lines += [f"### {scen}", ""]
        lines.append("| method | " + " | ".join(h for _, h, _ in cols) + " |")
        lines.append("|---|" + "---|" * len(cols))
        for meth, vals in methods.items():
            cells = [fmt_value(vals.get(m, math.nan) * s) for m, _, s in cols]
            lines.append(f"| {meth} | " + " | ".join(cells) + " |")
        lines.append("")
    return lines


def per_seed_table(
    records: Sequence[RunRecord], keys: Collection[str] = PER_SEED_KEYS
) -> list[str]:
    """Markdown lines: one row per run (scenario, seed, method, pos RMSE mm, `keys`)."""
    lines = ["| scenario | seed | method | pos RMSE [mm] | metrics |", "|---|---|---|---|---|"]
    for r in records:
        extra = ", ".join(f"{k}={fmt_value(v)}" for k, v in r.metrics.items() if k in keys)
        lines.append(
            f"| {r.scenario} | {r.seed} | {r.method} | "
            f"{fmt_value(r.metrics['position_rmse'] * 1e3)} | {extra} |"
        )
    return lines


def report_sections(
    records: Sequence[RunRecord],
    checks: Sequence[TargetCheck],
    *,
    metrics: Sequence[tuple[str, str, float]] = TABLE_METRICS,
    per_seed_keys: Collection[str] = PER_SEED_KEYS,
) -> list[str]:
    """The ``## Targets``, ``## Medians per method`` and ``## Per seed`` sections."""
    lines = ["## Targets", "", *targets_table(checks), "", "## Medians per method", ""]
    lines += medians_tables(summarize(records), metrics)
    lines += ["## Per seed", "", *per_seed_table(records, per_seed_keys), ""]
    return lines


def render_markdown(
    results: ExperimentResults[ExperimentConfig],
    checks: Sequence[TargetCheck],
    command: str,
    elapsed: float,
) -> str:
    """The Markdown report: targets, medians per (scenario, method), per-seed values."""
    cfg = results.config
    lines = [
        "# DBC-SLAM paper experiments (Sec. IV)",
        "",
        f"Command: `{command}`  ",
        f"Date: {utc_now()}; seeds: {list(cfg.seeds)}; particles: {cfg.particles}; steps: "
        f"{'full trajectories' if cfg.n_steps is None else cfg.n_steps}; "
        f"wall time {elapsed:.0f} s on {cfg.workers} worker(s); 1-min load average at the "
        f"end {os.getloadavg()[0]:.1f}.",
        "",
        "Values are medians over seeds. Position RMSE is the per-axis RMS error of the "
        "estimated centre of mass (directly comparable to the per-axis observation noise std); "
        "steps 1..T-1 are scored (step 0 initialises the filter). Step times are offline wall "
        "times with the worker processes sharing the CPUs (speed: see bench.md).",
        "",
    ]
    return "\n".join(lines + report_sections(results.records, checks))


# ------------------------------------------------------------------------------ files
def json_safe(x: Any) -> Any:
    """`x` with NaN/inf -> None, numpy scalars -> Python, tuples -> lists, keys -> str."""
    if isinstance(x, np.generic):
        return json_safe(x.item())
    if isinstance(x, float) and not math.isfinite(x):
        return None
    if isinstance(x, dict):
        return {str(k): json_safe(v) for k, v in x.items()}
    if isinstance(x, list | tuple):
        return [json_safe(v) for v in x]
    return x


def write_json(path: Path, payload: Any) -> Path:
    """Write `payload` (through :func:`json_safe`) as indented JSON; returns `path`."""
    path.write_text(json.dumps(json_safe(payload), indent=2) + "\n", encoding="utf-8")
    return path


def utc_now() -> str:
    """The current UTC time as ``YYYY-MM-DD HH:MM UTC``."""
    return dt.datetime.now(dt.UTC).strftime("%Y-%m-%d %H:%M UTC")


def report_payload(
    command: str,
    elapsed: float,
    config: Mapping[str, Any],
    checks: Sequence[TargetCheck],
    records: Sequence[RunRecord],
) -> dict[str, Any]:
    """The JSON report: command, date_utc, elapsed_s, loadavg_1min, config, targets, summary
    (medians per scenario/method) and runs."""
    return {
        "command": command,
        "date_utc": utc_now(),
        "elapsed_s": elapsed,
        "loadavg_1min": os.getloadavg()[0],
        "config": dict(config),
        "targets": [c.to_dict() for c in checks],
        "summary": summarize(records),
        "runs": [r.to_dict() for r in records],
    }


def figure_trace(
    traces: Mapping[tuple[str, int, str], RunTrace], scenario: str, seed: int
) -> RunTrace:
    """The DBC-SLAM trace of (scenario, seed) to draw; on the edge with the better
    fixed-friction baseline run of that seed (lower position RMSE) attached as baseline."""
    trace = traces[(scenario, seed, DBCSLAM)]
    fixed = [
        t
        for k, t in traces.items()
        if k[0] == scenario and k[1] == seed and k[2].startswith("fixed_mu_")
    ]
    if scenario != "edge" or not fixed:
        return trace
    best = min(fixed, key=lambda t: position_rmse(t.est_q[:, :2], t.true_q[:, :2]))
    mu = best.method.removeprefix("fixed_mu_")
    return dataclasses.replace(
        trace,
        baseline_q=best.est_q,
        baseline_label=f"fixed friction mu = {mu} (better of the two)",
    )


def save_figures(
    records: Sequence[RunRecord],
    traces: Mapping[tuple[str, int, str], RunTrace],
    scenarios: Sequence[str],
    out_dir: Path,
    prefix: str = "",
) -> list[Path]:
    """Figures of the representative seed (median DBC-SLAM position RMSE) per scenario:
    edge -> ``save_edge_figures``, others -> ``save_gripper_figures``; file names start with
    ``{prefix}{scenario}`` (e.g. prefix ``sim_`` -> ``sim_push_com.png``)."""
    from dbcslam_ros.offline.plotting import save_edge_figures, save_gripper_figures

    paths: list[Path] = []
    for scen in scenarios:
        trace = figure_trace(traces, scen, representative_seed(records, scen))
        if scen == "edge":
            paths += save_edge_figures(trace, out_dir, prefix=f"{prefix}{scen}")
        else:
            paths += save_gripper_figures(trace, out_dir, prefix=f"{prefix}{scen}")
    return paths


def write_outputs(
    results: ExperimentResults[ExperimentConfig],
    out_dir: Path,
    command: str,
    elapsed: float,
    figures: bool = True,
) -> list[Path]:
    """Write experiments.md, experiments.json and the figures; returns the written paths."""
    out_dir.mkdir(parents=True, exist_ok=True)
    checks = evaluate_targets(results.records)
    md = out_dir / "experiments.md"
    md.write_text(render_markdown(results, checks, command, elapsed), encoding="utf-8")
    cfg = results.config
    config = {
        "seeds": list(cfg.seeds),
        "particles": cfg.particles,
        "scenarios": list(cfg.scenarios),
        "n_steps": cfg.n_steps,
        "fixed_friction": cfg.fixed_friction,
        "filter_overrides": {kind: dict(o) for kind, o in cfg.filter_overrides.items() if o},
        "workers": cfg.workers,
    }
    payload = report_payload(command, elapsed, config, checks, results.records)
    paths = [md, write_json(out_dir / "experiments.json", payload)]
    if figures:
        paths += save_figures(results.records, results.traces, cfg.scenarios, out_dir)
    return paths


# ------------------------------------------------------------------------------ CLI helpers
def add_common_arguments(
    parser: argparse.ArgumentParser,
    *,
    default_out: Path,
    scenarios: Sequence[str],
    workers: int = 2,
) -> None:
    """Add ``--out --seeds --particles --scenarios --workers --no-fixed --no-figures
    --quiet`` (the options shared by the experiment drivers) to `parser`."""
    p = parser
    p.add_argument("--out", type=Path, default=default_out, help=f"output dir ({default_out})")
    p.add_argument("--seeds", type=int, default=5, help="number of seeds 0..N-1 (5)")
    p.add_argument("--particles", type=int, default=500, help="particles per filter (500)")
    p.add_argument(
        "--scenarios",
        default=",".join(scenarios),
        help=f"comma-separated subset of {','.join(scenarios)}",
    )
    p.add_argument("--workers", type=int, default=workers, help=f"parallel processes ({workers})")
    p.add_argument(
        "--no-fixed", action="store_true", help="skip the fixed-friction baseline (edge)"
    )
    p.add_argument("--no-figures", action="store_true", help="skip the PNG figures")
    p.add_argument("--quiet", action="store_true", help="no progress lines")


def parse_scenarios(text: str, valid: Sequence[str]) -> tuple[str, ...]:
    """``"edge,gripper"`` -> ``("edge", "gripper")``; ValueError naming the bad and the valid
    names if empty or unknown."""
    scenarios = tuple(s.strip() for s in text.split(",") if s.strip())
    bad = [s for s in scenarios if s not in valid]
    if bad or not scenarios:
        msg = f"unknown scenarios {bad or text!r}; valid: {list(valid)}"
        raise ValueError(msg)
    return scenarios


def command_line(prog: str, argv: Sequence[str] | None) -> str:
    """The command as typed: `prog` followed by `argv` (``sys.argv[1:]`` if None)."""
    return " ".join([prog, *(sys.argv[1:] if argv is None else argv)])


def progress_printer(quiet: bool) -> Callable[[str], None]:
    """A ``say(msg)`` that prints (flushed) unless `quiet`."""

    def say(msg: str) -> None:
        if not quiet:
            print(msg, flush=True)

    return say


def print_checks(checks: Sequence[TargetCheck], say: Callable[[str], None]) -> None:
    """One ``[PASS  ] scenario label: value`` line per check."""
    for c in checks:
        say(f"  [{verdict(c):6s}] {c.target.scenario:8s} {c.target.label}: {fmt_value(c.value)}")


def _parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog="python -m dbcslam_research.experiments",
        description="Run the DBC-SLAM paper experiments (edge, gripper) over seeds and write "
        "a target table (Markdown + JSON) and figures.",
    )
    add_common_arguments(p, default_out=DEFAULT_OUT, scenarios=SCENARIOS)
    p.add_argument(
        "--steps", type=int, default=None, help="truncate trajectories to N samples (full)"
    )
    add_set_argument(p)
    return p


def add_set_argument(p: argparse.ArgumentParser) -> None:
    """``--set KEY=VALUE`` (repeatable) into ``args.overrides``; see `parse_overrides`."""
    p.add_argument(
        "--set",
        dest="overrides",
        action="append",
        default=[],
        metavar="KEY=VALUE",
        help="a FilterConfig field on top of each scenario's preset, for every filter run "
        "(repeatable; VALUE a Python literal: 0.01, 64, True, (0.01, 0.01, 0.5)); e.g. "
        "--set prune_threshold=0.01",
    )


def parse_overrides(
    items: Sequence[str], scenarios: Sequence[str], particles: Sequence[int] = ()
) -> dict[str, Any]:
    """``--set KEY=VALUE`` items -> `FilterConfig` overrides (VALUE a Python literal, else
    the text). Raises ValueError naming the item when KEY is not a field of `FilterConfig`
    or is ``particles`` (the command's ``--particles`` sets it), and naming the scenario and
    the count when the overrides together are not valid on its preset at one of the
    `particles` counts the command runs (the preset depends on the count: the gripper's
    friction bank below `rbpf.GRIPPER_BANK_PARTICLES`; empty: the preset's default count)."""
    fields = sorted(f.name for f in dataclasses.fields(FilterConfig) if f.name != "particles")
    out = key_values(
        items,
        "--set",
        fields,
        f"with KEY one of {', '.join(fields)} (the particle count is --particles)",
    )
    counts: list[dict[str, int]] = [{"particles": n} for n in dict.fromkeys(particles)] or [{}]
    for kind in scenarios if out else ():
        for count in counts:
            try:
                FilterConfig.preset(kind, **count, **out)
            except (ModelError, TypeError, ValueError) as err:
                given = " ".join(f"--set {item!r}" for item in items)
                at = f" at {count['particles']} particles" if count else ""
                msg = f"{given} on the {kind} preset{at}: {err}"
                raise ValueError(msg) from err
    return out


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point; returns the exit code."""
    parser = _parser()
    args = parser.parse_args(argv)
    try:
        scenarios = parse_scenarios(args.scenarios, SCENARIOS)
        if args.seeds < 1 or args.particles < 1 or args.workers < 1:
            msg = "--seeds, --particles and --workers must be >= 1"
            raise ValueError(msg)
        if args.steps is not None and args.steps < 3:
            msg = f"--steps must be >= 3, got {args.steps}"
            raise ValueError(msg)
        overrides = parse_overrides(args.overrides, scenarios, [args.particles])
    except ValueError as err:
        parser.print_usage(sys.stderr)
        print(f"error: {err}", file=sys.stderr)
        return 2
    cfg = ExperimentConfig(
        seeds=tuple(range(args.seeds)),
        particles=args.particles,
        scenarios=scenarios,
        n_steps=args.steps,
        fixed_friction=not args.no_fixed,
        filter_overrides=dict.fromkeys(scenarios, overrides),
        workers=args.workers,
    )
    command = command_line("python -m dbcslam_research.experiments", argv)
    say = progress_printer(args.quiet)
    say(
        f"DBC-SLAM experiments: scenarios {list(scenarios)}, seeds 0..{args.seeds - 1}, "
        f"{args.particles} particles, {args.workers} worker(s) -> {args.out}"
    )
    t0 = time.perf_counter()
    results = run_experiments(cfg, progress=say)
    elapsed = time.perf_counter() - t0
    paths = write_outputs(results, args.out, command, elapsed, figures=not args.no_figures)
    say("")
    print_checks(evaluate_targets(results.records), say)
    say(f"wrote {len(paths)} files to {args.out} in {elapsed:.0f} s")
    return 0


if __name__ == "__main__":
    sys.exit(main())
