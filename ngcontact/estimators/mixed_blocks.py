r"""Element blocks of the hybridized mixed patch form on straight triangles, from reference matrices.

The patch problems of :mod:`.flux` use the form (broken RT_q x P_q x facet P_q, eps = 0)

    (s, tau)_K - (r, div tau)_K - (div s, w)_K + <s.n, v>_dK + <tau.n, m>_dK,

and :class:`.patches.PatchSolver` needs, per element K, the interior block A_II (RT_q and P_q dofs of K),
the RT-facet block A_VF and the facet dofs of K.  On a straight triangle only the RT mass block depends on
the shape of K: with the affine map x = x_0 + B xi from the triangle (0,0), (1,0), (0,1) and the contravariant
Piola map tau = B tau^ / det B,

    (s, tau)_K = sum_{a,b} G_ab R_ab,   G = B^T B / |det B|,   R_ab = (s^_a, tau^_b) on the reference triangle,

while the divergence and facet blocks are those of the reference triangle (det B > 0).  NGSolve's high-order
basis on K depends on the order of the global numbers of its three vertices (edge and cell orientation),
so the reference matrices are computed once per degree q and per ranking of the local vertices (six), by
assembling the form on a one-triangle mesh whose vertices are numbered in that ranking.

The hat-weighted flux operators of the patch right-hand sides (:func:`flux_operators`, trial space H1 of
degree p) transform the same way: their RT rows are reference rows, their P_q rows a combination of two
reference matrices per element.

Similar triangles share their blocks: :func:`shapes` groups the elements by ranking class and G (rounded to
2^-SHAPE_BITS relative), and :class:`ElementBlocks` keeps one block per shape (bisection-refined meshes have
far fewer shapes than elements) and applies per-shape matrices to the stacked elements of each shape.

Element matrices and operators from here and from NGSolve's assembly agree to rounding
(``tests/test_mixed_blocks.py``); :class:`AffineTriangles` is None where the premises do not hold (curved
elements, a triangle with det B <= 0), the functions return None then or for another dof layout, and the
caller assembles instead.  Cost: a few array operations per element, against NGSolve's assembly of the whole
form on the mesh (its graph and CSR arrays hold about (element dofs)^2 entries per element: 46^2 for q = 3,
29e6 entries at 14e3 triangles) and three assemblies per operator.
"""
from __future__ import annotations

import itertools
from dataclasses import dataclass
from functools import cached_property
from typing import Dict, Optional

import numpy as np
from ngsolve import (H1, HDiv, L2, BilinearForm, CoefficientFunction, ElementId, FacetFESpace, Mesh, VOL, div, dx,
                     grad, specialcf, x, y)

from ..discretizations.base import element_dofs
from ..discretizations.p1 import p1_tables

__all__ = ["AffineTriangles", "ElementBlocks", "shapes", "mixed_element_blocks", "flux_operators",
           "ElementFluxOperator", "reference_blocks", "reference_hat_products", "ranking_classes",
           "RANKINGS"]

#: rankings of the global numbers of a triangle's local vertices 0, 1, 2 (rank 0: the smallest number)
RANKINGS = tuple(itertools.permutations(range(3)))
_REF = np.array([[0.0, 0.0], [1.0, 0.0], [0.0, 1.0]])
_cache: Dict[object, tuple] = {}  # per q (the form) and per ("flux", q, p)


def _spaces(mesh, q: int):
    V = HDiv(mesh, order=q, RT=True, discontinuous=True)
    Q = L2(mesh, order=q)
    F = FacetFESpace(mesh, order=q)
    return V, Q, F, V * Q * F


def _one_triangle(ranking) -> Mesh:
    """The reference triangle as a mesh whose local vertex k has global number ranking[k]."""
    from netgen.csg import Pnt
    from netgen.meshing import Element1D, Element2D, FaceDescriptor, MeshPoint
    from netgen.meshing import Mesh as NGMesh

    ng = NGMesh(dim=2)
    pid = {}
    for k in np.argsort(ranking):  # points are numbered in the order they are added
        pid[int(k)] = ng.Add(MeshPoint(Pnt(_REF[k, 0], _REF[k, 1], 0.0)))
    ng.Add(FaceDescriptor(bc=1, domin=1, surfnr=1))
    ng.Add(Element2D(1, [pid[0], pid[1], pid[2]]))
    for a, b in ((0, 1), (1, 2), (2, 0)):
        ng.Add(Element1D([pid[a], pid[b]], index=1))
    return Mesh(ng)


