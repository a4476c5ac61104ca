"""``dbcslam discrepancy BAG ... [--heldout BAG ...] --json FILE``: model discrepancy analysis."""

from __future__ import annotations

import argparse
import time

from dbcslam_ros.cli.registry import Command

__all__ = ["COMMAND"]

_DESCRIPTION = """\
Show what the simulation model gets wrong on measured data, name the cause, extend the
model and measure the gain. Reads only /scenario, /object/pose, /object/wrench and
/joint_states (never /truth/*). The nominal model (the bag's /scenario; friction = prior
mean of the candidates) predicts the observed poses over open-loop rollouts from states
estimated from the observations; every candidate effect (friction_scale, friction_patch,
viscous_damping, mass_scale, input_gain, sensor_delay, sensor_bias, support_friction,
support_pressure) is fitted on the training data and compared on held-out data by
log-likelihood with a parameter penalty, with the rollouts' start state profiled out (a
noisy start is not an effect) and a size margin on the prediction RMSE. Bags given with
--heldout are never fitted on; without it every third 0.5 s block of each run is held out.
Writes the JSON (--json), a Markdown report and PNG figures beside it, and
<stem>_model.yaml: the extended model for the filter parameter model_file / `dbcslam replay
--model` (dynamic effects act in the model, sensor_bias / sensor_delay correct the poses).
--filter N also replays the held-out bags with the filter, nominal vs extended, and adds the
tracking RMSE to the JSON. Progress on stderr (about 15-30 s for a 10 s bag here)."""

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
    parser.add_argument("--horizon", type=int, default=None, help="rollout steps (default 20)")
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
    from dbcslam_ros.discrepancy_report import config_with, run_discrepancy
    from dbcslam_ros.errors import UsageError

    for name in ("horizon", "max_starts", "stride"):
        value = getattr(args, name)
        if value is not None and value < 1:
            msg = f"--{name.replace('_', '-')} must be >= 1, got {value}"
            raise UsageError(msg)
    cfg = config_with(
        DiscrepancyConfig(),
        horizon=args.horizon,
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
