"""MIT MCube planar-pushing files (``.h5``) -> aligned, resampled push series (numpy + h5py).

Data: "More than a Million Ways to Be Pushed" (K.-T. Yu, M. Bauza, N. Fazeli, A. Rodriguez,
IROS 2016). Each file holds ``tip_pose``, ``object_pose`` and ``ft_wrench``, N x 4 arrays
``[t, a, b, c]`` with their own Unix-time stamps (~250 Hz): the pusher tip (x, y, yaw), the
Vicon-tracked object frame (x, y, yaw) and the F/T reading (fx, fy, tau_z). File names carry
``motion_surface=S_shape=O_a=A_v=V_i=I_s=P_t=T`` (:func:`parse_push_name`).

What this module found in the 50 ABS training pushes and applies (numbers from
``python -m dbcslam_research.push_analysis``; see the report in that module):

* **Shapes.** Any shape with an outline ``shapes/<shape>_ext.npy`` (11 in the dataset; the
  training pushes use 4). Mass and inertia about the centroid are those of a uniform plate
  cut to the outline (:func:`mass_properties`, :mod:`dbcslam_core.mass_properties`):
  stainless steel 7950 kg/m^3, 13 mm, which reproduces the README's four masses within
  0.33 % and inertias within 0.74 % (least-squares density of the four: 7946 kg/m^3).
* **Frame alignment, estimated** (:mod:`dbcslam_ros.importers.mitpush_align`; ``python -m
  dbcslam_ros.importers.mitpush_align`` prints the numbers): per shape, over every push file of
  it in the same directory, the planar map outline file -> tracked frame (yaw, offset, mirrored or
  not) that makes the pusher tip touch the outline on in-contact steps and first touch it
  where the file name says (Huber, global search over yaw and both conventions). On the 50
  training pushes the data select the *mirrored* convention for all four shapes (robust cost
  1.1-13x lower than unmirrored): a point (x, y) of the file lies at about (-y, -x) in the
  tracked frame, body yaw = Vicon yaw + ~pi/2, as the first importer had found by hand. The
  fit reproduces its hand-fitted constants (:data:`ALIGNMENTS`) within 0.1 mm / 1.7 mrad for
  ellip3 and within 0.8 mm in offset for all four, but puts the yaw 11-24 mrad lower for
  ellip1, hex and rect1 (jackknife standard errors over the files 9-22 mrad), where its
  robust cost is 1-29 % lower than the constants'; ``push_analysis`` had found the same
  -10 to -25 mrad refit and left it unapplied. Residuals with the fit: median |tip-outline
  distance - radius| 0.35-0.73 mm per shape (median over files), first contact from the
  file name's point median 0.88-1.48 mm, max 4.1 mm (|t| < 1.2 rad). With this frame the
  file-name fields follow the natural convention: side ``i`` runs from body vertex ``i`` to
  ``i + 1`` (the mirrored file's order) and ``s`` is the fraction along it; for smooth
  outlines (ellipses, > 8 vertices) ``s`` is the fraction of the perimeter from vertex 0
  (:func:`expected_contact`). The numbers in the bullets below were measured with the hand-
  fitted constants (alignment changes of < 1 mm / 25 mrad).
* **F/T frame.** The force is the force the object exerts on the pusher, in the world (Vicon)
  axes already: while the object moves its direction is ``push direction + pi - t`` up to the
  friction tilt (median over files -0.012 rad, IQR [-0.14, +0.08] rad: no common rotation),
  so no rotation is applied; its sign convention is the simulator's ``/pusher/wrench`` one.
* **Stale F/T.** In every ``rect1`` file the F/T stream holds only 2-4 distinct readings (a
  frozen sensor buffer); :func:`ft_is_stale` detects it (fewer than half the samples
  distinct). Such files get no ``/pusher/wrench`` and a geometric contact flag.
* **Contact flag.** In contact when the F/T force magnitude (mean over the model step)
  exceeds :data:`CONTACT_THRESHOLD` = 0.25 N: the noise std at rest (first 0.15 s) is
  0.027 N per axis (median over files; max 0.15 N). No bias is removed: in about half the
  files the pusher already presses on the object at rest (preload 1-5 N along the later push
  force), which is contact, not bias. With a stale F/T stream the flag is geometric
  (:func:`geometric_contact`): tip-to-outline gap within :data:`GEOMETRIC_CONTACT_TOL` = 1 mm
  of the push's own gap while the object moves (that gap is 0.0-1.8 mm per file: the
  alignment varies slightly between recording sessions). It is a *touching* flag, not a force
  flag: on the 37 pushes with a live F/T stream (where both can be computed) it agrees with the
  F/T flag on 0.925 of the steps (median per push; 1.000 while the object moves, 0.738 at
  rest), recall 1.00 but specificity 0.00 (a pusher resting against the object with less than
  0.25 N counts as contact). For ``rect1`` it therefore flags resting contact (22-43 % of the
  steps per file) that nothing but a force sensor could confirm or refute.
* **Pusher tip noise.** The robot's tip pose is precise: std at rest 0.8 um (median over the
  files, max 1.3 um), residual about a quadratic fit at constant speed 21 um (max 40 um).
  The scenario declares :data:`JOINT_NOISE` = 20 um (``noise.joint``, the std the filter's
  joint smoother assumes). With the core's default 0.5 mm (a simulator value) the smoother
  lags the tip at starts and overshoots it at stops by up to 1.4 mm (median over the
  pushes of the largest deviation; 0.05 mm with 20 um): the estimated object is carried
  ~1 mm past the real stop and afterwards rests ~1 mm away from the pusher, "separated"
  while the F/T sensor reads 1-5 N.
* **Clocks.** The three streams start within 35 ms of each other; the series uses their
  common interval on one clock of step ``dt`` (stamps = the data's Unix time in ns). No
  offset between the tip and Vicon clocks is detectable: in near-sticking pushes the object
  stops with the pusher (median lag +0.0 ms, 6 of 10 within 10 ms), so none is applied.
"""

