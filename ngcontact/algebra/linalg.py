"""Sparse direct solves on scipy matrices: NGSolve's sparse Cholesky (SPD), UMFPACK and SuperLU (general).

The reduced SPD Newton systems are factorized by NGSolve's ``sparsecholesky``
(much faster than scipy's ``splu`` on the 3-field system, see
/work/shared/NGSOLVE-NOTES.md); ``scipy`` (SuperLU) is kept as a fallback and
for cross-checks.  :func:`sparse_solve` also solves non-symmetric systems
(the dG variants NIPG and IIPG).
"""
from __future__ import annotations

import time
from dataclasses import dataclass
from typing import Callable, Optional

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla

from .sparse import abs_matrix, abs_row_sums

__all__ = ["SPDSolver", "MassSolver", "FixedPatternCholesky", "SOLVERS", "FACTORIZATIONS", "ngsolve_coo", "sparse_solve",
           "pcg", "PCGResult"]

SOLVERS = ("sparsecholesky", "scipy")
#: methods of :func:`sparse_solve`
FACTORIZATIONS = ("sparsecholesky", "umfpack", "splu")


def ngsolve_coo(rows, cols, vals, height: int, width: int):
    """NGSolve ``SparseMatrixd`` from COO triplets (duplicates summed).

    ``CreateFromCOO`` converts numpy arguments element by element; filling
    pyngcore arrays through their buffer views first makes the call an order
    of magnitude faster on millions of entries.
    """
    import pyngcore
    from ngsolve import la

    k = len(vals)
    arrays = (pyngcore.Array_I_S(k), pyngcore.Array_I_S(k), pyngcore.Array_D_S(k))
    for arr, src in zip(arrays, (rows, cols, vals)):
        np.asarray(arr)[:] = src
    return la.SparseMatrixd.CreateFromCOO(*arrays, height, width)


def sparse_solve(A: sp.spmatrix, b: np.ndarray, method: str) -> np.ndarray:
    """Solve A z = b by one factorization: 'sparsecholesky' (A SPD, NGSolve), 'umfpack' (NGSolve,
    general) or 'splu' (scipy's SuperLU with the MMD(A^T + A) ordering, general)."""
    if method not in FACTORIZATIONS:
        raise ValueError(f"factorization must be 'sparsecholesky', 'umfpack' or 'splu', got {method!r}")
    if A.shape[0] == 0:
        return np.zeros(0)
    if method == "splu":
        return spla.splu(sp.csc_matrix(A), permc_spec="MMD_AT_PLUS_A").solve(np.asarray(b, float))
    coo = A.tocoo()
    mat = ngsolve_coo(coo.row, coo.col, coo.data, A.shape[0], A.shape[1])
    inv = mat.Inverse(inverse=method)
    rv, sv = mat.CreateRowVector(), mat.CreateColVector()
    rv.FV().NumPy()[:] = b
    sv.data = inv * rv
    return np.array(sv.FV().NumPy())


class SPDSolver:
    """Factorize a symmetric positive definite scipy matrix once, solve many times."""

    def __init__(self, A: sp.spmatrix, method: str = "sparsecholesky"):
        if method not in SOLVERS:
            raise ValueError(f"linear solver must be one of {SOLVERS}, got {method!r}")
        self.n = A.shape[0]
        self.method = method
        if self.n == 0:
            return
        if method == "sparsecholesky":
            coo = sp.triu(A, format="coo")  # the factorization reads one triangle
            coo = (coo + sp.triu(coo, 1, format="coo").T).tocoo()
            self._mat = ngsolve_coo(coo.row, coo.col, coo.data, self.n, self.n)
            del coo  # the triplets go before the factorization (which reads the NGSolve matrix only)
            from ngsolve import TaskManager

            with TaskManager():  # threaded factorization
                self._inv = self._mat.Inverse(inverse="sparsecholesky")
            self._rhs = self._mat.CreateRowVector()
            self._sol = self._mat.CreateColVector()
        else:
            self._lu = spla.splu(sp.csc_matrix(A))

    def solve(self, b: np.ndarray) -> np.ndarray:
        if self.n == 0:
            return np.zeros(0)
        if self.method == "sparsecholesky":
            self._rhs.FV().NumPy()[:] = b
            self._sol.data = self._inv * self._rhs
            return np.array(self._sol.FV().NumPy())
        return self._lu.solve(np.asarray(b, dtype=float))


