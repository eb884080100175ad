"""Disk test of [JSC20] (Ben Belgacem-Bernardi-Blouza-Vohralik 2012): contact on the disk r <= 1/sqrt(2).

Unit disk, mu1 = mu2 = 1, g = 0.05, g1 = g, g2 = 0; rho = 1/sqrt(2), c = sqrt(2)/(sqrt(2) - 1).
u1 = g(2r^2 - 1); u2 = u1 for r <= rho, g(1 - r)(2r^2 - 1)c for r >= rho; lam = 2g for r <= rho.
Newton-min from X0 = [g, 0, 0] as in [JSC20] (cold start).
"""
from math import sqrt as msqrt

from ngsolve import IfPos, sqrt, x, y

from ngcontact import ExactSolution, TwoMembraneProblem, UnitDisk

g = 0.05
rho = 1 / msqrt(2)
c = msqrt(2) / (msqrt(2) - 1)
r2 = x**2 + y**2
r = sqrt(r2)
u1 = g * (2 * r2 - 1)
u2 = IfPos(rho**2 - r2, g * (2 * r2 - 1), g * (1 - r) * (2 * r2 - 1) * c)

problem = TwoMembraneProblem(
    domain=UnitDisk(maxh=0.15),
    f1=IfPos(rho**2 - r2, -10 * g, -8 * g),
    f2=IfPos(rho**2 - r2, -6 * g, -g * (1 + 8 * r - 18 * r2) * c / r),
    g1=g, g2=0.0, mu1=1.0, mu2=1.0,
    exact=ExactSolution(u1=u1, u2=u2, lam=IfPos(rho**2 - r2, 2 * g, 0)),
    name="disk",
)
INITIAL_GUESS = (g, 0.0)
DEFAULTS = dict(order=1, levels=4)
TEST_OPTIONS = dict(levels=2)
