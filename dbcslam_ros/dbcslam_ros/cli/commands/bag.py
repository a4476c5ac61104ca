"""``dbcslam bag info BAG``: what a bag holds (like ``ros2 bag info``)."""

from __future__ import annotations

import argparse
import textwrap
import time
from pathlib import Path

from dbcslam_ros.cli.registry import Command

__all__ = ["COMMAND", "format_info"]


def _size(num: float) -> str:
    for unit in ("B", "KiB", "MiB", "GiB"):
        if num < 1024 or unit == "GiB":
            return f"{num:.1f} {unit}" if unit != "B" else f"{int(num)} B"
        num /= 1024
    return f"{num:.1f} GiB"  # pragma: no cover


def _stamp(ns: int) -> str:
    sec, frac = divmod(ns, 1_000_000_000)
    text = time.strftime("%b %d %Y %H:%M:%S", time.gmtime(sec))
    return f"{text}.{frac:09d} UTC ({sec}.{frac:09d})"


def format_info(bag_path: str, *, salvage: bool = False) -> str:
    """The ``bag info`` report of a bag (reads every message to check the file).

    Raises:
        BagError: missing, empty, truncated or corrupt bag (unless ``salvage``).
    """
    from dbcslam_ros.bag import open_bag

    with open_bag(bag_path, salvage=salvage) as bag:
        read = bag.verify()
        topics = bag.topics()
        size = sum(Path(f).stat().st_size for f in bag.files)
        meta = bag.metadata
        pad = " " * 19
        lines = [
            f"{'Files:':<19}" + f"\n{pad}".join(str(Path(f).name) for f in bag.files),
            f"{'Bag size:':<19}{_size(size)}",
            f"{'Storage id:':<19}mcap",
            f"{'ROS Distro:':<19}{(meta.ros_distro if meta else '') or 'unknown'}",
            f"{'Duration:':<19}{bag.duration_ns / 1e9:.9f}s",
            f"{'Start:':<19}{_stamp(bag.start_ns)}",
            f"{'End:':<19}{_stamp(bag.end_ns)}",
            f"{'Messages:':<19}{read}",
        ]
        rows = [
            f"Topic: {t.name} | Type: {t.msgtype} | Count: {t.message_count} | "
            f"Serialization Format: {t.serialization_format}"
            for t in topics.values()
        ]
        first = rows[0] if rows else ""
        lines.append(f"{'Topic information:':<19}{first}")
        lines.extend(pad + row for row in rows[1:])
        lines.append(f"{'Service:':<19}0")
        lines.append(f"{'Service information:':<19}")
        if bag.damage is not None:
            lines.append(f"{'Damage:':<19}{bag.damage} (salvaged {read} messages before it)")
        return "\n".join(lines)


def _configure(parser: argparse.ArgumentParser) -> None:
    sub = parser.add_subparsers(dest="bag_command", metavar="SUBCOMMAND", required=True)
    info = sub.add_parser(
        "info",
        help="print what a bag holds: files, size, duration, start/end, topics, types, counts",
        description=textwrap.fill(
            "Print what a bag holds (like 'ros2 bag info'): files, size, duration, first and "
            "last log time (UTC), message count, and per topic its type and count. Every "
            "message is read once, so a damaged bag is reported (exit code 2)."
        ),
        epilog=(
            "examples:\n  dbcslam bag info bags/edge\n  dbcslam bag info run.mcap\n"
            "  dbcslam bag info --salvage crashed_run/   # read up to the damage\n"
        ),
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    info.add_argument(
        "bag", metavar="BAG", help="bag directory or .mcap file, or a directory of bags"
    )
    info.add_argument(
        "--salvage",
        action="store_true",
        help="report what can be read before a truncation or damage instead of failing",
    )


def _run(args: argparse.Namespace) -> int:
    from dbcslam_ros.bag.reader import find_bags

    if args.bag_command == "info":
        paths = find_bags(args.bag)
        reports = [format_info(str(p), salvage=args.salvage) for p in paths]
        if len(paths) == 1:
            print(reports[0])
        else:
            print("\n\n".join(f"== {p} ==\n{r}" for p, r in zip(paths, reports, strict=True)))
        return 0
    return 2  # pragma: no cover - argparse requires a subcommand


COMMAND = Command(
    name="bag",
    help="inspect bags (info)",
    description="Inspect rosbag2 MCAP bags. 'bag info BAG' prints what a bag holds.",
    examples="  dbcslam bag info bags/edge\n  dbcslam bag info --help",
    configure=_configure,
    run=_run,
)
