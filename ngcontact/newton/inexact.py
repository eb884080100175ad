r"""Inexact and adaptive inexact semismooth Newton ([JSC20]; seed slides "Inexact
semismooth Newton method", "Adaptive algorithm", "Numerical experiments P2",
"Overall performance").

Step k solves A^{k-1} X^k = B^{k-1} (A = [E; J_C(X^{k-1})], B = [F;
J_C X^{k-1} - C(X^{k-1})]) by restarted GMRES + ILU (:mod:`ngcontact.algebra.krylov`)
warm-started from X^{k,0} = X^{k-1}, giving A X^{k,i} = B - R^{k,i}.

Which linear system GMRES sees.  [JSC20] runs GMRES on the 3-field system.
We run it on the reduced SPD system of :meth:`ComplementaritySystem.linearize`
(the system the exact driver :func:`ngcontact.newton.semismooth_newton`
factorizes: slave unknowns of the contact set eliminated, multiplier fixed
off it, recovered afterwards).  Every reduced iterate z^{i} is mapped to a
3-field iterate X^{k,i} = (x, y) (:meth:`LinearizedStep.recover`) that
satisfies the constraint rows of A X = B exactly, so the algebraic residual
of the 3-field system is

    R^{k,i} = B - A X^{k,i} = [F - (K x - B^T D y); 0],

nonzero only in the membrane equations, with ||R^{k,i}|| = ||b_red - A_red z^{i}||
(checked in ``tests/test_inexact.py``).  This is exactly the structure the
a posteriori analysis assumes (the algebraic residual functions r_alpha,h of
the membranes, complementarity rows of the linear system satisfied), and all
tolerances below are the [JSC20] ones, on the 3-field quantities ||R|| / ||B||.
The reduced system is SPD and 1/3 smaller; ILU needs no pivoting there.

Modes (:class:`InexactOptions`; defaults of [JSC20]):

* ``exact``: GMRES to ||R^{k,i}|| / ||B^{k-1}|| <= ``tol_alg`` (2e-12), Newton
  to ||Phi(X^k)|| / ||F|| <= ``tol`` (1e-10);
* ``inexact``: ||R^{k,i}|| <= eta_k ||R^{k,0}||, forcing term
  eta_k = min(||Phi(X^{k-1})|| / ||F||, ``forcing_max`` = 0.5) (the relative
  Newton residual R_lin of the previous iterate), same outer test.  The test
  as printed in [JSC20] / REFERENCE.md, ||R^{k,i}|| / ||B^{k-1}|| <=
  ||R_lin|| / ||F||, holds already at i = 0 for the warm start X^{k,0} =
  X^{k-1} (then R^{k,0} = -Phi(X^{k-1}) and ||B|| >= ||F||), so GMRES would
  never iterate; we read it as the Dembo-Eisenstat-Steihaug condition
  ||R^{k,i}|| <= eta_k ||R^{k,0}|| with that forcing term.  (R^{k,0} is the
  residual of the reduced warm start, i.e. of X^{k-1} with the new contact
  set's constraints imposed, not -Phi(X^{k-1}), hence the relative form;)
* ``adaptive``: every ``nu`` GMRES iterations the estimators eta_disc, eta_lin,
  eta_alg of the iterate X^{k,i} are evaluated
  (:func:`ngcontact.estimators.components.estimate_components`, with the
  algebraic flux of :mod:`ngcontact.estimators.algebraic`, built from the
  ``nu`` following iterations: evaluating X^{k,i} needs X^{k,i+nu}); GMRES
  stops at the first i >= nu with eta_alg <= gamma_alg max(eta_disc, eta_lin)
  (:func:`stop_linear`) and X^k := X^{k,i}; Newton stops when
  eta_lin <= gamma_lin eta_disc (:func:`stop_newton`) -- or, as a safeguard,
  when ||Phi|| / ||F|| <= tol.

GMRES counts are the iterations actually performed (for ``adaptive`` they
include the nu look-ahead iterations of the last evaluation); the index i of
the accepted iterate is recorded as well (``gmres_accepted``).
"""
from __future__ import annotations

import math
import time
from dataclasses import dataclass, field
from typing import Callable, List, Optional

import numpy as np

from ..algebra.cfunctions import get_cfunction
from ..algebra.system import ComplementaritySystem, LinearizedStep
from ..algebra.krylov import ILU, KrylovState, gmres
from .loop import IterationRecord, NewtonResult, armijo_backtracking, round_off_hint

