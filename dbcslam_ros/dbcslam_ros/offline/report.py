"""Plots and summaries of a bag's estimates (used by ``dbcslam replay`` and ``dbcslam demo``).

:func:`save_bag_figures` draws paper-style figures from the arrays of
:func:`dbcslam_ros.offline.evaluate.load_bag_arrays`, reusing the panel functions of
:mod:`dbcslam_ros.offline.plotting`, and writes them as PNG files:

* ``trajectory.png``: estimate vs truth vs observations (edge: x over time with the truly
  sticking spans shaded, and the x-y path along the edge; gripper/push: x-y path and yaw);
* ``contacts.png``: per contact, P(contact) with true contact shaded (without
  ``/truth/contact_modes``: the measured ``/pusher/contact`` flag, if any) and P(sticking) with
  true sticking shaded (paper Figs. 3c-d, 4);
* ``modes.png``: per contact, the four mode probabilities stacked over time above a strip
  with the true mode (bag-specific: shows every mode, not only contact/stick);
* ``friction.png``: friction posterior of every pair over time, true candidate bold;
* ``friction_map.png`` (edge): final per-cell P(mu = low candidate) along the edge;
* ``filter_health.png``: step time and ESS from ``/diagnostics`` (when recorded).

Times are seconds from the first stamp of the bag.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import NDArray

from dbcslam_ros.offline.evaluate import NS, BagArrays, FloatArray, IntArray, match_stamps

if TYPE_CHECKING:
    from collections.abc import Callable

    from matplotlib.axes import Axes
    from matplotlib.figure import Figure

    from dbcslam_core.scenario import Scenario

__all__ = ["MODE_COLOURS", "plot_mode_strip", "save_bag_figures"]

#: Colours of separated, sticking, sliding_pos, sliding_neg.
MODE_COLOURS = ("0.75", "tab:green", "tab:orange", "tab:blue")
MODE_LABELS = ("separated", "sticking", "sliding +", "sliding -")


def plot_mode_strip(
    ax: Axes,
    t: np.ndarray,
    probs: np.ndarray,
    true_modes: np.ndarray | None,
    *,
    title: str = "",
) -> None:
    """Stacked P(mode) over time for one contact; the true mode as a strip below 0."""
    tv = np.asarray(t, dtype=float)
    p = np.asarray(probs, dtype=float)
    ax.stackplot(tv, p.T, colors=MODE_COLOURS, labels=MODE_LABELS, alpha=0.9)
    if true_modes is not None and tv.size:
        tm = np.asarray(true_modes, dtype=np.int64)
        half = 0.5 * (float(np.median(np.diff(tv))) if tv.size > 1 else 0.01)
        for mode in range(4):
            sel = tm == mode
            if np.any(sel):
                ax.bar(
                    tv[sel],
                    0.12,
                    width=2 * half,
                    bottom=-0.15,
                    color=MODE_COLOURS[mode],
                    align="center",
                    linewidth=0,
                )
        ax.text(tv[0], -0.09, "truth", fontsize=6, va="center")
    ax.set_ylim(-0.16, 1.01)
    ax.set_ylabel("P(mode)")
    ax.set_title(title, fontsize=9)
    ax.grid(True, alpha=0.3)


def save_bag_figures(arrays: BagArrays, out_dir: str | Path) -> list[Path]:
    """Write the figures listed in the module docstring into ``out_dir``; returns the paths.

    Figures whose data the bag lacks are skipped (no truth: estimates and observations only).
    """
    import matplotlib.pyplot as plt

    from dbcslam_ros.offline import plotting as pl

    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    if arrays.est_t.size == 0:
        return []
    view = _FigureView.of(arrays)
    paths: list[Path] = []
    for name, draw in _FIGURES:
        fig = draw(view)
        if fig is None:
            continue
        path = out / name
        fig.tight_layout()
        fig.savefig(path, dpi=pl.DPI)
        plt.close(fig)
        paths.append(path)
    return paths


@dataclass(frozen=True)
class _FigureView:
    """A bag's arrays with the estimates matched to truth and observations, as plotted.

    ``rows`` are the plotted estimates (those with a truth sample when the bag has truth,
    else all); ``t`` their times (s from the first stamp), ``est``/``tru``/``obs_at`` their
    estimated, true and observed planar poses (x, y, yaw); ``truth_modes`` the true mode of
    each contact at them and ``stick`` whether any contact truly sticks.
    """

    arr: BagArrays
    sc: Scenario | None
    kind: str
    has_truth: bool
    i_est: IntArray
    i_tru: IntArray
    rows: IntArray
    t: FloatArray
    est: FloatArray
    tru: FloatArray | None
    obs_at: FloatArray | None
    truth_modes: IntArray | None
    stick: NDArray[np.bool_] | None

    @classmethod
    def of(cls, arr: BagArrays) -> _FigureView:
        sc = arr.scenario
        dt = sc.dt if sc is not None else 0.01
        t_est = (arr.est_t - arr.t0) / NS
        i_est, i_tru = match_stamps(arr.est_t, arr.truth_t, int(0.5 * dt * NS))
        has_truth = i_est.size > 0
        j_obs, j_est = match_stamps(arr.obs_t, arr.est_t, int(0.5 * dt * NS))
        rows = i_est if has_truth else np.arange(arr.est_t.size, dtype=np.int64)
        # Observation of each plotted estimate (NaN where the bag has none).
        obs_of_est = np.full((arr.est_t.size, 3), np.nan)
        obs_of_est[j_est] = arr.obs_pose[j_obs]
        truth_modes = (
            arr.truth_modes[i_tru] if (has_truth and arr.truth_modes is not None) else None
        )
        return cls(
            arr=arr,
            sc=sc,
            kind=sc.kind if sc is not None else "unknown",
            has_truth=has_truth,
            i_est=i_est,
            i_tru=i_tru,
            rows=rows,
            t=t_est[rows],
            est=arr.est_pose[rows],
            tru=arr.truth_pose[i_tru] if has_truth else None,
            obs_at=obs_of_est[rows] if j_obs.size else None,
            truth_modes=truth_modes,
            stick=(truth_modes == 1).any(axis=1) if truth_modes is not None else None,
        )

    def contact_names(self, n_c: int) -> list[str]:
        """The scenario's contact names, ``contact c`` for any beyond them."""
        names = list(self.sc.contacts) if self.sc is not None else []
        return [names[c] if c < len(names) else f"contact {c}" for c in range(n_c)]

    def mode_probs(self) -> FloatArray | None:
        """The estimated mode probabilities of the plotted estimates (step, contact, mode)."""
        modes = self.arr.modes
        if modes is None:
            return None
        return modes[self.i_est] if self.has_truth else modes


