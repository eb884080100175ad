"""Lagrange nodes and the change of basis hierarchical H1 <-> nodal P_p.

NGSolve's ``H1(order=p)`` basis is hierarchical (hat functions, edge and
cell bubbles).  The contact constraints of [CAMWA21] live at the Lagrange
nodes x_l and the multiplier is expanded in the basis dual to the Lagrange
basis (seed slides "Discrete complementarity problem", "Matrix
representation").  This module builds, for a triangular mesh and an H1
space,

* the Lagrange nodes of every element (a node set of :mod:`ngcontact.discretizations.nodesets`,
  labelled by the lattice points), deduplicated, numbered
  like the H1 dofs (entity by entity: a vertex node gets the vertex dof's
  number, the k-th node of an edge the k-th dof of that edge, ...), so that
  NGSolve's ``FreeDofs()`` marks the interior nodes directly;
* the sparse evaluation matrix ``V`` (nodal values = V @ coefficients),
  exact because it is built from ``CalcShape`` of the element itself;
* its sparse inverse ``T`` (coefficients = T @ nodal values).  Column l of
  ``T`` holds the hierarchical coefficients of the Lagrange basis function
  psi_l, hence ``T.T @ A @ T`` is the matrix of a form in the Lagrange basis.

``V`` is block lower triangular with respect to the entity levels vertex <
edge < cell (edge bubbles vanish at vertices, cell bubbles on edges), so
with ``V = Dg + L`` (``Dg`` its entity-diagonal blocks) and the nilpotent
``N = Dg^{-1} L`` (N^3 = 0) one has ``V^{-1} = (I - N + N^2) Dg^{-1}``,
sparse and local.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp
from ngsolve import BND, VOL, CoefficientFunction, ElementId, IntegrationRule, x, y

from .base import element_dofs
from .nodesets import lattice, reference_nodes

__all__ = ["LagrangeNodes", "lattice", "meshpoints"]


# local edges of an NGSolve triangle, as pairs of local vertices
_TRIG_EDGES = ((0, 2), (1, 2), (0, 1))


@dataclass
class LagrangeNodes:
    """Lagrange nodes of an H1 space of order p on a triangular mesh.

    Attributes
    ----------
    V : scipy.sparse.csr_matrix
        nodal values = V @ H1 coefficients (square, ndof x ndof).
    T : scipy.sparse.csr_matrix
        H1 coefficients = T @ nodal values (T = V^{-1}).
    coords : ndarray (ndof, 2)
        physical coordinates of node l (node numbering = dof numbering).
    level : ndarray (ndof,)
        0 vertex node, 1 edge node, 2 cell node.
    """

    V: sp.csr_matrix
    T: sp.csr_matrix
    coords: np.ndarray
    level: np.ndarray
    _points: np.ndarray = None  # MeshPoints of the nodes (numbered by dof)
    # element tables: H1 dofs (ne, npts) in NGSolve's local order, node of every lattice point (ne, npts),
    # and the (element, lattice point) that represents each node (kept for other bases on the same nodes)
    elem_dofs: np.ndarray = None
    elem_nodes: np.ndarray = None
    rep: tuple = None
    _mesh: object = None  # with _points None: the MeshPoints are made on each evaluation (P1: not kept)
    _ref: np.ndarray = None  # reference coordinates of the lattice points (node j_of of element e_of)
    # P1 on an ArrayMesh before its NGSolve mesh exists: MeshPoints of the nodes elsewhere (where -> MeshPoints,
    # domains.ArrayMesh.vertex_location), for data of the coordinates only; None once the mesh is attached
    _points_of: object = None

    @classmethod
    def from_p1_tables(cls, fes, X: np.ndarray, T: np.ndarray) -> "LagrangeNodes":
        """The nodes of ``fes = H1(mesh, order=1)`` from the vertex arrays (X, T) of
        :func:`~ngcontact.discretizations.p1.p1_tables`: the same nodes, numbering, element tables and
        MeshPoints as :meth:`build`, with the netgen vertices as coordinates (:meth:`build` maps the reference
        vertices, which can round differently by 1e-17), and without keeping the MeshPoints (they are made
        on each :meth:`evaluate`)."""
        return cls._p1(fes.ndof, X, T, mesh=fes.mesh)

    @classmethod
    def from_arrays(cls, X: np.ndarray, T: np.ndarray, points_of) -> "LagrangeNodes":
        """The nodes of P1 on the vertex arrays (X, T) of an :class:`~ngcontact.domains.ArrayMesh` before its
        NGSolve mesh exists (the nodes of :meth:`from_p1_tables` on that mesh); :meth:`evaluate` uses the
        MeshPoints ``points_of(where)`` until :meth:`attach` gives the mesh."""
        return cls._p1(len(X), X, T, points_of=points_of)

    def attach(self, mesh) -> None:
        """Evaluate on ``mesh`` (the NGSolve mesh of the arrays of :meth:`from_arrays`) from now on."""
        self._mesh, self._points_of = mesh, None

    @classmethod
    def _p1(cls, ndof: int, X, T, mesh=None, points_of=None) -> "LagrangeNodes":
        lat = lattice(1)
        perm = [int(np.flatnonzero(b)[0]) for b in lat]  # local vertex of lattice point j
        node = T[:, ::-1] if perm == [2, 1, 0] else T[:, perm]  # a view for NGSolve's lattice order
        first = np.full(ndof, -1, dtype=np.int64)
        first[node.ravel()] = np.arange(node.size)
        if (first < 0).any():
            raise ValueError(f"found {int((first >= 0).sum())} Lagrange nodes for {ndof} H1 dofs")
        V = sp.identity(ndof, format="csr")
        return cls(V=V, T=V, coords=X, level=np.zeros(ndof, dtype=np.int8), elem_dofs=T, elem_nodes=node,
                   rep=tuple(np.divmod(first, 3)), _mesh=mesh, _ref=reference_nodes(1, "positive"),
                   _points_of=points_of)

    @classmethod
    def build(cls, fes, node_set: str = "positive") -> "LagrangeNodes":
        """Build nodes, evaluation matrix and its inverse for ``fes = H1(mesh, order=p)``.

        ``node_set``: the reference nodes (:func:`~ngcontact.discretizations.nodesets.reference_nodes`,
        'positive' or 'equispaced'); their labels are the lattice points of ``lattice(p)``."""
        mesh = fes.mesh
        p = fes.globalorder
        lat = lattice(p)
        ref = reference_nodes(p, node_set)  # barycentric coordinates of the node of lattice point j
        npts = len(lat)
        ne = mesh.ne
        ndof = fes.ndof
        ndof_loc = (p + 1) * (p + 2) // 2
        if npts != ndof_loc:  # pragma: no cover - guards non-standard spaces
            raise ValueError(f"H1 space of order {p} has {ndof_loc} local dofs, lattice {npts}")

        dofs, verts = _element_tables(fes, ne, ndof_loc)
        if ne and dofs.min() < 0:
            raise ValueError("H1 space has unused (-1) dofs: compress or use a full space")

        # --- node number (= dof number) of every (element, lattice point)
        node = np.empty((ne, npts), dtype=np.int64)
        level = np.empty(ndof, dtype=np.int8)
        nb = p - 1  # nodes per edge
        cell_counter = 0
        for j, b in enumerate(lat):
            nz = np.flatnonzero(b)
            if len(nz) == 1:  # vertex node
                node[:, j] = dofs[:, nz[0]]
                level[dofs[:, nz[0]]] = 0
            elif len(nz) == 2:  # edge node
                a, c = nz
                k = _TRIG_EDGES.index((a, c)) if (a, c) in _TRIG_EDGES else _TRIG_EDGES.index((c, a))
                ea, eb = _TRIG_EDGES[k]
                edofs = np.sort(dofs[:, 3 + k * nb: 3 + (k + 1) * nb], axis=1)
                # position along the edge counted from its smaller global vertex
                w_big = np.where(verts[:, ea] > verts[:, eb], b[ea], b[eb])
                node[:, j] = edofs[np.arange(ne), w_big - 1]
                level[node[:, j]] = 1
            else:  # cell node
                cdofs = np.sort(dofs[:, 3 + 3 * nb:], axis=1)
                node[:, j] = cdofs[:, cell_counter]
                level[node[:, j]] = 2
                cell_counter += 1

        # --- keep one (element, point) per node, any one: values agree by continuity
        # (a scatter instead of np.unique: no sort of the 3 ne (element, point) pairs)
        flat_node = node.ravel()
        first = np.full(ndof, -1, dtype=np.int64)
        first[flat_node] = np.arange(len(flat_node))
        if (first < 0).any():
            raise ValueError(f"found {int((first >= 0).sum())} Lagrange nodes for {ndof} H1 dofs")
        e_of, j_of = np.divmod(first, npts)
        if p == 1:  # NGSolve's P1 shapes are the barycentric coordinates: nodal already
            V = sp.identity(ndof, format="csr")
        else:
            # --- local shape values per vertex-order class (shapes depend on it only)
            cls_id = _order_class(verts)
            vloc = np.empty((ne, npts, ndof_loc))
            for c in np.unique(cls_id):
                rep = int(np.flatnonzero(cls_id == c)[0])
                fe = fes.GetFE(ElementId(VOL, rep))
                block = np.array([np.asarray(fe.CalcShape(b[0], b[1])) for b in ref])
                vloc[cls_id == c] = block
            rows = np.repeat(np.arange(ndof), ndof_loc)
            cols = dofs[e_of].ravel()
            vals = vloc[e_of, j_of].ravel()
            keep = np.abs(vals) > 1e-13
            V = sp.csr_matrix((vals[keep], (rows[keep], cols[keep])), shape=(ndof, ndof))

        # --- one MeshPoint per node (its element e_of, reference point ref[j_of]): coordinates and
        # data are evaluated at ndof points, not at the ne * npts points of MapToAllElements
        points = meshpoints(mesh, e_of, ref[j_of, 0], ref[j_of, 1])
        coords = np.stack([np.asarray(x(points)).ravel(), np.asarray(y(points)).ravel()], axis=1)

        T = V if p == 1 else _block_triangular_inverse(V, dofs, level, p)
        return cls(V=V, T=T, coords=coords, level=level, _points=points, elem_dofs=dofs, elem_nodes=node,
                   rep=(e_of, j_of))

    @property
    def ndof(self) -> int:
        return self.V.shape[0]

    def _mesh_points(self, where: np.ndarray = None) -> np.ndarray:
        """MeshPoints of every node, or of the nodes ``where``."""
        if self._points is not None:
            return self._points if where is None else self._points[where]
        if self._points_of is not None:
            return self._points_of(where)
        e_of, j_of = self.rep if where is None else (self.rep[0][where], self.rep[1][where])
        return meshpoints(self._mesh, e_of, self._ref[j_of, 0], self._ref[j_of, 1])

    def evaluate(self, cf, where: np.ndarray = None) -> np.ndarray:
        """Values of a scalar CoefficientFunction at every node (vectorized), or at the nodes ``where``."""
        return np.asarray(cf(self._mesh_points(where))).reshape(-1)

    def evaluate_many(self, cfs) -> np.ndarray:
        """Values of scalar CoefficientFunctions at every node, (len(cfs), ndof): one compiled vector-valued
        CoefficientFunction evaluated in one pass (the points are mapped once; the same values as
        :meth:`evaluate` of each)."""
        cfs = list(cfs)
        if len(cfs) == 1:
            return self.evaluate(cfs[0].Compile())[None, :]
        vector = CoefficientFunction(tuple(cfs)).Compile()
        return np.asarray(vector(self._mesh_points())).reshape(-1, len(cfs)).T.copy()

    def from_values(self, values: np.ndarray) -> np.ndarray:
        """Coefficients in this basis of the interpolant with the given values at the nodes (the values)."""
        return values

    def to_values(self, coefficients: np.ndarray) -> np.ndarray:
        """Values at the nodes of the function with the given coefficients (the coefficients)."""
        return coefficients

    def transform(self, A: sp.spmatrix) -> sp.csr_matrix:
        """Matrix of a bilinear form in the Lagrange basis: ``T^T A T``."""
        if not self.level.any():  # P1: vertex nodes only, T = I
            return sp.csr_matrix(A)
        return (self.T.T @ (A @ self.T)).tocsr()


def meshpoints(mesh, elements: np.ndarray, xi: np.ndarray, eta: np.ndarray) -> np.ndarray:
    """NGSolve MeshPoints (structured array) at reference coordinates (xi, eta) of VOL ``elements``.

    The mesh pointer and VOL tag are copied from a one-point ``MapToAllElements`` (cheap; a point
    search ``mesh(x, y)`` would first build a search tree)."""
    proto = _mesh_point_proto(mesh)
    mp = np.zeros(len(elements), dtype=proto.dtype)
    mp["meshptr"], mp["VorB"], mp["nr"], mp["facetnr"] = proto["meshptr"][0], int(VOL), elements, -1
    mp["x"], mp["y"] = xi, eta
    return mp


def _mesh_point_proto(mesh) -> np.ndarray:
    """One MeshPoint of ``mesh`` (its dtype and mesh pointer): mapped on the boundary elements when there are
    any (a few, where mapping one point on every volume element costs a pass over the whole mesh)."""
    if mesh.GetNE(BND):
        return np.asarray(mesh.MapToAllElements(IntegrationRule([(0.5, 0.0, 0.0)], [0.0]), BND))[:1]
    return np.asarray(mesh.MapToAllElements(IntegrationRule([(1 / 3, 1 / 3, 0.0)], [0.0]), VOL))[:1]


def _element_tables(fes, ne: int, ndof_loc: int):
    """(dofs, verts) per element.  The vertex table of the netgen mesh, vectorized (a Python loop over the elements
    costs seconds at 1e5+ elements).  P1: it is the dof table too (H1 numbers its vertex dofs by vertex).  Higher
    orders: the dof table by one pass over the elements (:func:`~.base.element_dofs`, shared with the estimators),
    and the vertex table is taken where its columns are the elements' vertex dofs (else read element by element)."""
    ng = fes.mesh.ngmesh.Elements2D().NumPy()["nodes"][:, :3].astype(np.int64) - 1
    if fes.globalorder == 1 and fes.ndof == fes.mesh.nv and len(ng) == ne:
        return ng.copy(), ng
    dofs = element_dofs(fes)
    if dofs.shape[1] != ndof_loc:  # pragma: no cover - guards non-standard spaces
        raise ValueError(f"H1 space of order {fes.globalorder} has {dofs.shape[1]} dofs per element, "
                         f"{ndof_loc} expected")
    if len(ng) == ne and np.array_equal(dofs[:, :3], ng):
        return dofs, ng
    verts = np.empty((ne, 3), dtype=np.int64)
    for el in fes.Elements(VOL):
        verts[el.nr] = [v.nr for v in el.vertices]
    return dofs, verts


