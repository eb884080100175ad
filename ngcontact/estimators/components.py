r"""Error components of an arbitrary Newton / linear-solver iterate: eta_disc, eta_lin, eta_alg
(seed slides "Corollary (Distinction of the error components)", appendix "Discretization flux
reconstruction", "Strategy for constructing the estimators", "Distinguishing the error
components"; [JSC20] Sections 3-4).

The iterate.  X^{k,i} = (x, y), x = [X1, X2] (interior Lagrange values of u1h, u2h), y = X3
(lumped nodal multiplier for p = 1, dual-basis coefficients for p >= 2), in the layout of
``disc.system`` (:mod:`ngcontact.algebra.system`).  It need not satisfy anything: not the
complementarity (Newton not converged), not the linear equations (inexact linear solve).

Algebraic residual.  The first two block rows of every Newton-step matrix A^{k-1} are those of
E = [[mu1 S, 0, -D], [0, mu2 S, D]] (only the third block row, the linearized C-function,
changes with k), so the PDE part of R^{k,i} = B^{k-1} - A^{k-1} X^{k,i} is

    R_alpha = F_alpha - (E X)_alpha = -(K x - B^T D y - F)_alpha,

computed here from (x, y) (``r_alg`` is only cross-checked; its third block is not needed: the
estimate is evaluated for the actual (u_h, lam_h) of the iterate, whose complementarity defects
all go into eta_lin whatever the linearization was).  R_alpha is a functional on the interior
Lagrange basis; it is represented by the P1 function (p <= 2, RT degree q <= 2)

    r^_alpha = sum_a c_a psi_a,   c_a = (sum_l psi_a(x_l) R_alpha,l) / (psi_a, 1)

(the same device as the P1 multiplier lam^_h of :mod:`.flux`; p = 1: c_a = R_a / D_a), or for
q >= 3 by the dual-basis function r_h with (r_h, phi_l) = R_l.  Either way
(r^_alpha, psi_a) = R_alpha(psi_a) for every vertex a, which is what the patches need.

Fluxes (seed "Component flux reconstruction").  sigma_alpha,disc is the patchwise equilibrated
flux of :func:`.flux.equilibrate` with the data f_alpha - (-1)^alpha lam^_h - r^_alpha; the
interior patches are compatible because the patch moment of this datum equals the (inexact)
discrete equation tested with psi_a.  So div sigma_disc = Pi_q (f + s lam^ - r^) exactly.
sigma_alpha,alg (div sigma_alg ~ r^) is either given by the caller (``sigma_alg``; e.g. built
on a mesh hierarchy, [JSC20] / Papez-Rude-Vohralik-Wohlmuth) or, if ``r_alg`` is given and
``sigma_alg`` is not, built here by ONE GLOBAL solve: the lowest-order mixed (RT_0 x P_0)
solution of div sigma_alg = Pi_0 r^ (Crouzeix-Raviart solve + Marini's formula, the
``_P0Dual`` of :mod:`.estimators`; cost of one P1 Cholesky).  A patchwise equilibration of the
algebraic residual alone is not possible: its interior-patch moments R(psi_a) do not vanish.
Whatever sigma_alg is, the remaining algebraic datum r^ - div sigma_alg is bounded in H^{-1}
by Poincare on every element for its mean-free part and by the RT_0 field of its element means:

    eta_alg = (sum_alpha ||mu_alpha^{-1/2} sigma_alpha,alg||^2)^{1/2}
              + (sum_alpha mu_alpha^{-1} sum_K (h_K/pi)^2 ||r^ - div sigma_alg - mean_K||_K^2)^{1/2}
              + (sum_alpha mu_alpha^{-1} ||zeta(mean_K(r^ - div sigma_alg))||^2)^{1/2}.

(The seed writes only the first term, assuming div sigma_alg = r exactly.)

Nonconformity and contact: which term goes where.  s_h is the seed's step 1 (nodal averaging
where the nodal gap is negative, mu-weighted as in :mod:`.estimators`, t = mu2/(mu1 + mu2)):
s_h - u_h = (t, -(1 - t)) I_p(g_h^-), g_h^- the negative part of the NODAL gap; the nodal gap
of s_h is >= 0.  s~_h in K_g corrects the remaining pointwise negative part of the gap of
s_h + w_h (w_h: Dirichlet-data correction of :mod:`.estimators`), s~_h - (s_h + w_h) =
(t, -(1 - t)) (g_s)^-, g_s = gap(s_h + w_h) (in place of the seed's c_K bubble step, see
:func:`admissible_correction` for the reason).  Multiplier: lam^_h = lam^(y) (p = 1: the P1 moments
function above; p >= 2: the contact multiplier of :mod:`.flux`, a linear map of the moments once
the contact elements are fixed from y^+) is split linearly, lam^(y) = lam^(y^+) + lam^(y^-);
lam~_h >= 0 is lam^(y^+) where it is already >= 0 (p = 1, and p >= 2 with q <= 2) or its minimal
nonnegative modification (q >= 3, :func:`.estimators.nonnegative_multiplier`).

    term (seed name)                                     component   zero at convergence?
    eta_F(sigma_disc), eta_R, eta_quad                   disc        no
    |||s~_h - s_h - w_h|||      (seed |||s~ - s|||)       disc        no for p >= 2
    |||s_h - u_h|||             (seed |||s - u|||)        lin         yes (nodal gaps >= 0)
    C ||lam^(y^+) - lam~_h||  (seed C||lam^neg - lam~^neg||)  disc    no for q >= 3
      (includes the concentration defect of :func:`.estimators.concentrated_multiplier`)
    C ||lam^(y^-)||           (seed C||lam~^neg||)       lin         yes (y >= 0)
    2P_disc = max(2 (lam~, g_h) - P_lin + 2 (lam~, (g_s)^-), 0)
              (seed 2(lam^pos - lam, g) and the s~ - s part of eta_nonc,3)   disc   no
    2P_lin  = max(P_lin + 2 (lam~, I_p(g_h^-)), 0),  P_lin = 2 sum_l D_l y_l^+ g_l
              (seed 2(lam_h, g), the discrete product, and the s - u part of eta_nonc,3)  lin  yes
    eps_w, |||w_h|||           (Dirichlet data)          disc        no
    sigma_alg terms                                      alg         yes (exact solve)

For p = 1 with exact Dirichlet data this is the seed's p = 1 split (there the whole contact
term sits in eta_disc; P_lin, the discrete product, vanishes identically for Newton-min
iterates and at convergence of any C-function, so the two agree there), for p >= 2 the seed's
p >= 2 split.  C = C_{Omega,mu} enters through the multiplier-defect norm of
:mod:`.estimators` (Poincare per element + RT_0 for the means), sharper than C_F ||.||.

Direct combination (used when its eta_disc + eta_lin is the smaller; proof: "Direct bound" of
:mod:`.estimators`, with A = A_disc + A_lin + eta_alg, A_disc = eta_FR + eta_quad + eta_nonc2,disc +
d_disc, A_lin = eta_nonc2,lin + d_lin, B = Theta + sum eta_C / 2 <= B_disc + B_lin,
B_disc = max(Theta_disc + (sum eta_C - P_lin)/2, 0), B_lin = max(Theta_lin + P_lin/2, 0), Theta
split linearly with the correction n = (s~ - s_h - w_h) + (s_h - u_h), and
A/2 + (A^2/4 + B)^{1/2} = A/2 + |(A/2, B^{1/2})| <= the sum of the same per component):

    eta_disc = hypot(A_disc/2 + hypot(A_disc/2, B_disc^{1/2}) + eps_w, eta_bc)
    eta_lin  = A_lin/2 + hypot(A_lin/2, B_lin^{1/2}).

Combination of the seed's route (proof: :mod:`.estimators` with a = eta_FR + eta_quad + eta_nonc,2,
d = eta_nonc,1, 2P = sum eta_C + eta_nonc,3, and |||u - u_h|||^2 <=
(hypot(a + d, sqrt(2P)) + d + eps_w)^2 + eta_bc^2; every argument splits as
a <= a_disc + a_lin + eta_alg, d <= d_disc + d_lin, 2P <= 2P_disc + 2P_lin, and the
Euclidean triangle inequality gives the Corollary)

    E_disc   = hypot(eta_FR,disc + eta_quad + eta_nonc2,disc + d_disc, sqrt(2 P_disc))
    eta_disc = hypot(E_disc + d_disc + eps_w, eta_bc)
    eta_lin  = hypot(eta_nonc2,lin + d_lin, sqrt(2 P_lin)) + d_lin
    |||u - u_h||| <= eta := eta_disc + eta_lin + eta_alg.

This is sharper than the seed's additive formulas (which bound it): at a converged exact
solution eta_lin = sqrt(2|P_lin|) ~ round-off, eta_alg = 0 and eta_disc equals the total eta
of :func:`.estimators.estimate` (same fluxes, same terms).
"""
from __future__ import annotations