from __future__ import annotations

import math
import re
import zlib
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import numpy.typing as npt

from dbcslam_core.errors import ModelError
from dbcslam_core.mass_properties import (
    MIT_PUSH_THICKNESS,
    STAINLESS_STEEL_DENSITY,
    PlateProperties,
    plate_properties,
)
from dbcslam_core.polygon import convex_hull, polygon_area, polygon_centroid
from dbcslam_core.scenario import PUSH_MODELS
from dbcslam_ros.errors import BagError

__all__ = [
    "ALIGNMENTS",
    "CONTACT_THRESHOLD",
    "GEOMETRIC_CONTACT_TOL",
    "JOINT_NOISE",
    "PUSHER_RADIUS",
    "SHAPES",
    "STREAMS",
    "AlignmentCheck",
    "Clock",
    "ImportConfig",
    "MitPushError",
    "Outline",
    "PushInfo",
    "PushSeries",
    "RawPush",
    "ShapeAlignment",
    "ShapeFacts",
    "alignment_check",
    "body_pose",
    "common_clock",
    "convex_hull",
    "expected_contact",
    "find_shapes_dir",
    "ft_is_stale",
    "geometric_contact",
    "load_outline",
    "load_push",
    "mass_properties",
    "outline_from_vertices",
    "parse_push_name",
    "push_files",
    "read_shape_table",
    "resample_push",
    "shape_names",
    "signed_distance",
    "to_body",
]

FloatArray = npt.NDArray[np.float64]

STREAMS: tuple[str, ...] = ("tip_pose", "object_pose", "ft_wrench")
"""Datasets every push file must hold (N x 4 float arrays [t, ...])."""
PUSHER_RADIUS: float = 0.00475
"""Pusher tip radius, m (dataset configuration)."""
CONTACT_THRESHOLD: float = 0.25
"""Force magnitude (N) above which the F/T reading means contact (noise floor ~0.03 N)."""
GEOMETRIC_CONTACT_TOL: float = 0.001
JOINT_NOISE: float = 2e-5
"""Std (m) of the pusher tip readings written to the scenario (``noise.joint``): the tip pose
residual at constant speed (median 21 um); see the module docstring."""
"""Geometric contact flag (stale F/T): tip-outline gap above its bias below this, m."""
MOVING_SPEED: float = 0.003
"""Object speed (m/s) above which the object counts as moving (pushed, so in contact)."""
STALE_FT_FRACTION: float = 0.5
#: Push model written to the imported scenarios (``surface.model``); see the README section
#: "Measured data" for the measurement that chose it.
DEFAULT_PUSH_MODEL: str = "dynamic"
"""An F/T stream with fewer distinct readings than this fraction of its samples is stale."""
ONSET_DISPLACEMENT: float = 0.0002
"""Object displacement (m) from its initial position that marks the start of its motion."""


class MitPushError(BagError):
    """A push file (or its outline) cannot be imported; the message names the file."""


@dataclass(frozen=True)
class ShapeAlignment:
    """Body frame of a shape relative to the Vicon-tracked frame.

    yaw_offset: body yaw - Vicon yaw, rad. offset: position (m) of the outline file's origin
    in the tracked frame (the tracked frame is not exactly at the outline's origin).
    mirrored: the body frame is the x-mirrored outline file (a file point (x, y) lies at
    R(yaw_offset) (-x, y) + offset in the tracked frame); else the file as it is.
    """

    yaw_offset: float
    offset: tuple[float, float] = (0.0, 0.0)
    mirrored: bool = True


@dataclass(frozen=True)
class ShapeFacts:
    """Mass (kg) and polar inertia about the centroid (kg m^2) from the dataset's table."""

    mass: float
    inertia: float


SHAPES: dict[str, ShapeFacts] = {
    "rect1": ShapeFacts(0.8374, 1.131e-3),
    "ellip1": ShapeFacts(0.8937, 1.231e-3),
    "ellip3": ShapeFacts(1.3338, 2.973e-3),
    "hex": ShapeFacts(0.9827, 1.497e-3),
}
"""The dataset README's table (the four shapes of the training pushes): a reference the
computed plate properties are checked against, no longer a list of allowed shapes. The
importer reads the table of the dataset it imports (:func:`read_shape_table`)."""

