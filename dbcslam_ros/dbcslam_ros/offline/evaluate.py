"""Metrics of the estimates in a bag against its truth topics (``dbcslam evaluate``).

:func:`load_bag_arrays` turns a bag into numpy arrays (:class:`BagArrays`);
:func:`evaluate_bag` scores them with :mod:`dbcslam_core.metrics`.

Matching: the estimate of the observation stamped t (``/dbcslam/pose`` header stamp) is scored
against the truth sample stamped t (``/truth/object/pose`` header stamp; nearest within half a
model step). The unstamped arrays belong to the stamped message published just before them:
``/dbcslam/contact_modes`` and ``/dbcslam/friction`` to a ``/dbcslam/pose`` and
``/truth/contact_modes`` and ``/truth/friction`` to a ``/truth/object/pose``. When a bag holds
as many arrays as stamped messages they are paired by order (robust to the small reorderings
of a live recording); otherwise each array takes the stamp of the latest stamped message at
or before its log time (exact for replayed bags, which log the outputs at their stamp).

Metrics (JSON keys; SI units):

* ``position_rmse_m``: RMS error of one coordinate (x and y pooled), m, and
  ``position_rmse_over_noise`` = that / the ``/scenario`` position noise std;
  ``observation_rmse_m``: the same for the raw observations (what filtering gains).
* ``yaw_rmse_rad`` (polygon bodies) and ``yaw_rmse_over_noise``.
* ``contact_accuracy`` (in contact or not), ``stick_slide_accuracy`` (over truly-in-contact
  entries; null if there were none), ``contact_mode_accuracy`` (argmax of the 4 modes).
* ``friction``: per pair the final posterior over the candidates and its mean
  ``posterior_mean`` (also without truth), and with ``/truth/friction`` the true value at
  the last matched step, the candidate nearest to it and its final posterior ``p_true``;
  ``friction_p_true_min``: the minimum over pairs.
* Measured contact flag (``/pusher/contact``, e.g. MIT push bags from ``dbcslam
  import-mitpush``; used when the bag has no ``/truth/contact_modes``): Float64MultiArray
  contacts x [separated, in_contact], one row per scenario contact in order, logged at its
  stamp. ``contact_flag_agreement``: fraction of (matched step, contact) entries where
  "P(not separated) > 0.5" equals the flag's "in contact" (``1 - data[c, 0] > 0.5``);
  ``contact_flag_recall`` (over flagged in-contact entries), ``contact_flag_specificity``
  (over flagged separated entries), ``contact_flag_in_contact_fraction`` and
  ``contact_estimated_in_contact_fraction``, ``contact_flag_entries``. Diagnostic only (not
  the filter's mode estimate): ``contact_flag_agreement_touch`` scores the readout "P(not
  separated) > 0.5 or the estimated gap (mean pose, ``/joint_states``) < ``TOUCH_TOL``",
  which counts a pusher resting against the object at zero force as contact.
* ``friction_map_accuracy`` (edge only): over the cells the body truly slid across, the
  fraction whose final map probability of the true candidate exceeds 0.5.
* ``estimates``, ``matched``, ``observations``; ``step_time_ms_mean`` (mean over the
  ``/diagnostics`` messages) and the last diagnostics key/values.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from dbcslam_core.contact_modes import Mode
from dbcslam_core.errors import DbcSlamError
from dbcslam_core.scenario import Scenario
from dbcslam_core.surprise import SURPRISE_WARNING
from dbcslam_ros.bag import open_bag
from dbcslam_ros.contract import (
    CONTACT_MODES,
    DIAGNOSTICS,
    ESTIMATE_TOPICS,
    FRICTION,
    FRICTION_MAP,
    JOINT_STATES,
    OBJECT_POSE,
    POSE,
    PUSHER_CONTACT,
    PUSHER_WRENCH,
    SCENARIO,
    TRUTH_CONTACT_MODES,
    TRUTH_FRICTION,
    TRUTH_POSE,
    TRUTH_TOPICS,
)
from dbcslam_ros.convert import header_ns, planar_pose
from dbcslam_ros.errors import BagError

__all__ = [
    "ESTIMATE_TOPICS",
    "FLAG_TOPIC",
    "PUSHER_WRENCH_TOPIC",
    "TRUTH_TOPICS",
    "BagArrays",
    "BagMessages",
    "FrictionGrid",
    "MissingTopicsError",
    "bag_arrays",
    "contact_flag_metrics",
    "evaluate_bag",
    "load_bag_arrays",
    "match_stamps",
    "metrics_table",
]

FloatArray = NDArray[np.float64]
IntArray = NDArray[np.int64]
NS = 1_000_000_000
_Planar = tuple[float, float, float]

#: Measured (not simulated) contact flag and pusher force topics.
FLAG_TOPIC = PUSHER_CONTACT
PUSHER_WRENCH_TOPIC = PUSHER_WRENCH
#: Gap (m) below which the touching readout of ``contact_flag_agreement_touch`` counts a
#: contact as closed.
TOUCH_TOL = 0.001
_READ_TOPICS = (
    SCENARIO,
    JOINT_STATES,
    OBJECT_POSE,
    DIAGNOSTICS,
    FLAG_TOPIC,
    PUSHER_WRENCH_TOPIC,
    *ESTIMATE_TOPICS,
    *TRUTH_TOPICS,
)


class MissingTopicsError(BagError):
    """The bag lacks the topics a metric needs (CLI exit 2); ``missing`` names them."""

    def __init__(self, message: str, missing: tuple[str, ...]) -> None:
        super().__init__(message)
        self.missing = missing


@dataclass(frozen=True)
class FrictionGrid:
    """The last ``/dbcslam/friction_map``: per pair (row) and cell the probability (0..1) of
    the pair's highest candidate, NaN where never touched; cells along s from ``s_min``."""

    s_min: float
    cell: float
    p_high: FloatArray  # (pairs, cells)

    @property
    def edges(self) -> FloatArray:
        """Cell boundaries (m), shape (cells + 1,)."""
        n = self.p_high.shape[1]
        return np.asarray(self.s_min + self.cell * np.arange(n + 1), dtype=np.float64)


