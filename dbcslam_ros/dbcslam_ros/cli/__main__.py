"""``python -m dbcslam_ros.cli``: same as the ``dbcslam`` console script."""

from __future__ import annotations

import sys

from dbcslam_ros.cli import main

sys.exit(main())
