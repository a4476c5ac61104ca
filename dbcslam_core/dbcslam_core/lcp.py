"""Linear complementarity problem (LCP) solvers.

Problem: find z with  w = A z + b,  0 <= z  _|_  w >= 0  (z . w = 0).

* `LemkeSolver`: Lemke's complementary pivoting with covering vector d = 1, lexicographic
  minimum-ratio test (degeneracy safe, no cycling), a pivot cap, and a final polish that
  re-solves the terminal complementary basis with `np.linalg.solve` so the answer is exact to
  round-off. Raises `SolverError` on ray termination (no solution found by the method).
  Processes copositive-plus matrices (e.g. positive semi-definite A, and the Stewart-Trinkle
  contact LCP).
* `PGSSolver`: projected Gauss-Seidel, vectorised over a batch. The generic `solve` needs a
  positive diagonal; `solve_friction` is the dedicated contact solver on (ln, lt) with the
  planar friction cone |lt| <= mu ln (used by `PlanarModel` when the solver is PGS, because
  the Stewart-Trinkle LCP has a zero diagonal block).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Protocol, runtime_checkable

import numpy as np
from numpy.typing import ArrayLike, NDArray

from .errors import SolverError

__all__ = [
    "SOLVERS",
    "LCPResiduals",
    "LCPSolver",
    "LemkeSolver",
    "PGSSolver",
    "lcp_residuals",
    "make_solver",
    "row_violation",
]

F64 = NDArray[np.float64]


@runtime_checkable
class LCPSolver(Protocol):
    """Strategy interface of an LCP solver."""

    def solve(self, A: ArrayLike, b: ArrayLike) -> F64:
        """Solve one LCP: A[n, n], b[n] -> z[n]."""
        ...

    def solve_batch(self, A: ArrayLike, b: ArrayLike) -> F64:
        """Solve a batch of LCPs: A[B, n, n], b[B, n] -> z[B, n]."""
        ...


@dataclass(frozen=True)
class LCPResiduals:
    """Worst violations: z_neg = max(-z, 0), w_neg = max(-w, 0), comp = max |z_i w_i|."""

    z_neg: float
    w_neg: float
    comp: float

    @property
    def worst(self) -> float:
        """Largest of the three violations."""
        return max(self.z_neg, self.w_neg, self.comp)


def row_violation(a: F64, b: F64, z: F64, *, floor: float = 0.0) -> tuple[int, float]:
    """The row of the largest violation of w = A z + b >= 0 relative to that row's
    magnitudes sum_j |A_ij z_j| + |b_i|, and that relative violation (0 when w >= 0). The
    magnitudes are floored at 1e-9 of the problem's scale |b| + |A| |z| and at `floor` (in
    the units of w), so that round-off in rows with (almost) nothing in them does not
    count."""
    w = a @ z + b
    viol = np.maximum(-w, 0.0)
    if not np.any(viol > 0.0):
        return -1, 0.0
    terms = np.abs(a) @ np.abs(z) + np.abs(b)
    scale = float(np.max(np.abs(b))) + float(np.max(np.abs(a))) * float(np.max(z))
    rel = viol / np.maximum(terms, max(1e-9 * scale, floor, 1e-300))
    row = int(np.argmax(rel))
    return row, float(rel[row])


def lcp_residuals(A: ArrayLike, b: ArrayLike, z: ArrayLike) -> LCPResiduals:
    """Residuals of a candidate LCP solution (single or batched: A[..., n, n])."""
    a = np.asarray(A, dtype=np.float64)
    bb = np.asarray(b, dtype=np.float64)
    zz = np.asarray(z, dtype=np.float64)
    w = np.einsum("...ij,...j->...i", a, zz) + bb
    if zz.size == 0:
        return LCPResiduals(0.0, 0.0, 0.0)
    return LCPResiduals(
        float(np.max(np.maximum(-zz, 0.0))),
        float(np.max(np.maximum(-w, 0.0))),
        float(np.max(np.abs(zz * w))),
    )


def _check(A: ArrayLike, b: ArrayLike, batch: bool) -> tuple[F64, F64]:
    a = np.asarray(A, dtype=np.float64)
    bb = np.asarray(b, dtype=np.float64)
    nd = 3 if batch else 2
    if a.ndim != nd or a.shape[-1] != a.shape[-2] or bb.shape != a.shape[:-1]:
        shape = "A[B, n, n], b[B, n]" if batch else "A[n, n], b[n]"
        msg = f"LCP needs {shape}; got A {a.shape}, b {bb.shape}"
        raise SolverError(msg)
    if not (np.all(np.isfinite(a)) and np.all(np.isfinite(bb))):
        msg = "LCP data must be finite; A or b holds NaN/inf"
        raise SolverError(msg)
    return a, bb


@dataclass(frozen=True)
class LemkeSolver:
    """Lemke's method with lexicographic degeneracy resolution.

    max_pivots: cap on pivots (default 50 n + 100); pivot_tol: smallest pivot accepted;
    feas_tol: tolerance of the final polish check (scaled by max(1, |b|_inf)); row_tol:
    the per-row check of the terminal basis (`row_violation`).
    After a ray termination the solve is retried on slightly regularised copies of A (see
    `regularization`), polishing against the original A; SolverError if all attempts fail.
    """

    max_pivots: int | None = None
    pivot_tol: float = 1e-12
    feas_tol: float = 1e-9
    accept_tol: float = 1e-8
    """Relative LCP residual above which a terminal basis is rejected (then retried)."""
    regularization: tuple[float, ...] = (1e-12, 1e-10, 1e-8)
    """Retries after a ray termination with A + eps max|A| I, eps in this order."""
    row_tol: float = 0.1
    """Largest accepted violation of w >= 0 in one row relative to the magnitudes of that row
    (`row_violation`); a terminal basis above it is rejected (then retried). The rows of a
    Stewart-Trinkle LCP mix units (velocities, impulses), so the overall `accept_tol` alone
    lets an impulse-row violation pass whose size is the row's whole content (a tangential
    impulse without normal impulse: rel 1.0). Degenerate but acceptable bases of the
    synthetic pushes reach 1e-3."""
    row_floor: float = 1e-12
    """Violations below this (the units of w: m/s or N s in this package's SI contact LCPs)
    never count in the row check: a push LCP whose data are all round-off (|b| ~ 1e-16) has
    rows of nothing but round-off."""

    def solve(self, A: ArrayLike, b: ArrayLike) -> F64:
        """Solve w = A z + b, 0 <= z _|_ w >= 0; raises SolverError if Lemke fails."""
        a, bb = _check(A, b, batch=False)
        return self._solve(a, bb)

    def solve_batch(self, A: ArrayLike, b: ArrayLike) -> F64:
        """Solve each LCP of the batch (sequential pivoting per problem)."""
        a, bb = _check(A, b, batch=True)
        out = np.zeros(bb.shape)
        for i in range(bb.shape[0]):
            out[i] = self._solve(a[i], bb[i])
        return out

    # ------------------------------------------------------------------------- internals
    def _lexmin(self, tab: F64, rows: NDArray[np.intp], col: F64, n: int) -> int:
        """Lexicographic minimum ratio over `rows`: (rhs, B^-1 row) / col."""
        cand = rows
        rhs = tab[cand, 2 * n + 1] / col[cand]
        best = np.min(rhs)
        scale = max(1.0, abs(float(best)))
        cand = cand[rhs <= best + 1e-12 * scale]
        j = 0
        while len(cand) > 1 and j < n:
            r = tab[cand, j] / col[cand]
            best = np.min(r)
            cand = cand[r <= best + 1e-12 * max(1.0, abs(float(best)))]
            j += 1
        return int(cand[0])

    def _solve(self, a: F64, b: F64) -> F64:
        n = b.shape[0]
        if n == 0 or np.all(b >= 0.0):
            return np.zeros(n)
        # Lemke may ray-terminate on degenerate, merely copositive problems (Stewart-Trinkle
        # LCPs with redundant contacts); A + eps I is strictly copositive, which Lemke always
        # processes. The polish then re-solves the found basis with the original A.
        scale = max(1.0, float(np.max(np.abs(a))))
        try:
            return self._lemke(a, b, a)
        except SolverError as first:
            for eps in self.regularization:
                try:
                    return self._lemke(a, b, a + (eps * scale) * np.eye(n))
                except SolverError:
                    continue
            msg = f"{first} (regularised retries eps={list(self.regularization)} failed too)"
            raise SolverError(msg) from first

    def _lemke(self, a: F64, b: F64, a_piv: F64) -> F64:
        n = b.shape[0]
        a_orig = a
        a = a_piv
        # tableau [I | -A | -d | b]; B^-1 is the first n columns
        tab = np.zeros((n, 2 * n + 2))
        tab[:, :n] = np.eye(n)
        tab[:, n : 2 * n] = -a
        tab[:, 2 * n] = -1.0
        tab[:, 2 * n + 1] = b
        basis = np.arange(n)  # variable index per row: w_i = i, z_i = n + i, z0 = 2n
        z0 = 2 * n
        # initial pivot: z0 enters, the row with the most negative b leaves (lexicographic)
        rows = np.arange(n)
        r = self._lexmin(tab, rows, np.ones(n), n)
        self._pivot(tab, r, z0)
        leaving = int(basis[r])
        basis[r] = z0
        max_piv = self.max_pivots if self.max_pivots is not None else 50 * n + 100
        for _ in range(max_piv):
            entering = leaving + n if leaving < n else leaving - n
            col = tab[:, entering]
            pos = np.nonzero(col > self.pivot_tol)[0]
            if len(pos) == 0:
                msg = (
                    f"Lemke ray termination on an LCP of size {n} (entering variable "
                    f"{'z' if entering >= n else 'w'}{entering % n}); the LCP may have no "
                    "solution or A is not copositive-plus"
                )
                raise SolverError(msg)
            # z0 leaves as soon as it ties for the minimum ratio (standard rule)
            rhs = tab[pos, 2 * n + 1] / col[pos]
            z0_row = np.nonzero(basis == z0)[0][0]
            if z0_row in pos and rhs[pos == z0_row][0] <= np.min(rhs) + 1e-14 * max(
                1.0, float(np.min(rhs))
            ):
                r = int(z0_row)
            else:
                r = self._lexmin(tab, pos, col, n)
            self._pivot(tab, r, entering)
            leaving = int(basis[r])
            basis[r] = entering
            if leaving == z0:
                return self._polish(a_orig, b, basis, tab, n)
        msg = f"Lemke exceeded {max_piv} pivots on an LCP of size {n} (cycling or too large)"
        raise SolverError(msg)

    @staticmethod
    def _pivot(tab: F64, r: int, c: int) -> None:
        tab[r] /= tab[r, c]
        col = tab[:, c].copy()
        col[r] = 0.0
        tab -= np.outer(col, tab[r])

    def _polish(self, a: F64, b: F64, basis: NDArray[np.intp], tab: F64, n: int) -> F64:
        z = np.zeros(n)
        zb = basis[basis >= n] - n
        rows = np.nonzero(basis >= n)[0]
        z[zb] = tab[rows, 2 * n + 1]
        z = np.maximum(z, 0.0)
        best = lcp_residuals(a, b, z).worst
        if len(zb):
            sub = a[np.ix_(zb, zb)]
            try:
                sol = np.linalg.solve(sub, -b[zb])
            except np.linalg.LinAlgError:
                sol = np.linalg.lstsq(sub, -b[zb], rcond=None)[0]
            if np.all(np.isfinite(sol)):
                cand = np.zeros(n)
                cand[zb] = np.maximum(sol, 0.0)
                res = lcp_residuals(a, b, cand).worst
                if res <= best:
                    z, best = cand, res
        scale = max(1.0, float(np.max(np.abs(b))), float(np.max(z, initial=0.0)))
        if best > self.accept_tol * scale * max(1.0, float(np.max(np.abs(a)))):
            msg = (
                f"Lemke terminated but the solution violates the LCP by {best:.3g} "
                f"(size {n}); numerically unreliable"
            )
            raise SolverError(msg)
        row, rel = row_violation(a, b, z, floor=self.row_floor)
        if rel > self.row_tol:
            msg = (
                f"Lemke terminated but w[{row}] < 0 by {rel:.3g} of the magnitudes in that row "
                f"(size {n}); a degenerate basis"
            )
            raise SolverError(msg)
        return z


@dataclass(frozen=True)
class PGSSolver:
    """Projected Gauss-Seidel, vectorised over the batch.

    Converges for symmetric positive definite A (generic `solve`) and for the friction-cone
    contact problem (`solve_friction`) with a positive definite Delassus matrix; stops when the
    largest update is below `tol` or after `max_iter` sweeps. Accuracy is that of an iterative
    method: residuals ~ tol * |A| (documented tolerance 1e-6 in tests), not round-off.
    """

    max_iter: int = 500
    tol: float = 1e-12
    relax: float = 1.0

    def solve(self, A: ArrayLike, b: ArrayLike) -> F64:
        """Solve one LCP (A needs a positive diagonal)."""
        a, bb = _check(A, b, batch=False)
        return np.asarray(self._pgs(a[None], bb[None])[0], dtype=np.float64)

    def solve_batch(self, A: ArrayLike, b: ArrayLike) -> F64:
        """Solve a batch of LCPs A[B, n, n], b[B, n] (A needs a positive diagonal)."""
        a, bb = _check(A, b, batch=True)
        return self._pgs(a, bb)

    def _pgs(self, a: F64, b: F64) -> F64:
        n = b.shape[-1]
        diag = np.diagonal(a, axis1=-2, axis2=-1)
        if np.any(diag <= 0.0):
            bad = np.argwhere(diag <= 0.0)[0]
            msg = (
                f"PGS needs A with a positive diagonal; A[{bad[0]}] has diagonal entry "
                f"{diag[tuple(bad)]:.3g} at index {bad[1]} (use Lemke or solve_friction)"
            )
            raise SolverError(msg)
        z = np.zeros_like(b)
        for _ in range(self.max_iter):
            delta = np.zeros(b.shape[0])
            for i in range(n):
                wi = np.einsum("bj,bj->b", a[:, i, :], z) + b[:, i]
                zi = np.maximum(0.0, z[:, i] - self.relax * wi / diag[:, i])
                delta = np.maximum(delta, np.abs(zi - z[:, i]))
                z[:, i] = zi
            if np.max(delta, initial=0.0) <= self.tol * max(1.0, float(np.max(np.abs(z)))):
                break
        return z

    def solve_friction(self, W: ArrayLike, c: ArrayLike, mu: ArrayLike) -> F64:
        """Planar frictional contact: impulses p = (ln_1, lt_1, ..., ln_C, lt_C).

        W[..., 2C, 2C] Delassus matrix (J M^-1 J^T with rows (n_1, t_1, n_2, t_2, ...)),
        c[..., 2C] free velocities (normal rows include phi/dt - vn_env, tangent rows
        -vt_env), mu[..., C]. Solves ln >= 0 _|_ (W p + c)_n >= 0 and |lt| <= mu ln with
        maximum dissipation (lt opposes the tangential velocity when sliding).
        Returns p[..., 2C].
        """
        w = np.asarray(W, dtype=np.float64)
        cc = np.asarray(c, dtype=np.float64)
        mm = np.asarray(mu, dtype=np.float64)
        lead = cc.shape[:-1]
        n2 = cc.shape[-1]
        nc = n2 // 2
        w = np.broadcast_to(w, (*lead, n2, n2)).reshape(-1, n2, n2)
        cc = cc.reshape(-1, n2)
        mm = np.broadcast_to(mm, (*lead, nc)).reshape(-1, nc)
        diag = np.diagonal(w, axis1=-2, axis2=-1)
        if np.any(diag <= 0.0):
            msg = "PGS solve_friction needs a Delassus matrix with a positive diagonal"
            raise SolverError(msg)
        p = np.zeros_like(cc)
        for _ in range(self.max_iter):
            delta = np.zeros(cc.shape[0])
            for k in range(nc):
                i_n, i_t = 2 * k, 2 * k + 1
                vn = np.einsum("bj,bj->b", w[:, i_n, :], p) + cc[:, i_n]
                ln = np.maximum(0.0, p[:, i_n] - self.relax * vn / diag[:, i_n])
                delta = np.maximum(delta, np.abs(ln - p[:, i_n]))
                p[:, i_n] = ln
                vt = np.einsum("bj,bj->b", w[:, i_t, :], p) + cc[:, i_t]
                bound = mm[:, k] * ln
                lt = np.clip(p[:, i_t] - self.relax * vt / diag[:, i_t], -bound, bound)
                delta = np.maximum(delta, np.abs(lt - p[:, i_t]))
                p[:, i_t] = lt
            if np.max(delta, initial=0.0) <= self.tol * max(1.0, float(np.max(np.abs(p)))):
                break
        return p.reshape(*lead, n2)


SOLVERS: dict[str, type[LemkeSolver] | type[PGSSolver]] = {
    "lemke": LemkeSolver,
    "pgs": PGSSolver,
}


def make_solver(name: str) -> LemkeSolver | PGSSolver:
    """Instantiate a solver from the `SOLVERS` table by name."""
    try:
        return SOLVERS[name]()
    except KeyError as err:
        msg = f"unknown LCP solver {name!r}; valid solvers are {sorted(SOLVERS)}"
        raise SolverError(msg) from err
