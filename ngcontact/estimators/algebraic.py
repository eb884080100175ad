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

Limits: RT degree q <= 2 (P1 and P2; the P1 source uses the vertex-moment
formula of :mod:`.flux`).
"""
from __future__ import annotations

import math
from typing import List, Optional

import numpy as np
from ngsolve import H1, GridFunction, LinearForm, TRIG, dx, grad

from .flux import (PatchData, _vertex_moment_term, _vertex_rule, disc_cache, equilibrate_all, is_curved,
                   patch_regularization, patch_solver)
from ..domains import DIRICHLET

__all__ = ["algebraic_flux", "algebraic_correction_norm", "eta_alg_of"]


def _p1_data(disc):
    """(V1, test function, interior-vertex mask, (psi_a, 1) by the vertex rule, vertex rule), cached per disc."""
    c = disc_cache(disc)
    if "p1" not in c:
        V1 = H1(disc.mesh, order=1, dirichlet=DIRICHLET)
        v = V1.TestFunction()
        free = np.array(list(V1.FreeDofs()), dtype=bool)
        rule = {TRIG: _vertex_rule()}
        vol = LinearForm(v * dx(intrules=rule)).Assemble().vec.FV().NumPy().copy()
        c["p1"] = (V1, v, free, vol, rule)
    return c["p1"]


def _field_functions(disc, dx_alg: np.ndarray) -> List[GridFunction]:
    """d_alpha,h in the H1 space of ``disc`` from interior nodal values (zero Dirichlet)."""
    ni = disc.n_interior
    out = []
    for a in range(disc.nfields):
        X = np.zeros(disc.fes.ndof)
        X[disc.interior] = dx_alg[a * ni:(a + 1) * ni]
        gf = GridFunction(disc.fes, name=f"d_alg_{a + 1}")
        gf.vec.FV().NumPy()[:] = disc.nodes.T @ X
        out.append(gf)
    return out


def algebraic_flux(disc, dx_alg: np.ndarray, *, order: Optional[int] = None,
                   regularization: Optional[float] = None, batched: bool = True) -> List[GridFunction]:
    """sigma_alg,alpha for the correction ``dx_alg`` = x^{k,i+nu} - x^{k,i} (module docstring).

    Parameters
    ----------
    disc : FEMDiscretization
    dx_alg : ndarray
        x-block (all fields, interior nodes) of X^{k,i+nu} - X^{k,i}.
    order : int, optional
        RT degree q (default p; q <= 2).
    regularization, batched
        as in :func:`.flux.reconstruct_fluxes` (batched: the patch solver cached per discretization).

    Returns
    -------
    list of GridFunction
        one broken-RT_q GridFunction per field (normal-continuous by construction).
    """
    p = disc.order
    q = p if order is None else int(order)
    if q > 2:
        raise NotImplementedError(f"algebraic flux implemented for RT degree <= 2, got {q}")
    mesh = disc.mesh
    ds = _field_functions(disc, np.asarray(dx_alg, dtype=float))
    V1, v, free, vol, rule = _p1_data(disc)
    data = []
    for d, mu in zip(ds, disc.problem.mus):
        mom = LinearForm(mu * grad(d) * grad(v) * dx).Assemble().vec.FV().NumPy()  # small: no TaskManager
        g = GridFunction(V1, name="g_alg")
        g.vec.FV().NumPy()[:] = np.where(free, mom / vol, 0.0)  # (g, psi_a) = mu (grad d, grad psi_a)
        term = _vertex_moment_term(mesh, g, q)

        def source(w, term=term):  # -(psi_a g, w), vertex rule as in the flux module
            return -term(w) * dx(intrules=rule)
        data.append(PatchData(u=d, mu=mu, source=source, hessian=p > 1,
                              bonus_intorder=4 if is_curved(disc) else 0,
                              name=f"sigma_alg_{a_name(disc, len(data))}"))
    return equilibrate_all(mesh, q, data, regularization=patch_regularization(disc, regularization),
                           solver=patch_solver(disc, q) if batched else None)


def a_name(disc, i: int) -> str:
    return ("u1", "u2")[i] if disc.nfields == 2 else "u"


def eta_alg_of(disc, sigma_alg) -> float:
    """(sum_alpha ||mu_alpha^{-1/2} sigma_alg,alpha||^2)^{1/2}."""
    from ngsolve import Integrate

    s = 0.0
    for sig, mu in zip(sigma_alg, disc.problem.mus):
        s += float(Integrate(sig * sig * dx, disc.mesh)) / mu
    return math.sqrt(max(s, 0.0))


def algebraic_correction_norm(disc, dx_alg: np.ndarray) -> float:
    """|||d_h||| = (dx^T K dx)^{1/2}: the energy norm of an algebraic correction (exact, algebraic)."""
    dxa = np.asarray(dx_alg, dtype=float)[: disc.system.n]
    return math.sqrt(max(float(dxa @ (disc.system.K @ dxa)), 0.0))
