"""The particle set of the RBPF: what each particle carries, and how the set resamples.

Per particle i (P particles, B joint friction hypotheses, C potential contacts, the four modes
of `contact_modes.Mode`):

* continuous state, sampled: pose q[i] (x, y[, yaw]) (m, m, rad) of the body's centre of mass
  and twist v[i] (vx, vy[, omega]) (m/s, m/s, rad/s), world frame (REP-103);
* log weight log_w[i] (unnormalised);
* closed-form discrete beliefs given the particle's trajectory: fric[i, b], the friction
  belief over the joint friction hypotheses, and modes[i, b, c, m], the per-contact mode
  marginals conditioned on b;
* the particle's rows of the friction map's fixed-lag history (`MapHistory`).

With a friction bank (`FilterConfig.friction_bank`) each particle carries `copies` = B copies
of its continuous state and mode marginals, one per joint friction hypothesis (rows
i * B + b of q, v, fric, modes; their friction axis has length 1), and its friction belief
is `bank[i, b]`; log_w and the history stay per particle. With hypothesis resampling
(`FilterConfig.bank_resampling = "hypothesis"`) each copy also carries its log weight within
its hypothesis, copy_log_w[i, b], and `resample_copies` resamples each hypothesis' copies
separately.

Resampling moves all of it as one object (`ParticleSet.resample`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

__all__ = ["MapHistory", "ParticleSet"]

FloatArray = npt.NDArray[np.float64]
IntArray = npt.NDArray[np.int64]


class MapHistory:
    """Fixed-lag history of the friction map: a ring buffer (lag + 1, P, W) of packed
    per-particle rows ``[fric_pair (pairs * Kmax) | s (C) | P(in contact) (C)]``, the oldest
    of the `length` entries at slot `head`. Entries older than `lag` steps are handed back by
    `push` to be committed to the map under the weights of that time."""

    def __init__(self, lag: int, particles: int, width: int) -> None:
        self.lag = lag
        self.buf = np.zeros((lag + 1, particles, width))
        self.head = 0
        self.length = 0

    def clear(self) -> None:
        """Forget every entry (the buffer is reused)."""
        self.head = 0
        self.length = 0

    def push(self, row: FloatArray) -> FloatArray | None:
        """Append one step (P, W); returns the entry (P, W) that leaves the lag window (a
        view, valid until the next push) or None."""
        cap = self.buf.shape[0]
        self.buf[(self.head + self.length) % cap] = row
        self.length += 1
        if self.length <= self.lag:
            return None
        old: FloatArray = self.buf[self.head]
        self.head = (self.head + 1) % cap
        self.length -= 1
        return old

    def entries(self) -> FloatArray:
        """The uncommitted history (L, P, W), oldest first."""
        cap = self.buf.shape[0]
        if self.head + self.length <= cap:
            return self.buf[self.head : self.head + self.length]
        order = (self.head + np.arange(self.length)) % cap
        return self.buf.take(order, axis=0)

    def take(self, idx: IntArray) -> None:
        """Keep the particles idx (P,) (resampling)."""
        self.buf = self.buf.take(idx, axis=1)


@dataclass
class ParticleSet:
    """The particles (see the module docstring for shapes, units and frames)."""

    q: FloatArray
    v: FloatArray
    log_w: FloatArray
    fric: FloatArray
    modes: FloatArray
    history: MapHistory
    bank: FloatArray | None = None
    copies: int = 1
    copy_log_w: FloatArray | None = None

    @property
    def size(self) -> int:
        """Number of rows of the state arrays (particles x copies)."""
        return int(self.q.shape[0])

    @property
    def count(self) -> int:
        """Number of particles P (weights)."""
        return int(self.log_w.shape[0])

    def resample(self, idx: IntArray) -> None:
        """Replace the set by the particles idx (P,) with equal weights (a particle's copies
        move with it)."""
        rows = idx
        if self.copies > 1:
            rows = (idx[:, None] * self.copies + np.arange(self.copies)).reshape(-1)
        self.q = self.q[rows]
        self.v = self.v[rows]
        self.fric = self.fric[rows]
        self.modes = self.modes[rows]
        if self.bank is not None:
            self.bank = self.bank[idx]
        self.history.take(idx)
        self.log_w = np.zeros(idx.size)

    def resample_copies(self, anc: IntArray, lead: int) -> None:
        """Replace copy b of particle i by copy b of particle anc[i, b] (P, B): each
        hypothesis' copies resampled on their own, with equal copy weights afterwards; the
        history follows hypothesis `lead`'s ancestry (the particle weights are untouched)."""
        rows = (anc * self.copies + np.arange(self.copies)[None, :]).reshape(-1)
        self.q = self.q[rows]
        self.v = self.v[rows]
        self.fric = self.fric[rows]
        self.modes = self.modes[rows]
        self.history.take(anc[:, lead])
        self.copy_log_w = np.zeros(anc.shape)
