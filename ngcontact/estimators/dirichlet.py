r"""Correction of non-polynomial Dirichlet data: the lifting w_h, eta_bc and eps_w of :mod:`.bound`.

u_h interpolates g, so u - u_h is not in H^1_0 for non-polynomial g (test 1, test 2), and without
a correction test 1 with p = 2 gives I_eff < 1.  w_h in P_{p+2} has the boundary trace Pi g - u_h
(NGSolve's boundary projection of g), so u~_h = u_h + w_h = g up to O(h^{p+3}); it is discrete
harmonic in the strip of the elements within :func:`strip_layers` vertex layers of the boundary
elements where that trace is not zero and zero beyond ((grad w_h, grad v) = 0 for v in P_{p+2} vanishing
outside the strip and on the boundary): any w_h with that trace is admissible, and the strip keeps its two
sparse Cholesky factorizations small.  Trace values below 1e-13 max |Pi g| are round-off and taken as zero
(as a whole lifting below it is left out): on adaptive meshes the smallest boundary edges, at a re-entrant
corner, then leave the strip.  For P1 the trace error Pi g - I_1 g is one-signed on every edge and
its lifting decays slowly, hence ``STRIP_LAYERS`` layers (``tests/test_estimators.py::
test_dirichlet_lifting_in_a_boundary_strip``); for p >= 2 it oscillates along the edges and its lifting
decays within a layer or two: ``STRIP_LAYERS_HIGH`` layers (``python -m ngcontact.studies.strip_layers``,
``results/estimators/STRIP_LAYERS.md``: I_eff and the estimation time with 8, 2 and 1 layers).

Any divergence-free rho_a in H(div) gives (grad w_ah, grad v) = (grad w_ah + rho_a, grad v) for
v in H^1_0, so eps_w = (sum_a mu_a ||grad w_ah + rho_a||^2)^{1/2} bounds the coupling term
sup_z (w_h, z)_mu / |||z|||.  In 2D the curls rho = curl phi = (d_y phi, -d_x phi), phi in H^1, are
divergence-free; we take the best one in curl P_{k+1} (k = p + 2, or p + 1 for ``"fast"``) among
the phi supported on the strip and zero on its inner boundary (so that rho . n = 0 there and rho
extended by zero is in H(div)): phi solves (grad phi, grad psi) = -(grad w_ah, curl psi) for all
such psi, Neumann on the Dirichlet boundary (one sparse Cholesky for both fields; a tiny mass term
when the strip is the whole mesh).  It is the global minimizer over a space that contains the
divergence-free part of a patchwise equilibration of -grad w_ah.
"""
from __future__ import annotations

import math
from typing import Optional

import numpy as np
from ngsolve import (BND, H1, VOL, BilinearForm, CoefficientFunction, ElementId, GridFunction, InnerProduct,
                     Integrate, LinearForm, dx, grad, specialcf)

from ..discretizations.base import bit_array, bit_mask
from ..domains import DIRICHLET
from .view import DiscretizationView

__all__ = ["STRIP_LAYERS", "STRIP_LAYERS_HIGH", "TRACE_DEFECT_SHARE", "strip_layers", "boundary_strip",
           "dirichlet_correction", "dirichlet_lifting", "trace_defect", "trace_vertices"]

#: element layers along the Dirichlet boundary carrying the Dirichlet-data correction (module doc)
STRIP_LAYERS = 8
#: ... for FE degree p >= 2 (module doc)
STRIP_LAYERS_HIGH = 2
#: the bound counts as proven while the trace defect indicator eta_tr <= TRACE_DEFECT_SHARE * eta (module doc)
TRACE_DEFECT_SHARE = 0.1
#: degrees above that of the lifting at which the data's trace stands for g in :func:`trace_defect`
TRACE_DEFECT_EXTRA = 4


def strip_layers(p: int) -> int:
    """The width of the strip of the Dirichlet correction for FE degree ``p`` (module doc)."""
    return STRIP_LAYERS if p <= 1 else STRIP_LAYERS_HIGH


def boundary_strip(dv: DiscretizationView, layers: int, seed: Optional[np.ndarray] = None):
    """(strip, halo) element masks: the elements within ``layers`` vertex-neighbour layers of the vertices ``seed``
    (a vertex mask; default: those of the Dirichlet boundary), and the next layer (``halo`` empty when the strip is
    the whole mesh)."""
    mesh = dv.mesh
    ev = dv.element_vertices()
    if seed is None:
        V1 = H1(mesh, order=1, dirichlet=DIRICHLET)
        seed = ~bit_mask(V1.FreeDofs())[:mesh.nv]   # Dirichlet boundary vertices
    mark = np.array(seed, dtype=bool)
    strip = np.zeros(mesh.ne, dtype=bool)
    for _ in range(max(int(layers), 1)):
        grown = mark[ev].any(axis=1)
        if grown.sum() == strip.sum():  # the whole (connected) mesh
            break
        strip = grown
        mark = np.zeros(mesh.nv, dtype=bool)
        mark[ev[strip].ravel()] = True
    halo = mark[ev].any(axis=1) & ~strip
    return strip, halo


