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

(:func:`.moments.p1_from_functional`; p = 1: c_a = R_a / D_a), or for
q >= 3 by the dual-basis function r_h with (r_h, phi_l) = R_l.  Either way
(r^_alpha, psi_a) = R_alpha(psi_a) for every vertex a, which is what the patches need.

Fluxes (seed "Component flux reconstruction").  sigma_alpha,disc is the patchwise equilibrated
flux of :func:`.flux.equilibrate` with the data f_alpha - (-1)^alpha lam^_h - r^_alpha; the
interior patches are compatible because the patch moment of this datum equals the (inexact)
discrete equation tested with psi_a.  So div sigma_disc = Pi_q (f + s lam^ - r^) exactly.
sigma_alpha,alg (div sigma_alg ~ r^) is either given by the caller (``sigma_alg``; e.g. built
on a mesh hierarchy, [JSC20] / Papez-Rude-Vohralik-Wohlmuth) or, if ``r_alg`` is given and
``sigma_alg`` is not, built here by ONE GLOBAL solve: the lowest-order mixed (RT_0 x P_0)
solution of div sigma_alg = Pi_0 r^ (Crouzeix-Raviart solve + Marini's formula,
:class:`.terms.P0Dual`; cost of one P1 Cholesky).  A patchwise equilibration of the
algebraic residual alone is not possible: its interior-patch moments R(psi_a) do not vanish.
Whatever sigma_alg is, the remaining algebraic datum r^ - div sigma_alg is bounded in H^{-1}
by Poincare on every element for its mean-free part and by the RT_0 field of its element means:

    eta_alg = (sum_alpha ||mu_alpha^{-1/2} sigma_alpha,alg||^2)^{1/2}
              + (sum_alpha mu_alpha^{-1} sum_K (h_K/pi)^2 ||r^ - div sigma_alg - mean_K||_K^2)^{1/2}
              + (sum_alpha mu_alpha^{-1} ||zeta(mean_K(r^ - div sigma_alg))||^2)^{1/2}.

(The seed writes only the first term, assuming div sigma_alg = r exactly.)

Nonconformity and contact: which term goes where.  s_h is the seed's step 1 (nodal averaging
where the nodal gap is negative, mu-weighted as in :mod:`.terms`, t = mu2/(mu1 + mu2)):
s_h - u_h = (t, -(1 - t)) I_p(g_h^-), g_h^- the negative part of the NODAL gap; the nodal gap
of s_h is >= 0.  s~_h in K_g corrects the remaining pointwise negative part of the gap of
s_h + w_h (w_h: Dirichlet-data correction of :mod:`.dirichlet`), s~_h - (s_h + w_h) =
(t, -(1 - t)) (g_s)^-, g_s = gap(s_h + w_h) (in place of the seed's c_K bubble step, see
:func:`.terms.admissible_correction` for the reason).  Multiplier: lam^_h = lam^(y) (p = 1: the P1 moments
function above; p >= 2: the contact multiplier of :mod:`.multipliers`, a linear map of the moments once
the contact elements are fixed from y^+) is split linearly, lam^(y) = lam^(y^+) + lam^(y^-);
lam~_h >= 0 is lam^(y^+) where it is already >= 0 (p = 1, and p >= 2 with q <= 2) or its minimal
nonnegative modification (q >= 3, :func:`.nonnegative.nonnegative_multiplier`).

    term (seed name)                                     component   zero at convergence?
    eta_F(sigma_disc), eta_R, eta_quad                   disc        no
    |||s~_h - s_h - w_h|||      (seed |||s~ - s|||)       disc        no for p >= 2
    |||s_h - u_h|||             (seed |||s - u|||)        lin         yes (nodal gaps >= 0)
    C ||lam^(y^+) - lam~_h||  (seed C||lam^neg - lam~^neg||)  disc    no for q >= 3
      (includes the concentration defect of :func:`.nonnegative.concentrated_multiplier`)
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
:mod:`.terms` (Poincare per element + RT_0 for the means), sharper than C_F ||.||.

