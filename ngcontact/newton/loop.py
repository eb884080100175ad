"""Semismooth Newton for  K x - B^T D y = F,  C(g(x), y) = 0.

Step k (seed slide "Inexact semismooth Newton method", exact variant):
A^{k-1} X^k = B^{k-1} with A = [E; J_C(X^{k-1})], solved as a reduced SPD
system by :meth:`ComplementaritySystem.newton_step`.

* ``cfun='min'``: Newton-min = primal-dual active set; full steps (finite
  termination once the active set is identified, [CAMWA21] Theorem).
* ``cfun='fb'``: Newton-Fischer-Burmeister with Armijo backtracking on the
  merit function Psi = 1/2 ||Phi||^2, Phi = [K x - B^T D y - F; C(g, y)].

Stopping test on the whole system: ||Phi(X^k)|| / ||F|| <= tol (the
relative ||R_lin|| / ||F|| of [JSC20]).  Non-convergence is never silent:
the result carries ``converged = False`` and a named ``reason``.

Balanced stop (``stop='balanced'``, nested iteration only): also stop when the
linearization error is negligible next to the discretization error,

    eps_lin(X^k) <= gamma_balance * eps_disc(X^k),

a cheap, solve-free counterpart of the [JSC20] criterion eta_lin <= gamma_lin eta_disc:

* eps_lin = ( ||R||^2_{diag(K)^-1} + sum_{g_i <= y_i} kappa_i c_i^2 + sum_{y_i < g_i} (D_i c_i)^2 / kappa_i )^{1/2},
  c_i = min(g_i, y_i): the energy (diagonally scaled) of the defect left by step k --
  linear residual R, and per row the complementarity defect as a gap (penetration,
  or a gap left open where y > 0) or as a multiplier (y < 0, or y > 0 where g > 0);
  kappa_i = (1/K_uu + 1/K_ll)^{-1} is the stiffness of the gap at row i (K_uu for
  one-sided rows).  After a full Newton-min step c_i is a penetration (inactive
  row) or a negative multiplier (active row); Fischer-Burmeister iterates may also
  have g, y > 0, which c_i counts.  Measured against the true |||X^k - X^*|||_K:
  within a factor 0.4-2.5 (ex9, test 1, levels 1-5).
* eps_disc = 2^{-p} |||X^k - X_ref|||_K, X_ref the prolongated coarser solution: with
  Pythagoras (Galerkin orthogonality on nested spaces; approximate for the
  contact problem) and uniform refinement at rate h^r, |||u_l - I u_{l-1}||| =
  sqrt(4^r - 1) |||u - u_l|||, and 2^{-p} <= 1/sqrt(4^r - 1) for every r <= p, so
  eps_disc under-estimates the discretization error (conservative) unless
  the observed rate exceeds p.

With the default gamma_balance = 1e-3 the linearization error changes the
energy error by a relative ~ gamma^2/2 = 5e-7.  Why it matters: in degenerate
bands (test 1: u1 - u2 < 1e-12 and lambda = 0 around r = R) Newton-min moves
the discrete free boundary by about one node layer per step, and the residual
test then needs O(1/h) steps to settle gaps of ~1e-9 whose influence on the
solution is 1e-4 of the discretization error.  Not a guaranteed bound (the
estimators of :mod:`ngcontact.estimators` are); ``stop='residual'`` is the default.
"""
from __future__ import annotations

import time
from dataclasses import dataclass, field, replace
from typing import Callable, List, Optional

import numpy as np

from ..algebra.cfunctions import get_cfunction
from ..algebra.reuse import FactorReuse
from ..algebra.system import LINEAR_PATHS, ComplementaritySystem
from ..algebra.linalg import FixedPatternCholesky, SPDSolver

__all__ = ["NewtonOptions", "IterationRecord", "NewtonResult", "Reference", "semismooth_newton", "decoupled_newton",
           "armijo_backtracking", "linearization_defect"]


