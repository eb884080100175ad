"""Equilibrated flux reconstruction by vertex-patch mixed problems (seed slide
"Component flux reconstruction"; [JSC20] Section 3; Braess-Schoberl 2008,
Ern-Vohralik SINUM 2015).

For each field alpha the exact flux -mu_alpha grad u_alpha lies in H(div) and

    div(-mu_1 grad u_1) = f_1 + lam,      div(-mu_2 grad u_2) = f_2 - lam,

i.e. div(-mu_a grad u_a) = f_a - (-1)^a lam (obstacle: f + lam); we write
s_1 = +1, s_2 = -1 (obstacle s = +1).  The reconstruction is

    sigma_alpha_h = sum_a sigma^a,   sigma^a in RT_q(T_a) (broken over the patch T_a of the vertex a),

    sigma^a = argmin || mu^{-1/2} (tau + psi_a mu grad u_alpha_h) ||_{omega_a}
              over tau . n = 0 on the part of d(omega_a) inside Omega, with
    (div tau, w)_K = (psi_a (f_alpha + s_alpha c_a) - mu grad psi_a . grad u_alpha_h, w)_K,  w in P_q(K),

solved as a hybridized mixed problem (broken RT_q x P_q x facet P_q
multiplier), every right-hand side term multiplied by the hat function psi_a:
by default with the batched solver of :mod:`.patches` (element condensation
once per mesh, patch systems on the facet unknowns only, all fields in one
call; cached per discretization, :func:`patch_solver`), or with NGSolve's
compiled patch loop ``PatchwiseSolve`` (``batched=False``; same fluxes to
round-off on straight meshes).  Measured flux time, both fields (PatchwiseSolve
-> batched first / second / third and later calls with the cached solver, whose
flux operators and inverses are kept): disk P1, 70k elements, 3.49 s -> 3.39 /
2.06 / 0.52 s; disk P2, 17k elements, 3.47 s -> 2.48 / 1.10 / 0.36 s; test 1 P3,
16k elements, 6.93 s -> 3.69 / 2.15 / 0.62 s.

The multiplier seen by the patches.  Compatibility of an interior patch is
the discrete equation tested with psi_a,
mu (grad u_1h, grad psi_a) - m_a = (f_1, psi_a) with m_a the multiplier moment
(p = 1: m_a = X3_a (psi_a, 1), lumped; p >= 2: m_a = (lam_h, psi_a), dual basis).
We use the constant c_a = m_a / (psi_a, 1) on patch a, so that summing over
the patches the multiplier becomes the P1 function

    lam^_h = sum_a c_a psi_a,     c_a = m_a / (psi_a, 1) >= 0 when X3 >= 0,

(p = 1: lam^_h = lam_h exactly; for p >= 2 this is ``multiplier="p1"``; the
default there, ``"contact"``, keeps the jump of lam at the free boundary
instead of smearing it: :class:`PatchContactMultiplier`, the patch constants
put on the contact elements of the patch only, for q <= 2, and the
contact-weighted L2 fit :class:`ContactMultiplier` for q >= 3).  Then

    div sigma_alpha_h = Pi_q f_alpha + s_alpha lam^_h      (equilibration, exact)

and lam^_h >= 0 as soon as X3 >= 0, also for p >= 2 where the dual-basis
lam_h oscillates and changes sign along the contact boundary (any L2 function
with the hat moments m_a may replace lam_h in the a posteriori analysis, see
:mod:`.estimators`).  The patch-dependent constant c_a is obtained from the
vertex value of the P1 function lam^_h by a vertex quadrature rule (weights
|K|/3) and a Taylor expansion of the test function at the vertex: for affine
K and w in P_2,

    (psi_a, w)_K / (|K|/3) = w(a) + 3/4 grad w(a) . (x_K - a)
                             + 1/2 D^2 w(a) : (S_a / 20 + 9/20 (x_K - a)(x_K - a)^T),

S_a = sum_v (v - a)(v - a)^T over the vertices v of K, x_K the centroid
(moments int lam_a lam_b^2 = |K|/30, int lam_a lam_b lam_c = |K|/60).  This is
implemented for q <= 2; for q >= 3 (or ``multiplier="dual"``) the
dual-basis lam_h itself is used (source psi_a (f + s lam_h), FE mass rule).

Further implementation notes:

* Data quadrature: compatibility holds exactly only if the patch data are
  integrated like the FE system; :func:`data_rules` reproduces the rules of
  :class:`~ngcontact.discretizations.fem.FEMDiscretization` (load: order
  2p + quad_bonus; mass: order 2p).  Pi_q f is the projection for that rule.
* The term with grad psi_a is rewritten by elementwise integration by parts
  (PatchwiseSolve only provides psi_a):
  (grad psi_a . mu grad u, w)_K = -(psi_a, mu (Lap u w + grad u . grad w))_K
  + <psi_a mu grad u . n, w>_dK.
* Interior patches have the singular mode (r, mu_F) = const: the batched
  solver treats it exactly (the eps -> 0 limit, :mod:`.patches`); for
  ``PatchwiseSolve`` a tiny regularization eps (r, w) fixes it; with
  compatible data it leaves the solution unchanged (up to eps * ||r||).  eps = 1e-12 on straight meshes; on
  curved ones (p >= 2, netgen geometries) the vertex-rule multiplier term below is
  not exact, the patch data are compatible only up to that quadrature error,
  which the near-singular solve amplifies by 1/eps: with eps = 1e-12 one patch on
  the interface of ``test2_fitted`` (P2, level 4, 88k dofs) got a flux defect
  that alone made I_eff 4.85; eps = 1e-10 gave 1.122 (1e-8, 1e-6: the same to 4
  digits; measured with PatchwiseSolve before the direct bound, the default estimate now gives 1.044),
  hence :func:`patch_regularization`.
* Curved elements (disk, p >= 2): div sigma = (div-hat sigma-hat) / det J is
  not a mapped polynomial, so equilibration holds in the moment sense
  Pi_q (f + s lam^_h - div sigma) = 0 (checked to 1e-11 on the disk test); the
  Taylor formula above is exact on affine elements only (on curved ones it
  matters only where lam^_h != 0 next to the boundary).

Default RT degree q = p (RT_p, div in P_p, as [JSC20] and Ern-Vohralik): for
p = 1 this is RT_1, which contains psi_a mu grad u_h exactly; on the disk test
RT_1 gives I_eff 1.076 vs 1.40 for RT_0 (level 1).
"""
from __future__ import annotations

