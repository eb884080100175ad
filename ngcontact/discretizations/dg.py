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
    integrating cell K over F; measured on 6.2.2608).  Default c = 10 for every
    variant.  Measured on the criss-cross mesh T0 (smallest eigenvalue of the
    symmetric part of the matrix): SIPG is positive definite for c >= 3 (p = 1)
    and c >= 1.5 (p = 2..4) and indefinite for c = 2 (p = 1), c = 1 (p >= 2);
    IIPG from c = 1 (p = 1) and c = 0.5 (p = 3); NIPG for every c > 0 tried
    (0.1 .. 10).  c = 10 is a safe margin (tests/test_dg.py checks it).
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
    matrices: their Newton steps go through :class:`DGComplementaritySystem`
    (the base class's reduction with a general sparse LU, scipy's SuperLU);
    SIPG uses the same class with sparse Cholesky.

    :class:`BrokenLagrange` (the per-cell Lagrange basis of P_p(T_h): geometry,
    lattice nodes, edges, quadrature of data, conversion to NGSolve ``L2``
    GridFunctions) is shared with :mod:`ngcontact.discretizations.hho`.
    Meshes are taken as affine (straight) triangles.

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
from ngsolve import (VOL, BilinearForm, CoefficientFunction, GridFunction, Integrate, InnerProduct, IntegrationRule,
                     L2, LinearForm, TaskManager, TRIG, SEGM, ds, dx, grad, specialcf)

from ..algebra.linalg import ngsolve_coo
from ..algebra.system import ComplementaritySystem, StepInfo
from .lagrange import lattice
from ..domains import INTERFACE

__all__ = ["DGDiscretization", "SIPGDiscretization", "NIPGDiscretization", "IIPGDiscretization", "BrokenLagrange",
           "DGComplementaritySystem", "VARIANTS", "ngsolve_coo", "sparse_solve"]

#: theta of the interior penalty variants
VARIANTS = {"sipg": 1.0, "nipg": -1.0, "iipg": 0.0}

# reference triangle of NGSolve: local vertex 0 -> (1, 0), 1 -> (0, 1), 2 -> (0, 0)
_REF_VERTS = np.array([[1.0, 0.0], [0.0, 1.0], [0.0, 0.0]])
# local edge e is opposite to local vertex e
_LOCAL_EDGES = ((1, 2), (2, 0), (0, 1))


def _csr(bf_or_mat) -> sp.csr_matrix:
    mat = getattr(bf_or_mat, "mat", bf_or_mat)
    data, indices, indptr = mat.CSR()
    return sp.csr_matrix((np.array(data), np.array(indices), np.array(indptr)), shape=(mat.height, mat.width))


def _quadrature(shape, order: int):
    """NGSolve's integration rule on the reference TRIG (points (n, 2)) or SEGM (points (n,))."""
    ir = IntegrationRule(shape, order)
    pts = np.array([p[:2] if shape == TRIG else p[0] for p in ir.points], dtype=float)
    return pts, np.array(ir.weights, dtype=float)


