"""The algebraic complementarity system every discretization produces.

    K x - B^T (D y) = F,
    g(x) = B x - b >= 0,   y >= 0,   g(x) . y = 0,

with K symmetric positive definite (n x n), D > 0 diagonal (m weights) and
each constraint row l of B of the form  e_up(l) - e_lo(l)  (two-membrane
contact: g_l = X1_l - X2_l) or  e_up(l)  (obstacle: g_l = X_l - psi_l).
This is (DS2) / "Matrix representation" of [CAMWA21]:  x = [X1, X2],
y = X3,  E = [[mu1 S, 0, -D], [0, mu2 S, D]].

:meth:`ComplementaritySystem.newton_step` solves the linearization
    K x' - B^T D y' = F,   C + Ca (g(x') - g(x)) + Cb (y' - y) = 0
(Ca, Cb: diagonal generalized Jacobian of the C-function) through a reduced
SPD system:
  * rows with Cb = 0 ("equality", Newton-min active set): g(x') is
    prescribed and a slave unknown is eliminated (u2 = u1 - b at contact
    nodes, u = psi at obstacle nodes);
  * rows with Ca = 0 ("fixed", inactive set): y' is prescribed;
  * rows with both nonzero (Fischer-Burmeister): y' is eliminated and adds
    B^T diag(D Ca/Cb) B >= 0 to K.
The multiplier on equality rows is recovered from the slave equation.
"""
from __future__ import annotations

import time
from dataclasses import dataclass, field
from typing import Optional

import numpy as np
import scipy.sparse as sp

from .linalg import FixedPatternCholesky, SPDSolver, pcg

__all__ = ["ComplementaritySystem", "LinearizedStep", "StepInfo", "FactorReuse", "LINEAR_PATHS"]

#: how a Newton step's reduced system was solved (IterationRecord.linear_path is the index)
LINEAR_PATHS = ("factor", "pcg", "pcg-failed")


@dataclass
class StepInfo:
    reduced_size: int
    time_assemble: float
    time_solve: float
    path: str = "factor"  # LINEAR_PATHS: fresh factorization | PCG, reused factorization | PCG gave up, then factor
    pcg_its: int = 0


