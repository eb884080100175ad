"""Broken (per-cell) Lagrange bases P_p(T_h), shared by the HHO and dG discretizations.

:class:`BrokenLagrange` is the per-cell Lagrange nodal basis of P_p(T_h) on an
affine triangular mesh: geometry, lattice nodes, edges, quadrature of data,
conversion to NGSolve ``L2`` GridFunctions.  :class:`BrokenDiscretization` is
what the HHO and dG discretizations have in common on top of it: the
two-membrane problem only, the data checks on the cell nodes, the transfer of
a coarser level's cell polynomials (nested iteration) and the constraint rows
at cell nodes.
"""
from __future__ import annotations

from abc import abstractmethod

import numpy as np
import scipy.sparse as sp
from ngsolve import VOL, CoefficientFunction, GridFunction, IntegrationRule, L2, TRIG, SEGM

from ..domains import INTERFACE
from ..problems.base import check_data_on_points
from ..problems.membranes import TwoMembraneProblem
from .base import Discretization, evaluate_at_points
from .nodesets import lattice, reference_nodes

__all__ = ["BrokenLagrange", "BrokenDiscretization"]

# reference triangle of NGSolve: local vertex 0 -> (1, 0), 1 -> (0, 1), 2 -> (0, 0)
_REF_VERTS = np.array([[1.0, 0.0], [0.0, 1.0], [0.0, 0.0]])
# local edge e is opposite to local vertex e
_LOCAL_EDGES = ((1, 2), (2, 0), (0, 1))


def _quadrature(shape, order: int):
    """NGSolve's integration rule on the reference TRIG (points (n, 2)) or SEGM (points (n,))."""
    ir = IntegrationRule(shape, order)
    pts = np.array([p[:2] if shape == TRIG else p[0] for p in ir.points], dtype=float)
    return pts, np.array(ir.weights, dtype=float)


class BrokenLagrange:
    """Per-cell Lagrange nodal basis of P_p(T_h) on an affine triangular mesh.

    The nodes of cell K are the reference nodes of ``node_set``
    (:func:`ngcontact.discretizations.nodesets.reference_nodes`, labelled by the lattice points
    ``lat``) mapped by x = xi v0 + eta v1 + (1 - xi - eta) v2 (NGSolve's element map).

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

    def __init__(self, mesh, order: int, node_set: str = "positive"):
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
        self.nc = len(self.lat)
        self.ref_nodes = reference_nodes(order, node_set)[:, :2]
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
        self._l2 = self._mref = None  # built on first use

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
        if self._mref is None:
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
        return evaluate_at_points(mesh, cf, P).reshape(self.ne, self.nc)

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



class BrokenDiscretization(Discretization):
    """Common part of the HHO and dG discretizations (cell unknowns in a :class:`BrokenLagrange` basis).

    Subclasses set ``basis`` (a :class:`BrokenLagrange`) and implement :meth:`broken_fields`.
    """

    basis: BrokenLagrange

    def _check_setting(self, label: str, problem, mesh, order: int) -> None:
        """Order, problem and mesh this family supports (``label`` names it in the messages)."""
        if order not in self.orders:
            raise ValueError(f"order must be 1, 2, 3 or 4 for {label}, got {order!r}")
        if not isinstance(problem, TwoMembraneProblem):
            raise ValueError(f"{label} supports the two-membrane problem only, got {type(problem).__name__}")
        if INTERFACE in mesh.GetBoundaries():
            raise ValueError("{}: meshes with an internal '{}' curve (e.g. UnitDisk(interface_radius=...)) "
                             "are supported by disc fem only".format(label, INTERFACE))

    def _check_data(self) -> None:
        """The data checks of :func:`~ngcontact.problems.base.check_data_on_points` at every cell node
        (loads everywhere, Dirichlet data and g1 >= g2 at the nodes on the boundary)."""
        B = self.basis
        values = {name: B.interpolate(cf).ravel() for name, cf in self.problem.data().items()}
        check_data_on_points(self.problem, values, B.node_on_boundary.ravel(), B.coords.reshape(-1, 2))

    @abstractmethod
    def broken_fields(self, x, y):
        """(basis, (U1, U2, lam)): nodal values per cell of u1h, u2h and lam_h."""

    def _coarse_fields(self, previous: Discretization, x, y):
        """(U1, U2, lam) nodal per cell of this basis from a coarser level's solution (x, y): the coarse
        cell polynomials at this mesh's cell nodes (exact on nested meshes), or, from another kind of
        discretization, its GridFunctions evaluated there."""
        B = self.basis
        if isinstance(previous, BrokenDiscretization):
            Bc, fields = previous.broken_fields(x, y)
            return tuple(B.transfer_from(Bc, v) for v in fields)
        gfs = previous.gridfunctions(x, y)
        return tuple(B.values_from(previous.mesh, gfs[n]) for n in self.problem.field_names + ("lam",))
