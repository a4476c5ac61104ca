"""Full-push prediction on the MIT pushes: the metric of Bauza & Rodriguez (2017).

From the object's initial pose and the measured pusher trajectory, predict where the object
ends up; NMSE = mean squared error / variance of the true final displacement, per component
(dx, dy in the object's initial body frame, dtheta), then averaged over the three (their
analytical model: 0.72; a GP trained on the shape: 0.37).

Models:

* ``nominal dynamic``: the filter's own push model (`dbcslam_core.dynamics.PlanarModel`:
  Stewart-Trinkle impulses, implicit Coulomb support friction mu 0.25 under uniform
  pressure, pusher friction 0.2, plate mass from the outline), object at rest at the start;

and (`dbcslam_core.quasi_static`, the motion cone on an ellipsoidal limit surface):

* ``quasi-static, uniform c``: c from uniform support pressure over the outline, pusher
  friction mu_c = 0.2 (the dataset README's prior);
* ``quasi-static, fitted``: c = k * c_uniform and mu_c fitted on the OTHER shapes only
  (leave one shape out over the training shapes) by minimising their NMSE on a grid;
* ``filter's quasi-static model``: the same two predictions by the filter's own motion model
  (`PlanarModel` with ``surface.model: quasi_static``: the limit surface as the effective
  mass of the contact LCP, c of the uniform support points), the fitted one with the fit
  expressed as the vocabulary effect ``support_concentration`` (centre_fraction = 1 - k,
  for k <= 1; k > 1 would be a rim-heavy pressure, ``support_pressure``).

Run: ``python -m dbcslam_research.push_nmse [DATA] --out DIR`` (DATA: the dataset folder with
``abs/train`` and ``shapes``, default ``../shared/data/mit-push``); writes ``push_nmse.md``,
``push_nmse.json`` and ``push_nmse.png`` (predicted vs measured final displacement).
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import numpy.typing as npt

from dbcslam_core.dynamics import PlanarModel, State
from dbcslam_core.extensions import ModelExtension
from dbcslam_core.quasi_static import limit_surface_c, rollout_push
from dbcslam_core.scenario import push_scenario
from dbcslam_ros.importers.mitpush import (
    PUSHER_RADIUS,
    ImportConfig,
    load_outline,
    load_push,
    mass_properties,
    push_files,
    resample_push,
)

__all__ = ["PushCase", "displacement", "load_cases", "main", "nmse", "predict", "predict_dynamic"]

FloatArray = npt.NDArray[np.float64]

#: grids of the fitted model: c / c_uniform and pusher friction
C_FACTORS = np.round(np.arange(0.4, 1.61, 0.1), 3)
MU_C = np.round(np.arange(0.0, 0.61, 0.05), 3)
NOMINAL_MU_C = 0.2
#: support friction of the nominal dynamic model (the dataset README: roughly 0.1-0.35)
NOMINAL_SUPPORT_MU = 0.25


@dataclass(frozen=True)
class PushCase:
    """One push: shape, outline (body frame), start pose, tip path, true final displacement."""

    name: str
    shape: str
    vertices: FloatArray
    c_uniform: float
    pose0: FloatArray
    tip: FloatArray
    dt: float
    truth: FloatArray  # (3,) dx, dy (initial body frame, m), dtheta (rad)
    mass: float = 1.0  # kg (the stainless-steel plate of the outline)


def displacement(pose0: npt.ArrayLike, pose1: npt.ArrayLike) -> FloatArray:
    """(..., 3) final displacement of pose1 from pose0, in pose0's body frame."""
    p0 = np.asarray(pose0, dtype=np.float64)
    p1 = np.asarray(pose1, dtype=np.float64)
    d = p1[..., :2] - p0[..., :2]
    c, s = np.cos(p0[..., 2]), np.sin(p0[..., 2])
    return np.stack(
        [c * d[..., 0] + s * d[..., 1], -s * d[..., 0] + c * d[..., 1], p1[..., 2] - p0[..., 2]],
        -1,
    )