@dataclass
class ComplementaritySystem:
    """K x - B^T D y = F with constraints g = B x - b >= 0 (see module doc)."""

    K: sp.csr_matrix
    F: np.ndarray
    up: np.ndarray
    lo: np.ndarray  # -1 where the row has no "lower" unknown
    b: np.ndarray
    D: np.ndarray
    solver: str = "sparsecholesky"
    _B: sp.csr_matrix = field(init=False, repr=False)

    def __post_init__(self):
        n, m = self.K.shape[0], len(self.up)
        self.up = np.asarray(self.up, dtype=np.int64)
        self.lo = np.asarray(self.lo, dtype=np.int64)
        self.b = np.asarray(self.b, dtype=float)
        self.D = np.asarray(self.D, dtype=float)
        if not (len(self.lo) == len(self.b) == len(self.D) == m):
            raise ValueError("up, lo, b, D must have the same length")
        if np.any(self.D <= 0):
            raise ValueError("D must be positive")
        used = np.concatenate([self.up, self.lo[self.lo >= 0]])
        if len(used) and (used.min() < 0 or used.max() >= n):
            raise ValueError(f"constraint rows must refer to unknowns 0..{n - 1}")
        if len(used) and np.bincount(used, minlength=n).max() > 1:  # O(n): np.unique sorts (0.4 s at 1M)
            raise ValueError("each unknown may appear in at most one constraint row")
        has_lo = self.lo >= 0
        rows = np.concatenate([np.arange(m), np.flatnonzero(has_lo)])
        cols = np.concatenate([self.up, self.lo[has_lo]])
        vals = np.concatenate([np.ones(m), -np.ones(has_lo.sum())])
        self._B = sp.csr_matrix((vals, (rows, cols)), shape=(m, n))

    @property
    def n(self) -> int:
        return self.K.shape[0]

    @property
    def m(self) -> int:
        return len(self.up)

    def gap(self, x: np.ndarray) -> np.ndarray:
        """g(x) = B x - b."""
        return self._B @ x - self.b

    def residual(self, x: np.ndarray, y: np.ndarray) -> np.ndarray:
        """Linear residual K x - B^T D y - F."""
        return self.K @ x - self._B.T @ (self.D * y) - self.F

    def unconstrained_solve(self, rhs=None) -> np.ndarray:
        """Solve K x = F (the practical lower bound of any contact solve)."""
        return SPDSolver(self.K, self.solver).solve(self.F if rhs is None else rhs)

    def membrane_split(self, rtol: float = 1e-12):
        """(S, alpha) if K = blockdiag(S, alpha S) and g = x_1 - x_2 row by row, else None.

        That is the two-membrane problem with constant tensions on identical
        spaces (S = mu1 * stiffness, alpha = mu2 / mu1), where the change of
        variables s = x_1 + alpha x_2, w = x_1 - x_2 decouples
            S s = F_1 + F_2                                  (Poisson, no contact)
            S w - D (1 + 1/alpha) y = F_1 - F_2 / alpha,     w >= 0, y >= 0, w.y = 0
        (an obstacle problem for w);  x_1 = (s + alpha w)/(1 + alpha), x_2 = (s - w)/(1 + alpha).
        """
        m, n = self.m, self.n
        if n != 2 * m or np.any(self.b != 0) or not np.array_equal(self.up, np.arange(m)) \
                or not np.array_equal(self.lo, m + np.arange(m)):
            return None
        K = self.K.tocsr()
        S, K22 = K[:m, :m], K[m:, m:]
        if K[:m, m:].count_nonzero() or K[m:, :m].count_nonzero():
            return None
        d1 = S.diagonal()
        if np.any(d1 <= 0):
            return None
        alpha = float(K22.diagonal()[0] / d1[0])
        if not alpha > 0 or abs(K22 - alpha * S).max() > rtol * abs(S).max():
            return None
        return S.tocsr(), alpha

    #: projected Jacobi sweeps (damping) of :meth:`warm_start` for one-sided systems
    WARM_SWEEPS, WARM_OMEGA = 5, 2.0 / 3.0

    def warm_start(self, x0: np.ndarray, y0: np.ndarray):
        """Nested-iteration start (x, y) from an interpolated coarser solution (x0, y0).

        Newton-min's first step depends only on the active set {g(x) <= y} of
        its start, so this picks that set.  Two-sided rows (membranes, b = 0)
        are left alone: the interpolated gap of nonnegative nodal gaps stays
        nonnegative.  One-sided (obstacle) rows need more: the interpolant of
        a feasible coarse u lies below a concave obstacle at the new nodes, so
        every new node near the free boundary looks active.  There, as in the
        reduced-space method of PETSc (vinewtonrsls), the start is projected
        onto g >= 0 and a node is kept active only if, in addition, the
        multiplier read off the fine residual, y_res = D^-1 (K x - F), pushes
        into the constraint at the scale of K's diagonal:
        c g <= y_res, c = diag(K)/D.  Measured on ex9 (N = 256 from 128):
        218 -> 8 misclassified first-step nodes, Newton 4 -> 2 iterations;
        the converged solution is the same (finite termination).

        When every row is one-sided, ``WARM_SWEEPS`` damped projected Jacobi sweeps
        x <- max(b, x + omega diag(K)^-1 (F - K x)) (on the constrained unknowns) first
        smooth the interpolation error next to the free boundary (one SpMV each):
        ex9, N = 1024 from 512: 92 -> 60 rows changed by the first step and Newton
        3 -> 2 iterations (0.13 s for the sweeps); N = 256: 8 -> 4 changed rows.
        """
        x = np.array(x0, dtype=float)
        y = np.array(y0, dtype=float)
        one = self.lo < 0
        if not one.any():
            return x, y
        if one.all() and self.WARM_SWEEPS:
            dK = self.K.diagonal()
            for _ in range(self.WARM_SWEEPS):
                x += self.WARM_OMEGA * (self.F - self.K @ x) / dK
                x[self.up] = np.maximum(x[self.up], self.b)
        g = self.gap(x)
        rows = np.flatnonzero(one & (g < 0))
        x[self.up[rows]] -= g[rows]  # projection: g = 0 there
        g = self.gap(x)
        r = self.K @ x - self.F
        c = self.K.diagonal()[self.up[one]] / self.D[one]
        y_res = r[self.up[one]] / self.D[one]
        # active iff g <= y0 and c g <= y_res  <=>  g <= min(y0, y_res / c)
        y[one] = np.minimum(y[one], y_res / c)
        return x, y

    def newton_step(self, x, y, C, Ca, Cb, eps: float = 1e-12, reuse: "FactorReuse | None" = None):
        """New iterate (x', y') of the linearized system; see the module docstring.

        With ``reuse`` (one :class:`FactorReuse` per Newton run on this system)
        the reduced system may be solved by PCG preconditioned with an earlier
        step's factorization; otherwise it is factorized from scratch.
        """
        t0 = time.perf_counter()
        lin = self.linearize(x, y, C, Ca, Cb, eps)
        t1 = time.perf_counter()
        if reuse is None:
            z, path, its = SPDSolver(lin.A, self.solver).solve(lin.b), "factor", 0
        else:
            z, path, its = reuse.solve(lin, z0=lin.restrict(x))
        t2 = time.perf_counter()
        x_new, y_new = lin.recover(z)
        return x_new, y_new, StepInfo(lin.size, t1 - t0, t2 - t1, path, its)

    def linearize(self, x, y, C, Ca, Cb, eps: float = 1e-12) -> "LinearizedStep":
        """The reduced SPD system A z = b of the Newton step (module docstring) and the map z -> (x', y').

        Used by :meth:`newton_step` (direct solve) and by the inexact Newton
        driver (:mod:`ngcontact.newton.inexact`, Krylov solve).
        """
        n, m = self.n, self.m
        g = self.gap(x)
        aCa, aCb = np.abs(Ca), np.abs(Cb)
        eq = aCb <= eps * aCa
        fixed = ~eq & (aCa <= eps * aCb)
        mixed = ~eq & ~fixed

        # prescribed quantities
        g_target = np.zeros(m)
        g_target[eq] = g[eq] - C[eq] / Ca[eq]
        y_fixed = np.zeros(m)
        y_fixed[fixed] = y[fixed] - C[fixed] / Cb[fixed]
        # mixed rows: y' = c0 - w g(x'), w = Ca/Cb >= 0
        w = np.zeros(m)
        w[mixed] = Ca[mixed] / Cb[mixed]
        c0 = np.zeros(m)
        c0[mixed] = y[mixed] - C[mixed] / Cb[mixed] + w[mixed] * g[mixed]

        # right-hand side and matrix of the x-equation (before elimination)
        rhs = self.F + self._B.T @ (self.D * np.where(fixed, y_fixed, 0.0))
        Kaug = self.K
        if mixed.any():
            Wm = self.D * w
            Bm = sp.diags(np.where(mixed, 1.0, 0.0)) @ self._B
            Kaug = (self.K + Bm.T @ sp.diags(Wm) @ Bm).tocsr()
            # -B^T D y' = -B^T D c0 + B_m^T D w (B x' - b): move known parts right
            rhs = rhs + self._B.T @ (self.D * c0) + Bm.T @ (Wm * self.b)
        # elimination of the slaves of equality rows: x = Z z + x_aff
        eq_rows = np.flatnonzero(eq)
        slave_is_lo = self.lo[eq_rows] >= 0
        slaves = np.where(slave_is_lo, self.lo[eq_rows], self.up[eq_rows])
        masters = np.where(slave_is_lo, self.up[eq_rows], -1)
        keep = np.ones(n, dtype=bool)
        keep[slaves] = False
        red_index = -np.ones(n, dtype=np.int64)
        red_index[keep] = np.arange(keep.sum())
        nr = int(keep.sum())
        # Z: identity on kept unknowns, slave (lo) = master (up) - target - b
        zr = np.concatenate([np.flatnonzero(keep), slaves[slave_is_lo]])
        zc = np.concatenate([np.arange(nr), red_index[masters[slave_is_lo]]])
        Z = sp.csr_matrix((np.ones(len(zr)), (zr, zc)), shape=(n, nr))
        x_aff = np.zeros(n)
        tb = g_target[eq_rows] + self.b[eq_rows]
        x_aff[slaves] = np.where(slave_is_lo, -tb, tb)

        bred = Z.T @ (rhs - Kaug @ x_aff)
        # A = Z^T Kaug Z is formed on first use (the fixed-pattern factorization of FactorReuse does not
        # need it: 0.2 s per step at 1M unknowns)
        return LinearizedStep(self, None, bred, Z, x_aff, keep, eq, mixed, y_fixed, c0, w,
                              eq_rows, slaves, slave_is_lo, _Kaug=Kaug)


