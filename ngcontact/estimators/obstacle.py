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

The obstacle chosen here is psi~ = b_h + (1 - chi)(psi - b_h), b_h = psi_h + w_h, with
* w_h in P_{p+2} the lifting of the trace Pi psi - psi_h on the Dirichlet edges (Pi: NGSolve's boundary projection
  onto P_{p+2}), discrete harmonic in a boundary strip, built like the Dirichlet data correction
  (:func:`.dirichlet.dirichlet_correction`; for g = psi on the whole boundary it is the lifting that corrects u_h),
  so that b_h has the trace Pi psi;
* chi the P1 cutoff with vertex values 1 on the contact neighbourhood -- the vertices of the elements that touch a
  vertex of an element with a touching node (nodal gap <= 0 or multiplier > 0), so that the multiplier's patches lie
  inside -- and 0 elsewhere.
Where chi = 1, psi~ = b_h: the gap u~_h - psi~ (u~_h = u_h + the data's lifting) of a full-contact element vanishes
(on the boundary layer too when g = psi on the whole Dirichlet boundary: then w_h is the data's lifting), and |||delta||| = |||chi (psi - b_h)||| = O(h^p) lives on the contact
neighbourhood and one layer around it.  On the Dirichlet edges delta = chi (psi - Pi psi): the trace defect of psi
in P_{p+2}, which the shift argument takes as negligible exactly as the bound takes the data's own (g - Pi g,
:func:`.dirichlet.trace_defect`); its indicator is added to ``eta_trace``, so ``bound_proven`` checks it.
:func:`.bound.estimate` evaluates both guaranteed bounds, with psi and with psi~ (+ |||delta|||), on the same fluxes
and reports the smaller.  The argument needs psi in H^1 where chi > 0, as the obstacle problem itself does: an
obstacle that jumps there is caught when psi - psi_h exceeds at a quadrature point what a continuous psi with the
element's gradient bound allows (:func:`_lipschitz_consistent`), and keeps the plain bound.  Measured (``tests/test_obstacle_shift.py``), P3, full contact: I_eff 2.0-2.2 on the unit
square for psi = sin sin (zero trace) and for psi = cos x cos y / 10 (contact up to a non-polynomial trace; plain
131 -> 719); on the curved unit disk 31.6 -> 18.9 over three levels (plain 93 -> 375), where the flux term eta_F
of the curved boundary layer dominates.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Optional

import numpy as np
from ngsolve import H1, TRIG, CoefficientFunction, GridFunction, Integrate, IntegrationRule, dx, grad

from ..discretizations.base import bit_array
from .dirichlet import dirichlet_correction, trace_defect
from .nonnegative import QuadratureArrays
from .terms import cf_gradient, element_diameters
from .view import FieldData, SolutionView

__all__ = ["ShiftedObstacle", "shifted_obstacle", "SAME_OBSTACLE", "LIPSCHITZ_SLACK"]

#: |||psi - psi~||| below this fraction of |||psi_h||| on the cutoff's support: psi is in the FE space (round-off)
SAME_OBSTACLE = 1e-10
#: |psi - psi_h| beyond LIPSCHITZ_SLACK h_K max |grad psi| at a point of K: psi jumps in K (:func:`_lipschitz_consistent`)
LIPSCHITZ_SLACK = 8.0


@dataclass
class ShiftedObstacle:
    """psi~ of the module docstring, its gradient, |||delta||| and the element parts of |||delta|||^2."""

    psi: CoefficientFunction
    grad: CoefficientFunction
    eta: float
    loc: np.ndarray
    cutoff: GridFunction
    eta_trace: float = 0.0  # the trace defect indicator of psi - Pi psi (module doc)


def _boundary_lifting(dv, psi_h, psi):
    """(w, eta_tr): the lifting w_h in P_{p+2} (:func:`.dirichlet.dirichlet_correction`) of the trace Pi psi - psi_h
    on the Dirichlet edges (None below round-off), and the trace defect indicator of psi - Pi psi; kept per
    discretization (they depend on psi and the mesh only)."""
    key = ("obstacle_lifting", id(psi))
    hit = dv.cache.get(key)
    if hit is None or hit[0] is not psi:
        k = dv.order + 2
        fd = FieldData("psi", dv.mus[0], 0.0, 1, psi_h, psi)
        w = dirichlet_correction(dv, [fd], k, None)[0][0]
        eta_tr = trace_defect(dv, [fd], k, key=("obstacle_trace", id(psi))) if w is not None else 0.0
        hit = dv.cache[key] = (psi, w, eta_tr)  # psi referenced: its id stays unique
    return hit[1], hit[2]


def _lipschitz_consistent(dv, psi, psi_h, support: np.ndarray) -> bool:
    """Whether |psi - psi_h| stays, on every element K of ``support``, within LIPSCHITZ_SLACK h_K max_K |grad psi| at
    the points of a rule of order 2p + 6 (module doc).  For psi Lipschitz on K with constant G,
    psi - psi_h = sum_i (psi - psi(x_i)) phi_i is at most G h_K times the Lebesgue constant of the nodes (below 4 up to
    P4); the slack covers that and the sampling of G.  A jump of psi in K (not H^1) breaks it: psi_h then differs
    from psi by the jump at points of K while grad psi, piecewise, does not see it."""
    rows = np.flatnonzero(support)
    qa = QuadratureArrays(dv.mesh, 2 * dv.order + 6, rows)
    gp = cf_gradient(psi)
    diff = np.abs(qa.values(psi - psi_h)).max(axis=1)
    slope = np.sqrt(qa.values(gp * gp)).max(axis=1)
    h = (dv.cache['h'] if 'h' in dv.cache else element_diameters(dv.mesh))[rows]
    scale = float(np.abs(psi_h.vec.FV().NumPy()).max(initial=0.0))
    return bool(np.all(diff <= LIPSCHITZ_SLACK * h * slope + 1e-13 * scale))


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
    w, eta_tr = _boundary_lifting(dv, psi_h, psi)
    base, gbase = (psi_h, grad(psi_h)) if w is None else (psi_h + w, grad(psi_h) + grad(w))  # trace Pi psi
    diff = psi - base
    V1 = H1(dv.mesh, order=1)
    chi = GridFunction(V1, name="obstacle_cutoff")
    chi.vec.FV().NumPy()[:] = one.astype(float)      # P1 dofs = vertices
    support = one[ev].any(axis=1)                     # chi != 0 there
    gpsi = cf_gradient(psi)
    gdiff = gpsi - gbase
    g_delta = grad(chi) * diff + chi * gdiff          # grad of delta = chi (psi - psi_h - w_h)
    if not support.any():
        return None
    if not _lipschitz_consistent(dv, psi, psi_h, support):
        return None
    dxs = dx(definedonelements=bit_array(support), intrules={TRIG: IntegrationRule(TRIG, 2 * dv.order + 6)})
    loc = dv.mus[0] * Integrate((g_delta * g_delta).Compile() * dxs, dv.mesh, element_wise=True).NumPy().copy()
    eta = math.sqrt(max(float(loc.sum()), 0.0))
    ref = dv.mus[0] * float(Integrate((grad(psi_h) * grad(psi_h)).Compile() * dxs, dv.mesh))
    if eta <= SAME_OBSTACLE * math.sqrt(max(ref, 0.0)):  # psi_h = psi up to round-off: psi is in the FE space
        return None
    rest = 1.0 - chi
    return ShiftedObstacle(psi=base + rest * diff, grad=gbase + rest * gdiff - grad(chi) * diff, eta=eta,
                           loc=np.maximum(loc, 0.0), cutoff=chi, eta_trace=eta_tr)