@dataclass
class BagArrays:
    """Time series of one bag (stamps in ns; poses (x, y, yaw) in m, m, rad).

    Attributes:
        est_t: (T,) estimate stamps; est_pose (T, 3); est_cov (T, 3, 3) planar covariance.
        modes: (T, C, 4) P(mode) aligned with est_t (None if not recorded).
        friction: (T, P, K) friction posterior aligned with est_t (None if not recorded).
        obs_t, obs_pose: observations; truth_t, truth_pose: ground truth poses.
        truth_modes: (T', C) integer true modes aligned with truth_t (None if absent).
        truth_friction: (T', P) true coefficient per pair aligned with truth_t (None if absent).
        diagnostics: (stamp ns, key/values) of every /diagnostics message.
        flag_t, flag: measured contact flag (/pusher/contact): stamps (log time) and (T'', C)
            bool "in contact" per scenario contact (None if absent).
        force_t, force: /pusher/wrench stamps and (T''', 3) [fx, fy, tau_z] (N, N m).
        joint_t, joints: /joint_states stamps and (T'''', E) positions in the order of the
            scenario's joints (empty if absent or the names do not match).
    """

    path: Path
    scenario: Scenario | None = None
    est_t: IntArray = field(default_factory=lambda: np.zeros(0, dtype=np.int64))
    est_pose: FloatArray = field(default_factory=lambda: np.zeros((0, 3)))
    est_cov: FloatArray = field(default_factory=lambda: np.zeros((0, 3, 3)))
    modes: FloatArray | None = None
    friction: FloatArray | None = None
    friction_map: FrictionGrid | None = None
    obs_t: IntArray = field(default_factory=lambda: np.zeros(0, dtype=np.int64))
    obs_pose: FloatArray = field(default_factory=lambda: np.zeros((0, 3)))
    truth_t: IntArray = field(default_factory=lambda: np.zeros(0, dtype=np.int64))
    truth_pose: FloatArray = field(default_factory=lambda: np.zeros((0, 3)))
    truth_modes: IntArray | None = None
    truth_friction: FloatArray | None = None
    diagnostics: list[tuple[int, dict[str, str]]] = field(default_factory=list)
    flag_t: IntArray = field(default_factory=lambda: np.zeros(0, dtype=np.int64))
    flag: NDArray[np.bool_] | None = None
    force_t: IntArray = field(default_factory=lambda: np.zeros(0, dtype=np.int64))
    force: FloatArray = field(default_factory=lambda: np.zeros((0, 3)))
    joint_t: IntArray = field(default_factory=lambda: np.zeros(0, dtype=np.int64))
    joints: FloatArray = field(default_factory=lambda: np.zeros((0, 0)))
    counts: dict[str, int] = field(default_factory=dict)

    @property
    def t0(self) -> int:
        """Earliest stamp of the run (ns), the origin of plotted times."""
        firsts = [int(a[0]) for a in (self.obs_t, self.truth_t, self.est_t) if a.size]
        return min(firsts) if firsts else 0


def _array(msg: Any) -> FloatArray:
    dims = [int(d.size) for d in msg.layout.dim]
    data = np.asarray(msg.data, dtype=np.float64).reshape(-1)
    if dims and int(np.prod(dims)) == data.size:
        return data.reshape(dims)
    return data


