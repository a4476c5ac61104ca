"""Accuracy metrics of a filter run against ground truth, on plain numpy arrays.

Conventions (shared by every function here):

* time runs along axis 0 (T steps);
* positions are in metres in the `world` frame, yaw in radians (counter-clockwise about +z);
* contact-mode probabilities have shape (T, C, 4) in the mode order of
  :class:`dbcslam_core.contact_modes.Mode` (separated, sticking, sliding_pos, sliding_neg);
  true modes are integer codes of shape (T, C);
* friction posteriors have shape (T, B) (one pair) or (T, P, B) (P pairs, B candidates).

Every function validates shapes and raises :class:`~dbcslam_core.errors.ModelError` naming the
offending shape; none returns NaN silently: a metric over an empty selection (for example the
stick/slide accuracy of a run that never touched) raises unless ``empty`` is given.
"""

from __future__ import annotations

from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from dbcslam_core.angles import wrap_angle
from dbcslam_core.contact_modes import Mode
from dbcslam_core.errors import ModelError

__all__ = [
    "contact_accuracy",
    "contact_mode_accuracy",
    "final_true_friction_posterior",
    "friction_map_accuracy",
    "position_rmse",
    "slid_cells",
    "stick_slide_accuracy",
    "wrap_angle",
    "yaw_rmse",
]

FloatArray = NDArray[np.float64]


def _as_float(name: str, a: ArrayLike) -> FloatArray:
    arr = np.asarray(a, dtype=np.float64)
    if not np.all(np.isfinite(arr)):
        msg = f"{name} contains NaN or inf values; metrics need finite inputs"
        raise ModelError(msg)
    return arr


def _same_shape(name_a: str, a: NDArray[Any], name_b: str, b: NDArray[Any]) -> None:
    if a.shape != b.shape:
        msg = f"{name_a} has shape {a.shape} but {name_b} has shape {b.shape}; they must match"
        raise ModelError(msg)


def _mean_or(values: NDArray[np.bool_], what: str, empty: float | None) -> float:
    if values.size == 0:
        if empty is None:
            msg = f"{what}: no steps to score (empty selection); pass empty=... to allow it"
            raise ModelError(msg)
        return float(empty)
    return float(np.mean(values))


def position_rmse(estimate: ArrayLike, truth: ArrayLike, *, per_axis: bool = True) -> float:
    """Root-mean-square position error (m).

    Args:
        estimate: estimated positions, shape (T, D) (D = 2 for x, y), m.
        truth: true positions, same shape, m.
        per_axis: if True (default) the mean runs over steps *and* axes, i.e. the RMS error of
            one coordinate, directly comparable to a per-axis observation noise std; if False
            it is the RMS of the Euclidean error norm (= sqrt(D) times larger for isotropic
            errors).
    """
    est = _as_float("estimate", estimate)
    tru = _as_float("truth", truth)
    _same_shape("estimate", est, "truth", tru)
    if est.ndim != 2 or est.shape[0] == 0:
        msg = f"positions must have shape (T, D) with T > 0, got {est.shape}"
        raise ModelError(msg)
    sq = (est - tru) ** 2
    if per_axis:
        return float(np.sqrt(np.mean(sq)))
    return float(np.sqrt(np.mean(np.sum(sq, axis=1))))


def yaw_rmse(estimate: ArrayLike, truth: ArrayLike) -> float:
    """Root-mean-square yaw error (rad), with each difference wrapped to [-pi, pi)."""
    est = _as_float("estimate", estimate)
    tru = _as_float("truth", truth)
    _same_shape("estimate", est, "truth", tru)
    if est.size == 0:
        msg = "yaw arrays are empty; need at least one step"
        raise ModelError(msg)
    return float(np.sqrt(np.mean(wrap_angle(est - tru) ** 2)))