class MassSolver:
    """Solves with a mass matrix: Jacobi-preconditioned CG for the first :attr:`FACTOR_FROM` - 1 solves, a sparse
    Cholesky factorization (:class:`SPDSolver`) from then on.

    The Jacobi-scaled Lagrange mass matrix has a condition number bounded independently of h and of the grading
    (it depends on the degree only), so CG reaches the rounding floor in a fixed number of iterations (38 for
    P3 on the 186k-DOF level of the adaptive L-shape run) -- a few times cheaper than a factorization, which
    pays only when many right-hand sides come (the estimators of every Krylov iterate of an adaptive inexact
    Newton loop).  The CG target is :data:`RTOL` relative to the right-hand side, also row by row in the units
    of the solution (``pcg(..., jacobi=True)``); a CG run that misses it within :data:`MAXITER` iterations
    switches to the factorization at once (deterministic: no timing enters).
    """

    #: the call of :meth:`solve` that factorizes (earlier calls run CG)
    FACTOR_FROM = 5
    #: relative residual of the CG solves
    RTOL = 1e-14
    #: CG iterations before the factorization takes over
    MAXITER = 400

    def __init__(self, M: sp.spmatrix):
        self.M = sp.csr_matrix(M)
        self.calls = 0
        self._direct: Optional[SPDSolver] = None
        diag = self.M.diagonal()
        if self.M.shape[0] and not np.all(diag > 0.0):
            raise ValueError("MassSolver: the matrix has a non-positive diagonal entry (not a mass matrix)")
        self._dinv = 1.0 / diag

    @property
    def factorized(self) -> bool:
        return self._direct is not None

    def solve(self, b: np.ndarray) -> np.ndarray:
        self.calls += 1
        if self._direct is None and self.calls < self.FACTOR_FROM:
            res = pcg(self.M, np.asarray(b, dtype=float), lambda r: self._dinv * r, rtol=self.RTOL,
                      maxiter=self.MAXITER, jacobi=True)
            if res.converged:
                return res.x
        if self._direct is None:
            self._direct = SPDSolver(self.M)
        return self._direct.solve(b)


class FixedPatternCholesky:
    """Sparse Cholesky of the matrices ``K`` restricted to a changing set of kept unknowns, with the
    symbolic analysis (fill-reducing ordering, elimination tree) done once.

    A matrix of the family is K + diag(d) on the kept unknowns; it is embedded in K's pattern by
    zeroing the rows and columns of the dropped unknowns and putting 1 on their diagonal, so every
    member has the same pattern and NGSolve's ``SparseCholesky.Update()`` refactors it numerically,
    skipping the symbolic analysis of a fresh factorization.  Used by
    :class:`~ngcontact.algebra.reuse.FactorReuse` for one-sided (obstacle-type) constraints, whose
    Newton matrices are exactly of this form.
    """

    def __init__(self, K: sp.spmatrix):
        K = sp.csr_matrix(K, dtype=float, copy=True)
        K.sum_duplicates()
        # explicit zeros (P1 stiffness couplings across right angles: a 9- instead of a 5-point pattern on
        # ex9's mesh) would be kept as structural nonzeros and enlarge the factor
        K.eliminate_zeros()
        K.sort_indices()
        self.n = K.shape[0]
        self._K = K
        coo = K.tocoo()
        self._row, self._col = coo.row, coo.col
        self._diag = np.flatnonzero(self._row == self._col)  # position of (i, i): one per row, rows sorted
        if len(self._diag) != self.n:
            raise ValueError("K must store every diagonal entry")
        self._mat = ngsolve_coo(self._row, self._col, coo.data, self.n, self.n)
        self._vals = self._mat.AsVector().FV().NumPy()
        if not np.array_equal(self._vals, coo.data):  # NGSolve stores CSR sorted like scipy's canonical form
            raise RuntimeError("unexpected entry order of the NGSolve sparse matrix")
        self._inv = None
        self._rhs = self._mat.CreateRowVector()
        self._sol = self._mat.CreateColVector()
        self.factorizations = 0

    def factor(self, keep: np.ndarray, diag_add: Optional[np.ndarray] = None) -> None:
        """Factorize K + diag(diag_add) on the unknowns ``keep`` (identity elsewhere)."""
        from ngsolve import TaskManager

        drop = ~np.asarray(keep, dtype=bool)
        vals = self._K.data.copy()
        if diag_add is not None:
            vals[self._diag] += diag_add
        vals[drop[self._row] | drop[self._col]] = 0.0
        vals[self._diag[drop]] = 1.0
        self._vals[:] = vals
        with TaskManager():
            if self._inv is None:
                self._inv = self._mat.Inverse(inverse="sparsecholesky")
            else:
                self._inv.Update()
        self.factorizations += 1

    def solve(self, b: np.ndarray) -> np.ndarray:
        """Full-length solve (b must vanish on the dropped unknowns; the solution does there too)."""
        self._rhs.FV().NumPy()[:] = b
        self._sol.data = self._inv * self._rhs
        return np.array(self._sol.FV().NumPy())


@dataclass
class PCGResult:
    """Outcome of :func:`pcg`: iterate, iterations, whether ||b - A x|| <= rtol ||b|| (true residual)."""

    x: np.ndarray
    iterations: int
    converged: bool
    relres: float  # last true residual ||b - A x|| / ||b|| (recursive one if the loop broke off)


