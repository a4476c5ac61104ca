"""Regenerate the README's "Results" section from the files `make experiments` / `make bench`
wrote.

The part of ``README.md`` between the lines ``<!-- results:begin -->`` and
``<!-- results:end -->`` is replaced by Markdown built from the results directory
(default ``dbcslam_ros/research/results``):

* the target table of the synthetic paper experiments (``experiments.json``, written by
  ``python -m dbcslam_research.experiments``),
* the target table of the pybullet experiments if present (``sim/experiments_sim.json``,
  ``python -m dbcslam_research.experiments_sim``),
* the benchmark tables (``bench.md``, ``python -m dbcslam_research.bench``; ``bench_live.md``,
  ``python -m dbcslam_research.bench_live``, if present), headings demoted,
* every PNG figure of those directories: the ``*_overview.png`` figures embedded, the single
  panels linked, each with a one-line caption saying what it shows,

each with the command that produced it and its date (``date_utc`` of the JSON file, else the
file's modification time). Paths are relative to the README's directory. Nothing else in the
README changes; without both markers (in that order) the README is left alone and a message
says so. The output depends only on the results files, so running it twice changes nothing.

Usage:
``python -m dbcslam_research.readme_results [--readme README.md] [--results DIR] [--check]``.
Exit codes: 0 (written, unchanged, or markers absent), 1 (``--check`` and the section is out
of date), 2 (bad arguments, README missing, unreadable results file).
"""

from __future__ import annotations

import argparse
import datetime as dt
import json
import math
import os
import re
import sys
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from dbcslam_ros.errors import UsageError

__all__ = [
    "DEFAULT_README",
    "DEFAULT_RESULTS",
    "MARKER_BEGIN",
    "MARKER_END",
    "figure_caption",
    "main",
    "render_results",
    "replace_between_markers",
    "update_readme",
]

MARKER_BEGIN = "<!-- results:begin -->"
MARKER_END = "<!-- results:end -->"
DEFAULT_README = Path("README.md")
DEFAULT_RESULTS = Path("dbcslam_ros/research/results")

_SCENARIO_NAMES: dict[str, str] = {
    "edge": "Edge (table polishing)",
    "gripper": "Parallel-jaw gripper",
    "push": "Planar push",
    "push_offcentre": "Planar push, off-centre",
}

# (scenario or "" for any, figure kind) -> what the figure shows
_CAPTIONS: dict[tuple[str, str], str] = {
    ("edge", "overview"): "x-y path, x over time, friction map along the edge, P(contact), "
    "P(sticking | contact) and friction posterior over time, truth shaded; representative seed "
    "(median DBC-SLAM position RMSE)",
    ("gripper", "overview"): "centre-of-mass path, yaw, jaw friction posterior and live "
    "contact-mode hypotheses per particle; representative seed (median DBC-SLAM position RMSE)",
    ("push", "overview"): "object path, yaw, pusher friction posterior, P(pusher contact) and "
    "P(sticking | contact), truth shaded; representative seed (median DBC-SLAM position RMSE)",
    ("", "overview"): "all panels of the representative seed (median DBC-SLAM position RMSE)",
    ("edge", "trajectory"): "x-y path of the point mass: truth, observations, DBC-SLAM and "
    "the better fixed-friction baseline; rough (high-friction) region shaded",
    ("", "trajectory"): "x-y path of the object's centre of mass: truth, observations, "
    "DBC-SLAM estimate",
    ("", "x_time"): "x over time: truth, observations, DBC-SLAM and the fixed-friction "
    "baseline; true sticking shaded",
    ("edge", "contact"): "estimated P(contact) of the edge contact; true contact shaded",
    ("", "contact"): "estimated P(pusher contact) and P(sticking | contact); truth shaded",
    ("", "sticking"): "estimated P(sticking | contact); true sticking shaded",
    ("edge", "friction"): "friction posterior over time (left) and the final friction map "
    "along the edge (right); rough region shaded",
    ("gripper", "friction"): "posterior of the jaw friction candidates over time (true mu = 0.4)",
    ("", "friction"): "posterior of the pusher friction candidates over time",
    ("", "com"): "centre-of-mass path between the jaws: truth, observations, DBC-SLAM estimate",
    ("", "yaw"): "object yaw over time: truth, observations, DBC-SLAM estimate",
    ("", "hypotheses"): "live joint contact-mode hypotheses per particle over time (of "
    "4^6 = 4096 joint modes)",
}
_KINDS: tuple[str, ...] = (
    "overview",
    "trajectory",
    "x_time",
    "contact",
    "sticking",
    "friction",
    "com",
    "yaw",
    "hypotheses",
)


