"""Interior penalty discontinuous Galerkin P_p, p = 1..4 (seed "The Discontinuous Galerkin method").

Problem
    The two-membrane problem -mu_a Lap u_a -+ lam = f_a, u1 - u2 >= 0, lam >= 0,
    (u1 - u2) lam = 0, u_a = g_a on the boundary ([CAMWA21], (DS2)).

Discretisation
    Broken space X^p_h = {v in L2 : v|_K in P_p(K)}, unknowns the values of
    u_ah at the Lagrange nodes x_l of every cell (a per-cell nodal basis
    psi_{K,l}, block-diagonal change of basis from NGSolve's ``L2`` basis).
    A_h is the interior penalty form (F: edges, [v] = v^+ - v^-, {.} the mean,
    on boundary edges [v] = v, {w} = w)::

        A_h(u, v) = sum_K (grad u, grad v)_K
                    - sum_F ({grad u}.n, [v])_F - theta sum_F ({grad v}.n, [u])_F
                    + sum_F sigma_F ([u], [v])_F,          sigma_F = c p^2 / h,

    theta = 1 SIPG (symmetric, coercive for c large enough), theta = -1 NIPG
    (coercive for every c > 0, not symmetric), theta = 0 IIPG (not symmetric,
    coercive for c large enough).  h is NGSolve's ``specialcf.mesh_size``,
    which on edge integrals evaluates to 2|K|/|F| (the height of the
    integrating cell K over F; NGSolve 6.2.2608).  Default c = 10 for every
    variant: a safe margin above the smallest c that keeps the symmetric part
    positive definite on the criss-cross meshes (SIPG with c = 1 at p = 2 is
    indefinite); tests/test_dg.py checks both.
    Dirichlet data enter weakly (Nitsche): the load of field a is
    (f_a, v) + mu_a [-theta (g_a, grad v.n)_bnd + (sigma g_a, v)_bnd].

    Contact at the nodes of each cell that do not lie on the boundary
    (V^int_K of the seed): (u1h - u2h)|_K(x_l) >= 0; lam_h|_K is expanded in
    the basis dual to the cell's Lagrange basis, (Theta_{K,l}, psi_{K,m})_K =
    delta_lm, with vanishing moments at boundary nodes (Lambda^p_h of the
    seed), so that D = I:  E X = F,  X1 - X2 >= 0,  X3 >= 0,  (X1 - X2).X3 = 0.

Implementational aspects
    The forms are assembled by NGSolve (``L2(dgjumps=True)``, ``dx(skeleton=True)``,
    ``ds(skeleton=True)``) and transformed to the nodal basis by the
    block-diagonal matrix T (T_K = V_K^{-1}, V_K the values of NGSolve's L2
    basis at the cell's Lagrange nodes).  NIPG and IIPG give non-symmetric
    matrices: the Newton steps of :class:`DGComplementaritySystem` are the
    generic reduction of :mod:`ngcontact.algebra.system` with the reduced
    matrix factorized by a general sparse LU (UMFPACK or SuperLU); SIPG uses
    the same class with sparse Cholesky.

    The per-cell Lagrange basis is :class:`~ngcontact.discretizations.broken.BrokenLagrange`
    (shared with :mod:`ngcontact.discretizations.hho`).  Meshes are taken as
    affine (straight) triangles.

Literature
    D. N. Arnold, F. Brezzi, B. Cockburn, L. D. Marini, SINUM 39 (2002) (unified
    analysis of IP methods); B. Riviere, DG methods for elliptic problems (SIAM
    2008), ch. 2 (SIPG/NIPG/IIPG, penalty); J. Dabaghi, G. Delay, CAMWA 92 (2021)
    62-75 [CAMWA21].
"""
from __future__ import annotations

import time

import numpy as np
import scipy.sparse as sp
from ngsolve import L2, BilinearForm, InnerProduct, TaskManager, ds, dx, grad, specialcf

from ..algebra.linalg import sparse_solve
from ..algebra.system import ComplementaritySystem
from .base import assemble_load, scipy_csr
from .broken import BrokenDiscretization, BrokenLagrange
from .graded import integrate_graded
from .nodesets import constraint_node_set

__all__ = ["DGDiscretization", "DGComplementaritySystem", "VARIANTS"]

#: theta of the interior penalty variants
VARIANTS = {"sipg": 1.0, "nipg": -1.0, "iipg": 0.0}


