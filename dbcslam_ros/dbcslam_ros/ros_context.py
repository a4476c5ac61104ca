"""The one place the project starts and stops ROS 2 (rclpy, ROS 2 Jazzy).

Every node and CLI tool (filter, sim, demo nodes, ``record / play / topic / demo``) calls
:func:`init_ros` instead of ``rclpy.init`` so the network defaults of
:func:`dbcslam_ros.network.apply_loopback_defaults` (DDS traffic on loopback only; leaving the
machine is the explicit choice ``DBCSLAM_NETWORK=system``) are applied in one place.

:func:`spin_node` is ``rclpy.spin`` with the clean-shutdown rule of ``ros2/demos``: SIGINT
(``KeyboardInterrupt``) and SIGTERM (``ExternalShutdownException``) end it quietly, and so does
the race in Jazzy rclpy where the signal handler shuts the context down while the executor
builds its wait set (``RCLError: ... the given context is not valid``).
"""

from __future__ import annotations

from collections.abc import Sequence

import rclpy
from rclpy.executors import ExternalShutdownException
from rclpy.node import Node
from rclpy.utilities import ok

from dbcslam_ros.network import apply_loopback_defaults

__all__ = ["init_ros", "is_shutdown_error", "spin_node"]


def init_ros(args: Sequence[str] | None = None, *, handle_signals: bool = True) -> None:
    """``rclpy.init`` with the project's network defaults (see the module docstring).

    ``args`` is a full argv (``--ros-args ...`` is read by rcl); ``None`` means none.
    ``handle_signals=False`` leaves SIGINT/SIGTERM to the caller (the CLI tools stop on their
    own handlers); otherwise rclpy's handlers shut the context down on either signal.
    """
    from rclpy.signals import SignalHandlerOptions

    apply_loopback_defaults()
    options = SignalHandlerOptions.ALL if handle_signals else SignalHandlerOptions.NO
    rclpy.init(args=list(args) if args is not None else None, signal_handler_options=options)
    # Build the global executor now, while the context is valid: built later by the first
    # spin after a signal already shut the context down, its constructor fails half-way and
    # its __del__ prints "Exception ignored ... no attribute '_sigint_gc'" at exit.
    rclpy.get_global_executor()


def is_shutdown_error(err: BaseException) -> bool:
    """True when ``err`` only says that the context was shut down (by a signal)."""
    from rclpy._rclpy_pybind11 import RCLError

    if isinstance(err, (KeyboardInterrupt, ExternalShutdownException)):
        return True
    return isinstance(err, RCLError) and not ok()


def spin_node(node: Node) -> None:
    """Spin ``node`` until SIGINT/SIGTERM or shutdown; returns normally in those cases."""
    from rclpy._rclpy_pybind11 import RCLError

    try:
        rclpy.spin(node)
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    except RCLError:
        if ok():
            raise
