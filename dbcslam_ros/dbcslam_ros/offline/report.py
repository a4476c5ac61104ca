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

from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from dbcslam_ros.offline.evaluate import NS, BagArrays, match_stamps

if TYPE_CHECKING:
    from matplotlib.axes import Axes

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
    arr = arrays
    if arr.est_t.size == 0:
        return []
    sc = arr.scenario
    kind = sc.kind if sc is not None else "unknown"
    dt = sc.dt if sc is not None else 0.01
    t0 = arr.t0
    t_est = (arr.est_t - t0) / NS
    i_est, i_tru = match_stamps(arr.est_t, arr.truth_t, int(0.5 * dt * NS))
    has_truth = i_est.size > 0
    j_obs, j_est = match_stamps(arr.obs_t, arr.est_t, int(0.5 * dt * NS))
    paths: list[Path] = []

    def save(fig: object, name: str) -> None:
        path = out / name
        fig.tight_layout()  # type: ignore[attr-defined]
        fig.savefig(path, dpi=pl.DPI)  # type: ignore[attr-defined]
        plt.close(fig)  # type: ignore[arg-type]
        paths.append(path)

    # -- trajectory ------------------------------------------------------------------------
    rows = i_est if has_truth else np.arange(arr.est_t.size, dtype=np.int64)
    t = t_est[rows]
    est = arr.est_pose[rows]
    tru: np.ndarray | None = arr.truth_pose[i_tru] if has_truth else None
    # Observation of each plotted estimate (NaN where the bag has none).
    obs_of_est = np.full((arr.est_t.size, 3), np.nan)
    obs_of_est[j_est] = arr.obs_pose[j_obs]
    obs_at: np.ndarray | None = obs_of_est[rows] if j_obs.size else None
    fig, axes = plt.subplots(1, 2, figsize=(12, 4.2))
    truth_modes = arr.truth_modes[i_tru] if (has_truth and arr.truth_modes is not None) else None
    stick = (truth_modes == 1).any(axis=1) if truth_modes is not None else None
    if kind == "edge":
        pl.plot_value_vs_time(
            axes[0],
            t,
            tru[:, 0] if tru is not None else np.full(t.shape, np.nan),
            obs_at[:, 0] if obs_at is not None else None,
            est[:, 0],
            shade=stick,
            shade_label="true sticking",
            ylabel="x [m]",
            title="Position along the edge",
        )
    else:
        pl.plot_value_vs_time(
            axes[0],
            t,
            tru[:, 2] if tru is not None else np.full(t.shape, np.nan),
            obs_at[:, 2] if obs_at is not None else None,
            est[:, 2],
            shade=stick,
            shade_label="true sticking (any contact)",
            ylabel="yaw [rad]",
            title="Orientation",
        )
    pl.plot_trajectory_xy(
        axes[1],
        tru[:, :2] if tru is not None else np.full((t.size, 2), np.nan),
        obs_at[:, :2] if obs_at is not None else None,
        est[:, :2],
        edge_y=sc.edge_y if (sc is not None and kind == "edge") else None,
        title=f"Trajectory ({kind})",
    )
    save(fig, "trajectory.png")

    # -- contacts and modes -----------------------------------------------------------------
    if arr.modes is not None and sc is not None:
        names = list(sc.contacts)
        n_c = arr.modes.shape[1]
        probs = arr.modes[i_est] if has_truth else arr.modes
        flag_at = _flag_at(arr, arr.est_t[rows], sc.dt)
        fig, axes2 = plt.subplots(n_c, 2, figsize=(12, 1.9 * n_c + 0.6), squeeze=False)
        for c in range(n_c):
            name = names[c] if c < len(names) else f"contact {c}"
            pc = 1.0 - probs[:, c, 0]
            p_given = probs[:, c, 1] / np.maximum(pc, 1e-12)
            true_c = truth_modes[:, c] if truth_modes is not None else None
            pl.plot_contact_probability(
                axes2[c, 0],
                t,
                pc,
                (true_c != 0)
                if true_c is not None
                else (flag_at[:, c] if flag_at is not None else np.zeros(t.shape, dtype=bool)),
                title=f"P(contact): {name}"
                + (" (shaded: measured flag)" if true_c is None and flag_at is not None else ""),
            )
            pl.plot_stick_probability(
                axes2[c, 1],
                t,
                np.clip(p_given, 0.0, 1.0),
                (true_c == 1) if true_c is not None else np.zeros(t.shape, dtype=bool),
                title=f"P(sticking | contact): {name}",
            )
        save(fig, "contacts.png")
        fig, axes3 = plt.subplots(n_c, 1, figsize=(10, 1.6 * n_c + 0.8), squeeze=False)
        for c in range(n_c):
            name = names[c] if c < len(names) else f"contact {c}"
            plot_mode_strip(
                axes3[c, 0],
                t,
                probs[:, c, :],
                truth_modes[:, c] if truth_modes is not None else None,
                title=name,
            )
        axes3[0, 0].legend(fontsize=7, loc="upper right", ncol=4)
        axes3[-1, 0].set_xlabel("time [s]")
        save(fig, "modes.png")

    # -- friction ---------------------------------------------------------------------------
    if arr.friction is not None and sc is not None:
        pairs = list(sc.friction.pairs)
        post_all = arr.friction[i_est] if has_truth else arr.friction
        fig, axes4 = plt.subplots(len(pairs), 1, figsize=(8, 3.0 * len(pairs)), squeeze=False)
        for p, name in enumerate(pairs):
            cands = [float(c) for c in sc.friction.candidates[p]]
            highlight = None
            if has_truth and arr.truth_friction is not None and p < arr.truth_friction.shape[1]:
                tf = arr.truth_friction[i_tru, p]
                tf = tf[np.isfinite(tf)]
                if tf.size:
                    highlight = int(np.argmin(np.abs(np.asarray(cands) - tf[-1])))
            pl.plot_friction_posterior(
                axes4[p, 0],
                t,
                post_all[:, p, : len(cands)],
                cands,
                highlight=highlight,
                shade=stick,
                shade_label="true sticking" if stick is not None else None,
                title=f"Friction posterior: {name}",
            )
        save(fig, "friction.png")

    if kind == "edge" and arr.friction_map is not None and sc is not None:
        grid = arr.friction_map
        cands = [float(c) for c in sc.friction.candidates[0]]
        lo = float(min(cands))
        fig, ax = plt.subplots(figsize=(8, 3.4))
        p_hi = grid.p_high[0]
        weight = np.where(np.isfinite(p_hi), 1.0, 0.0)
        pl.plot_friction_map(
            ax, grid.edges, 1.0 - p_hi, weight=weight, candidate=lo, title="Final friction map"
        )
        save(fig, "friction_map.png")

    # -- filter health ----------------------------------------------------------------------
    diag = [(s, v) for s, v in arr.diagnostics if "step_time_ms_mean" in v]
    if diag:
        td = np.asarray([(s - t0) / NS for s, _ in diag])
        fig, ax = plt.subplots(figsize=(8, 3.2))
        ax.plot(td, [float(v["step_time_ms_mean"]) for _, v in diag], "o-", label="step time")
        ax.set_xlabel("time [s]")
        ax.set_ylabel("mean step time [ms]")
        ess = [float(v["ess"]) for _, v in diag if "ess" in v]
        if len(ess) == len(diag):
            ax2 = ax.twinx()
            ax2.plot(td, ess, "s--", color="tab:purple", label="ESS")
            ax2.set_ylabel("ESS [particles]")
            ax2.legend(fontsize=7, loc="upper right")
        ax.legend(fontsize=7, loc="upper left")
        ax.set_title("Filter health (/diagnostics)")
        ax.grid(True, alpha=0.3)
        save(fig, "filter_health.png")
    return paths


def _flag_at(arr: BagArrays, stamps: np.ndarray, dt: float) -> np.ndarray | None:
    """The measured contact flag (``/pusher/contact``) at each stamp (False where none is
    within dt/2); None without a flag or when its contacts differ from the estimate's."""
    if arr.flag is None or arr.modes is None or arr.flag.shape[1] != arr.modes.shape[1]:
        return None
    i, j = match_stamps(np.asarray(stamps, dtype=np.int64), arr.flag_t, int(0.5 * dt * NS))
    out = np.zeros((len(stamps), arr.flag.shape[1]), dtype=bool)
    out[i] = arr.flag[j]
    return out