_TABLE_ROW = re.compile(
    r"^\|\s*(?P<shape>[A-Za-z0-9]+)\s*\|[^|]*\|\s*(?P<mass>[0-9.eE+-]+)\s*\|"
    r"\s*(?P<inertia>[0-9.eE+-]+)\s*\|\s*$"
)


def shape_names(shapes_dir: str | Path) -> list[str]:
    """Shapes with an outline ``<shape>_ext.npy`` in ``shapes_dir`` (sorted; [] if none)."""
    d = Path(shapes_dir)
    if not d.is_dir():
        return []
    return sorted(p.name.removesuffix("_ext.npy") for p in d.glob("*_ext.npy"))


def read_shape_table(readme: str | Path) -> dict[str, ShapeFacts]:
    """Mass (kg) and I_z (kg m^2) per shape from the dataset README's facts table.

    Rows ``| shape | size | mass | I_z |`` with numeric mass and inertia; {} when the file
    does not exist or holds no such row.
    """
    try:
        text = Path(readme).read_text(encoding="utf-8")
    except OSError:
        return {}
    out: dict[str, ShapeFacts] = {}
    for line in text.splitlines():
        m = _TABLE_ROW.match(line.strip())
        if m is None:
            continue
        try:
            out[m["shape"]] = ShapeFacts(float(m["mass"]), float(m["inertia"]))
        except ValueError:
            continue
    return out


_HALF_PI = 0.5 * math.pi
ALIGNMENTS: dict[str, ShapeAlignment] = {
    "rect1": ShapeAlignment(_HALF_PI),
    "ellip1": ShapeAlignment(_HALF_PI, (0.0002, 0.0006)),
    "ellip3": ShapeAlignment(_HALF_PI - 0.0144, (-0.0005, -0.0015)),
    "hex": ShapeAlignment(_HALF_PI),
}
"""The hand-fitted per-shape constants of the first importer, kept as the reference the
estimated alignment (:mod:`dbcslam_ros.importers.mitpush_align`) is compared with; not used
to import."""

_NAME_RE = re.compile(
    r"motion_surface=(?P<surface>[A-Za-z0-9]+)_shape=(?P<shape>[A-Za-z0-9]+)"
    r"_a=(?P<a>-?[\d.]+)_v=(?P<v>-?[\d.]+)_i=(?P<i>-?[\d.]+)_s=(?P<s>-?[\d.]+)"
    r"_t=(?P<t>-?[\d.]+)$"
)


@dataclass(frozen=True)
class PushInfo:
    """File-name fields: surface, shape, acceleration (m/s^2), speed (m/s), side index,
    contact position along the side in [0, 1], push angle to the inward normal (rad)."""

    surface: str
    shape: str
    acceleration: float
    speed: float
    side: int
    position: float
    angle: float


def parse_push_name(path: str | Path) -> PushInfo:
    """Parse ``motion_surface=S_shape=O_a=A_v=V_i=I_s=P_t=T.h5`` (a in mm/s^2, v in mm/s).

    Any shape name is accepted here; whether an outline exists for it is checked when the
    outline is loaded (:func:`load_outline`).

    Raises:
        MitPushError: the name does not follow the pattern.
    """
    p = Path(path)
    stem = p.name.removesuffix(".h5")
    m = _NAME_RE.fullmatch(stem)
    if m is None:
        msg = (
            f"{p}: file name does not follow "
            "motion_surface=S_shape=O_a=A_v=V_i=I_s=P_t=T.h5 (MIT push dataset naming)"
        )
        raise MitPushError(msg)
    shape = m["shape"]
    try:
        side_f = float(m["i"])
        info = PushInfo(
            surface=m["surface"],
            shape=shape,
            acceleration=float(m["a"]) * 1e-3,
            speed=float(m["v"]) * 1e-3,
            side=round(side_f),
            position=float(m["s"]),
            angle=float(m["t"]),
        )
    except ValueError as err:
        msg = f"{p}: malformed number in the file name: {err}"
        raise MitPushError(msg) from err
    if abs(side_f - info.side) > 1e-9 or info.side < 0:
        msg = f"{p}: side index i={m['i']} is not a non-negative integer"
        raise MitPushError(msg)
    return info


@dataclass(frozen=True)
class RawPush:
    """One push file as stored: streams N x 4 [t (Unix s), ...], time-sorted, unique stamps."""

    path: Path
    info: PushInfo
    tip: FloatArray
    obj: FloatArray
    ft: FloatArray


