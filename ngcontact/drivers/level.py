"""One level step: discretize -> initial guess -> Newton -> errors -> estimate, and its history row.

Every driver (uniform levels, the adaptive loop) calls :func:`solve_level` once per mesh and
:func:`level_row` for the history.csv row; the drivers differ only in where the meshes come from
and when they stop.  The estimators reach the Newton layer as a :class:`LevelEstimator` object
(adaptive Krylov mode), so the Newton layer imports no estimator.
"""
from __future__ import annotations

import time
from dataclasses import asdict, dataclass, field, replace
from typing import Callable, List, Optional

import numpy as np

from ..algebra.multigrid import galerkin_consistent
from ..discretizations import DISCRETIZATIONS
from ..estimators import EstimatorOptions, algebraic_flux, estimate, estimate_components, expect_repeated_evaluations
from ..newton import NewtonOptions, Reference, decoupled_newton, semismooth_newton
from ..options import GMRES_NEWTON, MULTIGRID_NEWTON
from ..rates import rates

__all__ = ["RunResult", "LevelOutcome", "LevelEstimator", "solve_level", "newton_iterates", "level_row", "update_rates",
           "record_level", "iteration_callback", "status"]


@dataclass
class RunResult:
    """Per-level rows (history.csv), per-iteration rows (newton.csv), final level."""

    scene: object
    options: object
    rows: List[dict] = field(default_factory=list)
    iterations: List[dict] = field(default_factory=list)
    discretization: object = None
    x: Optional[np.ndarray] = None
    y: Optional[np.ndarray] = None
    estimate: object = None  # Estimate of the final level (when estimated)
    converged: bool = True
    failures: List[str] = field(default_factory=list)
    notes: List[str] = field(default_factory=list)  # safeguards the Newton loop took (newton.safeguards)
    caveats: List[str] = field(default_factory=list)  # levels whose error bound is not proven (Estimate.bound_proven)
    stop_reason: Optional[str] = None  # adaptive runs: why the loop ended; uniform runs: why they stopped early
    complete: bool = True  # False: the run stopped before its requested levels (stop_reason says why)


class LevelEstimator:
    """The estimators of one discretization, as the Krylov strategy of the Newton loop calls them:
    ``components(x, y, r_alg, dx)`` with ``dx`` the look-ahead increment that defines sigma_alg."""

    def __init__(self, disc, options: EstimatorOptions):
        self.disc, self.options = disc, options
        expect_repeated_evaluations(disc)  # every few Krylov iterations: per-mesh structures at the first call

    def components(self, x, y, r_alg, dx):
        sig = None if dx is None else algebraic_flux(self.disc, dx, self.options)
        return estimate_components(self.disc, x, y, r_alg=r_alg, sigma_alg=sig, options=self.options,
                                   shift_obstacle=True)


@dataclass
class LevelOutcome:
    """What :func:`solve_level` produced on one mesh, with its timings [s]."""

    disc: object
    sol: object  # NewtonResult
    errors: dict
    complementarity: dict
    estimate: object = None
    time_prolong: float = 0.0
    time_solve: float = 0.0
    time_post: float = 0.0
    time_estimate: float = 0.0


def newton_solve(disc, x0, y0, options, callback=None, warm: bool = False):
    """Newton on one discretization with the run's linear-solve strategy and stopping rule.

    ``warm``: x0 is the prolongated coarser solution -- the reference of the balanced stop,
    eps_disc = 2^-p |||x - x0||| (p = the energy rate of every discretization here, HHO's included).
    """
    nopts = options.newton_options
    if options.newton in ("direct",) + tuple(MULTIGRID_NEWTON):
        stop = options.stop_options.rule(Reference(np.array(x0, dtype=float), 2.0 ** -options.order) if warm else None)
        if options.newton != "direct":  # CG + multigrid on the hierarchy of this run's levels
            linear = replace(options.linear, prolongations=tuple(getattr(disc, "mg_prolongations", ())),
                             matrices=tuple(getattr(disc, "mg_matrices", ())))
            return semismooth_newton(disc.system, x0, y0, nopts, callback, linear=linear, stop=stop)
        solve = decoupled_newton if options.decouple else semismooth_newton
        return solve(disc.system, x0, y0, nopts, callback, stop=stop)
    estimator = LevelEstimator(disc, options.estimator_options) if options.newton == "adaptive" else None
    linear = replace(options.linear, estimator=estimator, prolongations=tuple(getattr(disc, "mg_prolongations", ())))
    return semismooth_newton(disc.system, x0, y0, nopts, callback, linear=linear, stop=options.stop_options.rule())


