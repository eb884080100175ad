"""Concentrated load: a narrow Gaussian force pushes membrane 1 onto membrane 2 in a small contact zone (no exact solution).

Unit square (criss-cross T0 = 4 x 4), mu1 = mu2 = 1; membrane 1 clamped at g1 = 0.02 above membrane 2 (g2 = 0);
f1 = -A exp(-|x - x0|^2 / (2 eps^2)), x0 = (0.35, 0.6), eps = 0.02, A = 60; f2 = 0.
The load (total A 2 pi eps^2 ~ 0.15) deflects membrane 1 by more than the gap 0.02 only near x0, so the
contact set is a small disk around x0 whose size is not known in closed form; u2 is then pushed down as well.
No exact solution: runs report the estimator eta only.
"""
from ngsolve import exp, x, y

from ngcontact import CrissCrossSquare, TwoMembraneProblem

A, EPS, X0, Y0 = 60.0, 0.02, 0.35, 0.6

problem = TwoMembraneProblem(
    domain=CrissCrossSquare(n0=4),
    f1=-A * exp(-((x - X0) ** 2 + (y - Y0) ** 2) / (2 * EPS**2)), f2=0.0,
    g1=0.02, g2=0.0, mu1=1.0, mu2=1.0,
    name="point_load",
)
DEFAULTS = dict(order=1, levels=4)
TEST_OPTIONS = dict(levels=2)
