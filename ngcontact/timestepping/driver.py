"""The time-stepping driver: backward Euler steps, each solved by the one Newton loop, with per-step rows.

:func:`run_parabolic` integrates a :class:`~ngcontact.problems.ParabolicProblem` on one mesh from t = 0
to T: per step the step system of :class:`.euler.BackwardEuler`, semismooth Newton warm-started from
the previous step (Newton-min or Fischer-Burmeister; direct solves with factorizations shared across
steps, or GMRES + ILU in the modes ``gmres`` / ``inexact`` / ``adaptive`` of the existing Krylov
strategy, with the preconditioner of a reduced matrix reused for later Newton iterations and steps
that produce the bitwise same matrix (:class:`~ngcontact.algebra.krylov.PreconditionerCache`); in
``adaptive`` the estimators of the step stop GMRES and Newton, [CMAME20] with gamma_alg = gamma_lin =
1e-3), then optionally the step's estimator (:mod:`.estimate`) and errors.
Newton takes full steps by default (``line_search=False``), also with Fischer-Burmeister: started
from the previous time step it converged at every step of test 6.2, whereas the Armijo search on
||Phi||^2 stalled at ||Phi||/||F|| ~ 1e-8 at some steps where contact begins (5 of 100 steps,
P1, maxh 0.1; ``line_search=None`` restores it).

Adaptive time steps (``adaptive_dt``; not in [CMAME20]): after step n the temporal part
B_n = |||u^n - u^{n-1}||| (eta_tm,n = B_n / sqrt(3)) is compared with the spatial part A_n = eta_sp,n.
The step is rejected (and redone with a smaller dt) when eta_tm,n > ``reject`` eta_sp,n and dt > dt_min.
The next dt is dt * clip(factor, 1/4, 2), rounded down to dt_0 2^k so that only few distinct matrices E
(and factorizations) occur, within [dt_min, dt_max], with the factor of ``dt_rule``:

* ``equidistribute`` (default): every step adds the same amount to the space-time estimate.  Its
  temporal part enters eta_st^2 through sum_n dt_n (A_n B_n + B_n^2 / 3), and B_n ~ dt_n |||d_t u|||, so
  the steps that minimize it for a given number of steps make dt_n A_n B_n equal; the target is
  dt_{n+1} A_n B_n (dt_{n+1} / dt_n) = ``safety`` dt_0 Abar^2, Abar^2 = (sum_m dt_m A_m^2) / t_n (the
  mean spatial part so far), i.e. factor = (safety dt_0 Abar^2 / (dt_n A_n B_n))^(1/2).
* ``balance``: eta_tm,n = ``safety`` eta_sp,n, i.e. factor = safety sqrt(3) A_n / B_n.  This makes
  B_n proportional to A_n at every step and so spends many steps where u changes fast.

The mesh is fixed for the whole run (chosen at the start; NGSolve has no coarsening, and refining along
the moving contact set without coarsening would leave the whole swept region fine).
"""
from __future__ import annotations

import math
import sys
import time
from dataclasses import dataclass, field, replace
from typing import Callable, Optional

import numpy as np
from ngsolve import IfPos, Integrate

from ..algebra.krylov import PreconditionerCache
from ..newton import AdaptiveStop, KrylovSolve, NewtonOptions, semismooth_newton
from ..newton.base import option_error
from .estimate import SpaceTimeEstimate, StepEstimator, TimeIntegrals, hypotheses, spatial_part
from .euler import BackwardEuler, SharedDirectSolve

__all__ = ["ParabolicOptions", "ParabolicResult", "run_parabolic", "NEWTON_MODES"]

NEWTON_MODES = ("direct", "gmres", "inexact", "adaptive")
DT_RULES = ("balance", "equidistribute")
#: default safety factor per rule (results/parabolic/REPORT.md, "Adaptive time steps")
DT_SAFETY = {"balance": 0.8, "equidistribute": 0.2}


def _positive(name, v, allow_none=False):
    if v is None and allow_none:
        return
    # a subnormal positive number (< 2.2e-308) counts as 0: 1/v overflows
    if isinstance(v, bool) or not isinstance(v, (int, float)) or not (sys.float_info.min <= v < math.inf):
        raise option_error(name, v, "> 0" + (" (or None)" if allow_none else ""))


