"""``dbcslam discrepancy BAG ... [--heldout BAG ...] --json FILE``: model discrepancy analysis."""

from __future__ import annotations

import argparse
import time

from dbcslam_ros.cli.registry import Command

__all__ = ["COMMAND"]

_DESCRIPTION = """\
Show what the simulation model gets wrong on measured data, name the cause, extend the
model and measure the gain. Reads only /scenario, /object/pose, /object/wrench and
/joint_states (never /truth/*). The score of a model is the DBC-SLAM filter's own
evidence: its summed log predictive likelihood of the observed poses (friction per region,
friction map, contact modes and start state are integrated by the filter). Every candidate
effect (friction_scale, viscous_damping, mass_scale, input_gain, sensor_delay,
sensor_bias, support_friction, support_pressure) is fitted on the training bags by
maximising that score (coarse grids of all effects, then parabolic refinement of the two
best; stderr from the curvature) and compared on the held-out bags against a margin of k/2
ln N plus 3 x the measured Monte-Carlo noise of the score; an estimate at a bound of its
search range is never named; mass_scale and input_gain, which the data cannot tell apart,
are named together. Bags given with --heldout are never fitted on; without it every second
bag is held out (one bag: its last 40 %). Writes the JSON (--json), a Markdown report and
PNG figures (open-loop rollouts: pictures, not evidence) beside it, and <stem>_model.yaml:
the extended model for the filter parameter model_file / `dbcslam replay --model`.
--filter N also replays the held-out bags with the filter node, nominal vs extended, and
adds that tracking RMSE to the JSON. Progress on stderr (each filter run is one line). The
filter runs of each round run in --workers processes (default 2; 1 = none)."""

_EXAMPLES = """\
  dbcslam discrepancy bags/edge --json out/disc/edge.json
  dbcslam discrepancy out/mitpush/rect1 --heldout out/mitpush/ellip2 --json out/disc/push.json
"""


def _configure(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("bags", metavar="BAG", nargs="+", help="bags (or folders of bags)")
    parser.add_argument(
        "--heldout", metavar="BAG", nargs="+", default=[], help="bags used only for scoring"
    )
    parser.add_argument("--json", metavar="FILE", required=True, help="JSON report path")
    parser.add_argument(
        "--particles", type=int, default=None, help="particles of the scoring filter (300)"
    )
    parser.add_argument("--seed", type=int, default=None, help="scoring filter seed (0)")
    parser.add_argument(
        "--workers",
        type=int,
        default=2,
        help="processes running the filter runs in parallel (2; 1 = in this process)",
    )
    parser.add_argument(
        "--horizon", type=int, default=None, help="rollout steps of the pictures (20)"
    )
    parser.add_argument(
        "--effects", nargs="+", default=None, help="candidate effects (default: per scenario)"
    )
    parser.add_argument(
        "--max-starts", type=int, default=None, help="rollout starts per bag (default 150)"
    )
    parser.add_argument("--stride", type=int, default=None, help="steps between starts (2)")
    parser.add_argument(
        "--filter",
        type=int,
        default=0,
        metavar="PARTICLES",
        help="also replay the held-out bags with the filter, nominal vs extended (0 = off)",
    )
    parser.add_argument("--no-plots", action="store_true", help="skip the PNG figures")


def _run(args: argparse.Namespace) -> int:
    from dbcslam_core.discrepancy import DiscrepancyConfig
    from dbcslam_ros.errors import UsageError
    from dbcslam_ros.offline.discrepancy_report import config_with, run_discrepancy

    for name in ("horizon", "max_starts", "stride", "particles", "workers"):
        value = getattr(args, name)
        if value is not None and value < 1:
            msg = f"--{name.replace('_', '-')} must be >= 1, got {value}"
            raise UsageError(msg)
    cfg = config_with(
        DiscrepancyConfig(),
        horizon=args.horizon,
        particles=args.particles,
        seed=args.seed,
        workers=args.workers,
        max_starts=args.max_starts,
        stride=args.stride,
        effects=tuple(args.effects) if args.effects else None,
    )
    t0 = time.monotonic()
    result, data = run_discrepancy(
        args.bags,
        args.heldout,
        args.json,
        config=cfg,
        plots=not args.no_plots,
        filter_particles=args.filter,
    )
    print(f"verdict: {result.verdict}")
    print(data["evidence"])
    print(f"gain {result.gain:.3f}; model file {data.get('model_file')}; wrote {args.json}")
    print(f"({time.monotonic() - t0:.1f} s)")
    return 0


COMMAND = Command(
    name="discrepancy",
    help="what the model gets wrong on measured bags, the cause, the gain of the fix",
    description=_DESCRIPTION,
    examples=_EXAMPLES,
    configure=_configure,
    run=_run,
)