Direct combination (used when its eta_disc + eta_lin is the smaller; proof: "Direct bound" of
:mod:`.bound`, with A = A_disc + A_lin + eta_alg, A_disc = eta_FR + eta_quad + eta_nonc2,disc +
d_disc, A_lin = eta_nonc2,lin + d_lin, B = Theta + sum eta_C / 2 <= B_disc + B_lin,
B_disc = max(Theta_disc + (sum eta_C - P_lin)/2, 0), B_lin = max(Theta_lin + P_lin/2, 0), Theta
split linearly with the correction n = (s~ - s_h - w_h) + (s_h - u_h), and
A/2 + (A^2/4 + B)^{1/2} = A/2 + |(A/2, B^{1/2})| <= the sum of the same per component):

    eta_disc = hypot(A_disc/2 + hypot(A_disc/2, B_disc^{1/2}) + eps_w, eta_bc)
    eta_lin  = A_lin/2 + hypot(A_lin/2, B_lin^{1/2}).

Combination of the seed's route (proof: :mod:`.bound` with a = eta_FR + eta_quad + eta_nonc,2,
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
of :func:`.bound.estimate` (same fluxes, same terms).
"""
from __future__ import annotations

import math
import time
import warnings
from dataclasses import dataclass, field
from typing import Optional

import numpy as np
from ngsolve import H1, TRIG, CoefficientFunction, Discontinuous, GridFunction, IfPos, TaskManager, dx, grad

from .affine_p1 import P1Arrays
from .affine_p1 import applies as affine_p1_applies
from .algebraic import algebraic_terms
from .boundary import boundary_nodal_values, boundary_vertex_values
from .dirichlet import dirichlet_lifting
from .flux import (PatchData, equilibrate_all, flux_bonus, patch_regularization, patch_solver,
                   vertex_device_exact)
from .moments import data_rules, p1_from_functional, vertex_function_values, vertex_moment_term, vertex_rule
from .multipliers import ContactMultiplier, PatchContactMultiplier
from .nonnegative import concentrated_multiplier
from .obstacle import shifted_obstacle
from .options import EstimatorOptions
from .terms import (Integrals, admissible_correction, contact_work, corrected_fields, defect_norm, direct_root,
                    flux_residual, nonnegative_part, split)
from .view import DiscretizationView, SolutionView

__all__ = ["Components", "estimate_components", "algebraic_residual_function"]


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


def _residual_functions(dv: DiscretizationView, R: np.ndarray, q: int) -> list:
    """r^_alpha per field for the PDE rows R of an algebraic residual (module doc): P1 where the vertex
    device is exact, else the dual-basis function."""
    ni = dv.n_interior
    if vertex_device_exact(dv, q):
        return [p1_from_functional(dv, R[a * ni:(a + 1) * ni], f"r_alg_{a + 1}") for a in range(dv.nfields)]
    return [dv.dual_function(R[a * ni:(a + 1) * ni], f"r_alg_{a + 1}") for a in range(dv.nfields)]


def algebraic_residual_function(disc, x, y, *, options: Optional[EstimatorOptions] = None) -> list:
    """r^_alpha per field: the function representing the PDE rows of the algebraic residual
    R = F - E X of the iterate (module docstring); an algebraic flux passed to
    :func:`estimate_components` should satisfy div sigma_alpha,alg = r^_alpha.

    Returns
    -------
    list of GridFunction
        P1 (RT degree q <= 2) or dual-basis P_p (q >= 3) functions.
    """
    dv = DiscretizationView.of(disc)
    q = (options or EstimatorOptions()).flux_degree(dv.order)
    return _residual_functions(dv, -dv.system.residual(np.asarray(x, float), np.asarray(y, float)), q)


def _gf_combination(a: GridFunction, ca: float, b: Optional[GridFunction], cb: float, name: str) -> GridFunction:
    gf = GridFunction(a.space, name=name)
    gf.vec.data = ca * a.vec
    if b is not None:
        gf.vec.data += cb * b.vec
    return gf


def _algebraic_residual(sv: SolutionView, q: int, r_alg, sigma_alg, res_tol: float):
    """(||R|| / ||F||, r^ or None): the PDE rows R = F - E X of the iterate's algebraic residual and their
    representation, None when the iterate solves them (no ``r_alg``, no ``sigma_alg``, ||R|| <= res_tol ||F||)."""
    system = sv.disc.system
    scale = max(float(np.linalg.norm(system.F)), np.finfo(float).tiny)
    R = -system.residual(sv.x, sv.y)  # F - E X, PDE rows
    res_alg = float(np.linalg.norm(R)) / scale
    if r_alg is not None:
        r_alg = np.asarray(r_alg, dtype=float)
        n = len(sv.x) + len(sv.y)
        if len(r_alg) != n:
            raise ValueError(f"r_alg must have {n} entries, got {len(r_alg)}")
        if np.linalg.norm(r_alg[:len(sv.x)] - R) > 1e-8 * scale + 1e-6 * np.linalg.norm(R):
            warnings.warn("r_alg[:len(x)] differs from F - E X of the iterate; estimating F - E X", stacklevel=3)
    inexact = r_alg is not None or sigma_alg is not None or res_alg > res_tol
    return res_alg, _residual_functions(sv.disc, R, q) if inexact else None


def _split_multiplier(sv: SolutionView, use_p1: bool, boundary: bool = True):
    """lam^(y) = lam^(y^+) + lam^(y^-): (positive part, negative part or None, the sum); ``boundary``: the
    positive part takes the residual multiplier of :mod:`.boundary` at the boundary vertices of contact
    elements (free values: boundary patches need no compatibility)."""
    dv, y = sv.disc, sv.y
    D = dv.D
    yp, yn = np.maximum(y, 0.0), np.minimum(y, 0.0)
    if dv.order == 1:  # the lumped P1 multiplier, >= 0 for y >= 0
        lam_p = p1_from_functional(dv, D * yp, "lam_pos")
        lam_n = p1_from_functional(dv, D * yn, "lam_neg") if (yn < 0).any() else None
        return lam_p, lam_n, _gf_combination(lam_p, 1.0, lam_n, 1.0, "lam_hat")
    # contact multiplier of .multipliers (marker from y+), one linear map for both parts
    cmult = (PatchContactMultiplier if use_p1 else ContactMultiplier)(dv, yp)
    bnd = (boundary_vertex_values if use_p1 else boundary_nodal_values)(sv, cmult.contact) if boundary else None
    lam_p = cmult(D * yp, "lam_pos", boundary=bnd)
    lam_n = cmult(D * yn, "lam_neg") if (yn < 0).any() else None
    return lam_p, lam_n, lam_p if lam_n is None else lam_p + lam_n


def _disc_fluxes(sv: SolutionView, q: int, lam_p, lam_n, lam_hat, r_hat, use_p1: bool, opts: EstimatorOptions):
    """sigma_alpha,disc with div sigma = Pi_q (f + m_alpha), m_alpha = s_alpha lam^ - r^_alpha (module doc):
    (fluxes, m_alpha per field)."""
    dv = sv.disc
    p = dv.order
    rules = data_rules(dv)
    vertex_dx = dx(intrules={TRIG: vertex_rule()})
    data, patch_data = [], []
    lam_v = None
    lam_b = None
    if use_p1 and opts.batched:  # vertex values of lam^ (both fields), for the batched patch-constant sources
        lam_v = vertex_function_values(dv, lam_p)
        if lam_n is not None:
            lam_v = lam_v + vertex_function_values(dv, lam_n)
    elif not use_p1:  # the elementwise-P1 fit lam^ (.multipliers.ContactMultiplier) as a broken-P1 GridFunction
        if "broken_p1" not in dv.cache:  # one space per mesh: the patch operators on it are kept (.flux)
            dv.cache["broken_p1"] = Discontinuous(H1(dv.mesh, order=1))
        lam_b = GridFunction(dv.cache["broken_p1"], name="lam_hat")
        lam_b.Set(lam_hat)  # exact: lam^ lies in the space
    for a, fd in enumerate(sv.fields):
        # m_alpha = s_alpha lam^ - r^_alpha; P1 functions by the patch-constant vertex device
        # (.moments), elementwise/dual ones exactly with the FE mass rule
        r = r_hat[a] if r_hat else None
        if p == 1:
            m = _gf_combination(lam_hat, float(fd.sign), r, -1.0, f"m_{fd.name}")
        else:
            m = fd.sign * lam_hat if r is None else fd.sign * lam_hat - r
        vvals, mass = None, None
        if lam_v is not None:  # vertex functions: exact patch-constant sources of the batched solver
            vterm = None
            vvals = fd.sign * lam_v
            if r is not None:
                vvals = vvals - vertex_function_values(dv, r)
        elif use_p1:  # P1 / elementwise-P1 vertex functions: the patch-constant vertex device
            vterm = vertex_moment_term(dv.mesh, m, q)
        else:  # q >= 3 / curved: exact products with the FE mass rule, by operators assembled once (.flux)
            vterm = None
            mass = [(lam_b, float(fd.sign), 2 * p)] + ([(r, -1.0, 2 * p)] if r is not None else [])
        data.append(m)

        def source(w, vterm=vterm):
            return -vterm(w) * vertex_dx

        def load(w, f=fd.f):  # the iterate-independent part: assembled once per load (.patches)
            return -f * w * dx(intrules=rules["load"])
        patch_data.append(PatchData(u=fd.u, mu=fd.mu, source=source if vterm is not None else None,
                                    hessian=p > 1, bonus_intorder=flux_bonus(dv), name=f"sigma_disc_{fd.name}",
                                    vertex_values=None if vvals is None else [(vvals, None)], load=(fd.f, load),
                                    mass=mass))
    sig_d = equilibrate_all(dv.mesh, q, patch_data, regularization=patch_regularization(dv, opts.regularization),
                            solver=patch_solver(dv, q) if opts.batched else None)
    return sig_d, data


def _contact_terms(ig, opts, p, fields, grads, lam_t, gap, ggap, gap_s, ggap_s, corr_d, c, ref: float, nonc2_d: float,
                   support_d=None):
    """(eta_C,K, nonc2_disc, nonc3_disc, nonc3_lin, Theta_disc, Theta_lin) by quadrature (module doc): lam~ moved
    towards the small gaps in every element, as in :func:`.bound.estimate` (the mean-free defect goes to
    eta_nonc2,disc); Theta of the direct bound split like the corrections: s~ - s_h - w_h (disc), s_h - u_h
    (lin); ``support_d``: the elements outside of which corr_d vanishes at the points of the rule of ``dxq``."""
    qa = ig.quadrature(2 * p + 6)
    lam_v, gap_v = qa.values(lam_t), qa.values(gap)
    cd_v, cl_v = qa.values(corr_d), qa.values(c)
    if opts.concentrates(p):
        lam_v, loc2 = concentrated_multiplier(qa, lam_v, gap_v + cd_v + cl_v, ig.h, ig.C_mu, ref)
        nonc2_d += ig.C_mu * math.sqrt(float(loc2.sum()))
    eta_C = 2.0 * qa.integrate(lam_v * gap_v)          # eta_C,K = 2 (lam~, g_h)_K
    nonc3_d = 2.0 * float(qa.integrate(lam_v * cd_v).sum())
    nonc3_l = 2.0 * float(qa.integrate(lam_v * cl_v).sum())
    zero2 = CoefficientFunction((0.0, 0.0))
    theta_d = contact_work(ig, fields, grads, corr_d, IfPos(-gap_s, -ggap_s, zero2), support_d) \
        if corr_d is not None else 0.0
    theta_l = contact_work(ig, fields, grads, c, grad(c)) if c is not None else 0.0
    return eta_C, nonc2_d, nonc3_d, nonc3_l, theta_d, theta_l


def estimate_components(disc, x, y, *, r_alg=None, sigma_alg=None, options: Optional[EstimatorOptions] = None,
                        errors: bool = False, shift_obstacle: bool = False) -> Components:
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
        of (x, y) exceeds ``options.res_tol`` ||F|| (then the global solve is done anyway, so that the
        bound stays guaranteed).
    options : EstimatorOptions, optional
        RT degree q of sigma_disc (``flux_order``), Dirichlet correction, quadrature, patch solver, ...
    errors : bool
        also compute |||u - u_h||| (exact solution needed) for ``i_eff``.
    shift_obstacle : bool
        stationary obstacle problems (with ``options.shift_obstacle``): also the bound for the interpolated obstacle
        psi~ of :mod:`.obstacle`, |||psi - psi~||| added to eta_disc; the variant with the smaller eta_disc + eta_lin
        is returned (``terms["eta_obstacle"]`` > 0 when it is the shifted one).  Off for the parabolic estimators,
        for which the shift argument is not made.

    Returns
    -------
    Components
    """
    t0 = time.perf_counter()
    sv = SolutionView.of(disc, x, y)
    dv, opts = sv.disc, EstimatorOptions() if options is None else options
    p, mesh, fields, mus = dv.order, dv.mesh, sv.fields, dv.mus
    q = opts.flux_degree(p)
    res_alg, r_hat = _algebraic_residual(sv, q, r_alg, sigma_alg, opts.res_tol)
    use_p1 = vertex_device_exact(dv, q)
    lam_p, lam_n, lam_hat = _split_multiplier(sv, use_p1, opts.boundary_multiplier)
    t_flux = time.perf_counter()
    sig_d, data = _disc_fluxes(sv, q, lam_p, lam_n, lam_hat, r_hat, use_p1, opts)
    t_flux = time.perf_counter() - t_flux

    with TaskManager():
        ig = Integrals.of(dv, opts)
        # Dirichlet correction: depends only on the boundary trace of u_h, fixed along the iterations (cached)
        ws, eta_bc, eps_w, _ = dirichlet_lifting(dv, fields, opts.dirichlet_correction)
        exact_bc = all(w is None for w in ws)
        vals, grads, gap, ggap = corrected_fields(dv, fields, ws)
        # P1 on affine elements: the same integrals in closed form from per-mesh arrays (.affine_p1)
        ar = P1Arrays.of(dv, ig.area, ig.bonus) if affine_p1_applies(dv, opts, exact_bc, sigma_alg) else None
        ar = ar if ar is not None and ar.seen([fd.f for fd in fields]) else None
        load_order = 2 * p + dv.quad_bonus  # the load rule of the FE system (.moments.data_rules)
        eta_F, eta_R, eta_FR, eta_quad = flux_residual(ig, fields, sig_d, grads, data,
                                                       ar and ar.flux_parts(fields, sig_d, data, load_order))  # disc
        alg_flux, alg_loc, alg_mean = algebraic_terms(ig, fields, r_hat, sigma_alg, ar and ar.alg_parts(
            r_hat, sigma_alg)) if r_hat else (0.0, 0.0, 0.0)
        eta_alg = alg_flux + alg_loc + alg_mean

        # ------------------------------------------------------------ multiplier defects (eta_nonc,2)
        if p == 1:
            lam_t, nonc2_d = lam_p, 0.0  # >= 0 (nonnegative vertex coefficients)
        else:
            lam_t, nonc2_d, _ = nonnegative_part(ig, lam_p, 1, eta_FR)
        nonc2_l = defect_norm(ig, lam_n, eta_FR, ar and ar.defect_parts(lam_n))[0] if lam_n is not None else 0.0

        # ------------------------------------------------------------ s_h (nodal averaging), s~_h
        _, weight = split(mus)
        g_nodal = dv.system.gap(sv.x)
        neg = np.maximum(-g_nodal, 0.0)
        if neg.any():
            c = dv.interior_function(neg, "gap_neg_nodal")
            loc_l = weight * np.maximum(ar.grad_sq(c) if ar else ig.ew(grad(c) * grad(c), dx), 0.0)
            d_l = math.sqrt(float(loc_l.sum()))
        else:
            c, loc_l, d_l = None, np.zeros(mesh.ne), 0.0
        P_lin = 2.0 * float((dv.D * np.maximum(sv.y, 0.0) * g_nodal).sum())  # discrete complementarity product
        # the obstacle psi, and the interpolated one psi~ (+ |||psi - psi~||| in eta_disc, .obstacle) when asked
        variants = [(gap, ggap, None)]
        shifted = shifted_obstacle(sv) if shift_obstacle and opts.shift_obstacle and dv.obstacle is not None else None
        if shifted is not None:
            variants.append((vals[0] - shifted.psi, grads[0] - shifted.grad, shifted))
        best = None
        nonc2_d0 = nonc2_d
        for gap, ggap, sh in variants:
            gap_s, ggap_s = (gap + c, ggap + grad(c)) if c is not None else (gap, ggap)
            d_d, corr_d, support_d = admissible_correction(ig, mus, gap_s, ggap_s,
                                                           exact_polynomial_gap=(p == 1 and exact_bc))
            # ---------------------------------------------------------- contact terms
            # lam~ moved towards the small gaps in every element, as in :func:`.bound.estimate`
            # (the mean-free defect goes to eta_nonc2,disc)
            if ar is not None:  # no s~ - s_h correction (P1 gap, exact data), no concentration
                eta_C, nonc3_l, theta_l = ar.contact(fields, lam_t, c, split(mus)[0], load_order)
                nonc2_d, nonc3_d, theta_d = nonc2_d0, 0.0, 0.0
            else:
                eta_C, nonc2_d, nonc3_d, nonc3_l, theta_d, theta_l = _contact_terms(
                    ig, opts, p, fields, grads, lam_t, gap, ggap, gap_s, ggap_s, corr_d, c,
                    eta_FR + eta_quad + nonc2_d0 + nonc2_l + 2.0 * (d_d + d_l), nonc2_d0, support_d)
            sum_C = float(eta_C.sum())
            # 2P = sum_C + nonc3 = (sum_C - P_lin + nonc3_d) + (P_lin + nonc3_l) <= 2P_disc + 2P_lin
            twoP_d = max(sum_C - P_lin + nonc3_d, 0.0)
            twoP_l = max(P_lin + nonc3_l, 0.0)
            E_d = math.hypot(eta_FR + eta_quad + nonc2_d + d_d, math.sqrt(twoP_d))
            eta_disc = math.hypot(E_d + d_d + eps_w, eta_bc)
            eta_lin = math.hypot(nonc2_l + d_l, math.sqrt(twoP_l)) + d_l
            # direct bound (module docstring): the root of x^2 = A x + B per component
            A_d, A_l = eta_FR + eta_quad + nonc2_d + d_d, nonc2_l + d_l
            disc_direct = math.hypot(direct_root(A_d, theta_d + 0.5 * (sum_C - P_lin)) + eps_w, eta_bc)
            lin_direct = direct_root(A_l, theta_l + 0.5 * P_lin)
            direct = disc_direct + lin_direct < eta_disc + eta_lin
            if direct:
                eta_disc, eta_lin = disc_direct, lin_direct
            if sh is not None:  # |||u - u_h||| <= |||psi - psi~||| + the bound for psi~ (.obstacle)
                eta_disc += sh.eta
            if best is None or eta_disc + eta_lin < best[0] + best[1]:
                best = (eta_disc, eta_lin, eta_C, sum_C, d_d, nonc2_d, nonc3_d, nonc3_l, theta_d, theta_l, direct, sh)
    eta_disc, eta_lin, eta_C, sum_C, d_d, nonc2_d, nonc3_d, nonc3_l, theta_d, theta_l, direct, sh = best
    eta = eta_disc + eta_lin + eta_alg
    loc = ((eta_F + eta_R) ** 2).sum(axis=0) + np.maximum(eta_C, 0.0)
    eta_K = np.sqrt(loc if sh is None else loc + sh.loc)
    terms = {"eta_FR_disc": eta_FR, "eta_F_disc": float(np.sqrt((eta_F ** 2).sum())),
             "eta_R": float(np.sqrt((eta_R ** 2).sum())), "eta_quad": eta_quad,
             "eta_C": sum_C, "P_lin": P_lin, "nonc1_disc": d_d, "nonc1_lin": d_l,
             "nonc2_disc": nonc2_d, "nonc2_lin": nonc2_l, "nonc3_disc": nonc3_d, "nonc3_lin": nonc3_l,
             "eta_bc": eta_bc, "eps_w": eps_w, "alg_flux": alg_flux, "alg_res": alg_loc + alg_mean,
             "theta_disc": theta_d, "theta_lin": theta_l, "direct": float(direct), "time_flux_s": t_flux,
             "eta_obstacle": 0.0 if sh is None else sh.eta}
    t_total = time.perf_counter() - t0
    return Components(eta_disc=eta_disc, eta_lin=eta_lin, eta_alg=eta_alg, eta=eta, eta_K=eta_K,
                      eta_K_lin=np.sqrt(loc_l), terms=terms, res_alg=res_alg,
                      err_energy=sv.energy_error() if errors else None,
                      time_total=t_total, sigma_disc=sig_d, r_hat=r_hat, data=data)