def trace_vertices(V, dofs: np.ndarray, nv: int) -> np.ndarray:
    """Vertex mask: the vertices of the boundary elements of ``V`` that hold one of the Dirichlet dofs ``dofs``
    (a dof mask: where the trace to lift is not zero)."""
    dofs = dofs & ~bit_mask(V.FreeDofs())
    seed = np.zeros(nv, dtype=bool)
    for el in V.Elements(BND):
        if dofs[list(el.dofs)].any():
            seed[[v.nr for v in el.vertices]] = True
    return seed


def _element_dofs(space, elements) -> np.ndarray:
    """The dof numbers of the elements of the mask ``elements`` (with repetitions)."""
    rows = [space.GetDofNrs(ElementId(VOL, int(e))) for e in np.flatnonzero(elements)]
    if not rows:
        return np.zeros(0, dtype=np.int64)
    if len({len(r) for r in rows}) == 1:  # one order everywhere: one (n, ndof) array, no flattening in Python
        return np.array(rows, dtype=np.int64).ravel()
    return np.concatenate([np.asarray(r, dtype=np.int64) for r in rows])


def dirichlet_correction(dv: DiscretizationView, fields, k: int, rt_order: Optional[int],
                         layers: Optional[int] = None):
    """Liftings w_h in P_k of the Dirichlet data error, discrete harmonic in a boundary strip (module doc).

    Parameters
    ----------
    dv : DiscretizationView
    fields : sequence of FieldData
        the fields (u_ah and g_a).
    k, rt_order : int
        degree of w_h; rho = curl phi with phi in P_{rt_order + 1} (``rt_order`` None: the liftings only, eps_w = 0
        and bc_K the parts of eta_bc^2 alone).
    layers : int, optional
        strip width (default :func:`strip_layers` of the discretization's degree).

    Returns
    -------
    ws : list of GridFunction or None
        w_h per field (None where u_h already has the exact trace).
    eta_bc : float
        |||w_h|||.
    eps_w : float
        (sum_a mu_a ||grad w_ah + rho_a||^2)^{1/2}, rho_a a divergence-free
        equilibration of -grad w_ah (bound of sup_z (w_h, z)_mu / |||z|||).
    bc_K : ndarray or None
        element parts of eta_bc^2 + eps_w^2 (for marking).
    """
    mesh = dv.mesh
    V = H1(mesh, order=k, dirichlet=DIRICHLET)
    ws = []
    trace = np.zeros(V.ndof, dtype=bool)  # dofs where a trace to lift is above round-off (of g's values)
    for fd in fields:
        gg, gu = GridFunction(V), GridFunction(V)
        gg.Set(fd.g, BND)
        gu.Set(fd.u, BND)
        w = GridFunction(V, name=f"w_{fd.name}")
        w.vec.data = gg.vec - gu.vec
        wv = w.vec.FV().NumPy()
        above = np.abs(wv) > 1e-13 * float(np.abs(gg.vec.FV().NumPy()).max())  # round-off in the units of g
        ws.append(w if above.any() else None)
        if above.any():
            wv[~above] = 0.0  # round-off of a zero trace: w_h = 0 there, off the strip
            trace |= above
    if all(w is None for w in ws):
        return ws, 0.0, 0.0, None
    # the strip along the part of the boundary where the trace to lift is not zero (elsewhere w_h = 0 satisfies it)
    strip, halo = boundary_strip(dv, strip_layers(dv.order) if layers is None else layers,
                                 seed=trace_vertices(V, trace, mesh.nv))
    inner = halo.any()
    on_strip = bit_array(strip)
    dxs = dx(definedonelements=on_strip)
    # w_h: discrete harmonic in the strip, zero on its inner boundary (extended by zero)
    free_v = np.zeros(V.ndof, dtype=bool)
    free_v[_element_dofs(V, strip)] = True
    free_v &= bit_mask(V.FreeDofs())
    if inner:
        free_v[_element_dofs(V, halo)] = False
    u, v = V.TnT()
    a = BilinearForm(grad(u) * grad(v) * dxs).Assemble()
    inv = a.mat.Inverse(bit_array(free_v), inverse="sparsecholesky")
    # divergence-free rho = curl phi, phi in P_{q+1} on the strip, phi = 0 on its inner boundary (so that
    # rho . n = 0 there and rho extended by zero is in H(div)); no inner boundary: the tiny mass term
    # fixes the constant
    if rt_order is not None:
        W = H1(mesh, order=rt_order + 1)
        free_w = np.zeros(W.ndof, dtype=bool)
        free_w[_element_dofs(W, strip)] = True
        if inner:
            free_w[_element_dofs(W, halo)] = False
        ph, ps = W.TnT()
        curl_ps = CoefficientFunction((grad(ps)[1], -grad(ps)[0]))
        c = BilinearForm(grad(ph) * grad(ps) * dxs + (0.0 if inner else 1e-10) * ph * ps * dxs).Assemble()
        cinv = c.mat.Inverse(bit_array(free_w), inverse="sparsecholesky")
    bc2 = eps2 = 0.0
    loc = np.zeros(mesh.ne)
    for fd, w in zip(fields, ws):
        if w is None:
            continue
        r = w.vec.CreateVector()
        r.data = a.mat * w.vec
        w.vec.data -= inv * r  # discrete harmonic in the strip: (grad w, grad v) = 0 for v in P_k, v = 0 off it
        # w and rho vanish off the strip (their dofs are those of strip elements): integrals on the strip only
        b_K = fd.mu * Integrate(grad(w) * grad(w) * dxs, mesh, element_wise=True).NumPy()
        e_K = np.zeros(mesh.ne)
        if rt_order is not None:
            phi = GridFunction(W, name=f"phi_{fd.name}")
            phi.vec.data = cinv * LinearForm(-grad(w) * curl_ps * dxs).Assemble().vec
            rho = CoefficientFunction((grad(phi)[1], -grad(phi)[0]))  # div rho = 0
            e_K = fd.mu * Integrate((grad(w) + rho) ** 2 * dxs, mesh, element_wise=True).NumPy()
        bc2 += float(b_K.sum())
        eps2 += float(e_K.sum())
        loc += b_K + e_K
    return ws, math.sqrt(max(bc2, 0.0)), math.sqrt(max(eps2, 0.0)), loc


