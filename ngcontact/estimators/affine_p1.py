r"""The element terms of :mod:`.components` for P1 on affine elements, from arrays built once per mesh.

Every function in the estimator terms of a P1 iterate is, on each (affine) element K, a polynomial --
u_ah, lam^_h, r^_a, the gap correction c_h (P_1, vertex values), sigma_a,disc in RT_1 (in P_2^2,
divergence in P_1), sigma_a,alg in RT_0 or RT_1 -- except the load f_a.  Their element integrals are
therefore exact closed forms in the values at the three vertices of K,

    (a, b)_K = |K|/12 (sum_j a_j b_j + sum_j a_j sum_j b_j),   (a, 1)_K = |K|/3 sum_j a_j,

or, for the squares of the RT fields, the sums of the 6-point rule exact for degree 4; the values of
an RT field at these points are a fixed linear map of its element coefficients (evaluated once per
mesh with unit coefficients: the broken spaces are element-local).  The load enters through
the residual f + m - div sigma, split exactly at every quadrature point as o_f + e with
o_f = f - Pi f (Pi: the L2(K) projection onto P_1 in the load rule of the FE system, computed once per
load) and e = Pi f + m - div sigma in P_1, so that with the rules that NGSolve uses for these
integrals in :mod:`.components` (order 5 + bonus: the integrand is not polynomial),

    ||f + m - div sigma||_K^2 = ||o_f||_K^2 + 2 (o_f, e)_K + ||e||_K^2,

where ||o_f||_K^2 and (o_f, lambda_j)_K are kept per load; likewise the element means (rule of order
13 + bonus) and the contact work (f, c_h)_K.  The values equal those of the quadrature path of
:mod:`.components` to round-off (``tests/test_affine_p1.py``), at the cost of a few array operations
per evaluation instead of about twenty quadrature passes over the mesh.
"""
from __future__ import annotations

import math

import numpy as np
from ngsolve import VOL, GridFunction, IntegrationRule

from .nonnegative import QuadratureArrays
from .patches import local_hats

__all__ = ["P1Arrays", "applies"]


def applies(dv, opts, exact_bc: bool, sigma_alg=None) -> bool:
    """Whether :class:`P1Arrays` computes the terms: P1 two-membrane problem on affine elements, RT_1
    disc fluxes, exact Dirichlet data, batched patch solver, no concentrated multiplier, an algebraic flux
    (if given) in a broken RT space of degree <= 1 (and ``opts.closed_form``)."""
    def broken(sigma):
        flags = sigma.space.flags.ToDict()
        return bool(flags.get("discontinuous")) and flags.get("RT") and flags.get("order", 99) <= 1
    return (opts.closed_form and dv.order == 1 and not dv.curved and dv.obstacle is None and opts.flux_degree(1) == 1
            and exact_bc and opts.batched and not opts.concentrates(1)
            and (sigma_alg is None or all(broken(s) for s in sigma_alg)))


def _mass(a, b, area):
    """(a, b)_K for P1 functions given by vertex values (ne, 3)."""
    return area / 12.0 * ((a * b).sum(axis=1) + a.sum(axis=1) * b.sum(axis=1))