def _clean_stream(path: Path, key: str, arr: FloatArray) -> FloatArray:
    if arr.ndim != 2 or arr.shape[1] != 4:
        msg = f"{path}: dataset '{key}' must be N x 4 [t, ...], got shape {arr.shape}"
        raise MitPushError(msg)
    if arr.shape[0] < 2:
        msg = f"{path}: dataset '{key}' is empty ({arr.shape[0]} samples; needs >= 2)"
        raise MitPushError(msg)
    if not np.all(np.isfinite(arr)):
        bad = int(np.sum(~np.all(np.isfinite(arr), axis=1)))
        msg = f"{path}: dataset '{key}' has {bad} rows with NaN/inf values"
        raise MitPushError(msg)
    order = np.argsort(arr[:, 0], kind="stable")
    arr = arr[order]
    keep = np.concatenate([[True], np.diff(arr[:, 0]) > 0.0])
    arr = arr[keep]
    if arr.shape[0] < 2:
        msg = f"{path}: dataset '{key}' has fewer than 2 distinct time stamps"
        raise MitPushError(msg)
    return np.ascontiguousarray(arr, dtype=np.float64)


def load_push(path: str | Path) -> RawPush:
    """Read and validate one push file.

    Raises:
        MitPushError: bad name, unreadable HDF5, missing dataset, wrong shape, empty stream,
            non-finite values.
    """
    import h5py

    p = Path(path)
    info = parse_push_name(p)
    streams: dict[str, FloatArray] = {}
    try:
        with h5py.File(p, "r") as h5:
            for key in STREAMS:
                if key not in h5:
                    msg = (
                        f"{p}: missing dataset '{key}' (a push file needs "
                        f"{', '.join(STREAMS)}; it has {', '.join(sorted(h5.keys())) or 'none'})"
                    )
                    raise MitPushError(msg)
                try:
                    streams[key] = np.asarray(h5[key][()], dtype=np.float64)
                except (TypeError, ValueError) as err:
                    msg = f"{p}: dataset '{key}' is not a numeric array: {err}"
                    raise MitPushError(msg) from err
    except OSError as err:
        msg = f"{p}: cannot read HDF5 file: {err}".splitlines()[0]
        raise MitPushError(msg) from err
    tip, obj, ft = (_clean_stream(p, k, streams[k]) for k in STREAMS)
    return RawPush(p, info, tip, obj, ft)


# ------------------------------------------------------------------------------- outlines
@dataclass(frozen=True)
class Outline:
    """Body-frame outline of a shape.

    vertices: strictly convex hull, counter-clockwise, about the centroid (m) - the
    scenario's ``vertices``. ordered: every vertex of the file, x-mirrored (file order:
    counter-clockwise for the dataset's clockwise files) and shifted by the same centroid -
    used for the side/position convention of the file names. centroid: centroid (m) of the
    x-mirrored file outline in its own frame.
    file_vertices: the outline as stored in the file (n, 2), m. mirrored: False when the body
    frame is the file's outline itself (not x-mirrored; ``ordered`` then in file order,
    clockwise or not as the file is, and ``centroid`` that of the file's outline).
    """

    shape: str
    vertices: FloatArray
    ordered: FloatArray
    centroid: tuple[float, float]
    file_vertices: FloatArray = field(default_factory=lambda: np.zeros((0, 2)))
    mirrored: bool = True


def find_shapes_dir(h5_path: str | Path) -> Path | None:
    """The dataset's ``shapes/`` directory: the nearest ``shapes`` in the file's ancestors."""
    for parent in Path(h5_path).resolve().parents:
        cand = parent / "shapes"
        if cand.is_dir():
            return cand
    return None


def load_outline(shape: str, shapes_dir: str | Path, mirrored: bool = True) -> Outline:
    """Load ``<shapes_dir>/<shape>_ext.npy`` and express it in the body frame.

    mirrored: body frame = the x-mirrored file outline (the convention the data selects for
    every shape of the dataset, see :mod:`dbcslam_ros.importers.mitpush_align`), else the file's.

    Raises:
        MitPushError: missing or malformed outline file.
    """
    path = Path(shapes_dir) / f"{shape}_ext.npy"
    if not path.is_file():
        known = ", ".join(shape_names(shapes_dir)) or "none"
        msg = f"unknown shape {shape!r}: no outline {path} (outlines in {shapes_dir}: {known})"
        raise MitPushError(msg)
    try:
        raw = np.load(path, allow_pickle=False)
    except (OSError, ValueError) as err:
        msg = f"{path}: cannot load the outline of shape {shape!r}: {err}".splitlines()[0]
        raise MitPushError(msg) from err
    if raw.ndim != 2 or raw.shape[1] != 2 or raw.shape[0] < 3 or not np.all(np.isfinite(raw)):
        msg = f"{path}: outline must be a finite (n >= 3, 2) array, got shape {raw.shape}"
        raise MitPushError(msg)
    try:
        return outline_from_vertices(shape, np.asarray(raw, dtype=np.float64), mirrored)
    except MitPushError as err:
        msg = f"{path}: {err}"
        raise MitPushError(msg) from err


