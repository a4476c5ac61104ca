"""Command-line helpers shared by the research entry points."""

from __future__ import annotations

import argparse
import ast
import time
from collections.abc import Callable, Collection, Mapping, Sequence
from concurrent.futures import ProcessPoolExecutor
from typing import Any, TypeVar

__all__ = ["doc_parser", "ints_argument", "key_values", "pool_map", "settings_dirname"]

T = TypeVar("T")
R = TypeVar("R")


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


def settings_dirname(prefix: str, settings: Mapping[str, Any]) -> str:
    """A folder name for a run with `settings` (KEY=VALUE overrides): `prefix` followed by
    ``KEY=VALUE`` items in key order joined by ``_``, characters other than letters, digits
    and ``._=-`` replaced by ``-`` (so that variants of a report do not overwrite each
    other)."""
    name = "_".join(f"{k}={v}" for k, v in sorted(settings.items()))
    return prefix + "".join(ch if ch.isalnum() or ch in "._=-" else "-" for ch in name)


def pool_map(
    fn: Callable[[T], R],
    tasks: Sequence[T],
    workers: int,
    say: Callable[[str], None],
    what: str,
) -> list[R]:
    """``[fn(t) for t in tasks]`` on `workers` processes, in order, with a progress line
    ``  <what>: i/n, s`` after every tenth of the tasks (`fn` must be picklable)."""
    out: list[R] = []
    t0 = time.perf_counter()
    with ProcessPoolExecutor(workers) as ex:
        for i, row in enumerate(ex.map(fn, tasks), 1):
            out.append(row)
            if i % max(1, len(tasks) // 10) == 0 or i == len(tasks):
                say(f"  {what}: {i}/{len(tasks)}, {time.perf_counter() - t0:.0f} s")
    return out
