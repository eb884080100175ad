r"""What the linearization component eta_lin of :mod:`.estimators` measures, checked on one time step.

:func:`linearization_check` runs the benchmark to ``t_years`` (Newton-min, direct LU), then solves the next
step with exact Newton-min from the run's predictor and compares, per Newton iterate X^k,

* eta_lin,c(X^k) (linearization at X^{k-1}, flux part dominant; :meth:`.TwoPhaseEstimator.components`) with
* the flux error of the iterate, ||F_c(X^k) - F_c(X^*)|| (X^* the converged step, F the FV face flux
  densities, RT0 norm: the norm of eta_lin's flux part),

and reports the flux change of the whole step ||F_c(X^*) - F_c(X^{n-1})|| next to eta_tm,c and eta_sp,c of
X^*.  If eta_lin tracks the flux error, the Newton criterion eta_lin <= gamma_lin max(eta_sp, eta_tm) asks
that the iterate's flux be within gamma_lin of the step's flux change (in the norm of eta_tm).
"""
from __future__ import annotations

import numpy as np

from ..newton import NewtonOptions, semismooth_newton
from ..newton.nonlinear import NonlinearDirect
from .estimators import TwoPhaseEstimator, _rt0_norm2
from .params import YEAR, TwoPhaseParams
from .run import predictor, run_h2

__all__ = ["flux_norm", "linearization_check"]


def flux_norm(est: TwoPhaseEstimator, x, x_ref) -> np.ndarray:
    """||F_c(x) - F_c(x_ref)|| per component (2,): RT0 norm of the difference of the face flux densities."""
    f = est._face_values(x)[0] - est._face_values(x_ref)[0]
    return np.sqrt(_rt0_norm2(f[:, :-1], f[:, 1:], est.h).sum(axis=1))


def linearization_check(t_years: float = 45000.0, cells: int = 1000, dt_years: float = 5000.0,
                        prm: TwoPhaseParams = TwoPhaseParams()) -> dict:
    """The comparison of the module docstring for the step t_years -> t_years + dt_years.

    Returns dict(rows=[{k, eta_lin_w, eta_lin_h, err_w, err_h}] (k = 0: the predictor, no eta_lin),
    step_change=(w, h), eta_tm=(w, h), eta_sp=(w, h) of X^*, newton=iterations of the exact solve, and the
    arguments t_years, cells, dt_years)."""
    if not (t_years >= 2 * dt_years):
        raise ValueError(f"option t_years must be >= 2 dt_years (the predictor needs two states), got {t_years!r}")
    x_old = run_h2(prm, cells=cells, dt_years=dt_years, t_final_years=t_years - dt_years, estimate=False).x
    run = run_h2(prm, cells=cells, dt_years=dt_years, t_final_years=t_years, estimate=False)
    t, dt = t_years * YEAR, dt_years * YEAR
    system = run.disc.step_system(run.x, t, t + dt)
    est = TwoPhaseEstimator(run.disc, system)
    iterates = []
    res = semismooth_newton(system, predictor(prm, run.x, x_old, 1.0), system.y0, NewtonOptions(cfun="min", tol=1e-8),
                            linear=NonlinearDirect(), on_iterate=lambda k, x, y: iterates.append(x.copy()))
    if not res.converged:
        raise RuntimeError(f"the exact Newton-min solve of the step at t = {t_years:g} y failed: {res.reason}")
    xs = res.x
    rows = [dict(k=0, eta_lin_w=float("nan"), eta_lin_h=float("nan"),
                 **dict(zip(("err_w", "err_h"), map(float, flux_norm(est, iterates[0], xs)))))]
    for k in range(1, len(iterates)):
        dx = iterates[k] - iterates[k - 1]
        comp = est.components(iterates[k - 1], dx, dx)
        err = flux_norm(est, iterates[k], xs)
        rows.append(dict(k=k, eta_lin_w=float(comp.eta_lin[0]), eta_lin_h=float(comp.eta_lin[1]),
                         err_w=float(err[0]), err_h=float(err[1])))
    star = est.components(xs, 0 * xs, 0 * xs)
    return dict(rows=rows, step_change=tuple(map(float, flux_norm(est, xs, run.x))),
                eta_tm=tuple(map(float, star.eta_tm)), eta_sp=tuple(map(float, star.eta_sp)), newton=res.iterations,
                t_years=t_years, cells=cells, dt_years=dt_years)
