"""The parabolic two-membrane contact problem ([CMAME20]; seed "Parabolic model problem with linear
complementarity constraints")::

    d_t u1 - mu1 Lap u1 - lam = f1,   d_t u2 - mu2 Lap u2 + lam = f2   in Omega x (0, T),
    u1 - u2 >= 0,  lam >= 0,  (u1 - u2) lam = 0,
    u_a = g_a on the boundary,  u_a(0) = u_a^0 (u1^0 >= u2^0).

A :class:`ParabolicProblem` wraps the stationary data (a :class:`~.membranes.TwoMembraneProblem`:
domain, mu, f, g) with the initial data and the final time, as pyMOR's instationary problems
do.  Loads (and the exact solution) may depend on t through an NGSolve ``Parameter`` given as
``time``; the Dirichlet data may not (checked on the nodes by :func:`check_initial_on_points`).
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Optional, Tuple

import numpy as np
from ngsolve import CoefficientFunction

from .base import ExactSolution, ProblemDataError, _as_cf
from .membranes import TwoMembraneProblem

__all__ = ["ParabolicProblem", "check_initial_on_points", "DIRICHLET_CHECK_TIMES"]


@dataclass(frozen=True)
class ParabolicProblem:
    """Parabolic two-membrane problem: stationary data + initial data + final time.

    Parameters
    ----------
    stationary : TwoMembraneProblem
        domain, tensions, loads f_a (may depend on ``time``), Dirichlet data g_a (constant in t).
        Its ``exact`` (if any) is the stationary solution (used for the distance at t = T).
    u0 : tuple of CoefficientFunction or float
        initial data (u1^0, u2^0), u1^0 >= u2^0 (checked on the nodes).
    t_final : float
        T > 0.
    time : ngsolve.Parameter, optional
        the parameter t the data depend on (set by the time stepper); None for data constant in t.
    exact : ExactSolution, optional
        exact (u1, u2, lam) as functions of x, y and ``time``.
    name : str
    """

    stationary: TwoMembraneProblem
    u0: Tuple = (0.0, 0.0)
    t_final: float = 1.0
    time: object = None
    exact: Optional[ExactSolution] = None
    name: str = "parabolic"

    def __post_init__(self):
        cls = type(self).__name__
        if not isinstance(self.stationary, TwoMembraneProblem):
            raise ProblemDataError(f"{cls}.stationary must be a TwoMembraneProblem, got "
                                   f"{type(self.stationary).__name__}")
        try:
            u0 = tuple(self.u0)
        except TypeError:
            u0 = None
        if u0 is None or len(u0) != 2:
            raise ProblemDataError(f"{cls}.u0 must be a pair (u1^0, u2^0), got {self.u0!r}")
        object.__setattr__(self, "u0", tuple(_as_cf(v, f"{cls}.u0[{i}]") for i, v in enumerate(u0)))
        T = self.t_final
        if isinstance(T, bool) or not isinstance(T, (int, float)) or not (math.isfinite(T) and T > 0):
            raise ProblemDataError(f"{cls}.t_final must be a positive finite number, got {T!r}")
        object.__setattr__(self, "t_final", float(T))
        if self.time is not None and type(self.time).__name__ != "Parameter":
            raise ProblemDataError(f"{cls}.time must be an ngsolve Parameter or None, got {type(self.time).__name__}")
        if self.time is None:  # data built from a Parameter that nobody sets would stay at its initial value
            for name, cf in self._data_fields():
                if "ParameterCoefficientFunction" in str(cf):
                    raise ProblemDataError(f"{cls}.{name} depends on an ngsolve Parameter but {cls}.time is None: "
                                           f"pass the Parameter of t as time=... (the time stepper sets it)")
        if self.exact is not None:
            if not isinstance(self.exact, ExactSolution) or self.exact.u2 is None:
                raise ProblemDataError(f"{cls}.exact must be an ExactSolution with u1 and u2, got {self.exact!r}")

    def _data_fields(self):
        """(name, CoefficientFunction) of the data that may depend on t: loads, Dirichlet data, initial data, exact
        solution."""
        st = self.stationary
        out = [(f"stationary.{n}", cf) for n, cf in zip(("f1", "f2"), st.loads)]
        out += list(zip((f"stationary.{n}" for n in st.dirichlet_names), st.dirichlet))
        out += [(f"u0[{i}]", cf) for i, cf in enumerate(self.u0)]
        if self.exact is not None:
            out += [(f"exact.{n}", getattr(self.exact, n)) for n in ("u1", "u2", "lam")
                    if getattr(self.exact, n, None) is not None]
        return [(n, cf) for n, cf in out if isinstance(cf, CoefficientFunction)]

    # the declared interface of the stationary problem, read through
    @property
    def domain(self):
        return self.stationary.domain

    @property
    def field_names(self):
        return self.stationary.field_names

    @property
    def nfields(self) -> int:
        return self.stationary.nfields

    @property
    def mus(self):
        return self.stationary.mus

    def set_time(self, t: float) -> None:
        """Set the data's time parameter (no-op for data constant in t)."""
        if self.time is not None:
            self.time.Set(float(t))


#: the times (fractions of T) at which the Dirichlet data are compared with those at t = 0 (irrational fractions: a
#: g periodic in t with g(0) = g(T) differs from g(0) at one of them)
DIRICHLET_CHECK_TIMES = (0.1309, 0.2718, 0.5, 0.7071, 0.9137, 1.0)


def check_initial_on_points(problem: ParabolicProblem, u0_values, boundary_at_0, boundary_later, coords,
                            tol: float = 1e-12) -> None:
    """Checks that need the nodes: u1^0 >= u2^0 everywhere, finite initial data, Dirichlet data constant in t.

    Parameters
    ----------
    u0_values : (ndarray, ndarray)
        u1^0, u2^0 at the nodes.
    boundary_at_0 : list of ndarray
        g1, g2 at the boundary nodes with the time parameter at 0.
    boundary_later : list of (t, list of ndarray)
        the same at later times t (e.g. :data:`DIRICHLET_CHECK_TIMES` times T).
    coords : ndarray (n, 2)
        the nodes (for the messages).
    """
    cls = type(problem).__name__
    for i, v in enumerate(u0_values):
        bad = ~np.isfinite(v)
        if bad.any():
            k = int(np.flatnonzero(bad)[0])
            raise ProblemDataError(f"{cls}.u0[{i}] is not finite at ({coords[k, 0]:.4g}, {coords[k, 1]:.4g}): {v[k]}")
    d = u0_values[0] - u0_values[1]
    scale = tol * max(1.0, float(np.max(np.abs(d), initial=0.0)))
    if (d < -scale).any():
        k = int(np.argmin(d))
        raise ProblemDataError(f"{cls}.u0: u1^0 < u2^0 (the initial data violate u1 - u2 >= 0); at "
                               f"({coords[k, 0]:.4g}, {coords[k, 1]:.4g}) the difference is {d[k]:.3e}")
    for t, values in boundary_later:
        for name, a, b in zip(problem.stationary.dirichlet_names, boundary_at_0, values):
            if len(a) and np.max(np.abs(a - b)) > 1e-12 * max(1.0, float(np.max(np.abs(a)))):
                raise ProblemDataError(f"{cls}.stationary.{name} depends on the time parameter (g(0) and g({t:.4g}) "
                                       f"differ by {np.max(np.abs(a - b)):.3e}): time-dependent Dirichlet data are not "
                                       f"supported")
