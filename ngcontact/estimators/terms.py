r"""The individual estimator terms of :mod:`.bound` and :mod:`.components`, and their constants.

Notation of :mod:`.bound`: |||v|||^2 = sum_a mu_a ||grad v_a||^2, s_1 = +1, s_2 = -1 (obstacle
s = +1), u~_h = u_h + w_h (:mod:`.dirichlet`), d_h = u~1h - u~2h (obstacle: u~_h - psi).

* flux / residual (:func:`flux_residual`): eta_F,K,a = || mu_a^{1/2} grad u~_ah + mu_a^{-1/2} sigma_ah ||_K
  and eta_R,K,a = h_K/pi mu_a^{-1/2} || f_a + m_a - div sigma_ah ||_K (h_K/pi: Payne-Weinberger
  constant of the convex K; m_a = s_a lam^_h, or s_a lam^_h - r^_a for an inexact iterate);
* element means (:func:`mean_term`): the FE load vector is integrated by quadrature, so the element
  means rbar_a of r_a = f_a + m_a - div sigma_ah vanish only up to that quadrature error; zeta_a in
  RT_0 with div zeta_a = rbar_a gives (rbar_a, z) = -(zeta_a, grad z) on H^1_0, so
  eta_quad = (sum_a ||zeta_a||^2 / mu_a)^{1/2} (zeta: the RT_0 mixed solution from a Crouzeix-Raviart
  solve by Marini's formula, :class:`P0Dual`, or C_F ||rbar|| when that is already negligible);
* multiplier defect (:func:`defect_norm`, :func:`nonnegative_part`): delta = lam^ - lam~ is bounded in
  H^{-1} by Poincare on K for its mean-free part and by an RT_0 field for its means,
  eta_nonc,2 = (sum_a 1/mu_a)^{1/2} [ (sum_K (h_K/pi)^2 ||delta - delta_K||_K^2)^{1/2} + ||zeta_delta|| ];
* nonconformity (:func:`nonconformity`): eta_nonc,1 = |||s~_h - u~_h||| for the admissible s~_h in
  K_g = {v in H^1_g1 x H^1_g2 : v1 - v2 >= 0} below, and n = (s~1 - s~2) - d_h >= 0;
* contact work (:func:`contact_work`): Theta = sum_a mu_a (grad u~_ah, grad v_a) - (f_a, v_a) for
  v = (t n, -(1 - t) n) (obstacle: v = n) of the direct bound;
* constants: element diameters h_K (:func:`element_diameters`), the Friedrichs constant C_F
  (:func:`friedrichs_constant`) and C_mu = (sum_a 1/mu_a)^{1/2}.

Admissible s~_h:

* p = 1, exact data (seed): at the nodes where d_h(a) < 0, s~_1(a) = s~_2(a), a weighted average:
  s~_1 = u1h + t I_1(d_h^-), s~_2 = u2h - (1 - t) I_1(d_h^-), d^- = max(-d, 0), t = mu2/(mu1 + mu2)
  (the |||.|||-optimal split; the seed's average t = 1/2 for mu1 = mu2); s~1 - s~2 = I_1(d_h^+) >= 0.
* otherwise (in place of the seed's three-step construction with c_K for p >= 2): the same split of
  the pointwise negative part, s~_1 = u~1h + t d_h^-, s~_2 = u~2h - (1 - t) d_h^-, in H^1 (not
  piecewise polynomial), s~1 - s~2 = d_h^+ >= 0 everywhere, eta_nonc,1 =
  (mu1 mu2/(mu1 + mu2))^{1/2} ||grad d_h^-||; obstacle: s~_h = max(u~_h, psi).
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Optional

import numpy as np
from ngsolve import (BND, L2, SEGM, TRIG, BilinearForm, CoefficientFunction, FESpace, GridFunction, IfPos, InnerProduct,
                     Integrate, IntegrationRule, LinearForm, VectorL2, div, dx, grad, x, y)

from ..discretizations.base import bit_array, bit_mask
from ..domains import DIRICHLET
from .nonnegative import QuadratureArrays, nonnegative_multiplier
from .options import EstimatorOptions
from .view import DiscretizationView, SolutionView

__all__ = ["Integrals", "element_diameters", "friedrichs_constant", "P0Dual", "flux_residual", "flux_rule_order",
           "mean_term", "defect_norm", "negative_part_squares", "nonnegative_part", "corrected_fields", "split",
           "Nonconformity", "nonconformity",
           "admissible_correction", "contact_work", "direct_root"]

J01 = 2.404825557695773  # first zero of the Bessel function J0


def element_diameters(mesh) -> np.ndarray:
    """h_K = diam(K) per element (longest straight edge), in NGSolve element order."""
    ngmesh = mesh.ngmesh
    P = ngmesh.Coordinates()[ngmesh.Elements2D().NumPy()["nodes"][:, :3] - 1]
    return np.sqrt(((P - np.roll(P, 1, axis=1)) ** 2).sum(axis=-1)).max(axis=1)


def _boundary_points(mesh) -> np.ndarray:
    """Vertices and points on the (possibly curved) boundary edges."""
    mips = mesh.MapToAllElements(IntegrationRule(SEGM, 8), BND)
    return np.vstack([np.asarray(mesh.ngmesh.Coordinates())[:, :2],
                      np.asarray(CoefficientFunction((x, y))(mips)).reshape(-1, 2)])


def friedrichs_constant(problem, mesh) -> float:
    """Upper bound of the Friedrichs constant of the mesh domain: ||v|| <= C_F ||grad v||, v in H^1_0.

    Domain monotonicity of the first Dirichlet eigenvalue lambda_1 = C_F^{-2}:
    the mesh domain lies in the bounding box (Lx x Ly) of its boundary points,
    so C_F <= 1 / (pi (Lx^-2 + Ly^-2)^{1/2}) (unit square: 1/(pi sqrt 2) = 0.2251);
    for a :class:`~ngcontact.domains.UnitDisk` it also lies in the disk of
    radius R = max |x - center| over the boundary points, C_F <= R / j_{0,1},
    j_{0,1} = 2.4048 (unit disk: 0.4158).
    """
    pts = _boundary_points(mesh)
    L = pts.max(axis=0) - pts.min(axis=0)
    cf = 1.0 / (math.pi * math.sqrt(float((1.0 / L ** 2).sum())))
    if type(problem.domain).__name__ == "UnitDisk":
        R = float(np.sqrt(((pts - np.asarray(problem.domain.center)) ** 2).sum(axis=1)).max())
        cf = min(cf, R / J01)
    return cf


class P0Dual:
    """||zeta|| for div zeta = rbar in P0, zeta in RT_0 free on the boundary: the RT_0
    mixed solution of -Lap phi = rbar, phi = 0, from the Crouzeix-Raviart solution
    by Marini's formula zeta = -grad_h phi_CR + rbar/2 (x - x_K) (exact RT_0, Marini 1985).

    Built once per mesh: the CR stiffness A (factorized by SuperLU), the load map B (P0 -> CR, (rbar, v)) and, on
    affine elements, J_K = ||x - x_K||_K^2; a norm then costs one solve:
    ||zeta||^2 = phi^T A phi + sum_K rbar_K^2 J_K / 4 (grad_h phi is constant on K and (x - x_K, 1)_K = 0).
    ``affine=False`` (curved elements): the load and ||zeta||^2 by quadrature of the functions themselves."""

    def __init__(self, mesh, affine: bool = True):
        self.mesh, self.affine = mesh, affine
        self._inv = None

    def _setup(self):
        from scipy.sparse import csr_matrix
        from scipy.sparse.linalg import splu

        mesh = self.mesh
        self.W = FESpace("nonconforming", mesh, dirichlet=DIRICHLET)
        self.P0 = L2(mesh, order=0)
        u, v = self.W.TnT()
        a = BilinearForm(grad(u) * grad(v) * dx).Assemble()
        load = BilinearForm(trialspace=self.P0, testspace=self.W)
        load += self.P0.TrialFunction() * v * dx
        load.Assemble()
        self._B = csr_matrix(tuple(np.array(m) for m in load.mat.CSR()), shape=(self.W.ndof, self.P0.ndof))
        self._A = csr_matrix(tuple(np.array(m) for m in a.mat.CSR()), shape=(self.W.ndof, self.W.ndof))
        # SuperLU of the free block (an NGSolve inverse applied inside a TaskManager was ~8x slower here), in its
        # symmetric mode (A is SPD: minimum degree on A + A^T, diagonal pivots; factors about half as large)
        self._free = np.flatnonzero(bit_mask(self.W.FreeDofs()))
        self._inv = splu(self._A[self._free][:, self._free].tocsc(), permc_spec="MMD_AT_PLUS_A", diag_pivot_thresh=0.0,
                         options={"SymmetricMode": True})
        self.centroid = GridFunction(VectorL2(mesh, order=0))
        self.centroid.Set(CoefficientFunction((x, y)))
        d = CoefficientFunction((x, y)) - self.centroid
        self._J = Integrate(d * d * dx, mesh, element_wise=True).NumPy().copy()
        self._phi = GridFunction(self.W)

    def norm(self, rbar_values: np.ndarray) -> float:
        if self._inv is None:
            self._setup()
        rbar_values = np.asarray(rbar_values, dtype=float)
        if self.affine:
            load = self._B @ rbar_values
        else:  # the quadrature of the linear form (not polynomial on curved elements)
            rbar = GridFunction(self.P0)
            rbar.vec.FV().NumPy()[:] = rbar_values
            load = LinearForm(rbar * self.W.TestFunction() * dx).Assemble().vec.FV().NumPy()
        pv = np.zeros(self.W.ndof)
        pv[self._free] = self._inv.solve(load[self._free])
        if self.affine:
            return math.sqrt(max(float(pv @ (self._A @ pv)) + 0.25 * float((rbar_values ** 2 * self._J).sum()), 0.0))
        self._phi.vec.FV().NumPy()[:] = pv
        zeta = -grad(self._phi) + 0.5 * rbar * (CoefficientFunction((x, y)) - self.centroid)
        return math.sqrt(max(Integrate(zeta * zeta * dx, self.mesh), 0.0))


@dataclass(frozen=True, eq=False)
class Integrals:
    """The quadrature and constants of the estimator integrals on one mesh.

    Attributes
    ----------
    mesh : ngsolve.Mesh
    bonus : int
        extra quadrature order of the estimator integrals (``dxq``).
    h, area : ndarray (ne,)
        element diameters and areas.
    C_F, C_mu : float
        Friedrichs constant and (sum_a 1/mu_a)^{1/2}.
    dual : P0Dual
        the RT_0 lifting of element means (its factorization is kept per discretization).
    rules : dict
        the :class:`.nonnegative.QuadratureArrays` of the mesh per order (:meth:`quadrature`; kept per
        discretization).
    data : dict
        element integrals of load functions with the rule of the element means (:meth:`data_integrals`; kept per
        discretization).
    """

    mesh: object
    bonus: int
    h: np.ndarray
    area: np.ndarray
    C_F: float
    C_mu: float
    dual: P0Dual
    rules: dict = field(default_factory=dict, repr=False)
    data: dict = field(default_factory=dict, repr=False)

    @classmethod
    def of(cls, dv: DiscretizationView, options: EstimatorOptions) -> "Integrals":
        """Call inside ``TaskManager`` (the areas are integrated on first use)."""
        mesh, cache = dv.mesh, dv.cache
        if "area" not in cache:
            cache["area"] = Integrate(CoefficientFunction(1.0) * dx, mesh, element_wise=True).NumPy().copy()
        if "dual" not in cache:
            cache["dual"] = P0Dual(mesh, affine=not dv.curved)
        if "h" not in cache:
            cache["h"] = element_diameters(mesh)
        if "C_F" not in cache:
            cache["C_F"] = friedrichs_constant(dv.problem, mesh)
        bonus = dv.quad_bonus + 4 if options.quad_bonus is None else options.quad_bonus
        C_F = cache["C_F"] if options.friedrichs is None else float(options.friedrichs)
        return cls(mesh=mesh, bonus=bonus, h=cache["h"], area=cache["area"], C_F=C_F,
                   C_mu=math.sqrt(sum(1.0 / mu for mu in dv.mus)), dual=cache["dual"],
                   rules=cache.setdefault("quadrature_arrays", {}), data=cache.setdefault("data_integrals", {}))

    def quadrature(self, order: int) -> QuadratureArrays:
        """The points and weights of the triangle rule of ``order`` on every element (kept)."""
        if order not in self.rules:
            self.rules[order] = QuadratureArrays(self.mesh, order)
        return self.rules[order]

    @property
    def dxq(self):
        return dx(bonus_intorder=self.bonus)

    #: extra quadrature order of the element means of the flux residual (:func:`flux_residual`) over ``dxq``: the
    #: means are the quadrature errors of the data rules, resolved by a finer rule
    MEAN_BONUS = 8

    def dx_mean(self, elements: Optional[np.ndarray] = None):
        """The measure of the element means (``dxq`` + :attr:`MEAN_BONUS`), on the elements of the mask ``elements``
        (default all)."""
        if elements is None:
            return dx(bonus_intorder=self.bonus + self.MEAN_BONUS)
        return dx(bonus_intorder=self.bonus + self.MEAN_BONUS, definedonelements=bit_array(elements))

    def data_integrals(self, f) -> np.ndarray:
        """Element integrals of the load ``f`` with :meth:`dx_mean` (kept per discretization while ``f`` is the same
        object: the same numbers for every estimate on this mesh)."""
        key = (id(f), self.bonus)
        hit = self.data.get(key)
        if hit is None or hit[0] is not f:
            hit = self.data[key] = (f, self.ew(CoefficientFunction(f), self.dx_mean()))  # f referenced: id unique
        return hit[1]

    def ew(self, cf, dxx=None) -> np.ndarray:
        """Element-wise integrals of cf (default measure ``dxq``)."""
        return Integrate(cf.Compile() * (self.dxq if dxx is None else dxx), self.mesh,
                         element_wise=True).NumPy().copy()

    def dxq_on(self, elements: np.ndarray):
        """``dxq`` restricted to the elements of the mask ``elements`` (the same rule on each of them)."""
        return dx(bonus_intorder=self.bonus, definedonelements=bit_array(elements))

    def negative_support(self, gap) -> np.ndarray:
        """The elements where ``gap`` < 0 at a point of the rule of ``dxq`` (bool mask): elsewhere IfPos(-gap, ., 0),
        the negative part of the gap and its gradient vanish at every point of that rule, so the ``dxq`` integrals
        of integrands with that factor (:func:`nonconformity`, :func:`contact_work`) need only these elements
        (the same numbers; contact is a small part of the mesh)."""
        return self.ew(IfPos(-gap, 1.0, 0.0)) > 0.0


def flux_residual(ig: Integrals, fields, sigmas, grads, data, parts=None, fl_rule=None, data_support=None):
    """eta_F,K,a, eta_R,K,a (arrays (nfields, ne)), eta_FR = (sum_K sum_a (eta_F + eta_R)^2)^{1/2} and
    eta_quad for fluxes with div sigma_a ~ f_a + data_a (module doc).  ``parts``: i -> (||fl||_K^2,
    ||res||_K^2, element means of res) of field i computed elsewhere (:mod:`.affine_p1`).  ``fl_rule``: the
    order of a triangle rule exact for the polynomial |fl|^2 (:func:`flux_rule_order`; None: ``dxq``).
    ``data_support``: mask of the elements outside of which every data_a vanishes (None: anywhere).

    The element means of res = f + data - div sigma are summed from the three parts, each with a rule that is
    exact or as fine as the one for res itself: the load's integrals with :meth:`Integrals.dx_mean` (kept per
    mesh), those of data_a with the same rule on ``data_support``, and those of div sigma (P_q on straight
    elements) with the rule of order q there (:meth:`Integrals.dx_mean` on curved ones)."""
    dfl = None if fl_rule is None else dx(intrules={TRIG: IntegrationRule(TRIG, int(fl_rule))})
    eta_F, eta_R = np.zeros((len(fields), ig.mesh.ne)), np.zeros((len(fields), ig.mesh.ne))
    rbar = []
    for i, (fd, sig, gu, m) in enumerate(zip(fields, sigmas, grads, data)):
        mu = fd.mu
        if parts is None:
            fl = math.sqrt(mu) * gu + sig / math.sqrt(mu)
            res = fd.f + m - div(sig)
            fl2, res2 = ig.ew(fl * fl, dfl), ig.ew(res * res)
            ddiv = dx(intrules={TRIG: IntegrationRule(TRIG, int(sig.space.globalorder))}) if ig.dual.affine \
                else ig.dx_mean()
            mean = (ig.data_integrals(fd.f) + ig.ew(m, ig.dx_mean(data_support)) - ig.ew(div(sig), ddiv)) / ig.area
        else:
            fl2, res2, mean = parts(i)
        eta_F[i] = np.sqrt(np.maximum(fl2, 0.0))                                           # eta_F,K,alpha
        eta_R[i] = ig.h / math.pi / math.sqrt(mu) * np.sqrt(np.maximum(res2, 0.0))          # eta_R,K,alpha
        rbar.append(mean)
    eta_FR = float(np.sqrt(((eta_F + eta_R) ** 2).sum()))
    return eta_F, eta_R, eta_FR, mean_term(ig, rbar, [fd.mu for fd in fields], eta_FR)


def flux_rule_order(dv: DiscretizationView, q: int, corrected: bool):
    """Degree of |fl|^2, fl = mu^{1/2} grad u~_h + mu^{-1/2} sigma_h, on straight elements: grad u~_h in
    P_{k-1} (k = p, or p + 2 with the Dirichlet lifting w_h, ``corrected``), sigma_h in RT_q, a subspace of
    P_{q+1}; None on curved elements (not polynomial there)."""
    if dv.curved:
        return None
    return 2 * max((dv.order + 2 if corrected else dv.order) - 1, q + 1)


def mean_term(ig: Integrals, rbar, mus, eta_FR, negligible: float = 1e-3) -> float:
    """eta_quad = (sum_a ||zeta_a||^2 / mu_a)^{1/2}, div zeta_a = rbar_a (module doc)."""
    per = [ig.C_F * math.sqrt(float((m ** 2 * ig.area).sum())) for m in rbar]
    friedrichs = math.sqrt(sum(c ** 2 / mu for c, mu in zip(per, mus)))
    if friedrichs <= negligible * max(eta_FR, np.finfo(float).tiny):
        return friedrichs
    total = sum(min(c, ig.dual.norm(m)) ** 2 / mu for c, m, mu in zip(per, rbar, mus))
    return math.sqrt(total)


def defect_norm(ig: Integrals, delta, ref: float, parts=None):
    """C_mu [(sum_K (h_K/pi)^2 ||delta - delta_K||_K^2)^{1/2} + ||zeta(delta_K)||]: bound of
    sup_z (delta, z1 - z2) / |||z||| (module doc), and the element parts (h_K/pi)^2 ||delta - delta_K||_K^2.
    The RT_0 solve is skipped when C_F ||delta_K|| is below 1e-3 ``ref``.  ``parts``: (element means,
    ||delta - delta_K||_K^2) computed elsewhere."""
    if parts is None:
        dbar = ig.ew(delta) / ig.area
        parts = dbar, ig.ew(delta * delta) - dbar ** 2 * ig.area
    dbar, free2 = parts
    loc_K = (ig.h / math.pi) ** 2 * np.maximum(free2, 0.0)
    dnorm = ig.C_F * math.sqrt(float((dbar ** 2 * ig.area).sum()))
    if dnorm > 1e-3 * max(ref, np.finfo(float).tiny):
        dnorm = min(dnorm, ig.dual.norm(dbar))
    return ig.C_mu * (math.sqrt(float(loc_K.sum())) + dnorm), loc_K


def negative_part_squares(ig: Integrals, lam) -> np.ndarray:
    """Element integrals of (lam^-)^2.  Zero without quadrature when lam is a GridFunction of P1 (H1 of order 1)
    with nonnegative coefficients: its vertex values, and a P1 function with nonnegative vertex values is
    nonnegative (the quadrature of IfPos(-lam, lam^2, 0) gives exactly 0 too)."""
    space = getattr(lam, "space", None)
    if space is not None and type(space).__name__ == "H1" and space.globalorder == 1 \
            and float(lam.vec.FV().NumPy().min(initial=0.0)) >= 0.0:
        return np.zeros(ig.mesh.ne)
    return ig.ew(IfPos(-lam, lam * lam, 0.0))


def nonnegative_part(ig: Integrals, lam, lam_order: int, ref: float):
    """(lam~, eta_nonc,2, element parts): lam~ = lam where lam >= 0 everywhere, else
    :func:`.nonnegative.nonnegative_multiplier` with the defect bounded by :func:`defect_norm`."""
    if float(negative_part_squares(ig, lam).sum()) > 0.0:
        lam_t, _ = nonnegative_multiplier(lam, ig.mesh, lam_order, ig.area)
        nonc2, loc_K = defect_norm(ig, lam - lam_t, ref)
        return lam_t, nonc2, loc_K
    return lam, 0.0, np.zeros(ig.mesh.ne)


def cf_gradient(cf) -> CoefficientFunction:
    """The gradient of a CoefficientFunction of the coordinates (its symbolic derivatives in x and y)."""
    return CoefficientFunction((cf.Diff(x), cf.Diff(y)))


def corrected_fields(dv: DiscretizationView, fields, ws):
    """u~_h = u_h + w_h per field, their gradients, and the gap of u~_h (u~1 - u~2, or u~ - psi) with its gradient."""
    grads = [grad(fd.u) + grad(w) if w is not None else grad(fd.u) for fd, w in zip(fields, ws)]
    vals = [fd.u + w if w is not None else fd.u for fd, w in zip(fields, ws)]
    if dv.obstacle is None:
        return vals, grads, vals[0] - vals[1], grads[0] - grads[1]
    psi = dv.obstacle
    gpsi = dv.obstacle_grad if dv.obstacle_grad is not None else cf_gradient(psi)
    return vals, grads, vals[0] - psi, grads[0] - gpsi


def split(mus):
    """(t, weight): the |||.|||-optimal split t = mu2/(mu1 + mu2) of a gap correction n into
    (t n, -(1 - t) n) and |||(t n, -(1 - t) n)|||^2 = weight ||grad n||^2 (obstacle: t = 1, weight mu)."""
    t = mus[1] / (mus[0] + mus[1]) if len(mus) == 2 else 1.0
    return t, mus[0] * t ** 2 + (mus[1] * (1 - t) ** 2 if len(mus) == 2 else 0.0)


@dataclass(frozen=True, eq=False)
class Nonconformity:
    """The result of :func:`nonconformity`: eta_nonc,1, n, grad n (None when n = 0), the element parts of
    eta_nonc,1^2 (for the marking indicators, or None), ``pointwise``: n is the pointwise negative part max(-d, 0)
    of the gap d (its values are then those of the gap's), and ``support``: a mask of the elements outside of which
    n and grad n vanish at every point of the rule of ``dxq`` (None: the whole mesh)."""

    eta: float
    n: object
    grad_n: object
    loc: Optional[np.ndarray]
    pointwise: bool = False
    support: Optional[np.ndarray] = None

    def values(self, qa: QuadratureArrays, gap_values: np.ndarray, elements=None) -> np.ndarray:
        """n at the points of ``qa`` (of the elements of the index array ``elements``, None: all), given the gap's
        values there: max(-gap, 0) when n is the pointwise negative part (the same numbers as evaluating n, one
        evaluation less), else evaluated."""
        return np.maximum(-gap_values, 0.0) if self.pointwise else qa.values(self.n, elements)


def nonconformity(sv: SolutionView, ig: Integrals, gap, ggap, exact_bc: bool) -> Nonconformity:
    """eta_nonc,1 = |||s~_h - u~_h||| and n = (s~1 - s~2) - d_h >= 0 for the s~_h of the module docstring
    (:class:`Nonconformity`)."""
    dv = sv.disc
    _, weight = split(dv.mus)
    support = None
    if dv.order == 1 and dv.nfields == 2 and exact_bc:
        # seed: nodal averaging where (u1h - u2h)(a) < 0; s~ - u_h = (t, -(1-t)) I_1(d^-)
        nodal = sv.nodal_fields()
        neg = np.maximum(nodal["u2"] - nodal["u1"], 0.0)
        if not neg.any():
            return Nonconformity(0.0, None, None, None)
        corr = dv.function(neg)
        gcorr = grad(corr)
        val_K = Integrate(gcorr * gcorr * dx, ig.mesh, element_wise=True).NumPy().copy()
    else:
        # pointwise negative part of the gap: grad d^- = -grad d on {d < 0}
        support = ig.negative_support(gap)
        val_K = np.zeros(ig.mesh.ne)
        if support.any():
            val_K = Integrate((IfPos(-gap, ggap * ggap, 0.0)).Compile() * ig.dxq_on(support), ig.mesh,
                              element_wise=True).NumPy().copy()
        corr = IfPos(-gap, -gap, 0.0)
        gcorr = IfPos(-gap, -ggap, CoefficientFunction((0.0, 0.0)))
    loc = weight * np.maximum(val_K, 0.0)
    return Nonconformity(math.sqrt(float(loc.sum())), corr, gcorr, loc, pointwise=support is not None, support=support)


def admissible_correction(ig: Integrals, mus, gap_s, ggap_s, exact_polynomial_gap: bool):
    r"""(|||s~_h - (s_h + w_h)|||, (g_s)^-, the elements where (g_s)^- is not zero at a point of the rule of
    ``dxq``, :meth:`Integrals.negative_support`) for the pointwise negative part of the gap of s_h + w_h
    (:mod:`.components`).

    The seed's p >= 2 step 2-3 adds c_K Psi_K / 2 with c_K = min{c > 0 : (s1h - s2h)|_K + c Psi_K >= 0};
    with an element bubble Psi_K this cannot repair a gap that is negative on an EDGE (for P2,
    nodal values a, b, m >= 0 on an edge give a negative gap at t = 1/4 as soon as b > 3a + 6m),
    and a conforming non-bubble Psi_K couples neighbouring c_K.  We use the H^1 function
    (t, -(1 - t)) (g_s)^- instead (t = mu2/(mu1 + mu2)): admissible everywhere, and
    |||.||| = (mu1 mu2/(mu1 + mu2))^{1/2} ||grad (g_s)^-||, no constant to estimate.
    """
    _, weight = split(mus)
    if exact_polynomial_gap:  # P1 gap with nonnegative nodal values: >= 0 everywhere
        return 0.0, None, None
    support = ig.negative_support(gap_s)  # (g_s)^- vanishes at the points of the rule elsewhere
    val = float(Integrate(IfPos(-gap_s, ggap_s * ggap_s, 0.0).Compile() * ig.dxq_on(support), ig.mesh)) \
        if support.any() else 0.0
    return math.sqrt(weight * max(val, 0.0)), IfPos(-gap_s, -gap_s, 0.0), support


def contact_work(ig: Integrals, fields, grads, corr, gcorr, support: Optional[np.ndarray] = None) -> float:
    """Theta = sum_a mu_a (grad u~_ah, grad v_a) - (f_a, v_a) for v = (t n, -(1 - t) n) (obstacle: v = n),
    n = (s~1 - s~2) - d_h the nonnegative correction of :func:`nonconformity` (module doc of
    :mod:`.bound`, "Direct bound"); 0 when n = 0.  ``support``: the elements outside of which n and grad n vanish
    at the points of the rule (:attr:`Nonconformity.support`; None: the whole mesh)."""
    if corr is None or (support is not None and not support.any()):
        return 0.0
    t, _ = split([fd.mu for fd in fields])
    coef = (t, -(1.0 - t)) if len(fields) == 2 else (1.0,)
    cf = CoefficientFunction(0.0)
    for c, fd, gu in zip(coef, fields, grads):
        cf = cf + c * (fd.mu * InnerProduct(gu, gcorr) - fd.f * corr)
    return float(Integrate(cf.Compile() * (ig.dxq if support is None else ig.dxq_on(support)), ig.mesh))


def direct_root(A: float, B: float) -> float:
    """The largest root A/2 + (A^2/4 + max(B, 0))^{1/2} of x^2 = A x + max(B, 0): x^2 <= A x + B bounds x by it.

    >>> direct_root(1.0, 2.0)
    2.0
    """
    return 0.5 * A + math.hypot(0.5 * A, math.sqrt(max(B, 0.0)))