@dataclass
class LinearizedStep:
    """Reduced SPD system A z = b of one Newton step, x' = Z z + x_aff (see
    :meth:`ComplementaritySystem.linearize`).

    For any z, :meth:`recover` returns (x', y') satisfying the constraint rows
    of the linearization exactly and the x-equation on the slave unknowns
    exactly; the remaining residual of the 3-field linear system is then
    ``F - (K x' - B^T D y')`` on the kept unknowns only, equal to the reduced
    residual ``b - A z`` (slaves add their row to the master's).
    """

    system: "ComplementaritySystem"
    _A: Optional[sp.csr_matrix]
    b: np.ndarray
    Z: sp.csr_matrix
    x_aff: np.ndarray
    keep: np.ndarray
    eq: np.ndarray
    mixed: np.ndarray
    y_fixed: np.ndarray
    c0: np.ndarray
    w: np.ndarray
    eq_rows: np.ndarray
    slaves: np.ndarray
    slave_is_lo: np.ndarray
    _Kaug: Optional[sp.csr_matrix] = field(default=None, repr=False)

    @property
    def A(self) -> sp.csr_matrix:
        """The reduced matrix Z^T Kaug Z (formed on first use)."""
        if self._A is None:
            self._A = (self.Z.T @ self._Kaug @ self.Z).tocsr()
        return self._A

    @property
    def size(self) -> int:
        return int(self.keep.sum())

    def restrict(self, x: np.ndarray) -> np.ndarray:
        """z with Z z = x on the kept unknowns (warm start from a full vector x)."""
        return np.asarray(x)[self.keep]

    def recover(self, z: np.ndarray):
        """(x', y') from the reduced unknowns z."""
        s = self.system
        x_new = self.Z @ z + self.x_aff
        y_new = self.y_fixed.copy()
        mixed, eq = self.mixed, self.eq
        y_new[mixed] = self.c0[mixed] - self.w[mixed] * (s._B @ x_new - s.b)[mixed]
        if len(self.eq_rows):
            r = s.K @ x_new - s._B.T @ (s.D * np.where(eq, 0.0, y_new)) - s.F
            sign = np.where(self.slave_is_lo, -1.0, 1.0)
            y_new[self.eq_rows] = r[self.slaves] / (sign * s.D[self.eq_rows])
        return x_new, y_new


