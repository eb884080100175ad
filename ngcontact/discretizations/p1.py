"""Vectorized P1 set-up on straight-sided triangular meshes: what the conforming P1 discretization needs,
computed with numpy from the vertex and triangle arrays of the netgen mesh.

* :func:`p1_tables`: vertex coordinates (those of the netgen mesh) and the triangles' vertex numbers,
  or None where the fast path does not apply (curved elements, non-vertex dofs, other element types);
* :func:`p1_matrices`: the stiffness matrix (grad psi_a, grad psi_b) of the hat functions, element by element
  K_ij = e_i . e_j / (4 |T|), e_i the edge of T opposite to its vertex i, and the integrals (psi_a, 1) = sum
  over the triangles at a of |T| / 3;
* :func:`dirichlet_vertices`: the vertices of the boundary elements of a boundary region (the P1 dofs that
  ``H1(mesh, order=1, dirichlet=...)`` fixes), checked against the space's count of free dofs.

NGSolve's hat functions are the barycentric coordinates and its P1 dofs are the vertex numbers, so these are
the matrices of ``BilinearForm(grad(u) * grad(v) * dx)`` and ``LinearForm(v * dx)`` up to rounding
(tests/test_p1_setup.py).  At 1e6 vertices they take a fraction of the time of NGSolve's assembly, and no
MeshPoints or CoefficientFunction evaluations.
"""
from __future__ import annotations

from typing import Optional, Tuple

import numpy as np
import scipy.sparse as sp

from ..algebra.sparse import place_rows

__all__ = ["p1_tables", "p1_matrices", "symmetric_from_upper", "dirichlet_vertices", "RIGHT_ANGLE"]

#: relative size below which a P1 stiffness coupling counts as the zero of a right angle (:func:`p1_matrices`):
#: rounding leaves a few machine epsilons, a genuine coupling is cot of an angle that differs from 90 degrees
RIGHT_ANGLE = 1e-14


def p1_tables(mesh, fes=None) -> Optional[Tuple[np.ndarray, np.ndarray]]:
    """(X, T): vertex coordinates (nv, 2, the netgen vertices) and triangles (ne, 3, NGSolve's local vertex
    order; int32 below 2^31 vertices) of a straight-sided triangular ``mesh``, or None (a curved mesh, an
    element that is not a triangle, or a space ``fes`` whose dofs are not the vertices)."""
    ng = mesh.ngmesh
    if ng.dim != 2 or ng.GetCurveOrder() > 1:
        return None
    if fes is not None and (fes.globalorder != 1 or fes.ndof != mesh.nv):
        return None
    nodes = ng.Elements2D().NumPy()["nodes"]
    if len(nodes) != mesh.ne or (nodes.shape[1] > 3 and np.any(nodes[:, 3])):
        return None
    X = np.array(ng.Coordinates()[:, :2], dtype=float)
    if len(X) != mesh.nv:
        return None
    itype = np.int32 if len(X) < np.iinfo(np.int32).max else np.int64
    return X, nodes[:, :3].astype(itype) - 1


