"""Test 2 of [CAMWA21] on meshes fitted to the contact boundary r = R = 1/3.

Same data and exact solution as the ``test2`` scene (unit square, lam = 8 R^2 for r <= R and 0
outside, f1 and f2 jump across r = R), but the coarse mesh has a curved internal line on the circle
r = R (netgen geometry with two subdomains), so the data are smooth on every element.  On the
criss-cross meshes of ``test2`` the jump cuts elements: the P2 error and the data oscillation part
of the estimator are then both O(h^1.5) and I_eff stays at 1.9-2.9 (results/estimators/TABLES.md).
"""
from dataclasses import replace

from netgen.geom2d import SplineGeometry
from ngsolve import CoefficientFunction, x, y

from ngcontact import GeometryDomain
from ngcontact.domains import INTERFACE
from ngcontact.scenes import load_scene

test2 = load_scene("test2")
R = 1 / 3
r2 = (x - 0.5) ** 2 + (y - 0.5) ** 2

geo = SplineGeometry()
geo.AddRectangle((0, 0), (1, 1), bc="boundary", leftdomain=2, rightdomain=0)
geo.AddCircle((0.5, 0.5), R, bc=INTERFACE, leftdomain=1, rightdomain=2)
geo.SetMaterial(1, "inner")
geo.SetMaterial(2, "outer")

problem = replace(
    test2.problem,
    domain=GeometryDomain(geometry=geo, maxh=0.2, label="unit square, mesh fitted to r = 1/3", curved=True),
    # per subdomain (inner r < R, outer), not IfPos(R^2 - r2) as in ``test2``: the curved elements along
    # the interface approximate the circle, and IfPos would flip at quadrature points just across it
    f1=CoefficientFunction([-8 * R**2, 8 * R**2 - 16 * r2]),
    f2=CoefficientFunction([8 * R**2, 0.0]),
    name="test2_fitted",
)
DEFAULTS = dict(order=1, levels=4)
TEST_OPTIONS = dict(levels=2)
