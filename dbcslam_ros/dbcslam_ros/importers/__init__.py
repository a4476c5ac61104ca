"""Importers of outside data into bags of the contract: the MIT MCube planar-pushing dataset
(``mitpush``: reading and resampling the .h5 files; ``mitpush_align``: the frame alignment of
the tracked shape; ``mitpush_bag``: one bag per push file, as ``dbcslam import-mitpush``
writes it)."""

from __future__ import annotations

__all__: list[str] = []
