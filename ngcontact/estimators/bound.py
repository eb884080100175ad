r"""Guaranteed a posteriori error estimate for conforming FE approximations of the two-membrane (and
obstacle) problem: seed slides "Estimators", "Violations of the complementarity constraints",
"Other nonconform estimators for the Lambda violation", "Theorem (A posteriori error estimate)";
[JSC20] Section 3; Ern-Vohralik SINUM 2015.

Notation.  |||v|||^2 = sum_a mu_a ||grad v_a||^2; s_1 = +1, s_2 = -1 (obstacle s = +1), so that
div(-mu_a grad u_a) = f_a + s_a lam.  From :mod:`.flux`: sigma_ah in RT_q(Omega) and the
multiplier of the equilibration lam^_h (:mod:`.multipliers`), div sigma_ah = Pi_q f_a + s_a lam^_h.
lam~_h >= 0 is lam^_h made nonnegative (:mod:`.nonnegative`; identical to lam^_h whenever X3 >= 0,
i.e. at convergence).  u~_h = u_h + w_h is the discrete solution with corrected Dirichlet data
(:mod:`.dirichlet`; w_h = 0 for piecewise polynomial g), d_h = u~1h - u~2h (obstacle: u~_h - psi).

Element estimators (field a, element K; :mod:`.terms`):

* flux        eta_F,K,a = || mu_a^{1/2} grad u~_ah + mu_a^{-1/2} sigma_ah ||_K
* residual    eta_R,K,a = h_K/pi mu_a^{-1/2} || f_a + s_a lam^_h - div sigma_ah ||_K
* contact     eta_C,K^pos = 2 (lam~_h, d_h)_K

Global terms:

* eta_nonc,1 = |||s~_h - u~_h|||, s~_h in K_g (:mod:`.terms`);
* eta_nonc,2 bounds -(lam^_h - lam~_h, z1 - z2); zero when lam^_h >= 0;
* eta_nonc,3 = 2 (lam~_h, (s~_h - u~_h)_1 - (s~_h - u~_h)_2), evaluated exactly
  (the seed bounds it by 2 C_{Omega,mu} ||lam_h^pos|| eta_nonc,1,
  C_{Omega,mu} = C_F (sum_a 1/mu_a)^{1/2}, C_F the Friedrichs constant of Omega);
* eta_quad (our addition): the element means of the residual, nonzero up to the quadrature of the
  FE load vector (round-off for smooth f; O(h^{1/2}) in L2 for f discontinuous across a curve);
* eta_bc = |||w_h||| and eps_w (our additions, zero for polynomial Dirichlet data);
* eta_trace: an indicator of the data part g - Pi g that w_h leaves out, assumed negligible by the proof below;
  the bound is reported as not proven when it is not (:attr:`Estimate.bound_proven`, :func:`.dirichlet.trace_defect`).

Totals, with eta_FR = (sum_K sum_a (eta_F,K,a + eta_R,K,a)^2)^{1/2}:

    eta_seed^2 = (eta_FR + eta_quad + eta_nonc,1 + eta_nonc,2)^2 + eta_nonc,3 + sum_K eta_C,K^pos
    eta^2      = (min(eta_seed + eta_nonc,1, eta_direct) + eps_w)^2 + eta_bc^2    >= |||u - u_h|||^2.

eta_seed is the total of the seed's Theorem (with the terms above); it bounds |||u - s~_h|||.
When s~_h = u_h (no K_g violation: p = 1 at convergence of Newton-min) and the Dirichlet data are
exact, eta = eta_seed.

Proof.  Let u be the exact solution, s~ in K_g, z = u - s~ in H^1_0 x H^1_0,
E = |||z|||, d = |||s~ - u~_h||| = eta_nonc,1 and R(z) = sum_a mu_a (grad(u_a - u~_ah), grad z_a).
The weak form and (div sigma, z) + (sigma, grad z) = 0 give, for *any* L2
function lam^ (the equilibration only needs its hat moments),

    R(z) = sum_a [(r_a, z_a) - (sigma_ah + mu_a grad u~_ah, grad z_a)] + (lam - lam^, z1 - z2).

(i)   (r_a, z_a) = sum_K (r_a - rbar_a, z_a - zbar_a)_K + (rbar_a, z_a): Poincare
      on K (||r_a - rbar_a||_K <= ||r_a||_K) and zeta_a bound the first sum by
      (eta_FR + eta_quad) E;
(ii)  (lam, z1 - z2) = -(lam, s~1 - s~2) <= 0       (lam >= 0, (lam, u1 - u2) = 0);
(iii) -(lam~, z1 - z2) <= (lam~, s~1 - s~2) = (sum_K eta_C,K^pos + eta_nonc,3) / 2   (lam~ >= 0, u1 >= u2);
(iv)  -(lam^ - lam~, z1 - z2) <= eta_nonc,2 E.
So R(z) <= a E + P, a = eta_FR + eta_quad + eta_nonc,2, P = (eta_nonc,3 + sum eta_C)/2,
E^2 = R(z) + sum mu (grad(u~_h - s~), grad z) <= (a + d) E + P, hence
E^2 <= (a + d)^2 + 2P = eta_seed^2 (Young).  Then |||u - u~_h||| <= E + d, and
with u - u_h = (u - u~_h) + w_h, u - u~_h in H^1_0 and
|(w_h, v)_mu| <= eps_w |||v||| (:mod:`.dirichlet`): |||u - u_h|||^2 <= (E + d + eps_w)^2 + |||w_h|||^2.

Direct bound (ours).  The route through s~_h pays eta_nonc,1 twice (inside E and
in |||u - u~_h||| <= E + d).  Bounding e = u - u~_h directly pays it once: with
n = (s~1 - s~2) - d_h >= d_h^- (the correction above, n = 0 on the boundary) and
v = (t n, -(1 - t) n) in H^1_0 (obstacle: v = n), |||v||| = eta_nonc,1,

    |||e|||^2 = R(e) <= (eta_FR + eta_quad) E' + (lam, e1 - e2) - (lam^, e1 - e2),   E' = |||e|||,
    (lam, e1 - e2) = -(lam, d_h) <= (lam, n) = sum_a mu_a (grad u_a, grad v_a) - (f_a, v_a)
                   = sum_a mu_a (grad e_a, grad v_a) + Theta <= eta_nonc,1 E' + Theta,
    -(lam^, e1 - e2) = -(lam~, u1 - u2) - (lam^ - lam~, e1 - e2) - (lam^ - lam~, d_h) + (lam^, d_h)
                     <= eta_nonc,2 E' + (lam~, d_h),

with the computable Theta = sum_a mu_a (grad u~_ah, grad v_a) - (f_a, v_a) (the weak form
tested with v; integrated with the estimator quadrature).  Hence E'^2 <= A E' + B,
A = eta_FR + eta_quad + eta_nonc,1 + eta_nonc,2, B = Theta + sum_K eta_C,K / 2, and

    eta_direct = A/2 + (A^2/4 + max(B, 0))^{1/2} >= |||u - u~_h|||.

Multiplier.  Every lam^_h with the hat moments of the discrete multiplier gives compatible patch
problems, hence a guaranteed bound; the bound is sharp when lam^_h is close to lam.  For p >= 2
two candidates are computed and the smaller bound is kept (the minimum of two guaranteed bounds
is one): a multiplier sharp when lam jumps at the free boundary -- for q <= 2 on affine elements
the patch constants :class:`.multipliers.PatchContactMultiplier`, for RT_3 the contact-weighted
fit :class:`.multipliers.ContactMultiplier` -- and :class:`.multipliers.ShapedContactMultiplier`,
which follows a smooth lam inside the contact set on coarse elements, where an elementwise P1
function cannot.  On curved P2 elements only the fit is used.  :attr:`Estimate.multiplier` says
which one was kept; the time is that of both.  Where the contact set reaches the Dirichlet boundary, the
hat moments of the boundary vertices are not moments of lam (no constraint rows on Dirichlet nodes) and
every candidate takes the residual multiplier of :mod:`.boundary` there instead
(``EstimatorOptions.boundary_multiplier``).

Limits: guaranteed up to the quadrature of the estimator integrals (high
order, but data with jumps and the kinks of max(0, .) are not integrated
exactly), the O(h^{p+3}) Dirichlet trace, and curved elements (where the
Payne-Weinberger constant and h_K are those of the straight triangle).
"""
from __future__ import annotations

