r"""Linear-solve strategies of the Newton loop for nonlinear complementarity systems
(:mod:`ngcontact.algebra.nonlinear`): the step J dX = -Phi(X) with the full nonsymmetric matrix.

* :class:`NonlinearDirect` -- sparse LU (SuperLU, ``scipy.sparse.linalg.splu``, COLAMD ordering).
* :class:`NonlinearKrylov` -- restarted GMRES + ILU (:mod:`ngcontact.algebra.krylov`), warm start
  dX = 0 (X^{k,0} = X^{k-1}), the algebraic residual R^{k,i} = -Phi(X^{k-1}) - J dX^{k,i}.  Modes:

  - ``gmres``: ||R^{k,i}|| <= ``tol_alg`` ||Phi(X^{k-1})|| (the "exact" mode);
  - ``inexact``: ||R^{k,i}|| <= eta_k ||Phi(X^{k-1})||, forcing eta_k = min(||Phi(X^{k-1})|| / scale, ``forcing_max``);
  - ``adaptive``: every ``nu`` iterations the driver's ``estimator.components(x_prev, dx_i, dx_lookahead)``
    returns the components of X^{k,i} (its algebraic part needs X^{k,i+nu}); GMRES stops when
    ``estimator.stop_linear(components)`` ([CG20]: eta_alg <= gamma_alg max(eta_sp, eta_tm, eta_lin) for
    every component).  The components of the accepted iterate (or of the final one, without look-ahead,
    when GMRES stopped otherwise) are stored as ``estimator.last`` for the Newton stopping rule.

Every GMRES iterate is passed through ``system.exact_rows`` (rows the system satisfies exactly, e.g.
S = 1 where Newton-min selects 1 - S).  Both return the loop's :class:`~.linear.Trial`; the
multiplier part y of the loop stays empty.
"""
from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np
import scipy.sparse.linalg as spla

from ..algebra.krylov import ILU, KrylovState, gmres
from .base import option_error
from .linear import GMRES_STOP, KrylovIterationRecord, Trial

__all__ = ["NonlinearDirect", "NonlinearKrylov", "NONLINEAR_MODES"]

NONLINEAR_MODES = ("gmres", "inexact", "adaptive")


@dataclass(frozen=True)
class NonlinearDirect:
    """Sparse LU of the Newton matrix every step."""

    record_type = KrylovIterationRecord

    def start(self, system, estimates):
        return _DirectSession(system)


class _DirectSession:
    def __init__(self, system):
        self.system = system

    def step(self, k, x, y, c, Ca, Cb, res_prev) -> Trial:
        t0 = time.perf_counter()
        J = self.system.jacobian(x, y, Ca, Cb)
        phi = self.system.stack(self.system.residual(x, y), c)
        try:
            dx = spla.splu(J.tocsc()).solve(-phi)
        except RuntimeError:  # singular Newton matrix: a non-finite iterate, which the loop reports as failure
            dx = np.full_like(x, np.nan)
        return Trial(x + dx, y, time.perf_counter() - t0, dict(linear_size=len(x)))

    def after_step(self, k, x, y, step) -> dict:
        return {}


@dataclass(frozen=True)
class NonlinearKrylov:
    """GMRES + ILU on the Newton matrix (module docstring); fields validated once."""

    mode: str = "inexact"
    tol_alg: float = 1e-10
    forcing_max: float = 0.5
    nu: int = 1
    restart: int = 100
    max_gmres: int = 2000
    ilu_drop_tol: float = 1e-4
    ilu_fill: float = 4.0
    estimator: object = None
    record_type = KrylovIterationRecord

    def __post_init__(self):
        if self.mode not in NONLINEAR_MODES:
            raise option_error("newton", self.mode, f"one of {NONLINEAR_MODES}")
        for name in ("tol_alg", "forcing_max"):
            v = getattr(self, name)
            if isinstance(v, bool) or not (isinstance(v, (int, float)) and 0 < v < 1):
                raise option_error(name, v, "a number in (0, 1)")
        for name in ("nu", "restart", "max_gmres"):
            v = getattr(self, name)
            if isinstance(v, bool) or not (isinstance(v, int) and v >= 1):
                raise option_error(name, v, "a positive integer")
        if self.mode == "adaptive" and self.estimator is None:
            raise ValueError("Krylov mode 'adaptive' needs an estimator (estimator=...)")

    def start(self, system, estimates):
        return _KrylovSession(self, system, estimates)