def pcg(A, b: np.ndarray, M: Callable[[np.ndarray], np.ndarray], x0: Optional[np.ndarray] = None, *,
        rtol: float = 1e-12, maxiter: int = 60, deadline: Optional[float] = None, jacobi: bool = False) -> PCGResult:
    """Preconditioned conjugate gradients for SPD ``A`` with SPD preconditioner ``M(r) ~ A^{-1} r``.

    Target: ``||b - A x|| <= max(rtol ||b||, 4 eps || |A| |x| ||)``; the
    second term is the residual a backward-stable direct solver leaves, so
    an ill-conditioned system with a small right-hand side (where rtol
    ||b|| is below rounding level) still converges to direct-solver accuracy.
    It is formed (one product with |A|) only where its cheap upper bound
    4 eps ||A||_inf ||x|| exceeds rtol ||b||: with rows of very different
    size (tensions 1e6 apart) that bound was above the residual and CG
    stopped at once, far from what a direct solve reaches.
    Convergence is declared on the *true* residual: when the recursively
    updated residual reaches the target, ``b - A x`` is recomputed; if it
    is still too large, the iteration restarts from it (residual
    replacement) instead of trusting the drifted recursion.  Stops without
    convergence after ``maxiter`` iterations, when ``time.perf_counter()``
    passes ``deadline``, or on a non-positive curvature p.Ap.

    ``jacobi``: convergence also needs the same test in the norm of diag(A)^{-1} v (residuals in the units of
    x, row by row), so that rows of very different size are each resolved to their own round-off: with the
    plain norm alone, rows 1e12 smaller than the others (two membranes with tensions 1e12 apart) kept a
    residual of 1e-4 of their own size.
    """
    bnorm = float(np.linalg.norm(b))
    x = np.zeros_like(b) if x0 is None else np.array(x0, dtype=float)
    if bnorm == 0.0:
        return PCGResult(np.zeros_like(b), 0, True, 0.0)
    anorm = float(abs_row_sums(A).max()) if A.shape[0] else 0.0
    eps4 = 4 * np.finfo(float).eps
    tol = rtol * bnorm
    absA = []  # |A|, formed on first use

    def abs_A():
        if not absA:
            absA.append(abs_matrix(A))
        return absA[0]

    def target_at(x, rnorm):
        """The target at x, its round-off term formed only where it could decide (docstring)."""
        if rnorm <= tol or eps4 * anorm * np.linalg.norm(x) <= tol:
            return tol
        return max(tol, eps4 * float(np.linalg.norm(abs_A() @ np.abs(x))))

    d = np.asarray(A.diagonal(), dtype=float) if jacobi and A.shape[0] else None
    scale = 1.0 / d if d is not None and np.all(d > 0) else None
    if scale is not None:
        tol_s = rtol * float(np.linalg.norm(scale * b))
        # ||diag(s) |A| ||_2 <= (||.||_1 ||.||_inf)^{1/2}, |A| symmetric: its column sums are |A| s
        anorm_s = float(np.sqrt((abs_A() @ scale).max() * (scale * abs_row_sums(A)).max()))

    def in_units(x, r) -> bool:
        """The ``jacobi`` test at x (True without it)."""
        if scale is None:
            return True
        target = max(tol_s, eps4 * np.linalg.norm(scale * (abs_A() @ np.abs(x))))
        return float(np.linalg.norm(scale * r)) <= target

    def may_hold(x, r) -> bool:
        """The recursive residual's ``jacobi`` norm within reach of its target (True without it): only then is
        the true residual formed, so that CG is not restarted on every iteration while the plain test holds."""
        if scale is None:
            return True
        rs = float(np.linalg.norm(scale * r))
        return rs <= tol_s or rs <= eps4 * anorm_s * np.linalg.norm(x)

    r = b - A @ x
    rnorm = float(np.linalg.norm(r))
    if rnorm <= target_at(x, rnorm) and in_units(x, r):
        return PCGResult(x, 0, True, rnorm / bnorm)
    z = M(r)
    p, rz = z.copy(), float(r @ z)
    work = np.empty_like(p)  # alpha p and alpha q formed in place: no new vector per iteration
    k = 0
    for k in range(1, maxiter + 1):
        q = A @ p
        pq = float(p @ q)
        if not pq > 0.0:
            break
        alpha = rz / pq
        x += np.multiply(p, alpha, out=work)
        r -= np.multiply(q, alpha, out=work)
        rnorm = float(np.linalg.norm(r))
        if (rnorm <= eps4 * anorm * np.linalg.norm(x) or rnorm <= tol) and may_hold(x, r):  # cheap bounds first
            r = b - A @ x
            rnorm = float(np.linalg.norm(r))
            if rnorm <= target_at(x, rnorm) and in_units(x, r):
                return PCGResult(x, k, True, rnorm / bnorm)
            z = M(r)  # residual replacement: restart from the true residual
            p, rz = z.copy(), float(r @ z)
            continue
        if deadline is not None and time.perf_counter() > deadline:
            break
        z = M(r)
        rz_new = float(r @ z)
        p *= rz_new / rz  # p = z + beta p, in place (the same numbers)
        p += z
        rz = rz_new
    return PCGResult(x, k, False, rnorm / bnorm)
