"""Friction bank: per particle, one copy of the continuous state per friction hypothesis.

`FilterConfig.friction_copies` = `bank` (and the row helpers of `filters`). Particle i (a
*bank*) carries B sub-particles (i, b), one per
joint friction hypothesis b, each with its own pose q, twist v and per-contact mode marginals,
moved by the reduced dynamics with friction b only (a fixed-friction filter per b) and driven
by the same random numbers (`shared_uniform`, `shared_normal`: the copies differ only through
their friction). The bank's friction belief fric[i, b] is updated by the predictive likelihood
of its b-copy, L[i, b] = p(o_l | sub-particle (i, b)):

    fric_post[i, b] = fric[i, b] L[i, b] / sum_b' fric[i, b'] L[i, b'],
    bank evidence   = sum_b fric[i, b] L[i, b]   (the particle weight increment),

and resampling moves whole banks. Unlike the single-copy filter, no friction hypothesis is
ever sampled into a particle's trajectory, so the belief cannot turn one-hot on the candidate
that one noisy velocity sample happened to favour at an impact: the evidence of each b
accumulates over its copy's own trajectory (the fixed-friction filters' marginal likelihoods).
Its weakness (measured, README "Known weakness"): a copy is never selected on its own fit,
so once a bank's belief leads with one b its other copies are carried along by that lead
and drift off the observations, which reinforces the lead.

Rows: sub-particle (i, b) is row i * B + b of the (P * B, ...) arrays. Pure numpy, vectorised
over (banks, friction hypotheses); no loop over particles.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from dbcslam_core.observation import GaussianProposal, _chol_entries, wrap_angle
from dbcslam_core.particles import ParticleSet

__all__ = [
    "FrictionBank",
    "bank_mean",
    "bank_rows",
    "combine_evidence",
    "sample_shared_proposal",
    "shared_normal",
    "shared_uniform",
    "weighted_rows",
]

FloatArray = npt.NDArray[np.float64]
IntArray = npt.NDArray[np.int64]


def bank_rows(idx: npt.ArrayLike, n_b: int) -> IntArray:
    """Rows (len(idx) * B,) of the sub-particles of banks idx: i * B + b, b = 0..B-1."""
    i = np.asarray(idx, dtype=np.int64).reshape(-1)
    return np.asarray((i[:, None] * n_b + np.arange(n_b)[None, :]).reshape(-1), dtype=np.int64)


def shared_uniform(
    rng: np.random.Generator, n_banks: int, n_b: int, tail: tuple[int, ...]
) -> FloatArray:
    """Uniform(0, 1) draws (n_banks * B, *tail), equal for the B copies of a bank."""
    u = rng.random((n_banks, *tail))
    return np.asarray(np.repeat(u, n_b, axis=0), dtype=np.float64)


def shared_normal(
    rng: np.random.Generator, n_banks: int, n_b: int, tail: tuple[int, ...]
) -> FloatArray:
    """Standard normal draws (n_banks * B, *tail), equal for the B copies of a bank."""
    z = rng.standard_normal((n_banks, *tail))
    return np.asarray(np.repeat(z, n_b, axis=0), dtype=np.float64)


def combine_evidence(fric: FloatArray, sub_log_lik: FloatArray) -> tuple[FloatArray, FloatArray]:
    """Bank evidence and friction posterior from the copies' log predictive likelihoods.

    fric (P, B) the predictive friction belief; sub_log_lik (P * B,) log L of each copy.
    Returns (log sum_b fric L (P,), fric_post (P, B)); a bank whose copies all have zero
    likelihood gets -inf and keeps its belief. Log space, max subtracted.
    """
    n_p, n_b = fric.shape
    with np.errstate(divide="ignore"):
        log_joint = np.log(fric) + sub_log_lik.reshape(n_p, n_b)
    m = log_joint.max(axis=1, keepdims=True)
    m = np.where(np.isfinite(m), m, 0.0)
    e = np.exp(log_joint - m)
    tot = e.sum(axis=1, keepdims=True)
    with np.errstate(divide="ignore"):
        incr = (np.log(tot) + m)[:, 0]
    fric_post = np.where(tot > 0.0, e / np.where(tot > 0.0, tot, 1.0), fric)
    return np.asarray(incr, dtype=np.float64), np.asarray(fric_post, dtype=np.float64)


def weighted_rows(x: FloatArray, weight: FloatArray) -> FloatArray:
    """sum_b weight[i, b] x[i * B + b] -> (P, ...) for rows x (P * B, ...), weight (P, B)."""
    n_p, n_b = weight.shape
    xs = x.reshape(n_p, n_b, -1)
    out = np.einsum("pb,pbk->pk", weight, xs)
    return np.asarray(out.reshape((n_p, *x.shape[1:])), dtype=np.float64)


def bank_mean(q: FloatArray, weight: FloatArray, *, angular: bool) -> FloatArray:
    """Weighted mean state per bank (P, n) of rows q (P * B, n) under weight (P, B) (rows of
    weight sum to 1). angular: the last column is an angle (rad), averaged as the wrapped
    offsets from each bank's first copy."""
    if not angular:
        return weighted_rows(q, weight)
    n_p, n_b = weight.shape
    qs = q.reshape(n_p, n_b, -1).copy()
    ref = qs[:, :1, -1]
    qs[..., -1] = ref + wrap_angle(qs[..., -1] - ref)
    out = np.einsum("pb,pbk->pk", weight, qs)
    out[:, -1] = wrap_angle(out[:, -1])
    return np.asarray(out, dtype=np.float64)


