"""The semismooth Newton loop for  K x - B^T D y = F,  C(g(x), y) = 0.

Step k (seed slide "Inexact semismooth Newton method") solves the linearization
A^{k-1} X^k = B^{k-1}, A = [E; J_C(X^{k-1})], through the reduced system of
:meth:`ComplementaritySystem.linearize`.  One loop serves every variant; they
differ in two objects handed in:

* the **linear-solve strategy** (:mod:`.linear`): direct solves with
  factorization reuse (:class:`~.linear.DirectSolve`), or restarted GMRES + ILU
  with the [JSC20] stopping rules (:class:`~.linear.KrylovSolve`, modes
  ``gmres`` / ``inexact`` / ``adaptive``);
* the **stopping rule** (:mod:`.stopping`): ||Phi(X^k)|| / ||F|| <= tol
  (:class:`~.stopping.ResidualStop`, the relative ||R_lin|| / ||F|| of [JSC20]),
  plus the balanced stop of nested iteration or the adaptive [JSC20] criterion
  eta_lin <= gamma_lin eta_disc with estimators handed in by the driver.

Globalization: ``cfun='min'`` takes full steps (Newton-min = primal-dual active
set, finite termination once the active set is identified, [CAMWA21]);
``cfun='fb'`` backtracks (Armijo) on the merit function Psi = 1/2 ||Phi||^2,
Phi = [K x - B^T D y - F; C(g, y)].

Non-convergence is never silent: the result carries ``converged = False`` and
a named ``reason`` (iteration cap, failed line search, non-finite residual).
"""
from __future__ import annotations

import time
from dataclasses import replace
from typing import Callable, Optional

import numpy as np

from ..algebra.cfunctions import get_cfunction
from ..algebra.system import power_of_two
from .base import IterationRecord, NewtonOptions, NewtonResult
from .linear import DirectSolve
from .safeguards import Safeguards
from .stopping import ResidualStop

__all__ = ["semismooth_newton", "armijo_backtracking", "round_off_hint", "safe_norm",
           "relative_residual", "exit_certificate"]