def _element_matrix(trial, test, integrand) -> np.ndarray:
    """The element matrix (test dofs x trial dofs, local order) of ``integrand`` on a one-triangle mesh."""
    bf = BilinearForm(trial, test) if trial is not test else BilinearForm(trial)
    bf += integrand
    bf.Assemble()
    rows, cols = (np.array(s.GetDofNrs(ElementId(VOL, 0))) for s in (test, trial))
    dense = np.zeros((test.ndof, trial.ndof))
    data, indices, indptr = (np.asarray(a) for a in bf.mat.CSR())
    for i in range(test.ndof):
        dense[i, indices[indptr[i]:indptr[i + 1]]] = data[indptr[i]:indptr[i + 1]]
    return dense[np.ix_(rows, cols)]


def reference_blocks(q: int):
    """Per ranking (index into :data:`RANKINGS`): R (3, n, n) -- the mass integrals with the coefficient
    matrices e_0 e_0^T, e_1 e_1^T, e_0 e_1^T + e_1 e_0^T -- and C (n, n), the divergence and facet terms;
    n = nV + nQ + nF3 in the local dof order of the product space.  Also (nV, nQ).  Computed once per q."""
    q = int(q)
    if q not in _cache:
        Rs, Cs = [], []
        for ranking in RANKINGS:
            mesh = _one_triangle(ranking)
            V, Q, F, X = _spaces(mesh, q)
            (s, r, m), (tau, w, v) = X.TnT()
            n = specialcf.normal(2)
            R = []
            for G in ((1, 0, 0, 0), (0, 0, 0, 1), (0, 1, 1, 0)):
                Gc = CoefficientFunction(tuple(float(g) for g in G), dims=(2, 2))
                R.append(_element_matrix(X, X, (Gc * s) * tau * dx))
            Rs.append(np.array(R))
            Cs.append(_element_matrix(X, X, (-r * div(tau) - div(s) * w) * dx
                                      + (s * n * v + tau * n * m) * dx(element_boundary=True)))
        _cache[q] = (np.array(Rs), np.array(Cs), (V.ndof, Q.ndof))
    return _cache[q]


def reference_flux_blocks(q: int, p: int):
    """Per ranking: Ft (3, nV, nU) -- (psi_i grad u, tau) for the hat psi_i of local vertex i -- and E (2, nQ, nU) --
    (d_b u, w) -- on the reference triangle, u in P_p (H1), tau in RT_q, w in P_q.  Computed once per (q, p)."""
    key = ("flux", int(q), int(p))
    if key not in _cache:
        Fs, Es = [], []
        hats = (1.0 - x - y, x, y)  # barycentric coordinates of the local vertices at (0,0), (1,0), (0,1)
        for ranking in RANKINGS:
            mesh = _one_triangle(ranking)
            V, Q, _, _ = _spaces(mesh, q)
            U = H1(mesh, order=int(p))
            u, tau, w = U.TrialFunction(), V.TestFunction(), Q.TestFunction()
            Fs.append(np.array([_element_matrix(U, V, hat * grad(u) * tau * dx(bonus_intorder=2)) for hat in hats]))
            Es.append(np.array([_element_matrix(U, Q, grad(u)[b] * w * dx) for b in range(2)]))
        _cache[key] = (np.array(Fs), np.array(Es))
    return _cache[key]


