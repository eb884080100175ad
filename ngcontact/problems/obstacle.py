"""One membrane above an obstacle psi::

    -mu Lap u - lam = f,  u - psi >= 0,  lam >= 0,  (u - psi) lam = 0  in Omega,  u = g on the boundary.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Optional

from ngsolve import CoefficientFunction

from .base import BoundaryOrder, ContactProblem, ExactSolution

__all__ = ["ObstacleProblem"]


@dataclass(frozen=True)
class ObstacleProblem(ContactProblem):
    """Obstacle problem: one membrane u >= psi (seed, "Motivation").

    Same algebra as :class:`~ngcontact.problems.membranes.TwoMembraneProblem` with one
    field: the constraint u - psi >= 0 replaces u1 - u2 >= 0.  Declared interface
    (:class:`~ngcontact.problems.base.Problem`): ``nfields`` = 1, ``field_names`` = ("u",),
    ``loads`` = (f,), ``dirichlet`` = (g,), ``mus`` = (mu,), ``signs`` = (+1,),
    ``obstacle`` = psi, ``boundary_order``: g >= psi.
    """

    domain: object
    psi: CoefficientFunction
    f: CoefficientFunction = 0.0
    g: CoefficientFunction = 0.0
    mu: float = 1.0
    exact: Optional[ExactSolution] = None
    name: str = "obstacle"

    field_names = ("u",)
    load_names = ("f",)
    dirichlet_names = ("g",)
    signs = (1,)
    boundary_order = BoundaryOrder("g", "psi", "obstacle psi above the Dirichlet data g on the boundary "
                                               "(empty admissible set)")

    def __post_init__(self):
        self._validate(("mu",), ("psi", "f", "g"))

    @property
    def mus(self) -> tuple:
        return (self.mu,)

    @property
    def obstacle(self) -> CoefficientFunction:
        return self.psi