import time
import weakref
from dataclasses import dataclass, field
from typing import List, Optional

import numpy as np

from ngsolve import (H1, TRIG, BilinearForm, CoefficientFunction, Discontinuous, FacetFESpace, GridFunction, HDiv,
                     IntegrationRule, L2, LinearForm, TaskManager, Trace, div, dx, grad, specialcf, x, y)
from ngsolve.comp import PatchwiseSolve
from ..domains import DIRICHLET
from .patches import PatchSolver

__all__ = ["FieldData", "FluxReconstruction", "ContactMultiplier", "PatchContactMultiplier", "field_data", "data_rules", "equilibrate",
           "multiplier_p1", "reconstruct_fluxes"]


@dataclass
class FieldData:
    """One membrane (or the obstacle problem's only field).

    Attributes
    ----------
    name : str
        ``"u1"``, ``"u2"`` or ``"u"``.
    mu : float
        tension mu_alpha.
    f : CoefficientFunction
        load f_alpha.
    sign : int
        s_alpha = -(-1)^alpha: div(-mu grad u) = f + s lam  (+1 for u1 / u, -1 for u2).
    u : GridFunction
        discrete solution u_alpha_h (Dirichlet lifting included).
    """

    name: str
    mu: float
    f: CoefficientFunction
    sign: int
    u: GridFunction


def field_data(disc, gfs: dict) -> List[FieldData]:
    """The fields of a discretized problem with their data and signs."""
    prob = disc.problem
    if prob.kind == "membranes":
        return [FieldData("u1", prob.mu1, prob.f1, +1, gfs["u1"]),
                FieldData("u2", prob.mu2, prob.f2, -1, gfs["u2"])]
    return [FieldData("u", prob.mu, prob.f, +1, gfs["u"])]


def data_rules(disc) -> dict:
    """Quadrature rules of the FE system, to be reused by the patch problems.

    ``FEMDiscretization`` assembles the load with ``dx(bonus_intorder=quad_bonus)``
    (NGSolve: rule of order 2p + bonus on triangles) and the mass matrix defining
    the dual basis with the default rule (order 2p), also on curved elements.

    Returns
    -------
    dict
        ``{"load": {TRIG: rule}, "mass": {TRIG: rule}}`` for ``dx(intrules=...)``.
    """
    p = disc.order
    return {"load": {TRIG: IntegrationRule(TRIG, 2 * p + disc.quad_bonus)},
            "mass": {TRIG: IntegrationRule(TRIG, 2 * p)}}


def _vertex_rule() -> IntegrationRule:
    """Trapezoidal (vertex) rule on the reference triangle, weights |K|/3."""
    return IntegrationRule(points=[(0, 0), (1, 0), (0, 1)], weights=[1 / 6, 1 / 6, 1 / 6])


@dataclass
class FluxReconstruction:
    """Result of :func:`reconstruct_fluxes`.

    Attributes
    ----------
    sigma : list of GridFunction
        sigma_alpha_h, one per field, in the broken space ``space`` (normal
        continuity holds by construction; see
        :func:`ngcontact.estimators.checks.normal_jump`).
    fields : list of FieldData
        the fields, same order.
    lam : GridFunction
        the multiplier of the equilibration, div sigma_alpha_h = Pi_q f_alpha + s_alpha lam:
        lam^_h (P1, :func:`multiplier_p1`) for q <= 2 and ``multiplier="p1"``,
        otherwise the dual-basis lam_h.
    order : int
        RT degree q (div sigma in P_q).
    space : HDiv
        broken ``HDiv(order=q, RT=True, discontinuous=True)``.
    time : float
        wall time [s].
    lam_rule : int or None
        order of the triangle rule with which the patch sources integrated lam^ (non-polynomial
        lam^ of :class:`ShapedContactMultiplier`; None: the FE mass rule); the equilibration check
        uses the same rule.
    lam_order : int
        polynomial degree of ``lam``.
    """

    sigma: List[GridFunction]
    fields: List[FieldData]
    lam: GridFunction
    order: int
    space: object
    time: float = 0.0
    lam_order: int = 1
    lam_rule: Optional[int] = None  # order of the TRIG rule of the lam-part of the sources (None: FE mass rule)
    _conforming: dict = field(default_factory=dict, repr=False)

    def conforming(self, i: int) -> GridFunction:
        """sigma_i as a GridFunction of the conforming ``HDiv(order=q, RT=True)``.

        Exact copy (``Set(..., dual=True)`` reproduces normal-continuous RT
        fields to round-off), for output or H(div) post-processing.
        """
        if i not in self._conforming:
            V = HDiv(self.space.mesh, order=self.order, RT=True)
            gf = GridFunction(V, name=f"sigma_{self.fields[i].name}")
            gf.Set(self.sigma[i], dual=True)
            self._conforming[i] = gf
        return self._conforming[i]


def vertex_function_values(disc, g) -> np.ndarray:
    """(ne, 3) values of a vertex function at the local vertices of every element (local order of
    ``Discontinuous(H1(order=1))``): a P1 GridFunction (H1 order 1, dof = vertex) or an elementwise P1
    one (``Discontinuous(H1(order=1))``, dof 3K + i, e.g. :class:`PatchContactMultiplier`)."""
    vals = np.asarray(g.vec.FV().NumPy())
    ne = disc.mesh.ne
    if len(vals) == 3 * ne:
        return vals.reshape(ne, 3).copy()
    if len(vals) != disc.mesh.nv:
        raise ValueError(f"P1 or elementwise P1 GridFunction expected, got {len(vals)} dofs "
                         f"({disc.mesh.nv} vertices, {ne} elements)")
    return vals[_element_vertices(disc)]


