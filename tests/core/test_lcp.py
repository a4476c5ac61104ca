"""Property tests of the LCP solvers (Lemke to 1e-9, PGS to a documented 1e-6)."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from dbcslam_core.dynamics import PlanarModel, State
from dbcslam_core.errors import SolverError
from dbcslam_core.lcp import (
    SOLVERS,
    LCPSolver,
    LemkeSolver,
    PGSSolver,
    lcp_residuals,
    make_solver,
)
from dbcslam_core.scenario import edge_scenario, gripper_scenario

LEMKE_TOL = 1e-9
PGS_TOL = 1e-6

seeds = st.integers(0, 2**32 - 1)


def _pd(rng: np.random.Generator, n: int, skew: bool) -> np.ndarray:
    b = rng.normal(size=(n, n))
    a = b @ b.T + 0.05 * np.eye(n)
    if skew:
        s = rng.normal(size=(n, n))
        a = a + (s - s.T)
    return a


def test_table_and_protocol() -> None:
    assert set(SOLVERS) == {"lemke", "pgs"}
    for name in SOLVERS:
        assert isinstance(make_solver(name), LCPSolver)
    with pytest.raises(SolverError, match="valid solvers"):
        make_solver("dantzig")


@settings(max_examples=150, deadline=None)
@given(seed=seeds, n=st.integers(1, 14), skew=st.booleans())
def test_lemke_positive_definite(seed: int, n: int, skew: bool) -> None:
    rng = np.random.default_rng(seed)
    a = _pd(rng, n, skew)
    b = rng.normal(size=n) * 10.0 ** rng.uniform(-2, 2)
    z = LemkeSolver().solve(a, b)
    res = lcp_residuals(a, b, z)
    assert res.worst <= LEMKE_TOL * max(1.0, float(np.abs(b).max()))


@settings(max_examples=150, deadline=None)
@given(seed=seeds, n=st.integers(2, 12), data=st.data())
def test_lemke_degenerate_psd_feasible(seed: int, n: int, data: st.DataObject) -> None:
    """Low-rank PSD A with b chosen so that a solution exists (Lemke processes these)."""
    rng = np.random.default_rng(seed)
    k = data.draw(st.integers(1, n - 1))
    f = rng.normal(size=(n, k))
    a = f @ f.T
    z_true = np.maximum(rng.normal(size=n), 0.0)
    slack = np.where(z_true > 0, 0.0, np.abs(rng.normal(size=n)) * rng.integers(0, 2, n))
    b = slack - a @ z_true
    z = LemkeSolver().solve(a, b)
    assert lcp_residuals(a, b, z).worst <= LEMKE_TOL * max(1.0, float(np.abs(b).max()))


def test_lemke_duplicate_rows_degenerate() -> None:
    a = np.ones((3, 3))
    b = -np.ones(3)
    z = LemkeSolver().solve(a, b)
    assert lcp_residuals(a, b, z).worst <= LEMKE_TOL
    assert z.sum() == pytest.approx(1.0)


def test_trivial_and_ray_termination() -> None:
    lemke = LemkeSolver()
    assert np.array_equal(lemke.solve(np.eye(2), [1.0, 0.0]), [0.0, 0.0])
    with pytest.raises(SolverError, match="ray termination"):
        lemke.solve([[-1.0]], [-1.0])
    with pytest.raises(SolverError, match="ray termination"):
        lemke.solve([[0.0, 0.0], [0.0, 1.0]], [-1.0, 1.0])
    with pytest.raises(SolverError, match="LCP needs"):
        lemke.solve(np.eye(2), [1.0])
    with pytest.raises(SolverError, match="finite"):
        lemke.solve(np.eye(1), [math.nan])


@settings(max_examples=40, deadline=None)
@given(seed=seeds, n=st.integers(1, 10), batch=st.integers(1, 6))
def test_pgs_symmetric_positive_definite(seed: int, n: int, batch: int) -> None:
    rng = np.random.default_rng(seed)
    a = np.stack([_pd(rng, n, skew=False) + n * np.eye(n) for _ in range(batch)])
    b = rng.normal(size=(batch, n))
    z = PGSSolver(max_iter=3000).solve_batch(a, b)
    assert lcp_residuals(a, b, z).worst <= PGS_TOL
    z_lemke = LemkeSolver().solve_batch(a, b)
    assert np.allclose(z, z_lemke, atol=1e-6)


def test_pgs_needs_positive_diagonal() -> None:
    with pytest.raises(SolverError, match="positive diagonal"):
        PGSSolver().solve(np.zeros((2, 2)), -np.ones(2))


# --------------------------------------------------------------------- contact LCPs (dynamics)
def _friction_cone_ok(z: np.ndarray, a: np.ndarray, b: np.ndarray, mu: np.ndarray) -> None:
    zc = z.reshape(-1, 4)
    w = (a @ z + b).reshape(-1, 4)
    ln, ltp, ltm, s = zc.T
    tol = LEMKE_TOL * max(1.0, float(np.abs(b).max()))
    assert np.all(ltp + ltm <= mu * ln + tol)  # |lt| <= mu ln
    # sliding (s > 0): the friction impulse is on the cone boundary
    sliding = s > 1e-7
    assert np.allclose((ltp + ltm)[sliding], (mu * ln)[sliding], atol=tol)
    # slide speed is |relative tangential velocity|: w+ = s + vt, w- = s - vt
    vt = (w[:, 1] - w[:, 2]) / 2.0
    assert np.allclose(s, np.abs(vt) * (ln > 1e-9) + s * (ln <= 1e-9), atol=1e-8)


@settings(max_examples=60, deadline=None)
@given(
    seed=seeds,
    mu=st.sampled_from([0.0, 0.1, 0.4, 0.7, 1.5]),
    yaw=st.floats(-math.pi, math.pi),
    gaps=st.tuples(st.floats(0.0, 0.003), st.floats(0.0, 0.003)),
    touching=st.sampled_from(["none", "lower", "upper", "both"]),
)
def test_lemke_gripper_contact_lcps(
    seed: int, mu: float, yaw: float, gaps: tuple[float, float], touching: str
) -> None:
    sc = gripper_scenario()
    rng = np.random.default_rng(seed)
    verts = np.asarray(sc.body.vertices)
    yv = verts[:, 0] * math.sin(yaw) + verts[:, 1] * math.cos(yaw)
    y = rng.uniform(-0.01, 0.01)
    lower = y + yv.min() - (0.0 if touching in ("lower", "both") else gaps[0])
    upper = y + yv.max() + (0.0 if touching in ("upper", "both") else gaps[1])
    env = np.array([lower, upper])
    state = State(np.array([0.0, y, yaw]), rng.normal(scale=[0.05, 0.05, 1.0]))
    u = rng.normal(scale=[0.5, 0.5, 0.01])
    model = PlanarModel(sc)
    a, b = model.lcp(state, u, env, env, mu=mu)
    z = LemkeSolver().solve(a, b)
    assert lcp_residuals(a, b, z).worst <= LEMKE_TOL * max(1.0, float(np.abs(b).max()))
    _friction_cone_ok(z, a, b, np.full(sc.n_contacts, mu))


@settings(max_examples=60, deadline=None)
@given(
    seed=seeds,
    mu=st.sampled_from([0.0, 0.3, 0.9]),
    y=st.floats(0.0, 0.01),
)
def test_edge_contact_lcp_lemke_and_pgs_agree(seed: int, mu: float, y: float) -> None:
    sc = edge_scenario()
    rng = np.random.default_rng(seed)
    state = State(np.array([0.0, y]), rng.normal(scale=0.5, size=2))
    u = rng.normal(scale=10.0, size=2)
    lemke = PlanarModel(sc).step(state, u, mu=mu)
    a, b = PlanarModel(sc).lcp(state, u, mu=mu)
    z = LemkeSolver().solve(a, b)
    assert lcp_residuals(a, b, z).worst <= LEMKE_TOL * max(1.0, float(np.abs(b).max()))
    _friction_cone_ok(z, a, b, np.array([mu]))
    pgs = PlanarModel(sc, solver=PGSSolver()).step(state, u, mu=mu)
    assert np.allclose(pgs.v, lemke.v, atol=PGS_TOL)
    assert np.allclose(pgs.ln, lemke.ln, atol=PGS_TOL)
    assert np.array_equal(pgs.modes, lemke.modes) or np.abs(lemke.slide).max() < 1e-6


def test_solve_batch_matches_single() -> None:
    rng = np.random.default_rng(3)
    a = np.stack([_pd(rng, 5, True) for _ in range(4)])
    b = rng.normal(size=(4, 5))
    zb = LemkeSolver().solve_batch(a, b)
    for i in range(4):
        assert np.allclose(zb[i], LemkeSolver().solve(a[i], b[i]))


def test_lemke_pivot_cap() -> None:
    rng = np.random.default_rng(7)
    a = _pd(rng, 8, skew=False)
    b = -np.abs(rng.normal(size=8)) - 1.0
    with pytest.raises(SolverError, match="pivots"):
        LemkeSolver(max_pivots=1, regularization=()).solve(a, b)
    z = LemkeSolver().solve(a, b)
    assert lcp_residuals(a, b, z).worst <= LEMKE_TOL * 10


def test_row_violation_is_relative_to_the_row() -> None:
    """A violation that is the whole content of its row counts (even if tiny against the
    problem's scale); round-off in an empty row does not."""
    from dbcslam_core.lcp import row_violation

    a = np.array([[1e4, 0.0], [0.0, 1.0]])
    b = np.array([-1e4, 0.0])
    assert row_violation(a, b, np.array([1.0, 0.0])) == (-1, 0.0)
    # -1e-3 in a row that holds nothing else: the whole row (1e-7 of the problem's scale)
    row, rel = row_violation(a, np.array([-1e4, -1e-3]), np.array([1.0, 0.0]))
    assert row == 1 and rel == pytest.approx(1.0)
    # round-off there (1e-14 of the scale) stays below the floor
    row, rel = row_violation(a, np.array([-1e4, -1e-10]), np.array([1.0, 0.0]))
    assert rel < 1e-3
