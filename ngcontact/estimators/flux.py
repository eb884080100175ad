r"""Equilibrated flux reconstruction by vertex-patch mixed problems (seed slide "Component flux
reconstruction"; [JSC20] Section 3; Braess-Schoberl 2008, Ern-Vohralik SINUM 2015).

For each field alpha the exact flux -mu_alpha grad u_alpha lies in H(div) and

    div(-mu_1 grad u_1) = f_1 + lam,      div(-mu_2 grad u_2) = f_2 - lam,

i.e. div(-mu_a grad u_a) = f_a - (-1)^a lam (obstacle: f + lam); we write
s_1 = +1, s_2 = -1 (obstacle s = +1).  The reconstruction is

    sigma_alpha_h = sum_a sigma^a,   sigma^a in RT_q(T_a) (broken over the patch T_a of the vertex a),

    sigma^a = argmin || mu^{-1/2} (tau + psi_a mu grad u_alpha_h) ||_{omega_a}
              over tau . n = 0 on the part of d(omega_a) inside Omega, with
    (div tau, w)_K = (psi_a (f_alpha + s_alpha lam^_h) - mu grad psi_a . grad u_alpha_h, w)_K,  w in P_q(K),

solved as a hybridized mixed problem (broken RT_q x P_q x facet P_q multiplier), every right-hand
side term multiplied by the hat function psi_a: by default with the batched solver of
:mod:`.patches` (element condensation once per mesh, patch systems on the facet unknowns only, all
fields in one call; cached per discretization, :func:`patch_solver`), or with NGSolve's compiled
patch loop ``PatchwiseSolve`` (``batched=False``; same fluxes to round-off on straight meshes).
lam^_h is a function with the hat moments of the discrete multiplier (:mod:`.multipliers`), so
every patch problem is compatible and

    div sigma_alpha_h = Pi_q f_alpha + s_alpha lam^_h      (equilibration, exact).

Implementation notes:

* Data quadrature: the patch data are integrated with the rules of the FE system
  (:func:`.moments.data_rules`); Pi_q f is the projection for that rule.
* The term with grad psi_a is rewritten by elementwise integration by parts
  (PatchwiseSolve only provides psi_a):
  (grad psi_a . mu grad u, w)_K = -(psi_a, mu (Lap u w + grad u . grad w))_K
  + <psi_a mu grad u . n, w>_dK.
* Interior patches have the singular mode (r, mu_F) = const: the batched solver treats it exactly
  (the eps -> 0 limit, :mod:`.patches`); for ``PatchwiseSolve`` a tiny regularization eps (r, w)
  fixes it; with compatible data it leaves the solution unchanged (up to eps * ||r||).
  eps = 1e-12 on straight meshes; on curved ones (p >= 2, netgen geometries) the vertex device of
  the multiplier term is not exact, the patch data are compatible only up to that quadrature
  error, which the near-singular solve amplifies by 1/eps; hence the larger eps of
  :func:`patch_regularization` there.
* Curved elements (disk, p >= 2): div sigma = (div-hat sigma-hat) / det J is not a mapped
  polynomial, so equilibration holds in the moment sense Pi_q (f + s lam^_h - div sigma) = 0.

Default RT degree q = p (RT_p, div in P_p, as [JSC20] and Ern-Vohralik; p + 1 on request,
:meth:`.options.EstimatorOptions.flux_degree`): for p = 1 this is RT_1, which contains
psi_a mu grad u_h exactly.
"""
from __future__ import annotations

import time
from dataclasses import dataclass, field
from typing import List, Optional

import numpy as np

from ngsolve import (TRIG, CoefficientFunction, FacetFESpace, GridFunction, HDiv, IntegrationRule, L2, TaskManager,
                     Trace, div, dx, grad, specialcf)
from ngsolve.comp import PatchwiseSolve

from ..discretizations.base import element_edges
from ..domains import DIRICHLET
from .boundary import boundary_nodal_values, boundary_vertex_values, residual_multiplier
from .moments import data_rules, vertex_function_values, vertex_moment_term, vertex_rule
from .multipliers import ContactMultiplier, PatchContactMultiplier, ShapedContactMultiplier, multiplier_p1
from .options import MULTIPLIERS, EstimatorOptions
from .mixed_blocks import AffineTriangles, flux_operators, mixed_element_blocks
from .patches import PatchSolver
from .view import REPEATED, DiscretizationView, FieldData, SolutionView

