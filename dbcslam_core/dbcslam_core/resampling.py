"""Particle resampling schemes behind one Protocol, and effective sample size.

Every resampler maps normalised weights w (shape (P,), sum 1) to ancestor indices (shape (N,),
int64, sorted ascending) such that the expected number of copies of particle i is N w_i
(unbiasedness). Randomness only comes from the explicit `numpy.random.Generator`.

Schemes (`RESAMPLERS` name -> class): `systematic` (one uniform, lowest variance in
practice), `stratified` (one uniform per stratum), `residual` (deterministic floor(N w) copies
plus multinomial on the residuals), `multinomial` (i.i.d. draws).
"""

from __future__ import annotations

import math
from typing import Protocol

import numpy as np
import numpy.typing as npt

from dbcslam_core.errors import ModelError

__all__ = [
    "RESAMPLERS",
    "MultinomialResampler",
    "Resampler",
    "ResidualResampler",
    "StratifiedResampler",
    "SystematicResampler",
    "effective_sample_size",
    "make_resampler",
    "normalise_log_weights",
]

FloatArray = npt.NDArray[np.float64]
IntArray = npt.NDArray[np.int64]


def normalise_log_weights(log_w: npt.ArrayLike) -> tuple[FloatArray, float]:
    """Normalise log weights in log space (max subtracted).

    Returns (w, log_sum): w = exp(log_w - log_sum) sums to 1 and log_sum = logsumexp(log_w).
    Raises ModelError if no weight is finite (all particles impossible) or any is NaN.
    """
    lw = np.asarray(log_w, dtype=np.float64)
    if lw.ndim != 1 or lw.size == 0:
        msg = f"log weights must be a non-empty 1-D array, got shape {lw.shape}"
        raise ModelError(msg)
    m = float(lw.max())  # NaN if any entry is NaN
    if math.isnan(m):
        msg = f"log weights contain NaN at indices {np.flatnonzero(np.isnan(lw))[:10].tolist()}"
        raise ModelError(msg)
    if not math.isfinite(m):
        msg = f"log weights have no finite entry (max = {m}): every particle has zero weight"
        raise ModelError(msg)
    e = np.exp(lw - m)
    s = float(e.sum())
    return e / s, m + float(np.log(s))


def effective_sample_size(weights: npt.ArrayLike) -> float:
    """ESS = 1 / sum(w_i^2) of normalised weights (between 1 and P)."""
    w = np.asarray(weights, dtype=np.float64)
    return float(1.0 / np.sum(w * w))


def _check_weights(weights: npt.ArrayLike) -> FloatArray:
    w = np.asarray(weights, dtype=np.float64)
    if w.ndim != 1 or w.size == 0:
        msg = f"weights must be a non-empty 1-D array, got shape {w.shape}"
        raise ModelError(msg)
    if not np.all(np.isfinite(w)) or np.any(w < 0.0):
        msg = "weights must be finite and >= 0"
        raise ModelError(msg)
    s = float(w.sum())
    if not np.isclose(s, 1.0, rtol=1e-6, atol=1e-9):
        msg = f"weights must sum to 1 (normalise first), got sum {s}"
        raise ModelError(msg)
    return w / s


def _inverse_cdf(w: FloatArray, u: FloatArray) -> IntArray:
    """Indices i with cdf[i-1] <= u < cdf[i] for sorted u in [0, 1)."""
    cdf = np.cumsum(w)
    cdf[-1] = 1.0
    idx = np.searchsorted(cdf, u, side="right")
    return np.minimum(idx, w.size - 1).astype(np.int64)


class Resampler(Protocol):
    """Strategy: draw n ancestor indices from normalised weights."""

    name: str

    def __call__(
        self, weights: npt.ArrayLike, rng: np.random.Generator, n: int | None = None
    ) -> IntArray:
        """Ancestor indices (n,), default n = len(weights), sorted ascending."""
        ...


class SystematicResampler:
    """Systematic resampling: u_j = (j + U) / n with a single U ~ U[0, 1)."""

    name = "systematic"

    def __call__(
        self, weights: npt.ArrayLike, rng: np.random.Generator, n: int | None = None
    ) -> IntArray:
        w = _check_weights(weights)
        n = w.size if n is None else int(n)
        u = (np.arange(n, dtype=np.float64) + rng.random()) / n
        return _inverse_cdf(w, u)


class StratifiedResampler:
    """Stratified resampling: u_j = (j + U_j) / n with independent U_j ~ U[0, 1)."""

    name = "stratified"

    def __call__(
        self, weights: npt.ArrayLike, rng: np.random.Generator, n: int | None = None
    ) -> IntArray:
        w = _check_weights(weights)
        n = w.size if n is None else int(n)
        u = (np.arange(n, dtype=np.float64) + rng.random(n)) / n
        return _inverse_cdf(w, u)


class MultinomialResampler:
    """Multinomial resampling: n i.i.d. draws from the weights."""

    name = "multinomial"

    def __call__(
        self, weights: npt.ArrayLike, rng: np.random.Generator, n: int | None = None
    ) -> IntArray:
        w = _check_weights(weights)
        n = w.size if n is None else int(n)
        u = np.sort(rng.random(n))
        return _inverse_cdf(w, u)


class ResidualResampler:
    """Residual resampling: floor(n w_i) deterministic copies, multinomial on the rest."""

    name = "residual"

    def __call__(
        self, weights: npt.ArrayLike, rng: np.random.Generator, n: int | None = None
    ) -> IntArray:
        w = _check_weights(weights)
        n = w.size if n is None else int(n)
        nw = n * w
        counts = np.floor(nw).astype(np.int64)
        rest = n - int(counts.sum())
        if rest > 0:
            resid = nw - counts
            resid = resid / resid.sum()
            counts += np.bincount(
                _inverse_cdf(resid, np.sort(rng.random(rest))), minlength=w.size
            ).astype(np.int64)
        return np.repeat(np.arange(w.size, dtype=np.int64), counts)


RESAMPLERS: dict[str, type[Resampler]] = {
    "systematic": SystematicResampler,
    "stratified": StratifiedResampler,
    "residual": ResidualResampler,
    "multinomial": MultinomialResampler,
}


def make_resampler(name: str) -> Resampler:
    """Instantiate the resampler called `name` (a key of RESAMPLERS)."""
    try:
        cls = RESAMPLERS[name]
    except KeyError as err:
        msg = f"unknown resampler {name!r}; valid names are {sorted(RESAMPLERS)}"
        raise ModelError(msg) from err
    return cls()