def _align(
    arrays: list[tuple[int, FloatArray]], stamps: list[tuple[int, int]], n_stamped: int
) -> tuple[list[int], list[FloatArray]]:
    """Stamp each unstamped array: by order if the counts agree, else by log time.

    arrays: (log time, value); stamps: (log time, stamp) of the stamped topic in log order.
    Returns the stamp per kept array and the arrays (arrays before any stamp are dropped).
    """
    if not arrays:
        return [], []
    if len(arrays) == n_stamped:
        return [s for _, s in stamps], [a for _, a in arrays]
    log_times = np.asarray([lt for lt, _ in stamps], dtype=np.int64)
    out_t: list[int] = []
    out_a: list[FloatArray] = []
    for lt, value in arrays:
        idx = int(np.searchsorted(log_times, lt, side="right")) - 1
        if idx >= 0:
            out_t.append(stamps[idx][1])
            out_a.append(value)
    return out_t, out_a


def _by_stamp(
    stamps: IntArray, t: list[int], values: list[FloatArray], shape: tuple[int, ...]
) -> FloatArray | None:
    """values re-indexed onto `stamps` (exact stamp match; the last one wins); None if any
    stamp has no value or the shapes disagree."""
    if not values:
        return None
    table: dict[int, FloatArray] = {}
    for s, v in zip(t, values, strict=True):
        if v.shape == shape:
            table[s] = v
    if any(int(s) not in table for s in stamps):
        return None
    return np.stack([table[int(s)] for s in stamps]) if stamps.size else np.zeros((0, *shape))


def load_bag_arrays(path: str | Path, *, salvage: bool = False) -> BagArrays:
    """Read the estimate, truth, observation and diagnostics topics of a bag into arrays.

    Raises:
        BagError: the bag cannot be read, or its /scenario is invalid.
    """
    return bag_arrays(_read_messages(Path(path), salvage=salvage))


def bag_arrays(msgs: BagMessages) -> BagArrays:
    """The arrays of messages collected as a bag's (read, or written by a replay)."""
    out = BagArrays(
        path=msgs.path,
        scenario=msgs.scenario,
        friction_map=msgs.friction_map,
        diagnostics=msgs.diagnostics,
        counts=msgs.counts,
    )
    _set_estimates(out, msgs)
    _set_truth(out, msgs)
    _set_observations(out, msgs.obs)
    _set_contact_flag(out, msgs.flags)
    _set_joints(out, msgs.joints)
    _set_forces(out, msgs.forces)
    return out


@dataclass
class BagMessages:
    """The messages of one bag as read, before they are stamped and stacked
    (:func:`bag_arrays`): rosbags or rclpy message objects, fed per topic in log order.

    Stamped topics keep (header stamp, value); unstamped arrays (log time, value), and the
    stamped topics they belong to also (log time, stamp) in log order (``*_log``).
    """

    path: Path
    counts: dict[str, int] = field(default_factory=dict)
    scenario: Scenario | None = None
    friction_map: FrictionGrid | None = None
    diagnostics: list[tuple[int, dict[str, str]]] = field(default_factory=list)
    est: list[tuple[int, _Planar, FloatArray]] = field(default_factory=list)
    est_log: list[tuple[int, int]] = field(default_factory=list)
    modes: list[tuple[int, FloatArray]] = field(default_factory=list)
    friction: list[tuple[int, FloatArray]] = field(default_factory=list)
    truth: list[tuple[int, _Planar]] = field(default_factory=list)
    truth_log: list[tuple[int, int]] = field(default_factory=list)
    tmodes: list[tuple[int, FloatArray]] = field(default_factory=list)
    tfriction: list[tuple[int, FloatArray]] = field(default_factory=list)
    obs: list[tuple[int, _Planar]] = field(default_factory=list)
    flags: list[tuple[int, FloatArray]] = field(default_factory=list)
    forces: list[tuple[int, _Planar]] = field(default_factory=list)
    joints: list[tuple[int, dict[str, float]]] = field(default_factory=list)

    def record(self, topic: str, lt: int, msg: Any) -> None:
        """Count one message of any topic written to the bag and keep it if it is read
        (:meth:`add`); for a bag being written, whose counts are not in a summary. A
        ``/scenario`` that does not parse is counted, not kept (the writer, e.g. a replay,
        rejects it as the filter node does), where reading it from a bag raises."""
        self.counts[topic] = self.counts.get(topic, 0) + 1
        try:
            self.add(topic, lt, msg)
        except BagError:
            if topic != SCENARIO:
                raise

    def add(self, topic: str, lt: int, msg: Any) -> None:
        """Keep one decoded message of ``topic`` logged at ``lt`` (ns) (other topics: ignored)."""
        if topic == POSE:
            stamp = header_ns(msg)
            self.est.append((stamp, planar_pose(msg.pose.pose), _planar_cov(msg.pose.covariance)))
            self.est_log.append((lt, stamp))
        elif topic == CONTACT_MODES:
            self.modes.append((lt, _array(msg)))
        elif topic == FRICTION:
            self.friction.append((lt, _array(msg)))
        elif topic == FRICTION_MAP:
            self.friction_map = _friction_grid(msg)
        elif topic == TRUTH_POSE:
            stamp = header_ns(msg)
            self.truth.append((stamp, planar_pose(msg.pose)))
            self.truth_log.append((lt, stamp))
        elif topic == TRUTH_CONTACT_MODES:
            self.tmodes.append((lt, _array(msg)))
        elif topic == TRUTH_FRICTION:
            self.tfriction.append((lt, _array(msg)))
        elif topic == FLAG_TOPIC:
            self.flags.append((lt, _array(msg)))
        elif topic == PUSHER_WRENCH_TOPIC:
            w = msg.wrench
            self.forces.append(
                (header_ns(msg), (float(w.force.x), float(w.force.y), float(w.torque.z)))
            )
        elif topic == JOINT_STATES:
            positions = dict(zip(msg.name, (float(v) for v in msg.position), strict=False))
            self.joints.append((header_ns(msg), positions))
        elif topic == OBJECT_POSE:
            self.obs.append((header_ns(msg), planar_pose(msg.pose)))
        elif topic == DIAGNOSTICS:
            values: dict[str, str] = {}
            for status in msg.status:
                values.update({str(kv.key): str(kv.value) for kv in status.values})
            self.diagnostics.append((header_ns(msg), values))
        elif topic == SCENARIO and self.scenario is None:
            try:
                self.scenario = Scenario.from_yaml(str(msg.data))
            except (DbcSlamError, ValueError, TypeError, KeyError) as err:
                problem = f"{self.path}: /scenario does not parse: {err}"
                raise BagError(problem) from err


