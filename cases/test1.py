"""Test 1 of [CAMWA21]: smooth solution, degenerate contact on the disk r < 1/3 (criss-cross meshes T0..T4).

u1 = -u2 = (r^2 - R^2)^N for r >= R, 0 otherwise; lam = 1000 r^3 (R^2 - r^2)^3 for r < R;
r = |x - (0.5, 0.5)|, R = 1/3, N = 6, mu1 = mu2 = 1, g_a = u_a on the boundary.
Published: energy-error order p for p = 1, 2, 3 (FEM and HHO), ~1 for p = 4.
"""
from ngsolve import IfPos, x, y

from ngcontact import CrissCrossSquare, ExactSolution, TwoMembraneProblem

R, N = 1 / 3, 6
r2 = (x - 0.5) ** 2 + (y - 0.5) ** 2
r3 = r2 * r2 ** 0.5
u1 = IfPos(r2 - R**2, (r2 - R**2) ** N, 0)
lam = IfPos(R**2 - r2, 1000 * r3 * (R**2 - r2) ** 3, 0)
f1 = IfPos(r2 - R**2, -4 * N * (r2 - R**2) ** (N - 2) * (N * r2 - R**2), -1000 * r3 * (R**2 - r2) ** 3)

problem = TwoMembraneProblem(
    domain=CrissCrossSquare(n0=4),
    f1=f1, f2=-f1, g1=u1, g2=-u1, mu1=1.0, mu2=1.0,
    exact=ExactSolution(u1=u1, u2=-u1, lam=lam),
    name="test1",
)
DEFAULTS = dict(order=1, levels=5)
TEST_OPTIONS = dict(levels=3)
