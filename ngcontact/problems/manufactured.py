"""Manufactured problems with known solutions for the stability checks, and the scaling of a problem's data.

:func:`disk_contact` is a family of two-membrane problems (test 1 of [CAMWA21] is one member) with
arbitrary tensions and an arbitrary contact disk; :func:`scale_problem` multiplies the data of any
problem by a data factor and a tension factor, with the exact solution following.

The family, with r = |x - c| and a contact disk r < R:

    Q = (r^2 - R^2)^N for r > R, 0 otherwise          (the gap profile, C^{N-1})
    u1 = base + a1 Q,   u2 = base - a2 Q              (gap u1 - u2 = (a1 + a2) Q >= 0)
    lam = A (R^2 - r^2)^M for r < R, 0 otherwise     (lam > 0 on the contact disk, = 0 off it)
    f1 = -mu1 Lap u1 - lam,   f2 = -mu2 Lap u2 + lam, g_a = u_a on the boundary,

with base = b (x^2 + y) (Lap base = 2 b) and -Lap Q = -4 N (r^2 - R^2)^(N-2) (N r^2 - R^2) for r > R
(Lap of a radial function (r^2 - R^2)^N: 4 N (r^2 - R^2)^(N-1) + 4 N (N - 1) r^2 (r^2 - R^2)^(N-2)).
Complementarity holds exactly: the gap vanishes where lam > 0 and lam vanishes where the gap is positive.
tests/test_stability.py checks the PDE residual of the data numerically.
"""
from __future__ import annotations

from dataclasses import replace

from ngsolve import IfPos, x, y

from .base import ExactSolution
from .membranes import TwoMembraneProblem

__all__ = ["disk_contact", "scale_problem"]


def disk_contact(mu1: float = 1.0, mu2: float = 1.0, *, centre=(0.5, 0.5), R: float = 1 / 3, N: int = 6,
                 M: int = 3, A: float = 1000.0, a1: float = 1.0, a2: float = 1.0, b: float = 0.0, lam_r3: bool = True,
                 domain=None, name: str = "disk-contact") -> TwoMembraneProblem:
    """A two-membrane problem of the family in the module doc (defaults: test 1 of [CAMWA21], whose lam
    carries an extra factor r^3: ``lam_r3``).  ``domain``: default the criss-cross unit square T0 = 4 x 4."""
    from ..domains import CrissCrossSquare

    cx, cy = centre
    r2 = (x - cx) ** 2 + (y - cy) ** 2
    Q = IfPos(r2 - R**2, (r2 - R**2) ** N, 0)
    mlapQ = IfPos(r2 - R**2, -4 * N * (r2 - R**2) ** (N - 2) * (N * r2 - R**2), 0)
    lam = A * (R**2 - r2) ** M * (r2 * r2 ** 0.5 if lam_r3 else 1.0)
    lam = IfPos(R**2 - r2, lam, 0)
    base = b * (x * x + y)
    u1, u2 = base + a1 * Q, base - a2 * Q
    f1 = mu1 * (-2 * b + a1 * mlapQ) - lam
    f2 = mu2 * (-2 * b - a2 * mlapQ) + lam
    return TwoMembraneProblem(domain=domain if domain is not None else CrissCrossSquare(n0=4),
                              f1=f1, f2=f2, g1=u1, g2=u2, mu1=mu1, mu2=mu2,
                              exact=ExactSolution(u1=u1, u2=u2, lam=lam), name=name)


def scale_problem(problem, data: float = 1.0, tension: float = 1.0):
    """The problem with u scaled by ``data`` and the tensions by ``tension``: loads and the multiplier times
    data * tension, Dirichlet data and obstacle times data; the exact solution follows.  Solutions scale
    exactly (u by data, lam by data * tension), so every computed ratio (rates, I_eff, relative errors)
    must stay the same."""
    ft = data * tension
    changes = {n: getattr(problem, n) * ft for n in problem.load_names}
    changes.update({n: getattr(problem, n) * data for n in problem.dirichlet_names})
    if "psi" in [f for f in problem.__dataclass_fields__]:
        changes["psi"] = problem.psi * data
    for n in ("mu1", "mu2", "mu"):
        if n in problem.__dataclass_fields__:
            changes[n] = getattr(problem, n) * tension
    ex = problem.exact
    if ex is not None:
        changes["exact"] = ExactSolution(
            u1=ex.u1 * data, u2=None if ex.u2 is None else ex.u2 * data,
            lam=None if ex.lam is None else ex.lam * ft,
            grad_u1=None if ex.grad_u1 is None else ex.grad_u1 * data,
            grad_u2=None if ex.grad_u2 is None else ex.grad_u2 * data)
    return replace(problem, **changes)
