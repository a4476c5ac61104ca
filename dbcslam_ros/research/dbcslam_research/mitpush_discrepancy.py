"""The discrepancy analysis on the MIT pushes: dynamic vs quasi-static, both splits.

Run ``python -m dbcslam_research.mitpush_discrepancy [DATA_DIR] --out DIR`` (DATA_DIR default
../shared/data/mit-push; reads ``abs/train``). For each push model (``surface.model``:
``dynamic`` and ``quasi_static``) the pushes are imported into bags (``dbcslam
import-mitpush --push-model M``, noise-free Vicon poses) and split by shape: split ``A`` fits
on rect1 + hex and holds out ellip1 + ellip3; split ``B`` the reverse; split ``R`` (``--splits
R``) fits every second push of the round objects (ellip1 + ellip3) and holds out the others.
Then, per split:

1. *Filter noise as a nuisance parameter.* The scoring filter's velocity process noise is
   the preset's (`FilterConfig.preset("push")`: 3 mm/s, 0.1 rad/s per step) times a factor
   from ``--noise-factors``, chosen per model by the training evidence (the filter's summed
   log predictive likelihood, `dbcslam_core.discrepancy.scoring.Scorer`). The two models
   need different noise: a quasi-static object has no velocity state, so its per-step twist
   error does not accumulate the way a velocity error of the dynamic model does.
2. *Dynamic vs quasi-static on data.* Held-out evidence of each nominal model at its own
   fitted noise (log-mean-exp over the filter seeds), one-step prediction and tracking RMSE.
3. *What is still wrong.* The evidence-based ``dbcslam discrepancy`` analysis
   (`dbcslam_ros.offline.discrepancy_report.run_discrepancy`; every candidate effect of the push
   vocabulary fitted on the training shapes, compared on the held-out shapes) with each
   model at its fitted noise; report, JSON and figures per model and split in ``--out``.

``summary.json`` and ``summary.md`` in ``--out`` collect the tables. ``--every N`` keeps
every N-th push of each shape (a faster, smaller run; say so when quoting it).
"""

from __future__ import annotations

import argparse
import json
import math
import subprocess
import sys
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from dbcslam_research.cli import doc_parser

__all__ = ["SPLITS", "DiscrepancyStudy", "add_data_args", "main", "run_study", "split_bags"]

DEFAULT_DATA = Path("../shared/data/mit-push")
SPLITS: dict[str, tuple[tuple[str, ...], tuple[str, ...]]] = {
    "A": (("rect1", "hex"), ("ellip1", "ellip3")),
    "B": (("ellip1", "ellip3"), ("rect1", "hex")),
    "R": (("ellip1", "ellip3"), ("ellip1", "ellip3")),
}
"""Split name -> (training shapes, held-out shapes). Where the two are the same objects
(``R``: the round ones) the pushes alternate: of the shapes' pushes in file-name order
(shape by shape) the 1st, 3rd, ... are fitted and the 2nd, 4th, ... held out, so the
held-out data are new pushes of the same objects (a property of the objects, such as their
support pressure, can be tested there; A and B test what transfers to other shapes)."""
MODELS: tuple[str, ...] = ("dynamic", "quasi_static")


@dataclass(frozen=True)
class DiscrepancyStudy:
    """Settings: data root, output folder, work folder for the bags, scoring particles,
    filter seeds (first: common random numbers for the fits), noise factors searched,
    every-n-th push kept, splits and models run, whether the full analysis runs (else
    only the model comparison), particles of the tracking replays (0: off), candidate
    effects of the analysis (None: the push defaults, `runs.default_effects`)."""

    data: Path = DEFAULT_DATA
    out: Path = Path("out/mitpush_discrepancy")
    work: Path | None = None
    particles: int = 100
    seeds: tuple[int, ...] = (0, 1, 2)
    noise_factors: tuple[float, ...] = (1.0, 3.0, 10.0)
    every: int = 1
    splits: tuple[str, ...] = ("A", "B")
    models: tuple[str, ...] = MODELS
    analyse: bool = True
    filter_particles: int = 0
    effects: tuple[str, ...] | None = None


def _shape(bag: Path) -> str:
    return bag.name.split("shape=")[1].split("_")[0]


