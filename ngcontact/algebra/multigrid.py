r"""Truncated geometric multigrid for the reduced SPD Newton systems.

A Newton step of the contact problem solves A z = b with A = Z^T K Z
(:meth:`~ngcontact.algebra.system.ComplementaritySystem.linearize`): z holds the unknowns x that
the step keeps (``keep``), the others are fixed by the active constraints.  Given the nested
P1 prolongations P_l of the unconstrained unknowns (level l-1 -> level l), the coarse spaces of
the reduced system are those of K with every fine basis function *truncated* on the unknowns the
step does not keep (Kornhuber's truncated multigrid, here in Galerkin form):

    P_red = P_L[keep, :]  (coarse unknowns whose truncated function vanishes are dropped),
    A_{L-1} = P_red^T A P_red,   A_{l-1} = P_l^T A_l P_l  (l < L, rows/columns of dropped
    coarse unknowns removed level by level),

so every coarse correction is a correction of the reduced problem: it never moves a fixed
unknown, and near the free boundary the coarse functions see the contact exactly.  Away from the
fixed unknowns the truncation changes nothing: where the unconstrained matrices K_l of the levels
are at hand (``matrices``; a nested run has them, :func:`galerkin_consistent` checks that
K_{l-1} = P_l^T K_l P_l), a row i of A_{l-1} is read off K_{l-1} when the fine rows in the support
of its basis function are *clean* -- rows of A_l that are rows of K_l (finest level: kept unknowns
whose neighbours in K are all kept; coarser: rows whose support is clean) -- and only the other
rows are formed by the products (:func:`_galerkin_rows`).  The
V-cycle smooths with Gauss-Seidel (forward before, backward after the coarse correction: the
cycle is a symmetric positive definite operator, a valid CG preconditioner; pyamg's compiled
kernel) or with a Chebyshev polynomial in D^{-1} A (the same before and after; numpy only), and
factorizes the coarsest level.  Set-up is sparse products, the cycle sparse matrix-vector products
and the compiled sweeps (no Python loop over unknowns).

:func:`p1_prolongation` builds P_l from the parent table of structured nested meshes; the
hierarchy of a run is kept by the discretizations (``mg_prolongations``).  Where there is no
nested hierarchy, :class:`AlgebraicMultigrid` (classical Ruge-Stueben AMG of pyamg built on the
reduced matrix itself) is the preconditioner.
"""
from __future__ import annotations

import copy
import time
from dataclasses import dataclass, field
from typing import List, Optional, Sequence

import numpy as np
import scipy.sparse as sp

from .linalg import SPDSolver
from .sparse import abs_row_sums, kept_entries, place_rows, row_entries, submatrix

__all__ = ["Multigrid", "MultigridLevel", "AlgebraicMultigrid", "HierarchyCache", "SMOOTHERS", "p1_prolongation",
           "field_prolongation", "galerkin_consistent"]

#: V-cycle smoothers of :class:`Multigrid`
SMOOTHERS = ("gauss-seidel", "chebyshev")
#: coarsest levels up to this size are factorized densely (a sparse factorization's set-up costs more there)
DENSE_COARSE = 1000
#: :func:`galerkin_consistent`: K_c v and P^T K P v of a random v agree row by row to this times (|K_c| |v|)_i (the
#: products round at 1e-16 of that; a coarse matrix that is not the Galerkin product differs at order 1)
GALERKIN_RTOL = 1e-12


def p1_prolongation(parents: np.ndarray, fine_interior: np.ndarray, coarse_interior: np.ndarray,
                    n_coarse_nodes: int) -> sp.csr_matrix:
    """Nested P1 interpolation from the coarse interior nodes to the fine interior nodes.

    ``parents``: (fine nodes, 2) -- fine node v is the midpoint of coarse nodes parents[v] (a
    repeated index: v is that coarse node); ``*_interior``: node numbers of the unknowns.  Coarse
    boundary nodes carry homogeneous corrections and are left out.
    """
    nc = len(coarse_interior)
    itype = np.int32 if max(nc, 2 * len(fine_interior)) < np.iinfo(np.int32).max else np.int64
    ci = np.full(n_coarse_nodes, -1, dtype=itype)
    ci[coarse_interior] = np.arange(nc, dtype=itype)
    nf = len(fine_interior)
    a, b = ci[parents[fine_interior, 0]], ci[parents[fine_interior, 1]]
    # CSR directly, columns increasing within a row: lo (weight 1 for a repeated parent, else 1/2), then hi
    lo, hi = np.minimum(a, b), np.maximum(a, b)
    same = lo == hi
    first, second = lo >= 0, (hi >= 0) & ~same  # coarse boundary parents carry no entry
    keep = np.stack([first, second], axis=1).ravel()
    cols = np.stack([lo, hi], axis=1).ravel()[keep]
    data = np.stack([np.where(same, 1.0, 0.5), np.full(nf, 0.5)], axis=1).ravel()[keep]
    indptr = np.zeros(nf + 1, dtype=itype)
    np.cumsum(first.astype(itype) + second, out=indptr[1:])
    return sp.csr_matrix((data, cols, indptr), shape=(nf, nc))