# ------------------------------------------------------------------------------ pieces
def figure_caption(name: str) -> str:
    """One-line caption of a figure file name such as ``edge_friction.png`` or
    ``sim_push_offcentre_yaw.png`` (``sim_`` prefix = pybullet data, else synthetic)."""
    stem = name.removesuffix(".png")
    source = "pybullet" if stem.startswith("sim_") else "synthetic"
    stem = stem.removeprefix("sim_")
    kind = next((k for k in _KINDS if stem.endswith(f"_{k}")), "")
    scen = stem[: -len(kind) - 1] if kind else stem
    base = scen.split("_", 1)[0]
    what = _CAPTIONS.get((base, kind)) or _CAPTIONS.get(("", kind)) or f"figure {name}"
    return f"{_SCENARIO_NAMES.get(scen, scen)} ({source} data): {what}."


def _fmt(x: Any) -> str:
    if x is None or (isinstance(x, float) and not math.isfinite(x)):
        return "n/a"
    if isinstance(x, bool) or not isinstance(x, int | float):
        return str(x)
    if abs(x) >= 1000:
        return f"{x:.0f}"
    return f"{x:.3f}"


def _load_json(path: Path) -> dict[str, Any]:
    try:
        data = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, json.JSONDecodeError) as err:
        msg = f"cannot read results file {path}: {err}"
        raise UsageError(msg) from err
    if not isinstance(data, dict):
        msg = f"results file {path} holds a {type(data).__name__}, expected a JSON object"
        raise UsageError(msg)
    return data


def _date(path: Path, data: dict[str, Any] | None) -> str:
    for src in (data or {}, (data or {}).get("meta") or {}):
        if isinstance(src, dict) and src.get("date_utc"):
            return str(src["date_utc"])
    ts = dt.datetime.fromtimestamp(path.stat().st_mtime, dt.UTC)
    return ts.strftime("%Y-%m-%d %H:%M UTC") + " (file time)"


def _command(data: dict[str, Any]) -> str | None:
    for src in (data, data.get("meta") or {}):
        if isinstance(src, dict) and src.get("command"):
            return str(src["command"])
    return None


def _rel(path: Path, base: Path) -> str:
    return Path(os.path.relpath(path.resolve(), base.resolve())).as_posix()


def _targets_section(
    title: str, path: Path, readme_dir: Path, what: str, level: str = "###"
) -> list[str]:
    data = _load_json(path)
    cmd = _command(data)
    md = path.with_suffix(".md")
    lines = [f"{level} {title}", ""]
    meta = [f"Produced by `{cmd}`" if cmd else "Command not recorded", f"on {_date(path, data)}"]
    if isinstance(data.get("elapsed_s"), int | float):
        meta.append(f"wall time {data['elapsed_s']:.0f} s")
    if isinstance(data.get("loadavg_1min"), int | float):
        meta.append(f"1-min load average {data['loadavg_1min']:.1f}")
    lines.append(", ".join(meta) + f". {what}")
    if md.is_file():
        lines.append(
            f"Full report (medians per method, per-seed values): [{md.name}]"
            f"({_rel(md, readme_dir)})."
        )
    lines += ["", "| scenario | target | median | threshold | verdict |", "|---|---|---|---|---|"]
    for t in data.get("targets") or []:
        op = t.get("op", "")
        thr = "-" if op == "report" else f"{op} {_fmt(t.get('threshold'))}"
        passed = t.get("passed")
        verdict = "report" if passed is None else ("PASS" if passed else "FAIL")
        lines.append(
            f"| {t.get('scenario', '?')} | {t.get('target', '?')} | {_fmt(t.get('value'))} "
            f"| {thr} | {verdict} |"
        )
    return [*lines, ""]


def _markdown_body(path: Path, level_shift: int) -> list[str]:
    """`path`'s Markdown without its ``# title`` line, headings demoted by `level_shift`."""
    out: list[str] = []
    for i, line in enumerate(path.read_text(encoding="utf-8").splitlines()):
        if i == 0 and line.startswith("# "):
            continue
        m = re.match(r"^(#+) ", line)
        out.append("#" * level_shift + line if m else line)
    while out and not out[0].strip():
        out.pop(0)
    while out and not out[-1].strip():
        out.pop()
    return [*out, ""]


def _figures_section(fig_dir: Path, readme_dir: Path) -> list[str]:
    pngs = sorted(fig_dir.glob("*.png"))
    if not pngs:
        return []
    lines: list[str] = []
    overviews = [p for p in pngs if p.stem.endswith("_overview")]
    for p in overviews:
        cap = figure_caption(p.name)
        lines += [f"![{cap}]({_rel(p, readme_dir)})", "", f"*{cap}*", ""]
    singles = [p for p in pngs if p not in overviews]
    if singles:
        lines.append("Single panels:")
        lines.append("")
        lines += [
            f"- [{p.name}]({_rel(p, readme_dir)}): {figure_caption(p.name)}" for p in singles
        ]
        lines.append("")
    return lines


