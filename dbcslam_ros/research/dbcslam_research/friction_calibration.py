"""How DBC-SLAM's final jaw-friction posterior compares with what the data say, run by run.

``python -m dbcslam_research.friction_calibration --evidence DIR/gripper_evidence.json``
runs DBC-SLAM (the gripper preset at each ``--particles`` count, filter seed = run number
as in `experiments_sim`, optional ``--set`` `FilterConfig` overrides) on the pybullet runs
that `gripper_evidence` measured, with the same simulator overrides, and compares its final
friction posterior with each run's *verdict*: the (near-)exact posterior P(mu | o) from the
fixed-friction filters' log-evidence at that report's largest particle count (its section 3).

Issue 10 asks for a final P(true mu) >= 0.9 on every run. Where the data themselves give the
true coefficient less than 0.9, a filter that ends above 0.9 is lucky or overconfident, so
the report separates, per particle count:

* *right where the data decide*: P(true) >= 0.9 on the runs whose verdict is >= 0.9;
* *confident where the data are not*: max_mu P >= 0.9 on the runs whose verdict is < 0.9;
* *confidently wrong*: max_mu P >= 0.9 on a wrong coefficient;
* *calibration gap*: mean |P(true) - verdict P(true)| over the runs.

Writes ``friction_calibration.md`` and ``.json`` into ``--out`` (default: the evidence
report's directory, with ``--set`` a ``calibration_KEY=VALUE`` folder in it) and prints the
table.
"""

from __future__ import annotations

import argparse
import json
import statistics
import sys
import time
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from dbcslam_core.experiments import run_dbcslam
from dbcslam_research.cli import pool_map, settings_dirname
from dbcslam_research.experiments import (
    add_set_argument,
    command_line,
    parse_overrides,
    progress_printer,
    utc_now,
    write_json,
)
from dbcslam_research.gripper_evidence import SimSet, grasp_run

__all__ = [
    "CONFIDENT",
    "compare",
    "default_out",
    "final_posteriors",
    "load_verdicts",
    "main",
    "render_markdown",
]

CONFIDENT = 0.9
"""The probability issue 10's target asks for (final P(true mu) >= 0.9)."""


def load_verdicts(path: Path) -> dict[str, Any]:
    """The verdicts of a `gripper_evidence` JSON report: {"sim_set", "verdicts",
    "verdict_particles", "candidates"}; raises ValueError naming the file when it cannot be
    read or has no section 3 (reports written before it existed)."""
    try:
        data = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, json.JSONDecodeError) as err:
        msg = f"--evidence {path}: cannot read a gripper_evidence JSON report ({err})"
        raise ValueError(msg) from err
    if not isinstance(data, dict) or not data.get("verdicts"):
        msg = (
            f"--evidence {path}: no per-run verdicts (section 3); re-run "
            "`python -m dbcslam_research.gripper_evidence` to write them"
        )
        raise ValueError(msg)
    return {  # JSON lists back to tuples: simulator values such as start = (x, y, yaw)
        "sim_set": {k: _tuples(v) for k, v in dict(data.get("sim_set", {})).items()},
        "verdicts": data["verdicts"],
        "verdict_particles": data["verdict_particles"],
        "candidates": data["cause"]["candidates"],
    }


def _tuples(value: Any) -> Any:
    """`value` with every list turned into a tuple (hashable, as the simulator expects)."""
    return tuple(_tuples(v) for v in value) if isinstance(value, list) else value


def default_out(evidence: Path, overrides: Mapping[str, Any]) -> Path:
    """The evidence report's directory, or for filter overrides a subdirectory named after
    them (so that a variant does not overwrite the preset's report)."""
    if not overrides:
        return evidence.parent
    return evidence.parent / settings_dirname("calibration_", overrides)