import math
import time
import warnings
from dataclasses import dataclass, field
from typing import Callable, List, Optional, Sequence

import numpy as np
from ngsolve import (L2, CoefficientFunction, GridFunction, IfPos, Integrate, TaskManager, TRIG,
                     div, dx, grad)

from ..algebra.cfunctions import get_cfunction
from .estimators import (QuadratureArrays, _P0Dual, _contact_work, _corrected_fields, _dirichlet_lifting, _mean_term,
                         concentrated_multiplier, element_diameters, friedrichs_constant, nonnegative_multiplier)
from .flux import (ContactMultiplier, PatchContactMultiplier, PatchData, _vertex_moment_term, _vertex_rule,
                   data_rules, disc_cache, equilibrate_all, field_data, is_curved, patch_regularization,
                   patch_solver, vertex_device_exact, vertex_function_values, vertex_moments)

__all__ = ["Components", "estimate_components", "algebraic_residual_function", "newton_history",
           "newton_iterates", "plot_components_history", "ComponentsHistory"]


@dataclass
class Components:
    """Error components of one iterate (formulas: module docstring).

    Attributes
    ----------
    eta_disc, eta_lin, eta_alg : float
        the components of the Corollary.
    eta : float
        eta_disc + eta_lin + eta_alg >= |||u - u_h^{k,i}|||.
    eta_K : ndarray (nelements,)
        local discretization indicators (sum_alpha (eta_F,disc + eta_R)^2 + max(eta_C,K, 0))^{1/2},
        for marking.
    eta_K_lin : ndarray (nelements,)
        local |||s_h - u_h|||_K (where the iterate violates the nodal constraint).
    terms : dict
        every sub-term (names of the table in the module docstring).
    res_alg : float
        ||R_alpha|| / ||F|| of the PDE rows (the algebraic residual actually estimated).
    err_energy : float or None
        |||u - u_h||| when requested and the exact solution is known.
    time_total : float
        wall time [s] (error computation excluded).
    sigma_disc : list of GridFunction
        sigma_alpha,disc (broken RT_q, normal-continuous).
    r_hat : list of GridFunction or None
        the representation r^_alpha of the algebraic residual (None if it is zero).
    data : list of GridFunction
        m_alpha = s_alpha lam^_h - r^_alpha: div sigma_alpha,disc = Pi_q (f_alpha + m_alpha).
    """

    eta_disc: float
    eta_lin: float
    eta_alg: float
    eta: float
    eta_K: np.ndarray
    eta_K_lin: np.ndarray
    terms: dict
    res_alg: float = 0.0
    err_energy: Optional[float] = None
    time_total: float = 0.0
    sigma_disc: Optional[list] = field(default=None, repr=False)
    r_hat: Optional[list] = field(default=None, repr=False)
    data: Optional[list] = field(default=None, repr=False)

    @property
    def i_eff(self) -> float:
        """eta / |||u - u_h||| (nan without exact solution)."""
        return self.eta / self.err_energy if self.err_energy else float("nan")

    def summary(self) -> dict:
        """Flat dict: ``eta_disc, eta_lin, eta_alg, eta_total`` (= eta), every sub-term prefixed
        ``c_``, ``res_alg``, ``time_components_s`` and, with an exact solution, ``err_energy``,
        ``i_eff_total``."""
        out = {"eta_disc": self.eta_disc, "eta_lin": self.eta_lin, "eta_alg": self.eta_alg,
               "eta_total": self.eta, "res_alg": self.res_alg, "time_components_s": self.time_total}
        out.update({f"c_{k}": v for k, v in self.terms.items()})
        if self.err_energy is not None:
            out["err_energy"] = self.err_energy
            out["i_eff_total"] = self.i_eff
        return out


