"""Problem data of the water-hydrogen two-phase benchmark (MoMaS / Couplex-gas 1D; [CG20], [BGJ14]).

Immutable, validated once (errors name the field and the value).  SI units throughout; times of
the scene are given in years and converted with :data:`YEAR`.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, fields

__all__ = ["TwoPhaseParams", "YEAR", "GAS_CONSTANT"]

#: seconds per year (Julian year, 365.25 d): 5.57e-6 kg/m^2/year of H2 = 8.83e-11 mol/m^2/s as the benchmark states
YEAR = 365.25 * 24 * 3600.0
#: J/(mol K)
GAS_CONSTANT = 8.314462618


@dataclass(frozen=True)
class TwoPhaseParams:
    """Parameters of the 1D water-hydrogen benchmark (defaults: the MoMaS case of /work/shared/REFERENCE.md).

    Attributes
    ----------
    length : float
        domain length L [m].
    porosity : float
        phi [-].
    permeability : float
        K [m^2].
    p_r : float
        van Genuchten pressure P_r [Pa].
    n_vg : float
        van Genuchten exponent n [-] (m = 1 - 1/n).
    s_lr, s_gr : float
        residual liquid and gas saturations [-].
    m_w, m_h : float
        molar masses of water and hydrogen [kg/mol].
    rho_w : float
        liquid water density [kg/m^3].
    diffusion : float
        molecular diffusion D of dissolved H2 [m^2/s].
    henry : float
        Henry constant H~ [mol/(Pa m^3)].
    mu_l, mu_g : float
        viscosities [Pa s] (mu_g = 9e-6: [CG20] prints 9e-9, a typo).
    temperature : float
        T [K] (ideal gas beta_g = M_h / (R T)).
    q_inject : float
        H2 mass flux injected at x = 0 [kg/m^2/year] during ``t_inject``.
    t_inject : float
        injection duration [year].
    p_right : float
        Dirichlet liquid pressure at x = L [Pa] (also the initial pressure).
    chi_right : float
        Dirichlet dissolved-H2 mole fraction at x = L [-] (also the initial value); S = 1 there.
    eps_reg : float
        width, in effective saturation S_e, of the interval [1 - eps_reg, 1] where P_c and k_rl (unbounded
        derivatives at S_e = 1 for n < 2) are replaced by their chords (:mod:`.laws`); 0 would be the exact law.
    """

    length: float = 200.0
    porosity: float = 0.15
    permeability: float = 5e-20
    p_r: float = 2e6
    n_vg: float = 1.49
    s_lr: float = 0.4
    s_gr: float = 0.0
    m_w: float = 1e-2
    m_h: float = 2e-3
    rho_w: float = 1e3
    diffusion: float = 3e-9
    henry: float = 7.65e-6
    mu_l: float = 1e-3
    mu_g: float = 9e-6
    temperature: float = 303.0
    q_inject: float = 5.57e-6
    t_inject: float = 5e5
    p_right: float = 1e6
    chi_right: float = 0.0
    eps_reg: float = 1e-4

    def __post_init__(self):
        positive = ("length", "permeability", "p_r", "m_w", "m_h", "rho_w", "diffusion", "henry", "mu_l", "mu_g",
                    "temperature", "p_right")
        for f in fields(self):
            v = getattr(self, f.name)
            if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
                raise ValueError(f"parameter {f.name} must be a finite number, got {v!r}")
            if f.name in positive and v <= 0:
                raise ValueError(f"parameter {f.name} must be > 0, got {v!r}")
        if not 0 < self.porosity <= 1:
            raise ValueError(f"parameter porosity must be in (0, 1], got {self.porosity!r}")
        if not self.n_vg > 1:
            raise ValueError(f"parameter n_vg must be > 1, got {self.n_vg!r}")
        if not (0 <= self.s_lr < 1 and 0 <= self.s_gr < 1 and self.s_lr + self.s_gr < 1):
            raise ValueError(f"parameters s_lr, s_gr must be >= 0 with s_lr + s_gr < 1, got {self.s_lr!r}, {self.s_gr!r}")
        for name in ("q_inject", "t_inject", "chi_right"):
            if getattr(self, name) < 0:
                raise ValueError(f"parameter {name} must be >= 0, got {getattr(self, name)!r}")
        chi_sat = self.h_mass * self.p_right / self.beta_l  # dissolved mole fraction at solubility at p_right
        if self.chi_right > chi_sat:
            raise ValueError(f"parameter chi_right must be <= H p_right / beta_l = {chi_sat:.4g} (the right boundary "
                             f"is liquid-saturated: dissolved hydrogen at most at solubility), got {self.chi_right!r}")
        if not 0 < self.eps_reg < 0.5:
            raise ValueError(f"parameter eps_reg must be in (0, 0.5), got {self.eps_reg!r}")

    # derived constants ([CG20] Section 2)
    @property
    def h_mass(self) -> float:
        """H = H~ M_h [kg/(m^3 Pa)]: dissolved H2 mass density at solubility per Pa of gas pressure."""
        return self.henry * self.m_h

    @property
    def beta_l(self) -> float:
        """beta_l = rho_w M_h / M_w [kg/m^3]: dissolved H2 mass density per unit mole fraction."""
        return self.rho_w * self.m_h / self.m_w

    @property
    def beta_g(self) -> float:
        """beta_g = M_h / (R T) [kg/(m^3 Pa)]: ideal-gas H2 density per Pa."""
        return self.m_h / (GAS_CONSTANT * self.temperature)

    def injection_rate(self, t0: float, t1: float) -> float:
        """Mean injected H2 mass flux over (t0, t1) [kg/m^2/s], times in seconds (exact injected mass per step)."""
        te = self.t_inject * YEAR
        overlap = max(0.0, min(t1, te) - max(t0, 0.0))
        return self.q_inject / YEAR * overlap / (t1 - t0)