def load_cases(data: Path, progress: bool = True) -> list[PushCase]:
    """Every push under DATA/abs/train, resampled on 10 ms and aligned (no added noise)."""
    files = push_files([data / "abs" / "train"])
    shapes_dir = data / "shapes"
    cfg = ImportConfig()
    cases: list[PushCase] = []
    outlines: dict[str, tuple[FloatArray, float]] = {}
    for i, path in enumerate(files):
        raw = load_push(path)
        shape = raw.info.shape
        series = resample_push(raw, load_outline(shape, shapes_dir), cfg)
        verts = np.asarray(series.outline.vertices, dtype=np.float64)
        mass, _inertia, _src = mass_properties(series.outline, cfg)
        if shape not in outlines:
            outlines[shape] = (verts, limit_surface_c(verts))
        cases.append(
            PushCase(
                name=path.name,
                shape=shape,
                vertices=verts,
                c_uniform=outlines[shape][1],
                pose0=series.pose[0].copy(),
                tip=series.tip.copy(),
                dt=series.dt,
                truth=displacement(series.pose[0], series.pose[-1]),
                mass=mass,
            )
        )
        if progress:
            print(f"\r[load {i + 1}/{len(files)}] {path.name[:60]}", end="", file=sys.stderr)
    if progress:
        print(file=sys.stderr)
    return cases


def predict(case: PushCase, c_factor: npt.ArrayLike, mu_c: npt.ArrayLike) -> FloatArray:
    """Predicted final displacement (*B, 3) for a batch of (c factor, mu_c) (broadcast)."""
    c = np.asarray(c_factor, dtype=np.float64) * case.c_uniform
    poses, _ = rollout_push(
        case.vertices, case.pose0, case.tip, radius=PUSHER_RADIUS, dt=case.dt, mu_c=mu_c, c=c
    )
    return displacement(case.pose0, poses[..., -1, :])


def predict_dynamic(case: PushCase, support_mu: float = NOMINAL_SUPPORT_MU) -> FloatArray:
    """Final displacement (3,) by the nominal dynamic model: the core's Stewart-Trinkle
    step with implicit Coulomb support friction (`PlanarModel`, uniform pressure), the object
    at rest at the start, driven by the measured tip path, pusher friction NOMINAL_MU_C."""
    sc = push_scenario(
        case.vertices.tolist(),
        mass=case.mass,
        dt=case.dt,
        pusher_radius=PUSHER_RADIUS,
        support_mu=support_mu,
    )
    model = PlanarModel(sc, active_set=True)
    state = State(q=case.pose0.copy(), v=np.zeros(3))
    for k in range(case.tip.shape[0] - 1):
        r = model.step(state, np.zeros(3), case.tip[k], case.tip[k + 1], mu=NOMINAL_MU_C)
        state = State(q=r.q, v=r.v)
    return displacement(case.pose0, state.q)


def predict_quasi_static_model(
    case: PushCase, mu_c: float = NOMINAL_MU_C, centre_fraction: float = 0.0
) -> FloatArray:
    """Final displacement (3,) by the filter's quasi-static motion model (`PlanarModel`,
    ``surface.model: quasi_static``, uniform pressure plus ``support_concentration``
    centre_fraction), object at rest at the start, driven by the measured tip path."""
    sc = push_scenario(
        case.vertices.tolist(),
        mass=case.mass,
        dt=case.dt,
        pusher_radius=PUSHER_RADIUS,
        support_mu=NOMINAL_SUPPORT_MU,
        model="quasi_static",
    )
    exts: tuple[ModelExtension, ...] = ()
    if centre_fraction > 0.0:
        exts = (ModelExtension.make("support_concentration", centre_fraction=centre_fraction),)
    model = PlanarModel(sc, exts, active_set=True, support_iterations=3)
    state = State(q=case.pose0.copy(), v=np.zeros(3))
    for k in range(case.tip.shape[0] - 1):
        r = model.step(state, np.zeros(3), case.tip[k], case.tip[k + 1], mu=mu_c)
        state = State(q=r.q, v=r.v)
    return displacement(case.pose0, state.q)


