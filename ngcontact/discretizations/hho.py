"""Hybrid High-Order method, cells P_p and faces P_{p-1}, p = 1..4 (seed "The Hybrid High-Order method").

Problem
    The two-membrane problem of [CAMWA21]: -mu_a Lap u_a -+ lam = f_a,
    u1 - u2 >= 0, lam >= 0, (u1 - u2) lam = 0, u_a = g_a on the boundary.

Discretisation
    X^p_h = prod_K P_p(K) x prod_F P_{p-1}(F) for u1 and u2, Lambda_h = prod_K P_p(K)
    for lam.  In every cell the potential reconstruction r_K: X^p_{h,K} -> P_p(K),

        (grad r_K v, grad w)_K = (grad v_K, grad w)_K + (v_dK - v_K, grad w.n_K)_dK  for all w in P_p(K),

    G_K = grad r_K, and the (Lehrenfeld-Schoeberl) stabilization
    s_K(v, w) = h_K^{-1} (Pi^{p-1}_dK (v_dK - v_K), w_dK - w_K)_dK define

        A_h(v, w) = sum_K (G_K v, G_K w)_K + s_K(v, w),

    symmetric and coercive: the mixed-order HHO (cells k+1 = p, faces k = p-1)
    of Cockburn-Di Pietro-Ern 2016, exact for u in P_p.  The seed slide prints
    G_K in P_p(K; R^2) tested with every q in P_p(K; R^2)
    (``reconstruction='full'``): then q.n has degree p on the edges, the
    unprojected degree-p mode of u - Pi^{p-1}_F u enters G_K, and the method
    is not exact on P_p; measured on test 1 it converges like h^{p-1} only
    (rates 1.2 for p = 2, 2.1 for p = 3 at T3), so it is kept for comparison.
    Dirichlet data: the boundary face unknowns are the L2 projection of g_a
    on P_{p-1}(F).

    Contact at the Lagrange nodes of every cell: the cell unknowns are the
    values X^C_a of u_aK at the nodes (per-cell nodal basis) and
    lam|_K = sum_l X3_l Theta_{K,l} with Theta dual to the nodal basis, so
    (v_1K - v_2K, lam_K)_K = (V1 - V2).X3 and (seed, "Discrete complementarity
    problem")

        E X = F,  X^C_1 - X^C_2 >= 0,  X3 >= 0,  (X^C_1 - X^C_2).X3 = 0,
        E = [[mu1 S_CC, mu1 S_CF, 0, 0, -I], [mu1 S_FC, mu1 S_FF, 0, 0, 0],
             [0, 0, mu2 S_CC, mu2 S_CF, I], [0, 0, mu2 S_FC, mu2 S_FF, 0]].

    Error: (sum_K sum_a mu_a ||grad(u_a - u_aK)||_K^2)^(1/2) (cell unknowns).

Implementational aspects
    Element matrices are computed by batched numpy on affine triangles
    (reference quadrature of NGSolve), data are evaluated with
    ``mesh.MapToAllElements``; output as NGSolve ``L2`` GridFunctions.
    ``condense=True`` (default) gives :class:`CondensedHHOSystem`, whose
    semismooth Newton step eliminates the cell unknowns and lam cell by cell
    for the current active set (every iteration) and solves for the face
    unknowns only; ``condense=False`` solves the full system with the generic
    step of :class:`~ngcontact.algebra.system.ComplementaritySystem`.  Both
    give the same iterates (to rounding).

Literature
    D. A. Di Pietro, A. Ern, S. Lemaire, CMAM 14 (2014); D. A. Di Pietro, A. Ern,
    CMAME 283 (2015); B. Cockburn, D. A. Di Pietro, A. Ern, M2AN 50 (2016)
    (mixed-order variant: cells k+1, faces k); J. Dabaghi, G. Delay, CAMWA 92
    (2021) 62-75 [CAMWA21].
"""
from __future__ import annotations

import time

import numpy as np
import scipy.sparse as sp
from numpy.polynomial import legendre
from ngsolve import SEGM, TRIG

