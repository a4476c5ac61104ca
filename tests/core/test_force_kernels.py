"""The compiled force likelihood (`force_kernels`) equals the numpy reference
(`force_likelihood.force_log_likelihood`, axes "normal") to round-off, for any row split."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from dbcslam_core import force_kernels
from dbcslam_core.force_likelihood import force_log_likelihood
from dbcslam_core.row_pool import RowPool

pytestmark = pytest.mark.skipif(not force_kernels.AVAILABLE, reason="numba not installed")


def _problem(seed: int, n_c: int, n_b: int, nv: int) -> dict[str, np.ndarray]:
    rng = np.random.default_rng(seed)
    n_r = int(rng.integers(1, 12))
    counts = rng.integers(0, 5, size=n_r)
    starts = np.concatenate([[0], np.cumsum(counts)])
    n_e = int(starts[-1])
    ang = rng.uniform(-np.pi, np.pi, size=(n_r, n_c))
    normal = np.stack([np.cos(ang), np.sin(ang)], axis=-1)  # unit normals (R, C, 2)
    ln = np.abs(rng.normal(size=(n_e, n_b, n_c))) * 0.05 * (rng.random((n_e, 1, n_c)) < 0.7)
    lt = rng.normal(size=(n_e, n_b, n_c)) * 0.02
    ir = rng.normal(size=(n_e, n_b, 2, n_c, nv)) * 0.3
    sel = np.flatnonzero(rng.random(n_c) < 0.6)
    if sel.size == 0:
        sel = np.array([0])
    return {
        "starts": starts,
        "normal": normal,
        "ln": ln,
        "lt": lt,
        "ir": ir,
        "sel": sel,
        "sig2": rng.uniform(0.01, 1.0, size=nv),
        "reading": rng.normal(size=2) * 3.0,
    }


def _reference(pb: dict[str, np.ndarray], *, with_ir: bool, frac: float) -> np.ndarray:
    pi = np.repeat(np.arange(pb["starts"].size - 1), np.diff(pb["starts"]))
    sel = pb["sel"]
    return force_log_likelihood(
        pb["reading"],
        0.2,
        pb["normal"][pi][:, None][:, :, sel, :],
        pb["ln"][..., sel],
        pb["lt"][..., sel],
        dt=0.01,
        impulse_response=pb["ir"][..., sel, :] if with_ir else None,
        sig2=pb["sig2"] if with_ir else None,
        axes="normal",
        outlier_fraction=frac,
    )


def _compiled(
    pb: dict[str, np.ndarray], *, with_ir: bool, frac: float, pool: RowPool | None = None
) -> np.ndarray:
    return force_kernels.normal_force_log_likelihood(
        pb["starts"],
        (float(pb["reading"][0]), float(pb["reading"][1])),
        std=0.2,
        normal=pb["normal"],
        sel=pb["sel"],
        ln=pb["ln"],
        lt=pb["lt"],
        dt=0.01,
        impulse_response=pb["ir"] if with_ir else None,
        sig2=pb["sig2"] if with_ir else None,
        outlier_fraction=frac,
        pool=pool,
    )


@settings(max_examples=40, deadline=None)
@given(
    seed=st.integers(0, 10_000),
    n_c=st.integers(1, 4),
    n_b=st.sampled_from([1, 3, 9]),
    nv=st.sampled_from([2, 3]),
    with_ir=st.booleans(),
    frac=st.sampled_from([0.0, 0.02, 0.3]),
)
def test_compiled_force_likelihood_equals_numpy(
    seed: int, n_c: int, n_b: int, nv: int, with_ir: bool, frac: float
) -> None:
    pb = _problem(seed, n_c, n_b, nv)
    ref = _reference(pb, with_ir=with_ir, frac=frac)
    got = _compiled(pb, with_ir=with_ir, frac=frac)
    assert got.shape == ref.shape
    np.testing.assert_allclose(got, ref, rtol=1e-12, atol=1e-12)


def test_row_split_does_not_change_the_result() -> None:
    pb = _problem(7, 3, 9, 3)
    pb["starts"] = np.arange(0, 4001, 4)  # 1000 rows of 4 entries: several ranges
    n_e = 4000
    rng = np.random.default_rng(1)
    pb["normal"] = np.repeat(pb["normal"][:1], 1000, axis=0)
    pb["ln"] = np.abs(rng.normal(size=(n_e, 9, 3))) * 0.05
    pb["lt"] = rng.normal(size=(n_e, 9, 3)) * 0.02
    pb["ir"] = rng.normal(size=(n_e, 9, 2, 3, 3)) * 0.3
    one = _compiled(pb, with_ir=True, frac=0.02)
    pool = RowPool(2)
    try:
        assert len(pool.chunks(1000, starts=pb["starts"], min_work=512)) == 2
        two = _compiled(pb, with_ir=True, frac=0.02, pool=pool)
    finally:
        pool.close()
    np.testing.assert_array_equal(one, two)


@pytest.mark.parametrize(
    ("change", "match"),
    [
        ({"outlier_fraction": 1.0}, "outlier_fraction"),
        ({"outlier_std": 0.0}, "outlier_std"),
        ({"sig2": None}, "both or neither"),
    ],
)
def test_bad_parameters_are_named(change: dict[str, object], match: str) -> None:
    pb = _problem(3, 2, 3, 3)
    kwargs: dict[str, object] = {
        "std": 0.2,
        "normal": pb["normal"],
        "sel": pb["sel"],
        "ln": pb["ln"],
        "lt": pb["lt"],
        "dt": 0.01,
        "impulse_response": pb["ir"],
        "sig2": pb["sig2"],
        **change,
    }
    with pytest.raises(ValueError, match=match):
        force_kernels.normal_force_log_likelihood(pb["starts"], (0.0, 0.0), **kwargs)  # type: ignore[arg-type]
