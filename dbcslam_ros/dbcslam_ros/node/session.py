"""Input synchronisation around the core filter, shared by the live node and offline replay.

A :class:`FilterSession` receives decoded input readings in arrival order and turns each pose
observation into filter steps. Rules (documented in the README):

* The pose observation drives the filter: every accepted `/object/pose` ends one model step
  (or several, see below) and yields one estimate stamped with the pose's stamp.
* Wrench (the input u): zero-order hold. The wrench applied during the step (t_prev, t] is the
  latest `/object/wrench` stamped at or before t_prev (what the robot commanded when the step
  began); before any wrench arrives, u = 0.
* Joints (jaw / pusher positions, the moving obstacles): the positions at the pose time t,
  linearly interpolated between the two joint messages that bracket t, or held from the
  latest one when no later message has arrived yet.
* Pusher force (`/pusher/wrench`, the F/T reading at the pusher: an observation, not an
  input): the force of the model step ending at t is the reading at t, linearly interpolated
  between the two readings that bracket t when they are at most `force_max_age_s` apart,
  else the nearest reading within `force_max_age_s` of t; with no reading that close the step
  has no force observation (a stale or missing sensor never blocks the filter). Only
  scenarios with a single disk obstacle (the pusher) take it; elsewhere it is rejected
  (reason `no_pusher`). The force is passed to the filter as `ForceObservation(fx, fy)`
  (world axes, force of the object on the pusher, noise `FilterConfig.force_noise`).
* Pose stamps that are not later than the previous one by at least half a model step are
  rejected (reason `stamp_order`); a jump back in time of more than `reset_after_s` (a bag
  played with --loop) resets the filter cleanly. A gap of n model steps runs n - 1
  predict-only steps first (dropped observations); a gap longer than `max_gap_s` (a stalled
  sensor) re-initialises the filter at the new pose instead (counted in `resets`), except in
  catch-up. A time jump (either kind) takes effect only when `JUMP_CONFIRMATIONS` (3) poses in
  a row continue the new time line (each within `max_gap_s` of the previous); the poses before
  are rejected (reason `stamp_jump`), so poses with corrupted stamps never throw the filter
  away while the real time line goes on.
* Catch-up (a live node that cannot keep up): `add_pose(reading, max_steps=m)` runs at most m
  model steps for a gap of n > m steps. The particles first coast over the n - m skipped
  steps at their own constant velocity (no contact dynamics; counted in `skipped_steps`),
  then the last m steps of the gap run with their wrenches and joint readings. A slow filter
  thus lags the data by a bounded amount instead of a growing backlog, at a cost in
  accuracy while it is behind.
* Bad messages raise :class:`~dbcslam_ros.convert.InputRejected` before they touch the filter;
  the session counts them per reason and stays usable.
* `process_pose` is the one call for a pose (live node and offline tools): gating against
  the last estimate (`gating_threshold` Mahalanobis distance; at most
  `MAX_CONSECUTIVE_OUTLIERS` rejected in a row, then the motion changed and the pose is
  taken; `DIVERGED_AFTER` poses in a row outside the gate reset the filter), catch-up after
  poses dropped from the node's queue (`note_backlog_drop`), the filter steps, and a reset on
  a failed step or a non-finite estimate. It returns a :class:`PoseOutcome`; the session
  keeps the statistics (counts per reason, step times, tracking health).
* Tracking health: the surprise of every estimate (`dbcslam_core.surprise`: how far its log
  predictive likelihood falls below the median of the recent steps, nats) over the last
  `SURPRISE_RECENT` estimates, its peak since start and the estimates above
  `SURPRISE_WARNING` (``/diagnostics`` turns WARN while a recent one is above it).
* Observation-side model extensions (from a model file of `dbcslam discrepancy`): the core
  model applies the dynamic effects itself; the session applies the sensor effects to every
  pose before the filter sees it. ``sensor_bias`` (x, y, yaw): the bias is subtracted from the
  observed pose (the filter estimates the true pose). ``sensor_delay`` (seconds): the pose
  stamped t shows the state at t - seconds, so it is processed (and its estimate stamped) at
  t - seconds, with the inputs of that time. Several of each add up.
"""