from ..algebra.system import ComplementaritySystem, StepInfo
from ..algebra.linalg import SPDSolver
from ..algebra.linalg import ngsolve_coo
from .dg import BrokenLagrange, _quadrature
from ..domains import INTERFACE

__all__ = ["HHODiscretization", "CondensedHHOSystem"]


def _face_basis(p: int, s) -> np.ndarray:
    """psi_k(s) = sqrt(2k+1) P_k(2s-1), k < p: orthogonal on every edge, (psi_k, psi_l)_F = |F| delta_kl."""
    s = np.asarray(s, float)
    return np.stack([np.sqrt(2 * k + 1) * legendre.legval(2 * s - 1, np.eye(p)[k]) for k in range(p)], axis=-1)


def hho_element_matrices(B: BrokenLagrange, reconstruction: str = "potential") -> np.ndarray:
    """HHO matrices A_K (ne, n_loc, n_loc), local dofs [cell nodes (nc) | edge 0 (p) | edge 1 | edge 2].

    ``reconstruction='potential'``: G_K = grad r_K, r_K in P_p(K) (default, optimal);
    ``'full'``: G_K in P_p(K; R^2) as printed on the seed slide (O(h^{p-1}) only, see module doc).
    """
    if reconstruction not in ("potential", "full"):
        raise ValueError(f"reconstruction must be 'potential' or 'full', got {reconstruction!r}")
    p, nc, ne = B.p, B.nc, B.ne
    nl = nc + 3 * p
    q, w = _quadrature(TRIG, 2 * p)
    phi, dphi = B.shape(q), B.dshape(q)  # (nq, nc), (nq, nc, 2)
    s, ws = _quadrature(SEGM, 2 * p)
    psi = _face_basis(p, s)  # (ns, p)
    phiE = B.edge_shapes(s)  # (ne, 3, ns, nc)
    L, nrm = B.edge_len, B.normals  # (ne, 3), (ne, 3, 2)
    # Pi^{p-1}_F phi_j in the face basis: (phi_j, psi_k)_F / |F|
    proj = np.einsum("s,sm,kesj->kemj", ws, psi, phiE, optimize=True)  # (ne, 3, p, nc)
    # trace operator per edge: D_e v = v_F - Pi_F v_K
    Dtr = np.zeros((ne, 3, p, nl))
    Dtr[:, :, :, :nc] = -proj
    for e in range(3):
        Dtr[:, e, :, nc + e * p: nc + (e + 1) * p] = np.eye(p)
    # values of v_F - v_K at the edge quadrature points, per local dof
    jump = np.zeros((ne, 3, len(s), nl))
    jump[:, :, :, :nc] = -phiE
    for e in range(3):
        jump[:, e, :, nc + e * p: nc + (e + 1) * p] = psi
    if reconstruction == "full":
        # rows (c, i) of q = phi_i e_c: (G v, q) = (d_c v_K, phi_i) + sum_F ((v_F - v_K) n_c, phi_i)_F
        Cref = np.einsum("q,qi,qjd->dij", w, phi, dphi, optimize=True)  # (phi_i, dref_d phi_j)
        vol = B.detJ[:, None, None, None] * np.einsum("kcd,dij->kcij", B.invJT, Cref)  # (ne, 2, nc, nc)
        Bm = np.zeros((ne, 2, nc, nl))
        Bm[:, :, :, :nc] = vol
        # (v_F - v_K, phi_i n_c)_F = |F| n_c sum_s ws phi_i (v_F - v_K)
        Bm += np.einsum("ke,kec,s,kesi,kesl->kcil", L, nrm, ws, phiE, jump, optimize=True)
        Bm = Bm.reshape(ne, 2 * nc, nl)
        Minv = np.linalg.inv(B.mass_ref)
        MB = np.einsum("ij,kcjl->kcil", Minv, Bm.reshape(ne, 2, nc, nl)).reshape(ne, 2 * nc, nl)
        AG = np.einsum("kim,kin->kmn", Bm, MB) / B.detJ[:, None, None]
    else:
        # rows i of w = phi_i: (grad r, grad phi_i) = (grad v_K, grad phi_i) + (v_F - v_K, grad phi_i.n)_dK
        G = np.einsum("kcd,qid->kqic", B.invJT, dphi)  # physical gradients (ne, nq, nc, 2)
        S = B.detJ[:, None, None] * np.einsum("q,kqic,kqjc->kij", w, G, G, optimize=True)
        Bm = np.zeros((ne, nc, nl))
        Bm[:, :, :nc] = S
        cfg_grad = np.stack([B.dshape(r) for r in B.edge_ref_points(s)])  # (6, ns, nc, 2)
        dE = cfg_grad[B.edge_config]  # (ne, 3, ns, nc, 2) reference gradients
        dnE = np.einsum("kcd,kesid,kec->kesi", B.invJT, dE, nrm, optimize=True)  # grad phi_i . n
        Bm += np.einsum("ke,s,kesi,kesl->kil", L, ws, dnE, jump, optimize=True)
        Sreg = S + 1.0  # S + 1 1^T: rows of Bm sum to zero, so S_reg^{-1} acts as S^+ on them
        AG = np.einsum("kim,kin->kmn", Bm, np.linalg.solve(Sreg, Bm), optimize=True)
    # s_K = h_K^-1 (Pi(v_F - v_K), w_F - w_K)_dK with M_F = |F| I
    stab = np.einsum("ke,kepm,kepn->kmn", L / B.hK[:, None], Dtr, Dtr, optimize=True)
    return AG + stab