class BrokenLagrange:
    """Per-cell Lagrange nodal basis of P_p(T_h) on an affine triangular mesh.

    The nodes of cell K are the lattice points :func:`ngcontact.discretizations.lagrange.lattice`
    mapped by x = xi v0 + eta v1 + (1 - xi - eta) v2 (NGSolve's element map).

    Attributes
    ----------
    p, nc, ne : int
        order, nodes per cell ((p+1)(p+2)/2), number of cells.
    verts : ndarray (ne, 3, 2)
        vertex coordinates in NGSolve's local order.
    detJ, hK : ndarray (ne,)
        |det| of the element map (= 2 |K|), cell diameter.
    invJT : ndarray (ne, 2, 2)
        J^{-T}: physical gradient = invJT @ reference gradient.
    coords : ndarray (ne, nc, 2)
        node coordinates.
    edges : ndarray (nE, 2)
        global edges as sorted vertex pairs; ``cell_edges`` (ne, 3) the edge of
        local edge e (opposite local vertex e); ``edge_orient`` (ne, 3) True if
        the cell runs through edge e from its smaller to its larger vertex
        number; ``bnd_edge`` (nE,) boundary edges.
    node_on_boundary : ndarray (ne, nc) bool
        node lies on the domain boundary.
    """

    def __init__(self, mesh, order: int):
        ngmesh = mesh.ngmesh
        elems = ngmesh.Elements2D().NumPy()
        if np.any(elems["type"] != 10):  # netgen TRIG (straight, 3 nodes)
            raise ValueError("broken P_p discretizations need a mesh of (straight) triangles")
        self.mesh, self.p = mesh, order
        self.el = el = (elems["nodes"][:, :3] - 1).astype(np.int64)
        self.ne = ne = len(el)
        pts = np.asarray(ngmesh.Coordinates())[:, :2]
        self.verts = V = pts[el]
        J = np.stack([V[:, 0] - V[:, 2], V[:, 1] - V[:, 2]], axis=-1)  # columns: d x / d xi, d x / d eta
        det = J[:, 0, 0] * J[:, 1, 1] - J[:, 0, 1] * J[:, 1, 0]
        self.detJ = np.abs(det)
        self.invJT = np.linalg.inv(J).transpose(0, 2, 1)
        self.hK = np.sqrt(((V - np.roll(V, 1, axis=1)) ** 2).sum(-1)).max(axis=1)

        # reference Lagrange basis: phi_i = sum_j C[j, i] m_j, monomials m_j = xi^a eta^b
        self.lat = lattice(order)
        self.nc = nc = len(self.lat)
        self.ref_nodes = self.lat[:, :2] / order
        self.exponents = np.array([(a, b) for a in range(order + 1) for b in range(order + 1 - a)])
        self._C = np.linalg.inv(self._monomials(self.ref_nodes))
        self.coords = self.map_points(self.ref_nodes)

        # edges
        loc = np.array(_LOCAL_EDGES)
        ends = el[:, loc]  # (ne, 3, 2)
        lo, hi = ends.min(-1), ends.max(-1)
        keys = lo * (pts.shape[0] + 1) + hi
        uniq, inv = np.unique(keys.ravel(), return_inverse=True)
        self.cell_edges = inv.reshape(ne, 3)
        self.nE = len(uniq)
        first = np.zeros(self.nE, dtype=np.int64)
        first[inv[::-1]] = np.arange(3 * ne)[::-1]  # a (cell, local edge) slot of every edge
        self.edges = np.stack([lo.ravel()[first], hi.ravel()[first]], axis=1)
        self.bnd_edge = np.bincount(inv, minlength=self.nE) == 1
        order_ = np.argsort(inv, kind="stable")  # (cell, local edge) slots k*3+e grouped by edge
        self.edge_slots = np.full((self.nE, 2), -1, dtype=np.int64)
        starts = np.searchsorted(inv[order_], np.arange(self.nE))
        self.edge_slots[:, 0] = order_[starts]
        inner = ~self.bnd_edge
        self.edge_slots[inner, 1] = order_[starts[inner] + 1]
        self.edge_orient = ends[:, :, 0] < ends[:, :, 1]
        # edge lengths and outward unit normals per cell and local edge
        xa, xb = V[:, loc[:, 0]], V[:, loc[:, 1]]
        t = xb - xa
        self.edge_len = np.sqrt((t ** 2).sum(-1))
        nrm = np.stack([t[..., 1], -t[..., 0]], axis=-1) / self.edge_len[..., None]
        outward = ((xa - V) * nrm).sum(-1) > 0  # opposite vertex of edge e is vertex e
        self.normals = np.where(outward[..., None], nrm, -nrm)
        # nodes on the boundary: on a boundary edge, or a boundary vertex
        bvert = np.zeros(pts.shape[0], dtype=bool)
        bvert[self.edges[self.bnd_edge].ravel()] = True
        on_edge = (self.lat[None, :, :] == 0) & self.bnd_edge[self.cell_edges][:, None, :]
        at_vertex = (self.lat[None, :, :] == order) & bvert[el][:, None, :]
        self.node_on_boundary = (on_edge | at_vertex).any(-1)
        self._l2 = None

    # ---------------------------------------------------------- reference basis
    def _monomials(self, ref_pts, deriv=None) -> np.ndarray:
        xi, eta = np.asarray(ref_pts, float)[:, 0:1], np.asarray(ref_pts, float)[:, 1:2]
        a, b = self.exponents[:, 0], self.exponents[:, 1]
        with np.errstate(divide="ignore", invalid="ignore"):
            if deriv is None:
                return xi ** a * eta ** b
            if deriv == 0:
                return np.where(a > 0, a * xi ** np.maximum(a - 1, 0), 0.0) * eta ** b
            return xi ** a * np.where(b > 0, b * eta ** np.maximum(b - 1, 0), 0.0)

    def shape(self, ref_pts) -> np.ndarray:
        """phi_i at reference points: (npts, nc)."""
        return self._monomials(ref_pts) @ self._C

    def dshape(self, ref_pts) -> np.ndarray:
        """Reference gradients of phi_i: (npts, nc, 2)."""
        return np.stack([self._monomials(ref_pts, 0) @ self._C, self._monomials(ref_pts, 1) @ self._C], axis=-1)

    def map_points(self, ref_pts) -> np.ndarray:
        """Physical coordinates (ne, npts, 2) of reference points in every cell."""
        r = np.asarray(ref_pts, float)
        lam = np.stack([r[:, 0], r[:, 1], 1 - r[:, 0] - r[:, 1]], axis=1)
        return np.einsum("qv,kvd->kqd", lam, self.verts)

    def edge_ref_points(self, s) -> np.ndarray:
        """Reference points (6, ns, 2) of the edge parameter s in [0, 1], for the 6
        configurations 2 e + o (local edge e; o = 1: s runs from the edge's first to its
        second local vertex, o = 0: reversed).  s always runs from the smaller to
        the larger global vertex number, so both cells of an edge see the same points."""
        s = np.asarray(s, float)
        out = np.empty((6, len(s), 2))
        for e, (i0, i1) in enumerate(_LOCAL_EDGES):
            a, b = _REF_VERTS[i0], _REF_VERTS[i1]
            out[2 * e + 1] = a + s[:, None] * (b - a)
            out[2 * e] = b + s[:, None] * (a - b)
        return out

    @property
    def edge_config(self) -> np.ndarray:
        """Configuration index 2 e + o (ne, 3) of every cell's local edges."""
        return 2 * np.arange(3)[None, :] + self.edge_orient.astype(np.int64)

    def edge_shapes(self, s) -> np.ndarray:
        """phi_i at the edge parameters s for every cell and local edge: (ne, 3, ns, nc)."""
        cfg = np.stack([self.shape(r) for r in self.edge_ref_points(s)])  # (6, ns, nc)
        return cfg[self.edge_config]

    def edge_evaluate(self, cf, s) -> np.ndarray:
        """Values (ne, 3, ns) of a CoefficientFunction at the edge parameters s of every cell edge."""
        pts = self.edge_ref_points(s)  # (6, ns, 2)
        vals = self.evaluate(cf, pts.reshape(-1, 2)).reshape(self.ne, 6, len(s))
        return np.take_along_axis(vals, self.edge_config[:, :, None], axis=1)

    def jump_seminorm2(self, nodal, g=None, quad_order=None) -> float:
        """sum_F |F|^-1 ||[v]||_F^2 (interior edges) + sum_F |F|^-1 ||v - g||_F^2 (boundary edges)
        for v with nodal values (ne, nc); computed from pointwise traces (no cancellation)."""
        s, w = _quadrature(SEGM, quad_order or 2 * self.p)
        tr = np.einsum("kesi,ki->kes", self.edge_shapes(s), np.reshape(nodal, (self.ne, self.nc))).reshape(-1, len(s))
        if g is not None:
            tr = tr - self.edge_evaluate(g, s).reshape(-1, len(s))
        a, b = self.edge_slots[:, 0], self.edge_slots[:, 1]
        jump = np.where((b >= 0)[:, None], tr[a] - tr[np.maximum(b, 0)], tr[a])
        # on interior edges g cancels in the difference of the two traces
        return float((jump ** 2 @ w).sum())

    @property
    def mass_ref(self) -> np.ndarray:
        """(phi_i, phi_j) on the reference triangle; M_K = detJ_K * mass_ref."""
        if not hasattr(self, "_mref"):
            q, w = _quadrature(TRIG, 2 * self.p)
            phi = self.shape(q)
            self._mref = np.einsum("q,qi,qj->ij", w, phi, phi)
        return self._mref

    # ------------------------------------------------------------------ data
    def evaluate(self, cf, ref_pts, dim: int = 1) -> np.ndarray:
        """Values (ne, npts[, dim]) of a CoefficientFunction at reference points of every cell."""
        r = np.asarray(ref_pts, float)
        ir = IntegrationRule([tuple(q) for q in r], [0.0] * len(r))
        vals = np.asarray(CoefficientFunction(cf)(self.mesh.MapToAllElements(ir, VOL)), dtype=float)
        return vals.reshape((self.ne, len(r)) + ((dim,) if dim > 1 else ()))

    def load(self, f, quad_order: int) -> np.ndarray:
        """(f, phi_{K,i})_K: (ne, nc)."""
        q, w = _quadrature(TRIG, quad_order)
        return self.detJ[:, None] * (self.evaluate(f, q) * w) @ self.shape(q)

    def interpolate(self, cf) -> np.ndarray:
        """Nodal values (ne, nc) of a CoefficientFunction (cell by cell)."""
        return self.evaluate(cf, self.ref_nodes)

    def transfer_from(self, other: "BrokenLagrange", nodal) -> np.ndarray:
        """Nodal values (ne, nc) on this mesh of the piecewise polynomial with nodal values
        ``nodal`` (ne_other, nc_other) on a coarser nested mesh: each cell is located in the
        coarse cell containing its centroid, whose polynomial is evaluated at the cell's
        nodes (exact for nested meshes)."""
        c = self.coords.mean(axis=1)
        elem = np.asarray(other.mesh(c[:, 0], c[:, 1])["nr"], dtype=np.int64)
        if np.any(elem < 0):
            raise ValueError("transfer_from: a cell centroid lies outside the other mesh (meshes not nested)")
        V = other.verts[elem]  # (ne, 3, 2)
        J = np.stack([V[:, 0] - V[:, 2], V[:, 1] - V[:, 2]], axis=-1)
        ref = np.linalg.solve(J[:, None], (self.coords - V[:, None, 2])[..., None])[..., 0]  # (ne, nc, 2)
        phi = other.shape(ref.reshape(-1, 2)).reshape(self.ne, self.nc, other.nc)
        return np.einsum("kli,ki->kl", phi, np.reshape(nodal, (other.ne, other.nc))[elem])

    def values_from(self, mesh, cf, shrink: float = 1e-6) -> np.ndarray:
        """Nodal values (ne, nc) of a CoefficientFunction living on another mesh (fallback of
        :meth:`transfer_from` for other discretizations).  Nodes are pulled towards the cell
        centroid by ``shrink`` (relative) so that a discontinuous function is mostly evaluated
        in the coarse cell containing this cell (approximate: point location has a tolerance)."""
        c = self.coords.mean(axis=1, keepdims=True)
        P = (self.coords + shrink * (c - self.coords)).reshape(-1, 2)
        try:
            vals = np.asarray(cf(mesh(P[:, 0], P[:, 1])), dtype=float).reshape(-1)
        except Exception:  # a point outside the other mesh (curved boundary): one by one
            vals = np.zeros(len(P))
            for i, (px, py) in enumerate(P):
                try:
                    vals[i] = cf(mesh(px, py))
                except Exception:
                    vals[i] = 0.0
        return vals.reshape(self.ne, self.nc)

    # --------------------------------------------------- NGSolve L2 interface
    @property
    def l2(self):
        """NGSolve ``L2(order=p)`` and the values V (ne, nc, nc) of its basis at the nodes."""
        if self._l2 is None:
            fes = L2(self.mesh, order=self.p)
            nc, ne = self.nc, self.ne
            if fes.ndof != ne * nc or tuple(fes.GetDofNrs(self.mesh[_elid(ne - 1)])) != tuple(
                    range((ne - 1) * nc, ne * nc)):
                raise RuntimeError("unexpected NGSolve L2 dof numbering (expected element-wise blocks)")
            gf = GridFunction(fes)
            vec = gf.vec.FV().NumPy()
            V = np.empty((ne, nc, nc))
            for j in range(nc):
                vec[:] = 0.0
                vec[j::nc] = 1.0
                V[:, :, j] = self.evaluate(gf, self.ref_nodes)
            self._l2 = (fes, V, np.linalg.inv(V))
        return self._l2

    def to_l2_matrix(self) -> sp.bsr_matrix:
        """T (block diagonal): L2 coefficients = T @ nodal values."""
        fes, V, Vinv = self.l2
        return sp.bsr_matrix((Vinv, np.arange(self.ne), np.arange(self.ne + 1)),
                             shape=(self.ne * self.nc,) * 2)

    def gridfunction(self, nodal, name: str = "u") -> GridFunction:
        """L2 GridFunction of the nodal values (ne, nc) (or flat)."""
        fes, V, Vinv = self.l2
        gf = GridFunction(fes, name=name)
        gf.vec.FV().NumPy()[:] = np.einsum("kij,kj->ki", Vinv, np.reshape(nodal, (self.ne, self.nc))).ravel()
        return gf

    def dual_to_nodal(self, y) -> np.ndarray:
        """Nodal values of lam_h = sum_l y_l Theta_l (Theta dual to the nodal basis): M_K^{-1} y."""
        Y = np.reshape(y, (self.ne, self.nc))
        return np.linalg.solve(self.mass_ref, Y.T).T / self.detJ[:, None]

    def nodal_to_dual(self, lam_nodal) -> np.ndarray:
        """Moments (lam_h, phi_{K,l})_K = M_K lam_nodal."""
        return (np.reshape(lam_nodal, (self.ne, self.nc)) @ self.mass_ref) * self.detJ[:, None]