def newton_iterates(disc, x0, y0, *, cfun: str = "min", tol: float = 1e-10, maxit: int = 100) -> list:
    """The iterates [(x^0, y^0), (x^1, y^1), ...] of semismooth Newton without line search and with fresh
    factorizations, until ||Phi|| / ||F|| <= tol or ``maxit`` steps (estimators along the Newton path:
    :func:`ngcontact.estimators.newton_history`)."""
    its = []
    semismooth_newton(disc.system, x0, y0, NewtonOptions(cfun=cfun, tol=tol, maxit=maxit, line_search=False,
                                                         reuse_factorization=False),
                      on_iterate=lambda k, x, y: its.append((x, y)))
    return its


def solve_level(problem, mesh, options, *, previous=None, initial_guess=None, with_estimate: bool = False,
                callback: Optional[Callable] = None, estimator_options=None, inputs=None) -> LevelOutcome:
    """Discretize ``problem`` on ``mesh``, solve, evaluate errors (and the estimate, with ``estimator_options``
    if given, else ``options.estimator_options``).

    ``previous``: (disc, x, y) of the coarser level, prolongated when ``options.start == 'nested'``;
    otherwise the start is ``initial_guess`` (the scene's, or None).  ``previous`` may also be handed over as
    a one-element list, which is emptied: when the caller keeps no other reference, the coarser level is freed
    as soon as it has been prolongated (before the Newton solve of this level).  ``inputs``: keyword arguments
    handed to the discretization (``FEMDiscretization.nested_inputs``: the level's loads, data).
    """
    if isinstance(previous, list):
        previous = previous.pop()
    Disc = DISCRETIZATIONS[options.disc]
    kw = {"condense": options.condense} if options.disc == "hho" else {}
    kw.update(inputs or {})
    disc = Disc(problem, mesh, order=options.order, solver=options.solver, constraints=options.constraints, **kw)
    warm = previous is not None and options.start == "nested"
    t0 = time.perf_counter()
    if options.newton in MULTIGRID_NEWTON or (options.newton in GMRES_NEWTON and options.krylov == "cg"):
        disc.mg_prolongations = multigrid_hierarchy(disc, previous[0] if previous is not None else None)
        disc.mg_matrices = galerkin_matrices(disc, previous[0] if previous is not None else None)
    x0, y0 = disc.prolongate(*previous, cfun=options.cfun) if warm else disc.initial_guess(initial_guess)
    previous = None
    t1 = time.perf_counter()
    sol = newton_solve(disc, x0, y0, options, callback, warm=warm)
    t2 = time.perf_counter()
    errs = disc.errors(sol.x, sol.y)
    comp = disc.complementarity(sol.x, sol.y)
    t3 = time.perf_counter()
    est = None
    if with_estimate:
        est = estimate(disc, sol.x, sol.y, estimator_options or options.estimator_options,
                       err_energy=errs.get("err_energy"), errors=False)
    t4 = time.perf_counter()
    return LevelOutcome(disc, sol, errs, comp, est, t1 - t0, t2 - t1, t3 - t2, t4 - t3)


def galerkin_matrices(disc, coarser) -> tuple:
    """The unconstrained matrices K_0..K_{L-1} of the levels below ``disc`` (those of ``coarser`` and its own) when
    each is the Galerkin product P^T K P of the next finer one
    (:func:`~ngcontact.algebra.multigrid.galerkin_consistent`): the truncated multigrid of the Newton steps then
    reads its coarse matrices off them away from the contact set; () otherwise (a missing link, a level that is
    not the Galerkin product)."""
    Ps = tuple(getattr(disc, "mg_prolongations", ()))
    if coarser is None or not Ps:
        return ()
    below = tuple(getattr(coarser, "mg_matrices", ()))
    if len(below) != len(Ps) - 1 or not galerkin_consistent(Ps[-1], disc.system.K, coarser.system.K):
        return ()
    return below + (coarser.system.K,)


def multigrid_hierarchy(disc, coarser) -> tuple:
    """The prolongations P_1..P_L (coarse to fine) from the coarsest level of the run to ``disc``: those of
    ``coarser`` and the one from ``coarser`` to ``disc``; () when a link is missing (the multigrid mode then
    factorizes)."""
    P = disc.unknown_prolongation(coarser) if coarser is not None else None
    if P is None:
        return ()
    return tuple(getattr(coarser, "mg_prolongations", ())) + (P,)


def balance_columns(sol) -> dict:
    """history.csv columns of the balanced stop."""
    last = sol.history[-1]
    return {"newton_balanced": int(sol.reason == "balanced"), "eps_lin_final": last.eps_lin,
            "eps_disc_final": last.eps_disc}


def krylov_columns(sol) -> dict:
    """history.csv columns of the GMRES Newton modes."""
    h = sol.history
    return {"gmres_its": sol.gmres_total, "gmres_max_step": max(r.gmres_its for r in h),
            "gmres_first_step": h[1].gmres_its if len(h) > 1 else 0,
            "n_estimates": sum(r.n_estimates for r in h), "time_estimate_newton_s": sol.time_estimate,
            "eta_disc_final": h[-1].eta_disc, "eta_lin_final": h[-1].eta_lin, "eta_alg_final": h[-1].eta_alg}


