"""Water-hydrogen two-phase flow, gas appearance and disappearance (MoMaS 1D benchmark, [CG20]).

Hydrogen produced in a deep nuclear-waste repository:

L = 200 m; 5.57e-6 kg/m^2/year of H2 injected at x = 0 for 5e5 years, then none; x = L: S = 1,
P = 1e6 Pa, chi = 0; initially S = 1, P = 1e6 Pa, chi = 0.  Every parameter: TwoPhaseParams
(defaults; mu_g = 9e-6 Pa s, T = 303 K, chi = 0 at x = L).  Reference values at x = 0
(five codes of the MoMaS comparison): gas appears at 1.27e4-1.52e4 years, P peaks at
1.1414-1.1656 MPa near 1e5 years, P_g at 1.368-1.470 MPa near 1.5e5 years, gas gone by
6.72e5-6.85e5 years.
"""
from ngcontact.twophase import TwoPhaseParams

problem = TwoPhaseParams()
DEFAULTS = dict(cells=1000, dt_years=5000.0, t_final_years=1e6)
TEST_OPTIONS = dict(cells=100, dt_years=5000.0, t_final_years=3e4)