class _KeptSolve:
    """Reduced solve A z = b through a full-length :class:`~ngcontact.algebra.linalg.FixedPatternCholesky`."""

    def __init__(self, fixed: FixedPatternCholesky, keep: np.ndarray):
        self.fixed, self.keep = fixed, keep

    def solve(self, b: np.ndarray) -> np.ndarray:
        full = np.zeros(self.fixed.n)
        full[self.keep] = b
        return self.fixed.solve(full)[self.keep]


class FactorReuse:
    """Solves the reduced systems of successive Newton steps on one system, reusing a factorization.

    The reduced matrix A = Z^T (K + B_m^T diag(D w) B_m) Z of a step is
    determined by K and, row by row, by the class of each constraint row
    (equality / fixed / mixed) and the weight w of mixed rows.  When these
    differ from those of the last *factorized* step in at most
    ``max_changed`` rows, A differs from the factorized A_f by a low-rank
    term, and A z = b is solved by PCG with the SPD preconditioner

        M^{-1} = P^T A_f^{-1} P + Q^T diag(A)^{-1} Q,

    P: reduced unknowns (of this step) that were also reduced unknowns of
    the factorized step -> their positions there (zero padding elsewhere);
    Q: selection of the unknowns that are new in this step (Jacobi on them).
    M^{-1} is block diagonal with blocks (A_f^{-1})_cc (a principal block of
    an SPD matrix) and a positive diagonal, hence SPD, and M - A has rank
    O(#changed rows) (Schur complement onto the common unknowns, rank-2
    couplings of new unknowns, rank-2 master updates of eliminated slaves),
    so CG ends in O(#changed) iterations.  It runs to ``||b - A z|| <= rtol
    ||b||`` on the true residual, or to the rounding floor of a direct solve
    (:func:`~ngcontact.algebra.linalg.pcg`), i.e. to direct-solver accuracy: the
    exact-Newton iterates are unchanged up to rounding.  (rtol = 1e-12 was
    not enough: the estimators' flux reconstruction inherits the residual,
    and its normal-continuity test failed at 7e-12; rtol = 1e-15 because
    the floor stops PCG anyway where rounding dominates.)  If PCG does not
    converge within ``maxiter`` iterations or ``time_fraction`` times the
    time the reused factorization took (only when that was >= TIME_CAP_FROM
    seconds, so that small systems take deterministic paths), the step is
    factorized afresh (and that factorization is kept for the next steps).

    Cost model (measured, 2 threads, 5-point Laplacian with 1.05M unknowns):
    factorization 5.4 s, one solve with the factor 0.4 s, so a PCG iteration
    costs ~1/13 of a factorization; ex9 needed 2-9 PCG iterations for 0-16
    changed rows.  Hence the defaults: PCG only for <= 64 changed rows, and
    an attempt never costs more than one more factorization.

    One-sided constraints (obstacle problem, the w-problem of the decoupled
    membranes): every Newton matrix is K + diag on the kept unknowns, so
    factorizations are numeric refactorizations in K's pattern with one
    symbolic analysis per system (:class:`~ngcontact.algebra.linalg.FixedPatternCholesky`,
    ``fixed_pattern``), about half the cost of a fresh one; PCG is then tried
    for <= 16 changed rows only and capped at the cost of a refactorization.
    """

    #: the time cap applies only if the reused factorization took at least this long [s]
    TIME_CAP_FROM = 0.5

    #: fixed-pattern mode: a numeric refactorization costs about this fraction of the first
    #: (symbolic + numeric) factorization (measured 0.44-0.62 on the 1.05M-unknown Laplacian)
    NUMERIC_FRACTION = 0.5

    def __init__(self, system: "ComplementaritySystem", max_changed: int | None = None, maxiter: int = 60,
                 rtol: float = 1e-15, time_fraction: float | None = 1.0, fixed_pattern: bool | None = None,
                 fixed: FixedPatternCholesky | None = None):
        self.system = system
        # one-sided constraints (obstacle, decoupled membranes): every Newton matrix is K + diag on the
        # kept unknowns, refactorized in K's pattern with one symbolic analysis (FixedPatternCholesky)
        if fixed_pattern is None:
            fixed_pattern = system.solver == "sparsecholesky" and bool(np.all(system.lo < 0))
        self.fixed_pattern = bool(fixed_pattern) and bool(np.all(system.lo < 0))
        # a refactorization being cheaper there, PCG is tried for fewer changed rows (ex9, N = 512:
        # 24 changed rows took 9 PCG iterations, 1.6 s, against ~0.9 s for refactorization + solve)
        if max_changed is None:
            max_changed = 16 if self.fixed_pattern else 64
        self.max_changed, self.maxiter, self.rtol, self.time_fraction = max_changed, maxiter, rtol, time_fraction
        # FixedPatternCholesky of K (created at the first factorization, or given: symbolic analysis reused)
        self._fixed = fixed if self.fixed_pattern else None
        self._symbolic_in_t_factor = False
        self._solver = None  # SPDSolver of the factorized step
        self._rows = None  # (eq, mixed, w) of the factorized step
        self._index = None  # full indices of its reduced unknowns
        self._t_factor = 0.0

    def changed_rows(self, lin: "LinearizedStep") -> int | None:
        """Constraint rows whose contribution to A differs from the factorized step (None: nothing to reuse)."""
        if self._solver is None or lin.system is not self.system:
            return None
        eq0, mixed0, w0 = self._rows
        diff = (lin.eq != eq0) | (lin.mixed != mixed0) | (lin.mixed & (lin.w != w0))
        return int(diff.sum())

    def solve(self, lin: "LinearizedStep", z0: np.ndarray | None = None):
        """(z, path, PCG iterations) for A z = b of ``lin``; see the class docstring for ``path``."""
        changed = self.changed_rows(lin)
        path, its = "factor", 0
        if changed is not None and changed <= self.max_changed:
            t0 = time.perf_counter()
            deadline = None  # time cap only where it matters: deterministic paths on small systems
            if self.time_fraction is not None and self._t_factor >= self.TIME_CAP_FROM:
                t_next = self._t_factor * (self.NUMERIC_FRACTION if self._symbolic_in_t_factor else 1.0)
                deadline = t0 + self.time_fraction * t_next
            res = pcg(lin.A, lin.b, self._preconditioner(lin), z0, rtol=self.rtol, maxiter=self.maxiter,
                      deadline=deadline)
            its = res.iterations
            if res.converged:
                return res.x, "pcg", its
            path = "pcg-failed"
        self._solver = None  # free the old factor first: never two factors in memory
        t0 = time.perf_counter()
        if self.fixed_pattern:
            self._symbolic_in_t_factor = self._fixed is None or self._fixed.factorizations == 0
            self._solver = self._factor_fixed(lin)
        else:
            self._solver = SPDSolver(lin.A, self.system.solver)
        self._t_factor = time.perf_counter() - t0
        self._rows = (lin.eq.copy(), lin.mixed.copy(), lin.w.copy())
        self._index = np.flatnonzero(lin.keep)
        return self._solver.solve(lin.b), path, its

    def _factor_fixed(self, lin: "LinearizedStep"):
        """Numeric refactorization in K's pattern; returns an object solving the reduced system."""
        s = self.system
        if self._fixed is None:
            self._fixed = FixedPatternCholesky(s.K)
        d = np.zeros(s.n)
        if lin.mixed.any():  # B_m^T diag(D w) B_m: diagonal for one-sided rows
            np.add.at(d, s.up[lin.mixed], (s.D * lin.w)[lin.mixed])
        self._fixed.factor(lin.keep, d)
        return _KeptSolve(self._fixed, lin.keep.copy())

    def _preconditioner(self, lin: "LinearizedStep"):
        index = np.flatnonzero(lin.keep)
        _, new_pos, old_pos = np.intersect1d(index, self._index, assume_unique=True, return_indices=True)
        fresh = np.ones(len(index), dtype=bool)
        fresh[new_pos] = False
        dinv = np.where(fresh, 1.0 / np.where(fresh, lin.A.diagonal(), 1.0), 0.0)
        n_old, solver = len(self._index), self._solver

        def apply(r):
            v = np.zeros(n_old)
            v[old_pos] = r[new_pos]
            out = dinv * r
            out[new_pos] = solver.solve(v)[old_pos]
            return out

        return apply
