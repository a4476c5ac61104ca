"""Convert a pybullet run into the core's `Trajectory` (to feed filters without ROS).

Indexing follows `dbcslam_core.synthetic`: t[k] = k / rate; u[k] is the input over
[t_k, t_k+1) (the recorded mean wrench); modes[k] are the modes at the end of the interval
that ends at t_k (row 0: the initial state); env[k] the joint positions at t_k.
"""

from __future__ import annotations

import numpy as np

from dbcslam_core.synthetic import Trajectory

from .records import SimRun

__all__ = ["to_trajectory"]


def to_trajectory(run: SimRun) -> Trajectory:
    """The run as a `dbcslam_core.synthetic.Trajectory`.

    q, v, obs take the first nq = scenario.nq columns of pose, twist and observed pose (a
    point mass has nq = 2); u the first nq columns of the recorded wrench. ln holds the
    normal force at t_k times the sample period (an impulse estimate, N s); lt is NaN
    (pybullet's per-contact friction impulses are not attributed to vertices). mu[k, c] is
    the true coefficient of contact c's pair; mu_pair[p] the pair's coefficient where it is
    constant over the run, NaN where it varies (the edge).
    """
    arr = run.stack()
    scenario = run.scenario
    nq = scenario.nq
    dt = 1.0 / float(run.params.rate)
    pair_of = np.asarray(scenario.contact_pairs, dtype=np.int64)
    friction = arr["friction"]
    constant = np.all(friction == friction[:1], axis=0)
    mu_pair = np.where(constant, friction[0], np.nan)
    return Trajectory(
        scenario=scenario,
        t=arr["t"],
        q=arr["pose"][:, :nq].copy(),
        v=arr["twist"][:, :nq].copy(),
        u=arr["wrench"][:, :nq].copy(),
        env=arr["joints"].copy(),
        modes=np.argmax(arr["modes"], axis=2).astype(np.int64),
        ln=arr["normal_forces"] * dt,
        lt=np.full_like(arr["normal_forces"], np.nan),
        mu=friction[:, pair_of],
        mu_pair=mu_pair,
        obs=arr["observed_pose"][:, :nq].copy(),
        env_obs=arr["observed_joints"].copy(),
    )
