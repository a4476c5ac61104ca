"""``dbcslam evaluate BAG --json FILE``: metrics of a bag's estimates against its truth."""

from __future__ import annotations

import argparse
import json
from pathlib import Path
from typing import Any

from dbcslam_ros.cli.registry import Command

__all__ = ["COMMAND"]

_DESCRIPTION = """\
Score the estimates in BAG (/dbcslam/pose, /dbcslam/contact_modes, /dbcslam/friction,
/dbcslam/friction_map, as written by `dbcslam replay` or recorded live) against its truth
topics (/truth/object/pose, /truth/contact_modes, /truth/friction). Estimates are matched
to truth by stamp (within half a model step).

Metrics: position RMSE (m, per axis) and as a multiple of the /scenario position noise
std; yaw RMSE (polygon bodies); in-contact, stick/slide and full contact-mode accuracy;
the final friction posterior of every pair and the posterior of the true value;
friction-map accuracy over the slid cells (edge); counts; the mean step time from
/diagnostics. Prints a table; --json writes every metric. BAG may be a directory of bags
(one JSON object per bag, keyed by bag path). No estimates or no truth in a bag: exit 2,
naming the missing topics."""

_EXAMPLES = """\
  dbcslam evaluate out/edge --json out/edge/metrics.json
  dbcslam evaluate bags/demo_gripper_20260101T120000
"""


def _configure(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("bag", metavar="BAG", help="bag directory, .mcap file or folder of bags")
    parser.add_argument("--json", metavar="FILE", help="write the metrics as JSON to FILE")
    parser.add_argument("--salvage", action="store_true", help="read a damaged bag up to it")


def _run(args: argparse.Namespace) -> int:
    from dbcslam_ros.bag import find_bags
    from dbcslam_ros.offline.evaluate import evaluate_bag, metrics_table

    bags = find_bags(args.bag)
    results: dict[str, dict[str, Any]] = {}
    for bag in bags:
        metrics = evaluate_bag(bag, salvage=args.salvage)
        results[str(bag)] = metrics
        print(metrics_table(metrics))
    if args.json:
        out = Path(args.json)
        payload: Any = next(iter(results.values())) if len(results) == 1 else results
        out.parent.mkdir(parents=True, exist_ok=True)
        out.write_text(json.dumps(payload, indent=2) + "\n")
        print(f"wrote {out}")
    return 0


COMMAND = Command(
    name="evaluate",
    help="metrics of a bag's estimates against its truth topics",
    description=_DESCRIPTION,
    examples=_EXAMPLES,
    configure=_configure,
    run=_run,
)
