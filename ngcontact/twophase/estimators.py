r"""A posteriori estimators of the water-hydrogen FV scheme and the adaptive stopping criteria ([CG20] Sections 4-5,
in the framework of Di Pietro, Flauraud, Vohralik, Yousef 2014), in 1D.

At Newton step k, GMRES iterate i of time step n, with linearization point X^{k-1}, the iterate
u = X^{k,i} and the look-ahead v = X^{k,i+nu}, per component c (water, hydrogen):

* flux reconstructions from the FV face fluxes (RT0 in 1D: affine on each cell, continuous, face
  values = face fluxes per unit area): sigma_disc from F(u); sigma_lin from F_lin(u) - F(u); sigma_alg
  from F_lin(v) - F_lin(u), where F_lin(z) = F(X^{k-1}) + dF(X^{k-1}) (z - X^{k-1}) is the flux of the
  linearized system.  sigma_disc + sigma_lin + sigma_alg = F_lin(v): its divergence balances the
  linearized accumulation up to the algebraic remainder;
* conforming potentials: S, P, P_g, chi interpolated affinely between cell centres (and the Dirichlet
  values at x = L); the "continuous" flux sigma_cf(u) evaluates the Darcy + Fick laws pointwise
  (no upwinding) on them.

Components per cell K (L^2(K) norms, h_K / pi the Poincare constant of an interval):

* eta_sp  = ||sigma_disc - sigma_cf(u)||_K                    (spatial: flux non-conformity, upwinding;
  not measured on the half cell at x = 0, where the flux is the prescribed injection);
* eta_tm  = ||sigma_cf(u) - sigma_cf(X^{n-1})||_K             (temporal);
* eta_lin = ||sigma_lin||_K + h_K/pi ||(A(u) - A_lin(u)) / dt||_K + h_K/pi ||C(u)||_K w_c
  (flux and accumulation linearization, and the complementarity defect C(u) as a mass rate:
  w_water = phi rho_w / dt where the min selects 1 - S, w_H2 = phi / dt where it selects H(P + P_c) - beta_l chi);
* eta_alg = ||sigma_alg||_K + h_K/pi ||(A_lin(v) - A_lin(u)) / dt||_K + h_K/pi ||rho_alg(v)||_K
  (rho_alg: the linearized cell residual left at v, per unit volume).

Step values: eta_x,c = (sum_K eta_x,K,c^2)^{1/2} [kg m^{-3/2} s^{-1} in 1D].  Stopping ([CG20] (5.1), (5.2)),
for every component c:  GMRES when eta_alg,c <= gamma_alg max(eta_sp,c, eta_tm,c, eta_lin,c);  Newton
when eta_lin,c <= gamma_lin max(eta_sp,c, eta_tm,c) (the accepted iterate projected onto S <= 1:
:class:`AdaptiveStepStop`).  In 1D the flux part of eta_lin,c is close to the flux error of the iterate,
||F_c(X^k) - F_c(X^*)|| against the converged step X^* (the linearized fluxes balance the linearized
accumulation from the prescribed flux at x = 0 on); :mod:`.diagnose` measures both.

What the estimate bounds: [CG20] proves, assuming a weak solution exists, that its estimator bounds a
dual norm of the residual of the continuous equations at the reconstructed approximate solution (plus a
complementarity term).  That is not an error bound for S, P, chi, and it is not claimed for the variant
here: the conforming reconstruction, the complementarity term and the constants are our choices, and
the regularized laws near S = 1 (:mod:`.laws`) are the ones estimated.  The components are used as in
[CG20]: to balance the solvers' errors against the discretization's.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..newton.stopping import EstimatorStop
from .fv import NV, TwoPhaseFV, TwoPhaseStep

__all__ = ["TwoPhaseEstimator", "Components", "AdaptiveStepStop", "COMPONENT_NAMES"]

COMPONENT_NAMES = ("w", "h")
_GAUSS = np.polynomial.legendre.leggauss(3)


@dataclass
class Components:
    """Step values per component (arrays of 2: water, hydrogen)."""

    eta_sp: np.ndarray
    eta_tm: np.ndarray
    eta_lin: np.ndarray
    eta_alg: np.ndarray

    def row(self) -> dict:
        return {f"{name}_{c}": float(getattr(self, name)[j]) for name in ("eta_sp", "eta_tm", "eta_lin", "eta_alg")
                for j, c in enumerate(COMPONENT_NAMES)}


def _rt0_norm2(left, right, h):
    """||sigma||^2_K of the affine sigma with end values (left, right) on cells of size h."""
    return h * (left * left + left * right + right * right) / 3.0


class TwoPhaseEstimator:
    """Estimators of one time step (module docstring); ``components(x_lin, dx_i, dx_j)``."""

    def __init__(self, disc: TwoPhaseFV, system: TwoPhaseStep, gamma_alg: float = 1e-3, gamma_lin: float = 1e-3):
        self.disc, self.system = disc, system
        self.gamma_alg, self.gamma_lin = gamma_alg, gamma_lin
        m = disc.mesh
        self.h = m.volume  # 1D: cell sizes
        self.cf_prev = self._conforming_flux(system.x_prev)
        self._lin_at = None
        self.last = None

    # --- fluxes
    def _face_values(self, x, lin=None):
        """Face flux densities in +x, (2, N+1): x = 0 (injection), interior faces, x = L; with their
        derivatives when ``lin`` (the linearization data) is requested."""
        inner, bnd = self.disc.fluxes(x)
        sys_ = self.system
        N = self.disc.mesh.ncells
        f = np.zeros((2, N + 1))
        f[1, 0] = sys_.q_in
        f[:, 1:N] = inner.F / self.disc.mesh.area
        f[:, N] = bnd.F[:, 0] / self.disc.mesh.b_area[self.disc.right[0]]
        return f, inner, bnd

    def _linearization(self, x_lin):
        if self._lin_at is None or not np.array_equal(self._lin_at[0], x_lin):
            f, inner, bnd = self._face_values(x_lin)
            A, dA = self.disc.accumulation(self.disc.state(x_lin))
            self._lin_at = (x_lin.copy(), f, inner, bnd, A, dA)
        return self._lin_at[1:]

    def _flux_lin(self, x_lin, dz):
        """F_lin(x_lin + dz) face densities and A_lin(x_lin + dz)."""
        m, N = self.disc.mesh, self.disc.mesh.ncells
        f, inner, bnd, A, dA = self._linearization(x_lin)
        d = dz.reshape(N, NV).T  # (3, N)
        out = f.copy()
        out[:, 1:N] += (np.einsum("cvf,vf->cf", inner.dL, d[:, m.left])
                        + np.einsum("cvf,vf->cf", inner.dR, d[:, m.right])) / m.area
        out[:, N] += np.einsum("cv,v->c", bnd.dL[:, :, 0], d[:, N - 1]) / m.b_area[self.disc.right[0]]
        return out, A + np.einsum("cvk,vk->ck", dA, d)

    def _conforming_flux(self, x):
        """sigma_cf at 3 Gauss points on each half cell: (2, N, 2 halves, 3)."""
        prm, d, N = self.disc.prm, self.disc, self.disc.mesh.ncells
        s, p, chi = d.split(x)
        pg = p + d.laws.pc(s)[0]
        xc = d.mesh.centre[:, 0]
        # nodal values at the centres, extended by the face values at x = 0 (no-flow: constant) and x = L (Dirichlet)
        nodes = np.concatenate([[0.0], xc, [prm.length]])
        vals = [np.concatenate([[v[0]], v, [bv]]) for v, bv in ((s, 1.0), (p, prm.p_right), (pg, prm.p_right),
                                                              (chi, prm.chi_right))]
        gx, gw = _GAUSS
        out = np.zeros((2, N, 2, 3))
        for half in range(2):
            a, b = np.arange(N) + half, np.arange(N) + half + 1  # node indices of the half cell
            xa, xb = nodes[a], nodes[b]
            t = 0.5 * (gx + 1.0)
            S, P, Pg, C = ((v[a][:, None] * (1 - t) + v[b][:, None] * t) for v in vals)
            dxn = (xb - xa)[:, None]
            dP, dPg, dC = ((v[b] - v[a])[:, None] / dxn for v in vals[1:])
            krl, krg = d.laws.krl(S.ravel())[0].reshape(S.shape), d.laws.krg(S.ravel())[0].reshape(S.shape)
            ql, qg = -prm.permeability * krl / prm.mu_l * dP, -prm.permeability * krg / prm.mu_g * dPg
            J = -prm.porosity * prm.m_h * S * (prm.rho_w / prm.m_w + prm.beta_l * C / prm.m_h) * prm.diffusion * dC
            out[0, :, half] = prm.rho_w * ql - J
            out[1, :, half] = prm.beta_l * C * ql + prm.beta_g * Pg * qg + J
        return out

    def _cell_norm(self, g):
        """(sum over halves and Gauss points) ||g||^2_K for g (2, N, 2, 3) given on the half cells."""
        gw = _GAUSS[1]
        return np.einsum("cnhq,q->cn", g * g, gw) * 0.25 * self.h  # each half: length h/2, weights sum 2

    def _rt0_at_gauss(self, f):
        """The RT0 reconstruction with face values f (2, N+1) at the half-cell Gauss points."""
        gx = _GAUSS[0]
        t = 0.5 * (gx + 1.0)
        fl, fr = f[:, :-1, None], f[:, 1:, None]
        lam = np.stack([0.5 * t, 0.5 + 0.5 * t])  # position in the cell of the Gauss points of each half
        return np.stack([fl * (1 - lam[h]) + fr * lam[h] for h in range(2)], axis=2)

    # --- the components
    def components(self, x_lin, dx_i, dx_j) -> Components:
        sys_, d = self.system, self.disc
        u = x_lin + dx_i
        f_u, _, _ = self._face_values(u)
        flin_u, Alin_u = self._flux_lin(x_lin, dx_i)
        flin_v, Alin_v = self._flux_lin(x_lin, dx_j)
        st = d.state(u)
        A_u, _ = d.accumulation(st)
        h, dt, poinc = self.h, sys_.dt, self.h / np.pi
        cf_u = self._conforming_flux(u)
        rt_u = self._rt0_at_gauss(f_u)
        cf_u[:, 0, 0] = rt_u[:, 0, 0]  # x = 0 half cell: the injection flux is data, no potential reconstruction there
        sp2 = self._cell_norm(rt_u - cf_u)
        tm2 = self._cell_norm(cf_u - self.cf_prev)
        # linearization: fluxes, accumulation, complementarity defect as a mass rate
        a, b = sys_.pair(u)
        C = np.minimum(a, b)
        rate = np.zeros((2, len(h)))
        sel_a = a <= b
        rate[0, sel_a] = d.prm.porosity * d.prm.rho_w * np.abs(C[sel_a]) / dt
        rate[1, ~sel_a] = d.prm.porosity * np.abs(C[~sel_a]) / dt
        lin_flux = flin_u - f_u
        lin = (np.sqrt(_rt0_norm2(lin_flux[:, :-1], lin_flux[:, 1:], h))
               + poinc * np.sqrt(h) * (np.abs(A_u - Alin_u) / dt + rate))
        # algebraic: flux increment, accumulation increment, remainder of the linearized balance at v
        alg_flux = flin_v - flin_u
        rem = (Alin_v - sys_.A_prev) / dt + (flin_v[:, 1:] - flin_v[:, :-1]) / h
        alg = (np.sqrt(_rt0_norm2(alg_flux[:, :-1], alg_flux[:, 1:], h))
               + poinc * np.sqrt(h) * (np.abs(Alin_v - Alin_u) / dt + np.abs(rem)))
        return Components(np.sqrt(sp2.sum(axis=1)), np.sqrt(tm2.sum(axis=1)), np.sqrt((lin ** 2).sum(axis=1)),
                          np.sqrt((alg ** 2).sum(axis=1)))

    def stop_linear(self, comp: Components) -> bool:
        """[CG20]: eta_alg,c <= gamma_alg max(eta_sp,c, eta_tm,c, eta_lin,c) for both components."""
        return bool(np.all(comp.eta_alg <= self.gamma_alg * np.maximum(np.maximum(comp.eta_sp, comp.eta_tm),
                                                                        comp.eta_lin)))

    def stop_newton(self, comp: Components) -> bool:
        """[CG20]: eta_lin,c <= gamma_lin max(eta_sp,c, eta_tm,c) for both components."""
        return bool(np.all(comp.eta_lin <= self.gamma_lin * np.maximum(comp.eta_sp, comp.eta_tm)))


class AdaptiveStepStop(EstimatorStop):
    """Newton stopping rule of the loop (:mod:`ngcontact.newton.stopping` interface): the [CG20] criterion on
    the components of the accepted iterate (``estimator.last``), or the residual test.

    The iterate the criterion accepts is returned with S projected onto S <= 1 (:meth:`accepted`).  A Newton
    iterate can leave S - 1 > 0 in cells the step moves from gas to liquid (Fischer-Burmeister: in any cell,
    the bound |C| <= tol holds only at residual convergence); that violation enters eta_lin,w as the
    complementarity mass rate phi rho_w (S - 1) / dt, so where the criterion holds, the water mass the
    projection removes is within the accepted linearization error.  The projection keeps each cell's
    hydrogen content A_h = phi (beta_l chi S + beta_g P_g (1 - S)): at S = 1, chi = A_h / (phi beta_l).
    ``projected`` holds max(S - 1, 0) of the last projection (0 if none was needed)."""

    def __init__(self, estimator: TwoPhaseEstimator):
        self.estimator = estimator
        self.projected = 0.0

    def measure(self, rec, system, x, y, r) -> None:
        comp = self.estimator.last
        if comp is not None:
            rec.eta_disc = 1.0  # the ratios below are relative to max(eta_sp, eta_tm) per component
            rec.eta_lin = float(np.max(comp.eta_lin / np.maximum(comp.eta_sp, comp.eta_tm)))
            rec.eta_alg = float(np.max(comp.eta_alg / np.maximum(comp.eta_sp, comp.eta_tm)))

    def check(self, rec, tol: float):
        comp = self.estimator.last
        if comp is not None and self.estimator.stop_newton(comp):
            return "adaptive stopping criterion"
        return "converged" if rec.res <= tol else None

    def accepted(self, x, y):
        """(x with S <= 1, y): the projection onto the physical range of the saturation that keeps the
        hydrogen content of every cell (class docstring)."""
        s = x[0::NV]
        self.projected = max(float(s.max()) - 1.0, 0.0)
        if self.projected == 0.0:
            return x, y
        disc = self.estimator.disc
        cells = np.flatnonzero(s > 1.0)
        a_h = disc.accumulation(disc.state(x))[0][1, cells]
        x = x.copy()
        x[NV * cells] = 1.0
        x[NV * cells + 2] = np.maximum(a_h / (disc.prm.porosity * disc.prm.beta_l), 0.0)
        return x, y
