r"""Linear-solve strategies of the Newton loop: how step k's linearized system is solved.

A strategy is a small immutable settings object; :meth:`start` opens a *session* for one Newton
run (state such as a reused factorization or the estimator log), whose ``step`` returns the full
Newton iterate and the record fields it measured, and whose ``after_step`` may evaluate
estimators at the accepted iterate.

* :class:`DirectSolve` -- the reduced SPD system of :meth:`ComplementaritySystem.linearize`
  factorized, or solved by PCG with an earlier step's factorization when few rows changed
  (:class:`~ngcontact.algebra.reuse.FactorReuse`; only where the system declares
  ``factor_reuse``).  Systems with their own step (HHO static condensation) solve it themselves.
* :class:`KrylovSolve` -- restarted GMRES + ILU ([JSC20]; :mod:`ngcontact.algebra.krylov`) on the
  same reduced system, warm-started from X^{k-1}.  Every reduced iterate z^{i} is mapped to a
  3-field iterate X^{k,i} = (x, y) (:meth:`LinearizedStep.recover`) that satisfies the
  constraint rows of A X = B exactly, so the algebraic residual of the 3-field system is
  R^{k,i} = B - A X^{k,i} = [F - (K x - B^T D y); 0], with ||R^{k,i}|| = ||b_red - A_red z^{i}||.
  Modes (defaults of [JSC20]):

  - ``gmres``: GMRES to ||R^{k,i}|| / ||B^{k-1}|| <= ``tol_alg`` (2e-12) -- the "exact" mode of [JSC20];
  - ``inexact``: ||R^{k,i}|| <= eta_k ||R^{k,0}||, forcing term eta_k = min(||Phi(X^{k-1})|| / ||F||,
    ``forcing_max``).  The test as printed in [JSC20], ||R^{k,i}|| / ||B^{k-1}|| <= ||R_lin|| / ||F||,
    holds already at i = 0 for the warm start (R^{k,0} = -Phi(X^{k-1}), ||B|| >= ||F||), so it is read
    as the Dembo-Eisenstat-Steihaug condition with that forcing term;
  - ``adaptive``: every ``nu`` GMRES iterations the estimators eta_disc, eta_lin, eta_alg of X^{k,i}
    are evaluated (the algebraic flux needs the ``nu`` following iterations, so evaluating X^{k,i}
    needs X^{k,i+nu}); GMRES stops at the first i >= nu with eta_alg <= gamma_alg max(eta_disc,
    eta_lin) (:func:`~.stopping.stop_linear`) and X^k := X^{k,i}.

  GMRES counts are the iterations performed (look-ahead included); the index of the accepted
  iterate is recorded as ``gmres_accepted``.  Rule for rows of very different size (tensions far apart):
  when the diagonal of the reduced matrix spans more than :data:`~ngcontact.algebra.krylov.UNITS_SPREAD`, GMRES +
  ILU solve the left Jacobi-scaled system D^{-1} A z = D^{-1} b, so that the residual it minimizes and tests (with the
  same relative tolerances) is in the units of u row by row (CG: the same iteration, its residuals measured
  as ||D^{-1} r||, which keeps A symmetric); in the plain 2-norm the stiff rows dominate
  and the soft membrane stayed unresolved (tensions 1e9 / 1e12 apart: Newton-min cycled or stopped on the
  certificate).  The estimators come from the driver (``estimator``:
  an object with ``components(x, y, r_alg, dx_lookahead)``); this layer imports none.
"""
from __future__ import annotations

import math
import time
from dataclasses import dataclass, field
from typing import List, Optional

import numpy as np
import scipy.sparse as sp

from ..algebra.krylov import ILU, KrylovState, cg, gmres, units_scale
from ..algebra.reuse import FactorReuse
from ..algebra.system import LINEAR_PATHS
from .base import IterationRecord, option_error
from .stopping import stop_linear

__all__ = ["DirectSolve", "KrylovSolve", "KrylovIterationRecord", "EstimatorRecord", "Trial", "KRYLOV_MODES",
           "KRYLOV_METHODS",
           "algebraic_residual", "rhs_norm"]