__all__ = ["FluxReconstruction", "PatchData", "equilibrate", "equilibrate_all", "flux_bonus", "patch_solver",
           "patch_regularization", "reconstruct", "reconstruct_fluxes", "reconstruct_several", "vertex_device_exact"]


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
        the multiplier of the equilibration, div sigma_alpha_h = Pi_q f_alpha + s_alpha lam
        (:mod:`.multipliers`).
    order : int
        RT degree q (div sigma in P_q).
    space : HDiv
        broken ``HDiv(order=q, RT=True, discontinuous=True)``.
    time : float
        wall time [s].
    lam_order : int
        polynomial degree of ``lam``.
    lam_rule : int or None
        order of the triangle rule with which the patch sources integrated lam^ (non-polynomial
        lam^ of :class:`.multipliers.ShapedContactMultiplier`; None: the FE mass rule); the
        equilibration check uses the same rule.
    lam_support : ndarray (ne,) of bool, or None
        elements outside of which ``lam`` vanishes identically (lam^ built from per-element vertex values:
        the patch-constant and shaped multipliers of the batched solver, zero on an element whose values are
        all zero); None: not known (lam may be nonzero anywhere).
    """

    sigma: List[GridFunction]
    fields: List[FieldData]
    lam: GridFunction
    order: int
    space: object
    time: float = 0.0
    lam_order: int = 1
    lam_rule: Optional[int] = None
    lam_support: Optional[np.ndarray] = None
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


#: eps of the patch regularization eps (r, w) on straight / curved meshes (module doc)
REGULARIZATION, REGULARIZATION_CURVED = 1e-12, 1e-10


def vertex_device_exact(dv: DiscretizationView, q: int) -> bool:
    """The vertex device (:func:`.moments.vertex_moment_term`) is exact: q <= 2 and affine elements."""
    return q <= 2 and not dv.curved


def patch_regularization(dv: DiscretizationView, given: Optional[float] = None) -> float:
    """``given``, or the default eps: larger on curved meshes (module doc)."""
    if given is not None:
        return float(given)
    return REGULARIZATION_CURVED if dv.curved else REGULARIZATION


def flux_bonus(dv: DiscretizationView) -> int:
    """Extra quadrature order of the flux terms of the patch problems: 4 on curved elements, where the
    integrands are not polynomial, else 0."""
    return 4 if dv.curved else 0


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
    """The SumOfIntegrals ``form`` with every integrand multiplied by ``cf``, compiled (the hat-weighted patch
    forms are assembled once per hat: common subexpressions such as the load are then evaluated once per point)."""
    out = None
    for integral in form:
        term = (cf * integral.coef).Compile() * integral.symbol
        out = term if out is None else out + term
    return out


def patch_solver(dv: DiscretizationView, q: int) -> PatchSolver:
    """The batched :class:`.patches.PatchSolver` of the mesh for RT degree q (cached per
    discretization: reused for every field, every Newton iterate and the algebraic fluxes; told to expect
    repeated calls when the discretization is marked so, :func:`.view.expect_repeated_evaluations`)."""
    c = dv.cache
    key = ("patch_solver", int(q))
    if key not in c:
        _, X, bf, _ = _mixed_patch_problem(dv.mesh, q, 0.0)  # the eps -> 0 limit, exactly (.patches)
        # straight triangles: the element blocks from reference matrices, not from an assembly of the form
        tri = None if dv.curved else AffineTriangles.of(dv.mesh)
        blocks = mixed_element_blocks(tri, X, q, edges=element_edges(dv.fes))
        c[key] = PatchSolver(dv.mesh, X, bf, dv.element_vertices(), blocks=blocks, affine=tri)
    if c.get(REPEATED):  # the estimators of a Newton loop (view.expect_repeated_evaluations)
        c[key].expect_repeats()
    return c[key]


@dataclass
class PatchData:
    """The data of one patchwise equilibration (:func:`equilibrate`): potential ``u`` (H1
    GridFunction), constant ``mu``, ``source`` (w -> SumOfIntegrals, the term -(g, w) before the
    hat weighting, or None), ``hessian`` (Laplacian of u in the integration by parts; False for
    P1), ``bonus_intorder`` of the flux terms, ``name`` of the result, and ``vertex_values``
    (batched solver only): further patch-constant sources, patch a sees -(psi_a g_a, w)
    with g_a|_K = vertex_values[K, i] for the local vertex i of K that is a (exact for every RT
    degree and on curved elements; the vertex device :func:`.moments.vertex_moment_term` is the
    ``PatchwiseSolve`` counterpart, exact for q <= 2 on affine elements), given as a list of
    (values, shape) pairs: g_a|_K = values[K, i] shape (shape None: 1; :class:`.multipliers.ShapedContactMultiplier`);
    ``load``: a further source part ``(owner, w -> SumOfIntegrals)`` that depends only on ``owner`` (a load
    CoefficientFunction whose values do not change while it is the same object), assembled once per owner
    by the batched solver; ``mass``: further sources -(psi_a s g, w) linear in a GridFunction g, given as (g, s,
    order) -- integrated with the triangle rule of that order -- or (g, s, key, form) with form(v, w) the integral
    of v times the test function w (batched: by operators on the space of g assembled once per key,
    :meth:`.patches.PatchSolver.operators`)."""

    u: object
    mu: float
    source: Optional[object] = None
    hessian: bool = True
    bonus_intorder: int = 0
    name: str = "sigma"
    vertex_values: Optional[object] = None
    load: Optional[tuple] = None
    mass: Optional[list] = None


def _flux_terms(u, tau, w, mu, hessian: bool, bonus: int):
    """The u-part of the patch right-hand side (before the hat weighting), linear in u:
    -(mu grad u, tau) - mu (Lap u w + grad u . grad w) + mu <grad u . n, w>_dK."""
    n = specialcf.normal(2)
    gu = grad(u)
    lap = Trace(u.Operator("hesse")) if hessian else CoefficientFunction(0.0)
    lf = (-mu * gu * tau - mu * (lap * w + gu * grad(w))) * dx(bonus_intorder=bonus)
    lf += mu * (gu * n) * w * dx(element_boundary=True, bonus_intorder=bonus)
    return lf


def _patch_rhs(X, d: PatchData, flux_part: bool = True, with_load: bool = True):
    """The right-hand side of the patch problems on X (every term is multiplied by psi_a):
    (s, tau) - (r, div tau) + <tau.n, m> = -(psi_a mu grad u, tau)   [mu constant]
    -(div s, w) - eps (r, w) = -(psi_a g, w) + (mu grad psi_a . grad u, w), with
    (grad psi_a . grad u, w)_K = -(psi_a, Lap u w + grad u . grad w)_K + <psi_a grad u . n, w>_dK.
    ``flux_part=False``: only the source part (None if there is none); ``with_load=False``: without ``d.load``."""
    tau, w = X.TestFunction()[:2]  # X = V x Q x F (PatchwiseSolve) or V x Q (batched: no facet rows)
    lf = _flux_terms(d.u, tau, w, d.mu, d.hessian, d.bonus_intorder) if flux_part else None
    for src in (d.source, d.load[1] if d.load is not None and with_load else None):
        if src is not None:
            lf = src(w) if lf is None else lf + src(w)
    for g, scale, _, form in (_linear_source(e) for e in (d.mass or []) if with_load):
        term = -scale * form(g, w)
        lf = term if lf is None else lf + term
    return lf


def _linear_source(entry):
    """(g, scale, key, form) of a ``PatchData.mass`` entry (the FE mass rule of the given order for (g, s, order))."""
    if len(entry) == 4:
        return entry
    g, scale, order = entry
    return g, scale, ("mass", int(order)), lambda v, w: v * w * dx(intrules={TRIG: IntegrationRule(TRIG, order)})


def _mass_operators(solver: PatchSolver, d: PatchData) -> list:
    """The ``linear`` entries of :meth:`.patches.PatchSolver.solve` for ``d.mass`` (one operator per space and rule)."""
    w = solver.Y.TestFunction()[1]
    out = []
    for g, scale, key, form in (_linear_source(e) for e in d.mass or []):
        trial = g.space.TrialFunction()

        def form_of_hat(hat, trial=trial, form=form):
            return _times(hat, form(trial, w))
        key = (key, id(g.space), g.space.ndof)
        out.append((key, g.space, form_of_hat, g.vec.FV().NumPy(), -float(scale)))
    return out


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

    def reference(solver):  # straight triangles: from reference matrices (.mixed_blocks), else None
        q = int(solver.X.components[1].globalorder)
        return flux_operators(solver.affine, solver.Y, q, space, hessian)

    key = ("flux", id(space), space.ndof, hessian, bonus)
    return key, space, form_of_hat, d.u.vec.FV().NumPy(), float(d.mu), reference


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
        lfs = [_patch_rhs(solver.Y, d, flux_part=lin is None, with_load=False) for d, lin in zip(data, linear)]
        linear = [([] if lin is None else [lin]) + _mass_operators(solver, d) for d, lin in zip(data, linear)]
        vertex = [_vertex_terms(d) for d in data]
        fixed = [d.load for d in data]  # (owner, source): assembled once per owner (PatchSolver.fixed_vectors)
        coefs = solver.solve([None if lf is None else (lambda hat, lf=lf: _times(hat, lf)) for lf in lfs], linear,
                             vertex, fixed)
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


def reconstruct_fluxes(disc, x, y, options: Optional[EstimatorOptions] = None) -> FluxReconstruction:
    """Equilibrated fluxes sigma_alpha_h of a conforming FE solution (module doc).

    Parameters
    ----------
    disc, x, y
        the discretization and the iterate, as in :func:`.bound.estimate`.
    options : EstimatorOptions, optional
        ``flux_order`` (RT degree q), ``multiplier``, ``batched``, ``regularization``.

    Returns
    -------
    FluxReconstruction
    """
    opts = options or EstimatorOptions()
    sv = SolutionView.of(disc, x, y)
    return reconstruct(sv, opts.flux_degree(sv.disc.order), multiplier=opts.multiplier, batched=opts.batched,
                       regularization=opts.regularization, boundary=opts.boundary_multiplier)


def reconstruct(sv: SolutionView, q: int, *, multiplier: Optional[str] = None, batched: bool = True,
                regularization: Optional[float] = None, boundary: bool = True) -> FluxReconstruction:
    """:func:`reconstruct_fluxes` on a solution view, for a given RT degree q.

    Parameters
    ----------
    sv : SolutionView
    q : int
        RT degree (0, 1 or 2 for p = 1; >= 0 otherwise).
    multiplier : {"contact", "fit", "shape", "p1", "dual"}, optional
        multiplier of the patch data for p >= 2 (:mod:`.multipliers`).  Default:
        :class:`.multipliers.PatchContactMultiplier` where the vertex device is exact (q <= 2, straight
        elements), else :class:`.multipliers.ContactMultiplier`.  ``"contact"``: the patch constants
        (for q >= 3 or curved elements only with ``batched``, whose patch-constant sources are exact
        there; else as the default); ``"shape"``: :class:`.multipliers.ShapedContactMultiplier` (batched
        only; else "fit"); ``"fit"``: always the contact-weighted fit; ``"p1"``: the continuous P1
        function with the lumped patch constants (q <= 2); ``"dual"``: the dual-basis lam_h.  p = 1:
        always lam_h (lumped).
    batched : bool
        the batched patch solver of :mod:`.patches` (cached per discretization) instead of NGSolve's
        ``PatchwiseSolve`` (same fluxes to round-off on straight meshes).
    regularization : float, optional
        eps of the ``PatchwiseSolve`` path (default :func:`patch_regularization`).
    boundary : bool
        p >= 2, ``"contact"``, ``"fit"`` and ``"shape"``: the residual multiplier of :mod:`.boundary` where contact
        reaches the Dirichlet boundary.
    """
    t0 = time.perf_counter()
    data, lam, lam_order, lam_rule = _equilibration_data(sv, q, multiplier, batched, boundary)
    sigmas = equilibrate_all(sv.disc.mesh, q, data, regularization=patch_regularization(sv.disc, regularization),
                             solver=patch_solver(sv.disc, q) if batched else None)
    return FluxReconstruction(sigma=sigmas, fields=list(sv.fields), lam=lam, order=q, space=sigmas[0].space,
                              time=time.perf_counter() - t0, lam_order=lam_order, lam_rule=lam_rule,
                              lam_support=_vertex_support(data))


def reconstruct_several(sv: SolutionView, q: int, multipliers, *, boundary: bool = True) -> list:
    """:func:`reconstruct` (batched) for several multipliers at once: the patch problems of all of them in
    one batched solve (one condensation and factorization of the patch matrices for all right-hand sides).
    Each :attr:`FluxReconstruction.time` is the wall time of the whole call."""
    t0 = time.perf_counter()
    parts = [_equilibration_data(sv, q, m, True, boundary) for m in multipliers]
    sigmas = equilibrate_all(sv.disc.mesh, q, [d for part in parts for d in part[0]], solver=patch_solver(sv.disc, q))
    t = time.perf_counter() - t0
    out, n = [], len(sv.fields)
    for j, (_, lam, lam_order, lam_rule) in enumerate(parts):
        sig = sigmas[j * n:(j + 1) * n]
        out.append(FluxReconstruction(sigma=sig, fields=list(sv.fields), lam=lam, order=q, space=sig[0].space,
                                      time=t, lam_order=lam_order, lam_rule=lam_rule,
                                      lam_support=_vertex_support(parts[j][0])))
    return out


def _vertex_support(data) -> Optional[np.ndarray]:
    """The elements outside of which the multiplier of the patch data ``data`` vanishes (mask), when every field's
    multiplier source is given by per-element vertex values (``PatchData.vertex_values``: lam^ = sum of those P1
    functions, each times its shape, zero on an element whose values are all zero) and there is no other multiplier
    source; else None."""
    if not data or any(d.vertex_values is None or d.source is not None for d in data):
        return None
    mask = None
    for d in data:
        for values, _ in d.vertex_values:
            nz = (np.asarray(values) != 0.0).any(axis=1)
            mask = nz if mask is None else mask | nz
    return mask


def _equilibration_data(sv: SolutionView, q: int, multiplier, batched: bool, boundary: bool):
    """(list of PatchData, lam^_h, its degree, its rule order) of :func:`reconstruct`."""
    dv = sv.disc
    p = dv.order
    if q < 0 or (p == 1 and q > 2):
        raise ValueError(f"RT degree q must be 0, 1 or 2 for p = 1 and >= 0 otherwise, got {q}")
    bonus = flux_bonus(dv)
    rules = data_rules(dv)
    auto = multiplier is None
    multiplier = "contact" if multiplier is None else multiplier
    if multiplier not in MULTIPLIERS:
        raise ValueError(f"multiplier must be one of {MULTIPLIERS}, got {multiplier!r}")
    if multiplier == "p1" and q > 2 and p > 1:
        raise ValueError(f"multiplier 'p1' needs RT degree <= 2, got {q}")
    lam_order = 1
    if multiplier == "contact" and p > 1 and (auto or not batched) and not vertex_device_exact(dv, q):
        # default for q >= 3 / curved elements: the weighted fit (sharper than the patch constants on
        # continuous free boundaries); explicit "contact" keeps the patch constants there in the batched
        # path (exact sources), PatchwiseSolve needs the vertex device
        multiplier = "fit"
    vertex_values = None
    if multiplier == "shape" and not batched:
        multiplier = "fit"  # shaped patch sources exist only in the batched solver
    lam_rule = None
    moments = dv.D * sv.y
    if p > 1 and multiplier == "shape":
        lam_rule = patch_solver(dv, q).shaped_rule_order(bonus + 1)
        lam, vertex_values = ShapedContactMultiplier(dv, sv.y, sv.gfs["lam"], rule_order=lam_rule,
                                                     boundary_shape=(lambda: residual_multiplier(sv)) if boundary else None
                                                     ).terms(moments)
        lam_term, lam_order = None, p
    elif p == 1 or multiplier in ("p1", "contact"):
        if p == 1 or multiplier == "p1":
            lam = multiplier_p1(sv)
        else:  # the residual multiplier at the boundary vertices of contact elements (.boundary)
            cmult = PatchContactMultiplier(dv, sv.y)
            lam = cmult(moments, boundary=boundary_vertex_values(sv, cmult.contact) if boundary else None)
        if batched:  # patch-constant sources, exact for every q and on curved elements
            vertex_values = [(vertex_function_values(dv, lam), None)]
            lam_term = None
        else:
            lam_term, lam_dx = vertex_moment_term(dv.mesh, lam, q), dx(intrules={TRIG: vertex_rule()})
    else:  # lam^ (contact-weighted L2 fit) or the dual-basis lam_h: exact product with the FE mass rule
        if multiplier == "fit":
            fit = ContactMultiplier(dv, sv.y)
            lam = fit(moments, boundary=boundary_nodal_values(sv, fit.contact) if boundary else None)
        else:
            lam, lam_order = sv.gfs["lam"], p

        def lam_term(w):
            return lam * w
        lam_dx = dx(intrules=rules["mass"])

    data = []
    for fd in sv.fields:
        def source(w, fd=fd):  # -(psi_a s lam_h, w)
            return -fd.sign * lam_term(w) * lam_dx

        def load(w, f=fd.f):  # -(psi_a f, w), data quadrature as in the FE system; the batched solver assembles
            return -f * w * dx(intrules=rules["load"])  # it once per load object (every multiplier, every iterate)
        data.append(PatchData(u=fd.u, mu=fd.mu, source=None if lam_term is None else source, hessian=p > 1,
                              bonus_intorder=bonus, name=f"sigma_{fd.name}", load=(fd.f, load),
                              vertex_values=None if vertex_values is None else
                              [(fd.sign * v, shape) for v, shape in vertex_values]))
    return data, lam, lam_order, lam_rule