def multiplier_p1(disc, gfs: dict) -> GridFunction:
    """lam^_h = sum_a c_a psi_a, c_a = m_a / (psi_a, 1): the P1 multiplier seen by the patches (module doc).

    p = 1: lam_h itself (lumped, m_a = X3_a (psi_a, 1)).  p >= 2: c_a =
    (lam_h, psi_a) / (psi_a, 1), with the FE mass rule (exact on affine
    elements; equal to sum_l psi_a(x_l) X3_l).
    """
    if disc.order == 1:
        return gfs["lam"]
    V1 = H1(disc.mesh, order=1)
    v = V1.TestFunction()
    rule = data_rules(disc)["mass"]
    with TaskManager():
        mom = LinearForm(gfs["lam"] * v * dx(intrules=rule)).Assemble().vec.FV().NumPy()
        vol = LinearForm(v * dx(intrules=rule)).Assemble().vec.FV().NumPy()
    lam = GridFunction(V1, name="lam_p1")
    lam.vec.FV().NumPy()[:] = mom / vol
    return lam


_CACHE: "weakref.WeakKeyDictionary" = weakref.WeakKeyDictionary()


def disc_cache(disc) -> dict:
    """Per-discretization cache (mesh-dependent objects reused along Newton iterations)."""
    try:
        return _CACHE.setdefault(disc, {})
    except TypeError:  # not weak-referenceable: no cache
        return {}


def vertex_moments(disc):
    """(Psi, vol, V1): Psi[l, a] = psi_a(x_l) over interior Lagrange nodes l, vol_a = (psi_a, 1)
    (FE mass rule), V1 = H1(order 1) (vertex a = dof a).  For a functional R on the interior
    Lagrange basis (R_l = (r, phi_l)), Psi^T R are its hat moments R(psi_a) (psi_a in P_p)."""
    c = disc_cache(disc)
    if "psi" not in c:
        mesh = disc.mesh
        V1 = H1(mesh, order=1)
        Psi = disc.nodes.V[disc.interior][:, :mesh.nv].tocsr()  # NGSolve: vertex dof a = vertex a
        v = V1.TestFunction()
        with TaskManager():
            vol = LinearForm(v * dx(intrules=data_rules(disc)["mass"])).Assemble().vec.FV().NumPy().copy()
        c["psi"] = (Psi, vol, V1)
    return c["psi"]