def _read_messages(path: Path, *, salvage: bool) -> BagMessages:
    """Every message of the topics :func:`load_bag_arrays` reads, in log order."""
    msgs = BagMessages(path=path)
    with open_bag(path, salvage=salvage) as reader:
        msgs.counts = reader.counts()
        for raw, msg in reader.decoded(t for t in _READ_TOPICS if msgs.counts.get(t)):
            msgs.add(raw.topic, raw.log_time_ns, msg)
    return msgs


def _planar_cov(covariance: Any) -> FloatArray:
    """The (x, y, yaw) block of a row-major 6x6 pose covariance."""
    cov6 = np.asarray(covariance, dtype=np.float64).reshape(6, 6)
    return cov6[np.ix_((0, 1, 5), (0, 1, 5))]


def _friction_grid(msg: Any) -> FrictionGrid:
    """A ``/dbcslam/friction_map`` OccupancyGrid (percent, -1 unknown) as a FrictionGrid."""
    info = msg.info
    data = np.asarray(msg.data, dtype=np.float64).reshape(int(info.height), int(info.width))
    return FrictionGrid(
        s_min=float(info.origin.position.x),
        cell=float(info.resolution),
        p_high=np.where(data < 0, np.nan, data / 100.0),
    )


def _aligned(
    items: list[tuple[int, FloatArray]], log: list[tuple[int, int]], stamps: IntArray
) -> FloatArray | None:
    """Unstamped arrays stamped by :func:`_align` and re-indexed onto ``stamps``
    (:func:`_by_stamp`, the shape of the last one); None if any stamp lacks one."""
    t, vals = _align(items, log, len(log))
    return _by_stamp(stamps, t, vals, vals[-1].shape if vals else ())


def _one_row_each(arr: FloatArray) -> FloatArray:
    """(T, K) arrays of a single contact or pair (recorded flat) as (T, 1, K)."""
    return arr[:, None, :] if arr.ndim == 2 else arr


def _set_estimates(out: BagArrays, msgs: BagMessages) -> None:
    """Estimated poses and covariances, and the mode and friction arrays at their stamps."""
    if not msgs.est:
        return
    out.est_t = np.asarray([e[0] for e in msgs.est], dtype=np.int64)
    out.est_pose = np.asarray([e[1] for e in msgs.est], dtype=np.float64)
    out.est_cov = np.stack([e[2] for e in msgs.est])
    modes = _aligned(msgs.modes, msgs.est_log, out.est_t)
    friction = _aligned(msgs.friction, msgs.est_log, out.est_t)
    # One contact / pair recorded as a flat (4,) / (K,) array: add its axis.
    out.modes = modes[:, None, :] if modes is not None and modes.ndim == 2 else modes
    out.friction = (
        friction[:, None, :] if friction is not None and friction.ndim == 2 else friction
    )


