"""Paper-style figures of DBC-SLAM runs (Figs. 3 and 4 of the paper), written as PNG files.

Every panel function draws on a matplotlib ``Axes`` from plain numpy arrays (SI units: s, m,
rad) so it can be reused by `dbcslam replay` and the experiment driver; ``save_*`` functions
build whole figures from a :class:`dbcslam_core.experiments.RunTrace` and write them to disk.
The non-interactive Agg backend is selected on import; no display is ever needed.
"""

from __future__ import annotations

import io
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

import matplotlib

matplotlib.use("Agg")

import matplotlib.pyplot as plt
import numpy as np
from numpy.typing import ArrayLike, NDArray

from dbcslam_core.angles import wrap_angle

if TYPE_CHECKING:
    from matplotlib.axes import Axes
    from matplotlib.figure import Figure

    from dbcslam_core.experiments import RunTrace

__all__ = [
    "Panel",
    "plot_contact_probability",
    "plot_friction_map",
    "plot_friction_posterior",
    "plot_live_hypotheses",
    "plot_stick_probability",
    "plot_trajectory_xy",
    "plot_value_vs_time",
    "save_edge_figures",
    "save_figure",
    "save_gripper_figures",
    "save_run_figures",
    "shade_mask",
    "write_panels",
]

TRUTH_STYLE: dict[str, Any] = {"color": "tab:blue", "ls": "--", "lw": 1.4, "label": "truth"}
OBS_STYLE: dict[str, Any] = {
    "color": "tab:green",
    "marker": ".",
    "ls": "none",
    "ms": 2.5,
    "alpha": 0.6,
    "label": "observations",
}
EST_STYLE: dict[str, Any] = {"color": "tab:red", "lw": 1.4, "label": "DBC-SLAM estimate"}
BASE_STYLE: dict[str, Any] = {"color": "0.35", "lw": 1.0, "ls": ":", "label": "fixed-friction"}
SHADE: dict[str, Any] = {"color": "0.85", "lw": 0, "zorder": 0}
DPI = 100


def _runs(mask: NDArray[np.bool_]) -> list[tuple[int, int]]:
    """Contiguous [start, stop) index runs where mask is True."""
    m = np.concatenate([[False], np.asarray(mask, dtype=bool), [False]])
    d = np.diff(m.astype(np.int8))
    starts = np.flatnonzero(d == 1)
    stops = np.flatnonzero(d == -1)
    return list(zip(starts.tolist(), stops.tolist(), strict=True))


def shade_mask(ax: Axes, t: ArrayLike, mask: ArrayLike, label: str | None = None) -> None:
    """Shade the time spans (axis x) where ``mask`` is True; spans reach half a step each side."""
    tv = np.asarray(t, dtype=float)
    mv = np.asarray(mask, dtype=bool)
    if tv.size == 0:
        return
    half = 0.5 * (float(np.median(np.diff(tv))) if tv.size > 1 else 1.0)
    for k, (a, b) in enumerate(_runs(mv)):
        ax.axvspan(tv[a] - half, tv[b - 1] + half, label=label if k == 0 else None, **SHADE)


def _shade_intervals(
    ax: Axes, intervals: Sequence[tuple[float, float]], label: str | None, vertical: bool = True
) -> None:
    for k, (a, b) in enumerate(intervals):
        lab = label if k == 0 else None
        if vertical:
            ax.axvspan(a, b, label=lab, **SHADE)
        else:
            ax.axhspan(a, b, label=lab, **SHADE)


def plot_trajectory_xy(
    ax: Axes,
    true_xy: ArrayLike,
    obs_xy: ArrayLike | None,
    est_xy: ArrayLike,
    *,
    rough_x: Sequence[tuple[float, float]] = (),
    edge_y: float | None = None,
    baseline_xy: ArrayLike | None = None,
    baseline_label: str = "fixed-friction baseline",
    title: str = "Trajectory",
) -> None:
    """x-y trajectory: truth (dashed), observations (dots), estimate (solid); rough x shaded."""
    tru = np.asarray(true_xy, dtype=float)
    est = np.asarray(est_xy, dtype=float)
    _shade_intervals(ax, rough_x, "rough region (high friction)")
    if edge_y is not None:
        ax.axhline(edge_y, color="k", lw=1.0, label="edge")
    if obs_xy is not None:
        obs = np.asarray(obs_xy, dtype=float)
        ax.plot(obs[:, 0], obs[:, 1], **OBS_STYLE)
    ax.plot(tru[:, 0], tru[:, 1], **TRUTH_STYLE)
    ax.plot(est[:, 0], est[:, 1], **EST_STYLE)
    if baseline_xy is not None:
        b = np.asarray(baseline_xy, dtype=float)
        ax.plot(b[:, 0], b[:, 1], **{**BASE_STYLE, "label": baseline_label})
    ax.set_xlabel("x [m]")
    ax.set_ylabel("y [m]")
    ax.set_title(title)
    ax.legend(fontsize=7, loc="best")
    ax.grid(True, alpha=0.3)


