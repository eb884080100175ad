"""Static condensation of the HHO Newton step: :class:`CondensedHHOSystem` and its face-system Cholesky.

Used by :class:`~ngcontact.discretizations.hho.HHODiscretization` with
``condense=True``; the uncondensed HHO system is the generic
:class:`~ngcontact.algebra.system.ComplementaritySystem`, and both give the
same iterates (to rounding).
"""
from __future__ import annotations

import time

import numpy as np
import scipy.sparse as sp

from ..algebra.linalg import SPDSolver, ngsolve_coo
from ..algebra.system import ComplementaritySystem, StepInfo, classify_rows

__all__ = ["CondensedHHOSystem"]


class CondensedHHOSystem(ComplementaritySystem):
    """HHO complementarity system whose Newton step is solved on the face unknowns only.

    The rows are classified by :func:`~ngcontact.algebra.system.classify_rows` like those of
    the generic step; the reduction is cell-wise instead of by slave elimination, so
    ``factor_reuse`` is False.

    Per cell K the linearized equations (module doc of
    :mod:`ngcontact.algebra.system`) couple the cell values X^C_1, X^C_2 of
    both fields and X3|_K through the C-function rows of the cell's nodes only.
    They are eliminated cell by cell for the current active set:

    * cells without equality (active) or mixed (Fischer-Burmeister) rows:
      X3 is prescribed and the fields decouple; the local inverse of
      mu_a A_CC is the same every step (computed once), only the right-hand
      side changes;
    * the other cells: in the variables s = the cell values of the stiffer field (X^C_1 when mu1 >= mu2, else
      X^C_2) and d = X^C_1 - X^C_2 the constraints read g = d (b = 0); d is prescribed on active rows, mixed
      rows add w to the d-diagonal; the symmetric (2 nc x 2 nc) cell block is
      inverted (batched numpy) and its Schur complement on the cell's
      2 x 3p face unknowns computed.  (With s the softer field's values the block carries mu_stiff in all four
      sub-blocks and its d-part is the difference of such entries: for tensions 1e12 apart its inverse lost all
      accuracy in the softer field, and Newton stalled at a residual of 1e-5.)

    The face system (SPD, 2 * p * #interior faces) is solved by sparse
    Cholesky; cell values and X3 are recovered cell by cell (active rows:
    X3_l = (mu1 (A_CC X1 + A_CF X1F) - F1)_l).  ``timings`` accumulates the
    seconds spent in condensation, linear solve and recovery.
    """

    factor_reuse = False

    def setup(self, A, ldofs, nc, p, mu1, mu2):
        """Cell-local data: element matrices A (ne, nl, nl), local-to-global dofs of one field."""
        ne = A.shape[0]
        self.nc, self.p, self.mu = nc, p, (mu1, mu2)
        self.n1 = self.n // 2
        self.ncell = ne * nc
        fd = ldofs[:, nc:]
        bnd = fd < 0
        Acc = A[:, :nc, :nc]
        Acf = np.where(bnd[:, None, :], 0.0, A[:, :nc, nc:])  # boundary faces: known, already in F
        Aff = np.where(bnd[:, None, :] | bnd[:, :, None], 0.0, A[:, nc:, nc:])
        self.Acc, self.Acf = Acc, Acf
        self.Acc_inv = np.linalg.inv(Acc)
        self.AccinvAcf = self.Acc_inv @ Acf
        S0 = Aff - np.swapaxes(Acf, 1, 2) @ self.AccinvAcf  # field-wise condensed cell matrix
        self.S0 = S0
        nf = self.n1 - self.ncell  # face unknowns of one field
        self.nf = nf
        fg = np.where(bnd, -1, fd - self.ncell)  # face-only numbering of field 1
        self.fg = np.concatenate([fg, np.where(bnd, -1, fg + nf)], axis=1)  # (ne, 6p) both fields
        # the active-set independent part: blockdiag(mu1 S0, mu2 S0) over all cells
        rows, cols, vals = [], [], []
        for a, mu in enumerate((mu1, mu2)):
            g = np.where(bnd, -1, fg + a * nf)
            r, c, v = _coo(g, mu * S0)
            rows.append(r), cols.append(c), vals.append(v)
        self.face_solver = _FaceCholesky(2 * nf, np.concatenate(rows), np.concatenate(cols), np.concatenate(vals),
                                         self.fg, self.solver)
        # coupled cell blocks in (s, d): x1 = s, x2 = s - d (mu1 >= mu2), or x2 = s, x1 = s + d; the d-rows are those
        # of field 2 (negated) or of field 1, the softer one
        self.primary = 2 if mu2 > mu1 else 1
        if self.primary == 1:
            self.Kzz = np.block([[(mu1 + mu2) * Acc, -mu2 * Acc], [-mu2 * Acc, mu2 * Acc]])
            self.Kzf = np.block([[mu1 * Acf, mu2 * Acf], [np.zeros_like(Acf), -mu2 * Acf]])
        else:
            self.Kzz = np.block([[(mu1 + mu2) * Acc, mu1 * Acc], [mu1 * Acc, mu1 * Acc]])
            self.Kzf = np.block([[mu1 * Acf, mu2 * Acf], [mu1 * Acf, np.zeros_like(Acf)]])
        self.Kff = np.block([[mu1 * Aff, np.zeros_like(Aff)], [np.zeros_like(Aff), mu2 * Aff]])
        self.timings = {"condense": 0.0, "solve": 0.0, "recover": 0.0, "steps": 0}

    def newton_step(self, x, y, C, Ca, Cb, eps: float = 1e-12, reuse=None):
        """New iterate (x', y') of the linearized system (class doc); ``reuse`` must be None
        (``factor_reuse`` is False)."""
        if reuse is not None:
            raise ValueError("CondensedHHOSystem solves its steps by condensation: no factorization reuse")
        t0 = time.perf_counter()
        nc, ne, n1, ncell, nf = self.nc, self.ncell // self.nc, self.n1, self.ncell, self.nf
        mu1, mu2 = self.mu
        if np.any(self.D != 1.0) or np.any(self.b != 0.0):
            raise ValueError("CondensedHHOSystem expects D = I and b = 0")
        rc = classify_rows(self.gap(x), y, C, Ca, Cb, eps, self.constraint_weight)  # g_target: prescribed d = x1 - x2 on equality rows
        EQ, MX = rc.eq.reshape(ne, nc), rc.mixed.reshape(ne, nc)
        YF, W, C0, T = (v.reshape(ne, nc) for v in (rc.y_fixed, rc.w, rc.c0, rc.g_target))
        F1C = self.F[:ncell].reshape(ne, nc)
        F2C = self.F[n1:n1 + ncell].reshape(ne, nc)
        rf = np.concatenate([self.F[ncell:n1], self.F[n1 + ncell:]])  # face loads (with lifting)

        coupled = (EQ | MX).any(axis=1)
        dec = np.flatnonzero(~coupled)
        cpl = np.flatnonzero(coupled)
        # decoupled cells: mu_a (A_CC X_a + A_CF X_aF) = r_a, r1 = F1 + y, r2 = F2 - y
        r1, r2 = F1C[dec] + YF[dec], F2C[dec] - YF[dec]
        fg = self.fg
        p3 = fg.shape[1] // 2
        for a, r in enumerate((r1, r2)):
            contrib = -np.einsum("kji,kj->ki", self.AccinvAcf[dec], r)  # -A_FC A_CC^{-1} r_a
            idx = fg[dec][:, a * p3:(a + 1) * p3]
            ok = idx >= 0
            np.add.at(rf, idx[ok], contrib[ok])
        # coupled cells
        if len(cpl):
            Kzz = self.Kzz[cpl].copy()
            Kzf = self.Kzf[cpl].copy()
            eqc, mxc = EQ[cpl], MX[cpl]
            dd = nc + np.arange(nc)
            Kzz[:, dd, dd] += W[cpl]
            d_load = -F2C[cpl] if self.primary == 1 else F1C[cpl]  # the d-rows: -(field 2) or field 1
            rz = np.concatenate([F1C[cpl] + F2C[cpl],
                                 d_load + YF[cpl] + np.where(mxc, C0[cpl], 0.0)], axis=1)
            tv = np.zeros((len(cpl), 2 * nc))
            tv[:, nc:] = np.where(eqc, T[cpl], 0.0)
            rz -= np.einsum("kij,kj->ki", Kzz, tv)
            rfl = -np.einsum("kij,ki->kj", Kzf, tv)
            keep = np.ones((len(cpl), 2 * nc))
            keep[:, nc:] = ~eqc
            Kzz *= keep[:, :, None] * keep[:, None, :]
            Kzz[:, np.arange(2 * nc), np.arange(2 * nc)] += 1.0 - keep
            rz = np.where(keep > 0, rz, tv)
            Kzf *= keep[:, :, None]
            Kinv = np.linalg.inv(Kzz)
            KinvKzf = Kinv @ Kzf
            Kinv_rz = np.einsum("kij,kj->ki", Kinv, rz)
            Sc = self.Kff[cpl] - np.swapaxes(Kzf, 1, 2) @ KinvKzf
            rfl -= np.einsum("kij,ki->kj", Kzf, Kinv_rz)
            idx = fg[cpl]
            ok = idx >= 0
            np.add.at(rf, idx[ok], rfl[ok])
            # correction of the base matrix on coupled cells
            base = np.zeros_like(Sc)
            base[:, :p3, :p3] = mu1 * self.S0[cpl]
            base[:, p3:, p3:] = mu2 * self.S0[cpl]
            correction = Sc - base
        else:
            correction = np.zeros((0, 2 * p3, 2 * p3))
        t1 = time.perf_counter()
        self.face_solver.factor(cpl, correction)
        phi = self.face_solver.solve(rf)
        t2 = time.perf_counter()

        # recovery
        x_new = np.empty(self.n)
        x_new[ncell:n1] = phi[:nf]
        x_new[n1 + ncell:] = phi[nf:]
        phi_ext = np.concatenate([phi, [0.0]])
        phil = phi_ext[np.where(fg >= 0, fg, len(phi))]  # (ne, 6p), 0 on boundary faces
        X1 = np.empty((ne, nc))
        X2 = np.empty((ne, nc))
        for a, (r, X, mu) in enumerate(((r1, X1, mu1), (r2, X2, mu2))):
            X[dec] = np.einsum("kij,kj->ki", self.Acc_inv[dec], r / mu) - np.einsum(
                "kij,kj->ki", self.AccinvAcf[dec], phil[dec][:, a * p3:(a + 1) * p3])
        Y = YF.copy()
        if len(cpl):
            z = Kinv_rz - np.einsum("kij,kj->ki", KinvKzf, phil[cpl])
            if self.primary == 1:
                X1[cpl] = z[:, :nc]
                X2[cpl] = z[:, :nc] - z[:, nc:]
            else:
                X2[cpl] = z[:, :nc]
                X1[cpl] = z[:, :nc] + z[:, nc:]
            Y[cpl] = np.where(mxc, C0[cpl] - W[cpl] * z[:, nc:], Y[cpl])
            # active rows: X3 = mu1 (A_CC X1 + A_CF X1F) - F1 (row of field 1)
            r_eq = mu1 * (np.einsum("kij,kj->ki", self.Acc[cpl], X1[cpl])
                          + np.einsum("kij,kj->ki", self.Acf[cpl], phil[cpl][:, :p3])) - F1C[cpl]
            Y[cpl] = np.where(eqc, r_eq, Y[cpl])
        x_new[:ncell] = X1.ravel()
        x_new[n1:n1 + ncell] = X2.ravel()
        t3 = time.perf_counter()
        tm = self.timings
        tm["condense"] += t1 - t0
        tm["solve"] += t2 - t1
        tm["recover"] += t3 - t2
        tm["steps"] += 1
        return x_new, Y.ravel(), StepInfo(len(rf), (t1 - t0) + (t3 - t2), t2 - t1)


