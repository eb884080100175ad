"""Manufactured parabolic two-membrane solution with a moving free boundary x = a(t) = 0.2 + 0.5 t (unit square).

mu1 = mu2 = 1, g1 = g2 = 0, T = 0.5.  With s = u1 + u2 and w = u1 - u2:

    s   = sin(pi x) sin(pi y)                              (no contact: d_t s - Lap s = f1 + f2),
    w   = c (x - a)_+^3 (1 - x) y (1 - y) >= 0,              contact set {x <= a(t)},
    lam = k (a - x)_+ y (1 - y) >= 0,                        lam w = 0,
    f1 - f2 = d_t w - Lap w - 2 lam,   f1 + f2 = d_t s - Lap s,

u1 = (s + w)/2, u2 = (s - w)/2.  w is C^2 in space (third derivative jumps at the free boundary),
lam and f are continuous, so the P1 and P2 energy errors can reach O(h) and O(h^2) and the
backward Euler error O(dt).  f is derived from u by NGSolve's symbolic ``Diff`` (in x, y and the
time parameter); tests/test_parabolic.py checks the PDE residual and the complementarity with
finite differences at sample points.
"""
from math import pi

from ngsolve import IfPos, Parameter, sin, x, y

from ngcontact import CrissCrossSquare, ExactSolution, TwoMembraneProblem
from ngcontact.problems import ParabolicProblem

t = Parameter(0.0)
c, k = 10.0, 1.0
a = 0.2 + 0.5 * t
z = x - a
s = sin(pi * x) * sin(pi * y)
w = c * IfPos(z, z**3, 0.0) * (1 - x) * y * (1 - y)
lam = k * IfPos(z, 0.0, -z) * y * (1 - y)


def heat(u):
    """d_t u - Lap u (symbolic derivatives)."""
    return u.Diff(t) - u.Diff(x).Diff(x) - u.Diff(y).Diff(y)


u1, u2 = (s + w) / 2, (s - w) / 2
stationary = TwoMembraneProblem(domain=CrissCrossSquare(n0=4), f1=heat(u1) - lam, f2=heat(u2) + lam,
                                g1=0.0, g2=0.0, name="manufactured")
problem = ParabolicProblem(stationary, u0=(u1, u2), t_final=0.5, time=t,
                           exact=ExactSolution(u1=u1, u2=u2, lam=lam), name="parabolic_manufactured")
DEFAULTS = dict(order=1, dt=0.01, level=2)
TEST_OPTIONS = dict(dt=0.05, t_final=0.2, level=0)
SPACE_AXIS = "x"