def semismooth_newton(system, x0: np.ndarray, y0: np.ndarray, options: NewtonOptions = NewtonOptions(),
                      callback: Optional[Callable[[IterationRecord], None]] = None, *,
                      linear=None, stop=None,
                      on_iterate: Optional[Callable[[int, np.ndarray, np.ndarray], None]] = None) -> NewtonResult:
    """Solve the complementarity system ``system`` from (x0, y0).

    Parameters
    ----------
    system : ComplementaritySystem or NonlinearComplementaritySystem
        the loop calls ``residual(x, y)``, ``pair(x, y) -> (a, b)`` (the complementary pair; (g(x), y)
        for the linear systems) and ``scale()`` (divisor of ||Phi||); a nonlinear system
        (:mod:`ngcontact.algebra.nonlinear`) is solved with the strategies of :mod:`.nonlinear`.
    x0, y0 : ndarray
        initial guess X^0.
    options : NewtonOptions
    callback : callable, optional
        ``callback(record)`` after every iteration (progress output).
    linear : linear-solve strategy, optional
        :class:`~.linear.DirectSolve` (default, with ``options.reuse_factorization``)
        or :class:`~.linear.KrylovSolve`.
    stop : stopping rule, optional
        :class:`~.stopping.ResidualStop` (default), :class:`~.stopping.BalancedStop`
        or :class:`~.stopping.AdaptiveStop`.
    on_iterate : callable, optional
        ``on_iterate(k, x, y)`` with every iterate X^k, k = 0 included (diagnostics that need the
        iterates themselves, e.g. estimators along the Newton path).

    Returns
    -------
    NewtonResult
    """
    linear = linear if linear is not None else DirectSolve(reuse=options.reuse_factorization)
    stop = stop if stop is not None else ResidualStop()
    cf = get_cfunction(options.cfun)
    line_search = options.line_search if options.line_search is not None else cf.name == "fb"
    # nondimensionalize: solve for (x, y) / s with the data / s (s a power of 2: the iterates are those of the
    # unscaled data, bit for bit, and no square under- or overflows for data from 1e-300 to 1e+300)
    s = system.data_scale()
    system = system.rescaled(s)
    linear, stop = _rescaled_strategy(linear, s), stop.rescaled(s)
    scale = system.scale()
    x, y = np.array(x0, dtype=float) / s, np.array(y0, dtype=float) / s
    Record = linear.record_type
    emit = (lambda k, x, y: on_iterate(k, x * s, y * s)) if on_iterate else None

    def merit(x, y, r=None):
        r = system.residual(x, y) if r is None else r
        c = cf.value(*system.pair(x, y))
        return r, c, 0.5 * (r @ r + c @ c)

    t_start = time.perf_counter()
    r, c, psi = merit(x, y)
    active = np.less_equal(*system.pair(x, y))
    history = [Record(0, float(np.sqrt(2 * psi) / scale), float(np.linalg.norm(r) / scale),
                      float(np.linalg.norm(c) / scale), int(active.sum()), 0, 0.0, 0.0,
                      time.perf_counter() - t_start)]
    estimates: list = []
    if callback:
        callback(history[-1])
    if emit:
        emit(0, x, y)
    guard = Safeguards()

    def cert_tol(reason):
        return options.certificate_tol if reason == "converged" else stop.certificate_tol(options)

    held = {}  # the certificate certified() computed, with the iterate and reason it belongs to

    def result(converged, reason, k):
        h = held.get("cert")
        same = h is not None and h[0] is x and h[1] is y and h[2] == reason
        cert = h[3] if same else system.certificate(x, y, cert_tol(reason))
        return NewtonResult(x * s, y * s, converged, reason, k, history, estimates, cert, guard.log)

    def certified(reason):
        """The stop ``reason`` if the certificate that the rule requires holds at the iterate the rule returns
        (:meth:`~.stopping.BalancedStop.accepted`), which then replaces (x, y); else None (iterate on)."""
        nonlocal x, y
        xa, ya = stop.accepted(x, y) if reason != "converged" else (x, y)
        cert = system.certificate(xa, ya, cert_tol(reason))
        if not cert.valid:
            return None
        x, y = xa, ya
        held["cert"] = (x, y, reason, cert)
        return reason

    if history[-1].res <= options.tol and certified("converged"):
        return result(True, "converged", 0)
    session = guard.session = linear.start(system, estimates)
    reason = f"maximum number of iterations ({options.maxit}) reached"
    for k in range(1, options.maxit + 1):
        t0 = time.perf_counter()
        Ca, Cb = system.chain(*cf.jacobian(*system.pair(x, y)))  # derivatives in the variables of newton_step
        trial = session.step(k, x, y, c, Ca, Cb, history[-1].res)
        step, failed, unchanged = 1.0, False, False
        if line_search:
            step, (xt, yt, rt, ct, psit) = armijo_backtracking(merit, x, y, trial.x, trial.y, psi,
                                                               options.armijo, options.min_step)
            failed = step < options.min_step
            if not failed:
                x, y, r, c, psi = xt, yt, rt, ct, psit
        else:
            unchanged = np.array_equal(trial.x, x) and np.array_equal(trial.y, y)
            x, y = trial.x, trial.y
            r, c, psi = merit(x, y, trial.residual)
        extra = session.after_step(k, x, y, step)
        new_active = np.less_equal(*system.pair(x, y))
        rec = Record(k=k, res=float(np.sqrt(2 * psi) / scale), res_lin=float(np.linalg.norm(r) / scale),
                     res_c=float(np.linalg.norm(c) / scale), n_active=int(new_active.sum()),
                     n_changed=int((new_active != active).sum()), step=step, time_linear=trial.time_linear,
                     time_step=0.0, **trial.fields, **extra)
        if not failed:
            stop.measure(rec, system, x, y, r)
        rec.time_step = time.perf_counter() - t0
        active = new_active
        history.append(rec)
        if not np.isfinite(rec.res):
            if callback:
                callback(rec)
            reason = f"non-finite residual at iteration {k}"
            break
        cycled = None if line_search or failed else guard.cycling(k, active, rec.res)
        if cycled is None and unchanged:  # a cycle of length one: every further step would return it again
            cycled = k - 1
        trouble = "stall" if failed else ("cycling" if cycled is not None else None)
        if trouble:
            code = guard.next_remedy(trouble)
            if code is None:
                if callback:
                    callback(rec)
                if failed:
                    reason = f"line search failed at iteration {k} (step < {options.min_step:.1e})"
                    reason += round_off_hint(rec.res, options.tol)
                elif unchanged:
                    reason = f"no progress at iteration {k}: the step returned the iterate it started from"
                    reason += round_off_hint(rec.res, options.tol)
                else:
                    reason = f"Newton-min cycles: the active set of iteration {k} is that of iteration {cycled}"
                if guard.log:
                    reason += " (after the remedies: " + "; ".join(guard.log) + ")"
                break
            rec.remedy = code
            guard.note(k, code, "line search failed" if failed else
                       "no progress" if unchanged else f"active set of iteration {cycled} again")
            if code in (2, 3):
                cf = get_cfunction("min" if code == 2 else "fb")
                line_search = code == 3
                r, c, psi = merit(x, y)
                rec.res = float(np.sqrt(2 * psi) / scale)
        if callback:
            callback(rec)
        if emit:
            emit(k, x, y)
        if failed:
            continue
        # a provisional point (a relaxed iterate, not the solution of a linearization) stops the loop by the residual
        # test at the point itself and its certificate only, never by the other tests of a rule (balanced, adaptive)
        done = None if not trial.may_stop else (ResidualStop() if trial.provisional else stop).check(rec, options.tol)
        if done is not None and certified(done):
            return result(True, done, k)
    if history[-1].res <= options.tol:  # what kept the loop going (any ending: cap, cycling, stall, no progress)
        failure = system.certificate(x, y, options.certificate_tol).failure()
        if failure:
            reason += f"; the residual test holds but the {failure}"
    return result(False, reason, len(history) - 1)


