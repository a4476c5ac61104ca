"""The filter on measured MIT pushes: import, replay, evaluate, tabulate (issue "Measured data").

``python -m dbcslam_research.mitpush_eval [--data DIR] [--out DIR] [--particles N] [--jobs 2]``

1. Imports every push file of the data (``--data``: the dataset root, whose ``abs/train`` split
   is used when present, or any directory/file of ``.h5`` pushes; default the shared copy
   ``../shared/data/mit-push`` next to the repository) with Gaussian noise added to the
   observed pose (``--noise-position`` 5 mm, ``--noise-yaw`` 0.05 rad, ``--seed``) into
   bags (:mod:`dbcslam_ros.importers.mitpush_bag`; a temporary directory, or
   ``--work DIR`` to keep them and the replays). Friction candidates: pusher 0.1 0.2 0.3 (the
   importer's), surface :data:`SURFACE_CANDIDATES` 0.2-0.5 (from the training pushes' F/T,
   see there); ``--pusher-candidates`` / ``--surface-candidates`` override them.
2. Replays each bag with the filter node's code (:func:`dbcslam_ros.offline.replay.replay_bag`,
   ``--particles``, markers off) in ``--jobs`` worker processes.
3. Evaluates each replay (:func:`dbcslam_ros.offline.evaluate.evaluate_bag`): position and yaw RMSE
   against the clean (aligned Vicon) pose, also as a multiple of the *added* noise std;
   agreement of "P(pusher not separated) > 0.5" with the measured contact flag
   (``/pusher/contact``: F/T force magnitude > 0.25 N, geometric for the ``rect1`` files
   whose F/T stream is stale); final friction posteriors (pusher, surface) and their means.
   A diagnostic column (not the target) scores the readout "P(not separated) > 0.5 or the
   pusher within 1 mm of the estimated outline" (``contact_flag_agreement_touch``).
4. Writes into ``--out`` (default ``dbcslam_ros/research/results/mitpush/``): ``mitpush.md``
   (table per shape and overall: medians over pushes, PASS/FAIL vs the targets),
   ``mitpush.json`` (the same plus every push's metrics) and ``mitpush_<shape>.png``
   (the push with the median contact agreement: trajectory vs Vicon, P(contact) vs the flag
   and the F/T force magnitude; agreement and RMSE of every push of the shape).

Targets (issue "Measured data"), medians over the pushes: pose RMSE <= 0.6 x added noise
(position and yaw each), contact/no-contact agreement with the F/T flag >= 0.9.

``--reuse`` re-evaluates the replays an earlier run left in ``--work`` (seconds, no filter).
The filter node's parameters go through ``-p NAME=VALUE`` (e.g. ``-p use_pusher_wrench=false``
for the kinematics-only baseline). Runtime: ~5.5 min wall for the 50 pushes (8461 steps)
at 300 particles with 2 workers on the shared 2-core machine (07:4x UTC, 2026-11-21).

API: :func:`run_eval` (:class:`EvalOptions`) returns the summary dict written as JSON;
:func:`summarise` and :func:`markdown_table` turn per-push metrics into the table.
"""

from __future__ import annotations

import argparse
import contextlib
import json
import math
import multiprocessing as mp
import os
import sys
import tempfile
import time
from collections.abc import Iterator, Sequence
from concurrent.futures import ProcessPoolExecutor, as_completed
from dataclasses import dataclass
from pathlib import Path
from typing import IO, TYPE_CHECKING, Any

import numpy as np

from dbcslam_ros.errors import UsageError

if TYPE_CHECKING:
    from dbcslam_ros.offline.evaluate import BagArrays

__all__ = [
    "DEFAULT_DATA",
    "DEFAULT_OUT",
    "SURFACE_CANDIDATES",
    "TARGET_CONTACT_AGREEMENT",
    "TARGET_RMSE_OVER_NOISE",
    "EvalOptions",
    "filter_uses_pusher_wrench",
    "main",
    "markdown_table",
    "resolve_data",
    "run_eval",
    "select_shapes",
    "summarise",
]

_REPO = Path(__file__).resolve().parents[3]  # dbcslam_ros/research/dbcslam_research/<this>
#: Default data location: the shared dataset copy next to the repository.
DEFAULT_DATA = _REPO.parent / "shared" / "data" / "mit-push"
#: Default output directory of the table and figures.
DEFAULT_OUT = Path("dbcslam_ros/research/results/mitpush")  # relative to the working directory
#: Target: median pose RMSE (position and yaw) as a multiple of the added noise std.
TARGET_RMSE_OVER_NOISE = 0.6
#: Target: median contact/no-contact agreement with the measured flag.
TARGET_CONTACT_AGREEMENT = 0.9
#: Object-surface friction candidates of the evaluation. The F/T force of the training
#: pushes says mu_surface = |F| / (m g) while the object moves (quasi-static pushing needs
#: |F| <= mu m g, so this is a lower bound): median 0.34 (ellip1), 0.42 (ellip3), 0.45 (hex),
#: range 0.26-0.58 over the 37 pushes with a live F/T stream, above the importer's default
#: candidates (0.1 0.2 0.3). With those (same filter, 300 particles) the force likelihood
#: pins mu = 0.3, the median contact agreement drops from 0.788 to 0.702 and the yaw RMSE
#: rises from 0.45 to 0.60 x noise (1.16 x on the pushes with F/T).
SURFACE_CANDIDATES: tuple[float, ...] = (0.2, 0.3, 0.4, 0.5)


