"""The algebraic complementarity system every discretization produces.

    K x - B^T (D y) = F,
    g(x) = B x - b >= 0,   y >= 0,   g(x) . y = 0,

with K symmetric positive definite (n x n; a subclass may admit a
non-symmetric K and factorize it in ``direct_solve``), D > 0 diagonal (m weights) and
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
The multiplier on equality rows is recovered from the slave equation.  The
row classes and the prescribed quantities come from :func:`classify_rows`,
shared with the systems that reduce the step otherwise (the condensed HHO
system); :meth:`ComplementaritySystem.direct_solve` is the one place a
subclass changes the factorization (the non-symmetric dG systems).
Factorization reuse across steps lives in :mod:`.reuse`.
"""
from __future__ import annotations

import copy
import math
import time
from dataclasses import dataclass, field
from typing import Optional, Tuple

import numpy as np
import scipy.sparse as sp

from .certificate import certificate
from .linalg import SPDSolver
from .relax import FreeBoundaryRelaxation
from .step import LinearizedStep

__all__ = ["ComplementaritySystem", "LinearizedStep", "StepInfo", "RowClasses", "classify_rows", "LINEAR_PATHS",
           "power_of_two"]


def power_of_two(v: float) -> float:
    """2^round(log2 v) for a positive finite v, else 1 (scaling by it is exact in floating point).

    >>> power_of_two(3.0), power_of_two(1e-160) == 2.0 ** -532, power_of_two(0.0)
    (4.0, True, 1.0)
    """
    if not (v > 0 and math.isfinite(v)):
        return 1.0
    return math.ldexp(1.0, round(math.log2(v)))

#: how a Newton step's reduced system was solved (IterationRecord.linear_path is the index): fresh
#: factorization, PCG with a reused factorization, PCG gave up (then factorized), PCG + truncated multigrid
LINEAR_PATHS = ("factor", "pcg", "pcg-failed", "multigrid")


@dataclass
class StepInfo:
    reduced_size: int
    time_assemble: float
    time_solve: float
    path: str = "factor"  # LINEAR_PATHS: fresh factorization | PCG, reused factorization | PCG gave up, then factor
    pcg_its: int = 0


@dataclass
class RowClasses:
    """Classes of the linearized complementarity rows C + Ca (g' - g) + Cb (y' - y) = 0 and what they prescribe.

    ``eq`` (Cb = 0 relative to Ca): g(x') = ``g_target``; ``fixed`` (Ca = 0 relative to Cb):
    y' = ``y_fixed``; ``mixed`` (both nonzero): y' = ``c0`` - ``w`` g(x'), w = Ca/Cb.  Each
    prescribed array is zero off its class.
    """

    eq: np.ndarray
    fixed: np.ndarray
    mixed: np.ndarray
    g_target: np.ndarray
    y_fixed: np.ndarray
    w: np.ndarray
    c0: np.ndarray


def classify_rows(g, y, C, Ca, Cb, eps: float = 1e-12, weight: float = 1.0) -> RowClasses:
    """Row classes of the Newton step at the gap ``g`` and multiplier ``y`` (see :class:`RowClasses`).

    ``C``, ``Ca``, ``Cb``: the value and diagonal generalized Jacobian of C(w g, y), w = ``weight``
    (the system's constraint weight, so Ca = w dC/da); a derivative counts as zero when it is at most
    ``eps`` times the other one, compared as dC/da and dC/db (dimensionless).
    """
    m = len(g)
    aCa, aCb = np.abs(Ca) / weight, np.abs(Cb)
    eq = aCb <= eps * aCa
    fixed = ~eq & (aCa <= eps * aCb)
    mixed = ~eq & ~fixed
    g_target = np.zeros(m)
    g_target[eq] = g[eq] - C[eq] / Ca[eq]
    y_fixed = np.zeros(m)
    y_fixed[fixed] = y[fixed] - C[fixed] / Cb[fixed]
    w = np.zeros(m)
    w[mixed] = Ca[mixed] / Cb[mixed]
    c0 = np.zeros(m)
    c0[mixed] = y[mixed] - C[mixed] / Cb[mixed] + w[mixed] * g[mixed]
    return RowClasses(eq, fixed, mixed, g_target, y_fixed, w, c0)


