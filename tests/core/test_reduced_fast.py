"""The optimised reduced-dynamics solver and small-matrix helpers against reference versions.

`solve_reduced` eliminates the identity rows of the padded Stewart-Trinkle system, solves
friction-independent assignments once per geometry element and tiny systems in closed form;
`reduced_reference.solve_reduced_reference` is the previous padded implementation (one
generic `np.linalg.solve` per element). They must agree to round-off on determinate
assignments (statically indeterminate ones, e.g. two sticking vertices, are ill-conditioned
by construction: their impulses only agree to ~cond * eps, their velocities closely).
"""

from __future__ import annotations

from typing import Any

import numpy as np
import pytest
from hypothesis import example, given, settings
from hypothesis import strategies as st
from reduced_reference import solve_reduced_reference

from dbcslam_core.contact_modes import (
    REDUCED_BACKENDS,
    ContactLayout,
    Mode,
    _solve_small,
    enumerate_hypotheses,
    geometric_feasible,
    solve_reduced,
)
from dbcslam_core.dynamics import PlanarModel
from dbcslam_core.errors import SolverError
from dbcslam_core.geometry import contact_coordinates, contact_kinematics
from dbcslam_core.observation import (
    LinearObservation,
    _cho_solve_small,
    _chol_entries,
    _cholesky_small,
    _proposal_all_observed,
    gaussian_log_density,
)
from dbcslam_core.scenario import edge_scenario, gripper_scenario

GRIPPER = gripper_scenario()
EDGE = edge_scenario()
BACKENDS = sorted(REDUCED_BACKENDS)


def _problem(seed: int, n_p: int, n_k: int, p_contact: float):  # type: ignore[no-untyped-def]
    """Random gripper states near the jaws, random mode assignments (N, 1, C) x mu (1, B, C)."""
    rng = np.random.default_rng(seed)
    model = PlanarModel(GRIPPER)
    env = np.array([-0.03, 0.03])
    q = np.column_stack(
        [rng.normal(0, 0.003, n_p), rng.normal(0, 0.003, n_p), rng.uniform(-np.pi, np.pi, n_p)]
    )
    v = rng.normal(size=(n_p, 3)) * np.array([0.05, 0.05, 0.5])
    kin = contact_kinematics(GRIPPER, q, env, rng.normal(size=2) * 0.01)
    vf = v + GRIPPER.dt * model.generalized_force(q, v, np.zeros(3)) / model.mass_diag
    modes = rng.integers(1, 4, size=(n_p, n_k, 6)) * (rng.random((n_p, n_k, 6)) < p_contact)
    mu = np.array([0.1, 0.4, 0.7])[:, None] * np.ones(6)
    pi = np.repeat(np.arange(n_p), n_k)
    args = (modes.reshape(-1, 1, 6), vf[pi][:, None])
    kwargs = {
        "inv_mass": 1.0 / model.mass_diag,
        "jn": kin.Jn[pi][:, None],
        "jt": kin.Jt[pi][:, None],
        "phi": kin.phi[pi][:, None],
        "vn_env": kin.vn_env[pi][:, None],
        "vt_env": kin.vt_env[pi][:, None],
        "mu": mu[None],
        "dt": GRIPPER.dt,
        "groups": [c.obstacle for c in GRIPPER.potential_contacts],
    }
    return args, kwargs


def _well_posed(modes: np.ndarray, phi: np.ndarray) -> np.ndarray:
    """Determinate (equality rows <= dofs) and geometrically feasible assignments (what the
    filter keeps: e.g. not one vertex on both jaws, whose rows are linearly dependent)."""
    layout = ContactLayout(
        feature_vertex=tuple(c.vertex for c in GRIPPER.potential_contacts),
        obstacle=tuple(c.obstacle for c in GRIPPER.potential_contacts),
        n_vertices=len(GRIPPER.body.vertices),
    )
    rows = (modes != Mode.SEPARATED).sum(-1) + (modes == Mode.STICKING).sum(-1)
    return np.asarray((rows <= 3) & geometric_feasible(layout, modes, phi))


