"""Obstacle problem whose contact set {x <= 1/2} touches the Dirichlet boundary (x = 0, y = 0, y = 1).

psi = sin(pi x) sin(pi y), u = psi + 16 (x - 1/2)_+^4 y (1 - y), lam = 4 (1/2 - x)_+^2 (1 + x/2 + y/4)
(lam > 0 on the boundary of the contact set except at the free boundary x = 1/2, where it vanishes like the
distance squared);
-Lap u - lam = f: f = 2 pi^2 psi - lam for x < 1/2,
f = 2 pi^2 psi - 16 [12 (x - 1/2)^2 y (1 - y) - 2 (x - 1/2)^4] for x > 1/2; mu = 1, g = u (= y (1 - y) on
x = 1, 0 elsewhere).  The free boundary x = 1/2 is a line of every criss-cross mesh.
Estimator at p >= 2: results/stability/BOUNDARY_CONTACT.md.
"""
from math import pi

from ngsolve import IfPos, sin, x, y

from ngcontact import CrissCrossSquare, ExactSolution, ObstacleProblem

psi = sin(pi * x) * sin(pi * y)
s = IfPos(x - 0.5, x - 0.5, 0.0)
c = IfPos(0.5 - x, 0.5 - x, 0.0)
u = psi + 16 * s**4 * y * (1 - y)
lam = 4 * c**2 * (1 + x / 2 + y / 4)
f = 2 * pi**2 * psi - lam - 16 * (12 * s**2 * y * (1 - y) - 2 * s**4)

problem = ObstacleProblem(
    domain=CrissCrossSquare(n0=4),
    psi=psi, f=f, g=16 * s**4 * y * (1 - y), mu=1.0,
    exact=ExactSolution(u1=u, lam=lam),
    name="obstacle_boundary",
)
DEFAULTS = dict(order=2, levels=4)
TEST_OPTIONS = dict(levels=2)
