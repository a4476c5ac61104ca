"""``dbcslam`` subcommands: one module per command, each defining ``COMMAND``.

See :mod:`dbcslam_ros.cli.registry`. Modules whose name starts with ``_`` are helpers.
"""

from __future__ import annotations

__all__: list[str] = []