def dirichlet_lifting(dv: DiscretizationView, fields, mode):
    """(ws, eta_bc, eps_w, bc_K) of :func:`dirichlet_correction` with w_h in P_{p+2}; ``mode``:
    True (rho in curl P_{p+3}), "fast" (curl P_{p+2}) or False (no correction).

    w_h depends only on the boundary trace of u_h, i.e. on the discretization's Dirichlet values (the
    algebraic solution holds interior nodes only): computed once per discretization and mode, shared by
    every estimate and every iterate of :mod:`.components`."""
    if not mode:
        return [None] * len(fields), 0.0, 0.0, None
    key = ("bc", mode)
    if key not in dv.cache:
        k = dv.order + 2
        dv.cache[key] = dirichlet_correction(dv, fields, k, k - 1 if mode == "fast" else k)
    return dv.cache[key]


def trace_defect(dv: DiscretizationView, fields, k: int, key=None) -> float:
    """The indicator eta_tr of the Dirichlet data part g - Pi_k g that a lifting of degree ``k`` leaves out (module
    doc), with g taken as its boundary projection of degree k + :data:`TRACE_DEFECT_EXTRA`; cached per
    discretization and ``k`` (or under ``key``: data other than the fields' own, e.g. an obstacle's trace).
    Boundary-only spaces: the cost is that of the Dirichlet edges."""
    key = ("trace", k) if key is None else key
    if key in dv.cache:
        return dv.cache[key]
    mesh = dv.mesh
    bnd = mesh.Boundaries(DIRICHLET)
    hi = k + TRACE_DEFECT_EXTRA
    Vk = H1(mesh, order=k, dirichlet=DIRICHLET, definedon=bnd)
    Vh = H1(mesh, order=hi, dirichlet=DIRICHLET, definedon=bnd)
    h, t = specialcf.mesh_size, specialcf.tangential(2)
    total = 0.0
    for fd in fields:
        low, high, d = GridFunction(Vk), GridFunction(Vh), GridFunction(Vh)
        low.Set(fd.g, BND)
        high.Set(fd.g, BND)
        d.Set(low, BND)  # exact: Pi_k g is a polynomial of degree k <= hi on every edge
        d.vec.data -= high.vec  # Pi_k g - Pi_hi g (d.vec.data = high.vec - d.vec would alias d.vec)
        total += fd.mu * Integrate(d * d / h + h * InnerProduct(grad(d), t) ** 2, mesh, BND, definedon=bnd,
                                   order=2 * hi)
    dv.cache[key] = math.sqrt(max(total, 0.0))
    return dv.cache[key]