# ------------------------------------------------------------------ per-discretization cache
def _p1_from_functional(disc, values: np.ndarray, name: str) -> GridFunction:
    """P1 function sum_a c_a psi_a with (., psi_a) = sum_l psi_a(x_l) values_l (module doc)."""
    Psi, vol, V1 = vertex_moments(disc)
    gf = GridFunction(V1, name=name)
    gf.vec.FV().NumPy()[:] = (Psi.T @ values) / vol
    return gf


def _dual_from_functional(disc, values: np.ndarray, name: str) -> GridFunction:
    """Dual-basis function r_h in P_p with (r_h, phi_l) = values_l (interior l), 0 on the boundary nodes."""
    rhs = np.zeros(disc.fes.ndof)
    rhs[disc.interior] = values
    gf = GridFunction(disc.fes, name=name)
    gf.vec.FV().NumPy()[:] = disc.nodes.T @ disc.mass_nodal_lu().solve(rhs)
    return gf


def _use_p1(disc, q: int) -> bool:
    """Patch-constant vertex device or exact mass-rule products: the choice of :func:`.flux.reconstruct_fluxes`."""
    return vertex_device_exact(disc, q)


def algebraic_residual_function(disc, x, y, *, flux_order: Optional[int] = None) -> list:
    """r^_alpha per field: the function representing the PDE rows of the algebraic residual
    R = F - E X of the iterate (module docstring); an algebraic flux passed to
    :func:`estimate_components` should satisfy div sigma_alpha,alg = r^_alpha.

    Returns
    -------
    list of GridFunction
        P1 (RT degree q <= 2) or dual-basis P_p (q >= 3) functions.
    """
    q = disc.order if flux_order is None else int(flux_order)
    R = -disc.system.residual(np.asarray(x, float), np.asarray(y, float))
    ni = disc.n_interior
    make = _p1_from_functional if _use_p1(disc, q) else _dual_from_functional
    return [make(disc, R[a * ni:(a + 1) * ni], f"r_alg_{a + 1}") for a in range(disc.nfields)]


