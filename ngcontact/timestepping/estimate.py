r"""Space-time a posteriori estimate of the backward Euler / P_p scheme ([CMAME20]; Ern-Vohralik SINUM 2010
for the heat equation).

Per step (spatial part).  At step n the discrete equations are those of the stationary problem
with the load f_a(t_n) - tau_a^n, tau^n = (u_h^n - u_h^{n-1}) / dt = d_t u_htau (u_htau the
affine-in-time interpolant of the u_h^n): the stationary estimator of :mod:`ngcontact.estimators`
(:func:`~ngcontact.estimators.estimate_components`, equilibrated fluxes sigma_a^n with
div sigma_a^n = Pi_q(f_a^n - tau_a^n + s_a lam^_h)) is evaluated on a :class:`StepDiscretization`:
the discretization with that load and the step's system E X = F^n (its residual is the algebraic
residual of the step).  With the consistent mass matrix in E the patch problems are compatible.

Energy argument.  e = u - u_htau (two fields), |||v|||^2 = sum_a mu_a ||grad v_a||^2.  Testing the
weak form with e on I_n and inserting sigma^n:

    1/2 d_t ||e||^2 + |||e|||^2 = sum_a [(f_a - f_a^n, e_a) + (rho_a, e_a) - (sigma_a^n + mu_a grad u_htau,a, grad e_a)]
                                  + (lam - lam^, e1 - e2),

rho_a = f_a^n - tau_a + s_a lam^ - div sigma_a^n.  With u_htau(t) - u_h^n = (1 - s)(u_h^{n-1} - u_h^n),
s = (t - t_{n-1}) / dt, and the stationary terms, the residual is bounded by
eta(t) |||e||| + P(t), where

    eta(t) = A_n + (1 - s) B_n + eta_f(t),
    A_n    = eta_FR + eta_quad + eta_nonc,2 (disc + lin) + eta_alg        (spatial: the stationary terms),
    B_n    = |||u_h^n - u_h^{n-1}|||                                        (temporal),
    eta_f  = (sum_a C_F^2 / mu_a ||f_a(t) - f_a(t_n)||^2)^{1/2}             (data oscillation in time),
    P(t)   = (lam~^n, g_htau(t)),  g_htau = u1htau - u2htau,

provided g_htau >= 0 and lam~^n >= 0 (then (lam, e1 - e2) = -(lam, g_htau) <= 0 and
-(lam~, e1 - e2) <= (lam~, g_htau)).  Young's inequality and integration over (0, T) give

    ||e(T)||^2 + int_0^T |||e|||^2 dt <= ||e(0)||^2 + (eta_sp,tm + eta_f)^2 + eta_C^2 =: eta_st^2,
    eta_sp,tm^2 = sum_n dt (A_n^2 + A_n B_n + B_n^2 / 3)       (exact integral of the affine part),
    eta_f^2     = sum_n int_{I_n} eta_f(t)^2 dt                   (3-point Gauss in t),
    eta_C^2     = 2 int P = sum_n dt (lam~^n, g_h^n + g_h^{n-1}).

The hypotheses hold for P1 with nodal gaps >= 0 and X3 >= 0 (the P1 gap is then >= 0 everywhere,
affine in time as well; lam~ = lam^ = lam_h >= 0): :attr:`SpaceTimeEstimate.proven` records whether
they held at every step (and that the Dirichlet data needed no correction).  For p >= 2 the
discrete gap may be negative between the nodes, which this argument does not cover: the numbers
are then reported with ``proven = False``.  The reported parts are eta_sp = (sum dt A_n^2)^{1/2},
eta_tm = (sum dt B_n^2 / 3)^{1/2}, eta_f, eta_C, eta_init = ||e(0)||.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field, replace

import numpy as np
from ngsolve import GridFunction, Integrate, InnerProduct, grad

from ..algebra.certificate import gap_unit
from ..estimators import EstimatorOptions, algebraic_flux, estimate_components, friedrichs_constant
from ..estimators.nonnegative import QuadratureArrays

__all__ = ["StepDiscretization", "StepEstimator", "SpaceTimeEstimate", "GAUSS3"]

#: 3-point Gauss rule on (0, 1): points, weights
GAUSS3 = (np.array([0.5 - math.sqrt(0.15), 0.5, 0.5 + math.sqrt(0.15)]), np.array([5.0, 8.0, 5.0]) / 18.0)


class StepDiscretization:
    """The stationary discretization seen by the estimators at one time step: the base
    :class:`~ngcontact.discretizations.fem.FEMDiscretization` with ``system`` the step's system and
    ``problem`` the stationary data with loads f_a(t_n) - tau_a (set per iterate by :meth:`set_iterate`).
    Everything else is the base discretization's (one object per run: the estimators' per-mesh cache
    is kept across steps)."""

    def __init__(self, base):
        self._base = base
        self.system = base.system
        self.problem = base.problem

    def __getattr__(self, name):
        return getattr(self._base, name)

    def set_iterate(self, system, x, x_prev, dt: float) -> None:
        base = self._base
        self.system = system
        ni = base.n_interior
        taus = []
        for a in range(base.nfields):
            full = np.zeros(base.fes.ndof)
            full[base.interior] = (x[a * ni:(a + 1) * ni] - x_prev[a * ni:(a + 1) * ni]) / dt
            gf = GridFunction(base.fes, name=f"tau{a + 1}")
            gf.vec.FV().NumPy()[:] = base.nodes.T @ full
            taus.append(gf)
        stat = base.problem
        self.problem = replace(stat, f1=stat.f1 - taus[0], f2=stat.f2 - taus[1], exact=None)


class StepEstimator:
    """Estimator components of an iterate of step n (``components(d, y, r_alg, dx)``: the interface the
    adaptive Krylov strategy of the Newton loop calls), d the increment X - X^{n-1} that the loop solves for
    (:meth:`~.euler.BackwardEuler.increment_system`); the estimators see X and the step's ``system``."""

    def __init__(self, stepper, options: EstimatorOptions = None):
        self.stepper = stepper
        self.view = StepDiscretization(stepper.disc)
        self.options = options or EstimatorOptions()
        self.system = self.x_prev = self.dt = None

    def set_step(self, system, x_prev, t: float, dt: float) -> None:
        self.system, self.x_prev, self.t, self.dt = system, x_prev, t, dt

    def components(self, d, y, r_alg=None, dx_alg=None):
        x = self.x_prev + d
        self.stepper.problem.set_time(self.t)
        self.view.set_iterate(self.system, x, self.x_prev, self.dt)
        sig = None if dx_alg is None else algebraic_flux(self.view, dx_alg, self.options)
        return estimate_components(self.view, x, y, r_alg=r_alg, sigma_alg=sig, options=self.options)


