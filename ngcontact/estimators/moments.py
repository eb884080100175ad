r"""Hat moments of discrete functionals and the vertex device of the patch sources.

A functional R on the interior Lagrange basis (R_l = (r, phi_l): the discrete multiplier D X3, an
algebraic residual) enters the patch problems of :mod:`.flux` only through its hat moments
R(psi_a) = sum_l psi_a(x_l) R_l (psi_a in P_p), so it can be represented by any function with these
moments.  The P1 representative

    r^ = sum_a c_a psi_a,     c_a = R(psi_a) / (psi_a, 1)

(:func:`p1_from_functional`) puts the patch-constant c_a on patch a; patch a then sees the source
psi_a c_a.  The patch-dependent constant is obtained from the vertex value of the P1 function by
a vertex quadrature rule (weights |K|/3) and a Taylor expansion of the test function at the vertex
(the *vertex device*, :func:`vertex_moment_term`): for affine K and w in P_2,

    (psi_a, w)_K / (|K|/3) = w(a) + 3/4 grad w(a) . (x_K - a)
                             + 1/2 D^2 w(a) : (S_a / 20 + 9/20 (x_K - a)(x_K - a)^T),

S_a = sum_v (v - a)(v - a)^T over the vertices v of K, x_K the centroid (moments
int lam_a lam_b^2 = |K|/30, int lam_a lam_b lam_c = |K|/60).  It is exact for RT degree q <= 2 on
affine elements; the batched solver of :mod:`.patches` takes patch-constant sources directly
(:func:`vertex_function_values`), exact for every q and on curved elements.

Data quadrature: compatibility of the patch problems holds exactly only if the patch data are
integrated like the FE system; :func:`data_rules` reproduces the rules of
:class:`~ngcontact.discretizations.fem.FEMDiscretization` (load: order 2p + quad_bonus; mass: order 2p).
"""
from __future__ import annotations

import numpy as np
from ngsolve import H1, L2, TRIG, GridFunction, IntegrationRule, LinearForm, TaskManager, dx, grad, x, y

from .view import DiscretizationView

__all__ = ["data_rules", "vertex_rule", "vertex_moments", "vertex_function_values", "vertex_moment_term",
           "p1_from_functional"]


def data_rules(dv: DiscretizationView) -> dict:
    """Quadrature rules of the FE system, to be reused by the patch problems.

    ``FEMDiscretization`` assembles the load with ``dx(bonus_intorder=quad_bonus)``
    (NGSolve: rule of order 2p + bonus on triangles) and the mass matrix defining
    the dual basis with the default rule (order 2p), also on curved elements.

    Returns
    -------
    dict
        ``{"load": {TRIG: rule}, "mass": {TRIG: rule}}`` for ``dx(intrules=...)``.
    """
    p = dv.order
    return {"load": {TRIG: IntegrationRule(TRIG, 2 * p + dv.quad_bonus)},
            "mass": {TRIG: IntegrationRule(TRIG, 2 * p)}}


def vertex_rule() -> IntegrationRule:
    """Trapezoidal (vertex) rule on the reference triangle, weights |K|/3."""
    return IntegrationRule(points=[(0, 0), (1, 0), (0, 1)], weights=[1 / 6, 1 / 6, 1 / 6])


def vertex_moments(dv: DiscretizationView):
    """(Psi, vol, V1): Psi[l, a] = psi_a(x_l) over interior Lagrange nodes l, vol_a = (psi_a, 1)
    (FE mass rule), V1 = H1(order 1) (vertex a = dof a).  For a functional R on the interior
    Lagrange basis (R_l = (r, phi_l)), Psi^T R are its hat moments R(psi_a) (psi_a in P_p)."""
    c = dv.cache
    if "psi" not in c:
        V1 = H1(dv.mesh, order=1)
        v = V1.TestFunction()
        with TaskManager():
            vol = LinearForm(v * dx(intrules=data_rules(dv)["mass"])).Assemble().vec.FV().NumPy().copy()
        c["psi"] = (dv.hats_at_nodes(), vol, V1)
    return c["psi"]


def p1_from_functional(dv: DiscretizationView, values: np.ndarray, name: str) -> GridFunction:
    """P1 function sum_a c_a psi_a with (., psi_a) = sum_l psi_a(x_l) values_l (module doc)."""
    Psi, vol, V1 = vertex_moments(dv)
    gf = GridFunction(V1, name=name)
    gf.vec.FV().NumPy()[:] = (Psi.T @ values) / vol
    return gf


def vertex_function_values(dv: DiscretizationView, g) -> np.ndarray:
    """(ne, 3) values of a vertex function at the local vertices of every element (local order of
    ``Discontinuous(H1(order=1))``): a P1 GridFunction (H1 order 1, dof = vertex) or an elementwise P1
    one (``Discontinuous(H1(order=1))``, dof 3K + i, e.g. :class:`.multipliers.PatchContactMultiplier`)."""
    vals = np.asarray(g.vec.FV().NumPy())
    ne = dv.mesh.ne
    if len(vals) == 3 * ne:
        return vals.reshape(ne, 3).copy()
    if len(vals) != dv.mesh.nv:
        raise ValueError(f"P1 or elementwise P1 GridFunction expected, got {len(vals)} dofs "
                         f"({dv.mesh.nv} vertices, {ne} elements)")
    return vals[dv.element_vertices()]


def vertex_moment_term(mesh, lam, q: int):
    """w -> integrand whose vertex-rule integral is (psi_a lam(a), w)_K, w in P_q, q <= 2 (module doc)."""
    ngmesh = mesh.ngmesh
    P = ngmesh.Coordinates()[ngmesh.Elements2D().NumPy()["nodes"][:, :3] - 1][:, :, :2]
    P0 = L2(mesh, order=0)

    def piecewise(values):
        gf = GridFunction(P0)
        gf.vec.FV().NumPy()[:] = values
        return gf

    xc, yc = piecewise(P[:, :, 0].mean(axis=1)), piecewise(P[:, :, 1].mean(axis=1))
    dxc, dyc = xc - x, yc - y  # x_K - a at the vertex a
    if q >= 2:
        vxx = piecewise((P[:, :, 0] ** 2).sum(axis=1))
        vxy = piecewise((P[:, :, 0] * P[:, :, 1]).sum(axis=1))
        vyy = piecewise((P[:, :, 1] ** 2).sum(axis=1))
        # S_a = sum_v (v - a)(v - a)^T,  M = S_a/20 + 9/20 (x_K - a)(x_K - a)^T
        Mxx = (vxx - 6 * xc * x + 3 * x * x) / 20 + 0.45 * dxc * dxc
        Mxy = (vxy - 3 * (xc * y + x * yc) + 3 * x * y) / 20 + 0.45 * dxc * dyc
        Myy = (vyy - 6 * yc * y + 3 * y * y) / 20 + 0.45 * dyc * dyc

    def term(w):
        out = w
        if q >= 1:
            gw = grad(w)
            out = out + 0.75 * (gw[0] * dxc + gw[1] * dyc)
        if q >= 2:
            H = w.Operator("hesse")
            out = out + 0.5 * (H[0, 0] * Mxx + 2 * H[0, 1] * Mxy + H[1, 1] * Myy)
        return (lam * out).Compile()
    return term
