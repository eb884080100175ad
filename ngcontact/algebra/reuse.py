"""Factorization reuse across Newton steps: PCG preconditioned with an earlier step's factorization.

:class:`FactorReuse` solves the reduced SPD systems A z = b of successive
:class:`~ngcontact.algebra.step.LinearizedStep` s.  It keeps the last
factorized step and reuses it for any later step whose system has the same
matrix K and the same constraint rows (up, lo, D): the steps of one Newton
run, and equally the steps of systems that share K but differ in F or b
(e.g. the time steps of a time-dependent problem).
"""
from __future__ import annotations

import time
from typing import TYPE_CHECKING, Optional

import numpy as np

from .linalg import FixedPatternCholesky, SPDSolver, pcg

if TYPE_CHECKING:  # pragma: no cover
    from .step import LinearizedStep
    from .system import ComplementaritySystem

__all__ = ["FactorReuse"]


class _KeptSolve:
    """Reduced solve A z = b through a full-length :class:`~ngcontact.algebra.linalg.FixedPatternCholesky`."""

    def __init__(self, fixed: FixedPatternCholesky, keep: np.ndarray):
        self.fixed, self.keep = fixed, keep

    def solve(self, b: np.ndarray) -> np.ndarray:
        full = np.zeros(self.fixed.n)
        full[self.keep] = b
        return self.fixed.solve(full)[self.keep]


class _MatrixKey:
    """What the reduced matrix of a step depends on besides its row classes: K (the object, or one
    sharing its shape, number of entries and data array) and the constraint rows up, lo, D."""

    def __init__(self, system: "ComplementaritySystem"):
        K = system.K
        self.shape, self.nnz, self.data = K.shape, K.nnz, K.data
        self.up, self.lo, self.D = system.up, system.lo, system.D

    def matches(self, system: "ComplementaritySystem") -> bool:
        K = system.K
        if K.shape != self.shape or K.nnz != self.nnz or K.data is not self.data:
            return False
        return all(a is b or np.array_equal(a, b)
                   for a, b in ((system.up, self.up), (system.lo, self.lo), (system.D, self.D)))