def render_results(results_dir: Path, readme_dir: Path) -> str:
    """The generated Markdown (without the markers) from the files in `results_dir`; links
    are relative to `readme_dir`."""
    res = results_dir
    lines = [
        "<!-- generated by `python -m dbcslam_research.readme_results`; do not edit -->",
        "",
        "Regenerate with `make experiments` (synthetic + pybullet experiments) and "
        "`make bench` (speed); both end with `python -m dbcslam_research.readme_results`, which "
        "writes this section. Values are medians over seeds; position/yaw RMSE are relative to "
        "the observation noise std (per axis).",
        "",
    ]
    exp = res / "experiments.json"
    if exp.is_file():
        lines += _targets_section(
            "Paper experiments on synthetic data (issue 3)",
            exp,
            readme_dir,
            "Ground truth from the filter's own contact model (`dbcslam_core.synthetic`).",
        )
        lines += _figures_section(res, readme_dir)
    else:
        lines += ["(no synthetic results yet: run `make experiments`)", ""]
    sim = res / "sim" / "experiments_sim.json"
    if sim.is_file():
        lines += _targets_section(
            "DBC-SLAM on pybullet data (issue 4)",
            sim,
            readme_dir,
            "Ground truth, observations and inputs from the pybullet simulator, whose contact "
            "model is not the filter's.",
        )
        lines += _figures_section(sim.parent, readme_dir)
    for name, title in (
        ("bench.md", "Speed: DBC-SLAM vs a black-box NCP particle filter"),
        ("bench_live.md", "Live timing (filter node next to the simulator)"),
    ):
        path = res / name
        if path.is_file():
            data = (
                _load_json(path.with_suffix(".json"))
                if path.with_suffix(".json").is_file()
                else None
            )
            body = _markdown_body(path, level_shift=2)
            lines += [f"### {title}", ""]
            if not any(re.search(r"\d{4}-\d{2}-\d{2}", ln) for ln in body[:5]):
                lines += [f"Date: {_date(path, data)}.", ""]  # the report states none
            lines += body
    return "\n".join(lines).rstrip() + "\n"


def replace_between_markers(text: str, block: str) -> str | None:
    """`text` with the lines strictly between the marker lines replaced by `block`; None if a
    marker is missing or the end marker comes first."""
    begin = text.find(MARKER_BEGIN)
    end = text.find(MARKER_END, begin + len(MARKER_BEGIN)) if begin >= 0 else -1
    if begin < 0 or end < 0:
        return None
    head = text[: begin + len(MARKER_BEGIN)]
    return head + "\n" + block.rstrip("\n") + "\n" + text[end:]


def update_readme(readme: Path, results_dir: Path, *, check: bool = False) -> str:
    """Rewrite `readme`'s results section; returns ``"updated"``, ``"unchanged"``,
    ``"outdated"`` (only with `check`: nothing written) or ``"no-markers"``."""
    try:
        text = readme.read_text(encoding="utf-8")
    except OSError as err:
        msg = f"cannot read README {readme}: {err}"
        raise UsageError(msg) from err
    new = replace_between_markers(text, render_results(results_dir, readme.parent))
    if new is None:
        return "no-markers"
    if new == text:
        return "unchanged"
    if check:
        return "outdated"
    readme.write_text(new, encoding="utf-8")
    return "updated"


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point; returns the exit code."""
    p = argparse.ArgumentParser(
        prog="python -m dbcslam_research.readme_results",
        description="Rewrite the README section between "
        f"'{MARKER_BEGIN}' and '{MARKER_END}' from the generated result files.",
    )
    p.add_argument("--readme", type=Path, default=DEFAULT_README, help=f"({DEFAULT_README})")
    p.add_argument(
        "--results", type=Path, default=DEFAULT_RESULTS, help=f"results dir ({DEFAULT_RESULTS})"
    )
    p.add_argument(
        "--check", action="store_true", help="write nothing; exit 1 if the section is outdated"
    )
    args = p.parse_args(argv)
    try:
        state = update_readme(args.readme, args.results, check=args.check)
    except UsageError as err:
        print(f"error: {err}", file=sys.stderr)
        return 2
    if state == "no-markers":
        print(f"{args.readme}: markers {MARKER_BEGIN} ... {MARKER_END} not found; nothing changed")
        return 0
    print(f"{args.readme}: results section {state} (from {args.results})")
    return 1 if state == "outdated" else 0


if __name__ == "__main__":
    sys.exit(main())
