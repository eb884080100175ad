"""Conforming finite elements P_p, p = 1..4 ([CAMWA21], seed "The finite element method").

Unknowns are the values at the interior Lagrange nodes x_l:
u_ah = sum_l (X_a)_l psi_l (+ Dirichlet lifting by nodal interpolation of g_a).
The multiplier is lam_h = sum_l (X3)_l Theta_l with

* p = 1: Theta_l = psi_l and the lumped product <w, v>_h = sum_a w(a) v(a) (psi_a, 1),
  so D = diag((psi_a, 1)) (Ben Belgacem, Bernardi, Blouza, Vohralik 2012);
* p >= 2: Theta_l the basis dual to the Lagrange basis, (Theta_l, psi_m) = delta_lm,
  so D = I and X3 >= 0  <=>  (lam_h, psi_l) >= 0 (Lambda_h^p of the seed).

The nodes x_l are those of :mod:`ngcontact.discretizations.nodesets` (``constraints='nodal'``: no psi_l
with a negative integral; 'equispaced': the lattice of [CAMWA21]); with ``constraints='bernstein'`` the
X_a, X3 are coefficients in the Bernstein basis and its dual basis (:mod:`ngcontact.discretizations.bernstein`).

The algebraic problem is (DS2): E X = F, X1 - X2 >= 0, X3 >= 0, (X1 - X2).X3 = 0,
E = [[mu1 S, 0, -D], [0, mu2 S, D]], S the Lagrange-basis stiffness matrix,
obtained from NGSolve's hierarchical H1 matrices by the exact change of
basis of :mod:`ngcontact.discretizations.lagrange`.  The obstacle problem is the same with one
field and g = X - psi.
"""
from __future__ import annotations

import time
import weakref
from typing import Optional

import numpy as np
import scipy.sparse as sp
from ngsolve import (BilinearForm, CoefficientFunction, GridFunction, H1, InnerProduct, LinearForm, TaskManager,
                     dx, grad)

from ..algebra.linalg import MassSolver
from ..algebra.multigrid import field_prolongation, p1_prolongation
from ..algebra.sparse import submatrix
from ..algebra.system import ComplementaritySystem
from ..domains import DIRICHLET, ArrayMesh
from ..domains.base import matplotlib_tri
from ..problems.base import check_data_on_points
from .base import Discretization, bit_mask, coordinate_only, evaluate_at_points, scipy_csr
from .bernstein import BernsteinBasis
from .graded import integrate_graded
from .lagrange import LagrangeNodes, meshpoints
from .nodesets import constraint_node_set
from .p1 import dirichlet_vertices, p1_matrices, p1_tables
from .p1_levels import _assemble_load, _nodal_data, _zero, nested_inputs

__all__ = ["FEMDiscretization"]


def _block_diag_csr(blocks) -> sp.csr_matrix:
    """blockdiag of CSR matrices by concatenating their arrays (scipy's block_diag goes through
    COO, much slower on large matrices)."""
    blocks = [sp.csr_matrix(B) for B in blocks]
    if len(blocks) == 1:
        return blocks[0]
    big = max(sum(B.nnz for B in blocks), sum(B.shape[1] for B in blocks)) >= np.iinfo(np.int32).max
    itype = np.int64 if big else np.int32  # the index type scipy would choose (no second conversion)
    indptr, indices, data, nnz, r, c = [np.zeros(1, dtype=itype)], [], [], 0, 0, 0
    for B in blocks:
        indptr.append(B.indptr[1:].astype(itype) + itype(nnz))
        indices.append(B.indices.astype(itype) + itype(c))
        data.append(B.data)
        nnz, r, c = nnz + B.nnz, r + B.shape[0], c + B.shape[1]
    return sp.csr_matrix((np.concatenate(data), np.concatenate(indices), np.concatenate(indptr)), shape=(r, c))