class ContactMultiplier:
    r"""lam^_h for p >= 2 where the vertex device of :class:`PatchContactMultiplier` is not exact
    (RT degree q >= 3, or curved elements): the contact-weighted, elementwise-P1 function with the
    hat moments of the discrete multiplier.

    Any L2 function with the hat moments m_a = (lam_h, psi_a) of the discrete multiplier makes the
    interior patches compatible.  The continuous P1 function with these moments smears the jump of
    lam at the free boundary over one element layer on both sides (and under-/overshoots there),
    which costs O(h^{3/2}) in eta_F against an O(h^2) P2 error (measured I_eff 2.7 -> 6.1 on the
    disk with the interface fitted).  Instead we take the minimizer of sum_K w_K ||lam^||_K^2 under
    the moment constraints of the interior vertices, with weights 1/w_K = 1 on *contact elements*
    (all three vertices with c_a = m_a / (psi_a, 1) > tol max c), ``mixed`` on elements with some,
    ``empty`` on elements with none.  The minimizer is lam^|_K = (1/w_K) nu|_K with nu in P1
    solving the weighted mass system M_w nu = m (SPD; one sparse Cholesky).

    The weights off the contact elements must be tiny: a vertex of a contact element gets its
    moment from its contact elements, and whatever weight its other elements carry puts a
    fraction ~ (weight) of lam next to the contact set, where the gap u1h - u2h > 0; the contact
    term 2 (lam~, d_h) then decays like that fraction times h^3 while the P3 error squared decays
    like h^6.  Measured (disk with the interface fitted, P3, levels 0-2): I_eff 2.16, 6.12, 18.5
    with (mixed, empty) = (1e-3, 1e-6); 1.007, 1.022, 1.161 with (1e-6, 1e-9); 1.005, 1.004, 1.004
    with the default (1e-9, 1e-12) (the sparse Cholesky of M_w is still exact to round-off in the
    moments: equilibration ~1e-12).  A vertex with a moment but no contact element (where lam
    vanishes continuously at the free boundary) spreads it over its mixed elements, whatever
    their weight.  Where lam vanishes continuously at the free boundary the weighted mass
    inverse has negative lobes, which cost eta_nonc,2 (test 1 / L-shape P3 adaptive: the
    largest term after eta_F, I_eff up to 2.9); so ``ROUNDS`` = 3 times the weight of every
    element where lam^ (of the marker y^+) is negative somewhere is multiplied by ``DAMP`` =
    1e-3 and the fit recomputed (the moments stay exact for any weights): eta_nonc,2 drops to
    round-off (L-shape P3 levels 0-2: I_eff 1.464, 1.388, 1.374 -> 1.387, 1.374, 1.372; test 1
    P3 levels 1-2: 1.258, 1.173 -> 1.211, 1.151; fitted disk P2/P3 and test 2 P2 unchanged).

    The weights are fixed by one multiplier (``y_marker``) and the map m -> lam^ is linear, so
    the positive and negative parts of a Newton iterate's multiplier are mapped separately
    (:func:`.components.estimate_components`).  lam^ is not nonnegative by construction (the
    weighted mass inverse); :func:`.estimators.nonnegative_multiplier` takes care of that.
    The patch source integrates lam^ psi_a w with the FE mass rule, as M_w is assembled, so the
    moments are matched to round-off also on curved elements (where the vertex device is not
    exact: P2 on the fitted disk / test 2 meshes, I_eff 1.363, 1.147, 1.084 / 1.809, 1.410, 1.232
    on levels 0-2 against 1.421, 1.185, 1.107 / 2.208, 1.586, 1.324 with the patch constants, measured
    when introduced, before the direct bound; now 1.193, 1.081, 1.047 / 1.441, 1.247, 1.130,
    results/estimators/TABLES.md).

    Parameters
    ----------
    disc : FEMDiscretization (p >= 2)
    y_marker : ndarray
        X3 (nonnegative part used) defining the contact elements.
    mixed, empty : float
        1/w_K on elements with some / no contact vertex (> 0: every interior vertex keeps a
        positive-weight element, so the constraints are always solvable).
    tol : float
        relative threshold for c_a > 0.
    """

    ROUNDS = 3    #: reweighting rounds against negative lobes (class doc)
    DAMP = 1e-3   #: weight factor of an element with negative lam^ per round

    def __init__(self, disc, y_marker, *, mixed: float = 1e-9, empty: float = 1e-12, tol: float = 1e-8):
        mesh = disc.mesh
        self.Psi, self.disc = vertex_moments(disc)[0], disc
        ev = _element_vertices(disc)
        k = _contact_vertices(disc, y_marker, tol)[ev].sum(axis=1)
        winv = np.where(k == 3, 1.0, np.where(k > 0, mixed, empty))
        self.n_contact_elements = int((k == 3).sum())
        P0 = L2(mesh, order=0)
        self.weight = GridFunction(P0, name="contact_weight")
        self.V = H1(mesh, order=1, dirichlet=DIRICHLET)  # the interior vertices carry constraints
        self._free = np.array(list(self.V.FreeDofs()), dtype=bool)
        u, v = self.V.TnT()
        m0 = self.Psi.T @ (disc.D * np.maximum(np.asarray(y_marker, float), 0.0))
        for r in range(self.ROUNDS + 1):
            self.weight.vec.FV().NumPy()[:] = winv
            with TaskManager():
                a = BilinearForm(self.weight * u * v * dx(intrules=data_rules(disc)["mass"])).Assemble()
                self._inv = a.mat.Inverse(self.V.FreeDofs(), inverse="sparsecholesky")
            if r == self.ROUNDS:
                break
            rhs = GridFunction(self.V)
            rhs.vec.FV().NumPy()[:] = np.where(self._free, m0, 0.0)
            nu = GridFunction(self.V)
            nu.vec.data = self._inv * rhs.vec
            vals = nu.vec.FV().NumPy()[:mesh.nv][ev]
            neg = (vals.min(axis=1) < -1e-12 * max(np.abs(vals).max(), 1e-300)) & (winv > 0)
            if not neg.any():
                break
            winv = np.where(neg, winv * self.DAMP, winv)

    def __call__(self, functional: np.ndarray, name: str = "lam_hat") -> CoefficientFunction:
        """lam^ for a functional on the interior Lagrange basis (e.g. D X3): (lam^, psi_a) = Psi^T values."""
        m = self.Psi.T @ np.asarray(functional, float)
        rhs = GridFunction(self.V)
        rhs.vec.FV().NumPy()[:] = np.where(self._free, m, 0.0)
        nu = GridFunction(self.V, name=name)
        nu.vec.data = self._inv * rhs.vec
        return self.weight * nu


class PatchContactMultiplier:
    r"""lam^_h for p >= 2 and RT degree q <= 2: per-patch constants on the contact elements.

    Patch a sees the source psi_a g_a with g_a >= 0 piecewise constant on the patch: on its
    *contact elements* (all three vertices with c_b = m_b / (psi_b, 1) > tol max c, from the
    multiplier ``y_marker``) g_a = m_a / (psi_a, 1)_{contact elements of the patch}, zero on the
    other elements; a patch without contact elements uses the lumped constant m_a / (psi_a, 1) on
    all its elements (the ``multiplier="p1"`` choice).  The patch moment (psi_a g_a, 1) is m_a
    (compatibility, exact), and the multiplier equilibrated by sigma = sum_a sigma^a is

        lam^_h = sum_a psi_a g_a,   lam^_h|_K = the P1 function with the vertex values g_a|_K,

    elementwise P1, discontinuous across the boundary of the contact set and >= 0 whenever the
    moments are (X3 >= 0): no nonnegativity defect (eta_nonc,2 = 0 at convergence), unlike the
    weighted L2 fit of :class:`ContactMultiplier`, whose negative lobes next to a continuous
    free boundary (test 1, L-shape) cost more than they gain.  On meshes fitted to a jump of
    lam (disk) lam^ is zero outside the contact set and ~lam inside, where the continuous P1
    function with the same moments smears the jump over two element layers.

    The patch source uses the vertex-rule device of :func:`_vertex_moment_term` with the
    elementwise function G = lam^_h (G|_K(a) = g_a|_K), exact for affine elements and q <= 2.

    Parameters
    ----------
    disc : FEMDiscretization (p >= 2)
    y_marker : ndarray
        X3 (nonnegative part) defining the contact elements.
    tol : float
        relative threshold for c_b > 0.
    """

    def __init__(self, disc, y_marker, *, tol: float = 1e-8):
        mesh = disc.mesh
        Psi, vol, _ = vertex_moments(disc)
        self.Psi, self.disc = Psi, disc
        ev = _element_vertices(disc)
        contact = self.contact = _contact_vertices(disc, y_marker, tol)[ev].all(axis=1)
        self.n_contact_elements = int(contact.sum())
        self.V = Discontinuous(H1(mesh, order=1))  # dof 3K + i = value at vertex i of element K
        c_ = disc_cache(disc)
        if "vol_ka" not in c_:
            with TaskManager():
                c_["vol_ka"] = LinearForm(self.V.TestFunction() * dx(intrules=data_rules(disc)["mass"])) \
                    .Assemble().vec.FV().NumPy().reshape(mesh.ne, 3).copy()
        vol_ka = c_["vol_ka"]  # (psi_a, 1)_K
        volC = np.bincount(ev[contact].ravel(), weights=vol_ka[contact].ravel(), minlength=mesh.nv)
        has = volC > 0
        # coefficient of m_a on the (K, i) entries: 1/volC_a on contact K, 0 on others; 1/vol_a if none
        self._coef = np.where(has[ev], np.where(contact[:, None], 1.0 / np.where(has, volC, 1.0)[ev], 0.0),
                              1.0 / vol[ev])
        self._ev = ev

    def __call__(self, functional: np.ndarray, name: str = "lam_hat") -> GridFunction:
        """lam^ (elementwise P1) for a functional on the interior Lagrange basis (e.g. D X3)."""
        m = self.Psi.T @ np.asarray(functional, float)
        gf = GridFunction(self.V, name=name)
        gf.vec.FV().NumPy()[:] = (self._coef * m[self._ev]).ravel()
        return gf