def sample_shared_proposal(
    prop: GaussianProposal,
    *,
    v_h: FloatArray,
    innovation: FloatArray,
    v_mean: FloatArray,
    v_cov: FloatArray,
    dt: float,
    z_v: FloatArray,
    z_q: FloatArray,
) -> tuple[FloatArray, FloatArray]:
    """`observation.sample_gaussian_proposal` with given standard normals z_v, z_q (N, nq)
    (e.g. `shared_normal`): v' = v_mean + chol(v_cov) z_v, then e_q | v', o. The same
    operations as the rng-driven version (equal results for equal normals)."""
    cov = 0.5 * (v_cov + np.swapaxes(v_cov, -1, -2))
    n = v_mean.shape[-1]
    diag = np.abs(np.diagonal(cov, axis1=-2, axis2=-1))
    scale = diag[..., 0]
    for i in range(1, n):  # max over the (short) diagonal
        scale = np.maximum(scale, diag[..., i])
    ar = np.arange(n)
    cov[..., ar, ar] += 1e-12 * np.maximum(scale, 1e-300)[..., None]  # jitter on the diagonal
    low = _chol_entries(cov)
    corr = np.stack(
        [
            sum((low[i][k] * z_v[..., k] for k in range(1, i + 1)), low[i][0] * z_v[..., 0])
            for i in range(n)
        ],
        axis=-1,
    )
    v_new = v_mean + corr
    r = innovation - dt * (v_new - v_h)
    q_mean = np.where(prop.observed, prop.q_gain * r, 0.0)
    e_q = q_mean + prop.q_std * z_q
    return np.asarray(v_new, dtype=np.float64), np.asarray(e_q, dtype=np.float64)


@dataclass
class FrictionBank:
    """Bank-level state: friction belief fric (P, B) over the joint friction hypotheses and
    unnormalised log weights log_w (P,). The copies themselves are rows of a `ParticleSet`
    (row i * B + b)."""

    fric: FloatArray
    log_w: FloatArray

    @property
    def size(self) -> int:
        """Number of banks P."""
        return int(self.fric.shape[0])

    @property
    def n_b(self) -> int:
        """Copies per bank B."""
        return int(self.fric.shape[1])

    def resample(self, idx: IntArray, rows: ParticleSet) -> None:
        """Replace the banks by banks idx (P,) with equal weights, moving their copies
        (rows of `rows`) with them."""
        rows.resample(bank_rows(idx, self.n_b))
        self.fric = self.fric[idx]
        self.log_w = np.zeros(idx.size)