def outline_from_vertices(shape: str, file_vertices: FloatArray, mirrored: bool) -> Outline:
    """Body-frame :class:`Outline` of an outline file's vertices (n, 2), m.

    Raises:
        MitPushError: degenerate outline (zero area, fewer than 3 hull vertices).
    """
    v = np.asarray(file_vertices, dtype=np.float64)
    body = v * np.array([-1.0, 1.0]) if mirrored else v.copy()
    area = polygon_area(body)
    if not abs(area) > 0.0:
        msg = f"outline of shape {shape!r} is degenerate (zero area)"
        raise MitPushError(msg)
    cx, cy = polygon_centroid(body)
    hull = convex_hull(body)
    if len(hull) < 3:
        msg = f"outline of shape {shape!r} is degenerate (fewer than 3 hull vertices)"
        raise MitPushError(msg)
    c = np.array([cx, cy])
    return Outline(shape, hull - c, body - c, (cx, cy), v.copy(), mirrored)


# ------------------------------------------------------------------------------- geometry
def signed_distance(vertices: FloatArray, points: npt.ArrayLike) -> FloatArray:
    """Signed distance (m, > 0 outside) of points (m, 2) to a convex CCW polygon (n, 2)."""
    pts = np.atleast_2d(np.asarray(points, dtype=np.float64))
    a = vertices
    e = np.roll(vertices, -1, axis=0) - a
    ap = pts[:, None, :] - a[None]
    u = np.clip(np.einsum("mnk,nk->mn", ap, e) / np.einsum("nk,nk->n", e, e), 0.0, 1.0)
    d = np.linalg.norm(ap - u[..., None] * e[None], axis=-1).min(axis=1)
    outside = np.any(e[None, :, 0] * ap[..., 1] - e[None, :, 1] * ap[..., 0] < 0.0, axis=1)
    out: FloatArray = np.where(outside, d, -d)
    return out


def to_body(pose: npt.ArrayLike, points: npt.ArrayLike) -> FloatArray:
    """World points (T, 2) in the body frames of poses (T, 3) [x, y, yaw] -> (T, 2)."""
    q = np.atleast_2d(np.asarray(pose, dtype=np.float64))
    p = np.atleast_2d(np.asarray(points, dtype=np.float64)) - q[:, :2]
    c, s = np.cos(q[:, 2]), np.sin(q[:, 2])
    return np.stack([c * p[:, 0] + s * p[:, 1], -s * p[:, 0] + c * p[:, 1]], axis=-1)


def expected_contact(
    outline: Outline, side: int, position: float, radius: float = PUSHER_RADIUS
) -> tuple[FloatArray, FloatArray]:
    """Pusher centre at first contact named by the file (side i, position s), body frame.

    Polygons (<= 8 vertices): the point at fraction s from body vertex i to vertex i + 1 of the
    file's order (x-mirrored unless ``outline.mirrored`` is False); smooth outlines: the point
    at fraction s of the perimeter from vertex 0. Returns (pusher centre = point + radius *
    outward normal, normal).

    Raises:
        MitPushError: side index out of range or position outside [0, 1].
    """
    if not 0.0 <= position <= 1.0:
        msg = f"contact position s={position} of shape {outline.shape} is outside [0, 1]"
        raise MitPushError(msg)
    from dbcslam_ros.importers.mitpush_align import named_contact

    try:
        bare = named_contact(outline.ordered, side, position, 0.0)
        normal = named_contact(outline.ordered, side, position, 1.0) - bare
    except MitPushError as err:
        msg = f"shape {outline.shape}: {err}"
        raise MitPushError(msg) from err
    return bare + radius * normal, normal


