"""Exceptions of sim_publisher: one root, a few specific kinds.

Every message names the offending value and what would have been valid.
"""

from __future__ import annotations

__all__ = ["BulletError", "ParamError", "SimError"]


class SimError(Exception):
    """Root of every exception raised by sim_publisher."""


class ParamError(SimError, ValueError):
    """A simulation parameter (dataclass field or params YAML entry) is invalid."""


class BulletError(SimError, RuntimeError):
    """pybullet failed (cannot connect, cannot create a body) or the simulation diverged."""
