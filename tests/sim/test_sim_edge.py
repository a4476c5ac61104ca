"""Edge scenario: phases of the paper's Fig. 3 and Coulomb friction of pybullet's contact."""

from __future__ import annotations

from typing import Any

import numpy as np
import pytest

from sim_publisher.bullet import SEPARATED, SLIDING_NEG, SLIDING_POS, STICKING
from sim_publisher.edge import EdgeSimulation
from sim_publisher.params import EdgeParams
from sim_publisher.records import SimRun

G = 9.81


def _mode(run: SimRun) -> np.ndarray:
    return np.asarray(np.argmax(run.stack()["modes"][:, 0, :], axis=1))


def test_edge_shows_separated_sticking_and_sliding(edge_run: SimRun) -> None:
    mode = _mode(edge_run)
    for m in (SEPARATED, STICKING, SLIDING_POS):
        assert np.count_nonzero(mode == m) >= 20, f"mode {m} seen {np.count_nonzero(mode == m)}"
    # separated at the start (falling onto the edge) and at the end (lifted off)
    assert mode[0] == SEPARATED and mode[-1] == SEPARATED
    # the sequence goes sliding -> sticking -> sliding again
    changes = [int(m) for i, m in enumerate(mode) if i == 0 or m != mode[i - 1]]
    s = "".join(str(c) for c in changes)
    assert f"{SLIDING_POS}{STICKING}{SLIDING_POS}" in s


def test_edge_sticks_only_in_the_rough_segment(edge_run: SimRun) -> None:
    arr = edge_run.stack()
    mode = _mode(edge_run)
    stick = mode == STICKING
    rough = next(seg for seg in edge_run.params.segments if seg[2] == 0.9)
    x = arr["pose"][stick, 0]
    assert np.all((x >= rough[0]) & (x <= rough[1]))
    assert np.all(arr["friction"][stick, 0] == 0.9)
    # while sticking the point does not move (positions, not the velocity used for the mode)
    runs = np.flatnonzero(stick[1:] & stick[:-1])
    assert np.max(np.abs(arr["pose"][runs + 1, 0] - arr["pose"][runs, 0])) < 1e-5


def test_edge_truth_modes_agree_with_kinematics(edge_run: SimRun) -> None:
    arr = edge_run.stack()
    mode = _mode(edge_run)
    y = arr["pose"][:, 1]
    fn = arr["normal_forces"][:, 0]
    contact = mode != SEPARATED
    # in contact the point is on the edge (y = edge_y) and pressed onto it
    assert np.max(np.abs(y[contact] - edge_run.params.edge_y)) < 2e-4
    assert np.all(fn[contact] > 0.0)
    assert np.all(fn[~contact] <= edge_run.params.contact_force_threshold)
    # sliding_pos: the point moves +x between consecutive sliding samples
    both = np.flatnonzero((mode[1:] == SLIDING_POS) & (mode[:-1] == SLIDING_POS))
    assert np.all(arr["pose"][both + 1, 0] > arr["pose"][both, 0])
    # true friction is the coefficient of the segment under the point
    mu = [edge_run.params.mu_at(float(xx)) for xx in arr["pose"][:, 0]]
    assert np.array_equal(arr["friction"][:, 0], mu)


def test_sliding_acceleration_matches_coulomb(edge_run: SimRun) -> None:
    """On the left smooth segment under constant force: a = (fx - mu m g) / m."""
    arr = edge_run.stack()
    p = edge_run.params
    mode = _mode(edge_run)
    t = arr["t"]
    sel = (mode == SLIDING_POS) & (t > 0.3) & (t < 1.0)
    assert np.count_nonzero(sel) > 30
    a = np.polyfit(t[sel], arr["twist"][sel, 0], 1)[0]
    fx = arr["wrench"][sel, 0]
    assert np.ptp(fx) == 0.0
    expected = (fx[0] - 0.3 * p.mass * G) / p.mass
    assert a == pytest.approx(expected, rel=0.01)


@pytest.mark.parametrize("mu", [0.3, 0.9])
def test_free_slide_decelerates_at_mu_g_and_stops(mu: float) -> None:
    """No applied force, initial speed 1 m/s: v(t) = 1 - mu g t, then it sticks."""
    params = EdgeParams(
        duration=0.5,
        segments=((-5.0, 5.0, mu),),
        start=(0.0, 0.0),
        start_velocity=(1.0, 0.0),
        force=((0.0, 0.0, 0.0),),
    )
    arr = EdgeSimulation(params).run().stack()
    t, v = arr["t"], arr["twist"][:, 0]
    stop = 1.0 / (mu * G)
    sel = (t > 0.02) & (t < stop - 0.02)
    decel = -np.polyfit(t[sel], v[sel], 1)[0]
    assert decel == pytest.approx(mu * G, rel=0.01)
    x_stop = arr["pose"][-1, 0]
    assert x_stop == pytest.approx(1.0 / (2.0 * mu * G), rel=0.02)
    assert np.all(np.argmax(arr["modes"][t > stop + 0.02, 0], axis=1) == STICKING)


def test_static_friction_holds_below_the_cone_and_yields_above() -> None:
    base: dict[str, Any] = {"segments": ((-5.0, 5.0, 0.5),), "start": (0.0, 0.0), "duration": 0.5}
    below = EdgeSimulation(EdgeParams(force=((0.0, 0.45 * G, 0.0),), **base)).run().stack()
    assert np.max(np.abs(below["pose"][:, 0])) < 1e-5
    above = EdgeSimulation(EdgeParams(force=((0.0, -0.55 * G, 0.0),), **base)).run().stack()
    assert above["pose"][-1, 0] < -0.005
    mode = np.argmax(above["modes"][:, 0], axis=1)
    assert np.count_nonzero(mode == SLIDING_NEG) > 40


def test_recorded_wrench_is_the_input_of_the_next_interval(edge_run: SimRun) -> None:
    """In free flight m (v[k+1] - v[k]) / dt = u[k] + m g exactly: u[k] is the mean input."""
    arr = edge_run.stack()
    p = edge_run.params
    mode = _mode(edge_run)
    free = np.flatnonzero((mode[:-1] == SEPARATED) & (mode[1:] == SEPARATED))
    free = free[arr["t"][free] > 4.8]  # after the lift-off near the right end
    assert len(free) > 30
    dt = 1.0 / p.rate
    acc = (arr["twist"][free + 1, :2] - arr["twist"][free, :2]) / dt
    expected = arr["wrench"][free, :2] / p.mass + np.array([0.0, -p.gravity])
    assert np.max(np.abs(acc - expected)) < 1e-6