def _gf_combination(a: GridFunction, ca: float, b: Optional[GridFunction], cb: float, name: str) -> GridFunction:
    gf = GridFunction(a.space, name=name)
    gf.vec.data = ca * a.vec
    if b is not None:
        gf.vec.data += cb * b.vec
    return gf


def _defect_norm(delta, ew, h, area, C_F, C_mu, dual, ref) -> float:
    """C_mu [(sum_K (h_K/pi)^2 ||delta - delta_K||_K^2)^{1/2} + ||zeta(delta_K)||]: bound of
    sup_z (delta, z1 - z2) / |||z||| (eta_nonc,2 of :mod:`.estimators`)."""
    dbar = ew(delta) / area
    loc = float(((h / math.pi) ** 2 * np.maximum(ew(delta * delta) - dbar ** 2 * area, 0.0)).sum())
    dnorm = C_F * math.sqrt(float((dbar ** 2 * area).sum()))
    if dnorm > 1e-3 * max(ref, np.finfo(float).tiny):
        dnorm = min(dnorm, dual.norm(dbar))
    return C_mu * (math.sqrt(loc) + dnorm)


def admissible_correction(disc, gap_s, ggap_s, dxq, exact_polynomial_gap: bool):
    r"""(|||s~_h - (s_h + w_h)|||, (g_s)^-) for the pointwise negative part of the gap of s_h + w_h.

    The seed's p >= 2 step 2-3 adds c_K Psi_K / 2 with c_K = min{c > 0 : (s1h - s2h)|_K + c Psi_K >= 0};
    with an element bubble Psi_K this cannot repair a gap that is negative on an EDGE (for P2,
    nodal values a, b, m >= 0 on an edge give a negative gap at t = 1/4 as soon as b > 3a + 6m),
    and a conforming non-bubble Psi_K couples neighbouring c_K.  We use the H^1 function
    (t, -(1 - t)) (g_s)^- instead (t = mu2/(mu1 + mu2)): admissible everywhere, and
    |||.||| = (mu1 mu2/(mu1 + mu2))^{1/2} ||grad (g_s)^-||, no constant to estimate.
    """
    mus = disc.problem.mus
    t = mus[1] / (mus[0] + mus[1]) if len(mus) == 2 else 1.0
    weight = mus[0] * t ** 2 + (mus[1] * (1 - t) ** 2 if len(mus) == 2 else 0.0)
    if exact_polynomial_gap:  # P1 gap with nonnegative nodal values: >= 0 everywhere
        return 0.0, None
    val = Integrate(IfPos(-gap_s, ggap_s * ggap_s, 0.0) * dxq, disc.mesh)
    return math.sqrt(weight * max(val, 0.0)), IfPos(-gap_s, -gap_s, 0.0)


