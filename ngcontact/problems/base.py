"""Problem data: what is solved, independent of any finite element space.

Two problems share one algebra:

* :class:`TwoMembraneProblem` -- contact between two membranes ([JSC20], [CAMWA21])::

      -mu1 Lap u1 - lam = f1,   -mu2 Lap u2 + lam = f2   in Omega,
      u1 - u2 >= 0,  lam >= 0,  (u1 - u2) lam = 0          in Omega,
      u1 = g1, u2 = g2 on the boundary  (g1 >= g2).

* :class:`ObstacleProblem` -- one membrane above an obstacle psi::

      -mu Lap u - lam = f,  u - psi >= 0,  lam >= 0,  (u - psi) lam = 0,  u = g on the boundary.

Data are NGSolve CoefficientFunctions (numbers are converted), so expressions
in ``x``, ``y`` with ``IfPos``, ``sqrt``, ... work.  Instances are frozen and
validated on construction; checks that need points of the domain (finite
data, g1 >= g2 and psi <= g on the boundary) run once a mesh exists, through
:func:`check_data_on_points`.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field, fields
from typing import Optional

import numpy as np
from ngsolve import CoefficientFunction

__all__ = [
    "ProblemDataError",
    "ExactSolution",
    "TwoMembraneProblem",
    "ObstacleProblem",
    "check_data_on_points",
]


class ProblemDataError(ValueError):
    """Invalid problem data; the message names the field and the bad value."""


def _as_cf(value, name: str) -> CoefficientFunction:
    if isinstance(value, CoefficientFunction):
        return value
    if isinstance(value, (int, float)) and not isinstance(value, bool):
        if not math.isfinite(value):
            raise ProblemDataError(f"{name} must be finite, got {value}")
        return CoefficientFunction(float(value))
    raise ProblemDataError(
        f"{name} must be a number or an ngsolve CoefficientFunction, got {type(value).__name__}"
    )


def _positive(value, name: str) -> float:
    try:
        v = float(value)
    except (TypeError, ValueError):
        raise ProblemDataError(f"{name} must be a positive number, got {value!r}") from None
    if not math.isfinite(v) or v <= 0:
        raise ProblemDataError(f"{name} must be a positive finite number, got {value!r}")
    return v


def _convert_cfs(obj, names) -> None:
    for name in names:
        val = getattr(obj, name)
        if val is not None:
            object.__setattr__(obj, name, _as_cf(val, f"{type(obj).__name__}.{name}"))


@dataclass(frozen=True)
class ExactSolution:
    """Known solution, used only to compute errors.

    For the two-membrane problem give ``u1``, ``u2`` (and optionally ``lam``);
    for the obstacle problem give ``u1`` (= u) and optionally ``lam``.
    Gradients are obtained by symbolic differentiation (``cf.Diff(x)``) unless
    given explicitly as 2-vectors ``grad_u1``, ``grad_u2``.
    """

    u1: CoefficientFunction
    u2: Optional[CoefficientFunction] = None
    lam: Optional[CoefficientFunction] = None
    grad_u1: Optional[CoefficientFunction] = None
    grad_u2: Optional[CoefficientFunction] = None

    def __post_init__(self):
        _convert_cfs(self, ["u1", "u2", "lam"])

    def gradient(self, alpha: int) -> CoefficientFunction:
        """Gradient of u_alpha (alpha = 1 or 2)."""
        from ngsolve import x, y

        given = self.grad_u1 if alpha == 1 else self.grad_u2
        if given is not None:
            return given
        u = self.u1 if alpha == 1 else self.u2
        return CoefficientFunction((u.Diff(x), u.Diff(y)))


@dataclass(frozen=True)
class TwoMembraneProblem:
    """Contact between two membranes (model problem of [JSC20], [CAMWA21]).

    Parameters
    ----------
    domain : ngcontact.domains.Domain
        where the problem lives (gives the meshes).
    f1, f2 : CoefficientFunction or float
        loads of membranes 1 and 2.
    g1, g2 : CoefficientFunction or float
        Dirichlet data, g1 >= g2 on the boundary (checked on the mesh).
    mu1, mu2 : float
        tensions, > 0.
    exact : ExactSolution, optional
        exact (u1, u2, lam) for error computation.
    name : str
        label used in outputs.
    """

    domain: object
    f1: CoefficientFunction
    f2: CoefficientFunction
    g1: CoefficientFunction = 0.0
    g2: CoefficientFunction = 0.0
    mu1: float = 1.0
    mu2: float = 1.0
    exact: Optional[ExactSolution] = None
    name: str = "two-membrane"

    kind = "membranes"
    fields_ = ("u1", "u2")

    def __post_init__(self):
        object.__setattr__(self, "mu1", _positive(self.mu1, "TwoMembraneProblem.mu1"))
        object.__setattr__(self, "mu2", _positive(self.mu2, "TwoMembraneProblem.mu2"))
        _convert_cfs(self, ["f1", "f2", "g1", "g2"])
        _check_domain(self)
        if self.exact is not None and not isinstance(self.exact, ExactSolution):
            raise ProblemDataError(f"TwoMembraneProblem.exact must be an ExactSolution, got {type(self.exact).__name__}")
        if self.exact is not None and self.exact.u2 is None:
            raise ProblemDataError("TwoMembraneProblem.exact.u2 is missing (both u1 and u2 are needed)")

    @property
    def mus(self) -> tuple:
        return (self.mu1, self.mu2)


@dataclass(frozen=True)
class ObstacleProblem:
    """Obstacle problem: one membrane u >= psi (seed, "Motivation").

    Same algebra as :class:`TwoMembraneProblem` with one field: the
    constraint u - psi >= 0 replaces u1 - u2 >= 0.
    """

    domain: object
    psi: CoefficientFunction
    f: CoefficientFunction = 0.0
    g: CoefficientFunction = 0.0
    mu: float = 1.0
    exact: Optional[ExactSolution] = None
    name: str = "obstacle"

    kind = "obstacle"
    fields_ = ("u",)

    def __post_init__(self):
        object.__setattr__(self, "mu", _positive(self.mu, "ObstacleProblem.mu"))
        _convert_cfs(self, ["psi", "f", "g"])
        _check_domain(self)
        if self.exact is not None and not isinstance(self.exact, ExactSolution):
            raise ProblemDataError(f"ObstacleProblem.exact must be an ExactSolution, got {type(self.exact).__name__}")

    @property
    def mus(self) -> tuple:
        return (self.mu,)


def _check_domain(problem) -> None:
    dom = problem.domain
    if not (hasattr(dom, "mesh") and hasattr(dom, "meshes")):
        raise ProblemDataError(
            f"{type(problem).__name__}.domain must be an ngcontact domain (e.g. CrissCrossSquare()), "
            f"got {type(dom).__name__}"
        )


def check_data_on_points(problem, values: dict, boundary: np.ndarray, coords: np.ndarray, tol: float = 1e-12) -> None:
    """Checks that need the domain: finite data, g1 >= g2 / psi <= g on the boundary.

    Parameters
    ----------
    values : dict name -> ndarray
        data evaluated at the points (names as the problem's fields).
    boundary : bool ndarray
        which points lie on the Dirichlet boundary.
    coords : ndarray (n, 2)
        the points, for the error message.
    """
    cls = type(problem).__name__
    for name, val in values.items():
        # Dirichlet data only matter on the boundary (e.g. -A log r is -inf at r = 0)
        where = boundary if name in ("g", "g1", "g2") else np.ones(len(val), dtype=bool)
        bad = where & ~np.isfinite(val)
        if bad.any():
            i = int(np.flatnonzero(bad)[0])
            raise ProblemDataError(
                f"{cls}.{name} is not finite at ({coords[i, 0]:.4g}, {coords[i, 1]:.4g}): {val[i]}"
            )
    if problem.kind == "membranes":
        gap = values["g1"] - values["g2"]
        what = "g1 < g2 on the boundary (empty admissible set: u1 - u2 >= 0 is impossible)"
    else:
        gap = values["g"] - values["psi"]
        what = "obstacle psi above the Dirichlet data g on the boundary (empty admissible set)"
    scale = tol * max(1.0, float(np.max(np.abs(gap[boundary]))) if boundary.any() else 1.0)
    bad = boundary & (gap < -scale)
    if bad.any():
        i = int(np.flatnonzero(bad)[np.argmin(gap[bad])])
        raise ProblemDataError(
            f"{cls}: {what}; at ({coords[i, 0]:.4g}, {coords[i, 1]:.4g}) the difference is {gap[i]:.3e}"
        )


def data_fields(problem) -> dict:
    """Name -> CoefficientFunction of every datum (for evaluation and checks)."""
    names = ["f1", "f2", "g1", "g2"] if problem.kind == "membranes" else ["f", "g", "psi"]
    return {n: getattr(problem, n) for n in names}