class FEMDiscretization(Discretization):
    """Conforming P_p discretization of a two-membrane or obstacle problem on one mesh.

    Parameters
    ----------
    problem : TwoMembraneProblem or ObstacleProblem
    mesh : ngsolve.Mesh or ArrayMesh
        an :class:`~ngcontact.domains.ArrayMesh` (a level of a structured rectangle as arrays) stays arrays
        for P1 with data that are functions of the coordinates only (:func:`~.base.coordinate_only`): the
        system is built from the arrays, the data evaluated at the vertices on the coarsest mesh of the
        hierarchy, and :attr:`mesh` and :attr:`fes` are built on first use (errors, GridFunctions, VTK,
        estimators, a nonzero load that is not given as ``loads``); otherwise its NGSolve mesh is built at once.
    order : int, 1..4
    solver : str
        sparse SPD solver of the Newton steps ('sparsecholesky' or 'scipy').
    quad_bonus : int
        extra quadrature order for data (loads, errors).
    constraints : str
        'nodal' (default): constraints at the Lagrange nodes of the positive node set
        (:mod:`~ngcontact.discretizations.nodesets`: no cardinal function has a negative integral);
        'equispaced': at the equispaced lattice of [CAMWA21] (the same nodes for p = 1, 2, 3);
        'bernstein': unknowns are Bernstein coefficients (:mod:`~ngcontact.discretizations.bernstein`),
        the gap's coefficients >= 0 and the multiplier in the dual basis (the same as 'nodal' for p = 1).
    loads : sequence of arrays, optional
        the load vectors (f_a, psi_i) of the fields at all nodes (boundary nodes included), used instead of
        assembling them; :func:`~.p1_levels.nested_loads` gives those of a nested P1 hierarchy.
    data : dict, optional
        P1 on an ArrayMesh that stays arrays: the data at the vertices as the set-up evaluates them (name ->
        values; Dirichlet data at the boundary vertices, zero elsewhere), used instead of evaluating them;
        :func:`~.p1_levels.nested_data` gives those of a nested hierarchy.
    """

    name = "fem"
    orders = (1, 2, 3, 4)
    estimable = True
    array_meshes = True

    def __init__(self, problem, mesh, order: int = 1, solver: str = "sparsecholesky", quad_bonus: int = 6,
                 constraints: str = "nodal", loads=None, data=None):
        if order not in self.orders:
            raise ValueError(f"order must be 1, 2, 3 or 4 for fem, got {order!r}")
        node_set = constraint_node_set(constraints)
        self.constraints = constraints
        t0 = time.perf_counter()
        self.problem, self.order, self.quad_bonus = problem, order, quad_bonus
        self._mass = self._mass_solver = None  # nodal mass matrix and its factorization, built on first use
        # an ArrayMesh stays arrays while P1 needs nothing else (class docstring)
        arrays = mesh if isinstance(mesh, ArrayMesh) else None
        if arrays is not None and not (order == 1 and constraints != "bernstein"
                                       and all(map(coordinate_only, problem.data().values()))):
            mesh, arrays = arrays.build(), None
        self._arrays, self._mesh, self._fes = arrays, (None if arrays is not None else mesh), None
        if arrays is not None:
            tables = (np.asarray(arrays.X, dtype=float), arrays.T)  # T: int32 below 2^31 vertices (as p1_tables)
            bnd = arrays.dirichlet_vertices()
            self.nodes = nodes = LagrangeNodes.from_arrays(
                *tables, lambda where: meshpoints(*arrays.vertex_location(where)))
            free = ~bnd
        else:
            if getattr(problem.domain, "curved", False) and order > 1:
                mesh.Curve(order)
            self._fes = fes = H1(mesh, order=order, dirichlet=DIRICHLET)
            # P1 on straight triangles: numpy set-up from the vertex arrays (discretizations.p1), same matrices
            tables = p1_tables(mesh, fes) if constraints != "bernstein" else None
            bnd = dirichlet_vertices(mesh, DIRICHLET, fes) if tables is not None else None
            if bnd is None:
                tables = None
                self.nodes = nodes = BernsteinBasis.build(fes) if constraints == "bernstein" \
                    else LagrangeNodes.build(fes, node_set)
                free = bit_mask(fes.FreeDofs())
            else:
                self.nodes = nodes = LagrangeNodes.from_p1_tables(fes, *tables)
                free = ~bnd
        self.interior = np.flatnonzero(free)
        self.boundary = np.flatnonzero(~free)
        ni = len(self.interior)

        # data at the nodes, checked once
        if data is not None:
            if arrays is None:
                raise ValueError("data: nodal data are taken by P1 on an ArrayMesh with coordinate data only")
            if list(data) != list(problem.data()) or any(np.shape(v) != (nodes.ndof,) for v in data.values()):
                raise ValueError(f"data: expected the values of {list(problem.data())} at {nodes.ndof} vertices, got "
                                 f"{ {k: np.shape(v) for k, v in data.items()} }")
        elif constraints == "bernstein":  # coefficients from the values at every node (BernsteinBasis.from_values)
            data = {name: nodes.evaluate(cf) for name, cf in problem.data().items()}
        else:  # nodal values: the Dirichlet data are used at the boundary nodes only
            data = _nodal_data(problem, nodes, self.boundary)
        check_data_on_points(problem, data, ~free, nodes.coords)
        coef = {name: nodes.from_values(v) for name, v in data.items()}  # coefficients of the interpolants

        if tables is None:
            u, v = fes.TnT()
            with TaskManager():
                S = BilinearForm(grad(u) * grad(v) * dx).Assemble()
                ones = LinearForm(v * dx).Assemble()
            S = nodes.transform(scipy_csr(S))
            weights = nodes.T.T @ ones.vec.FV().NumPy() if order == 1 else None
            del ones
        else:
            S, weights = p1_matrices(*tables)
        del tables
        Sii = submatrix(S, self.interior, self.interior)
        # D: lumped weights (psi_a, 1) for p = 1, identity (dual basis) for p >= 2
        self.D = weights[self.interior] if order == 1 else np.ones(ni)

        self.lift = []  # nodal Dirichlet values of each field (zero inside)
        F = []
        if loads is not None and (len(loads) != problem.nfields or any(np.shape(v) != (nodes.ndof,) for v in loads)):
            raise ValueError(f"loads: expected {problem.nfields} vectors of length {nodes.ndof}, got shapes "
                             f"{[np.shape(v) for v in loads]}")
        for k, (mu, f, gname) in enumerate(zip(problem.mus, problem.loads, problem.dirichlet_names)):
            Fn = nodes.T.T @ self.load_vector(f) if loads is None else np.asarray(loads[k], dtype=float)
            gb = np.zeros(nodes.ndof)
            gb[self.boundary] = coef[gname][self.boundary]
            self.lift.append(gb)
            F.append(Fn[self.interior] - mu * (S @ gb)[self.interior])  # S_ib g_b: gb is zero inside
        self.nfields = problem.nfields
        K = _block_diag_csr([Sii if mu == 1.0 else mu * Sii for mu in problem.mus])  # 1.0 * s == s exactly
        del Sii, S
        if problem.obstacle is None:  # u1 - u2 >= 0
            up, lo, b = np.arange(ni), ni + np.arange(ni), np.zeros(ni)
        else:  # u - psi >= 0
            up, lo, b = np.arange(ni), -np.ones(ni, dtype=np.int64), coef["psi"][self.interior]  # psi of problem.data()
        self.system = ComplementaritySystem(K, np.concatenate(F), up, lo, b, self.D, solver=solver,
                                             stiffness_scale=problem.stiffness_scale,
                                             tensions=tuple(problem.mus) if problem.obstacle is None else None)
        self.time_assembly = time.perf_counter() - t0

    def load_vector(self, f) -> np.ndarray:
        """(f, phi_i) for the hierarchical basis; zero for an identically zero f.  Assembled with f compiled: the
        same vector (bitwise), faster.  (A nonzero load on an ArrayMesh builds its NGSolve mesh here.)"""
        if self._arrays is not None and _zero(f):
            return np.zeros(self.nodes.ndof)
        return _assemble_load(self.fes, f, self.quad_bonus)

    @classmethod
    def nested_inputs(cls, problem, meshes, order: int = 1, constraints: str = "nodal") -> Optional[list]:
        """Per level of a nested array hierarchy, the ``loads`` and ``data`` arguments computed once on the finest
        level (:func:`~.p1_levels.nested_inputs`), or None."""
        return nested_inputs(problem, meshes, order, constraints)

    # ------------------------------------------------------------------ mesh and space
    @property
    def mesh(self):
        """The NGSolve mesh (of an ArrayMesh: built on first use, and the nodes evaluate on it from then on)."""
        if self._mesh is None:
            self._mesh = self._arrays.build()
            self.nodes.attach(self._mesh)
        return self._mesh

    @property
    def fes(self):
        """``H1(mesh, order, dirichlet=DIRICHLET)`` (of an ArrayMesh: built on first use, checked against the
        Dirichlet vertices of the arrays)."""
        if self._fes is None:
            fes = H1(self.mesh, order=self.order, dirichlet=DIRICHLET)
            if fes.ndof != self.nodes.ndof or fes.FreeDofs().NumSet() != self.n_interior:
                raise RuntimeError(f"the P1 space of the built mesh ({fes.ndof} dofs, {fes.FreeDofs().NumSet()} free) "
                                   f"does not match the arrays ({self.nodes.ndof}, {self.n_interior})")
            self._fes = fes
        return self._fes

    @property
    def nelem(self) -> int:
        return self._arrays.ne if self._mesh is None else self._mesh.ne

    @property
    def nvert(self) -> int:
        return self._arrays.nv if self._mesh is None else self._mesh.nv

    @property
    def parents(self):
        """The parent table ``ngc_parents`` of structured nested meshes (domains), or None."""
        return getattr(self._arrays if self._mesh is None else self._mesh, "ngc_parents", None)

    # ------------------------------------------------------------------ sizes
    @property
    def n_interior(self) -> int:
        return len(self.interior)

    @property
    def ndof(self) -> int:
        """DOFs as counted in [CAMWA21]: (fields + multiplier) x interior Lagrange nodes."""
        return (self.nfields + 1) * self.n_interior

    @property
    def constraint_points(self) -> np.ndarray:
        """Coordinates of the interior Lagrange nodes (one constraint row each)."""
        return self.nodes.coords[self.interior]

    # --------------------------------------------------------- initial guesses
    def initial_guess(self, fields=None):
        """(x0, y0) from CoefficientFunctions per field (None: zero), y0 = 0."""
        ni = self.n_interior
        x0 = np.zeros(self.nfields * ni)
        for a, cf in enumerate(fields or ()):
            if cf is not None:
                if not coordinate_only(CoefficientFunction(cf)):
                    _ = self.mesh  # built now: the nodes evaluate on this level's own mesh from then on
                x0[a * ni:(a + 1) * ni] = self.nodes.from_values(self.nodes.evaluate(CoefficientFunction(cf)))[self.interior]
        return x0, np.zeros(ni)

    def prolongate(self, previous: "FEMDiscretization", x, y, cfun: str = "min"):
        """Nested iteration: interpolate a coarser level's solution at this level's nodes
        (:meth:`~ngcontact.algebra.system.ComplementaritySystem.warm_start`; ``cfun`` the Newton run's C-function)."""
        names = list(self.problem.field_names)
        if self.order == 1 and previous.order == 1:  # nested P1 meshes: no point search needed
            nodal = previous.nodal_fields(x, y)
            stacked = np.stack([nodal[n] for n in names + ["lam"]])
            vals = _parent_p1_values(previous, self, stacked)
            self.__dict__.pop("_parent_cache", None)  # the hierarchy has asked already: not kept with the level
            if vals is None:
                vals = _nested_p1_values(previous, self.nodes.coords[self.interior], stacked)
            if vals is not None:
                return self.system.warm_start(np.concatenate(vals[:-1]), vals[-1], hand_on=cfun == "min",
                                              prolongations=tuple(getattr(self, "mg_prolongations", ())))
        gfs = previous.gridfunctions(x, y)
        pts = self.nodes.coords[self.interior]
        curved = getattr(previous.problem.domain, "curved", False) and previous.order > 1
        bernstein = self.constraints == "bernstein" and self.order > 1
        if bernstein:  # Bernstein coefficients need the values at all domain points
            pts = self.nodes.coords
        mp = None if curved else _locate(previous.mesh, pts)  # one point search for all fields
        vals = [_evaluate_at(previous.mesh, gfs[n], pts, mp) for n in names + ["lam"]]
        if bernstein:
            vals = [self.nodes.from_values(v)[self.interior] for v in vals]
        x0, lam = np.concatenate(vals[:-1]), vals[-1]
        if self.order == 1:
            y0 = lam
        else:  # y_l = (lam_h, psi_l) for the interpolated lam_h
            full = np.zeros(self.fes.ndof)
            full[self.interior] = lam
            y0 = self.mass_nodal() @ full
            y0 = y0[self.interior]
        return self.system.warm_start(x0, y0, hand_on=cfun == "min")  # obstacle rows: projected, first active set from the residual

    def unknown_prolongation(self, previous: "FEMDiscretization"):
        """Nested P1 interpolation of all fields' interior unknowns from ``previous`` (P1 on the parent
        table of structured nested meshes, :func:`_parent_p1_values`), or None."""
        if not (self.order == previous.order == 1 and self.problem.field_names == previous.problem.field_names):
            return None
        if _parent_pairs(previous, self) is None:
            return None
        P = p1_prolongation(self.parents, self.interior, previous.interior, previous.nodes.ndof)
        return field_prolongation(P, len(self.problem.field_names))

    # ------------------------------------------------------------ postprocess
    def mass_nodal(self) -> sp.csr_matrix:
        if self._mass is None:
            u, v = self.fes.TnT()
            M = BilinearForm(u * v * dx).Assemble()
            self._mass = self.nodes.transform(scipy_csr(M))
        return self._mass

    def _field_values(self, x) -> dict:
        """Nodal values (all nodes, boundary included) of the fields u_a."""
        ni = self.n_interior
        out = {}
        for a, name in enumerate(self.problem.field_names):
            X = self.lift[a].copy()
            X[self.interior] = x[a * ni:(a + 1) * ni]
            out[name] = X
        return out

    def nodal_fields(self, x, y) -> dict:
        """Nodal values (all nodes, boundary included) of u_a and lam_h."""
        out = self._field_values(x)
        rhs = np.zeros(self.nodes.ndof)
        rhs[self.interior] = y
        if self.order == 1:
            out["lam"] = rhs  # lam_h(a) = X3_a, zero on the boundary
        else:  # lam_h = sum_l X3_l Theta_l:  M Lambda = [X3; 0]
            out["lam"] = self.mass_nodal_solver().solve(rhs)
        return out

    def mass_nodal_solver(self):
        """A solver of :meth:`mass_nodal` (``solve(b)``; :class:`~ngcontact.algebra.linalg.MassSolver`: CG for the
        first solves, e.g. lam_h of the one estimate of an adaptive level, then a sparse Cholesky factorization
        that every further Newton iterate and estimate reuses)."""
        if self._mass_solver is None:
            self._mass_solver = MassSolver(self.mass_nodal())
        return self._mass_solver

    def gridfunctions(self, x, y) -> dict:
        """GridFunctions u1, u2 (or u), lam and the gap u1 - u2 (or u - psi)."""
        out = {name: self._function(X, name) for name, X in self.nodal_fields(x, y).items()}
        out["gap"] = self.problem.gap([out[name] for name in self.problem.field_names])
        return out

    def _function(self, X, name: str):
        """The GridFunction of the nodal values X."""
        gf = GridFunction(self.fes, name=name)
        gf.vec.FV().NumPy()[:] = self.nodes.T @ X
        return gf

    def errors(self, x, y) -> dict:
        """Energy error (sum_a mu_a ||grad(u_a - u_ah)||^2)^(1/2) and max nodal error."""
        ex = self.problem.exact
        if ex is None:
            return {}
        nodal = self._field_values(x)  # the fields only: lam_h (a mass solve for p >= 2) is not needed here
        gfs = {name: self._function(X, name) for name, X in nodal.items()}
        e2, emax = 0.0, 0.0
        order = 2 * self.order + self.quad_bonus
        for a, (name, mu) in enumerate(zip(self.problem.field_names, self.problem.mus)):
            d = ex.gradient(a + 1) - grad(gfs[name])
            # compiled integrands: the same values (bitwise), evaluated faster; threaded (per-thread partial sums:
            # the sum may differ in its last bit)
            with TaskManager():
                e2 += mu * integrate_graded(InnerProduct(d, d).Compile(), self.mesh, order, ex.singular_points)
                exact_nodal = self.nodes.evaluate((ex.u1 if a == 0 else ex.u2).Compile())
            emax = max(emax, float(np.max(np.abs(exact_nodal - self.nodes.to_values(nodal[name])))))
        return {"err_energy": float(np.sqrt(max(e2, 0.0))), "err_max_nodal": emax}



