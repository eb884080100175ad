r"""Algebraic flux sigma_alg: an H(div) lifting of the algebraic error of an inexact Newton step.

Setting (seed slide "Inexact semismooth Newton method", [JSC20] Section 2.3):
step k of Newton solves A^{k-1} X^k = B^{k-1} iteratively; after i GMRES
iterations A^{k-1} X^{k,i} = B^{k-1} - R^{k,i}.  The algebraic error is
e^{k,i} = u_h^k - u_h^{k,i} (u_h^k: the exact solution of the linear step) and
the a posteriori analysis needs sigma_alg,alpha in H(div) with
div sigma_alg,alpha ~ r_alpha^{k,i} (the functional representation of
R^{k,i}) such that eta_alg = (sum_alpha ||mu_alpha^{-1/2} sigma_alg,alpha||^2)^{1/2}
estimates |||e^{k,i}|||.

Construction ("nu additional iterations", Ern-Vohralik SIAM J. Sci. Comput.
35 (2013) A1761, Section 6; Jiranek-Strakos-Vohralik SISC 32 (2010)): the
iterative solver is run nu more steps, giving X^{k,i+nu}.  The correction
d_h = u_h^{k,i+nu} - u_h^{k,i} (zero on the boundary) is an approximation of
e^{k,i} (GMRES on the SPD reduced system: |||d_h||| -> |||e^{k,i}||| as the
residual R^{k,i+nu} -> 0), and sigma_alg,alpha is the patchwise equilibrated
flux of -mu_alpha grad d_alpha,h with the source g_alpha in P_1 whose hat
moments are its own Galerkin residual,

    (g_alpha, psi_a) = mu_alpha (grad d_alpha,h, grad psi_a)      (every interior vertex a),

so that every patch problem is compatible and, by the Braess-Schoberl /
Ern-Vohralik equivalence, ||mu^{-1/2} sigma_alg,alpha|| is equivalent to
||mu^{1/2} grad d_alpha,h|| with constants independent of h (and in practice
within a few per cent of it, measured in ``tests/test_inexact.py``).  The
moments satisfy (g_1, psi_a) = (R^{k,i} - R^{k,i+nu})_{1,a} + (Delta lam_h, psi_a)_h
and similarly for alpha = 2 (Delta lam_h: the change of the multiplier over
the nu steps), i.e. sigma_alg lifts exactly the part of the algebraic
residual that the nu further steps remove; the remainder R^{k,i+nu} is what
[JSC20] calls the (negligible) remainder.

Why not the multilevel construction of [JSC20] (Papez-Rude-Vohralik-Wohlmuth
2020, residual lifted on a hierarchy of nested meshes): the study's meshes of
2k..35k elements are independent netgen meshes of the disk (as in [JSC20]'s
mesh sequence), so no hierarchy exists on most of them; the construction here
needs only the current mesh.  Its price is nu extra GMRES iterations per
estimator evaluation, which the inexact Newton driver counts (see
:mod:`ngcontact.newton.inexact`).

RT degree: :meth:`.options.EstimatorOptions.alg_flux_degree` (default p - 1, which contains
-mu grad d_h); q <= 2 (the P1 source uses the vertex device of :mod:`.moments`).

:func:`algebraic_terms` evaluates eta_alg of :mod:`.components` for a given or a global RT_0
algebraic flux.
"""
from __future__ import annotations

import math
from typing import List, Optional

import numpy as np
from ngsolve import H1, L2, TRIG, BilinearForm, GridFunction, Integrate, LinearForm, div, dx, grad

from ..discretizations.base import bit_mask
from ..domains import DIRICHLET
from .flux import PatchData, equilibrate_all, flux_bonus, patch_regularization, patch_solver, vertex_device_exact
from .moments import vertex_moment_term, vertex_rule
from .options import EstimatorOptions
from .terms import Integrals
from .view import DiscretizationView

__all__ = ["algebraic_flux", "algebraic_correction_norm", "algebraic_terms", "eta_alg_of"]


def _p1_data(dv: DiscretizationView):
    """(V1, test function, interior-vertex mask, (psi_a, 1) by the vertex rule, vertex rule, S) with
    S[a, j] = (grad phi_j, grad psi_a) (phi_j: the basis of ``dv.fes``; None on curved elements), cached per disc."""
    c = dv.cache
    if "p1" not in c:
        from scipy.sparse import csr_matrix

        V1 = H1(dv.mesh, order=1, dirichlet=DIRICHLET)
        v = V1.TestFunction()
        free = bit_mask(V1.FreeDofs())
        rule = {TRIG: vertex_rule()}
        vol = LinearForm(v * dx(intrules=rule)).Assemble().vec.FV().NumPy().copy()
        S = None
        if not dv.curved:
            form = BilinearForm(trialspace=dv.fes, testspace=V1)
            form += grad(dv.fes.TrialFunction()) * grad(v) * dx
            form.Assemble()
            S = csr_matrix(tuple(np.array(a) for a in form.mat.CSR()), shape=(V1.ndof, dv.fes.ndof))
        c["p1"] = (V1, v, free, vol, rule, S)
    return c["p1"]


