"""Compiled force likelihood of the filter step (numba): `force_likelihood.force_log_likelihood`
for what `DbcSlamFilter` asks of a force reading (e.g. `/pusher/wrench`): the component along
the mean contact normal (axes "normal"), the impulse sensitivity widening the predicted force,
the contaminated Gaussian, no preload allowance. One loop over the live entries of each row
instead of ~25 numpy passes over (entries, friction, ...) temporaries (push, 500 particles:
2.4 ms of a 7.4 ms step).

The numpy function is the reference: the kernel computes the same expressions per element
(the quadratic form n^T S n summed in another order), equal to round-off
(`tests/core/test_force_kernels.py`). Any other configuration (axes "both", a preload bound,
numba missing) takes the numpy function.

Frames and units as in `force_likelihood`: world frame (REP-103), forces in N, impulses in
N s, time in s.
"""

from __future__ import annotations

import math

import numpy as np
import numpy.typing as npt

from dbcslam_core import kernels
from dbcslam_core.force_likelihood import OUTLIER_FRACTION, OUTLIER_STD, check_outlier_model
from dbcslam_core.row_pool import RowPool

__all__ = ["AVAILABLE", "normal_force_log_likelihood", "warm_up"]

FloatArray = npt.NDArray[np.float64]
IntArray = npt.NDArray[np.int64]

AVAILABLE = kernels.AVAILABLE

_LN2 = math.log(2.0)
_MIN_ENTRIES = 512
"""Fewest live entries per thread (~50 us of work; smaller problems run in the caller)."""


def _logaddexp(a: float, b: float) -> float:
    """`np.logaddexp` of two floats (the same branches)."""
    if a == b:
        return a + _LN2
    d = a - b
    if d > 0.0:
        return a + math.log1p(math.exp(-d))
    if d <= 0.0:
        return b + math.log1p(math.exp(d))
    return a + b  # a NaN


def _force_kernel(  # noqa: PLR0917 - numba entry point: positional arrays
    starts: IntArray,
    normal: FloatArray,
    sel: IntArray,
    ln: FloatArray,
    lt: FloatArray,
    ir: FloatArray,
    has_ir: bool,
    sig2: FloatArray,
    params: FloatArray,
    out: FloatArray,
    lo: int,
    hi: int,
) -> None:
    """out[n, b] = log p(f | entry n, friction b) for the entries of rows lo .. hi - 1.

    params = (fx, fy, std, dt, outlier fraction, outlier std)."""
    fx, fy, std, dt, frac, o_std = params[0], params[1], params[2], params[3], params[4], params[5]
    n_b = ln.shape[1]
    nv = sig2.shape[0]
    n_s = sel.shape[0]
    log_keep = math.log1p(-frac) if frac > 0.0 else 0.0
    log_frac = math.log(frac) if frac > 0.0 else 0.0
    out2 = o_std * o_std
    gn = np.empty(nv)
    for p in range(lo, hi):
        if starts[p + 1] == starts[p]:
            continue
        nbx = 0.0
        nby = 0.0
        for k in range(n_s):
            nbx += normal[p, sel[k], 0]
            nby += normal[p, sel[k], 1]
        den = max(math.sqrt(nbx * nbx + nby * nby), 1e-12)
        nbx = nbx / den
        nby = nby / den
        for n in range(starts[p], starts[p + 1]):
            for b in range(n_b):
                sx = 0.0
                sy = 0.0
                for k in range(n_s):
                    c = sel[k]
                    nx = normal[p, c, 0]
                    ny = normal[p, c, 1]
                    # t = (ny, -nx): the tangent of `force_likelihood.predicted_force`
                    sx += nx * ln[n, b, c] + ny * lt[n, b, c]
                    sy += ny * ln[n, b, c] + (-nx) * lt[n, b, c]
                rx = fx - (-sx / dt)
                ry = fy - (-sy / dt)
                rn = rx * nbx + ry * nby
                vn = std * std * (nbx * nbx + nby * nby)
                if has_ir:  # + n^T G diag(sig2) G^T n, G = d f / d v_free (2, nv)
                    for v in range(nv):
                        g_x = 0.0
                        g_y = 0.0
                        for k in range(n_s):
                            c = sel[k]
                            nx = normal[p, c, 0]
                            ny = normal[p, c, 1]
                            g_x += nx * ir[n, b, 0, c, v] + ny * ir[n, b, 1, c, v]
                            g_y += ny * ir[n, b, 0, c, v] + (-nx) * ir[n, b, 1, c, v]
                        gn[v] = (-g_x / dt) * nbx + (-g_y / dt) * nby
                    for v in range(nv):
                        vn += gn[v] * sig2[v] * gn[v]
                ll = -0.5 * (rn * rn / vn + math.log(2.0 * math.pi * vn))
                if frac > 0.0:
                    vo = vn + out2
                    llo = -0.5 * (rn * rn / vo + math.log(2.0 * math.pi * vo))
                    ll = _logaddexp(log_keep + ll, log_frac + llo)
                out[n, b] = ll


