"""Command-line helpers shared by the research entry points."""

from __future__ import annotations

import argparse
import ast
from collections.abc import Collection, Sequence
from typing import Any

__all__ = ["doc_parser", "ints_argument", "key_values"]


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


def key_values(
    items: Sequence[str], option: str, keys: Collection[str] | None, expected: str
) -> dict[str, Any]:
    """``KEY=VALUE`` items of a repeatable `option` -> {KEY: VALUE} (VALUE a Python literal,
    else the text). Raises ValueError naming the item and `expected` (what KEY may be) when
    an item has no ``=`` or an empty KEY, or, given `keys`, a KEY outside them."""
    out: dict[str, Any] = {}
    for item in items:
        key, sep, text = (part.strip() for part in item.partition("="))
        if not sep or not key or (keys is not None and key not in keys):
            msg = f"{option} {item!r}: expected KEY=VALUE {expected}"
            raise ValueError(msg)
        try:
            out[key] = ast.literal_eval(text)
        except (ValueError, SyntaxError):
            out[key] = text
    return out
