"""Mass properties of a uniform flat plate cut to a polygonal outline.

A pushed object of the MIT MCube dataset is a stainless-steel plate of constant thickness; its
mass and its polar moment of inertia about the centroid (the z axis through the centre of
mass, the only one planar pushing needs) follow from the outline alone:

* area ``A = 1/2 sum (x_i y_{i+1} - x_{i+1} y_i)`` (shoelace; m^2),
* centroid ``c = 1/(6A) sum (p_i + p_{i+1}) (x_i y_{i+1} - x_{i+1} y_i)`` (m),
* second polar moment of area about c ``J = 1/12 sum cr_i (|p_i|^2 + p_i . p_{i+1} +
  |p_{i+1}|^2) - A |c|^2`` (m^4, the origin's moment moved to the centroid),
* ``mass = density * thickness * |A|`` (kg), ``inertia = density * thickness * |J|``
  (kg m^2) = mass * J / A.

The formulas are exact for the polygon; a smooth outline sampled as a polygon loses the
slivers between its vertices (ellip1, 61 vertices: area -0.46 % of the 105 mm disc, whose
exact mass at 7950 kg/m^3 would be +0.13 % off the table instead of -0.33 %). Units are SI
throughout: density kg/m^3, thickness m. Pure numpy; the polygon algebra is the core's
(:mod:`dbcslam_core.geometry`).

Checked against the dataset's table (``tests/core/test_mass_properties.py``): with
:data:`STAINLESS_STEEL_DENSITY` = 7950 kg/m^3 and 13 mm the four tabulated masses are matched
within 0.33 % and the inertias within 0.74 %.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike

from .errors import ModelError
from .polygon import polygon_area, polygon_centroid, polygon_inertia

__all__ = [
    "MIT_PUSH_THICKNESS",
    "STAINLESS_STEEL_DENSITY",
    "PlateProperties",
    "plate_properties",
]

STAINLESS_STEEL_DENSITY: float = 7950.0
"""kg/m^3: stainless steel (304/316: 7900-8000 kg/m^3). The least-squares density of the four
masses the MIT dataset tabulates, given their outline files and 13 mm, is 7946 kg/m^3 (per
shape 7934-7976)."""
MIT_PUSH_THICKNESS: float = 0.013
"""m: thickness of every object of the MIT push dataset ("stainless steel, 13 mm thick")."""


@dataclass(frozen=True)
class PlateProperties:
    """Mass properties of a uniform plate.

    area: m^2 (> 0). centroid: (x, y) in the outline's own frame, m. mass: kg. inertia:
    polar moment about the centroid (z axis), kg m^2. density (kg/m^3) and thickness (m):
    the values used.
    """

    area: float
    centroid: tuple[float, float]
    mass: float
    inertia: float
    density: float
    thickness: float


def _check_positive(name: str, value: float) -> float:
    v = float(value)
    if not (math.isfinite(v) and v > 0.0):
        msg = f"{name} must be a finite number > 0, got {value!r}"
        raise ModelError(msg)
    return v


def plate_properties(
    vertices: Sequence[Sequence[float]] | ArrayLike,
    density: float = STAINLESS_STEEL_DENSITY,
    thickness: float = MIT_PUSH_THICKNESS,
) -> PlateProperties:
    """Mass and polar inertia about the centroid of a uniform plate with this outline.

    vertices: (n >= 3, 2) outline of a simple polygon, m, either winding. density: kg/m^3.
    thickness: m.

    Raises:
        ModelError: malformed vertices (shape, NaN/inf), zero area, density or thickness
            not a finite positive number.
    """
    rho = _check_positive("density", density)
    h = _check_positive("thickness", thickness)
    v = np.asarray(vertices, dtype=np.float64)
    if v.ndim != 2 or v.shape[1] != 2 or v.shape[0] < 3 or not np.all(np.isfinite(v)):
        msg = f"outline must be a finite (n >= 3, 2) array of vertices, m; got shape {v.shape}"
        raise ModelError(msg)
    signed = polygon_area(v)
    scale = float(np.max(np.abs(v))) if v.size else 0.0
    if not abs(signed) > 1e-12 * max(scale * scale, 1e-300):
        msg = f"outline has zero area (signed area {signed:.3g} m^2); cannot compute its mass"
        raise ModelError(msg)
    area = abs(signed)
    cx, cy = (float(c) for c in polygon_centroid(v))
    mass = rho * h * area
    # polygon_inertia divides by the signed area: the winding cancels.
    inertia = polygon_inertia(v, mass, about_centroid=True)
    return PlateProperties(
        area=area,
        centroid=(cx, cy),
        mass=mass,
        inertia=abs(inertia),
        density=rho,
        thickness=h,
    )
