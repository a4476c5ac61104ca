"""Time- and space-varying model parameters (Sec. III-C): eq. (7), the grid update (8)-(9)
and the spatial friction map.

Eq. (7) gives the predictive distribution of beta^{l+1} from the current posterior f^l and the
prior f^0 with a weight w^l in [0, 1]. Throughout this module w is the weight ON THE POSTERIOR
(how much of the past is kept), in all three forms:

* ``reuse``:     p = f^l                                   (w ignored)
* ``mixture``:   p = w f^l + (1 - w) f^0
* ``geometric``: p proportional to (f^l)^w (f^0)^(1 - w)

The paper writes the geometric form as (f^0)^w (f^l)^(1-w); we use the same orientation of w as
in the mixture so that, in every form, w = 0 (pair out of contact) relaxes the belief to the
prior and w = 1 keeps the posterior. The filter sets w from the contact state.

Discrete candidates (friction coefficients) use the exact grid update of eqs. (8)-(9):
posterior proportional to likelihood x predictive, in log space.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Literal, get_args

import numpy as np
import numpy.typing as npt

from dbcslam_core.contact_modes import sum_last
from dbcslam_core.errors import ModelError

__all__ = [
    "PARAMETER_MODELS",
    "FrictionMap",
    "FrictionMapView",
    "ParameterModel",
    "grid_update",
    "predict_parameters",
]

FloatArray = npt.NDArray[np.float64]
ParameterModel = Literal["reuse", "mixture", "geometric"]
PARAMETER_MODELS: tuple[str, ...] = get_args(ParameterModel)

_TINY = 1e-300


def predict_parameters(
    posterior: npt.ArrayLike,
    prior: npt.ArrayLike,
    weight: npt.ArrayLike,
    model: str,
) -> FloatArray:
    """Eq. (7): predictive distribution over K discrete parameter values.

    posterior: (..., K) distributions f^l; prior: (K,) f^0; weight: broadcastable to (...)
    in [0, 1], the weight on the posterior. Returns (..., K) distributions (rows sum to 1).
    """
    f = np.asarray(posterior, dtype=np.float64)
    f0 = np.asarray(prior, dtype=np.float64)
    w = np.clip(np.asarray(weight, dtype=np.float64), 0.0, 1.0)[..., None]
    if f.shape[-1] != f0.shape[-1]:
        msg = f"posterior has {f.shape[-1]} candidates but the prior has {f0.shape[-1]}"
        raise ModelError(msg)
    if model == "reuse":
        out = f.copy()
    elif model == "mixture":
        out = w * f + (1.0 - w) * f0
    elif model == "geometric":
        lf = np.log(np.maximum(f, _TINY))
        lf0 = np.log(np.maximum(f0, _TINY))
        lg = w * lf + (1.0 - w) * lf0
        lg = lg - lg.max(axis=-1, keepdims=True)
        out = np.exp(lg)
    else:
        msg = f"unknown parameter model {model!r}; valid models are {list(PARAMETER_MODELS)}"
        raise ModelError(msg)
    if out.shape != f.shape:  # (out is a new array otherwise)
        out = np.broadcast_to(out, np.broadcast_shapes(out.shape, f.shape)).copy()
    s = sum_last(out)[..., None]
    return np.asarray(out / np.where(s > 0.0, s, 1.0), dtype=np.float64)


def grid_update(
    predictive: npt.ArrayLike, log_likelihood: npt.ArrayLike
) -> tuple[FloatArray, FloatArray]:
    """Eq. (8): exact posterior over K grid values, in log space.

    predictive: (..., K) p(beta | past); log_likelihood: (..., K) log p(o | beta).
    Returns (posterior (..., K), log evidence (...) = log sum_k p(o | k) p(k)).
    Rows whose evidence is zero keep the predictive (and get log evidence -inf).
    """
    p = np.asarray(predictive, dtype=np.float64)
    ll = np.asarray(log_likelihood, dtype=np.float64)
    with np.errstate(divide="ignore"):
        lj = np.log(p) + ll
    m = np.max(lj, axis=-1, keepdims=True)
    finite = np.isfinite(m)
    m_safe = np.where(finite, m, 0.0)
    e = np.exp(lj - m_safe)
    s = e.sum(axis=-1, keepdims=True)
    ok = finite & (s > 0.0)
    post = np.where(ok, e / np.where(ok, s, 1.0), p)
    with np.errstate(divide="ignore"):
        log_ev = np.where(ok, m_safe + np.log(np.where(ok, s, 1.0)), -np.inf)[..., 0]
    return np.asarray(post, dtype=np.float64), np.asarray(log_ev, dtype=np.float64)


@dataclass(frozen=True)
class FrictionMapView:
    """Immutable snapshot of the friction map (one 1-D grid per friction pair).

    Cell j of every pair covers s in [s_min + j cell_size, s_min + (j + 1) cell_size), s being
    the contact coordinate along the obstacle tangent (m, see geometry.contact_kinematics).
    probs[p]: (n_cells, K_p) posterior over pair p's candidates per cell (the prior where
    never touched); weight[p]: (n_cells,) accumulated contact evidence weight (0 = untouched).
    """

    s_min: float
    cell_size: float
    n_cells: int
    probs: tuple[FloatArray, ...]
    weight: tuple[FloatArray, ...]

    @property
    def centers(self) -> FloatArray:
        """Cell centres along s, m, shape (n_cells,)."""
        c = self.s_min + (np.arange(self.n_cells, dtype=np.float64) + 0.5) * self.cell_size
        return np.asarray(c, dtype=np.float64)

    def touched(self, pair: int) -> npt.NDArray[np.bool_]:
        """Cells of pair `pair` where contact happened."""
        return self.weight[pair] > 0.0

    def cell_of(self, s: npt.ArrayLike) -> npt.NDArray[np.int64]:
        """Cell index of coordinate(s) s (clipped to the grid)."""
        j = np.floor((np.asarray(s, dtype=np.float64) - self.s_min) / self.cell_size)
        return np.clip(j, 0, self.n_cells - 1).astype(np.int64)


class FrictionMap:
    """Spatial friction map: per friction pair, a posterior over candidates per cell of s.

    Each committed observation of a pair is a (cell, friction distribution, weight) triple
    (the filter commits fixed-lag-smoothed per-particle friction posteriors weighted by particle
    weight x contact probability). The cell belief is the weight-averaged committed
    distribution, i.e. the expected smoothed posterior at the times the contact was in the cell.
    Coordinates outside [s_min, s_max) are clipped to the border cells.
    """

    def __init__(
        self,
        priors: tuple[tuple[float, ...], ...],
        s_min: float = -1.0,
        s_max: float = 1.0,
        cell_size: float = 0.02,
    ) -> None:
        if not (np.isfinite(s_min) and np.isfinite(s_max) and s_max > s_min):
            msg = f"friction map range needs finite s_min < s_max, got [{s_min}, {s_max}]"
            raise ModelError(msg)
        if not (np.isfinite(cell_size) and cell_size > 0.0):
            msg = f"friction map cell_size must be > 0, got {cell_size}"
            raise ModelError(msg)
        self.s_min = float(s_min)
        self.cell_size = float(cell_size)
        self.n_cells = int(np.ceil((s_max - s_min) / cell_size))
        self._priors = [np.asarray(p, dtype=np.float64) for p in priors]
        self._sums = [np.zeros((self.n_cells, p.size)) for p in self._priors]
        self._weight = [np.zeros(self.n_cells) for _ in self._priors]

    def copy(self) -> FrictionMap:
        """An independent copy (same grid, same accumulated evidence)."""
        out = FrictionMap.__new__(FrictionMap)
        out.s_min, out.cell_size, out.n_cells = self.s_min, self.cell_size, self.n_cells
        out._priors = [p.copy() for p in self._priors]
        out._sums = [a.copy() for a in self._sums]
        out._weight = [a.copy() for a in self._weight]
        return out

    @property
    def n_pairs(self) -> int:
        """Number of friction pairs."""
        return len(self._priors)

    def cell_of(self, s: npt.ArrayLike) -> npt.NDArray[np.int64]:
        """Cell index of coordinate(s) s (clipped to the grid)."""
        j = np.floor((np.asarray(s, dtype=np.float64) - self.s_min) / self.cell_size)
        return np.clip(j, 0, self.n_cells - 1).astype(np.int64)

    def add(
        self, pair: int, s: npt.ArrayLike, probs: npt.ArrayLike, weight: npt.ArrayLike
    ) -> None:
        """Commit N observations of pair `pair`: s (N,), probs (N, K_pair), weight (N,) >= 0."""
        if not 0 <= pair < self.n_pairs:
            msg = f"friction pair index {pair} out of range [0, {self.n_pairs})"
            raise ModelError(msg)
        s_a = np.atleast_1d(np.asarray(s, dtype=np.float64))
        p_a = np.asarray(probs, dtype=np.float64).reshape(s_a.size, -1)
        w_a = np.broadcast_to(np.asarray(weight, dtype=np.float64), s_a.shape)
        if p_a.shape[1] != self._priors[pair].size:
            msg = (
                f"pair {pair} has {self._priors[pair].size} candidates, got probabilities "
                f"with {p_a.shape[1]}"
            )
            raise ModelError(msg)
        ok = np.isfinite(s_a) & (w_a > 0.0)
        if not ok.any():
            return
        sums, wsum = self.accumulate(s_a[ok], p_a[ok], w_a[ok])
        self._sums[pair] += sums
        self._weight[pair] += wsum

    def accumulate(
        self, s: FloatArray, probs: FloatArray, weight: FloatArray
    ) -> tuple[FloatArray, FloatArray]:
        """Per-cell sums of weight x probs (n_cells, K) and of weight (n_cells,) of N
        observations s (N,) finite, probs (N, K), weight (N,) > 0: what `add` adds (no
        validation; e.g. for `view(pending=...)`)."""
        cells = self.cell_of(s)
        n = self.n_cells
        wp = weight[:, None] * probs
        n_k = wp.shape[1]
        # one bincount over (cell, candidate) bins (much faster than np.add.at; same order of
        # accumulation per bin as one bincount per candidate)
        bins = (cells[:, None] * n_k + np.arange(n_k)).reshape(-1)
        sums = np.bincount(bins, weights=wp.reshape(-1), minlength=n * n_k).reshape(n, n_k)
        wsum = np.bincount(cells, weights=weight, minlength=n)
        return np.asarray(sums, dtype=np.float64), np.asarray(wsum, dtype=np.float64)

    def posterior(self, pair: int) -> FloatArray:
        """(n_cells, K) per-cell posterior of pair `pair` (the prior in untouched cells)."""
        return self._posterior(pair, self._sums[pair], self._weight[pair])

    def _posterior(self, pair: int, sums: FloatArray, w: FloatArray) -> FloatArray:
        post = np.where(
            w[:, None] > 0.0,
            sums / np.where(w > 0.0, w, 1.0)[:, None],
            self._priors[pair][None, :],
        )
        return np.asarray(post / sum_last(post)[:, None], dtype=np.float64)

    def view(
        self, pending: Sequence[tuple[FloatArray, FloatArray] | None] | None = None
    ) -> FrictionMapView:
        """Immutable snapshot. pending: per pair None or (sums, weights) from `accumulate`
        of observations not (yet) added: the snapshot includes them, the map is unchanged
        (same values as a copy of the map with them added, without the copy)."""
        probs: list[FloatArray] = []
        weight: list[FloatArray] = []
        for p in range(self.n_pairs):
            extra = None if pending is None else pending[p]
            if extra is None:
                sums, w = self._sums[p], self._weight[p].copy()
            else:
                sums, w = self._sums[p] + extra[0], self._weight[p] + extra[1]
            probs.append(self._posterior(p, sums, w))
            weight.append(w)
        return FrictionMapView(
            s_min=self.s_min,
            cell_size=self.cell_size,
            n_cells=self.n_cells,
            probs=tuple(probs),
            weight=tuple(weight),
        )
