"""Parabolic disk test 6.1 of [CMAME20]: the stationary [JSC20] disk data for all times, X0 = [g, 0, 0], T = 0.3.

Unit disk, mu1 = mu2 = 1, g = 0.05 (u1 = g, u2 = 0 on the boundary); f1, f2 of the ``disk`` scene
(constant in t).  [CMAME20]: contact starts before t = 0.17; the radial equation of u1 - u2 gives
t* = 0.172 (``ngcontact.studies.parabolic.disk_onset_radial``, results/parabolic/REPORT.md); the
solution tends to the stationary [JSC20] solution (its ``exact``: the summary's ``dist_stationary_T`` is the energy distance at T).
Mesh fitted to the stationary free boundary r = 1/sqrt(2) (``disk_fitted``); ``FITTED = False`` in a
copy of this file gives the unfitted disk meshes of ``disk``.
"""
from ngcontact.problems import ParabolicProblem
from ngcontact.scenes import load_scene

FITTED = True
stationary = load_scene("disk_fitted" if FITTED else "disk").problem
g = 0.05

problem = ParabolicProblem(stationary, u0=(g, 0.0), t_final=0.3, name="parabolic_disk")
DEFAULTS = dict(order=1, dt=1e-3, level=1)
TEST_OPTIONS = dict(dt=2e-2, t_final=0.3, level=0)
REGIONS = {"disk": (0.0, 1 / 2 ** 0.5)}
SPACE_AXIS = "r"
