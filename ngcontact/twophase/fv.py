r"""Two-point finite volumes, upwind mobilities, backward Euler for the water-hydrogen model ([CG20] Section 3).

Unknowns per cell K (interleaved, X[3K:3K+3] = (S_K, P_K, chi_K)); equations per cell, in this row
order of the Newton matrix (a nonzero diagonal for both choices of Newton-min, which ILU needs):

* row 3K:   the complementarity C(a_K, b_K) = 0 with a = 1 - S, b = H (P + P_c(S)) - beta_l chi ([CG20] (2.5));
* row 3K+1: water   |K| (A_w(X_K) - A_w(X_K^{n-1})) / dt + sum_faces F_w = 0,          A_w = phi rho_w S;
* row 3K+2: hydrogen |K| (A_h(X_K) - A_h(X_K^{n-1})) / dt + sum_faces F_h = |dK_in| q_in,
  A_h = phi (beta_l chi S + beta_g P_g (1 - S)),  P_g = P + P_c(S).

Face fluxes from K to L (T = |sigma| / d_KL; upwinding by the sign of each phase's potential jump):

    Q_l = K T k_rl(S_up,l) / mu_l (P_K - P_L),   Q_g = K T k_rg(S_up,g) / mu_g (P_g,K - P_g,L),
    J   = phi M_h D T S_f c_f (chi_K - chi_L),   S_f, chi_f arithmetic means, c_f = rho_w / M_w + beta_l chi_f / M_h,
    F_w = rho_w Q_l - J,    F_h = beta_l chi_up,l Q_l + beta_g P_g,up,g Q_g + J.

Boundary: x = L Dirichlet (S = 1, P = p_right, chi = chi_right) through a ghost state at distance
d = h/2; x = 0 no flow, plus the injected H2 flux (mean over the step, so the injected mass is exact).
The conservation rows are divided by w_w = phi rho_w |K| / dt and w_h = phi beta_g p_right |K| / dt
(pore-volume fractions per step), so the Newton residual is dimensionless.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp

from ..algebra.certificate import pair_certificate
from ..algebra.nonlinear import NonlinearComplementaritySystem
from .laws import VanGenuchten
from .mesh1d import CellMesh
from .params import TwoPhaseParams

__all__ = ["TwoPhaseFV", "TwoPhaseStep", "FaceFluxes", "initial_state"]

NV = 3  # unknowns per cell


def initial_state(prm: TwoPhaseParams, mesh: CellMesh) -> np.ndarray:
    """S = 1, P = p_right, chi = chi_right in every cell (the benchmark's initial state)."""
    x = np.empty(NV * mesh.ncells)
    x[0::3], x[1::3], x[2::3] = 1.0, prm.p_right, prm.chi_right
    return x


@dataclass
class FaceFluxes:
    """Fluxes through faces [kg/s] (component 0 water, 1 hydrogen) and their derivatives.

    ``F``: (2, nf); ``dL``, ``dR``: (2, 3, nf) derivatives in the (S, P, chi) of the left / right state.
    """

    F: np.ndarray
    dL: np.ndarray
    dR: np.ndarray


class _State:
    """Cell or ghost states with the laws evaluated."""

    def __init__(self, laws: VanGenuchten, s, p, chi):
        self.s, self.p, self.chi = s, p, chi
        self.pc, self.dpc = laws.pc(s)
        self.krl, self.dkrl = laws.krl(s)
        self.krg, self.dkrg = laws.krg(s)
        self.pg = p + self.pc

    def take(self, idx):
        out = object.__new__(_State)
        for k, v in vars(self).items():
            out.__dict__[k] = v[idx]
        return out


def face_fluxes(prm: TwoPhaseParams, L: _State, R: _State, trans: np.ndarray) -> FaceFluxes:
    """Water and hydrogen fluxes from the state L to the state R (module docstring) with derivatives."""
    nf = len(trans)
    F, dL, dR = np.zeros((2, nf)), np.zeros((2, 3, nf)), np.zeros((2, 3, nf))
    kt = prm.permeability * trans
    # liquid Darcy flux Q_l [m^3/s]
    dp = L.p - R.p
    up = dp >= 0
    krl = np.where(up, L.krl, R.krl)
    cl = kt / prm.mu_l
    ql = cl * krl * dp
    dql = {"sL": np.where(up, cl * L.dkrl * dp, 0.0), "sR": np.where(up, 0.0, cl * R.dkrl * dp),
           "pL": cl * krl, "pR": -cl * krl}
    # gas Darcy flux Q_g
    dpg = L.pg - R.pg
    upg = dpg >= 0
    krg = np.where(upg, L.krg, R.krg)
    cg = kt / prm.mu_g
    qg = cg * krg * dpg
    dqg = {"sL": cg * (np.where(upg, L.dkrg, 0.0) * dpg + krg * L.dpc),
           "sR": cg * (np.where(upg, 0.0, R.dkrg) * dpg - krg * R.dpc), "pL": cg * krg, "pR": -cg * krg}
    # Fick diffusion of dissolved H2 [kg/s]
    cd = prm.porosity * prm.m_h * prm.diffusion * trans
    sf, chif, dchi = 0.5 * (L.s + R.s), 0.5 * (L.chi + R.chi), L.chi - R.chi
    cf = prm.rho_w / prm.m_w + prm.beta_l * chif / prm.m_h
    J = cd * sf * cf * dchi
    dcf = prm.beta_l / (2 * prm.m_h)
    dJ = {"sL": cd * 0.5 * cf * dchi, "sR": cd * 0.5 * cf * dchi,
          "cL": cd * sf * (cf + dcf * dchi), "cR": cd * sf * (dcf * dchi - cf)}
    # upwinded transported densities
    chi_up = np.where(up, L.chi, R.chi)
    pg_up = np.where(upg, L.pg, R.pg)
    F[0] = prm.rho_w * ql - J
    F[1] = prm.beta_l * chi_up * ql + prm.beta_g * pg_up * qg + J
    for side, D, mask_l, mask_g, st in (("L", dL, up, upg, L), ("R", dR, ~up, ~upg, R)):
        ds, dpp, dc = "s" + side, "p" + side, "c" + side
        D[0, 0] = prm.rho_w * dql[ds] - dJ[ds]
        D[0, 1] = prm.rho_w * dql[dpp]
        D[0, 2] = -dJ[dc]
        D[1, 0] = (prm.beta_l * chi_up * dql[ds] + prm.beta_g * pg_up * dqg[ds]
                   + prm.beta_g * np.where(mask_g, st.dpc, 0.0) * qg + dJ[ds])
        D[1, 1] = prm.beta_l * chi_up * dql[dpp] + prm.beta_g * pg_up * dqg[dpp] + prm.beta_g * np.where(mask_g, qg, 0.0)
        D[1, 2] = prm.beta_l * np.where(mask_l, ql, 0.0) + dJ[dc]
    return FaceFluxes(F, dL, dR)


class TwoPhaseFV:
    """The discretization: parameters + mesh -> one :class:`TwoPhaseStep` per time step."""

    def __init__(self, prm: TwoPhaseParams, mesh: CellMesh):
        self.prm, self.mesh = prm, mesh
        self.laws = VanGenuchten(prm)
        self.right = mesh.boundary("right")
        self.left = mesh.boundary("left")
        self.w_ref = np.array([prm.porosity * prm.rho_w, prm.porosity * prm.beta_g * prm.p_right])

    def split(self, x):
        return x[0::3], x[1::3], x[2::3]

    def state(self, x) -> _State:
        return _State(self.laws, *self.split(x))

    def accumulation(self, st: _State):
        """A_w, A_h [kg/m^3] and their derivatives (2, 3, N) in (S, P, chi)."""
        prm = self.prm
        phi = prm.porosity
        A = np.array([phi * prm.rho_w * st.s,
                      phi * (prm.beta_l * st.chi * st.s + prm.beta_g * st.pg * (1.0 - st.s))])
        dA = np.zeros((2, 3, len(st.s)))
        dA[0, 0] = phi * prm.rho_w
        dA[1, 0] = phi * (prm.beta_l * st.chi + prm.beta_g * st.dpc * (1.0 - st.s) - prm.beta_g * st.pg)
        dA[1, 1] = phi * prm.beta_g * (1.0 - st.s)
        dA[1, 2] = phi * prm.beta_l * st.s
        return A, dA

    def ghost(self) -> _State:
        prm = self.prm
        nb = len(self.right)
        return _State(self.laws, np.ones(nb), np.full(nb, prm.p_right), np.full(nb, prm.chi_right))

    def fluxes(self, x, st: _State = None):
        """(interior FaceFluxes, Dirichlet-boundary FaceFluxes) at the state x (outward at the boundary)."""
        m = self.mesh
        st = self.state(x) if st is None else st
        inner = face_fluxes(self.prm, st.take(m.left), st.take(m.right), m.area / m.dist)
        rb = self.right
        bnd = face_fluxes(self.prm, st.take(m.b_cell[rb]), self.ghost(), m.b_area[rb] / m.b_dist[rb])
        return inner, bnd

    def masses(self, x) -> np.ndarray:
        """Total water and hydrogen mass in the domain [kg per m^2 of cross-section in 1D]."""
        A, _ = self.accumulation(self.state(x))
        return A @ self.mesh.volume

    def step_system(self, x_prev: np.ndarray, t0: float, t1: float) -> "TwoPhaseStep":
        return TwoPhaseStep(self, x_prev, t0, t1)


class TwoPhaseStep(NonlinearComplementaritySystem):
    """One backward-Euler step (t0, t1] [s] as a nonlinear complementarity system (:mod:`ngcontact.algebra.nonlinear`).

    ``residual(x, y)`` are the scaled conservation rows (2N, order (water, H2) per cell); ``pair(x, y)``
    is (1 - S, H (P + P_c) - beta_l chi); ``y`` is empty (no separate multiplier).
    """

    def __init__(self, disc: TwoPhaseFV, x_prev, t0, t1):
        self.disc, self.prm, self.mesh = disc, disc.prm, disc.mesh
        self.x_prev = np.array(x_prev, dtype=float)
        self.t0, self.t1, self.dt = float(t0), float(t1), float(t1 - t0)
        self.q_in = self.prm.injection_rate(t0, t1)
        self.A_prev, _ = disc.accumulation(disc.state(self.x_prev))
        self.weights = disc.w_ref[:, None] * self.mesh.volume[None, :] / self.dt  # row scaling (2, N)
        self.n = len(self.x_prev)
        self.y0 = np.zeros(0)
        self._scale = None  # scale(), computed at its first call

    # --- unscaled conservation residual [kg/s] and its Jacobian blocks
    def _conservation(self, x, jac: bool):
        d, m = self.disc, self.mesh
        st = d.state(x)
        A, dA = d.accumulation(st)
        vol = m.volume / self.dt
        R = (A - self.A_prev) * vol
        inner, bnd = d.fluxes(x, st)
        for c in range(2):
            np.add.at(R[c], m.left, inner.F[c])
            np.add.at(R[c], m.right, -inner.F[c])
            np.add.at(R[c], m.b_cell[d.right], bnd.F[c])
        for b in d.left:
            R[1, m.b_cell[b]] -= m.b_area[b] * self.q_in
        if not jac:
            return R, None
        N = m.ncells
        rows, cols, vals = [], [], []

        def put(cells_r, cells_c, block):  # block (2, 3, k): d(eq e at cell_r)/d(var v at cell_c)
            for e in range(2):
                for v in range(3):
                    rows.append(NV * cells_r + 1 + e)
                    cols.append(NV * cells_c + v)
                    vals.append(block[e, v])
        put(np.arange(N), np.arange(N), dA * vol)
        put(m.left, m.left, inner.dL)
        put(m.left, m.right, inner.dR)
        put(m.right, m.left, -inner.dL)
        put(m.right, m.right, -inner.dR)
        put(m.b_cell[d.right], m.b_cell[d.right], bnd.dL)
        return R, (np.concatenate(rows), np.concatenate(cols), np.concatenate(vals))

    # --- the protocol
    def residual(self, x, y=None):
        R, _ = self._conservation(x, False)
        return (R / self.weights).T.ravel()

    def conservation_defect(self, x) -> np.ndarray:
        """Unscaled residual sum per component [kg/s]: the step's mass-balance defect / dt."""
        R, _ = self._conservation(x, False)
        return R.sum(axis=1)

    def pair(self, x, y=None):
        prm = self.prm
        s, p, chi = self.disc.split(x)
        pc, _ = self.disc.laws.pc(s)
        return 1.0 - s, prm.h_mass * (p + pc) - prm.beta_l * chi

    def stack(self, r, c):
        phi = np.empty(self.n)
        phi[0::3] = c
        phi[1::3] = r[0::2]
        phi[2::3] = r[1::2]
        return phi

    def jacobian(self, x, y, Ca, Cb):
        prm = self.prm
        _, (rows, cols, vals) = self._conservation(x, True)
        w = self.weights.T.ravel()  # scaling of row 3K+1+e is weights[e, K]
        cell_eq = (rows - 1) // NV * 2 + (rows - 1) % NV
        vals = vals / w[cell_eq]
        s, p, chi = self.disc.split(x)
        _, dpc = self.disc.laws.pc(s)
        N = len(s)
        k = np.arange(N)
        crow = np.repeat(NV * k, 3)
        ccol = (NV * k[:, None] + np.arange(3)[None, :]).ravel()
        # C-row: Ca da/dX + Cb db/dX, da = (-1, 0, 0), db = (H P_c', H, -beta_l)
        cval = np.stack([-Ca + Cb * prm.h_mass * dpc, Cb * prm.h_mass, -Cb * prm.beta_l], axis=1).ravel()
        J = sp.coo_matrix((np.concatenate([vals, cval]), (np.concatenate([rows, crow]), np.concatenate([cols, ccol]))),
                          shape=(self.n, self.n))
        return J.tocsr()

    def exact_rows(self, x, dx, c, Ca, Cb):
        """Rows where the C-function's derivative is that of a = 1 - S alone (|Cb| <= 1e-12 |Ca|: Newton-min's
        liquid rows, Fischer-Burmeister's where a = 0 < b): dS = c / Ca exactly (the Cb db term dropped), so an
        inexact solve leaves no S != 1 in the liquid-only cells."""
        out = dx.copy()
        sel = (np.abs(Cb) <= 1e-12 * np.abs(Ca)) & (Ca != 0)
        out[0::3][sel] = c[sel] / Ca[sel]
        return out

    #: smallest divisor of :meth:`scale`: the loop's test then asks 0.1 tol of the scaled rows, above their round-off
    #: floor (~1e-10 on 1000 cells late in the benchmark, results/twophase/REPORT.md)
    SCALE_FLOOR = 0.1

    def scale(self) -> float:
        """Divisor of ||Phi|| in the loop's test: min(1, max(||R(X^{n-1})||, SCALE_FLOOR)), R the scaled conservation
        rows at the start of the step (relative mass changes per cell: what the injection and the fluxes of the
        previous state drive in this step).  The test is absolute (tol in the units of the rows) unless the step's
        own driving terms are smaller: with dt = 1e-4 years on 50 cells the injection is ~1e-9 of a cell's
        reference mass, below the absolute tolerance 1e-8, so that test held at the start (no Newton step, no
        hydrogen injected).  Steps whose driving terms are below even 0.1 tol are caught by the mass balance of
        :func:`~ngcontact.twophase.run.run_h2`."""
        if self._scale is None:
            r0 = float(np.linalg.norm(self.residual(self.x_prev)))
            self._scale = min(1.0, max(r0, self.SCALE_FLOOR)) if np.isfinite(r0) else 1.0
        return self._scale

    def certificate(self, x, y, tol: float):
        """The exit certificate of (a, b) = (1 - S, H (P + P_c) - beta_l chi): a relative to max(||a||_inf, 1), b
        relative to the size of its two terms (b is resolved to the round-off of H (P + P_c) and beta_l chi: where
        gas fills every cell b vanishes everywhere and ||b||_inf alone is round-off)."""
        a, b = self.pair(x, y)
        s, p, chi = self.disc.split(x)
        pc, _ = self.disc.laws.pc(s)
        terms = (b, self.prm.h_mass * (p + pc), self.prm.beta_l * chi)
        unit = max(float(np.max(np.abs(v), initial=0.0)) for v in terms)
        return pair_certificate(a, b, max(float(np.max(np.abs(a), initial=0.0)), 1.0), unit, tol,
                                names=("saturation S > 1", "dissolved H2 above solubility (b < 0)",
                                       "gas (S < 1) with dissolved H2 below solubility (b > 0)"))