def estimate_components(disc, x, y, *, r_alg=None, sigma_alg=None, flux_order=None,
                        errors: bool = False, dirichlet_correction=True, friedrichs: Optional[float] = None,
                        bonus_intorder: Optional[int] = None, regularization: Optional[float] = None,
                        res_tol: float = 1e-12, batched: bool = True) -> Components:
    """eta_disc, eta_lin, eta_alg of an arbitrary iterate X^{k,i} (seed Corollary; module docstring).

    Parameters
    ----------
    disc : FEMDiscretization
    x : ndarray
        [X1, X2] (interior-node values of u1h, u2h; ``[X1]`` for the obstacle problem), layout of
        ``disc.system``.
    y : ndarray
        X3 (lumped multiplier for p = 1, dual basis for p >= 2).
    r_alg : ndarray, optional
        None for an exact linear solve; else B - A X of the current Newton-step system in the
        3-field layout (length len(x) + len(y)).  Its first len(x) entries must equal
        F - E X (checked; a warning if not): that is what is estimated.  The third block is not
        used (see module docstring).
    sigma_alg : list of GridFunction, optional
        algebraic fluxes per field (RT, H(div)-conforming; ideally div sigma_alg = r^_alpha of
        :func:`algebraic_residual_function`).  None with ``r_alg`` given: one global RT_0
        mixed solve (module docstring).  None with ``r_alg`` None: zero, unless the residual
        of (x, y) exceeds ``res_tol`` ||F|| (then the global solve is done anyway, so that the
        bound stays guaranteed).
    flux_order : int, optional
        RT degree q of sigma_disc (default p).
    errors : bool
        also compute |||u - u_h||| (exact solution needed) for ``i_eff``.
    dirichlet_correction, friedrichs, bonus_intorder, regularization
        as in :func:`.estimators.estimate`.
    res_tol : float
        relative residual below which an exact solve is assumed when r_alg is None.
    batched : bool
        batched patch solver (default; its setup is cached per discretization and reused by
        every iterate) or NGSolve's PatchwiseSolve (:func:`.flux.equilibrate_all`).

    Returns
    -------
    Components
    """
    t0 = time.perf_counter()
    x = np.asarray(x, dtype=float)
    y = np.asarray(y, dtype=float)
    mesh, p, system = disc.mesh, disc.order, disc.system
    prob = disc.problem
    q = p if flux_order is None else int(flux_order)
    ni, nf = disc.n_interior, disc.nfields
    if len(x) != nf * ni or len(y) != ni:
        raise ValueError(f"x must have {nf * ni} and y {ni} entries, got {len(x)} and {len(y)}")

    # ---------------------------------------------------------------- algebraic residual
    scale = max(float(np.linalg.norm(system.F)), np.finfo(float).tiny)
    R = -system.residual(x, y)  # F - E X, PDE rows
    res_alg = float(np.linalg.norm(R)) / scale
    if r_alg is not None:
        r_alg = np.asarray(r_alg, dtype=float)
        if len(r_alg) != len(x) + len(y):
            raise ValueError(f"r_alg must have {len(x) + len(y)} entries, got {len(r_alg)}")
        if np.linalg.norm(r_alg[:len(x)] - R) > 1e-8 * scale + 1e-6 * np.linalg.norm(R):
            warnings.warn("r_alg[:len(x)] differs from F - E X of the iterate; estimating F - E X", stacklevel=2)
    inexact = r_alg is not None or sigma_alg is not None or res_alg > res_tol
    use_p1 = _use_p1(disc, q)
    make = _p1_from_functional if use_p1 else _dual_from_functional
    r_hat = [make(disc, R[a * ni:(a + 1) * ni], f"r_alg_{a + 1}") for a in range(nf)] if inexact else None

    # ---------------------------------------------------------------- multiplier lam^(y) = lam^(y+) + lam^(y-)
    gfs = disc.gridfunctions(x, y)
    fields = field_data(disc, gfs)
    D = disc.D
    yp, yn = np.maximum(y, 0.0), np.minimum(y, 0.0)
    lam_order = 1
    if p == 1:  # the lumped P1 multiplier, >= 0 for y >= 0
        lam_p = _p1_from_functional(disc, D * yp, "lam_pos")
        lam_n = _p1_from_functional(disc, D * yn, "lam_neg") if (yn < 0).any() else None
        lam_hat = _gf_combination(lam_p, 1.0, lam_n, 1.0, "lam_hat")
    else:  # contact multiplier of .flux (marker from y+), one linear map for both parts
        cmult = (PatchContactMultiplier if use_p1 else ContactMultiplier)(disc, yp)
        lam_p = cmult(D * yp, "lam_pos")
        lam_n = cmult(D * yn, "lam_neg") if (yn < 0).any() else None
        lam_hat = lam_p if lam_n is None else lam_p + lam_n

    # ---------------------------------------------------------------- sigma_disc
    fbonus = 4 if is_curved(disc) else 0
    rules = data_rules(disc)
    vertex_dx, mass_dx = dx(intrules={TRIG: _vertex_rule()}), dx(intrules=rules["mass"])
    sig_d, data, patch_data = [], [], []
    t_flux = time.perf_counter()
    lam_v = None
    if use_p1 and batched:  # vertex values of lam^ (both fields), for the batched patch-constant sources
        lam_v = vertex_function_values(disc, lam_p)
        if lam_n is not None:
            lam_v = lam_v + vertex_function_values(disc, lam_n)
    for a, fd in enumerate(fields):
        # m_alpha = s_alpha lam^ - r^_alpha; P1 functions by the patch-constant vertex device
        # (module doc of .flux), elementwise/dual ones exactly with the FE mass rule
        r = r_hat[a] if r_hat else None
        if p == 1:
            m = _gf_combination(lam_hat, float(fd.sign), r, -1.0, f"m_{fd.name}")
        else:
            m = fd.sign * lam_hat if r is None else fd.sign * lam_hat - r
        vvals = None
        if lam_v is not None:  # vertex functions: exact patch-constant sources of the batched solver
            vterm, mterm = None, None
            vvals = fd.sign * lam_v
            if r is not None:
                vvals = vvals - vertex_function_values(disc, r)
        elif use_p1:  # P1 / elementwise-P1 vertex functions: the patch-constant vertex device
            vterm, mterm = _vertex_moment_term(mesh, m, q), None
        else:  # q >= 3: exact products with the FE mass rule
            vterm, mterm = None, m
        data.append(m)

        def source(w, fd=fd, vterm=vterm, mterm=mterm):
            out = -fd.f * w * dx(intrules=rules["load"])
            if vterm is not None:
                out += -vterm(w) * vertex_dx
            if mterm is not None:
                out += -mterm * w * mass_dx
            return out
        patch_data.append(PatchData(u=fd.u, mu=fd.mu, source=source, hessian=p > 1, bonus_intorder=fbonus,
                                    name=f"sigma_disc_{fd.name}",
                                    vertex_values=None if vvals is None else [(vvals, None)]))
    sig_d = equilibrate_all(mesh, q, patch_data, regularization=patch_regularization(disc, regularization),
                            solver=patch_solver(disc, q) if batched else None)
    t_flux = time.perf_counter() - t_flux

    bonus = disc.quad_bonus + 4 if bonus_intorder is None else int(bonus_intorder)
    dxq = dx(bonus_intorder=bonus)
    mus = prob.mus
    h = element_diameters(mesh)
    C_F = friedrichs_constant(prob, mesh) if friedrichs is None else float(friedrichs)
    C_mu = math.sqrt(sum(1.0 / mu for mu in mus))
    cache = disc_cache(disc)
    dual = cache.setdefault("dual", _P0Dual(mesh))

    def ew(cf, dxx=dxq):
        return Integrate(cf * dxx, mesh, element_wise=True).NumPy().copy()

    with TaskManager():
        if "area" not in cache:
            cache["area"] = ew(CoefficientFunction(1.0), dx)
        area = cache["area"]
        # Dirichlet correction: depends only on the boundary trace of u_h, fixed along the iterations (cached)
        ws, eta_bc, eps_w, _ = _dirichlet_lifting(disc, fields, p, dirichlet_correction)
        exact_bc = all(w is None for w in ws)
        vals, grads, gap, ggap = _corrected_fields(prob, fields, ws)

        # ------------------------------------------------------------ flux / residual (disc)
        eta_F = np.zeros((nf, mesh.ne))
        eta_R = np.zeros((nf, mesh.ne))
        rbar = []
        for i, (fd, sig, gu, m) in enumerate(zip(fields, sig_d, grads, data)):
            mu = fd.mu
            fl = math.sqrt(mu) * gu + sig / math.sqrt(mu)
            eta_F[i] = np.sqrt(np.maximum(ew(fl * fl), 0.0))
            res = fd.f + m - div(sig)  # f + s lam^ - r^ - div sigma_disc
            eta_R[i] = h / math.pi / math.sqrt(mu) * np.sqrt(np.maximum(ew(res * res), 0.0))
            rbar.append(ew(res, dx(bonus_intorder=bonus + 8)) / area)
        eta_FR = float(np.sqrt(((eta_F + eta_R) ** 2).sum()))
        eta_quad = _mean_term(dual, rbar, area, mus, C_F, eta_FR)

        # ------------------------------------------------------------ algebraic flux
        alg_flux = alg_loc = alg_mean = 0.0
        if inexact:
            fl2, loc2, mean2 = 0.0, 0.0, 0.0
            for a, (fd, r) in enumerate(zip(fields, r_hat)):
                mu = fd.mu
                rb = ew(r, dx) / area
                if sigma_alg is None:  # RT_0 mixed solution of div sigma = Pi_0 r^ (global CR solve)
                    fl2 += dual.norm(rb) ** 2 / mu
                    rem = r - _p0(mesh, rb)
                    loc2 += float(((h / math.pi) ** 2 * np.maximum(ew(rem * rem), 0.0)).sum()) / mu
                else:
                    sa = sigma_alg[a]
                    fl2 += max(Integrate(sa * sa * dxq, mesh), 0.0) / mu
                    rem = r - div(sa)
                    mb = ew(rem, dx(bonus_intorder=bonus + 8)) / area
                    loc2 += float(((h / math.pi) ** 2 * np.maximum(ew(rem * rem) - mb ** 2 * area, 0.0)).sum()) / mu
                    mn = C_F * math.sqrt(float((mb ** 2 * area).sum()))
                    if mn > 0.0:
                        mn = min(mn, dual.norm(mb))
                    mean2 += mn ** 2 / mu
            alg_flux, alg_loc, alg_mean = math.sqrt(fl2), math.sqrt(loc2), math.sqrt(mean2)
        eta_alg = alg_flux + alg_loc + alg_mean

        # ------------------------------------------------------------ multiplier defects (eta_nonc,2)
        if p == 1:
            lam_t = lam_p  # >= 0 (nonnegative vertex coefficients)
            nonc2_d = 0.0
        else:
            lam_neg2 = float(ew(IfPos(-lam_p, lam_p * lam_p, 0.0)).sum())
            if lam_neg2 > 0.0:
                lam_t, _ = nonnegative_multiplier(lam_p, mesh, lam_order, area)
                nonc2_d = _defect_norm(lam_p - lam_t, ew, h, area, C_F, C_mu, dual, eta_FR)
            else:
                lam_t, nonc2_d = lam_p, 0.0
        nonc2_l = _defect_norm(lam_n, ew, h, area, C_F, C_mu, dual, eta_FR) if lam_n is not None else 0.0

        # ------------------------------------------------------------ s_h (nodal averaging), s~_h
        mt = mus[1] / (mus[0] + mus[1]) if len(mus) == 2 else 1.0
        weight = mus[0] * mt ** 2 + (mus[1] * (1 - mt) ** 2 if len(mus) == 2 else 0.0)
        g_nodal = system.gap(x)
        neg = np.maximum(-g_nodal, 0.0)
        if neg.any():
            full = np.zeros(disc.fes.ndof)
            full[disc.interior] = neg
            c = GridFunction(disc.fes, name="gap_neg_nodal")
            c.vec.FV().NumPy()[:] = disc.nodes.T @ full
            loc_l = weight * np.maximum(ew(grad(c) * grad(c), dx), 0.0)
            d_l = math.sqrt(float(loc_l.sum()))
            gap_s, ggap_s = gap + c, ggap + grad(c)
        else:
            c, loc_l, d_l = None, np.zeros(mesh.ne), 0.0
            gap_s, ggap_s = gap, ggap
        d_d, corr_d = admissible_correction(disc, gap_s, ggap_s, dxq, exact_polynomial_gap=(p == 1 and exact_bc))

        # ------------------------------------------------------------ contact terms
        # lam~ moved towards the small gaps in every element, as in :func:`.estimators.estimate`
        # (the mean-free defect goes to eta_nonc2,disc)
        qa = QuadratureArrays(mesh, 2 * p + 6)
        lam_v, gap_v = qa.values(lam_t), qa.values(gap)
        cd_v, cl_v = qa.values(corr_d), qa.values(c)
        if p >= 2:  # as in estimate(): never changed anything for p = 1
            lam_v, loc2 = concentrated_multiplier(qa, lam_v, gap_v + cd_v + cl_v, h, C_mu,
                                                  eta_FR + eta_quad + nonc2_d + nonc2_l + 2.0 * (d_d + d_l))
            nonc2_d += C_mu * math.sqrt(float(loc2.sum()))
        eta_C = 2.0 * qa.integrate(lam_v * gap_v)          # eta_C,K = 2 (lam~, g_h)_K
        sum_C = float(eta_C.sum())
        P_lin = 2.0 * float((D * yp * g_nodal).sum())      # discrete complementarity product
        nonc3_d = 2.0 * float(qa.integrate(lam_v * cd_v).sum())
        nonc3_l = 2.0 * float(qa.integrate(lam_v * cl_v).sum())
        # Theta of the direct bound, split like the corrections: s~ - s_h - w_h (disc), s_h - u_h (lin)
        zero2 = CoefficientFunction((0.0, 0.0))
        theta_d = _contact_work(prob, fields, grads, corr_d, IfPos(-gap_s, -ggap_s, zero2), dxq) \
            if corr_d is not None else 0.0
        theta_l = _contact_work(prob, fields, grads, c, grad(c), dxq) if c is not None else 0.0
    # 2P = sum_C + nonc3 = (sum_C - P_lin + nonc3_d) + (P_lin + nonc3_l) <= 2P_disc + 2P_lin
    twoP_d = max(sum_C - P_lin + nonc3_d, 0.0)
    twoP_l = max(P_lin + nonc3_l, 0.0)

    E_d = math.hypot(eta_FR + eta_quad + nonc2_d + d_d, math.sqrt(twoP_d))
    eta_disc = math.hypot(E_d + d_d + eps_w, eta_bc)
    eta_lin = math.hypot(nonc2_l + d_l, math.sqrt(twoP_l)) + d_l
    # direct bound (module docstring): f(A, B) = A/2 + hypot(A/2, sqrt(B)) per component
    A_d, A_l = eta_FR + eta_quad + nonc2_d + d_d, nonc2_l + d_l
    B_d = max(theta_d + 0.5 * (sum_C - P_lin), 0.0)
    B_l = max(theta_l + 0.5 * P_lin, 0.0)
    disc_direct = math.hypot(0.5 * A_d + math.hypot(0.5 * A_d, math.sqrt(B_d)) + eps_w, eta_bc)
    lin_direct = 0.5 * A_l + math.hypot(0.5 * A_l, math.sqrt(B_l))
    direct = disc_direct + lin_direct < eta_disc + eta_lin
    if direct:
        eta_disc, eta_lin = disc_direct, lin_direct
    eta = eta_disc + eta_lin + eta_alg
    eta_K = np.sqrt(((eta_F + eta_R) ** 2).sum(axis=0) + np.maximum(eta_C, 0.0))
    terms = {"eta_FR_disc": eta_FR, "eta_F_disc": float(np.sqrt((eta_F ** 2).sum())),
             "eta_R": float(np.sqrt((eta_R ** 2).sum())), "eta_quad": eta_quad,
             "eta_C": sum_C, "P_lin": P_lin, "nonc1_disc": d_d, "nonc1_lin": d_l,
             "nonc2_disc": nonc2_d, "nonc2_lin": nonc2_l, "nonc3_disc": nonc3_d, "nonc3_lin": nonc3_l,
             "eta_bc": eta_bc, "eps_w": eps_w, "alg_flux": alg_flux, "alg_res": alg_loc + alg_mean,
             "theta_disc": theta_d, "theta_lin": theta_l, "direct": float(direct), "time_flux_s": t_flux}
    t_total = time.perf_counter() - t0
    err = None
    if errors and prob.exact is not None:
        err = disc.errors(x, y).get("err_energy")
    return Components(eta_disc=eta_disc, eta_lin=eta_lin, eta_alg=eta_alg, eta=eta, eta_K=eta_K,
                      eta_K_lin=np.sqrt(loc_l), terms=terms, res_alg=res_alg, err_energy=err,
                      time_total=t_total, sigma_disc=sig_d, r_hat=r_hat, data=data)


