"""Bernstein basis of the conforming P_p space and its change of basis to NGSolve's H1 basis.

The Bernstein polynomials of a triangle, labelled by the lattice points b (b0 + b1 + b2 = p),

    B_b = p! / (b0! b1! b2!) lam0^b0 lam1^b1 lam2^b2,

are nonnegative, sum to 1 and have equal integrals (B_b, 1)_K = |K| / dim P_p.  The trace of B_b on an
edge is the 1D Bernstein polynomial of the edge (or zero), so coefficients shared at the domain points
b / p of neighbouring cells give a C^0 basis of the same space as the Lagrange basis, with the
coefficients numbered like the equispaced Lagrange nodes.

``--constraints bernstein`` (:class:`~ngcontact.discretizations.fem.FEMDiscretization`): the unknowns are
Bernstein coefficients, the multiplier lam_h = sum_l X3_l Theta_l with Theta dual to the Bernstein basis,
and the constraints are X1 - X2 >= 0 (nonnegative Bernstein coefficients of the gap: u1h >= u2h
everywhere, not only at nodes) and X3_l = (lam_h, B_l) >= 0 (every B_l >= 0 with a positive integral,
the rule of :mod:`~ngcontact.discretizations.nodesets`).  Data (Dirichlet lifting, obstacle) enter as
the Bernstein coefficients of their equispaced Lagrange interpolant (nodal values of g are not).

:class:`BernsteinBasis` has the interface of :class:`~ngcontact.discretizations.lagrange.LagrangeNodes`
(``V``, ``T``, ``coords``, ``level``, ``evaluate``, ``from_values``, ``to_values``, ``transform``) with
"nodal values" read as Bernstein coefficients.
"""
from __future__ import annotations

from dataclasses import dataclass
from math import factorial

import numpy as np
import scipy.sparse as sp

from .lagrange import LagrangeNodes, _block_triangular_inverse
from .nodesets import lattice

__all__ = ["BernsteinBasis", "bernstein_values"]


def bernstein_values(p: int, bary: np.ndarray) -> np.ndarray:
    """B_b at barycentric points (n, 3): (n, npts), columns in the order of ``lattice(p)``.

    >>> bernstein_values(2, np.array([[0.5, 0.5, 0.0]])).round(3).tolist()  # edge midpoint
    [[0.0, 0.0, 0.25, 0.0, 0.5, 0.25]]
    """
    bary = np.asarray(bary, float)
    lat = lattice(p)
    coef = np.array([factorial(p) / (factorial(a) * factorial(b) * factorial(c)) for a, b, c in lat])
    return coef * np.prod(bary[:, None, :] ** lat[None, :, :], axis=2)


@dataclass
class BernsteinBasis:
    """Bernstein basis of ``H1(mesh, order=p)`` (module doc); coefficients numbered like the H1 dofs.

    Attributes
    ----------
    V, T : scipy.sparse.csr_matrix
        Bernstein coefficients = V @ H1 coefficients, H1 coefficients = T @ Bernstein coefficients.
    M, Minv : scipy.sparse.csr_matrix
        values at the domain points = M @ Bernstein coefficients, and its inverse.
    coords, level :
        the domain points (equispaced Lagrange nodes) and their entity level (0 vertex, 1 edge, 2 cell).
    """

    V: sp.csr_matrix
    T: sp.csr_matrix
    M: sp.csr_matrix
    Minv: sp.csr_matrix
    lagrange: LagrangeNodes

    @classmethod
    def build(cls, fes) -> "BernsteinBasis":
        L = LagrangeNodes.build(fes, "equispaced")
        p = fes.globalorder
        n = L.ndof
        if p == 1:  # the Bernstein basis of P1 is the hat basis
            return cls(V=L.V, T=L.T, M=L.V, Minv=L.V, lagrange=L)
        lat = lattice(p)
        Mloc = bernstein_values(p, lat / p)  # Mloc[j, k] = B_k(xi_j)
        e_of, j_of = L.rep
        npts = len(lat)
        rows = np.repeat(np.arange(n), npts)
        cols = L.elem_nodes[e_of].ravel()
        vals = Mloc[j_of].ravel()
        keep = vals != 0.0
        M = sp.csr_matrix((vals[keep], (rows[keep], cols[keep])), shape=(n, n))
        # M is block lower triangular by entity (edge B vanish at vertices, cell B on edges): sparse inverse
        Minv = _block_triangular_inverse(M, L.elem_dofs, L.level, p)
        return cls(V=(Minv @ L.V).tocsr(), T=(L.T @ M).tocsr(), M=M, Minv=Minv, lagrange=L)

    @property
    def coords(self) -> np.ndarray:
        return self.lagrange.coords

    @property
    def level(self) -> np.ndarray:
        return self.lagrange.level

    @property
    def ndof(self) -> int:
        return self.V.shape[0]

    def evaluate(self, cf) -> np.ndarray:
        """Values of a CoefficientFunction at the domain points."""
        return self.lagrange.evaluate(cf)

    def from_values(self, values: np.ndarray) -> np.ndarray:
        """Bernstein coefficients of the interpolant with the given values at the domain points."""
        return self.Minv @ values

    def to_values(self, coefficients: np.ndarray) -> np.ndarray:
        """Values at the domain points of the function with the given Bernstein coefficients."""
        return self.M @ coefficients

    def transform(self, A: sp.spmatrix) -> sp.csr_matrix:
        """Matrix of a bilinear form in the Bernstein basis: ``T^T A T``."""
        return (self.T.T @ (A @ self.T)).tocsr()