class P1Arrays:
    """Per-mesh arrays of the affine P1 terms (module docstring); cached in the discretization's cache
    (:meth:`of`)."""

    def __init__(self, dv, area: np.ndarray, bonus: int):
        mesh = dv.mesh
        self.mesh, self.area, self.bonus = mesh, area, bonus
        # vertex numbers at the reference points (1, 0), (0, 1), (0, 0): lambda_j = xi, eta, 1 - xi - eta
        self.ir = IntegrationRule(points=[(1, 0), (0, 1), (0, 0)], weights=[0.0] * 3)
        self.mips = mesh.MapToAllElements(self.ir, VOL)
        ev = dv.element_vertices()
        coords = np.asarray(mesh.ngmesh.Coordinates())[:, :2]
        from ngsolve import CoefficientFunction, x, y

        pts = np.asarray(CoefficientFunction((x, y))(self.mips)).reshape(mesh.ne, 3, 2)
        dist = ((coords[ev][:, None, :, :] - pts[:, :, None, :]) ** 2).sum(axis=-1)  # (ne, point, local vertex)
        self.pv = np.take_along_axis(ev, dist.argmin(axis=2), axis=1)
        if not np.array_equal(self.pv, ev):  # NGSolve: vertex j of an element sits at the j-th reference point
            raise RuntimeError("the local vertex order of the mesh elements is not that of the reference points")
        self._hat_gfs = None
        P = coords[self.pv]                                   # (ne, 3, 2)
        e1, e2 = P[:, 0] - P[:, 2], P[:, 1] - P[:, 2]
        det = e1[:, 0] * e2[:, 1] - e1[:, 1] * e2[:, 0]
        # grad lambda_0, grad lambda_1 (rows of J^-T), grad lambda_2 = -(sum)
        g0 = np.stack([e2[:, 1], -e2[:, 0]], axis=1) / det[:, None]
        g1 = np.stack([-e1[:, 1], e1[:, 0]], axis=1) / det[:, None]
        self.grad_lam = np.stack([g0, g1, -g0 - g1], axis=1)  # (ne, 3, 2)
        self._rules = dv.cache.setdefault("quadrature_arrays", {})  # shared with terms.Integrals.quadrature
        self.q4 = self.rule(4)  # exact for the squares of RT_1 fields
        self._rt = {}
        self._loads = {}

    @classmethod
    def of(cls, dv, area, bonus: int) -> "P1Arrays":
        key = ("affine_p1", int(bonus))
        if key not in dv.cache:
            dv.cache[key] = cls(dv, area, bonus)
        return dv.cache[key]

    def rule(self, order: int) -> QuadratureArrays:
        """The points and weights of the triangle rule of ``order`` on every element (kept)."""
        if order not in self._rules:
            self._rules[order] = QuadratureArrays(self.mesh, order)
        return self._rules[order]

    # ------------------------------------------------------------ fields at the vertices of every element
    def vertex_values(self, gf) -> np.ndarray:
        """(ne, 3) vertex values of a P1 GridFunction (H1 order 1: dof = vertex)."""
        return np.asarray(gf.vec.FV().NumPy())[self.pv]

    def gradient(self, vals: np.ndarray) -> np.ndarray:
        """(ne, 2) gradient of the P1 function with vertex values ``vals``."""
        return np.einsum("kj,kjd->kd", vals, self.grad_lam)

    def rt(self, sigma):
        """(values (ne, nq, 2) at the points of :attr:`q4`, divergence (ne, 3) at the vertices) of a broken
        RT_q (q <= 1) GridFunction."""
        space = sigma.space
        key = id(space)
        if key not in self._rt:
            ne = self.mesh.ne
            nV = space.ndof // ne
            from ngsolve import div

            nq = self.q4.W.shape[1]
            E, D = np.empty((ne, nq, 2, nV)), np.empty((ne, 3, nV))
            unit = GridFunction(space)
            for j in range(nV):
                c = np.zeros((ne, nV))
                c[:, j] = 1.0
                unit.vec.FV().NumPy()[:] = c.ravel()
                E[..., j] = np.asarray(unit(self.q4.mips)).reshape(ne, nq, 2)
                D[..., j] = np.asarray(div(unit)(self.mips)).reshape(ne, 3)
            self._rt[key] = (space, E, D)  # the space is kept alive: its id stays unique
        _, E, D = self._rt[key]
        c = np.asarray(sigma.vec.FV().NumPy()).reshape(self.mesh.ne, -1)
        ne, nq = E.shape[:2]
        return (np.matmul(E.reshape(ne, 2 * nq, -1), c[:, :, None]).reshape(ne, nq, 2),
                np.matmul(D, c[:, :, None])[:, :, 0])

    # ------------------------------------------------------------ the load
    def seen(self, loads) -> bool:
        """Whether every load object was met before (registering the new ones): a load that changes with every
        evaluation (the time-step loads f - tau of :mod:`ngcontact.timestepping.estimate`) is cheaper by
        quadrature than by building its arrays, so the closed form starts with the second evaluation of a load."""
        new = [f for f in loads if not (id(f) in self._loads and self._loads[id(f)][0] is f)]
        for f in new:
            if len(self._loads) >= 4:
                self._loads.pop(next(iter(self._loads)))
            self._loads[id(f)] = (f, None)  # the load is referenced: its id stays unique
        return not new

    def load(self, f, load_order: int) -> dict:
        """Per-load arrays (kept while ``f`` is the same object; the last four loads): Pi f at the vertices,
        ||o_f||_K^2, (o_f, lambda_j)_K and (f, lambda_j)_K in the rule of order 5 + bonus, (o_f, 1)_K in the
        rule of order 13 + bonus.  Element-wise ``Integrate`` with those rules (the integrand compiled): eleven
        passes in C++, no values of f at the points held in Python."""
        hit = self._loads.get(id(f))
        if hit is not None and hit[0] is f and hit[1] is not None:
            return hit[1]
        from ngsolve import Integrate

        ne, area, mesh = self.mesh.ne, self.area, self.mesh
        hats = self._hats()
        fc = f.Compile()

        def per_vertex(cf, order):  # (cf, lambda_j)_K, j: the local vertex (that of pv)
            return np.stack([np.asarray(Integrate((cf * h).Compile(), mesh, order=order, element_wise=True))
                             for h in hats], axis=1)

        def per_element(cf, order):
            return np.asarray(Integrate(cf.Compile(), mesh, order=order, element_wise=True))

        b = per_vertex(fc, load_order)                                       # (f, lambda_j)_K, load rule
        pif = 12.0 / area[:, None] * (b - b.sum(axis=1, keepdims=True) / 4.0)  # the P1 mass matrix inverted
        pi_gf = GridFunction(hats[0].space)
        pi_gf.vec.FV().NumPy()[:] = pif.ravel()
        o = f - pi_gf                                                        # o_f = f - Pi f
        r1, r2 = 5 + self.bonus, 13 + self.bonus
        out = {"pi": pif, "oo": per_element(o * o, r1), "ol": per_vertex(o, r1), "fl": per_vertex(fc, r1),
               "o1": per_element(o, r2)}
        if id(f) not in self._loads and len(self._loads) >= 4:
            self._loads.pop(next(iter(self._loads)))
        self._loads[id(f)] = (f, out)
        assert out["pi"].shape == (ne, 3)
        return out

    def _hats(self):
        """The barycentric coordinates lambda_j of every element (:func:`.patches.local_hats`, kept; local vertex j
        is ``pv[K, j]``, checked in the constructor)."""
        if self._hat_gfs is None:
            self._hat_gfs = local_hats(self.mesh)
        return self._hat_gfs

    # ------------------------------------------------------------ the terms
    def mass(self, a, b) -> np.ndarray:
        return _mass(a, b, self.area)

    def norm2(self, v) -> np.ndarray:
        """||v||_K^2 of a vector field given at the points of :attr:`q4` (ne, nq, 2)."""
        return self.q4.integrate((v * v).sum(axis=2))

    def mean(self, a) -> np.ndarray:
        """(a, 1)_K / |K| of a P1 function (vertex values (ne, 3))."""
        return a.sum(axis=1) / 3.0

    def flux_parts(self, fields, sigmas, data, load_order: int):
        """The ``parts`` of :func:`.terms.flux_residual`: i -> (||fl||_K^2, ||f + m - div sigma||_K^2, element
        means of f + m - div sigma), fl = mu^{1/2} grad u + mu^{-1/2} sigma, for the P1 fields, RT_1 fluxes
        and P1 data m."""
        def part(i):
            fd, mu = fields[i], fields[i].mu
            sv, dsv = self.rt(sigmas[i])
            fl = math.sqrt(mu) * self.gradient(self.vertex_values(fd.u))[:, None, :] + sv / math.sqrt(mu)
            L = self.load(fd.f, load_order)
            e = L["pi"] + self.vertex_values(data[i]) - dsv
            res2 = L["oo"] + 2.0 * (L["ol"] * e).sum(axis=1) + self.mass(e, e)
            return self.norm2(fl), res2, (L["o1"] + self.area / 3.0 * e.sum(axis=1)) / self.area
        return part

    def alg_parts(self, r_hat, sigma_alg):
        """The ``parts`` of :func:`.algebraic.algebraic_terms` for P1 r^ and an RT_0/RT_1 sigma_alg (or None)."""
        def part(a):
            r = self.vertex_values(r_hat[a])
            sa2 = None
            if sigma_alg is not None:
                sv, dsv = self.rt(sigma_alg[a])
                r, sa2 = r - dsv, float(self.norm2(sv).sum())
            return (sa2,) + self._mean_free(r)
        return part

    def defect_parts(self, delta):
        """The ``parts`` of :func:`.terms.defect_norm` for a P1 function."""
        return self._mean_free(self.vertex_values(delta))

    def _mean_free(self, v):
        """(element means, ||v - mean_K v||_K^2) of a P1 function, without the cancellation of
        ||v||^2 - |K| mean^2."""
        m = self.mean(v)
        d = v - m[:, None]
        return m, self.mass(d, d)

    def grad_sq(self, c) -> np.ndarray:
        """||grad c||_K^2 of a P1 function."""
        g = self.gradient(self.vertex_values(c))
        return self.area * (g * g).sum(axis=1)

    def contact(self, fields, lam, c, t: float, load_order: int):
        """(eta_C,K = 2 (lam, g_h)_K, 2 (lam, c)_K summed, Theta of :func:`.terms.contact_work` for v = (t c,
        -(1 - t) c)) for the P1 multiplier ``lam``, the gap u1h - u2h and the P1 correction ``c`` (or None)."""
        lv = self.vertex_values(lam)
        u = [self.vertex_values(fd.u) for fd in fields]
        eta_C = 2.0 * self.mass(lv, u[0] - u[1])
        if c is None:
            return eta_C, 0.0, 0.0
        cv = self.vertex_values(c)
        gc = self.gradient(cv)
        theta = np.zeros(self.mesh.ne)  # summed per element (work and load nearly cancel)
        for coef, fd, uv in zip((t, -(1.0 - t)), fields, u):
            work = fd.mu * self.area * (self.gradient(uv) * gc).sum(axis=1)
            theta += coef * (work - (self.load(fd.f, load_order)["fl"] * cv).sum(axis=1))
        return eta_C, 2.0 * float(self.mass(lv, cv).sum()), float(theta.sum())