def reference_hat_products(q: int) -> np.ndarray:
    """T (6, 3, nQ, nP): per ranking, psi_i w_j = sum_m T[c, i, j, m] v_m on the reference triangle, for the hat psi_i
    of local vertex i, the P_q basis w (L2 order q) and the P_{q+1} basis v (L2 order q + 1): exact, the products
    lie in P_{q+1}, so (g psi_i, w_j)_K = sum_m T[c, i, j, m] (g, v_m)_K for every g, every rule and every element of
    ranking c, straight or curved (the bases are those of the reference element).  Computed once per q."""
    key = ("hat_products", int(q))
    if key not in _cache:
        Ts = []
        for ranking in RANKINGS:
            mesh = _one_triangle(ranking)
            Q, P = L2(mesh, order=int(q)), L2(mesh, order=int(q) + 1)
            v, w = P.TrialFunction(), Q.TestFunction()
            M = _element_matrix(P, P, v * P.TestFunction() * dx(bonus_intorder=2))
            B = [_element_matrix(P, Q, hat * v * w * dx(bonus_intorder=2)) for hat in (1.0 - x - y, x, y)]
            Ts.append(np.array([np.linalg.solve(M, b.T).T for b in B]))  # (psi_i w_j, v_n) = sum_m T_jm M_mn
        _cache[key] = np.array(Ts)
    return _cache[key]


#: gradients of the reference hats (rows: local vertices 0, 1, 2)
_HAT_GRADS = np.array([[-1.0, -1.0], [1.0, 0.0], [0.0, 1.0]])


@dataclass(frozen=True, eq=False)
class AffineTriangles:
    """The affine maps x = x_0 + B xi of the triangles of a mesh from the reference triangle (local vertex k at
    (0,0), (1,0), (0,1)) and the ranking class of their vertex numbers; :meth:`of` gives None where the
    reference matrices do not apply (module doc)."""

    B: np.ndarray       # (ne, 2, 2)
    det: np.ndarray     # (ne,)
    cls: np.ndarray     # (ne,) index into RANKINGS
    vertices: np.ndarray = None  # (ne, 3) vertex numbers in the local order (the dofs of H1 order 1)

    @classmethod
    def of(cls, mesh) -> Optional["AffineTriangles"]:
        tables = p1_tables(mesh)  # straight triangles whose points are the vertices, else None
        if tables is None:
            return None
        P, ev = tables
        xv = P[ev]                                                     # (ne, 3, 2)
        B = np.stack([xv[:, 1] - xv[:, 0], xv[:, 2] - xv[:, 0]], axis=2)  # columns: images of (1,0), (0,1)
        det = B[:, 0, 0] * B[:, 1, 1] - B[:, 0, 1] * B[:, 1, 0]
        if not np.all(det > 0):
            return None
        return cls(B=B, det=det, cls=ranking_classes(ev), vertices=ev)

    def classes(self):
        """(class index, its elements) for the classes present."""
        return _class_groups(self.cls)


def ranking_classes(ev: np.ndarray) -> np.ndarray:
    """(ne,) index into :data:`RANKINGS` of the ranking of the vertex numbers ``ev`` (ne, 3, local order) of every
    element."""
    rank = np.argsort(np.argsort(ev, axis=1, kind="stable"), axis=1)
    lookup = np.full(27, -1, dtype=np.int64)
    for c, r in enumerate(RANKINGS):
        lookup[r[0] * 9 + r[1] * 3 + r[2]] = c
    return lookup[rank[:, 0] * 9 + rank[:, 1] * 3 + rank[:, 2]]


def _class_groups(cls: np.ndarray):
    """(ranking class, the indices with that class) for the classes present in ``cls``."""
    for c in range(len(RANKINGS)):
        sel = np.flatnonzero(cls == c)
        if len(sel):
            yield c, sel


