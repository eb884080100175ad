"""Disk test of [JSC20] on meshes fitted to the free boundary r = 1/sqrt(2).

Same data as ``disk`` (unit disk, mu1 = mu2 = 1, g = 0.05; f1, f2 and lam jump
across r = rho = 1/sqrt(2), which is also the exact contact boundary), but the
coarse mesh has a curved internal line on r = rho (``UnitDisk(interface_radius=rho)``),
so the data are smooth on every element and P_p, p >= 2, converge at the
optimal rate.  On the unfitted ``disk`` meshes the jump cuts elements and the
P2 error and estimator are both limited to about O(h^1.5).
"""
from math import sqrt as msqrt

from ngsolve import CoefficientFunction, IfPos, sqrt, x, y

from ngcontact import ExactSolution, TwoMembraneProblem, UnitDisk

g = 0.05
rho = 1 / msqrt(2)
c = msqrt(2) / (msqrt(2) - 1)
r2 = x**2 + y**2
r = sqrt(r2)
u1 = g * (2 * r2 - 1)
u2 = IfPos(rho**2 - r2, g * (2 * r2 - 1), g * (1 - r) * (2 * r2 - 1) * c)

problem = TwoMembraneProblem(
    domain=UnitDisk(maxh=0.15, interface_radius=rho),
    # per subdomain (inner r < rho, outer), not IfPos(r - rho): the curved elements along the interface
    # approximate the circle, and IfPos would flip at quadrature points just across it
    f1=CoefficientFunction([-10 * g, -8 * g]),
    f2=CoefficientFunction([-6 * g, -g * (1 + 8 * r - 18 * r2) * c / r]),
    g1=g, g2=0.0, mu1=1.0, mu2=1.0,
    exact=ExactSolution(u1=u1, u2=u2, lam=IfPos(rho**2 - r2, 2 * g, 0)),
    name="disk_fitted",
)
INITIAL_GUESS = (g, 0.0)
DEFAULTS = dict(order=1, levels=4)
TEST_OPTIONS = dict(levels=2)