__all__ = ["MODES", "InexactOptions", "InexactIterationRecord", "InexactResult", "EstimatorRecord",
           "inexact_semismooth_newton", "stop_linear", "stop_newton", "algebraic_residual", "rhs_norm"]

MODES = ("exact", "inexact", "adaptive")
#: numeric codes of :attr:`KrylovResult.reason` in the records (newton.csv holds numbers only)
GMRES_STOP = {"tolerance": 0, "monitor": 1, "maxiter": 2, "stagnation": 3}


def stop_linear(eta_alg: float, eta_disc: float, eta_lin: float, gamma_alg: float) -> bool:
    """Adaptive stopping criterion of the linear solver ([JSC20], seed "Adaptive algorithm").

    >>> stop_linear(0.3, 1.0, 0.5, 0.3), stop_linear(0.31, 1.0, 0.5, 0.3), stop_linear(0.3, 0.5, 1.0, 0.3)
    (True, False, True)
    """
    return eta_alg <= gamma_alg * max(eta_disc, eta_lin)


def stop_newton(eta_lin: float, eta_disc: float, gamma_lin: float) -> bool:
    """Adaptive stopping criterion of the semismooth Newton loop: eta_lin <= gamma_lin eta_disc.

    >>> stop_newton(0.03, 0.1, 0.3), stop_newton(0.031, 0.1, 0.3)
    (True, False)
    """
    return eta_lin <= gamma_lin * eta_disc


@dataclass(frozen=True)
class InexactOptions:
    """Settings of :func:`inexact_semismooth_newton` (module docstring).

    Every field is checked; errors name it.
    """

    mode: str = "inexact"
    cfun: str = "min"
    tol: float = 1e-10          # outer: ||Phi(X^k)|| / ||F||
    tol_alg: float = 2e-12      # exact mode: ||R^{k,i}|| / ||B^{k-1}||
    gamma_alg: float = 0.3
    gamma_lin: float = 0.3
    nu: int = 10
    maxit: int = 200
    restart: int = 100
    max_gmres: int = 5000       # per Newton step
    # ILU(drop 1e-5, fill 8): measured on the disk P1 35k exact-gmres run (14 Newton steps):
    # (1e-4, 2) 3712 GMRES / 12.5 s, (1e-5, 2) 3884 / 12.9 s, (1e-4, 4) 3117 / 13.1 s,
    # (1e-5, 8) 2314 / 11.7 s, (1e-6, 10) 2128 / 12.2 s -- fewest iterations at the lowest time
    ilu_drop_tol: float = 1e-5
    ilu_fill: float = 8.0
    line_search: Optional[bool] = None  # default: on for 'fb'
    armijo: float = 1e-4
    min_step: float = 2.0 ** -30
    flux_order: Optional[int] = None    # RT degree of the estimators (default: p)
    alg_flux_order: Optional[int] = None  # RT degree of sigma_alg (default p - 1: contains -mu grad u_h)
    log_estimators: bool = False  # exact/inexact: also evaluate eta_* after every Newton step
    forcing_max: float = 0.5      # inexact: cap of the forcing term eta_k

    def __post_init__(self):
        def bad(name, want):
            raise ValueError(f"option {name} must be {want}, got {getattr(self, name)!r}")

        if self.mode not in MODES:
            bad("mode", f"one of {MODES}")
        try:
            get_cfunction(self.cfun)
        except Exception:
            bad("cfun", "'min' or 'fb'")
        for name in ("tol", "tol_alg"):
            v = getattr(self, name)
            if not (isinstance(v, (int, float)) and 0 < v < 1):
                bad(name, "a number in (0, 1)")
        for name in ("gamma_alg", "gamma_lin"):
            v = getattr(self, name)
            if isinstance(v, bool) or not (isinstance(v, (int, float)) and 0 < v < 1):
                bad(name, "a number in (0, 1) ([JSC20]: gamma < 1)")
        if isinstance(self.ilu_drop_tol, bool) or not (isinstance(self.ilu_drop_tol, (int, float))
                                                       and 0 <= self.ilu_drop_tol < 1):
            bad("ilu_drop_tol", "a number in [0, 1)")
        if isinstance(self.ilu_fill, bool) or not (isinstance(self.ilu_fill, (int, float))
                                                   and 1 <= self.ilu_fill < math.inf):
            bad("ilu_fill", "a number >= 1")
        for name in ("nu", "maxit", "restart", "max_gmres"):
            v = getattr(self, name)
            if not (isinstance(v, int) and v >= 1):
                bad(name, "a positive integer")