def _p0(mesh, values: np.ndarray) -> GridFunction:
    gf = GridFunction(L2(mesh, order=0))
    gf.vec.FV().NumPy()[:] = values
    return gf


# ------------------------------------------------------------------ history along Newton iterations
def newton_history(disc, iterates, *, errors: bool = True, **kwargs) -> List[dict]:
    """Components per iterate, like the [JSC20] figures (eta_disc, eta_lin, eta_alg vs k).

    Parameters
    ----------
    disc : FEMDiscretization
    iterates : iterable of (x, y) or (x, y, r_alg)
        the iterates X^k (k = 0, 1, ...) in order.
    errors : bool
        add ``err_energy`` and ``i_eff_total`` when the exact solution is known.
    **kwargs
        passed to :func:`estimate_components`.

    Returns
    -------
    list of dict
        one row per iterate: ``k`` and :meth:`Components.summary`.
    """
    rows = []
    for k, it in enumerate(iterates):
        xk, yk = it[0], it[1]
        r = it[2] if len(it) > 2 else None
        comp = estimate_components(disc, xk, yk, r_alg=r, errors=errors, **kwargs)
        rows.append({"k": k, **comp.summary()})
    return rows


class ComponentsHistory:
    """Callback collecting :func:`estimate_components` rows along a Newton loop.

    ``hist = ComponentsHistory(disc, every=1)``; call ``hist(k, x, y)`` (or ``hist(k, x, y,
    r_alg=...)``) after every iterate; ``hist.rows`` is the list of
    ``{"k": k, **Components.summary()}``; ``hist.plot(png)`` draws them.
    """

    def __init__(self, disc, every: int = 1, errors: bool = True, **kwargs):
        self.disc, self.every, self.errors, self.kwargs = disc, max(int(every), 1), errors, kwargs
        self.rows: List[dict] = []

    def __call__(self, k: int, x, y, r_alg=None, sigma_alg=None):
        if k % self.every:
            return None
        comp = estimate_components(self.disc, x, y, r_alg=r_alg, sigma_alg=sigma_alg, errors=self.errors,
                                   **self.kwargs)
        self.rows.append({"k": k, **comp.summary()})
        return comp

    def plot(self, out_png) -> None:
        plot_components_history(self.rows, out_png)