@dataclass(frozen=True)
class ParabolicOptions:
    """Options of a time-dependent run (validated once; errors name the option and the value)."""

    order: int = 1
    dt: float = 1e-3
    t_final: Optional[float] = None  # default: the problem's T
    newton: str = "direct"
    cfun: str = "min"
    tol: float = 1e-10  # ||Phi|| / ||F|| of every step (the residual test; adaptive mode: the safeguard)
    maxit: int = 100
    line_search: Optional[bool] = False  # full steps (None: Armijo for fb, as in the stationary runs)
    gamma_lin: float = 1e-3
    gamma_alg: float = 1e-3
    nu: int = 10
    krylov: str = "gmres"  # Krylov modes: 'gmres' (GMRES + ILU, [CMAME20]) or 'cg' (CG + algebraic multigrid)
    estimate: bool = False  # the step estimator and the space-time bound
    adaptive_dt: bool = False
    dt_min: Optional[float] = None  # default dt / 64
    dt_max: Optional[float] = None  # default 64 dt
    safety: Optional[float] = None  # adaptive dt: default 0.8 ('balance') or 0.2 ('equidistribute')
    dt_rule: str = "equidistribute"  # adaptive dt: DT_RULES (module docstring)
    reject: float = 2.0
    max_steps: int = 100000

    def __post_init__(self):
        if isinstance(self.order, bool) or self.order not in (1, 2, 3, 4):
            raise option_error("order", self.order, "1, 2, 3 or 4")
        _positive("dt", self.dt)
        _positive("t_final", self.t_final, allow_none=True)
        if self.newton not in NEWTON_MODES:
            raise option_error("newton", self.newton, f"one of {NEWTON_MODES}")
        for name in ("estimate", "adaptive_dt"):
            if not isinstance(getattr(self, name), bool):
                raise option_error(name, getattr(self, name), "True or False")
        _positive("dt_min", self.dt_min, allow_none=True)
        _positive("dt_max", self.dt_max, allow_none=True)
        if self.dt_rule not in DT_RULES:
            raise option_error("dt_rule", self.dt_rule, f"one of {DT_RULES}")
        _positive("safety", self.safety, allow_none=True)
        if self.safety is None:
            object.__setattr__(self, "safety", DT_SAFETY[self.dt_rule])
        if not (isinstance(self.reject, (int, float)) and self.reject >= 1):
            raise option_error("reject", self.reject, "a number >= 1")
        if isinstance(self.max_steps, bool) or not isinstance(self.max_steps, int) or self.max_steps < 1:
            raise option_error("max_steps", self.max_steps, "a positive integer")
        set_ = object.__setattr__
        set_(self, "newton_options", NewtonOptions(cfun=self.cfun, tol=self.tol, maxit=self.maxit,
                                                           line_search=self.line_search))
        set_(self, "stop", AdaptiveStop(self.gamma_lin) if self.newton == "adaptive" else None)
        if self.newton != "direct":
            set_(self, "krylov_solve", KrylovSolve(mode=self.newton, gamma_alg=self.gamma_alg, nu=self.nu,
                                                   method=self.krylov))
        elif self.krylov != "gmres":
            raise option_error("krylov", self.krylov, "'gmres' (the default) with newton 'direct', which solves no "
                                                      "Krylov system; 'cg' needs newton gmres, inexact or adaptive")

    @property
    def needs_estimator(self) -> bool:
        return self.estimate or self.adaptive_dt or self.newton == "adaptive"


@dataclass
class ParabolicResult:
    """Per-step rows, the run summary, the final state (and snapshots for VTK output)."""

    rows: list = field(default_factory=list)
    summary: dict = field(default_factory=dict)
    stepper: object = None
    x: Optional[np.ndarray] = None
    y: Optional[np.ndarray] = None
    snapshots: list = field(default_factory=list)  # (n, t, x, y)
    spacetime: list = field(default_factory=list)  # (t, contact fraction per bin)
    bins: Optional[np.ndarray] = None
    converged: bool = True
    failures: list = field(default_factory=list)


def _contact_measure(disc, x, y) -> float:
    """|{u1h - u2h <= eps}|, eps = 1e-10 max |nodal gap| (the area of the discrete contact set; eps in the units of
    the gap: the same set for data scaled by any factor or u shifted by a constant)."""
    gap = disc.gridfunctions(x, y)["gap"]
    eps = max(1e-10 * float(np.max(np.abs(disc.system.gap(x)), initial=0.0)), np.finfo(float).tiny)
    return float(Integrate(IfPos(eps - gap, 1.0, 0.0), disc.mesh, order=2 * disc.order + 2))


def _min(v: np.ndarray) -> float:
    """The smallest entry (nan for no entry)."""
    return float(v.min()) if len(v) else float("nan")


def _quantize(dt: float, dt0: float) -> float:
    """dt rounded down to dt0 * 2^k."""
    return dt0 * 2.0 ** math.floor(math.log2(dt / dt0) + 1e-12)


