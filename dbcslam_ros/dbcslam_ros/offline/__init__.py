"""Offline tools on bags: ``replay`` (the filter over a bag as fast as it can), ``evaluate``
(metrics against the truth topics), ``report`` and ``plotting`` (figures), ``demo`` (simulator
and filter as processes, recorded, then summarised) and ``discrepancy_report`` (``dbcslam
discrepancy``: what the model gets wrong on measured bags)."""

from __future__ import annotations

__all__: list[str] = []