@dataclass(frozen=True)
class Reference:
    """Discretization-error proxy of the balanced stop: eps_disc = weight * |||x - x_ref|||_K.

    ``x``: the prolongated solution of the coarser level; ``weight`` = 2^-p (module doc).
    """

    x: np.ndarray
    weight: float

    def eps_disc(self, system, x: np.ndarray) -> float:
        d = x - self.x
        return float(self.weight * np.sqrt(max(d @ (system.K @ d), 0.0)))


def linearization_defect(system: ComplementaritySystem, x: np.ndarray, y: np.ndarray, r=None) -> float:
    """eps_lin of the balanced stop (module doc): energy of the residual and complementarity defect."""
    dK = system.K.diagonal()
    r = system.residual(x, y) if r is None else r
    kappa = dK[system.up].astype(float)
    two = system.lo >= 0
    kappa[two] = 1.0 / (1.0 / kappa[two] + 1.0 / dK[system.lo[two]])
    g = system.gap(x)
    c = np.minimum(g, y)
    as_gap = g <= y
    return float(np.sqrt(np.sum(r * r / dK) + np.sum(kappa[as_gap] * c[as_gap] ** 2)
                         + np.sum((system.D[~as_gap] * c[~as_gap]) ** 2 / kappa[~as_gap])))


@dataclass(frozen=True)
class NewtonOptions:
    """Settings of the semismooth Newton loop."""

    cfun: str = "min"
    tol: float = 1e-10
    maxit: int = 200
    line_search: Optional[bool] = None  # default: on for 'fb', off for 'min'
    armijo: float = 1e-4
    min_step: float = 2.0 ** -30
    reuse_factorization: bool = True  # PCG with an earlier step's factorization when few rows changed (FactorReuse)
    stop: str = "residual"  # 'residual' | 'balanced' (also eps_lin <= gamma_balance eps_disc; module doc)
    gamma_balance: float = 1e-3

    def __post_init__(self):
        get_cfunction(self.cfun)
        if not (self.tol > 0):
            raise ValueError(f"tol must be positive, got {self.tol}")
        if int(self.maxit) != self.maxit or self.maxit < 1:
            raise ValueError(f"maxit must be a positive integer, got {self.maxit}")
        if self.stop not in ("residual", "balanced"):
            raise ValueError(f"stop must be 'residual' or 'balanced', got {self.stop!r}")
        if not (0 < self.gamma_balance < 1):
            raise ValueError(f"gamma_balance must be in (0, 1), got {self.gamma_balance}")


@dataclass
class IterationRecord:
    """One Newton iteration (k = 0 is the initial guess)."""

    k: int
    res: float  # ||Phi|| / ||F||
    res_lin: float  # ||K x - B^T D y - F|| / ||F||
    res_c: float  # ||C(g, y)|| / ||F||
    n_active: int  # constraint rows with g <= y (contact set)
    n_changed: int  # rows whose active/inactive status changed
    step: float  # line-search step length
    time_linear: float  # reduced system factorization + solve
    time_step: float  # whole iteration
    linear_size: int = 0  # unknowns of the linear system actually solved (reduced / condensed)
    linear_path: int = 0  # index in complementarity.LINEAR_PATHS: 0 factorized, 1 PCG with a reused factorization, 2 PCG gave up
    pcg_its: int = 0  # PCG iterations of this step (also those of a failed attempt)
    eps_lin: float = float("nan")  # balanced stop only: linearization defect (module doc)
    eps_disc: float = float("nan")  # balanced stop only: discretization proxy 2^-p |||x - x_ref|||


@dataclass
class NewtonResult:
    """Outcome of :func:`semismooth_newton`."""

    x: np.ndarray
    y: np.ndarray
    converged: bool
    reason: str
    iterations: int
    history: List[IterationRecord] = field(default_factory=list)

    @property
    def time_linear(self) -> float:
        return sum(r.time_linear for r in self.history)

    @property
    def time_total(self) -> float:
        return sum(r.time_step for r in self.history)


