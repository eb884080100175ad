"""Run a scene over mesh levels: mesh -> discretize -> Newton -> errors.

Builds no forms itself (that is the discretization's job) and draws nothing
(that is :mod:`ngcontact.plotting`, reading the written files).
"""
from __future__ import annotations

import time
from dataclasses import asdict, dataclass, field, replace
from typing import Callable, List, Optional

import numpy as np

from ..discretizations import DISCRETIZATIONS
from ..algebra.linalg import SOLVERS
from ..newton.loop import NewtonOptions, Reference, decoupled_newton, semismooth_newton
from ..rates import rates

__all__ = ["RunOptions", "RunResult", "run_scene", "ESTIMATED"]

#: Newton drivers: exact = direct solves (ngcontact.newton); the others GMRES + ILU (ngcontact.newton.inexact);
#: 'exact-gmres' is the "exact" mode of [JSC20] (GMRES to 2e-12)
NEWTON_MODES = ("exact", "exact-gmres", "inexact", "adaptive")

#: discretizations with an a posteriori estimator (:mod:`ngcontact.estimators`)
ESTIMATED = ("fem",)


@dataclass(frozen=True)
class RunOptions:
    """What a run computes.  Every field is validated; errors name it."""

    order: int = 1
    levels: int = 4
    disc: str = "fem"
    cfun: str = "min"
    start: str = "nested"  # 'nested' (prolongate the coarser level) or 'cold'
    tol: float = 1e-10
    maxit: int = 200
    solver: str = "sparsecholesky"
    condense: bool = True  # hho: static condensation inside every Newton step
    estimate: bool = False  # a posteriori estimators per level (fem)
    flux_order: Optional[int] = None  # RT degree q of the estimators' flux: p (default) or p + 1 (~2x time; cli help)
    decouple: bool = False  # two membranes, K = blockdiag(S, alpha S): Newton on w = u1 - u2 only (newton.decoupled_newton)
    newton: str = "exact"  # 'exact' (direct solves) | 'exact-gmres' | 'inexact' | 'adaptive' (ngcontact.newton.inexact)
    gamma_alg: float = 0.3  # adaptive: stop GMRES when eta_alg <= gamma_alg max(eta_disc, eta_lin)
    gamma_lin: float = 0.3  # adaptive: stop Newton when eta_lin <= gamma_lin eta_disc
    nu: int = 10  # GMRES iterations between estimator evaluations
    ilu_drop_tol: float = 1e-5  # GMRES modes: ILU threshold (scipy spilu drop_tol; ngcontact.newton.inexact)
    ilu_fill: float = 8.0  # GMRES modes: ILU fill bound, nnz(L + U) <= ilu_fill nnz(A) (spilu fill_factor)
    newton_stop: str = "residual"  # exact Newton: 'residual' (||Phi||/||F|| <= tol) | 'balanced' (newton module doc)
    gamma_balance: float = 1e-3  # balanced: stop when eps_lin <= gamma_balance eps_disc (nested levels only)
    adaptive: bool = False  # solve -> estimate -> mark -> refine (ngcontact.drivers.adaptive) instead of uniform levels
    marking: str = "doerfler"  # adaptive: 'doerfler' (bulk, theta) or 'max' (eta_K >= theta max eta_K)
    theta: float = 0.5  # adaptive: marking parameter in (0, 1]
    max_ndof: Optional[int] = None  # adaptive: do not solve on a mesh with more DOFs
    target_eta: Optional[float] = None  # adaptive: stop when eta <= target_eta
    max_time: Optional[float] = None  # adaptive: stop when the cumulative wall time [s] exceeds it
    max_levels: int = 30  # adaptive: at most this many levels

    def __post_init__(self):
        def bad(name, want):
            raise ValueError(f"option {name} must be {want}, got {getattr(self, name)!r}")

        if self.disc not in DISCRETIZATIONS:
            bad("disc", f"one of {sorted(DISCRETIZATIONS)}")
        if not isinstance(self.order, int) or self.order not in DISCRETIZATIONS[self.disc].orders:
            bad("order", f"one of {list(DISCRETIZATIONS[self.disc].orders)} for {self.disc}")
        if not isinstance(self.levels, int) or not 1 <= self.levels <= 12:
            bad("levels", "an integer between 1 and 12")
        if self.cfun not in ("min", "fb"):
            bad("cfun", "'min' or 'fb'")
        if self.start not in ("nested", "cold"):
            bad("start", "'nested' or 'cold'")
        if not (isinstance(self.tol, float) and 0 < self.tol < 1):
            bad("tol", "a number in (0, 1)")
        if not isinstance(self.maxit, int) or self.maxit < 1:
            bad("maxit", "a positive integer")
        if self.solver not in SOLVERS:
            bad("solver", f"one of {SOLVERS}")
        if not isinstance(self.condense, bool):
            bad("condense", "True or False")
        if not isinstance(self.estimate, bool):
            bad("estimate", "True or False")
        if self.estimate and self.disc not in ESTIMATED:
            bad("estimate", f"False for disc {self.disc!r} (estimators exist for {sorted(ESTIMATED)})")
        if self.flux_order is not None and (isinstance(self.flux_order, bool) or not isinstance(self.flux_order, int)
                                            or self.flux_order not in (self.order, self.order + 1)):
            bad("flux_order", f"{self.order} or {self.order + 1} (the order p or p + 1), or None")
        if self.newton not in NEWTON_MODES:
            bad("newton", f"one of {NEWTON_MODES}")
        if self.newton != "exact" and self.disc != "fem":
            bad("newton", f"'exact' for disc {self.disc!r} (inexact Newton is implemented for fem)")
        for name in ("gamma_alg", "gamma_lin"):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, (int, float)) or not 0 < v < 1:
                bad(name, "a number in (0, 1) ([JSC20]: gamma < 1)")
        if isinstance(self.nu, bool) or not isinstance(self.nu, int) or self.nu < 1:
            bad("nu", "a positive integer")
        v = self.ilu_drop_tol
        if isinstance(v, bool) or not isinstance(v, (int, float)) or not 0 <= v < 1:
            bad("ilu_drop_tol", "a number in [0, 1)")
        v = self.ilu_fill
        if isinstance(v, bool) or not isinstance(v, (int, float)) or not 1 <= v < float("inf"):
            bad("ilu_fill", "a number >= 1")
        if self.newton_stop not in ("residual", "balanced"):
            bad("newton_stop", "'residual' or 'balanced'")
        if self.newton_stop == "balanced" and self.newton != "exact":
            bad("newton_stop", f"'residual' with newton {self.newton!r} (the GMRES modes have their own stopping rules)")
        v = self.gamma_balance
        if isinstance(v, bool) or not isinstance(v, (int, float)) or not 0 < v < 1:
            bad("gamma_balance", "a number in (0, 1)")
        if not isinstance(self.adaptive, bool):
            bad("adaptive", "True or False")
        if self.adaptive and self.disc not in ESTIMATED:
            bad("adaptive", f"False for disc {self.disc!r} (estimators exist for {sorted(ESTIMATED)})")
        if self.marking not in ("doerfler", "max"):
            bad("marking", "'doerfler' or 'max'")
        if isinstance(self.theta, bool) or not isinstance(self.theta, (int, float)) or not 0 < self.theta <= 1:
            bad("theta", "a number in (0, 1]")
        if self.max_ndof is not None and (isinstance(self.max_ndof, bool) or not isinstance(self.max_ndof, int)
                                          or self.max_ndof < 1):
            bad("max_ndof", "a positive integer (or None)")
        for name in ("target_eta", "max_time"):
            v = getattr(self, name)
            if v is not None and (isinstance(v, bool) or not isinstance(v, (int, float)) or not 0 < v < float("inf")):
                bad(name, "a positive number (or None)")
        if isinstance(self.max_levels, bool) or not isinstance(self.max_levels, int) or not 1 <= self.max_levels <= 200:
            bad("max_levels", "an integer between 1 and 200")

    @classmethod
    def for_scene(cls, scene, **given) -> "RunOptions":
        """Scene defaults, overridden by explicitly given (non-None) options."""
        opts = {**scene.defaults, **{k: v for k, v in given.items() if v is not None}}
        unknown = set(opts) - set(cls.__dataclass_fields__)
        if unknown:
            raise ValueError(f"unknown option(s) {sorted(unknown)} in scene {scene.name} DEFAULTS")
        return cls(**opts)


