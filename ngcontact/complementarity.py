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

import numpy as np
import scipy.sparse as sp

from .linalg import SPDSolver

__all__ = ["ComplementaritySystem", "StepInfo"]


@dataclass
class StepInfo:
    reduced_size: int
    time_assemble: float
    time_solve: float


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
        if len(np.unique(used)) != len(used):
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

    def newton_step(self, x, y, C, Ca, Cb, eps: float = 1e-12):
        """New iterate (x', y') of the linearized system; see the module docstring."""
        t0 = time.perf_counter()
        n, m = self.n, self.m
        g = self.gap(x)
        aCa, aCb = np.abs(Ca), np.abs(Cb)
        eq = aCb <= eps * aCa
        fixed = ~eq & (aCa <= eps * aCb)
        mixed = ~eq & ~fixed

        # prescribed quantities
        g_target = np.zeros(m)
        g_target[eq] = g[eq] - C[eq] / Ca[eq]
        y_new = np.zeros(m)
        y_new[fixed] = y[fixed] - C[fixed] / Cb[fixed]
        # mixed rows: y' = c0 - w g(x'), w = Ca/Cb >= 0
        w = np.zeros(m)
        w[mixed] = Ca[mixed] / Cb[mixed]
        c0 = np.zeros(m)
        c0[mixed] = y[mixed] - C[mixed] / Cb[mixed] + w[mixed] * g[mixed]

        # right-hand side and matrix of the x-equation (before elimination)
        rhs = self.F + self._B.T @ (self.D * np.where(fixed, y_new, 0.0))
        Kaug = self.K
        if mixed.any():
            Wm = self.D * w
            Bm = sp.diags(np.where(mixed, 1.0, 0.0)) @ self._B
            Kaug = (self.K + Bm.T @ sp.diags(Wm) @ Bm).tocsr()
            # -B^T D y' = -B^T D c0 + B^T D w (B x' - b)
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

        Ared = (Z.T @ Kaug @ Z).tocsr()
        bred = Z.T @ (rhs - Kaug @ x_aff)
        t1 = time.perf_counter()
        z = SPDSolver(Ared, self.solver).solve(bred)
        t2 = time.perf_counter()
        x_new = Z @ z + x_aff

        # multipliers
        y_new[mixed] = c0[mixed] - w[mixed] * (self._B @ x_new - self.b)[mixed]
        if len(eq_rows):
            r = self.K @ x_new - self._B.T @ (self.D * np.where(eq, 0.0, y_new)) - self.F
            sign = np.where(slave_is_lo, -1.0, 1.0)
            y_new[eq_rows] = r[slaves] / (sign * self.D[eq_rows])
        return x_new, y_new, StepInfo(nr, t1 - t0, t2 - t1)