def algebraic_flux(disc, dx_alg: np.ndarray, options: Optional[EstimatorOptions] = None) -> List[GridFunction]:
    """sigma_alg,alpha for the correction ``dx_alg`` = x^{k,i+nu} - x^{k,i} (module docstring).

    Parameters
    ----------
    disc : FEMDiscretization
    dx_alg : ndarray
        x-block (all fields, interior nodes) of X^{k,i+nu} - X^{k,i}.
    options : EstimatorOptions, optional
        RT degree (:meth:`~.options.EstimatorOptions.alg_flux_degree`, at most 2), ``batched``,
        ``regularization``.

    Returns
    -------
    list of GridFunction
        one broken-RT_q GridFunction per field (normal-continuous by construction).
    """
    opts = EstimatorOptions() if options is None else options
    dv = DiscretizationView.of(disc)
    p = dv.order
    q = opts.alg_flux_degree(p)
    if q > 2:
        raise NotImplementedError(f"algebraic flux implemented for RT degree <= 2, got {q}")
    mesh = dv.mesh
    ni = dv.n_interior
    dx_alg = np.asarray(dx_alg, dtype=float)
    V1, v, free, vol, rule, S = _p1_data(dv)
    vertex = opts.batched and vertex_device_exact(dv, q)  # exact patch-constant sources, no assembly
    data = []
    for a, (name, mu) in enumerate(zip(dv.names, dv.mus)):
        d = dv.interior_function(dx_alg[a * ni:(a + 1) * ni], f"d_alg_{a + 1}")  # d_alpha,h, zero Dirichlet
        if dv.curved:  # the quadrature of the linear form (not polynomial on curved elements)
            mom = LinearForm(mu * grad(d) * grad(v) * dx).Assemble().vec.FV().NumPy()  # small: no TaskManager
        else:  # (g, psi_a) = mu (grad d, grad psi_a), exact
            mom = mu * (S @ d.vec.FV().NumPy())
        gv = np.where(free, mom / vol, 0.0)
        vvals, lin = None, None
        if vertex:
            vvals = [(gv[dv.element_vertices()], None)]
        else:  # -(psi_a g, w) by the vertex device and rule of the flux module, an operator on g (.flux)
            g = GridFunction(V1, name="g_alg")
            g.vec.FV().NumPy()[:] = gv
            lin = [(g, 1.0, ("vertex device", q), lambda v, w: vertex_moment_term(mesh, v, q)(w) * dx(intrules=rule))]
        data.append(PatchData(u=d, mu=mu, hessian=p > 1, bonus_intorder=flux_bonus(dv), name=f"sigma_alg_{name}",
                              vertex_values=vvals, mass=lin))
    return equilibrate_all(mesh, q, data, regularization=patch_regularization(dv, opts.regularization),
                           solver=patch_solver(dv, q) if opts.batched else None)


def eta_alg_of(disc, sigma_alg) -> float:
    """(sum_alpha ||mu_alpha^{-1/2} sigma_alg,alpha||^2)^{1/2}."""
    dv = DiscretizationView.of(disc)
    s = 0.0
    for sig, mu in zip(sigma_alg, dv.mus):
        s += float(Integrate(sig * sig * dx, dv.mesh)) / mu
    return math.sqrt(max(s, 0.0))


def algebraic_correction_norm(disc, dx_alg: np.ndarray) -> float:
    """|||d_h||| = (dx^T K dx)^{1/2}: the energy norm of an algebraic correction (exact, algebraic)."""
    system = DiscretizationView.of(disc).system
    dxa = np.asarray(dx_alg, dtype=float)[: system.n]
    return math.sqrt(max(float(dxa @ (system.K @ dxa)), 0.0))


def _p0(mesh, values: np.ndarray) -> GridFunction:
    gf = GridFunction(L2(mesh, order=0))
    gf.vec.FV().NumPy()[:] = values
    return gf


def algebraic_terms(ig: Integrals, fields, r_hat, sigma_alg=None, parts=None):
    """(flux, mean-free, mean) parts of eta_alg of :mod:`.components` for the representations r^_alpha of
    the algebraic residual: ||mu^{-1/2} sigma_alg||, the Poincare bound of the mean-free part of
    r^ - div sigma_alg and the RT_0 bound of its element means.  ``sigma_alg`` None: the RT_0 mixed
    solution of div sigma_alg = Pi_0 r^ (one global Crouzeix-Raviart solve).  ``parts``: a -> (||sigma_alg||^2
    or None for the global solve, element means of r^ (sigma_alg None) or of rem = r^ - div sigma_alg,
    ||rem - mean_K rem||_K^2) computed elsewhere (:mod:`.affine_p1`)."""
    mesh, h, area = ig.mesh, ig.h, ig.area
    fl2, loc2, mean2 = 0.0, 0.0, 0.0
    for a, (fd, r) in enumerate(zip(fields, r_hat)):
        mu = fd.mu
        if parts is not None:
            sa2, mb, free2 = parts(a)
        elif sigma_alg is None:
            mb = ig.ew(r, dx) / area
            rem = r - _p0(mesh, mb)
            sa2, free2 = None, ig.ew(rem * rem)
        else:
            sa = sigma_alg[a]
            sa2 = Integrate(sa * sa * ig.dxq, mesh)
            rem = r - div(sa)
            mb = ig.ew(rem, dx(bonus_intorder=ig.bonus + 8)) / area
            free2 = ig.ew(rem * rem) - mb ** 2 * area
        # sa2 None: the RT_0 mixed solution of div sigma = Pi_0 r^ (global CR solve); r^ - Pi_0 r^ is mean-free
        fl2 += (ig.dual.norm(mb) ** 2 if sa2 is None else max(sa2, 0.0)) / mu
        loc2 += float(((h / math.pi) ** 2 * np.maximum(free2, 0.0)).sum()) / mu
        if sa2 is not None:
            mn = ig.C_F * math.sqrt(float((mb ** 2 * area).sum()))
            if mn > 0.0:
                mn = min(mn, ig.dual.norm(mb))
            mean2 += mn ** 2 / mu
    return math.sqrt(fl2), math.sqrt(loc2), math.sqrt(mean2)
