"""``python -m dbcslam_ros.cli``: same as the ``dbcslam`` console script."""

from __future__ import annotations

from dbcslam_ros.cli import console_main

console_main()
