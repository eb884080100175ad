"""Time loop of the water-hydrogen benchmark: one Newton solve (:func:`ngcontact.newton.semismooth_newton`)
per backward-Euler step, the step halved and retried on Newton failure (logged), one row per step.

Entry point: :func:`run_h2` -> :class:`TwoPhaseRun`.
"""
from __future__ import annotations

import time
from dataclasses import dataclass, field
from typing import Callable, List, Optional

import numpy as np

from ..newton import NewtonOptions, semismooth_newton
from ..newton.nonlinear import NonlinearDirect, NonlinearKrylov
from .estimators import AdaptiveStepStop, TwoPhaseEstimator
from .fv import TwoPhaseFV, initial_state
from .mesh1d import interval_mesh
from .params import YEAR, TwoPhaseParams

__all__ = ["run_h2", "check_options", "TwoPhaseRun", "StepRow", "NEWTON_MODES", "STEP_COLUMNS", "ITERATE_COLUMNS"]

NEWTON_MODES = ("direct", "gmres", "inexact", "adaptive")
#: most steps a run may take (t_final / dt)
MAX_STEPS = 1e6
#: a step whose hydrogen defect exceeds this fraction of the hydrogen injected in it stops the run (named)
UNRESOLVED = 0.5

#: columns of steps.csv (units in the names; *_defect_rel: the step's mass-balance defect relative to the component's
#: mass in the domain, or to the mass that crossed the boundary in the step if that is larger (no hydrogen in the
#: domain yet); *_defect_flux: relative to the mass that crossed the boundary in the step (injected + flowed out;
#: nan if that is below 1e-9 of the mass in the domain): the defect of the step itself, which a large mass in the
#: domain hides in *_defect_rel)
STEP_COLUMNS = ("step", "t_years", "dt_years", "newton_its", "gmres_its", "dt_cuts", "gas_end_m", "S_0", "P_0_Pa",
                "Pg_0_Pa", "chi_0", "water_defect_rel", "h2_defect_rel", "water_defect_flux", "h2_defect_flux",
                "min_S_minus_Slr", "max_S_minus_1",
                "min_chi", "eta_sp_w", "eta_sp_h", "eta_tm_w", "eta_tm_h", "eta_lin_w", "eta_lin_h", "eta_alg_w",
                "eta_alg_h", "time_s")

#: columns of iterates.csv (adaptive mode): one row per Newton iterate X^k of every attempted step, with the
#: [CG20] components of X^k (linearization at X^{k-1}) and ratio_c = eta_lin,c / max(eta_sp,c, eta_tm,c), the
#: quantity the Newton criterion compares with gamma_lin; stop: the loop's reason at the last iterate of an
#: attempt ('' before it); projected_S: max(S - 1, 0) removed by the projection of the accepted iterate
ITERATE_COLUMNS = ("step", "t_years", "dt_years", "k", "gmres_its", "gmres_accepted", "res", "eta_sp_w", "eta_sp_h",
                   "eta_tm_w", "eta_tm_h", "eta_lin_w", "eta_lin_h", "eta_alg_w", "eta_alg_h", "ratio_w", "ratio_h",
                   "stop", "projected_S")


@dataclass
class StepRow:
    step: int
    t_years: float
    dt_years: float
    newton_its: int
    gmres_its: int
    dt_cuts: int
    gas_end_m: float
    S_0: float
    P_0_Pa: float
    Pg_0_Pa: float
    chi_0: float
    water_defect_rel: float
    h2_defect_rel: float
    min_S_minus_Slr: float
    max_S_minus_1: float
    min_chi: float
    eta_sp_w: float = float("nan")  # [CG20] components of the step (estimators.py), water / hydrogen
    eta_sp_h: float = float("nan")
    eta_tm_w: float = float("nan")
    eta_tm_h: float = float("nan")
    eta_lin_w: float = float("nan")  # adaptive mode only (the accepted iterate)
    eta_lin_h: float = float("nan")
    eta_alg_w: float = float("nan")
    eta_alg_h: float = float("nan")
    water_defect_flux: float = float("nan")
    h2_defect_flux: float = float("nan")
    time_s: float = 0.0

    def values(self):
        return [getattr(self, c) for c in STEP_COLUMNS]


