r"""van Genuchten-Mualem laws with their derivatives in S ([CG20] (2.3); van Genuchten 1980).

S_e = (S - S_lr) / (1 - S_lr - S_gr),  m = 1 - 1/n,

    P_c  = P_r (S_e^{-1/m} - 1)^{1/n},
    k_rl = sqrt(S_e) (1 - (1 - S_e^{1/m})^m)^2,
    k_rg = sqrt(1 - S_e) (1 - S_e^{1/m})^{2m}.

Behaviour at S_e -> 1 for n = 1.49: P_c' ~ (1 - S_e)^{1/n - 1} and k_rl' ~ (1 - S_e)^{m - 1} are
unbounded (m - 1 = -0.33), while k_rg and k_rg P_c' tend to 0.  Newton on the complementarity
pair needs P_c' exactly where gas appears (a cell with S = 1 whose second function H(P + P_c) -
beta_l chi becomes active), so the laws are **regularized**: on [1 - eps, 1] (``eps`` =
``TwoPhaseParams.eps_reg``, in S_e) P_c, k_rl and k_rg are replaced by their chords between
S_e = 1 - eps and S_e = 1 (values P_c(1) = 0, k_rl(1) = 1, k_rg(1) = 0), continued linearly for
S_e > 1 (P_c, k_rl; k_rg = 0 there) so that Newton iterates with S > 1 stay defined.  The laws
stay continuous and monotone, with bounded derivatives.  Below S_e = ``SE_LOW`` the laws are
frozen at their value there (never reached in the benchmark: S >= 0.98).
"""
from __future__ import annotations

import numpy as np

from .params import TwoPhaseParams

__all__ = ["VanGenuchten", "SE_LOW"]

SE_LOW = 1e-3


class VanGenuchten:
    """P_c(S), k_rl(S), k_rg(S), each as ``(value, d/dS)`` on arrays (module docstring).

    >>> vg = VanGenuchten(TwoPhaseParams())
    >>> [float(v[0]) for v in (vg.pc(np.array([1.0]))[0], vg.krl(np.array([1.0]))[0], vg.krg(np.array([1.0]))[0])]
    [0.0, 1.0, 0.0]
    """

    def __init__(self, prm: TwoPhaseParams):
        self.prm = prm
        self.n = prm.n_vg
        self.m = 1.0 - 1.0 / prm.n_vg
        self.ds = 1.0 / (1.0 - prm.s_lr - prm.s_gr)  # dS_e/dS
        self.eps = prm.eps_reg
        se1 = np.array([1.0 - self.eps])
        # chords on [1 - eps, 1]: value at 1 - eps and slope (value(1) - value(1 - eps)) / eps
        self._pc1, self._krl1, self._krg1 = (float(f(se1)[0][0]) for f in (self._pc, self._krl, self._krg))
        self._pc_slope = (0.0 - self._pc1) / self.eps
        self._krl_slope = (1.0 - self._krl1) / self.eps
        self._krg_slope = (0.0 - self._krg1) / self.eps

    def se(self, s):
        return (np.asarray(s, dtype=float) - self.prm.s_lr) * self.ds

    # exact laws in S_e (value, d/dS_e), for S_e in (0, 1)
    def _pc(self, se):
        m, n, pr = self.m, self.n, self.prm.p_r
        a = se ** (-1.0 / m) - 1.0
        v = pr * a ** (1.0 / n)
        d = pr / n * a ** (1.0 / n - 1.0) * (-1.0 / m) * se ** (-1.0 / m - 1.0)
        return v, d

    def _krl(self, se):
        m = self.m
        u = se ** (1.0 / m)
        w = 1.0 - u
        f = 1.0 - w ** m
        v = np.sqrt(se) * f * f
        d = 0.5 / np.sqrt(se) * f * f + np.sqrt(se) * 2.0 * f * w ** (m - 1.0) * se ** (1.0 / m - 1.0)
        return v, d

    def _krg(self, se):
        m = self.m
        w = 1.0 - se ** (1.0 / m)
        r = np.sqrt(1.0 - se)
        v = r * w ** (2 * m)
        d = -0.5 / r * w ** (2 * m) - 2.0 * r * w ** (2 * m - 1.0) * se ** (1.0 / m - 1.0)
        return v, d

    def _law(self, s, exact, v_end, slope, above_one):
        se = self.se(s)
        hi = se >= 1.0 - self.eps
        lo = se <= SE_LOW
        mid = ~hi & ~lo
        v, d = np.empty_like(se), np.empty_like(se)
        v[mid], d[mid] = exact(se[mid])
        vl, _ = exact(np.array([SE_LOW]))
        v[lo], d[lo] = vl[0], 0.0
        v[hi], d[hi] = v_end + slope * (se[hi] - 1.0), slope  # the chord through (1, v_end)
        if not above_one:
            over = se > 1.0
            v[over], d[over] = 0.0, 0.0
        return v, d * self.ds

    def pc(self, s):
        """Capillary pressure P_c(S) [Pa] and dP_c/dS."""
        return self._law(s, self._pc, 0.0, self._pc_slope, True)

    def krl(self, s):
        """Liquid relative permeability k_rl(S) and dk_rl/dS."""
        return self._law(s, self._krl, 1.0, self._krl_slope, True)

    def krg(self, s):
        """Gas relative permeability k_rg(S) and dk_rg/dS (0 for S_e > 1; the chord slope at S_e = 1)."""
        return self._law(s, self._krg, 0.0, self._krg_slope, False)

    def saturation(self, pc):
        """Inverse of the regularized P_c: S with P_c(S) = ``pc`` (pc >= 0), for initial guesses and checks."""
        pc = np.asarray(pc, dtype=float)
        m, n = self.m, self.n
        with np.errstate(divide="ignore"):
            se = (1.0 + (np.maximum(pc, 0.0) / self.prm.p_r) ** n) ** (-m)
        chord = pc <= self._pc1
        se = np.where(chord, 1.0 + pc / self._pc_slope, se)
        return self.prm.s_lr + se / self.ds
