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
from typing import Callable, Optional

import numpy as np

from ..algebra.cfunctions import get_cfunction
from .base import IterationRecord, NewtonOptions, NewtonResult
from .linear import DirectSolve
from .stopping import ResidualStop

__all__ = ["semismooth_newton", "armijo_backtracking", "round_off_hint"]


def semismooth_newton(system, x0: np.ndarray, y0: np.ndarray, options: NewtonOptions = NewtonOptions(),
                      callback: Optional[Callable[[IterationRecord], None]] = None, *,
                      linear=None, stop=None,
                      on_iterate: Optional[Callable[[int, np.ndarray, np.ndarray], None]] = None) -> NewtonResult:
    """Solve the complementarity system ``system`` from (x0, y0).

    Parameters
    ----------
    system : ComplementaritySystem
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
    scale = max(np.linalg.norm(system.F), np.finfo(float).tiny)
    x, y = np.array(x0, dtype=float), np.array(y0, dtype=float)
    Record = linear.record_type

    def merit(x, y):
        r = system.residual(x, y)
        c = cf.value(system.gap(x), y)
        return r, c, 0.5 * (r @ r + c @ c)

    t_start = time.perf_counter()
    r, c, psi = merit(x, y)
    active = system.gap(x) <= y
    history = [Record(0, float(np.sqrt(2 * psi) / scale), float(np.linalg.norm(r) / scale),
                      float(np.linalg.norm(c) / scale), int(active.sum()), 0, 0.0, 0.0,
                      time.perf_counter() - t_start)]
    estimates: list = []
    if callback:
        callback(history[-1])
    if on_iterate:
        on_iterate(0, x, y)

    def result(converged, reason, k):
        return NewtonResult(x, y, converged, reason, k, history, estimates)

    if history[-1].res <= options.tol:
        return result(True, "converged", 0)
    session = linear.start(system, estimates)
    reason = f"maximum number of iterations ({options.maxit}) reached"
    for k in range(1, options.maxit + 1):
        t0 = time.perf_counter()
        g = system.gap(x)
        Ca, Cb = cf.jacobian(g, y)
        trial = session.step(k, x, y, c, Ca, Cb, history[-1].res)
        step, failed = 1.0, False
        if line_search:
            step, (xt, yt, rt, ct, psit) = armijo_backtracking(merit, x, y, trial.x, trial.y, psi,
                                                               options.armijo, options.min_step)
            failed = step < options.min_step
            x, y, r, c, psi = xt, yt, rt, ct, psit
        else:
            x, y = trial.x, trial.y
            r, c, psi = merit(x, y)
        extra = session.after_step(k, x, y, step)
        new_active = system.gap(x) <= y
        rec = Record(k=k, res=float(np.sqrt(2 * psi) / scale), res_lin=float(np.linalg.norm(r) / scale),
                     res_c=float(np.linalg.norm(c) / scale), n_active=int(new_active.sum()),
                     n_changed=int((new_active != active).sum()), step=step, time_linear=trial.time_linear,
                     time_step=0.0, **trial.fields, **extra)
        if not failed:
            stop.measure(rec, system, x, y, r)
        rec.time_step = time.perf_counter() - t0
        active = new_active
        history.append(rec)
        if callback:
            callback(rec)
        if on_iterate:
            on_iterate(k, x, y)
        if failed:
            reason = f"line search failed at iteration {k} (step < {options.min_step:.1e})"
            reason += round_off_hint(rec.res, options.tol)
            break
        if not np.isfinite(rec.res):
            reason = f"non-finite residual at iteration {k}"
            break
        done = stop.check(rec, options.tol)
        if done is not None:
            return result(True, done, k)
    return result(False, reason, len(history) - 1)


def round_off_hint(res: float, tol: float) -> str:
    """Advice appended to a failed line search that ended within 100x of the tolerance: there the merit
    function cannot decrease any more in floating point (e.g. HHO without condensation with
    Fischer-Burmeister on test 1 T1 stalls just above tol = 1e-10)."""
    if not (res <= 100.0 * tol):
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
