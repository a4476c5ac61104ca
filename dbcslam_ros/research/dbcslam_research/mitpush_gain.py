"""Tracking gain of an extended push model on real pushes: nominal vs extended filter runs.

Run ``python -m dbcslam_research.mitpush_gain --nominal N1 [N2 ...] --extended E1 [E2 ...]
[--discrepancy REPORT.json] --out DIR``. Each N_i / E_i is the output folder (or the
``mitpush.json``) of one ``python -m dbcslam_research.mitpush_eval`` run over the same pushes,
the same added noise and seed, without and with the extended model (``-p
model_file=MODEL.yaml``, the model file `dbcslam discrepancy` writes); pair i is one seed.
With ``--discrepancy`` (the analysis' JSON report) the pushes it fitted on and held out are
reported apart, so the held-out gain is the one of pushes the fit never saw.

Per pair and group of pushes: root mean square over the pushes of the position and yaw
tracking RMSE (posterior mean vs the Vicon pose), nominal -> extended and their ratio (the
gain), medians, and how many pushes are tracked worse than the added noise. Writes
``gain.md`` and ``gain.json`` in ``--out``.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from dbcslam_research.cli import doc_parser

__all__ = ["compare", "load_eval", "main", "markdown"]


def load_eval(path: Path) -> dict[str, dict[str, Any]]:
    """Push name -> metrics of one `mitpush_eval` run (its folder or its ``mitpush.json``)."""
    file = path / "mitpush.json" if path.is_dir() else path
    data = json.loads(file.read_text())
    return {p["name"]: p["metrics"] for p in data["pushes"]}


def _group(
    nom: dict[str, dict[str, Any]], ext: dict[str, dict[str, Any]], names: Sequence[str]
) -> dict[str, Any]:
    rows = np.asarray(
        [
            [
                nom[n]["position_rmse_m"],
                ext[n]["position_rmse_m"],
                nom[n]["yaw_rmse_rad"],
                ext[n]["yaw_rmse_rad"],
            ]
            for n in names
        ],
        dtype=np.float64,
    )
    over = np.asarray(
        [
            [
                max(nom[n]["position_rmse_over_noise"], nom[n]["yaw_rmse_over_noise"]),
                max(ext[n]["position_rmse_over_noise"], ext[n]["yaw_rmse_over_noise"]),
            ]
            for n in names
        ]
    )
    rms = np.sqrt(np.mean(rows**2, axis=0))
    med = np.median(rows, axis=0)
    return {
        "pushes": len(names),
        "position_rms_m": [float(rms[0]), float(rms[1])],
        "yaw_rms_rad": [float(rms[2]), float(rms[3])],
        "position_gain": float(rms[0] / rms[1]),
        "yaw_gain": float(rms[2] / rms[3]),
        "position_median_m": [float(med[0]), float(med[1])],
        "yaw_median_rad": [float(med[2]), float(med[3])],
        "worse_than_noise": [int((over[:, 0] > 1.0).sum()), int((over[:, 1] > 1.0).sum())],
    }


def compare(
    nominal: Sequence[Path], extended: Sequence[Path], groups: Mapping[str, Sequence[str]] | None
) -> list[dict[str, Any]]:
    """Per (nominal, extended) pair: the group summaries (groups: name -> push names; None:
    one group ``all`` of every push both runs have)."""
    if len(nominal) != len(extended) or not nominal:
        msg = (
            f"need as many --nominal as --extended runs (>= 1), got {len(nominal)} and "
            f"{len(extended)}"
        )
        raise ValueError(msg)
    out = []
    for n_path, e_path in zip(nominal, extended, strict=True):
        nom, ext = load_eval(n_path), load_eval(e_path)
        common = sorted(set(nom) & set(ext))
        if not common:
            msg = f"{n_path} and {e_path} share no push"
            raise ValueError(msg)
        sel = {"all": common} if groups is None else groups
        block: dict[str, Any] = {"nominal": str(n_path), "extended": str(e_path), "groups": {}}
        for g, names in sel.items():
            missing = [n for n in names if n not in nom or n not in ext]
            if missing:
                msg = f"group {g!r}: pushes missing from {n_path} or {e_path}: {missing[:3]}"
                raise ValueError(msg)
            block["groups"][g] = _group(nom, ext, names)
        out.append(block)
    return out


def _groups_from_report(report: Path) -> dict[str, list[str]]:
    bags = json.loads(report.read_text())["bags"]
    return {
        "held out": [Path(b).name for b in bags["heldout"]],
        "fitted": [Path(b).name for b in bags["fit"]],
    }


def markdown(pairs: Sequence[dict[str, Any]], title: str) -> str:
    lines = [
        f"# {title}",
        "",
        "Tracking RMSE (posterior mean vs Vicon), root mean square over the pushes, nominal -> "
        "extended (gain = nominal / extended); medians over the pushes; pushes tracked worse "
        "than the added noise (position or yaw).",
        "",
        "| run pair | pushes | position RMS (mm) | gain | yaw RMS (rad) | gain | median "
        "position (mm) | median yaw (rad) | worse than noise |",
        "|---|---|---|---|---|---|---|---|---|",
    ]
    for i, p in enumerate(pairs):
        for g, r in p["groups"].items():
            pos, yaw = r["position_rms_m"], r["yaw_rms_rad"]
            pm, ym = r["position_median_m"], r["yaw_median_rad"]
            w = r["worse_than_noise"]
            lines.append(
                f"| {i}: {g} | {r['pushes']} | {1e3 * pos[0]:.2f} -> {1e3 * pos[1]:.2f} | "
                f"{r['position_gain']:.2f} | {yaw[0]:.4f} -> {yaw[1]:.4f} | {r['yaw_gain']:.2f} | "
                f"{1e3 * pm[0]:.2f} -> {1e3 * pm[1]:.2f} | {ym[0]:.4f} -> {ym[1]:.4f} | "
                f"{w[0]} -> {w[1]} |"
            )
    by_group: dict[str, list[float]] = {}
    for p in pairs:
        for g, r in p["groups"].items():
            by_group.setdefault(g, []).append(r["yaw_gain"])
    lines.append("")
    for g, gains in by_group.items():
        geo = math.exp(sum(math.log(x) for x in gains) / len(gains))
        lines.append(
            f"- {g}: yaw gain {', '.join(f'{x:.2f}' for x in gains)} over {len(gains)} run "
            f"pair(s) (geometric mean {geo:.2f})"
        )
    return "\n".join(lines) + "\n"


def _parser() -> argparse.ArgumentParser:
    p = doc_parser("dbcslam_research.mitpush_gain", __doc__)
    p.add_argument("--nominal", type=Path, nargs="+", required=True, help="mitpush_eval runs")
    p.add_argument("--extended", type=Path, nargs="+", required=True, help="the same, extended")
    p.add_argument(
        "--discrepancy", type=Path, default=None, help="analysis JSON: fitted / held-out pushes"
    )
    p.add_argument("--title", default="Tracking gain of the extended model on real pushes")
    p.add_argument("--out", type=Path, required=True, help="output folder")
    return p


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point; exit 0 on success, 2 on bad usage or input."""
    args = _parser().parse_args(argv)
    try:
        groups = None if args.discrepancy is None else _groups_from_report(args.discrepancy)
        pairs = compare(args.nominal, args.extended, groups)
    except (OSError, KeyError, ValueError) as err:
        print(f"error: {err}", file=sys.stderr)
        return 2
    args.out.mkdir(parents=True, exist_ok=True)
    (args.out / "gain.json").write_text(json.dumps(pairs, indent=1) + "\n")
    (args.out / "gain.md").write_text(markdown(pairs, args.title))
    print(markdown(pairs, args.title))
    return 0


if __name__ == "__main__":
    sys.exit(main())