@dataclass
class InexactIterationRecord(IterationRecord):
    """One Newton iteration of :func:`inexact_semismooth_newton` (adds the Krylov counters and estimators)."""

    gmres_its: int = 0           # GMRES iterations performed in this step
    gmres_cum: int = 0           # cumulated over the steps of this solve
    gmres_accepted: int = 0      # index i of the accepted iterate X^{k,i}
    gmres_stop: int = 0          # why GMRES stopped: 0 tolerance, 1 adaptive criterion, 2 maxiter, 3 stagnation
    res_alg: float = float("nan")  # ||R^{k,i}|| / ||B^{k-1}|| of the accepted iterate
    eta_disc: float = float("nan")
    eta_lin: float = float("nan")
    eta_alg: float = float("nan")
    eta: float = float("nan")
    n_estimates: int = 0
    time_estimate: float = 0.0
    time_ilu: float = 0.0
    ilu_fill_ratio: float = float("nan")  # nnz(L + U) / nnz(A) of the ILU of this step


@dataclass
class EstimatorRecord:
    """One estimator evaluation (adaptive mode: every nu GMRES iterations)."""

    k: int
    i: int
    eta_disc: float
    eta_lin: float
    eta_alg: float
    res_alg: float
    stop_linear: bool
    alg_flux: float = float("nan")  # ||mu^{-1/2} sigma_alg|| part of eta_alg (when the estimator reports it)
    alg_res: float = float("nan")   # remainder part ||r - div sigma_alg||_{-1} of eta_alg


@dataclass
class InexactResult(NewtonResult):
    """:class:`~ngcontact.newton.NewtonResult` plus Krylov counters and the estimator log."""

    mode: str = "inexact"
    estimates: List[EstimatorRecord] = field(default_factory=list)

    @property
    def gmres_total(self) -> int:
        return sum(getattr(r, "gmres_its", 0) for r in self.history)

    @property
    def time_estimate(self) -> float:
        return sum(getattr(r, "time_estimate", 0.0) for r in self.history)


def rhs_norm(system: ComplementaritySystem, x, y, C, Ca, Cb) -> float:
    """||B^{k-1}|| of the 3-field linearization, B = [F; Ca (g + b) + Cb y - C] at (x, y) = X^{k-1}."""
    g = system.gap(x)
    b3 = Ca * (g + system.b) + Cb * y - C
    return float(np.sqrt(system.F @ system.F + b3 @ b3))


def algebraic_residual(system: ComplementaritySystem, x_new, y_new, x, y, C, Ca, Cb) -> np.ndarray:
    """R = B - A X' of the 3-field linearization at X = (x, y), for X' = (x_new, y_new).

    Layout [membrane rows (n); constraint rows (m)], the layout of ``disc.system``.
    """
    r_x = -system.residual(x_new, y_new)  # F - (K x' - B^T D y')
    g = system.gap(x)
    r_c = (Ca * (g + system.b) + Cb * y - C) - (Ca * (system.gap(x_new) + system.b) + Cb * y_new)
    return np.concatenate([r_x, r_c])


def _alg_terms(comp):
    terms = getattr(comp, "terms", None) or {}
    return float(terms.get("alg_flux", float("nan"))), float(terms.get("alg_res", float("nan")))


def _components(disc, x, y, r_alg, sigma_alg, flux_order):
    from ..estimators import EstimatorOptions, estimate_components

    return estimate_components(disc, x, y, r_alg=r_alg, sigma_alg=sigma_alg,
                               options=EstimatorOptions(flux_order=flux_order))