def _portable(path: Path) -> str:
    """`path` as written into reports: relative to the working directory (no machine paths)."""
    try:
        return os.path.relpath(Path(path).resolve(), Path.cwd())
    except ValueError:  # another drive (Windows)
        return str(path)


@dataclass(frozen=True)
class EvalOptions:
    """Settings of one evaluation run.

    data: dataset root (``abs/train`` is used when present) or a directory/file of pushes.
    out: output directory of the table and figures. work: directory for the bags and replays
    (None: a temporary directory, deleted afterwards). particles: filter particles.
    jobs: worker processes (1: in this process). noise_position / noise_yaw: added noise std
    (m, rad). seed: noise seed (per file combined with its name) and filter seed.
    figures: write the per-shape figures. progress: stream of the progress lines.
    params: further filter node parameters. pusher_candidates / surface_candidates: friction
    candidates written to the scenarios (None: the importer's defaults, 0.1 0.2 0.3; the
    surface default here is :data:`SURFACE_CANDIDATES`). reuse: re-evaluate
    the replays already in ``work`` (a previous run's) instead of importing and replaying.
    push_model: the scenarios' ``surface.model`` (None: the importer's default,
    :data:`dbcslam_ros.importers.mitpush.DEFAULT_PUSH_MODEL`). every: evaluate every N-th push file
    (sorted by name; the alignment is still fitted on every file of the shape's directory).
    shapes: evaluate only the pushes of these shapes (None: all).
    """

    data: Path = DEFAULT_DATA
    out: Path = DEFAULT_OUT
    work: Path | None = None
    particles: int = 300
    jobs: int = 2
    noise_position: float = 0.005
    noise_yaw: float = 0.05
    seed: int = 0
    figures: bool = True
    progress: IO[str] | None = None
    params: tuple[tuple[str, Any], ...] = ()
    pusher_candidates: tuple[float, ...] | None = None
    surface_candidates: tuple[float, ...] | None = SURFACE_CANDIDATES
    reuse: bool = False
    push_model: str | None = None
    every: int = 1
    shapes: tuple[str, ...] | None = None


def select_shapes(files: Sequence[Path], shapes: Sequence[str] | None) -> list[Path]:
    """The push files of `shapes` (all when None), in the given order.

    Raises:
        UsageError: a shape without any push file among `files`.
    """
    from dbcslam_ros.importers.mitpush import parse_push_name

    if shapes is None:
        return list(files)
    found = {f: parse_push_name(f).shape for f in files}
    missing = sorted(set(shapes) - set(found.values()))
    if missing:
        msg = (
            f"no push files of shape(s) {missing}; shapes in the data: "
            f"{sorted(set(found.values()))}"
        )
        raise UsageError(msg)
    return [f for f in files if found[f] in shapes]


def resolve_data(data: str | Path) -> list[Path]:
    """The push files of ``data``: ``data/abs/train`` if it exists, else every ``.h5`` in
    ``data`` (recursively) or ``data`` itself.

    Raises:
        UsageError: no such path or no push file in it.
    """
    from dbcslam_ros.importers.mitpush import MitPushError, push_files

    root = Path(data)
    if not root.exists():
        msg = (
            f"MIT push data not found at {root}; pass --data DIR (the dataset root holding "
            "abs/train and shapes/, or a directory of .h5 push files)"
        )
        raise UsageError(msg)
    split = root / "abs" / "train"
    try:
        files = push_files([split if split.is_dir() else root])
    except MitPushError as err:
        msg = f"{root}: no .h5 push files found ({err})"
        raise UsageError(msg) from err
    if not files:
        msg = f"{root}: no .h5 push files found"
        raise UsageError(msg)
    return files


def filter_uses_pusher_wrench(params: dict[str, Any] | None = None) -> bool:
    """True when the filter node with these parameters uses ``/pusher/wrench`` as a force
    observation (it subscribes to it and its ``use_pusher_wrench`` parameter is on)."""
    from dbcslam_ros.contract import INPUT_TOPICS, PUSHER_WRENCH
    from dbcslam_ros.node.params import coerce_params

    return PUSHER_WRENCH in INPUT_TOPICS and bool(coerce_params(params or {})["use_pusher_wrench"])


