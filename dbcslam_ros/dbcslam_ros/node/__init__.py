"""The live nodes: the filter node (``filter_node``: parameters, subscriptions, publishing,
markers, diagnostics), the per-run filter state it drives (``session``: stamp rules, gating,
gaps, catch-up) and the small talker/listener demo nodes (``demo_nodes``)."""

from __future__ import annotations

__all__: list[str] = []
