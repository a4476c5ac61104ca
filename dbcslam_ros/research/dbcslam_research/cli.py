"""Command-line helpers shared by the research entry points."""

from __future__ import annotations

import argparse

__all__ = ["doc_parser"]


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