def plot_value_vs_time(
    ax: Axes,
    t: ArrayLike,
    truth: ArrayLike,
    obs: ArrayLike | None,
    est: ArrayLike,
    *,
    shade: ArrayLike | None = None,
    shade_label: str | None = None,
    ylabel: str = "x [m]",
    title: str = "",
    baseline: ArrayLike | None = None,
    baseline_label: str = "fixed-friction baseline",
) -> None:
    """A scalar (e.g. x or yaw) over time: truth, observations, estimate; optional shaded mask."""
    tv = np.asarray(t, dtype=float)
    if shade is not None:
        shade_mask(ax, tv, shade, shade_label)
    if obs is not None:
        ax.plot(tv, np.asarray(obs, dtype=float), **OBS_STYLE)
    ax.plot(tv, np.asarray(truth, dtype=float), **TRUTH_STYLE)
    ax.plot(tv, np.asarray(est, dtype=float), **EST_STYLE)
    if baseline is not None:
        ax.plot(tv, np.asarray(baseline, dtype=float), **{**BASE_STYLE, "label": baseline_label})
    ax.set_xlabel("time [s]")
    ax.set_ylabel(ylabel)
    ax.set_title(title)
    ax.legend(fontsize=7, loc="best")
    ax.grid(True, alpha=0.3)


def _prob_axes(ax: Axes, title: str, ylabel: str) -> None:
    ax.set_ylim(-0.03, 1.03)
    ax.set_xlabel("time [s]")
    ax.set_ylabel(ylabel)
    ax.set_title(title)
    ax.legend(fontsize=7, loc="best")
    ax.grid(True, alpha=0.3)


def _plot_probability(
    ax: Axes, t: ArrayLike, p: ArrayLike, truth: ArrayLike, *, what: str, title: str
) -> None:
    tv = np.asarray(t, dtype=float)
    shade_mask(ax, tv, truth, f"true {what}")
    ax.plot(tv, np.asarray(p, dtype=float), **{**EST_STYLE, "label": f"P({what})"})
    _prob_axes(ax, title or f"Probability of {what}", f"P({what}) [-]")


def plot_contact_probability(
    ax: Axes, t: ArrayLike, p_contact: ArrayLike, true_contact: ArrayLike, *, title: str = ""
) -> None:
    """P(in contact) over time with the truly-in-contact periods shaded."""
    _plot_probability(ax, t, p_contact, true_contact, what="contact", title=title)


def plot_stick_probability(
    ax: Axes, t: ArrayLike, p_stick: ArrayLike, true_stick: ArrayLike, *, title: str = ""
) -> None:
    """P(sticking) over time with the truly-sticking periods shaded."""
    _plot_probability(ax, t, p_stick, true_stick, what="sticking", title=title)


def plot_friction_posterior(
    ax: Axes,
    t: ArrayLike,
    posterior: ArrayLike,
    candidates: Sequence[float],
    *,
    highlight: int | None = None,
    shade: ArrayLike | None = None,
    shade_label: str | None = None,
    title: str = "",
) -> None:
    """Friction posterior P(mu = candidate) over time, one line per candidate.

    Args:
        posterior: (T, B) posterior of one friction pair.
        highlight: index of the candidate drawn bold (e.g. the true one); others thin.
    """
    tv = np.asarray(t, dtype=float)
    post = np.asarray(posterior, dtype=float)
    if shade is not None:
        shade_mask(ax, tv, shade, shade_label)
    for b, mu in enumerate(candidates):
        bold = highlight is None or b == highlight
        ax.plot(
            tv,
            post[:, b],
            lw=1.6 if bold else 0.9,
            color="tab:red" if (highlight is not None and bold) else None,
            alpha=1.0 if bold else 0.7,
            label=f"P(mu = {mu:g})",
        )
    _prob_axes(ax, title or "Friction posterior", "probability [-]")


