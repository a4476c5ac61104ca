"""``dbcslam sim``: run the simulator node (sim_publisher) for one scenario."""

from __future__ import annotations

import argparse
from pathlib import Path

from dbcslam_ros.cli.registry import Command, add_ros_args
from dbcslam_ros.errors import UsageError

__all__ = ["COMMAND"]

_DESCRIPTION = """\
Start the simulator node (node name sim_publisher). It simulates the scenario and publishes,
every sample (100 Hz by default): /joint_states, /object/wrench, /pusher/wrench (push),
/object/pose (noisy observations; the pose last, the filter steps on it), then the truth
/truth/object/pose, /truth/contact_modes, /truth/friction. /scenario is latched and holds
only the a-priori model (never the true friction). The node paces itself in real time and
exits with code 0 after --duration seconds of simulated time.

--fast runs as fast as possible, stamps with simulated time and publishes /clock.
--engine core publishes the core's own synthetic trajectories (edge, gripper) instead of
the pybullet physics: deterministic and exactly the filter's model, useful for tests.
--params FILE is a simulation parameters YAML (common keys plus one section per scenario,
see sim_publisher.params). Extra node parameters: --ros-args -p NAME:=VALUE
(wait_for_subscribers, frame_id)."""

_EXAMPLES = """\
  dbcslam sim --scenario gripper
  dbcslam sim --scenario edge --seed 3 --duration 4
  dbcslam sim --scenario push --params push.yaml --fast
  dbcslam sim --scenario edge --engine core --ros-args -p wait_for_subscribers:=0.0
"""

_SCENARIOS = ("edge", "gripper", "push")


def _configure(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--scenario", choices=_SCENARIOS, required=True, help="scenario")
    parser.add_argument("--params", metavar="FILE", help="simulation parameters YAML file")
    parser.add_argument("--seed", type=int, help="seed of the observation noise (>= 0)")
    parser.add_argument("--duration", type=float, metavar="S", help="simulated time (s)")
    parser.add_argument("--rate", type=float, metavar="HZ", help="sample rate (Hz)")
    parser.add_argument(
        "--fast", action="store_true", help="no real-time pacing; stamp with sim time + /clock"
    )
    parser.add_argument(
        "--engine",
        choices=("pybullet", "core"),
        default="pybullet",
        help="pybullet physics (default) or the core's synthetic trajectories",
    )
    add_ros_args(parser)


def _run(args: argparse.Namespace) -> int:
    if args.params and not Path(args.params).is_file():
        msg = f"{args.params}: no such parameters file"
        raise UsageError(msg)
    if args.seed is not None and args.seed < 0:
        msg = f"--seed {args.seed}: expected an integer >= 0"
        raise UsageError(msg)
    for name in ("duration", "rate"):
        value = getattr(args, name)
        if value is not None and not value > 0.0:
            msg = f"--{name} {value}: expected a value > 0"
            raise UsageError(msg)
    if args.engine == "core" and args.scenario == "push":
        msg = "--engine core has no push trajectory; use --engine pybullet for push"
        raise UsageError(msg)
    if args.engine == "core" and args.params:
        msg = "--engine core takes no --params (its trajectories are fixed)"
        raise UsageError(msg)
    from sim_publisher.node import main

    params = [f"scenario:={args.scenario}", f"engine:={args.engine}"]
    if args.params:
        params.append(f"params_file:={Path(args.params).resolve()}")
    if args.seed is not None:
        params.append(f"seed:={args.seed}")
    if args.duration is not None:
        params.append(f"duration:={float(args.duration)!r}")
    if args.rate is not None:
        params.append(f"rate:={float(args.rate)!r}")
    if args.fast:
        params.append("fast:=true")
    argv = ["sim_publisher", "--ros-args"]
    for p in params:
        argv += ["-p", p]
    return main(argv + list(args.ros_args))


COMMAND = Command(
    name="sim",
    help="run the simulator node for a scenario (edge, gripper, push)",
    description=_DESCRIPTION,
    examples=_EXAMPLES,
    configure=_configure,
    run=_run,
)