@dataclass
class ComplementaritySystem:
    """K x - B^T D y = F with constraints g = B x - b >= 0 (see module doc).

    ``factor_reuse`` (class attribute) declares that the Newton loop may solve this system's
    steps through :class:`~ngcontact.algebra.reuse.FactorReuse`: the reduced matrix of
    :meth:`linearize` is SPD and :meth:`newton_step` is the generic direct solve of it.
    """

    factor_reuse = True

    K: sp.csr_matrix
    F: np.ndarray
    up: np.ndarray
    lo: np.ndarray  # -1 where the row has no "lower" unknown
    b: np.ndarray
    D: np.ndarray
    solver: str = "sparsecholesky"
    stiffness_scale: float = 1.0  # tension scale of the problem (Problem.stiffness_scale): see constraint_weight
    # (mu1, mu2) when K was built as blockdiag(mu1 S, mu2 S), the two blocks on one pattern (FEM): membrane_split
    # then reads S and alpha off without comparing K's arrays
    tensions: Optional[Tuple[float, float]] = None
    _B: sp.csr_matrix = field(init=False, repr=False)
    # rows in the unknowns' order, the gap read off slices of x (the same numbers as B x): 1 an obstacle on
    # up = 0..m-1, 2 two membranes with up = 0..m-1, lo = m..2m-1; 0 otherwise
    _ordered: int = field(init=False, repr=False, default=0)
    _diag: Optional[np.ndarray] = field(init=False, repr=False, default=None)

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
        if len(used) and np.bincount(used, minlength=n).max() > 1:  # O(n), where np.unique would sort
            raise ValueError("each unknown may appear in at most one constraint row")
        has_lo = self.lo >= 0
        rows = np.concatenate([np.arange(m), np.flatnonzero(has_lo)])
        cols = np.concatenate([self.up, self.lo[has_lo]])
        vals = np.concatenate([np.ones(m), -np.ones(has_lo.sum())])
        self._B = sp.csr_matrix((vals, (rows, cols)), shape=(m, n))
        if np.array_equal(self.up, np.arange(m)):
            self._ordered = 1 if not has_lo.any() else (2 if np.array_equal(self.lo, m + np.arange(m)) else 0)

    def diagonal(self) -> np.ndarray:
        """diag(K), extracted once (K is not changed after construction; rescaled copies share it)."""
        if self._diag is None:
            self._diag = self.K.diagonal()
        return self._diag

    @property
    def n(self) -> int:
        return self.K.shape[0]

    @property
    def m(self) -> int:
        return len(self.up)

    @property
    def constraint_weight(self) -> float:
        """w in the complementarity pair (w g, y) handed to the C-function: ``stiffness_scale``.  g is in
        units of u and y in units of the tension times u (per unit area), so C(w g, y) treats both alike
        when the tensions are scaled: the Newton iterates of a problem with all tensions and loads times s
        are those of the unscaled one (up to rounding; bit for bit when s is a power of 2)."""
        return float(self.stiffness_scale)

    def rescaled(self, s: float) -> "ComplementaritySystem":
        """The same system for the data divided by ``s`` (F / s, b / s; a power of 2 keeps it exact):
        its solution is (x / s, y / s).  Shares K and every other array."""
        if s == 1.0:
            return self
        out = copy.copy(self)
        out.F, out.b = self.F / s, self.b / s
        return out

    def pair(self, x: np.ndarray, y: np.ndarray):
        """The complementary pair (w g(x), y) handed to the C-function (w = :attr:`constraint_weight`; the
        Newton loop's view, shared with :mod:`.nonlinear`)."""
        return self.constraint_weight * self.gap(x), y

    def chain(self, da: np.ndarray, db: np.ndarray):
        """(Ca, Cb): the C-function's derivatives with respect to the pair turned into derivatives with respect
        to (g, y), as :meth:`newton_step` takes them: (w da, db)."""
        return self.constraint_weight * da, db

    def scale(self) -> float:
        """Divisor of ||Phi|| in the Newton loop's relative residual: ||F||; without loads (F = 0: an obstacle
        problem driven by its obstacle alone) the force that holds the unknowns at the constraint values,
        ||K B^T b||, so that the relative residual is not divided by zero."""
        f = float(np.linalg.norm(self.F))
        if f == 0.0 and np.any(self.b != 0):
            f = float(np.linalg.norm(self.K @ (self._B.T @ self.b)))
        return max(f, np.finfo(float).tiny)

    def data_scale(self) -> float:
        """The power of 2 nearest to the size of the data: ||F||_inf, else ||b||_inf times the constraint
        weight (a load-free obstacle problem), else 1 (the Newton loop solves the system :meth:`rescaled` by it)."""
        for v in (self.F, self.constraint_weight * self.b):
            if len(v):
                m = float(np.max(np.abs(v)))
                if m > 0 and math.isfinite(m):
                    return power_of_two(m)
        return 1.0

    def certificate(self, x: np.ndarray, y: np.ndarray, tol: float):
        """The exit certificate of (x, y) (:mod:`.certificate`)."""
        return certificate(self, x, y, tol)

    def gap(self, x: np.ndarray) -> np.ndarray:
        """g(x) = B x - b (on rows in the unknowns' order from slices of x: the same numbers, no product)."""
        m = len(self.up)
        if self._ordered == 1:
            return x[:m] - self.b
        if self._ordered == 2:
            return (x[:m] - x[m:2 * m]) - self.b
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
        With :attr:`tensions` (K built so) S is K's leading block and alpha = mu2 / mu1, not compared.
        """
        m, n = self.m, self.n
        if n != 2 * m or np.any(self.b != 0) or not np.array_equal(self.up, np.arange(m)) \
                or not np.array_equal(self.lo, m + np.arange(m)):
            return None
        K = self.K.tocsr()
        nnz1 = int(K.indptr[m])
        if self.tensions is not None and m > 0:
            mu1, mu2 = self.tensions
            return sp.csr_matrix((K.data[:nnz1], K.indices[:nnz1], K.indptr[:m + 1]), shape=(m, m), copy=False), \
                float(mu2) / float(mu1)
        if m > 0 and K.nnz == 2 * nnz1 and np.array_equal(K.indptr[m:] - nnz1, K.indptr[:m + 1]) \
                and np.array_equal(K.indices[nnz1:] - m, K.indices[:nnz1]) \
                and (nnz1 == 0 or int(K.indices[:nnz1].max()) < m):
            # the two diagonal blocks share their pattern (as the FEM assembles them) and nothing couples them:
            # compare the values array to array, S a view of the leading block (no sparse slicing or difference)
            S = sp.csr_matrix((K.data[:nnz1], K.indices[:nnz1], K.indptr[:m + 1]), shape=(m, m), copy=False)
            d1 = S.diagonal()
            if np.any(d1 <= 0):
                return None
            alpha = float(K[m, m] / d1[0])
            d1_all, d2_all = K.data[:nnz1], K.data[nnz1:]
            if not alpha > 0 or float(np.max(np.abs(d2_all - alpha * d1_all))) > rtol * float(np.max(np.abs(d1_all))):
                return None
            return S, alpha
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
    #: layers of the band around the free boundary on which :meth:`warm_start` solves the obstacle problem
    #: (0: none).  With 40 the nested ex9 levels whose band is solved take one Newton step each
    #: (results/bench/BENCH.md, newton_its).  Above WARM_BAND_ALL rows the band solve is skipped when the band
    #: holds more than WARM_BAND_FRACTION of them and its systems are factorized (no multigrid hierarchy): there
    #: its sparse Cholesky factorizations cost about as much as the multigrid Newton step they save, or more
    WARM_BAND, WARM_BAND_ALL, WARM_BAND_FRACTION = 40, 20000, 0.2
    #: above WARM_BAND_ALL rows: solves of the band iteration; after the last one, its next active set is handed
    #: to the first Newton step (which takes the iteration's next step on the whole system: on the nested ex9
    #: levels the second band solve only confirmed the active set the first Newton step keeps); Newton-min only
    #: (warm_start's ``hand_on``: Fischer-Burmeister took 4 steps from such a start on the 261k ex9 level, 1 from
    #: the settled one).  Otherwise up to 8 solves, and the band start only if the active set settles
    WARM_BAND_STEPS = 1

    def warm_start(self, x0: np.ndarray, y0: np.ndarray, hand_on: bool = True, prolongations=()):
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
        c g <= y_res, c = diag(K)/D.  Only the start changes: the converged
        solution is the same (finite termination); the Newton counts of the
        nested obstacle runs (``ex9-p1-balanced`` in tests/data/reference_histories.json,
        results/bench/BENCH.md) are those of this start.

        When every row is one-sided, ``WARM_SWEEPS`` damped projected Jacobi sweeps
        x <- max(b, x + omega diag(K)^-1 (F - K x)) (on the constrained unknowns) first
        smooth the interpolation error next to the free boundary (one SpMV each), which
        leaves fewer rows for the first Newton step to change.  Then the obstacle problem is
        solved on the band of ``WARM_BAND`` layers of rows around the free boundary of that start,
        the rest frozen (:meth:`~ngcontact.algebra.relax.FreeBoundaryRelaxation.solve_band`: a
        few sparse Cholesky solves of the band's free rows; above ``WARM_BAND_ALL`` rows and with
        ``hand_on`` (the start of Newton-min) ``WARM_BAND_STEPS`` of them, the active set after the last
        one handed on to the first Newton step; otherwise until the active set settles): the discrete
        free boundary moves by about one layer per Newton-min step, the band solve moves it in one
        go, and the first Newton step usually keeps its active set.  ``prolongations``: the level's nested
        multigrid hierarchy, if any (the band's systems are then solved by CG + truncated multigrid, and a band
        of any size is solved).
        """
        x = np.array(x0, dtype=float)
        y = np.array(y0, dtype=float)
        one = self.lo < 0
        if not one.any():
            return x, y
        if one.all() and self.WARM_SWEEPS:
            dK = self.diagonal()
            up, n = self.up, len(x)
            every = len(up) == n and (n == 0 or (up[0] == 0 and up[-1] == n - 1 and bool(np.all(np.diff(up) == 1))))
            for _ in range(self.WARM_SWEEPS):
                r = self.F - self.K @ x  # x += omega (F - K x) / dK, in place
                r *= self.WARM_OMEGA
                r /= dK
                x += r
                if every:  # an obstacle on every unknown, in order
                    np.maximum(x, self.b, out=x)
                else:
                    x[up] = np.maximum(x[up], self.b)
        g = self.gap(x)
        rows = np.flatnonzero(one & (g < 0))
        x[self.up[rows]] -= g[rows]  # projection: g = 0 there
        g = self.gap(x)
        r = self.K @ x - self.F
        c = self.diagonal()[self.up[one]] / self.D[one]
        y_res = r[self.up[one]] / self.D[one]
        # Newton-min's test is w g <= y (w: the constraint weight); active iff w g <= y0 and c g <= y_res
        #   <=>  w g <= min(y0, w y_res / c)   (w y_res / c is in the units of y)
        w = self.constraint_weight
        y[one] = np.minimum(y[one], w * y_res / c)
        if one.all() and self.WARM_BAND:
            small = self.m <= self.WARM_BAND_ALL
            settle = small or not hand_on
            band = FreeBoundaryRelaxation(self).solve_band(
                x, y, self.WARM_BAND, max_fraction=1.0 if small or prolongations else self.WARM_BAND_FRACTION,
                max_steps=8 if settle else self.WARM_BAND_STEPS, settle=settle, prolongations=prolongations)
            if band is not None:
                x, y = band[0], band[1]
        return x, y

    def direct_solve(self, A: sp.csr_matrix, b: np.ndarray) -> np.ndarray:
        """Solve the reduced system A z = b of a step by a fresh factorization (A SPD: ``self.solver``)."""
        return SPDSolver(A, self.solver).solve(b)

    def newton_step(self, x, y, C, Ca, Cb, eps: float = 1e-12, reuse=None):
        """New iterate (x', y') of the linearized system; see the module docstring.

        With ``reuse`` (a :class:`~ngcontact.algebra.reuse.FactorReuse`; only where
        ``factor_reuse``) the reduced system may be solved by PCG preconditioned with an
        earlier step's factorization; otherwise by :meth:`direct_solve`.
        """
        t0 = time.perf_counter()
        lin = self.linearize(x, y, C, Ca, Cb, eps)
        t1 = time.perf_counter()
        if reuse is None:
            z, path, its = self.direct_solve(lin.A, lin.b), "factor", 0
        else:
            z, path, its = reuse.solve(lin, z0=lin.restrict(x))
        t2 = time.perf_counter()
        x_new, y_new = lin.recover(z)
        return x_new, y_new, StepInfo(lin.size, t1 - t0, t2 - t1, path, its)

    def linearize(self, x, y, C, Ca, Cb, eps: float = 1e-12) -> "LinearizedStep":
        """The reduced SPD system A z = b of the Newton step (module docstring) and the map z -> (x', y').

        Used by :meth:`newton_step` (direct solve or factorization reuse) and by the
        inexact Newton driver (:mod:`ngcontact.newton.inexact`, Krylov solve).
        """
        n = self.n
        rc = classify_rows(self.gap(x), y, C, Ca, Cb, eps, self.constraint_weight)
        eq, mixed, g_target, y_fixed, w, c0 = rc.eq, rc.mixed, rc.g_target, rc.y_fixed, rc.w, rc.c0

        # matrix of the x-equation (before elimination); its right-hand side is formed on first use
        Kaug = self.K
        if mixed.any():
            Bm = sp.diags(np.where(mixed, 1.0, 0.0)) @ self._B
            Kaug = (self.K + Bm.T @ sp.diags(self.D * w) @ Bm).tocsr()
        # elimination of the slaves of equality rows: x = Z z + x_aff (Z formed on first use)
        eq_rows = np.flatnonzero(eq)
        slave_is_lo = self.lo[eq_rows] >= 0
        slaves = np.where(slave_is_lo, self.lo[eq_rows], self.up[eq_rows])
        masters = np.where(slave_is_lo, self.up[eq_rows], -1)
        keep = np.ones(n, dtype=bool)
        keep[slaves] = False
        x_aff = np.zeros(n)
        tb = g_target[eq_rows] + self.b[eq_rows]
        x_aff[slaves] = np.where(slave_is_lo, -tb, tb)

        # A = Z^T Kaug Z and b = Z^T (rhs - Kaug x_aff) are formed on first use (the fixed-pattern factorization
        # of FactorReuse does not need A, the s/w splitting of two membranes neither)
        return LinearizedStep(self, None, None, x_aff, keep, eq, mixed, y_fixed, c0, w,
                              eq_rows, slaves, slave_is_lo, _Kaug=Kaug, _masters=masters)
