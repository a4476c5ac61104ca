"""``dbcslam replay BAG -o OUTDIR``: run the filter over a bag as fast as it can."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import Any

from dbcslam_ros.cli.registry import Command
from dbcslam_ros.errors import UsageError

__all__ = ["COMMAND"]

_DESCRIPTION = """\
Run the DBC-SLAM filter over the inputs of BAG (a bag, or a directory of bags) as fast
as it can, with exactly the live filter node's processing (same synchronisation,
validation, gating and messages; no dropped poses). The filter is configured from the
bag's /scenario (or --scenario-file) and the filter parameters (--params, --particles,
--seed, --model).

Writes OUTDIR (for a directory of bags: OUTDIR/<bag name>/ per bag): a bag with the
source's topics (inputs, /scenario, truth; earlier /dbcslam/* and /diagnostics are
dropped) and the filter's outputs /dbcslam/pose (first), /dbcslam/odometry,
/dbcslam/contact_modes, /dbcslam/friction, /dbcslam/friction_map, /dbcslam/markers
(every 0.1 s of bag time as live; `marker_period: 0.0` in --params: one per estimate) and
/diagnostics (once per second of bag time), every output logged at the stamp of the
observation it answers; metrics.json (`dbcslam evaluate` output plus replay timing;
counts only when the bag has no truth) and PNG plots. A progress line goes to stderr.
A bad or damaged bag is an error (exit 2) unless --salvage replays what lies before
the damage."""

_EXAMPLES = """\
  dbcslam replay bags/edge -o out/edge
  dbcslam replay bags/ -o out/ --particles 300          # every bag under bags/
  dbcslam replay run.mcap -o out/run --params filter.yaml --seed 3 --no-plots
"""


def _configure(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("bag", metavar="BAG", help="bag directory, .mcap file or folder of bags")
    parser.add_argument("-o", "--out", required=True, metavar="OUTDIR", help="output directory")
    parser.add_argument("--params", metavar="FILE", help="filter parameters YAML (ROS 2 style)")
    parser.add_argument("--particles", type=int, metavar="N", help="number of particles")
    parser.add_argument("--seed", type=int, metavar="N", help="seed of the filter")
    parser.add_argument("--model", metavar="FILE", help="model-extension YAML (discrepancy)")
    parser.add_argument(
        "--scenario-file", metavar="FILE", help="scenario YAML used instead of /scenario"
    )
    parser.add_argument(
        "--salvage", action="store_true", help="replay a damaged bag up to the damage"
    )
    parser.add_argument("--overwrite", action="store_true", help="replace existing outputs")
    parser.add_argument("--no-plots", action="store_true", help="skip the PNG plots")
    parser.add_argument("--quiet", action="store_true", help="no progress line")


def _params(args: argparse.Namespace) -> dict[str, Any]:
    from dbcslam_ros.offline.replay import load_filter_params

    params: dict[str, Any] = {}
    if args.params:
        if not Path(args.params).is_file():
            msg = f"{args.params}: no such parameters file"
            raise UsageError(msg)
        params.update(load_filter_params(args.params))
    if args.particles is not None:
        if args.particles < 1:
            msg = f"--particles {args.particles}: expected an integer >= 1"
            raise UsageError(msg)
        params["particles"] = args.particles
    if args.seed is not None:
        if args.seed < 0:
            msg = f"--seed {args.seed}: expected an integer >= 0"
            raise UsageError(msg)
        params["seed"] = args.seed
    for flag, name in (("model", "model_file"), ("scenario_file", "scenario_file")):
        value = getattr(args, flag)
        if value:
            if not Path(value).is_file():
                msg = f"--{flag.replace('_', '-')} {value}: no such file"
                raise UsageError(msg)
            params[name] = str(Path(value).resolve())
    return params


def _run(args: argparse.Namespace) -> int:
    from dbcslam_ros.offline.evaluate import metrics_table
    from dbcslam_ros.offline.replay import ReplayOptions, replay_many

    options = ReplayOptions(
        params=_params(args),
        salvage=args.salvage,
        plots=not args.no_plots,
        progress=None if args.quiet else sys.stderr,
        overwrite=args.overwrite,
    )
    results = replay_many(args.bag, args.out, options)
    for res in results:
        print(
            f"{res.source} -> {res.out}: {res.estimates} estimates from {res.poses} poses in "
            f"{res.wall_s:.2f} s ({res.steps_per_s:.0f} steps/s); metrics.json, "
            f"{len(res.plots)} plots"
        )
        print(metrics_table(res.metrics))
        rec = res.metrics["replay"].get("recorded_estimates")
        if rec is not None and rec["same_stamps"]:
            print(
                f"vs the {rec['recorded']} estimates recorded in the source: "
                f"{rec['same_stamps']} at the same stamps, position difference mean "
                f"{rec['position_diff_mean_m']:.2e} m, max {rec['position_diff_max_m']:.2e} m"
            )
    return 0


COMMAND = Command(
    name="replay",
    help="run the filter over a bag as fast as possible; write estimates, metrics, plots",
    description=_DESCRIPTION,
    examples=_EXAMPLES,
    configure=_configure,
    run=_run,
    fast_exit=True,  # the output bag is closed and metrics.json written when _run returns
)