@dataclass
class SpaceTimeEstimate:
    """Accumulates the space-time bound (module docstring) step by step."""

    eta_init: float = 0.0
    sp_tm2: float = 0.0
    sp2: float = 0.0
    tm2: float = 0.0
    f2: float = 0.0
    C2: float = 0.0
    proven: bool = True
    why_not: list = field(default_factory=list)

    def add_step(self, n: int, dt: float, A: float, B: float, C: float, f2: float, ok: bool, why: str = "") -> dict:
        """Add step n: spatial A_n, temporal B_n, contact C_n = (lam~, g^n + g^{n-1}), int_{I_n} eta_f^2."""
        self.sp_tm2 += dt * (A * A + A * B + B * B / 3.0)
        self.sp2 += dt * A * A
        self.tm2 += dt * B * B / 3.0
        self.f2 += f2
        self.C2 += dt * max(C, 0.0)
        if not ok and self.proven:
            self.proven = False
            self.why_not.append(f"step {n}: {why}")
        return {"eta_sp_n": A, "eta_tm_n": B / math.sqrt(3.0), "eta_C_n": math.sqrt(max(C, 0.0)),
                "eta_f_n": math.sqrt(f2 / dt)}

    @property
    def eta(self) -> float:
        return math.sqrt(self.eta_init ** 2 + (math.sqrt(self.sp_tm2) + math.sqrt(self.f2)) ** 2 + self.C2)

    def summary(self) -> dict:
        return {"eta_st": self.eta, "eta_sp": math.sqrt(self.sp2), "eta_tm": math.sqrt(self.tm2),
                "eta_f": math.sqrt(self.f2), "eta_C": math.sqrt(self.C2), "eta_init": self.eta_init,
                "bound_proven": self.proven, "bound_not_proven_because": "; ".join(self.why_not)}