def plot_friction_map(
    ax: Axes,
    cell_edges: ArrayLike,
    p_cell: ArrayLike,
    *,
    rough_x: Sequence[tuple[float, float]] = (),
    step_x: ArrayLike | None = None,
    step_p: ArrayLike | None = None,
    weight: ArrayLike | None = None,
    min_weight: float = 0.5,
    candidate: float = 0.3,
    title: str = "",
) -> None:
    """Friction map along the edge: per-cell P(mu = candidate) vs x (like Fig. 3b).

    Args:
        cell_edges: (N + 1,) cell boundaries along the edge (m).
        p_cell: (N,) per-cell probability of the candidate (NaN: never touched).
        step_x, step_p: optional per-step estimated x and instantaneous P(mu = candidate),
            drawn as dots (the paper's Fig. 3b shows these).
        weight: optional (N,) accumulated contact evidence per cell; cells below `min_weight`
            (about half a step in contact) are left blank, and the x axis spans the cells
            above it.
    """
    edges = np.asarray(cell_edges, dtype=float)
    p = np.asarray(p_cell, dtype=float).copy()
    if weight is not None:
        wv = np.asarray(weight, dtype=float)
        p[wv < min_weight] = np.nan
        seen = np.flatnonzero(wv >= min_weight)
        if seen.size:
            lo, hi = edges[seen[0]], edges[seen[-1] + 1]
            pad = 0.1 * (hi - lo) + 1e-9
            ax.set_xlim(lo - pad, hi + pad)
    _shade_intervals(ax, rough_x, "rough region (high friction)")
    if step_x is not None and step_p is not None:
        ax.plot(
            np.asarray(step_x, dtype=float),
            np.asarray(step_p, dtype=float),
            ".",
            ms=2.5,
            color="tab:blue",
            alpha=0.5,
            label="per step (at estimated x)",
        )
    ax.stairs(
        p,
        edges,
        baseline=None,
        color="tab:red",
        lw=1.6,
        label="friction map (per cell)",
    )
    ax.axhline(0.5, color="k", lw=0.6, ls=":")
    ax.set_ylim(-0.03, 1.03)
    ax.set_xlabel("x along the edge [m]")
    ax.set_ylabel(f"P(mu = {candidate:g}) [-]")
    ax.set_title(title or f"Friction map: P(mu = {candidate:g}) along the edge")
    ax.legend(fontsize=7, loc="best")
    ax.grid(True, alpha=0.3)


def plot_live_hypotheses(
    ax: Axes, t: ArrayLike, live: ArrayLike, *, total: int | None = None, title: str = ""
) -> None:
    """Mean number of live joint contact-mode hypotheses per particle over time."""
    tv = np.asarray(t, dtype=float)
    ax.plot(
        tv,
        np.asarray(live, dtype=float),
        color="tab:purple",
        lw=1.2,
        label="live hypotheses / particle",
    )
    ax.set_xlabel("time [s]")
    ax.set_ylabel("hypotheses [-]")
    ttl = title or "Live mode hypotheses per particle"
    if total is not None:
        ttl += f" (of {total})"
    ax.set_title(ttl)
    ax.set_yscale("log")
    ax.legend(fontsize=7, loc="best")
    ax.grid(True, alpha=0.3, which="both")


def save_figure(fig: Figure, path: Path) -> Path:
    """Write `fig` as a PNG at ``DPI`` with a 256-colour palette (about a third of the RGBA
    size; the plots use few colours, so nothing visible is lost)."""
    from PIL import Image

    fig.tight_layout()
    buf = io.BytesIO()
    fig.savefig(buf, dpi=DPI, format="png")
    plt.close(fig)
    buf.seek(0)
    with Image.open(buf) as im:
        pal = im.convert("RGB").quantize(
            colors=256, method=Image.Quantize.MEDIANCUT, dither=Image.Dither.NONE
        )
        pal.save(path, format="PNG", optimize=True)
    return path


def _edge_trajectory(ax: Axes, tr: RunTrace) -> None:
    base = tr.baseline_q
    plot_trajectory_xy(
        ax,
        tr.true_q[:, :2],
        tr.obs_q[:, :2],
        tr.est_q[:, :2],
        rough_x=list(tr.rough_intervals),
        edge_y=tr.edge_y,
        baseline_xy=None if base is None else base[:, :2],
        baseline_label=tr.baseline_label,
        title=f"Edge: point-mass trajectory (seed {tr.seed})",
    )


def _edge_x_time(ax: Axes, tr: RunTrace) -> None:
    base = tr.baseline_q
    plot_value_vs_time(
        ax,
        tr.t,
        tr.true_q[:, 0],
        tr.obs_q[:, 0],
        tr.est_q[:, 0],
        shade=tr.true_modes[:, 0] == 1,
        shade_label="true sticking",
        ylabel="x [m]",
        title="Edge: x over time (true sticking shaded)",
        baseline=None if base is None else base[:, 0],
        baseline_label=tr.baseline_label,
    )