class ShapedContactMultiplier:
    r"""lam^_h for the batched solver, p >= 2: patch sources psi_a s_a phi with the shape phi = lam_h^+.

    Patch a sees the source psi_a s_a phi, s_a = m_a / (psi_a phi, 1) >= 0 (the hat moment m_a of
    the discrete multiplier; exact compatibility), when the shape carries the moment
    (1/2 <= s_a <= 2: the patch lies in the contact set, where lam_h >= 0 and s_a ~ 1); every
    other patch uses the patch constant of :class:`PatchContactMultiplier`.  The equilibrated
    multiplier lam^ = sum_a psi_a s_a phi (+ the constant parts) is >= 0 and equals ~lam_h (P_p)
    inside the contact set, where the P1 functions of :class:`ContactMultiplier` and
    :class:`PatchContactMultiplier` cannot follow a curved lam on coarse elements (L-shape P3,
    adaptive level 6: ||lam^ - lam||_K / ||lam||_K 0.73 with the fit, 0.05 with lam_h).
    Batched solver only (its shaped sources, :meth:`.patches.PatchSolver.shaped_mass`).

    Parameters
    ----------
    disc : FEMDiscretization (p >= 2)
    y_marker : ndarray
        X3 (nonnegative part defines the contact elements of the fallback constants).
    lam_h : GridFunction
        the discrete (dual-basis) multiplier; its positive part is the shape.
    low, high : float
        range of s_a in which the shape is used.
    rule_order : int, optional
        order of the triangle rule of the patch sources (:meth:`.patches.PatchSolver.shaped_rule_order`),
        used for (psi_a phi, 1) too, so that the patch data are compatible to round-off.
    """

    def __init__(self, disc, y_marker, lam_h, *, low: float = 0.5, high: float = 2.0, tol: float = 1e-8,
                 rule_order: Optional[int] = None):
        from ngsolve import IfPos

        self.low, self.high = float(low), float(high)
        self.const = PatchContactMultiplier(disc, y_marker, tol=tol)
        mesh, V = disc.mesh, self.const.V
        contact = GridFunction(L2(mesh, order=0), name="contact_elements")
        contact.vec.FV().NumPy()[:] = self.const.contact
        self.shape = contact * IfPos(lam_h, lam_h, 0.0)
        rule = data_rules(disc)["mass"] if rule_order is None else {TRIG: IntegrationRule(TRIG, int(rule_order))}
        with TaskManager():
            A = LinearForm(self.shape * V.TestFunction() * dx(intrules=rule)) \
                .Assemble().vec.FV().NumPy().reshape(mesh.ne, 3)                 # (psi_i phi, 1)_K
        self._ev = self.const._ev
        self._Aphi = np.bincount(self._ev.ravel(), weights=A.ravel(), minlength=mesh.nv)  # (psi_a phi, 1)

    def terms(self, functional: np.ndarray):
        """(lam^ CoefficientFunction, [(values, shape), (values, None)]) for a functional on the
        interior Lagrange basis (e.g. D X3)."""
        m = self.const.Psi.T @ np.asarray(functional, float)
        s = np.where(self._Aphi > 0, m / np.where(self._Aphi > 0, self._Aphi, 1.0), -1.0)
        shaped = (s >= self.low) & (s <= self.high)
        vs = np.where(shaped[self._ev], s[self._ev], 0.0)                                   # (ne, 3)
        vc = np.where(shaped[self._ev], 0.0, self.const._coef * m[self._ev])               # (ne, 3)
        gs, gc = GridFunction(self.const.V, name="lam_shape_coef"), GridFunction(self.const.V, name="lam_const")
        gs.vec.FV().NumPy()[:] = vs.ravel()
        gc.vec.FV().NumPy()[:] = vc.ravel()
        self.n_shaped = int(shaped.sum())
        return self.shape * gs + gc, [(vs, self.shape), (vc, None)]


def _contact_vertices(disc, y_marker, tol: float) -> np.ndarray:
    """Vertices whose hat moment of the multiplier y_marker^+ is positive: c_a = m_a / (psi_a, 1) > tol max c."""
    Psi, vol, _ = vertex_moments(disc)
    c = Psi.T @ (disc.D * np.maximum(np.asarray(y_marker, float), 0.0)) / vol
    cmax = float(c.max(initial=0.0))
    return c > tol * cmax if cmax > 0 else np.zeros(disc.mesh.nv, bool)


def _element_vertices(disc) -> np.ndarray:
    """(ne, 3) vertex numbers of the elements (cached)."""
    c = disc_cache(disc)
    if "ev" not in c:
        c["ev"] = disc.mesh.ngmesh.Elements2D().NumPy()["nodes"][:, :3].astype(np.int64) - 1
    return c["ev"]


