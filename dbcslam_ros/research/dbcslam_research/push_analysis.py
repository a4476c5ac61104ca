"""How the MIT pushes really move: alignment fit, F/T findings, quasi-static prediction.

Run ``python -m dbcslam_research.push_analysis [DATA_DIR]`` (default: ../shared/data/mit-push,
relative to the working directory; reads ``abs/train/*.h5`` and ``shapes/``). It prints, per shape:

1. Alignment: the first-contact location error and tip-outline gap with the importer's
   constants (:data:`dbcslam_ros.importers.mitpush.ALIGNMENTS`), and an unconstrained least-squares
   fit of (yaw correction, tracked-frame offset) for comparison.
2. Clocks: stream start offsets; object-stop minus tip-stop time in near-sticking pushes.
   F/T: stale streams, noise floor at rest, the friction tilt of the force direction
   (force angle - push angle - pi + t; ~0 means the F/T axes are the world axes).
3. Motion vs a quasi-static pushing prediction: each push is replayed with the measured
   pusher trajectory through the classic quasi-static model (ellipsoidal limit surface of a
   uniform support pressure, c = mean |r| over the outline; motion cone of the pusher
   contact with pusher friction ``mu_p`` = 0.25; Lynch & Mason 1996), starting from the
   measured initial pose. Reported: object/pusher displacement ratio, rotation, slip of the
   contact point along the outline (measured and predicted), final pose error.

Pure numpy/scipy; no ROS. Numbers are for the issue "Measured data" (discrepancy of the
nominal push model on real data).
"""

from __future__ import annotations

import math
import sys
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from dbcslam_core.angles import wrap_angle
from dbcslam_ros.importers import mitpush as mp

__all__ = [
    "PushMotion",
    "analyse_motion",
    "fit_alignment",
    "friction_radius",
    "main",
    "quasi_static_replay",
    "stop_lags",
]

FloatArray = mp.FloatArray
DEFAULT_DATA = Path("../shared/data/mit-push")
PUSHER_MU = 0.25
C_SCALES = (1.0, 0.8, 0.7, 0.6, 0.5)


def _load(data_dir: Path, dt: float) -> list[mp.PushSeries]:
    files = mp.push_files([data_dir / "abs" / "train"])
    outlines: dict[str, mp.Outline] = {}
    out = []
    for f in files:
        raw = mp.load_push(f)
        if raw.info.shape not in outlines:
            outlines[raw.info.shape] = mp.load_outline(raw.info.shape, data_dir / "shapes")
        out.append(mp.resample_push(raw, outlines[raw.info.shape], mp.ImportConfig(dt=dt)))
    return out


# ---------------------------------------------------------------------------- alignment fit
def fit_alignment(series: Sequence[mp.PushSeries]) -> tuple[float, float, float]:
    """Least-squares (yaw correction rad, offset x, y m in the tracked frame) for one shape.

    Residuals: tip-outline distance - radius while the object moves (each file weighted
    equally) and the first-contact location error (files with |t| < 1.2 rad). Corrections
    are relative to the importer's constants.
    """
    from scipy.optimize import least_squares

    def residuals(x: FloatArray) -> FloatArray:
        eps, dx, dy = (float(v) for v in x)
        out = []
        for s in series:
            pose = s.pose.copy()
            yaw_v = pose[:, 2] - s.alignment.yaw_offset
            c, sn = np.cos(yaw_v), np.sin(yaw_v)
            pose[:, 0] += c * dx - sn * dy
            pose[:, 1] += sn * dx + c * dy
            pose[:, 2] += eps
            body_tip = mp.to_body(pose, s.tip)
            gap = mp.signed_distance(s.outline.vertices, body_tip) - mp.PUSHER_RADIUS
            speed = np.linalg.norm(np.gradient(s.pose[:, :2], s.dt, axis=0), axis=1)
            moving = speed > 0.003
            if moving.any():
                out.append(gap[moving] * 3.0 / math.sqrt(moving.sum()))
            check = mp.alignment_check(s)
            if check.onset_index is not None and abs(s.raw.info.angle) < 1.2:
                exp, _ = mp.expected_contact(s.outline, s.raw.info.side, s.raw.info.position)
                out.append(body_tip[check.onset_index] - exp)
        return np.concatenate(out)

    sol = least_squares(residuals, np.zeros(3), loss="soft_l1", f_scale=0.002)
    eps, dx, dy = (float(v) for v in sol.x)
    return eps, dx, dy