def _elid(i):
    from ngsolve import ElementId

    return ElementId(VOL, int(i))


# ---------------------------------------------------------------------------
class DGComplementaritySystem(ComplementaritySystem):
    """:class:`ComplementaritySystem` whose Newton steps allow a non-symmetric K (NIPG, IIPG).

    The linearization and its reduction are those of the base class (module
    doc of :mod:`ngcontact.algebra.system`): on equality rows the slave
    unknown is eliminated, x = Z z + x_aff; fixed rows move y' to the
    right-hand side; mixed rows add B_m^T diag(D w) B_m.  Z^T B^T e_l = 0 on
    equality rows, so Z^T (K x - B^T D y' - F) = 0 is free of the unknown
    multipliers whether K is symmetric or not; only the solver changes:
    ``factorization='umfpack'`` (NGSolve's UMFPACK) or ``'splu'`` (scipy's
    SuperLU) for a non-symmetric K, ``'sparsecholesky'`` for SIPG.  The
    equality multipliers come from the slave rows afterwards, as in the base
    class.  The NGSolve matrix is built by :func:`ngsolve_coo` (~20x faster
    than passing numpy arrays to ``CreateFromCOO``).
    """

    factorization: str = "umfpack"

    def newton_step(self, x, y, C, Ca, Cb, eps: float = 1e-12):
        t0 = time.perf_counter()
        n, m, D, b, B = self.n, self.m, self.D, self.b, self._B
        g = self.gap(x)
        aCa, aCb = np.abs(Ca), np.abs(Cb)
        eq = aCb <= eps * aCa
        fixed = ~eq & (aCa <= eps * aCb)
        mixed = ~eq & ~fixed
        safe = lambda den, mask: np.where(mask, den, 1.0)  # noqa: E731
        y_new = np.where(fixed, y - C / safe(Cb, fixed), 0.0)
        w = np.where(mixed, Ca / safe(Cb, mixed), 0.0)  # mixed: y' = c0 - w g(x')
        c0 = np.where(mixed, y - C / safe(Cb, mixed) + w * g, 0.0)
        target = np.where(eq, g - C / safe(Ca, eq) + b, 0.0)  # equality rows: (B x')_l = target_l

        rhs = self.F + B.T @ (D * (y_new + c0))
        Kaug = self.K
        if mixed.any():
            Bm = sp.diags(mixed.astype(float)) @ B
            Kaug = (Kaug + Bm.T @ sp.diags(D * w) @ Bm).tocsr()
            rhs = rhs + Bm.T @ (D * w * b)
        rows = np.flatnonzero(eq)
        two = self.lo[rows] >= 0
        slaves = np.where(two, self.lo[rows], self.up[rows])
        keep = np.ones(n, dtype=bool)
        keep[slaves] = False
        red = np.full(n, -1, dtype=np.int64)
        red[keep] = np.arange(keep.sum())
        nr = int(keep.sum())
        # x_lo = x_up - target (two-sided rows), x_up = target (one-sided rows)
        zr = np.concatenate([np.flatnonzero(keep), slaves[two]])
        zc = np.concatenate([np.arange(nr), red[self.up[rows][two]]])
        Z = sp.csr_matrix((np.ones(len(zr)), (zr, zc)), shape=(n, nr))
        x_aff = np.zeros(n)
        x_aff[slaves] = np.where(two, -target[rows], target[rows])
        Ared = (Z.T @ Kaug @ Z).tocsr()
        bred = Z.T @ (rhs - Kaug @ x_aff)
        t1 = time.perf_counter()
        z = sparse_solve(Ared, bred, self.factorization)
        t2 = time.perf_counter()
        x_new = Z @ z + x_aff
        y_new[mixed] = c0[mixed] - w[mixed] * (B @ x_new - b)[mixed]
        if len(rows):
            r = self.K @ x_new - B.T @ (D * np.where(eq, 0.0, y_new)) - self.F
            y_new[rows] = r[slaves] / (np.where(two, -1.0, 1.0) * D[rows])
        return x_new, y_new, StepInfo(nr, (t1 - t0) + (time.perf_counter() - t2), t2 - t1)


