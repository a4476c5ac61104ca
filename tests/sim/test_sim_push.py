"""Push scenario: pusher path, object motion, contact truth and the pusher F/T force."""

from __future__ import annotations

import numpy as np
import pytest

from sim_publisher.bullet import SEPARATED, SLIDING_NEG, SLIDING_POS, STICKING
from sim_publisher.errors import ParamError
from sim_publisher.params import PushParams
from sim_publisher.push import PushSimulation, push_path
from sim_publisher.records import SimRun

G = 9.81


def _push_phase(sim: PushSimulation, t: np.ndarray) -> np.ndarray:
    touch = sim.params.approach / sim.params.speed
    return np.asarray((t > touch + 0.05) & (t < sim.move_time - 0.01))


def test_pusher_follows_the_straight_path(push_sim: PushSimulation, push_run: SimRun) -> None:
    arr = push_run.stack()
    targets = np.array([push_sim.pusher_target(float(t))[0] for t in arr["t"]])
    assert np.max(np.linalg.norm(arr["joints"] - targets, axis=1)) < 2e-4
    assert push_run.joint_names == ("pusher_x", "pusher_y")


def test_object_moves_in_the_push_direction(push_sim: PushSimulation, push_run: SimRun) -> None:
    arr = push_run.stack()
    d = arr["pose"][-1, :2] - arr["pose"][0, :2]
    along = float(d @ push_sim.direction)
    assert along == pytest.approx(push_sim.params.travel, abs=0.003)
    assert abs(float(d @ np.array([-push_sim.direction[1], push_sim.direction[0]]))) < 0.003
    assert abs(arr["pose"][-1, 2]) < 0.01  # centred straight push: no turning


def test_pusher_in_contact_during_the_push(push_sim: PushSimulation, push_run: SimRun) -> None:
    arr = push_run.stack()
    mode = np.argmax(arr["modes"][:, 0], axis=1)
    phase = _push_phase(push_sim, arr["t"])
    assert np.mean(mode[phase] != SEPARATED) > 0.95
    before = arr["t"] < push_sim.params.approach / push_sim.params.speed - 0.02
    assert np.all(mode[before] == SEPARATED)
    assert np.all(arr["pusher_wrench"][before] == 0.0)


def test_pusher_force_balances_support_friction(
    push_sim: PushSimulation, push_run: SimRun
) -> None:
    """Quasi-static straight push: F on the pusher = -mu_s m g along the push direction."""
    arr = push_run.stack()
    phase = _push_phase(push_sim, arr["t"])
    f = arr["pusher_wrench"][phase, :2].mean(axis=0)
    expected = push_sim.params.mu_surface * push_sim.outline.mass * G
    assert float(-f @ push_sim.direction) == pytest.approx(expected, rel=0.05)


def test_angled_push_slides_at_the_friction_cone() -> None:
    sim = PushSimulation(PushParams(shape="hex", side=2, side_position=0.3, angle=0.6))
    arr = sim.run().stack()
    mode = np.argmax(arr["modes"][:, 0], axis=1)
    sliding = (mode == SLIDING_POS) | (mode == SLIDING_NEG)
    assert np.count_nonzero(sliding) > 30
    assert np.count_nonzero(mode == STICKING) < np.count_nonzero(sliding)
    # sliding contact force lies on the cone edge: |f_t| / f_n = mu_pusher, with the pushed
    # side's normal rotated by the object's yaw
    f = arr["pusher_wrench"][sliding, :2]
    yaw = arr["pose"][sliding, 2]
    n0 = _outward_normal(sim, sim.params.side)
    c, s = np.cos(yaw), np.sin(yaw)
    normal = np.stack([c * n0[0] - s * n0[1], s * n0[0] + c * n0[1]], axis=1)
    fn = np.abs(np.sum(f * normal, axis=1))
    ft = np.abs(f[:, 0] * normal[:, 1] - f[:, 1] * normal[:, 0])
    steady = fn > 1.0
    assert np.count_nonzero(steady) > 20
    assert np.median(ft[steady] / fn[steady]) == pytest.approx(sim.params.mu_pusher, rel=0.1)


def _outward_normal(sim: PushSimulation, side: int) -> np.ndarray:
    v = sim.outline.vertices
    e = v[(side + 1) % len(v)] - v[side]
    return np.array([e[1], -e[0]]) / float(np.linalg.norm(e))


def test_object_stops_at_mu_g_after_the_pusher_stops() -> None:
    p = PushParams(speed=0.3, approach=0.01, travel=0.05, duration=0.5, rate=1000.0)
    sim = PushSimulation(p)
    arr = sim.run().stack()
    t = arr["t"]
    speed = np.linalg.norm(arr["twist"][:, :2], axis=1)
    after = (t > sim.move_time + 0.01) & (speed > 0.05)
    assert np.count_nonzero(after) > 20
    decel = -np.polyfit(t[after], speed[after], 1)[0]
    assert decel == pytest.approx(p.mu_surface * G, rel=0.05)


def test_push_path_geometry_and_bad_side() -> None:
    square = np.array([[-1.0, -1.0], [1.0, -1.0], [1.0, 1.0], [-1.0, 1.0]])
    start, d, touch = push_path(
        square, side=0, side_position=0.25, angle=0.0, pusher_radius=0.1, approach=0.5
    )
    assert np.allclose(d, [0.0, 1.0])
    assert np.allclose(touch, [-0.5, -1.1])
    assert np.allclose(start, [-0.5, -1.6])
    with pytest.raises(ParamError, match="side"):
        push_path(square, side=4, side_position=0.5, angle=0.0, pusher_radius=0.1, approach=0.1)


@pytest.mark.parametrize("shape", ["rect1", "ellip1", "ellip3", "hex"])
@pytest.mark.parametrize("side", [0, 1])
def test_every_shipped_shape_is_pushed_along(shape: str, side: int) -> None:
    sim = PushSimulation(PushParams(shape=shape, side=side))
    arr = sim.run().stack()
    d = arr["pose"][-1, :2] - arr["pose"][0, :2]
    assert float(d @ sim.direction) > 0.9 * sim.params.travel
    mode = np.argmax(arr["modes"][:, 0], axis=1)
    assert np.mean(mode[_push_phase(sim, arr["t"])] != SEPARATED) > 0.95
    # contact geometry (margin compensated): the outline's distance to the pusher axis is
    # the pusher radius while in contact and never less
    dist = np.array(
        [
            _distance_to_outline(sim, pose, p)
            for pose, p in zip(arr["pose"], arr["joints"], strict=True)
        ]
    )
    r = sim.params.pusher_radius
    assert np.min(dist) > r - 5e-5
    assert np.max(np.abs(dist[mode != SEPARATED] - r)) < 5e-5


def _distance_to_outline(sim: PushSimulation, pose: np.ndarray, point: np.ndarray) -> float:
    c, s = np.cos(pose[2]), np.sin(pose[2])
    local = np.array([[c, s], [-s, c]]) @ (point - pose[:2])
    a = sim.outline.vertices
    b = np.roll(a, -1, axis=0)
    ab = b - a
    u = np.clip(np.einsum("ij,ij->i", local - a, ab) / np.einsum("ij,ij->i", ab, ab), 0, 1)
    return float(np.min(np.linalg.norm(a + u[:, None] * ab - local, axis=1)))