@dataclass(frozen=True, eq=False)
class ElementBlocks:
    """The element blocks of the patch form (:func:`mixed_element_blocks`), stored once per shape: block s of
    ``A_II`` (ns, nI, nI) and ``A_VF`` (ns, nV, nF3) is that of every element K with ``shape[K] == s``;
    ``shape`` None: one block per element, in element order.  ``fdofs`` (ne, nF3): the facet dofs of every
    element in the numbering of the product space."""

    A_II: np.ndarray
    A_VF: np.ndarray
    fdofs: np.ndarray
    shape: Optional[np.ndarray] = None

    def per_element(self, arr: np.ndarray) -> np.ndarray:
        """``arr`` (ns, ...), one entry per shape, as one entry per element (no copy without shapes)."""
        return arr if self.shape is None else arr[self.shape]

    @property
    def nshapes(self) -> int:
        return len(self.A_II)

    @cached_property
    def _groups(self):
        """[(shapes (m,), their elements (m, n))] for the shapes with n elements, one entry per n."""
        order = np.argsort(self.shape, kind="stable")
        count = np.bincount(self.shape, minlength=self.nshapes)
        start = np.concatenate([[0], np.cumsum(count)])
        out = []
        for n in np.unique(count[count > 0]):
            sid = np.flatnonzero(count == n)
            out.append((sid, order[start[sid][:, None] + np.arange(n)]))
        return out

    def apply(self, M: np.ndarray, X: np.ndarray) -> np.ndarray:
        """(ne, r, k): M[shape of K] @ X[K] for every element K, with M (ns, r, c) one matrix per shape and
        X (ne, c, k).  The shapes' matrices are applied to the stacked elements of the shapes with equal
        numbers of elements (one batched product per such number), not gathered per element (ne r c entries of
        fresh memory cost more than the product)."""
        if self.shape is None:
            return np.matmul(M, X)
        out = np.empty((X.shape[0], M.shape[1], X.shape[2]))
        for sid, elems in self._groups:
            out[elems] = np.matmul(M[sid][:, None], X[elems])
        return out


#: resolution of the shape key of :func:`shapes`: G rounded to 2^-30 of its largest entry (~1e-9 relative).  The
#: rounding of the bisection midpoints accumulates over the levels of an adaptive run, so that a much finer key
#: (2^-44) splits the similar triangles of a deep adaptive mesh into several shapes; at 2^-30 the RT mass block of
#: an element is that of its representative to ~1e-9 relative, and the fluxes stay exactly equilibrated (:func:`shapes`)
SHAPE_BITS = 30


def shapes(cls: np.ndarray, coef: np.ndarray):
    """(representatives, shape index (ne,)) of the elements with equal ranking class ``cls`` and equal metric
    coefficients ``coef`` (ne, 3) = (G_00, G_11, G_01), G = B^T B / |det B| (invariant under translation, rotation
    and scaling of K, so the similar triangles of a bisection-refined mesh share one element block).  G is compared
    after rounding to 2^-SHAPE_BITS of its largest entry: elements whose G differ by rounding only (bisection
    midpoints are rounded) get the block of the representative, whose G differs from theirs by at most that
    relative amount; the RT mass block changes by as much, the divergence and facet blocks not at all, so the
    patch fluxes stay exactly equilibrated (the estimate stays a guaranteed bound).  None where there are more
    shapes than half the elements (little to gain: one block per element then)."""
    top = np.abs(coef).max(axis=1)
    e = np.floor(np.log2(top))
    q = np.round(coef / np.exp2(e)[:, None] * 2.0 ** SHAPE_BITS).astype(np.int64)  # |q| < 2^(SHAPE_BITS + 1)
    key = np.concatenate([cls[:, None].astype(np.int64), e[:, None].astype(np.int64), q], axis=1)
    _, rep, index = np.unique(key, axis=0, return_index=True, return_inverse=True)
    if 2 * len(rep) > len(cls):
        return None
    return rep, index.ravel()


