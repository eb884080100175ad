"""Parabolic rings test 6.2 of [CMAME20]: piecewise constant radial loads on five rings, X0 = [g, 0, 0], T = 0.3.

Unit disk, mu1 = mu2 = 1, g = 0.05, u1 = g, u2 = 0 on the boundary; on the rings [0,1/5], [1/5,2/5],
[2/5,3/5], [3/5,4/5], [4/5,1]: f1 = -20g, -50g, +50g, -50g, +50g and f2 = +90g, -40g, +70g, -30g, +40g.
[CMAME20]: contact appears at t ~ 0.011 on r <= 1/5 and at t ~ 0.060 on the ring 2/5 <= r <= 3/5
(dt = 1e-3).  The default mesh (maxh = 0.02) has ~19k triangles, the size of [CMAME20]'s P1 runs.
"""
from ngsolve import IfPos, x, y

from ngcontact import TwoMembraneProblem, UnitDisk
from ngcontact.problems import ParabolicProblem

g = 0.05
r2 = x**2 + y**2


def rings(values):
    """The piecewise constant radial function with ``values`` on [0,1/5], ..., [4/5,1]."""
    out = values[-1]
    for k in range(len(values) - 2, -1, -1):
        out = IfPos(((k + 1) / 5) ** 2 - r2, values[k], out)
    return out


stationary = TwoMembraneProblem(
    domain=UnitDisk(maxh=0.02),
    f1=rings([-20 * g, -50 * g, 50 * g, -50 * g, 50 * g]),
    f2=rings([90 * g, -40 * g, 70 * g, -30 * g, 40 * g]),
    g1=g, g2=0.0, mu1=1.0, mu2=1.0, name="rings",
)
problem = ParabolicProblem(stationary, u0=(g, 0.0), t_final=0.3, name="parabolic_rings")
DEFAULTS = dict(order=1, dt=1e-3, level=0)
TEST_OPTIONS = dict(dt=1e-2, t_final=0.08, maxh=0.15)
REGIONS = {"disk": (0.0, 0.2), "ring": (0.4, 0.6)}
SPACE_AXIS = "r"
