r"""The nonnegative multiplier lam~_h >= 0 of the contact terms of :mod:`.bound`.

The proof of the bound holds for every lam~ >= 0; the defect lam^_h - lam~_h of the multiplier of
the equilibration is paid in eta_nonc,2 (:func:`.terms.nonnegative_part`), the product with the gap in
eta_C.  Two constructions:

* :func:`nonnegative_multiplier` -- when lam^_h < 0 somewhere (Newton iterates, the dual-basis lam_h
  for p >= 3, the negative lobes of the weighted fit): the minimal nonnegative modification keeping
  the element means, lam~|_K = max(0, m_K + theta_K (lam^ - m_K)), m_K the mean on K, theta_K in
  [0, 1] largest with m_K + theta_K (min_K lam^ - m_K) >= 0 (min over a P_{3p} lattice and the
  vertices).  (The seed takes lam~ = (lam_h)^pos with eta_nonc,2 = C_{Omega,mu} ||lam_h^neg||,
  reported as ``eta_nonc2_seed``; it dominates for p >= 2.)
* :func:`concentrated_multiplier` -- for p >= 2, lam~ moved towards the small gaps inside every
  element, keeping the element means, chosen to decrease the bound.
"""
from __future__ import annotations

import math

import numpy as np
from ngsolve import L2, TRIG, VOL, GridFunction, IfPos, Integrate, IntegrationRule, dx, specialcf

from ..discretizations.lagrange import lattice

__all__ = ["nonnegative_multiplier", "lam_vertex_min", "QuadratureArrays", "concentrated_multiplier"]


def _element_values(mesh, cf, p: int) -> np.ndarray:
    """Values of cf at the P_{3p} lattice points of every element, shape (ne, npts)."""
    lat = lattice(3 * p) / (3.0 * p)
    ir = IntegrationRule(points=[tuple(b[:2]) for b in lat], weights=[0.0] * len(lat))
    vals = np.asarray(cf(mesh.MapToAllElements(ir, VOL)))
    return vals.reshape(mesh.ne, len(lat))


def nonnegative_multiplier(lam, mesh, p: int, area: np.ndarray):
    """lam~_h >= 0: the minimal modification of lam_h keeping the element means (module doc).

    Returns
    -------
    lam_t : CoefficientFunction
        lam~_h = max(0, m_K + theta_K (lam_h - m_K)).
    changed : int
        number of elements where lam_h had negative values (theta_K < 1).
    """
    m = Integrate(lam * dx, mesh, element_wise=True).NumPy() / area
    lmin = np.minimum(_element_values(mesh, lam, p).min(axis=1), lam_vertex_min(lam, mesh))
    theta = np.ones(mesh.ne)
    neg = lmin < 0
    with np.errstate(divide="ignore", invalid="ignore"):
        theta[neg] = np.where(m[neg] > 0, m[neg] / (m[neg] - lmin[neg]), 0.0)
    P0 = L2(mesh, order=0)
    gm, gt = GridFunction(P0), GridFunction(P0)
    gm.vec.FV().NumPy()[:] = m
    gt.vec.FV().NumPy()[:] = theta
    mod = gm + gt * (lam - gm)
    return IfPos(mod, mod, 0.0), int(neg.sum())


def lam_vertex_min(lam, mesh) -> np.ndarray:
    """min of lam over the three vertices of every element."""
    ir = IntegrationRule(points=[(0, 0), (1, 0), (0, 1)], weights=[0.0] * 3)
    return np.asarray(lam(mesh.MapToAllElements(ir, VOL))).reshape(mesh.ne, 3).min(axis=1)



class QuadratureArrays:
    """Values of CoefficientFunctions at the points of one rule on every element (or on the elements of the index
    array ``elements``, in that order: row i of every array belongs to element ``elements[i]``), and the
    weights w_j |det J| (vectorized; for the element sums of products of non-polynomial
    functions such as the kinks of max(0, .))."""

    def __init__(self, mesh, order: int, elements=None):
        self.mesh = mesh
        ir = IntegrationRule(TRIG, order)
        self.ref = np.array([ip.point[:2] for ip in ir])
        w = np.array([ip.weight for ip in ir])
        self.elements = None if elements is None else np.asarray(elements, dtype=np.int64)
        if elements is None:
            self.mips = mesh.MapToAllElements(ir, VOL)
            n = mesh.ne
        else:  # the mapped points of those elements only: NGSolve's point records, one per element, repeated
            n = len(self.elements)
            one = mesh.MapToAllElements(IntegrationRule(points=[(1 / 3, 1 / 3)], weights=[0.0]), VOL)
            self.mips = np.repeat(one[self.elements], len(w))
            self.mips["x"] = np.tile(self.ref[:, 0], n)
            self.mips["y"] = np.tile(self.ref[:, 1], n)
        J = specialcf.JacobianMatrix(2)
        det = np.abs(np.asarray((J[0, 0] * J[1, 1] - J[0, 1] * J[1, 0])(self.mips))).reshape(n, len(w))
        self.W = w[None, :] * det
        # barycentric coordinates of the reference triangle (vertex order irrelevant here)
        xi, et = self.ref[:, 0], self.ref[:, 1]
        self.bary = np.stack([xi, et, 1.0 - xi - et])  # (3, nq)

    def values(self, cf, elements=None) -> np.ndarray:
        """Values of ``cf`` at the points of every row's element (nrows, nq), or of the rows of the index array
        ``elements`` (len(elements), nq); None: zeros."""
        if elements is None:
            return np.zeros_like(self.W) if cf is None else np.asarray(cf(self.mips)).reshape(self.W.shape)
        if cf is None:
            return np.zeros((len(elements), self.W.shape[1]))
        mips = self.mips.reshape(self.W.shape)[np.asarray(elements, dtype=np.int64)].ravel()
        return np.asarray(cf(mips)).reshape(len(elements), self.W.shape[1])

    def integrate(self, vals) -> np.ndarray:
        return (self.W * vals).sum(axis=1)


