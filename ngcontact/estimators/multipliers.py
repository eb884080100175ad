r"""The multiplier lam^_h of the equilibration: functions with the hat moments of the discrete multiplier.

Compatibility of an interior patch a is the discrete equation tested with psi_a,
mu (grad u_1h, grad psi_a) - m_a = (f_1, psi_a), with the multiplier moment m_a (p = 1:
m_a = X3_a (psi_a, 1), lumped; p >= 2: m_a = (lam_h, psi_a), dual basis).  Any L2 function lam^_h
with (lam^_h, psi_a) = m_a at every interior vertex makes every patch problem compatible, and
then div sigma_alpha_h = Pi_q f_alpha + s_alpha lam^_h exactly; the a posteriori analysis
(:mod:`.bound`) holds for any such lam^_h, and the bound is sharp when lam^_h is close to lam.
The choices:

* :func:`multiplier_p1` -- the continuous P1 function sum_a c_a psi_a, c_a = m_a / (psi_a, 1)
  (``"p1"``; p = 1: lam_h itself); nonnegative when X3 >= 0, smeared across the free boundary;
* :class:`PatchContactMultiplier` -- the patch constants put on the contact elements of the patch
  (``"contact"``), elementwise P1, keeps the jump of lam at the free boundary;
* :class:`ContactMultiplier` -- the contact-weighted elementwise-P1 L2 fit (``"fit"``), for RT
  degree q >= 3 and curved elements, where the vertex device of :mod:`.moments` is not exact;
* :class:`ShapedContactMultiplier` -- patch sources psi_a s_a lam_h^+ (``"shape"``), following a
  smooth lam inside the contact set (batched patch solver only);
* the dual-basis lam_h itself (``"dual"``).

The multiplier maps are linear in the moments once the contact elements are fixed (from a marker
multiplier y^+), so the positive and negative parts of a Newton iterate's multiplier can be mapped
separately (:mod:`.components`).
"""
from __future__ import annotations

from typing import Optional

import numpy as np
from ngsolve import (H1, L2, TRIG, BilinearForm, CoefficientFunction, Discontinuous, GridFunction, IfPos,
                     IntegrationRule, LinearForm, TaskManager, dx)

from ..discretizations.base import bit_mask
from ..domains import DIRICHLET
from .boundary import boundary_vertices, contact_band
from .moments import data_rules, vertex_moments
from .view import DiscretizationView, SolutionView

__all__ = ["multiplier_p1", "ContactMultiplier", "PatchContactMultiplier", "ShapedContactMultiplier"]


def multiplier_p1(sv: SolutionView) -> GridFunction:
    """lam^_h = sum_a c_a psi_a, c_a = m_a / (psi_a, 1): the P1 multiplier seen by the patches (module doc).

    p = 1: lam_h itself (lumped, m_a = X3_a (psi_a, 1)).  p >= 2: c_a =
    (lam_h, psi_a) / (psi_a, 1), with the FE mass rule (exact on affine
    elements; equal to sum_l psi_a(x_l) X3_l).
    """
    dv = sv.disc
    if dv.order == 1:
        return sv.gfs["lam"]
    V1 = H1(dv.mesh, order=1)
    v = V1.TestFunction()
    rule = data_rules(dv)["mass"]
    with TaskManager():
        mom = LinearForm(sv.gfs["lam"] * v * dx(intrules=rule)).Assemble().vec.FV().NumPy()
        vol = LinearForm(v * dx(intrules=rule)).Assemble().vec.FV().NumPy()
    lam = GridFunction(V1, name="lam_p1")
    lam.vec.FV().NumPy()[:] = mom / vol
    return lam


def _contact_vertices(dv: DiscretizationView, y_marker, tol: float) -> np.ndarray:
    """Vertices whose hat moment of the multiplier y_marker^+ is positive: c_a = m_a / (psi_a, 1) > tol max c."""
    Psi, vol, _ = vertex_moments(dv)
    c = Psi.T @ (dv.D * np.maximum(np.asarray(y_marker, float), 0.0)) / vol
    cmax = float(c.max(initial=0.0))
    return c > tol * cmax if cmax > 0 else np.zeros(dv.mesh.nv, bool)