def import_bags(data: Path, work: Path, model: str, say: Callable[[str], None]) -> list[Path]:
    """Import every push of ``data/abs/train`` with push model ``model`` (cached in work)."""
    target = work / model
    if not target.exists():
        say(f"importing the pushes with push model {model} into {target}")
        cmd = [
            sys.executable,
            "-m",
            "dbcslam_ros.cli",
            "import-mitpush",
            str(data / "abs" / "train"),
            "-o",
            str(target),
            "--push-model",
            model,
        ]
        subprocess.run(cmd, check=True, capture_output=True)
    return sorted(p for p in target.iterdir() if p.is_dir())


def _subset(bags: Sequence[Path], shapes: Sequence[str], every: int) -> list[Path]:
    out: list[Path] = []
    for s in shapes:
        out += [b for b in bags if _shape(b) == s][::every]
    return out


def split_bags(bags: Sequence[Path], split: str, every: int) -> tuple[list[Path], list[Path]]:
    """(training, held-out) bags of `split` (see `SPLITS`), every `every`-th push kept."""
    fit_shapes, held_shapes = SPLITS[split]
    if fit_shapes == held_shapes:
        pushes = _subset(bags, fit_shapes, every)
        return pushes[::2], pushes[1::2]
    return _subset(bags, fit_shapes, every), _subset(bags, held_shapes, every)


def _noise(factor: float) -> tuple[float, ...]:
    from dbcslam_core.rbpf import FilterConfig

    return tuple(float(factor * x) for x in FilterConfig.preset("push").process_noise)


def _overrides(factor: float) -> tuple[tuple[str, object], ...]:
    return (("process_noise", _noise(factor)),)


def _lme(values: Sequence[float]) -> float:
    fin = [v for v in values if math.isfinite(v)]
    if not fin:
        return -math.inf
    m = max(fin)
    return m + math.log(sum(math.exp(v - m) for v in values) / len(values))


def compare_models(
    runs: dict[str, tuple[list[Any], list[Any]]],
    cfg: DiscrepancyStudy,
    say: Callable[[str], None],
) -> dict[str, Any]:
    """Per model: training evidence per noise factor, the chosen factor, held-out evidence
    over the seeds, one-step prediction and tracking RMSE (runs: model -> (train, held))."""
    from dbcslam_core.discrepancy.analysis import NOMINAL
    from dbcslam_core.discrepancy.scoring import ScoreConfig, Scorer

    out: dict[str, Any] = {}
    for model, (train, held) in runs.items():
        t0 = time.process_time()
        train_ll: dict[float, float] = {}
        for f in cfg.noise_factors:
            sc = Scorer(
                ScoreConfig(
                    particles=cfg.particles, seed=cfg.seeds[0], filter_overrides=_overrides(f)
                )
            )
            train_ll[f] = sc.score(NOMINAL, train).loglik
            say(f"  {model}: noise x{f:g}: training evidence {train_ll[f]:.1f} nats")
        best = max(train_ll, key=lambda f: train_ll[f])
        sc = Scorer(
            ScoreConfig(
                particles=cfg.particles, seed=cfg.seeds[0], filter_overrides=_overrides(best)
            )
        )
        scores = [sc.score(NOMINAL, held, s) for s in cfg.seeds]
        lls = [s.loglik for s in scores]
        out[model] = {
            "train_loglik_by_noise_factor": {str(k): round(v, 2) for k, v in train_ll.items()},
            "noise_factor": best,
            "process_noise": list(_noise(best)),
            "heldout_loglik_seeds": [round(v, 2) for v in lls],
            "heldout_loglik": round(_lme(lls), 2),
            "heldout_pred_rmse_m": scores[0].pred_rmse,
            "heldout_track_rmse_m": scores[0].track_rmse,
            "heldout_observations": scores[0].n_obs,
            "cpu_s": round(time.process_time() - t0, 1),
        }
        say(
            f"  {model}: noise x{best:g}; held-out evidence {_lme(lls):.1f} nats (seeds "
            f"{', '.join(f'{v:.1f}' for v in lls)}), one-step RMSE "
            f"{1e3 * scores[0].pred_rmse:.3f} mm, tracking {1e3 * scores[0].track_rmse:.3f} mm"
        )
    return out