def _vertex_moment_term(mesh, lam, q: int):
    """w -> integrand whose vertex-rule integral is (psi_a lam(a), w)_K, w in P_q, q <= 2 (module doc)."""
    ngmesh = mesh.ngmesh
    P = ngmesh.Coordinates()[ngmesh.Elements2D().NumPy()["nodes"][:, :3] - 1][:, :, :2]
    P0 = L2(mesh, order=0)

    def piecewise(values):
        gf = GridFunction(P0)
        gf.vec.FV().NumPy()[:] = values
        return gf

    xc, yc = piecewise(P[:, :, 0].mean(axis=1)), piecewise(P[:, :, 1].mean(axis=1))
    dxc, dyc = xc - x, yc - y  # x_K - a at the vertex a
    if q >= 2:
        vxx = piecewise((P[:, :, 0] ** 2).sum(axis=1))
        vxy = piecewise((P[:, :, 0] * P[:, :, 1]).sum(axis=1))
        vyy = piecewise((P[:, :, 1] ** 2).sum(axis=1))
        # S_a = sum_v (v - a)(v - a)^T,  M = S_a/20 + 9/20 (x_K - a)(x_K - a)^T
        Mxx = (vxx - 6 * xc * x + 3 * x * x) / 20 + 0.45 * dxc * dxc
        Mxy = (vxy - 3 * (xc * y + x * yc) + 3 * x * y) / 20 + 0.45 * dxc * dyc
        Myy = (vyy - 6 * yc * y + 3 * y * y) / 20 + 0.45 * dyc * dyc

    def term(w):
        out = w
        if q >= 1:
            gw = grad(w)
            out = out + 0.75 * (gw[0] * dxc + gw[1] * dyc)
        if q >= 2:
            H = w.Operator("hesse")
            out = out + 0.5 * (H[0, 0] * Mxx + 2 * H[0, 1] * Mxy + H[1, 1] * Myy)
        return (lam * out).Compile()
    return term


#: eps of the patch regularization eps (r, w) on straight / curved meshes (module doc)
REGULARIZATION, REGULARIZATION_CURVED = 1e-12, 1e-10


def is_curved(disc) -> bool:
    """Curved elements: a netgen geometry with a curved boundary or interface and p >= 2
    (``FEMDiscretization`` calls ``mesh.Curve(p)`` then)."""
    return bool(getattr(disc.problem.domain, "curved", False)) and disc.order > 1


def vertex_device_exact(disc, q: int) -> bool:
    """The patch-constant vertex device (:func:`_vertex_moment_term`) is exact: q <= 2 and affine elements."""
    return q <= 2 and not is_curved(disc)


def patch_regularization(disc, given: Optional[float] = None) -> float:
    """``given``, or the default eps for ``disc``: larger on curved meshes (module doc)."""
    if given is not None:
        return float(given)
    return REGULARIZATION_CURVED if is_curved(disc) else REGULARIZATION


def _mixed_patch_problem(mesh, q: int, regularization: float):
    """Hybridized broken RT_q x P_q x facet-P_q space and the patch bilinear form."""
    V = HDiv(mesh, order=q, RT=True, discontinuous=True)
    Q = L2(mesh, order=q)
    F = FacetFESpace(mesh, order=q, dirichlet=DIRICHLET)  # no flux condition on the Dirichlet boundary
    X = V * Q * F
    (s, r, m), (tau, w, v) = X.TnT()
    n = specialcf.normal(2)
    # symmetric saddle point; rows tau, w, v
    bf = ((s * tau - r * div(tau) - div(s) * w - regularization * r * w) * dx
          + (s * n * v + tau * n * m) * dx(element_boundary=True))
    return V, X, bf, (tau, w)


def _times(cf, form):
    """The SumOfIntegrals ``form`` with every integrand multiplied by ``cf``."""
    out = None
    for integral in form:
        term = (cf * integral.coef) * integral.symbol
        out = term if out is None else out + term
    return out


def patch_solver(disc, q: int) -> PatchSolver:
    """The batched :class:`.patches.PatchSolver` of ``disc``'s mesh for RT degree q (cached per
    discretization: reused for every field, every Newton iterate and the algebraic fluxes)."""
    c = disc_cache(disc)
    key = ("patch_solver", int(q))
    if key not in c:
        mesh = disc.mesh
        _, X, bf, _ = _mixed_patch_problem(mesh, q, 0.0)  # the eps -> 0 limit, exactly (.patches)
        c[key] = PatchSolver(mesh, X, bf, _element_vertices(disc))
    return c[key]


@dataclass
class PatchData:
    """The data of one patchwise equilibration (:func:`equilibrate`): potential ``u`` (H1
    GridFunction), constant ``mu``, ``source`` (w -> SumOfIntegrals, the term -(g, w) before the
    hat weighting, or None), ``hessian`` (Laplacian of u in the integration by parts; False for
    P1), ``bonus_intorder`` of the flux terms, ``name`` of the result, and ``vertex_values``
    (batched solver only): further patch-constant sources, patch a sees -(psi_a g_a, w)
    with g_a|_K = vertex_values[K, i] for the local vertex i of K that is a (exact for every RT
    degree and on curved elements; the vertex device :func:`_vertex_moment_term` is the
    ``PatchwiseSolve`` counterpart, exact for q <= 2 on affine elements), given as a list of
    (values, shape) pairs: g_a|_K = values[K, i] shape (shape None: 1; :class:`ShapedContactMultiplier`)."""

    u: object
    mu: float
    source: Optional[object] = None
    hessian: bool = True
    bonus_intorder: int = 0
    name: str = "sigma"
    vertex_values: Optional[object] = None


