r"""Newton steps of two membranes solved through the s/w splitting (the multigrid strategy's fast path).

With K = blockdiag(S, alpha S) and the gap g = x_1 - x_2 row by row
(:meth:`~ngcontact.algebra.system.ComplementaritySystem.membrane_split`), the change of variables
s = x_1 + alpha x_2, w = x_1 - x_2 block-diagonalizes the x-equation of every linearized step:

    S s' = F_1 + F_2,                      S w' - a D y' = F_w = F_1 - F_2 / alpha,   a = 1 + 1/alpha,

and the constraint rows of the step act on w' and y' only (eq rows: w'_l = g_target_l; fixed rows:
y'_l = y_fixed_l; mixed rows: y'_l = c0_l - w_l w'_l).  So the coupled step -- the reduced SPD system
Z^T Kaug Z z = b of :meth:`~ngcontact.algebra.system.ComplementaritySystem.linearize`, twice the size, whose
matrix is a sparse triple product -- is solved as

* s': one Poisson solve per Newton run (it does not depend on the step), CG + multigrid on S;
* w': an obstacle-type system, (S + a D W_mixed)[free, free], by CG + truncated multigrid on the nested
  hierarchy of one field (the coarse levels reused while few rows change, as for the coupled system),

and the coupled iterate is read off: x_1 = (s' + alpha w') / (1 + alpha), x_2 = (s' - w') / (1 + alpha), its
kept unknowns mapped through the coupled step's :meth:`~ngcontact.algebra.step.LinearizedStep.recover`
(which sets the slaves and y' as the coupled step does).  The step is the coupled Newton step: the Newton
loop, its residuals, certificates and relaxation see the coupled system.  It is accepted on the coupled
step's own tests -- ||F - K x' + B^T D y'|| (the reduced residual ||b - A z||; zero at the slave rows) below
the target and the Jacobi-scaled residual in units of u -- otherwise CG continues with 1e-3 times the targets,
at most three times, and then the step is solved on the coupled system.  The splitting is used where the
tensions are within ``SPLIT_ALPHA`` of each other (x_2 = (s' - w') / (1 + alpha) loses the digits of
alpha otherwise), in the exact mode.
"""
from __future__ import annotations

from typing import Optional

import numpy as np
import scipy.sparse as sp

from ..algebra.linalg import pcg
from ..algebra.multigrid import HierarchyCache, Multigrid
from ..algebra.sparse import submatrix

__all__ = ["MembraneSplit", "SPLIT_ALPHA"]

#: the splitting is used for 1 / SPLIT_ALPHA <= alpha = mu_2 / mu_1 <= SPLIT_ALPHA
SPLIT_ALPHA = 1e3


