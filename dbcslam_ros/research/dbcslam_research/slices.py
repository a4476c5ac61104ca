"""Slices of the synthetic trajectories that the benchmarks time: the window with the most
true contacts (so the contact-mode enumeration is exercised)."""

from __future__ import annotations

import numpy as np

from dbcslam_core.synthetic import Trajectory

__all__ = ["contact_window", "slice_trajectory"]


def slice_trajectory(tr: Trajectory, start: int, stop: int) -> Trajectory:
    """Samples [start, stop) of a trajectory (the filter initialises at `start`)."""
    return Trajectory(
        tr.scenario,
        tr.t[start:stop],
        tr.q[start:stop],
        tr.v[start:stop],
        tr.u[start:stop],
        tr.env[start:stop],
        tr.modes[start:stop],
        tr.ln[start:stop],
        tr.lt[start:stop],
        tr.mu[start:stop],
        tr.mu_pair,
        tr.obs[start:stop],
        tr.env_obs[start:stop],
    )


def contact_window(tr: Trajectory, length: int) -> int:
    """Start index of the `length`-sample window with the most true (step, contact) contacts."""
    n = tr.n_steps
    if length >= n:
        return 0
    c = (tr.modes != 0).sum(axis=1).astype(np.float64)
    cs = np.concatenate([[0.0], np.cumsum(c)])
    sums = cs[length:] - cs[:-length]
    return int(np.argmax(sums))
