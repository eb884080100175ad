"""Structural checks of a flux reconstruction and of the discrete complementarity.

Library functions used by tests and scenes alike (in the spirit of
dolfinx_eqlb's ``check_divergence_condition`` / ``check_jump_condition``):

* :func:`equilibration_defect` -- ||Pi_q (f_alpha + s_alpha lam^_h - div sigma_alpha_h)||_K,
  the equilibration of the seed slide "Component flux reconstruction";
* :func:`normal_jump` -- ||[sigma_alpha_h . n]|| on the interior edges (H(div) conformity);
* :func:`complementarity_report` -- signs of gap and multiplier, nodal and continuous.
"""
from __future__ import annotations

import numpy as np
from ngsolve import (TRIG, BilinearForm, FacetFESpace, GridFunction, IfPos, Integrate, IntegrationRule, L2, LinearForm,
                     TaskManager, div, dx, specialcf)

from ..domains import DIRICHLET
from .flux import FluxReconstruction
from .moments import data_rules
from .view import DiscretizationView, SolutionView

__all__ = ["projected_source", "equilibration_defect", "normal_jump", "complementarity_report"]


def _l2_projection(dv: DiscretizationView, q: int, lf_terms) -> GridFunction:
    """Elementwise L2 projection onto P_q of the functional w -> lf_terms(w)."""
    Q = L2(dv.mesh, order=q)
    u, w = Q.TnT()
    lf = LinearForm(lf_terms(w))
    with TaskManager():
        lf.Assemble()
    gh = GridFunction(Q)
    if dv.curved:
        # L2.SolveM is only approximate on curved elements (measured 2e-4): exact block-diagonal mass
        M = BilinearForm(u * w * dx(bonus_intorder=4)).Assemble()
        gh.vec.data = M.mat.Inverse(inverse="sparsecholesky") * lf.vec
    else:
        gh.vec.data = lf.vec
        Q.SolveM(rho=1.0, vec=gh.vec)
    return gh


def projected_source(disc, flux: FluxReconstruction, i: int) -> GridFunction:
    """Pi_q (f_i + s_i lam), the elementwise L2 projection onto P_q (lam = ``flux.lam``).

    f and lam are integrated with the FE load and mass rules
    (:func:`~.moments.data_rules`), the quadratures the discrete problem itself
    saw; on affine elements the lam term is exact (a non-polynomial lam^: the
    rule of the patch sources, ``flux.lam_rule``).
    """
    return _projected_source(DiscretizationView.of(disc), flux, i)


def _projected_source(dv: DiscretizationView, flux: FluxReconstruction, i: int) -> GridFunction:
    fd, rules = flux.fields[i], data_rules(dv)
    return _l2_projection(dv, flux.order, lambda w: fd.f * w * dx(intrules=rules["load"])
                          + fd.sign * flux.lam * w * _lam_dx(dv, flux))


def _lam_dx(dv: DiscretizationView, flux: FluxReconstruction):
    """The measure of the lam-part of the patch sources: the FE mass rule, or the fixed rule of a
    non-polynomial lam^ (``flux.lam_rule``)."""
    if flux.lam_rule is None:
        return dx(intrules=data_rules(dv)["mass"])
    return dx(intrules={TRIG: IntegrationRule(TRIG, flux.lam_rule)})


def equilibration_defect(disc, flux: FluxReconstruction) -> dict:
    """Equilibration error of every reconstructed flux.

    The defect is Pi_q (f_alpha + s_alpha lam - div sigma_alpha_h) (= Pi_q g - div sigma
    on affine elements; on curved elements div sigma = (div-hat sigma-hat) / det J is not
    in the mapped P_q, and equilibration means that its moments against P_q match).

    Returns
    -------
    dict
        for each field name: ``{"max_K": max_K ||defect||_K / ||Pi g||_Omega,
        "global": ||defect||_Omega / ||Pi g||_Omega}``, g = f_alpha + s_alpha lam.
        Round-off level (<= 1e-10) means exact equilibration.
    """
    out = {}
    dv = DiscretizationView.of(disc)
    rules = data_rules(dv)
    for i, (fd, sig) in enumerate(zip(flux.fields, flux.sigma)):
        gh = _projected_source(dv, flux, i)
        dh = _l2_projection(dv, flux.order, lambda w: fd.f * w * dx(intrules=rules["load"])
                            + fd.sign * flux.lam * w * _lam_dx(dv, flux) - div(sig) * w * dx(bonus_intorder=2))
        with TaskManager():
            dK = Integrate(dh * dh * dx(bonus_intorder=2), dv.mesh, element_wise=True).NumPy()
            ref = Integrate(gh * gh * dx(bonus_intorder=2), dv.mesh)
        scale = np.sqrt(max(ref, np.finfo(float).tiny))
        out[fd.name] = {"max_K": float(np.sqrt(np.maximum(dK, 0).max()) / scale),
                        "global": float(np.sqrt(max(dK.sum(), 0.0)) / scale)}
    return out