def _import(files: list[Path], bags_dir: Path, opts: EvalOptions) -> list[dict[str, Any]]:
    """Import every file into ``bags_dir``; per push: name, shape, bag path, contact source."""
    from dbcslam_ros.importers.mitpush import (
        Outline,
        find_shapes_dir,
        load_outline,
        load_push,
        resample_push,
    )
    from dbcslam_ros.importers.mitpush_bag import write_push_bag

    config = _import_config(opts)
    outlines: dict[tuple[str, Path], Outline] = {}
    pushes: list[dict[str, Any]] = []
    for f in files:
        raw = load_push(f)
        shapes = find_shapes_dir(f)
        if shapes is None:
            msg = f"{f}: no 'shapes' directory with the outline of {raw.info.shape!r} above it"
            raise UsageError(msg)
        key = (raw.info.shape, shapes)
        if key not in outlines:
            outlines[key] = load_outline(raw.info.shape, shapes)
        series = resample_push(raw, outlines[key], config)
        bag = bags_dir / f.name.removesuffix(".h5")
        write_push_bag(series, config, bag, overwrite=True)
        pushes.append(
            {
                "name": f.name.removesuffix(".h5"),
                "shape": raw.info.shape,
                "bag": str(bag),
                "steps": len(series),
                "contact_source": series.contact_source,
            }
        )
    return pushes


def _import_config(opts: EvalOptions) -> Any:
    from dbcslam_ros.importers.mitpush import ImportConfig

    cands: dict[str, Any] = {}
    if opts.pusher_candidates is not None:
        cands["pusher_candidates"] = tuple(opts.pusher_candidates)
    if opts.surface_candidates is not None:
        cands["surface_candidates"] = tuple(opts.surface_candidates)
    if opts.push_model is not None:
        cands["push_model"] = opts.push_model
    return ImportConfig(
        noise_position=opts.noise_position, noise_yaw=opts.noise_yaw, seed=opts.seed, **cands
    )


def _candidates(pushes: list[dict[str, Any]], pair: str) -> list[float] | None:
    """Friction candidates of ``pair`` in the evaluated scenarios (None if absent)."""
    for entry in pushes[0]["metrics"].get("friction", []) if pushes else []:
        if entry.get("pair") == pair:
            return [float(c) for c in entry["candidates"]]
    return None


def _replayed_by(work: Path) -> dict[str, Any] | None:
    """Command, wall time and jobs of the run that made the replays in ``work``."""
    try:
        data = json.loads((work / "run.json").read_text())
    except (OSError, ValueError):
        return None
    return data if isinstance(data, dict) else None


def _reevaluate(bags_dir: Path, replays_dir: Path) -> list[dict[str, Any]]:
    """Pushes of an earlier run (its imported bags and replays), evaluated again."""
    from dbcslam_ros.bag.metadata import load_metadata
    from dbcslam_ros.offline.evaluate import evaluate_bag

    pushes: list[dict[str, Any]] = []
    for rep in sorted(d for d in replays_dir.iterdir() if (d / "metrics.json").exists()):
        meta = load_metadata(bags_dir / rep.name / "metadata.yaml")
        old = json.loads((rep / "metrics.json").read_text())
        metrics = evaluate_bag(rep)
        metrics["replay"] = old.get("replay", {})
        pushes.append(
            {
                "name": rep.name,
                "shape": meta.custom_data.get("shape", "?"),
                "bag": str(bags_dir / rep.name),
                "steps": int(metrics["observations"]),
                "contact_source": meta.custom_data.get("contact_source", "?"),
                "replay": str(rep),
                "metrics": metrics,
            }
        )
    if not pushes:
        msg = f"{replays_dir}: no replays to re-evaluate (run without --reuse first)"
        raise UsageError(msg)
    return pushes


def _replay_one(bag: str, out: str, params: dict[str, Any]) -> dict[str, Any]:
    """Worker: replay one bag; its metrics (evaluate's dict incl. the replay summary)."""
    from dbcslam_ros.offline.replay import ReplayOptions, replay_bag

    res = replay_bag(bag, out, ReplayOptions(params=params, plots=False, overwrite=True))
    return res.metrics


def _num(v: Any) -> float:
    return float(v) if isinstance(v, (int, float)) and math.isfinite(float(v)) else math.nan


def _median(values: Sequence[float]) -> float | None:
    arr = np.asarray([v for v in values if math.isfinite(v)], dtype=np.float64)
    return round(float(np.median(arr)), 6) if arr.size else None