def _assert_agree(new: Any, ref: Any, ok: np.ndarray, lam: np.ndarray) -> None:
    """Two reduced solutions agree on the elements ok (impulse scale lam, N s): velocities
    and response maps to 1e-9 absolute plus 1e-8 of the largest entry of the same element's
    vector / matrix plus 1e-11 of its impulse scale (nearly singular assignments of the random
    problems reach |v'| ~ 6e4 m/s and response entries ~ 40, where the two elimination orders
    differ by ~1e-13 relative times the conditioning, in every entry of the element)."""
    assert ok.any()
    for f in ("v_next", "response", "gap_rate", "vt"):
        a, b = getattr(new, f)[ok], getattr(ref, f)[ok]
        axes = tuple(range(1, b.ndim))
        scale = np.abs(b).max(axis=axes, keepdims=True) if axes else np.abs(b)
        # + 1e-11 of the impulse scale: a near-singular system's impulses (hundreds of N s)
        # carry the conditioning into the response (seed 4796: 2.6e-9 at lam = 528 N s)
        tol = 1e-9 + 1e-8 * scale + 1e-11 * lam[ok].reshape(-1, *(1,) * len(axes))
        err = np.abs(a - b)
        assert np.all(err <= tol), (f, float(np.max(err - tol)))
    for f in ("ln", "lt"):
        err = np.abs(getattr(new, f) - getattr(ref, f)).max(-1)
        assert np.all(err[ok] <= 1e-9 * (1.0 + lam[ok]))
    np.testing.assert_allclose(new.score[ok], ref.score[ok], rtol=1e-8, atol=1e-9)
    if ref.impulse_response is not None:
        assert new.impulse_response is not None
        np.testing.assert_allclose(
            new.impulse_response[ok], ref.impulse_response[ok], rtol=1e-7, atol=1e-7
        )


@pytest.mark.parametrize("backend", BACKENDS)
@settings(max_examples=25, deadline=None)
@given(seed=st.integers(0, 10_000), p_contact=st.sampled_from([0.1, 0.25, 0.5]))
def test_solve_reduced_matches_padded_reference(backend: str, seed: int, p_contact: float) -> None:
    args, kwargs = _problem(seed, 12, 4, p_contact)
    for sens in (False, True):
        new = solve_reduced(  # type: ignore[arg-type]
            *args, impulse_sensitivity=sens, backend=backend, **kwargs
        )
        ref = solve_reduced_reference(*args, impulse_sensitivity=sens, **kwargs)
        lam = np.abs(ref.ln).max(-1) + np.abs(ref.lt).max(-1)  # impulse scale (N s)
        # well-posed and well-conditioned: near-singular sliding systems (Painleve-like,
        # G M^-1 F^T ~ singular) give impulses of ~1e9 N s and are round-off dominated in
        # both implementations (the filter's proposal rejects them: v' ~ 1e3 m/s)
        ok = np.broadcast_to(_well_posed(args[0], kwargs["phi"]), lam.shape) & (lam < 1e3)
        _assert_agree(new, ref, ok, lam)


@pytest.mark.parametrize("backend", BACKENDS)
def test_friction_independent_entries_solved_once_are_identical_across_mu(backend: str) -> None:
    """Assignments without sliding contacts do not depend on mu: same solution per beta."""
    args, kwargs = _problem(3, 20, 3, 0.3)
    modes = np.where(args[0] >= Mode.SLIDING_POS, Mode.STICKING, args[0])
    sol = solve_reduced(modes, args[1], backend=backend, **kwargs)  # type: ignore[arg-type]
    for b in (1, 2):
        np.testing.assert_array_equal(sol.v_next[:, b], sol.v_next[:, 0])
        np.testing.assert_array_equal(sol.ln[:, b], sol.ln[:, 0])
        np.testing.assert_array_equal(sol.response[:, b], sol.response[:, 0])


