"""Vectorized P1 set-up on straight-sided triangular meshes: what the conforming P1 discretization needs,
computed with numpy from the vertex and triangle arrays of the netgen mesh.

* :func:`p1_tables`: vertex coordinates (those of the netgen mesh) and the triangles' vertex numbers,
  or None where the fast path does not apply (curved elements, non-vertex dofs, other element types);
* :func:`p1_stiffness`: the stiffness matrix (grad psi_a, grad psi_b) of the hat functions, element by element
  K_ij = e_i . e_j / (4 |T|), e_i the edge of T opposite to its vertex i;
* :func:`p1_lumped_weights`: the integrals (psi_a, 1) = sum over the triangles at a of |T| / 3;
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

from ..algebra.sparse import assemble_csr

__all__ = ["p1_tables", "p1_stiffness", "p1_lumped_weights", "dirichlet_vertices"]


def p1_tables(mesh, fes=None) -> Optional[Tuple[np.ndarray, np.ndarray]]:
    """(X, T): vertex coordinates (nv, 2, the netgen vertices) and triangles (ne, 3, int64, NGSolve's local vertex order) of a
    straight-sided triangular ``mesh``, or None (a curved mesh, an element that is not a triangle, or a space
    ``fes`` whose dofs are not the vertices)."""
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
    return X, nodes[:, :3].astype(np.int64) - 1


def _edges(X: np.ndarray, T: np.ndarray):
    """x and y components (ne, 3) of the edges e_i = P_{i+2} - P_{i+1} opposite to the vertices, and 2 |T|."""
    x, y = X[:, 0][T], X[:, 1][T]
    ex = np.stack([x[:, 2] - x[:, 1], x[:, 0] - x[:, 2], x[:, 1] - x[:, 0]], axis=1)
    ey = np.stack([y[:, 2] - y[:, 1], y[:, 0] - y[:, 2], y[:, 1] - y[:, 0]], axis=1)
    return ex, ey, np.abs(ex[:, 1] * ey[:, 2] - ey[:, 1] * ex[:, 2])


def p1_stiffness(X: np.ndarray, T: np.ndarray) -> sp.csr_matrix:
    """The P1 stiffness matrix (nv x nv CSR, sorted indices, every vertex pair of a triangle stored)."""
    def local(lo, hi):
        ex, ey, area2 = _edges(X, T[lo:hi])
        inv = 1.0 / (2.0 * area2)
        loc = np.empty((hi - lo, 3, 3))
        for i in range(3):
            for j in range(i, 3):
                loc[:, i, j] = (ex[:, i] * ex[:, j] + ey[:, i] * ey[:, j]) * inv
                loc[:, j, i] = loc[:, i, j]
        return loc

    return assemble_csr(T, local, len(X))


def p1_lumped_weights(X: np.ndarray, T: np.ndarray) -> np.ndarray:
    """(psi_a, 1) for every vertex a: the sum of |T| / 3 over its triangles."""
    area2 = _edges(X, T)[2]
    return np.bincount(T.ravel(), weights=np.repeat(area2 / 6.0, 3), minlength=len(X))


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