# ------------------------------------------------------------------------------- resampling
@dataclass(frozen=True)
class ImportConfig:
    """Importer settings.

    dt: model step and resampling period, s. noise_position / noise_yaw: std of the Gaussian
    noise added to the observed pose (m, rad); seed: base seed of that noise (combined with
    the file name, so each file gets its own reproducible stream). contact_threshold: N.
    pusher_candidates / surface_candidates: friction candidates (uniform prior).
    joint_noise: std (m) of the pusher tip readings declared in the scenario (``noise.joint``).
    position_floor / yaw_floor: observation noise std written to the scenario when no noise
    is added, m / rad: the alignment error (median 0.3-0.8 mm) dominates the Vicon noise; with
    1 mm / 0.01 rad ``dbcslam replay`` (100 particles) on the hex t=0.349 push rejects no
    pose, with 0.5 mm / 0.005 rad it rejects 17 of 105 as outliers (ESS 1.5).
    density (kg/m^3) and thickness (m): the plate the mass and inertia are computed from
    (:func:`mass_properties`). mass (kg) / inertia (kg m^2): given values instead (None:
    computed; a mass alone scales the computed inertia with it). push_model: the scenario's
    ``surface.model`` (``dynamic`` or ``quasi_static``, `dbcslam_core.scenario.PUSH_MODELS`).
    """

    dt: float = 0.01
    noise_position: float = 0.0
    noise_yaw: float = 0.0
    seed: int = 0
    contact_threshold: float = CONTACT_THRESHOLD
    pusher_candidates: tuple[float, ...] = (0.1, 0.2, 0.3)
    surface_candidates: tuple[float, ...] = (0.1, 0.2, 0.3)
    position_floor: float = 0.001
    yaw_floor: float = 0.01
    joint_noise: float = JOINT_NOISE
    density: float = STAINLESS_STEEL_DENSITY
    thickness: float = MIT_PUSH_THICKNESS
    mass: float | None = None
    inertia: float | None = None
    push_model: str = DEFAULT_PUSH_MODEL

    def __post_init__(self) -> None:
        if self.push_model not in PUSH_MODELS:
            msg = f"push_model must be one of {list(PUSH_MODELS)}, got {self.push_model!r}"
            raise MitPushError(msg)
        for name in ("density", "thickness", "mass", "inertia"):
            v = getattr(self, name)
            if v is not None and not (math.isfinite(v) and v > 0.0):
                unit = {"density": "kg/m^3", "thickness": "m", "mass": "kg"}.get(name, "kg m^2")
                msg = f"{name} must be a finite value > 0 ({unit}), got {v}"
                raise MitPushError(msg)
        if not (math.isfinite(self.dt) and 0.0 < self.dt <= 0.1):
            msg = f"dt must be in (0, 0.1] s, got {self.dt}"
            raise MitPushError(msg)
        for name in ("noise_position", "noise_yaw", "contact_threshold", "joint_noise"):
            v = getattr(self, name)
            if not (math.isfinite(v) and v >= 0.0):
                msg = f"{name} must be a finite value >= 0, got {v}"
                raise MitPushError(msg)
        for name in ("pusher_candidates", "surface_candidates"):
            cands = getattr(self, name)
            if not cands or any(not (math.isfinite(c) and c >= 0.0) for c in cands):
                msg = f"{name} must be a non-empty list of coefficients >= 0, got {list(cands)}"
                raise MitPushError(msg)

    @property
    def position_std(self) -> float:
        """Observation noise std of the position written to the scenario, m."""
        return self.noise_position if self.noise_position > 0.0 else self.position_floor

    @property
    def yaw_std(self) -> float:
        """Observation noise std of the yaw written to the scenario, rad."""
        return self.noise_yaw if self.noise_yaw > 0.0 else self.yaw_floor


def mass_properties(outline: Outline, config: ImportConfig) -> tuple[float, float, str]:
    """(mass kg, inertia about the centroid kg m^2, source) of a shape for the scenario.

    Computed from the outline file as a uniform plate of ``config.density`` and
    ``config.thickness`` (:func:`dbcslam_core.mass_properties.plate_properties`; the full
    outline, not its convex hull), unless ``config.mass`` / ``config.inertia`` give them.
    source: ``outline``, ``given`` or ``given mass, outline inertia``.

    Raises:
        MitPushError: the outline is degenerate.
    """
    try:
        plate: PlateProperties = plate_properties(
            outline.file_vertices if len(outline.file_vertices) else outline.vertices,
            density=config.density,
            thickness=config.thickness,
        )
    except ModelError as err:
        msg = f"shape {outline.shape!r}: {err}"
        raise MitPushError(msg) from err
    mass, inertia = plate.mass, plate.inertia
    if config.mass is not None:
        inertia *= config.mass / mass
        mass = config.mass
    if config.inertia is not None:
        inertia = config.inertia
    if config.mass is None and config.inertia is None:
        source = "outline"
    elif config.mass is not None and config.inertia is not None:
        source = "given"
    elif config.mass is not None:
        source = "given mass, outline inertia (scaled)"
    else:
        source = "outline mass, given inertia"
    return mass, inertia, source


@dataclass(frozen=True)
class PushSeries:
    """A push on one clock.

    stamps_ns: (T,) Unix time, ns. tip: (T, 2) pusher centre, world, m. pose: (T, 3) clean
    body pose (aligned Vicon) [x, y, yaw], yaw continuous (unwrapped). observed: (T, 3) pose
    with the added noise. force: (T, 3) F/T [fx, fy, tau_z] (force on the pusher, world axes,
    N, N m; mean over each step), or None when the stream is stale. contact: (T,) bool.
    contact_source: ``ft`` or ``geometry``. start_offsets: first stamp of each stream minus
    the earliest one, s.
    """

    raw: RawPush
    outline: Outline
    alignment: ShapeAlignment
    dt: float
    stamps_ns: npt.NDArray[np.int64]
    tip: FloatArray
    pose: FloatArray
    observed: FloatArray
    force: FloatArray | None
    contact: npt.NDArray[np.bool_]
    contact_source: str
    start_offsets: dict[str, float] = field(default_factory=dict)

    @property
    def t(self) -> FloatArray:
        """Seconds since the first step."""
        out: FloatArray = (self.stamps_ns - self.stamps_ns[0]).astype(np.float64) * 1e-9
        return out

    def __len__(self) -> int:
        return int(self.stamps_ns.size)


def ft_is_stale(ft: FloatArray) -> bool:
    """True when the F/T stream holds fewer distinct readings than half its samples."""
    distinct = int(np.unique(ft[:, 1:], axis=0).shape[0])
    return bool(distinct < STALE_FT_FRACTION * ft.shape[0])


