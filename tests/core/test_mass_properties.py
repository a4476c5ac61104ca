"""Plate mass properties (dbcslam_core.mass_properties): exact shapes, invariance, MIT table."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from dbcslam_core.errors import ModelError
from dbcslam_core.mass_properties import (
    MIT_PUSH_THICKNESS,
    STAINLESS_STEEL_DENSITY,
    plate_properties,
)

SHAPES = Path(__file__).resolve().parents[1] / "data" / "mit-push" / "shapes"
#: The MIT push dataset README's table: shape -> (mass kg, I_z kg m^2).
TABLE = {
    "rect1": (0.8374, 1.131e-3),
    "ellip1": (0.8937, 1.231e-3),
    "ellip3": (1.3338, 2.973e-3),
    "hex": (0.9827, 1.497e-3),
}

lengths = st.floats(0.01, 0.5)


def _rect(a: float, b: float) -> np.ndarray:
    return np.array([[0.0, 0.0], [a, 0.0], [a, b], [0.0, b]])


def _transform(v: np.ndarray, yaw: float, shift: tuple[float, float]) -> np.ndarray:
    c, s = math.cos(yaw), math.sin(yaw)
    return v @ np.array([[c, s], [-s, c]]) + np.array(shift)


@given(lengths, lengths, st.floats(100.0, 20000.0), st.floats(0.001, 0.05))
def test_rectangle_exact(a: float, b: float, density: float, thickness: float) -> None:
    p = plate_properties(_rect(a, b), density, thickness)
    mass = density * thickness * a * b
    assert p.area == pytest.approx(a * b, rel=1e-12)
    assert p.centroid == pytest.approx((a / 2, b / 2), rel=1e-9)
    assert p.mass == pytest.approx(mass, rel=1e-12)
    assert p.inertia == pytest.approx(mass * (a * a + b * b) / 12.0, rel=1e-9)


@settings(max_examples=50)
@given(
    st.lists(st.tuples(st.floats(-0.1, 0.1), st.floats(-0.1, 0.1)), min_size=3, max_size=12),
    st.floats(-math.pi, math.pi),
    st.tuples(st.floats(-1.0, 1.0), st.floats(-1.0, 1.0)),
    st.booleans(),
)
def test_invariant_under_rigid_motion_and_winding(
    pts: list[tuple[float, float]], yaw: float, shift: tuple[float, float], reverse: bool
) -> None:
    # A star-shaped simple polygon: points sorted by angle about their mean.
    v = np.array(pts)
    ang = np.arctan2(*(v - v.mean(axis=0)).T[::-1])
    v = v[np.argsort(ang)]
    area = 0.5 * abs(
        float(np.sum(v[:, 0] * np.roll(v[:, 1], -1) - np.roll(v[:, 0], -1) * v[:, 1]))
    )
    if area < 1e-5:
        return
    p = plate_properties(v)
    moved = _transform(v, yaw, shift)
    q = plate_properties(moved[::-1] if reverse else moved)
    assert q.area == pytest.approx(p.area, rel=1e-7)
    assert q.mass == pytest.approx(p.mass, rel=1e-7)
    assert q.inertia == pytest.approx(p.inertia, rel=1e-6, abs=1e-15)
    expected_c = _transform(np.array([p.centroid]), yaw, shift)[0]
    np.testing.assert_allclose(q.centroid, expected_c, atol=1e-9)


@pytest.mark.parametrize("n", [64, 256, 1024])
def test_disc_converges(n: int) -> None:
    r = 0.0525
    th = 2 * math.pi * np.arange(n) / n
    p = plate_properties(np.column_stack([r * np.cos(th), r * np.sin(th)]))
    mass = STAINLESS_STEEL_DENSITY * MIT_PUSH_THICKNESS * math.pi * r * r
    tol = 2.0 * (2 * math.pi / n) ** 2  # inscribed polygon: relative error ~ (2 pi / n)^2 / 6
    assert p.mass == pytest.approx(mass, rel=tol)
    assert p.inertia == pytest.approx(0.5 * mass * r * r, rel=2 * tol)
    assert np.hypot(*p.centroid) < 1e-12


@pytest.mark.parametrize("shape", sorted(TABLE))
def test_steel_plate_matches_the_dataset_table(shape: str) -> None:
    """7950 kg/m^3 and 13 mm reproduce the README's masses within 0.33 %, inertias 0.74 %."""
    p = plate_properties(np.load(SHAPES / f"{shape}_ext.npy"))
    mass, inertia = TABLE[shape]
    assert p.mass == pytest.approx(mass, rel=0.004)
    assert p.inertia == pytest.approx(inertia, rel=0.008)


def test_least_squares_density_is_stainless_steel() -> None:
    vols = np.array([plate_properties(np.load(SHAPES / f"{s}_ext.npy")).area for s in TABLE])
    vols *= MIT_PUSH_THICKNESS
    masses = np.array([TABLE[s][0] for s in TABLE])
    density = float(vols @ masses / (vols @ vols))
    assert 7900.0 < density < 8000.0  # stainless steel (304/316)
    assert density == pytest.approx(STAINLESS_STEEL_DENSITY, rel=0.002)


@pytest.mark.parametrize(
    ("args", "problem"),
    [
        (([[0, 0], [1, 0]],), "n >= 3"),
        (([[0, 0], [1, 0], [2, 0]],), "zero area"),
        (([[0, 0], [1, 0], [0, float("nan")]],), "finite"),
        ((_rect(1, 1), -1.0), "density"),
        ((_rect(1, 1), 7950.0, 0.0), "thickness"),
        ((_rect(1, 1), float("inf")), "density"),
    ],
)
def test_bad_input_is_named(args: tuple[object, ...], problem: str) -> None:
    with pytest.raises(ModelError, match=problem):
        plate_properties(*args)  # type: ignore[arg-type]