def _final_task(args: tuple[int, int, SimSet, tuple[tuple[str, Any], ...]]) -> dict[str, Any]:
    """DBC-SLAM's final friction posterior (pair 0) on pybullet run `run`."""
    run, particles, sim_set, overrides = args
    tr = grasp_run(run, None, sim_set)
    trace = run_dbcslam(tr, seed=run, particles=particles, overrides=dict(overrides))
    return {
        "run": run,
        "particles": particles,
        "posterior": [float(x) for x in trace.friction_post[-1]],
        "true": trace.true_friction_index,
    }


def final_posteriors(
    runs: Sequence[int],
    particles: Sequence[int],
    *,
    sim_set: SimSet,
    overrides: Mapping[str, Any],
    workers: int,
    say: Callable[[str], None],
) -> list[dict[str, Any]]:
    """One row per (particle count, run): DBC-SLAM's final friction posterior."""
    ov = tuple(sorted(overrides.items()))
    tasks = [(r, p, sim_set, ov) for p in particles for r in runs]
    return pool_map(_final_task, tasks, workers, say, "DBC-SLAM (runs)")


def compare(
    verdicts: Sequence[Mapping[str, Any]], finals: Sequence[Mapping[str, Any]]
) -> list[dict[str, Any]]:
    """Per particle count of `finals`: the counts and the calibration gap of the module
    docstring (a final without a verdict, or with another true coefficient, is an error)."""
    by_run = {int(v["run"]): v for v in verdicts}
    counts = sorted({int(f["particles"]) for f in finals})
    out: list[dict[str, Any]] = []
    for p in counts:
        rows = [f for f in finals if int(f["particles"]) == p]
        missing = sorted(int(f["run"]) for f in rows if int(f["run"]) not in by_run)
        if missing:
            msg = f"runs {missing} have no verdict in the evidence report"
            raise ValueError(msg)
        other = sorted(
            int(f["run"]) for f in rows if int(f["true"]) != int(by_run[int(f["run"])]["true"])
        )
        if other:  # e.g. a simulator override that did not reach the simulation
            msg = (
                f"runs {other}: the filter's true coefficient is not the evidence report's; "
                "the runs differ from the ones the verdicts were measured on"
            )
            raise ValueError(msg)
        right = decided = confident_undecided = confidently_wrong = ends_right = 0
        gaps: list[float] = []
        off: list[dict[str, Any]] = []
        for f in sorted(rows, key=lambda f: int(f["run"])):
            v = by_run[int(f["run"])]
            post = np.asarray(f["posterior"], dtype=np.float64)
            true = int(v["true"])
            p_true = float(post[true])
            top = int(np.argmax(post))
            confident = float(post[top]) >= CONFIDENT
            ends_right += p_true >= CONFIDENT
            if v["p_true"] >= CONFIDENT:
                decided += 1
                right += p_true >= CONFIDENT
            else:
                confident_undecided += confident
            confidently_wrong += confident and top != true
            gap = p_true - float(v["p_true"])
            gaps.append(abs(gap))
            if abs(gap) > 0.5:
                off.append({"run": int(f["run"]), "p_true": p_true, "verdict": float(v["p_true"])})
        out.append(
            {
                "particles": p,
                "runs": len(rows),
                "ends_right": ends_right,
                "decided": decided,
                "right_where_decided": right,
                "undecided": len(rows) - decided,
                "confident_where_undecided": confident_undecided,
                "confidently_wrong": confidently_wrong,
                "calibration_gap": statistics.mean(gaps) if gaps else float("nan"),
                "off_by_more_than_half": off,
            }
        )
    return out