def run_parabolic(problem, mesh, options: ParabolicOptions = ParabolicOptions(), *,
                  progress: Optional[Callable[[str], None]] = None, regions: Optional[dict] = None,
                  space_axis: str = "r", snapshot_every: int = 0, nbins: int = 40) -> ParabolicResult:
    """Integrate ``problem`` on ``mesh`` from 0 to T (module docstring).

    Parameters
    ----------
    regions : dict name -> (rmin, rmax), optional
        annuli whose contact onset is recorded (column ``active_<name>``, summary ``onset_<name>``).
    space_axis : 'r' or 'x'
        coordinate of the space-time contact picture.
    snapshot_every : int
        keep (x, y) every k-th step (and the last) for the .pvd series (0: none).
    """
    say = progress or (lambda m: None)
    o = options
    T = o.t_final if o.t_final is not None else problem.t_final
    t_start = time.perf_counter()
    stepper = BackwardEuler(problem, mesh, order=o.order)
    disc = stepper.disc
    pts = disc.constraint_points
    coord = np.hypot(pts[:, 0], pts[:, 1]) if space_axis == "r" else pts[:, 0]
    bins = np.linspace(coord.min(initial=0.0), coord.max(initial=1.0), nbins + 1)
    which = np.clip(np.digitize(coord, bins) - 1, 0, nbins - 1)
    per_bin = np.maximum(np.bincount(which, minlength=nbins), 1)
    masks = {name: (np.hypot(pts[:, 0], pts[:, 1]) >= lo) & (np.hypot(pts[:, 0], pts[:, 1]) <= hi)
             for name, (lo, hi) in (regions or {}).items()}
    est = StepEstimator(stepper) if o.needs_estimator else None
    ti = TimeIntegrals(stepper)
    st = SpaceTimeEstimate()
    gfs_prev = ti.fields(stepper.x0, stepper.y0)
    st.eta_init = math.sqrt(ti.l2_error2(gfs_prev, 0.0, fields=problem.u0))
    exact = problem.exact is not None
    err2 = 0.0
    direct = SharedDirectSolve() if o.newton == "direct" else None
    linear = direct
    if o.newton != "direct":
        linear = replace(o.krylov_solve, estimator=est if o.newton == "adaptive" else None,
                         preconditioner_cache=PreconditionerCache())
    res = ParabolicResult(stepper=stepper, bins=bins)
    x, y, t, dt, n = stepper.x0, stepper.y0, 0.0, o.dt, 0
    dt_min, dt_max = o.dt_min or o.dt / 64, o.dt_max or 64 * o.dt
    cum = dict(newton=0, gmres=0, fact=0, rejected=0)
    onset = {}
    while t < T * (1 - 1e-12) and n < o.max_steps:
        h = min(dt, T - t)
        t_new = t + h
        t0 = time.perf_counter()
        system = stepper.system(x, t_new, h)
        if est is not None:
            est.set_step(system, x, t_new, h)
        # Newton on the increment d = X^n - X^{n-1} (from d = 0, X3 of the last step); X^n = X^{n-1} + d
        sol = semismooth_newton(stepper.increment_system(system, x, t_new), np.zeros_like(x), y, o.newton_options,
                                linear=linear, stop=o.stop)
        x_new = x + sol.x
        hist = sol.history[1:]
        row = {"n": n + 1, "t": t_new, "dt": h, "newton_its": sol.iterations, "newton_converged": int(sol.converged),
               "res_final": sol.history[-1].res, "gmres_its": sol.gmres_total,
               "factorizations": sum(r.linear_path != 1 for r in hist) if direct else 0,
               "pcg_its": sum(r.pcg_its for r in hist)}
        if est is not None:
            problem.set_time(t_new)
            comp = est.components(sol.x, sol.y)
            ok, why = hypotheses(disc, x_new, sol.y, comp)
            dxv = sol.x
            A, B = spatial_part(comp), math.sqrt(max(float(dxv @ (stepper.K @ dxv)), 0.0))
            if o.adaptive_dt and B / math.sqrt(3) > o.reject * A and h > dt_min * (1 + 1e-12) and h == dt:
                dt = max(_quantize(h * max(o.safety * A * math.sqrt(3) / B, 0.25), o.dt), dt_min)
                cum["rejected"] += 1
                cum["newton"] += sol.iterations
                cum["gmres"] += sol.gmres_total
                cum["fact"] += row["factorizations"]
                say(f"  step {n + 1}: t={t_new:.4g} rejected (eta_tm={B / math.sqrt(3):.2e} > {o.reject:g} eta_sp="
                    f"{A:.2e}); dt -> {dt:.3g}")
                continue
            gfs_now = ti.fields(x_new, np.maximum(sol.y, 0.0))
            C = ti.contact(gfs_now["gap"], gfs_prev["gap"], gfs_now["lam"])
            row.update(st.add_step(n + 1, h, A, B, C, ti.f_oscillation(t, t_new), ok, why))
            row.update(eta_disc=comp.eta_disc, eta_lin=comp.eta_lin, eta_alg=comp.eta_alg)
        gfs_now = ti.fields(x_new, sol.y)
        if exact:
            e2 = ti.energy_error2(gfs_prev, gfs_now, t, t_new)
            err2 += e2
            row["err_energy_n"] = math.sqrt(e2 / h)
        gap = system.gap(x_new)
        active = gap <= sol.y
        row.update(active_nodes=int(active.sum()), contact_area=_contact_measure(disc, x_new, sol.y),
                   gap_min=_min(gap), lam_min=_min(sol.y))
        for name, m in masks.items():
            row[f"active_{name}"] = int((active & m).sum())
            if row[f"active_{name}"] and name not in onset:
                onset[name] = t_new
        if "all" not in onset and active.any():
            onset["all"] = t_new
        res.spacetime.append((t_new, np.bincount(which[active], minlength=nbins) / per_bin))
        row["time_s"] = time.perf_counter() - t0
        cum["newton"] += sol.iterations
        cum["gmres"] += sol.gmres_total
        cum["fact"] += row["factorizations"]
        row.update(newton_cum=cum["newton"], gmres_cum=cum["gmres"])
        res.rows.append(row)
        if not sol.converged:
            res.converged = False
            res.failures.append(f"step {n + 1} (t = {t_new:.6g}): Newton did not converge: {sol.reason}")
        x, y, t, n, gfs_prev = x_new, sol.y, t_new, n + 1, gfs_now
        if snapshot_every and (n % snapshot_every == 0 or t >= T * (1 - 1e-12)):
            res.snapshots.append((n, t, x.copy(), y.copy()))
        if o.adaptive_dt and est is not None:
            if o.dt_rule == "balance":  # eta_tm,n = safety eta_sp,n
                factor = o.safety * A * math.sqrt(3) / B if B > 0 else 2.0
            else:  # next dt A B = safety dt0 Abar^2 with B ~ dt (module docstring); st.sp2 = sum_m dt_m A_m^2
                abar2 = st.sp2 / t
                factor = math.sqrt(o.safety * o.dt * abar2 / (A * B * h)) if A * B > 0 else 2.0
            dt = min(max(_quantize(h * min(max(factor, 0.25), 2.0), o.dt), dt_min), dt_max)
        eta_txt = f" eta_sp={row['eta_sp_n']:.2e} eta_tm={row['eta_tm_n']:.2e}" if "eta_sp_n" in row else ""
        say(f"  step {n}: t={t:.4g} dt={h:.3g} newton={sol.iterations} gmres={sol.gmres_total} "
            f"active={row['active_nodes']}{eta_txt}")
    if t < T * (1 - 1e-12):  # the loop ended on the step cap before T
        res.converged = False
        res.failures.append(f"max_steps: {n} steps (max_steps = {o.max_steps}) reached at t = {t:.6g} < T = {T:.6g}")
    res.x, res.y = x, y
    dts = [r["dt"] for r in res.rows]
    s = {"t_final": t, "steps": n, "dt": o.dt, "dt_min_used": min(dts, default=float("nan")),
         "dt_max_used": max(dts, default=float("nan")), "order": o.order, "newton": o.newton, "cfun": o.cfun,
         "adaptive_dt": o.adaptive_dt, "nelem": mesh.ne, "ndof": disc.ndof, "newton_total": cum["newton"],
         "gmres_total": cum["gmres"], "factorizations_total": cum["fact"], "rejected_steps": cum["rejected"],
         "converged": res.converged, "time_total_s": time.perf_counter() - t_start}
    s.update({f"onset_{k}": v for k, v in onset.items()})
    if o.newton != "direct":
        cache = linear.preconditioner_cache
        s.update(preconditioners_built=cache.misses, preconditioners_reused=cache.hits)
    if est is not None:
        s.update(st.summary())
    if exact:
        eT2 = ti.l2_error2(gfs_prev, t)
        s.update(err_energy_L2H1=math.sqrt(err2), err_L2_T=math.sqrt(eT2),
                 err_spacetime=math.sqrt(err2 + eT2 + 0.0))
        if est is not None:
            s["i_eff"] = s["eta_st"] / s["err_spacetime"] if s["err_spacetime"] > 0 else float("nan")
    if problem.stationary.exact is not None:  # distances at T to the stationary exact and discrete solutions
        s["dist_stationary_T"] = disc.errors(x, y)["err_energy"]
        stat = semismooth_newton(disc.system, x, y, o.newton_options)
        d = x - stat.x
        s["dist_stationary_discrete_T"] = math.sqrt(max(float(d @ (disc.system.K @ d)), 0.0))
        s["err_stationary_discrete"] = disc.errors(stat.x, stat.y)["err_energy"]
    res.summary = s
    return res
