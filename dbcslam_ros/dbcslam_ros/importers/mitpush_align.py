"""Frame alignment of an MIT push file, estimated from the data (one procedure for every shape).

The Vicon system tracks a frame attached to the object; the outline file
``shapes/<shape>_ext.npy`` gives the object in its own frame. Where the outline lies in the
tracked frame is not written anywhere, so it is fitted: a planar rigid map, optionally
mirrored, from the outline file's frame to the tracked frame,

    q_tracked = R(yaw) S q_file + offset,   S = diag(-1, 1) (mirrored) or I,

with three continuous unknowns (yaw rad, offset x, y m) and one discrete one (mirrored). The
evidence, per push file (:func:`push_evidence`), on the importer's clock:

1. **Tip touching the outline.** On the in-contact steps (F/T force magnitude above the
   contact threshold; with a stale F/T stream, the steps where the object moves faster than
   3 mm/s, which only a touching pusher can cause) the pusher tip centre, expressed in the
   tracked frame, lies one tip radius (4.75 mm) outside the outline: residual = signed
   distance to the outline's convex hull - radius. At most :data:`MAX_POINTS` steps per file,
   evenly spaced, so that slow pushes do not outweigh fast ones.
2. **First contact where the file name says.** At the first step where the object has moved
   0.2 mm the tip centre should be at the point the name encodes (side ``i`` from file vertex
   ``i`` to ``i + 1`` at fraction ``s``, or fraction ``s`` of the perimeter from vertex 0 for
   smooth outlines of more than 8 vertices), plus one radius along the outward normal:
   a 2-D residual with the weight of :data:`ONSET_WEIGHT` contact steps. Only pushes with
   |t| < 1.2 rad: a steeper push grazes the outline before it moves it (first-contact errors
   of 6-30 mm there). This term alone tells apart the orientations of a symmetric outline
   (square, hexagon, circle) that the distances cannot.

Estimate (:func:`fit_alignment`): Huber loss (scale :data:`HUBER_SCALE` = 1 mm) over every
residual of the files given (one file, or all files of a shape pooled). Both conventions
(mirrored or not) are searched globally: 72 start yaws (5 deg apart) each, the offset
started where the first contacts put it, the 3 best starts of each convention refined by
scipy's trust-region least squares. A weak prior keeps the outline file's origin near the
tracked frame's origin (std :data:`OFFSET_PRIOR_STD` = 5 mm per axis; the pooled fits of the
four training shapes put it within 1.5 mm): it only matters where the data leave the offset
free. The convention with the smaller robust cost wins (the stored one must be
:data:`MIRROR_MARGIN` = 5 % better, so that a symmetric outline seen by a single push keeps
the dataset's mirrored convention); both costs are reported. Deterministic (fixed grid, no
random starts).

**Pooled per shape and recording set.** One push constrains its alignment poorly (a push
that sticks to a flat side sees one point of the outline, a circle none of its yaw, a push at
|t| = 1.4 rad has no first-contact term): fitted alone, 30 of the 50 training pushes put the
outline more than 3 mm (Hausdorff distance) from where the pooled fit puts it, while their
own residuals are as small. So a push's alignment is fitted over every push file of its shape
in its directory (:func:`shape_alignment`; the dataset's ``abs/train`` holds 10-14 per
shape), the same whichever of them are imported and in which order. See
:mod:`dbcslam_ros.importers.mitpush` for the numbers on the dataset.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import numpy.typing as npt

from dbcslam_ros.importers import mitpush as mp

__all__ = [
    "HUBER_SCALE",
    "MAX_POINTS",
    "MIRROR_MARGIN",
    "OFFSET_PRIOR_STD",
    "ONSET_MAX_ANGLE",
    "ONSET_WEIGHT",
    "AlignmentFit",
    "PushEvidence",
    "fit_alignment",
    "named_contact",
    "push_evidence",
    "shape_alignment",
]

FloatArray = npt.NDArray[np.float64]

HUBER_SCALE: float = 0.001
"""m: residuals beyond this count linearly (Huber loss)."""
MAX_POINTS: int = 120
"""In-contact steps used per file at most (evenly spaced)."""
ONSET_WEIGHT: float = 40.0
"""Weight of the first-contact residual, in contact steps (a third of a file's MAX_POINTS)."""
ONSET_MAX_ANGLE: float = 1.2
"""rad: pushes steeper than this (|t|) get no first-contact term."""
MIRROR_MARGIN: float = 0.05
"""The stored (not mirrored) convention must beat the mirrored one by this fraction of its
cost: on a near tie (a symmetric outline seen by one push) the dataset's convention stays."""
OFFSET_PRIOR_STD: float = 0.005
"""m: prior std of the outline file's origin in the tracked frame (per axis, about 0)."""
_N_YAW = 72
_N_REFINE = 3
_MIRROR = np.array([-1.0, 1.0])


@dataclass(frozen=True)
class PushEvidence:
    """What one push file says about its alignment.

    name: file name. points: (K, 2) pusher tip centre in the tracked frame on in-contact
    steps, m. onset: (2,) tip centre in the tracked frame when the object starts to move,
    or None (it never moves, or |t| >= ONSET_MAX_ANGLE). expected: (2,) tip centre at first
    contact named by the file, in the outline file's frame, m (None with onset None).
    """

    name: str
    points: FloatArray
    onset: FloatArray | None
    expected: FloatArray | None


@dataclass(frozen=True)
class AlignmentFit:
    """Result of :func:`fit_alignment`.

    alignment: the estimate (yaw_offset = yaw of the map, offset, mirrored). cost: robust
    cost (Huber, m^2) of the winner; other_cost: the best cost of the other convention.
    gaps: per file, median |tip-to-outline distance - radius| over its in-contact steps, m.
    onset_errors: per file, distance of the tip at first motion from the named contact
    point, m (NaN without a first-contact term). names: the files, in order.
    """

    alignment: mp.ShapeAlignment
    cost: float
    other_cost: float
    gaps: tuple[float, ...]
    onset_errors: tuple[float, ...]
    names: tuple[str, ...]

    @property
    def median_gap(self) -> float:
        """Median over the files of their median |gap|, m."""
        return float(np.median(self.gaps)) if self.gaps else float("nan")


def named_contact(
    vertices: FloatArray, side: int, position: float, radius: float = mp.PUSHER_RADIUS
) -> FloatArray:
    """Pusher centre at the first contact a file name encodes, in the vertices' frame (m).

    Polygons (<= 8 vertices): fraction ``position`` from vertex ``side`` to ``side + 1``;
    smooth outlines: fraction ``position`` of the perimeter from vertex 0; then ``radius``
    along the outward normal of that edge (either winding).

    Raises:
        MitPushError: side index out of range or position outside [0, 1].
    """
    w = np.asarray(vertices, dtype=np.float64)
    n = len(w)
    if not 0.0 <= position <= 1.0:
        msg = f"contact position s={position} is outside [0, 1]"
        raise mp.MitPushError(msg)
    if n > 8:
        seg = np.linalg.norm(np.roll(w, -1, axis=0) - w, axis=1)
        cum = np.concatenate([[0.0], np.cumsum(seg)])
        target = position * cum[-1]
        k = min(int(np.searchsorted(cum, target, side="right")) - 1, n - 1)
        u = (target - cum[k]) / seg[k]
    else:
        if side >= n:
            msg = f"side index i={side} out of range for an outline of {n} sides"
            raise mp.MitPushError(msg)
        k, u = side, position
    a, b = w[k], w[(k + 1) % n]
    e = b - a
    ccw = float(np.sum(w[:, 0] * np.roll(w[:, 1], -1) - np.roll(w[:, 0], -1) * w[:, 1])) > 0.0
    normal = np.array([e[1], -e[0]]) if ccw else np.array([-e[1], e[0]])
    out: FloatArray = a + u * e + radius * normal / float(np.linalg.norm(e))
    return out


def push_evidence(
    raw: mp.RawPush,
    file_vertices: FloatArray,
    dt: float = 0.01,
    contact_threshold: float = mp.CONTACT_THRESHOLD,
) -> PushEvidence:
    """In-contact tip positions and first contact of one push (see the module docstring)."""
    clock = mp.common_clock(raw, dt)
    tip, vic = clock.tip, clock.vicon
    body_tip = mp.to_body(vic, tip)
    speed = np.linalg.norm(np.gradient(vic[:, :2], dt, axis=0), axis=1)
    moving = speed > mp.MOVING_SPEED
    if mp.ft_is_stale(raw.ft):
        contact = moving
    else:
        force = clock.force_mean(raw)
        contact = np.hypot(force[:, 0], force[:, 1]) > contact_threshold
    idx = np.flatnonzero(contact)
    if idx.size > MAX_POINTS:
        idx = idx[np.round(np.linspace(0, idx.size - 1, MAX_POINTS)).astype(np.int64)]
    disp = np.linalg.norm(vic[:, :2] - vic[0, :2], axis=1)
    moved = disp > mp.ONSET_DISPLACEMENT
    onset: FloatArray | None = None
    expected: FloatArray | None = None
    info = raw.info
    if bool(np.any(moved)) and abs(info.angle) < ONSET_MAX_ANGLE:
        onset = body_tip[int(np.argmax(moved))].copy()
        expected = named_contact(file_vertices, info.side, info.position)
    return PushEvidence(raw.path.name, body_tip[idx], onset, expected)


def _to_file(points: FloatArray, x: FloatArray, mirrored: bool) -> FloatArray:
    """Tracked-frame points -> outline-file frame under the map x = (yaw, ox, oy)."""
    c, s = math.cos(float(x[0])), math.sin(float(x[0]))
    p = points - x[1:3]
    q = np.column_stack([c * p[:, 0] + s * p[:, 1], -s * p[:, 0] + c * p[:, 1]])
    return q * _MIRROR if mirrored else q


def _to_tracked(points: FloatArray, x: FloatArray, mirrored: bool) -> FloatArray:
    q = points * _MIRROR if mirrored else points
    c, s = math.cos(float(x[0])), math.sin(float(x[0]))
    out: FloatArray = np.column_stack(
        [c * q[:, 0] - s * q[:, 1] + x[1], s * q[:, 0] + c * q[:, 1] + x[2]]
    )
    return out


class _Problem:
    """Residuals of one alignment fit (pooled over files)."""

    def __init__(self, evidence: Sequence[PushEvidence], hull: FloatArray, radius: float):
        self.hull = hull
        self.radius = radius
        self.points = np.vstack([e.points for e in evidence] or [np.zeros((0, 2))])
        with_onset = [e for e in evidence if e.onset is not None and e.expected is not None]
        self.onsets = np.array([e.onset for e in with_onset]).reshape(-1, 2)
        self.expected = np.array([e.expected for e in with_onset]).reshape(-1, 2)
        self.onset_scale = math.sqrt(ONSET_WEIGHT)

    def residuals(self, x: FloatArray, mirrored: bool) -> FloatArray:
        gap = mp.signed_distance(self.hull, _to_file(self.points, x, mirrored)) - self.radius
        onset = (_to_tracked(self.expected, x, mirrored) - self.onsets) * self.onset_scale
        prior = x[1:3] * (HUBER_SCALE / OFFSET_PRIOR_STD)
        return np.concatenate([gap, onset.ravel(), prior])

    def start_offset(self, yaw: float, mirrored: bool) -> FloatArray:
        """Offset putting the named first contacts on the measured ones (median), m."""
        if len(self.onsets) == 0:
            return np.zeros(2)
        moved = _to_tracked(self.expected, np.array([yaw, 0.0, 0.0]), mirrored)
        out: FloatArray = np.median(self.onsets - moved, axis=0)
        return out


def _huber_cost(r: FloatArray) -> float:
    a = np.abs(r)
    d = HUBER_SCALE
    return float(np.sum(np.where(a <= d, 0.5 * a * a, d * (a - 0.5 * d))))


def _best(problem: _Problem, mirrored: bool) -> tuple[float, FloatArray]:
    """Global search over the yaw of one convention: (robust cost, x)."""
    from scipy.optimize import least_squares

    starts = []
    for yaw in 2.0 * math.pi * np.arange(_N_YAW) / _N_YAW:
        x0 = np.concatenate([[yaw], problem.start_offset(float(yaw), mirrored)])
        starts.append((_huber_cost(problem.residuals(x0, mirrored)), x0))
    starts.sort(key=lambda item: item[0])
    best_cost, best_x = math.inf, starts[0][1]
    for _, x0 in starts[:_N_REFINE]:
        sol = least_squares(
            problem.residuals,
            x0,
            args=(mirrored,),
            loss="huber",
            f_scale=HUBER_SCALE,
            x_scale=np.array([0.01, 0.001, 0.001]),
            method="trf",
        )
        cost = _huber_cost(problem.residuals(sol.x, mirrored))
        if cost < best_cost:
            best_cost, best_x = cost, np.asarray(sol.x, dtype=np.float64)
    return best_cost, best_x


def fit_alignment(
    evidence: Sequence[PushEvidence],
    file_vertices: FloatArray,
    radius: float = mp.PUSHER_RADIUS,
) -> AlignmentFit:
    """Fit the map outline file -> tracked frame to the evidence of one or more pushes.

    file_vertices: the outline as stored in the file (n, 2), m. See the module docstring.

    Raises:
        MitPushError: no in-contact step and no first contact in any file.
    """
    if not evidence or (
        sum(len(e.points) for e in evidence) == 0 and all(e.onset is None for e in evidence)
    ):
        names = ", ".join(e.name for e in evidence) or "no file"
        msg = (
            f"{names}: no in-contact step and no first contact to align the outline with "
            "(the pusher never touches the object?)"
        )
        raise mp.MitPushError(msg)
    hull = mp.convex_hull(np.asarray(file_vertices, dtype=np.float64))
    problem = _Problem(evidence, hull, radius)
    results = {m: _best(problem, m) for m in (True, False)}
    mirrored = results[True][0] <= (1.0 + MIRROR_MARGIN) * results[False][0]
    cost, x = results[mirrored]
    yaw = math.remainder(float(x[0]), 2.0 * math.pi)
    alignment = mp.ShapeAlignment(yaw, (float(x[1]), float(x[2])), mirrored)
    gaps, errors = [], []
    for e in evidence:
        if len(e.points):
            g = mp.signed_distance(hull, _to_file(e.points, x, mirrored)) - radius
            gaps.append(float(np.median(np.abs(g))))
        else:
            gaps.append(float("nan"))
        if e.onset is not None and e.expected is not None:
            moved = _to_tracked(e.expected[None, :], x, mirrored)[0]
            errors.append(float(np.linalg.norm(moved - e.onset)))
        else:
            errors.append(float("nan"))
    return AlignmentFit(
        alignment=alignment,
        cost=cost,
        other_cost=results[not mirrored][0],
        gaps=tuple(gaps),
        onset_errors=tuple(errors),
        names=tuple(e.name for e in evidence),
    )


_CACHE: dict[tuple[object, ...], AlignmentFit] = {}


def shape_alignment(
    raw: mp.RawPush,
    file_vertices: FloatArray,
    dt: float = 0.01,
    contact_threshold: float = mp.CONTACT_THRESHOLD,
) -> AlignmentFit:
    """Pooled fit over the push files of ``raw``'s shape in ``raw``'s directory (cached).

    Files of the directory that cannot be read or do not follow the dataset's naming are
    skipped (the push itself always takes part).
    """
    info = raw.info
    siblings = sorted(raw.path.parent.glob(f"motion_surface=*_shape={info.shape}_*.h5"))
    names = tuple(p.name for p in siblings)
    if raw.path.name not in names:
        names = tuple(sorted((*names, raw.path.name)))
    key = (
        str(raw.path.parent.resolve()),
        info.shape,
        names,
        np.asarray(file_vertices, dtype=np.float64).tobytes(),
        dt,
        contact_threshold,
    )
    cached = _CACHE.get(key)
    if cached is not None:
        return cached
    evidence = []
    for name in names:
        path = raw.path.parent / name
        if path.name == raw.path.name:
            evidence.append(push_evidence(raw, file_vertices, dt, contact_threshold))
            continue
        else:
            try:
                other = mp.load_push(path)
            except mp.MitPushError:
                continue
        if other.info.shape != info.shape:
            continue
        try:
            evidence.append(push_evidence(other, file_vertices, dt, contact_threshold))
        except mp.MitPushError:
            continue
    fit = fit_alignment(evidence, file_vertices)
    _CACHE[key] = fit
    return fit


def _reference_stats(
    evidence: Sequence[PushEvidence], hull: FloatArray, ref: mp.ShapeAlignment
) -> tuple[float, float, float]:
    """(robust cost, median over files of median |gap| m, median first-contact error m) of
    a given alignment on the evidence."""
    x = np.array([ref.yaw_offset, *ref.offset])
    problem = _Problem(evidence, hull, mp.PUSHER_RADIUS)
    cost = _huber_cost(problem.residuals(x, ref.mirrored))
    gaps = [
        float(
            np.median(
                np.abs(
                    mp.signed_distance(hull, _to_file(e.points, x, ref.mirrored))
                    - mp.PUSHER_RADIUS
                )
            )
        )
        for e in evidence
        if len(e.points)
    ]
    errs = [
        float(np.linalg.norm(_to_tracked(e.expected[None], x, ref.mirrored)[0] - e.onset))
        for e in evidence
        if e.onset is not None and e.expected is not None
    ]
    return cost, float(np.median(gaps)), float(np.median(errs)) if errs else float("nan")


def main(argv: Sequence[str] | None = None) -> int:
    """Print the pooled alignment of every shape of a dataset and how well it is determined.

    ``python -m dbcslam_ros.importers.mitpush_align [DATA_DIR]`` (default ../shared/data/mit-push):
    per shape the fit, both conventions' costs, residuals, the first importer's constants
    (:data:`dbcslam_ros.importers.mitpush.ALIGNMENTS`) on the same evidence, a jackknife standard
    error over the files, and how many single-file fits land elsewhere.
    """
    import sys
    import time

    args = list(sys.argv[1:] if argv is None else argv)
    data = Path(args[0]) if args else Path("../shared/data/mit-push")
    files = mp.push_files([data / "abs" / "train"])
    groups: dict[str, list[PushEvidence]] = {}
    verts: dict[str, FloatArray] = {}
    for f in files:
        raw = mp.load_push(f)
        v = mp.load_outline(raw.info.shape, data / "shapes").file_vertices
        verts.setdefault(raw.info.shape, v)
        groups.setdefault(raw.info.shape, []).append(push_evidence(raw, v))
    print(f"{len(files)} pushes from {data}; units mm, mrad")
    for shape, ev in sorted(groups.items()):
        v, hull = verts[shape], mp.convex_hull(verts[shape])
        t0 = time.process_time()
        fit = fit_alignment(ev, v)
        cpu = time.process_time() - t0
        a = fit.alignment
        x = np.array([a.yaw_offset, *a.offset])
        jack = np.array(
            [
                [b.yaw_offset, *b.offset]
                for b in (
                    fit_alignment([*ev[:i], *ev[i + 1 :]], v).alignment for i in range(len(ev))
                )
            ]
        )
        n = len(ev)
        se = np.sqrt((n - 1) / n * np.sum((jack - jack.mean(axis=0)) ** 2, axis=0))
        onset = [e for e in fit.onset_errors if math.isfinite(e)]
        print(
            f"{shape}: n={n} {'mirrored' if a.mirrored else 'as stored'} (cost {fit.cost:.3g}"
            f" vs {fit.other_cost:.3g} other convention) yaw {a.yaw_offset:+.4f} rad offset "
            f"({1e3 * a.offset[0]:+.2f}, {1e3 * a.offset[1]:+.2f}); jackknife se yaw "
            f"{1e3 * se[0]:.1f} offset ({1e3 * se[1]:.2f}, {1e3 * se[2]:.2f}); median |gap| "
            f"{1e3 * fit.median_gap:.2f}, first contact median {1e3 * np.median(onset):.2f} "
            f"max {1e3 * np.max(onset):.2f}; {cpu:.2f} s CPU"
        )
        ref = mp.ALIGNMENTS.get(shape)
        if ref is not None:
            rc, rg, ro = _reference_stats(ev, hull, ref)
            print(
                f"   constants: yaw {ref.yaw_offset:+.4f} offset ({1e3 * ref.offset[0]:+.2f}, "
                f"{1e3 * ref.offset[1]:+.2f}) -> fit - constants: yaw "
                f"{1e3 * (a.yaw_offset - ref.yaw_offset):+.1f}, offset "
                f"({1e3 * (a.offset[0] - ref.offset[0]):+.2f}, "
                f"{1e3 * (a.offset[1] - ref.offset[1]):+.2f}); constants' cost {rc:.3g}, "
                f"median |gap| {1e3 * rg:.2f}, first contact median {1e3 * ro:.2f}"
            )
        pts = _boundary_points(hull)
        placed = _to_tracked(pts, x, a.mirrored)
        away = 0
        for e in ev:
            b = fit_alignment([e], v).alignment
            other = _to_tracked(pts, np.array([b.yaw_offset, *b.offset]), b.mirrored)
            d = np.linalg.norm(placed[:, None] - other[None], axis=-1)
            if max(d.min(axis=0).max(), d.min(axis=1).max()) > 0.003:
                away += 1
        print(f"   single-file fits whose outline lies > 3 mm from the pooled one: {away}/{n}")
    return 0


def _boundary_points(hull: FloatArray, n: int = 120) -> FloatArray:
    e = np.roll(hull, -1, axis=0) - hull
    seg = np.linalg.norm(e, axis=1)
    cum = np.concatenate([[0.0], np.cumsum(seg)])
    pos = np.linspace(0.0, cum[-1], n, endpoint=False)
    j = np.clip(np.searchsorted(cum, pos, side="right") - 1, 0, len(hull) - 1)
    out: FloatArray = hull[j] + ((pos - cum[j]) / seg[j])[:, None] * e[j]
    return out


if __name__ == "__main__":
    raise SystemExit(main())