def p1_matrices(X: np.ndarray, T: np.ndarray, chunk: int = 1 << 19):
    """(S, w): the P1 stiffness matrix (nv x nv CSR, canonical: sorted, summed indices) and the lumped weights
    w_a = (psi_a, 1), the sum of |T| / 3 over the triangles at a.

    One pass over the triangles in chunks of ``chunk``: the diagonal and w are sums per vertex (bincount), the
    couplings are summed once per vertex pair a < b (the upper triangle U: 3 entries per triangle instead of
    9), and S = U + U^T + diag (:func:`symmetric_from_upper`).

    S stores the couplings that do not vanish: an off-diagonal entry with |S_ab| <= ``RIGHT_ANGLE`` sqrt(S_aa S_bb)
    is dropped.  Such an entry is the sum of cot(angle) / 2 over the angles opposite to the edge ab; it is zero
    across right angles (a pair of right-angled triangles on a structured or criss-cross mesh, where about
    30 % of the vertex pairs of the triangles are such), computed as 0 or as a rounding residue of a few
    machine epsilons relative to sqrt(S_aa S_bb).  Dropping an entry below that bound perturbs the diagonally
    scaled matrix diag(S)^-1/2 S diag(S)^-1/2 by at most 1e-14 per entry, the order of the backward error of its
    Cholesky factorization.  Not storing them makes every product with S cheaper."""
    nv = len(X)
    w, diag = np.zeros(nv), np.zeros(nv)
    U = None
    for lo in range(0, len(T), chunk):
        Tc = T[lo:lo + chunk]
        x0, x1, x2 = (X[Tc[:, k], 0] for k in range(3))
        y0, y1, y2 = (X[Tc[:, k], 1] for k in range(3))
        ex, ey = (x2 - x1, x0 - x2, x1 - x0), (y2 - y1, y0 - y2, y1 - y0)  # e_i opposite to vertex i
        area2 = np.abs(ex[1] * ey[2] - ey[1] * ex[2])  # 2 |T|
        w += np.bincount(Tc.ravel(), weights=np.repeat(area2 / 6.0, 3), minlength=nv)
        inv = 0.5 / area2
        rows, cols, vals = [], [], []
        for i, j in ((0, 0), (1, 1), (2, 2), (1, 2), (2, 0), (0, 1)):
            v = ex[i] * ex[j]
            v += ey[i] * ey[j]
            v *= inv  # (grad psi_i, grad psi_j)_T = e_i . e_j / (4 |T|)
            if i == j:
                diag += np.bincount(Tc[:, i], weights=v, minlength=nv)
            else:
                a, b = Tc[:, i], Tc[:, j]
                rows.append(np.minimum(a, b))
                cols.append(np.maximum(a, b))
                vals.append(v)
        part = sp.csr_matrix((np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))), shape=(nv, nv))
        part.sum_duplicates()
        U = part if U is None else U + part
        del part, rows, cols, vals
    if U is None:
        return sp.csr_matrix((nv, nv)), w
    d = np.sqrt(diag)
    r = np.repeat(np.arange(nv, dtype=U.indices.dtype), np.diff(U.indptr))
    U.data[np.abs(U.data) <= RIGHT_ANGLE * d[r] * d[U.indices]] = 0.0
    U.eliminate_zeros()
    return symmetric_from_upper(U, diag), w


def symmetric_from_upper(U: sp.csr_matrix, diag: np.ndarray) -> sp.csr_matrix:
    """S = U + U^T + diag(diag) for a strictly upper triangular U with sorted indices, as ``U + U.T + diags``
    gives it (canonical, zero diagonal entries not stored), written directly: row a of S is row a of U^T
    (columns < a), the diagonal, row a of U (columns > a); no column occurs twice, so nothing is summed and
    every entry is placed by its row's offset (two passes over the entries instead of two sparse sums)."""
    nv = U.shape[0]
    L = U.T.tocsr()  # the CSC -> CSR conversion appends each row's columns in increasing order
    itype = U.indices.dtype if 2 * U.nnz + nv < np.iinfo(np.int32).max else np.int64
    has_d = diag != 0
    nl, nu = np.diff(L.indptr), np.diff(U.indptr)
    indptr = np.zeros(nv + 1, dtype=itype)
    np.cumsum(nl + has_d + nu, out=indptr[1:])
    data = np.empty(int(indptr[-1]))
    indices = np.empty(int(indptr[-1]), dtype=itype)
    start = indptr[:-1]
    place_rows(data, indices, start, L)
    place_rows(data, indices, start + nl + has_d, U)
    at = (start + nl)[has_d]
    data[at] = diag[has_d]
    indices[at] = np.flatnonzero(has_d)
    return sp.csr_matrix((data, indices, indptr), shape=(nv, nv))


def dirichlet_vertices(mesh, region: str, fes=None) -> Optional[np.ndarray]:
    """Boolean mask of the vertices on the boundary elements of ``mesh.Boundaries(region)``; with ``fes``
    (a P1 H1 space with ``dirichlet=region``) None unless its number of free dofs is that of the mask."""
    bnd = np.zeros(mesh.nv, dtype=bool)
    for el in mesh.Boundaries(region).Elements():
        for v in el.vertices:
            bnd[v.nr] = True
    if fes is not None and fes.FreeDofs().NumSet() != mesh.nv - int(bnd.sum()):
        return None
    return bnd
