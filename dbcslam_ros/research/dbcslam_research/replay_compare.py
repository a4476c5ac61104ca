"""Record every filter estimate of bag replays, and compare two recordings (before / after a
change of the filter's numerics).

``python -m dbcslam_research.replay_compare record OUT.npz [--particles N] [--bags ...]``
replays the curated bags (``bags/edge``, ``bags/gripper``, ``bags/push``) through the whole
filter (:func:`dbcslam_ros.offline.replay.replay_bag`, no plots) and stores, per step, the
estimate's pose, covariances, twist, mode marginals, friction, ESS, live hypotheses, log
likelihood, resampling flag, particle cloud and friction-map probabilities.
``python -m dbcslam_research.replay_compare compare A.npz B.npz`` prints, per bag, the largest
difference of the pose estimate and of all fields (relative to 1 + |value|) and the first
step that differs by more than ``--tol`` (default 1e-9).

The backend of the filter's hot path can be chosen with ``--backend numpy|compiled``
(`dbcslam_core.contact_modes.DEFAULT_BACKEND`).
"""

from __future__ import annotations

import argparse
import sys
import tempfile
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

__all__ = ["compare", "main", "record"]

BAGS = ("edge", "gripper", "push")


def _row(est: Any) -> np.ndarray:
    parts = [
        est.pose,
        est.pose_cov,
        est.twist,
        est.twist_cov,
        est.modes,
        est.friction,
        np.array([est.ess, est.live_hypotheses, est.log_likelihood, float(est.resampled)]),
        est.particle_poses,
        est.particle_weights,
        *est.friction_map.probs,
    ]
    return np.concatenate([np.asarray(p, dtype=np.float64).ravel() for p in parts])


def record(out: Path, bags: Sequence[Path], particles: int, backend: str | None) -> None:
    """Replay `bags` and store every estimate (see the module docstring) in `out`."""
    from dbcslam_core import contact_modes
    from dbcslam_core.rbpf import DbcSlamFilter
    from dbcslam_ros.offline.replay import ReplayOptions, replay_bag

    if backend is not None:
        contact_modes.DEFAULT_BACKEND = backend
    rows: list[np.ndarray] = []
    original = DbcSlamFilter.step

    def step(self: DbcSlamFilter, *args: Any, **kwargs: Any) -> Any:
        est = original(self, *args, **kwargs)
        rows.append(_row(est))
        return est

    DbcSlamFilter.step = step  # type: ignore[method-assign]
    data: dict[str, np.ndarray] = {}
    try:
        for bag in bags:
            rows.clear()
            with tempfile.TemporaryDirectory() as tmp:
                replay_bag(
                    bag,
                    Path(tmp) / "out",
                    ReplayOptions(params={"particles": particles}, plots=False),
                )
            for k, r in enumerate(rows):
                data[f"{bag.name}/{k}"] = r
            print(f"{bag}: {len(rows)} estimates", flush=True)
    finally:
        DbcSlamFilter.step = original  # type: ignore[method-assign]
    np.savez(out, **data)  # type: ignore[arg-type]


def compare(a_path: Path, b_path: Path, tol: float) -> bool:
    """Print the differences of two recordings; True when every field is within tol."""
    a, b = np.load(a_path), np.load(b_path)
    if set(a.files) != set(b.files):
        print(f"different steps: {len(a.files)} vs {len(b.files)}")
        return False
    ok = True
    for bag in sorted({k.split("/")[0] for k in a.files}):
        keys = sorted(
            (k for k in a.files if k.startswith(bag + "/")), key=lambda k: int(k[len(bag) + 1 :])
        )
        worst = pose = 0.0
        first = None
        for k in keys:
            x, y = a[k], b[k]
            if x.shape != y.shape:
                worst, first = np.inf, first or k
                continue
            fin = np.isfinite(x) & np.isfinite(y)
            same_fin = bool(np.array_equal(np.isfinite(x), np.isfinite(y)))
            d = float(np.max(np.abs(x[fin] - y[fin]) / (1.0 + np.abs(x[fin])), initial=0.0))
            d = d if same_fin else np.inf
            pose = max(pose, float(np.max(np.abs(x[:3] - y[:3]))))
            if d > tol and first is None:
                first = k
            worst = max(worst, d)
        ok = ok and worst <= tol
        print(
            f"{bag}: {len(keys)} steps, max pose difference {pose:.3g}, max relative "
            f"difference of all fields {worst:.3g}, first step above {tol:g}: {first}"
        )
    return ok


def main(argv: Sequence[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    sub = p.add_subparsers(dest="command", required=True)
    rec = sub.add_parser("record", help="replay the bags and store every estimate")
    rec.add_argument("out", type=Path)
    rec.add_argument("--particles", type=int, default=300)
    rec.add_argument("--bags", nargs="+", type=Path, default=[Path("bags") / b for b in BAGS])
    rec.add_argument("--backend", choices=("compiled", "numpy"), default=None)
    cmp_ = sub.add_parser("compare", help="compare two recordings")
    cmp_.add_argument("a", type=Path)
    cmp_.add_argument("b", type=Path)
    cmp_.add_argument("--tol", type=float, default=1e-9)
    args = p.parse_args(argv)
    if args.command == "record":
        record(args.out, args.bags, args.particles, args.backend)
        return 0
    return 0 if compare(args.a, args.b, args.tol) else 1


if __name__ == "__main__":
    sys.exit(main())