class _FaceCholesky:
    """Sparse Cholesky of the condensed face system S = S_base + sum over coupled cells of their corrections.

    S_base (both fields, decoupled) never changes; the coupled cells change with
    the active set.  The sparsity pattern (S_base plus the full face blocks of a
    set U of cells) is kept while the coupled cells stay inside U (and U is not
    much larger): the values are then written into the existing NGSolve matrix
    and the factorization is redone by ``Update()`` (no new ordering, no new
    matrix).
    ``solver='scipy'`` uses scipy's SuperLU on a scipy matrix instead.
    """

    def __init__(self, n, rows, cols, vals, fg, solver):
        self.n, self.fg, self.solver = n, fg, solver
        self.base_keys, inv = np.unique(rows.astype(np.int64) * n + cols, return_inverse=True)
        self.base_vals = np.bincount(inv.ravel(), weights=vals, minlength=len(self.base_keys))
        self.cells = None  # bool mask U of the cells whose blocks are in the pattern
        self.rebuilds = 0

    def _local_keys(self, cells):
        idx = self.fg[cells]
        r = np.broadcast_to(idx[:, :, None], idx.shape + idx.shape[1:]).astype(np.int64)
        c = np.broadcast_to(idx[:, None, :], r.shape)
        return np.where((r >= 0) & (c >= 0), r * self.n + c, -1)  # (len(cells), k, k)

    def _build(self, U):
        cells = np.flatnonzero(U)
        local = self._local_keys(cells)
        keys = _sorted_unique(np.concatenate([self.base_keys, local[local >= 0]]))
        self.keys, self.cells = keys, U.copy()
        self.data_base = np.zeros(len(keys))
        self.data_base[np.searchsorted(keys, self.base_keys)] = self.base_vals
        self.slot = np.full(len(U), -1, dtype=np.int64)
        self.slot[cells] = np.arange(len(cells))
        self.pos = np.where(local >= 0, np.searchsorted(keys, local), -1)  # (|U|, k, k) data positions
        rows, cols = keys // self.n, keys % self.n
        self.indptr = np.searchsorted(rows, np.arange(self.n + 1))
        self.cols = cols
        self.inv = None
        self.rebuilds += 1
        if self.solver == "sparsecholesky":
            self.mat = ngsolve_coo(rows, cols, self.data_base, self.n, self.n)
            data, indices, indptr = self.mat.CSR()
            self.view = np.asarray(data)  # a view: values are written here before Update()
            if not (np.array_equal(np.asarray(indices), cols) and np.array_equal(np.asarray(indptr), self.indptr)):
                raise RuntimeError("NGSolve reordered the sparse matrix entries")
            self.rhs, self.sol = self.mat.CreateRowVector(), self.mat.CreateColVector()

    def factor(self, cells, blocks):
        """Factorize S_base + the correction blocks (len(cells), k, k) of the coupled cells."""
        mask = np.zeros(len(self.fg), dtype=bool)
        mask[cells] = True
        if self.cells is None or (mask & ~self.cells).any() or self.cells.sum() > 2 * mask.sum() + 64:
            self._build(mask)
        data = self.data_base.copy()
        if len(cells):
            pos = self.pos[self.slot[cells]]
            ok = pos >= 0
            data += np.bincount(pos[ok], weights=blocks[ok], minlength=len(data))
        if self.solver == "sparsecholesky":
            self.view[:] = data
            if self.inv is None:
                self.inv = self.mat.Inverse(inverse="sparsecholesky")
            else:
                self.inv.Update()
        else:
            A = sp.csr_matrix((data, self.cols, self.indptr), shape=(self.n, self.n))
            self.inv = SPDSolver(A, self.solver)

    def solve(self, b):
        if self.solver != "sparsecholesky":
            return self.inv.solve(b)
        self.rhs.FV().NumPy()[:] = b
        self.sol.data = self.inv * self.rhs
        return np.array(self.sol.FV().NumPy())


def _sorted_unique(a: np.ndarray) -> np.ndarray:
    """np.unique by sorting (numpy's hash-based unique is several times slower on 1e7 int64)."""
    a = np.sort(a)
    return a[np.concatenate([[True], a[1:] != a[:-1]])] if len(a) else a


def _coo(idx: np.ndarray, blocks: np.ndarray):
    """COO triplets of local blocks (ne, k, k) scattered by idx (ne, k); entries with idx < 0 dropped."""
    r = np.broadcast_to(idx[:, :, None], blocks.shape)
    c = np.broadcast_to(idx[:, None, :], blocks.shape)
    ok = (r >= 0) & (c >= 0)
    return r[ok], c[ok], blocks[ok]
