"""Session-wide test settings: every test run talks on its own DDS domain, on loopback only."""

from __future__ import annotations

import os
import random

# A random domain per test run so parallel runs (and a developer's live demo) never cross-talk.
os.environ.setdefault("ROS_DOMAIN_ID", str(random.SystemRandom().randint(1, 100)))
