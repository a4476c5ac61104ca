"""Root exception hierarchy of ``dbcslam_ros``.

Every error raised on purpose by this package derives from :class:`DbcSlamRosError`, so a
caller (for example the ``dbcslam`` CLI) can map it to exit code 2 ("bad usage or bad input")
and anything else to exit code 1.
"""

from __future__ import annotations

__all__ = [
    "BagError",
    "DbcSlamRosError",
    "MessageTypeError",
    "ParameterError",
    "UsageError",
]


class DbcSlamRosError(Exception):
    """Root of all errors raised deliberately by ``dbcslam_ros``."""


class UsageError(DbcSlamRosError):
    """Bad command line usage or bad user input (CLI exit code 2)."""


class MessageTypeError(DbcSlamRosError):
    """Unknown ROS message type name, or a message object / CDR buffer that does not fit it."""


class ParameterError(DbcSlamRosError):
    """A node parameter is undeclared, declared twice, or overridden with a wrong type."""


class BagError(DbcSlamRosError):
    """A bag cannot be read or written (missing, corrupt, or of an unsupported layout)."""