@dataclass
class TwoPhaseRun:
    """Outcome of :func:`run_h2`: per-step rows, saved profiles {t_years: x}, the final state."""

    prm: TwoPhaseParams
    disc: TwoPhaseFV
    rows: List[StepRow]
    profiles: dict
    x: np.ndarray
    log: List[str] = field(default_factory=list)
    completed: bool = True
    iterates: List[dict] = field(default_factory=list)  # adaptive mode: ITERATE_COLUMNS per Newton iterate

    @property
    def newton_total(self) -> int:
        return sum(r.newton_its for r in self.rows)

    @property
    def gmres_total(self) -> int:
        return sum(r.gmres_its for r in self.rows)


def gas_end(disc: TwoPhaseFV, x: np.ndarray) -> float:
    """Right face of the last cell with gas (S < 1), 0 if there is none [m]."""
    s = x[0::3]
    gas = np.flatnonzero(1.0 - s > 1e-12)
    if not len(gas):
        return 0.0
    return float(disc.mesh.centre[gas[-1], 0] + 0.5 * disc.mesh.volume[gas[-1]])


def _linear(newton: str, estimator):
    if newton == "direct":
        return NonlinearDirect()
    return NonlinearKrylov(mode=newton, estimator=estimator if newton == "adaptive" else None)


def check_options(cells=1000, dt_years=5000.0, t_final_years=1e6, newton="direct", maxit=30, max_cuts=6,
                  cfun="min", tol=1e-8, gamma_alg=1e-3, gamma_lin=1e-3) -> None:
    """The run options of :func:`run_h2` (errors name the option and the value)."""
    NewtonOptions(cfun=cfun, tol=tol, maxit=maxit)
    for name, v in (("gamma_alg", gamma_alg), ("gamma_lin", gamma_lin)):
        if isinstance(v, bool) or not isinstance(v, (int, float)) or not 0 < v < 1:
            raise ValueError(f"option {name} must be a number in (0, 1), got {v!r}")
    for name, v in (("cells", cells), ("maxit", maxit), ("max_cuts", max_cuts)):
        if isinstance(v, bool) or not isinstance(v, int) or v < (0 if name == "max_cuts" else 1):
            raise ValueError(f"option {name} must be a positive integer, got {v!r}")
    for name, v in (("dt_years", dt_years), ("t_final_years", t_final_years)):
        if isinstance(v, bool) or not isinstance(v, (int, float)) or not 0 < v < float("inf"):
            raise ValueError(f"option {name} must be a finite number > 0, got {v!r}")
    if t_final_years / dt_years > MAX_STEPS:
        raise ValueError(f"option dt_years = {dt_years!r} gives {t_final_years / dt_years:.3g} steps to "
                         f"t_final_years = {t_final_years!r} (at most {MAX_STEPS:.0e})")
    if newton not in NEWTON_MODES:
        raise ValueError(f"option newton must be one of {NEWTON_MODES} for the two-phase flow (the multigrid modes are "
                         f"for the FE discretizations), got {newton!r}")