def _product_dofs(X, ne: int, nI: int, edges) -> np.ndarray:
    """(ne, nI + nF3): the dofs of every element of X = V x Q x F (:func:`mixed_element_blocks`): V and Q numbered
    element by element, F = facet P_q with q + 1 dofs per edge, edge by edge, so that with the ranks of the elements'
    edges ``edges`` (:func:`~ngcontact.discretizations.base.element_edges`) no pass over the elements is needed;
    checked against NGSolve's dofs of a sample of elements (the whole table by one pass over the elements without
    ``edges`` or when the sample disagrees)."""
    V, Q, F = X.components
    q1 = int(F.globalorder) + 1
    if edges is None or len(edges) != ne or not ne or F.ndof % q1 or edges.max() >= F.ndof // q1:
        return element_dofs(X)
    nV, nQ = V.ndof // ne, Q.ndof // ne
    K = np.arange(ne)[:, None]
    facet = V.ndof + Q.ndof + (edges[:, :, None] * q1 + np.arange(q1)).reshape(ne, 3 * q1)
    dofs = np.concatenate([K * nV + np.arange(nV), V.ndof + K * nQ + np.arange(nQ), facet], axis=1)
    sample = np.unique(np.linspace(0, ne - 1, min(ne, 33)).astype(np.int64))
    if dofs.shape[1] != nI + 3 * q1 or any(list(X.GetDofNrs(ElementId(VOL, int(e)))) != list(dofs[e]) for e in sample):
        return element_dofs(X)
    return dofs


def mixed_element_blocks(tri: Optional[AffineTriangles], X, q: int, edges=None) -> Optional[ElementBlocks]:
    """The :class:`ElementBlocks` (A_II (nI x nI), A_VF (nV x nF3) and the facet dofs (nF3) in the numbering of
    ``X``, one block per :func:`shapes` class) of the form of the module docstring, eps = 0, for ``X`` = broken
    RT_q x P_q x facet P_q (the space of :func:`.flux._mixed_patch_problem`) on the triangles ``tri``, or None
    (``tri`` None, another dof layout).  The RT and P_q rows are in the order of the dof numbers (those of K are
    consecutive), the facet columns in the local order of K.  ``edges``: the ranks of the elements' edges, if known
    (:func:`~ngcontact.discretizations.base.element_edges`: no pass over the elements, :func:`_product_dofs`)."""
    if tri is None:
        return None
    R, C, (nV, nQ) = reference_blocks(q)
    V, Q, F = X.components
    ne = len(tri.det)
    nI = nV + nQ
    nF3 = C.shape[1] - nI
    if V.ndof != ne * nV or Q.ndof != ne * nQ:
        return None
    dofs = _product_dofs(X, ne, nI, edges)
    expect = np.concatenate([(np.arange(ne) * nV)[:, None] + np.arange(nV),
                             V.ndof + (np.arange(ne) * nQ)[:, None] + np.arange(nQ)], axis=1)
    if dofs.shape[1] != nI + nF3 or not np.array_equal(dofs[:, :nI], expect):
        return None
    B, det = tri.B, tri.det
    G = np.einsum("kia,kib->kab", B, B) / det[:, None, None]        # B^T B / |det B|
    coef = np.stack([G[:, 0, 0], G[:, 1, 1], G[:, 0, 1]], axis=1)  # (ne, 3)
    found = shapes(tri.cls, coef)
    rep, index = (np.arange(ne), None) if found is None else found
    cls, coef = tri.cls[rep], coef[rep]
    A_II = np.empty((len(rep), nI, nI))
    A_VF = np.empty((len(rep), nV, nF3))
    for c, sel in _class_groups(cls):
        A_II[sel] = C[c][:nI, :nI]
        A_II[sel, :nV, :nV] = np.einsum("kt,tij->kij", coef[sel], R[c][:, :nV, :nV])
        A_VF[sel] = C[c][:nV, nI:]
    return ElementBlocks(A_II, A_VF, dofs[:, nI:].copy(), index)