def _trajectory_figure(v: _FigureView) -> Figure:
    """Estimate vs truth vs observations: x (edge) or yaw over time, and the x-y path."""
    import matplotlib.pyplot as plt

    from dbcslam_ros.offline import plotting as pl

    t, tru, obs_at = v.t, v.tru, v.obs_at
    fig, axes = plt.subplots(1, 2, figsize=(12, 4.2))
    col, shade_label, ylabel, title = (
        (0, "true sticking", "x [m]", "Position along the edge")
        if v.kind == "edge"
        else (2, "true sticking (any contact)", "yaw [rad]", "Orientation")
    )
    pl.plot_value_vs_time(
        axes[0],
        t,
        tru[:, col] if tru is not None else np.full(t.shape, np.nan),
        obs_at[:, col] if obs_at is not None else None,
        v.est[:, col],
        shade=v.stick,
        shade_label=shade_label,
        ylabel=ylabel,
        title=title,
    )
    pl.plot_trajectory_xy(
        axes[1],
        tru[:, :2] if tru is not None else np.full((t.size, 2), np.nan),
        obs_at[:, :2] if obs_at is not None else None,
        v.est[:, :2],
        edge_y=v.sc.edge_y if (v.sc is not None and v.kind == "edge") else None,
        title=f"Trajectory ({v.kind})",
    )
    return fig


def _contacts_figure(v: _FigureView) -> Figure | None:
    """Per contact, P(contact) and P(sticking | contact) over time with the truth shaded."""
    import matplotlib.pyplot as plt

    from dbcslam_ros.offline import plotting as pl

    probs = v.mode_probs()
    if probs is None or v.sc is None:
        return None
    t, truth_modes = v.t, v.truth_modes
    n_c = probs.shape[1]
    flag_at = _flag_at(v.arr, v.arr.est_t[v.rows], v.sc.dt)
    fig, axes = plt.subplots(n_c, 2, figsize=(12, 1.9 * n_c + 0.6), squeeze=False)
    for c, name in enumerate(v.contact_names(n_c)):
        pc = 1.0 - probs[:, c, 0]
        p_given = probs[:, c, 1] / np.maximum(pc, 1e-12)
        true_c = truth_modes[:, c] if truth_modes is not None else None
        pl.plot_contact_probability(
            axes[c, 0],
            t,
            pc,
            (true_c != 0)
            if true_c is not None
            else (flag_at[:, c] if flag_at is not None else np.zeros(t.shape, dtype=bool)),
            title=f"P(contact): {name}"
            + (" (shaded: measured flag)" if true_c is None and flag_at is not None else ""),
        )
        pl.plot_stick_probability(
            axes[c, 1],
            t,
            np.clip(p_given, 0.0, 1.0),
            (true_c == 1) if true_c is not None else np.zeros(t.shape, dtype=bool),
            title=f"P(sticking | contact): {name}",
        )
    return fig