def _modes_pair(mode_probs: ArrayLike, true_modes: ArrayLike) -> tuple[FloatArray, NDArray[Any]]:
    p = _as_float("mode_probs", mode_probs)
    t = np.asarray(true_modes)
    if p.ndim == 2:  # (T, 4): one contact
        p = p[:, None, :]
    if t.ndim == 1:
        t = t[:, None]
    if p.ndim != 3 or p.shape[-1] != len(Mode):
        msg = f"mode_probs must have shape (T, C, {len(Mode)}), got {p.shape}"
        raise ModelError(msg)
    if t.shape != p.shape[:2]:
        msg = f"true_modes has shape {t.shape}, expected {p.shape[:2]} to match mode_probs"
        raise ModelError(msg)
    if not np.issubdtype(t.dtype, np.integer):
        ti = t.astype(np.int64)
        if not np.array_equal(ti, t):
            msg = "true_modes must hold integer mode codes 0..3"
            raise ModelError(msg)
        t = ti
    if t.size and (t.min() < 0 or t.max() >= len(Mode)):
        msg = f"true_modes must be in 0..{len(Mode) - 1}, got range [{t.min()}, {t.max()}]"
        raise ModelError(msg)
    return p, t


def contact_accuracy(
    mode_probs: ArrayLike, true_modes: ArrayLike, *, empty: float | None = None
) -> float:
    """Fraction of (step, contact) entries where "in contact" is classified right.

    Estimated in contact: P(not separated) = 1 - P(separated) > 0.5. True in contact: the true
    mode is not SEPARATED.

    Args:
        mode_probs: (T, C, 4) or (T, 4) mode probabilities.
        true_modes: (T, C) or (T,) integer true modes.
    """
    p, t = _modes_pair(mode_probs, true_modes)
    est = (1.0 - p[..., Mode.SEPARATED]) > 0.5
    tru = t != Mode.SEPARATED
    return _mean_or(est == tru, "contact_accuracy", empty)


def stick_slide_accuracy(
    mode_probs: ArrayLike, true_modes: ArrayLike, *, empty: float | None = None
) -> float:
    """Stick/slide classification accuracy over the entries that are truly in contact.

    Estimated sticking: P(sticking) > P(sliding_pos) + P(sliding_neg) (the decision given
    contact, independent of P(separated)). Scored only where the true mode is not SEPARATED.
    """
    p, t = _modes_pair(mode_probs, true_modes)
    in_contact = t != Mode.SEPARATED
    est_stick = p[..., Mode.STICKING] > (p[..., Mode.SLIDING_POS] + p[..., Mode.SLIDING_NEG])
    tru_stick = t == Mode.STICKING
    return _mean_or((est_stick == tru_stick)[in_contact], "stick_slide_accuracy", empty)


def contact_mode_accuracy(
    mode_probs: ArrayLike,
    true_modes: ArrayLike,
    *,
    mask: ArrayLike | None = None,
    empty: float | None = None,
) -> float:
    """Fraction of entries where argmax over the 4 modes equals the true mode.

    Args:
        mode_probs: (T, C, 4) or (T, 4) mode probabilities.
        true_modes: (T, C) or (T,) integer true modes.
        mask: optional boolean (T, C) selection of the entries to score (e.g. truly in contact).
    """
    p, t = _modes_pair(mode_probs, true_modes)
    hit = np.argmax(p, axis=-1) == t
    if mask is not None:
        m = np.asarray(mask, dtype=bool)
        if m.ndim == 1:
            m = m[:, None]
        if m.shape != hit.shape:
            msg = f"mask has shape {m.shape}, expected {hit.shape}"
            raise ModelError(msg)
        hit = hit[m]
    return _mean_or(hit, "contact_mode_accuracy", empty)