def level_row(level: int, out: LevelOutcome, options, *, h: float, head: dict = None, times: dict = None) -> dict:
    """The history.csv row of one level (results.py documents the columns).

    ``head``: driver columns after ``nodes`` (adaptive: ``marked``); ``times``: driver timings
    (``time_mesh_s`` first, then e.g. ``time_mark_s``), placed before the level's own timings.
    """
    disc, sol = out.disc, out.sol
    est_cols = out.estimate.summary() if out.estimate is not None else {}
    times = dict(times or {})
    row = {"level": level, "nelem": disc.nelem, "h": h, "ndof": disc.ndof,
           **({"ndof_sc": disc.ndof_sc} if disc.ndof_sc is not None else {}),
           "nodes": disc.n_interior, **(head or {}), **out.errors,
           "newton_its": sol.iterations, "newton_converged": int(sol.converged), "res_final": sol.history[-1].res,
           **certificate_columns(sol),
           **(balance_columns(sol) if options.newton_stop == "balanced" else {}),
           "active_nodes": sol.history[-1].n_active,
           "linear_size": max((r.linear_size for r in sol.history), default=0),
           **(krylov_columns(sol) if options.newton in GMRES_NEWTON else {}),
           **(multigrid_columns(sol) if options.newton in MULTIGRID_NEWTON else {}),
           **out.complementarity,
           "time_mesh_s": times.pop("time_mesh_s", 0.0), **times,
           "time_assembly_s": disc.time_assembly, "time_prolong_s": out.time_prolong,
           "time_solve_s": out.time_solve, "time_linear_s": sol.time_linear,
           **({"time_condense_s": disc.time_condense} if disc.time_condense is not None else {}),
           "time_post_s": out.time_post, **est_cols,
           **({"time_estimate_s": out.time_estimate} if out.estimate is not None else {})}
    return row


def multigrid_columns(sol) -> dict:
    """history.csv columns of the multigrid Newton modes."""
    h = sol.history[1:]
    return {"cg_its": sum(r.pcg_its for r in h), "mg_levels": max((r.mg_levels for r in h), default=0),
            "mg_algebraic": int(any(r.amg for r in h)),
            "mg_builds": sum(r.mg_rebuilt == 1 for r in h), "mg_updates": sum(r.mg_rebuilt == 2 for r in h),
            "time_mg_setup_s": sum(r.time_mg_setup for r in h)}


def certificate_columns(sol) -> dict:
    """The exit certificate of a level's Newton result (results.py documents the columns)."""
    c = sol.certificate
    if c is None:
        return {}
    return {"certified": int(c.valid), "cert_penetration": c.penetration, "cert_negativity": c.negativity,
            "cert_slackness": c.slackness, "cert_equilibrium": c.equilibrium, "cert_tol": c.tol,
            "newton_remedies": len(sol.remedies)}


def update_rates(rows: List[dict], h_key) -> None:
    """rate_energy / rate_eta of every row against ``h_key(row)`` (h, or ndof^-1/2 on adaptive meshes)."""
    hs = [h_key(q) for q in rows]
    for col, rate_col in (("err_energy", "rate_energy"), ("eta", "rate_eta")):
        if rows and col in rows[-1]:
            for q, r in zip(rows, rates(hs, [q[col] for q in rows])):
                q[rate_col] = r


def record_level(result: RunResult, level: int, out: LevelOutcome) -> None:
    """Keep the final level's solution in ``result``; a level whose Newton failed is a named failure, one whose
    estimate is not a proven bound a caveat."""
    result.discretization, result.x, result.y = out.disc, out.sol.x, out.sol.y
    if out.estimate is not None:
        result.estimate = out.estimate
        if not out.estimate.bound_proven:
            result.caveats.append(f"level {level}: error bound eta not proven: {out.estimate.why_not_proven}")
    if not out.sol.converged:
        result.converged = False
        result.failures.append(f"level {level}: Newton did not converge: {out.sol.reason}")
    result.notes.extend(f"level {level}: {line}" for line in out.sol.remedies)


def iteration_callback(result: RunResult, level: int, newton_callback=None):
    """The Newton callback of one level: newton.csv rows (+ the caller's progress callback)."""
    def cb(rec):
        result.iterations.append({"level": level, **asdict(rec)})
        if newton_callback:
            newton_callback(level, rec)
    return cb


def status(sol) -> str:
    """The Newton outcome in a progress line (with the safeguards taken and an unmet certificate)."""
    text = sol.reason if sol.converged else "NOT converged: " + sol.reason
    if sol.remedies:
        text += " [safeguards: " + "; ".join(sol.remedies) + "]"
    cert = sol.certificate
    if cert is not None and sol.converged and not cert.valid:
        text += f" [{cert.failure()}]"
    return text