def newton_iterates(disc, x0, y0, *, cfun: str = "min", tol: float = 1e-10, maxit: int = 100,
                    callback: Optional[Callable] = None):
    """Plain semismooth Newton (no line search) yielding (x^k, y^k) for k = 0, 1, ...

    The loop of :func:`ngcontact.newton.semismooth_newton` with ``line_search=False``, exposing
    the iterates (the production loop's callback receives only an ``IterationRecord``).
    Stops after ||Phi|| / ||F|| <= tol or ``maxit`` steps.
    """
    system = disc.system
    cf = get_cfunction(cfun)
    scale = max(float(np.linalg.norm(system.F)), np.finfo(float).tiny)
    x, y = np.array(x0, dtype=float), np.array(y0, dtype=float)
    for k in range(maxit + 1):
        yield x, y
        g = system.gap(x)
        c = cf.value(g, y)
        res = math.sqrt(float(np.sum(system.residual(x, y) ** 2) + np.sum(c ** 2))) / scale
        if res <= tol or k == maxit:
            return
        Ca, Cb = cf.jacobian(g, y)
        x, y, _ = system.newton_step(x, y, c, Ca, Cb)


def plot_components_history(rows: Sequence[dict], out_png) -> None:
    """eta_disc, eta_lin, eta_alg (and the error, if present) vs iteration k, log scale (matplotlib Agg)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    ks = [r["k"] for r in rows]
    fig, ax = plt.subplots(figsize=(6, 4))
    floor = 1e-16
    for key, style, label in [("eta_total", "k-", r"$\eta$"), ("eta_disc", "b-o", r"$\eta_{disc}$"),
                              ("eta_lin", "r-s", r"$\eta_{lin}$"), ("eta_alg", "g-^", r"$\eta_{alg}$"),
                              ("err_energy", "k--", r"$|||u-u_h|||$")]:
        if all(key in r for r in rows):
            ax.semilogy(ks, [max(r[key], floor) for r in rows], style, ms=4, label=label)
    ax.set_xlabel("Newton iteration k")
    ax.set_ylabel("estimators")
    ax.grid(True, which="both", alpha=0.3)
    ax.legend()
    fig.tight_layout()
    fig.savefig(out_png, dpi=120)
    plt.close(fig)