KRYLOV_MODES = ("gmres", "inexact", "adaptive")
#: Krylov method and preconditioner: restarted GMRES + ILU ([JSC20]) or CG + multigrid (the reduced system is SPD)
KRYLOV_METHODS = ("gmres", "cg")
#: numeric codes of :attr:`KrylovResult.reason` in the records (newton.csv holds numbers only)
GMRES_STOP = {"tolerance": 0, "monitor": 1, "maxiter": 2, "stagnation": 3}


@dataclass
class Trial:
    """The full Newton iterate of one step, the linear-solve time and the record fields the strategy measured.
    ``provisional``: the point is not the solution of the step's linearization (a relaxed iterate,
    :mod:`.multigrid`); the loop stops at it only by the residual test at the point and its certificate (not by the
    other tests of a stopping rule), and only where ``may_stop`` (the strategy's own test of the point), else the
    next step starts from it.  ``residual``: K x - B^T D y - F
    at (x, y) where the strategy has computed it for its own tests (the loop's merit takes it instead of forming
    it again), else None."""

    x: np.ndarray
    y: np.ndarray
    time_linear: float
    fields: dict
    provisional: bool = False
    residual: Optional[np.ndarray] = None
    may_stop: bool = True


# ---------------------------------------------------------------- direct solves
@dataclass(frozen=True)
class DirectSolve:
    """Direct solves of the reduced system; ``reuse``: PCG with an earlier factorization when few rows
    changed (where the system declares ``factor_reuse``); ``fixed``: a FixedPatternCholesky of K whose
    symbolic analysis the factorizations reuse (one-sided constraints)."""

    reuse: bool = True
    fixed: object = None
    record_type = IterationRecord

    def start(self, system, estimates):
        reuse = FactorReuse(system, fixed=self.fixed) if self.reuse and system.factor_reuse else None
        return _DirectSession(system, reuse)


class _DirectSession:
    def __init__(self, system, reuse):
        self.system, self.reuse = system, reuse
        if reuse is not None:
            reuse.new_run()

    @property
    def can_refresh(self) -> bool:
        """Whether :meth:`fresh` changes anything (steps are solved with reused factorizations)."""
        return self.reuse is not None

    def fresh(self) -> None:
        """Factorize every later step afresh (a safeguard of the loop, :mod:`.safeguards`)."""
        self.reuse = None

    def step(self, k, x, y, c, Ca, Cb, res_prev) -> Trial:
        if self.reuse is None:
            xn, yn, info = self.system.newton_step(x, y, c, Ca, Cb)
        else:
            xn, yn, info = self.system.newton_step(x, y, c, Ca, Cb, reuse=self.reuse)
        return Trial(xn, yn, info.time_solve + info.time_assemble,
                     dict(linear_size=int(info.reduced_size), linear_path=LINEAR_PATHS.index(info.path),
                          pcg_its=int(info.pcg_its)))

    def after_step(self, k, x, y, step) -> dict:
        return {}


# ---------------------------------------------------------------- Krylov solves
@dataclass
class KrylovIterationRecord(IterationRecord):
    """One Newton iteration with Krylov solves (adds the GMRES counters and the estimators)."""

    gmres_its: int = 0           # GMRES iterations performed in this step
    gmres_cum: int = 0           # cumulated over the steps of this solve
    gmres_accepted: int = 0      # index i of the accepted iterate X^{k,i}
    gmres_stop: int = 0          # why GMRES stopped: 0 tolerance, 1 adaptive criterion, 2 maxiter, 3 stagnation
    res_alg: float = float("nan")  # ||R^{k,i}|| / ||B^{k-1}|| of the accepted iterate
    eta_disc: float = float("nan")
    eta_lin: float = float("nan")
    eta_alg: float = float("nan")
    eta: float = float("nan")
    n_estimates: int = 0
    time_estimate: float = 0.0
    time_ilu: float = 0.0          # set-up of the preconditioner of this step (ILU, or multigrid with method cg)
    ilu_fill_ratio: float = float("nan")  # nnz(L + U) / nnz(A) of the ILU of this step


@dataclass
class EstimatorRecord:
    """One estimator evaluation inside the loop (adaptive mode: every nu GMRES iterations)."""

    k: int
    i: int
    eta_disc: float
    eta_lin: float
    eta_alg: float
    res_alg: float
    stop_linear: bool
    alg_flux: float = float("nan")  # ||mu^{-1/2} sigma_alg|| part of eta_alg (when the estimator reports it)
    alg_res: float = float("nan")   # remainder part ||r - div sigma_alg||_{-1} of eta_alg


