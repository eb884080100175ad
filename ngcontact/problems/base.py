"""What every contact problem declares, exact solutions and the checks of problem data.

Two problems share one algebra (:mod:`.membranes`, :mod:`.obstacle`)::

    -mu_a Lap u_a - s_a lam = f_a  in Omega,  u_a = g_a on the boundary  (a = 1..nfields),
    gap >= 0,  lam >= 0,  gap lam = 0,

with ``gap = u1 - u2`` and signs (s_1, s_2) = (+1, -1) for two membranes, and
``gap = u - psi``, s = +1 for one membrane above an obstacle psi.  A
discretization reads only the attributes documented in :class:`Problem`.

Data are NGSolve CoefficientFunctions (numbers are converted), so expressions
in ``x``, ``y`` with ``IfPos``, ``sqrt``, ... work.  Problems are frozen and
validated on construction; checks that need points of the domain (finite
data; the boundary order g1 >= g2, respectively g >= psi) run once a
discretization has its points, through :func:`check_data_on_points`.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Dict, Optional, Protocol, Sequence, Tuple

import numpy as np
from ngsolve import CoefficientFunction

from ..domains import as_domain

__all__ = ["ProblemDataError", "ExactSolution", "Problem", "ContactProblem", "BoundaryOrder",
           "check_data_on_points", "data_fields"]


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
    given explicitly as 2-vectors ``grad_u1``, ``grad_u2``.  ``singular_points``: the points (x, y) where the
    gradient is singular (the L-shape's re-entrant corner); the energy error is then integrated with a rule
    graded towards them (:mod:`ngcontact.discretizations.graded`; a fixed-order rule underestimates it; FEM and
    dG errors, HHO's keep their fixed rule).
    """

    u1: CoefficientFunction
    u2: Optional[CoefficientFunction] = None
    lam: Optional[CoefficientFunction] = None
    grad_u1: Optional[CoefficientFunction] = None
    grad_u2: Optional[CoefficientFunction] = None
    singular_points: tuple = ()

    def __post_init__(self):
        _convert_cfs(self, ["u1", "u2", "lam"])
        try:
            given = tuple(self.singular_points)
            pts = tuple((float(p[0]), float(p[1])) for p in given if len(p) == 2)
        except (TypeError, ValueError):
            given, pts = (), None
        if pts is None or len(pts) != len(given):
            raise ValueError(f"singular_points must be a sequence of points (x, y), got {self.singular_points!r}")
        object.__setattr__(self, "singular_points", pts)

    def gradient(self, alpha: int) -> CoefficientFunction:
        """Gradient of u_alpha (alpha = 1 or 2)."""
        from ngsolve import x, y

        given = self.grad_u1 if alpha == 1 else self.grad_u2
        if given is not None:
            return given
        u = self.u1 if alpha == 1 else self.u2
        return CoefficientFunction((u.Diff(x), u.Diff(y)))


@dataclass(frozen=True)
class BoundaryOrder:
    """The data pair that must satisfy ``upper >= lower`` on the boundary, else the admissible set
    is empty; ``message`` says so in the error."""

    upper: str
    lower: str
    message: str


