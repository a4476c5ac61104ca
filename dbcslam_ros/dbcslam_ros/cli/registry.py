"""Subcommand table of the ``dbcslam`` command line.

Every module in :mod:`dbcslam_ros.cli.commands` that defines ``COMMAND`` (a :class:`Command`)
is a subcommand; adding a command means adding one module there, nothing else. Other packages
add commands through the entry-point group :data:`ENTRY_POINT_GROUP` (``dbcslam.commands``;
each entry point names a :class:`Command`): ``sim_publisher`` supplies ``dbcslam sim`` that
way, so ``dbcslam_ros`` never imports the simulator. Command modules import heavy dependencies
(DDS, numpy, the filter) inside ``run`` so ``dbcslam --help`` stays fast and one command's
missing dependency does not break the others.
"""

from __future__ import annotations

import argparse
import importlib
import pkgutil
import sys
from collections.abc import Callable
from dataclasses import dataclass
from importlib.metadata import entry_points

__all__ = [
    "COMMANDS_PACKAGE",
    "ENTRY_POINT_GROUP",
    "Command",
    "add_ros_args",
    "discover_commands",
]

COMMANDS_PACKAGE = "dbcslam_ros.cli.commands"
#: Entry-point group through which other installed packages add ``dbcslam`` subcommands.
ENTRY_POINT_GROUP = "dbcslam.commands"


def add_ros_args(parser: argparse.ArgumentParser) -> None:
    """The ``--ros-args ...`` pass-through of a command that runs a node (``args.ros_args``:
    the ROS arguments, ``-p NAME:=VALUE ...``; must come last)."""
    parser.add_argument(
        "--ros-args",
        dest="ros_args",
        nargs=argparse.REMAINDER,
        default=[],
        metavar="ARG",
        help="ROS arguments passed to the node (-p NAME:=VALUE ...); must come last",
    )


@dataclass(frozen=True)
class Command:
    """One ``dbcslam`` subcommand.

    Attributes:
        name: subcommand name (``dbcslam NAME``).
        help: one line shown in ``dbcslam --help``.
        description: what the command does (``dbcslam NAME --help``).
        examples: example invocations, shown under "examples:" in the help.
        configure: adds the command's arguments (and sub-subcommands) to its parser.
        run: executes the parsed command; returns the exit code (0 success, 2 bad usage or
            input, 1 internal failure). May raise :class:`dbcslam_ros.errors.DbcSlamRosError`
            for bad input, which the CLI turns into exit code 2 and a one-line message.
        fast_exit: the console script may end the process without tearing the interpreter
            down once ``run`` returned (`dbcslam_ros.cli.console_main`): only for batch
            commands that close everything they write before returning and start no
            processes or DDS participants that outlive ``run``.
    """

    name: str
    help: str
    description: str
    examples: str
    configure: Callable[[argparse.ArgumentParser], None]
    run: Callable[[argparse.Namespace], int]
    fast_exit: bool = False


def _add(found: dict[str, Command], command: object, where: str) -> None:
    if not isinstance(command, Command):
        return
    if command.name in found:
        msg = f"two places define the dbcslam subcommand {command.name!r} (one is {where})"
        raise RuntimeError(msg)
    found[command.name] = command


def discover_commands() -> dict[str, Command]:
    """All commands of :data:`COMMANDS_PACKAGE` and of the installed entry points of
    :data:`ENTRY_POINT_GROUP`, by name, sorted. An entry point that fails to load is left out
    with a warning on stderr (one broken plugin must not break the command line)."""
    package = importlib.import_module(COMMANDS_PACKAGE)
    found: dict[str, Command] = {}
    for info in pkgutil.iter_modules(package.__path__):
        if info.name.startswith("_"):
            continue
        module = importlib.import_module(f"{COMMANDS_PACKAGE}.{info.name}")
        _add(found, getattr(module, "COMMAND", None), f"{COMMANDS_PACKAGE}.{info.name}")
    for ep in entry_points(group=ENTRY_POINT_GROUP):
        try:
            command = ep.load()
        except Exception as err:  # a plugin's own import error: report, keep the others
            print(f"dbcslam: warning: command {ep.name!r} ({ep.value}): {err}", file=sys.stderr)
            continue
        _add(found, command, f"entry point {ep.value}")
    return dict(sorted(found.items()))
