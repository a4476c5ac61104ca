"""Command-line helpers shared by the research entry points."""

from __future__ import annotations

import argparse

__all__ = ["doc_parser", "ints_argument"]


def doc_parser(module: str, doc: str | None) -> argparse.ArgumentParser:
    """A parser for ``python -m <module>`` whose description is the first paragraph of the
    module docstring `doc` and whose epilog is the rest (layout kept)."""
    head, _, rest = (doc or "").partition("\n\n")
    return argparse.ArgumentParser(
        prog=f"python -m {module}",
        description=head,
        epilog=rest or None,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )


def ints_argument(text: str) -> list[int]:
    """argparse type: comma-separated positive integers (e.g. particle counts)."""
    try:
        vals = [int(v) for v in text.split(",") if v.strip()]
    except ValueError as err:
        msg = f"expected comma-separated integers, got {text!r}"
        raise argparse.ArgumentTypeError(msg) from err
    if not vals or min(vals) < 1:
        msg = f"expected positive integers, got {text!r}"
        raise argparse.ArgumentTypeError(msg)
    return vals