def spatial_part(comp) -> float:
    """A_n of the module docstring from the stationary components of the final iterate of a step."""
    t = comp.terms
    return float(t["eta_FR_disc"] + t["eta_quad"] + t["nonc2_disc"] + t["nonc2_lin"] + comp.eta_alg)


#: gaps and multipliers above -ROUND_OFF_HYP times their units count as nonnegative in :func:`hypotheses`
#: (Fischer-Burmeister iterates end with X3 ~ -1e-14 where the multiplier is 0)
ROUND_OFF_HYP = 1e-13


def hypotheses(disc, x, y, comp) -> tuple:
    """(ok, why): the hypotheses of the bound at this step (P1, nodal gaps >= 0, X3 >= 0, exact Dirichlet data)."""
    if disc.order != 1:
        return False, f"P{disc.order}: the discrete gap may be negative between the nodes"
    g = disc.system.gap(x)
    if g.min(initial=0.0) < -ROUND_OFF_HYP * gap_unit(disc.system, x):  # round-off of the gaps, in units of u
        return False, f"negative nodal gap {g.min():.3e}"
    if y.min(initial=0.0) < -ROUND_OFF_HYP * float(np.max(np.abs(y), initial=0.0)):  # in units of X3
        return False, f"negative multiplier X3 {y.min():.3e}"
    if comp.terms["eta_bc"] > 0 or comp.terms["eps_w"] > 0:
        return False, "Dirichlet data needed a correction"
    return True, ""


class TimeIntegrals:
    """The integrals over a step that need the data at several times: exact errors, f oscillation, contact term."""

    def __init__(self, stepper):
        self.stepper = stepper
        disc = stepper.disc
        self.problem = stepper.problem
        self.order = 2 * disc.order + disc.quad_bonus
        self.qa = QuadratureArrays(disc.mesh, min(self.order, 12))
        self.C_F = friedrichs_constant(stepper.problem.stationary, disc.mesh)

    def fields(self, x, y):
        return self.stepper.disc.gridfunctions(x, y)

    def contact(self, g_now, g_prev, lam) -> float:
        """(lam~, g^n + g^{n-1}) with lam~ = the multiplier function of X3^+ (p = 1: lam_h)."""
        mesh = self.stepper.disc.mesh
        return float(Integrate(lam * (g_now + g_prev), mesh, order=self.order))

    def f_oscillation(self, t0: float, t1: float) -> float:
        """int_{t0}^{t1} sum_a C_F^2 / mu_a ||f_a(t) - f_a(t1)||^2 dt (3-point Gauss in t); 0 for data constant in t."""
        if not self.stepper.time_dependent:
            return 0.0
        P, st = self.problem, self.problem.stationary
        P.set_time(t1)
        ref = [self.qa.values(f) for f in st.loads]
        total = 0.0
        for s, w in zip(*GAUSS3):
            P.set_time(t0 + s * (t1 - t0))
            for f, fn, mu in zip(st.loads, ref, st.mus):
                total += w * (t1 - t0) * self.C_F ** 2 / mu * float(self.qa.integrate((self.qa.values(f) - fn) ** 2).sum())
        P.set_time(t1)
        return total

    def energy_error2(self, gf_prev, gf_now, t0: float, t1: float) -> float:
        """int_{t0}^{t1} |||u(t) - u_htau(t)|||^2 dt (3-point Gauss in t; exact solution needed)."""
        P = self.problem
        ex, mesh = P.exact, self.stepper.disc.mesh
        total = 0.0
        for s, w in zip(*GAUSS3):
            P.set_time(t0 + s * (t1 - t0))
            for a, (name, mu) in enumerate(zip(P.field_names, P.mus)):
                d = ex.gradient(a + 1) - ((1 - s) * grad(gf_prev[name]) + s * grad(gf_now[name]))
                total += w * (t1 - t0) * mu * Integrate(InnerProduct(d, d), mesh, order=self.order)
        P.set_time(t1)
        return total

    def l2_error2(self, gfs, t: float, fields=None) -> float:
        """sum_a ||u_a - u_ah||^2 at time t (u: ``fields``, default the exact solution)."""
        P = self.problem
        P.set_time(t)
        ex = fields or (P.exact.u1, P.exact.u2)
        mesh = self.stepper.disc.mesh
        return float(sum(Integrate((u - gfs[n]) ** 2, mesh, order=self.order) for u, n in zip(ex, P.field_names)))