def _parent_p1_values(previous, fine, values):
    """P1 interpolant of nodal ``values`` (k x coarse nodes) at ``fine``'s interior nodes from the
    parent table ``fine.mesh.ngc_parents`` of structured domains (``domains.boxes._BoxDomain.meshes``),
    or None (no table, or it does not describe these two meshes: checked on the coordinates,
    bitwise).  Cheaper than the coordinate matching of :func:`_nested_p1_values`."""
    pairs = _parent_pairs(previous, fine)
    if pairs is None:
        return None
    a, b = pairs
    return 0.5 * (np.take(values, a, axis=1) + np.take(values, b, axis=1))  # take: faster than fancy indexing


def _parent_pairs(previous, fine):
    """(a, b): the coarse parents of ``fine``'s interior nodes in the table ``fine.mesh.ngc_parents``, or None
    (no table, or it does not describe these two P1 meshes: checked on the coordinates, bitwise).  Kept on
    ``fine`` for ``previous`` (the multigrid hierarchy and the prolongation of a level both ask)."""
    cached = getattr(fine, "_parent_cache", None)
    if cached is not None and cached[0]() is previous:
        return cached[1]
    pairs = _check_parent_pairs(previous, fine)
    fine._parent_cache = (weakref.ref(previous), pairs)
    return pairs