def _edge_contact(ax: Axes, tr: RunTrace) -> None:
    plot_contact_probability(
        ax,
        tr.t,
        1.0 - tr.est_modes[:, 0, 0],
        tr.true_modes[:, 0] != 0,
        title="Edge: P(contact) (true contact shaded)",
    )


def _edge_sticking(ax: Axes, tr: RunTrace) -> None:
    p_stick = tr.est_modes[:, 0, 1] / np.maximum(1.0 - tr.est_modes[:, 0, 0], 1e-12)
    plot_stick_probability(
        ax,
        tr.t,
        np.clip(p_stick, 0.0, 1.0),
        tr.true_modes[:, 0] == 1,
        title="Edge: P(sticking | contact) (true sticking shaded)",
    )


def _edge_friction_time(ax: Axes, tr: RunTrace) -> None:
    low = int(np.argmin(tr.candidates))
    in_rough = np.zeros(tr.t.size, dtype=bool)
    for a, b in tr.rough_intervals:
        in_rough |= (tr.true_q[:, 0] >= a) & (tr.true_q[:, 0] <= b)
    plot_friction_posterior(
        ax,
        tr.t,
        tr.friction_post,
        tr.candidates,
        highlight=low,
        shade=in_rough & (tr.true_modes[:, 0] != 0),
        shade_label="contact in rough region",
        title="Edge: friction posterior over time",
    )


def _edge_friction_map(ax: Axes, tr: RunTrace) -> None:
    if tr.map_edges is None or tr.map_post is None:
        ax.set_axis_off()
        return
    low = int(np.argmin(tr.candidates))
    true_contact = tr.true_modes[:, 0] != 0
    plot_friction_map(
        ax,
        tr.map_edges,
        tr.map_post[:, low],
        rough_x=list(tr.rough_intervals),
        step_x=tr.est_q[true_contact, 0],
        step_p=tr.friction_post[true_contact, low],
        weight=tr.map_weight,
        candidate=float(tr.candidates[low]),
    )


def _gripper_com(ax: Axes, tr: RunTrace) -> None:
    plot_trajectory_xy(
        ax,
        tr.true_q[:, :2],
        tr.obs_q[:, :2],
        tr.est_q[:, :2],
        title=f"Gripper: centre-of-mass trajectory (seed {tr.seed})",
    )


def _gripper_yaw(ax: Axes, tr: RunTrace) -> None:
    yaw_true = np.unwrap(tr.true_q[:, 2])
    plot_value_vs_time(
        ax,
        tr.t,
        yaw_true,
        yaw_true + wrap_angle(tr.obs_q[:, 2] - yaw_true),
        yaw_true + wrap_angle(tr.est_q[:, 2] - yaw_true),
        ylabel="yaw (unwrapped) [rad]",
        title="Gripper: orientation over time",
    )


def _gripper_friction(ax: Axes, tr: RunTrace) -> None:
    ti = tr.true_friction_index
    if ti < 0:
        ax.set_axis_off()
        return
    mu = float(tr.candidates[ti])
    shade_mask(ax, tr.t, np.any(tr.true_modes != 0, axis=1), "true contact (any)")
    ax.plot(tr.t, tr.friction_post[:, ti], **{**EST_STYLE, "label": f"P(mu = {mu:g})"})
    _prob_axes(ax, f"Gripper: probability of the true friction mu = {mu:g}", "probability [-]")


def _gripper_hypotheses(ax: Axes, tr: RunTrace) -> None:
    if tr.live_hypotheses is None:
        ax.set_axis_off()
        return
    plot_live_hypotheses(ax, tr.t, tr.live_hypotheses, total=tr.n_joint_modes)


_Panel = Callable[["Axes", "RunTrace"], None]
Panel = Callable[["Axes"], None]
"""A panel: draws on one matplotlib Axes."""