def rhs_norm(system, x, y, C, Ca, Cb) -> float:
    """||B^{k-1}|| of the 3-field linearization, B = [F; Ca (g + b) + Cb y - C] at (x, y) = X^{k-1}."""
    g = system.gap(x)
    b3 = Ca * (g + system.b) + Cb * y - C
    return float(np.sqrt(system.F @ system.F + b3 @ b3))


def algebraic_residual(system, x_new, y_new, x, y, C, Ca, Cb) -> np.ndarray:
    """R = B - A X' of the 3-field linearization at X = (x, y), for X' = (x_new, y_new).

    Layout [membrane rows (n); constraint rows (m)], the layout of the system.
    """
    r_x = -system.residual(x_new, y_new)  # F - (K x' - B^T D y')
    g = system.gap(x)
    r_c = (Ca * (g + system.b) + Cb * y - C) - (Ca * (system.gap(x_new) + system.b) + Cb * y_new)
    return np.concatenate([r_x, r_c])


@dataclass(frozen=True)
class KrylovSolve:
    """Restarted GMRES + ILU on the reduced Newton system (module docstring).  Fields validated once.

    ``estimator`` (adaptive mode, or ``log_estimators``): object with
    ``components(x, y, r_alg, dx_lookahead) -> Components`` (eta_disc, eta_lin, eta_alg, eta, terms).
    """

    mode: str = "inexact"
    tol_alg: float = 2e-12       # gmres mode: ||R^{k,i}|| / ||B^{k-1}||
    gamma_alg: float = 0.3       # adaptive: stop GMRES when eta_alg <= gamma_alg max(eta_disc, eta_lin)
    nu: int = 10                 # adaptive: GMRES iterations between estimator evaluations
    restart: int = 100
    max_gmres: int = 5000        # per Newton step
    ilu_drop_tol: float = 1e-5   # default chosen in results/inexact/TABLES.md (ILU table)
    ilu_fill: float = 8.0
    forcing_max: float = 0.5     # inexact: cap of the forcing term eta_k
    log_estimators: bool = False  # gmres/inexact: also evaluate the estimators after every step
    estimator: object = None
    method: str = "gmres"        # KRYLOV_METHODS: GMRES + ILU, or CG + multigrid
    prolongations: tuple = ()    # cg: the nested hierarchy of the geometric multigrid (else algebraic multigrid)
    preconditioner_cache: object = field(default=None, compare=False)  # PreconditionerCache shared by solves
    record_type = KrylovIterationRecord

    def __post_init__(self):
        if self.mode not in KRYLOV_MODES:
            raise option_error("newton", self.mode, f"one of {KRYLOV_MODES}")
        if self.method not in KRYLOV_METHODS:
            raise option_error("krylov", self.method, f"one of {KRYLOV_METHODS}")
        for name, lo in (("tol_alg", 0.0), ("gamma_alg", 0.0), ("forcing_max", 0.0)):
            v = getattr(self, name)
            if isinstance(v, bool) or not (isinstance(v, (int, float)) and lo < v < 1):
                raise option_error(name, v, "a number in (0, 1)" + (" ([JSC20]: gamma < 1)" if "gamma" in name else ""))
        v = self.ilu_drop_tol
        if isinstance(v, bool) or not (isinstance(v, (int, float)) and 0 <= v < 1):
            raise option_error("ilu_drop_tol", v, "a number in [0, 1)")
        v = self.ilu_fill
        if isinstance(v, bool) or not (isinstance(v, (int, float)) and 1 <= v < math.inf):
            raise option_error("ilu_fill", v, "a number >= 1")
        for name in ("nu", "restart", "max_gmres"):
            v = getattr(self, name)
            if isinstance(v, bool) or not (isinstance(v, int) and v >= 1):
                raise option_error(name, v, "a positive integer")
    def start(self, system, estimates: list):
        if (self.mode == "adaptive" or self.log_estimators) and self.estimator is None:
            raise ValueError(f"Krylov mode {self.mode!r} with estimators needs an estimator (estimator=...)")
        return _KrylovSession(self, system, estimates)