def _set_truth(out: BagArrays, msgs: BagMessages) -> None:
    """True poses, and the true modes (argmax) and friction coefficients at their stamps."""
    if not msgs.truth:
        return
    out.truth_t = np.asarray([s for s, _ in msgs.truth], dtype=np.int64)
    out.truth_pose = np.asarray([v for _, v in msgs.truth], dtype=np.float64)
    modes = _aligned(msgs.tmodes, msgs.truth_log, out.truth_t)
    if modes is not None:
        out.truth_modes = np.argmax(_one_row_each(modes), axis=-1).astype(np.int64)
    friction = _aligned(msgs.tfriction, msgs.truth_log, out.truth_t)
    if friction is not None:
        out.truth_friction = friction.reshape(friction.shape[0], -1)


def _set_observations(out: BagArrays, obs: list[tuple[int, _Planar]]) -> None:
    """The observed poses (``/object/pose``)."""
    if obs:
        out.obs_t = np.asarray([s for s, _ in obs], dtype=np.int64)
        out.obs_pose = np.asarray([v for _, v in obs], dtype=np.float64)


def _set_contact_flag(out: BagArrays, flags: list[tuple[int, FloatArray]]) -> None:
    """The measured "in contact" flag of each contact, from the messages shaped as the last."""
    if not flags:
        return
    shape = flags[-1][1].shape
    kept = [(lt, a) for lt, a in flags if a.shape == shape and a.ndim == 2 and shape[1] >= 1]
    if kept:
        out.flag_t = np.asarray([lt for lt, _ in kept], dtype=np.int64)
        out.flag = np.stack([1.0 - a[:, 0] > 0.5 for _, a in kept])


def _set_joints(out: BagArrays, joints: list[tuple[int, dict[str, float]]]) -> None:
    """Joint positions in the scenario's joint order, from the messages naming them all."""
    names = list(out.scenario.joints) if out.scenario is not None else []
    full = [(t, [j[n] for n in names]) for t, j in joints if names and all(n in j for n in names)]
    if full:
        out.joint_t = np.asarray([t for t, _ in full], dtype=np.int64)
        out.joints = np.asarray([v for _, v in full], dtype=np.float64)


def _set_forces(out: BagArrays, forces: list[tuple[int, _Planar]]) -> None:
    """The pusher's planar wrench [fx, fy, tau_z] (``/pusher/wrench``)."""
    if forces:
        out.force_t = np.asarray([s for s, _ in forces], dtype=np.int64)
        out.force = np.asarray([v for _, v in forces], dtype=np.float64)


def match_stamps(a: IntArray, b: IntArray, tol_ns: int) -> tuple[IntArray, IntArray]:
    """Index pairs (i, j) with |a[i] - b[j]| <= tol_ns, each a[i] to its nearest b[j].

    ``b`` must be sorted ascending (bag order of the truth stamps).
    """
    if a.size == 0 or b.size == 0:
        return np.zeros(0, dtype=np.int64), np.zeros(0, dtype=np.int64)
    order = np.argsort(b, kind="stable")
    bs = b[order]
    pos = np.clip(np.searchsorted(bs, a), 1, bs.size - 1) if bs.size > 1 else np.zeros_like(a)
    if bs.size > 1:
        left = bs[pos - 1]
        right = bs[pos]
        pick = np.where(np.abs(a - left) <= np.abs(right - a), pos - 1, pos)
    else:
        pick = pos
    ok = np.abs(bs[pick] - a) <= tol_ns
    i = np.flatnonzero(ok).astype(np.int64)
    return i, order[pick[ok]].astype(np.int64)


def _round(value: float | None, digits: int = 6) -> float | None:
    if value is None or not math.isfinite(value):
        return None
    return round(float(value), digits)


def _missing(arrays: BagArrays, topics: tuple[str, ...]) -> tuple[str, ...]:
    return tuple(t for t in topics if not arrays.counts.get(t))