def concentrated_multiplier(qa: QuadratureArrays, lam_vals, gap_vals, h, C_mu: float, scale: float,
                            exponents=(1, 2, 4)):
    r"""lam~ >= 0 for the contact term: per element, lam~|_K = lam^ or m_K phi / mean_K(phi) with
    phi = b_i^k (towards a vertex) or (1 - b_i)^k (towards an edge), b_i the barycentric
    coordinates of K, m_K the mean of lam^ on K; chosen to decrease the bound.

    Why.  For p >= 2 the multiplier lam^_h (P1 moments function) is smeared over the elements
    along the contact boundary, where the gap u1h - u2h > 0 grows linearly: the contact term
    sum_K eta_C,K = 2 (lam^, g_h) = O(h^2) enters the bound as its square root, O(h), while the
    P2 error is O(h^{3/2}) (disk, test 2): the effectivity index grows like h^{-1/2}.  Moving the mass of lam^ on K towards the vertex where the gap is smallest keeps
    lam~ >= 0 and the element mean (so delta = lam^ - lam~ is mean-free on every K and costs
    only the Poincare term C_mu (sum_K (h_K/pi)^2 ||delta||_K^2)^{1/2} in eta_nonc,2, O(h^2)),
    while the contact term drops.  Any choice is admissible (the proof in :mod:`.bound`
    holds for every lam~ >= 0); the choice only tries to make the bound small: the objective
    (scale + eta_nonc,2)^2 + sum_K eta_C,K is minimized over the choices per element by a
    Lagrangian sweep (argmin_K 2 (lam~, g)_K + t (h_K/pi)^2 ||delta||_K^2 for 46 prices t),
    keeping lam~ = lam^ if nothing is better.

    Parameters
    ----------
    lam_vals, gap_vals : ndarray (ne, nq)
        lam^ >= 0 and the gap at the quadrature points.
    h : ndarray (ne,)
    C_mu : float
        (sum_alpha 1/mu_alpha)^{1/2}.
    scale : float
        the rest of the linear part of the bound (eta_FR + eta_quad + eta_nonc,1 + ...).

    Returns
    -------
    lam_t : ndarray (ne, nq)
        lam~ at the quadrature points.
    loc2 : ndarray (ne,)
        (h_K/pi)^2 ||lam^ - lam~||_K^2.
    """
    W = qa.W
    area = W.sum(axis=1)
    m = (W * lam_vals).sum(axis=1) / area
    ne = lam_vals.shape[0]
    lam_t = np.array(lam_vals, dtype=float)
    loc2 = np.zeros(ne)
    # elements with m_K = 0 carry lam^ = 0 (lam^ >= 0): every candidate is 0 there and adds nothing
    # to either sum of the objective, so the search runs over the elements with m_K > 0 only
    active = np.flatnonzero(m > 0)
    if not len(active):
        return lam_t, loc2
    Wa, La, Ga, ma, areaa, ha = W[active], lam_vals[active], gap_vals[active], m[active], area[active], h[active]
    # the candidates c_j = s_j phi_j (j >= 1), s_j = m_K / mean_K(phi_j), and c_0 = lam^; their sums
    # (c_j, g)_K and ||lam^ - c_j||_K^2 for the search from products with the shape matrix Phi (nc, nq)
    # (vertex i: b_i^k; edge opposite to vertex i - 3: (1 - b_{i-3})^k)
    Phi = np.array([qa.bary[i] ** k if i < 3 else (1.0 - qa.bary[i - 3]) ** k
                    for k in exponents for i in range(6)])
    S = ma[:, None] * areaa[:, None] / (Wa @ Phi.T)                                 # (n, nc)
    WL = Wa * La
    hk = (ha / math.pi) ** 2
    C = np.concatenate([[(WL * Ga).sum(axis=1)], (S * ((Wa * Ga) @ Phi.T)).T])      # (1 + nc, n): (lam~, g)_K
    # defects^2 expanded (rounding of the order of eps ||lam^||_K^2: the search only; the defect of the
    # chosen candidate is summed directly below), clamped at 0
    XL = (WL * La).sum(axis=1)
    X = hk[:, None] * np.maximum(XL[:, None] - 2.0 * S * (WL @ Phi.T) + S * S * (Wa @ (Phi * Phi).T), 0.0)
    X = np.concatenate([np.zeros((1, len(active))), X.T])
    cols = np.arange(len(active))

    def objective(idx):
        return (scale + C_mu * math.sqrt(X[idx, cols].sum())) ** 2 + 2.0 * C[idx, cols].sum()

    best = np.zeros(len(active), dtype=np.int64)
    best_val = objective(best)
    # Lagrangian sweep over the price t of the squared defect: per element argmin 2 C + t X
    # (the Pareto front of (sum X, sum C)), keeping the t with the smallest objective
    ref = max(scale, np.finfo(float).tiny)
    for t in np.logspace(-3, 6, 46) * C_mu / ref * np.abs(C).max() / max(X[X > 0].max(initial=1e-300), 1e-300):
        idx = np.argmin(2.0 * C + t * X, axis=0)
        val = objective(idx)
        if val < best_val:
            best, best_val = idx, val
    moved = best > 0
    chosen = np.array(La)
    chosen[moved] = S[moved, best[moved] - 1][:, None] * Phi[best[moved] - 1]
    lam_t[active] = chosen
    loc2[active] = hk * (Wa * (La - chosen) ** 2).sum(axis=1)
    return lam_t, loc2