class _KrylovSession:
    def __init__(self, opt: NonlinearKrylov, system, estimates):
        self.opt, self.system, self.estimates = opt, system, estimates
        self.gmres_cum = 0

    def step(self, k, x, y, c, Ca, Cb, res_prev) -> Trial:
        opt, system = self.opt, self.system
        t0 = time.perf_counter()
        J = system.jacobian(x, y, Ca, Cb)
        rhs = -system.stack(system.residual(x, y), c)
        try:
            M = ILU(J, opt.ilu_drop_tol, opt.ilu_fill)
        except RuntimeError:  # a zero pivot after dropping: the complete factorization (ILU without dropping)
            try:
                M = ILU(J, 0.0, 100.0)
            except RuntimeError:  # singular Newton matrix: a non-finite iterate, which the loop reports as failure
                return Trial(np.full_like(x, np.nan), y, time.perf_counter() - t0, dict(linear_size=len(x)))
        bnorm = float(np.linalg.norm(rhs)) or 1.0
        if opt.mode == "gmres":
            rtol = opt.tol_alg
        elif opt.mode == "inexact":
            rtol = min(res_prev, opt.forcing_max)
        else:
            rtol = 1e-14  # the estimators stop GMRES; this guards stagnation
        monitor, accepted, t_est = None, {}, [0.0]
        if opt.mode == "adaptive":
            est = opt.estimator
            checkpoints = []

            def monitor(st: KrylovState):  # X^{k,i} is evaluated with the look-ahead X^{k,i+nu}
                checkpoints.append(system.exact_rows(x, st.x, c, Ca, Cb))
                if len(checkpoints) < 3:  # X^{k,i} for i >= nu (never the zero step X^{k,0} = X^{k-1})
                    return False
                te = time.perf_counter()
                comp = est.components(x, checkpoints[-2], checkpoints[-1])
                stop = est.stop_linear(comp)
                self.estimates.append(comp)
                t_est[0] += time.perf_counter() - te
                if stop:
                    accepted.update(dx=checkpoints[-2], i=st.i - opt.nu, comp=comp)
                return stop
        kr = gmres(J, rhs, np.zeros_like(rhs), M, rtol=rtol, restart=opt.restart, maxiter=opt.max_gmres,
                   nu=opt.nu, monitor=monitor)
        self.gmres_cum += kr.iterations
        dx, i_acc = (accepted["dx"], accepted["i"]) if accepted else (system.exact_rows(x, kr.x, c, Ca, Cb),
                                                                       kr.iterations)
        if opt.mode == "adaptive":  # the components of the accepted iterate, for the Newton stopping rule
            opt.estimator.last = accepted["comp"] if accepted else opt.estimator.components(x, dx, dx)
        res_alg = float(np.linalg.norm(rhs - J @ dx)) / bnorm
        time_linear = time.perf_counter() - t0 - t_est[0]
        return Trial(x + dx, y, time_linear, dict(
            linear_size=len(x), gmres_its=kr.iterations, gmres_cum=self.gmres_cum, gmres_accepted=i_acc,
            gmres_stop=GMRES_STOP[kr.reason], res_alg=res_alg, time_ilu=M.time_setup, time_estimate=t_est[0],
            ilu_fill_ratio=M.nnz / max(J.nnz, 1)))

    def after_step(self, k, x, y, step) -> dict:
        return {}