def _group_summary(rows: list[dict[str, Any]]) -> dict[str, Any]:
    """Medians (and friction posterior averages) over the pushes of ``rows``."""
    out: dict[str, Any] = {"pushes": len(rows)}
    keys = (
        "position_rmse_m",
        "position_rmse_over_noise",
        "yaw_rmse_rad",
        "yaw_rmse_over_noise",
        "observation_rmse_m",
        "contact_flag_agreement",
        "contact_flag_agreement_touch",
        "contact_flag_recall",
        "contact_flag_specificity",
        "contact_flag_in_contact_fraction",
        "contact_estimated_in_contact_fraction",
        "steps_per_s",
    )
    for key in keys:
        out[key] = _median([_num(r["metrics"].get(key)) for r in rows])
    friction: dict[str, Any] = {}
    for r in rows:
        for entry in r["metrics"].get("friction", []):
            f = friction.setdefault(
                entry["pair"], {"candidates": entry["candidates"], "post": [], "mean": []}
            )
            f["post"].append([_num(v) for v in entry["final_posterior"]])
            f["mean"].append(_num(entry.get("posterior_mean")))
    out["friction"] = {
        pair: {
            "candidates": f["candidates"],
            "final_posterior_average": [
                round(float(v), 4) for v in np.nanmean(np.asarray(f["post"]), axis=0)
            ],
            "posterior_mean_median": _median(f["mean"]),
            "posterior_mean_range": [
                round(float(np.nanmin(f["mean"])), 4),
                round(float(np.nanmax(f["mean"])), 4),
            ],
        }
        for pair, f in friction.items()
    }
    # tracking failures the medians hide: pose RMSE above the added noise (position or yaw)
    out["pushes_over_noise"] = sum(
        1
        for r in rows
        if not (
            _num(r["metrics"].get("position_rmse_over_noise")) <= 1.0
            and _num(r["metrics"].get("yaw_rmse_over_noise")) <= 1.0
        )
    )
    pos = out["position_rmse_over_noise"]
    yaw = out["yaw_rmse_over_noise"]
    agree = out["contact_flag_agreement"]
    out["pass_pose"] = bool(
        pos is not None
        and yaw is not None
        and pos <= TARGET_RMSE_OVER_NOISE
        and yaw <= TARGET_RMSE_OVER_NOISE
    )
    out["pass_contact"] = bool(agree is not None and agree >= TARGET_CONTACT_AGREEMENT)
    return out


def summarise(pushes: list[dict[str, Any]]) -> dict[str, Any]:
    """Per-shape and overall medians of per-push results (``{"shape", "contact_source",
    "metrics"}``); ``ft_flag`` covers the pushes whose flag comes from the F/T sensor."""
    shapes = sorted({p["shape"] for p in pushes})
    groups: dict[str, Any] = {
        s: _group_summary([p for p in pushes if p["shape"] == s]) for s in shapes
    }
    ft = [p for p in pushes if p.get("contact_source") == "ft"]
    if ft and len(ft) < len(pushes):
        groups["ft_flag"] = _group_summary(ft)
    groups["overall"] = _group_summary(pushes)
    return groups


def _fmt(v: Any, spec: str) -> str:
    return "n/a" if v is None else format(v, spec)