def _flux_terms(u, tau, w, mu, hessian: bool, bonus: int):
    """The u-part of the patch right-hand side (before the hat weighting), linear in u:
    -(mu grad u, tau) - mu (Lap u w + grad u . grad w) + mu <grad u . n, w>_dK."""
    n = specialcf.normal(2)
    gu = grad(u)
    lap = Trace(u.Operator("hesse")) if hessian else CoefficientFunction(0.0)
    lf = (-mu * gu * tau - mu * (lap * w + gu * grad(w))) * dx(bonus_intorder=bonus)
    lf += mu * (gu * n) * w * dx(element_boundary=True, bonus_intorder=bonus)
    return lf


def _patch_rhs(X, d: PatchData, flux_part: bool = True):
    """The right-hand side of the patch problems on X (every term is multiplied by psi_a):
    (s, tau) - (r, div tau) + <tau.n, m> = -(psi_a mu grad u, tau)   [mu constant]
    -(div s, w) - eps (r, w) = -(psi_a g, w) + (mu grad psi_a . grad u, w), with
    (grad psi_a . grad u, w)_K = -(psi_a, Lap u w + grad u . grad w)_K + <psi_a grad u . n, w>_dK.
    ``flux_part=False``: only the source part (None if there is none)."""
    tau, w = X.TestFunction()[:2]  # X = V x Q x F (PatchwiseSolve) or V x Q (batched: no facet rows)
    lf = _flux_terms(d.u, tau, w, d.mu, d.hessian, d.bonus_intorder) if flux_part else None
    if d.source is not None:
        lf = d.source(w) if lf is None else lf + d.source(w)
    return lf


def _vertex_terms(d: PatchData):
    """The ``vertex`` entry of :meth:`.patches.PatchSolver.solve` for ``d.vertex_values``."""
    if d.vertex_values is None:
        return None
    return [(values, d.bonus_intorder + 1, shape) for values, shape in d.vertex_values]


def _flux_operator(solver: PatchSolver, d: PatchData):
    """The ``linear`` entry of :meth:`.patches.PatchSolver.solve` for the flux terms of ``d``, or
    None when u is not a GridFunction.  The bilinear forms get one more quadrature order than the
    linear forms (their default order does not count the hat factor; then both are exact on
    straight meshes and agree to round-off on curved ones)."""
    space = getattr(d.u, "space", None)
    if space is None or not hasattr(d.u, "vec"):
        return None
    tau, w = solver.Y.TestFunction()[:2]
    trial = space.TrialFunction()
    hessian, bonus = bool(d.hessian), int(d.bonus_intorder) + 1

    def form_of_hat(hat):
        return _times(hat, _flux_terms(trial, tau, w, 1.0, hessian, bonus))

    key = ("flux", id(space), space.ndof, hessian, bonus)
    return key, space, form_of_hat, d.u.vec.FV().NumPy(), float(d.mu)


def equilibrate_all(mesh, q: int, data, *, regularization: float = 1e-12, solver: Optional[PatchSolver] = None):
    """Patchwise equilibrated fluxes for several :class:`PatchData` on one mesh (module docstring).

    With ``solver`` (:func:`patch_solver`) all of them are computed in one batched solve (the
    eps -> 0 limit of the regularized patch problems, :mod:`.patches`); without, by NGSolve's
    ``PatchwiseSolve`` with eps = ``regularization``, one call per entry.

    Returns
    -------
    list of GridFunction
        sigma = sum_a sigma^a in ``HDiv(order=q, RT=True, discontinuous=True)``, one per entry.
    """
    out = []
    if solver is not None:
        linear = [_flux_operator(solver, d) for d in data]
        lfs = [_patch_rhs(solver.Y, d, flux_part=lin is None) for d, lin in zip(data, linear)]
        vertex = [_vertex_terms(d) for d in data]
        coefs = solver.solve([None if lf is None else (lambda hat, lf=lf: _times(hat, lf)) for lf in lfs], linear,
                             vertex)
        for d, c in zip(data, coefs):
            sig = GridFunction(solver.X.components[0], name=d.name)
            sig.vec.FV().NumPy()[:] = c.ravel()
            out.append(sig)
        return out
    if any(d.vertex_values is not None for d in data):
        raise ValueError("vertex_values (patch-constant sources) need the batched solver")
    V, X, bf, _ = _mixed_patch_problem(mesh, q, regularization)
    for d in data:
        gf = GridFunction(X)
        with TaskManager():
            PatchwiseSolve(bf, _patch_rhs(X, d), gf)
        sig = GridFunction(V, name=d.name)
        sig.vec.data = gf.components[0].vec
        out.append(sig)
    return out


def equilibrate(mesh, u, mu: float, q: int, source=None, *, bonus_intorder: int = 0,
                regularization: float = 1e-12, hessian: bool = True, name: str = "sigma",
                solver: Optional[PatchSolver] = None) -> GridFunction:
    """One patchwise equilibrated flux sigma ~ -mu grad u in broken RT_q (module docstring).

    Solves, on every vertex patch, the mixed problem with
    (div sigma^a, w)_K = (psi_a g, w)_K - (mu grad psi_a . grad u, w)_K, where the
    source part is given as a function ``source(w) -> (form whose integrand is
    multiplied by psi_a)`` representing -(psi_a g, w) (sign of the w-row).
    Parameters as in :class:`PatchData` and :func:`equilibrate_all`.

    Returns
    -------
    GridFunction
        sigma = sum_a sigma^a in ``HDiv(order=q, RT=True, discontinuous=True)``.
    """
    d = PatchData(u=u, mu=mu, source=source, hessian=hessian, bonus_intorder=bonus_intorder, name=name)
    return equilibrate_all(mesh, q, [d], regularization=regularization, solver=solver)[0]


