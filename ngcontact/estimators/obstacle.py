r"""Obstacle problems with a non-polynomial obstacle: the bound for the interpolated obstacle.

The discrete constraints hold at the nodes, where psi and its interpolant psi_h (the discretization's own: nodal
values, or Bernstein coefficients of them) agree.  On a contact element every node is active, u_h = psi_h there,
and the gap u_h - psi = psi_h - psi is the interpolation error of psi: the contact term 2 (lam~, u~_h - psi) of
:mod:`.bound` is O(h^{p+1}) over the contact set and its square root, O(h^{(p+1)/2}), exceeds the O(h^p) error
for p >= 2 (full contact, psi = sin(pi x) sin(pi y) / (2 pi^2), lam = 10, five uniform levels: I_eff 6.9 -> 26.8
for P2 and 26 -> 393 for P3; ``tests/test_obstacle_shift.py``).

Shifting the obstacle.  Let psi~ be an obstacle with delta = psi - psi~ in H^1_0.  Then K(psi) = K(psi~) + delta
(v >= psi~ and v = g on the boundary <=> v + delta >= psi and v + delta = g there), and testing the variational
inequality of u = u(psi) with u~ + delta and that of u~ = u(psi~) with u - delta and adding gives
a(u - u~, u - u~) <= a(u - u~, delta), i.e. |||u - u~||| <= |||delta|||.  Hence

    |||u - u_h||| <= |||u - u~||| + |||u~ - u_h||| <= |||delta||| + eta(psi~),

eta(psi~) the guaranteed bound of :mod:`.bound` for the obstacle psi~ (it holds for any u_h; u_h need not be the
discrete solution for psi~, although here it is: psi~ = psi at every node).

The obstacle chosen here is psi~ = psi_h + (1 - chi)(psi - psi_h), chi the P1 cutoff with vertex values 1 on the
contact neighbourhood -- the vertices of the elements that touch a vertex of an element with a touching node
(nodal gap <= 0 or multiplier > 0), so that the multiplier's patches lie inside -- and 0 elsewhere, also at the
Dirichlet vertices of a boundary edge on which psi_h differs from psi (then delta = chi (psi - psi_h) vanishes on the
boundary).  Where chi = 1, psi~ = psi_h: the gap of a full-contact element is 0 and its contact term vanishes, and
|||delta||| = O(h^p) lives on the contact neighbourhood and one layer around it.  :func:`.bound.estimate` evaluates
both guaranteed bounds, with psi and with psi~ (+ |||delta|||), on the same fluxes and reports the smaller.  Where the
contact set reaches Dirichlet edges on which psi is not a polynomial, chi < 1 on that boundary layer and its contact
term is the plain one: the gain is then partial (full contact on the unit disk, curved P3: I_eff 85.7 against 182).
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Optional

import numpy as np
from ngsolve import BND, H1, TRIG, CoefficientFunction, GridFunction, Integrate, IntegrationRule, dx, grad, x, y

from ..discretizations.base import bit_array
from ..domains import DIRICHLET
from .view import SolutionView

__all__ = ["ShiftedObstacle", "shifted_obstacle", "BOUNDARY_ROUNDOFF", "SAME_OBSTACLE"]

#: |psi - psi_h| on a Dirichlet edge below this fraction of max |psi_h| counts as zero (round-off of the data)
BOUNDARY_ROUNDOFF = 1e-13
#: |||psi - psi~||| below this fraction of |||psi_h||| on the cutoff's support: psi is in the FE space (round-off)
SAME_OBSTACLE = 1e-10


@dataclass
class ShiftedObstacle:
    """psi~ of the module docstring, its gradient, |||delta||| and the element parts of |||delta|||^2."""

    psi: CoefficientFunction
    grad: CoefficientFunction
    eta: float
    loc: np.ndarray
    cutoff: GridFunction


def _obstacle_gradient(psi) -> CoefficientFunction:
    return CoefficientFunction((psi.Diff(x), psi.Diff(y)))


def _inexact_boundary_vertices(dv, diff, scale: float) -> np.ndarray:
    """Vertex mask: the vertices of the Dirichlet edges e on which psi - psi_h exceeds round-off (module doc):
    ||psi - psi_h||_e^2 > (BOUNDARY_ROUNDOFF scale)^2 |e|."""
    mesh = dv.mesh
    bad = np.zeros(mesh.nv, dtype=bool)
    d2 = Integrate(diff * diff, mesh, BND, element_wise=True, order=2 * dv.order + 6).NumPy()
    dirichlet = mesh.Boundaries(DIRICHLET).Mask()
    for el in mesh.Elements(BND):
        if dirichlet[el.index]:
            ends = [np.array(mesh[v].point) for v in el.vertices]
            if d2[el.nr] > (BOUNDARY_ROUNDOFF * scale) ** 2 * float(np.linalg.norm(ends[1] - ends[0])):
                bad[[v.nr for v in el.vertices]] = True
    return bad


def shifted_obstacle(sv: SolutionView) -> Optional[ShiftedObstacle]:
    """psi~ for the iterate ``sv`` (module docstring), or None: no obstacle, or psi = psi_h (a polynomial of degree p,
    so that psi~ = psi), or no node touches the obstacle."""
    dv = sv.disc
    psi = dv.obstacle
    if psi is None:
        return None
    disc = dv._disc
    nodes = disc.nodes
    psi_h = dv.function(nodes.from_values(nodes.evaluate(psi)), "psi_h")
    # touching nodes: nodal gap <= 0 or a positive multiplier
    touching = np.zeros(nodes.ndof, dtype=bool)
    touching[dv.interior[(dv.system.gap(sv.x) <= 0.0) | (sv.y > 0.0)]] = True
    elem_nodes = getattr(nodes, "lagrange", nodes).elem_nodes  # Bernstein: coefficients numbered like the nodes
    elements = touching[elem_nodes].any(axis=1)
    if not elements.any():
        return None
    ev = dv.element_vertices()
    near = np.zeros(dv.mesh.nv, dtype=bool)
    near[ev[elements].ravel()] = True
    patch = near[ev].any(axis=1)                      # the elements touching those vertices
    one = np.zeros(dv.mesh.nv, dtype=bool)
    one[ev[patch].ravel()] = True
    diff = psi - psi_h
    scale = float(np.abs(psi_h.vec.FV().NumPy()).max(initial=0.0))
    one &= ~_inexact_boundary_vertices(dv, diff, scale)
    V1 = H1(dv.mesh, order=1)
    chi = GridFunction(V1, name="obstacle_cutoff")
    chi.vec.FV().NumPy()[:] = one.astype(float)      # P1 dofs = vertices
    support = one[ev].any(axis=1)                     # chi != 0 there
    gpsi = _obstacle_gradient(psi)
    gdiff = gpsi - grad(psi_h)
    g_delta = grad(chi) * diff + chi * gdiff          # grad of delta = chi (psi - psi_h)
    if not support.any():
        return None
    dxs = dx(definedonelements=bit_array(support), intrules={TRIG: IntegrationRule(TRIG, 2 * dv.order + 6)})
    loc = dv.mus[0] * Integrate((g_delta * g_delta).Compile() * dxs, dv.mesh, element_wise=True).NumPy().copy()
    eta = math.sqrt(max(float(loc.sum()), 0.0))
    ref = dv.mus[0] * float(Integrate((grad(psi_h) * grad(psi_h)).Compile() * dxs, dv.mesh))
    if eta <= SAME_OBSTACLE * math.sqrt(max(ref, 0.0)):  # psi_h = psi up to round-off: psi is in the FE space
        return None
    rest = 1.0 - chi
    return ShiftedObstacle(psi=psi_h + rest * diff, grad=grad(psi_h) + rest * gdiff - grad(chi) * diff, eta=eta,
                           loc=np.maximum(loc, 0.0), cutoff=chi)