from __future__ import annotations

import bisect
import time
from collections import Counter, deque
from collections.abc import Sequence
from dataclasses import dataclass, field, replace

import numpy as np

from dbcslam_core.extensions import ModelExtension
from dbcslam_core.geometry import wrap_angle
from dbcslam_core.observation import ForceObservation, PoseObservation
from dbcslam_core.rbpf import DbcSlamFilter, Estimate, FilterConfig, FilterInput
from dbcslam_core.scenario import Disk, Scenario
from dbcslam_core.surprise import SURPRISE_WARNING, SurpriseMonitor
from dbcslam_ros.convert import InputRejected, JointReading, PoseReading, WrenchReading

__all__ = [
    "DIVERGED_AFTER",
    "MAX_CONSECUTIVE_OUTLIERS",
    "SURPRISE_RECENT",
    "WINDOW",
    "FilterSession",
    "PoseOutcome",
    "StampedEstimate",
    "observation_correction",
]

NS = 1_000_000_000

#: Poses in a row outside the gate (accepted ones included) after which the filter is
#: considered lost and re-initialised at the next pose (reason `diverged`).
DIVERGED_AFTER = 12

#: Number of recent processed poses the step-time statistics cover.
WINDOW = 1000

#: Number of recent estimates whose largest surprise ``/diagnostics`` reports (1 s at 100 Hz).
SURPRISE_RECENT = 100

#: Poses in a row rejected by the gate; the next one is accepted (a persistent deviation is
#: a change of motion the filter must follow, not a sensor outlier).
MAX_CONSECUTIVE_OUTLIERS = 3


def observation_correction(
    extensions: Sequence[ModelExtension],
) -> tuple[tuple[float, float, float], float]:
    """Summed ``sensor_bias`` (x m, y m, yaw rad) and ``sensor_delay`` (s) of extensions."""
    bias = [0.0, 0.0, 0.0]
    delay = 0.0
    for e in extensions:
        if e.effect == "sensor_bias":
            bias[0] += e.param("x")
            bias[1] += e.param("y")
            bias[2] += e.param("yaw")
        delay += e.delay
    return (bias[0], bias[1], bias[2]), delay


#: Poses in a row on a new time line before a time jump resets the filter (`add_pose`).
JUMP_CONFIRMATIONS = 3


@dataclass(frozen=True)
class StampedEstimate:
    """An estimate with the stamp (ns) of the observation it answers, its compute time (s)
    and the number of model steps it took."""

    stamp_ns: int
    estimate: Estimate
    step_time_s: float
    model_steps: int = 1


@dataclass(frozen=True)
class PoseOutcome:
    """What one pose did (`FilterSession.process_pose`): the estimates it produced (0 or 1),
    the reason it was rejected (None: used), whether the filter was reset, and a message
    for the log (``level`` ``warning`` or ``info``; empty: nothing to say)."""

    estimates: tuple[StampedEstimate, ...] = ()
    rejected: str | None = None
    reset: bool = False
    message: str = ""
    level: str = "warning"