def _order_class(verts: np.ndarray) -> np.ndarray:
    """Index 0..5 of the permutation sorting each element's global vertex numbers."""
    perm = np.argsort(verts, axis=1)
    return perm[:, 0] * 3 + perm[:, 1]


def _block_triangular_inverse(V: sp.csr_matrix, dofs: np.ndarray, level: np.ndarray, p: int) -> sp.csr_matrix:
    """Sparse V^{-1} = (I - N + N^2) Dg^{-1} with Dg the entity blocks of V."""
    n = V.shape[0]
    # entity id of every dof: vertex dofs are their own entity; edge/cell dofs
    # are grouped by the element table (an edge's dofs are contiguous in it).
    entity = np.arange(n)
    nb = p - 1
    for k in range(3):
        if nb > 0:
            ed = dofs[:, 3 + k * nb: 3 + (k + 1) * nb]
            entity[ed] = ed.min(axis=1, keepdims=True)
    if p >= 3:
        cd = dofs[:, 3 + 3 * nb:]
        entity[cd] = cd.min(axis=1, keepdims=True)

    coo = V.tocoo()
    same = entity[coo.row] == entity[coo.col]
    Dg = sp.csr_matrix((coo.data[same], (coo.row[same], coo.col[same])), shape=V.shape)
    L = sp.csr_matrix((coo.data[~same], (coo.row[~same], coo.col[~same])), shape=V.shape)
    if L.nnz and np.any(level[L.tocoo().row] <= level[L.tocoo().col]):
        raise ArithmeticError("nodal evaluation matrix is not block lower triangular")

    Dinv = _invert_entity_blocks(Dg, entity)
    N = (Dinv @ L).tocsr()
    T = Dinv - N @ Dinv + N @ (N @ Dinv)
    T = T.tocsr()
    T.data[np.abs(T.data) < 1e-14 * np.abs(T.data).max()] = 0.0
    T.eliminate_zeros()
    return T