class Problem(Protocol):
    """The problem interface the discretizations and estimators read.

    Attributes
    ----------
    domain : ngcontact.domains.Domain
        where the problem lives (gives the meshes).
    exact : ExactSolution or None
    name : str
        label used in outputs.
    nfields : int
        number of unknown fields (2 membranes, 1 obstacle).
    field_names : tuple of str
        ``("u1", "u2")`` or ``("u",)``: names of the solution fields in outputs.
    mus, loads, dirichlet : tuples, one entry per field
        tensions mu_a > 0, loads f_a and Dirichlet data g_a (CoefficientFunctions).
    signs : tuple of int
        s_a in -mu_a Lap u_a - s_a lam = f_a.
    obstacle : CoefficientFunction or None
        psi of the constraint u - psi >= 0; None for u1 - u2 >= 0.
    dirichlet_names : tuple of str
        names of the Dirichlet data (they need to be finite on the boundary only).
    boundary_order : BoundaryOrder
        the pair checked on the boundary: (g1, g2) or (g, psi).
    """

    domain: object
    exact: Optional[ExactSolution]
    name: str
    nfields: int
    field_names: Tuple[str, ...]
    mus: Tuple[float, ...]
    loads: Tuple[CoefficientFunction, ...]
    dirichlet: Tuple[CoefficientFunction, ...]
    signs: Tuple[int, ...]
    obstacle: Optional[CoefficientFunction]
    dirichlet_names: Tuple[str, ...]
    boundary_order: BoundaryOrder
    stiffness_scale: float

    def data(self) -> Dict[str, CoefficientFunction]:
        """Every datum by name: loads, Dirichlet data, obstacle (the fields :func:`check_data_on_points` checks)."""

    def gap(self, fields: Sequence) -> CoefficientFunction:
        """The constrained quantity (u1 - u2, or u - psi) of the given field values."""


class ContactProblem:
    """Shared implementation of :class:`Problem` for the dataclasses of :mod:`.membranes` and :mod:`.obstacle`.

    A subclass declares ``field_names``, ``load_names``, ``dirichlet_names``, ``signs``,
    ``boundary_order`` and defines ``mus``
    and ``obstacle``.
    """

    field_names: Tuple[str, ...] = ()
    load_names: Tuple[str, ...] = ()
    dirichlet_names: Tuple[str, ...] = ()
    signs: Tuple[int, ...] = ()
    boundary_order: BoundaryOrder
    obstacle: Optional[CoefficientFunction] = None

    @property
    def nfields(self) -> int:
        return len(self.field_names)

    @property
    def stiffness_scale(self) -> float:
        """Harmonic mean of the tensions: the stiffness with which the gap u1 - u2 (or u - psi) answers a
        contact force; the algebraic system weighs the gap by it in the C-function
        (:attr:`~ngcontact.algebra.system.ComplementaritySystem.constraint_weight`)."""
        mus = [float(m) for m in self.mus]
        return len(mus) / sum(1.0 / m for m in mus)

    @property
    def loads(self) -> tuple:
        return tuple(getattr(self, n) for n in self.load_names)

    @property
    def dirichlet(self) -> tuple:
        return tuple(getattr(self, n) for n in self.dirichlet_names)

    def data(self) -> Dict[str, CoefficientFunction]:
        """Every datum by name: loads, Dirichlet data, then the obstacle psi if any."""
        out = {n: getattr(self, n) for n in self.load_names + self.dirichlet_names}
        if self.obstacle is not None:
            out["psi"] = self.obstacle
        return out

    def gap(self, fields: Sequence) -> CoefficientFunction:
        """u1 - u2 (two membranes) or u - psi (obstacle) of the given field values."""
        return fields[0] - (fields[1] if self.obstacle is None else self.obstacle)

    def _validate(self, tensions: Sequence[str], cfs: Sequence[str]) -> None:
        """Checks of ``__post_init__``: positive tensions, data converted to CFs, a domain, the exact solution's type."""
        cls = type(self).__name__
        for name in tensions:
            object.__setattr__(self, name, _positive(getattr(self, name), f"{cls}.{name}"))
        _convert_cfs(self, cfs)
        try:  # a domain, or a user's ngsolve / netgen mesh (refined uniformly for the levels)
            object.__setattr__(self, "domain", as_domain(self.domain))
        except TypeError:
            raise ProblemDataError(f"{cls}.domain must be an ngcontact domain (e.g. CrissCrossSquare()) or an "
                                   f"ngsolve.Mesh, got {type(self.domain).__name__}") from None
        if self.exact is not None and not isinstance(self.exact, ExactSolution):
            raise ProblemDataError(f"{cls}.exact must be an ExactSolution, got {type(self.exact).__name__}")