class ContactMultiplier:
    r"""lam^_h for p >= 2 where the vertex device is not exact (RT degree q >= 3, or curved elements):
    the contact-weighted, elementwise-P1 function with the hat moments of the discrete multiplier.

    The continuous P1 function with the moments m_a smears the jump of lam at the free boundary over
    one element layer on both sides (and under-/overshoots there), which costs O(h^{3/2}) in eta_F
    against an O(h^2) P2 error.  Instead we take the minimizer of sum_K w_K ||lam^||_K^2 under the
    moment constraints of the interior vertices, with weights 1/w_K = 1 on *contact elements* (all
    three vertices with c_a = m_a / (psi_a, 1) > tol max c), ``mixed`` on elements with some,
    ``empty`` on elements with none.  The minimizer is lam^|_K = (1/w_K) nu|_K with nu in P1 solving
    the weighted mass system M_w nu = m (SPD; one sparse Cholesky).

    The weights off the contact elements must be tiny: a vertex of a contact element gets its
    moment from its contact elements, and whatever weight its other elements carry puts a fraction
    ~ (weight) of lam next to the contact set, where the gap u1h - u2h > 0; the contact term
    2 (lam~, d_h) then decays like that fraction times h^3 while the P3 error squared decays like
    h^6 (fitted disk P3: ``tests/test_estimators.py::test_disk_fitted_p3_effectivity``).  A vertex
    with a moment but no contact element (where lam vanishes continuously at the free boundary)
    spreads it over its mixed elements, whatever their weight.  There the weighted mass inverse has
    negative lobes, which cost eta_nonc,2; so ``ROUNDS`` times the weight of every element where
    lam^ (of the marker y^+) is negative somewhere is multiplied by ``DAMP`` and the fit recomputed
    (the moments stay exact for any weights; ``test_contact_fit_reweighting_removes_negative_lobes``).
    lam^ is not nonnegative by construction; :func:`.nonnegative.nonnegative_multiplier` takes care
    of that.  The patch source integrates lam^ psi_a w with the FE mass rule, as M_w is assembled,
    so the moments are matched to round-off also on curved elements.

    Parameters
    ----------
    dv : DiscretizationView (p >= 2)
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
    KEPT = 4      #: weighted mass matrices and factorizations kept per discretization (repeated evaluations)

    def __init__(self, dv: DiscretizationView, y_marker, *, mixed: float = 1e-9, empty: float = 1e-12,
                 tol: float = 1e-8):
        mesh = dv.mesh
        self.Psi = vertex_moments(dv)[0]
        ev = dv.element_vertices()
        k = _contact_vertices(dv, y_marker, tol)[ev].sum(axis=1)
        winv = np.where(k == 3, 1.0, np.where(k > 0, mixed, empty))
        self.contact = k == 3
        self.n_contact_elements = int((k == 3).sum())
        P0 = L2(mesh, order=0)
        self.weight = GridFunction(P0, name="contact_weight")
        if "contact_fit_space" not in dv.cache:
            V = H1(mesh, order=1, dirichlet=DIRICHLET)  # the interior vertices carry constraints
            dv.cache["contact_fit_space"] = (V, bit_mask(V.FreeDofs()))
        self.V, self._free = dv.cache["contact_fit_space"]
        u, v = self.V.TnT()
        m0 = self.Psi.T @ (dv.D * np.maximum(np.asarray(y_marker, float), 0.0))
        kept = dv.cache.setdefault("contact_fit_matrices", [])  # [(weights, matrix, factorization)], newest last
        for r in range(self.ROUNDS + 1):
            self.weight.vec.FV().NumPy()[:] = winv
            hit = next((e for e in kept if np.array_equal(e[0], winv)), None)
            if hit is None:  # the same weights (the same contact set along a Newton step): the same matrix
                with TaskManager():
                    a = BilinearForm(self.weight * u * v * dx(intrules=data_rules(dv)["mass"])).Assemble()
                    hit = (winv.copy(), a, a.mat.Inverse(self.V.FreeDofs(), inverse="sparsecholesky"))
                kept.append(hit)
                if len(kept) > self.KEPT:
                    kept.pop(0)
            _, self._a, self._inv = hit
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

    def __call__(self, functional: np.ndarray, name: str = "lam_hat",
                 boundary: Optional[np.ndarray] = None) -> CoefficientFunction:
        """lam^ for a functional on the interior Lagrange basis (e.g. D X3): (lam^, psi_a) = Psi^T values.
        ``boundary`` ((nv,), NaN where unused): values of nu at Dirichlet boundary vertices (else 0; their
        patches need no compatibility), lifted into the fit (:func:`.boundary.boundary_nodal_values`)."""
        m = self.Psi.T @ np.asarray(functional, float)
        rhs = GridFunction(self.V)
        rhs.vec.FV().NumPy()[:] = np.where(self._free, m, 0.0)
        nu = GridFunction(self.V, name=name)
        if boundary is not None:
            nu.vec.FV().NumPy()[:] = np.where(self._free, 0.0, np.nan_to_num(np.asarray(boundary, float)))
            rhs.vec.data -= self._a.mat * nu.vec
            rhs.vec.FV().NumPy()[~self._free] = 0.0
        nu.vec.data += self._inv * rhs.vec
        return self.weight * nu


class PatchContactMultiplier:
    r"""lam^_h for p >= 2: per-patch constants on the contact elements.

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

    The patch source uses the vertex device of :func:`.moments.vertex_moment_term` with the
    elementwise function G = lam^_h (G|_K(a) = g_a|_K), exact for affine elements and q <= 2, or the
    batched solver's patch-constant sources (exact for every q and on curved elements).

    Parameters
    ----------
    dv : DiscretizationView (p >= 2)
    y_marker : ndarray
        X3 (nonnegative part) defining the contact elements.
    tol : float
        relative threshold for c_b > 0.
    """

    def __init__(self, dv: DiscretizationView, y_marker, *, tol: float = 1e-8):
        mesh = dv.mesh
        Psi, vol, _ = vertex_moments(dv)
        self.Psi = Psi
        ev = dv.element_vertices()
        contact = self.contact = _contact_vertices(dv, y_marker, tol)[ev].all(axis=1)
        self.n_contact_elements = int(contact.sum())
        self.V = Discontinuous(H1(mesh, order=1))  # dof 3K + i = value at vertex i of element K
        c_ = dv.cache
        if "vol_ka" not in c_:
            with TaskManager():
                c_["vol_ka"] = LinearForm(self.V.TestFunction() * dx(intrules=data_rules(dv)["mass"])) \
                    .Assemble().vec.FV().NumPy().reshape(mesh.ne, 3).copy()
        vol_ka = c_["vol_ka"]  # (psi_a, 1)_K
        volC = np.bincount(ev[contact].ravel(), weights=vol_ka[contact].ravel(), minlength=mesh.nv)
        has = volC > 0
        # coefficient of m_a on the (K, i) entries: 1/volC_a on contact K, 0 on others; 1/vol_a if none
        self._coef = np.where(has[ev], np.where(contact[:, None], 1.0 / np.where(has, volC, 1.0)[ev], 0.0),
                              1.0 / vol[ev])
        self._ev = ev

    def __call__(self, functional: np.ndarray, name: str = "lam_hat",
                 boundary: Optional[np.ndarray] = None) -> GridFunction:
        """lam^ (elementwise P1) for a functional on the interior Lagrange basis (e.g. D X3); ``boundary``
        ((ne, 3), NaN where unused): values g_a|_K replacing those of the Dirichlet boundary vertices
        (:func:`.boundary.boundary_vertex_values`; boundary patches need no compatibility)."""
        m = self.Psi.T @ np.asarray(functional, float)
        vals = self._coef * m[self._ev]
        if boundary is not None:
            vals = np.where(np.isnan(boundary), vals, boundary)
        gf = GridFunction(self.V, name=name)
        gf.vec.FV().NumPy()[:] = vals.ravel()
        return gf


class ShapedContactMultiplier:
    r"""lam^_h for the batched solver, p >= 2: patch sources psi_a s_a phi with the shape phi = lam_h^+.

    Patch a sees the source psi_a s_a phi, s_a = m_a / (psi_a phi, 1) >= 0 (the hat moment m_a of
    the discrete multiplier; exact compatibility), when the shape carries the moment
    (1/2 <= s_a <= 2: the patch lies in the contact set, where lam_h >= 0 and s_a ~ 1); every
    other patch uses the patch constant of :class:`PatchContactMultiplier`.  The equilibrated
    multiplier lam^ = sum_a psi_a s_a phi (+ the constant parts) is >= 0 and equals ~lam_h (P_p)
    inside the contact set, where the P1 functions of :class:`ContactMultiplier` and
    :class:`PatchContactMultiplier` cannot follow a curved lam on coarse elements.
    Batched solver only (its shaped sources, :meth:`.patches.PatchSolver.shaped_mass`).

    Parameters
    ----------
    dv : DiscretizationView (p >= 2)
    y_marker : ndarray
        X3 (nonnegative part defines the contact elements of the fallback constants).
    lam_h : GridFunction
        the discrete (dual-basis) multiplier; its positive part is the shape.
    low, high : float
        range of s_a in which the shape is used.
    rule_order : int, optional
        order of the triangle rule of the patch sources (:meth:`.patches.PatchSolver.shaped_rule_order`),
        used for (psi_a phi, 1) too, so that the patch data are compatible to round-off.
    boundary_shape : CoefficientFunction or a function returning one, optional
        (a function: built only when the band below is not empty)
        the shape on the contact elements connected to a Dirichlet boundary vertex of a contact element
        (:func:`.boundary.contact_band`), where the dual-basis lam_h, which vanishes at the boundary
        nodes, is polluted (:func:`.boundary.residual_multiplier`); the boundary vertices then take
        s_a = 1 (their patches need no compatibility), so lam^ ~ boundary_shape^+ there.
    """

    def __init__(self, dv: DiscretizationView, y_marker, lam_h, *, low: float = 0.5, high: float = 2.0,
                 tol: float = 1e-8, rule_order: Optional[int] = None, boundary_shape=None):
        self.low, self.high = float(low), float(high)
        self.const = PatchContactMultiplier(dv, y_marker, tol=tol)
        mesh, V = dv.mesh, self.const.V
        contact = GridFunction(L2(mesh, order=0), name="contact_elements")
        contact.vec.FV().NumPy()[:] = self.const.contact
        self._fixed = np.zeros(mesh.nv, bool)  # vertices with s_a = 1
        band = None if boundary_shape is None else contact_band(dv, self.const.contact)
        if band is None or not band.any():
            self.shape = contact * IfPos(lam_h, lam_h, 0.0)
        else:
            shape = boundary_shape() if callable(boundary_shape) else boundary_shape
            layer = GridFunction(L2(mesh, order=0), name="boundary_band")
            layer.vec.FV().NumPy()[:] = band
            self.shape = contact * IfPos(layer, IfPos(shape, shape, 0.0), IfPos(lam_h, lam_h, 0.0))
        if band is not None:
            self._fixed = boundary_vertices(dv)
        rule = data_rules(dv)["mass"] if rule_order is None else {TRIG: IntegrationRule(TRIG, int(rule_order))}
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
        s = np.where(self._fixed & (self._Aphi > 0), 1.0, s)
        shaped = (s >= self.low) & (s <= self.high)
        vs = np.where(shaped[self._ev], s[self._ev], 0.0)                                   # (ne, 3)
        vc = np.where(shaped[self._ev], 0.0, self.const._coef * m[self._ev])               # (ne, 3)
        gs, gc = GridFunction(self.const.V, name="lam_shape_coef"), GridFunction(self.const.V, name="lam_const")
        gs.vec.FV().NumPy()[:] = vs.ravel()
        gc.vec.FV().NumPy()[:] = vc.ravel()
        self.n_shaped = int(shaped.sum())
        return self.shape * gs + gc, [(vs, self.shape), (vc, None)]