def nmse(pred: FloatArray, truth: FloatArray) -> FloatArray:
    """NMSE per component over pushes (axis -2), averaged over the 3 components (axis -1).

    pred (..., N, 3), truth (N, 3): mean squared error / variance of the truth, per
    component, then the mean of the three."""
    var = np.var(truth, axis=0)
    err = np.mean((pred - truth) ** 2, axis=-2) / np.maximum(var, 1e-300)
    return np.asarray(np.mean(err, axis=-1), dtype=np.float64)


def _grid_predictions(cases: list[PushCase]) -> FloatArray:
    """(len(C_FACTORS), len(MU_C), N, 3) predictions of every push on the fit grid."""
    cf, mu = np.meshgrid(C_FACTORS, MU_C, indexing="ij")
    out = np.empty((*cf.shape, len(cases), 3))
    t0 = time.monotonic()
    for i, case in enumerate(cases):
        out[:, :, i] = predict(case, cf, mu)
        el = time.monotonic() - t0
        print(f"\r[grid {i + 1}/{len(cases)}, {el:.0f} s]", end="", file=sys.stderr)
    print(file=sys.stderr)
    return out


def evaluate(cases: list[PushCase]) -> dict[str, object]:
    """Leave-one-shape-out table: per held-out shape, NMSE of each model and the fit."""
    grid = _grid_predictions(cases)
    dyn = np.stack([predict_dynamic(c) for c in cases])
    shapes = sorted({c.shape for c in cases})
    truth = np.stack([c.truth for c in cases])
    shape_of = np.array([c.shape for c in cases])
    i_nom = (int(np.argmin(np.abs(C_FACTORS - 1.0))), int(np.argmin(np.abs(MU_C - NOMINAL_MU_C))))
    rows = []
    for held in shapes:
        test = shape_of == held
        train_shapes = [s for s in shapes if s != held]
        # fit: mean over the training shapes of each shape's NMSE
        score = np.mean(
            [nmse(grid[:, :, shape_of == s], truth[shape_of == s]) for s in train_shapes], axis=0
        )
        bi, bj = np.unravel_index(int(np.argmin(score)), score.shape)
        on_edge = bi in (0, len(C_FACTORS) - 1) or bj in (0, len(MU_C) - 1)
        held_cases = [c for c in cases if c.shape == held]
        k_fit = float(C_FACTORS[bi])
        qs_nom = np.stack([predict_quasi_static_model(c) for c in held_cases])
        qs_fit = np.stack(
            [
                predict_quasi_static_model(c, float(MU_C[bj]), max(0.0, 1.0 - k_fit))
                for c in held_cases
            ]
        )
        rows.append(
            {
                "shape": held,
                "pushes": int(test.sum()),
                "nmse_dynamic": float(nmse(dyn[test], truth[test])),
                "nmse_uniform": float(nmse(grid[i_nom][test], truth[test])),
                "nmse_fitted": float(nmse(grid[bi, bj][test], truth[test])),
                "nmse_filter_model_uniform": float(nmse(qs_nom, truth[test])),
                "nmse_filter_model_fitted": float(nmse(qs_fit, truth[test])),
                "fit_centre_fraction": round(max(0.0, 1.0 - k_fit), 3),
                "fit_c_factor": float(C_FACTORS[bi]),
                "fit_mu_c": float(MU_C[bj]),
                "fit_at_grid_edge": bool(on_edge),
                "train_nmse": float(score[bi, bj]),
            }
        )
    return {
        "rows": rows,
        "mean_nmse_dynamic": float(np.mean([r["nmse_dynamic"] for r in rows])),
        "mean_nmse_uniform": float(np.mean([r["nmse_uniform"] for r in rows])),
        "mean_nmse_fitted": float(np.mean([r["nmse_fitted"] for r in rows])),
        "mean_nmse_filter_model_uniform": float(
            np.mean([r["nmse_filter_model_uniform"] for r in rows])
        ),
        "mean_nmse_filter_model_fitted": float(
            np.mean([r["nmse_filter_model_fitted"] for r in rows])
        ),
        "grid": {"c_factor": C_FACTORS.tolist(), "mu_c": MU_C.tolist()},
        "predictions_fitted": {
            r["shape"]: grid[
                int(np.argmin(np.abs(C_FACTORS - r["fit_c_factor"]))),
                int(np.argmin(np.abs(MU_C - r["fit_mu_c"]))),
            ][shape_of == r["shape"]].tolist()
            for r in rows
        },
        "truth": {s: truth[shape_of == s].tolist() for s in shapes},
    }


