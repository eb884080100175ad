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

    rho_h|_K = (sum_a s_a (-mu_a Lap u_ah - Pi f_a) / mu_a) / (sum_a 1 / mu_a)     (obstacle: -mu Lap u_h - Pi f),

Pi the elementwise L2 projection onto P_{p-2} (the degree of Lap u_ah), the weights 1/mu_a minimizing
sum_a mu_a^{-1} ||s_a rho - (-mu_a Lap u_ah - Pi f_a)||_K^2, i.e. the flux misfit of both fields.
rho_h = lam + O(h^{p-1}) on contact elements, so the layer costs O(h^{p+1/2}) in eta_F.  Where it is used (elsewhere the multipliers of :mod:`.multipliers` are unchanged):

* :class:`.multipliers.PatchContactMultiplier` -- rho_h^+ at the boundary vertices of the contact
  elements (:func:`boundary_vertex_values`);
* :class:`.multipliers.ContactMultiplier` -- the mean of these values over the contact elements of a boundary
  vertex, as the value of the fitted P1 function there (:func:`boundary_nodal_values`);
* :class:`.multipliers.ShapedContactMultiplier` -- the shape rho_h^+ instead of lam_h^+ on the contact
  elements connected to the boundary (:func:`contact_band`): the dual-basis lam_h solves a global mass
  system with zero boundary values, so its error at the boundary spreads inwards, geometrically
  decaying per element layer but over more layers the finer the mesh and the higher p.
"""
from __future__ import annotations

import numpy as np
from ngsolve import H1, L2, VOL, CoefficientFunction, GridFunction, IntegrationRule, Trace

from ..discretizations.base import bit_mask
from ..domains import DIRICHLET
from .view import DiscretizationView, SolutionView

__all__ = ["boundary_vertices", "contact_band", "residual_multiplier", "vertex_values", "boundary_vertex_values",
           "boundary_nodal_values"]

#: the vertices of NGSolve's reference triangle, in the local vertex order of the element
_VERTICES = [(1.0, 0.0), (0.0, 1.0), (0.0, 0.0)]


def boundary_vertices(dv: DiscretizationView) -> np.ndarray:
    """(nv,) bool: the vertices on the Dirichlet boundary (cached)."""
    c = dv.cache
    if "boundary_vertices" not in c:
        V1 = H1(dv.mesh, order=1, dirichlet=DIRICHLET)
        c["boundary_vertices"] = ~bit_mask(V1.FreeDofs())[:dv.mesh.nv]
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
    """rho_h, the elementwise multiplier of the discrete solution (module doc), with f_a replaced by its
    elementwise L2 projection onto P_{p-2}, the degree of Lap u_ah: rho_h in P_{p-2}(K), whose error
    comes from lam and u - u_h only (not from the variation of f_a).  On straight elements a GridFunction of
    L2(P_{p-2}) (exact to round-off), on curved ones the expression with the Hessians of the fields.  Computed
    once per iterate (kept in ``sv.cache``)."""
    if "rho_h" not in sv.cache:
        sv.cache["rho_h"] = _residual_multiplier(sv)
    return sv.cache["rho_h"]


def _residual_multiplier(sv: SolutionView) -> CoefficientFunction:
    dv = sv.disc
    Q = L2(dv.mesh, order=max(dv.order - 2, 0))
    num, den = CoefficientFunction(0.0), 0.0
    for fd in sv.fields:
        f = GridFunction(Q)
        f.Set(fd.f, bonus_intorder=dv.quad_bonus + 4)
        num = num + (fd.sign / fd.mu) * (-fd.mu * Trace(fd.u.Operator("hesse")) - f)
        den += 1.0 / fd.mu
    if dv.curved:
        return num / den
    # straight elements: rho_h is in P_{p-2}(K), held exactly by its elementwise L2 projection (to round-off);
    # a GridFunction is evaluated without the Hessians of the fields (the shape of :class:`.multipliers.
    # ShapedContactMultiplier` evaluates it in every estimator integral)
    rho = GridFunction(Q, name="rho_h")
    rho.Set(num / den)
    return rho


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


def boundary_nodal_values(sv: SolutionView, contact: np.ndarray) -> np.ndarray:
    """(nv,) the mean of :func:`boundary_vertex_values` over the contact elements of every Dirichlet boundary
    vertex, NaN at the other vertices."""
    ev = sv.disc.element_vertices()
    vals = boundary_vertex_values(sv, contact)
    on = ~np.isnan(vals)
    n = np.bincount(ev[on], minlength=sv.disc.mesh.nv)
    total = np.bincount(ev[on], weights=vals[on], minlength=sv.disc.mesh.nv)
    return np.where(n > 0, total / np.maximum(n, 1), np.nan)
