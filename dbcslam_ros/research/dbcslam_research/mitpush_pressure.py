"""Why the pushes' kinematics favour a lower support friction than their F/T force says.

Run ``python -m dbcslam_research.mitpush_pressure [DATA_DIR] --out DIR`` (DATA_DIR default
../shared/data/mit-push). On the MIT pushes the filter's evidence prefers the low support
coefficients of its candidates (0.1-0.3) while the F/T force of the sliding objects says
mu_s ~ 0.4-0.45 (|F| / m g, a lower bound). This study scores, on every push (noise-free
Vicon poses, the dynamic push model, `dbcslam_core.discrepancy.scoring.Scorer`: the filter's
summed log predictive likelihood), the nominal model against variants that fix the support
coefficient at the F/T value and then change one other part of the model:

* the support pressure distribution: `support_concentration` (``centre_fraction`` of the
  weight at the centre of mass, the rest uniform over the outline: the limit surface's
  moment ratio c shrinks to about (1 - centre_fraction) c_uniform);
* the pusher-object friction candidates (wider, up to 0.8);

and the same concentration at a low coefficient (0.12), to read how much of the gap between
the low and the F/T coefficient the pressure closes, per shape.

Per push and per shape, the evidence of each variant relative to the nominal model (nats)
goes to ``pressure.json`` and ``pressure.md`` in ``--out``. Reading: the variant that takes
back most of what fixing mu_s at the F/T value costs is the part of the model the low
coefficients were standing in for.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import sys
import tempfile
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from dbcslam_core.discrepancy import Run
from dbcslam_core.discrepancy.effects import Hypothesis
from dbcslam_core.discrepancy.scoring import ScoreConfig, Scorer
from dbcslam_research.cli import doc_parser
from dbcslam_research.mitpush_discrepancy import add_data_args, import_bags

__all__ = ["VARIANTS", "Variant", "main", "score_variants", "with_candidates"]

FT_SUPPORT_MU = 0.45
"""Support coefficient the F/T force gives while the objects slide (|F| / m g, median 0.42-0.45
for hex and ellip3, `mitpush_eval`)."""

LOW_SUPPORT_MU = 0.12
"""A low support coefficient, where the kinematic evidence of the pushes peaks (the
`support_friction` walk of the evidence analysis: 0.12 best of 0.05 / 0.12 / 0.25 / 0.45)."""


@dataclass(frozen=True)
class Variant:
    """A model variant: candidates of the support (``surface``) and pusher pairs (None: the
    bag's), and a support concentration (centre_fraction; None: the bag's pressure)."""

    name: str
    surface: tuple[float, ...] | None = None
    pusher: tuple[float, ...] | None = None
    centre_fraction: float | None = None

    def hypothesis(self) -> Hypothesis:
        if self.centre_fraction is None:
            return Hypothesis()
        return Hypothesis.make("support_concentration", {"centre_fraction": self.centre_fraction})


WIDE_PUSHER = (0.2, 0.4, 0.6, 0.8)
VARIANTS: tuple[Variant, ...] = (
    Variant("nominal"),
    Variant("mu_s = 0.12", surface=(LOW_SUPPORT_MU,)),
    Variant("mu_s = 0.12, centre 0.5", surface=(LOW_SUPPORT_MU,), centre_fraction=0.5),
    Variant("mu_s = F/T", surface=(FT_SUPPORT_MU,)),
    Variant("mu_s = F/T, centre 0.3", surface=(FT_SUPPORT_MU,), centre_fraction=0.3),
    Variant("mu_s = F/T, centre 0.5", surface=(FT_SUPPORT_MU,), centre_fraction=0.5),
    Variant("mu_s = F/T, centre 0.7", surface=(FT_SUPPORT_MU,), centre_fraction=0.7),
    Variant("mu_s = F/T, pusher 0.2-0.8", surface=(FT_SUPPORT_MU,), pusher=WIDE_PUSHER),
    Variant("nominal, centre 0.5", centre_fraction=0.5),
    Variant("nominal, pusher 0.2-0.8", pusher=WIDE_PUSHER),
)
"""The variants scored (first: the reference)."""


def with_candidates(run: Run, **pairs: tuple[float, ...] | None) -> Run:
    """`run` with the friction candidates of the named pairs replaced (uniform prior); a
    pair given as None keeps its candidates. Unknown pair names raise `ScenarioError`."""
    fr = run.scenario.friction
    cands, prior = list(fr.candidates), list(fr.prior)
    for name, values in pairs.items():
        if values is None:
            continue
        i = fr.pair_index(name)
        cands[i] = tuple(float(v) for v in values)
        prior[i] = tuple(1.0 / len(values) for _ in values)
    friction = dataclasses.replace(fr, candidates=tuple(cands), prior=tuple(prior))
    return dataclasses.replace(run, scenario=dataclasses.replace(run.scenario, friction=friction))


def score_variants(
    runs: Sequence[Run],
    scorer: Scorer,
    variants: Sequence[Variant] = VARIANTS,
    say: Callable[[str], None] = lambda s: None,
) -> dict[str, list[float]]:
    """Evidence (nats, `ScoreConfig.skip` steps left out) of every variant on every run."""
    out: dict[str, list[float]] = {v.name: [] for v in variants}
    for k, run in enumerate(runs):
        for v in variants:
            r = with_candidates(run, surface=v.surface, pusher=v.pusher)
            out[v.name].append(scorer.trace(v.hypothesis(), r).loglik_from(scorer.cfg.skip))
        say(f"[{k + 1}/{len(runs)}] {run.name}")
    return out


def summarise(names: Sequence[str], scores: dict[str, list[float]]) -> dict[str, Any]:
    """Per variant: evidence relative to the first variant, in total and per shape (names:
    the runs' bags, named after their MIT push files)."""
    from dbcslam_ros.importers.mitpush import parse_push_name

    shape_of = {n: parse_push_name(n).shape for n in names}
    ref = next(iter(scores.values()))
    shapes = sorted({shape_of[n] for n in names})
    table: dict[str, Any] = {}
    for v, vals in scores.items():
        delta = [a - b for a, b in zip(vals, ref, strict=True)]
        per = {
            s: sum(d for d, n in zip(delta, names, strict=True) if shape_of[n] == s)
            for s in shapes
        }
        table[v] = {
            "total": round(sum(delta), 1),
            "per_shape": {s: round(x, 1) for s, x in per.items()},
        }
    return {"shapes": shapes, "relative_to": next(iter(scores)), "variants": table}


def markdown(summary: dict[str, Any], settings: dict[str, Any]) -> str:
    shapes = summary["shapes"]
    lines = [
        "# MIT pushes: what the low support friction stands in for",
        "",
        f"Settings: {json.dumps(settings)}",
        "",
        f"Evidence relative to `{summary['relative_to']}` (nats; the filter's summed log "
        "predictive likelihood of the noise-free Vicon poses, dynamic push model):",
        "",
        "| variant | " + " | ".join(shapes) + " | all |",
        "|---|" + "---|" * (len(shapes) + 1),
    ]
    for v, row in summary["variants"].items():
        cells = " | ".join(f"{row['per_shape'][s]:+.1f}" for s in shapes)
        lines.append(f"| {v} | {cells} | {row['total']:+.1f} |")
    return "\n".join(lines) + "\n"


def _parser() -> argparse.ArgumentParser:
    p = doc_parser("dbcslam_research.mitpush_pressure", __doc__)
    add_data_args(p)
    p.add_argument("--seed", type=int, default=0, help="scoring filter seed (0)")
    return p


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point; exit 0 on success, 2 on bad usage."""
    from dbcslam_ros.offline.discrepancy_report import load_run

    args = _parser().parse_args(argv)
    if args.particles < 1:
        print(f"error: --particles must be >= 1, got {args.particles}", file=sys.stderr)
        return 2
    if not (args.data / "abs" / "train").is_dir():
        print(f"error: no abs/train folder under {args.data}", file=sys.stderr)
        return 2
    t0 = time.monotonic()

    def say(s: str) -> None:
        print(f"{s} ({time.monotonic() - t0:.0f} s)", file=sys.stderr, flush=True)

    with tempfile.TemporaryDirectory() as tmp:
        work = args.work or Path(tmp)
        bags = import_bags(args.data, work, "dynamic", say)
        runs = [load_run(b) for b in bags]
        scorer = Scorer(ScoreConfig(particles=args.particles, seed=args.seed))
        scores = score_variants(runs, scorer, say=say)
    names = [r.name for r in runs]
    summary = summarise(names, scores)
    settings = {"particles": args.particles, "seed": args.seed, "pushes": len(runs)}
    args.out.mkdir(parents=True, exist_ok=True)
    data = {"settings": settings, "summary": summary, "pushes": names, "scores": scores}
    (args.out / "pressure.json").write_text(json.dumps(data, indent=1) + "\n")
    (args.out / "pressure.md").write_text(markdown(summary, settings))
    print(f"wrote {args.out / 'pressure.md'} ({time.monotonic() - t0:.0f} s)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
