"""Full contact up to the Dirichlet boundary: u1 = u2 = S / (2 pi^2), S = sin(pi x) sin(pi y), lam = 1 + x/2 + y/4 > 0
on the closed square.

-mu_a Lap u_a - s_a lam = f_a with s_1 = +1, s_2 = -1, -Lap u = S:
f1 = mu1 S - lam, f2 = mu2 S + lam; g1 = g2 = 0; mu1 = 1, mu2 = 2 (criss-cross meshes T0..T4).
The contact set is the whole square, so lam > 0 on every boundary patch (estimator at p >= 2:
results/stability/BOUNDARY_CONTACT.md).
"""
from math import pi

from ngsolve import sin, x, y

from ngcontact import CrissCrossSquare, ExactSolution, TwoMembraneProblem

MU1, MU2 = 1.0, 2.0
S = sin(pi * x) * sin(pi * y)
u = S / (2 * pi**2)
lam = 1 + x / 2 + y / 4

problem = TwoMembraneProblem(
    domain=CrissCrossSquare(n0=4),
    f1=MU1 * S - lam, f2=MU2 * S + lam,
    g1=0.0, g2=0.0, mu1=MU1, mu2=MU2,
    exact=ExactSolution(u1=u, u2=u, lam=lam),
    name="full_contact",
)
DEFAULTS = dict(order=2, levels=4)
TEST_OPTIONS = dict(levels=2)