def evaluate_bag(
    path: str | Path,
    *,
    require_truth: bool = True,
    salvage: bool = False,
    arrays: BagArrays | None = None,
) -> dict[str, Any]:
    """Metrics of the bag's estimates against its truth (see the module docstring).

    require_truth: without truth topics raise MissingTopicsError (the CLI's behaviour);
    with False the metrics hold only counts and timings (replay of a bag without truth).

    Raises:
        MissingTopicsError: no estimates, or (require_truth) no truth poses.
        BagError: unreadable bag or bad /scenario.
    """
    from dbcslam_core import metrics as m

    arr = arrays if arrays is not None else load_bag_arrays(path, salvage=salvage)
    p = Path(path)
    if arr.est_t.size == 0:
        msg = (
            f"{p}: no estimates (/dbcslam/pose has no messages); run `dbcslam replay` on it "
            "first or record the filter's outputs"
        )
        raise MissingTopicsError(msg, (POSE,))
    sc = arr.scenario
    res: dict[str, Any] = {
        "bag": str(p),
        "scenario": sc.kind if sc is not None else None,
        "estimates": int(arr.est_t.size),
        "observations": int(arr.obs_t.size),
    }
    res.update(_diagnostics_summary(arr))
    missing_truth = _missing(arr, TRUTH_TOPICS)
    if arr.truth_t.size == 0:
        if require_truth:
            msg = (
                f"{p}: no truth to compare with; missing topic(s) {', '.join(missing_truth)} "
                "(only simulated bags carry /truth/*)"
            )
            raise MissingTopicsError(msg, missing_truth)
        res["truth"] = False
        res["missing_topics"] = list(missing_truth)
        return res
    res["truth"] = True
    if missing_truth:
        res["missing_topics"] = list(missing_truth)
    dt = sc.dt if sc is not None else 0.01
    i_est, i_tru = match_stamps(arr.est_t, arr.truth_t, int(0.5 * dt * NS))
    res["matched"] = int(i_est.size)
    if i_est.size == 0:
        msg = f"{p}: no estimate stamp matches a /truth/object/pose stamp (within dt/2)"
        raise MissingTopicsError(msg, (TRUTH_POSE,))
    est_xy = arr.est_pose[i_est, :2]
    tru_xy = arr.truth_pose[i_tru, :2]
    pos = m.position_rmse(est_xy, tru_xy)
    res["position_rmse_m"] = _round(pos)
    noise = sc.noise.position if sc is not None else None
    res["position_noise_std_m"] = noise
    res["position_rmse_over_noise"] = _round(pos / noise, 4) if noise else None
    j_obs, j_tru = match_stamps(arr.obs_t, arr.truth_t, int(0.5 * dt * NS))
    if j_obs.size:
        res["observation_rmse_m"] = _round(
            m.position_rmse(arr.obs_pose[j_obs, :2], arr.truth_pose[j_tru, :2])
        )
    polygon = sc is not None and sc.body.shape == "polygon"
    if polygon:
        yaw = m.yaw_rmse(arr.est_pose[i_est, 2], arr.truth_pose[i_tru, 2])
        res["yaw_rmse_rad"] = _round(yaw)
        res["yaw_noise_std_rad"] = sc.noise.yaw if sc is not None else None
        ynoise = sc.noise.yaw if sc is not None else 0.0
        res["yaw_rmse_over_noise"] = _round(yaw / ynoise, 4) if ynoise else None
    else:
        res["yaw_rmse_rad"] = None
    res.update(_mode_metrics(arr, i_est, i_tru))
    if arr.truth_modes is None and arr.flag is not None:
        res.update(contact_flag_metrics(arr, int(0.5 * dt * NS)))
    res.update(_friction_metrics(arr, i_est, i_tru))
    return res


def contact_flag_metrics(arr: BagArrays, tol_ns: int) -> dict[str, Any]:
    """Agreement of the estimated contact (P(not separated) > 0.5) with the measured flag.

    Each estimate is matched to the flag stamped within ``tol_ns`` of it (see the module
    docstring for the keys). Empty dict without a flag or mode estimates.
    """
    if arr.flag is None or arr.modes is None:
        return {}
    i_est, i_flag = match_stamps(arr.est_t, arr.flag_t, tol_ns)
    out: dict[str, Any] = {"contact_flag_entries": int(i_est.size * arr.flag.shape[1])}
    if arr.modes.shape[1] != arr.flag.shape[1]:
        out["contact_flag_error"] = (
            f"estimate has {arr.modes.shape[1]} contact(s), the flag {arr.flag.shape[1]}"
        )
        return out
    if i_est.size == 0:
        out["contact_flag_error"] = "no estimate stamp matches a /pusher/contact stamp"
        return out
    est = 1.0 - arr.modes[i_est, :, Mode.SEPARATED] > 0.5
    flag = arr.flag[i_flag]
    out["contact_flag_agreement"] = _round(float(np.mean(est == flag)), 4)
    out["contact_flag_recall"] = _round(float(np.mean(est[flag])), 4) if flag.any() else None
    out["contact_flag_specificity"] = (
        _round(float(np.mean(~est[~flag])), 4) if (~flag).any() else None
    )
    out["contact_flag_in_contact_fraction"] = _round(float(np.mean(flag)), 4)
    out["contact_estimated_in_contact_fraction"] = _round(float(np.mean(est)), 4)
    gap = _estimated_gaps(arr, i_est, tol_ns)
    if gap is not None:
        ok = np.isfinite(gap)
        touch = est | (gap < TOUCH_TOL)
        if np.any(ok.all(axis=1)):
            rows = ok.all(axis=1)
            out["contact_flag_agreement_touch"] = _round(
                float(np.mean(touch[rows] == flag[rows])), 4
            )
            out["touch_tol_m"] = TOUCH_TOL
    return out


