"""Pushed-object outlines (MIT MCube push dataset) and their mass properties.

Outlines are (n, 2) vertex arrays in metres; the package ships `rect1`, `ellip1`, `ellip3`
and `hex` (stainless steel, 13 mm thick) in `data/shapes/`. `load_outline` returns the
outline counter-clockwise, about its centroid (the centre of mass of a uniform plate),
reduced to its strictly convex hull (the pybullet collision shape is that hull).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from dbcslam_core.mass_properties import STAINLESS_STEEL_DENSITY
from dbcslam_core.polygon import convex_hull, polygon_area, polygon_centroid, polygon_inertia
from dbcslam_ros.importers.mitpush import SHAPES as DATASET_SHAPES
from dbcslam_ros.importers.mitpush import ShapeFacts

from .errors import ParamError

__all__ = ["SHAPES", "SHAPE_DIR", "STEEL_DENSITY", "Outline", "ShapeInfo", "load_outline"]

SHAPE_DIR: Path = Path(__file__).resolve().parent / "data" / "shapes"
STEEL_DENSITY: float = STAINLESS_STEEL_DENSITY
"""kg/m^3, consistent with the dataset's rect1 mass (0.8374 kg for 90 x 90 x 13 mm)."""

#: Dataset facts of one shape: mass (kg) and polar inertia about the centroid (kg m^2).
ShapeInfo = ShapeFacts

#: The dataset README's table of the four training shapes (the MIT importer's, one table).
SHAPES: dict[str, ShapeInfo] = DATASET_SHAPES


@dataclass(frozen=True)
class Outline:
    """A convex outline about its centroid (counter-clockwise, m) and its mass properties.

    offset: position (m) of the centroid in the file's object frame (vertices_file =
    vertices + offset). mass in kg, inertia about the centroid in kg m^2.
    """

    name: str
    vertices: NDArray[np.float64]
    offset: tuple[float, float]
    area: float
    mass: float
    inertia: float


def load_outline(
    shape: str,
    *,
    thickness: float = 0.013,
    mass: float | None = None,
    inertia: float | None = None,
) -> Outline:
    """Outline of `shape` (a name of `SHAPES` or a path to an (n, 2) `.npy` file).

    mass/inertia default to the dataset table for known shapes, else to a uniform steel plate
    of `thickness` (m). Raises `ParamError` for unknown shapes or malformed files.
    """
    path = Path(shape)
    if shape in SHAPES:
        path = SHAPE_DIR / f"{shape}_ext.npy"
    elif path.suffix != ".npy":
        msg = (
            f"unknown shape {shape!r}; valid shapes are {sorted(SHAPES)} or a path to an "
            "(n, 2) .npy outline"
        )
        raise ParamError(msg)
    try:
        raw = np.load(path, allow_pickle=False)
    except (OSError, ValueError) as err:
        msg = f"cannot load outline file {path}: {err}"
        raise ParamError(msg) from err
    if raw.ndim != 2 or raw.shape[1] != 2 or raw.shape[0] < 3 or not np.all(np.isfinite(raw)):
        msg = f"outline file {path} must hold a finite (n >= 3, 2) array, got shape {raw.shape}"
        raise ParamError(msg)
    hull = convex_hull(np.asarray(raw, dtype=np.float64))
    if len(hull) < 3:
        msg = f"outline file {path} is degenerate (fewer than 3 hull vertices)"
        raise ParamError(msg)
    area = polygon_area(hull)  # > 0: the hull is counter-clockwise and not degenerate
    cx, cy = polygon_centroid(hull)
    verts = hull - np.array([cx, cy])
    info = SHAPES.get(shape)
    m = mass if mass is not None else (info.mass if info else STEEL_DENSITY * area * thickness)
    if inertia is not None:
        izz = inertia
    elif info is not None and mass is None:
        izz = info.inertia
    else:
        izz = polygon_inertia(verts, m)
    return Outline(path.stem.removesuffix("_ext"), verts, (cx, cy), area, float(m), float(izz))