def safe_norm(v: np.ndarray) -> float:
    """||v||_2 without under- or overflow of the squares (scaled by a power of 2 near ||v||_inf)."""
    if not len(v):
        return 0.0
    s = power_of_two(float(np.max(np.abs(v))))
    return s * float(np.linalg.norm(v / s))


def relative_residual(system, cfun, x: np.ndarray, y: np.ndarray) -> float:
    """||Phi(X)|| / ||F|| of the loop's stopping test at (x, y), Phi = [K x - B^T D y - F; C(w g, y)]."""
    s = system.data_scale()
    sysS, xs, ys = system.rescaled(s), x / s, y / s
    r = sysS.residual(xs, ys)
    c = get_cfunction(cfun).value(*sysS.pair(xs, ys))
    return float(np.sqrt(r @ r + c @ c) / sysS.scale())


def exit_certificate(system, x: np.ndarray, y: np.ndarray, tol: float):
    """The exit certificate of (x, y), evaluated on the nondimensionalized system."""
    s = system.data_scale()
    return system.rescaled(s).certificate(x / s, y / s, tol)


def _rescaled_strategy(linear, s: float):
    """The linear strategy for the system with data / s: its estimator (Krylov modes) sees unscaled iterates."""
    est = getattr(linear, "estimator", None)
    if s == 1.0 or est is None:
        return linear
    return replace(linear, estimator=_UnscaledEstimator(est, s))


class _UnscaledEstimator:
    """Evaluates ``estimator`` at (x, y) * s: the estimators work in the units of the problem's data."""

    def __init__(self, estimator, s: float):
        self.estimator, self.s = estimator, s

    def components(self, x, y, r_alg, dx):
        s = self.s
        return self.estimator.components(x * s, y * s, None if r_alg is None else r_alg * s,
                                         None if dx is None else dx * s)


def round_off_hint(res: float, tol: float) -> str:
    """Advice appended to a failed line search that ended within 100x of the tolerance: there the merit
    function cannot decrease any more in floating point (e.g. HHO without condensation with
    Fischer-Burmeister on test 1 T1 stalls just above tol = 1e-10)."""
    if not (tol < res <= 100.0 * tol):  # at or below tol the residual test holds: the certificate stopped the loop
        return ""
    return (f"; it stalled at ||Phi||/||F|| = {res:.2e}, within 100x of tol = {tol:g}: the round-off floor of "
            f"this system: try a looser tolerance (e.g. {10 * tol:g})")


def armijo_backtracking(merit, x, y, x_full, y_full, psi: float, armijo: float, min_step: float):
    """Step t = 1, 1/2, 1/4, ... along (x_full - x, y_full - y) until the merit
    psi = 1/2 ||Phi||^2 decreases by the Armijo factor (1 - 2 armijo t), or t < min_step.

    ``merit(x, y) -> (r, c, psi)``.  Returns t and (x_t, y_t, r_t, c_t, psi_t) of the last
    trial (the caller decides what t < min_step means).
    """
    dx, dy = x_full - x, y_full - y
    step = 1.0
    while True:
        xt, yt = x + step * dx, y + step * dy
        rt, ct, psit = merit(xt, yt)
        if psit <= (1.0 - 2.0 * armijo * step) * psi or step < min_step:
            return step, (xt, yt, rt, ct, psit)
        step *= 0.5