def _truncated(P: sp.csr_matrix, rows) -> "tuple[sp.csr_matrix, np.ndarray]":
    """(P[rows][:, used], used): the rows ``rows`` (boolean mask or increasing indices) of P and its columns with a
    nonzero entry in them (the coarse unknowns whose truncated function survives).  One pass over P's entries:
    every entry of a selected row is kept unless it is an explicit zero (:func:`~.sparse.kept_entries`)."""
    sel = np.asarray(rows)
    if sel.dtype != bool:
        mask = np.zeros(P.shape[0], dtype=bool)
        mask[sel] = True
        sel = mask
    entries = np.repeat(sel, np.diff(P.indptr))
    entries &= P.data != 0
    hit = np.zeros(P.shape[1], dtype=bool)
    hit[P.indices[entries]] = True
    used = np.flatnonzero(hit)
    new_col = np.cumsum(hit) - 1
    return kept_entries(P, entries, np.flatnonzero(sel), new_col[P.indices], len(used)), used


def galerkin_consistent(P: sp.csr_matrix, K: sp.csr_matrix, Kc: sp.csr_matrix) -> bool:
    """Whether the coarse matrix ``Kc`` is the Galerkin product P^T K P (to ``GALERKIN_RTOL``), tested on one random
    vector (seeded): three products instead of the triple product.  Nested conforming spaces with the same bilinear
    form give it exactly in exact arithmetic (P1 on nested meshes with piecewise constant coefficients)."""
    if P.shape != (K.shape[0], Kc.shape[0]) or K.shape[0] != K.shape[1] or Kc.shape[0] != Kc.shape[1]:
        return False
    if Kc.shape[0] == 0:
        return True
    Kc = Kc.tocsr()
    v = np.random.default_rng(0).standard_normal(Kc.shape[0])
    e = P.T @ (K @ (P @ v)) - Kc @ v
    # row by row in the row's own scale: blocks of very different size (tensions 1e12 apart) are each checked
    scale = abs_row_sums(sp.csr_matrix((np.abs(Kc.data) * np.abs(v)[Kc.indices], Kc.indices, Kc.indptr),
                                       shape=Kc.shape))
    return bool(np.all(np.abs(e) <= GALERKIN_RTOL * scale))


def _clean_fine(K: sp.csr_matrix, keep: np.ndarray) -> np.ndarray:
    """Rows of K[keep][:, keep] that are rows of K: kept unknowns whose neighbours in K are all kept (mask).  K is
    symmetric, so the unknowns next to a dropped one are the columns of the dropped unknowns' rows."""
    touched = np.zeros(K.shape[0], dtype=bool)
    touched[K.indices[row_entries(K.indptr, np.flatnonzero(~keep))]] = True
    return keep & ~touched


def _galerkin_rows(A: sp.csr_matrix, P: sp.csr_matrix, used: np.ndarray, P_full: sp.csr_matrix,
                   clean: np.ndarray, Kc: sp.csr_matrix) -> "tuple[sp.csr_matrix, np.ndarray]":
    """(P^T A P, clean rows of the coarse level): rows whose basis function is supported on ``clean`` fine rows
    (rows of A that are rows of the unconstrained K, over the fine level's numbering) are K_c's rows (their
    columns are all in ``used``); the others are formed by products.  ``P`` = P_full[rows of A][:, used]."""
    dirty = (P_full.T @ (~clean).astype(np.float32)) > 0  # P >= 0: a positive sum is a non-clean fine row
    clean_c = np.zeros(P_full.shape[1], dtype=bool)
    clean_c[used] = True
    clean_c &= ~dirty
    keep_rows = clean_c[used]
    own, other = np.flatnonzero(keep_rows), np.flatnonzero(~keep_rows)
    rows_own = submatrix(Kc, used[own], used)
    rows_other = (_transpose_csr(P)[other] @ A) @ P
    return _merge_rows(len(used), own, rows_own, other, rows_other), clean_c