# ---------------------------------------------------------------------------- quasi-static
def friction_radius(vertices: FloatArray, n: int = 200) -> float:
    """c = m_max / f_max of a uniform pressure over the outline = mean |r| over the area, m."""
    lo, hi = vertices.min(axis=0), vertices.max(axis=0)
    gx, gy = np.meshgrid(np.linspace(lo[0], hi[0], n), np.linspace(lo[1], hi[1], n))
    pts = np.column_stack([gx.ravel(), gy.ravel()])
    inside = mp.signed_distance(vertices, pts) < 0.0
    return float(np.mean(np.linalg.norm(pts[inside], axis=1)))


def _closest_on_outline(v: FloatArray, p: FloatArray) -> tuple[FloatArray, FloatArray, float]:
    """Closest outline point to p, outward normal of its edge, arc-length coordinate (m)."""
    a = v
    e = np.roll(v, -1, axis=0) - a
    ap = p[None, :] - a
    u = np.clip(np.einsum("nk,nk->n", ap, e) / np.einsum("nk,nk->n", e, e), 0.0, 1.0)
    q = a + u[:, None] * e
    k = int(np.argmin(np.linalg.norm(q - p[None, :], axis=1)))
    seg = np.linalg.norm(e, axis=1)
    arc = float(np.sum(seg[:k]) + u[k] * seg[k])
    normal = np.array([e[k, 1], -e[k, 0]]) / seg[k]
    return q[k], normal, arc


def _twist(r: FloatArray, n: FloatArray, vp: FloatArray, c: float, mu: float) -> FloatArray:
    """Body twist*dt (dx, dy, dtheta) when the contact at r (outward normal n) is pushed by vp.

    Quasi-static, ellipsoidal limit surface twist ~ (fx, fy, m / c^2); stick inside the
    motion cone, else slide on its nearer edge with the pusher's normal velocity.
    """
    x, y = float(r[0]), float(r[1])
    c2 = c * c
    m_mat = np.array([[1.0 + y * y / c2, -x * y / c2], [-x * y / c2, 1.0 + x * x / c2]])
    inward = -n
    tangent = np.array([-n[1], n[0]])
    f = np.linalg.solve(m_mat, vp)  # sticking force (up to scale)
    fn, ft = float(f @ inward), float(f @ tangent)
    if fn <= 0.0:
        return np.zeros(3)
    if abs(ft) > mu * fn:
        f = inward + math.copysign(mu, ft) * tangent
        vc = m_mat @ f
        f = f * (float(vp @ inward) / float(vc @ inward))
    moment = x * f[1] - y * f[0]
    return np.array([f[0], f[1], moment / c2])


@dataclass(frozen=True)
class PushMotion:
    """One push, measured and predicted (m, rad).

    pusher: pusher path length while in contact; measured/predicted: object displacement and
    rotation over the push; slip: arc-length change of the contact point along the outline;
    final_error: predicted vs measured final position (m) and yaw (rad).
    """

    name: str
    shape: str
    angle: float
    pusher: float
    displacement: float
    rotation: float
    slip: float
    predicted_displacement: float
    predicted_rotation: float
    predicted_slip: float
    final_position_error: float
    final_yaw_error: float


def _arc_delta(a0: float, a1: float, perimeter: float) -> float:
    return (a1 - a0 + 0.5 * perimeter) % perimeter - 0.5 * perimeter