@dataclass
class RunResult:
    """Per-level rows (history.csv), per-iteration rows (newton.csv), final level."""

    scene: object
    options: RunOptions
    rows: List[dict] = field(default_factory=list)
    iterations: List[dict] = field(default_factory=list)
    discretization: object = None
    x: Optional[np.ndarray] = None
    y: Optional[np.ndarray] = None
    estimate: object = None  # Estimate of the final level (when options.estimate)
    converged: bool = True
    failures: List[str] = field(default_factory=list)
    stop_reason: Optional[str] = None  # adaptive runs: why the loop ended


def newton_options(options: RunOptions) -> NewtonOptions:
    """The exact Newton settings of a run."""
    return NewtonOptions(cfun=options.cfun, tol=options.tol, maxit=options.maxit, stop=options.newton_stop,
                         gamma_balance=float(options.gamma_balance))


def balance_reference(options: RunOptions, x0) -> Reference:
    """Balanced stop: the prolongated coarser solution x0, eps_disc = 2^-p |||x - x0||| (newton module doc;
    p = the energy rate of every discretization here, HHO's order included)."""
    return Reference(np.array(x0, dtype=float), 2.0 ** -options.order)


def balance_columns(sol) -> dict:
    """history.csv columns of the balanced stop (results.py)."""
    last = sol.history[-1]
    return {"newton_balanced": int(sol.reason == "balanced"), "eps_lin_final": getattr(last, "eps_lin", float("nan")),
            "eps_disc_final": getattr(last, "eps_disc", float("nan"))}