def semismooth_newton(
    system: ComplementaritySystem,
    x0: np.ndarray,
    y0: np.ndarray,
    options: NewtonOptions = NewtonOptions(),
    callback: Optional[Callable[[IterationRecord], None]] = None,
    fixed: Optional[FixedPatternCholesky] = None,
    reference: Optional[Reference] = None,
) -> NewtonResult:
    """Solve the complementarity system from (x0, y0).

    ``callback(record)`` is called after every iteration (progress output).
    ``fixed``: a :class:`~ngcontact.algebra.linalg.FixedPatternCholesky` of ``system.K`` whose symbolic
    analysis the factorizations reuse (one-sided constraints only; see :class:`FactorReuse`).
    ``reference``: the coarser level's prolongated solution for ``options.stop == 'balanced'``
    (without it the balanced stop is the residual stop).
    """
    balanced = options.stop == "balanced" and reference is not None
    cf = get_cfunction(options.cfun)
    line_search = options.line_search if options.line_search is not None else cf.name == "fb"
    scale = max(np.linalg.norm(system.F), np.finfo(float).tiny)
    x, y = np.array(x0, dtype=float), np.array(y0, dtype=float)

    def merit(x, y):
        r = system.residual(x, y)
        c = cf.value(system.gap(x), y)
        return r, c, 0.5 * (r @ r + c @ c)

    t_start = time.perf_counter()
    r, c, psi = merit(x, y)
    active = system.gap(x) <= y
    history = [IterationRecord(0, np.sqrt(2 * psi) / scale, np.linalg.norm(r) / scale,
                               np.linalg.norm(c) / scale, int(active.sum()), 0, 0.0, 0.0,
                               time.perf_counter() - t_start)]
    if callback:
        callback(history[-1])
    if history[-1].res <= options.tol:
        return NewtonResult(x, y, True, "converged", 0, history)

    # factorization reuse needs the generic reduced step (subclasses with their own newton_step: no)
    reuse = None
    if options.reuse_factorization and system.factor_reuse:
        reuse = FactorReuse(system, fixed=fixed)
    reason = f"maximum number of iterations ({options.maxit}) reached"
    for k in range(1, options.maxit + 1):
        t0 = time.perf_counter()
        g = system.gap(x)
        Ca, Cb = cf.jacobian(g, y)
        if reuse is None:
            x_full, y_full, info = system.newton_step(x, y, c, Ca, Cb)
        else:
            x_full, y_full, info = system.newton_step(x, y, c, Ca, Cb, reuse=reuse)
        step = 1.0
        if line_search:
            step, (xt, yt, rt, ct, psit) = armijo_backtracking(merit, x, y, x_full, y_full, psi,
                                                               options.armijo, options.min_step)
            if step < options.min_step:
                reason = f"line search failed at iteration {k} (step < {options.min_step:.1e})"
                reason += round_off_hint(float(np.sqrt(2 * min(psi, psit)) / scale), options.tol)
                x, y, r, c, psi = xt, yt, rt, ct, psit
                history.append(_record(k, r, c, psi, scale, system, x, y, active, step, info, t0))
                if callback:
                    callback(history[-1])
                break
            x, y, r, c, psi = xt, yt, rt, ct, psit
        else:
            x, y = x_full, y_full
            r, c, psi = merit(x, y)
        rec = _record(k, r, c, psi, scale, system, x, y, active, step, info, t0)
        if balanced:
            rec.eps_lin = linearization_defect(system, x, y, r)
            rec.eps_disc = reference.eps_disc(system, x)
        active = system.gap(x) <= y
        history.append(rec)
        if callback:
            callback(rec)
        if not np.isfinite(rec.res):
            reason = f"non-finite residual at iteration {k}"
            break
        if rec.res <= options.tol:
            return NewtonResult(x, y, True, "converged", k, history)
        if balanced and rec.eps_lin <= options.gamma_balance * rec.eps_disc:
            return NewtonResult(x, y, True, "balanced", k, history)
    return NewtonResult(x, y, False, reason, len(history) - 1, history)