class _KrylovSession:
    def __init__(self, opt: KrylovSolve, system, estimates: list):
        self.opt, self.system, self.estimates = opt, system, estimates
        self.adaptive = opt.mode == "adaptive"
        self.want_eta = self.adaptive or opt.log_estimators
        self.gmres_cum = 0
        self.exact = False  # inexact mode after the cycling remedy: every later step solved to tol_alg

    #: what :meth:`fresh` does, for the safeguards' log
    refresh_label = "solve the steps to the gmres tolerance"

    @property
    def can_refresh(self) -> bool:
        """Whether :meth:`fresh` changes anything: the inexact mode's steps stop at their forcing term."""
        return self.opt.mode == "inexact" and not self.exact

    def fresh(self) -> None:
        """Solve every later step to the gmres mode's tolerance (a safeguard of the loop, :mod:`.safeguards`: steps
        left at a forcing term can take Newton-min back to an earlier active set)."""
        self.exact = True

    def step(self, k, x, y, c, Ca, Cb, res_prev) -> Trial:
        opt, system = self.opt, self.system
        lin = system.linearize(x, y, c, Ca, Cb)
        Bnorm = rhs_norm(system, x, y, c, Ca, Cb)
        bred = float(np.linalg.norm(lin.b)) or 1.0
        A, b = lin.A, lin.b
        scale = units_scale(A)
        weights = scale if opt.method == "cg" else None  # CG: the same iteration, its residuals weighted
        if scale is not None and weights is None:  # GMRES: on the scaled system (residuals in the units of u)
            A, b = (sp.diags(scale) @ A).tocsr(), scale * b
        self.A, self.b, self.weights = A, b, weights

        def norm(v):
            return float(np.linalg.norm(v if weights is None else weights * v))
        build = (lambda: _MultigridPreconditioner(lin, opt.prolongations)) if opt.method == "cg" else \
            (lambda: ILU(A, opt.ilu_drop_tol, opt.ilu_fill))
        M, reused = (build(), False) if opt.preconditioner_cache is None else \
            opt.preconditioner_cache.get(A, build, extra=getattr(lin, "keep", None))
        time_setup = 0.0 if reused else M.time_setup
        z0 = lin.restrict(x)
        self.t_est, self.n_est = 0.0, 0
        accepted = {}
        floor = 1e-14 * Bnorm / bred  # attainable accuracy in double precision
        if opt.mode == "gmres" or self.exact:
            rtol = opt.tol_alg * Bnorm / bred                    # ||R^{k,i}|| <= tol_alg ||B^{k-1}||
        elif opt.mode == "inexact":
            eta_k = min(res_prev, opt.forcing_max)               # forcing ||Phi(X^{k-1})|| / ||F||
            rtol = eta_k * norm(b - A @ z0) / (norm(b) or 1.0)  # ||R^{k,i}|| <= eta_k ||R^{k,0}||
        else:
            rtol = floor  # adaptive: the estimators stop GMRES; this only guards stagnation
        rtol = max(rtol, floor)  # relative to ||b_red|| (||r_red|| = ||R^{k,i}||, module docstring), or scaled alike

        monitor = None
        if self.adaptive:
            checkpoints: List[KrylovState] = []

            def monitor(st: KrylovState):
                checkpoints.append(KrylovState(st.i, st.x.copy(), st.r, st.res))
                if len(checkpoints) < 3:  # evaluate X^{k,i} for i >= nu (needs X^{k,i+nu})
                    return False
                prev, cur = checkpoints[-2], checkpoints[-1]
                te = time.perf_counter()
                xi, yi = lin.recover(prev.x)
                xj, _ = lin.recover(cur.x)
                R = algebraic_residual(system, xi, yi, x, y, c, Ca, Cb)
                comp = opt.estimator.components(xi, yi, R, xj - xi)
                self.n_est += 1
                self.t_est += time.perf_counter() - te
                res_alg = float(np.linalg.norm(R)) / Bnorm
                stop = stop_linear(comp.eta_alg, comp.eta_disc, comp.eta_lin, opt.gamma_alg)
                self.estimates.append(EstimatorRecord(k, prev.i, comp.eta_disc, comp.eta_lin, comp.eta_alg,
                                                      res_alg, stop, *_alg_terms(comp)))
                if stop:
                    accepted.update(x=xi, y=yi, i=prev.i, comp=comp, res_alg=res_alg)
                return stop

        tl = time.perf_counter()
        if opt.method == "cg":
            kr = cg(A, b, z0, M, rtol=rtol, maxiter=opt.max_gmres, nu=opt.nu, monitor=monitor, weights=weights)
        else:
            kr = gmres(A, b, z0, M, rtol=rtol, restart=opt.restart, maxiter=opt.max_gmres, nu=opt.nu,
                       monitor=monitor)
        time_linear = time.perf_counter() - tl - self.t_est + time_setup
        self.gmres_cum += kr.iterations
        if accepted:
            xf, yf, i_acc, comp, res_alg = (accepted[key] for key in ("x", "y", "i", "comp", "res_alg"))
        else:
            xf, yf = lin.recover(kr.x)
            i_acc, comp = kr.iterations, None
            R = algebraic_residual(system, xf, yf, x, y, c, Ca, Cb)
            res_alg = float(np.linalg.norm(R)) / Bnorm
        # state for after_step
        self.lin, self.M, self.kr, self.comp, self.i_acc, self.res_alg = lin, M, kr, comp, i_acc, res_alg
        self.prev = (x, y, c, Ca, Cb)
        return Trial(xf, yf, time_linear, dict(
            linear_size=lin.size, gmres_its=kr.iterations, gmres_cum=self.gmres_cum, gmres_accepted=i_acc,
            gmres_stop=GMRES_STOP[kr.reason], res_alg=res_alg, time_ilu=time_setup,
            ilu_fill_ratio=M.nnz / max(lin.A.nnz, 1) if M.nnz is not None else float("nan")))

    def after_step(self, k, x, y, step) -> dict:
        """Estimators of the accepted iterate: logging modes, a damped (fb) step, or an adaptive GMRES
        run that ended on its tolerance before the adaptive test triggered."""
        opt, comp = self.opt, self.comp
        if self.want_eta and (comp is None or step < 1.0):
            te = time.perf_counter()
            dx, r_alg = None, None
            if step == 1.0:
                xp, yp, cp, Ca, Cb = self.prev
                r_alg = algebraic_residual(self.system, x, y, xp, yp, cp, Ca, Cb)
                if self.kr.reason != "tolerance" or opt.mode == "inexact":
                    # sigma_alg from nu further iterations (diagnostic look-ahead, not counted)
                    if opt.method == "cg":
                        extra = cg(self.A, self.b, self.kr.x, self.M, rtol=0.0, maxiter=opt.nu, weights=self.weights)
                    else:
                        extra = gmres(self.A, self.b, self.kr.x, self.M, rtol=0.0, restart=opt.nu, maxiter=opt.nu)
                    xj, _ = self.lin.recover(extra.x)
                    dx = xj - x
            comp = opt.estimator.components(x, y, r_alg, dx)
            self.n_est += 1
            self.t_est += time.perf_counter() - te
            self.estimates.append(EstimatorRecord(k, self.i_acc, comp.eta_disc, comp.eta_lin, comp.eta_alg,
                                                  self.res_alg, False, *_alg_terms(comp)))
        out = dict(n_estimates=self.n_est, time_estimate=self.t_est)
        if comp is not None:
            out.update(eta_disc=float(comp.eta_disc), eta_lin=float(comp.eta_lin), eta_alg=float(comp.eta_alg),
                       eta=float(comp.eta))
        return out


def _alg_terms(comp):
    terms = comp.terms or {}
    return float(terms.get("alg_flux", float("nan"))), float(terms.get("alg_res", float("nan")))


class _MultigridPreconditioner:
    """CG's preconditioner of a step: one V-cycle of the truncated geometric multigrid on ``prolongations``
    (:class:`~ngcontact.algebra.multigrid.Multigrid`), or of algebraic multigrid without them."""

    nnz = None  # no fill to report (the ILU's record field)

    def __init__(self, lin, prolongations):
        from ..algebra.multigrid import AlgebraicMultigrid, Multigrid

        self.mg = Multigrid(lin.A, prolongations, lin.keep) if prolongations else AlgebraicMultigrid(lin.A)
        self.time_setup = self.mg.time_setup

    def solve(self, r):
        return self.mg(r)