def _check_parent_pairs(previous, fine):
    par = fine.parents
    if par is None or fine.nodes.ndof != fine.nvert or previous.nodes.ndof != previous.nvert \
            or par.shape != (fine.nvert, 2) or par.max(initial=0) >= previous.nvert:
        return None
    a, b = par[fine.interior, 0], par[fine.interior, 1]
    P, Q = previous.nodes.coords, fine.nodes.coords
    for k in range(P.shape[1]):  # one coordinate at a time: gathers from contiguous vectors, not rows of P
        Pk = np.ascontiguousarray(P[:, k])
        if not np.array_equal(0.5 * (Pk[a] + Pk[b]), Q[fine.interior, k]):
            return None
    return a, b


def _nested_p1_values(previous, pts, values):
    """P1 interpolant of nodal ``values`` (k x coarse nodes) of ``previous`` at ``pts``, or None.

    A uniform (red) or bisection refinement of a straight-sided mesh puts
    every new vertex at a coarse vertex or at the midpoint of a coarse edge,
    where the P1 interpolant is the nodal value or the mean of the edge's two
    nodal values.  Points are matched bitwise against those coordinates
    (midpoints computed as 0.5 * (a + b), as the refinements do); if any
    point does not match (curved boundary, another refinement), None and the
    caller searches the points (:func:`_locate`, much slower on large meshes).
    """
    P = previous.nodes.coords
    T = previous.mesh.ngmesh.Elements2D().NumPy()["nodes"][:, :3].astype(np.int64) - 1
    if previous.fes.ndof != previous.mesh.nv or len(T) != previous.mesh.ne:
        return None
    pairs = np.sort(T[:, [0, 1, 1, 2, 2, 0]].reshape(-1, 2), axis=1)
    ekey = np.unique(pairs[:, 0] * len(P) + pairs[:, 1])  # 1-d integer keys: much faster than unique(axis=0)
    E = np.stack([ekey // len(P), ekey % len(P)], axis=1)
    cand = np.concatenate([P[:, 0] + 1j * P[:, 1], 0.5 * (P[E[:, 0], 0] + P[E[:, 1], 0])
                           + 1j * (0.5 * (P[E[:, 0], 1] + P[E[:, 1], 1]))])
    order = np.argsort(cand)
    key = pts[:, 0] + 1j * pts[:, 1]
    pos = np.minimum(np.searchsorted(cand[order], key), len(cand) - 1)
    if not len(cand) or np.any(cand[order][pos] != key):
        return None
    idx = order[pos]
    out = np.empty((len(values), len(pts)))
    vert = idx < len(P)
    out[:, vert] = values[:, idx[vert]]
    e = E[idx[~vert] - len(P)]
    out[:, ~vert] = 0.5 * (values[:, e[:, 0]] + values[:, e[:, 1]])
    return out


def _locate(mesh, pts):
    """MeshPoints of ``pts`` in a straight-sided triangular mesh, or None if some point is outside.

    NGSolve's ``mesh(xs, ys)`` searches point by point; matplotlib's
    trapezoid-map TriFinder plus barycentric coordinates does the same much
    faster on large meshes.  NGSolve's reference
    triangle has vertices (1,0), (0,1), (0,0), so the local coordinates are
    the first two barycentric coordinates.
    """
    mtri = matplotlib_tri()
    ng = mesh.ngmesh
    P = np.asarray(ng.Coordinates())[:, :2]
    T = ng.Elements2D().NumPy()["nodes"][:, :3].astype(np.int64) - 1
    try:
        el = np.asarray(mtri.Triangulation(P[:, 0], P[:, 1], T).get_trifinder()(pts[:, 0], pts[:, 1]))
    except (RuntimeError, ValueError):  # e.g. a triangulation matplotlib rejects
        return None
    if len(el) and el.min() < 0:
        return None
    A, B, C = P[T[el, 0]], P[T[el, 1]], P[T[el, 2]]
    lam = np.linalg.solve(np.stack([A - C, B - C], axis=-1), (pts - C)[..., None])[..., 0]
    mp = meshpoints(mesh, el, lam[:, 0], lam[:, 1])
    return mp


def _evaluate_at(mesh, cf, pts, mp=None) -> np.ndarray:
    """Values of cf at points (``mp``: their MeshPoints from :func:`_locate`);
    points outside the (curved) mesh get the value 0."""
    if mp is not None:
        return np.asarray(cf(mp)).reshape(-1)
    return evaluate_at_points(mesh, cf, pts)