def check_data_on_points(problem, values: dict, boundary: np.ndarray, coords: np.ndarray, tol: float = 1e-12) -> None:
    """Checks that need the domain: finite data, ``problem.boundary_order`` (g1 >= g2 / psi <= g) on the boundary.

    Parameters
    ----------
    problem : Problem
    values : dict name -> ndarray
        data evaluated at the points (names as in ``problem.data()``).
    boundary : bool ndarray
        which points lie on the Dirichlet boundary.
    coords : ndarray (n, 2)
        the points, for the error message.
    """
    cls = type(problem).__name__
    for name, val in values.items():
        # Dirichlet data only matter on the boundary (e.g. -A log r is -inf at r = 0)
        where = boundary if name in problem.dirichlet_names else np.ones(len(val), dtype=bool)
        bad = where & ~np.isfinite(val)
        if bad.any():
            i = int(np.flatnonzero(bad)[0])
            raise ProblemDataError(
                f"{cls}.{name} is not finite at ({coords[i, 0]:.4g}, {coords[i, 1]:.4g}): {val[i]}"
            )
    check_magnitudes(problem, values, boundary, coords)
    order = problem.boundary_order
    gap = values[order.upper] - values[order.lower]
    # relative to the data's own size over the domain (units of u): on the boundary alone both may be round-off
    # (psi = 0.1 sin(pi x) sin(pi y) with g = 0 is -1.2e-17 there: sin(pi) rounds to 1.2e-16); finite values only
    # (Dirichlet data may be infinite inside, e.g. -log r)
    size = max(float(np.max(np.abs(v[np.isfinite(v)]), initial=0.0))
               for v in (values[order.upper], values[order.lower])) if boundary.any() else 0.0
    bad = boundary & (gap < -tol * size)
    if bad.any():
        i = int(np.flatnonzero(bad)[np.argmin(gap[bad])])
        raise ProblemDataError(
            f"{cls}: {order.message}; at ({coords[i, 0]:.4g}, {coords[i, 1]:.4g}) the difference is {gap[i]:.3e}"
        )


#: magnitudes of the data (in units of u: loads divided by the smallest tension) and of the tensions that the
#: package computes with: squares of errors and estimators stay in floating-point range
MAGNITUDE_RANGE = (1e-100, 1e100)


def check_magnitudes(problem, values: dict, boundary: np.ndarray, coords: np.ndarray) -> None:
    """Refuse data whose size is outside :data:`MAGNITUDE_RANGE` (a named error, never silently
    underflowing errors and estimators): the tensions, and each datum where it matters (loads divided by
    the smallest tension, so in units of u).  The problem is linear in (f, g, psi): scaled data give the
    scaled solution, so such a problem is solved by scaling it into the range."""
    lo, hi = MAGNITUDE_RANGE
    cls = type(problem).__name__
    mus = [float(m) for m in problem.mus]
    for i, mu in enumerate(mus):
        if not lo <= mu <= hi:
            names = ("mu",) if len(mus) == 1 else ("mu1", "mu2")
            raise ProblemDataError(f"{cls}.{names[i]} = {mu:.3e} is outside [{lo:g}, {hi:g}]: rescale the problem "
                                   f"(u solves the same problem with mu, f divided by the same factor)")
    for name, val in values.items():
        where = boundary if name in problem.dirichlet_names else np.ones(len(val), dtype=bool)
        a = np.abs(val[where])
        if not len(a):
            continue
        i = int(np.argmax(a))
        size = float(a[i]) / (min(mus) if name in problem.load_names else 1.0)
        if size != 0.0 and not lo <= size <= hi:
            j = int(np.flatnonzero(where)[i])
            unit = " / min(mu)" if name in problem.load_names else ""
            raise ProblemDataError(
                f"{cls}.{name}: max |{name}|{unit} = {size:.3e} (at ({coords[j, 0]:.4g}, {coords[j, 1]:.4g})) is "
                f"outside [{lo:g}, {hi:g}]: divide f, g and psi by a common factor s and multiply the solution by s "
                f"(the problem is linear in its data)")


def data_fields(problem) -> dict:
    """Name -> CoefficientFunction of every datum (``problem.data()``), for evaluation and checks."""
    return problem.data()