def _estimated_gaps(arr: BagArrays, i_est: IntArray, tol_ns: int) -> FloatArray | None:
    """Gap (m) of every contact at the estimated mean pose and the joint positions of each
    estimate in ``i_est`` (NaN where no joint reading matches); None without joints."""
    sc = arr.scenario
    if sc is None or arr.joint_t.size == 0 or i_est.size == 0:
        return None
    from dbcslam_core.geometry import contact_kinematics

    k, j = match_stamps(arr.est_t[i_est], arr.joint_t, tol_ns)
    gap = np.full((i_est.size, sc.n_contacts), np.nan)
    if k.size:
        q = arr.est_pose[i_est[k]][:, : sc.nq]
        gap[k] = contact_kinematics(sc, q, arr.joints[j]).phi
    return gap


def _diagnostics_summary(arr: BagArrays) -> dict[str, Any]:
    out: dict[str, Any] = {"step_time_ms_mean": None}
    times = [float(v["step_time_ms_mean"]) for _, v in arr.diagnostics if "step_time_ms_mean" in v]
    if times:
        out["step_time_ms_mean"] = _round(float(np.mean(times)), 3)
    # counters since start: the last message that has them holds the run's
    health = next((v for _, v in reversed(arr.diagnostics) if "surprise_nats_peak" in v), None)
    if health is not None:
        out["surprise_nats_peak"] = _round(float(health["surprise_nats_peak"]), 1)
        out["surprised_steps"] = int(health.get("surprised_steps", 0))
    if arr.diagnostics:
        out["diagnostics_last"] = arr.diagnostics[-1][1]
    return out


def _mode_metrics(arr: BagArrays, i_est: IntArray, i_tru: IntArray) -> dict[str, Any]:
    from dbcslam_core import metrics as m

    out: dict[str, Any] = {
        "contact_accuracy": None,
        "stick_slide_accuracy": None,
        "contact_mode_accuracy": None,
    }
    if arr.modes is None or arr.truth_modes is None:
        return out
    probs = arr.modes[i_est]
    true = arr.truth_modes[i_tru]
    if probs.shape[:2] != true.shape:
        out["modes_error"] = (
            f"estimate modes {probs.shape[1:]} and truth modes {true.shape[1:]} disagree"
        )
        return out
    out["contact_accuracy"] = _round(m.contact_accuracy(probs, true), 4)
    out["contact_mode_accuracy"] = _round(m.contact_mode_accuracy(probs, true), 4)
    in_contact = true != Mode.SEPARATED
    out["in_contact_entries"] = int(np.count_nonzero(in_contact))
    if np.any(in_contact):
        out["stick_slide_accuracy"] = _round(m.stick_slide_accuracy(probs, true), 4)
        out["contact_mode_accuracy_in_contact"] = _round(
            m.contact_mode_accuracy(probs, true, mask=in_contact), 4
        )
    return out


def _friction_metrics(arr: BagArrays, i_est: IntArray, i_tru: IntArray) -> dict[str, Any]:
    from dbcslam_core import metrics as m

    out: dict[str, Any] = {"friction": [], "friction_p_true_min": None}
    sc = arr.scenario
    if arr.friction is None or sc is None:
        return out
    pairs = list(sc.friction.pairs)
    final = arr.friction[i_est[-1]]
    truth = (
        arr.truth_friction[i_tru]
        if arr.truth_friction is not None
        else np.zeros((i_tru.size, 0), dtype=np.float64)
    )
    p_true_all: list[float] = []
    for p, name in enumerate(pairs):
        cands = np.asarray(sc.friction.candidates[p], dtype=np.float64)
        col = truth[:, p] if p < truth.shape[1] else np.zeros(0)
        finite = col[np.isfinite(col)]
        entry: dict[str, Any] = {
            "pair": name,
            "candidates": [float(c) for c in cands],
            "final_posterior": [_round(float(v), 4) for v in final[p, : cands.size]],
            "posterior_mean": _round(float(np.dot(final[p, : cands.size], cands)), 4),
        }
        if finite.size:
            true_value = float(finite[-1])
            k = int(np.argmin(np.abs(cands - true_value)))
            entry["true_value"] = true_value
            entry["true_index"] = k
            entry["p_true"] = _round(float(final[p, k]), 4)
            p_true_all.append(float(final[p, k]))
        out["friction"].append(entry)
    if p_true_all:
        out["friction_p_true_min"] = _round(min(p_true_all), 4)
    if (
        sc.kind == "edge"
        and arr.friction_map is not None
        and arr.truth_modes is not None
        and arr.truth_friction is not None
    ):
        grid = arr.friction_map
        edges = grid.edges
        cands = np.asarray(sc.friction.candidates[0], dtype=np.float64)
        hi = int(np.argmax(cands))
        tmodes = arr.truth_modes[:, 0]
        s = arr.truth_pose[:, 0]  # edge: s = x along the edge
        cells = m.slid_cells(s, tmodes, edges)
        # True candidate per cell: the truth friction while sliding there (majority vote).
        tf = arr.truth_friction[:, 0]
        sliding = np.isin(tmodes, (Mode.SLIDING_POS, Mode.SLIDING_NEG)) & np.isfinite(tf)
        idx = np.searchsorted(edges, s, side="right") - 1
        true_hi = np.zeros(cells.size, dtype=np.int64)
        for c in np.flatnonzero(cells):
            sel = sliding & (idx == c)
            if np.any(sel):
                ks = np.argmin(np.abs(tf[sel][:, None] - cands[None, :]), axis=1)
                true_hi[c] = int(np.mean(ks == hi) >= 0.5)
        p_hi = grid.p_high[0]
        post = np.stack([1.0 - p_hi, p_hi], axis=1)
        out["friction_map_cells"] = int(np.count_nonzero(cells))
        out["friction_map_accuracy"] = (
            _round(m.friction_map_accuracy(post, true_hi, cells), 4) if np.any(cells) else None
        )
    return out