def _modes_figure(v: _FigureView) -> Figure | None:
    """Per contact, the four mode probabilities stacked over time above the true mode."""
    import matplotlib.pyplot as plt

    probs = v.mode_probs()
    if probs is None or v.sc is None:
        return None
    n_c = probs.shape[1]
    fig, axes = plt.subplots(n_c, 1, figsize=(10, 1.6 * n_c + 0.8), squeeze=False)
    for c, name in enumerate(v.contact_names(n_c)):
        plot_mode_strip(
            axes[c, 0],
            v.t,
            probs[:, c, :],
            v.truth_modes[:, c] if v.truth_modes is not None else None,
            title=name,
        )
    axes[0, 0].legend(fontsize=7, loc="upper right", ncol=4)
    axes[-1, 0].set_xlabel("time [s]")
    return fig


def _friction_figure(v: _FigureView) -> Figure | None:
    """The friction posterior of every pair over time, the true candidate highlighted."""
    import matplotlib.pyplot as plt

    from dbcslam_ros.offline import plotting as pl

    arr, sc = v.arr, v.sc
    if arr.friction is None or sc is None:
        return None
    pairs = list(sc.friction.pairs)
    post_all = arr.friction[v.i_est] if v.has_truth else arr.friction
    fig, axes = plt.subplots(len(pairs), 1, figsize=(8, 3.0 * len(pairs)), squeeze=False)
    for p, name in enumerate(pairs):
        cands = [float(c) for c in sc.friction.candidates[p]]
        pl.plot_friction_posterior(
            axes[p, 0],
            v.t,
            post_all[:, p, : len(cands)],
            cands,
            highlight=_true_candidate(v, p, cands),
            shade=v.stick,
            shade_label="true sticking" if v.stick is not None else None,
            title=f"Friction posterior: {name}",
        )
    return fig


def _true_candidate(v: _FigureView, pair: int, cands: list[float]) -> int | None:
    """Index of the candidate nearest the last finite true friction of ``pair`` (or None)."""
    truth = v.arr.truth_friction
    if not v.has_truth or truth is None or pair >= truth.shape[1]:
        return None
    tf = truth[v.i_tru, pair]
    tf = tf[np.isfinite(tf)]
    if not tf.size:
        return None
    return int(np.argmin(np.abs(np.asarray(cands) - tf[-1])))


def _friction_map_figure(v: _FigureView) -> Figure | None:
    """Edge only: the final per-cell P(mu = low candidate) along the edge."""
    import matplotlib.pyplot as plt

    from dbcslam_ros.offline import plotting as pl

    grid, sc = v.arr.friction_map, v.sc
    if v.kind != "edge" or grid is None or sc is None:
        return None
    lo = float(min(float(c) for c in sc.friction.candidates[0]))
    fig, ax = plt.subplots(figsize=(8, 3.4))
    p_hi = grid.p_high[0]
    weight = np.where(np.isfinite(p_hi), 1.0, 0.0)
    pl.plot_friction_map(
        ax, grid.edges, 1.0 - p_hi, weight=weight, candidate=lo, title="Final friction map"
    )
    return fig


def _health_figure(v: _FigureView) -> Figure | None:
    """Mean step time (and ESS when every message has it) from ``/diagnostics``."""
    import matplotlib.pyplot as plt

    diag = [(s, d) for s, d in v.arr.diagnostics if "step_time_ms_mean" in d]
    if not diag:
        return None
    td = np.asarray([(s - v.arr.t0) / NS for s, _ in diag])
    fig, ax = plt.subplots(figsize=(8, 3.2))
    ax.plot(td, [float(d["step_time_ms_mean"]) for _, d in diag], "o-", label="step time")
    ax.set_xlabel("time [s]")
    ax.set_ylabel("mean step time [ms]")
    ess = [float(d["ess"]) for _, d in diag if "ess" in d]
    if len(ess) == len(diag):
        ax2 = ax.twinx()
        ax2.plot(td, ess, "s--", color="tab:purple", label="ESS")
        ax2.set_ylabel("ESS [particles]")
        ax2.legend(fontsize=7, loc="upper right")
    ax.legend(fontsize=7, loc="upper left")
    ax.set_title("Filter health (/diagnostics)")
    ax.grid(True, alpha=0.3)
    return fig


def _flag_at(arr: BagArrays, stamps: np.ndarray, dt: float) -> np.ndarray | None:
    """The measured contact flag (``/pusher/contact``) at each stamp (False where none is
    within dt/2); None without a flag or when its contacts differ from the estimate's."""
    if arr.flag is None or arr.modes is None or arr.flag.shape[1] != arr.modes.shape[1]:
        return None
    i, j = match_stamps(np.asarray(stamps, dtype=np.int64), arr.flag_t, int(0.5 * dt * NS))
    out = np.zeros((len(stamps), arr.flag.shape[1]), dtype=bool)
    out[i] = arr.flag[j]
    return out


#: The figures in the order they are drawn: file name, and the function that draws it from
#: the matched arrays (None when the bag lacks its data).
_FIGURES: tuple[tuple[str, Callable[[_FigureView], Figure | None]], ...] = (
    ("trajectory.png", _trajectory_figure),
    ("contacts.png", _contacts_figure),
    ("modes.png", _modes_figure),
    ("friction.png", _friction_figure),
    ("friction_map.png", _friction_map_figure),
    ("filter_health.png", _health_figure),
)