@pytest.mark.parametrize("backend", BACKENDS)
def test_solve_reduced_edge_point_mass_matches_reference(backend: str) -> None:
    model = PlanarModel(EDGE)
    rng = np.random.default_rng(1)
    q = np.column_stack([rng.uniform(0, 2, 40), rng.normal(0, 1e-3, 40)])
    v = rng.normal(size=(40, 2)) * 0.2
    kin = contact_kinematics(EDGE, q)
    # (N, K, B, C) = (40, 4, 3, 1): every mode for every particle x 3 frictions
    modes = np.broadcast_to(np.arange(4)[None, :, None, None], (40, 4, 1, 1))
    common = {
        "inv_mass": 1.0 / model.mass_diag,
        "jn": kin.Jn[:, None, None],
        "jt": kin.Jt[:, None, None],
        "phi": kin.phi[:, None, None],
        "vn_env": kin.vn_env[:, None, None],
        "vt_env": kin.vt_env[:, None, None],
        "mu": np.array([[0.1], [0.3], [0.5]])[None, None],
        "dt": EDGE.dt,
        "groups": [0],
    }
    new = solve_reduced(  # type: ignore[arg-type]
        modes, v[:, None, None], backend=backend, **common
    )
    ref = solve_reduced_reference(modes, v[:, None, None], **common)
    for f in ("v_next", "ln", "lt", "score", "response", "gap_rate", "vt"):
        np.testing.assert_allclose(getattr(new, f), getattr(ref, f), rtol=1e-10, atol=1e-12)


@settings(max_examples=30, deadline=None)
@given(seed=st.integers(0, 10_000), p_contact=st.sampled_from([0.1, 0.3, 0.6]))
@example(seed=175, p_contact=0.6)  # found by hypothesis: 2.3e-7 on v' = 59 m/s (4e-9 relative)
@example(seed=4796, p_contact=0.1)  # found by hypothesis: response 2.6e-9 off at lam = 528 N s
def test_compiled_backend_equals_numpy_backend(seed: int, p_contact: float) -> None:
    """The compiled kernel and the numpy path solve the same equations: equal to round-off
    on every well-posed, well-conditioned assignment, with and without impulse sensitivity."""
    args, kwargs = _problem(seed, 40, 4, p_contact)
    for sens in (False, True):
        a = solve_reduced(  # type: ignore[arg-type]
            *args, impulse_sensitivity=sens, backend="numpy", **kwargs
        )
        b = solve_reduced(  # type: ignore[arg-type]
            *args, impulse_sensitivity=sens, backend="compiled", **kwargs
        )
        lam = np.abs(a.ln).max(-1) + np.abs(a.lt).max(-1)
        ok = np.broadcast_to(_well_posed(args[0], kwargs["phi"]), lam.shape) & (lam < 1e3)
        _assert_agree(b, a, ok, lam)


@pytest.mark.parametrize("sens", [False, True])
def test_compiled_backend_full_mass_matrix(sens: bool) -> None:
    """Full (effective) mass matrices per (entry, friction) element, as the push scenario's
    implicit support friction gives them: both backends agree."""
    args, kwargs = _problem(11, 30, 3, 0.3)
    rng = np.random.default_rng(11)
    n = args[0].shape[0]
    x = rng.normal(size=(n, 3, 3, 5)) * 0.1
    mass = np.diag(PlanarModel(GRIPPER).mass_diag) + x @ np.swapaxes(x, -1, -2)  # (N, 3, 3, 3)
    vf = np.broadcast_to(args[1], (n, 3, 3)) + rng.normal(size=(n, 3, 3)) * 0.01
    out = [
        solve_reduced(  # type: ignore[arg-type]
            args[0], vf, mass=mass, impulse_sensitivity=sens, backend=be, **kwargs
        )
        for be in ("numpy", "compiled")
    ]
    lam = np.abs(out[0].ln).max(-1) + np.abs(out[0].lt).max(-1)
    ok = np.broadcast_to(_well_posed(args[0], kwargs["phi"]), lam.shape) & (lam < 1e3)
    assert ok.any()
    for f in ("v_next", "response", "score"):
        np.testing.assert_allclose(
            getattr(out[1], f)[ok], getattr(out[0], f)[ok], rtol=1e-8, atol=1e-9
        )


def test_compiled_backend_reports_singular_systems() -> None:
    """Two identical sticking contacts on one dof: the kernel's zero pivot is a SolverError
    naming how many systems failed, never a silent inf."""
    kw = {
        "inv_mass": np.array([1.0, 1.0]),
        "jn": np.array([[[0.0, 1.0], [0.0, 1.0]]]),
        "jt": np.array([[[1.0, 0.0], [1.0, 0.0]]]),
        "phi": np.zeros((1, 2)),
        "vn_env": np.zeros((1, 2)),
        "vt_env": np.zeros((1, 2)),
        "mu": np.array([0.5, 0.5]),
        "dt": 0.01,
    }
    with pytest.raises(SolverError, match="singular"):
        solve_reduced(  # type: ignore[arg-type]
            np.array([[Mode.STICKING, Mode.STICKING]]),
            np.zeros((1, 2)),
            eps_rel=0.0,
            backend="compiled",
            **kw,
        )


