r"""The multiplier lam^_h on the patches of Dirichlet boundary vertices (p >= 2).

The discrete system has no constraint rows on the Dirichlet nodes, so the hat moment
m_a = sum_l psi_a(x_l) (D X3)_l of a boundary vertex a sums over the interior Lagrange nodes of its
patch only: it is not a moment of lam, and c_a = m_a / (psi_a, 1) misses the boundary part of the
patch (the dual-basis lam_h vanishes at the boundary nodes alike).  Boundary patches need no
compatibility (no mean-value condition on a patch with a Dirichlet facet), so the value of lam^_h
there is free for the bound; but it is what the flux must equilibrate: where lam > 0 reaches the
boundary, an O(1) error of lam^_h on the layer of boundary elements (width h) costs
h |layer|^{1/2} = O(h^{3/2}) in eta_F, against the O(h^p) error.

The value used instead is the element residual of the discrete equations (the pointwise
multiplier of the discrete solution): from -mu_a Lap u_a - s_a lam = f_a,

    rho_h|_K = (sum_a s_a (-mu_a Lap u_ah - f_a) / mu_a) / (sum_a 1 / mu_a)     (obstacle: -mu Lap u_h - f),

the weights 1/mu_a minimizing sum_a mu_a^{-1} ||s_a rho - (-mu_a Lap u_ah - f_a)||_K^2, i.e. the
flux misfit of both fields.  rho_h = lam + O(h^{p-1}) on contact elements, so the layer costs
O(h^{p+1/2}) in eta_F.  Where it is used (elsewhere the multipliers of :mod:`.multipliers` are unchanged):

* :class:`.multipliers.PatchContactMultiplier` -- rho_h^+ at the boundary vertices of the contact
  elements (:func:`boundary_vertex_values`);
* :class:`.multipliers.ShapedContactMultiplier` -- the shape rho_h^+ instead of lam_h^+ on the contact
  elements connected to the boundary (:func:`contact_band`): the dual-basis lam_h solves a global mass
  system with zero boundary values, so its error at the boundary spreads inwards, geometrically
  decaying per element layer but over more layers the finer the mesh and the higher p.
"""
from __future__ import annotations

import numpy as np
from ngsolve import H1, VOL, CoefficientFunction, IntegrationRule, Trace

from ..domains import DIRICHLET
from .view import DiscretizationView, SolutionView

__all__ = ["boundary_vertices", "contact_band", "residual_multiplier", "vertex_values", "boundary_vertex_values"]

#: the vertices of NGSolve's reference triangle, in the local vertex order of the element
_VERTICES = [(1.0, 0.0), (0.0, 1.0), (0.0, 0.0)]


def boundary_vertices(dv: DiscretizationView) -> np.ndarray:
    """(nv,) bool: the vertices on the Dirichlet boundary (cached)."""
    c = dv.cache
    if "boundary_vertices" not in c:
        V1 = H1(dv.mesh, order=1, dirichlet=DIRICHLET)
        c["boundary_vertices"] = ~np.array(list(V1.FreeDofs()), dtype=bool)[:dv.mesh.nv]
    return c["boundary_vertices"]


def contact_band(dv: DiscretizationView, contact: np.ndarray) -> np.ndarray:
    """(ne,) bool: the contact elements connected, through contact elements sharing a vertex, to a Dirichlet
    boundary vertex of a contact element (empty when no contact element touches the boundary)."""
    ev = dv.element_vertices()
    contact = np.asarray(contact, bool)
    reached = boundary_vertices(dv) & (np.bincount(ev[contact].ravel(), minlength=dv.mesh.nv) > 0)
    band = np.zeros(len(ev), bool)
    while True:
        grown = contact & reached[ev].any(axis=1)
        if (grown == band).all():
            return band
        band = grown
        reached[ev[band].ravel()] = True


def residual_multiplier(sv: SolutionView) -> CoefficientFunction:
    """rho_h, the elementwise multiplier of the discrete solution (module doc)."""
    num, den = CoefficientFunction(0.0), 0.0
    for fd in sv.fields:
        lap = Trace(fd.u.Operator("hesse"))
        num = num + (fd.sign / fd.mu) * (-fd.mu * lap - fd.f)
        den += 1.0 / fd.mu
    return num / den


def vertex_values(dv: DiscretizationView, cf) -> np.ndarray:
    """(ne, 3) values of cf at the vertices of every element, taken inside the element (local vertex order
    of :meth:`.view.DiscretizationView.element_vertices`)."""
    ir = IntegrationRule(points=_VERTICES, weights=[0.0] * 3)
    return np.asarray(cf(dv.mesh.MapToAllElements(ir, VOL))).reshape(dv.mesh.ne, 3)


def boundary_vertex_values(sv: SolutionView, contact: np.ndarray) -> np.ndarray:
    """(ne, 3) rho_h^+ at the boundary vertices of the contact elements (``contact``: (ne,) bool), NaN elsewhere
    (the entries the multipliers keep)."""
    dv = sv.disc
    ev = dv.element_vertices()
    on = boundary_vertices(dv)[ev] & np.asarray(contact, bool)[:, None]
    out = np.full(ev.shape, np.nan)
    if on.any():
        out[on] = np.maximum(vertex_values(dv, residual_multiplier(sv))[on], 0.0)
    return out