class DGComplementaritySystem(ComplementaritySystem):
    """:class:`~ngcontact.algebra.system.ComplementaritySystem` whose K may be non-symmetric (NIPG, IIPG).

    The Newton step is the base class's (:meth:`linearize`, then ``recover``): on
    equality rows the slave unknown is eliminated, x = Z z + x_aff, and
    Z^T B^T e_l = 0 there, so Z^T (K x - B^T D y' - F) = 0 is free of the
    unknown multipliers whether K is symmetric or not; the equality
    multipliers come from the slave rows afterwards.  Only the factorization
    of the reduced matrix changes (:meth:`direct_solve`): ``factorization``
    'umfpack' (NGSolve's UMFPACK) or 'splu' (scipy's SuperLU) for a
    non-symmetric K, 'sparsecholesky' for SIPG
    (:func:`~ngcontact.algebra.linalg.sparse_solve`).  Steps are always
    factorized afresh (``factor_reuse`` False).
    """

    factor_reuse = False
    factorization: str = "umfpack"

    def direct_solve(self, A: sp.csr_matrix, b: np.ndarray) -> np.ndarray:
        return sparse_solve(A, b, self.factorization)


class DGDiscretization(BrokenDiscretization):
    """Interior penalty dG (SIPG / NIPG / IIPG) for the two-membrane problem (module doc).

    Parameters
    ----------
    problem : TwoMembraneProblem
    mesh : ngsolve.Mesh (straight triangles)
    order : int, 1..4
    solver : str
        'sparsecholesky' (default): sparse Cholesky for SIPG and NGSolve's UMFPACK for NIPG/IIPG;
        'scipy': scipy's SuperLU with the MMD(A^T + A) ordering for every variant.  A general
        sparse LU is the bottleneck of NIPG/IIPG, and no ordering is fastest on every matrix
        (UMFPACK on the high orders, SuperLU on some low-order matrices); SIPG (Cholesky) does
        not have it.
    variant : 'sipg' | 'nipg' | 'iipg'
    penalty : float, optional
        c in sigma_F = c p^2 / h (default 10).
    quad_bonus : int
        extra quadrature order for data and errors.
    constraints : str
        'nodal' (default): cell nodes of the positive node set (:mod:`~ngcontact.discretizations.nodesets`);
        'equispaced': the equispaced lattice of [CAMWA21] (the same nodes for p = 1, 2, 3).
    """

    name = "dg"
    orders = (1, 2, 3, 4)
    default_penalty = 10.0

    def __init__(self, problem, mesh, order: int = 1, solver: str = "sparsecholesky", variant: str = "sipg",
                 penalty=None, quad_bonus: int = 6, constraints: str = "nodal"):
        if variant not in VARIANTS:
            raise ValueError(f"variant must be one of {sorted(VARIANTS)}, got {variant!r}")
        self._check_setting("dg", problem, mesh, order)
        c = self.default_penalty if penalty is None else float(penalty)
        if not np.isfinite(c) or c <= 0:
            raise ValueError(f"penalty must be a positive number, got {penalty!r}")
        t0 = time.perf_counter()
        self.problem, self.mesh, self.order, self.variant = problem, mesh, order, variant
        self.name, self.nfields = variant, problem.nfields
        self.theta, self.penalty, self.quad_bonus = VARIANTS[variant], c, quad_bonus
        self.constraints = constraints
        self.basis = B = BrokenLagrange(mesh, order, constraint_node_set(constraints, variant))
        self._check_data()
        ne, nc = B.ne, B.nc
        fes = L2(mesh, order=order, dgjumps=True)
        self.fes = fes
        T = B.to_l2_matrix().tocsr()
        u, v = fes.TnT()
        nrm, h = specialcf.normal(2), specialcf.mesh_size
        self.sigma = sigma = c * order ** 2 / h
        th = self.theta
        jump_u, jump_v = u - u.Other(), v - v.Other()
        mean_dn_u = 0.5 * (grad(u) + grad(u.Other())) * nrm
        mean_dn_v = 0.5 * (grad(v) + grad(v.Other())) * nrm
        a = BilinearForm(fes, symmetric=False)
        a += grad(u) * grad(v) * dx
        a += (-mean_dn_u * jump_v - th * mean_dn_v * jump_u + sigma * jump_u * jump_v) * dx(skeleton=True)
        a += (-grad(u) * nrm * v - th * grad(v) * nrm * u + sigma * u * v) * ds(skeleton=True)
        with TaskManager():
            a.Assemble()
        self.A = (T.T @ scipy_csr(a) @ T).tocsr()
        # F_a = (f_a, v) + mu_a [-theta (g_a, grad v.n) + (sigma g_a, v)]_bnd: the Nitsche
        # terms belong to mu_a A_h and scale with mu_a like it
        bonus = dict(bonus_intorder=quad_bonus)
        F = []
        for mu, f, gd in zip(problem.mus, problem.loads, problem.dirichlet):
            Ff = assemble_load(fes, lambda: f * v * dx(**bonus), lambda: f.Compile() * v * dx(**bonus))
            Fg = assemble_load(fes, lambda: (-th * gd * grad(v) * nrm + sigma * gd * v) * ds(skeleton=True, **bonus))
            F.append(T.T @ (Ff + mu * Fg))
        self.n1 = n1 = ne * nc
        mu1, mu2 = problem.mus
        K = sp.block_diag([mu1 * self.A, mu2 * self.A], format="csr")
        F = np.concatenate(F)
        cons = ~B.node_on_boundary.ravel()
        self.constrained = np.flatnonzero(cons)  # (cell * nc + node) of each constraint row
        m = len(self.constrained)
        up, lo = self.constrained, n1 + self.constrained
        self.system = DGComplementaritySystem(K, F, up, lo, np.zeros(m), np.ones(m), solver=solver,
                                             stiffness_scale=problem.stiffness_scale)
        if solver == "sparsecholesky":
            self.system.factorization = "sparsecholesky" if variant == "sipg" else "umfpack"
        else:
            self.system.factorization = "splu"
        self.time_assembly = time.perf_counter() - t0

    # ------------------------------------------------------------------ sizes
    @property
    def n_interior(self) -> int:
        """Number of constraint rows (cell nodes off the boundary)."""
        return len(self.constrained)

    @property
    def ndof(self) -> int:
        """u1, u2 on all cell nodes + lam on the constrained cell nodes."""
        return 2 * self.n1 + self.n_interior

    @property
    def constraint_points(self) -> np.ndarray:
        """Coordinates of the constrained cell nodes."""
        return self.basis.coords.reshape(-1, 2)[self.constrained]

    # ------------------------------------------------------------- guesses
    def _split(self, x):
        return x[: self.n1].reshape(self.basis.ne, -1), x[self.n1:].reshape(self.basis.ne, -1)

    def initial_guess(self, fields=None):
        """(x0, y0): nodal values of CoefficientFunctions per field (None: zero), y0 = 0."""
        x0 = np.zeros(2 * self.n1)
        for a, cf in enumerate(fields or ()):
            if cf is not None:
                x0[a * self.n1:(a + 1) * self.n1] = self.basis.interpolate(cf).ravel()
        return x0, np.zeros(self.n_interior)

    def prolongate(self, previous, x, y, cfun: str = "min"):
        """Nested iteration: the coarse cell polynomials at this mesh's cell nodes (exact on
        nested meshes) and the moments of the coarse lam_h against the fine nodal basis."""
        U1, U2, lam = self._coarse_fields(previous, x, y)
        x0 = np.concatenate([U1.ravel(), U2.ravel()])
        y0 = self.basis.nodal_to_dual(lam).ravel()[self.constrained]
        return x0, y0

    def broken_fields(self, x, y):
        """(basis, (U1, U2, lam)): nodal values per cell of u1h, u2h and lam_h."""
        X1, X2 = self._split(x)
        Y = np.zeros(self.n1)
        Y[self.constrained] = y
        return self.basis, (X1, X2, self.basis.dual_to_nodal(Y))

    # ------------------------------------------------------------ postprocess
    def gridfunctions(self, x, y) -> dict:
        """L2 GridFunctions u1, u2, lam (lam_h = sum_l X3_l Theta_l) and the CF gap = u1 - u2."""
        B, (X1, X2, lam) = self.broken_fields(x, y)
        out = {name: B.gridfunction(X, name) for name, X in zip(self.problem.field_names, (X1, X2))}
        out["lam"] = B.gridfunction(lam, "lam")
        out["gap"] = self.problem.gap([out["u1"], out["u2"]])
        return out

    def errors(self, x, y) -> dict:
        """Broken energy error (sum_K sum_a mu_a ||grad(u_a - u_ah)||_K^2)^(1/2) ('err_energy') and
        the jump seminorm (sum_a mu_a sum_F |F|^-1 ||[u_ah]||_F^2)^(1/2)
        ('err_jump', with |F| the edge length; boundary: ||u_ah - g_a||_F); max nodal error
        'err_max_nodal'."""
        ex = self.problem.exact
        if ex is None:
            return {}
        gfs = self.gridfunctions(x, y)
        order = 2 * self.order + self.quad_bonus
        e2 = j2 = emax = 0.0
        for a, (name, mu, gd, uex) in enumerate(zip(self.problem.field_names, self.problem.mus,
                                                    self.problem.dirichlet, (ex.u1, ex.u2))):
            d = ex.gradient(a + 1) - grad(gfs[name])
            with TaskManager():  # compiled: same values, faster; threaded (the sum may differ in its last bit)
                e2 += mu * integrate_graded(InnerProduct(d, d).Compile(), self.mesh, order, ex.singular_points)
            X = x[a * self.n1:(a + 1) * self.n1]
            j2 += mu * self.basis.jump_seminorm2(X, gd, order)
            emax = max(emax, float(np.abs(self.basis.interpolate(uex).ravel() - X).max()))
        return {"err_energy": float(np.sqrt(max(e2, 0.0))), "err_jump": float(np.sqrt(max(j2, 0.0))),
                "err_max_nodal": emax}