def normal_jump(flux: FluxReconstruction) -> dict:
    """Relative normal jumps of the broken RT fields over interior edges.

    The facet moments j_F(v) = sum_{K ⊃ F} <sigma|_K . n_K, v>_F for v in P_q(F)
    are assembled by NGSolve (both sides add, so j_F = <[sigma . n], v>_F);
    since [sigma . n] is in P_q(F), ||[sigma . n]||_F^2 = j^T M_F^{-1} j exactly.

    Returns
    -------
    dict
        field name -> ||[sigma . n]||_{interior edges} / (sum_K ||sigma . n||^2_dK)^(1/2).
    """
    mesh, q = flux.space.mesh, flux.order
    F = FacetFESpace(mesh, order=q, dirichlet=DIRICHLET)
    u, v = F.TnT()
    n = specialcf.normal(2)
    # element_boundary counts each interior edge twice: M2 = 2 M_F there
    M2 = BilinearForm(u * v * dx(element_boundary=True)).Assemble()
    inv = M2.mat.Inverse(F.FreeDofs(), inverse="sparsecholesky")
    out = {}
    for fd, sig in zip(flux.fields, flux.sigma):
        lf = LinearForm(sig * n * v * dx(element_boundary=True)).Assemble()
        tmp = lf.vec.CreateVector()
        tmp.data = inv * lf.vec
        jump2 = 2.0 * float(np.dot(tmp.FV().NumPy(), lf.vec.FV().NumPy()))
        scale2 = Integrate((sig * n) ** 2 * dx(element_boundary=True), mesh)
        out[fd.name] = float(np.sqrt(max(jump2, 0.0) / max(scale2, np.finfo(float).tiny)))
    return out


def complementarity_report(disc, x, y) -> dict:
    """Signs and products of the discrete gap and multiplier.

    Nodal quantities are what Newton enforces ((DS2) of [CAMWA21]); the
    continuous ones are what the estimators see (seed slide "Violations of
    the complementarity constraints": nodal signs do not imply pointwise
    signs for p >= 2).

    Returns
    -------
    dict
        ``gap_min_nodal`` (min (u1h - u2h)(x_l)), ``y_min`` (min X3),
        ``product_max_nodal`` (max |gap_l X3_l|), ``lam_neg_L2`` (||lam_h^neg||),
        ``gap_neg_L2`` (||(u1h - u2h)^neg||), ``contact_product``
        ((lam_h^pos, u1h - u2h)_Omega), ``lam_pos_L2``.
    """
    sv = SolutionView.of(disc, x, y)
    g = sv.disc.system.gap(sv.x)
    lam, gap = sv.gfs["lam"], sv.gfs["gap"]
    mesh, bonus = sv.disc.mesh, 2 * sv.disc.order + 4
    with TaskManager():
        vals = {
            "lam_neg_L2": Integrate(IfPos(-lam, lam * lam, 0) * dx(bonus_intorder=bonus), mesh),
            "lam_pos_L2": Integrate(IfPos(lam, lam * lam, 0) * dx(bonus_intorder=bonus), mesh),
            "gap_neg_L2": Integrate(IfPos(-gap, gap * gap, 0) * dx(bonus_intorder=bonus), mesh),
            "contact_product": Integrate(IfPos(lam, lam, 0) * gap * dx(bonus_intorder=bonus), mesh),
        }
    out = {"gap_min_nodal": float(g.min(initial=0.0)), "y_min": float(sv.y.min(initial=0.0)),
           "product_max_nodal": float(np.max(np.abs(g * sv.y), initial=0.0))}
    for k in ("lam_neg_L2", "lam_pos_L2", "gap_neg_L2"):
        out[k] = float(np.sqrt(max(vals[k], 0.0)))
    out["contact_product"] = float(vals["contact_product"])
    return out