def markdown_table(summary: dict[str, Any]) -> str:
    """The Markdown table of :func:`run_eval`'s summary (medians over pushes)."""
    groups = summary["groups"]
    lines = [
        "| group | pushes (> 1 x noise) | pos RMSE (mm) | pos / noise | yaw RMSE (rad) "
        "| yaw / noise "
        "| contact agreement | recall / specificity | flag / est. in contact "
        "| (diag.) touch readout agreement "
        "| mu pusher: avg final posterior (mean) | mu surface: avg final posterior (mean) "
        "| pose | contact |",
        "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for name, g in groups.items():
        fr = []
        for pair in ("pusher", "surface"):
            f = g["friction"].get(pair)
            if f is None:
                fr.append("n/a")
                continue
            post = ", ".join(
                f"{c:g}: {p:.2f}"
                for c, p in zip(f["candidates"], f["final_posterior_average"], strict=False)
            )
            fr.append(f"{post} ({_fmt(f['posterior_mean_median'], '.3f')})")
        pos_mm = g["position_rmse_m"]
        lines.append(
            f"| {name} | {g['pushes']} ({g.get('pushes_over_noise', 'n/a')})"
            f" | {_fmt(None if pos_mm is None else 1000 * pos_mm, '.2f')}"
            f" | {_fmt(g['position_rmse_over_noise'], '.3f')}"
            f" | {_fmt(g['yaw_rmse_rad'], '.4f')} | {_fmt(g['yaw_rmse_over_noise'], '.3f')}"
            f" | {_fmt(g['contact_flag_agreement'], '.3f')}"
            f" | {_fmt(g['contact_flag_recall'], '.2f')} / "
            f"{_fmt(g['contact_flag_specificity'], '.2f')}"
            f" | {_fmt(g['contact_flag_in_contact_fraction'], '.2f')} / "
            f"{_fmt(g['contact_estimated_in_contact_fraction'], '.2f')}"
            f" | {_fmt(g['contact_flag_agreement_touch'], '.3f')}"
            f" | {fr[0]} | {fr[1]}"
            f" | {'PASS' if g['pass_pose'] else 'FAIL'}"
            f" | {'PASS' if g['pass_contact'] else 'FAIL'} |"
        )
    return "\n".join(lines)


def _provenance(s: dict[str, Any]) -> str:
    if not s.get("reused_work"):
        return f"wall time {s['wall_s']:.0f} s on {s['jobs']} worker(s)."
    by = s.get("replayed_by") or {}
    text = f"re-evaluated the replays in `{s['reused_work']}`"
    if by:
        text += (
            f", made by `{by.get('command', '?')}` (wall time {by.get('wall_s', '?')} s on "
            f"{by.get('jobs', '?')} worker(s))"
        )
    return text + "."


def _markdown(summary: dict[str, Any]) -> str:
    s = summary["settings"]
    return "\n".join(
        [
            "# DBC-SLAM filter on measured MIT pushes",
            "",
            f"Command: `{s['command']}`  ",
            f"Data: {s['pushes']} push files from `{s['data']}`; added observation noise "
            f"{1000 * s['noise_position']:g} mm / {s['noise_yaw']:g} rad (seed {s['seed']}); "
            f"friction candidates pusher {s['pusher_candidates']}, surface "
            f"{s['surface_candidates']}; "
            f"{s['particles']} particles; filter uses /pusher/wrench: "
            f"{'yes' if s['filter_uses_pusher_wrench'] else 'no'}; " + _provenance(s),
            "",
            "Medians over the pushes of each group. Pose RMSE against the aligned Vicon pose "
            "(`/truth/object/pose`), also divided by the added noise std. Contact agreement: "
            "fraction of steps where P(pusher not separated) > 0.5 equals the measured flag "
            "(F/T force magnitude > 0.25 N; geometric for rect1, whose F/T stream is stale; "
            "`ft_flag` = the pushes with an F/T flag). The geometric flag is a touching flag "
            "(tip within 1 mm of the outline, after the push's own offset): where both exist "
            "it agrees with the F/T flag on 0.925 of the steps (median over the 37 F/T pushes; "
            "1.00 while the object moves, 0.74 at rest), with specificity 0, so on rect1 it "
            "also counts resting touches that carry no measurable force, which a filter "
            "without a force reading cannot see. In brackets after the number of pushes: how "
            "many have a position or yaw RMSE above the added noise (tracking failures the "
            "medians hide). Recall = agreement on flagged-contact "
            "steps, specificity = on flagged-separated steps. Friction: final posterior "
            "averaged over the pushes (median of the posterior mean). Diagnostic column "
            "(not the target metric): agreement of the readout 'P(not separated) > 0.5 or "
            "pusher within 1 mm of the estimated outline', which counts a pusher resting "
            "against the object at zero model force as contact.",
            "",
            f"Targets: pose RMSE <= {TARGET_RMSE_OVER_NOISE} x added noise (position and yaw); "
            f"contact agreement >= {TARGET_CONTACT_AGREEMENT}.",
            "",
            markdown_table(summary),
            "",
        ]
    )


def _figure(shape: str, rows: list[dict[str, Any]], path: Path) -> Path:
    """One shape: the push with the median contact agreement in detail, all pushes summarised."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from dbcslam_ros.offline.evaluate import load_bag_arrays

    agree = np.asarray([_num(r["metrics"].get("contact_flag_agreement")) for r in rows])
    pick = _median_push(rows, agree)
    arr = load_bag_arrays(pick["replay"])
    fig, axes = plt.subplots(1, 3, figsize=(15, 4.4))
    _trajectory_panel(axes[0], arr, shape, pick)
    _contact_panel(axes[1], arr, pick)
    _pushes_panel(axes[2], shape, rows, agree)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def _median_push(rows: list[dict[str, Any]], agree: np.ndarray) -> dict[str, Any]:
    """The push with the median contact agreement (those without one sort last)."""
    order = np.argsort(np.where(np.isfinite(agree), agree, np.inf))
    return rows[int(order[(int(np.isfinite(agree).sum()) or 1) // 2])]


def _trajectory_panel(ax: Any, arr: BagArrays, shape: str, pick: dict[str, Any]) -> None:
    """Observed, Vicon and estimated x-y path of one push (mm), its RMSE in the title."""
    ax.plot(
        1000 * arr.obs_pose[:, 0],
        1000 * arr.obs_pose[:, 1],
        ".",
        ms=2,
        color="0.7",
        label="observed (Vicon + noise)",
    )
    ax.plot(1000 * arr.truth_pose[:, 0], 1000 * arr.truth_pose[:, 1], "k-", lw=2, label="Vicon")
    ax.plot(
        1000 * arr.est_pose[:, 0],
        1000 * arr.est_pose[:, 1],
        "-",
        color="tab:red",
        label="estimate",
    )
    ax.set_xlabel("x (mm)")
    ax.set_ylabel("y (mm)")
    ax.set_aspect("equal", adjustable="datalim")
    ax.legend(fontsize=7)
    m = pick["metrics"]
    ax.set_title(
        f"{shape}: {pick['name'].split('shape=')[-1]}\npos RMSE "
        f"{_fmt(m.get('position_rmse_over_noise'), '.2f')}"
        f" x noise, yaw {_fmt(m.get('yaw_rmse_over_noise'), '.2f')} x noise",
        fontsize=8,
    )


def _contact_panel(ax: Any, arr: BagArrays, pick: dict[str, Any]) -> None:
    """P(pusher in contact) over time against the measured flag, |F| and the Vicon speed
    (each scaled to its maximum)."""
    from dbcslam_ros.offline.evaluate import NS

    t0 = arr.t0
    if arr.modes is not None:
        ax.plot(
            (arr.est_t - t0) / NS,
            1.0 - arr.modes[:, 0, 0],
            color="tab:red",
            label="P(pusher in contact)",
        )
    if arr.flag is not None:
        ax.fill_between(
            (arr.flag_t - t0) / NS,
            0,
            arr.flag[:, 0].astype(float),
            step="mid",
            color="tab:green",
            alpha=0.25,
            label=f"flag ({pick['contact_source']})",
        )
    if arr.force.size:
        fmag = np.hypot(arr.force[:, 0], arr.force[:, 1])
        scale = max(float(fmag.max()), 1e-9)
        ax.plot(
            (arr.force_t - t0) / NS,
            fmag / scale,
            color="tab:blue",
            lw=0.8,
            label=f"|F| / {scale:.2f} N",
        )
    if arr.truth_t.size > 2:
        tt = (arr.truth_t - t0) / NS
        speed = np.linalg.norm(np.gradient(arr.truth_pose[:, :2], tt, axis=0), axis=1)
        vmax = max(float(speed.max()), 1e-9)
        ax.plot(
            tt,
            speed / vmax,
            color="0.3",
            lw=0.8,
            ls=":",
            label=f"Vicon speed / {1000 * vmax:.0f} mm/s",
        )
    ax.axhline(0.5, color="0.5", lw=0.5, ls="--")
    ax.set_ylim(-0.02, 1.05)
    ax.set_xlabel("t (s)")
    agreement = _fmt(pick["metrics"].get("contact_flag_agreement"), ".3f")
    ax.set_title(f"contact agreement {agreement}", fontsize=8)
    ax.legend(fontsize=7)


def _pushes_panel(ax: Any, shape: str, rows: list[dict[str, Any]], agree: np.ndarray) -> None:
    """Contact agreement and pose RMSE / noise of every push of the shape, targets dashed."""
    pos = np.asarray([_num(r["metrics"].get("position_rmse_over_noise")) for r in rows])
    yaw = np.asarray([_num(r["metrics"].get("yaw_rmse_over_noise")) for r in rows])
    x = np.arange(len(rows))
    ax.plot(x, agree, "o", color="tab:green", label="contact agreement")
    ax.plot(x, pos, "s", color="tab:red", label="pos RMSE / noise")
    ax.plot(x, yaw, "^", color="tab:purple", label="yaw RMSE / noise")
    ax.axhline(TARGET_CONTACT_AGREEMENT, color="tab:green", lw=0.6, ls="--")
    ax.axhline(TARGET_RMSE_OVER_NOISE, color="tab:red", lw=0.6, ls="--")
    ax.set_xlabel("push (file order)")
    ax.set_title(f"all {len(rows)} {shape} pushes (dashed: targets)", fontsize=8)
    ax.legend(fontsize=7)
    ax.grid(True, alpha=0.3)


def _say(stream: IO[str] | None, text: str) -> None:
    if stream is not None:
        stream.write(text + "\n")
        stream.flush()


def run_eval(opts: EvalOptions, *, command: str = "") -> dict[str, Any]:
    """Import, replay and evaluate every push of ``opts.data``; write the table, JSON and
    figures into ``opts.out`` and return the summary (see the module docstring).

    Raises:
        UsageError: bad options or no data.
        BagError: a push file cannot be imported or replayed.
    """
    if opts.particles < 1 or opts.jobs < 1 or opts.every < 1:
        msg = (
            f"particles, jobs and every must be >= 1, got {opts.particles}, {opts.jobs} and "
            f"{opts.every}"
        )
        raise UsageError(msg)
    files = select_shapes(resolve_data(opts.data), opts.shapes)[:: opts.every]
    started = time.perf_counter()
    with _work_dir(opts.work) as work:
        bags_dir = work / "bags"
        replays_dir = work / "replays"
        bags_dir.mkdir(parents=True, exist_ok=True)
        replays_dir.mkdir(parents=True, exist_ok=True)
        params: dict[str, Any] = {"particles": opts.particles, "marker_particles": 0}
        params["seed"] = opts.seed
        params.update(dict(opts.params))
        if opts.reuse:
            pushes, params = _reevaluate_work(bags_dir, replays_dir, params, opts)
        else:
            pushes = _import_and_replay(
                files, bags_dir, replays_dir, params, opts, started=started
            )
        summary = _summary(pushes, params, opts, work, command)
        out = Path(opts.out)
        out.mkdir(parents=True, exist_ok=True)
        summary["figures"] = _shape_figures(pushes, out) if opts.figures else []
        summary["settings"]["wall_s"] = round(time.perf_counter() - started, 1)
        summary["pushes"] = [
            {k: v for k, v in p.items() if k not in ("bag", "replay")} for p in pushes
        ]
        _write_outputs(summary, out, work, opts)
        return summary


@contextlib.contextmanager
def _work_dir(work: Path | None) -> Iterator[Path]:
    """``work`` (created), or a temporary directory deleted afterwards when None."""
    if work is None:
        with tempfile.TemporaryDirectory(prefix="dbcslam_mitpush_") as tmp:
            yield Path(tmp)
    else:
        path = Path(work)
        path.mkdir(parents=True, exist_ok=True)
        yield path


def _reevaluate_work(
    bags_dir: Path, replays_dir: Path, params: dict[str, Any], opts: EvalOptions
) -> tuple[list[dict[str, Any]], dict[str, Any]]:
    """``--reuse``: the pushes of an earlier run's replays and the filter parameters it used."""
    pushes = _reevaluate(bags_dir, replays_dir)
    _say(opts.progress, f"re-evaluated {len(pushes)} replays in {replays_dir}")
    used = pushes[0]["metrics"].get("replay", {}).get("params")
    return pushes, dict(used) if isinstance(used, dict) else params


def _import_and_replay(
    files: list[Path],
    bags_dir: Path,
    replays_dir: Path,
    params: dict[str, Any],
    opts: EvalOptions,
    *,
    started: float,
) -> list[dict[str, Any]]:
    """Import the push files into bags and replay each into ``replays_dir``."""
    pushes = _import(files, bags_dir, opts)
    _say(
        opts.progress,
        f"imported {len(pushes)} pushes into {bags_dir} "
        f"({time.perf_counter() - started:.1f} s); replaying with {opts.particles} "
        f"particles on {opts.jobs} worker(s)",
    )
    for p in pushes:
        p["replay"] = str(replays_dir / p["name"])
    _replay_all(pushes, params, opts)
    return pushes


def _summary(
    pushes: list[dict[str, Any]],
    params: dict[str, Any],
    opts: EvalOptions,
    work: Path,
    command: str,
) -> dict[str, Any]:
    """Settings, targets and per-group medians of the evaluation (``wall_s`` set at the end)."""
    return {
        "settings": {
            "command": command,
            "data": _portable(opts.data),
            "pushes": len(pushes),
            "every": opts.every,
            "push_model": opts.push_model,
            "particles": int(params.get("particles", opts.particles)),
            "jobs": opts.jobs,
            "reused_work": str(work) if opts.reuse else None,
            "replayed_by": _replayed_by(work) if opts.reuse else None,
            "noise_position": opts.noise_position,
            "noise_yaw": opts.noise_yaw,
            "seed": opts.seed,
            "params": params,
            "pusher_candidates": _candidates(pushes, "pusher"),
            "surface_candidates": _candidates(pushes, "surface"),
            "filter_uses_pusher_wrench": filter_uses_pusher_wrench(params),
            "wall_s": 0.0,
        },
        "targets": {
            "rmse_over_noise_max": TARGET_RMSE_OVER_NOISE,
            "contact_agreement_min": TARGET_CONTACT_AGREEMENT,
        },
        "groups": summarise(pushes),
    }


def _shape_figures(pushes: list[dict[str, Any]], out: Path) -> list[str]:
    """``mitpush_<shape>.png`` per shape (sorted) in ``out``; returns their file names."""
    figures: list[str] = []
    for shape in sorted({p["shape"] for p in pushes}):
        rows = [p for p in pushes if p["shape"] == shape]
        figures.append(_figure(shape, rows, out / f"mitpush_{shape}.png").name)
    return figures


def _write_outputs(summary: dict[str, Any], out: Path, work: Path, opts: EvalOptions) -> None:
    """``mitpush.json`` and ``mitpush.md`` into ``out`` (and, after a replay, ``run.json``
    with the command and wall time into ``work``); the table to the progress stream."""
    (out / "mitpush.json").write_text(json.dumps(summary, indent=2) + "\n")
    if not opts.reuse:
        run = {k: summary["settings"][k] for k in ("command", "wall_s", "jobs")}
        (work / "run.json").write_text(json.dumps(run, indent=2) + "\n")
    (out / "mitpush.md").write_text(_markdown(summary))
    _say(opts.progress, markdown_table(summary))
    _say(opts.progress, f"wrote {out / 'mitpush.md'}, {out / 'mitpush.json'}")


def _progress_line(i: int, n: int, push: dict[str, Any], wall: float) -> str:
    m = push["metrics"]
    return (
        f"[{i}/{n}] {push['name']}: pos {_fmt(m.get('position_rmse_over_noise'), '.2f')} x noise"
        f", yaw {_fmt(m.get('yaw_rmse_over_noise'), '.2f')} x noise, contact agreement "
        f"{_fmt(m.get('contact_flag_agreement'), '.3f')} ({push['contact_source']}), "
        f"{wall:.0f} s"
    )


def _replay_all(pushes: list[dict[str, Any]], params: dict[str, Any], opts: EvalOptions) -> None:
    """Replay every push (``metrics`` added to each dict), in order of decreasing length."""
    started = time.perf_counter()
    n = len(pushes)
    order = sorted(range(n), key=lambda k: -int(pushes[k]["steps"]))
    if opts.jobs == 1:
        for i, k in enumerate(order, start=1):
            pushes[k]["metrics"] = _replay_one(pushes[k]["bag"], pushes[k]["replay"], params)
            _say(opts.progress, _progress_line(i, n, pushes[k], time.perf_counter() - started))
        return
    ctx = mp.get_context("spawn")
    with ProcessPoolExecutor(max_workers=opts.jobs, mp_context=ctx) as pool:
        futures = {
            pool.submit(_replay_one, pushes[k]["bag"], pushes[k]["replay"], params): k
            for k in order
        }
        for i, fut in enumerate(as_completed(futures), start=1):
            k = futures[fut]
            pushes[k]["metrics"] = fut.result()
            _say(opts.progress, _progress_line(i, n, pushes[k], time.perf_counter() - started))


def _parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="python -m dbcslam_research.mitpush_eval",
        description=(__doc__ or "").split("\n\n")[0],
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    parser.add_argument(
        "--data",
        type=Path,
        default=DEFAULT_DATA,
        help=f"dataset root (abs/train used) or a directory of .h5 (default {DEFAULT_DATA})",
    )
    parser.add_argument(
        "--out", type=Path, default=DEFAULT_OUT, help=f"output directory (default {DEFAULT_OUT})"
    )
    parser.add_argument(
        "--work", type=Path, default=None, help="keep the bags and replays here (default: temp)"
    )
    parser.add_argument("--particles", type=int, default=300, help="filter particles (300)")
    parser.add_argument("--jobs", type=int, default=2, help="worker processes (2)")
    parser.add_argument(
        "--noise-position", type=float, default=0.005, help="added position noise std, m"
    )
    parser.add_argument("--noise-yaw", type=float, default=0.05, help="added yaw noise std, rad")
    parser.add_argument("--seed", type=int, default=0, help="noise and filter seed (0)")
    parser.add_argument(
        "--pusher-candidates",
        type=float,
        nargs="+",
        default=None,
        metavar="MU",
        help="pusher-object friction candidates (default: the importer's, 0.1 0.2 0.3)",
    )
    parser.add_argument(
        "--surface-candidates",
        type=float,
        nargs="+",
        default=list(SURFACE_CANDIDATES),
        metavar="MU",
        help="object-surface friction candidates (default 0.2 0.3 0.4 0.5: the training "
        "pushes' F/T says mu ~0.34-0.45; the importer's default is 0.1 0.2 0.3)",
    )
    parser.add_argument(
        "--reuse",
        action="store_true",
        help="re-evaluate the replays of an earlier run in --work (no import, no replay)",
    )
    parser.add_argument("--no-figures", action="store_true", help="skip the figures")
    parser.add_argument(
        "--every", type=int, default=1, help="evaluate every N-th push file (1: all)"
    )
    parser.add_argument(
        "--push-model",
        choices=("dynamic", "quasi_static"),
        default=None,
        help="push model of the imported scenarios (surface.model; default: the importer's)",
    )
    parser.add_argument(
        "--shapes",
        nargs="+",
        default=None,
        metavar="SHAPE",
        help="evaluate only the pushes of these shapes (default: all)",
    )
    parser.add_argument(
        "-p",
        "--param",
        action="append",
        default=[],
        metavar="NAME=VALUE",
        help="extra filter node parameter (repeatable)",
    )
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    """Command-line entry point; exit 0 on success, 2 on bad usage or data."""
    from dbcslam_core.errors import DbcSlamError
    from dbcslam_ros.errors import BagError

    args = _parser().parse_args(argv)
    extra: list[tuple[str, Any]] = []
    for item in args.param:
        name, sep, value = str(item).partition("=")
        if not sep:
            print(f"error: --param expects NAME=VALUE, got {item!r}", file=sys.stderr)
            return 2
        extra.append((name, value))
    opts = EvalOptions(
        data=args.data,
        out=args.out,
        work=args.work,
        particles=args.particles,
        jobs=args.jobs,
        noise_position=args.noise_position,
        noise_yaw=args.noise_yaw,
        seed=args.seed,
        figures=not args.no_figures,
        progress=sys.stderr,
        params=tuple(extra),
        reuse=args.reuse,
        push_model=args.push_model,
        every=args.every,
        shapes=None if args.shapes is None else tuple(args.shapes),
        pusher_candidates=None
        if args.pusher_candidates is None
        else tuple(args.pusher_candidates),
        surface_candidates=(
            None if args.surface_candidates is None else tuple(args.surface_candidates)
        ),
    )
    command = "python -m dbcslam_research.mitpush_eval " + " ".join(
        sys.argv[1:] if argv is None else list(argv)
    )
    try:
        run_eval(opts, command=command.strip())
    except (UsageError, BagError, DbcSlamError) as err:
        print(f"error: {err}", file=sys.stderr)
        return 2
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