def _invert_entity_blocks(Dg: sp.csr_matrix, entity: np.ndarray) -> sp.csr_matrix:
    """Invert a block-diagonal matrix whose blocks are the dofs sharing an entity id."""
    n = Dg.shape[0]
    order = np.lexsort((np.arange(n), entity))
    ent_sorted = entity[order]
    starts = np.flatnonzero(np.r_[True, ent_sorted[1:] != ent_sorted[:-1]])
    sizes = np.diff(np.r_[starts, n])
    local = np.empty(n, dtype=np.int64)
    local[order] = np.arange(n) - np.repeat(starts, sizes)
    block_of = np.empty(n, dtype=np.int64)
    block_of[order] = np.repeat(np.arange(len(starts)), sizes)

    coo = Dg.tocoo()
    rows, cols, vals = [], [], []
    for s in np.unique(sizes):
        blocks = np.flatnonzero(sizes == s)
        index = -np.ones(len(starts), dtype=np.int64)
        index[blocks] = np.arange(len(blocks))
        dense = np.zeros((len(blocks), s, s))
        sel = index[block_of[coo.row]] >= 0
        dense[index[block_of[coo.row[sel]]], local[coo.row[sel]], local[coo.col[sel]]] = coo.data[sel]
        inv = np.linalg.inv(dense)
        members = order[np.repeat(starts[blocks], s) + np.tile(np.arange(s), len(blocks))].reshape(len(blocks), s)
        rows.append(np.repeat(members, s, axis=1).ravel())
        cols.append(np.tile(members, (1, s)).ravel())
        vals.append(inv.ravel())
    rows, cols, vals = map(np.concatenate, (rows, cols, vals))
    return sp.csr_matrix((vals, (rows, cols)), shape=(n, n))
