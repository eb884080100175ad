"""Two membranes with K = blockdiag(S, alpha S): Newton on w = u1 - u2 only.

Same discrete solution as the coupled Newton, half-size Newton systems: the w-problem is an
obstacle-type complementarity system (one-sided rows), s = x_1 + alpha x_2 one unconstrained solve
(:meth:`ComplementaritySystem.membrane_split` gives S and alpha, or None when the structure does
not allow it).
"""
from __future__ import annotations

import time
from dataclasses import replace
from typing import Callable, Optional

import numpy as np

from ..algebra.linalg import FixedPatternCholesky, SPDSolver
from ..algebra.system import ComplementaritySystem
from .base import IterationRecord, NewtonOptions, NewtonResult
from .linear import DirectSolve
from .loop import exit_certificate, relative_residual, safe_norm, semismooth_newton

__all__ = ["decoupled_newton"]


def decoupled_newton(
    system: ComplementaritySystem,
    x0: np.ndarray,
    y0: np.ndarray,
    options: NewtonOptions = NewtonOptions(),
    callback: Optional[Callable[[IterationRecord], None]] = None,
    stop=None,
) -> NewtonResult:
    """Two membranes with K = blockdiag(S, alpha S): Newton on the obstacle problem for
    w = x_1 - x_2 plus one unconstrained solve for s = x_1 + alpha x_2
    (:meth:`ComplementaritySystem.membrane_split`); otherwise :func:`semismooth_newton`.

    Same discrete solution, half-size Newton systems.  The stopping test keeps
    its meaning: the w-loop runs to min(tol ||F|| / ||F_w||, tol), and the result is
    accepted only if ||Phi(X)|| / ||F|| <= tol on the coupled system; if not,
    the coupled Newton continues from it.  Records report the w-iterations.
    ``stop``: the stopping rule of the coupled problem (residual or balanced).
    """
    split = system.membrane_split()
    if split is None:
        return semismooth_newton(system, x0, y0, options, callback, stop=stop)
    S, alpha = split
    m = system.m
    F1, F2 = system.F[:m], system.F[m:]
    Fw = F1 - F2 / alpha
    wsys = ComplementaritySystem(S, Fw, np.arange(m), -np.ones(m, dtype=np.int64), np.zeros(m),
                                 system.D * (1.0 + 1.0 / alpha), solver=system.solver,
                                 stiffness_scale=system.stiffness_scale)
    scale, scale_w = safe_norm(system.F), max(safe_norm(Fw), np.finfo(float).tiny)
    t0 = time.perf_counter()
    fixed = None
    if system.solver == "sparsecholesky" and options.reuse_factorization:
        # S is also the w-system's matrix: its symbolic analysis serves the w-Newton steps
        fixed = FixedPatternCholesky(S)
        fixed.factor(np.ones(m, dtype=bool))
        s = fixed.solve(F1 + F2)
    else:
        s = SPDSolver(S, system.solver).solve(F1 + F2)
    t_s = time.perf_counter() - t0
    # ||Phi_w|| / ||F_w|| <= tol * ||F|| / ||F_w|| is the coupled test, but never looser than tol in the w-system's
    # own units: with mu2 / mu1 = 1e12, ||F|| / ||F_w|| ~ 1e12 let the w-loop stop at its start (x1 off by 0.8)
    wopts = replace(options, tol=max(options.tol * min(scale / scale_w, 1.0), np.finfo(float).eps))
    wstop = None if stop is None else stop.on_difference(m)
    res = semismooth_newton(wsys, x0[:m] - x0[m:], y0, wopts, callback,
                            linear=DirectSolve(reuse=options.reuse_factorization, fixed=fixed), stop=wstop)
    w = res.x
    x = np.concatenate([(s + alpha * w) / (1 + alpha), (s - w) / (1 + alpha)])
    if res.history:
        res.history[0].time_linear += t_s
        res.history[0].time_step += t_s
    full = relative_residual(system, options.cfun, x, res.y)
    cert_tol = options.certificate_tol if stop is None or res.reason == "converged" else stop.certificate_tol(options)
    cert = exit_certificate(system, x, res.y, cert_tol)
    if res.converged and (full <= options.tol or res.reason == "balanced") and cert.valid:
        return NewtonResult(x, res.y, True, res.reason, res.iterations, res.history, certificate=cert)
    more = semismooth_newton(system, x, res.y, options, callback, stop=stop)  # fallback: coupled Newton
    more.history = res.history + more.history[1:]
    more.iterations = res.iterations + more.iterations
    return more