import math
import time
from dataclasses import dataclass, field, replace
from typing import Optional, Tuple

import numpy as np
from ngsolve import L2, GridFunction, TaskManager

from .dirichlet import TRACE_DEFECT_SHARE, dirichlet_lifting, trace_defect
from .flux import FluxReconstruction, reconstruct, reconstruct_several, vertex_device_exact
from .nonnegative import QuadratureArrays, concentrated_multiplier
from .obstacle import shifted_obstacle
from .options import EstimatorOptions
from .terms import (Integrals, contact_work, corrected_fields, direct_root, flux_residual, flux_rule_order,
                    negative_part_squares, nonconformity, nonnegative_part)
from .view import DiscretizationView, SolutionView

__all__ = ["Estimate", "estimate"]


@dataclass
class Estimate:
    """Estimators of one discrete solution (formulas: module docstring).

    Attributes
    ----------
    fields : tuple of str
        field names (``("u1", "u2")`` or ``("u",)``).
    eta_F, eta_R : ndarray, shape (nfields, nelements)
        eta_F,K,alpha and eta_R,K,alpha.
    eta_C : ndarray, shape (nelements,)
        eta_C,K^pos = 2 (lam~_h, d_h)_K (negative where d_h < 0).
    h : ndarray, shape (nelements,)
        element diameters h_K.
    eta_FR, eta_quad, eta_nonc1, eta_nonc2, eta_nonc3 : float
        global terms.
    eta_bc, eps_w : float
        Dirichlet data correction |||w_h||| and its non-orthogonality (0 for
        polynomial data).
    eta_nonc2_seed : float
        the seed's C_{Omega,mu} ||lam_h^neg|| for the dual-basis lam_h
        (diagnostic; not used in eta).
    C_F, C_Omega_mu : float
        Friedrichs constant and C_F (sum 1/mu_alpha)^(1/2).
    eta_seed : float
        total of the seed's Theorem, a bound of |||u - s~_h|||.
    eta_direct : float
        the direct bound of |||u - u~_h||| (module docstring, "Direct bound").
    theta_contact : float
        Theta of the direct bound.
    eta : float
        guaranteed bound of |||u - u_h|||: min(eta_seed + eta_nonc,1, eta_direct) with the
        Dirichlet data terms (= eta_seed when s~_h = u_h and the Dirichlet data are exact).
    err_energy : float or None
        |||u - u_h||| when the exact solution is known.
    time_flux, time_total : float
        wall times [s] of the flux reconstruction and of the whole estimate
        (flux included, error computation excluded).
    flux : FluxReconstruction
    bc_K : ndarray or None
        per element sum_a mu_a (||grad w_ah||_K^2 + ||grad w_ah + rho_a||_K^2): where the Dirichlet
        data correction lives (enters ``eta_K``; None for exact data).
    multiplier : str
        the multiplier choice of the equilibration when :func:`estimate` chose between two ("contact",
        "fit" or "shape", see ``multiplier`` there); empty otherwise.
    eta_candidates : dict
        the bound of each candidate when :func:`estimate` chose between two (name -> eta); empty otherwise.
    eta_trace : float
        indicator of the Dirichlet data part that w_h leaves out (:func:`.dirichlet.trace_defect`; 0 for
        polynomial data); :attr:`bound_proven` compares it with eta.
    eta_obstacle : float
        obstacle problems with psi outside the FE space: |||psi - psi~||| when the bound for the interpolated
        obstacle psi~ of :mod:`.obstacle` was the smaller one (then eta = eta(psi~) + eta_obstacle, and the other
        fields are those of eta(psi~)); 0 otherwise.
    obstacle_K : ndarray or None
        the element parts of eta_obstacle^2 (enter ``eta_K``).
    eta_plain_obstacle : float
        the bound with psi itself when :func:`estimate` also evaluated psi~ (nan otherwise).
    """

    fields: Tuple[str, ...]
    eta_F: np.ndarray
    eta_R: np.ndarray
    eta_C: np.ndarray
    h: np.ndarray
    eta_FR: float
    eta_quad: float
    eta_nonc1: float
    eta_nonc2: float
    eta_nonc3: float
    eta_bc: float
    eps_w: float
    eta_nonc2_seed: float
    C_F: float
    C_Omega_mu: float
    eta_seed: float
    eta: float
    err_energy: Optional[float] = None
    time_flux: float = 0.0
    time_total: float = 0.0
    flux: Optional[FluxReconstruction] = field(default=None, repr=False)
    bc_K: Optional[np.ndarray] = field(default=None, repr=False)
    nonc2_K: Optional[np.ndarray] = field(default=None, repr=False)
    nonc1_K: Optional[np.ndarray] = field(default=None, repr=False)
    eta_direct: float = float("inf")
    theta_contact: float = 0.0
    multiplier: str = ""
    eta_candidates: dict = field(default_factory=dict)
    eta_trace: float = 0.0
    eta_obstacle: float = 0.0
    obstacle_K: Optional[np.ndarray] = field(default=None, repr=False)
    eta_plain_obstacle: float = float("nan")

    @property
    def bound_proven(self) -> bool:
        """False when the trace defect indicator eta_trace (:func:`.dirichlet.trace_defect`: the part g - Pi g of
        non-polynomial Dirichlet data that the lifting w_h leaves out) exceeds
        :data:`.dirichlet.TRACE_DEFECT_SHARE` eta: the proof assumes that part negligible."""
        return bool(self.eta_trace <= TRACE_DEFECT_SHARE * self.eta)  # NaN: not proven

    @property
    def why_not_proven(self) -> str:
        """The reason :attr:`bound_proven` is False ('' when it is True)."""
        if self.bound_proven:
            return ""
        return (f"the Dirichlet data are not resolved on the boundary: trace defect indicator {self.eta_trace:.2e} > "
                f"{TRACE_DEFECT_SHARE:g} eta (eta = {self.eta:.2e}; data singular inside a boundary edge?), which "
                "the bound assumes negligible")

    @property
    def i_eff(self) -> float:
        """Effectivity index eta / |||u - u_h||| (nan without exact solution)."""
        return self.eta / self.err_energy if self.err_energy else float("nan")

    @property
    def eta_K(self) -> np.ndarray:
        """Local indicators (sum_alpha (eta_F + eta_R)^2 + max(eta_C, 0) + bc_K + nonc2_K + nonc1_K)^(1/2),
        for marking (bc_K: the element parts of eta_bc^2 + eps_w^2, so that refinement also reduces the
        error of non-polynomial Dirichlet data; nonc2_K: the squared element parts of the Poincare
        part of eta_nonc,2, C_mu^2 (h_K/pi)^2 ||delta - delta_K||_K^2, so that refinement also reaches
        the negative lobes of lam^ next to a continuous free boundary, p >= 3; nonc1_K: the element
        parts |||s~_h - u~_h|||_K^2 of eta_nonc,1^2, where the discrete gap is negative)."""
        loc = ((self.eta_F + self.eta_R) ** 2).sum(axis=0) + np.maximum(self.eta_C, 0.0)
        if self.bc_K is not None:
            loc = loc + np.maximum(self.bc_K, 0.0)
        if self.nonc2_K is not None:
            loc = loc + np.maximum(self.nonc2_K, 0.0)
        if self.nonc1_K is not None:
            loc = loc + np.maximum(self.nonc1_K, 0.0)
        if self.obstacle_K is not None:
            loc = loc + self.obstacle_K
        return np.sqrt(loc)

    def cell_data(self) -> dict:
        """Per-element fields as piecewise constant GridFunctions (for ``VTKOutput`` cell data).

        Returns
        -------
        dict
            ``eta_K``, ``eta_F_<field>``, ``eta_R_<field>``, ``eta_C`` -> GridFunction (L2, order 0).
        """
        mesh = self.flux.space.mesh
        P0 = L2(mesh, order=0)
        arrays = {"eta_K": self.eta_K, "eta_C": self.eta_C}
        for i, name in enumerate(self.fields):
            arrays[f"eta_F_{name}"] = self.eta_F[i]
            arrays[f"eta_R_{name}"] = self.eta_R[i]
        out = {}
        for name, values in arrays.items():
            gf = GridFunction(P0, name=name)
            gf.vec.FV().NumPy()[:] = values
            out[name] = gf
        return out

    def summary(self) -> dict:
        """Flat dict of totals: the proposed ``history.csv`` columns.

        ``eta`` (guaranteed bound of |||u - u_h|||), ``eta_seed`` (the seed's
        Theorem), ``eta_F`` / ``eta_R`` ((sum_K sum_alpha eta_.,K,alpha^2)^(1/2)),
        ``eta_FR``, ``eta_C`` (sum_K eta_C,K^pos), ``eta_nonc1..3``,
        ``eta_quad``, ``eta_bc``, ``eps_w``, ``eta_obstacle``, ``eta_nonc2_seed``,
        ``time_estimate_s`` and, with an exact solution, ``i_eff``.
        """
        out = {
            "eta": self.eta,
            "eta_seed": self.eta_seed,
            "eta_direct": self.eta_direct,
            "theta_contact": self.theta_contact,
            "eta_F": float(np.sqrt((self.eta_F ** 2).sum())),
            "eta_R": float(np.sqrt((self.eta_R ** 2).sum())),
            "eta_FR": self.eta_FR,
            "eta_C": float(self.eta_C.sum()),
            "eta_nonc1": self.eta_nonc1,
            "eta_nonc2": self.eta_nonc2,
            "eta_nonc3": self.eta_nonc3,
            "eta_quad": self.eta_quad,
            "eta_bc": self.eta_bc,
            "eps_w": self.eps_w,
            "eta_obstacle": self.eta_obstacle,
            "eta_trace": self.eta_trace,
            "bound_proven": int(self.bound_proven),
            "eta_nonc2_seed": self.eta_nonc2_seed,
            "time_estimate_s": self.time_total,
        }
        if self.err_energy is not None:
            out["i_eff"] = self.i_eff
        return out

