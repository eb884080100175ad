"""Test 2 of [CAMWA21]: lam discontinuous across the contact boundary r = 1/3 (criss-cross meshes T0..T4).

u1 = (r^2 - R^2)^2 for r > R, 0 otherwise; u2 = 0; lam = 8 R^2 for r <= R, 0 otherwise
(the talk prints lam = 1; 8 R^2 is the value consistent with the PDE, see REFERENCE.md).
f1 = -8R^2 (r <= R), 8R^2 - 16 r^2 (r > R); f2 = 8R^2 (r <= R), 0 (r > R); mu1 = mu2 = 1.
Published orders: ~1 (p=1), ~1.5 (p=2,3), ~1 (p=4).
"""
from ngsolve import IfPos, x, y

from ngcontact import CrissCrossSquare, ExactSolution, TwoMembraneProblem

R = 1 / 3
r2 = (x - 0.5) ** 2 + (y - 0.5) ** 2
u1 = IfPos(r2 - R**2, (r2 - R**2) ** 2, 0)
lam = IfPos(R**2 - r2, 8 * R**2, 0)

problem = TwoMembraneProblem(
    domain=CrissCrossSquare(n0=4),
    f1=IfPos(R**2 - r2, -8 * R**2, 8 * R**2 - 16 * r2),
    f2=IfPos(R**2 - r2, 8 * R**2, 0),
    g1=u1, g2=0.0, mu1=1.0, mu2=1.0,
    exact=ExactSolution(u1=u1, u2=0.0, lam=lam),
    name="test2",
)
DEFAULTS = dict(order=1, levels=5)
TEST_OPTIONS = dict(levels=3)
