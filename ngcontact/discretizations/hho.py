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
    is not exact on P_p (tests/test_hho.py) and converges like h^{p-1} only
    on test 1; it is kept for comparison.
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
    ``condense=True`` (default) gives
    :class:`~ngcontact.discretizations.condensed.CondensedHHOSystem`, whose
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
from ngsolve import SEGM, TRIG, InnerProduct, grad

from ..algebra.system import ComplementaritySystem
from .broken import BrokenDiscretization, BrokenLagrange, _quadrature
from .condensed import CondensedHHOSystem
from .graded import integrate_graded
from .nodesets import constraint_node_set

__all__ = ["HHODiscretization", "CondensedHHOSystem", "hho_element_matrices"]


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


class HHODiscretization(BrokenDiscretization):
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
    constraints : str
        'nodal' (default): cell nodes of the positive node set (:mod:`~ngcontact.discretizations.nodesets`);
        'equispaced': the equispaced lattice of [CAMWA21] (the same nodes for p = 1, 2, 3).

    Attributes
    ----------
    ndof, ndof_sc : int
        DOFs as counted in [CAMWA21] (u1, u2 on cells and interior faces, lam on
        cells) and after static condensation (u1, u2 on interior faces).
    """

    name = "hho"
    orders = (1, 2, 3, 4)

    def __init__(self, problem, mesh, order: int = 1, solver: str = "sparsecholesky", condense: bool = True,
                 reconstruction: str = "potential", quad_bonus: int = 6, constraints: str = "nodal"):
        self._check_setting("hho", problem, mesh, order)
        t0 = time.perf_counter()
        self.problem, self.mesh, self.order, self.condense = problem, mesh, order, bool(condense)
        self.quad_bonus, self.reconstruction, self.nfields = quad_bonus, reconstruction, problem.nfields
        self.constraints = constraints
        self.basis = B = BrokenLagrange(mesh, order, constraint_node_set(constraints, "hho"))
        self._check_data()
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
        for gd in problem.dirichlet:
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
        for a, (mu, f) in enumerate(zip((mu1, mu2), problem.loads)):
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
            self.system = CondensedHHOSystem(*args, solver=solver, stiffness_scale=problem.stiffness_scale)
            self.system.setup(A, ldofs, nc, p, mu1, mu2)
        else:
            self.system = ComplementaritySystem(*args, solver=solver, stiffness_scale=problem.stiffness_scale)
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
        """[CAMWA21] count after static condensation: u1, u2 on interior faces (with or without
        ``condense``: a count of the method, as in the DOF tables of [CAMWA21])."""
        return 2 * self.nFi * self.order

    @property
    def constraint_points(self) -> np.ndarray:
        """Coordinates of the cell nodes (every cell node carries a constraint row)."""
        return self.basis.coords.reshape(-1, 2)

    @property
    def timings(self) -> dict:
        """Seconds accumulated by the condensed Newton steps: 'condense' (cell eliminations and
        face right-hand side), 'solve' (face matrix, Cholesky, triangular solves),
        'recover' (cell values and X3), 'steps'.  Empty without condensation."""
        return dict(self.system.timings) if self.condense else {}

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

    def prolongate(self, previous, x, y, cfun: str = "min"):
        """Nested iteration: the coarse cell polynomials at this mesh's cell nodes (exact on
        nested meshes), faces from the cell traces, X3 = moments of the coarse lam_h."""
        U1, U2, lam = self._coarse_fields(previous, x, y)
        return self._assemble_x(U1, U2), self.basis.nodal_to_dual(lam).ravel()

    def broken_fields(self, x, y):
        """(basis, (U1, U2, lam)): nodal values per cell of u1K, u2K and lam_h."""
        return self.basis, (self._cells(x, 0), self._cells(x, 1), self.basis.dual_to_nodal(y))

    # ------------------------------------------------------------ postprocess
    def gridfunctions(self, x, y) -> dict:
        """L2 GridFunctions of the cell unknowns u1, u2, of lam_h = sum_l X3_l Theta_l, and gap = u1 - u2."""
        B, fields = self.broken_fields(x, y)
        out = {name: B.gridfunction(X, name) for name, X in zip(self.problem.field_names + ("lam",), fields)}
        out["gap"] = self.problem.gap([out["u1"], out["u2"]])
        return out

    def errors(self, x, y) -> dict:
        """Energy error of the cell unknowns (sum_K sum_a mu_a ||grad(u_a - u_aK)||_K^2)^(1/2) and
        the max error at the cell nodes.  The rule of order 2p + quad_bonus on every cell; graded towards the
        exact solution's declared ``singular_points`` on the cells at them (:mod:`.graded`, as FEM and dG)."""
        ex = self.problem.exact
        if ex is None:
            return {}
        B = self.basis
        order = 2 * self.order + self.quad_bonus
        q, w = _quadrature(TRIG, order)
        G = np.einsum("kcd,qid->kqic", B.invJT, B.dshape(q))  # (ne, nq, nc, 2)
        e2, emax = 0.0, 0.0
        for a, (mu, uex) in enumerate(zip(self.problem.mus, (ex.u1, ex.u2))):
            U = self._cells(x, a)
            if ex.singular_points:
                d = ex.gradient(a + 1) - grad(B.gridfunction(U))
                e2 += mu * integrate_graded(InnerProduct(d, d).Compile(), self.mesh, order, ex.singular_points)
            else:
                gex = B.evaluate(ex.gradient(a + 1), q, dim=2)  # (ne, nq, 2)
                d = gex - np.einsum("kqic,ki->kqc", G, U)
                e2 += mu * float(np.einsum("k,q,kqc->", B.detJ, w, d * d))
            emax = max(emax, float(np.abs(B.interpolate(uex) - U).max()))
        return {"err_energy": float(np.sqrt(e2)), "err_max_nodal": emax}
