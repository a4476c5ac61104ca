"""Discrete contact modes of a potential contact (Sec. III-A of the paper).

Mode order is the order of dim 1 of `/dbcslam/contact_modes` in the contract:
`separated, sticking, sliding_pos, sliding_neg`. Sliding directions refer to the relative
tangential velocity of the body w.r.t. the obstacle along the contact tangent
`t = (n_y, -n_x)` (the normal rotated by -90 degrees).
"""

from __future__ import annotations

from enum import IntEnum

__all__ = ["MODE_NAMES", "N_MODES", "Mode"]


class Mode(IntEnum):
    """Contact mode of one potential contact."""

    SEPARATED = 0
    STICKING = 1
    SLIDING_POS = 2
    SLIDING_NEG = 3


MODE_NAMES: tuple[str, ...] = ("separated", "sticking", "sliding_pos", "sliding_neg")
N_MODES: int = len(MODE_NAMES)
