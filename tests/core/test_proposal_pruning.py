"""The proposal's pruning of negligible (entry, friction) elements (`step_kernels.PRUNE_NATS`)
changes nothing but round-off: the same draws, evidence and sampled states, posteriors within
e^-PRUNE_NATS, on rows whose weights span hundreds of nats."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from dbcslam_core import step_kernels

pytestmark = pytest.mark.skipif(not step_kernels.AVAILABLE, reason="numba not installed")

N_F, NV, N_C = 3, 3, 4


def _problem(seed: int, shared: bool) -> dict[str, object]:
    rng = np.random.default_rng(seed)
    n_r = 40
    counts = rng.integers(1, 9, size=n_r)
    starts = np.concatenate([[0], np.cumsum(counts)])
    n_e = int(starts[-1])
    md = rng.integers(0, 4, size=(n_e, N_C))
    if shared:  # v_h, cov of an entry without sliding contacts are the same for every f
        md[rng.random(n_e) < 0.5] %= 2
    sig2 = rng.uniform(0.5, 2.0, size=NV) * 1e-2
    a = rng.normal(size=(n_e, N_F, NV, NV)) * 0.1
    cov = a @ np.swapaxes(a, -1, -2) + 0.01 * np.diag(sig2)
    v_h = rng.normal(size=(n_e, N_F, NV)) * 0.05
    if shared:
        still = ~(md >= 2).any(axis=1)
        cov[still] = cov[still][:, :1]
        v_h[still] = v_h[still][:, :1]
    # log weights spread over hundreds of nats: most elements are negligible
    log_alpha = -rng.exponential(150.0, size=(n_e, N_F))
    log_alpha[rng.random((n_e, N_F)) < 0.05] = -np.inf
    k_max = int(counts.max())
    value = rng.normal(size=NV) * 0.1
    return {
        "starts": starts,
        "md": md,
        "q": value + rng.normal(size=(n_r, NV)) * 2e-3,  # particles near the reading
        "v_h": v_h,
        "cov": cov,
        "log_alpha": log_alpha,
        "observation": (
            value,
            np.array([False, False, True]),
            np.diag([4e-6, 4e-6, 1e-4]),
        ),
        "q_gain": rng.uniform(0.1, 0.9, size=NV),
        "q_std": rng.uniform(1e-4, 1e-3, size=NV),
        "dt": 0.01,
        "shared": shared,
        "uniforms": rng.random((n_r, k_max * N_F)),
        "copies": 1,
        "z_v": rng.normal(size=(n_r, NV)),
        "z_q": rng.normal(size=(n_r, NV)),
        "pair_mask": np.ones((1, N_C), dtype=bool),
        "cov_floor": 0.01 * sig2,
    }


@settings(max_examples=30, deadline=None)
@given(seed=st.integers(0, 10_000), shared=st.booleans(), observed=st.booleans())
def test_pruning_changes_nothing_but_round_off(seed: int, shared: bool, observed: bool) -> None:
    pb = _problem(seed, shared)
    if not observed:
        pb["observation"] = None
    starts = pb.pop("starts")
    md = pb.pop("md")
    pruned = step_kernels.propose_rows(starts, md, **pb)  # type: ignore[arg-type]
    full = step_kernels.propose_rows(starts, md, **pb, prune=False)  # type: ignore[arg-type]
    for name in ("incr", "v_new", "q_new"):  # the same draw of every row
        np.testing.assert_allclose(pruned[name], full[name], rtol=1e-14, atol=0.0)
    tol = math.exp(-step_kernels.PRUNE_NATS) * 10
    for name in ("fric_post", "marg_post", "pair_in"):
        np.testing.assert_allclose(pruned[name], full[name], rtol=1e-13, atol=tol)
    # the mode marginals given f are normalised by P(f), which can itself be ~e^-100: the
    # joint P(f, mode) is what the pruning leaves within e^-PRUNE_NATS
    pj = pruned["modes_post"] * (pruned["fric_post"][..., None, None] + 1e-12)
    fj = full["modes_post"] * (full["fric_post"][..., None, None] + 1e-12)
    np.testing.assert_allclose(pj, fj, rtol=1e-13, atol=tol)


def test_pruning_is_exercised() -> None:
    """On such rows the bound is tight enough to prune: a friction hypothesis whose elements
    are all pruned has posterior exactly 0 with pruning and a positive one (below
    e^-PRUNE_NATS) without."""
    pb = _problem(1, False)
    la = pb["log_alpha"]
    assert isinstance(la, np.ndarray)
    la[:, 2] = la[:, 0] - 400.0  # the third friction hypothesis is all but impossible
    starts = pb.pop("starts")
    md = pb.pop("md")
    pruned = step_kernels.propose_rows(starts, md, **pb)  # type: ignore[arg-type]
    full = step_kernels.propose_rows(starts, md, **pb, prune=False)  # type: ignore[arg-type]
    exact_zero = (pruned["fric_post"] == 0.0) & (full["fric_post"] > 0.0)
    assert exact_zero.any()
    assert full["fric_post"][exact_zero].max() < math.exp(-step_kernels.PRUNE_NATS)