def estimate(disc, x, y, options: Optional[EstimatorOptions] = None, *, err_energy: Optional[float] = None,
             errors: bool = True, flux: Optional[FluxReconstruction] = None) -> Estimate:
    """A posteriori estimate of a conforming FE solution (formulas: module docstring).

    Parameters
    ----------
    disc : FEMDiscretization
    x, y : ndarray
        algebraic solution (x = [X1, X2] at interior nodes, y = X3).
    options : EstimatorOptions, optional
        RT degree, multiplier, Dirichlet correction, ...  (default ``EstimatorOptions()``).
    err_energy : float, optional
        |||u - u_h||| computed by the caller: reported as :attr:`Estimate.err_energy` and in ``i_eff``.
    errors : bool
        without ``err_energy``: compute |||u - u_h||| when the exact solution is known.
    flux : FluxReconstruction, optional
        fluxes already computed by :func:`~.flux.reconstruct_fluxes` (then no choice of multiplier).

    Returns
    -------
    Estimate
    """
    t0 = time.perf_counter()
    opts = EstimatorOptions() if options is None else options
    sv = SolutionView.of(disc, x, y)
    q = opts.flux_degree(sv.disc.order)
    pair = None if flux is not None or opts.multiplier is not None else _candidates(sv.disc, q)
    per_flux = {} if opts.shift_obstacle and sv.disc.obstacle is not None else None
    if pair:
        # two admissible multipliers, two guaranteed bounds: keep the smaller (module doc, "Multiplier")
        if opts.batched:  # both in one batched patch solve
            fluxes = reconstruct_several(sv, q, pair, boundary=opts.boundary_multiplier)
        else:
            fluxes = [reconstruct(sv, q, multiplier=m, batched=False, regularization=opts.regularization,
                                  boundary=opts.boundary_multiplier) for m in pair]
        shared = {}  # the terms that do not depend on the multiplier, evaluated once for both
        both = [_bound(sv, q, opts, fl, shared, per_flux) for fl in fluxes]
        est = min(both, key=lambda e: e.eta)
        est.multiplier = pair[0] if est is both[0] else pair[1]
        est.eta_candidates = {m: e.eta for m, e in zip(pair, both)}
        est.time_flux = fluxes[0].time if opts.batched else sum(fl.time for fl in fluxes)
    else:
        if flux is None:
            flux = reconstruct(sv, q, multiplier=opts.multiplier, batched=opts.batched,
                               regularization=opts.regularization, boundary=opts.boundary_multiplier)
        est = _bound(sv, q, opts, flux, per_flux=per_flux)
        fluxes = [flux]
    shifted = shifted_obstacle(sv) if opts.shift_obstacle else None
    if shifted is not None:
        est.eta_plain_obstacle = est.eta
    if shifted is not None and shifted.eta < est.eta:
        # the bound for the interpolated obstacle psi~ (+ |||psi - psi~|||): the smaller one wins
        sv_t = replace(sv, disc=replace(sv.disc, obstacle=shifted.psi, obstacle_grad=shifted.grad))
        shared_t = {}
        cands = [_bound(sv_t, q, opts, fl, shared_t, per_flux) for fl in fluxes]
        k = min(range(len(cands)), key=lambda i: cands[i].eta)
        best = cands[k]
        if best.eta + shifted.eta < est.eta:
            if pair:
                best.multiplier = pair[k]
                best.eta_candidates = {m: e.eta + shifted.eta for m, e in zip(pair, cands)}
            best.time_flux, best.eta_plain_obstacle = est.time_flux, est.eta
            best.eta += shifted.eta
            best.eta_obstacle, best.obstacle_K = shifted.eta, shifted.loc
            best.eta_trace = math.hypot(best.eta_trace, shifted.eta_trace)  # psi's trace defect too (.obstacle)
            est = best
    est.time_total = time.perf_counter() - t0
    if err_energy is None and errors:
        err_energy = sv.energy_error()
    est.err_energy = err_energy
    return est


