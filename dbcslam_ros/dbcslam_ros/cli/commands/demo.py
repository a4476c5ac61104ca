"""``dbcslam demo``: simulator + filter + recorder over DDS, then a summary and plots."""

from __future__ import annotations

import argparse
import signal
import sys
from pathlib import Path
from types import FrameType

from dbcslam_ros.cli.registry import Command

__all__ = ["COMMAND"]

_DESCRIPTION = """\
Run the whole stack live: `dbcslam sim` (real-time pacing) and `dbcslam filter` as two
processes talking over DDS (this process's ROS_DOMAIN_ID, loopback only), recorded by
`dbcslam record` (a third process) into an MCAP bag: bags/demo_<scenario>_<UTC time> or
--out DIR. A progress line shows the simulated time and the number of estimates. When the
simulator ends, the filter is given time to drain, the processes are stopped (SIGINT) and
a summary table is printed (position RMSE vs the observation noise, contact/mode accuracy,
final friction posterior); metrics.json and paper-style PNG plots are written into the
bag directory. Defaults: scenario gripper, the simulator's duration (4 s for gripper),
particles: the filter node's live defaults (edge 1000, gripper 500, push 500), 20 particles
drawn in /dbcslam/markers (every 0.1 s, the node's default). A filter slower than the
100 Hz input drops poses (bounded lag); the summary says how many, and `dbcslam replay` of
the bag answers every pose."""

_EXAMPLES = """\
  dbcslam demo
  dbcslam demo --scenario edge --duration 5 --out /tmp/edge_demo
  dbcslam demo --scenario gripper --engine core --particles 100 --duration 3
"""


def _configure(parser: argparse.ArgumentParser) -> None:
    from dbcslam_ros.offline.demo import SCENARIOS

    parser.add_argument("--scenario", choices=SCENARIOS, default="gripper", help="scenario")
    parser.add_argument("--out", metavar="DIR", help="bag directory to create")
    parser.add_argument("--duration", type=float, metavar="S", help="simulated time (s)")
    parser.add_argument("--seed", type=int, metavar="N", help="seed of sim noise and filter")
    parser.add_argument("--particles", type=int, metavar="N", help="particles of the filter")
    parser.add_argument(
        "--engine", choices=("pybullet", "core"), default="pybullet", help="simulator engine"
    )
    parser.add_argument("--rate", type=float, metavar="HZ", help="simulator sample rate (Hz)")
    parser.add_argument("--no-plots", action="store_true", help="skip the PNG plots")
    parser.add_argument(
        "--no-markers", action="store_true", help="the filter publishes no /dbcslam/markers"
    )


def _run(args: argparse.Namespace) -> int:
    from dbcslam_ros.offline.demo import DemoError, DemoOptions, run_demo

    opts = DemoOptions(
        scenario=args.scenario,
        out=Path(args.out) if args.out else None,
        duration=args.duration,
        seed=args.seed,
        particles=args.particles,
        engine=args.engine,
        rate=args.rate,
        plots=not args.no_plots,
        markers=not args.no_markers,
        progress=sys.stdout,
    )
    previous = signal.getsignal(signal.SIGTERM)
    signal.signal(signal.SIGTERM, _terminate)  # so the child processes are stopped too
    try:
        run_demo(opts)
    except DemoError as err:
        print(f"dbcslam demo: {err}", file=sys.stderr)
        return 1
    finally:
        signal.signal(signal.SIGTERM, previous)
    return 0


def _terminate(_signum: int, _frame: FrameType | None) -> None:
    raise KeyboardInterrupt


COMMAND = Command(
    name="demo",
    help="simulator + filter over DDS, recorded; summary table and plots",
    description=_DESCRIPTION,
    examples=_EXAMPLES,
    configure=_configure,
    run=_run,
)