def run_h2(prm: TwoPhaseParams = TwoPhaseParams(), cells: int = 1000, dt_years: float = 5000.0,
           t_final_years: float = 1e6, newton: str = "direct", cfun: str = "min", tol: float = 1e-8,
           maxit: int = 30, profile_years=(), max_cuts: int = 6, line_search: bool = False,
           gamma_alg: float = 1e-3, gamma_lin: float = 1e-3, estimate: bool = True, predict: bool = True,
           progress: Optional[Callable[[str], None]] = None) -> TwoPhaseRun:
    """Run the benchmark from the initial state to ``t_final_years``.

    ``newton``: 'direct' (sparse LU), 'gmres' (GMRES + ILU to ||R|| <= 1e-10 ||Phi||), 'inexact' (GMRES with a
    forcing term), 'adaptive' (GMRES and Newton stopped by the [CG20] criteria with ``gamma_alg``,
    ``gamma_lin``; :mod:`.estimators`).  ``tol``: Newton tolerance on ||Phi|| (scaled rows, :mod:`.fv`);
    ``line_search``: Armijo backtracking on 1/2 ||Phi||^2 (off by default for both C-functions: the
    time-step cut is the globalization).  ``estimate``: the spatial and temporal components of every
    step in the rows (the adaptive mode always has all four).
    ``predict``: the Newton initial guess of a step is the linear extrapolation in time of the two previous
    states, X^{n-1} + dt/dt_prev (X^{n-1} - X^{n-2}), S clipped to [S_lr, 1] and chi to >= 0 (else X^{n-1}).
    A step whose Newton fails is retried with dt/2 (at most ``max_cuts`` halvings, each logged); the
    following step starts again from ``dt_years``.
    """
    check_options(cells=cells, dt_years=dt_years, t_final_years=t_final_years, newton=newton, maxit=maxit,
                  max_cuts=max_cuts, cfun=cfun, tol=tol, gamma_alg=gamma_alg, gamma_lin=gamma_lin)
    disc = TwoPhaseFV(prm, interval_mesh(prm.length, cells))
    opts = NewtonOptions(cfun=cfun, tol=tol, maxit=maxit, line_search=line_search)
    say = progress or (lambda m: None)
    x = initial_state(prm, disc.mesh)
    t, T = 0.0, t_final_years * YEAR
    rows, profiles, log, iterates = [], {}, [], []
    wanted = sorted(float(p) for p in profile_years)
    M_prev = disc.masses(x)
    step = 0
    x_old, dt_old = None, 1.0
    while t < T * (1 - 1e-12):
        step += 1
        dt_full = min(dt_years * YEAR, T - t)
        dt, cuts, its, gits = dt_full, 0, 0, 0
        t0 = time.perf_counter()
        t_start = t
        eta, outflow = {}, np.zeros(2)
        while t < t_start + dt_full * (1 - 1e-12):
            dt = min(dt, t_start + dt_full - t)
            system = disc.step_system(x, t, t + dt)
            est = TwoPhaseEstimator(disc, system, gamma_alg, gamma_lin) if (estimate or newton == "adaptive") else None
            stop = AdaptiveStepStop(est) if newton == "adaptive" else None
            guess = predictor(prm, x, x_old, dt / dt_old) if predict and x_old is not None else x
            first = len(iterates)
            record = _iterate_logger(iterates, est, step, (t + dt) / YEAR, dt / YEAR) if stop else None
            with np.errstate(over="ignore", invalid="ignore"):  # a diverging Newton is reported (non-finite) and cut
                res = semismooth_newton(system, guess, system.y0, opts, record, linear=_linear(newton, est), stop=stop)
            if len(iterates) > first:
                iterates[-1].update(stop=res.reason, projected_S=stop.projected if res.converged else 0.0)
            its += res.iterations
            gits += res.gmres_total
            if not res.converged:
                cuts += 1
                msg = (f"step {step}: Newton failed at t = {t / YEAR:.6g} y, dt = {dt / YEAR:.4g} y "
                       f"({res.reason}); dt halved")
                log.append(msg)
                say("  " + msg)
                if cuts > max_cuts:
                    log.append(f"step {step}: gave up after {max_cuts} dt cuts")
                    return TwoPhaseRun(prm, disc, rows, profiles, x, log, completed=False, iterates=iterates)
                dt *= 0.5
                continue
            if est is not None:
                comp = est.last if newton == "adaptive" else est.components(res.x, 0 * res.x, 0 * res.x)
                eta = comp.row() if newton == "adaptive" else {k: v for k, v in comp.row().items()
                                                                if k.startswith(("eta_sp", "eta_tm"))}
            outflow += _boundary_outflow(disc, res.x) * dt
            x_old, dt_old = x, dt
            x, t = res.x, t + dt
        M = disc.masses(x)
        inflow = prm.injection_rate(t_start, t) * (t - t_start)
        defect = np.abs(M - M_prev - np.array([0.0, inflow]) + outflow)
        crossed = np.array([0.0, inflow]) + np.abs(outflow)  # mass through the boundary in the step, per component
        rel = defect / np.maximum(np.maximum(M, crossed), np.finfo(float).tiny)
        seen = crossed > 1e-9 * M  # through the boundary: above the round-off of the masses (else nan)
        flux = np.where(seen, defect / np.where(seen, crossed, 1.0), np.nan)
        if inflow > 0 and defect[1] > UNRESOLVED * inflow:  # the injected hydrogen is not in the domain: the solve
            # did not see it (a defect against the outflow alone is what the adaptive stop leaves, e.g. gamma_lin 0.1)
            log.append(f"step {step}: mass balance not resolved at t = {t / YEAR:.6g} y: the H2 defect is "
                       f"{defect[1] / inflow:.2g} of the hydrogen injected in the step "
                       f"(dt = {(t - t_start) / YEAR:.4g} y is below what the Newton tolerance {tol:g} resolves)")
            say("  " + log[-1])
            return TwoPhaseRun(prm, disc, rows, profiles, x, log, completed=False, iterates=iterates)
        s, p, chi = disc.split(x)
        pc, _ = disc.laws.pc(s[:1])
        row = StepRow(step, t / YEAR, (t - t_start) / YEAR, its, gits, cuts, gas_end(disc, x), float(s[0]),
                      float(p[0]), float(p[0] + pc[0]), float(chi[0]), float(rel[0]), float(rel[1]),
                      float(s.min() - prm.s_lr), float(s.max() - 1.0), float(chi.min()),
                      water_defect_flux=float(flux[0]), h2_defect_flux=float(flux[1]), time_s=time.perf_counter() - t0,
                      **eta)
        rows.append(row)
        M_prev = M
        for tp in wanted:
            if abs(tp * YEAR - t) <= 1e-6 * dt_full:
                profiles[tp] = x.copy()
        say(f"  step {step:4d} t = {row.t_years:9.4g} y | Newton {its:3d}" + (f" GMRES {gits:4d}" if gits else "")
            + f" | gas to {row.gas_end_m:6.1f} m | P(0) = {row.P_0_Pa / 1e6:.4f} MPa, Pg(0) = {row.Pg_0_Pa / 1e6:.4f} MPa"
            + (f" | {cuts} dt cuts" if cuts else ""))
    return TwoPhaseRun(prm, disc, rows, profiles, x, log, iterates=iterates)