def reconstruct_fluxes(disc, x_sol=None, y_sol=None, *, gfs: Optional[dict] = None, order: Optional[int] = None,
                       regularization: Optional[float] = None, bonus_intorder: Optional[int] = None,
                       multiplier: Optional[str] = None, batched: bool = True) -> FluxReconstruction:
    """Equilibrated fluxes sigma_alpha_h of a conforming FE solution (module doc).

    Parameters
    ----------
    disc : FEMDiscretization
    x_sol, y_sol : ndarray
        algebraic solution (x = [X1, X2] at interior nodes, y = X3); not
        needed if ``gfs`` is given.
    gfs : dict, optional
        ``disc.gridfunctions(x, y)`` if already computed.
    order : int, optional
        RT degree q; default ``disc.order`` (RT_p).
    regularization : float, optional
        eps of the term eps (r, w) fixing the constants of interior patches in the
        ``PatchwiseSolve`` path (default :func:`patch_regularization`: 1e-12, 1e-10 on curved
        meshes); the batched path solves the eps -> 0 limit exactly.
    batched : bool
        use the batched patch solver of :mod:`.patches` (default; cached per discretization)
        instead of NGSolve's ``PatchwiseSolve`` (same fluxes to round-off on straight meshes).
    bonus_intorder : int, optional
        extra quadrature order of the flux terms (default 0 on straight
        meshes, 4 on curved ones where integrands are not polynomial).
    multiplier : {"contact", "fit", "p1", "dual"}, optional
        multiplier of the patch data for p >= 2.  Default: :class:`PatchContactMultiplier` for
        q <= 2 on straight meshes, else :class:`ContactMultiplier`.  ``"contact"``:
        :class:`PatchContactMultiplier` (for q >= 3 or curved elements only with ``batched``, whose
        patch-constant sources are exact there; else as the default), ``"shape"``
        (:class:`ShapedContactMultiplier`, batched only; else "fit"), ``"fit"`` (always :class:`ContactMultiplier`),
        the continuous P1 function lam^_h with the lumped patch
        constants (q <= 2; nonnegative when X3 >= 0, but smeared across the
        free boundary) or the dual-basis lam_h.  p = 1: always lam_h (lumped).

    Returns
    -------
    FluxReconstruction
    """
    t0 = time.perf_counter()
    if gfs is None:
        gfs = disc.gridfunctions(x_sol, y_sol)
    mesh, p = disc.mesh, disc.order
    q = p if order is None else int(order)
    if q < 0 or (p == 1 and q > 2):
        raise ValueError(f"order (RT degree) must be 0, 1 or 2 for p = 1 and >= 0 otherwise, got {q}")
    bonus = (4 if is_curved(disc) else 0) if bonus_intorder is None else int(bonus_intorder)
    rules = data_rules(disc)
    fields = field_data(disc, gfs)
    auto = multiplier is None
    multiplier = "contact" if multiplier is None else multiplier
    if multiplier not in ("contact", "fit", "shape", "p1", "dual"):
        raise ValueError(f"multiplier must be 'contact', 'fit', 'shape', 'p1' or 'dual', got {multiplier!r}")
    if multiplier == "p1" and q > 2 and p > 1:
        raise ValueError(f"multiplier 'p1' needs RT degree <= 2, got {q}")
    lam_order = 1
    if multiplier in ("contact", "fit", "shape") and p > 1 and y_sol is None:
        raise ValueError("the contact multiplier needs y_sol (X3)")
    if multiplier == "contact" and p > 1 and (auto or not batched) and not vertex_device_exact(disc, q):
        # default for q >= 3 / curved elements: the weighted fit (sharper than the patch constants on
        # continuous free boundaries: test 1 P3 I_eff 1.151 vs 1.220 on T2); explicit "contact" keeps the
        # patch constants there in the batched path (exact sources), PatchwiseSolve needs the vertex device
        multiplier = "fit"
    vertex_values = None
    if multiplier == "shape" and not batched:
        multiplier = "fit"  # shaped patch sources exist only in the batched solver
    lam_rule = None
    if p > 1 and multiplier == "shape":
        lam_rule = patch_solver(disc, q).shaped_rule_order(bonus + 1)
        lam, vertex_values = ShapedContactMultiplier(disc, y_sol, gfs["lam"], rule_order=lam_rule) \
            .terms(disc.D * np.asarray(y_sol, float))
        lam_term, lam_order = None, p
    elif p == 1 or multiplier in ("p1", "contact"):
        if p == 1 or multiplier == "p1":
            lam = multiplier_p1(disc, gfs)
        else:
            lam = PatchContactMultiplier(disc, y_sol)(disc.D * np.asarray(y_sol, float))
        if batched:  # patch-constant sources, exact for every q and on curved elements
            vertex_values = [(vertex_function_values(disc, lam), None)]
            lam_term = None
        else:
            lam_term, lam_dx = _vertex_moment_term(mesh, lam, q), dx(intrules={TRIG: _vertex_rule()})
    else:  # lam^ (contact-weighted L2 fit) or the dual-basis lam_h: exact product with the FE mass rule
        if multiplier == "fit":
            lam = ContactMultiplier(disc, y_sol)(disc.D * np.asarray(y_sol, float))
        else:
            lam, lam_order = gfs["lam"], p

        def lam_term(w):
            return lam * w
        lam_dx = dx(intrules=rules["mass"])

    data = []
    for fd in fields:
        def source(w, fd=fd):  # -(psi_a (f + s lam_h), w), data quadrature as in the FE system
            out = -fd.f * w * dx(intrules=rules["load"])
            return out if lam_term is None else out - fd.sign * lam_term(w) * lam_dx
        data.append(PatchData(u=fd.u, mu=fd.mu, source=source, hessian=p > 1, bonus_intorder=bonus,
                              name=f"sigma_{fd.name}",
                              vertex_values=None if vertex_values is None else
                              [(fd.sign * v, shape) for v, shape in vertex_values]))
    solver = patch_solver(disc, q) if batched else None
    sigmas = equilibrate_all(mesh, q, data, regularization=patch_regularization(disc, regularization),
                             solver=solver)
    V = sigmas[0].space
    return FluxReconstruction(sigma=sigmas, fields=fields, lam=lam, order=q, space=V,
                              time=time.perf_counter() - t0, lam_order=lam_order, lam_rule=lam_rule)