def _merge_rows(n: int, idx1: np.ndarray, M1: sp.csr_matrix, idx2: np.ndarray, M2: sp.csr_matrix) -> sp.csr_matrix:
    """The n-row CSR matrix whose rows idx1 are those of M1 and rows idx2 those of M2 (disjoint, covering 0..n-1)."""
    counts = np.zeros(n, dtype=np.int64)
    counts[idx1] = np.diff(M1.indptr)
    counts[idx2] = np.diff(M2.indptr)
    nnz = int(counts.sum())
    itype = np.int32 if max(nnz, M1.shape[1]) < np.iinfo(np.int32).max else np.int64
    indptr = np.zeros(n + 1, dtype=itype)
    np.cumsum(counts, out=indptr[1:])
    data, indices = np.empty(nnz), np.empty(nnz, dtype=itype)
    for idx, M in ((idx1, M1), (idx2, M2)):
        place_rows(data, indices, indptr[idx], M)
    return sp.csr_matrix((data, indices, indptr), shape=(n, M1.shape[1]))


def _level(A: sp.csr_matrix, P: sp.csr_matrix, chebyshev: bool) -> MultigridLevel:
    if not chebyshev:  # Gauss-Seidel needs A only
        return MultigridLevel(A, P)
    dinv = 1.0 / A.diagonal()
    lmax = float((abs_row_sums(A) * dinv).max())  # Gershgorin bound of D^-1 A
    return MultigridLevel(A, P, dinv, lmax)


def _transpose_csr(M: sp.csr_matrix) -> sp.csr_matrix:
    """M^T in CSR form: the Galerkin products then multiply CSR by CSR.  scipy's CSC @ CSR converts
    the right factor (A P, the larger) to CSC first; transposing P (two entries per row) is cheaper."""
    return M.T.tocsr()


def field_prolongation(P: sp.csr_matrix, nfields: int) -> sp.csr_matrix:
    """blockdiag(P, ..., P): the prolongation of ``nfields`` stacked fields."""
    return P if nfields == 1 else sp.block_diag([P] * nfields, format="csr")


@dataclass
class MultigridLevel:
    """One level of the V-cycle: matrix, prolongation from the next coarser level, smoother data."""

    A: sp.csr_matrix
    P: Optional[sp.csr_matrix]  # coarser -> this level (None on the coarsest)
    dinv: np.ndarray = field(repr=False, default=None)
    lmax: float = 0.0  # upper bound of the spectrum of D^-1 A (Gershgorin)