@dataclass
class _History:
    """Time-ordered readings with bounded length."""

    stamps: deque[int] = field(default_factory=lambda: deque(maxlen=512))
    values: deque[tuple[float, ...]] = field(default_factory=lambda: deque(maxlen=512))

    def add(self, stamp_ns: int, value: tuple[float, ...]) -> None:
        if self.stamps and stamp_ns < self.stamps[-1]:
            # Late message from the past: keep the order so interpolation stays valid.
            idx = bisect.bisect_right(list(self.stamps), stamp_ns)
            stamps, values = list(self.stamps), list(self.values)
            stamps.insert(idx, stamp_ns)
            values.insert(idx, value)
            self.stamps = deque(stamps, maxlen=512)
            self.values = deque(values, maxlen=512)
            return
        self.stamps.append(stamp_ns)
        self.values.append(value)

    def clear(self) -> None:
        self.stamps.clear()
        self.values.clear()

    def drop_after(self, t_ns: int) -> None:
        """Forget readings stamped later than t."""
        while self.stamps and self.stamps[-1] > t_ns:
            self.stamps.pop()
            self.values.pop()

    def held(self, t_ns: int) -> tuple[float, ...] | None:
        """Latest value stamped at or before t (zero-order hold)."""
        stamps = list(self.stamps)
        idx = bisect.bisect_right(stamps, t_ns) - 1
        if idx < 0:
            return None
        return self.values[idx]

    def near(self, t_ns: int, max_age_ns: int) -> tuple[float, ...] | None:
        """Value at t: interpolated between bracketing readings at most max_age apart, else
        the nearest reading within max_age of t, else None."""
        if not self.stamps:
            return None
        stamps = list(self.stamps)
        idx = bisect.bisect_left(stamps, t_ns)
        if idx < len(stamps) and stamps[idx] == t_ns:
            return self.values[idx]
        before = idx - 1 if idx > 0 else None
        after = idx if idx < len(stamps) else None
        if before is not None and after is not None:
            t0, t1 = stamps[before], stamps[after]
            if t1 - t0 <= max_age_ns:
                a = (t_ns - t0) / (t1 - t0)
                v0, v1 = np.asarray(self.values[before]), np.asarray(self.values[after])
                return tuple(float(v) for v in (1.0 - a) * v0 + a * v1)
        near = [
            j for j in (before, after) if j is not None and abs(stamps[j] - t_ns) <= max_age_ns
        ]
        if not near:
            return None
        return self.values[min(near, key=lambda j: abs(stamps[j] - t_ns))]

    def interpolated(self, t_ns: int) -> tuple[float, ...] | None:
        """Linear interpolation at t between bracketing values; hold at the ends."""
        if not self.stamps:
            return None
        stamps = list(self.stamps)
        idx = bisect.bisect_right(stamps, t_ns)
        if idx == 0:
            return self.values[0]
        if idx == len(stamps):
            return self.values[-1]
        t0, t1 = stamps[idx - 1], stamps[idx]
        v0, v1 = np.asarray(self.values[idx - 1]), np.asarray(self.values[idx])
        a = 0.0 if t1 == t0 else (t_ns - t0) / (t1 - t0)
        return tuple(float(v) for v in (1.0 - a) * v0 + a * v1)


