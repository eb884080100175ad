"""Options, iteration records and result of the Newton loop (:mod:`.loop`)."""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import List, Optional

import numpy as np

from ..algebra.cfunctions import get_cfunction

__all__ = ["NewtonOptions", "IterationRecord", "NewtonResult", "option_error"]


def option_error(name: str, value, want: str) -> ValueError:
    """The one wording of a bad option: ``option NAME must be WANT, got VALUE`` (the CLI maps NAME to its flag)."""
    return ValueError(f"option {name} must be {want}, got {value!r}")


def _is_number(v) -> bool:
    return isinstance(v, (int, float)) and not isinstance(v, bool)


@dataclass(frozen=True)
class NewtonOptions:
    """Settings of the Newton loop itself (the linear solves and the stopping rule are handed in).

    Every field is validated here once; errors name it.
    """

    cfun: str = "min"
    tol: float = 1e-10  # ||Phi|| / ||F||
    maxit: int = 200
    line_search: Optional[bool] = None  # default: on for 'fb', off for 'min'
    armijo: float = 1e-4
    min_step: float = 2.0 ** -30
    reuse_factorization: bool = True  # direct solves: PCG with an earlier step's factorization (algebra.reuse)
    cert_tol: Optional[float] = None  # exit certificate (algebra.certificate); None: certificate_tol's default

    @property
    def certificate_tol(self) -> float:
        """Bound on the relative penetration, negative multiplier, slackness and residual in the units of each field
        at exit (:mod:`ngcontact.algebra.certificate`):
        ``cert_tol``, default 1e3 tol."""
        return self.cert_tol if self.cert_tol is not None else 1e3 * self.tol

    def __post_init__(self):
        try:
            get_cfunction(self.cfun)
        except ValueError:
            raise option_error("cfun", self.cfun, "'min' or 'fb'") from None
        if not (_is_number(self.tol) and 0 < self.tol < float("inf")):
            raise option_error("tol", self.tol, "a positive number")
        if isinstance(self.maxit, bool) or not isinstance(self.maxit, int) or self.maxit < 1:
            raise option_error("maxit", self.maxit, "a positive integer")
        if self.line_search not in (None, True, False):
            raise option_error("line_search", self.line_search, "True, False or None")
        if not (_is_number(self.armijo) and 0 < self.armijo < 0.5):
            raise option_error("armijo", self.armijo, "a number in (0, 1/2)")
        if not (_is_number(self.min_step) and 0 < self.min_step < 1):
            raise option_error("min_step", self.min_step, "a number in (0, 1)")
        if not isinstance(self.reuse_factorization, bool):
            raise option_error("reuse_factorization", self.reuse_factorization, "True or False")
        if self.cert_tol is not None and not (_is_number(self.cert_tol) and 0 < self.cert_tol < 1):
            raise option_error("cert_tol", self.cert_tol, "a number in (0, 1)")


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
    time_linear: float  # linear solve of the step (as the strategy counts it)
    time_step: float  # whole iteration
    linear_size: int = 0  # unknowns of the linear system actually solved (reduced / condensed)
    linear_path: int = 0  # index in algebra.system.LINEAR_PATHS: 0 factorized, 1 PCG with a reused factorization, 2 PCG gave up, 3 PCG + multigrid
    pcg_its: int = 0  # PCG iterations of this step (also those of a failed attempt)
    eps_lin: float = float("nan")  # balanced stop only: linearization defect (newton.stopping)
    eps_disc: float = float("nan")  # balanced stop only: discretization proxy 2^-p |||x - x_ref|||
    remedy: int = 0  # safeguard taken after this iteration (index in newton.safeguards.REMEDIES)


@dataclass
class NewtonResult:
    """Outcome of :func:`semismooth_newton`.

    ``estimates``: the estimator evaluations of the adaptive Krylov mode
    (:class:`~.linear.EstimatorRecord`), empty otherwise.
    """

    x: np.ndarray
    y: np.ndarray
    converged: bool
    reason: str
    iterations: int
    history: List[IterationRecord] = field(default_factory=list)
    estimates: list = field(default_factory=list)
    certificate: Optional[object] = None  # algebra.certificate.Certificate of (x, y)
    remedies: List[str] = field(default_factory=list)  # safeguards taken (newton.safeguards), one line each

    @property
    def time_linear(self) -> float:
        return sum(r.time_linear for r in self.history)

    @property
    def time_total(self) -> float:
        return sum(r.time_step for r in self.history)

    @property
    def gmres_total(self) -> int:
        """GMRES iterations performed (0 for direct solves)."""
        return sum(getattr(r, "gmres_its", 0) for r in self.history)

    @property
    def time_estimate(self) -> float:
        """Seconds spent in estimator evaluations inside the loop (adaptive Krylov mode)."""
        return sum(getattr(r, "time_estimate", 0.0) for r in self.history)