def write_panels(
    out_dir: Path | str,
    singles: Sequence[tuple[str, tuple[float, float], Sequence[Panel]]],
    overview: tuple[str, int, int, Sequence[Panel]] | None = None,
) -> list[Path]:
    """Write one PNG per `singles` entry (file name, (width, height) in inches, panels drawn
    side by side) and, if given, an overview (file name, rows, cols, panels; unused axes
    hidden, 5.2 x 3.6 in per panel) into `out_dir` via :func:`save_figure`; returns the paths."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    paths: list[Path] = []
    for name, size, panels in singles:
        fig, axs = plt.subplots(1, len(panels), figsize=size, squeeze=False)
        for ax, draw in zip(axs[0], panels, strict=True):
            draw(ax)
        paths.append(save_figure(fig, out / name))
    if overview is not None:
        name, rows, cols, panels = overview
        fig, axs = plt.subplots(rows, cols, figsize=(5.2 * cols, 3.6 * rows), squeeze=False)
        flat = list(axs.ravel())
        for ax, draw in zip(flat, panels, strict=False):
            draw(ax)
        for ax in flat[len(panels) :]:
            ax.set_axis_off()
        paths.append(save_figure(fig, out / name))
    return paths


def _bound(draw: _Panel, tr: RunTrace) -> Panel:
    def panel(ax: Axes) -> None:
        draw(ax, tr)

    return panel


def _write_panels(
    tr: RunTrace,
    out: Path,
    singles: Sequence[tuple[str, tuple[float, float], Sequence[_Panel]]],
    overview: tuple[str, int, int, Sequence[_Panel]],
) -> list[Path]:
    def bind(panels: Sequence[_Panel]) -> list[Panel]:
        return [_bound(draw, tr) for draw in panels]

    name, rows, cols, panels = overview
    return write_panels(
        out, [(n, size, bind(p)) for n, size, p in singles], (name, rows, cols, bind(panels))
    )


def save_edge_figures(trace: RunTrace, out_dir: Path | str, prefix: str = "edge") -> list[Path]:
    """Write the edge (table polishing, Fig. 3) figures of one run; returns the PNG paths.

    Files: ``{prefix}_trajectory.png`` (x-y, rough region shaded), ``{prefix}_x_time.png``
    (x vs time, true sticking shaded), ``{prefix}_contact.png`` (P(contact), true contact
    shaded), ``{prefix}_sticking.png`` (P(sticking | contact), true sticking shaded),
    ``{prefix}_friction.png`` (friction posterior over time and the friction map along the
    edge) and ``{prefix}_overview.png`` (all panels).
    """
    singles: list[tuple[str, tuple[float, float], Sequence[_Panel]]] = [
        (f"{prefix}_trajectory.png", (6.5, 3.8), [_edge_trajectory]),
        (f"{prefix}_x_time.png", (6.0, 3.6), [_edge_x_time]),
        (f"{prefix}_contact.png", (6.0, 3.6), [_edge_contact]),
        (f"{prefix}_sticking.png", (6.0, 3.6), [_edge_sticking]),
        (f"{prefix}_friction.png", (11.0, 3.6), [_edge_friction_time, _edge_friction_map]),
    ]
    panels: list[_Panel] = [
        _edge_trajectory,
        _edge_x_time,
        _edge_friction_map,
        _edge_contact,
        _edge_sticking,
        _edge_friction_time,
    ]
    return _write_panels(trace, Path(out_dir), singles, (f"{prefix}_overview.png", 2, 3, panels))


def save_gripper_figures(
    trace: RunTrace, out_dir: Path | str, prefix: str = "gripper"
) -> list[Path]:
    """Write the gripper figures of one run (Fig. 4); returns the PNG paths.

    Files: ``{prefix}_com.png`` (centre-of-mass trajectory), ``{prefix}_yaw.png`` (yaw vs
    time), ``{prefix}_friction.png`` (P(true mu) vs time), ``{prefix}_hypotheses.png`` (live
    hypotheses per particle) and ``{prefix}_overview.png`` (all panels).
    """
    singles: list[tuple[str, tuple[float, float], Sequence[_Panel]]] = [
        (f"{prefix}_com.png", (5.0, 4.2), [_gripper_com]),
        (f"{prefix}_yaw.png", (6.0, 3.6), [_gripper_yaw]),
        (f"{prefix}_friction.png", (6.0, 3.6), [_gripper_friction]),
        (f"{prefix}_hypotheses.png", (6.0, 3.6), [_gripper_hypotheses]),
    ]
    panels: list[_Panel] = [_gripper_com, _gripper_yaw, _gripper_friction, _gripper_hypotheses]
    return _write_panels(trace, Path(out_dir), singles, (f"{prefix}_overview.png", 2, 2, panels))


def save_run_figures(trace: RunTrace, out_dir: Path | str) -> list[Path]:
    """Dispatch on ``trace.scenario`` (``edge`` or ``gripper``)."""
    if trace.scenario == "edge":
        return save_edge_figures(trace, out_dir)
    return save_gripper_figures(trace, out_dir)
