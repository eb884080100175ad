"""Disk test of [JSC20] on meshes fitted to the free boundary r = 1/sqrt(2).

Same data and exact solution as the ``disk`` scene (unit disk, mu1 = mu2 = 1,
g = 0.05; f1, f2 and lam jump across r = rho = 1/sqrt(2), which is also the
exact contact boundary), but the coarse mesh has a curved internal line on
r = rho (``UnitDisk(interface_radius=rho)``), so the data are smooth on every
element.  On the unfitted ``disk`` meshes the jump cuts elements and the P2
error and estimator are both limited to about O(h^1.5).
"""
from dataclasses import replace
from math import sqrt as msqrt

from ngsolve import CoefficientFunction, sqrt, x, y

from ngcontact import UnitDisk
from ngcontact.scenes import load_scene

disk = load_scene("disk")
g = 0.05
c = msqrt(2) / (msqrt(2) - 1)
r = sqrt(x**2 + y**2)

problem = replace(
    disk.problem,
    domain=UnitDisk(maxh=0.15, interface_radius=1 / msqrt(2)),
    # per subdomain (inner r < rho, outer), not IfPos(r - rho) as in ``disk``: the curved elements along
    # the interface approximate the circle, and IfPos would flip at quadrature points just across it
    f1=CoefficientFunction([-10 * g, -8 * g]),
    f2=CoefficientFunction([-6 * g, -g * (1 + 8 * r - 18 * r**2) * c / r]),
    name="disk_fitted",
)
INITIAL_GUESS = disk.initial_guess
DEFAULTS = dict(order=1, levels=4)
TEST_OPTIONS = dict(levels=2)