def round_off_hint(res: float, tol: float) -> str:
    """Advice appended to a failed line search that ended within 100x of the tolerance: there the merit
    function cannot decrease any more in floating point (measured: HHO without condensation,
    Fischer-Burmeister, test 1 T1 stalls at ||Phi||/||F|| = 1.07e-10 against tol = 1e-10)."""
    if not (res <= 100.0 * tol):
        return ""
    return (f"; it stalled at ||Phi||/||F|| = {res:.2e}, within 100x of tol = {tol:g}: the round-off floor of "
            f"this system: try a looser --tol (e.g. {10 * tol:g})")


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


def decoupled_newton(
    system: ComplementaritySystem,
    x0: np.ndarray,
    y0: np.ndarray,
    options: NewtonOptions = NewtonOptions(),
    callback: Optional[Callable[[IterationRecord], None]] = None,
    reference: Optional[Reference] = None,
) -> NewtonResult:
    """Two membranes with K = blockdiag(S, alpha S): Newton on the obstacle problem for
    w = x_1 - x_2 plus one unconstrained solve for s = x_1 + alpha x_2
    (:meth:`ComplementaritySystem.membrane_split`); otherwise :func:`semismooth_newton`.

    Same discrete solution, half-size Newton systems.  The stopping test keeps
    its meaning: the w-loop runs to tol * ||F|| / ||F_w||, and the result is
    accepted only if ||Phi(X)|| / ||F|| <= tol on the coupled system; if not,
    the coupled Newton continues from it.  Records report the w-iterations.
    """
    split = system.membrane_split()
    if split is None:
        return semismooth_newton(system, x0, y0, options, callback, reference=reference)
    S, alpha = split
    m = system.m
    F1, F2 = system.F[:m], system.F[m:]
    Fw = F1 - F2 / alpha
    wsys = ComplementaritySystem(S, Fw, np.arange(m), -np.ones(m, dtype=np.int64), np.zeros(m),
                                 system.D * (1.0 + 1.0 / alpha), solver=system.solver)
    scale, scale_w = np.linalg.norm(system.F), max(np.linalg.norm(Fw), np.finfo(float).tiny)
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
    wopts = replace(options, tol=max(options.tol * scale / scale_w, np.finfo(float).eps))
    # balanced stop on w in the S-norm: |||(ds, dw)|||_K^2 = (|ds|_S^2 + alpha |dw|_S^2)/(1 + alpha), the
    # w-loop leaves s fixed, so eps_lin and eps_disc (which ignores ds: conservative) scale alike
    wref = None if reference is None else Reference(reference.x[:m] - reference.x[m:], reference.weight)
    res = semismooth_newton(wsys, x0[:m] - x0[m:], y0, wopts, callback, fixed=fixed, reference=wref)
    w = res.x
    x = np.concatenate([(s + alpha * w) / (1 + alpha), (s - w) / (1 + alpha)])
    if res.history:
        res.history[0].time_linear += t_s
        res.history[0].time_step += t_s
    cf = get_cfunction(options.cfun)
    full = np.sqrt(np.linalg.norm(system.residual(x, res.y)) ** 2
                   + np.linalg.norm(cf.value(system.gap(x), res.y)) ** 2) / max(scale, np.finfo(float).tiny)
    if res.converged and (full <= options.tol or res.reason == "balanced"):
        return NewtonResult(x, res.y, True, res.reason, res.iterations, res.history)
    more = semismooth_newton(system, x, res.y, options, callback, reference=reference)  # fallback: coupled Newton
    more.history = res.history + more.history[1:]
    more.iterations = res.iterations + more.iterations
    return more


def _record(k, r, c, psi, scale, system, x, y, active_old, step, info, t0):
    active = system.gap(x) <= y
    return IterationRecord(
        k=k,
        res=float(np.sqrt(2 * psi) / scale),
        res_lin=float(np.linalg.norm(r) / scale),
        res_c=float(np.linalg.norm(c) / scale),
        n_active=int(active.sum()),
        n_changed=int((active != active_old).sum()),
        step=step,
        time_linear=info.time_solve + info.time_assemble,
        time_step=time.perf_counter() - t0,
        linear_size=int(getattr(info, "reduced_size", 0)),
        linear_path=LINEAR_PATHS.index(getattr(info, "path", "factor")),
        pcg_its=int(getattr(info, "pcg_its", 0)),
    )