def quasi_static_replay(
    series: mp.PushSeries, c: float, mu: float = PUSHER_MU
) -> tuple[FloatArray, FloatArray]:
    """Replay the measured pusher path through the quasi-static model.

    Returns (predicted poses (T, 3), predicted contact arc coordinate (T,), NaN when apart).
    """
    v = series.outline.vertices
    r = mp.PUSHER_RADIUS
    q = series.pose[0].copy()
    poses = np.empty_like(series.pose)
    arcs = np.full(len(series), np.nan)
    poses[0] = q
    for k in range(len(series) - 1):
        cth, sth = math.cos(q[2]), math.sin(q[2])
        rot_t = np.array([[cth, sth], [-sth, cth]])
        tip_next = rot_t @ (series.tip[k + 1] - q[:2])
        d_b = rot_t @ (series.tip[k + 1] - series.tip[k])
        depth = r - float(mp.signed_distance(v, tip_next)[0])
        if depth > 0.0:
            point, normal, arc = _closest_on_outline(v, tip_next)
            arcs[k + 1] = arc
            push_in = float(d_b @ -normal)
            if push_in > 1e-12:
                vp = d_b * (depth / push_in)
                tw = _twist(point, normal, vp, c, mu)
                q[:2] += np.array([[cth, -sth], [sth, cth]]) @ tw[:2]
                q[2] += tw[2]
        poses[k + 1] = q
    return poses, arcs


def analyse_motion(series: mp.PushSeries, c: float, mu: float = PUSHER_MU) -> PushMotion:
    """Measured vs quasi-static motion of one push (see :class:`PushMotion`)."""
    v = series.outline.vertices
    perimeter = float(np.sum(np.linalg.norm(np.roll(v, -1, axis=0) - v, axis=1)))
    body_tip = mp.to_body(series.pose, series.tip)
    touching = np.flatnonzero(
        mp.geometric_contact(series.pose, series.tip, series.outline, series.dt)
    )
    steps = np.linalg.norm(np.diff(series.tip, axis=0), axis=1)
    pusher = float(np.sum(steps[touching[touching < len(steps)]])) if touching.size else 0.0
    disp = float(np.linalg.norm(series.pose[-1, :2] - series.pose[0, :2]))
    rot = float(series.pose[-1, 2] - series.pose[0, 2])
    slip = 0.0
    if touching.size >= 2:
        a0 = _closest_on_outline(v, body_tip[touching[0]])[2]
        a1 = _closest_on_outline(v, body_tip[touching[-1]])[2]
        slip = _arc_delta(a0, a1, perimeter)
    pred, arcs = quasi_static_replay(series, c, mu)
    valid = np.flatnonzero(np.isfinite(arcs))
    pslip = (
        _arc_delta(float(arcs[valid[0]]), float(arcs[valid[-1]]), perimeter)
        if valid.size >= 2
        else 0.0
    )
    return PushMotion(
        name=series.raw.path.name.removeprefix("motion_surface=abs_shape=").removesuffix(".h5"),
        shape=series.raw.info.shape,
        angle=series.raw.info.angle,
        pusher=pusher,
        displacement=disp,
        rotation=rot,
        slip=slip,
        predicted_displacement=float(np.linalg.norm(pred[-1, :2] - pred[0, :2])),
        predicted_rotation=float(pred[-1, 2] - pred[0, 2]),
        predicted_slip=pslip,
        final_position_error=float(np.linalg.norm(pred[-1, :2] - series.pose[-1, :2])),
        final_yaw_error=float(pred[-1, 2] - series.pose[-1, 2]),
    )


# ---------------------------------------------------------------------------- clocks
def _last_fast(stream: FloatArray) -> float:
    """Unix time (s) of the last sample faster than half the cruise speed of a pose stream."""
    t = stream[:, 0]
    v = np.linalg.norm(np.gradient(stream[:, 1:3], t, axis=0), axis=1)
    v = np.convolve(v, np.ones(5) / 5.0, mode="same")
    cruise = float(np.median(v[v > 0.5 * v.max()]))
    idx = np.flatnonzero(v > 0.5 * cruise)
    return float(t[idx[-1]]) if idx.size else float("nan")


def stop_lags(series: Sequence[mp.PushSeries], min_ratio: float = 0.85) -> FloatArray:
    """Object stop time - tip stop time (s) on the raw clocks, for near-sticking pushes.

    In a quasi-static push that sticks (object/pusher displacement > min_ratio) the object
    stops with the pusher, so this measures the offset between the tip and Vicon clocks.
    """
    out = []
    for s in series:
        tip, obj = s.raw.tip, s.raw.obj
        ratio = np.linalg.norm(obj[-1, 1:3] - obj[0, 1:3]) / np.linalg.norm(
            tip[-1, 1:3] - tip[0, 1:3]
        )
        if ratio > min_ratio:
            out.append(_last_fast(obj) - _last_fast(tip))
    return np.asarray(out, dtype=np.float64)