def inexact_semismooth_newton(
    system: ComplementaritySystem,
    x0: np.ndarray,
    y0: np.ndarray,
    options: InexactOptions = InexactOptions(),
    callback: Optional[Callable[[InexactIterationRecord], None]] = None,
    *,
    disc=None,
    components: Optional[Callable] = None,
) -> InexactResult:
    """Inexact / adaptive inexact semismooth Newton (module docstring).

    Parameters
    ----------
    system : ComplementaritySystem
    x0, y0 : ndarray
        initial guess X^0.
    options : InexactOptions
    callback : callable, optional
        ``callback(record)`` after every Newton iteration.
    disc : FEMDiscretization, optional
        needed for ``mode="adaptive"`` and ``log_estimators`` (the estimators
        live on the mesh).
    components : callable, optional
        ``components(disc, x, y, r_alg, sigma_alg, flux_order)`` returning an
        object with ``eta_disc``, ``eta_lin``, ``eta_alg`` (and ``eta``);
        default :func:`ngcontact.estimators.components.estimate_components`.

    Returns
    -------
    InexactResult
    """
    opt = options
    adaptive = opt.mode == "adaptive"
    want_eta = adaptive or opt.log_estimators
    if want_eta and disc is None:
        raise ValueError(f"mode {opt.mode!r} with estimators needs the discretization (disc=...)")
    comp_fn = components or _components
    cf = get_cfunction(opt.cfun)
    line_search = opt.line_search if opt.line_search is not None else cf.name == "fb"
    scale = max(np.linalg.norm(system.F), np.finfo(float).tiny)
    x, y = np.array(x0, dtype=float), np.array(y0, dtype=float)

    def merit(x, y):
        r = system.residual(x, y)
        c = cf.value(system.gap(x), y)
        return r, c, 0.5 * (r @ r + c @ c)

    def sigma_alg_of(dx):
        from ..estimators import EstimatorOptions, algebraic_flux

        return algebraic_flux(disc, dx, EstimatorOptions(alg_flux_order=opt.alg_flux_order))

    t_start = time.perf_counter()
    r, c, psi = merit(x, y)
    active = system.gap(x) <= y
    history: List[InexactIterationRecord] = [InexactIterationRecord(
        0, float(np.sqrt(2 * psi) / scale), float(np.linalg.norm(r) / scale), float(np.linalg.norm(c) / scale),
        int(active.sum()), 0, 0.0, 0.0, time.perf_counter() - t_start)]
    estimates: List[EstimatorRecord] = []
    if callback:
        callback(history[-1])

    def result(converged, reason, k):
        return InexactResult(x, y, converged, reason, k, history, mode=opt.mode, estimates=estimates)

    if history[-1].res <= opt.tol:
        return result(True, "converged", 0)
    reason = f"maximum number of iterations ({opt.maxit}) reached"
    gmres_cum = 0
    for k in range(1, opt.maxit + 1):
        t0 = time.perf_counter()
        g = system.gap(x)
        Ca, Cb = cf.jacobian(g, y)
        lin: LinearizedStep = system.linearize(x, y, c, Ca, Cb)
        Bnorm = rhs_norm(system, x, y, c, Ca, Cb)
        bred = float(np.linalg.norm(lin.b)) or 1.0
        M = ILU(lin.A, opt.ilu_drop_tol, opt.ilu_fill)
        z0 = lin.restrict(x)
        t_est = 0.0
        n_est = 0
        accepted = {}

        if opt.mode == "exact":
            target = opt.tol_alg * Bnorm                       # ||R^{k,i}|| <= tol_alg ||B^{k-1}||
        elif opt.mode == "inexact":
            eta_k = min(history[-1].res, opt.forcing_max)      # forcing ||Phi(X^{k-1})|| / ||F||
            target = eta_k * float(np.linalg.norm(lin.b - lin.A @ z0))  # ||R^{k,i}|| <= eta_k ||R^{k,0}||
        else:
            target = 1e-14 * Bnorm  # adaptive: the estimators stop GMRES; this only guards stagnation
        target = max(target, 1e-14 * Bnorm)  # attainable accuracy in double precision
        rtol = target / bred  # ||r_red|| = ||R^{k,i}|| (module docstring)

        monitor = None
        if adaptive:
            checkpoints: List[KrylovState] = []

            def monitor(st: KrylovState):
                nonlocal t_est, n_est
                checkpoints.append(KrylovState(st.i, st.x.copy(), st.r, st.res))
                if len(checkpoints) < 3:  # evaluate X^{k,i} for i >= nu (needs X^{k,i+nu})
                    return False
                prev, cur = checkpoints[-2], checkpoints[-1]
                te = time.perf_counter()
                xi, yi = lin.recover(prev.x)
                xj, _ = lin.recover(cur.x)
                R = algebraic_residual(system, xi, yi, x, y, c, Ca, Cb)
                comp = comp_fn(disc, xi, yi, R, sigma_alg_of(xj - xi), opt.flux_order)
                n_est += 1
                t_est += time.perf_counter() - te
                res_alg = float(np.linalg.norm(R)) / Bnorm
                stop = stop_linear(comp.eta_alg, comp.eta_disc, comp.eta_lin, opt.gamma_alg)
                estimates.append(EstimatorRecord(k, prev.i, comp.eta_disc, comp.eta_lin, comp.eta_alg, res_alg, stop,
                                                 *_alg_terms(comp)))
                if stop:
                    accepted.update(x=xi, y=yi, i=prev.i, comp=comp, res_alg=res_alg)
                return stop

        tl = time.perf_counter()
        kr = gmres(lin.A, lin.b, z0, M, rtol=rtol, restart=opt.restart, maxiter=opt.max_gmres, nu=opt.nu,
                   monitor=monitor)
        time_linear = time.perf_counter() - tl - t_est + M.time_setup
        gmres_cum += kr.iterations
        if accepted:
            x_full, y_full, i_acc, comp = accepted["x"], accepted["y"], accepted["i"], accepted["comp"]
            res_alg = accepted["res_alg"]
        else:
            x_full, y_full = lin.recover(kr.x)
            i_acc, comp = kr.iterations, None
            R = algebraic_residual(system, x_full, y_full, x, y, c, Ca, Cb)
            res_alg = float(np.linalg.norm(R)) / Bnorm

        xp, yp, cp = x, y, c
        step = 1.0
        if line_search:
            step, (xt, yt, rt, ct, psit) = armijo_backtracking(merit, x, y, x_full, y_full, psi,
                                                               opt.armijo, opt.min_step)
            failed = step < opt.min_step
            x, y, r, c, psi = xt, yt, rt, ct, psit
        else:
            failed = False
            x, y = x_full, y_full
            r, c, psi = merit(x, y)

        if want_eta and (comp is None or step < 1.0):
            # estimators of the new iterate: exact/inexact logging, a damped (fb) step, or an
            # adaptive GMRES run that ended on its tolerance before the adaptive test triggered
            te = time.perf_counter()
            sig, r_alg = None, None
            if step == 1.0:
                r_alg = algebraic_residual(system, x, y, xp, yp, cp, Ca, Cb)
                if kr.reason != "tolerance" or opt.mode == "inexact":
                    # sigma_alg from nu further iterations (diagnostic look-ahead, not counted)
                    extra = gmres(lin.A, lin.b, kr.x, M, rtol=0.0, restart=opt.nu, maxiter=opt.nu)
                    xj, _ = lin.recover(extra.x)
                    sig = sigma_alg_of(xj - x)
            comp = comp_fn(disc, x, y, r_alg, sig, opt.flux_order)
            n_est += 1
            t_est += time.perf_counter() - te
            estimates.append(EstimatorRecord(k, i_acc, comp.eta_disc, comp.eta_lin, comp.eta_alg, res_alg, False,
                                             *_alg_terms(comp)))

        new_active = system.gap(x) <= y
        rec = InexactIterationRecord(
            k=k, res=float(np.sqrt(2 * psi) / scale), res_lin=float(np.linalg.norm(r) / scale),
            res_c=float(np.linalg.norm(c) / scale), n_active=int(new_active.sum()),
            n_changed=int((new_active != active).sum()), step=step, time_linear=time_linear,
            time_step=time.perf_counter() - t0, linear_size=lin.size,
            gmres_its=kr.iterations, gmres_cum=gmres_cum, gmres_accepted=i_acc, gmres_stop=GMRES_STOP[kr.reason],
            res_alg=res_alg, n_estimates=n_est, time_estimate=t_est, time_ilu=M.time_setup,
            ilu_fill_ratio=M.nnz / max(lin.A.nnz, 1))
        if comp is not None:
            rec.eta_disc, rec.eta_lin, rec.eta_alg = (float(comp.eta_disc), float(comp.eta_lin),
                                                      float(comp.eta_alg))
            rec.eta = float(getattr(comp, "eta", float("nan")))
        active = new_active
        history.append(rec)
        if callback:
            callback(rec)
        if failed:
            reason = f"line search failed at iteration {k} (step < {opt.min_step:.1e})"
            reason += round_off_hint(rec.res, opt.tol)
            break
        if not np.isfinite(rec.res):
            reason = f"non-finite residual at iteration {k}"
            break
        if adaptive and comp is not None and stop_newton(rec.eta_lin, rec.eta_disc, opt.gamma_lin):
            return result(True, "adaptive stopping criterion", k)
        if rec.res <= opt.tol:
            return result(True, "converged", k)
    return result(False, reason, len(history) - 1)
