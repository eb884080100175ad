"""The reduced SPD system of one Newton step and the map from its unknowns to the full iterate.

:meth:`~ngcontact.algebra.system.ComplementaritySystem.linearize` classifies the constraint rows and returns a
:class:`LinearizedStep`; its matrix, right-hand side and elimination matrix are formed on first use, so that a
strategy pays only for what it reads (the fixed-pattern factorization of :mod:`.reuse` needs no reduced matrix,
the s/w splitting of two membranes (:mod:`ngcontact.newton.split`) neither matrix nor right-hand side).
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Optional

import numpy as np
import scipy.sparse as sp

from .sparse import submatrix

__all__ = ["LinearizedStep"]


@dataclass
class LinearizedStep:
    """Reduced SPD system A z = b of one Newton step, x' = Z z + x_aff (see
    :meth:`~ngcontact.algebra.system.ComplementaritySystem.linearize`).

    For any z, :meth:`recover` returns (x', y') satisfying the constraint rows
    of the linearization exactly and the x-equation on the slave unknowns
    exactly; the remaining residual of the 3-field linear system is then
    ``F - (K x' - B^T D y')`` on the kept unknowns only, equal to the reduced
    residual ``b - A z`` (slaves add their row to the master's).
    """

    system: object  # the ComplementaritySystem that linearized the step (K, F, D, b, _B, n)
    _A: Optional[sp.csr_matrix]
    _b: Optional[np.ndarray]
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
    _Ks: Optional[sp.csr_matrix] = field(default=None, repr=False)
    _masters: Optional[np.ndarray] = field(default=None, repr=False)  # master of each eq row's slave (-1: none)
    _Z: Optional[sp.csr_matrix] = field(default=None, repr=False)

    @property
    def Z(self) -> sp.csr_matrix:
        """x' = Z z + x_aff: identity on the kept unknowns, a lower slave's row its master's column (formed on
        first use; :meth:`recover` does without it).  At most one entry per row, written as CSR directly."""
        if self._Z is None:
            n, keep = self.system.n, self.keep
            nr = int(keep.sum())
            red_index = -np.ones(n, dtype=np.int64)
            red_index[keep] = np.arange(nr)
            lo = self.slave_is_lo
            zcol = red_index.copy()
            zcol[self.slaves[lo]] = red_index[self._masters[lo]]
            has = zcol >= 0
            itype = np.int32 if max(n, nr) < np.iinfo(np.int32).max else np.int64
            zptr = np.zeros(n + 1, dtype=itype)
            np.cumsum(has, out=zptr[1:])
            self._Z = sp.csr_matrix((np.ones(int(zptr[-1])), zcol[has].astype(itype), zptr), shape=(n, nr))
        return self._Z

    @property
    def rhs(self) -> np.ndarray:
        """The right-hand side of the x-equation before the elimination: F + B^T D y_fixed on the fixed rows, and on
        mixed rows -B^T D y' = -B^T D c0 + B_m^T D w (B x' - b) with the known parts moved right."""
        s = self.system
        out = s.F + s._B.T @ (s.D * np.where(~self.eq & ~self.mixed, self.y_fixed, 0.0))
        if self.mixed.any():
            Bm = sp.diags(np.where(self.mixed, 1.0, 0.0)) @ s._B
            out = out + s._B.T @ (s.D * self.c0) + Bm.T @ ((s.D * self.w) * s.b)
        return out

    @property
    def b(self) -> np.ndarray:
        """The reduced right-hand side Z^T (rhs - Kaug x_aff) (formed on first use; where Z selects the kept unknowns,
        by indexing)."""
        if self._b is None:
            v = self.rhs - self._Kaug @ self.x_aff
            self._b = self.Z.T @ v if self.slave_is_lo.any() else v[self.keep]
        return self._b

    def diagonal(self) -> np.ndarray:
        """diag(A) (where A is K restricted to the kept unknowns, read off the system's diagonal)."""
        if not self.slave_is_lo.any() and not self.mixed.any() and hasattr(self.system, "diagonal"):
            return self.system.diagonal()[self.keep]
        return self.A.diagonal()

    @property
    def A(self) -> sp.csr_matrix:
        """The reduced matrix Z^T Kaug Z (formed on first use)."""
        if self._A is None:
            if self.slave_is_lo.any():  # slaves follow masters: Z merges columns
                ZT = self.Z.T.tocsr()  # CSR products only: Z^T as CSC would convert Z^T K to CSC
                self._A = (ZT @ self._Kaug) @ self.Z
            else:  # Z selects the kept unknowns
                self._A = submatrix(self._Kaug, self.keep, self.keep)  # one pass, no K[keep] copy
        return self._A

    def share_matrix(self, A: sp.csr_matrix) -> None:
        """Use ``A`` as :attr:`A` (not formed again): the caller holds the reduced matrix of a step with the same
        row classes (``eq``, ``mixed``, ``w``) of the same system, which is this one, entry for entry."""
        self._A = A

    @property
    def size(self) -> int:
        return int(self.keep.sum())

    def restrict(self, x: np.ndarray) -> np.ndarray:
        """z with Z z = x on the kept unknowns (warm start from a full vector x)."""
        return np.asarray(x)[self.keep]

    def expand(self, z: np.ndarray) -> np.ndarray:
        """x' = Z z + x_aff (by indexing: the kept unknowns are z, a lower slave its master's value)."""
        x = np.zeros(self.system.n)
        x[self.keep] = z
        lo = self.slave_is_lo
        x[self.slaves[lo]] = x[self._masters[lo]]
        x += self.x_aff
        return x

    def recover(self, z: np.ndarray):
        """(x', y') from the reduced unknowns z."""
        s = self.system
        x_new = self.expand(z)
        y_new = self.y_fixed.copy()
        mixed = self.mixed
        if mixed.any():
            y_new[mixed] = self.c0[mixed] - self.w[mixed] * (s._B @ x_new - s.b)[mixed]
        if len(self.eq_rows):
            # the slave equations: (K x' - B^T D y' - F)[slave] = 0, where B^T D y' on the slave of row l is
            # +-D_l y'_l only (each unknown lies in at most one constraint row); the rows of K at the slaves only
            r = self._K_slaves @ x_new - s.F[self.slaves]
            sign = np.where(self.slave_is_lo, -1.0, 1.0)
            y_new[self.eq_rows] = r / (sign * s.D[self.eq_rows])
            soft = self._soft_masters
            if len(soft):  # rows whose master is far softer: its equation (the same y in exact arithmetic)
                k = np.flatnonzero(soft)
                m = self._masters[k]
                rm = s.K[m] @ x_new - s.F[m]
                y_new[self.eq_rows[k]] = rm / s.D[self.eq_rows[k]]
        return x_new, y_new

    #: a master's equation gives y when its diagonal of K is below this share of the slave's
    SOFT_MASTER = 1e-3

    @property
    def _soft_masters(self) -> np.ndarray:
        """Mask over the eq rows: two-sided rows whose master (the upper field's unknown) has a diagonal of K below
        :attr:`SOFT_MASTER` times the slave's.  The slave's equation (K x' - F)[slave] then subtracts terms of the
        stiff field's size to give a multiplier of the soft field's size, and loses it (two membranes with tensions
        1e12 apart: 1e-4 relative); the master's equation gives the same y without that cancellation."""
        if not len(self.eq_rows) or not self.slave_is_lo.any():
            return np.zeros(0, dtype=bool)
        dK = self.system.K.diagonal()
        m = self._masters
        soft = self.slave_is_lo & (m >= 0)
        soft[soft] = np.abs(dK[m[soft]]) < self.SOFT_MASTER * np.abs(dK[self.slaves[soft]])
        return soft if soft.any() else np.zeros(0, dtype=bool)

    @property
    def _K_slaves(self) -> sp.csr_matrix:
        """The rows of K at the slave unknowns (formed on first use: :meth:`recover` runs once per CG
        monitor check and once per step)."""
        if self._Ks is None:
            self._Ks = self.system.K[self.slaves]
        return self._Ks

