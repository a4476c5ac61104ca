"""Exceptions of dbcslam_core: one root, a few specific kinds.

Every error message names the offending value and what would have been valid.
"""

from __future__ import annotations

__all__ = ["DbcSlamError", "ModelError", "ScenarioError", "SolverError"]


class DbcSlamError(Exception):
    """Root of every exception raised by dbcslam_core."""


class ScenarioError(DbcSlamError, ValueError):
    """A scenario description (the /scenario YAML) is malformed or inconsistent."""


class SolverError(DbcSlamError, RuntimeError):
    """A complementarity or linear solve failed (no solution, ray termination, bad input)."""


class ModelError(DbcSlamError, ValueError):
    """Model inputs (states, observations, parameters) are invalid: wrong shape, NaN, ..."""
