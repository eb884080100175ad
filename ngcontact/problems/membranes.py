"""Contact between two membranes ([JSC20], [CAMWA21])::

    -mu1 Lap u1 - lam = f1,   -mu2 Lap u2 + lam = f2   in Omega,
    u1 - u2 >= 0,  lam >= 0,  (u1 - u2) lam = 0          in Omega,
    u1 = g1, u2 = g2 on the boundary  (g1 >= g2).
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Optional

from ngsolve import CoefficientFunction

from .base import BoundaryOrder, ContactProblem, ExactSolution, ProblemDataError

__all__ = ["TwoMembraneProblem"]


@dataclass(frozen=True)
class TwoMembraneProblem(ContactProblem):
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

    The declared interface (:class:`~ngcontact.problems.base.Problem`): ``nfields`` = 2,
    ``field_names`` = ("u1", "u2"), ``loads`` = (f1, f2), ``dirichlet`` = (g1, g2),
    ``mus`` = (mu1, mu2), ``signs`` = (+1, -1), ``obstacle`` = None (gap u1 - u2),
    ``boundary_order``: g1 >= g2.
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

    field_names = ("u1", "u2")
    load_names = ("f1", "f2")
    dirichlet_names = ("g1", "g2")
    signs = (1, -1)
    boundary_order = BoundaryOrder("g1", "g2", "g1 < g2 on the boundary (empty admissible set: u1 - u2 >= 0 is impossible)")

    def __post_init__(self):
        self._validate(("mu1", "mu2"), ("f1", "f2", "g1", "g2"))
        if self.exact is not None and self.exact.u2 is None:
            raise ProblemDataError("TwoMembraneProblem.exact.u2 is missing (both u1 and u2 are needed)")

    @property
    def mus(self) -> tuple:
        return (self.mu1, self.mu2)