def run_study(cfg: DiscrepancyStudy, say: Callable[[str], None]) -> dict[str, Any]:
    """Import, compare the push models, run the discrepancy analysis; write the summary."""
    import tempfile

    from dbcslam_core.discrepancy import DiscrepancyConfig
    from dbcslam_ros.offline.discrepancy_report import load_run, run_discrepancy

    cfg.out.mkdir(parents=True, exist_ok=True)
    work = cfg.work if cfg.work is not None else Path(tempfile.mkdtemp(prefix="mitpush_disc_"))
    bags = {m: import_bags(cfg.data, work, m, say) for m in cfg.models}
    summary: dict[str, Any] = {"settings": _settings(cfg), "splits": {}}
    for split in cfg.splits:
        fit_shapes, held_shapes = SPLITS[split]
        alternate = " (alternate pushes)" if fit_shapes == held_shapes else ""
        say(
            f"split {split}: fit on {'+'.join(fit_shapes)}, held out {'+'.join(held_shapes)}"
            + alternate
        )
        sel = {m: split_bags(b, split, cfg.every) for m, b in bags.items()}
        runs = {
            m: ([load_run(p) for p in t], [load_run(p) for p in h]) for m, (t, h) in sel.items()
        }
        block: dict[str, Any] = {
            "fit": list(fit_shapes),
            "heldout": list(held_shapes),
            "n_fit": len(next(iter(sel.values()))[0]),
            "n_heldout": len(next(iter(sel.values()))[1]),
            "models": compare_models(runs, cfg, say),
        }
        _write(cfg.out, summary, split, block)
        if cfg.analyse:
            block["analysis"] = {}
            for m, (t, h) in sel.items():
                factor = float(block["models"][m]["noise_factor"])
                dcfg = DiscrepancyConfig(
                    particles=cfg.particles,
                    seed=cfg.seeds[0],
                    noise_seeds=tuple(cfg.seeds[1:]),
                    filter_overrides=_overrides(factor),
                    effects=cfg.effects,
                )
                say(f"  discrepancy analysis, {m} model (noise x{factor:g})")
                _, data = run_discrepancy(
                    t,
                    h,
                    cfg.out / f"{split}_{m}.json",
                    config=dcfg,
                    plots=True,
                    progress=say,
                    filter_particles=cfg.filter_particles,
                )
                block["analysis"][m] = _analysis_row(data)
                _write(cfg.out, summary, split, block)
        _write(cfg.out, summary, split, block)
    return summary


def _write(out: Path, summary: dict[str, Any], split: str, block: dict[str, Any]) -> None:
    """Write summary.json / summary.md with the split's block so far (after every step)."""
    summary["splits"][split] = block
    (out / "summary.json").write_text(json.dumps(summary, indent=2) + "\n")
    (out / "summary.md").write_text(markdown(summary))


def _settings(cfg: DiscrepancyStudy) -> dict[str, Any]:
    return {
        "particles": cfg.particles,
        "seeds": list(cfg.seeds),
        "noise_factors": list(cfg.noise_factors),
        "every": cfg.every,
        "models": list(cfg.models),
        "effects": None if cfg.effects is None else list(cfg.effects),
    }


def _analysis_row(data: dict[str, Any]) -> dict[str, Any]:
    ext = data.get("extended", {})
    return {
        "verdict": data.get("verdict"),
        "effect": ext.get("effect"),
        "params": ext.get("params"),
        "stderr": ext.get("stderr"),
        "gain": data.get("gain"),
        "loglik_gain": data.get("loglik_gain"),
        "tracking_gain": data.get("tracking_gain"),
        "nominal_heldout_rmse": data.get("nominal", {}).get("heldout_rmse"),
        "extended_heldout_rmse": ext.get("heldout_rmse"),
        "candidates": [
            {
                k: c.get(k)
                for k in ("effect", "params", "stderr", "delta_loglik", "heldout_rmse", "note")
            }
            for c in data.get("candidates", [])
        ],
    }


def _mm(x: Any) -> str:
    return "-" if x is None or not math.isfinite(float(x)) else f"{1e3 * float(x):.3f}"