class Multigrid:
    """Symmetric V-cycle preconditioner of the reduced system of one Newton step (module docstring).

    ``prolongations``: P_1..P_L of the unconstrained unknowns, coarse to fine (P_L maps level L-1 to
    the unknowns of ``keep``'s length); ``keep``: the unknowns of A among them (None: all), A = K_L[keep][:, keep]
    when ``matrices`` K_0..K_L (the unconstrained matrices of the levels, Galerkin-consistent with the
    prolongations) are given: the clean rows of every coarse matrix are then read off them (module docstring).
    ``smoother``: one of :data:`SMOOTHERS`; ``degree``: its sweeps (Gauss-Seidel) or steps (Chebyshev)
    before and after the coarse correction; ``ratio``: the Chebyshev smoother damps the part
    [lmax / ratio, lmax] of the spectrum of D^-1 A.
    """

    def __init__(self, A: sp.csr_matrix, prolongations: Sequence[sp.csr_matrix], keep: Optional[np.ndarray] = None,
                 *, degree: int = 1, ratio: float = 8.0, solver: str = "sparsecholesky", smoother: str = "gauss-seidel",
                 matrices: Sequence[sp.csr_matrix] = ()):
        if smoother not in SMOOTHERS:
            raise ValueError(f"smoother must be one of {SMOOTHERS}, got {smoother!r}")
        t0 = time.perf_counter()
        self.degree, self.ratio, self.solver, self.smoother = int(degree), float(ratio), solver, smoother
        if smoother == "gauss-seidel":  # pyamg's compiled sweep (imported here: half a second)
            from pyamg.relaxation.relaxation import gauss_seidel

            self._gauss_seidel = gauss_seidel
        A = A.tocsr()
        Ps = list(prolongations)
        levels: List[MultigridLevel] = []
        self._finest = (Ps[-1] if Ps else None, None)
        rows = keep if keep is not None else (np.ones(Ps[-1].shape[0], dtype=bool) if Ps else None)
        clean = None
        if Ps and len(matrices) == len(Ps) + 1:
            mask = np.zeros(Ps[-1].shape[0], dtype=bool)
            mask[rows] = True
            clean = _clean_fine(matrices[-1], mask)
        for j in range(len(Ps) - 1, -1, -1):
            P, used = _truncated(Ps[j], rows)
            if j == len(Ps) - 1:
                self._finest = (Ps[-1], used)
            levels.append(_level(A, P, smoother == "chebyshev"))
            if clean is not None:
                A, clean = _galerkin_rows(A, P, used, Ps[j], clean, matrices[j])
            else:
                A = _transpose_csr(P) @ (A @ P)  # CSR products only (a CSC factor would convert A P)
            rows = used
        levels.append(MultigridLevel(A, None))
        self.levels = levels  # fine first
        self.coarse = _DenseCholesky(A) if A.shape[0] <= DENSE_COARSE else SPDSolver(A, solver)
        self.time_setup = time.perf_counter() - t0

    def updated(self, A: sp.csr_matrix, keep: Optional[np.ndarray]) -> "Multigrid":
        """This hierarchy for another reduced matrix ``A`` of the same K (another ``keep``): the finest level
        is rebuilt (matrix, truncated prolongation, smoother), the coarse levels are reused.  A valid SPD
        preconditioner for any ``keep``; a good one when few unknowns changed (successive Newton steps)."""
        t0 = time.perf_counter()
        P_full, used = self._finest
        if P_full is None:
            return Multigrid(A, (), degree=self.degree, ratio=self.ratio, solver=self.solver, smoother=self.smoother)
        out = copy.copy(self)
        P = submatrix(P_full, keep if keep is not None else np.ones(P_full.shape[0], dtype=bool), used)
        out.levels = [_level(A.tocsr(), P, self.smoother == "chebyshev")] + self.levels[1:]
        out.time_setup = time.perf_counter() - t0
        return out

    @property
    def sizes(self) -> List[int]:
        return [lev.A.shape[0] for lev in self.levels]

    def _smooth(self, lev: MultigridLevel, x: Optional[np.ndarray], b: np.ndarray) -> np.ndarray:
        """``degree`` Chebyshev steps for D^-1 A on [lmax / ratio, lmax] from x (None: from 0; x is updated)."""
        hi = lev.lmax
        lo = hi / self.ratio
        theta, delta = 0.5 * (hi + lo), 0.5 * (hi - lo)
        sigma = theta / delta
        rho = 1.0 / sigma
        r = b.copy() if x is None else b - lev.A @ x
        d = lev.dinv * r
        d *= 1.0 / theta
        if x is None:
            x = d.copy()
        else:
            x += d
        for _ in range(1, self.degree):
            r -= lev.A @ d
            rho_new = 1.0 / (2.0 * sigma - rho)
            d *= rho_new * rho
            d += (2.0 * rho_new / delta) * (lev.dinv * r)
            x += d
            rho = rho_new
        return x

    def _cycle(self, j: int, b: np.ndarray) -> np.ndarray:
        lev = self.levels[j]
        if lev.P is None:
            return self.coarse.solve(b)
        if self.smoother == "gauss-seidel":
            x = np.zeros_like(b)
            self._gauss_seidel(lev.A, x, b, iterations=self.degree, sweep="forward")
            r = b - lev.A @ x
            x += lev.P @ self._cycle(j + 1, lev.P.T @ r)
            self._gauss_seidel(lev.A, x, b, iterations=self.degree, sweep="backward")
            return x
        x = self._smooth(lev, None, b)
        r = b - lev.A @ x
        x += lev.P @ self._cycle(j + 1, lev.P.T @ r)
        return self._smooth(lev, x, b)

    def __call__(self, r: np.ndarray) -> np.ndarray:
        """One V-cycle applied to ``r`` from a zero start: z ~ A^-1 r."""
        return self._cycle(0, np.asarray(r, dtype=float))