class HHODiscretization:
    """HHO (cells P_p, faces P_{p-1}) for the two-membrane problem (module doc).

    Parameters
    ----------
    problem : TwoMembraneProblem
    mesh : ngsolve.Mesh (straight triangles)
    order : int, 1..4
    solver : str
        SPD solver of the (condensed or full) Newton systems: 'sparsecholesky' or 'scipy'.
    condense : bool
        static condensation inside every Newton step (default) or the full system.
    reconstruction : 'potential' | 'full'
        gradient reconstruction in grad P_p(K) (default) or P_p(K; R^2) (seed slide; suboptimal).
    quad_bonus : int
        extra quadrature order for data and errors.

    Attributes
    ----------
    ndof, ndof_sc : int
        DOFs as counted in [CAMWA21] (u1, u2 on cells and interior faces, lam on
        cells) and after static condensation (u1, u2 on interior faces).
    """

    name = "hho"
    orders = (1, 2, 3, 4)

    def __init__(self, problem, mesh, order: int = 1, solver: str = "sparsecholesky", condense: bool = True,
                 reconstruction: str = "potential", quad_bonus: int = 6):
        if order not in self.orders:
            raise ValueError(f"order must be 1, 2, 3 or 4 for hho, got {order!r}")
        if getattr(problem, "kind", None) != "membranes":
            raise ValueError(f"hho supports the two-membrane problem only, got {type(problem).__name__}")
        if INTERFACE in mesh.GetBoundaries():
            raise ValueError("hho: meshes with an internal '{}' curve (e.g. UnitDisk(interface_radius=...)) "
                             "are supported by disc fem only".format(INTERFACE))
        t0 = time.perf_counter()
        self.problem, self.mesh, self.order, self.condense = problem, mesh, order, bool(condense)
        self.quad_bonus, self.reconstruction = quad_bonus, reconstruction
        self.basis = B = BrokenLagrange(mesh, order)
        p, nc, ne = order, B.nc, B.ne
        self.A_loc = A = hho_element_matrices(B, reconstruction)
        nl = nc + 3 * p

        # numbering of one field: cells (ne*nc, cell-major), then interior faces (nFi*p)
        interior = ~B.bnd_edge
        self.nFi = nFi = int(interior.sum())
        fnum = np.full(B.nE, -1, dtype=np.int64)
        fnum[interior] = np.arange(nFi)
        self.n_cell = ncell = ne * nc
        self.n1 = n1 = ncell + nFi * p
        cell_dofs = np.arange(ncell).reshape(ne, nc)
        fe = fnum[B.cell_edges]  # (ne, 3)
        face_dofs = np.where(fe[:, :, None] >= 0, ncell + fe[:, :, None] * p + np.arange(p), -1).reshape(ne, 3 * p)
        self.loc_dofs = ldofs = np.concatenate([cell_dofs, face_dofs], axis=1)  # (ne, nl), -1: boundary face

        # boundary face values: L2 projection of g on P_{p-1}(F) (psi orthogonal, (psi_k, psi_k)_F = |F|)
        s, ws = _quadrature(SEGM, 2 * p + quad_bonus)
        psi = _face_basis(p, s)
        self.g_loc = []  # per field, local boundary face values (ne, 3p), 0 on interior faces
        bmask = B.bnd_edge[B.cell_edges]  # (ne, 3)
        for gd in (problem.g1, problem.g2):
            gvals = B.edge_evaluate(gd, s)  # (ne, 3, ns)
            gF = np.einsum("kes,s,sj->kej", gvals, ws, psi) * bmask[:, :, None]
            self.g_loc.append(gF.reshape(ne, 3 * p))

        # global stiffness of one field (cells + interior faces) and loads with the Dirichlet lifting
        valid = ldofs >= 0
        rr = np.broadcast_to(ldofs[:, :, None], A.shape)
        cc = np.broadcast_to(ldofs[:, None, :], A.shape)
        both = valid[:, :, None] & valid[:, None, :]
        self.S = sp.csr_matrix((A[both], (rr[both], cc[both])), shape=(n1, n1))
        quad = 2 * p + quad_bonus
        mu1, mu2 = problem.mus
        F = []
        for a, (mu, f) in enumerate(zip((mu1, mu2), (problem.f1, problem.f2))):
            Fa = np.zeros(n1)
            Fa[:ncell] = B.load(f, quad).ravel()
            lift = -mu * np.einsum("kij,kj->ki", A[:, :, nc:], self.g_loc[a])  # -mu A_{., bnd} g
            np.add.at(Fa, ldofs[valid], lift[valid])
            F.append(Fa)
        K = sp.block_diag([mu1 * self.S, mu2 * self.S], format="csr")
        up = np.arange(ncell)
        lo = n1 + up
        m = ncell
        args = (K, np.concatenate(F), up, lo, np.zeros(m), np.ones(m))
        if self.condense:
            self.system = CondensedHHOSystem(*args, solver=solver)
            self.system.setup(A, ldofs, nc, p, mu1, mu2)
        else:
            self.system = ComplementaritySystem(*args, solver=solver)
        self.time_assembly = time.perf_counter() - t0

    # ------------------------------------------------------------------ sizes
    @property
    def n_interior(self) -> int:
        """Number of constraint rows: all cell nodes."""
        return self.n_cell

    @property
    def ndof(self) -> int:
        """[CAMWA21] count without condensation: u1, u2 on cells + interior faces, lam on cells."""
        return 2 * self.n1 + self.n_cell

    @property
    def ndof_sc(self) -> int:
        """[CAMWA21] count after static condensation: u1, u2 on interior faces."""
        return 2 * self.nFi * self.order

    @property
    def timings(self) -> dict:
        """Seconds accumulated by the condensed Newton steps: 'condense' (cell eliminations and
        face right-hand side), 'solve' (face matrix, Cholesky, triangular solves),
        'recover' (cell values and X3), 'steps'.  Empty without condensation."""
        return dict(getattr(self.system, "timings", {}))

    @property
    def time_condense(self) -> float:
        """Seconds spent in static condensation and recovery over all Newton steps so far."""
        t = self.timings
        return t.get("condense", 0.0) + t.get("recover", 0.0)

    # --------------------------------------------------------- unknown layout
    def _cells(self, x, a: int) -> np.ndarray:
        o = a * self.n1
        return x[o:o + self.n_cell].reshape(self.basis.ne, self.basis.nc)

    def _faces_from_cells(self, U: np.ndarray) -> np.ndarray:
        """Interior face values: P_{p-1} projection of the mean of the two cell traces."""
        B, p = self.basis, self.order
        s, ws = _quadrature(SEGM, 2 * p)
        proj = np.einsum("s,sm,kesj->kemj", ws, _face_basis(p, s), B.edge_shapes(s))
        tr = np.einsum("kemj,kj->kem", proj, U).reshape(-1, p)  # (ne*3, p)
        a, b = B.edge_slots[:, 0], B.edge_slots[:, 1]
        inner = b >= 0
        vals = 0.5 * (tr[a[inner]] + tr[b[inner]])
        return vals.ravel()  # interior edges in edge order = face numbering

    def _assemble_x(self, U1, U2) -> np.ndarray:
        return np.concatenate([np.concatenate([U.ravel(), self._faces_from_cells(U)]) for U in (U1, U2)])

    # --------------------------------------------------------- initial guesses
    def initial_guess(self, fields=None):
        """(x0, y0) from CoefficientFunctions per field (None: zero): cell nodal values, faces the
        projected mean trace; y0 = 0."""
        B = self.basis
        U = [np.zeros((B.ne, B.nc)), np.zeros((B.ne, B.nc))]
        for a, cf in enumerate(fields or ()):
            if cf is not None:
                U[a] = B.interpolate(cf)
        return self._assemble_x(*U), np.zeros(self.n_interior)

    def prolongate(self, previous, x, y):
        """Nested iteration: the coarse cell polynomials at this mesh's cell nodes (exact on
        nested meshes), faces from the cell traces, X3 = moments of the coarse lam_h."""
        B = self.basis
        fields = previous.broken_fields(x, y) if hasattr(previous, "broken_fields") else None
        if fields is not None and isinstance(fields[0], BrokenLagrange):
            Bc, (U1, U2, lam) = fields
            U1, U2, lam = (B.transfer_from(Bc, v) for v in (U1, U2, lam))
        else:  # another kind of discretization: evaluate its GridFunctions
            gfs = previous.gridfunctions(x, y)
            U1, U2, lam = (B.values_from(previous.mesh, gfs[n]) for n in ("u1", "u2", "lam"))
        return self._assemble_x(U1, U2), B.nodal_to_dual(lam).ravel()

    def broken_fields(self, x, y):
        """(basis, (U1, U2, lam)): nodal values per cell of u1K, u2K and lam_h."""
        return self.basis, (self._cells(x, 0), self._cells(x, 1), self.basis.dual_to_nodal(y))

    # ------------------------------------------------------------ postprocess
    def gridfunctions(self, x, y) -> dict:
        """L2 GridFunctions of the cell unknowns u1, u2, of lam_h = sum_l X3_l Theta_l, and gap = u1 - u2."""
        B = self.basis
        out = {"u1": B.gridfunction(self._cells(x, 0), "u1"), "u2": B.gridfunction(self._cells(x, 1), "u2"),
               "lam": B.gridfunction(B.dual_to_nodal(y), "lam")}
        out["gap"] = out["u1"] - out["u2"]
        return out

    def errors(self, x, y) -> dict:
        """Energy error of the cell unknowns (sum_K sum_a mu_a ||grad(u_a - u_aK)||_K^2)^(1/2) and
        the max error at the cell nodes."""
        ex = self.problem.exact
        if ex is None:
            return {}
        B = self.basis
        q, w = _quadrature(TRIG, 2 * self.order + self.quad_bonus)
        G = np.einsum("kcd,qid->kqic", B.invJT, B.dshape(q))  # (ne, nq, nc, 2)
        e2, emax = 0.0, 0.0
        for a, (mu, uex) in enumerate(zip(self.problem.mus, (ex.u1, ex.u2))):
            U = self._cells(x, a)
            gex = B.evaluate(ex.gradient(a + 1), q, dim=2)  # (ne, nq, 2)
            d = gex - np.einsum("kqic,ki->kqc", G, U)
            e2 += mu * float(np.einsum("k,q,kqc->", B.detJ, w, d * d))
            emax = max(emax, float(np.abs(B.interpolate(uex) - U).max()))
        return {"err_energy": float(np.sqrt(e2)), "err_max_nodal": emax}

    def contact_points(self, x, y) -> np.ndarray:
        """Coordinates (k, 2) of the cell nodes in the discrete contact set (gap <= X3)."""
        return self.basis.coords.reshape(-1, 2)[self.system.gap(x) <= y]

    def complementarity(self, x, y) -> dict:
        """Min gap, min X3, max |gap * X3| over the cell nodes."""
        g = self.system.gap(x)
        return {"gap_min": float(g.min(initial=0.0)), "lam_min": float(y.min(initial=0.0)),
                "product_max": float(np.max(np.abs(g * y), initial=0.0))}