def _assemble_load(fes, integrand) -> np.ndarray:
    """Assembled linear form; zero if NGSolve folds the integrand to 0 (zero data)."""
    try:
        lf = LinearForm(integrand())
        with TaskManager():
            lf.Assemble()
    except Exception as exc:  # "Linearform must have TestFunction" for 0 * v
        if "TestFunction" not in str(exc):
            raise
        return np.zeros(fes.ndof)
    return np.array(lf.vec.FV().NumPy())


def sparse_solve(A: sp.spmatrix, b: np.ndarray, method: str) -> np.ndarray:
    """Solve A z = b: 'sparsecholesky' (A SPD), 'umfpack' (NGSolve, general) or 'splu' (scipy, general)."""
    if A.shape[0] == 0:
        return np.zeros(0)
    if method == "splu":
        import scipy.sparse.linalg as spla

        return spla.splu(sp.csc_matrix(A), permc_spec="MMD_AT_PLUS_A").solve(np.asarray(b, float))
    if method not in ("sparsecholesky", "umfpack"):
        raise ValueError(f"factorization must be 'sparsecholesky', 'umfpack' or 'splu', got {method!r}")
    coo = A.tocoo()
    mat = ngsolve_coo(coo.row, coo.col, coo.data, A.shape[0], A.shape[1])
    inv = mat.Inverse(inverse=method)
    rv, sv = mat.CreateRowVector(), mat.CreateColVector()
    rv.FV().NumPy()[:] = b
    sv.data = inv * rv
    return np.array(sv.FV().NumPy())