def test_unknown_backend_is_refused() -> None:
    args, kwargs = _problem(0, 2, 1, 0.5)
    with pytest.raises(SolverError, match="backend must be one of"):
        solve_reduced(*args, backend="fortran", **kwargs)  # type: ignore[arg-type]


@pytest.mark.parametrize("k", [1, 2, 3, 4])
def test_solve_small_matches_linalg_solve(k: int) -> None:
    rng = np.random.default_rng(k)
    a = rng.normal(size=(200, k, k)) + 3.0 * np.eye(k)
    b = rng.normal(size=(200, k, 4))
    np.testing.assert_allclose(_solve_small(a, b), np.linalg.solve(a, b), rtol=1e-10, atol=1e-12)


@settings(max_examples=60, deadline=None)
@given(
    entries=st.lists(st.floats(-1e3, 1e3), min_size=4, max_size=4)
    | st.lists(st.floats(-1e-170, 1e-170), min_size=4, max_size=4),
    rhs=st.lists(st.floats(-1e3, 1e3), min_size=2, max_size=2),
)
# well conditioned but subnormal: x[0] = 1 / 2.23e-309 = 4.5e308 exceeds the largest double
# (found by hypothesis; np.linalg.solve gives inf as well): not a solvable system in float64
@example(entries=[0.0, 1.11e-308, 2.23e-309, 0.0], rhs=[0.0, 1.0])
@example(entries=[0.0, 1.11e-308, 2.23e-309, 0.0], rhs=[0.0, 1e-300])  # solvable: 4.5e8
def test_cramer_2x2_is_accurate(entries: list[float], rhs: list[float]) -> None:
    a = np.asarray(entries).reshape(1, 2, 2)
    b = np.asarray(rhs).reshape(1, 2, 1)
    cond = np.linalg.cond(a[0])
    if not np.isfinite(cond) or cond > 1e8:
        return
    # reference: both sides scaled by a power of two (exact; LAPACK's pivots of subnormal
    # matrices would overflow)
    e = int(np.frexp(np.abs(a).max())[1])
    with np.errstate(all="ignore"):
        reference = np.linalg.solve(np.ldexp(a, -e), np.ldexp(b, -e))
    if not np.isfinite(reference).all():  # the solution is not representable in float64
        with pytest.raises(SolverError, match="overflows"), np.errstate(all="ignore"):
            _solve_small(a, b)
        return
    x = _solve_small(a, b)
    scale = np.abs(b).max() + np.abs(a).max() * np.abs(x).max()
    # (plus a few units of the smallest subnormal: a residual of one such unit is exact
    # round-off where 1e-9 * scale underflows to 0; found by hypothesis, seed 2)
    tiny = 4 * np.finfo(np.float64).smallest_subnormal
    np.testing.assert_allclose(a @ x, b, atol=max(1e-9 * scale, tiny))


def test_solve_small_raises_on_singular() -> None:
    for k in (1, 2, 3):
        with pytest.raises(SolverError, match="singular"), np.errstate(all="ignore"):
            _solve_small(np.zeros((2, k, k)), np.ones((2, k, 1)))


@pytest.mark.parametrize("n", [1, 2, 3])
def test_small_cholesky_matches_numpy(n: int) -> None:
    rng = np.random.default_rng(n)
    x = rng.normal(size=(50, n, n + 2))
    a = x @ np.swapaxes(x, -1, -2)
    np.testing.assert_allclose(_cholesky_small(a), np.linalg.cholesky(a), rtol=1e-10, atol=1e-12)
    low = _chol_entries(a)
    np.testing.assert_allclose(low[n - 1][0], np.linalg.cholesky(a)[:, n - 1, 0], rtol=1e-10)
    b = rng.normal(size=(50, n, 3))
    np.testing.assert_allclose(
        _cho_solve_small(_cholesky_small(a), b), np.linalg.solve(a, b), rtol=1e-8, atol=1e-10
    )
    v = rng.normal(size=(50, n))
    _, logdet = np.linalg.slogdet(a)
    sol = np.linalg.solve(a, v[..., None])[..., 0]
    ref = -0.5 * (np.einsum("pi,pi->p", v, sol) + logdet + n * np.log(2 * np.pi))
    np.testing.assert_allclose(gaussian_log_density(v, a), ref, rtol=1e-10)