def slid_cells(
    s: ArrayLike, true_modes: ArrayLike, cell_edges: ArrayLike, *, include_sticking: bool = False
) -> NDArray[np.bool_]:
    """Which friction-map cells the body truly slid over.

    Args:
        s: (T,) true contact coordinate along the obstacle tangent (m), e.g. x on the edge.
        true_modes: (T,) integer true modes of that contact.
        cell_edges: (N + 1,) increasing cell boundaries (m).
        include_sticking: also count cells where the contact was only sticking.

    Returns:
        (N,) boolean mask of cells visited while sliding (or in contact, if include_sticking).
    """
    sv = _as_float("s", s).reshape(-1)
    tm = np.asarray(true_modes).reshape(-1)
    edges = _as_float("cell_edges", cell_edges).reshape(-1)
    if sv.shape != tm.shape:
        msg = f"s has shape {sv.shape} but true_modes has shape {tm.shape}"
        raise ModelError(msg)
    if edges.size < 2 or np.any(np.diff(edges) <= 0.0):
        msg = "cell_edges must be strictly increasing with at least 2 entries"
        raise ModelError(msg)
    sel = np.isin(tm, (Mode.SLIDING_POS, Mode.SLIDING_NEG))
    if include_sticking:
        sel |= tm == Mode.STICKING
    sv = sv[sel]
    inside = (sv >= edges[0]) & (sv < edges[-1])
    idx = np.searchsorted(edges, sv[inside], side="right") - 1
    out = np.zeros(edges.size - 1, dtype=bool)
    out[idx] = True
    return out


def friction_map_accuracy(
    cell_posterior: ArrayLike,
    true_index: ArrayLike,
    cells: ArrayLike,
    *,
    threshold: float = 0.5,
    empty: float | None = None,
) -> float:
    """Fraction of selected cells whose true friction candidate has posterior > threshold.

    Args:
        cell_posterior: (N, B) per-cell posterior over the B friction candidates (rows may be
            NaN for never-touched cells; those count as wrong if selected).
        true_index: (N,) index of the true candidate in each cell (value at the cell centre).
        cells: (N,) boolean selection, normally :func:`slid_cells`.
        threshold: posterior the true candidate must exceed.
    """
    post = np.asarray(cell_posterior, dtype=np.float64)
    ti = np.asarray(true_index).astype(np.int64).reshape(-1)
    sel = np.asarray(cells, dtype=bool).reshape(-1)
    if post.ndim != 2 or post.shape[0] != ti.size or sel.size != ti.size:
        msg = (
            f"cell_posterior {post.shape}, true_index {ti.shape} and cells {sel.shape} "
            "must be (N, B), (N,), (N,)"
        )
        raise ModelError(msg)
    if ti.size and (ti.min() < 0 or ti.max() >= post.shape[1]):
        msg = f"true_index must be in 0..{post.shape[1] - 1}"
        raise ModelError(msg)
    p_true = post[np.arange(ti.size), ti]
    ok = np.where(np.isfinite(p_true), p_true, -np.inf) > threshold
    return _mean_or(ok[sel], "friction_map_accuracy", empty)


def final_true_friction_posterior(posterior: ArrayLike, true_index: ArrayLike | int) -> float:
    """Posterior of the true friction candidate at the last step.

    Args:
        posterior: (T, B) or (T, P, B) friction posteriors over time.
        true_index: index of the true candidate (int, or (P,) per pair).

    Returns:
        The probability for a single pair; for several pairs the minimum over pairs.
    """
    post = _as_float("posterior", posterior)
    if post.ndim == 2:
        post = post[:, None, :]
    if post.ndim != 3 or post.shape[0] == 0:
        msg = f"posterior must have shape (T, B) or (T, P, B) with T > 0, got {post.shape}"
        raise ModelError(msg)
    ti = np.broadcast_to(np.asarray(true_index, dtype=np.int64), (post.shape[1],))
    if ti.min() < 0 or ti.max() >= post.shape[2]:
        msg = f"true_index {true_index!r} out of range 0..{post.shape[2] - 1}"
        raise ModelError(msg)
    return float(np.min(post[-1, np.arange(post.shape[1]), ti]))