def metrics_table(metrics: dict[str, Any]) -> str:
    """A short human-readable summary table of a metrics dict."""

    def fmt(v: Any, spec: str = ".4f") -> str:
        return "n/a" if v is None else format(v, spec)

    rows = [
        ("bag", str(metrics.get("bag", ""))),
        ("scenario", str(metrics.get("scenario"))),
        ("estimates", f"{metrics.get('estimates')} ({metrics.get('matched', 0)} matched)"),
    ]
    if metrics.get("truth", True) and "position_rmse_m" in metrics:
        rows.append(
            (
                "position RMSE",
                f"{fmt(metrics.get('position_rmse_m'), '.5f')} m = "
                f"{fmt(metrics.get('position_rmse_over_noise'), '.2f')} x noise std "
                f"({fmt(metrics.get('position_noise_std_m'), 'g')} m); raw observations "
                f"{fmt(metrics.get('observation_rmse_m'), '.5f')} m",
            )
        )
        if metrics.get("yaw_rmse_rad") is not None:
            rows.append(
                (
                    "yaw RMSE",
                    f"{fmt(metrics['yaw_rmse_rad'], '.5f')} rad = "
                    f"{fmt(metrics.get('yaw_rmse_over_noise'), '.2f')} x noise std",
                )
            )
        rows.append(("contact accuracy", fmt(metrics.get("contact_accuracy"), ".3f")))
        if metrics.get("contact_flag_agreement") is not None:
            rows.append(
                (
                    "contact vs measured flag",
                    f"{metrics['contact_flag_agreement']:.3f} agreement (recall "
                    f"{fmt(metrics.get('contact_flag_recall'), '.3f')}, specificity "
                    f"{fmt(metrics.get('contact_flag_specificity'), '.3f')}; flag in contact "
                    f"{fmt(metrics.get('contact_flag_in_contact_fraction'), '.2f')}, "
                    "estimate "
                    f"{fmt(metrics.get('contact_estimated_in_contact_fraction'), '.2f')})",
                )
            )
        rows.append(("stick/slide accuracy", fmt(metrics.get("stick_slide_accuracy"), ".3f")))
        rows.append(("mode accuracy", fmt(metrics.get("contact_mode_accuracy"), ".3f")))
        for entry in metrics.get("friction", []):
            post = ", ".join(
                f"{c:g}: {fmt(v, '.3f')}"
                for c, v in zip(entry["candidates"], entry["final_posterior"], strict=False)
            )
            true = entry.get("true_value")
            text = f"final P(mu) {{{post}}}, mean {fmt(entry.get('posterior_mean'), '.3f')}"
            if true is not None:
                text += f"; true mu {fmt(true, 'g')} -> P(true) {fmt(entry.get('p_true'), '.3f')}"
            rows.append((f"friction '{entry['pair']}'", text))
        if metrics.get("friction_map_accuracy") is not None:
            rows.append(
                (
                    "friction map accuracy",
                    f"{metrics['friction_map_accuracy']:.3f} "
                    f"({metrics.get('friction_map_cells')} slid cells)",
                )
            )
    elif not metrics.get("truth", True):
        rows.append(("truth", "none (missing " + ", ".join(metrics["missing_topics"]) + ")"))
    rows.append(("mean step time", f"{fmt(metrics.get('step_time_ms_mean'), '.2f')} ms"))
    if metrics.get("surprise_nats_peak") is not None:
        rows.append(
            (
                "tracking health",
                f"largest surprise {metrics['surprise_nats_peak']:.1f} nats, "
                f"{metrics.get('surprised_steps', 0)} step(s) above the "
                f"{SURPRISE_WARNING:g}-nat warning (README 'Tracking health')",
            )
        )
    width = max(len(k) for k, _ in rows)
    return "\n".join(f"{k:<{width}}  {v}" for k, v in rows)


def write_metrics(metrics: dict[str, Any], path: str | Path) -> Path:
    """Write metrics as indented JSON."""
    out = Path(path)
    out.write_text(json.dumps(metrics, indent=2) + "\n")
    return out