class FactorReuse:
    """Solves the reduced systems of successive Newton steps, reusing a factorization.

    The reduced matrix A = Z^T (K + B_m^T diag(D w) B_m) Z of a step is
    determined by K, the constraint rows and, row by row, by the class of
    each row (equality / fixed / mixed) and the weight w of mixed rows.
    When K and the rows are those of the last *factorized* step (see
    :class:`_MatrixKey`) and the classes and weights differ in at most
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
    so CG ends in O(#changed) iterations (rank + 1 in exact arithmetic).  It
    runs to ``||b - A z|| <= rtol ||b||`` on the true residual, or to the
    rounding floor of a direct solve (:func:`~ngcontact.algebra.linalg.pcg`),
    i.e. to direct-solver accuracy: the exact-Newton iterates are unchanged
    up to rounding, which the estimators' flux reconstruction needs (it
    inherits the residual).  If PCG does not converge within
    ``min(maxiter, 2 #changed + ITER_SLACK)`` iterations or ``time_fraction``
    times the time the reused factorization took (only when that was >=
    TIME_CAP_FROM seconds, so that small systems take deterministic paths),
    the step is factorized afresh (and that factorization is kept for the
    next steps); where that time cap applies and not even 2 #changed + 1
    solves with the kept factorization (measured when it was made) fit in
    it, PCG is not tried.  After ``MAX_FAILED`` such failures no further PCG is tried
    in this Newton run (:meth:`new_run` starts the count afresh for a FactorReuse shared
    by several runs, e.g. the time steps of :mod:`ngcontact.timestepping`):
    rounding then spoils the low-rank argument (ill-conditioned systems,
    e.g. P3 on graded meshes, where a fresh factorization is the cheaper
    solve).

    Cost model: a PCG iteration costs one solve with the factor and one
    product with A, a small fraction of a factorization on large 2D
    problems; hence PCG only for few changed rows (``max_changed``), and an
    attempt never costs more than one more factorization.

    One-sided constraints (obstacle problem, the w-problem of the decoupled
    membranes): every Newton matrix is K + diag on the kept unknowns, so
    factorizations are numeric refactorizations in K's pattern with one
    symbolic analysis (:class:`~ngcontact.algebra.linalg.FixedPatternCholesky`,
    ``fixed_pattern``), cheaper than a fresh one; PCG is then tried for fewer
    changed rows and capped at the cost of a refactorization.
    """

    #: the time cap applies only if the reused factorization took at least this long [s]
    TIME_CAP_FROM = 0.05

    #: PCG iterations allowed beyond twice the changed rows (rank of M - A <= 2 #changed)
    ITER_SLACK = 10

    #: failed PCG attempts after which every later step is factorized
    MAX_FAILED = 1

    #: fixed-pattern mode: the assumed cost of a numeric refactorization relative to the first
    #: (symbolic + numeric) factorization
    NUMERIC_FRACTION = 0.5

    def __init__(self, system: "ComplementaritySystem", max_changed: Optional[int] = None, maxiter: int = 60,
                 rtol: float = 1e-15, time_fraction: Optional[float] = 1.0, fixed_pattern: Optional[bool] = None,
                 fixed: Optional[FixedPatternCholesky] = None):
        self.system = system
        # one-sided constraints (obstacle, decoupled membranes): every Newton matrix is K + diag on the
        # kept unknowns, refactorized in K's pattern with one symbolic analysis (FixedPatternCholesky)
        if fixed_pattern is None:
            fixed_pattern = system.solver == "sparsecholesky" and bool(np.all(system.lo < 0))
        self.fixed_pattern = bool(fixed_pattern) and bool(np.all(system.lo < 0))
        # a refactorization being cheaper there, PCG is tried for fewer changed rows
        if max_changed is None:
            max_changed = 16 if self.fixed_pattern else 64
        self.max_changed, self.maxiter, self.rtol, self.time_fraction = max_changed, maxiter, rtol, time_fraction
        # FixedPatternCholesky of K (created at the first factorization, or given: symbolic analysis reused)
        self._fixed = fixed if self.fixed_pattern else None
        self._own = _MatrixKey(system)  # the fixed-pattern factorizations are those of system.K and its rows
        self._symbolic_in_t_factor = False
        self._solver = None  # solver of the factorized step
        self._key = None  # _MatrixKey of the factorized step's system
        self._rows = None  # (eq, mixed, w) of the factorized step
        self._index = None  # full indices of its reduced unknowns
        self._t_factor = 0.0
        self._t_solve = 0.0  # one solve with the kept factorization
        self.failed = 0  # PCG attempts that did not converge

    def new_run(self) -> None:
        """A new Newton run starts: failed PCG attempts of earlier runs no longer count."""
        self.failed = 0

    def changed_rows(self, lin: "LinearizedStep") -> Optional[int]:
        """Constraint rows whose contribution to A differs from the factorized step (None: nothing to
        reuse, or ``lin`` belongs to a system with another K or other constraint rows)."""
        if self._solver is None or not self._key.matches(lin.system):
            return None
        eq0, mixed0, w0 = self._rows
        diff = (lin.eq != eq0) | (lin.mixed != mixed0) | (lin.mixed & (lin.w != w0))
        return int(diff.sum())

    def solve(self, lin: "LinearizedStep", z0: Optional[np.ndarray] = None):
        """(z, path, PCG iterations) for A z = b of ``lin``; ``path`` in
        :data:`~ngcontact.algebra.system.LINEAR_PATHS` (see the class docstring)."""
        path, its = "factor", 0
        attempt = self._attempt(self.changed_rows(lin))
        if attempt is not None:
            maxiter, deadline = attempt
            res = pcg(lin.A, lin.b, self._preconditioner(lin), z0, rtol=self.rtol, maxiter=maxiter, deadline=deadline,
                      jacobi=True)
            its = res.iterations
            if res.converged:
                return res.x, "pcg", its
            self.failed += 1
            path = "pcg-failed"
        self._solver = None  # free the old factor first: never two factors in memory
        t0 = time.perf_counter()
        self._symbolic_in_t_factor = False
        if self.fixed_pattern and self._own.matches(lin.system):
            self._symbolic_in_t_factor = self._fixed is None or self._fixed.factorizations == 0
            self._solver = self._factor_fixed(lin)
        else:
            self._solver = SPDSolver(lin.A, lin.system.solver)
        self._t_factor = time.perf_counter() - t0
        self._key = _MatrixKey(lin.system)
        self._rows = (lin.eq.copy(), lin.mixed.copy(), lin.w.copy())
        self._index = np.flatnonzero(lin.keep)
        t0 = time.perf_counter()
        z = self._solver.solve(lin.b)
        self._t_solve = time.perf_counter() - t0
        return z, path, its

    def _attempt(self, changed: Optional[int]):
        """(maxiter, deadline) of a PCG attempt with ``changed`` rows changed since the kept factorization, or
        None: factorize (nothing kept, too many changes, an earlier attempt failed, or a budget too small)."""
        if changed is None or changed > self.max_changed or self.failed >= self.MAX_FAILED:
            return None
        deadline = None  # time cap only where it matters: deterministic paths on small systems
        if self.time_fraction is not None and self._t_factor >= self.TIME_CAP_FROM:
            t_next = self._t_factor * (self.NUMERIC_FRACTION if self._symbolic_in_t_factor else 1.0)
            # a PCG iteration costs at least one solve with the factor: when not even the 2 #changed + 1
            # iterations of the exact-arithmetic bound fit in the time of a factorization, factorize at once
            if self.time_fraction * t_next < (2 * changed + 1) * self._t_solve:
                return None
            deadline = time.perf_counter() + self.time_fraction * t_next
        return min(self.maxiter, 2 * changed + self.ITER_SLACK), deadline

    def _factor_fixed(self, lin: "LinearizedStep"):
        """Numeric refactorization in K's pattern; returns an object solving the reduced system."""
        s = lin.system
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