class FilterSession:
    """Feeds readings to a :class:`DbcSlamFilter` with the synchronisation rules above."""

    def __init__(
        self,
        scenario: Scenario,
        config: FilterConfig,
        *,
        seed: int = 0,
        extensions: tuple[ModelExtension, ...] = (),
        reset_after_s: float = 0.5,
        max_gap_s: float = 1.0,
        force_max_age_s: float | None = None,
        gating_threshold: float = 0.0,
        catch_up_steps: int | None = None,
    ) -> None:
        self.scenario = scenario
        self.config = config
        self.seed = seed
        self.extensions = extensions
        self.obs_bias, delay_s = observation_correction(extensions)
        self.obs_delay_ns = round(delay_s * NS)
        self.reset_after_ns = int(reset_after_s * NS)
        self.max_gap_ns = int(max_gap_s * NS)
        # default: 1.5 model steps, so a reading at every sample is always found
        age = 1.5 * scenario.dt if force_max_age_s is None else float(force_max_age_s)
        self.force_max_age_ns = int(age * NS)
        self.has_pusher = sum(isinstance(o, Disk) for o in scenario.obstacles) == 1
        self.force_steps = 0
        self.rejected: Counter[str] = Counter()
        self.resets = 0
        self.steps = 0
        self.skipped_steps = 0
        self.gap_steps = 0
        self._wrench = _History()
        self._joints = _History()
        self._force = _History()
        self._last_pose_ns: int | None = None
        self._jump_chain: list[int] = []  # stamps of a not yet confirmed time jump
        self._filter: DbcSlamFilter | None = None
        self._new_filter()
        # process_pose: gating, catch-up, statistics
        self.gating_threshold = float(gating_threshold)
        self.catch_up_steps = catch_up_steps
        self.last_estimate: StampedEstimate | None = None
        self.backlog_dropped = 0
        self.step_times: deque[float] = deque(maxlen=WINDOW)
        self.model_steps: deque[int] = deque(maxlen=WINDOW)
        self.surprises: deque[float] = deque(maxlen=SURPRISE_RECENT)  # nats, recent estimates
        self.surprise_peak = 0.0  # nats, since start
        self.surprised_steps = 0  # estimates above SURPRISE_WARNING, since start
        self._dropped_since_step = False
        self._outliers_in_row = 0
        self._exceed_in_row = 0
        self._pending: tuple[PoseReading, float] | None = None  # offer_pose / process_pending
        self.warm_up_s = self._warm_up()  # before the first pose, not in its step

    # -- inputs ---------------------------------------------------------------------------
    def add_wrench(self, reading: WrenchReading) -> None:
        """Record an applied wrench (the known input u)."""
        self._wrench.add(reading.stamp_ns, (reading.fx, reading.fy, reading.tau))

    def add_joints(self, reading: JointReading) -> None:
        """Record joint positions (already in scenario.joints order)."""
        self._joints.add(reading.stamp_ns, reading.positions)

    def add_pusher_wrench(self, reading: WrenchReading) -> None:
        """Record a pusher F/T reading (force of the object on the pusher, world axes, N;
        the torque is ignored). Raises InputRejected (reason ``no_pusher``) when the scenario
        has no single disk obstacle to attribute it to."""
        if not self.has_pusher:
            self.rejected["no_pusher"] += 1
            msg = (
                f"scenario '{self.scenario.kind}' has no single pusher (disk obstacle): "
                "a pusher force reading cannot be used"
            )
            raise InputRejected("no_pusher", msg)
        self._force.add(reading.stamp_ns, (reading.fx, reading.fy))

    def reject(self, reason: str) -> None:
        """Count an input rejected before it reached the session (e.g. failed conversion)."""
        self.rejected[reason] += 1

    def note_backlog_drop(self) -> None:
        """A pose was dropped from the node's queue unprocessed (the filter was busy): the
        next pose catches up over its gap (`catch_up_steps`)."""
        self.rejected["backlog"] += 1
        self.backlog_dropped += 1
        self._dropped_since_step = True

    # -- the pose queue (depth one) -----------------------------------------------------
    def offer_pose(self, reading: PoseReading, received: float = 0.0) -> None:
        """Queue a pose for :meth:`process_pending` (``received``: its arrival time, s, for
        the caller's latency). Depth one: a newer pose drops an unprocessed one (counted
        ``backlog``, the next step catches up). The stamp is screened first against the newest
        pose used or queued (:meth:`screen_pose`): raises InputRejected (counted) for a stamp
        that would displace a good pose."""
        stamps = [self.last_pose_ns]
        if self._pending is not None:
            stamps.append(self.correct(self._pending[0]).stamp_ns)
        newest = max((s for s in stamps if s is not None), default=None)
        self.screen_pose(reading, newest)
        if self._pending is not None:
            self.note_backlog_drop()
        self._pending = (reading, received)

    def process_pending(self) -> tuple[PoseOutcome, float] | None:
        """Process the queued pose (:meth:`process_pose`): its outcome and arrival time, or
        None when no pose is queued."""
        if self._pending is None:
            return None
        reading, received = self._pending
        self._pending = None
        return self.process_pose(reading), received

    def process_pose(self, reading: PoseReading) -> PoseOutcome:
        """The whole handling of one pose: gate, catch-up, filter steps, statistics, resets
        (module docstring). Never raises for bad data or a failed filter step."""
        verdict = self._gate(reading)
        if isinstance(verdict, PoseOutcome):
            return verdict
        # Catch up only over gaps of poses we received but did not use (own backlog);
        # a gap in the data itself is run in full.
        catch_up = self.catch_up_steps if self._dropped_since_step else None
        self._dropped_since_step = False
        resets = self.resets
        try:
            results = self.add_pose(reading, max_steps=catch_up)
        except InputRejected as err:
            return PoseOutcome(rejected=err.reason, message=f"rejected /object/pose: {err}")
        except Exception as err:  # a failed step must not stop the node: start over
            text = f"filter step failed ({err!r}); filter reset"
            return self._failed("filter_error", text, reading)
        reset = self.resets != resets
        if reset:
            self.last_estimate = None
            verdict = f"filter reset (jump in time at stamp {reading.stamp_ns * 1e-9:.3f} s)"
        for res in results:
            bad = res.estimate.non_finite_field()
            if bad is not None:
                text = f"not publishing: estimate field {bad} is not finite; filter reset"
                return self._failed("nan_estimate", text, reading)
            self.step_times.append(res.step_time_s)
            self.model_steps.append(res.model_steps)
            self._note_surprise(res.estimate)
            self.last_estimate = res
        return PoseOutcome(tuple(results), reset=reset, message=verdict, level="info")

    def _failed(self, reason: str, text: str, reading: PoseReading) -> PoseOutcome:
        """Count the reason, reset the filter (keeping the inputs up to the pose)."""
        self.rejected[reason] += 1
        self.reset(keep_until_ns=reading.stamp_ns)
        self.last_estimate = None
        return PoseOutcome(rejected=reason, reset=True, message=text)

    def _gate(self, reading: PoseReading) -> PoseOutcome | str:
        """Gating against the last estimate (module docstring): an outcome (rejected or
        reset), or a note (maybe empty) when the pose is to be used."""
        c = self.correct(reading)  # the gate compares like with like (model sensor effects)
        note = ""
        if self._outside_gate(c):
            self._exceed_in_row += 1
            if self._exceed_in_row >= DIVERGED_AFTER:
                # Even accepted poses did not pull the estimate back: the filter is lost.
                self._exceed_in_row = 0
                self._outliers_in_row = 0
                text = "estimate far from the observations: filter reset"
                return self._failed("diverged", text, reading)
            if self._outliers_in_row < MAX_CONSECUTIVE_OUTLIERS:
                self._outliers_in_row += 1
                self._dropped_since_step = True  # the gap it leaves is data we had
                self.rejected["outlier"] += 1
                text = "rejected /object/pose: outside the gating threshold"
                return PoseOutcome(rejected="outlier", message=text)
            # Persistent: the motion changed, not the sensor. Let the filter follow.
            note = f"{self._outliers_in_row} poses in a row outside the gate: accepting"
        else:
            self._exceed_in_row = 0
        self._outliers_in_row = 0
        return note

    def _outside_gate(self, c: PoseReading) -> bool:
        """Whether a (corrected) pose lies outside the gate around the last estimate's
        prediction (Mahalanobis distance with the estimate's and the sensor's covariance)."""
        gate = self.gating_threshold
        last = self.last_estimate
        if gate <= 0.0 or last is None:
            return False
        dt = (c.stamp_ns - last.stamp_ns) * 1e-9
        if not 0.0 <= dt <= 0.5:
            return False  # time jumps are handled by the stamp rules
        est = last.estimate
        pred = est.pose[:2] + est.twist[:2] * dt
        noise = self.scenario.noise.position
        cov = est.pose_cov[:2, :2] + est.twist_cov[:2, :2] * dt * dt + noise**2 * np.eye(2)
        r = np.array([c.x, c.y]) - pred
        try:
            d2 = float(r @ np.linalg.solve(cov, r))
        except np.linalg.LinAlgError:
            return False
        return bool(not np.isfinite(d2) or d2 > gate * gate)  # inf: estimate blew up

    def add_pose(
        self, reading: PoseReading, max_steps: int | None = None
    ) -> list[StampedEstimate]:
        """Process one pose observation; returns the estimate(s) it produced (0 or 1).

        max_steps: run at most this many model steps for this pose (catch-up, see the module
        docstring); None runs the whole gap. Raises InputRejected (and counts it) for
        observations that cannot be used. The reading is first corrected for the model's
        sensor effects (`correct`).
        """
        reading = self.correct(reading)
        dt_ns = round(self.scenario.dt * NS)
        last = self._last_pose_ns
        if last is not None and self._is_time_jump(reading.stamp_ns, last, max_steps):
            self._confirm_time_jump(reading.stamp_ns, last)
            self.reset(keep_until_ns=reading.stamp_ns + dt_ns)
            last = None
        self._jump_chain.clear()
        if last is not None and reading.stamp_ns - last < dt_ns // 2:
            self.rejected["stamp_order"] += 1
            msg = (
                f"pose stamp {reading.stamp_ns} ns is not later than the previous "
                f"{last} ns by at least half a model step ({dt_ns / 2e9:.4f} s)"
            )
            raise InputRejected("stamp_order", msg)
        joints = self._joints_at(reading.stamp_ns)
        obs = PoseObservation(
            reading.x, reading.y, reading.yaw if self.scenario.body.shape == "polygon" else None
        )
        flt = self._filter
        assert flt is not None
        if last is None:
            q0 = [reading.x, reading.y] + ([reading.yaw] if self.scenario.nq == 3 else [])
            std = [self.scenario.noise.position] * 2 + (
                [self.scenario.noise.yaw] if self.scenario.nq == 3 else []
            )
            flt.initialize(q0, std, joints=joints)
            self._last_pose_ns = reading.stamp_ns
            return []
        n_gap = max(1, round((reading.stamp_ns - last) / dt_ns))
        n_run = n_gap if max_steps is None else max(1, min(n_gap, int(max_steps)))
        started = time.perf_counter()
        est: Estimate | None = None
        # Run the LAST n_run steps of the gap; in catch-up the particles first coast over the
        # skipped steps at their own velocity and the joints restart from their readings.
        first = last
        if n_run < n_gap:
            first = reading.stamp_ns - n_run * dt_ns
            self._coast(flt, (n_gap - n_run) * self.scenario.dt)
        for k in range(n_run):
            t_start = first + k * dt_ns
            t_end = reading.stamp_ns if k == n_run - 1 else t_start + dt_ns
            wrench = self._wrench.held(t_start) or (0.0, 0.0, 0.0)
            joints_start = self._joints_at(t_start) if (k == 0 and first != last) else None
            inp = FilterInput(
                wrench=wrench, joints=self._joints_at(t_end), joints_start=joints_start
            )
            force = self._force_at(t_end)
            step_obs = obs if k == n_run - 1 else None
            if force is None:
                est = flt.step(step_obs, inp)
            else:
                est = flt.step(step_obs, inp, force=force)
            self.force_steps += force is not None
        assert est is not None
        self._last_pose_ns = reading.stamp_ns
        self.steps += n_run
        self.gap_steps += n_gap - 1
        self.skipped_steps += n_gap - n_run
        return [StampedEstimate(reading.stamp_ns, est, time.perf_counter() - started, n_run)]

    def screen_pose(self, reading: PoseReading, newest_ns: int | None) -> None:
        """Check a pose's stamp on arrival, before it is queued (live node).

        newest_ns: stamp of the newest pose used or queued. Raises InputRejected (and counts
        it) for a stamp that repeats or goes back by at most ``reset_after`` (``stamp_order``)
        and for the first pose of a time jump (``stamp_jump``, see `add_pose`), so that such a
        pose never displaces a good one from the node's queue.
        """
        if newest_ns is None:
            return
        stamp_ns = self.correct(reading).stamp_ns
        if 0 <= newest_ns - stamp_ns <= self.reset_after_ns:
            self.rejected["stamp_order"] += 1
            msg = f"pose stamp {stamp_ns} ns is not newer than the newest pose ({newest_ns} ns)"
            raise InputRejected("stamp_order", msg)
        if self._is_time_jump(stamp_ns, newest_ns, None):
            self._confirm_time_jump(stamp_ns, newest_ns)
        else:  # the old time line goes on: held jump candidates are forgotten
            self._jump_chain.clear()

    def _is_time_jump(self, stamp_ns: int, last_ns: int, max_steps: int | None) -> bool:
        """A jump back in time beyond ``reset_after`` (a looped bag), or forward beyond
        ``max_gap`` (a stalled sensor; not in catch-up, where our own backlog made the gap)."""
        if stamp_ns < last_ns - self.reset_after_ns:
            return True
        return max_steps is None and stamp_ns - last_ns > self.max_gap_ns

    def _confirm_time_jump(self, stamp_ns: int, last_ns: int) -> None:
        """Accept a time jump only when `JUMP_CONFIRMATIONS` poses in a row show the new line.

        A pose whose stamp jumps (corrupted or hostile, or the first of a looped bag) must not
        throw the filter away on its own: it is held as a candidate and rejected
        (``stamp_jump``). The jump is accepted at the pose that makes `JUMP_CONFIRMATIONS`
        consecutive poses on the new time line (each within ``max_gap`` after the previous
        one); any pose that continues the old time line forgets the candidates.
        """
        chain = self._jump_chain
        if chain and stamp_ns == chain[-1] and len(chain) >= JUMP_CONFIRMATIONS:
            return  # confirmed on arrival (`screen_pose`), now processed
        if chain and 0 < stamp_ns - chain[-1] <= self.max_gap_ns:
            chain.append(stamp_ns)
        else:
            chain[:] = [stamp_ns]
        if len(chain) >= JUMP_CONFIRMATIONS:
            return  # the chain is forgotten once the jump is taken (`add_pose`)
        self.rejected["stamp_jump"] += 1
        msg = (
            f"pose stamp {stamp_ns * 1e-9:.3f} s jumps from the last pose at "
            f"{last_ns * 1e-9:.3f} s: held until {JUMP_CONFIRMATIONS} poses in a row confirm "
            "the new time line"
        )
        raise InputRejected("stamp_jump", msg)

    def correct(self, reading: PoseReading) -> PoseReading:
        """The pose reading as the model's sensor effects say the true pose was: bias
        removed, stamp moved back by the delay (identity without such extensions)."""
        bx, by, byaw = self.obs_bias
        if bx == 0.0 and by == 0.0 and byaw == 0.0 and self.obs_delay_ns == 0:
            return reading
        return replace(
            reading,
            stamp_ns=reading.stamp_ns - self.obs_delay_ns,
            x=reading.x - bx,
            y=reading.y - by,
            yaw=float(wrap_angle(reading.yaw - byaw)),
        )

    # -- introspection --------------------------------------------------------------------
    @property
    def last_pose_ns(self) -> int | None:
        """Stamp (ns) of the last pose used (None before the first one / after a reset)."""
        return self._last_pose_ns

    def particles(self) -> tuple[np.ndarray, np.ndarray]:
        """Particle configurations q (P, nq) and normalised weights (P,) (for markers)."""
        flt = self._filter
        assert flt is not None
        q, w = flt.weighted_particles()
        return np.asarray(q, dtype=np.float64), np.asarray(w, dtype=np.float64)

    def last_joints(self) -> tuple[float, ...]:
        """Latest joint positions received (scenario.joints order), () if none."""
        return self._joints.values[-1] if self._joints.values else ()

    # -- control --------------------------------------------------------------------------
    def statistics(self) -> dict[str, str]:
        """The session's part of the filter's ``/diagnostics`` values (counters since start;
        step times in ms over the last :data:`WINDOW` estimates; keys documented in
        :meth:`dbcslam_ros.node.filter_node.FilterCore.diagnostics_values`)."""
        values = {
            "particles": str(self.config.particles),
            "rejected_total": str(sum(self.rejected.values())),
        }
        for reason, count in sorted(self.rejected.items()):
            values[f"rejected_{reason}"] = str(count)
        values["resets"] = str(self.resets)
        values["filter_steps"] = str(self.steps)
        values["skipped_steps"] = str(self.skipped_steps)
        values["gap_steps"] = str(self.gap_steps)
        values["force_steps"] = str(self.force_steps)
        if self.last_estimate is not None:
            est = self.last_estimate.estimate
            values["ess"] = f"{est.ess:.1f}"
            values["live_hypotheses"] = f"{est.live_hypotheses:.2f}"
        if self.surprises:
            values["surprise_nats_max"] = f"{max(self.surprises):.1f}"
            values["surprise_nats_peak"] = f"{self.surprise_peak:.1f}"
            values["surprised_steps"] = str(self.surprised_steps)
        if self.step_times:
            times = np.asarray(self.step_times) * 1e3
            per_step = times / np.asarray(self.model_steps, dtype=np.float64)
            values["step_time_ms_mean"] = f"{times.mean():.3f}"
            values["step_time_ms_p95"] = f"{np.percentile(times, 95):.3f}"
            values["step_time_ms_max"] = f"{times.max():.3f}"
            values["model_step_time_ms_mean"] = f"{per_step.mean():.3f}"
            values["model_step_time_ms_p95"] = f"{np.percentile(per_step, 95):.3f}"
        return values

    def reset(self, keep_until_ns: int | None = None) -> None:
        """Forget the filter state (new particles from the next pose); counters survive.

        keep_until_ns: keep wrench/joint readings stamped at or before this time (the inputs
        of the new time line that arrived before the pose that triggered the reset); None
        forgets them all.
        """
        self.resets += 1
        if keep_until_ns is None:
            self._wrench.clear()
            self._joints.clear()
            self._force.clear()
        else:
            self._wrench.drop_after(keep_until_ns)
            self._joints.drop_after(keep_until_ns)
            self._force.drop_after(keep_until_ns)
        self._last_pose_ns = None
        self._new_filter()

    def _warm_up(self) -> float:
        """`DbcSlamFilter.warm_up` of the new filter (seconds spent)."""
        return 0.0 if self._filter is None else self._filter.warm_up()

    def _new_filter(self) -> None:
        rng = np.random.default_rng(self.seed + self.resets)
        self._filter = DbcSlamFilter(self.scenario, self.config, rng, extensions=self.extensions)
        self._surprise = SurpriseMonitor()  # a new track: a new reference

    def _note_surprise(self, est: Estimate) -> None:
        """Record the surprise of an estimate (tracking health, module docstring)."""
        surprise = self._surprise.update(est.log_likelihood)
        self.surprises.append(surprise)
        self.surprise_peak = max(self.surprise_peak, surprise)
        self.surprised_steps += surprise > SURPRISE_WARNING

    def _coast(self, flt: DbcSlamFilter, seconds: float) -> None:
        """Move every particle at its own constant velocity for `seconds` (catch-up only).

        Uses the filter's public particle arrays q (P, nq) and v (P, nq); yaw is wrapped.
        """
        q = np.asarray(flt.q, dtype=np.float64) + np.asarray(flt.v, dtype=np.float64) * seconds
        if self.scenario.nq == 3:
            q[:, 2] = wrap_angle(q[:, 2])
        flt.q = q

    def _force_at(self, t_ns: int) -> ForceObservation | None:
        """Pusher force for the model step ending at t (rules in the module docstring)."""
        value = self._force.near(t_ns, self.force_max_age_ns)
        return None if value is None else ForceObservation(value[0], value[1])

    def _joints_at(self, t_ns: int) -> tuple[float, ...]:
        n = len(self.scenario.joints)
        if n == 0:
            return ()
        value = self._joints.interpolated(t_ns)
        if value is None:
            self.rejected["no_joints"] += 1
            msg = f"no /joint_states received yet; need {list(self.scenario.joints)}"
            raise InputRejected("no_joints", msg)
        return value