class _DenseCholesky:
    """Dense Cholesky factorization of a small SPD matrix (the coarsest level).  A truncated coarse matrix may be
    only semidefinite: where few fine unknowns are kept, more coarse functions survive than the kept unknowns can
    tell apart (7 kept of 261,121 gave a 9 x 9 matrix of rank 7).  Then the coarse solve is the pseudo-inverse
    (symmetric eigen-decomposition, eigenvalues below 1e-12 of the largest dropped): the V-cycle stays a symmetric
    positive semidefinite correction, and with the smoothers a valid CG preconditioner."""

    def __init__(self, A: sp.spmatrix):
        from scipy.linalg import LinAlgError, cho_factor

        self._c = self._pinv = None
        if not A.shape[0]:
            return
        dense = A.toarray()
        try:
            self._c = cho_factor(dense)
        except LinAlgError:
            w, V = np.linalg.eigh(0.5 * (dense + dense.T))
            keep = w > 1e-12 * max(float(w.max(initial=0.0)), np.finfo(float).tiny)
            self._pinv = (V[:, keep] / w[keep]) @ V[:, keep].T

    def solve(self, b: np.ndarray) -> np.ndarray:
        from scipy.linalg import cho_solve

        if self._c is not None:
            return cho_solve(self._c, b)
        return self._pinv @ b if self._pinv is not None else np.zeros(0)


class AlgebraicMultigrid:
    """Ruge-Stueben AMG V-cycle (pyamg, Gauss-Seidel smoothing) of one reduced matrix: the preconditioner of
    the multigrid Newton modes where the mesh has no nested hierarchy.  Same interface as :class:`Multigrid`."""

    def __init__(self, A: sp.csr_matrix):
        import pyamg

        t0 = time.perf_counter()
        self._ml = pyamg.ruge_stuben_solver(sp.csr_matrix(A))
        self._M = self._ml.aspreconditioner(cycle="V")
        self.levels = self._ml.levels
        self.time_setup = time.perf_counter() - t0

    @property
    def sizes(self) -> List[int]:
        return [lev.A.shape[0] for lev in self.levels]

    def updated(self, A: sp.csr_matrix, keep: Optional[np.ndarray]) -> "AlgebraicMultigrid":
        """A new hierarchy for ``A`` (the algebraic coarsening depends on the whole matrix)."""
        return AlgebraicMultigrid(A)

    def __call__(self, r: np.ndarray) -> np.ndarray:
        return self._M @ np.asarray(r, dtype=float)


class HierarchyCache:
    """The V-cycle of the successive reduced systems of one Newton run: reused while the row classes of the
    steps do not change, its finest level updated when at most ``update_fraction`` of the reduced unknowns
    changed class (:meth:`Multigrid.updated`; an algebraic one is rebuilt), otherwise rebuilt.

    ``prolongations``: the nested prolongations (empty: :class:`AlgebraicMultigrid`); ``opt``: the multigrid
    settings (``update_fraction``, ``degree``, ``ratio``, ``smoother``).  :meth:`get` takes a step with row
    classes ``eq``, ``mixed``, ``w``, kept unknowns ``keep``, ``size``, the reduced matrix ``A`` and
    ``share_matrix`` (:class:`~ngcontact.algebra.step.LinearizedStep`)."""

    def __init__(self, prolongations, opt, solver: str, matrices=()):
        self.prolongations, self.opt, self.solver = tuple(prolongations), opt, solver
        self.matrices = tuple(matrices)  # K_0..K_L of the levels (Multigrid), or ()
        self.mg = None
        self._rows = None  # row classes the hierarchy was built for

    def get(self, lin):
        """(V-cycle, how): 0 reused, 1 built, 2 finest level updated."""
        rows = (lin.eq, lin.mixed, lin.w)
        if self.mg is not None:
            changed = sum(int(np.count_nonzero(a != b)) for a, b in zip(rows, self._rows))
            if changed == 0:
                if isinstance(self.mg, Multigrid):  # the same row classes: the same reduced matrix, not formed again
                    lin.share_matrix(self.mg.levels[0].A)
                return self.mg, 0
            if changed <= self.opt.update_fraction * lin.size:
                self.mg.levels[0].A = None  # the old finest matrix goes before the new one is formed
                self.mg = self.mg.updated(lin.A, lin.keep)
                self._rows = tuple(np.array(a, copy=True) for a in rows)
                return self.mg, 2
        self.mg = None  # free the old hierarchy first
        opt = self.opt
        if self.prolongations:
            self.mg = Multigrid(lin.A, self.prolongations, lin.keep, degree=opt.degree, ratio=opt.ratio,
                                solver=self.solver, smoother=opt.smoother, matrices=self._matrices(lin))
        else:
            self.mg = AlgebraicMultigrid(lin.A)
        self._rows = tuple(np.array(a, copy=True) for a in rows)
        return self.mg, 1

    def _matrices(self, lin):
        """The levels' matrices where the step's matrix is K restricted to the kept unknowns (no mixed rows, every
        slave an obstacle row's unknown, not merged into a master), else ()."""
        if not self.matrices or lin.mixed.any() or lin.slave_is_lo.any():
            return ()
        return self.matrices