def predictor(prm: TwoPhaseParams, x, x_old, ratio: float) -> np.ndarray:
    """Linear extrapolation x + ratio (x - x_old) (ratio = dt / dt_prev), S clipped to [S_lr, 1], chi to >= 0."""
    guess = x + (x - x_old) * ratio
    guess[0::3] = np.clip(guess[0::3], prm.s_lr, 1.0)
    guess[2::3] = np.maximum(guess[2::3], 0.0)
    return guess


def _iterate_logger(iterates: list, est: TwoPhaseEstimator, step: int, t_years: float, dt_years: float):
    """The loop's callback that appends one ITERATE_COLUMNS row per Newton iterate k >= 1 (``est.last``: the
    components of the iterate the linear solver accepted)."""

    def record(rec):
        comp = est.last
        if rec.k == 0 or comp is None:
            return
        disc = np.maximum(comp.eta_sp, comp.eta_tm)
        iterates.append(dict(step=step, t_years=t_years, dt_years=dt_years, k=rec.k,
                             gmres_its=getattr(rec, "gmres_its", 0), gmres_accepted=getattr(rec, "gmres_accepted", 0),
                             res=rec.res, **comp.row(), ratio_w=float(comp.eta_lin[0] / disc[0]),
                             ratio_h=float(comp.eta_lin[1] / disc[1]), stop="", projected_S=0.0))

    return record


def _boundary_outflow(disc: TwoPhaseFV, x) -> np.ndarray:
    """Mass flux [kg/s] per component leaving through the Dirichlet boundary at the state x."""
    _, bnd = disc.fluxes(x)
    return bnd.F.sum(axis=1)
