"""`dbcslam_research.push_analysis` on outlines of the MIT dataset and one real push: the
quasi-static friction radius, the twist of a pushed body, a replayed push."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

import dbcslam_ros.importers.mitpush as mp
from dbcslam_research.push_analysis import _twist, analyse_motion, friction_radius

DATA = Path(__file__).resolve().parents[1] / "data" / "mit-push"
FILES = sorted((DATA / "abs" / "train").glob("*.h5"))


def test_friction_radius_of_square() -> None:
    square = mp.load_outline("rect1", DATA / "shapes").vertices
    side = 0.09
    exact = side * (math.sqrt(2.0) + math.log(1.0 + math.sqrt(2.0))) / 6.0  # mean |r|
    assert friction_radius(square) == pytest.approx(exact, rel=0.01)


def test_quasi_static_twist_directions() -> None:
    c = 0.03
    # Centred push on the -x side, straight in: pure translation along +x.
    tw = _twist(np.array([-0.045, 0.0]), np.array([-1.0, 0.0]), np.array([0.001, 0.0]), c, 0.25)
    np.testing.assert_allclose(tw, [0.001, 0.0, 0.0], atol=1e-12)
    # Off-centre (+y) push along +x turns the body clockwise, and the contact slides less
    # than it is pushed (the normal velocity of the contact equals the pusher's).
    r, n, vp = np.array([-0.045, 0.03]), np.array([-1.0, 0.0]), np.array([0.001, 0.0])
    tw = _twist(r, n, vp, c, 0.25)
    assert tw[2] < 0.0
    vc = tw[:2] + tw[2] * np.array([-r[1], r[0]])
    assert vc[0] == pytest.approx(vp[0])
    # Pulling away does not move the body.
    np.testing.assert_array_equal(_twist(r, n, -vp, c, 0.25), np.zeros(3))


def test_quasi_static_replay_on_real_push() -> None:
    path = next(f for f in FILES if "hex" in f.name)
    raw = mp.load_push(path)
    outline = mp.load_outline("hex", DATA / "shapes")
    series = mp.resample_push(raw, outline, mp.ImportConfig(dt=0.004))
    motion = analyse_motion(series, friction_radius(outline.vertices))
    assert motion.pusher == pytest.approx(0.05, abs=0.003)  # 5 cm push, in contact throughout
    assert 0.04 < motion.displacement < 0.05
    assert motion.predicted_displacement == pytest.approx(motion.displacement, abs=0.005)
    assert np.sign(motion.predicted_rotation) == np.sign(motion.rotation)