# ---------------------------------------------------------------------------- report
def _ft_report(series: Sequence[mp.PushSeries]) -> list[str]:
    lines = []
    tilts: list[float] = []
    floors: list[float] = []
    stale = [s.raw.path.name for s in series if s.force is None]
    for s in series:
        ft = s.raw.ft
        if s.force is None:
            continue
        rest = ft[:, 0] < ft[0, 0] + 0.15
        floors.append(float(np.median(np.std(ft[rest, 1:3], axis=0))))
        push = s.tip[-1] - s.tip[0]
        speed = np.linalg.norm(np.gradient(s.pose[:, :2], s.dt, axis=0), axis=1)
        moving = speed > 0.003
        if moving.any():
            f = s.force[moving, :2]
            tilt = np.arctan2(f[:, 1], f[:, 0]) - math.atan2(push[1], push[0]) - math.pi
            tilt = wrap_angle(tilt + s.raw.info.angle)
            tilts.append(float(np.median(tilt)))
    lines.append(f"F/T: stale streams in {len(stale)}/{len(series)} files")
    lines.append(
        f"F/T noise floor at rest (std per axis, median over files): median "
        f"{np.median(floors):.3f} N, max {np.max(floors):.3f} N"
    )
    lines.append(
        f"F/T force direction - (push + pi - t) while the object moves: median over files "
        f"{np.median(tilts):+.3f} rad, mean {np.mean(tilts):+.3f}, IQR "
        f"[{np.percentile(tilts, 25):+.3f}, {np.percentile(tilts, 75):+.3f}] rad"
    )
    return lines


def main(argv: Sequence[str] | None = None) -> int:
    """Print the analysis of the training pushes."""
    args = list(sys.argv[1:] if argv is None else argv)
    data = Path(args[0]) if args else DEFAULT_DATA
    series = _load(data, dt=0.004)
    groups = _by_shape(series)
    print(f"{len(series)} pushes from {data}")
    _print_section(
        "alignment (importer constants; fit = extra correction on top of them)",
        _alignment_report(groups),
    )
    _print_section("clocks", _clock_report(series))
    _print_section("F/T", _ft_report(series))
    motion_lines, motions = _motion_report(groups)
    _print_section(
        f"motion vs quasi-static prediction (mu_pusher={PUSHER_MU}, uniform pressure)",
        motion_lines,
    )
    _print_section(
        "friction radius c scaled (pressure concentrated toward the centre: scale < 1)",
        _friction_radius_report(groups),
    )
    print("\nper push: name | pusher mm | disp mm (pred) | rot rad (pred) | slip mm (pred)")
    for line in _per_push_report(motions):
        print(line)
    return 0


def _print_section(title: str, lines: Sequence[str]) -> None:
    print(f"\n== {title}")
    for line in lines:
        print(line)


def _by_shape(series: Sequence[mp.PushSeries]) -> dict[str, list[mp.PushSeries]]:
    """The pushes of each shape, shapes sorted by name."""
    shapes = sorted({s.raw.info.shape for s in series})
    return {shape: [s for s in series if s.raw.info.shape == shape] for shape in shapes}


def _alignment_report(groups: dict[str, list[mp.PushSeries]]) -> list[str]:
    """Per shape: the importer's alignment, its first-contact and gap errors, the extra fit."""
    lines = []
    for shape, group in groups.items():
        checks = [mp.alignment_check(s) for s in group]
        onset = [
            c.onset_error
            for c, s in zip(checks, group, strict=True)
            if c.onset_index is not None and abs(s.raw.info.angle) < 1.2
        ]
        moving = [c.moving_gap for c in checks if math.isfinite(c.moving_gap)]
        eps, dx, dy = fit_alignment(group)
        a = mp.ALIGNMENTS[shape]
        lines.append(
            f"{shape:6s} n={len(group):2d} yaw_offset={a.yaw_offset:+.4f} offset=("
            f"{a.offset[0] * 1e3:+.1f}, {a.offset[1] * 1e3:+.1f}) mm | first-contact error "
            f"median {np.median(onset) * 1e3:.2f} max {np.max(onset) * 1e3:.2f} mm | "
            f"|gap| while moving median {np.median(moving) * 1e3:.2f} mm | fit extra: "
            f"yaw {eps:+.4f} rad, offset ({dx * 1e3:+.2f}, {dy * 1e3:+.2f}) mm"
        )
    return lines


