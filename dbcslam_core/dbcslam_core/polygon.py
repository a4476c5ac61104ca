"""Polygons in the plane: the planar cross product, area, centroid and polar moment of inertia
of a uniform polygon, the strictly convex hull (SI units; vertices as an (n >= 3, 2) array
in m).

Needs nothing but numpy, so both `scenario` (default inertia of a pushed outline) and
`geometry` / `mass_properties` import it without importing each other; the MIT importer and
the simulator take their convex hull from here.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np
from numpy.typing import ArrayLike, NDArray

from .errors import ModelError

__all__ = [
    "as_polygon",
    "convex_hull",
    "cross2",
    "polygon_area",
    "polygon_centroid",
    "polygon_inertia",
]

F64 = NDArray[np.float64]


def cross2(a: ArrayLike, b: ArrayLike) -> F64:
    """Planar cross product a_x b_y - a_y b_x over the last axis (size 2)."""
    aa = np.asarray(a, dtype=np.float64)
    bb = np.asarray(b, dtype=np.float64)
    return np.asarray(aa[..., 0] * bb[..., 1] - aa[..., 1] * bb[..., 0], dtype=np.float64)


def as_polygon(vertices: Sequence[Sequence[float]] | ArrayLike) -> F64:
    """The vertices as a float (n >= 3, 2) array (m); ModelError for any other shape."""
    v = np.asarray(vertices, dtype=np.float64)
    if v.ndim != 2 or v.shape[1] != 2 or v.shape[0] < 3:
        msg = f"polygon needs vertices of shape (n >= 3, 2), got shape {v.shape}"
        raise ModelError(msg)
    return v


def polygon_area(vertices: Sequence[Sequence[float]] | ArrayLike) -> float:
    """Signed area (m^2, > 0 for counter-clockwise vertices) of a simple polygon."""
    v = as_polygon(vertices)
    return float(0.5 * np.sum(cross2(v, np.roll(v, -1, axis=0))))


def polygon_centroid(vertices: Sequence[Sequence[float]] | ArrayLike) -> F64:
    """Centroid (m) of the uniform-density polygon area."""
    v = as_polygon(vertices)
    w = np.roll(v, -1, axis=0)
    cr = cross2(v, w)
    a = 0.5 * np.sum(cr)
    if abs(a) < 1e-300:
        msg = f"polygon has zero area: {v.tolist()}"
        raise ModelError(msg)
    return np.asarray(np.sum((v + w) * cr[:, None], axis=0) / (6.0 * a), dtype=np.float64)


def polygon_inertia(
    vertices: Sequence[Sequence[float]] | ArrayLike, mass: float, about_centroid: bool = False
) -> float:
    """Polar moment of inertia (kg m^2) of a uniform polygon of `mass` about the origin.

    With `about_centroid` the moment is taken about the area centroid instead.
    """
    v = as_polygon(vertices)
    if about_centroid:
        v = v - polygon_centroid(v)
    w = np.roll(v, -1, axis=0)
    cr = cross2(v, w)
    a = 0.5 * np.sum(cr)
    j = np.sum(cr * (np.sum(v * v, 1) + np.sum(v * w, 1) + np.sum(w * w, 1))) / 12.0
    return float(mass * j / a)


def convex_hull(points: ArrayLike) -> F64:
    """Strictly convex hull, counter-clockwise (monotone chain, collinear points dropped)."""
    pts = sorted({(float(x), float(y)) for x, y in np.asarray(points, dtype=np.float64)})
    if len(pts) < 3:
        return np.asarray(pts, dtype=np.float64)
    scale = max(math.hypot(x, y) for x, y in pts)
    tol = 1e-10 * scale * scale

    def cross(o: tuple[float, float], a: tuple[float, float], b: tuple[float, float]) -> float:
        return (a[0] - o[0]) * (b[1] - o[1]) - (a[1] - o[1]) * (b[0] - o[0])

    lower: list[tuple[float, float]] = []
    for p in pts:
        while len(lower) >= 2 and cross(lower[-2], lower[-1], p) <= tol:
            lower.pop()
        lower.append(p)
    upper: list[tuple[float, float]] = []
    for p in reversed(pts):
        while len(upper) >= 2 and cross(upper[-2], upper[-1], p) <= tol:
            upper.pop()
        upper.append(p)
    return np.asarray(lower[:-1] + upper[:-1], dtype=np.float64)
