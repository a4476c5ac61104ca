"""The ``dbcslam`` command line: argparse with one module per subcommand.

Exit codes: 0 success, 2 bad usage or bad input (one-line message naming the file and the
problem: any ``DbcSlamRosError``, and core ``DbcSlamError``s
that are ``ValueError``s), 1 internal failure. Set ``DBCSLAM_DEBUG=1`` to get tracebacks of
internal failures.
"""

from __future__ import annotations

import argparse
import os
import sys
import textwrap
import traceback
from collections.abc import Sequence

from dbcslam_core.errors import DbcSlamError
from dbcslam_ros.cli.registry import Command, discover_commands
from dbcslam_ros.errors import DbcSlamRosError

__all__ = [
    "EXIT_FAILURE",
    "EXIT_OK",
    "EXIT_USAGE",
    "Command",
    "build_parser",
    "console_main",
    "main",
]

EXIT_OK = 0
EXIT_FAILURE = 1
EXIT_USAGE = 2

_EPILOG = """\
exit codes: 0 success, 2 bad usage or bad input, 1 internal failure.
DDS traffic stays on loopback unless configured otherwise; ROS_DOMAIN_ID selects the domain.
Run 'dbcslam COMMAND --help' for a command's options and examples.
"""


def build_parser(commands: dict[str, Command] | None = None) -> argparse.ArgumentParser:
    """The ``dbcslam`` argument parser with every discovered subcommand."""
    commands = discover_commands() if commands is None else commands
    parser = argparse.ArgumentParser(
        prog="dbcslam",
        description="DBC-SLAM tools: simulation, filtering, bags and topic inspection.",
        epilog=_EPILOG,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", required=True)
    for command in commands.values():
        child = sub.add_parser(
            command.name,
            help=command.help,
            # Pre-formatted descriptions (with line breaks) are kept; one-liners are wrapped.
            description=command.description
            if "\n" in command.description
            else textwrap.fill(command.description, 88),
            epilog=f"examples:\n{command.examples}",
            formatter_class=argparse.RawDescriptionHelpFormatter,
        )
        command.configure(child)
        child.set_defaults(_command=command)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    """The ``dbcslam`` command line on argv (default: sys.argv); returns the exit code."""
    return _run_command(build_parser().parse_args(argv))


def console_main() -> None:
    """Entry point of the ``dbcslam`` console script and ``python -m dbcslam_ros.cli``: `main`
    on sys.argv, then the exit. After a command marked ``fast_exit`` (batch work whose files
    are closed when it returns) the process ends right after the exit handlers, without the
    interpreter's teardown of every module and object: after a replay that teardown alone
    took 0.23 s of a 4 s run (freeing the filter's buffers and the recorded messages one by
    one), memory the operating system reclaims at once."""
    args = build_parser().parse_args()
    code = _run_command(args)
    if args._command.fast_exit:
        _exit_now(code)
    sys.exit(code)


def _exit_now(code: int) -> None:
    """Flush the standard streams and logging, run the atexit handlers, end the process."""
    import atexit
    import contextlib
    import logging

    for stream in (sys.stdout, sys.stderr):
        with contextlib.suppress(OSError, ValueError):  # closed or broken pipe: nothing to say
            stream.flush()
    logging.shutdown()
    atexit._run_exitfuncs()  # the handlers Python would run at exit; then no teardown
    os._exit(code)


def _run_command(args: argparse.Namespace) -> int:
    """Run the parsed command; the exit code (the module docstring's mapping of errors)."""
    command: Command = args._command
    prefix = f"dbcslam {command.name}"
    try:
        return int(command.run(args))
    except DbcSlamRosError as err:
        print(f"{prefix}: error: {err}", file=sys.stderr)
        return EXIT_USAGE
    except DbcSlamError as err:
        # Core errors that are ValueErrors (bad scenario, bad model input) are bad input.
        print(f"{prefix}: error: {err}", file=sys.stderr)
        return EXIT_USAGE if isinstance(err, ValueError) else EXIT_FAILURE
    except KeyboardInterrupt:
        return 130
    except BrokenPipeError:
        # Output piped into e.g. `head` that exited: not an error of ours.
        devnull = os.open(os.devnull, os.O_WRONLY)
        os.dup2(devnull, sys.stdout.fileno())
        return EXIT_OK
    except Exception as err:
        text = str(err).strip().splitlines()
        detail = f"{type(err).__name__}: {text[0]}" if text else type(err).__name__
        print(f"{prefix}: internal error: {detail}", file=sys.stderr)
        if os.environ.get("DBCSLAM_DEBUG"):
            traceback.print_exc()
        return EXIT_FAILURE