def _clock_report(series: Sequence[mp.PushSeries]) -> list[str]:
    """Stream start offsets and the object-stop minus tip-stop lag of near-sticking pushes."""
    offsets = np.array([[s.start_offsets[k] for k in mp.STREAMS] for s in series])
    lags = stop_lags(series)
    return [
        "stream start after the earliest (s), max over files: "
        + ", ".join(f"{k} {v:.3f}" for k, v in zip(mp.STREAMS, offsets.max(axis=0), strict=True)),
        f"object stop - tip stop in {lags.size} near-sticking pushes: median "
        f"{np.median(lags) * 1e3:+.1f} ms, {np.sum(np.abs(lags) < 0.01)}/{lags.size} within "
        "+-10 ms (the rest: stop not detected cleanly)",
    ]


def _motion_report(
    groups: dict[str, list[mp.PushSeries]],
) -> tuple[list[str], list[PushMotion]]:
    """Per shape: measured vs quasi-static displacement ratio, rotation and final error;
    also every push's :class:`PushMotion` (shapes in order)."""
    lines = []
    motions: list[PushMotion] = []
    for shape, group in groups.items():
        c = friction_radius(group[0].outline.vertices)
        ms = [analyse_motion(s, c) for s in group]
        motions.extend(ms)
        ratio = np.array([m.displacement / m.pusher for m in ms if m.pusher > 0.01])
        pratio = np.array([m.predicted_displacement / m.pusher for m in ms if m.pusher > 0.01])
        rot = np.array([m.rotation for m in ms])
        prot = np.array([m.predicted_rotation for m in ms])
        sign = np.mean(np.sign(rot[np.abs(rot) > 0.02]) == np.sign(prot[np.abs(rot) > 0.02]))
        lines.append(
            f"{shape:6s} c={c * 1e3:.1f} mm | object/pusher displacement measured "
            f"{np.median(ratio):.2f} (range {ratio.min():.2f}-{ratio.max():.2f}) predicted "
            f"{np.median(pratio):.2f} | |rotation| measured median {np.median(np.abs(rot)):.3f}"
            f" rad, predicted {np.median(np.abs(prot)):.3f} rad, same sign {sign:.0%} | "
            f"final position error median "
            f"{np.median([m.final_position_error for m in ms]) * 1e3:.1f} mm, yaw "
            f"{np.median(np.abs([m.final_yaw_error for m in ms])):.3f} rad"
        )
    return lines, motions


def _friction_radius_report(groups: dict[str, list[mp.PushSeries]]) -> list[str]:
    """Final errors and rotation ratio with the friction radius c scaled by each C_SCALES."""
    lines = []
    for scale in C_SCALES:
        yaw_err: list[float] = []
        pos_err: list[float] = []
        rot_ratio: list[float] = []
        for group in groups.values():
            c = scale * friction_radius(group[0].outline.vertices)
            for s in group:
                m = analyse_motion(s, c)
                yaw_err.append(abs(m.final_yaw_error))
                pos_err.append(m.final_position_error)
                if abs(m.rotation) > 0.05:
                    rot_ratio.append(m.predicted_rotation / m.rotation)
        lines.append(
            f"c x {scale:.2f}: final yaw error median {np.median(yaw_err):.3f} rad, position "
            f"{np.median(pos_err) * 1e3:.1f} mm, predicted/measured rotation median "
            f"{np.median(rot_ratio):.2f}"
        )
    return lines


def _per_push_report(motions: Sequence[PushMotion]) -> list[str]:
    """One line per push: pusher travel, displacement, rotation and slip (predicted)."""
    return [
        f"  {m.name:38s} {m.pusher * 1e3:5.1f} | {m.displacement * 1e3:5.1f} "
        f"({m.predicted_displacement * 1e3:5.1f}) | {m.rotation:+.3f} "
        f"({m.predicted_rotation:+.3f}) | {m.slip * 1e3:+6.1f} "
        f"({m.predicted_slip * 1e3:+6.1f})"
        for m in motions
    ]


if __name__ == "__main__":
    raise SystemExit(main())