@pytest.mark.parametrize("scenario", [EDGE, GRIPPER])
def test_contact_coordinates_equal_kinematics(scenario) -> None:  # type: ignore[no-untyped-def]
    rng = np.random.default_rng(0)
    q = rng.normal(size=(30, scenario.nq))
    env = rng.normal(size=len(scenario.joints))
    np.testing.assert_array_equal(
        contact_coordinates(scenario, q, env), contact_kinematics(scenario, q, env).s
    )


@settings(max_examples=30, deadline=None)
@given(seed=st.integers(0, 10_000), n=st.sampled_from([2, 3]))
def test_compiled_proposal_equals_numpy_proposal(seed: int, n: int) -> None:
    """The compiled Kalman-form proposal update and the entry-by-entry numpy one agree to
    round-off (log predictive, posterior mean and covariance of v')."""
    rng = np.random.default_rng(seed)
    m = 50
    x = rng.normal(size=(m, 4, n, n + 1)) * rng.uniform(1e-3, 1.0)
    sv = x @ np.swapaxes(x, -1, -2)
    q = rng.normal(size=(m, 1, n))
    vh = rng.normal(size=(m, 4, n))
    var = rng.uniform(1e-6, 1e-2, n)
    obs = LinearObservation(
        index=np.arange(n),
        value=rng.normal(size=n),
        var=var,
        angular=np.arange(n) == 2,
    )
    s_diag = np.diag(var + 1e-8)
    out = [
        _proposal_all_observed(q, vh, sv, dt=0.01, obs=obs, s_diag=s_diag, compiled=c)
        for c in (False, True)
    ]
    for a, b in zip(out[0], out[1], strict=True):
        np.testing.assert_allclose(b, a, rtol=1e-9, atol=1e-12)


@settings(max_examples=40, deadline=None)
@given(
    seed=st.integers(0, 10_000),
    threshold=st.sampled_from([1e-3, 1e-2, 0.05]),
    max_h=st.sampled_from([4, 8, 32]),
    n_p=st.sampled_from([3, 40]),
)
def test_compiled_enumeration_equals_numpy(
    seed: int, threshold: float, max_h: int, n_p: int
) -> None:
    """The compiled hypothesis enumeration keeps the same hypotheses in the same order as
    the numpy path (continuous random marginals: no exact ties), with the gripper's
    geometric exclusions and gaps."""
    rng = np.random.default_rng(seed)
    layout = ContactLayout(
        feature_vertex=tuple(c.vertex for c in GRIPPER.potential_contacts),
        obstacle=tuple(c.obstacle for c in GRIPPER.potential_contacts),
        n_vertices=len(GRIPPER.body.vertices),
    )
    c = len(GRIPPER.potential_contacts)
    mg = rng.dirichlet(np.full(4, 0.3), size=(n_p, c))
    phi = rng.uniform(-1e-3, 3e-3, size=(n_p, c))
    out = [
        enumerate_hypotheses(mg, threshold, max_h, layout=layout, phi=phi, compiled=flag)
        for flag in (False, True)
    ]
    np.testing.assert_array_equal(out[1].valid, out[0].valid)
    np.testing.assert_array_equal(out[1].modes[out[0].valid], out[0].modes[out[0].valid])
    np.testing.assert_array_equal(out[1].log_prior, out[0].log_prior)


def test_compiled_enumeration_truncated_path_keeps_the_most_probable() -> None:
    """Many particles and contacts (the argpartition pre-selection of the numpy path): the
    same hypotheses when there are no ties."""
    rng = np.random.default_rng(5)
    mg = rng.dirichlet(np.full(4, 1.0), size=(800, 6))
    a, b = (enumerate_hypotheses(mg, 1e-3, 32, compiled=flag) for flag in (False, True))
    np.testing.assert_array_equal(b.valid, a.valid)
    np.testing.assert_array_equal(b.modes[a.valid], a.modes[a.valid])
    np.testing.assert_array_equal(b.log_prior, a.log_prior)