def single_field(prolongations) -> Optional[tuple]:
    """The prolongations of one field from those of two stacked fields (blockdiag(P, P)), or None."""
    out = []
    for P2 in prolongations:
        rf, rc = P2.shape
        if rf % 2 or rc % 2:
            return None
        P = P2[: rf // 2, : rc // 2].tocsr()
        if 2 * P.nnz != P2.nnz:
            return None
        out.append(P)
    return tuple(out)


def _upper_block(K: sp.csr_matrix) -> Optional[sp.csr_matrix]:
    """K[:m, :m] (m = half of K's rows) of a block-diagonal K as a view of K's arrays, or None (K has an entry of
    the first m rows right of column m)."""
    K = K.tocsr()
    m = K.shape[0] // 2
    nnz1 = int(K.indptr[m])
    if nnz1 and int(K.indices[:nnz1].max()) >= m:
        return None
    return sp.csr_matrix((K.data[:nnz1], K.indices[:nnz1], K.indptr[:m + 1]), shape=(m, m), copy=False)


def _lower_block(K: sp.csr_matrix, m: int) -> sp.csr_matrix:
    """K[m:, m:] of a block-diagonal K (no entry of the rows m.. left of column m): a view of K's arrays but for the
    shifted column indices."""
    K = K.tocsr()
    nnz1 = int(K.indptr[m])
    if K.nnz == nnz1 or int(K.indices[nnz1:].min()) >= m:
        return sp.csr_matrix((K.data[nnz1:], K.indices[nnz1:] - m, K.indptr[m:] - nnz1), shape=(K.shape[0] - m,
                                                                                                K.shape[1] - m))
    return K[m:, m:].tocsr()


class _WStep:
    """The w-system of one coupled step, with the interface :class:`~ngcontact.algebra.multigrid.HierarchyCache`
    reads (row classes, kept unknowns, the reduced matrix formed on first use)."""

    #: no unknown of the w-system is merged into another (its matrix is Kw restricted to the kept unknowns)
    slave_is_lo = np.zeros(0, dtype=bool)

    def __init__(self, Kw: sp.csr_matrix, keep: np.ndarray, b: np.ndarray, lin):
        self.Kw, self.keep, self.b = Kw, keep, b
        self.eq, self.mixed, self.w = lin.eq, lin.mixed, lin.w
        self._A = None

    @property
    def A(self) -> sp.csr_matrix:
        if self._A is None:
            self._A = submatrix(self.Kw, self.keep, self.keep)
        return self._A

    def share_matrix(self, A: sp.csr_matrix) -> None:
        self._A = A

    @property
    def size(self) -> int:
        return int(self.keep.sum())


class MembraneSplit:
    """The s/w splitting of one Newton run's two-membrane system (module docstring); :meth:`build` returns None
    where it does not apply."""

    def __init__(self, system, S: sp.csr_matrix, alpha: float, prolongations: tuple, opt, matrices: tuple = ()):
        self.system, self.S, self.alpha, self.opt = system, S, float(alpha), opt
        self.prolongations = prolongations
        self.matrices = matrices  # S of the levels (the leading blocks of their K), S last; or ()
        m = system.m
        self.Fw = system.F[:m] - system.F[m:] / alpha
        self.a = 1.0 + 1.0 / alpha
        self.dS = S.diagonal()
        self.K22 = _lower_block(system.K, m)  # the x_2 block of K (alpha S up to rounding)
        self.hierarchy = HierarchyCache(prolongations, opt, system.solver, matrices=matrices)
        self.s = None  # s' (the same for every step), solved at the first step
        self._mg_s = None  # its V-cycle, built when s of the iterate does not solve its equation
        self.its = 0  # CG iterations of the last :meth:`step` (s and w), also when it returned None

    @classmethod
    def build(cls, system, opt) -> Optional["MembraneSplit"]:
        if opt.mode != "exact" or not opt.prolongations or not hasattr(system, "membrane_split"):
            return None
        split = system.membrane_split()
        if split is None:
            return None
        S, alpha = split
        if not (1.0 / SPLIT_ALPHA <= alpha <= SPLIT_ALPHA):
            return None
        Ps = single_field(opt.prolongations)
        if Ps is None or Ps[-1].shape[0] != system.m:
            return None
        # the levels' S: the leading blocks of their K (Galerkin-consistent as the K are, P = blockdiag(P1, P1))
        blocks = tuple(_upper_block(K) for K in getattr(opt, "matrices", ()))
        matrices = blocks + (S,) if blocks and all(B is not None for B in blocks) else ()
        return cls(system, S, alpha, Ps, opt, matrices)

    def _solve_s(self, x: np.ndarray, target: float) -> bool:
        """s' = S^-1 (F_1 + F_2) from s of the iterate x, to ||S s' - F_1 - F_2|| <= ``target``: whether CG got
        there (its iterations are added to :attr:`its`)."""
        m, sys_ = self.system.m, self.system
        rhs = sys_.F[:m] + sys_.F[m:]
        s0 = x[:m] + self.alpha * x[m:] if self.s is None else self.s
        bnorm = float(np.linalg.norm(rhs)) or 1.0
        if float(np.linalg.norm(rhs - self.S @ s0)) <= target:  # s of the iterate is s' already (no hierarchy)
            self.s = s0
            return True
        if self._mg_s is None:
            self._mg_s = Multigrid(self.S, self.prolongations, None, degree=self.opt.degree, ratio=self.opt.ratio,
                                   solver=sys_.solver, smoother=self.opt.smoother, matrices=self.matrices)
        res = pcg(self.S, rhs, self._mg_s, s0, rtol=target / bnorm, maxiter=self.opt.maxiter)
        self.its += res.iterations
        if not res.converged:
            return False
        self.s = res.x
        return True

    def _fields(self, w_free: np.ndarray, ws: _WStep, w_eq: np.ndarray, lin):
        """(x_1', x_2', w'): the membranes of w' (kept rows ``w_free``, eq rows ``w_eq``) and s', the slaves x_2 of the
        eq rows set from their masters as Z z + x_aff does (x_2 = x_1 - g_target)."""
        a = self.alpha
        w = w_eq.copy()
        w[ws.keep] = w_free
        x1, x2 = (self.s + a * w) / (1.0 + a), (self.s - w) / (1.0 + a)
        x2[lin.eq_rows] = x1[lin.eq_rows] + lin.x_aff[lin.slaves]
        return x1, x2, w

    def _coupled(self, w_free: np.ndarray, ws: _WStep, w_eq: np.ndarray, lin):
        """(x', y', K x' - B^T D y' - F): the coupled iterate of w' (kept rows ``w_free``, eq rows ``w_eq``) and s'
        as the coupled step's :meth:`~ngcontact.algebra.step.LinearizedStep.recover` maps its kept unknowns
        (the slaves x_2 = x_1 - g_target on the eq rows, y' on them from the slaves' equations), and its residual
        -- the same numbers, from one product with each diagonal block of K (no rows of K extracted)."""
        system, m = self.system, self.system.m
        x1, x2, _ = self._fields(w_free, ws, w_eq, lin)
        rows = lin.eq_rows
        K2x = self.K22 @ x2
        y = lin.y_fixed.copy()
        if lin.mixed.any():
            mixed = lin.mixed
            y[mixed] = lin.c0[mixed] - lin.w[mixed] * (x1 - x2)[mixed]
        y[rows] = (K2x[rows] - system.F[m:][rows]) / -system.D[rows]
        Dy = system.D * y
        r = np.concatenate([self.S @ x1 - Dy, K2x + Dy]) - system.F
        return np.concatenate([x1, x2]), y, r

    def _active(self, w_free: np.ndarray, ws: _WStep, w_eq: np.ndarray, lin) -> np.ndarray:
        """The Newton-min active set {weight g <= y} of the coupled iterate of w' (no mixed rows): g = w', y' = y_fixed
        on the fixed rows and, on the eq rows, the multiplier of the slave's equation (x_2 row of the step) as
        :meth:`_coupled` reads it."""
        system, m = self.system, self.system.m
        _, x2, w = self._fields(w_free, ws, w_eq, lin)
        y = lin.y_fixed.copy()
        rows = lin.eq_rows
        y[rows] = ((self.K22 @ x2)[rows] - system.F[m:][rows]) / -system.D[rows]
        return system.constraint_weight * w <= y

    def step(self, k: int, x: np.ndarray, lin, target: float, early) -> Optional[tuple]:
        """(x', y', fields, K x' - B^T D y' - F) of the coupled step ``lin`` at the iterate x, or None (the step is to
        be solved on the coupled system; :attr:`its` counts the CG iterations spent either way).  ``early(A, b, z0, mg, target,
        active, eq)``: the session's early-exit CG (or None)."""
        opt, system, m = self.opt, self.system, self.system.m
        self.its = 0
        if self.s is None and not self._solve_s(x, 0.25 * target):
            return None
        eq, mixed = lin.eq, lin.mixed
        # the step's rows on w: eq rows fix w' at the target gap (the coupled slave is x_2 = x_1 - g_target)
        w_eq = np.zeros(m)
        w_eq[lin.eq_rows] = -lin.x_aff[lin.slaves]
        aD = self.a * system.D
        Kw = self.S if not mixed.any() else (self.S + sp.diags(np.where(mixed, aD * lin.w, 0.0))).tocsr()
        rhs = self.Fw + aD * (lin.y_fixed + np.where(mixed, lin.c0, 0.0)) - Kw @ w_eq
        ws = _WStep(Kw, ~eq, rhs[~eq], lin)
        mg, how = self.hierarchy.get(ws)
        z0 = (x[:m] - x[m:])[ws.keep]
        bnorm = float(np.linalg.norm(ws.b)) or 1.0
        t_w = 0.5 * target
        fields = dict(linear_size=ws.size, mg_levels=len(mg.levels), mg_rebuilt=how,
                      time_mg_setup=mg.time_setup if how else 0.0, split=1, cg_early=0)

        def to_full(z):
            return self._coupled(z, ws, w_eq, lin)

        if early is not None:
            res, stopped = early(ws.A, ws.b, z0, mg, t_w, lambda z: self._active(z, ws, w_eq, lin), eq)
            self.its += res.iterations
            if stopped:
                xn, yn, r = to_full(res.x)
                return xn, yn, dict(fields, pcg_its=self.its, cg_early=1), r
        else:
            res = pcg(ws.A, ws.b, mg, z0, rtol=t_w / bnorm, maxiter=opt.maxiter)
            self.its += res.iterations
        # diag of the coupled reduced matrix at the kept unknowns (a merged pair: both diagonals; mixed rows: + D w)
        dmix = np.where(mixed, system.D * lin.w, 0.0)
        dA = np.concatenate([self.dS * np.where(eq, 1.0 + self.alpha, 1.0) + dmix, self.alpha * self.dS + dmix])
        for _ in range(4):
            if not res.converged:
                return None
            xn, yn, r = to_full(res.x)
            u_scale = float(np.max(np.abs(xn), initial=0.0))
            if float(np.linalg.norm(r)) <= target \
                    and float(np.max(np.abs(r / dA), initial=0.0)) <= opt.accuracy * opt.tol * u_scale:
                return xn, yn, dict(fields, pcg_its=self.its), r
            # CG continues on both parts with 1e-3 times the targets
            target, t_w = 1e-3 * target, 1e-3 * t_w
            if not self._solve_s(x, 0.25 * target):
                return None
            res = pcg(ws.A, ws.b, mg, res.x, rtol=t_w / bnorm, maxiter=opt.maxiter)
            self.its += res.iterations
        return None
