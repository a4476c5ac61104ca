"""The pybullet edge run against the core's time-stepping model (two independent simulators).

From each recorded state the core's LCP model (one 10 ms step, true friction) predicts the
next recorded state; pybullet takes ten 1 ms steps. They must agree closely.
"""

from __future__ import annotations

import numpy as np

from dbcslam_core.dynamics import PlanarModel, State
from sim_publisher.records import SimRun
from sim_publisher.trajectory import to_trajectory


def test_core_model_predicts_the_pybullet_edge_run(edge_run: SimRun) -> None:
    tr = to_trajectory(edge_run)
    model = PlanarModel(tr.scenario)
    err = []
    same_mode = []
    for k in range(tr.n_steps - 1):
        res = model.step(State(tr.q[k], tr.v[k]), tr.u[k], mu_pair=tr.mu[k + 1])
        err.append(np.abs(np.asarray(res.q) - tr.q[k + 1]))
        same_mode.append(bool(np.all(np.asarray(res.modes) == tr.modes[k + 1])))
    e = np.array(err)
    assert np.all(np.median(e, axis=0) < 5e-5)
    assert np.all(np.percentile(e, 99, axis=0) < 1e-3)
    assert np.mean(same_mode) > 0.97


def test_trajectory_view_of_a_run(gripper_run: SimRun) -> None:
    tr = to_trajectory(gripper_run)
    arr = gripper_run.stack()
    assert tr.q.shape == (len(arr["t"]), 3) and tr.env.shape == (len(arr["t"]), 2)
    assert np.array_equal(tr.modes, np.argmax(arr["modes"], axis=2))
    assert np.allclose(tr.mu, 0.4) and np.allclose(tr.mu_pair, [0.4])
    assert tr.scenario.contacts == gripper_run.contacts