def _markdown(res: dict[str, object]) -> str:
    rows = res["rows"]
    assert isinstance(rows, list)
    lines = [
        "| held-out shape | pushes | NMSE nominal dynamic (support mu 0.25) | NMSE quasi-static "
        "(uniform c, mu_c 0.2) | NMSE quasi-static fitted on the other shapes | "
        "fit: c / c_uniform, mu_c | filter's quasi-static model: uniform / fitted "
        "(support_concentration) |",
        "|---|---|---|---|---|---|---|",
    ]
    for r in rows:
        edge = " (grid edge)" if r["fit_at_grid_edge"] else ""
        lines.append(
            f"| {r['shape']} | {r['pushes']} | {r['nmse_dynamic']:.3f} | {r['nmse_uniform']:.3f} "
            f"| {r['nmse_fitted']:.3f} "
            f"| {r['fit_c_factor']:.1f}, {r['fit_mu_c']:.2f}{edge} "
            f"| {r['nmse_filter_model_uniform']:.3f} / {r['nmse_filter_model_fitted']:.3f} "
            f"(centre_fraction {r['fit_centre_fraction']:.1f}) |"
        )
    dyn, uni, fit, fu, ff = (
        res[f"mean_nmse_{k}"]
        for k in ("dynamic", "uniform", "fitted", "filter_model_uniform", "filter_model_fitted")
    )
    lines.append(f"| **mean** | | {dyn:.3f} | {uni:.3f} | {fit:.3f} | | {fu:.3f} / {ff:.3f} |")
    return "\n".join(lines) + "\n"


def _figure(res: dict[str, object], path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    pred = res["predictions_fitted"]
    truth = res["truth"]
    assert isinstance(pred, dict) and isinstance(truth, dict)
    fig, axes = plt.subplots(1, 3, figsize=(12, 4))
    labels = ("dx [mm]", "dy [mm]", "dtheta [deg]")
    scale = (1e3, 1e3, 180.0 / np.pi)
    for k, ax in enumerate(axes):
        for shape in sorted(truth):
            t = np.asarray(truth[shape])[:, k] * scale[k]
            p = np.asarray(pred[shape])[:, k] * scale[k]
            ax.scatter(t, p, s=14, label=shape)
        lo, hi = ax.get_xlim()
        ax.plot([lo, hi], [lo, hi], "k--", lw=0.8)
        ax.set_xlabel(f"measured {labels[k]}")
        ax.set_ylabel(f"predicted {labels[k]}")
    axes[0].legend(fontsize=8)
    fig.suptitle("Quasi-static full-push prediction, fitted on the other shapes (held out)")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    ap.add_argument("data", nargs="?", default="../shared/data/mit-push", type=Path)
    ap.add_argument("--out", type=Path, default=Path("dbcslam_ros/research/results/push_nmse"))
    args = ap.parse_args(argv)
    if not (args.data / "abs" / "train").is_dir():
        print(f"push_nmse: no abs/train folder under {args.data}", file=sys.stderr)
        return 2
    started = time.monotonic()
    cases = load_cases(args.data)
    res = evaluate(cases)
    res["wall_s"] = round(time.monotonic() - started, 1)
    args.out.mkdir(parents=True, exist_ok=True)
    (args.out / "push_nmse.json").write_text(json.dumps(res, indent=1))
    md = _markdown(res)
    (args.out / "push_nmse.md").write_text(md)
    _figure(res, args.out / "push_nmse.png")
    print(md)
    print(f"written to {args.out} in {res['wall_s']} s")
    return 0


if __name__ == "__main__":
    sys.exit(main())