class CondensedHHOSystem(ComplementaritySystem):
    """HHO complementarity system whose Newton step is solved on the face unknowns only.

    Per cell K the linearized equations (module doc of
    :mod:`ngcontact.algebra.system`) couple the cell values X^C_1, X^C_2 of
    both fields and X3|_K through the C-function rows of the cell's nodes only.
    They are eliminated cell by cell for the current active set:

    * cells without equality (active) or mixed (Fischer-Burmeister) rows:
      X3 is prescribed and the fields decouple; the local inverse of
      mu_a A_CC is the same every step (computed once), only the right-hand
      side changes;
    * the other cells: in the variables s = X^C_1, d = X^C_1 - X^C_2 the
      constraints read g = d (b = 0); d is prescribed on active rows, mixed
      rows add w to the d-diagonal; the symmetric (2 nc x 2 nc) cell block is
      inverted (batched numpy) and its Schur complement on the cell's
      2 x 3p face unknowns computed.

    The face system (SPD, 2 * p * #interior faces) is solved by sparse
    Cholesky; cell values and X3 are recovered cell by cell (active rows:
    X3_l = (mu1 (A_CC X1 + A_CF X1F) - F1)_l).  ``timings`` accumulates the
    seconds spent in condensation, linear solve and recovery.
    """

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
        # coupled cell blocks in (s, d): x1 = s, x2 = s - d
        self.Kzz = np.block([[(mu1 + mu2) * Acc, -mu2 * Acc], [-mu2 * Acc, mu2 * Acc]])
        self.Kzf = np.block([[mu1 * Acf, mu2 * Acf], [np.zeros_like(Acf), -mu2 * Acf]])
        self.Kff = np.block([[mu1 * Aff, np.zeros_like(Aff)], [np.zeros_like(Aff), mu2 * Aff]])
        self.timings = {"condense": 0.0, "solve": 0.0, "recover": 0.0, "steps": 0}

    def newton_step(self, x, y, C, Ca, Cb, eps: float = 1e-12):
        t0 = time.perf_counter()
        nc, ne, n1, ncell, nf = self.nc, self.ncell // self.nc, self.n1, self.ncell, self.nf
        mu1, mu2 = self.mu
        if np.any(self.D != 1.0) or np.any(self.b != 0.0):
            raise ValueError("CondensedHHOSystem expects D = I and b = 0")
        g = self.gap(x)
        aCa, aCb = np.abs(Ca), np.abs(Cb)
        eq = aCb <= eps * aCa
        fixed = ~eq & (aCa <= eps * aCb)
        mixed = ~eq & ~fixed
        safe = lambda den, mask: np.where(mask, den, 1.0)  # noqa: E731
        yfix = np.where(fixed, y - C / safe(Cb, fixed), 0.0)
        w = np.where(mixed, Ca / safe(Cb, mixed), 0.0)
        c0 = np.where(mixed, y - C / safe(Cb, mixed) + w * g, 0.0)
        t = np.where(eq, g - C / safe(Ca, eq), 0.0)  # prescribed d = x1 - x2 on equality rows
        EQ, MX = eq.reshape(ne, nc), mixed.reshape(ne, nc)
        YF, W, C0, T = (v.reshape(ne, nc) for v in (yfix, w, c0, t))
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
            rz = np.concatenate([F1C[cpl] + F2C[cpl],
                                 -F2C[cpl] + YF[cpl] + np.where(mxc, C0[cpl], 0.0)], axis=1)
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
            X1[cpl] = z[:, :nc]
            X2[cpl] = z[:, :nc] - z[:, nc:]
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