def flux_operators(tri: Optional[AffineTriangles], Y, q: int, space, hessian: bool):
    """The hat-weighted flux operators of :func:`.flux._flux_operator` (mu = 1) as one :class:`ElementFluxOperator`
    (3 ne nI x space.ndof, rows in the layout of :meth:`.patches.PatchSolver.operators`: hat i, element K, local RT
    then P_q dof): for the hat psi_i of the local vertex i, the rows of

        -(psi_i grad u, tau)_K + (grad psi_i . grad u, w)_K,

    which is the operator's form -(psi_i grad u, tau) - (psi_i (Lap u w + grad u . grad w)) + <psi_i grad u . n, w>
    after an integration by parts on each K (exact: polynomials on straight triangles; without the Laplacian
    only for p = 1, where it vanishes).  With tau = B tau^ / det B, grad = B^-T grad^: the tau rows are those of
    the reference triangle, the w rows sum_b (H grad^ psi_i)_b (d_b u, w)^ with H = det B (B^T B)^-1.  None
    where the reference matrices do not apply (``tri`` None, ``space`` not H1 of one order p with p = 1 or
    ``hessian``, another dof layout of ``Y``)."""
    p = int(getattr(space, "globalorder", 0))
    if tri is None or type(space).__name__ != "H1" or p < 1 or not (hessian or p == 1):
        return None
    Ft, E = reference_flux_blocks(q, p)
    V, Q = Y.components
    ne = len(tri.det)
    nV, nQ, nU = Ft.shape[2], E.shape[2], Ft.shape[3]
    if V.ndof != ne * nV or Q.ndof != ne * nQ:
        return None
    # P1: the dofs of K are its vertices in the local order (GetDofNrs element by element otherwise)
    p1 = p == 1 and tri.vertices is not None and space.ndof == space.mesh.nv
    udofs = tri.vertices.astype(np.int64) if p1 else element_dofs(space)
    if udofs.shape[1] != nU:
        return None
    B, det = tri.B, tri.det
    BtB = np.einsum("kia,kib->kab", B, B)
    H = np.linalg.inv(BtB) * det[:, None, None]
    coef = np.stack([H @ _HAT_GRADS[i] for i in range(3)])                  # (3, ne, 2)
    return ElementFluxOperator(Ft, E, coef, udofs, list(tri.classes()), space.ndof)


class ElementFluxOperator:
    """The operator of :func:`flux_operators` applied element by element, without forming its matrix: ``op @ u``
    (u: coefficients of the trial space, (ndof,) or (ndof, m)) gives the rows (hat i, element K, RT then P_q
    dof), ``-Ft_c[i] u_K`` and ``sum_b coef[i, K, b] E_c[b] u_K`` on K of ranking class c.  The matrix has
    3 nI nU entries per element (14e6 at 14e3 triangles for q = p = 3): forming it cost more than the few
    products an estimate takes with it.  :meth:`tocsr` forms it (tests)."""

    def __init__(self, Ft, E, coef, udofs, classes, ndof: int):
        self.Ft, self.E, self.coef, self.udofs, self.classes = Ft, E, coef, udofs, classes
        self.nV, self.nQ = Ft.shape[2], E.shape[2]
        self.shape = (3 * len(udofs) * (self.nV + self.nQ), int(ndof))

    def __matmul__(self, u):
        u = np.asarray(u, dtype=float)
        ne, nV = len(self.udofs), self.nV
        uK = u[self.udofs]                                                # (ne, nU[, m])
        out = np.empty((3, ne, nV + self.nQ) + u.shape[1:])
        for c, sel in self.classes:
            uc = uK[sel]
            t = np.einsum("bjn,kn...->kbj...", self.E[c], uc)             # (k, 2, nQ[, m])
            for i in range(3):
                out[i, sel, :nV] = -np.einsum("jn,kn...->kj...", self.Ft[c][i], uc)
                out[i, sel, nV:] = np.einsum("kb,kbj...->kj...", self.coef[i, sel], t)
        return out.reshape((self.shape[0],) + u.shape[1:])

    def tocsr(self):
        """The operator as a CSR matrix (every row holds the element's dofs in their local order)."""
        from scipy.sparse import csr_matrix

        nU = self.udofs.shape[1]
        ne, nI = len(self.udofs), self.nV + self.nQ
        data = np.empty((3, ne, nI, nU))
        for c, sel in self.classes:
            for i in range(3):
                data[i, sel, :self.nV] = -self.Ft[c][i]
                data[i, sel, self.nV:] = np.einsum("kb,bjn->kjn", self.coef[i, sel], self.E[c])
        indices = np.broadcast_to(self.udofs[None, :, None, :], (3, ne, nI, nU)).ravel()
        indptr = np.arange(3 * ne * nI + 1) * nU
        return csr_matrix((data.ravel(), indices, indptr), shape=self.shape)
