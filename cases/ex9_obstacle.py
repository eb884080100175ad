"""Obstacle problem of PETSc SNES ex9: hemisphere obstacle on (-2,2)^2, exact solution known.

-Lap u = 0 off the contact set, u >= psi, psi = sqrt(1 - r^2) for r <= 1, -1 otherwise;
u = psi for r <= a, u = -A log r + B for r > a, a = 0.697965148223374, A = a^2/sqrt(1 - a^2),
B = A log 2; g = exact solution.  P1 on N x N squares cut by one diagonal, N = 16 * 2^level.
PETSc max-norm errors: 9.340e-5 (N=256), 1.918e-5 (512), 6.59e-6 (1024).
"""
from math import log as mlog
from math import sqrt as msqrt

from ngsolve import IfPos, log, sqrt, x, y

from ngcontact import ExactSolution, ObstacleProblem, StructuredSquare

a = 0.697965148223374
A = a**2 / msqrt(1 - a**2)
B = A * mlog(2.0)
r2 = x**2 + y**2
psi = IfPos(1 - r2, sqrt(IfPos(1 - r2, 1 - r2, 0)), -1)
u_out = -A * log(sqrt(r2)) + B
u = IfPos(r2 - a**2, u_out, sqrt(IfPos(1 - r2, 1 - r2, 0)))

problem = ObstacleProblem(
    domain=StructuredSquare(n0=16, xmin=-2, xmax=2, ymin=-2, ymax=2),
    psi=psi, f=0.0, g=u_out, mu=1.0,
    exact=ExactSolution(u1=u),
    name="ex9_obstacle",
)
DEFAULTS = dict(order=1, levels=5)
TEST_OPTIONS = dict(levels=3)
