"""Run options: what one run computes, validated once.

:class:`RunOptions` is the flat, user-facing set (the CLI flags and scene ``DEFAULTS`` use its
field names).  Each field is validated exactly once, by the option group of the layer that uses
it, built here once per run:

* :attr:`RunOptions.newton_options` -- :class:`~ngcontact.newton.NewtonOptions` (cfun, tol, maxit);
* :attr:`RunOptions.linear` -- the linear-solve strategy: :class:`~ngcontact.newton.DirectSolve` or
  :class:`~ngcontact.newton.KrylovSolve` (newton mode, gamma_alg, nu, ILU);
* :attr:`RunOptions.stop_options` -- :class:`~ngcontact.newton.StopOptions` (newton_stop,
  gamma_balance, gamma_lin);
* :attr:`RunOptions.estimator_options` -- the estimators' options (flux degree);
* :attr:`RunOptions.adaptive_options` -- :class:`AdaptiveOptions` (marking, theta, budgets).

:class:`RunOptions` itself checks only what concerns the run as a whole (discretization, degree,
levels, start) and the rules that combine groups (e.g. Krylov modes need an estimable
discretization).  Errors are ``ValueError("option NAME must be ..., got VALUE")``.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Optional

from .algebra.linalg import SOLVERS
from .discretizations import DISCRETIZATIONS
from .discretizations.nodesets import CONSTRAINTS, NODAL_CONSTRAINTS
from .estimators import EstimatorOptions
from .marking import check_marking
from .newton import DirectSolve, KrylovSolve, MultigridSolve, NewtonOptions, StopOptions
from .newton.base import option_error

__all__ = ["RunOptions", "AdaptiveOptions", "NEWTON_MODES", "MULTIGRID_NEWTON", "GMRES_NEWTON"]

#: Newton linear solves: direct (sparse factorizations), gmres (GMRES + ILU to 2e-12: the "exact" mode of
#: [JSC20]), inexact (GMRES with a forcing term), adaptive (GMRES stopped by the estimators, [JSC20]),
#: multigrid (CG + multigrid to a tenth of the Newton tolerance: truncated geometric multigrid on nested P1
#: levels, else algebraic multigrid), multigrid-inexact (the same with a forcing term; :mod:`ngcontact.newton.multigrid`)
NEWTON_MODES = ("direct", "gmres", "inexact", "adaptive", "multigrid", "multigrid-inexact")
#: the modes of :class:`~ngcontact.newton.MultigridSolve`
MULTIGRID_NEWTON = {"multigrid": "exact", "multigrid-inexact": "inexact"}
#: the modes that solve with GMRES (and need an estimable discretization)
GMRES_NEWTON = ("gmres", "inexact", "adaptive")


def _positive_or_none(name, v):
    if v is not None and (isinstance(v, bool) or not isinstance(v, (int, float)) or not 0 < v < float("inf")):
        raise option_error(name, v, "a positive number (or None)")


@dataclass(frozen=True)
class AdaptiveOptions:
    """The adaptive loop: marking and when to stop."""

    marking: str = "doerfler"  # 'doerfler' (bulk, theta) or 'max' (eta_K >= theta max eta_K)
    theta: float = 0.5  # marking parameter in (0, 1]
    max_ndof: Optional[int] = None  # do not solve on a mesh with more DOFs
    target_eta: Optional[float] = None  # stop when eta <= target_eta
    max_time: Optional[float] = None  # stop when the cumulative wall time [s] exceeds it
    max_levels: int = 30  # at most this many levels

    def __post_init__(self):
        check_marking(self.marking, self.theta)
        v = self.max_ndof
        if v is not None and (isinstance(v, bool) or not isinstance(v, int) or v < 1):
            raise option_error("max_ndof", v, "a positive integer (or None)")
        _positive_or_none("target_eta", self.target_eta)
        _positive_or_none("max_time", self.max_time)
        v = self.max_levels
        if isinstance(v, bool) or not isinstance(v, int) or not 1 <= v <= 200:
            raise option_error("max_levels", v, "an integer between 1 and 200")


@dataclass(frozen=True)
class RunOptions:
    """What a run computes (module doc).  Every field is validated once; errors name it."""

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
    flux_order: Optional[int] = None  # RT degree q of the estimators' flux: p (default) or p + 1
    decouple: bool = False  # two membranes, K = blockdiag(S, alpha S): Newton on w = u1 - u2 only
    newton: str = "direct"  # NEWTON_MODES
    gamma_alg: float = 0.3  # adaptive: stop GMRES when eta_alg <= gamma_alg max(eta_disc, eta_lin)
    gamma_lin: float = 0.3  # adaptive: stop Newton when eta_lin <= gamma_lin eta_disc
    nu: int = 10  # adaptive: GMRES iterations between estimator evaluations
    krylov: str = "gmres"  # GMRES modes: 'gmres' (GMRES + ILU, [JSC20]) or 'cg' (CG + multigrid)
    ilu_drop_tol: float = 1e-5  # GMRES modes: ILU threshold (scipy spilu drop_tol)
    ilu_fill: float = 8.0  # GMRES modes: ILU fill bound, nnz(L + U) <= ilu_fill nnz(A) (spilu fill_factor)
    newton_stop: str = "residual"  # direct Newton: 'residual' | 'balanced' (newton.stopping)
    gamma_balance: float = 1e-3  # balanced: stop when eps_lin <= gamma_balance eps_disc (nested levels only)
    adaptive: bool = False  # solve -> estimate -> mark -> refine instead of uniform levels
    marking: str = "doerfler"  # adaptive: AdaptiveOptions
    theta: float = 0.5
    max_ndof: Optional[int] = None
    target_eta: Optional[float] = None
    max_time: Optional[float] = None
    max_levels: int = 30
    constraints: str = "nodal"  # 'nodal' (positive node set), 'equispaced' ([CAMWA21]) or 'bernstein' (fem)

    def __post_init__(self):
        def bad(name, want):
            raise option_error(name, getattr(self, name), want)

        if self.disc not in DISCRETIZATIONS:
            bad("disc", f"one of {sorted(DISCRETIZATIONS)}")
        Disc = DISCRETIZATIONS[self.disc]
        if isinstance(self.order, bool) or not isinstance(self.order, int) or self.order not in Disc.orders:
            bad("order", f"one of {list(Disc.orders)} for {self.disc}")
        if isinstance(self.levels, bool) or not isinstance(self.levels, int) or not 1 <= self.levels <= 12:
            bad("levels", "an integer between 1 and 12")
        if self.start not in ("nested", "cold"):
            bad("start", "'nested' or 'cold'")
        if self.constraints not in CONSTRAINTS:
            bad("constraints", f"one of {sorted(CONSTRAINTS)}")
        if self.disc != "fem" and self.constraints not in NODAL_CONSTRAINTS:
            bad("constraints", f"one of {sorted(NODAL_CONSTRAINTS)} for disc {self.disc!r} (bernstein: fem only)")
        if self.solver not in SOLVERS:
            bad("solver", f"one of {SOLVERS}")
        for name in ("condense", "estimate", "decouple", "adaptive"):
            if not isinstance(getattr(self, name), bool):
                bad(name, "True or False")
        if self.newton not in NEWTON_MODES:
            bad("newton", f"one of {NEWTON_MODES}")
        estimable = Disc.estimable
        if self.estimate and not estimable:
            bad("estimate", f"False for disc {self.disc!r} (estimators exist for {_estimable()})")
        if self.adaptive and not estimable:
            bad("adaptive", f"False for disc {self.disc!r} (estimators exist for {_estimable()})")
        if self.newton in GMRES_NEWTON and not estimable:
            bad("newton", f"'direct' for disc {self.disc!r} (the GMRES modes are implemented for {_estimable()})")
        if self.newton in MULTIGRID_NEWTON and self.disc != "fem":
            bad("newton", f"'direct' for disc {self.disc!r} (the multigrid modes are implemented for fem)")
        if self.newton_stop not in ("residual", "balanced"):
            bad("newton_stop", "'residual' or 'balanced'")
        if self.newton_stop == "balanced" and self.newton in GMRES_NEWTON:
            bad("newton_stop", f"'residual' with newton {self.newton!r} (the GMRES modes have their own stopping rules)")
        if self.decouple and self.disc != "fem":
            raise ValueError(f"option decouple needs disc 'fem' (got disc {self.disc!r})")
        if self.decouple and self.newton != "direct":
            raise ValueError(f"option decouple needs the direct Newton solves: option newton 'direct' "
                             f"(got {self.newton!r})")
        # the option groups: each validates its own fields
        set_ = object.__setattr__
        set_(self, "newton_options", NewtonOptions(cfun=self.cfun, tol=self.tol, maxit=self.maxit))
        # built also for the other modes: it validates the GMRES fields, which they ignore
        krylov = KrylovSolve(mode=self.newton if self.newton in GMRES_NEWTON else "inexact", gamma_alg=self.gamma_alg,
                             nu=self.nu, ilu_drop_tol=self.ilu_drop_tol, ilu_fill=self.ilu_fill, method=self.krylov)
        if self.newton in MULTIGRID_NEWTON:
            linear = MultigridSolve(mode=MULTIGRID_NEWTON[self.newton], tol=min(self.tol, 0.5))
        else:
            linear = DirectSolve() if self.newton == "direct" else krylov
        set_(self, "linear", linear)
        set_(self, "stop_options", StopOptions(newton_stop="adaptive" if self.newton == "adaptive" else self.newton_stop,
                                               gamma_balance=self.gamma_balance, gamma_lin=self.gamma_lin))
        estimator_options = EstimatorOptions(flux_order=self.flux_order)
        estimator_options.flux_degree(self.order)  # the flux_order rule that depends on p
        set_(self, "estimator_options", estimator_options)
        set_(self, "adaptive_options", AdaptiveOptions(self.marking, self.theta, self.max_ndof, self.target_eta,
                                                       self.max_time, self.max_levels))

    @classmethod
    def for_scene(cls, scene, **given) -> "RunOptions":
        """Scene defaults, overridden by explicitly given (non-None) options."""
        explicit = {k: v for k, v in given.items() if v is not None}
        opts = {**scene.defaults, **explicit}
        unknown = set(opts) - set(cls.__dataclass_fields__)
        if unknown:
            raise ValueError(f"unknown option(s) {sorted(unknown)} in scene {scene.name} DEFAULTS")
        try:
            return cls(**opts)
        except ValueError as exc:  # say where a value that did not come from the caller came from
            text = str(exc)
            if any(k not in explicit and (f"option {k} " in text or f"--{k.replace('_', '-')} " in text)
                   for k in scene.defaults):
                raise ValueError(f"{text} (from the DEFAULTS of scene {scene.name})") from None
            raise


def _estimable() -> list:
    return sorted(name for name, D in DISCRETIZATIONS.items() if D.estimable)