def gap_elements(lam_values: np.ndarray) -> np.ndarray:
    """The elements whose gap values the contact terms need (mask): those where lam^ is not 0 at a point of the
    rule.  The gap enters only through products with lam~, and lam~ is 0 where lam^ is (every candidate of
    :func:`.nonnegative.concentrated_multiplier` is 0 on an element with lam^ = 0 at its points)."""
    return (lam_values != 0.0).any(axis=1)


def _candidates(dv: DiscretizationView, q: int) -> Optional[Tuple[str, str]]:
    """The two multipliers of the default estimate (module doc, "Multiplier"), or None for one."""
    if dv.order < 2:
        return None
    if q >= 3:
        return ("fit", "shape")
    return ("contact", "shape") if vertex_device_exact(dv, q) else None


def _bound(sv: SolutionView, q: int, opts: EstimatorOptions, flux: FluxReconstruction,
           shared: Optional[dict] = None, per_flux: Optional[dict] = None) -> Estimate:
    """The estimate with the fluxes ``flux`` (module docstring); times and the error are set by the caller.
    ``shared``: a dict filled by the first call and read by the next ones with the same (sv, opts): the
    corrected fields and the terms independent of the multiplier (eta_nonc,2 seed, eta_nonc,1, Theta, the gap at the
    quadrature points of :func:`.nonnegative.concentrated_multiplier`).  ``per_flux``: a dict filled and read by the
    calls for the same fluxes and two obstacles (:mod:`.obstacle`): the terms that do not depend on the obstacle
    (the flux residuals and lam~ per flux, the seed's eta_nonc,2)."""
    dv = sv.disc
    p = dv.order
    fields, lam = flux.fields, flux.lam  # lam: the multiplier of the equilibration, lam^_h
    with TaskManager():
        ig = Integrals.of(dv, opts)
        C_om = ig.C_F * ig.C_mu
        # corrected solution u~_h = u_h + w_h (exact Dirichlet trace)
        ws, eta_bc, eps_w, bc_K = dirichlet_lifting(dv, fields, opts.dirichlet_correction)  # cached per disc
        if not shared:
            shared = {} if shared is None else shared
            vals, grads, gap, ggap = corrected_fields(dv, fields, ws)
            if per_flux is None or "seed" not in per_flux:
                lam_d = sv.gfs["lam"]  # the discrete (dual-basis for p >= 2) multiplier of the seed
                seed = C_om * math.sqrt(max(float(negative_part_squares(ig, lam_d).sum()), 0.0))
                if per_flux is not None:
                    per_flux["seed"] = seed
            shared["seed"] = seed if per_flux is None else per_flux["seed"]
            nc = nonconformity(sv, ig, gap, ggap, exact_bc=all(w is None for w in ws))
            shared.update(fields=(vals, grads, gap, ggap), nc=nc,
                          theta=contact_work(ig, fields, grads, nc.n, nc.grad_n, nc.support))
        vals, grads, gap, ggap = shared["fields"]
        nc = shared["nc"]
        nonc1, corr, nonc1_K = nc.eta, nc.n, nc.loc
        nonc2_seed, theta = shared["seed"], shared["theta"]
        if per_flux is not None and id(flux) in per_flux:  # the flux is alive in the caller: its id is unique
            eta_F, eta_R, eta_FR, eta_quad, (lam_t, nonc2, loc_K) = per_flux[id(flux)]
        else:
            corrected = any(w is not None for w in ws)
            eta_F, eta_R, eta_FR, eta_quad = flux_residual(ig, fields, flux.sigma, grads,
                                                           [fd.sign * lam for fd in fields],
                                                           fl_rule=flux_rule_order(dv, q, corrected),
                                                           data_support=flux.lam_support)
            # multiplier: lam~ >= 0 and eta_nonc,2
            lam_t, nonc2, loc_K = nonnegative_part(ig, lam, flux.lam_order, eta_FR)
            if per_flux is not None:
                per_flux[id(flux)] = (eta_F, eta_R, eta_FR, eta_quad, (lam_t, nonc2, loc_K))
        if opts.concentrates(p):
            # lam~ moved towards the small gaps inside every element (:func:`concentrated_multiplier`); lam~
            # vanishes where lam^ does (.nonnegative), so with lam^'s support known only its elements are visited
            sub = None if flux.lam_support is None else np.flatnonzero(flux.lam_support)
            if sub is not None:
                qa = QuadratureArrays(ig.mesh, 2 * p + 6, sub)
                gap_v, corr_v, known = np.zeros(qa.W.shape), np.zeros(qa.W.shape), np.zeros(len(sub), dtype=bool)
            else:
                if "qa" not in shared:  # the values of the gap and of n, filled element by element as needed
                    qa = ig.quadrature(2 * p + 6)
                    shared["qa"] = qa, np.zeros(qa.W.shape), np.zeros(qa.W.shape), np.zeros(len(qa.W), dtype=bool)
                qa, gap_v, corr_v, known = shared["qa"]
            rows = slice(None) if sub is None else sub  # the elements of the rows of qa's arrays
            lam_v = qa.values(lam_t)
            need = np.flatnonzero(gap_elements(lam_v) & ~known)
            if len(need):
                gap_v[need] = qa.values(gap, need)
                corr_v[need] = nc.values(qa, gap_v[need], need)
                known[need] = True
            lam_v, loc2 = concentrated_multiplier(qa, lam_v, gap_v + corr_v, ig.h[rows], ig.C_mu,
                                                  eta_FR + eta_quad + nonc2 + 2.0 * nonc1)
            nonc2 += ig.C_mu * math.sqrt(float(loc2.sum()))
            loc_K = loc_K.copy()
            loc_K[rows] += loc2
            eta_C = np.zeros(ig.mesh.ne)
            eta_C[rows] = 2.0 * qa.integrate(lam_v * gap_v)                        # eta_C,K^pos
            nonc3 = 2.0 * float(qa.integrate(lam_v * corr_v).sum()) if corr is not None else 0.0
        else:
            eta_C = 2.0 * ig.ew(lam_t * gap)                                        # eta_C,K^pos
            # 2 (lam~, (s~ - u~_h)_1 - (s~ - u~_h)_2), evaluated exactly (the seed bounds it by 2 C ||lam^pos|| eta_nonc,1)
            nonc3 = 2.0 * float(ig.ew(lam_t * corr).sum()) if corr is not None else 0.0
    sum_C = float(eta_C.sum())
    # seed "Theorem (A posteriori error estimate)": bound of |||u - s~_h|||
    eta_seed = math.sqrt(max((eta_FR + eta_quad + nonc1 + nonc2) ** 2 + nonc3 + sum_C, 0.0))
    # direct bound of |||u - u~_h||| (module docstring, "Direct bound"): x^2 <= A x + B; B < 0 would be
    # admissible here, but not in the split of .components (its per-component roots need B_disc, B_lin >= 0):
    # clamped alike, so that eta_disc = eta at convergence
    eta_direct = direct_root(eta_FR + eta_quad + nonc1 + nonc2, theta + 0.5 * sum_C)
    eta = math.hypot(min(eta_seed + nonc1, eta_direct) + eps_w, eta_bc)           # bound of |||u - u_h|||
    # what the lifting leaves out of non-polynomial data (w_h of degree p + 2), or without the correction what u_h's
    # trace (degree p) does: the proof takes it as negligible either way
    if opts.dirichlet_correction:
        eta_tr = trace_defect(dv, fields, p + 2) if any(w is not None for w in ws) else 0.0
    else:
        eta_tr = trace_defect(dv, fields, p)
    return Estimate(fields=tuple(fd.name for fd in fields), eta_F=eta_F, eta_R=eta_R, eta_C=eta_C, h=ig.h,
                    eta_FR=eta_FR, eta_quad=eta_quad, eta_nonc1=nonc1, eta_nonc2=nonc2, eta_nonc3=nonc3,
                    eta_bc=eta_bc, eps_w=eps_w, eta_nonc2_seed=nonc2_seed, C_F=ig.C_F, C_Omega_mu=C_om,
                    eta_seed=eta_seed, eta=eta, time_flux=flux.time, flux=flux, bc_K=bc_K,
                    nonc2_K=ig.C_mu ** 2 * loc_K, nonc1_K=nonc1_K, eta_direct=eta_direct, theta_contact=theta,
                    eta_trace=eta_tr)