def run_scene(scene, options: RunOptions, progress: Optional[Callable[[str], None]] = None,
              newton_callback=None) -> RunResult:
    """Solve ``scene`` on levels 0..options.levels-1 of its domain."""
    if options.adaptive:  # solve -> estimate -> mark -> refine
        from .adaptive import run_adaptive

        return run_adaptive(scene, options, progress=progress, newton_callback=newton_callback)
    say = progress or (lambda msg: None)
    problem = scene.problem
    Disc = DISCRETIZATIONS[options.disc]
    nopts = newton_options(options)
    result = RunResult(scene=scene, options=options)
    prev, t_cum = None, 0.0
    meshes = problem.domain.meshes(options.levels)
    for level in range(options.levels):
        t0 = time.perf_counter()
        mesh = next(meshes)
        t_mesh = time.perf_counter() - t0
        kw = {"condense": options.condense} if options.disc == "hho" else {}
        disc = Disc(problem, mesh, order=options.order, solver=options.solver, **kw)
        if prev is not None and options.start == "nested":
            x0, y0 = disc.prolongate(prev, result.x, result.y)
        else:
            x0, y0 = disc.initial_guess(scene.initial_guess)

        def cb(rec, level=level):
            result.iterations.append({"level": level, **asdict(rec)})
            if newton_callback:
                newton_callback(level, rec)

        t1 = time.perf_counter()
        if options.newton == "exact":
            ref = balance_reference(options, x0) if prev is not None and options.start == "nested" else None
            sol = (decoupled_newton if options.decouple else semismooth_newton)(disc.system, x0, y0, nopts, callback=cb,
                                                                               reference=ref)
        else:
            from ..newton.inexact import InexactOptions, inexact_semismooth_newton

            iopts = InexactOptions(mode=options.newton.replace("exact-gmres", "exact"), cfun=options.cfun,
                                   tol=options.tol, maxit=options.maxit, gamma_alg=options.gamma_alg,
                                   gamma_lin=options.gamma_lin, nu=options.nu,
                                   ilu_drop_tol=options.ilu_drop_tol, ilu_fill=options.ilu_fill,
                                   flux_order=options.flux_order)
            sol = inexact_semismooth_newton(disc.system, x0, y0, iopts, callback=cb, disc=disc)
        t2 = time.perf_counter()
        errs = disc.errors(sol.x, sol.y)
        comp = disc.complementarity(sol.x, sol.y)
        t3 = time.perf_counter()
        est, est_cols = None, {}
        if options.estimate:
            from ..estimators import estimate

            est = estimate(disc, sol.x, sol.y, errors=False, flux_order=options.flux_order)
            if "err_energy" in errs:
                est.err_energy = errs["err_energy"]
            est_cols = est.summary()
            result.estimate = est
        t4 = time.perf_counter()
        total = t4 - t0
        t_cum += total
        row = {
            "level": level,
            "nelem": mesh.ne,
            "h": problem.domain.h(level),
            "ndof": disc.ndof,
            **({"ndof_sc": disc.ndof_sc} if disc.ndof_sc is not None else {}),
            "nodes": disc.n_interior,
            **errs,
            "newton_its": sol.iterations,
            "newton_converged": int(sol.converged),
            "res_final": sol.history[-1].res,
            **(balance_columns(sol) if options.newton_stop == "balanced" else {}),
            "active_nodes": sol.history[-1].n_active,
            "linear_size": max((r.linear_size for r in sol.history), default=0),
            **({"gmres_its": sol.gmres_total, "gmres_max_step": max(r.gmres_its for r in sol.history),
                "gmres_first_step": sol.history[1].gmres_its if len(sol.history) > 1 else 0,
                "n_estimates": sum(r.n_estimates for r in sol.history),
                "time_estimate_newton_s": sol.time_estimate,
                "eta_disc_final": sol.history[-1].eta_disc, "eta_lin_final": sol.history[-1].eta_lin,
                "eta_alg_final": sol.history[-1].eta_alg} if options.newton != "exact" else {}),
            **comp,
            "time_mesh_s": t_mesh,
            "time_assembly_s": disc.time_assembly,
            "time_solve_s": t2 - t1,
            "time_linear_s": sol.time_linear,
            **({"time_condense_s": disc.time_condense} if disc.time_condense is not None else {}),
            "time_post_s": t3 - t2,
            **est_cols,
            "time_total_s": total,
            "time_cum_s": t_cum,
        }
        result.rows.append(row)
        if "err_energy" in errs:
            r = rates([q["h"] for q in result.rows], [q["err_energy"] for q in result.rows])
            for q, rate in zip(result.rows, r):
                q["rate_energy"] = rate
        if "eta" in est_cols:
            r = rates([q["h"] for q in result.rows], [q["eta"] for q in result.rows])
            for q, rate in zip(result.rows, r):
                q["rate_eta"] = rate
        if not sol.converged:
            result.converged = False
            result.failures.append(f"level {level}: Newton did not converge: {sol.reason}")
        msg = (f"level {level}: ndof {disc.ndof:>8d}  Newton {sol.iterations:3d} its"
               f" ({sol.reason if sol.converged else 'NOT converged: ' + sol.reason})  "
               f"solve {t2 - t1:7.2f} s")
        if "err_energy" in errs:
            rate = row["rate_energy"]
            msg += f"  err {errs['err_energy']:.3e}" + (f"  rate {rate:.2f}" if np.isfinite(rate) else "")
        if est is not None:
            msg += f"  eta {est.eta:.3e}" + (f"  I_eff {est.i_eff:.3f}" if "i_eff" in est_cols else "")
        say(msg)
        result.discretization, result.x, result.y, prev = disc, sol.x, sol.y, disc
    return result
