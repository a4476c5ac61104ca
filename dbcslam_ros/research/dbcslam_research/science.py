"""Benchmark of the discrepancy analysis: hidden effects in seeded random draws.

``python -m dbcslam_research.science --out DIR [--draws 30] [--clean 30] [--particles 300]
[--workers 2] [-v]`` (``make science``). Edge scenario as in the paper (point mass, rough
mu 0.9 region between smooth mu 0.3 edge, 1 cm pose noise), data from
`synthetic.edge_sweep_trajectory` (10 s, swept across the regions, two lift-offs): per draw
i one effect uniformly from `synthetic.EDGE_HIDDEN_EFFECTS` at a realistic size
(`synthetic.draw_edge_effect`) hidden in a training run and an independent held-out run;
clean draws hide nothing. Each draw runs `dbcslam_core.discrepancy.analyse` (train on one
run, score on the other) and counts:

* right: the verdict names the hidden effect (mass_scale / input_gain: the pair named
  together, or the hidden one alone) and its parameters are within 25 % (positions within
  2 cm; for the pair the named parameter is compared as k or 1 / k);
* wrong: another effect named, or the right one with a parameter off;
* none: nothing named (on clean draws: the right answer).

Writes ``DIR/science.json`` (every draw) and ``DIR/science.md`` (the table, with the wall
time, the summed CPU time of the filter runs and their number per analysis) after every
draw, so an interrupted run leaves its partial table; progress on stderr. Parts of the
benchmark can run as separate processes (``--start``, ``--draws``, ``--clean``) and be
merged: ``python -m dbcslam_research.science --out DIR --merge PART_DIR ...``.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np

from dbcslam_core.discrepancy import Analysis, DiscrepancyConfig, Run, analyse
from dbcslam_core.extensions import ModelExtension
from dbcslam_core.synthetic import draw_edge_effect, edge_sweep_trajectory

__all__ = ["edge_draw", "main", "recovered"]

PAIR = {"mass_scale", "input_gain"}


def edge_draw(index: int, *, clean: bool, duration: float = 10.0) -> tuple[Run, Run, Any]:
    """Training run, held-out run and the hidden extension (None when clean) of draw i."""
    rng = np.random.default_rng([2026, index, int(clean)])
    ext = None if clean else draw_edge_effect(rng)
    exts = () if ext is None else (ext,)
    seed = int(rng.integers(1_000_000))
    runs = []
    for j in range(2):
        tr = edge_sweep_trajectory(seed + j, duration=duration, extensions=exts)
        runs.append(Run(f"edge-{index}-{j}", tr.scenario, tr.t, tr.obs, tr.u, tr.env_obs))
    return runs[0], runs[1], ext


def _close(name: str, got: float, true: float) -> bool:
    if name in ("x", "y", "x_min", "x_max"):
        return abs(got - true) <= 0.02
    if name == "yaw":
        return abs(got - true) <= 0.01
    return abs(got - true) <= 0.25 * abs(true)


def recovered(res: Analysis, ext: ModelExtension) -> bool:
    """Whether `res` names the hidden `ext` with its parameters (module docstring)."""
    w = res.winner
    if w is None:
        return False
    named = set(res.ambiguous) if res.ambiguous else {w.effect}
    if ext.effect not in named:
        return False
    if len(named) > 1 and named != PAIR:
        return False
    if w.effect == ext.effect:
        return all(_close(k, w.params[k], v) for k, v in ext.params)
    # the pair: mass_scale k and input_gain 1 / k are the same motion
    return _close("factor", 1.0 / w.params["factor"], ext.param("factor"))


def _table(rows: list[dict[str, Any]]) -> str:
    eff = [r for r in rows if not r["clean"]]
    cln = [r for r in rows if r["clean"]]
    right = sum(r["outcome"] == "right" for r in eff)
    wrong = sum(r["outcome"] == "wrong" for r in eff)
    none_ = sum(r["outcome"] == "none" for r in eff)
    clean_none = sum(r["outcome"] == "none" for r in cln)

    def med(key: str) -> float:
        vals = [float(r[key]) for r in rows if r.get(key) is not None]
        return float(np.median(vals)) if vals else float("nan")

    lines = [
        "| scenario | draws | right | wrong | none | right rate | clean runs | none on clean |"
        " median s / analysis | median CPU s | median filter runs |",
        "|---|---|---|---|---|---|---|---|---|---|---|",
        f"| edge (varying friction, 1 cm noise) | {len(eff)} | {right} | {wrong} | {none_} | "
        f"{right / max(len(eff), 1):.0%} | {len(cln)} | {clean_none} "
        f"({clean_none / max(len(cln), 1):.0%}) | {med('seconds'):.0f} | "
        f"{med('cpu_seconds'):.0f} | {med('filter_runs'):.0f} |",
        "",
        "| draw | hidden | verdict | fitted | outcome | s | CPU s | filter runs |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for r in rows:
        cpu = r.get("cpu_seconds")
        lines.append(
            f"| {r['index']}{' (clean)' if r['clean'] else ''} | {r['hidden']} | "
            f"{r['verdict']} | {r['fitted']} | {r['outcome']} | {r['seconds']:.0f} | "
            f"{'' if cpu is None else f'{cpu:.0f}'} | {r.get('filter_runs', '')} |"
        )
    return "\n".join(lines) + "\n"


def _fmt(effect: str, params: dict[str, float]) -> str:
    return effect + " " + ", ".join(f"{k}={v:.4g}" for k, v in sorted(params.items()))


def _say(line: str) -> None:
    print(line, file=sys.stderr, flush=True)


def run(
    out: Path,
    draws: int,
    clean: int,
    cfg: DiscrepancyConfig,
    start: int = 0,
    *,
    verbose: bool = False,
) -> None:
    """Run the benchmark, writing the table after every draw."""
    out.mkdir(parents=True, exist_ok=True)
    rows: list[dict[str, Any]] = []
    plan = [(i, False) for i in range(start, start + draws)]
    plan += [(i, True) for i in range(start, start + clean)]
    # interleave effect and clean draws so that a partial run has both
    plan.sort(key=lambda p: (p[0], p[1]))
    t_all = time.monotonic()
    for n, (i, is_clean) in enumerate(plan):
        train, held, ext = edge_draw(i, clean=is_clean)
        t0 = time.monotonic()
        res = analyse([train], [held], cfg, progress=_say if verbose else None)
        secs = time.monotonic() - t0
        if ext is None:
            outcome = "none" if res.winner is None else "wrong"
        elif res.winner is None:
            outcome = "none"
        else:
            outcome = "right" if recovered(res, ext) else "wrong"
        w = res.winner
        rows.append(
            {
                "index": i,
                "clean": is_clean,
                "hidden": "none" if ext is None else _fmt(ext.effect, dict(ext.params)),
                "verdict": res.verdict,
                "fitted": "" if w is None else _fmt(w.effect, w.params),
                "outcome": outcome,
                "seconds": secs,
                "filter_runs": res.filter_runs,
                "cpu_seconds": res.cpu_seconds,
                "mc_noise": res.mc_noise,
                "candidates": [c.to_dict() for c in res.candidates],
            }
        )
        (out / "science.json").write_text(json.dumps(rows, indent=1) + "\n")
        (out / "science.md").write_text(_table(rows))
        print(
            f"[{n + 1}/{len(plan)}, {time.monotonic() - t_all:.0f} s] draw {i}"
            f"{' clean' if is_clean else ''}: hidden {rows[-1]['hidden']} -> {res.verdict} "
            f"{rows[-1]['fitted']} ({outcome}, {secs:.0f} s, {res.filter_runs} filter runs, "
            f"{res.cpu_seconds:.0f} s CPU)",
            file=sys.stderr,
            flush=True,
        )


def merge(out: Path, parts: list[Path]) -> None:
    """Combine the science.json of benchmark parts (one row per draw) into DIR."""
    rows: dict[tuple[int, bool], dict[str, Any]] = {}
    for part in parts:
        for r in json.loads((part / "science.json").read_text()):
            rows[(int(r["index"]), bool(r["clean"]))] = r
    ordered = [rows[k] for k in sorted(rows, key=lambda k: (k[1], k[0]))]
    out.mkdir(parents=True, exist_ok=True)
    (out / "science.json").write_text(json.dumps(ordered, indent=1) + "\n")
    (out / "science.md").write_text(_table(ordered))
    print(_table(ordered).split("\n\n")[0])


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(
        prog="python -m dbcslam_research.science",
        description=__doc__.split("\n\n")[0] if __doc__ else None,
    )
    ap.add_argument("--out", required=True, type=Path, help="output directory")
    ap.add_argument("--draws", type=int, default=30, help="draws with a hidden effect (30)")
    ap.add_argument("--clean", type=int, default=30, help="clean draws (30)")
    ap.add_argument("--start", type=int, default=0, help="first draw index (0)")
    ap.add_argument("--particles", type=int, default=300, help="scoring filter particles")
    ap.add_argument(
        "--workers",
        type=int,
        default=2,
        help="processes running the filter runs of an analysis in parallel (2)",
    )
    ap.add_argument(
        "-v", "--verbose", action="store_true", help="progress of each analysis (each filter run)"
    )
    ap.add_argument(
        "--merge", nargs="+", type=Path, default=None, help="merge the results of these dirs"
    )
    args = ap.parse_args(argv)
    if args.merge:
        merge(args.out, args.merge)
        return 0
    if args.draws < 0 or args.clean < 0 or args.particles < 1 or args.workers < 1:
        ap.error("--draws/--clean must be >= 0, --particles and --workers >= 1")
    cfg = DiscrepancyConfig(particles=args.particles, pictures=False, workers=args.workers)
    run(args.out, args.draws, args.clean, cfg, args.start, verbose=args.verbose)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
