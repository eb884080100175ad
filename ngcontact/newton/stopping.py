r"""Stopping rules of the Newton loop.

A rule has ``measure(record, system, x, y, r)`` (fills what it needs into the iteration
record) and ``check(record, tol) -> reason | None``.  Every rule also stops on the
residual test ||Phi(X^k)|| / ||F|| <= tol (reason ``"converged"``).

* :class:`ResidualStop` -- the residual test only.
* :class:`BalancedStop` -- nested iteration: also stop when the linearization error is
  negligible next to the discretization error (reason ``"balanced"``),

      eps_lin(X^k) <= gamma_balance * eps_disc(X^k),

  a cheap, solve-free counterpart of the [JSC20] criterion eta_lin <= gamma_lin eta_disc:

  * eps_lin = ( ||R||^2_{diag(K)^-1} + sum_{g_i <= y_i} kappa_i c_i^2 + sum_{y_i < g_i} (D_i c_i)^2 / kappa_i )^{1/2},
    c_i = g_i where w g_i <= y_i, else y_i (w: the system's constraint weight; the defect of
    C = min(w g, y)): the energy (diagonally scaled) of the defect left by step k --
    linear residual R, and per row the complementarity defect as a gap (penetration,
    or a gap left open where y > 0) or as a multiplier (y < 0, or y > 0 where g > 0);
    kappa_i = (1/K_uu + 1/K_ll)^{-1} is the stiffness of the gap at row i (K_uu for
    one-sided rows).
  * eps_disc = 2^{-p} |||X^k - X_ref|||_K, X_ref the prolongated coarser solution: with
    Pythagoras (Galerkin orthogonality on nested spaces; approximate for the contact
    problem) and uniform refinement at rate h^r, |||u_l - I u_{l-1}||| = sqrt(4^r - 1)
    |||u - u_l|||, and 2^{-p} <= 1/sqrt(4^r - 1) for every r <= p, so eps_disc
    under-estimates the discretization error (conservative) unless the observed rate
    exceeds p.

  With gamma_balance = 1e-3 the linearization error changes the energy error by a
  relative ~ gamma^2/2 = 5e-7.  Why it matters: in degenerate bands (test 1: u1 - u2 <
  1e-12 and lambda = 0 around r = R) Newton-min moves the discrete free boundary by about
  one node layer per step, and the residual test then needs O(1/h) steps to settle gaps
  whose influence on the solution is far below the discretization error.  Not a
  guaranteed bound (the estimators of :mod:`ngcontact.estimators` are).
* :class:`AdaptiveStop` -- [JSC20]: stop when eta_lin <= gamma_lin eta_disc, with the
  estimators the Krylov strategy evaluated at the iterate (reason
  ``"adaptive stopping criterion"``); the residual test is the safeguard.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["StopOptions", "StopRule", "EstimatorStop", "ResidualStop", "BalancedStop", "AdaptiveStop", "Reference", "linearization_defect",
           "stop_linear", "stop_newton"]

RULES = ("residual", "balanced", "adaptive")


def _check_fraction(name: str, v) -> None:
    if isinstance(v, bool) or not isinstance(v, (int, float)) or not 0 < v < 1:
        raise ValueError(f"option {name} must be a number in (0, 1), got {v!r}")


@dataclass(frozen=True)
class StopOptions:
    """Which stopping rule, with its parameters (validated once).

    ``newton_stop``: 'residual', 'balanced' (needs the coarser level's solution: :meth:`rule`) or
    'adaptive' (the Krylov strategy's estimators).
    """

    newton_stop: str = "residual"
    gamma_balance: float = 1e-3
    gamma_lin: float = 0.3

    def __post_init__(self):
        if self.newton_stop not in RULES:
            raise ValueError(f"option newton_stop must be one of {RULES}, got {self.newton_stop!r}")
        _check_fraction("gamma_balance", self.gamma_balance)
        _check_fraction("gamma_lin", self.gamma_lin)

    def rule(self, reference: "Reference | None" = None):
        """The rule object; the balanced stop without a reference (first or cold-started level) is the
        residual stop."""
        if self.newton_stop == "adaptive":
            return AdaptiveStop(self.gamma_lin)
        if self.newton_stop == "balanced" and reference is not None:
            return BalancedStop(reference, self.gamma_balance)
        return ResidualStop()


def stop_linear(eta_alg: float, eta_disc: float, eta_lin: float, gamma_alg: float) -> bool:
    """Adaptive stopping criterion of the linear solver ([JSC20], seed "Adaptive algorithm").

    >>> stop_linear(0.3, 1.0, 0.5, 0.3), stop_linear(0.31, 1.0, 0.5, 0.3), stop_linear(0.3, 0.5, 1.0, 0.3)
    (True, False, True)
    """
    return eta_alg <= gamma_alg * max(eta_disc, eta_lin)


def stop_newton(eta_lin: float, eta_disc: float, gamma_lin: float) -> bool:
    """Adaptive stopping criterion of the semismooth Newton loop: eta_lin <= gamma_lin eta_disc.

    >>> stop_newton(0.03, 0.1, 0.3), stop_newton(0.031, 0.1, 0.3)
    (True, False)
    """
    return eta_lin <= gamma_lin * eta_disc


class StopRule:
    """What every stopping rule provides; the defaults are those of the residual test."""

    def on_difference(self, m: int):
        """The rule for the difference w = x[:m] - x[m:] (:mod:`.decoupled`)."""
        return self

    def rescaled(self, s: float):
        """The rule for the system with data / s (:meth:`ComplementaritySystem.rescaled`)."""
        return self

    def certificate_tol(self, options) -> float:
        """Tolerance of the exit certificate (:mod:`ngcontact.algebra.certificate`) when this rule's own test
        stopped the loop."""
        return options.certificate_tol

    def accepted(self, x, y):
        """The iterate this rule returns when its own test stopped the loop at (x, y)."""
        return x, y

    def measure(self, rec, system, x, y, r) -> None:
        """Fill what the rule needs into the iteration record ``rec``."""

    def check(self, rec, tol: float):
        return "converged" if rec.res <= tol else None


class EstimatorStop(StopRule):
    """A rule whose accepted iterate the a posteriori estimators certify: the exit certificate is recorded,
    not required."""

    def certificate_tol(self, options) -> float:
        return float("inf")


class ResidualStop(StopRule):
    """||Phi(X^k)|| / ||F|| <= tol."""


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


def linearization_defect(system, x: np.ndarray, y: np.ndarray, r=None) -> float:
    """eps_lin of the balanced stop (module doc): energy of the residual and complementarity defect."""
    dK = system.K.diagonal()
    r = system.residual(x, y) if r is None else r
    kappa = dK[system.up].astype(float)
    two = system.lo >= 0
    kappa[two] = 1.0 / (1.0 / kappa[two] + 1.0 / dK[system.lo[two]])
    g = system.gap(x)
    as_gap = system.constraint_weight * g <= y
    c = np.where(as_gap, g, y)
    return float(np.sqrt(np.sum(r * r / dK) + np.sum(kappa[as_gap] * c[as_gap] ** 2)
                         + np.sum((system.D[~as_gap] * c[~as_gap]) ** 2 / kappa[~as_gap])))


@dataclass(frozen=True)
class BalancedStop(StopRule):
    """Residual test, or eps_lin <= gamma_balance eps_disc against ``reference`` (module doc)."""

    reference: Reference
    gamma_balance: float = 1e-3

    def on_difference(self, m: int):
        """The rule for w = x[:m] - x[m:] in the S-norm: |||(ds, dw)|||_K^2 = (|ds|_S^2 + alpha |dw|_S^2) /
        (1 + alpha); the w-loop leaves s fixed, so eps_lin and eps_disc (which ignores ds: conservative)
        scale alike."""
        ref = self.reference
        return BalancedStop(Reference(ref.x[:m] - ref.x[m:], ref.weight), self.gamma_balance)

    def rescaled(self, s: float):
        if s == 1.0:
            return self
        return BalancedStop(Reference(self.reference.x / s, self.reference.weight), self.gamma_balance)

    def certificate_tol(self, options) -> float:
        """The balanced stop leaves a linearization error of relative size gamma_balance: the certificate
        (penetration, slackness; the multiplier is nonnegative, :meth:`accepted`) is required at that level."""
        return max(options.certificate_tol, self.gamma_balance)

    def accepted(self, x, y):
        """(x, y^+): the balanced iterate's multiplier may still be negative on rows the remaining Newton steps
        would settle (its size is part of eps_lin <= gamma eps_disc); the rule returns its nonnegative part."""
        return x, np.maximum(y, 0.0)

    def measure(self, rec, system, x, y, r) -> None:
        rec.eps_lin = linearization_defect(system, x, y, r)
        rec.eps_disc = self.reference.eps_disc(system, x)

    def check(self, rec, tol: float):
        if rec.res <= tol:
            return "converged"
        if rec.eps_lin <= self.gamma_balance * rec.eps_disc:
            return "balanced"
        return None


@dataclass(frozen=True)
class AdaptiveStop(EstimatorStop):
    """[JSC20]: eta_lin <= gamma_lin eta_disc (estimators recorded by the Krylov strategy), or the residual test."""

    gamma_lin: float = 0.3

    def check(self, rec, tol: float):
        if stop_newton(rec.eta_lin, rec.eta_disc, self.gamma_lin):
            return "adaptive stopping criterion"
        return "converged" if rec.res <= tol else None