# ---------------------------------------------------------------------------
class DGDiscretization:
    """Interior penalty dG (SIPG / NIPG / IIPG) for the two-membrane problem (module doc).

    Parameters
    ----------
    problem : TwoMembraneProblem
    mesh : ngsolve.Mesh (straight triangles)
    order : int, 1..4
    solver : str
        'sparsecholesky' (default): sparse Cholesky for SIPG; 'scipy': SuperLU.
        NIPG/IIPG use NGSolve's UMFPACK (solver 'sparsecholesky', the default)
        or scipy's SuperLU with the MMD(A^T + A) ordering (solver 'scipy').
        Measured on the NIPG P4 matrix of test 1, one factorization + solve:
        1.2e5 unknowns UMFPACK 1.85 s, SuperLU-MMD 2.75 s, SuperLU-COLAMD
        (scipy's default ordering) 11.5 s; 3e4 unknowns 0.39 / 0.28 / 0.72 s.
        No ordering wins everywhere: on the NIPG P1 matrix at 1e5 unknowns
        UMFPACK took 23 s, SuperLU-COLAMD 5.7 s, SuperLU-MMD 306 s (3.6 s in
        SymmetricMode without pivoting).  A general sparse LU is the
        bottleneck of NIPG/IIPG; SIPG (Cholesky) does not have it.
    variant : 'sipg' | 'nipg' | 'iipg'
    penalty : float, optional
        c in sigma_F = c p^2 / h (default 10).
    quad_bonus : int
        extra quadrature order for data and errors.
    """

    name = "dg"
    orders = (1, 2, 3, 4)
    default_penalty = 10.0

    def __init__(self, problem, mesh, order: int = 1, solver: str = "sparsecholesky", variant: str = "sipg",
                 penalty=None, quad_bonus: int = 6):
        if order not in self.orders:
            raise ValueError(f"order must be 1, 2, 3 or 4 for dg, got {order!r}")
        if variant not in VARIANTS:
            raise ValueError(f"variant must be one of {sorted(VARIANTS)}, got {variant!r}")
        if INTERFACE in mesh.GetBoundaries():
            raise ValueError("dg: meshes with an internal '{}' curve (e.g. UnitDisk(interface_radius=...)) "
                             "are supported by disc fem only".format(INTERFACE))
        if getattr(problem, "kind", None) != "membranes":
            raise ValueError(f"dg supports the two-membrane problem only, got {type(problem).__name__}")
        c = self.default_penalty if penalty is None else float(penalty)
        if not np.isfinite(c) or c <= 0:
            raise ValueError(f"penalty must be a positive number, got {penalty!r}")
        t0 = time.perf_counter()
        self.problem, self.mesh, self.order, self.variant = problem, mesh, order, variant
        self.name = variant
        self.theta, self.penalty, self.quad_bonus = VARIANTS[variant], c, quad_bonus
        self.basis = B = BrokenLagrange(mesh, order)
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
        self.A = (T.T @ _csr(a) @ T).tocsr()
        # F_a = (f_a, v) + mu_a [-theta (g_a, grad v.n) + (sigma g_a, v)]_bnd: the Nitsche
        # terms belong to mu_a A_h and scale with mu_a like it
        bonus = dict(bonus_intorder=quad_bonus)
        F = []
        for mu, f, gd in zip(problem.mus, (problem.f1, problem.f2), (problem.g1, problem.g2)):
            Ff = _assemble_load(fes, lambda: f * v * dx(**bonus))
            Fg = _assemble_load(fes, lambda: (-th * gd * grad(v) * nrm + sigma * gd * v) * ds(skeleton=True, **bonus))
            F.append(T.T @ (Ff + mu * Fg))
        self.n1 = n1 = ne * nc
        mu1, mu2 = problem.mus
        K = sp.block_diag([mu1 * self.A, mu2 * self.A], format="csr")
        F = np.concatenate(F)
        cons = ~B.node_on_boundary.ravel()
        self.constrained = np.flatnonzero(cons)  # (cell * nc + node) of each constraint row
        m = len(self.constrained)
        up, lo = self.constrained, n1 + self.constrained
        self.system = DGComplementaritySystem(K, F, up, lo, np.zeros(m), np.ones(m), solver=solver)
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

    def prolongate(self, previous, x, y):
        """Nested iteration: the coarse cell polynomials at this mesh's cell nodes (exact on
        nested meshes) and the moments of the coarse lam_h against the fine nodal basis."""
        B = self.basis
        fields = previous.broken_fields(x, y) if hasattr(previous, "broken_fields") else None
        if fields is not None and isinstance(fields[0], BrokenLagrange):
            Bc, (U1, U2, lam) = fields
            U1, U2, lam = (B.transfer_from(Bc, v) for v in (U1, U2, lam))
        else:  # another kind of discretization: evaluate its GridFunctions
            gfs = previous.gridfunctions(x, y)
            U1, U2, lam = (B.values_from(previous.mesh, gfs[n]) for n in ("u1", "u2", "lam"))
        x0 = np.concatenate([U1.ravel(), U2.ravel()])
        y0 = B.nodal_to_dual(lam).ravel()[self.constrained]
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
        X1, X2 = self._split(x)
        Y = np.zeros(self.n1)
        Y[self.constrained] = y
        out = {"u1": self.basis.gridfunction(X1, "u1"), "u2": self.basis.gridfunction(X2, "u2"),
               "lam": self.basis.gridfunction(self.basis.dual_to_nodal(Y), "lam")}
        out["gap"] = out["u1"] - out["u2"]
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
        for a, (name, mu, gd, uex) in enumerate(zip(("u1", "u2"), self.problem.mus, (self.problem.g1, self.problem.g2),
                                                    (ex.u1, ex.u2))):
            d = ex.gradient(a + 1) - grad(gfs[name])
            e2 += mu * Integrate(InnerProduct(d, d), self.mesh, order=order)
            X = x[a * self.n1:(a + 1) * self.n1]
            j2 += mu * self.basis.jump_seminorm2(X, gd, order)
            emax = max(emax, float(np.abs(self.basis.interpolate(uex).ravel() - X).max()))
        return {"err_energy": float(np.sqrt(max(e2, 0.0))), "err_jump": float(np.sqrt(max(j2, 0.0))),
                "err_max_nodal": emax}

    def contact_points(self, x, y) -> np.ndarray:
        """Coordinates (k, 2) of the constrained nodes in the discrete contact set (gap <= X3)."""
        pts = self.basis.coords.reshape(-1, 2)[self.constrained]
        return pts[self.system.gap(x) <= y]

    def complementarity(self, x, y) -> dict:
        """Min gap, min X3, max |gap * X3| over the constraint rows."""
        g = self.system.gap(x)
        return {"gap_min": float(g.min(initial=0.0)), "lam_min": float(y.min(initial=0.0)),
                "product_max": float(np.max(np.abs(g * y), initial=0.0))}


class SIPGDiscretization(DGDiscretization):
    """:class:`DGDiscretization` with ``variant='sipg'`` (theta = 1), for the registry."""

    name = "sipg"

    def __init__(self, problem, mesh, order: int = 1, solver: str = "sparsecholesky", penalty=None, **kw):
        super().__init__(problem, mesh, order, solver, variant="sipg", penalty=penalty, **kw)


class NIPGDiscretization(DGDiscretization):
    """:class:`DGDiscretization` with ``variant='nipg'`` (theta = -1), for the registry."""

    name = "nipg"

    def __init__(self, problem, mesh, order: int = 1, solver: str = "sparsecholesky", penalty=None, **kw):
        super().__init__(problem, mesh, order, solver, variant="nipg", penalty=penalty, **kw)


class IIPGDiscretization(DGDiscretization):
    """:class:`DGDiscretization` with ``variant='iipg'`` (theta = 0), for the registry."""

    name = "iipg"

    def __init__(self, problem, mesh, order: int = 1, solver: str = "sparsecholesky", penalty=None, **kw):
        super().__init__(problem, mesh, order, solver, variant="iipg", penalty=penalty, **kw)