def geometric_contact(
    pose: FloatArray, tip: FloatArray, outline: Outline, dt: float
) -> npt.NDArray[np.bool_]:
    """Contact flag from geometry: tip-outline gap within GEOMETRIC_CONTACT_TOL of its bias.

    The gap (distance - radius) while the object moves is in contact by definition; its
    median (clipped to +-2 mm) is the push's calibration bias (0.0-1.8 mm in the data: the
    alignment differs slightly between recording sessions). Without motion the bias is 0.
    """
    gap = signed_distance(outline.vertices, to_body(pose, tip)) - PUSHER_RADIUS
    speed = np.linalg.norm(np.gradient(pose[:, :2], dt, axis=0), axis=1)
    moving = speed > MOVING_SPEED
    bias = float(np.clip(np.median(gap[moving]), -0.002, 0.002)) if moving.any() else 0.0
    out: npt.NDArray[np.bool_] = gap - bias < GEOMETRIC_CONTACT_TOL
    return out


def _window_mean(t: FloatArray, values: FloatArray, grid: FloatArray, dt: float) -> FloatArray:
    """Mean of the samples in [g - dt/2, g + dt/2) per grid time; interpolated where empty."""
    csum = np.vstack([np.zeros((1, values.shape[1])), np.cumsum(values, axis=0)])
    lo = np.searchsorted(t, grid - 0.5 * dt, side="left")
    hi = np.searchsorted(t, grid + 0.5 * dt, side="left")
    count = (hi - lo)[:, None]
    interp = np.stack([np.interp(grid, t, values[:, j]) for j in range(values.shape[1])], -1)
    with np.errstate(invalid="ignore", divide="ignore"):
        mean = (csum[hi] - csum[lo]) / count
    return np.where(count > 0, mean, interp)


@dataclass(frozen=True)
class Clock:
    """The streams of a push on one clock (the interval where all three have data).

    grid: (T,) seconds since the earliest stream's first stamp. stamps_ns: (T,) Unix time,
    ns. tip: (T, 2) tip centre, world, m. vicon: (T, 3) tracked frame [x, y, yaw], yaw
    unwrapped. t_ft: F/T stamps on the same time axis as grid, s. offsets: first stamp of
    each stream minus the earliest one, s. dt: step, s.
    """

    grid: FloatArray
    stamps_ns: npt.NDArray[np.int64]
    tip: FloatArray
    vicon: FloatArray
    t_ft: FloatArray
    offsets: dict[str, float]
    dt: float

    def force_mean(self, raw: RawPush) -> FloatArray:
        """(T, 3) F/T reading [fx, fy, tau_z] averaged over each step (N, N m)."""
        return _window_mean(self.t_ft, raw.ft[:, 1:], self.grid, self.dt)


def common_clock(raw: RawPush, dt: float) -> Clock:
    """Resample the tip and Vicon streams of a push onto one clock of step ``dt`` (s).

    Positions are interpolated linearly, yaw after unwrapping.

    Raises:
        MitPushError: the streams do not overlap for at least two steps.
    """
    t_ref = min(raw.tip[0, 0], raw.obj[0, 0], raw.ft[0, 0])
    tt, to, tf = (a[:, 0] - t_ref for a in (raw.tip, raw.obj, raw.ft))
    start = max(tt[0], to[0], tf[0])
    end = min(tt[-1], to[-1], tf[-1])
    n_steps = math.floor((end - start) / dt + 1e-9) + 1
    if n_steps < 2:
        msg = (
            f"{raw.path}: the tip, object and F/T streams overlap for only "
            f"{max(end - start, 0.0):.4f} s (needs at least 2 steps of {dt} s)"
        )
        raise MitPushError(msg)
    grid = start + dt * np.arange(n_steps)
    t0_ns = round((t_ref + start) * 1e9)
    dt_ns = round(dt * 1e9)
    stamps = t0_ns + dt_ns * np.arange(n_steps, dtype=np.int64)
    tip = np.stack([np.interp(grid, tt, raw.tip[:, j]) for j in (1, 2)], axis=-1)
    vic = np.stack(
        [
            np.interp(grid, to, raw.obj[:, 1]),
            np.interp(grid, to, raw.obj[:, 2]),
            np.interp(grid, to, np.unwrap(raw.obj[:, 3])),
        ],
        axis=-1,
    )
    offsets = {"tip_pose": float(tt[0]), "object_pose": float(to[0]), "ft_wrench": float(tf[0])}
    return Clock(grid, stamps, tip, vic, tf, offsets, dt)


def body_pose(vicon: FloatArray, alignment: ShapeAlignment, outline: Outline) -> FloatArray:
    """Body pose (T, 3) [x, y, yaw] of the outline's centroid frame from the tracked frame."""
    c, s = np.cos(vicon[:, 2]), np.sin(vicon[:, 2])
    ox, oy = alignment.offset
    yaw = vicon[:, 2] + alignment.yaw_offset
    cx, cy = outline.centroid
    cb, sb = np.cos(yaw), np.sin(yaw)
    return np.stack(
        [
            vicon[:, 0] + c * ox - s * oy + cb * cx - sb * cy,
            vicon[:, 1] + s * ox + c * oy + sb * cx + cb * cy,
            yaw,
        ],
        axis=-1,
    )