def render_markdown(result: Mapping[str, Any], command: str) -> str:
    """The report as Markdown."""
    sim = ", ".join(f"{k}={v!r}" for k, v in result["sim_set"].items()) or "none"
    over = ", ".join(f"{k}={v!r}" for k, v in result["overrides"].items()) or "none"
    lines = [
        "# DBC-SLAM's final jaw-friction posterior against the data's verdict",
        "",
        f"Command: `{command}`  ",
        f"Date: {result['date']}; {result['wall_s']:.0f} s wall; evidence: "
        f"`{result['evidence']}` (verdicts from {result['verdict_particles']}-particle "
        f"fixed-friction filters); simulator overrides: {sim}; filter overrides: {over}.",
        "",
        f"'ends right': final P(true mu) >= {CONFIDENT} (issue 10's target); 'decided': runs "
        f"whose verdict gives the true mu >= {CONFIDENT}; 'confident': max P >= {CONFIDENT}; "
        "'gap': mean |P(true) - verdict P(true)|; 'off by > 0.5': run (DBC-SLAM / verdict).",
        "",
        "| particles | runs | ends right | decided: right | undecided: confident | "
        "confidently wrong | gap | off by > 0.5 |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for c in result["comparison"]:
        off = ", ".join(
            f"{o['run']} ({o['p_true']:.2f} / {o['verdict']:.2f})"
            for o in c["off_by_more_than_half"]
        )
        lines.append(
            f"| {c['particles']} | {c['runs']} | {c['ends_right']} | "
            f"{c['right_where_decided']} of {c['decided']} | "
            f"{c['confident_where_undecided']} of {c['undecided']} | "
            f"{c['confidently_wrong']} | {c['calibration_gap']:.2f} | {off or '-'} |"
        )
    return "\n".join(lines) + "\n"


def main(argv: Sequence[str] | None = None) -> int:
    """Command line (see the module docstring)."""
    p = argparse.ArgumentParser(
        prog="python -m dbcslam_research.friction_calibration",
        description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
        epilog="example: python -m dbcslam_research.friction_calibration --evidence "
        "dbcslam_ros/research/results/gripper_evidence/jaw_mu_0.7/gripper_evidence.json "
        "--particles 40 500",
    )
    p.add_argument(
        "--evidence", type=Path, required=True, help="a gripper_evidence.json with verdicts"
    )
    p.add_argument("--particles", type=int, nargs="+", default=[40, 500], help="(40 500)")
    add_set_argument(p)
    p.add_argument("--workers", type=int, default=2, help="processes (2)")
    p.add_argument(
        "--out",
        type=Path,
        default=None,
        help="output dir (the evidence's dir; with --set a calibration_KEY=VALUE subdir)",
    )
    p.add_argument("--quiet", action="store_true", help="no progress lines or table")
    a = p.parse_args(argv)
    if a.workers < 1 or min(a.particles) < 1:
        p.error(f"--workers and --particles must be >= 1, got {a.workers}, {a.particles}")
    try:
        ev = load_verdicts(a.evidence)
        overrides = parse_overrides(a.overrides, ["gripper"], a.particles)
    except ValueError as err:
        p.error(str(err))
    say = progress_printer(a.quiet)
    t0 = time.perf_counter()
    runs = [int(v["run"]) for v in ev["verdicts"]]
    sim_set: SimSet = tuple(sorted(ev["sim_set"].items()))
    finals = final_posteriors(
        runs, a.particles, sim_set=sim_set, overrides=overrides, workers=a.workers, say=say
    )
    result: dict[str, Any] = {
        "date": utc_now(),
        "evidence": str(a.evidence),
        "sim_set": ev["sim_set"],
        "overrides": overrides,
        "verdict_particles": ev["verdict_particles"],
        "finals": finals,
        "comparison": compare(ev["verdicts"], finals),
        "wall_s": time.perf_counter() - t0,
    }
    out = a.out if a.out is not None else default_out(a.evidence, overrides)
    out.mkdir(parents=True, exist_ok=True)
    md = render_markdown(
        result, command_line("python -m dbcslam_research.friction_calibration", argv)
    )
    (out / "friction_calibration.md").write_text(md, encoding="utf-8")
    write_json(out / "friction_calibration.json", result)
    if not a.quiet:
        print(md)
    return 0


if __name__ == "__main__":
    sys.exit(main())
