"""Subcommand table of the ``dbcslam`` command line.

Every module in :mod:`dbcslam_ros.cli.commands` that defines ``COMMAND`` (a :class:`Command`)
is a subcommand; adding a command means adding one module there, nothing else. Command modules
import heavy dependencies (DDS, numpy, the filter) inside ``run`` so ``dbcslam --help`` stays
fast and one command's missing dependency does not break the others.
"""

from __future__ import annotations

import argparse
import importlib
import pkgutil
from collections.abc import Callable
from dataclasses import dataclass

__all__ = ["Command", "discover_commands"]

COMMANDS_PACKAGE = "dbcslam_ros.cli.commands"


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
    """

    name: str
    help: str
    description: str
    examples: str
    configure: Callable[[argparse.ArgumentParser], None]
    run: Callable[[argparse.Namespace], int]


def discover_commands() -> dict[str, Command]:
    """All commands of :data:`COMMANDS_PACKAGE`, by name, sorted."""
    package = importlib.import_module(COMMANDS_PACKAGE)
    found: dict[str, Command] = {}
    for info in pkgutil.iter_modules(package.__path__):
        if info.name.startswith("_"):
            continue
        module = importlib.import_module(f"{COMMANDS_PACKAGE}.{info.name}")
        command = getattr(module, "COMMAND", None)
        if isinstance(command, Command):
            if command.name in found:
                msg = f"two modules define the dbcslam subcommand {command.name!r}"
                raise RuntimeError(msg)
            found[command.name] = command
    return dict(sorted(found.items()))
