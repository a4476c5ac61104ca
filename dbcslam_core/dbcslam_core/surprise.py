"""How badly the filter's own prediction explains each observation: the surprise of a step.

The surprise of an observed step l is how far its log predictive likelihood
log p(o_l | o_<l) (nats, `Estimate.log_likelihood`) falls below the median of the recent
observed steps. A filter that tracks the body sees surprises of a few nats (pybullet runs at
the live particle counts: at most 7.9 over 10 runs of each scenario); a cloud that has lost
the observations, or that holds a wrong friction coefficient against a sliding body, sees tens
to hundreds (README, "Tracking health"). The median makes the reference robust to the
surprising steps themselves; it moves with the data, so a slow change of the noise level is
not surprising.

Used by the friction bank's gate (`FilterConfig.bank_surprise_gate`) and by the filter node's
``/diagnostics`` (`dbcslam_ros.node.session`).
"""

from __future__ import annotations

import math
from collections import deque

import numpy as np

from dbcslam_core.errors import ModelError

__all__ = ["MIN_REFERENCE_STEPS", "SURPRISE_WARNING", "SurpriseMonitor"]

#: Observed steps a reference median needs; before that every surprise is 0.
MIN_REFERENCE_STEPS = 5

#: Surprise (nats) above which a step is badly explained. Measured on pybullet runs
#: (`python -m dbcslam_research.tracking_health`, README "Tracking health"): at the live
#: particle counts (edge 1000, gripper and push 500, runs 0-9) no step exceeds 7.8 nats, nor
#: 9.3 on 40 gripper runs at 500 particles with true jaw mu 0.4 / 0.7; the 100-particle edge
#: runs whose position RMSE reaches 0.6-2.0x the sensor noise exceed it, and every gripper
#: run at true mu 0.1 that ends on a wrong coefficient (7 at 40 particles, 2 at 500) has a
#: step above 95.
SURPRISE_WARNING = 10.0


class SurpriseMonitor:
    """Running surprise of the log predictive likelihoods of observed steps.

    window: how many recent observed steps (finite log likelihoods) form the reference
    median (>= `MIN_REFERENCE_STEPS`).
    """

    def __init__(self, window: int = 20) -> None:
        if window < MIN_REFERENCE_STEPS:
            msg = f"surprise window must be >= {MIN_REFERENCE_STEPS} steps, got {window}"
            raise ModelError(msg)
        self._recent: deque[float] = deque(maxlen=window)

    def update(self, log_likelihood: float) -> float:
        """The surprise of a step with log predictive likelihood `log_likelihood` (nats):
        the median of the reference steps minus it (inf for a step the filter gave zero
        likelihood; 0.0 while fewer than `MIN_REFERENCE_STEPS` steps are recorded). The
        step then joins the reference if its likelihood is finite."""
        surprise = 0.0
        if len(self._recent) >= MIN_REFERENCE_STEPS:
            surprise = float(np.median(self._recent)) - log_likelihood
        if math.isfinite(log_likelihood):
            self._recent.append(log_likelihood)
        return surprise

    def __len__(self) -> int:
        """Number of reference steps recorded (at most the window)."""
        return len(self._recent)

    def clear(self) -> None:
        """Forget the reference (a new track)."""
        self._recent.clear()
