"""``dbcslam filter``: run the DBC-SLAM filter node on live topics."""

from __future__ import annotations

import argparse
from pathlib import Path

from dbcslam_ros.cli.registry import Command, add_ros_args
from dbcslam_ros.errors import UsageError

__all__ = ["COMMAND"]

_DESCRIPTION = """\
Start the filter node (node name dbcslam_filter). It waits for the latched /scenario
(what the robot knows a priori; a changed /scenario reconfigures it), then turns every
/object/pose into one estimate, using /object/wrench (the applied input, held from the
start of the step), /joint_states (jaw or pusher positions, interpolated to the pose
stamp) and, in push scenarios, /pusher/wrench (the F/T force on the pusher: an
observation, taken at the pose stamp when a reading is within 1.5 samples). It publishes
/dbcslam/pose first, then /dbcslam/odometry, /dbcslam/contact_modes,
/dbcslam/friction, /dbcslam/friction_map, /dbcslam/markers; and /diagnostics every
diagnostics_period s (ESS, live hypotheses, step time, latency from pose receipt to
publication, input rate, rejected inputs by reason). It may start before or after the
simulator.

A bad message (NaN, zero quaternion, stamp going backwards, unknown joint) is logged
(throttled), counted and dropped; the node keeps running. A jump back in time (a bag played
with --loop) resets the filter. If the filter is slower than the input, stale poses are
dropped (reason backlog) and the next step catches up with at most catch_up_steps model
steps, so the lag stays bounded.

Parameters (ROS params file `dbcslam_filter: {ros__parameters: {...}}` or
--ros-args -p NAME:=VALUE): particles (-1 = live default per scenario kind: edge 1000,
gripper 500, push 500), ess_threshold, prune_threshold, parameter_model
(reuse|mixture|geometric), contact_weight, gating_threshold, seed, scenario_file,
model_file (a model extension from `dbcslam discrepancy`), frame_id, marker_particles,
marker_period, diagnostics_period, catch_up_steps, use_pusher_wrench, force_noise, max_gap,
reset_after. SIGINT/SIGTERM stop it."""

_EXAMPLES = """\
  dbcslam filter
  dbcslam filter --params filter.yaml
  dbcslam filter --ros-args -p particles:=1000 -p parameter_model:=geometric
"""


def _configure(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--params", metavar="FILE", help="ROS 2 parameters YAML file")
    add_ros_args(parser)


def _run(args: argparse.Namespace) -> int:
    from dbcslam_ros.node.filter_node import main

    argv = ["dbcslam_filter", "--ros-args"]
    if args.params:
        path = Path(args.params)
        if not path.is_file():
            msg = f"{path}: no such parameters file"
            raise UsageError(msg)
        argv += ["--params-file", str(path)]
    return main(argv + list(args.ros_args))


COMMAND = Command(
    name="filter",
    help="run the DBC-SLAM filter node on live topics",
    description=_DESCRIPTION,
    examples=_EXAMPLES,
    configure=_configure,
    run=_run,
)