if AVAILABLE:
    import numba

    _logaddexp = numba.njit(cache=True, nogil=True, inline="always")(_logaddexp)
    _force_kernel = numba.njit(cache=True, nogil=True, error_model="numpy")(_force_kernel)


def normal_force_log_likelihood(
    starts: IntArray,
    reading: tuple[float, float],
    *,
    std: float,
    normal: FloatArray,
    sel: IntArray,
    ln: FloatArray,
    lt: FloatArray,
    dt: float,
    impulse_response: FloatArray | None = None,
    sig2: FloatArray | None = None,
    outlier_fraction: float = OUTLIER_FRACTION,
    outlier_std: float = OUTLIER_STD,
    pool: RowPool | None = None,
) -> FloatArray:
    """log p(f | entry, friction) (N, B) of a force reading, component along the mean contact
    normal (`force_likelihood.force_log_likelihood` with axes "normal", no preload).

    starts (R + 1,): row p holds the entries starts[p] .. starts[p + 1]; reading (fx, fy)
    (N, world frame, the force on the obstacle); std: reading noise std (N); normal (R, C, 2)
    contact normals of every contact of each row (into the body); sel (Cs,) the indices of
    the obstacle's contacts; ln, lt (N, B, C) the entries' impulses (N s); impulse_response
    (N, B, 2, C, nv) = d (ln, lt) / d v_free and sig2 (nv,) the velocity process-noise
    variances (both or neither); dt: step (s); outlier_fraction in [0, 1), outlier_std (N,
    > 0): the gross-error component. pool: threads over ranges of rows (same output for any
    split).

    Raises:
        ValueError: bad outlier parameters or impulse_response without sig2.
    """
    check_outlier_model(outlier_fraction, outlier_std)
    if (impulse_response is None) != (sig2 is None):
        msg = "impulse_response and sig2 go together (both or neither)"
        raise ValueError(msg)
    n_e, n_b = ln.shape[:2]
    nv = normal.shape[-1] if sig2 is None else int(np.shape(sig2)[0])
    out = np.empty((n_e, n_b))
    c = np.ascontiguousarray
    starts = c(starts, dtype=np.int64)
    args = (
        starts,
        c(normal, dtype=np.float64),
        c(sel, dtype=np.int64),
        c(ln, dtype=np.float64),
        c(lt, dtype=np.float64),
        np.zeros((0, n_b, 2, ln.shape[2], nv))
        if impulse_response is None
        else c(impulse_response),
        impulse_response is not None,
        np.zeros(nv) if sig2 is None else c(sig2, dtype=np.float64),
        np.array([reading[0], reading[1], std, dt, outlier_fraction, outlier_std], dtype=float),
        out,
    )
    n_r = starts.shape[0] - 1
    bounds = [(0, n_r)] if pool is None else pool.chunks(n_r, starts=starts, min_work=_MIN_ENTRIES)
    if pool is None or len(bounds) == 1:
        for lo, hi in bounds:
            _force_kernel(*args, lo, hi)
    else:
        pool.map(lambda lo, hi: _force_kernel(*args, lo, hi), bounds)
    return out


def warm_up(nv: int = 3) -> None:
    """Load (or compile) the kernel on a one-entry problem."""
    if not AVAILABLE:
        return
    normal_force_log_likelihood(
        np.array([0, 1]),
        (0.0, 0.0),
        std=0.2,
        normal=np.array([[[1.0, 0.0]]]),
        sel=np.array([0]),
        ln=np.zeros((1, 1, 1)),
        lt=np.zeros((1, 1, 1)),
        dt=0.01,
        impulse_response=np.zeros((1, 1, 2, 1, nv)),
        sig2=np.ones(nv),
    )
