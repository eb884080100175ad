"""L-shaped domain: re-entrant corner singularity r^(2/3) sin(2 theta/3) plus a contact zone (free boundary r_c = R).

Omega = (-1, 1)^2 minus [0, 1] x [-1, 0], re-entrant corner at the origin; mu1 = mu2 = 1.
Exact solution (manufactured): s = r^(2/3) sin(2 theta/3), theta in [0, 3 pi/2] (harmonic, zero on
the two edges at the corner, s in H^(5/3 - eps) only), phi = kappa (r_c^2 - R^2)^3 for r_c >= R, 0 inside,
r_c = |x - c|, c = (-1/2, 1/2), R = 0.3, kappa = 0.02;
u1 = s + phi/2, u2 = s - phi/2 (so u1 - u2 = phi >= 0, contact exactly on the disk r_c <= R),
lam = 100 (R^2 - r_c^2)^2 on r_c < R, 0 outside; f1 = -Lap(phi)/2 - lam = -f2; g_a = u_a on the boundary.
Uniform refinement: energy error ~ ndof^(-1/3) for every p (corner); optimal adaptive rate ndof^(-p/2).
"""
from math import pi

from ngsolve import CoefficientFunction, IfPos, atan2, cos, sin, sqrt, x, y

from ngcontact import ExactSolution, LShape, TwoMembraneProblem

cx, cy, R, KAPPA, LAM = -0.5, 0.5, 0.3, 0.02, 100.0
r2 = x**2 + y**2
r = sqrt(r2)
# polar angle in (-pi/4, 7 pi/4]: the branch cut (angle -pi/4) lies in the removed quadrant, so that
# theta = 0 on {y = 0, x > 0} and 3 pi/2 on {x = 0, y < 0} hold exactly at boundary nodes
theta = 3 * pi / 4 + atan2(-(x + y) / sqrt(2), (y - x) / sqrt(2))
s = r2 ** (1 / 3) * sin(2 * theta / 3)
grad_s = CoefficientFunction((-2 / 3 * r2 ** (-1 / 6) * sin(theta / 3), 2 / 3 * r2 ** (-1 / 6) * cos(theta / 3)))

rc2 = (x - cx) ** 2 + (y - cy) ** 2
rho = IfPos(rc2 - R**2, rc2 - R**2, 0)  # (r_c^2 - R^2)^+
phi = KAPPA * rho**3
grad_phi = CoefficientFunction((6 * KAPPA * rho**2 * (x - cx), 6 * KAPPA * rho**2 * (y - cy)))
lap_phi = KAPPA * (12 * rho**2 + 24 * rho * rc2)
lam = IfPos(R**2 - rc2, LAM * (R**2 - rc2) ** 2, 0)
f1 = -0.5 * lap_phi - lam

problem = TwoMembraneProblem(
    domain=LShape(maxh=0.25),
    f1=f1, f2=-f1, g1=s + phi / 2, g2=s - phi / 2, mu1=1.0, mu2=1.0,
    exact=ExactSolution(u1=s + phi / 2, u2=s - phi / 2, lam=lam,
                        grad_u1=grad_s + grad_phi / 2, grad_u2=grad_s - grad_phi / 2, singular_points=((0.0, 0.0),)),
    name="lshape",
)
DEFAULTS = dict(order=1, levels=4)
TEST_OPTIONS = dict(levels=2)