def resample_push(
    raw: RawPush,
    outline: Outline,
    config: ImportConfig,
    alignment: ShapeAlignment | None = None,
) -> PushSeries:
    """Resample a push onto one clock of step ``config.dt``, align it and add noise.

    Positions are interpolated linearly, yaw after unwrapping; the F/T force is averaged over
    each step. The clock covers the interval where all three streams have data. alignment:
    the outline's place in the tracked frame; None fits it over the push files of the same
    shape in the file's directory
    (:func:`dbcslam_ros.importers.mitpush_align.shape_alignment`). When the alignment's
    convention (mirrored or not) differs from the outline's, the outline is rebuilt from its
    file vertices.

    Raises:
        MitPushError: the streams do not overlap for at least two steps.
    """
    clock = common_clock(raw, config.dt)
    if alignment is None:
        from dbcslam_ros.importers.mitpush_align import shape_alignment

        fit = shape_alignment(raw, outline.file_vertices, config.dt, config.contact_threshold)
        alignment = fit.alignment
    if alignment.mirrored != outline.mirrored:
        outline = outline_from_vertices(outline.shape, outline.file_vertices, alignment.mirrored)
    n_steps = len(clock.grid)
    pose = body_pose(clock.vicon, alignment, outline)
    tip = clock.tip

    rng = np.random.default_rng([config.seed, zlib.crc32(raw.path.name.encode("utf-8"))])
    noise = np.column_stack(
        [
            rng.normal(0.0, 1.0, (n_steps, 2)) * config.noise_position,
            rng.normal(0.0, 1.0, n_steps) * config.noise_yaw,
        ]
    )
    observed = pose + noise

    stale = ft_is_stale(raw.ft)
    force: FloatArray | None = None
    if stale:
        contact = geometric_contact(pose, tip, outline, config.dt)
        source = "geometry"
    else:
        force = clock.force_mean(raw)
        contact = np.hypot(force[:, 0], force[:, 1]) > config.contact_threshold
        source = "ft"
    return PushSeries(
        raw=raw,
        outline=outline,
        alignment=alignment,
        dt=config.dt,
        stamps_ns=clock.stamps_ns,
        tip=tip,
        pose=pose,
        observed=observed,
        force=force,
        contact=np.asarray(contact, dtype=np.bool_),
        contact_source=source,
        start_offsets=dict(clock.offsets),
    )


# ------------------------------------------------------------------------------- checks
@dataclass(frozen=True)
class AlignmentCheck:
    """How well the aligned outline explains the pusher tip (m).

    onset_index: step where the object has moved ONSET_DISPLACEMENT (None: it never moves).
    onset_error: distance of the tip at onset from the contact point the file name gives.
    onset_gap: tip-to-outline distance minus radius at onset. moving_gap: median
    |distance - radius| over the steps where the object moves (> 3 mm/s).
    """

    onset_index: int | None
    onset_error: float
    onset_gap: float
    moving_gap: float


def alignment_check(series: PushSeries, radius: float = PUSHER_RADIUS) -> AlignmentCheck:
    """Compare the aligned outline with the tip trajectory (first contact and while pushing)."""
    pose, tip = series.pose, series.tip
    body_tip = to_body(pose, tip)
    gap = signed_distance(series.outline.vertices, body_tip) - radius
    disp = np.linalg.norm(pose[:, :2] - pose[0, :2], axis=1)
    moved = disp > ONSET_DISPLACEMENT
    onset = int(np.argmax(moved)) if bool(np.any(moved)) else None
    info = series.raw.info
    expected, _ = expected_contact(series.outline, info.side, info.position, radius)
    if onset is None:
        err = float("nan")
        onset_gap = float("nan")
    else:
        err = float(np.linalg.norm(body_tip[onset] - expected))
        onset_gap = float(gap[onset])
    speed = np.linalg.norm(np.gradient(pose[:, :2], series.dt, axis=0), axis=1)
    moving = speed > MOVING_SPEED
    moving_gap = float(np.median(np.abs(gap[moving]))) if bool(np.any(moving)) else float("nan")
    return AlignmentCheck(onset, err, onset_gap, moving_gap)


def push_files(paths: Sequence[str | Path]) -> list[Path]:
    """The ``.h5`` files named by arguments (files, or directories searched recursively).

    Raises:
        MitPushError: a path does not exist or a directory holds no ``.h5`` file.
    """
    out: list[Path] = []
    for arg in paths:
        p = Path(arg)
        if p.is_dir():
            found = sorted(p.rglob("*.h5"))
            if not found:
                msg = f"{p}: directory holds no .h5 push file"
                raise MitPushError(msg)
            out.extend(found)
        elif p.is_file():
            out.append(p)
        else:
            msg = f"{p}: no such file or directory"
            raise MitPushError(msg)
    return out