def markdown(summary: dict[str, Any]) -> str:
    """The summary tables (model comparison; discrepancy verdicts)."""
    lines = [
        "# MIT pushes: dynamic vs quasi-static, and what is still wrong",
        "",
        f"Settings: {json.dumps(summary['settings'])}",
        "",
        "| split (fit -> held out) | model | noise factor (fitted) | training evidence (nats) "
        "| held-out evidence (nats) | held-out one-step RMSE (mm) | held-out tracking RMSE (mm) |",
        "|---|---|---|---|---|---|---|",
    ]
    for name, b in summary["splits"].items():
        fit, held = "+".join(b["fit"]), "+".join(b["heldout"])
        label = f"{name}: {fit} ({b['n_fit']}) -> {held} ({b['n_heldout']})"
        if fit == held:
            label += ", alternate pushes"
        for m, r in b["models"].items():
            f = r["noise_factor"]
            lines.append(
                f"| {label} | {m} | x{f:g} | {r['train_loglik_by_noise_factor'][str(f)]:.1f} | "
                f"{r['heldout_loglik']:.1f} | {_mm(r['heldout_pred_rmse_m'])} | "
                f"{_mm(r['heldout_track_rmse_m'])} |"
            )
    if any("analysis" in b for b in summary["splits"].values()):
        lines += [
            "",
            "| split | model | verdict | estimate +- stderr | held-out RMSE gain | "
            "log-likelihood gain (nats) | tracking gain |",
            "|---|---|---|---|---|---|---|",
        ]
        for name, b in summary["splits"].items():
            for m, a in b.get("analysis", {}).items():
                est = ", ".join(
                    f"{k} = {v:.4g} +- {(a.get('stderr') or {}).get(k) or float('nan'):.2g}"
                    for k, v in (a.get("params") or {}).items()
                )
                lines.append(
                    f"| {name} | {m} | {a['verdict']} | {est or '-'} | {a['gain']} | "
                    f"{a['loglik_gain']} | {a['tracking_gain']} |"
                )
    return "\n".join(lines) + "\n"


def add_data_args(p: argparse.ArgumentParser) -> None:
    """The arguments of the MIT push studies: dataset root, --out, --work, --particles."""
    p.add_argument("data", nargs="?", type=Path, default=DEFAULT_DATA, help="dataset root")
    p.add_argument("--out", type=Path, required=True, help="output folder")
    p.add_argument("--work", type=Path, default=None, help="folder for the bags (default temp)")
    p.add_argument("--particles", type=int, default=100, help="scoring particles (100)")


def _parser() -> argparse.ArgumentParser:
    p = doc_parser("dbcslam_research.mitpush_discrepancy", __doc__)
    add_data_args(p)
    p.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2], help="filter seeds")
    p.add_argument(
        "--noise-factors",
        type=float,
        nargs="+",
        default=[1.0, 3.0, 10.0],
        help="process-noise factors searched per model (1 3 10)",
    )
    p.add_argument("--every", type=int, default=1, help="keep every N-th push per shape (1)")
    p.add_argument("--splits", nargs="+", default=["A", "B"], choices=sorted(SPLITS))
    p.add_argument("--models", nargs="+", default=list(MODELS), choices=MODELS)
    p.add_argument(
        "--effects", nargs="+", default=None, help="candidate effects (default: the push set)"
    )
    p.add_argument("--compare-only", action="store_true", help="skip the discrepancy analysis")
    p.add_argument(
        "--filter",
        type=int,
        default=0,
        metavar="PARTICLES",
        help="also replay the held-out bags with the filter node (tracking gain; 0 = off)",
    )
    return p


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point; exit 0 on success, 2 on bad usage."""
    args = _parser().parse_args(argv)
    if args.particles < 1 or args.every < 1 or not args.seeds:
        print("error: --particles and --every must be >= 1, --seeds non-empty", file=sys.stderr)
        return 2
    cfg = DiscrepancyStudy(
        data=args.data,
        out=args.out,
        work=args.work,
        particles=args.particles,
        seeds=tuple(args.seeds),
        noise_factors=tuple(args.noise_factors),
        every=args.every,
        splits=tuple(args.splits),
        models=tuple(args.models),
        analyse=not args.compare_only,
        filter_particles=args.filter,
        effects=None if args.effects is None else tuple(args.effects),
    )
    t0 = time.monotonic()
    run_study(cfg, lambda s: print(s, file=sys.stderr, flush=True))
    print(f"wrote {cfg.out / 'summary.md'} ({time.monotonic() - t0:.0f} s)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
